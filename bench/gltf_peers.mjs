// Independent glTF tools run on gsz's files (installed by bench/bench_gltf.py into bench/.peers):
//
//   node bench/gltf_peers.mjs validate FILE...   Khronos glTF-Validator report per file (JSON on stdout)
//   node bench/gltf_peers.mjs three FILE OUTDIR   three.js GLTFLoader + its KHR_gaussian_splatting
//                                                 plugin: writes what the loader built (centres,
//                                                 covariances, RGBA bytes, packed SH bands) to OUTDIR
//
// The Python side (bench/bench_gltf.py, tests/test_gltf_peers.py) compares those with the values
// gsz started from.  Node resolves the packages from bench/.peers/node_modules (NODE_PATH does not
// apply to ES modules, so they are imported through createRequire / file URLs).
import { createRequire } from 'node:module';
import { readFileSync, writeFileSync, mkdirSync } from 'node:fs';
import { basename, dirname, join } from 'node:path';
import { fileURLToPath, pathToFileURL } from 'node:url';

const peers = join(dirname(fileURLToPath(import.meta.url)), '.peers', 'node_modules');
const require = createRequire(join(peers, 'noop.js'));

async function validate(files) {
    const validator = require('gltf-validator');
    const out = [];
    for (const file of files) {
        const bytes = new Uint8Array(readFileSync(file));
        const report = await validator.validateBytes(bytes, {
            uri: basename(file),
            maxIssues: 100,
            externalResourceFunction: (uri) => Promise.resolve(new Uint8Array(readFileSync(join(dirname(file), decodeURIComponent(uri))))),
        });
        out.push({
            file,
            validatorVersion: report.validatorVersion,
            numErrors: report.issues.numErrors,
            numWarnings: report.issues.numWarnings,
            numInfos: report.issues.numInfos,
            numHints: report.issues.numHints,
            messages: report.issues.messages.map((m) => ({ code: m.code, severity: m.severity, message: m.message, pointer: m.pointer })),
        });
    }
    process.stdout.write(JSON.stringify(out, null, 1) + '\n');
}

async function three(file, outdir) {
    const threeRoot = pathToFileURL(join(peers, 'three', 'examples', 'jsm')).href;
    const { GLTFLoader } = await import(`${threeRoot}/loaders/GLTFLoader.js`);
    const { GLTFGaussianSplatLoaderExtension } = await import(`${threeRoot}/loaders/GLTFGaussianSplatLoaderExtension.js`);
    const data = readFileSync(file);
    const loader = new GLTFLoader();
    loader.register((parser) => new GLTFGaussianSplatLoaderExtension(parser));
    const gltf = await loader.parseAsync(data.buffer.slice(data.byteOffset, data.byteOffset + data.byteLength), '');
    const splats = [];
    gltf.scene.traverse((o) => { if (o.isGaussianSplat || o.constructor.name === 'GaussianSplat') splats.push(o); });
    if (splats.length !== 1) throw new Error(`expected one GaussianSplat, found ${splats.length}`);
    const geometry = splats[0].splatGeometry ?? splats[0].geometry;   // the splat data (geometry is its quad)
    mkdirSync(outdir, { recursive: true });
    const meta = { count: null, attributes: {} };
    for (const [name, attr] of Object.entries(geometry.attributes)) {
        const array = attr.array;
        writeFileSync(join(outdir, `${name}.bin`), Buffer.from(array.buffer, array.byteOffset, array.byteLength));
        meta.attributes[name] = { type: array.constructor.name, itemSize: attr.itemSize, count: attr.count };
    }
    for (const [key, value] of Object.entries(geometry.userData || {})) {
        if (ArrayBuffer.isView(value)) {
            writeFileSync(join(outdir, `userData.${key}.bin`), Buffer.from(value.buffer, value.byteOffset, value.byteLength));
            meta.attributes[`userData.${key}`] = { type: value.constructor.name };
        }
    }
    writeFileSync(join(outdir, 'meta.json'), JSON.stringify(meta, null, 1));
    process.stdout.write(JSON.stringify(meta) + '\n');
}

const [cmd, ...args] = process.argv.slice(2);
if (cmd === 'validate') await validate(args);
else if (cmd === 'three') await three(args[0], args[1]);
else { process.stderr.write('usage: gltf_peers.mjs validate FILE... | three FILE OUTDIR\n'); process.exit(2); }
