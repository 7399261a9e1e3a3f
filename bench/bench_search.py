"""Size-search benchmark: 5 budgets per scene spanning 8x..40x compression, RD plots.

    .venv/bin/python bench/bench_search.py [--scenes a,b] [--ratios 8,12,18,27,40] [--noise]
                                           [--scaling [--fractions 0.125,0.25,0.5,1]]
                                           [--out bench/out/search.json]

Per scene and budget: target, actual bytes, deviation, test-view PSNR/SSIM (gsz-eval's
protocol, default cameras), search seconds and per-stage seconds.  --scaling also times the
search on flowers subsampled to 1/8, 1/4, 1/2, 1.  One RD plot PNG per scene goes to
bench/out/rd_<scene>.png (needs matplotlib, the [bench] extra).
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
sys.path.insert(0, str(ROOT / "bench"))
from bench_codec import SCENES, add_noise  # noqa: E402


def plot(scene, rows, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(5, 3.6), dpi=110)
    for variant in sorted({r["variant"] for r in rows}):
        rr = sorted((r for r in rows if r["variant"] == variant), key=lambda r: r["bytes"])
        ax.plot([r["bytes"] / 1e6 for r in rr], [r["psnr"] for r in rr], "o-", label=f"gsz ({variant})")
    ax.set_xlabel("file size (MB)")
    ax.set_ylabel("PSNR vs original render (dB)")
    ax.set_title(scene)
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--scenes", default=",".join(SCENES))
    ap.add_argument("--ratios", default="8,12,18,27,40")
    ap.add_argument("--noise", action="store_true")
    ap.add_argument("--scaling", action="store_true")
    ap.add_argument("--fractions", default="0.125,0.25,0.5,1", help="--scaling: subsample fractions")
    ap.add_argument("--width", type=int, default=800)
    ap.add_argument("--out", default=str(ROOT / "bench" / "out" / "search.json"))
    a = ap.parse_args(argv)
    if not SHARED.exists():
        print(f"SKIP: {SHARED} not present")
        return 0
    import gsz
    from gsz.encoder.cameras import load_cameras
    from gsz.encoder.evaluate import evaluate, render_views
    from gsz.encoder.pipeline import EncodeOptions, compute_train_importance
    from gsz.encoder.progress import Progress
    from gsz.encoder.search import BudgetError, encode_to_budget

    rows = []
    out_dir = Path(a.out).parent
    out_dir.mkdir(parents=True, exist_ok=True)
    for scene in a.scenes.split(","):
        path = SHARED / f"{scene}.ply"
        if not path.exists():
            continue
        ply_bytes = os.path.getsize(path)
        base = gsz.read_ply(path)
        variants = [("grid", base)] + ([("noised", add_noise(base))] if a.noise else [])
        scene_rows = []
        for variant, cloud in variants:
            cams = load_cameras(None, cloud, n_test=8, width=a.width).test
            refs = render_views(cloud, cams)
            t0 = time.perf_counter()
            imp = compute_train_importance(cloud, EncodeOptions())
            t_imp = time.perf_counter() - t0
            for ratio in [float(r) for r in a.ratios.split(",")]:
                target = int(ply_bytes / ratio)
                prog = Progress(quiet=True)
                t0 = time.perf_counter()
                try:
                    res = encode_to_budget(cloud, target, importance=imp, progress=prog)
                except BudgetError as e:
                    print(f"{scene:30s} {variant:6s} {ratio:4.0f}x: unreachable ({e})")
                    continue
                t_search = time.perf_counter() - t0 + t_imp
                ev = evaluate(refs, res.cloud, cams)
                r = res.report
                row = {"scene": scene, "variant": variant, "ratio_target": ratio, "target": target,
                       "bytes": r["bytes"], "deviation": r["deviation"], "psnr": ev["psnr"], "ssim": ev["ssim"],
                       "reserve": r["reserve"], "sh_keep": r["sh_keep"], "rounds": len(r["calibration"]),
                       "search_seconds": t_search, "stage_seconds": {"importance": t_imp, **r["seconds"]},
                       "gaussians": len(cloud)}
                rows.append(row)
                scene_rows.append(row)
                print(f"{scene:30s} {variant:6s} {ratio:4.0f}x: target {target:>11,} actual {r['bytes']:>11,} "
                      f"({100 * r['deviation']:+.3f} %)  PSNR {ev['psnr']:6.2f} SSIM {ev['ssim']:.4f}  "
                      f"tau {r['reserve']} keep {r['sh_keep']} rounds {row['rounds']}  {t_search:.1f} s",
                      flush=True)
        if scene_rows:
            plot(scene, scene_rows, out_dir / f"rd_{scene}.png")
    if a.scaling:
        c = gsz.read_ply(SHARED / "flowers_daffodils_sh2.ply")
        for frac in [float(f) for f in a.fractions.split(",")]:
            idx = np.sort(np.random.default_rng(0).choice(len(c), int(frac * len(c)), replace=False))
            sub = c.subset(idx)
            target = int(os.path.getsize(SHARED / "flowers_daffodils_sh2.ply") * frac / 20)
            prog = Progress(quiet=True)
            t0 = time.perf_counter()
            res = encode_to_budget(sub, target, progress=prog)
            dt = time.perf_counter() - t0
            print(f"scaling flowers x{frac}: N={len(sub):,} target {target:,} -> {res.report['bytes']:,} "
                  f"in {dt:.1f} s  stages " + ", ".join(f"{k} {v:.1f}" for k, v in prog.seconds.items()), flush=True)
            rows.append({"scaling": frac, "n": len(sub), "seconds": dt, "stage_seconds": prog.seconds})
    Path(a.out).write_text(json.dumps(rows, indent=1, default=float))
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
