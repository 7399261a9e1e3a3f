"""``gsz-eval``: how faithful is a compressed scene to its original, seen through cameras.

Both scenes are rendered from the same TEST views (a cameras.json / COLMAP model split like the
3DGS protocol, or the ORIGINAL's :func:`~gsz.encoder.cameras.default_cameras`), on the same
background, and compared with :mod:`gsz.encoder.metrics` (renders clamped and rounded to 8 bits,
PSNR capped at 100 dB for identical images, reference SSIM).

    gsz-eval ORIGINAL COMPRESSED [--cameras FILE_OR_DIR] [--views N] [--width W] [--json]
             [--out DIR] [--background R,G,B] [--up AXIS]

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
from ..decoder.errors import GszError
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
        raise GszError(f"the renderer (gsz.encoder.render) is unavailable: {e}") from None
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

def error_map(a, b, full_scale: float = ERROR_MAP_FULL_SCALE) -> np.ndarray:
    """[H, W, 3] uint8 heat map of max-over-RGB |a - b|: black (0) -> red -> yellow -> white
    (>= ``full_scale``)."""
    e = np.abs(np.asarray(a, np.float64) - np.asarray(b, np.float64)).max(axis=2)
    t = np.clip(e / full_scale, 0.0, 1.0) * 3.0
    rgb = np.stack([np.clip(t, 0, 1), np.clip(t - 1, 0, 1), np.clip(t - 2, 0, 1)], axis=-1)
    return np.round(rgb * 255.0).astype(np.uint8)


def _png_bytes(arr: np.ndarray) -> bytes:
    from PIL import Image
    buf = io.BytesIO()
    Image.fromarray(arr, "RGB").save(buf, format="PNG")
    return buf.getvalue()


def write_view_pngs(out_dir, index: int, name: str, ref, comp) -> list:
    """Write ``NNN_<name>_side_by_side.png`` (original | compressed) and ``NNN_<name>_error.png``
    atomically into ``out_dir``; returns the two paths."""
    safe = re.sub(r"[^A-Za-z0-9._-]+", "_", name).strip("._") or "view"
    sbs = np.concatenate([to_uint8(ref), to_uint8(comp)], axis=1)
    p1 = os.path.join(out_dir, f"{index:03d}_{safe}_side_by_side.png")
    p2 = os.path.join(out_dir, f"{index:03d}_{safe}_error.png")
    atomic_write(p1, _png_bytes(sbs))
    atomic_write(p2, _png_bytes(error_map(ref, comp)))
    return [p1, p2]


# --- CLI -----------------------------------------------------------------------------------------

class _UsageError(Exception):
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
    p = argparse.ArgumentParser(
        prog="gsz-eval",
        description="Render an original and a compressed 3DGS scene from the same test views and "
                    "report PSNR / SSIM (8-bit protocol; identical images = 100 dB cap).")
    from ..decoder.cli import add_version_flag
    add_version_flag(p)
    p.add_argument("original", help="original scene, told by content (.ply, .gsz, .glb, .gltf, .spz, .sog or its "
                                     "meta.json, .ksplat, .splat)")
    p.add_argument("compressed", help="compressed / decoded scene (.gsz, a .glb carrying one, or any format the "
                                       "original can be)")
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
    p.add_argument("--out", metavar="DIR", help="write side-by-side and error-map PNGs per view")
    return p


def _run(args) -> dict:
    bg = _parse_background(args.background)
    if args.views is not None and args.views < 1:
        raise _UsageError(f"--views must be at least 1, got {args.views}")
    if args.width is not None and not 8 <= args.width <= 8192:
        raise _UsageError(f"--width must be in 8..8192, got {args.width}")
    t0 = time.perf_counter()
    original = load_cloud(args.original)
    compressed = load_cloud(args.compressed)
    try:
        if args.cameras is None:
            cams = load_cameras(None, original, n_test=args.views or 8,
                                width=args.width, up=args.up).test
        else:
            cams = pick_evenly(load_cameras(args.cameras, original, width=args.width).test, args.views)
    except ValueError as e:
        if isinstance(e, GszError):
            raise
        raise _UsageError(str(e)) from None

    def progress(i, n, name, p, s):
        print(f"gsz-eval: view {i + 1}/{n} {name}: PSNR {p:.2f} dB  SSIM {s:.4f}",
              file=sys.stderr, flush=True)

    res = evaluate(original, compressed, cams, background=bg, progress=progress,
                   return_images=args.out is not None)
    images = res.pop("images", None)
    if args.out is not None:
        written = []
        try:
            os.makedirs(args.out, exist_ok=True)
            for i, (v, (ref, comp)) in enumerate(zip(res["views"], images)):
                written += write_view_pngs(args.out, i, v["name"], ref, comp)
        except OSError as e:
            raise GszError(f"cannot write images: {e.strerror or e}", args.out) from None
        res["images_written"] = written
        res["error_map_full_scale"] = ERROR_MAP_FULL_SCALE
    res["original"] = os.fspath(args.original)
    res["compressed"] = os.fspath(args.compressed)
    so, sc = os.path.getsize(args.original), os.path.getsize(args.compressed)
    res["bytes"] = {"original": so, "compressed": sc, "ratio": (so / sc) if sc else None}
    res["cameras"] = args.cameras if args.cameras is not None else "default"
    res["width"], res["height"] = cams[0].width, cams[0].height
    res["seconds"] = round(time.perf_counter() - t0, 3)
    return res


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


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        with warnings.catch_warnings():
            # Warnings (extra PLY properties, lens distortion dropped) go to stderr as one line.
            warnings.simplefilter("always")
            warnings.showwarning = lambda msg, *a, **k: print(f"gsz-eval: warning: {msg}",
                                                              file=sys.stderr)
            res = _run(args)
    except (GszError, _UsageError) as e:
        print(f"gsz-eval: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("gsz-eval: interrupted", file=sys.stderr)
        return 130
    if args.json:
        print(json.dumps(res, allow_nan=False))
    else:
        _print_table(res)
    return 0


if __name__ == "__main__":
    sys.exit(main())
