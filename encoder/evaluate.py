"""``gsz-eval``: how faithful is a compressed scene to its original, seen through cameras.

Both scenes are rendered from the same TEST views (a cameras.json / COLMAP model split like the
3DGS protocol, or the ORIGINAL's :func:`~gsz.encoder.cameras.default_cameras`), on the same
background, and compared with :mod:`gsz.encoder.metrics` (renders clamped and rounded to 8 bits,
PSNR capped at 100 dB for identical images, reference SSIM).

    gsz-eval ORIGINAL COMPRESSED [--cameras FILE_OR_DIR] [--views N] [--width W] [--json]
             [-o DIR] [--background R,G,B] [--up AXIS] [-w] [-q | -v]
    gsz-eval --rd SCENE --sizes 1MB,2MB,4MB -o DIR    # encode at each budget, score, plot

Python API: :func:`load_cloud`, :func:`render_views`, :func:`evaluate` (reused by the encoder's
size/quality search, which renders the original once and passes its images as ``original``).
"""
from __future__ import annotations

import argparse
import io
import json
import math
import os
import re
import sys
import time
import warnings

import numpy as np

from ..decoder.cloud import GaussianCloud
from ..decoder.errors import GszError, GszUsageError
from ..decoder.io_util import atomic_write

from .cameras import load_cameras
from .metrics import PSNR_CAP_DB, psnr, quantize_8bit, ssim, to_uint8

NOTE = (f"PSNR of identical images is reported as the cap ({PSNR_CAP_DB:g} dB), not infinity; "
        "renders are clamped to [0,1] and rounded to 8 bits before comparison, so differences "
        "below half an 8-bit level also read as the cap.")
#: Full scale of the error-map PNG: an absolute error of this much (per channel, max over RGB)
#: is drawn white.  0.1 = about 25 8-bit levels, enough to see codec artefacts.
ERROR_MAP_FULL_SCALE = 0.1


def load_cloud(path, *, max_gaussians: int | None = None) -> GaussianCloud:
    """A scene from a 3DGS ``.ply``, a ``.gsz``, a ``.glb`` (plain ``KHR_gaussian_splatting`` or
    carrying a .gsz), a ``.gltf`` or another format :func:`gsz.load` reads (.spz, .sog, .ksplat,
    .splat, compressed PLY), told by content (:func:`gsz.load`; a .gsz within
    ``max_gaussians``, see :func:`gsz.decoder.decode`).  Raises a
    :class:`GszError` naming the file."""
    path = os.fspath(path)
    if not os.path.exists(path):
        raise GszError("file not found", path)
    if os.path.isdir(path):
        raise GszError("is a directory, expected a scene file (.ply, .gsz, .glb, .gltf, .spz, .sog or "
                       "meta.json, .ksplat, .splat)", path)
    from ..decoder.formats import load
    return load(path, max_gaussians=max_gaussians)


def _default_render_fn():
    try:
        from .render import render
    except ImportError as e:
        from ..decoder.cli_common import missing_extra
        raise (missing_extra(e, "rendering") or GszError(f"the renderer (gsz.encoder.render) is "
                                                         f"unavailable: {e}")) from None
    return render


def render_views(cloud: GaussianCloud, cameras, *, background=(0.0, 0.0, 0.0), render_fn=None,
                 progress=None) -> list:
    """Render ``cloud`` from each camera: a list of [H, W, 3] float64 images in [0, 1] rounded
    to 8 bits (the evaluation protocol's form).  ``render_fn(cloud, camera, background=...)``
    must return an object with ``.image``; default :func:`gsz.encoder.render.render`."""
    render_fn = render_fn or _default_render_fn()
    out = []
    for i, cam in enumerate(cameras):
        img = np.asarray(render_fn(cloud, cam, background=tuple(background)).image)
        if img.shape != (cam.height, cam.width, 3):
            raise GszError(f"renderer returned shape {img.shape} for a {cam.width}x{cam.height} view")
        out.append(quantize_8bit(img))
        if progress is not None:
            progress(i, len(cameras), cam.name)
    return out


