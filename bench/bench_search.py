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
from bench_codec import SCENES, add_noise, git_commit  # noqa: E402


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


def _evaluate(refs, cloud, cams):
    """Test-view PSNR/SSIM with torch single-threaded (SSIM's convolutions stall with two
    OpenMP threads on the shared machine; the values do not depend on it)."""
    import torch
    from gsz.evaluation.evaluate import evaluate
    from gsz.evaluation.render import render_threads
    old = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        with render_threads(old):
            return evaluate(refs, cloud, cams)
    finally:
        torch.set_num_threads(old)


def _native() -> bool:
    """Whether the optional C accelerator (gsz.decoder._native) is in use (GSZ_NATIVE=0: no)."""
    try:
        from gsz.decoder import native
        return bool(native.enabled())
    except Exception:
        return False


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
    from gsz.evaluation.cameras import load_cameras
    from gsz.evaluation.evaluate import render_views
    from gsz.encoder.pipeline import EncodeOptions, compute_train_importance
    from gsz.encoder.progress import Progress
    from gsz.encoder.search import BudgetError, encode_to_budget

    from gsz.evaluation.render import kernel_available
    kernel_available()      # build/load the C++ rasteriser before anything is timed
    rows = []
    print(f"uptime: {os.popen('uptime').read().strip()}; native accelerator: {_native()}", flush=True)
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
            t0, c0 = time.perf_counter(), time.process_time()
            imp = compute_train_importance(cloud, EncodeOptions())
            t_imp, c_imp = time.perf_counter() - t0, time.process_time() - c0
            for ratio in [float(r) for r in a.ratios.split(",")]:
                target = int(ply_bytes / ratio)
                prog = Progress(quiet=True)
                load0 = os.getloadavg()[0]
                t0 = time.perf_counter()
                try:
                    res = encode_to_budget(cloud, target, importance=imp, progress=prog)
                except BudgetError as e:
                    print(f"{scene:30s} {variant:6s} {ratio:4.0f}x: unreachable ({e})")
                    continue
                # search seconds = the search plus the importance pass it would run itself
                t_search = time.perf_counter() - t0 + t_imp
                load1 = os.getloadavg()[0]
                ev = _evaluate(refs, res.cloud, cams)
                r = res.report
                row = {"scene": scene, "variant": variant, "ratio_target": ratio, "target": target,
                       "bytes": r.bytes, "deviation": r.search.deviation, "psnr": ev["psnr"], "ssim": ev["ssim"],
                       "reserve": r.reserve, "depth": r.depth, "sh_keep": r.sh_keep,
                       "codebook_size": r.codebook_size, "rounds": len(r.search.calibration),
                       "candidates": len(r.search.candidates), "screened": sum(s["skipped"] for s in r.search.screened),
                       "note": r.search.note,
                       "search_seconds": t_search, "cpu_seconds": r.cpu_seconds + c_imp,
                       "stage_seconds": {"importance": t_imp, **r.seconds},
                       "load_before": load0, "load_after": load1, "native": _native(),
                       "gaussians": len(cloud)}
                rows.append(row)
                scene_rows.append(row)
                print(f"{scene:30s} {variant:6s} {ratio:4.0f}x: target {target:>11,} actual {r.bytes:>11,} "
                      f"({100 * r.search.deviation:+.3f} %)  PSNR {ev['psnr']:6.2f} SSIM {ev['ssim']:.4f}  "
                      f"tau {r.reserve} d {r.depth} K {r.codebook_size} keep {r.sh_keep} "
                      f"rounds {row['rounds']} cand {row['candidates']}+{row['screened']} screened  "
                      f"{t_search:.1f} s ({row['cpu_seconds']:.1f} s CPU, load {load0:.1f}-{load1:.1f})"
                      + (f"  [{r.search.note}]" if r.search.note else ""), flush=True)
        if scene_rows:
            plot(scene, scene_rows, out_dir / f"rd_{scene}.png")
    if a.scaling:
        c = gsz.read_ply(SHARED / "flowers_daffodils_sh2.ply")
        for frac in [float(f) for f in a.fractions.split(",")]:
            idx = np.sort(np.random.default_rng(0).choice(len(c), int(frac * len(c)), replace=False))
            sub = c.subset(idx)
            target = int(os.path.getsize(SHARED / "flowers_daffodils_sh2.ply") * frac / 20)
            prog = Progress(quiet=True)
            load0 = os.getloadavg()[0]
            t0 = time.perf_counter()
            res = encode_to_budget(sub, target, progress=prog)     # importance included
            dt = time.perf_counter() - t0
            r = res.report
            print(f"scaling flowers x{frac}: N={len(sub):,} target {target:,} -> {r.bytes:,} "
                  f"in {dt:.1f} s ({r.cpu_seconds:.1f} s CPU, load {load0:.1f}), {len(r.search.candidates)} candidates, "
                  f"stages " + ", ".join(f"{k} {v:.1f}" for k, v in prog.seconds.items()), flush=True)
            rows.append({"scaling": frac, "n": len(sub), "target": target, "bytes": r.bytes, "seconds": dt,
                         "cpu_seconds": r.cpu_seconds, "candidates": len(r.search.candidates),
                         "screened": sum(s["skipped"] for s in r.search.screened), "reserve": r.reserve,
                         "load_before": load0, "native": _native(), "stage_seconds": prog.seconds})
    commit = git_commit()
    res = {"command": "bench/bench_search.py " + " ".join(sys.argv[1:] if argv is None else argv),
           "commit": commit, "when": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
           "machine": {"nproc": os.cpu_count()}, "rows": rows}
    Path(a.out).write_text(json.dumps(res, indent=1, default=float))
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
