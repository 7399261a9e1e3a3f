// Writes .spz fixtures with the official SPZ library (@adobe/spz, the WASM build splat-transform bundles).
import fs from 'fs';
import createSpzModule from "@adobe/spz";

function readPly(path) {
    const buf = fs.readFileSync(path);
    const end = buf.indexOf('end_header\n') + 'end_header\n'.length;
    const head = buf.subarray(0, end).toString('ascii').split('\n');
    const n = parseInt(head.find((l) => l.startsWith('element vertex')).split(' ')[2]);
    const names = head.filter((l) => l.startsWith('property float')).map((l) => l.split(' ')[2]);
    const body = new Float32Array(buf.buffer.slice(buf.byteOffset + end, buf.byteOffset + end + n * names.length * 4));
    const col = (name) => { const j = names.indexOf(name); return Float32Array.from({ length: n }, (_, i) => body[i * names.length + j]); };
    return { n, names, col };
}

function toCloud(ply) {
    const { n, names, col } = ply;
    const rest = names.filter((s) => s.startsWith('f_rest_')).length;
    const k = rest / 3;
    const shDegree = { 0: 0, 3: 1, 8: 2, 15: 3 }[k];
    const c = (s) => col(s);
    const [x, y, z] = ['x', 'y', 'z'].map(c);
    const sc = ['scale_0', 'scale_1', 'scale_2'].map(c);
    const dc = ['f_dc_0', 'f_dc_1', 'f_dc_2'].map(c);
    const rot = ['rot_0', 'rot_1', 'rot_2', 'rot_3'].map(c);
    const op = c('opacity');
    const fr = Array.from({ length: rest }, (_, i) => c(`f_rest_${i}`));
    const positions = new Float32Array(n * 3), scales = new Float32Array(n * 3), colors = new Float32Array(n * 3);
    const rotations = new Float32Array(n * 4), alphas = new Float32Array(n), sh = new Float32Array(n * rest);
    for (let i = 0; i < n; i++) {
        positions.set([x[i], y[i], z[i]], i * 3);
        scales.set([sc[0][i], sc[1][i], sc[2][i]], i * 3);
        colors.set([dc[0][i], dc[1][i], dc[2][i]], i * 3);
        rotations.set([rot[1][i], rot[2][i], rot[3][i], rot[0][i]], i * 4);   // spz: x y z w
        alphas[i] = op[i];
        for (let j = 0; j < k; j++) for (let ch = 0; ch < 3; ch++) sh[i * rest + j * 3 + ch] = fr[ch * k + j][i];
    }
    return { numPoints: n, shDegree, antialiased: false, extensions: [], positions, scales, rotations, alphas, colors, sh };
}

const spz = await createSpzModule();
const [, , src, out, version, from, ext] = process.argv;
const cloud = toCloud(readPly(src));
if (ext) {
    const e = new spz.SpzExtensionCoordinateSystemAdobe();
    e.coordinateSystem = spz.CoordinateSystem[ext];
    cloud.extensions = [e];
}
const bytes = spz.saveSpzToBuffer(cloud, { version: parseInt(version), from: spz.CoordinateSystem[from], sh1Bits: 5, shRestBits: 4 });
fs.writeFileSync(out, bytes);
console.log(out, bytes.length, 'extension support', spz.SpzHasExtensionSupport());