def evaluate(original, compressed, cameras, *, background=(0.0, 0.0, 0.0), render_fn=None,
             progress=None, return_images: bool = False) -> dict:
    """Compare two scenes through ``cameras``.

    original    GaussianCloud, or a list of reference images [H, W, 3] (e.g. from
                :func:`render_views`, so a search renders the original only once)
    compressed  GaussianCloud
    cameras     list of Camera (the test views)
    progress    optional ``callback(i, n, name, psnr_db, ssim)`` after each view

    Returns ``{"psnr": mean dB, "ssim": mean, "views": [{"name", "psnr", "ssim"}...],
    "psnr_cap_db": 100, "note": ..., "num_gaussians": {"original", "compressed"},
    "background": [r, g, b]}`` plus ``"images": [(orig, comp)...]`` when ``return_images``.
    Means are plain means of the per-view values (the reference protocol).
    """
    cameras = list(cameras)
    if not cameras:
        raise GszError("no cameras to evaluate with")
    bg = tuple(float(v) for v in background)
    if isinstance(original, GaussianCloud):
        refs = render_views(original, cameras, background=bg, render_fn=render_fn)
        n_orig = len(original)
    else:
        refs = [np.asarray(r, np.float64) for r in original]
        n_orig = None
        if len(refs) != len(cameras):
            raise GszError(f"{len(refs)} reference images for {len(cameras)} cameras")
    render_fn = render_fn or _default_render_fn()
    views, images = [], []
    for i, (cam, ref) in enumerate(zip(cameras, refs)):
        comp = render_views(compressed, [cam], background=bg, render_fn=render_fn)[0]
        p, s = psnr(ref, comp), ssim(ref, comp)
        views.append({"name": cam.name, "psnr": p, "ssim": s})
        if return_images:
            images.append((ref, comp))
        if progress is not None:
            progress(i, len(cameras), cam.name, p, s)
    result = {
        "psnr": float(np.mean([v["psnr"] for v in views])),
        "ssim": float(np.mean([v["ssim"] for v in views])),
        "views": views,
        "psnr_cap_db": PSNR_CAP_DB,
        "note": NOTE,
        "num_gaussians": {"original": n_orig, "compressed": len(compressed)},
        "background": list(bg),
    }
    if return_images:
        result["images"] = images
    return result


# --- images --------------------------------------------------------------------------------------

#: height of the caption bar above a side-by-side PNG and of the colour bar below an error map
CAPTION_PX = 30
COLOUR_BAR_PX = 34


def error_map(a, b, full_scale: float = ERROR_MAP_FULL_SCALE) -> np.ndarray:
    """[H, W, 3] uint8 heat map of max-over-RGB |a - b|: black (0) -> red -> yellow -> white
    (>= ``full_scale``)."""
    e = np.abs(np.asarray(a, np.float64) - np.asarray(b, np.float64)).max(axis=2)
    return _heat(e / full_scale)


def _heat(t) -> np.ndarray:
    """The error map's colour ramp of ``t`` in [0, 1] (clipped): black, red, yellow, white."""
    t = np.clip(np.asarray(t, np.float64), 0.0, 1.0) * 3.0
    rgb = np.stack([np.clip(t, 0, 1), np.clip(t - 1, 0, 1), np.clip(t - 2, 0, 1)], axis=-1)
    return np.round(rgb * 255.0).astype(np.uint8)


def _png_bytes(arr: np.ndarray) -> bytes:
    from PIL import Image
    buf = io.BytesIO()
    Image.fromarray(arr, "RGB").save(buf, format="PNG")
    return buf.getvalue()


def _caption(width: int, lines: list, height: int = CAPTION_PX) -> np.ndarray:
    """[height, width, 3] uint8: ``lines`` in white on dark grey (PIL's default font), clipped
    to the width so a half's caption never runs into the other half."""
    from PIL import Image, ImageDraw
    img = Image.new("RGB", (int(width), int(height)), (32, 32, 32))
    d = ImageDraw.Draw(img)
    for i, text in enumerate(lines):
        d.text((4, 2 + 13 * i), text, fill=(255, 255, 255))
    return np.asarray(img)


def _colour_bar(width: int, full_scale: float, height: int = COLOUR_BAR_PX) -> np.ndarray:
    """[height, width, 3] uint8: the error map's ramp from 0 to ``full_scale`` with ticks."""
    from PIL import Image, ImageDraw
    img = Image.new("RGB", (int(width), int(height)), (32, 32, 32))
    left, right = 6, max(7, int(width) - 6)
    ramp = _heat(np.linspace(0.0, 1.0, right - left))
    img.paste(Image.fromarray(np.repeat(ramp[None], 10, axis=0), "RGB"), (left, 4))
    d = ImageDraw.Draw(img)
    for frac, text in ((0.0, "0"), (0.5, f"{full_scale / 2:g}"), (1.0, f">= {full_scale:g}")):
        x = left + frac * (right - left - 1)
        d.line([(x, 14), (x, 17)], fill=(255, 255, 255))
        w = d.textlength(text)
        d.text((min(max(0, x - w / 2), width - w - 1), 19), text, fill=(255, 255, 255))
    return np.asarray(img)


