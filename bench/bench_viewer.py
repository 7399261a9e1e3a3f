"""Benchmark of gsz-view's GL renderer: frame time / FPS at 1280x720 and depth-sort time.

    .venv/bin/python bench/bench_viewer.py [--scenes a.ply,b.ply] [--width 1280] [--height 720]
        [--repeat 3] [--camera 0] [--json]

For every scene of ../shared/data (default: all of them) it renders TEST camera ``--camera`` of
the default camera set (the view gsz-eval scores) at ``width`` x ``height`` and reports, best
and median of ``--repeat`` frames after one warm-up:

* frame  = GPU preprocess (compute shader) + instanced draw + glFinish, as the window does it
           (the sort runs on a worker thread in the app, so it is reported separately)
* sort   = numpy stable argsort of view depth (``gsz.viewer.gl_renderer.depth_order``)
* split  = one compare-mode frame (two scenes + composite), the scene against itself

On this project's machines the GL driver is Mesa llvmpipe (software rasteriser on 2 CPU
cores), so these numbers say how usable the viewer is without a GPU, NOT what it does on one;
the driver name is printed.  Exits cleanly (rc 0) with a message when ../shared is absent or no
GL context can be created.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SHARED = Path(os.environ.get("GSZ_SHARED", ROOT.parent / "shared")) / "data"


def _timed(fn, repeat):
    fn()                                  # warm-up (shader compile, buffer first touch)
    ts = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return min(ts), statistics.median(ts)


def bench_scene(ctx, path, width, height, repeat, camera):
    from gsz.decoder import read_ply
    from gsz.evaluation.cameras import load_cameras
    from gsz.viewer.app import Scene, Settings, ViewerApp
    from gsz.viewer.gl_renderer import FloatTarget, SplatRenderer, depth_order

    cloud = read_ply(path)
    cams = load_cameras(None, cloud, width=width)
    c = cams.test[camera]
    from gsz.evaluation.cameras import Camera
    cam = Camera(c.R, c.t, c.fx, c.fy, c.cx, c.cy + (height - c.height) / 2, width, height, c.name)
    r = SplatRenderer(ctx, cloud)
    target = FloatTarget(ctx, width, height)
    order = depth_order(cloud.positions, cam)

    def frame():
        r.render(cam, target, order=order)
        ctx.finish()

    f_best, f_med = _timed(frame, repeat)
    s_best, s_med = _timed(lambda: depth_order(cloud.positions, cam), repeat)
    target.release()
    r.release()

    a, b = Scene("a", cloud), Scene("b", cloud)
    app = ViewerApp(ctx, a, b, cameras=cams, up=(0, -1, 0), width=width, height=height,
                    settings=Settings(mode="split", auto_metrics=False), threaded_sort=False)
    app.control.snap_to(cam)

    def split_frame():
        app.render()
        ctx.finish()

    sp_best, sp_med = _timed(split_frame, max(1, repeat - 1))
    app.close()
    return {"scene": path.name, "splats": len(cloud), "sh_degree": cloud.sh_degree,
            "visible": int(len(order)), "frame_s": f_med, "frame_best_s": f_best,
            "fps": 1.0 / f_med, "sort_s": s_med, "sort_best_s": s_best,
            "split_frame_s": sp_med}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default=None, help="comma-separated names in ../shared/data")
    ap.add_argument("--width", type=int, default=1280)
    ap.add_argument("--height", type=int, default=720)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--camera", type=int, default=0)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)

    if not SHARED.exists():
        print(f"SKIP: {SHARED} not present")
        return 0
    names = args.scenes.split(",") if args.scenes else sorted(p.name for p in SHARED.glob("*.ply"))
    from gsz.viewer.gl_renderer import GLUnavailable, create_headless_context
    try:
        ctx = create_headless_context()
    except GLUnavailable as e:
        print(f"SKIP: {e}")
        return 0
    renderer = ctx.info.get("GL_RENDERER", "?")
    print(f"GL_RENDERER: {renderer}; {args.width}x{args.height}; median of {args.repeat}",
          file=sys.stderr)
    rows = []
    for name in names:
        p = SHARED / name
        if not p.exists():
            print(f"SKIP: {p} not present", file=sys.stderr)
            continue
        row = bench_scene(ctx, p, args.width, args.height, args.repeat, args.camera)
        rows.append(row)
        if not args.json:
            print(f"{row['scene']:38s} {row['splats']:>8,} splats (SH{row['sh_degree']}, "
                  f"{row['visible']:,} in front)  frame {1e3 * row['frame_s']:7.1f} ms "
                  f"({row['fps']:5.2f} FPS)  sort {1e3 * row['sort_s']:6.1f} ms  "
                  f"split-compare frame {1e3 * row['split_frame_s']:7.1f} ms", flush=True)
    if args.json:
        print(json.dumps({"gl_renderer": renderer, "width": args.width, "height": args.height,
                          "rows": rows}, indent=1))
    ctx.release()
    return 0


if __name__ == "__main__":
    sys.exit(main())
