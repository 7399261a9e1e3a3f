"""Whole-codec estimate of a per-file SH KLT, outside the format (docs/design/sh-klt.md).

    .venv/bin/python bench/bench_sh_klt_codec_probe.py SCENE BYTES[,BYTES...] auto,rgb,klt [--out JSON]

Mode klt: the SH rest of every Gaussian (one 3K-vector, RGB) turned by the principal axes of
their covariance, encoded by the size search as if it were RGB (``sh_colour="rgb"``, so the DC is
not turned either), every render the search judges turned back first (the judge's ``rgb_view``
replaced for the run), the file decoded and turned back, then scored by gsz-eval's protocol (8
default test views at 800 px) against the original.  Modes auto and rgb: the codec as it is,
with ``--sh-colour auto`` / ``rgb``.  Prints one row per (mode, budget); the matrix's own bytes
are not counted (D^2 floats, 4 kB at SH 3) and nothing of it is in the file: a probe.
"""
import sys, json, subprocess, dataclasses, os
import numpy as np
from gsz.decoder.ply import read_ply, write_ply
from gsz.decoder.decode import decode
from gsz.decoder.cloud import MadeRows
from gsz.encoder.search.driver import encode_to_budget
from gsz.encoder.search.options import SearchOptions
import gsz.encoder.search.judge as J
scene, budgets, modes = sys.argv[1], [int(b) for b in sys.argv[2].split(',')], sys.argv[3].split(',')
out = sys.argv[sys.argv.index('--out') + 1] if '--out' in sys.argv else None
orig = read_ply(scene)
n = len(orig.positions); k = orig.sh_rest.shape[1]
x = np.asarray(orig.sh_rest, np.float64).reshape(n, -1)
_, Q = np.linalg.eigh(np.cov(x.T)); Q = Q[:, ::-1]          # columns: principal axes
to_klt = lambda v: (np.asarray(v, np.float64).reshape(len(v), -1) @ Q).astype(np.float32).reshape(len(v), k, 3)
from_klt = lambda v: (np.asarray(v, np.float64).reshape(len(v), -1) @ Q.T).astype(np.float32).reshape(len(v), k, 3)
rgb_view0 = J.rgb_view
def klt_view(cloud, colour):
    rest = cloud.sh_rest
    rest = rest.rows(0, len(rest)) if isinstance(rest, MadeRows) else np.asarray(rest)
    if rest.ndim < 2 or rest.shape[1] != k:
        return rgb_view0(cloud, colour)
    return rgb_view0(dataclasses.replace(cloud, sh_rest=from_klt(rest)), colour)
import tempfile
tmp = os.path.join(tempfile.mkdtemp(prefix='gsz-klt-'), 'decoded.ply')
res = []
for mode in modes:
    for b in budgets:
        cloud = read_ply(scene)
        opts = SearchOptions(sh_colour="rgb" if mode == "klt" else mode)
        if mode == "klt":
            cloud = dataclasses.replace(cloud, sh_rest=to_klt(cloud.sh_rest)); J.rgb_view = klt_view
        else:
            J.rgb_view = rgb_view0
        r = encode_to_budget(cloud, b, options=opts)
        dec = decode(r.data)
        if mode == "klt" and dec.sh_rest.shape[1] == k:
            dec = dataclasses.replace(dec, sh_rest=from_klt(dec.sh_rest))
        write_ply(dec, tmp)
        p = subprocess.run([os.path.join(os.path.dirname(sys.executable), 'gsz-eval'), scene, tmp, '--json'], capture_output=True, text=True)
        ev = json.loads(p.stdout)
        row = dict(mode=mode, budget=b, bytes=len(r.data), test_psnr=round(ev['psnr'],2))
        print(row, flush=True); res.append(row)
if out:
    with open(out, 'a') as f:
        for row in res:
            f.write(json.dumps(dict(scene=os.path.basename(scene), **row)) + '\n')