def view_png_names(index: int, name: str) -> tuple[str, str]:
    """File names of view ``index``'s side-by-side and error-map PNGs."""
    safe = re.sub(r"[^A-Za-z0-9._-]+", "_", name).strip("._") or "view"
    return f"{index:03d}_{safe}_side_by_side.png", f"{index:03d}_{safe}_error.png"


def write_view_pngs(out_dir, index: int, name: str, ref, comp, *, labels=None,
                    full_scale: float = ERROR_MAP_FULL_SCALE) -> list:
    """Write ``NNN_<name>_side_by_side.png`` (original | compressed, under a caption bar with
    ``labels`` = (left lines, right lines)) and ``NNN_<name>_error.png`` (the error map above a
    colour bar) atomically into ``out_dir``; returns the two paths."""
    a, b = to_uint8(ref), to_uint8(comp)
    h, w = a.shape[:2]
    left, right = labels or (["original"], ["compressed"])
    top = np.concatenate([_caption(w, left), _caption(w, right)], axis=1)
    sbs = np.concatenate([top, np.concatenate([a, b], axis=1)], axis=0)
    err = np.concatenate([error_map(ref, comp, full_scale), _colour_bar(w, full_scale)], axis=0)
    n1, n2 = view_png_names(index, name)
    p1, p2 = os.path.join(out_dir, n1), os.path.join(out_dir, n2)
    atomic_write(p1, _png_bytes(sbs))
    atomic_write(p2, _png_bytes(err))
    return [p1, p2]


def _view_labels(res: dict, view: dict, names=("original", "decoded")) -> tuple:
    """Caption lines of a side-by-side PNG: what each half is, its bytes, the view's scores."""
    b = res["bytes"]
    n = res["num_gaussians"]
    left = [f"{names[0]}: {os.path.basename(res['original'])}",
            f"{b['original']:,} B, {n['original']:,} Gaussians"]
    right = [f"{names[1]}: {b['compressed']:,} B" + (f" ({b['ratio']:.1f}x)" if b["ratio"] else ""),
             f"PSNR {view['psnr']:.2f} dB  SSIM {view['ssim']:.4f}"]
    return left, right


# --- CLI -----------------------------------------------------------------------------------------

class _UsageError(GszUsageError):
    pass


def _parse_background(s: str):
    try:
        vals = [float(v) for v in s.split(",")]
    except ValueError:
        raise _UsageError(f"--background must be R,G,B numbers in [0,1], got {s!r}") from None
    if len(vals) != 3 or not all(math.isfinite(v) and 0.0 <= v <= 1.0 for v in vals):
        raise _UsageError(f"--background must be three numbers in [0,1] like 0,0,0 or 1,1,1, got {s!r}")
    return tuple(vals)


def pick_evenly(items, n):
    """``n`` items spread evenly over ``items`` (all of them when n >= len)."""
    if n is None or n >= len(items):
        return list(items)
    idx = np.unique(np.round(np.linspace(0, len(items) - 1, n)).astype(int))
    return [items[i] for i in idx]


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
    bg = _parse_background(args.background)
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
                written += write_view_pngs(args.out, i, v["name"], ref, comp, labels=_view_labels(res, v))
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
    from .sizes import parse_size
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
    from ..decoder.cli_common import EXIT_INTERRUPTED, fail, missing_extra, warn
    args = build_parser().parse_args(argv)
    try:
        with warnings.catch_warnings():
            # Warnings (extra PLY properties, lens distortion dropped) go to stderr as one line.
            warnings.simplefilter("always")
            warnings.showwarning = lambda msg, *a, **k: warn("gsz-eval", msg, args.verbosity)
            res = _run(args)
    except GszError as e:
        return fail("gsz-eval", e)
    except ImportError as e:                  # a core-only install: name the extra, no traceback
        err = missing_extra(e, "gsz-eval")
        if err is None:
            raise
        return fail("gsz-eval", err)
    except KeyboardInterrupt:
        print("gsz-eval: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    if args.json:
        print(json.dumps(res, allow_nan=False))
    elif args.rd is not None:
        _print_rd(res)
    else:
        _print_table(res)
    return 0


if __name__ == "__main__":
    sys.exit(main())
