"""``gsz-eval``, the command line: score a compressed scene against its original
(:mod:`gsz.evaluation.evaluate` does the rendering and the metrics), or with ``--rd`` encode one
scene at several budgets and plot PSNR/SSIM against size (:mod:`gsz.encoder.rd`).

    gsz-eval ORIGINAL COMPRESSED [--cameras FILE_OR_DIR] [--views N] [--width W] [--json]
             [-o DIR] [--background R,G,B] [--up AXIS] [-w] [-q | -v]
    gsz-eval --rd SCENE --sizes 1MB,2MB,4MB -o DIR    # encode at each budget, score, plot

Kept apart from the library so the size search (which scores candidates with
:func:`~gsz.evaluation.evaluate.evaluate`) and ``--rd`` (which runs the size search) do not import
each other in a circle.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
import warnings


from ..decoder.errors import GszError, GszUsageError
from ..decoder.io_util import atomic_write
from ..evaluation.cameras import load_cameras
from ..evaluation.evaluate import (ERROR_MAP_FULL_SCALE, NOTE, view_labels, evaluate, load_cloud, pick_evenly,
                                   view_png_names, write_view_pngs)
from ..evaluation.metrics import PSNR_CAP_DB


class _UsageError(GszUsageError):
    pass


def build_parser() -> argparse.ArgumentParser:
    from ..decoder.cli_common import HelpFormatter, add_overwrite, add_verbosity, add_version_flag
    p = argparse.ArgumentParser(
        prog="gsz-eval",
        usage="%(prog)s ORIGINAL COMPRESSED [options]\n       %(prog)s --rd SCENE --sizes LIST -o DIR [options]",
        formatter_class=HelpFormatter,
        description="Render an original and a compressed 3DGS scene from the same test views and "
                    "report PSNR / SSIM (8-bit protocol; identical images = 100 dB cap); or, with "
                    "--rd, encode one scene at several budgets and plot PSNR/SSIM against size.",
        epilog="Exit status: 0 ok, 1 error (bad input, unreachable sizes, outputs exist), 2 bad "
               "options, 130 interrupted.")
    add_version_flag(p)
    p.add_argument("original", nargs="?", help="original scene, told by content (.ply, .gsz, .glb, .gltf, .spz, "
                                               ".sog or its meta.json, .ksplat, .splat)")
    p.add_argument("compressed", nargs="?",
                   help="compressed / decoded scene (.gsz, a .glb carrying one, or any format the original can be)")
    p.add_argument("--cameras", metavar="FILE_OR_DIR",
                   help="graphdeco cameras.json or COLMAP model (test = every 8th by name); "
                        "default: deterministic views around the original")
    p.add_argument("--views", type=int, metavar="N",
                   help="number of test views (default 8 default views, or every test camera)")
    p.add_argument("--width", type=int, metavar="W",
                   help="image width (default 800 for default views; camera files: native, at most 1600)")
    p.add_argument("--background", default="0,0,0", metavar="R,G,B",
                   help="background colour in [0,1] (default 0,0,0, the reference protocol)")
    p.add_argument("--up", default="auto", metavar="AXIS",
                   help="up axis of default views: auto (default: y, sign from the ground plane), "
                        "-y, +y, +z, ...")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    p.add_argument("-o", "--out", metavar="DIR",
                   help="write per view a side-by-side PNG (captioned with bytes and PSNR/SSIM) and "
                        "an error map with its colour bar; with --rd: the encoded files, rd.json and rd.png")
    add_overwrite(p)
    add_verbosity(p, quiet_help="errors only", verbose_help="also the size search's story (--rd)")
    rd = p.add_argument_group("rate-distortion curve (--rd)")
    rd.add_argument("--rd", metavar="SCENE", help="encode SCENE at each of --sizes, score every file "
                                                  "against SCENE and plot the curve into -o DIR")
    rd.add_argument("--sizes", metavar="LIST", help="budgets for --rd, e.g. 1MB,2MB,4MB")
    rd.add_argument("--train-views", type=int, default=None, metavar="N",
                    help="--rd: generated train views of the encoder's importance pass (default 24)")
    rd.add_argument("--importance-width", type=int, default=None, metavar="W",
                    help="--rd: render width of the importance pass (default 800)")
    return p


def _test_cameras(args, original):
    try:
        if args.cameras is None:
            return load_cameras(None, original, n_test=args.views or 8, width=args.width, up=args.up).test
        return pick_evenly(load_cameras(args.cameras, original, width=args.width).test, args.views)
    except ValueError as e:
        if isinstance(e, GszError):
            raise
        raise _UsageError(str(e)) from None


def _check_common(args):
    from ..decoder.cli_common import parse_background
    bg = parse_background(args.background)
    if args.views is not None and args.views < 1:
        raise _UsageError(f"--views must be at least 1, got {args.views}")
    if args.width is not None and not 8 <= args.width <= 8192:
        raise _UsageError(f"--width must be in 8..8192, got {args.width}")
    return bg


def _check_outputs(args, names, inputs) -> None:
    """Every file this run will write into --out, checked before any rendering."""
    from ..decoder.cli_common import check_output
    if os.path.exists(args.out) and not os.path.isdir(args.out):
        raise GszError("is a file, expected a folder for the images", args.out)
    for n in names:
        check_output(os.path.join(args.out, n), inputs=inputs, overwrite=args.overwrite)


def _run(args) -> dict:
    if args.rd is not None:
        return _run_rd(args)
    if args.sizes or args.train_views is not None or args.importance_width is not None:
        raise _UsageError("--sizes/--train-views/--importance-width belong to --rd SCENE")
    if args.original is None or args.compressed is None:
        raise _UsageError("give ORIGINAL and COMPRESSED (or --rd SCENE --sizes LIST -o DIR)")
    bg = _check_common(args)
    import torch  # noqa: F401  (rendering needs it: a core-only install is told before any work)
    t0 = time.perf_counter()
    original = load_cloud(args.original)
    compressed = load_cloud(args.compressed)
    cams = _test_cameras(args, original)
    if args.out is not None:
        _check_outputs(args, [n for i, c in enumerate(cams) for n in view_png_names(i, c.name)],
                       [args.original, args.compressed])

    def progress(i, n, name, p, s):
        if args.verbosity > 0:
            print(f"gsz-eval: view {i + 1}/{n} {name}: PSNR {p:.2f} dB  SSIM {s:.4f}",
                  file=sys.stderr, flush=True)

    res = evaluate(original, compressed, cams, background=bg, progress=progress,
                   return_images=args.out is not None)
    images = res.pop("images", None)
    res["original"] = os.fspath(args.original)
    res["compressed"] = os.fspath(args.compressed)
    so, sc = os.path.getsize(args.original), os.path.getsize(args.compressed)
    res["bytes"] = {"original": so, "compressed": sc, "ratio": (so / sc) if sc else None}
    if args.out is not None:
        written = []
        try:
            os.makedirs(args.out, exist_ok=True)
            for i, (v, (ref, comp)) in enumerate(zip(res["views"], images)):
                written += write_view_pngs(args.out, i, v["name"], ref, comp, labels=view_labels(res, v))
        except OSError as e:
            raise GszError(f"cannot write images: {e.strerror or e}", args.out) from None
        res["images_written"] = written
        res["error_map_full_scale"] = ERROR_MAP_FULL_SCALE
    res["cameras"] = args.cameras if args.cameras is not None else "default"
    res["width"], res["height"] = cams[0].width, cams[0].height
    res["seconds"] = round(time.perf_counter() - t0, 3)
    return res


def _run_rd(args) -> dict:
    """``--rd SCENE --sizes LIST -o DIR``: rd.json, rd.png and one .gsz per reachable budget."""
    from ..decoder.io_util import check_input_file
    from .rd import budget_file_name, png_bytes, rd_figure, rd_points
    from .report import require_matplotlib
    if args.original is not None or args.compressed is not None:
        raise _UsageError("--rd SCENE takes no ORIGINAL/COMPRESSED (it makes the compressed files)")
    if not args.sizes or not args.out:
        raise _UsageError("--rd SCENE needs --sizes LIST and -o DIR")
    bg = _check_common(args)
    from ..decoder.sizes import parse_size
    items = [x.strip() for x in args.sizes.split(",") if x.strip()]
    if not items:
        raise _UsageError(f"--sizes: expected budgets like 1MB,2MB,4MB, got {args.sizes!r}")
    targets = sorted({(parse_size(x), x) for x in items})          # SizeSpecError: a usage error
    targets = [(label, n) for n, label in targets]
    from .search import SearchOptions
    kw = {k: v for k, v in (("train_views", args.train_views), ("importance_width", args.importance_width))
          if v is not None}
    sopts = SearchOptions(**kw)

    def bad(msg):
        raise _UsageError(msg)
    sopts.check_scene_options(bad)
    require_matplotlib("--rd")
    import torch  # noqa: F401  (the encodes need it: a core-only install is told before any work)
    in_bytes = check_input_file(args.rd)
    stem = os.path.splitext(os.path.basename(args.rd))[0]
    names = ["rd.json", "rd.png"] + [budget_file_name(stem, label) for label, _ in targets]
    _check_outputs(args, names, [args.rd])
    t0 = time.perf_counter()
    scene = load_cloud(args.rd)
    cams = _test_cameras(args, scene)
    from .progress import Progress
    prog = Progress(verbosity=1) if args.verbosity >= 2 else None

    def say(text):
        if args.verbosity > 0:
            print(f"gsz-eval: {text}", file=sys.stderr, flush=True)
    points, unreachable = rd_points(scene, targets, cams, background=bg, options=sopts, source=args.rd,
                                    report=say, progress=prog)
    if not points:
        raise GszError("no budget of --sizes is reachable: " + "; ".join(u["error"] for u in unreachable),
                       args.rd)
    os.makedirs(args.out, exist_ok=True)
    for pt in points:
        pt["file"] = os.path.join(args.out, budget_file_name(stem, pt["target"]))
        atomic_write(pt["file"], pt.pop("data"))
    rd = {"scene": os.fspath(args.rd), "input_bytes": in_bytes, "cameras": [c.name for c in cams],
          "width": cams[0].width, "height": cams[0].height, "background": list(bg),
          "psnr_cap_db": PSNR_CAP_DB, "note": NOTE, "points": points, "unreachable": unreachable,
          "search": {k: getattr(sopts, k) for k in ("train_views", "importance_width", "blocks")},
          "seconds": round(time.perf_counter() - t0, 2)}
    rd["rd_png"] = os.path.join(args.out, "rd.png")
    rd["rd_json"] = os.path.join(args.out, "rd.json")
    atomic_write(rd["rd_png"], png_bytes(rd_figure(rd)))
    atomic_write(rd["rd_json"], json.dumps(rd, indent=1, allow_nan=False).encode())
    return rd


def _print_table(res: dict) -> None:
    print(f"original   {res['original']}  ({res['num_gaussians']['original']} Gaussians, "
          f"{res['bytes']['original']} bytes)")
    print(f"compressed {res['compressed']}  ({res['num_gaussians']['compressed']} Gaussians, "
          f"{res['bytes']['compressed']} bytes)")
    print(f"{'view':<24} {'PSNR dB':>9} {'SSIM':>8}")
    for v in res["views"]:
        print(f"{v['name']:<24} {v['psnr']:>9.3f} {v['ssim']:>8.4f}")
    print(f"{'mean':<24} {res['psnr']:>9.3f} {res['ssim']:>8.4f}")
    print(f"({res['note']})")


def _print_rd(rd: dict) -> None:
    print(f"scene {rd['scene']}  ({rd['input_bytes']:,} bytes), {len(rd['cameras'])} test views at "
          f"{rd['width']}x{rd['height']}")
    print(f"{'budget':<10} {'bytes':>12} {'PSNR dB':>9} {'SSIM':>8}  file")
    for p in rd["points"]:
        print(f"{p['target']:<10} {p['bytes']:>12,} {p['psnr']:>9.3f} {p['ssim']:>8.4f}  {p['file']}")
    for u in rd["unreachable"]:
        print(f"{u['target']:<10} {'unreachable':>12}")
    print(f"curve: {rd['rd_png']}, {rd['rd_json']}")


def main(argv=None) -> int:
    from ..decoder.cli_common import run_guarded, warn
    args = build_parser().parse_args(argv)

    def work():
        with warnings.catch_warnings():
            # Warnings (extra PLY properties, lens distortion dropped) go to stderr as one line.
            warnings.simplefilter("always")
            warnings.showwarning = lambda msg, *a, **k: warn("gsz-eval", msg, args.verbosity)
            return _run(args)
    code, res = run_guarded("gsz-eval", work)
    if code is not None:
        return code
    if args.json:
        print(json.dumps(res, allow_nan=False))
    elif args.rd is not None:
        _print_rd(res)
    else:
        _print_table(res)
    return 0


if __name__ == "__main__":
    sys.exit(main())
