"""How visible a squared error is depends on how it is spread: rendered image MSE per unit of
parameter SSE for errors shaped like the codec's, relative to the i.i.d. per-Gaussian noise the
allocation's channel weights are measured with (encoder/search/sensitivity.py).

    .venv/bin/python bench/bench_coherence.py SCENE.ply [--depth 14] [--views 4] [--codebooks 65,262,1024]
        [--noise] [--out bench/out/coherence_<scene>.json]

Two probes, every render at gsz-eval's 800 px on the scene's default train cameras:

* RAHT bands: the DC colour (red channel's RAHT over the Morton tree of the scene's positions at
  --depth, one Gaussian per occupied voxel) with i.i.d. noise added to one band of AC
  coefficients at a time (bands by stream position, coarse levels first; a coefficient at
  stream index i spans about N / (i + 1) Gaussians), the same total SSE for every band.
* SH codebooks: the SH rest replaced by its k-means reconstruction (gsz's own trainer), against
  noise of the same SSE i.i.d. and against the same error vectors shuffled across Gaussians.

A factor above 1 says the error renders worse than the i.i.d. weight predicts: neighbouring
Gaussians err alike and their errors add in a pixel instead of averaging out.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(Path(__file__).resolve().parent))
from rd import gsz_source, machine  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scene")
    ap.add_argument("--depth", type=int, default=14)
    ap.add_argument("--views", type=int, default=4)
    ap.add_argument("--codebooks", default="65,262,1024")
    ap.add_argument("--noise", action="store_true", help="of the RD bench's noised variant (bench_codec.add_noise)")
    ap.add_argument("--out", default=None)
    a = ap.parse_args(argv)

    import gsz
    from gsz.decoder.cloud import GaussianCloud
    from gsz.decoder.morton import morton_encode
    from gsz.decoder.raht import build_raht_tree, raht_inverse
    from gsz.encoder.raht import raht_forward
    from gsz.encoder.vq import assign, train_codebook
    from gsz.evaluation.cameras import load_cameras
    from gsz.evaluation.render import render

    t0 = time.time()
    path = Path(a.scene)
    c = gsz.read_ply(path)
    if a.noise:
        from bench_codec import add_noise
        c = add_noise(c)
    n = len(c)
    cams = load_cameras(None, c, n_test=8, width=800).train[:a.views]
    base = [render(c, k).image.astype(np.float64) for k in cams]
    rng = np.random.default_rng(0)

    def mse(cloud) -> float:
        return float(np.mean([((render(cloud, k).image - b) ** 2).mean() for k, b in zip(cams, base)]))

    def variant(**kw) -> GaussianCloud:
        f = dict(positions=c.positions, scales=c.scales, rotations=c.rotations, opacities=c.opacities,
                 sh_dc=c.sh_dc, sh_rest=c.sh_rest, sh_degree=c.sh_degree)
        f.update(kw)
        return GaussianCloud(**f)

    # --- RAHT bands of the DC colour (red) ---------------------------------------------------
    p = c.positions.astype(np.float64)
    lo = p.min(0)
    side = float((p.max(0) - lo).max()) * 1.0001
    codes = morton_encode(np.floor((p - lo) / side * (1 << a.depth)).astype(np.int64))
    uniq, first = np.unique(codes, return_index=True)
    tree = build_raht_tree(uniq, a.depth, None)
    dc_all = c.sh_dc.reshape(n, -1).astype(np.float64)
    red = dc_all[first, :1]
    r_dc, r_ac = raht_forward(red, tree)

    def with_red(values) -> GaussianCloud:
        d = dc_all.copy()
        d[first, 0] = values[:, 0]
        return variant(sh_dc=d.reshape(c.sh_dc.shape).astype(np.float32))
    sigma = 0.02
    noisy = red + rng.normal(0, sigma, red.shape)
    sse_iid = float(((noisy - red) ** 2).sum())
    w_iid = mse(with_red(noisy)) / sse_iid
    m = r_ac.shape[0]
    edges = sorted({0, m} | {int(m * f) for f in (0.001, 0.004, 0.016, 0.06, 0.2, 0.5)})
    bands = []
    for b0, b1 in zip(edges[:-1], edges[1:]):
        e = rng.normal(0, 1, (b1 - b0, 1))
        e *= np.sqrt(sse_iid / float((e ** 2).sum()))
        ac = r_ac.copy()
        ac[b0:b1] += e
        rec = raht_inverse(r_dc, ac, tree)
        sse = float(((rec - red) ** 2).sum())
        f = mse(with_red(rec)) / sse / w_iid
        span = ((m + 1) / (b1), (m + 1) / (b0 + 1))
        bands.append({"coefficients": [b0, b1], "gaussians_spanned": [round(span[0], 1), round(span[1], 1)],
                      "factor": f})
        print(f"RAHT band [{b0:,}, {b1:,}) of {m:,} (each spans ~{span[0]:.1f}-{span[1]:.1f} Gaussians): "
              f"{f:.2f}x the i.i.d. weight", flush=True)

    # --- SH codebooks ------------------------------------------------------------------------
    books = []
    if c.sh_degree > 0:
        sh = c.sh_rest.reshape(n, -1).astype(np.float32)

        def with_sh(x) -> GaussianCloud:
            return variant(sh_rest=np.asarray(x, np.float32).reshape(c.sh_rest.shape))
        s = 0.01
        w_sh = mse(with_sh(sh + rng.normal(0, s, sh.shape))) / (s * s * sh.size)
        for k in (int(v) for v in a.codebooks.split(",") if v):
            cb = train_codebook(sh, np.ones(n, np.float32), min(k, n), seed=0)
            idx = assign(sh, cb)
            idx = idx[0] if isinstance(idx, tuple) else idx
            err = cb[idx] - sh
            sse = float((err.astype(np.float64) ** 2).sum())
            row = {"codebook": k, "factor": mse(with_sh(sh + err)) / (w_sh * sse),
                   "iid_same_sse": mse(with_sh(sh + rng.normal(0, np.sqrt(sse / sh.size), sh.shape))) / (w_sh * sse),
                   "shuffled": mse(with_sh(sh + err[rng.permutation(n)])) / (w_sh * sse)}
            books.append(row)
            print(f"SH codebook {k}: {row['factor']:.2f}x the i.i.d. weight (same SSE i.i.d. "
                  f"{row['iid_same_sse']:.2f}x, the errors shuffled across Gaussians {row['shuffled']:.2f}x)",
                  flush=True)

    out = Path(a.out) if a.out else ROOT / "bench" / "out" / f"coherence_{path.stem}{'_noised' if a.noise else ''}.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({
        "command": "bench/bench_coherence.py " + " ".join(argv if argv is not None else sys.argv[1:]),
        "scene": path.stem, "noised": a.noise, "gaussians": n, "voxels": int(uniq.size), "depth": a.depth, "views": len(cams),
        "raht_bands": bands, "sh_codebooks": books, "seconds": round(time.time() - t0, 1),
        "machine": machine(), "gsz": gsz_source(gsz)}, indent=1) + "\n")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
