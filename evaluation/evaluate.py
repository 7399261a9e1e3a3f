"""How faithful is a compressed scene to its original, seen through cameras (the library of
``gsz-eval``, whose command line is :mod:`gsz.encoder.eval_cli`).

Both scenes are rendered from the same TEST views (a cameras.json / COLMAP model split like the
3DGS protocol, or the ORIGINAL's :func:`~gsz.evaluation.cameras.default_cameras`), on the same
background, and compared with :mod:`gsz.evaluation.metrics` (renders clamped and rounded to 8 bits,
PSNR capped at 100 dB for identical images, reference SSIM).

    gsz-eval ORIGINAL COMPRESSED [--cameras FILE_OR_DIR] [--views N] [--width W] [--json]
             [-o DIR] [--background R,G,B] [--up AXIS] [-w] [-q | -v]
    gsz-eval --rd SCENE --sizes 1MB,2MB,4MB -o DIR    # encode at each budget, score, plot

Python API: :func:`load_cloud`, :func:`render_views`, :func:`evaluate` (reused by the encoder's
size/quality search, which renders the original once and passes its images as ``original``).
"""
from __future__ import annotations

import io
import os
import re

import numpy as np

from ..decoder.cloud import GaussianCloud
from ..decoder.errors import GszError
from ..decoder.io_util import atomic_write

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
        raise (missing_extra(e, "rendering") or GszError(f"the renderer (gsz.evaluation.render) is "
                                                         f"unavailable: {e}")) from None
    return render


def render_views(cloud: GaussianCloud, cameras, *, background=(0.0, 0.0, 0.0), render_fn=None,
                 progress=None) -> list:
    """Render ``cloud`` from each camera: a list of [H, W, 3] float64 images in [0, 1] rounded
    to 8 bits (the evaluation protocol's form).  ``render_fn(cloud, camera, background=...)``
    must return an object with ``.image``; default :func:`gsz.evaluation.render.render`."""
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


def view_labels(res: dict, view: dict, names=("original", "decoded")) -> tuple:
    """Caption lines of a side-by-side PNG: what each half is, its bytes, the view's scores."""
    b = res["bytes"]
    n = res["num_gaussians"]
    left = [f"{names[0]}: {os.path.basename(res['original'])}",
            f"{b['original']:,} B, {n['original']:,} Gaussians"]
    right = [f"{names[1]}: {b['compressed']:,} B" + (f" ({b['ratio']:.1f}x)" if b["ratio"] else ""),
             f"PSNR {view['psnr']:.2f} dB  SSIM {view['ssim']:.4f}"]
    return left, right


# --- CLI -----------------------------------------------------------------------------------------

def pick_evenly(items, n):
    """``n`` items spread evenly over ``items`` (all of them when n >= len)."""
    if n is None or n >= len(items):
        return list(items)
    idx = np.unique(np.round(np.linspace(0, len(items) - 1, n)).astype(int))
    return [items[i] for i in idx]
