// Writes .ksplat fixtures with mkkellogg's GaussianSplats3D library (what its util/create-ksplat.js does).
import * as GaussianSplats3D from '@mkkellogg/gaussian-splats-3d';
import * as fs from 'fs';
const [, , src, out, level, shDegree] = process.argv;
const data = fs.readFileSync(src);
const buf = data.buffer.slice(data.byteOffset, data.byteOffset + data.byteLength);
const splatArray = GaussianSplats3D.PlyParser.parseToUncompressedSplatArray(buf, parseInt(shDegree));
// alpha removal threshold 0: keep every Gaussian; default section size, scene centre, block and bucket sizes
const gen = GaussianSplats3D.SplatBufferGenerator.getStandardGenerator(0, parseInt(level), 0, undefined, undefined, undefined);
const sb = gen.generateFromUncompressedSplatArray(splatArray);
fs.writeFileSync(out, Buffer.from(sb.bufferData));
console.log(out, sb.bufferData.byteLength, sb.getSplatCount());
