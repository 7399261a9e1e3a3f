"""Benchmark of the CPU renderer (gsz.evaluation.render): seconds per view.

    .venv/bin/python bench/bench_render.py [--scene flowers_daffodils_sh2.ply] [--width 800]
        [--height 600] [--repeat 3] [--distance 2.0] [--backend auto|cpp|torch]

Renders ../shared/data/<scene> from a camera at the median position looking from
``distance`` x the 1-99 percentile extent (``framing_camera``), image-only and
image + importance, and prints the best and median seconds per view.  Exits cleanly (rc 0)
with a message when ../shared is absent.
"""
from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SHARED = Path(os.environ.get("GSZ_SHARED", ROOT.parent / "shared")) / "data"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="flowers_daffodils_sh2.ply")
    ap.add_argument("--width", type=int, default=800)
    ap.add_argument("--height", type=int, default=600)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--distance", type=float, default=2.0)
    ap.add_argument("--backend", choices=["auto", "cpp", "torch"], default="auto")
    args = ap.parse_args(argv)

    path = SHARED / args.scene
    if not path.exists():
        print(f"SKIP: {path} not present (../shared/data absent)")
        return 0

    import numpy as np
    import torch

    import gsz
    from gsz.evaluation import render as R

    t0 = time.perf_counter()
    kernel = args.backend != "torch" and R.kernel_available()
    t_build = time.perf_counter() - t0
    cloud = gsz.read_ply(path)
    cam = R.framing_camera(cloud.positions, args.width, args.height,
                           distance_factor=args.distance)
    print(f"scene {args.scene}: {len(cloud):,} Gaussians, SH degree {cloud.sh_degree}; "
          f"{args.width}x{args.height}; distance {args.distance} x extent; "
          f"backend {'cpp' if kernel else 'torch'} (kernel load/build {t_build:.1f} s); "
          f"torch threads {torch.get_num_threads()}")
    backend = "cpp" if kernel else "torch"
    for label, imp in (("image-only", False), ("image+importance", True)):
        times = []
        for _ in range(max(1, args.repeat)):
            t = time.perf_counter()
            out = R._render(cloud, cam, return_importance=imp, backend=backend)
            times.append(time.perf_counter() - t)
        extra = ""
        if imp:
            extra = (f"; importance sum {out.importance.sum():.2f} vs alpha sum "
                     f"{float(out.alpha.sum(dtype=np.float64)):.2f}, "
                     f"{int((out.importance > 0).sum()):,} Gaussians > 0")
        print(f"{label:17s} best {min(times):.3f} s/view, median {statistics.median(times):.3f} "
              f"s/view over {len(times)} (alpha mean {out.alpha.mean():.3f}{extra})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
