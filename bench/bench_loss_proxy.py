"""Does the loss the bit allocation minimises predict rendered fidelity?

    .venv/bin/python bench/bench_loss_proxy.py [--scenes houseplant_sh0,measuring_jug_sh3]
                                               [--ratio 18] [--reserve 0.8] [--count 16]
                                               [--out bench/out/loss_proxy.json]

Per scene, at one reserve ratio and the attribute budget of the size search for PLY/ratio:
``--count`` different allocations of the *same* solver budget are made by solving the MCKP with
the loss matrix Ω multiplied by random per-channel factors (log-normal, sigma 1), plus the
allocations that minimise the unweighted Ω and the sensitivity-weighted Ω (what the search uses).
Each is encoded for real (exact attribute bytes) and rendered from 6 train views at 640 px; the
table reports the Spearman rank correlation between -ΣΩ (unweighted and weighted) and the
rendered PSNR over the allocations, and the PSNR of the two optimal allocations.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
SHARED = ROOT.parent / "shared" / "data"


def spearman(a, b) -> float:
    """Spearman rank correlation (average ranks for ties), numpy only."""
    def ranks(x):
        x = np.asarray(x, float)
        order = np.argsort(x, kind="stable")
        r = np.empty(len(x))
        r[order] = np.arange(len(x))
        for v in np.unique(x):                  # average tied ranks
            m = x == v
            r[m] = r[m].mean()
        return r
    ra, rb = ranks(a), ranks(b)
    ra -= ra.mean()
    rb -= rb.mean()
    return float((ra * rb).sum() / np.sqrt((ra ** 2).sum() * (rb ** 2).sum()))


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--scenes", default="houseplant_sh0,measuring_jug_sh3")
    ap.add_argument("--ratio", type=float, default=18.0)
    ap.add_argument("--reserve", type=float, default=0.8)
    ap.add_argument("--count", type=int, default=16)
    ap.add_argument("--out", default=str(ROOT / "bench" / "out" / "loss_proxy.json"))
    a = ap.parse_args(argv)
    if not SHARED.exists():
        print(f"SKIP: {SHARED} not present")
        return 0
    import gsz
    from gsz.decoder.cloud import GaussianCloud
    from gsz.encoder.bit_allocation import allocate
    from gsz.evaluation.cameras import load_cameras
    from gsz.evaluation.evaluate import evaluate, render_views
    from gsz.encoder.pipeline import EncodeOptions, attribute_chunks, compute_train_importance, prepare_stage
    from gsz.encoder.search import channel_weights
    from gsz.encoder.search.tables import attribute_tables, group_meta_bytes, split_bits

    rows = []
    for scene in a.scenes.split(","):
        path = SHARED / f"{scene}.ply"
        if not path.exists():
            continue
        cloud = gsz.read_ply(path)
        budget_file = os.path.getsize(path) / a.ratio
        t0 = time.perf_counter()
        imp = compute_train_importance(cloud, EncodeOptions())
        stage = prepare_stage(cloud, imp, a.reserve)
        cams = load_cameras(None, cloud, n_train=6, n_test=1, width=640).train[:6]
        refs = render_views(cloud, cams)
        weights = channel_weights(cloud, cams[:2])
        loss_u, rate, shapes = attribute_tables(stage, 80, None)
        loss_w, _, _ = attribute_tables(stage, 80, weights)
        # the attribute share of the budget: what is left after geometry, SH and metadata
        sh_bytes = stage.sh.shape[0] * 1.5 if stage.sh.shape[1] else 0
        attr_bits = 8.0 * (budget_file - stage.geometry_bytes - sh_bytes - group_meta_bytes(shapes) - 600)
        m = stage.num_points
        order = stage.order
        pos = stage.positions()                     # one tile: in output (= order) order
        k = stage.sh.shape[1] // 3
        sh_rest = stage.sh[order].reshape(m, k, 3)
        chan = np.concatenate([np.repeat(np.arange(c), b) + (7 if i % 2 else 0)
                               for i, (c, b) in enumerate(shapes)])
        rng = np.random.default_rng(0)
        picks = [("weighted optimum", allocate(loss_w, rate, attr_bits)),
                 ("unweighted optimum", allocate(loss_u, rate, attr_bits))]
        for i in range(a.count):
            f = np.exp(rng.normal(0, 1.0, 10))
            picks.append((f"random weights {i}", allocate(loss_u * f[chan][:, None], rate, attr_bits)))
        results = []
        for name, pick in picks:
            payloads, dec, _ = attribute_chunks(stage, split_bits(pick, shapes), 80)
            c = GaussianCloud(positions=pos, scales=dec.scales, rotations=dec.rotations,
                              opacities=dec.opacities, sh_dc=dec.sh_dc, sh_rest=sh_rest,
                              sh_degree=cloud.sh_degree)
            ev = evaluate(refs, c, cams)
            g = np.arange(len(pick))
            results.append({"name": name, "attr_bytes": sum(map(len, payloads)),
                            "omega": float(loss_u[g, pick].sum()), "omega_weighted": float(loss_w[g, pick].sum()),
                            "psnr": ev["psnr"]})
            print(f"  {scene} {name}: {results[-1]['attr_bytes']:,} B, PSNR {ev['psnr']:.2f}", file=sys.stderr)
        psnr = [r["psnr"] for r in results]
        row = {"scene": scene, "reserve": a.reserve, "ratio": a.ratio, "allocations": len(results),
               "spearman_unweighted": spearman([-r["omega"] for r in results], psnr),
               "spearman_weighted": spearman([-r["omega_weighted"] for r in results], psnr),
               "psnr_weighted_optimum": results[0]["psnr"], "psnr_unweighted_optimum": results[1]["psnr"],
               "psnr_random_best": max(psnr[2:]), "psnr_random_median": float(np.median(psnr[2:])),
               "attr_bytes_range": [min(r["attr_bytes"] for r in results), max(r["attr_bytes"] for r in results)],
               "weights": weights, "results": results, "seconds": time.perf_counter() - t0}
        rows.append(row)
        print(f"{scene}: Spearman(-Omega, PSNR) unweighted {row['spearman_unweighted']:.3f}, weighted "
              f"{row['spearman_weighted']:.3f}; PSNR weighted opt {row['psnr_weighted_optimum']:.2f}, "
              f"unweighted opt {row['psnr_unweighted_optimum']:.2f}, random best {row['psnr_random_best']:.2f}, "
              f"median {row['psnr_random_median']:.2f}")
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
