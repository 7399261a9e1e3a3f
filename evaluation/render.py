"""CPU reference renderer of 3D Gaussian Splatting scenes, with exact per-Gaussian importance.

The forward pass follows graphdeco-inria's ``diff-gaussian-rasterization`` (the 3DGS paper's
CUDA rasteriser) step by step:

* **Culling**: Gaussians with camera-space depth ``z <= 0.2`` are dropped (graphdeco's
  ``in_frustum``; its x/y frustum test is disabled there too).
* **3D covariance**: the quaternion (w, x, y, z) is normalised, scales are ``exp(log_scale) *
  scale_modifier``, ``Sigma = R diag(s^2) R^T``.
* **EWA projection**: ``cov2d = J W Sigma W^T J^T`` with the perspective Jacobian at the
  centre, whose x/z and y/z are clamped to ``+-1.3 tan(fov/2)`` first (``tan(fovx/2) =
  width / (2 fx)``); then 0.3 px is added to the diagonal (low-pass dilation).  Gaussians with
  ``det(cov2d) == 0`` are dropped.  ``conic = cov2d^-1``;
  ``radius = ceil(3 sqrt(lambda_max))`` with ``lambda_max = mid + sqrt(max(0.1, mid^2 - det))``.
* **Tiles**: 16x16 pixel tiles; a Gaussian is considered by every pixel of every tile in its
  graphdeco rectangle ``[int((m - r) / 16), int((m + r + 15) / 16))`` (clamped to the grid),
  and by no other pixel.  Gaussians whose rectangle is empty are dropped.
* **Colour**: real SH up to the requested degree with graphdeco's constants C0..C3 and view
  direction ``normalise(position - camera centre)``; colour = SH + 0.5, clamped at 0 from below
  (no upper clamp).
* **Compositing** (per pixel, front to back in increasing depth, ties in index order):
  ``power = -0.5 (a dx^2 + c dy^2) - b dx dy`` with ``d = mean - pixel``, skipped if
  ``power > 0``; ``alpha = min(0.99, sigmoid(opacity) exp(power))``, skipped if
  ``alpha < 1/255``; if ``T (1 - alpha) < 1e-4`` the pixel stops and this Gaussian is *not*
  added; otherwise ``C += colour alpha T``, ``T *= 1 - alpha``.  Output ``C + T * background``.
* **Importance**: per Gaussian, ``sum over pixels of alpha * T`` for exactly the contributions
  that were added to ``C`` (the MesonGS "imp" mode).  Products are formed in float64 from the
  float32 alpha and T and summed in a fixed order, so the result is deterministic; by
  construction ``importance.sum() == alpha_map.sum()`` up to float32 rounding of T.

Pixel convention: :class:`~gsz.evaluation.cameras.Camera` puts pixel centres at integer + 0.5, so
a centre projects to ``fx x / z + cx - 0.5`` in graphdeco's integer-centred pixel coordinates.

Remaining differences to graphdeco (all below ~1e-6 relative unless noted):

* The mean is projected directly with ``fx, fy, cx, cy`` (float64, then float32) instead of
  through the OpenGL projection matrix with its ``1/(w + 1e-7)``; for a centred principal point
  this is the same mapping.  An off-centre principal point is honoured here (graphdeco cannot
  express one); the Jacobian clamp still uses the symmetric ``tan(fov/2) = width / (2 fx)``.
* The camera-space position is computed in float64 (graphdeco: float32).
* The CPU does not contract multiply-adds (``-ffp-contract=off``) and uses glibc/Sleef ``expf``
  instead of CUDA's fast ``__expf``, so single values differ in the last bits.
* NaN / infinite inputs raise :class:`GszError` (graphdeco would draw garbage), except
  +-inf opacity logits and -inf log-scales, which are well defined.

Two implementations: a compiled C++ kernel (``kernels/render_cpu.cpp``: preprocessing and
rasterisation, built once with ``torch.utils.cpp_extension`` and cached in
``~/.cache/torch_extensions`` under a name keyed by the gsz and torch versions and the source,
:func:`kernel_build_name`) and a pure-torch reference (:func:`_preprocess`, vectorised over
Gaussians, and :func:`_rasterize_torch`, a literal transcription of the per-pixel loop,
vectorised over pixels; ~100x slower).  The kernel additionally skips, per Gaussian, the pixels outside a conservative
box beyond which ``alpha < 1/255`` holds (an exact shortcut: such pixels are skipped by the rule
anyway); the tests check both against each other.  If the kernel cannot be built, a warning is
issued and the torch path is used.  ``GSZ_RENDER_BACKEND=torch`` forces the reference.
"""
from __future__ import annotations

import contextlib
import dataclasses
import math
import os
import threading
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from ..decoder.cloud import ColourRows, GaussianCloud, MadeRows
from ..decoder.errors import GszError
from .cameras import Camera, look_at, robust_bounds

__all__ = ["RenderOutput", "render", "accumulate_importance", "framing_camera",
           "kernel_available", "SH_C0", "SH_C1", "SH_C2", "SH_C3"]

# graphdeco's real spherical-harmonics constants (auxiliary/forward.cu).
SH_C0 = 0.28209479177387814
SH_C1 = 0.4886025119029199
SH_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005,
         -1.0925484305920792, 0.5462742152960396)
SH_C3 = (-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
         -0.4570457994644658, 1.445305721320277, -0.5900435899266435)

BLOCK = 16            # tile side in pixels (graphdeco BLOCK_X = BLOCK_Y)
NEAR = 0.2            # graphdeco in_frustum: p_view.z <= 0.2 is culled
DILATION = 0.3        # low-pass filter added to the 2D covariance diagonal
ALPHA_MIN = 1.0 / 255.0
ALPHA_MAX = 0.99
T_MIN = 1e-4


@dataclass
class RenderOutput:
    """Result of :func:`render`.

    image      [H, W, 3] float32  linear RGB, background composited, not clamped to 1
    alpha      [H, W]    float32  1 - final transmittance
    importance [N]       float64  sum over pixels of alpha*T per Gaussian (None unless asked)
    """

    image: np.ndarray
    alpha: np.ndarray
    importance: np.ndarray | None


# ----------------------------------------------------------------------------------------------
# preprocessing (shared by both rasterisers)
# ----------------------------------------------------------------------------------------------

@dataclass
class _Projected:
    """Visible Gaussians in front-to-back order (M of them). All tensors are CPU torch."""

    index: torch.Tensor    # [M] int64  index into the cloud
    means: torch.Tensor    # [M, 2] f32 graphdeco pixel coordinates
    conic: torch.Tensor    # [M, 3] f32 (a, b, c) of the inverse 2D covariance
    opacity: torch.Tensor  # [M] f32   sigmoid(logit)
    colors: torch.Tensor   # [M, 3] f32 SH colour + 0.5, clamped >= 0
    rects: torch.Tensor    # [M, 4] i32 tile rectangle x0, y0, x1, y1 (exclusive)


#: Gaussians whose fields _check_inputs checks at a time.
CHECK_ROWS = 1 << 16


def _check_inputs(cloud: GaussianCloud, camera: Camera, sh_degree: int | None) -> int:
    if not isinstance(cloud, GaussianCloud):
        raise GszError(f"render: expected a GaussianCloud, got {type(cloud).__name__}")
    n = len(cloud)
    for fname, shape in (("positions", (n, 3)), ("scales", (n, 3)), ("rotations", (n, 4)),
                         ("opacities", (n,)), ("sh_dc", (n, 3))):
        if getattr(cloud, fname).shape != shape:
            raise GszError(f"render: cloud field '{fname}' has shape "
                           f"{getattr(cloud, fname).shape}, expected {shape}")
    # Non-finite values would silently poison pixels (NaN alpha compares false everywhere), so
    # reject them; +-inf opacity logits (alpha 0 or 1, produced by some 8-bit formats) and
    # -inf log-scales (a zero-size Gaussian, still dilated to 0.3 px) are well defined.
    for fname, arr, ok in (
            ("positions", cloud.positions, np.isfinite),
            ("rotations", cloud.rotations, np.isfinite),
            ("sh_dc", cloud.sh_dc, np.isfinite),
            ("sh_rest", cloud.sh_rest, np.isfinite),
            ("scales", cloud.scales, lambda a: ~np.isnan(a) & (a != np.inf)),
            ("opacities", cloud.opacities, lambda a: ~np.isnan(a))):
        if isinstance(arr, MadeRows):
            continue            # checked as its rows are made (_made_rows), not made twice
        # row steps: a whole-field mask of the SH rest was 270 MB per render at 6 M Gaussians
        if not all(ok(arr[s:s + CHECK_ROWS]).all() for s in range(0, n, CHECK_ROWS)):
            _raise_invalid(fname, arr, ok)
    # each row's 4 "!= 0" flags read as one uint32: non-zero iff the quaternion is (one pass;
    # the sum along a 4-wide axis cost 20 ms a render at 1.2 M Gaussians)
    if n and not (np.ascontiguousarray(cloud.rotations != 0).view(np.uint32) != 0).all():
        raise GszError("render: cloud has an all-zero quaternion (first at Gaussian "
                       f"{int(np.argmin(np.abs(cloud.rotations).sum(axis=1) > 0))})")
    if camera.width <= 0 or camera.height <= 0:
        raise GszError(f"render: camera '{camera.name}' has an empty image size "
                       f"{camera.width}x{camera.height}")
    if not (camera.fx > 0 and camera.fy > 0 and math.isfinite(camera.fx)
            and math.isfinite(camera.fy)):
        raise GszError(f"render: camera '{camera.name}' has invalid focal lengths "
                       f"fx={camera.fx}, fy={camera.fy}")
    if not (np.isfinite(camera.R).all() and np.isfinite(camera.t).all()):
        raise GszError(f"render: camera '{camera.name}' has a non-finite pose")
    deg = cloud.sh_degree if sh_degree is None else int(sh_degree)
    if not 0 <= deg <= cloud.sh_degree:
        raise GszError(f"render: sh_degree must be in 0..{cloud.sh_degree} for this cloud, "
                       f"got {sh_degree}")
    k = (deg + 1) ** 2 - 1
    if k and (cloud.sh_rest.ndim != 3 or cloud.sh_rest.shape[0] != n
              or cloud.sh_rest.shape[1] < k or cloud.sh_rest.shape[2] != 3):
        raise GszError(f"render: cloud sh_rest has shape {cloud.sh_rest.shape}, "
                       f"expected ({n}, >={k}, 3) for SH degree {deg}")
    return deg


def _raise_invalid(fname: str, arr, ok) -> None:
    """Raise the GszError naming field ``fname``'s invalid values (``ok``: the per-value test)
    when it has any."""
    good = ok(np.asarray(arr))
    if not good.all():
        n = good.shape[0]
        first = int(np.argmin(good.reshape(n, -1).all(axis=1))) if n else 0
        raise GszError(f"render: cloud field '{fname}' has {int((~good).sum())} invalid "
                       f"(NaN/inf) values, first at Gaussian {first}")


def _made_rows(arr: MadeRows):
    """(start, stop, rows) of a :class:`MadeRows` SH rest, CHECK_ROWS at a time, each range
    checked finite as it is made (what _check_inputs does for an array)."""
    for s in range(0, len(arr), CHECK_ROWS):
        rows = arr.rows(s, s + CHECK_ROWS)
        if not np.isfinite(rows).all():
            _raise_invalid("sh_rest", arr, np.isfinite)
        yield s, s + rows.shape[0], rows


def _eval_sh(deg: int, dc: torch.Tensor, rest: torch.Tensor, dirs: torch.Tensor,
             colour: torch.Tensor | None = None) -> torch.Tensor:
    """graphdeco computeColorFromSH without the +0.5/clamp: [M,3] from dc [M,3], rest [M,K,3].
    ``colour`` [3, 3]: ``rest`` is held in another colour space (:class:`ColourRows`); its
    view-dependent sum v is turned to ``v @ colour`` before the DC term is added."""
    if colour is not None:
        v = _eval_sh(deg, torch.zeros_like(dc), rest, dirs)
        # term by term, in the C++ kernel's order
        return SH_C0 * dc + (v[:, 0:1] * colour[0] + v[:, 1:2] * colour[1] + v[:, 2:3] * colour[2])
    result = SH_C0 * dc
    if deg > 0:
        x, y, z = (dirs[:, i:i + 1] for i in range(3))
        result = (result - SH_C1 * y * rest[:, 0] + SH_C1 * z * rest[:, 1]
                  - SH_C1 * x * rest[:, 2])
        if deg > 1:
            xx, yy, zz = x * x, y * y, z * z
            xy, yz, xz = x * y, y * z, x * z
            result = (result + SH_C2[0] * xy * rest[:, 3] + SH_C2[1] * yz * rest[:, 4]
                      + SH_C2[2] * (2.0 * zz - xx - yy) * rest[:, 5]
                      + SH_C2[3] * xz * rest[:, 6] + SH_C2[4] * (xx - yy) * rest[:, 7])
            if deg > 2:
                result = (result
                          + SH_C3[0] * y * (3.0 * xx - yy) * rest[:, 8]
                          + SH_C3[1] * xy * z * rest[:, 9]
                          + SH_C3[2] * y * (4.0 * zz - xx - yy) * rest[:, 10]
                          + SH_C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy) * rest[:, 11]
                          + SH_C3[4] * x * (4.0 * zz - xx - yy) * rest[:, 12]
                          + SH_C3[5] * z * (xx - yy) * rest[:, 13]
                          + SH_C3[6] * x * (xx - 3.0 * yy) * rest[:, 14])
    return result


def _preprocess(cloud: GaussianCloud, camera: Camera, deg: int, scale_modifier: float,
                want_color: bool = True, colour: np.ndarray | None = None) -> _Projected:
    W, H = camera.width, camera.height
    fx, fy, cx, cy = camera.fx, camera.fy, camera.cx, camera.cy
    R64 = torch.from_numpy(camera.R)
    pos = torch.from_numpy(cloud.positions)
    # Camera-space positions in float64 (cheap, and removes one rounding source), then f32.
    pv64 = pos.double() @ R64.T + torch.from_numpy(camera.t)
    keep = pv64[:, 2] > NEAR
    idx = torch.nonzero(keep).squeeze(1)
    pv64 = pv64[idx]
    pv = pv64.float()
    tx, ty, tz = pv[:, 0], pv[:, 1], pv[:, 2]

    # 3D covariance Sigma = R S S R^T from the normalised quaternion.
    q = torch.from_numpy(cloud.rotations)[idx]
    q = q / q.norm(dim=1, keepdim=True)
    r, x, y, z = q.unbind(1)
    Rq = torch.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - r * z), 2 * (x * z + r * y),
        2 * (x * y + r * z), 1 - 2 * (x * x + z * z), 2 * (y * z - r * x),
        2 * (x * z - r * y), 2 * (y * z + r * x), 1 - 2 * (x * x + y * y)], 1).view(-1, 3, 3)
    s = torch.exp(torch.from_numpy(cloud.scales)[idx]) * float(scale_modifier)
    Msr = Rq * s[:, None, :]                                  # R diag(s)
    sigma = Msr @ Msr.transpose(1, 2)                          # [M,3,3]

    # EWA: clamped perspective Jacobian.
    limx = 1.3 * (W / (2.0 * fx))
    limy = 1.3 * (H / (2.0 * fy))
    txc = torch.clamp(tx / tz, -limx, limx) * tz
    tyc = torch.clamp(ty / tz, -limy, limy) * tz
    zero = torch.zeros_like(tz)
    J = torch.stack([fx / tz, zero, -(fx * txc) / (tz * tz),
                     zero, fy / tz, -(fy * tyc) / (tz * tz)], 1).view(-1, 2, 3)
    T = J @ R64.float()                                        # J W, [M,2,3]
    cov = T @ sigma @ T.transpose(1, 2)                        # [M,2,2]
    a = cov[:, 0, 0] + DILATION
    b = cov[:, 0, 1]
    c = cov[:, 1, 1] + DILATION
    det = a * c - b * b
    det_inv = 1.0 / det
    conic = torch.stack([c * det_inv, -b * det_inv, a * det_inv], 1)
    mid = 0.5 * (a + c)
    lam1 = mid + torch.sqrt(torch.clamp(mid * mid - det, min=0.1))
    radius = torch.ceil(3.0 * torch.sqrt(lam1))
    means = torch.stack([(fx * pv64[:, 0] / pv64[:, 2] + (cx - 0.5)),
                         (fy * pv64[:, 1] / pv64[:, 2] + (cy - 0.5))], 1).float()
    gx, gy = (W + BLOCK - 1) // BLOCK, (H + BLOCK - 1) // BLOCK
    mx, my = means[:, 0], means[:, 1]
    # graphdeco getRect: C (int) casts truncate towards zero, then clamp to [0, grid].
    x0 = torch.clamp(((mx - radius) / BLOCK).to(torch.int64), 0, gx)
    y0 = torch.clamp(((my - radius) / BLOCK).to(torch.int64), 0, gy)
    x1 = torch.clamp(((mx + radius + (BLOCK - 1)) / BLOCK).to(torch.int64), 0, gx)
    y1 = torch.clamp(((my + radius + (BLOCK - 1)) / BLOCK).to(torch.int64), 0, gy)
    ok = (det != 0) & (radius > 0) & ((x1 - x0) * (y1 - y0) > 0)
    sel = torch.nonzero(ok).squeeze(1)
    # Front-to-back; stable so equal depths keep index order (graphdeco's stable radix sort).
    order = sel[torch.sort(tz[sel], stable=True).indices]
    idx = idx[order]
    conic = conic[order].contiguous()
    means = means[order].contiguous()
    rects = torch.stack([x0, y0, x1, y1], 1)[order].to(torch.int32).contiguous()
    opacity = torch.sigmoid(torch.from_numpy(cloud.opacities)[idx])

    if want_color:
        dc = torch.from_numpy(cloud.sh_dc)[idx]
        k = (deg + 1) ** 2 - 1
        rest = torch.from_numpy(cloud.sh_rest[:, :k])[idx] if k else None
        campos = torch.from_numpy(camera.center).float()
        dirs = pos[idx] - campos
        dirs = dirs / dirs.norm(dim=1, keepdim=True)
        turn = torch.from_numpy(colour) if colour is not None and k else None
        colors = torch.clamp_min(_eval_sh(deg, dc, rest, dirs, turn) + 0.5, 0.0).contiguous()
    else:
        colors = torch.zeros((len(idx), 3), dtype=torch.float32)

    return _Projected(idx, means, conic, opacity, colors, rects)


# ----------------------------------------------------------------------------------------------
# pure-torch reference rasteriser
# ----------------------------------------------------------------------------------------------

def _rasterize_torch(p: _Projected, W: int, H: int, want_importance: bool):
    """Reference: graphdeco's per-pixel loop, vectorised over all pixels of all tiles.

    Returns (image [H,W,3] f32 without background, T [H,W] f32, importance [M] f64 or None).
    Step k processes the k-th entry (front to back) of every tile's list at once, so float32
    T is updated sequentially exactly like the CUDA kernel (no cumprod re-association).
    """
    M = p.means.shape[0]
    gx, gy = (W + BLOCK - 1) // BLOCK, (H + BLOCK - 1) // BLOCK
    ntiles = gx * gy
    counts_g = ((p.rects[:, 2] - p.rects[:, 0]) * (p.rects[:, 3] - p.rects[:, 1])).long()
    E = int(counts_g.sum())
    # Entries in depth order; each Gaussian's tiles row-major inside its rectangle.
    ent_g = torch.repeat_interleave(torch.arange(M), counts_g)
    start = torch.cumsum(counts_g, 0) - counts_g
    local = torch.arange(E) - torch.repeat_interleave(start, counts_g)
    rw = (p.rects[:, 2] - p.rects[:, 0]).long()[ent_g]
    ent_tile = ((p.rects[ent_g, 1].long() + local // rw) * gx
                + p.rects[ent_g, 0].long() + local % rw)
    order = torch.sort(ent_tile, stable=True).indices          # by tile, depth order kept
    ent_g, ent_tile = ent_g[order], ent_tile[order]
    tile_count = torch.bincount(ent_tile, minlength=ntiles)
    tile_start = torch.cumsum(tile_count, 0) - tile_count
    # Tiles by decreasing list length: the tiles still active at step k are a prefix.
    torder = torch.sort(tile_count, descending=True, stable=True).indices
    cnt_sorted = tile_count[torder]
    lmax = int(cnt_sorted[0]) if ntiles else 0

    ty, tx = torder // gx, torder % gx
    loc = torch.arange(BLOCK * BLOCK)
    px = (tx[:, None] * BLOCK + loc[None, :] % BLOCK)           # [ntiles, 256]
    py = (ty[:, None] * BLOCK + loc[None, :] // BLOCK)
    inside = (px < W) & (py < H)
    pxf, pyf = px.float(), py.float()
    T = torch.ones(ntiles, BLOCK * BLOCK)
    C = torch.zeros(ntiles, BLOCK * BLOCK, 3)
    done = ~inside
    ent_imp = torch.zeros(E, dtype=torch.float64) if want_importance else None
    base = tile_start[torder]
    # Number of tiles with a list longer than k, for every k.
    n_active = torch.searchsorted(-cnt_sorted, -torch.arange(lmax), right=False) \
        if lmax else torch.zeros(0, dtype=torch.long)
    # searchsorted on the negated descending counts: first position with -cnt >= -k, i.e.
    # cnt <= k; tiles before it have cnt > k.
    for k in range(lmax):
        n = int(n_active[k])
        if n == 0:
            break
        if bool(done[:n].all()):
            continue
        e = base[:n] + k
        g = ent_g[e]
        m = p.means[g]
        dx = m[:, 0:1] - pxf[:n]
        dy = m[:, 1:2] - pyf[:n]
        cq = p.conic[g]
        power = (-0.5 * (cq[:, 0:1] * dx * dx + cq[:, 2:3] * dy * dy)
                 - cq[:, 1:2] * dx * dy)
        alpha = torch.clamp_max(p.opacity[g][:, None] * torch.exp(power), ALPHA_MAX)
        contrib = ~done[:n] & ~(power > 0) & ~(alpha < ALPHA_MIN)
        Tn = T[:n]
        test_t = Tn * (1.0 - alpha)
        stop = contrib & (test_t < T_MIN)
        add = contrib & ~stop
        done[:n] |= stop
        C[:n] += torch.where(add[..., None],
                             p.colors[g][:, None, :] * alpha[..., None] * Tn[..., None], 0.0)
        if want_importance:
            ent_imp[e] = torch.where(add, alpha.double() * Tn.double(), 0.0).sum(1)
        T[:n] = torch.where(add, test_t, Tn)

    img = torch.zeros(H * W, 3)
    trans = torch.ones(H * W)
    flat = (py * W + px)[inside]
    img[flat] = C[inside]
    trans[flat] = T[inside]
    imp = None
    if want_importance:
        # Sequential reduction in (tile, depth) entry order: deterministic.
        imp = np.bincount(ent_g.numpy(), weights=ent_imp.numpy(), minlength=M)
    return img.view(H, W, 3), trans.view(H, W), imp


# ----------------------------------------------------------------------------------------------
# compiled kernel
# ----------------------------------------------------------------------------------------------

_KERNEL = None
_KERNEL_TRIED = False
#: Threads of the compiled kernel when set (see :func:`render_threads`); None: torch's setting.
_THREADS = None
_KERNEL_LOCK = threading.Lock()
_KERNEL_SRC = Path(__file__).resolve().parent.parent / "kernels" / "render_cpu.cpp"


#: Compiler flags of the kernel: fixed (no -march=native) so every machine builds the same
#: arithmetic; part of the build key.
_KERNEL_CFLAGS = ["-O3", "-ffp-contract=off", "-fno-math-errno"]
#: What gsz says, once, when it compiles the kernel (a first use, or a new gsz/torch/source).
COMPILE_MESSAGE = "gsz: compiling the CPU rasteriser (once, ~1 min)"


def _kernel_source() -> Path:
    src = _KERNEL_SRC
    if not src.exists():  # installed (non-editable) layout: gsz/kernels/render_cpu.cpp
        from .. import kernels
        src = Path(kernels.__file__).resolve().parent / "render_cpu.cpp"
    return src


def kernel_build_name(src: Path | None = None) -> str:
    """The kernel's module and cache-folder name: ``gsz_render_cpu_<key>``, the key a hash of
    the gsz version, the source, the flags, torch's version and the Python ABI.  Installs of
    different gsz or torch versions (or a changed source) each keep their own build instead
    of rebuilding a shared fixed-name one in turn; the same install finds its build again."""
    import hashlib
    import sys

    from .. import __version__
    h = hashlib.sha256()
    for part in (__version__, torch.__version__, " ".join(_KERNEL_CFLAGS),
                 f"py{sys.version_info[0]}{sys.version_info[1]}{getattr(sys, 'abiflags', '')}"):
        h.update(part.encode() + b"\0")
    h.update((src or _kernel_source()).read_bytes())
    return f"gsz_render_cpu_{h.hexdigest()[:16]}"


def _kernel_built(name: str) -> bool:
    """Whether the build folder of ``name`` already holds its compiled module."""
    try:
        from torch.utils.cpp_extension import _get_build_directory
        folder = _get_build_directory(name, verbose=False)
    except Exception:                  # a torch without the helper: say nothing rather than wrong
        return True
    return any(Path(folder).glob(f"{name}*.so")) or any(Path(folder).glob(f"{name}*.pyd"))


#: A build lock older than this is left by a compile that was killed (a real one takes
#: minutes): torch would wait on it forever, so every later encode would hang.
STALE_LOCK_S = 900


def _clear_stale_lock(name: str) -> None:
    """Remove the build folder's ``lock`` when it is older than STALE_LOCK_S (with a warning)."""
    try:
        from torch.utils.cpp_extension import _get_build_directory
        lock = Path(_get_build_directory(name, verbose=False)) / "lock"
        age = time.time() - lock.stat().st_mtime
    except Exception:                  # no lock (the usual case), or a torch without the helper
        return
    if age > STALE_LOCK_S:
        warnings.warn(f"gsz.evaluation.render: removing a stale rasteriser build lock ({age / 60:.0f} min "
                      f"old, left by a killed compile): {lock}", RuntimeWarning, stacklevel=3)
        lock.unlink(missing_ok=True)


def _load_kernel():
    """The compiled rasteriser module, or None (with a warning) when it cannot be built."""
    global _KERNEL, _KERNEL_TRIED
    with _KERNEL_LOCK:
        if _KERNEL_TRIED:
            return _KERNEL
        _KERNEL_TRIED = True
        try:
            from torch.utils.cpp_extension import load
            src = _kernel_source()
            name = kernel_build_name(src)
            _clear_stale_lock(name)
            if not _kernel_built(name):
                import sys
                print(COMPILE_MESSAGE, file=sys.stderr, flush=True)
            _KERNEL = load(name=name, sources=[str(src)], extra_cflags=list(_KERNEL_CFLAGS), verbose=False)
        except Exception as exc:  # compiler missing, headers missing, ...
            warnings.warn(f"gsz.evaluation.render: C++ rasteriser unavailable ({exc!r}); "
                          f"falling back to the (much slower) pure-torch rasteriser",
                          RuntimeWarning, stacklevel=3)
            _KERNEL = None
        return _KERNEL


@contextlib.contextmanager
def render_threads(n: int | None):
    """Run the compiled kernel with ``n`` threads inside the block, whatever torch's own
    thread count is.  The size search runs torch's maths single-threaded (OpenMP barriers stall
    on a shared 2-core machine) but keeps the renderer, whose tiles are handed out dynamically,
    on every core; the kernel's output does not depend on its thread count."""
    global _THREADS
    old = _THREADS
    _THREADS = None if n is None else max(1, int(n))
    try:
        yield
    finally:
        _THREADS = old


def kernel_available() -> bool:
    """True when the compiled C++ rasteriser can be used (builds it on first call)."""
    return _load_kernel() is not None


def _backend() -> str:
    b = os.environ.get("GSZ_RENDER_BACKEND", "auto").lower()
    if b not in ("auto", "torch", "cpp"):
        raise GszError(f"GSZ_RENDER_BACKEND must be auto, torch or cpp, got {b!r}")
    return b


def _render_arrays(cloud: GaussianCloud, camera: Camera, deg: int, scale_modifier: float,
                   want_color: bool, want_importance: bool, backend: str,
                   colour: np.ndarray | None = None):
    """(image [H,W,3] f32 without background, T [H,W] f32, importance [N] f64 or None);
    ``colour``: the [3, 3] matrix of an SH rest held in another colour space (ColourRows)."""
    W, H = camera.width, camera.height
    kern = _load_kernel() if backend in ("auto", "cpp") else None
    if kern is None and backend == "cpp":
        raise GszError("render: the C++ rasteriser was requested but could not be built")
    made = isinstance(cloud.sh_rest, MadeRows)
    k = (deg + 1) ** 2 - 1
    if made and (kern is None or not (want_color and k)):
        # no chunked colour pass reads the rows: they are checked here (the torch reference
        # then takes them whole)
        whole = np.empty(cloud.sh_rest.shape, np.float32) if kern is None and want_color and k else None
        for s, e, rows in _made_rows(cloud.sh_rest):
            if whole is not None:
                whole[s:e] = rows
        if whole is not None:
            cloud = dataclasses.replace(cloud, sh_rest=whole)
        made = False
    if kern is None:
        p = _preprocess(cloud, camera, deg, scale_modifier, want_color, colour)
        img, trans, imp_vis = _rasterize_torch(p, W, H, want_importance)
        imp = None
        if want_importance:
            imp = np.zeros(len(cloud), dtype=np.float64)
            imp[p.index.numpy()] = imp_vis
        return img, trans, imp
    nthreads = _THREADS or max(1, torch.get_num_threads())
    cam = np.concatenate([camera.R.reshape(-1), camera.t,
                          [camera.fx, camera.fy, camera.cx, camera.cy]]).astype(np.float64)
    rest = cloud.sh_rest[:, :k] if k and not made else np.zeros((len(cloud), 0, 3), np.float32)
    f32 = [torch.from_numpy(np.ascontiguousarray(a, dtype=np.float32)) for a in (
        cloud.positions, cloud.scales, cloud.rotations, cloud.opacities, cloud.sh_dc, rest)]
    cam_t = torch.from_numpy(cam)
    turn = torch.from_numpy(colour if colour is not None and k else np.zeros(0, np.float32))
    # a made SH rest: colours after preprocessing, a row range at a time (its rows never whole)
    means, conic, opac, colors, boxes, order = kern.preprocess(
        *f32, turn, cam_t, W, H, 0 if made else deg, float(scale_modifier),
        bool(want_color and not made), nthreads)
    if made:
        for s, e, rows in _made_rows(cloud.sh_rest):
            kern.sh_colors(f32[0][s:e], f32[4][s:e], torch.from_numpy(np.ascontiguousarray(rows[:, :k])),
                           turn, cam_t, deg, colors[s:e], nthreads)
    img, trans, imp = kern.rasterize(means, conic, opac, colors, boxes, order, W, H,
                                     bool(want_importance), nthreads)
    return img, trans, (imp.numpy() if want_importance else None)


# ----------------------------------------------------------------------------------------------
# public API
# ----------------------------------------------------------------------------------------------

def _render(cloud: GaussianCloud, camera: Camera, *, background=(0.0, 0.0, 0.0),
            sh_degree: int | None = None, return_importance: bool = False,
            scale_modifier: float = 1.0, backend: str | None = None,
            want_color: bool = True) -> RenderOutput:
    colour = None
    if isinstance(cloud, GaussianCloud) and isinstance(cloud.sh_rest, ColourRows):
        # the coded field is read as it is and its colours turned (the same colours, rounded
        # apart): no row range made, and a whole field keeps the whole-array path
        colour = cloud.sh_rest.matrix
        cloud = dataclasses.replace(cloud, sh_rest=cloud.sh_rest.coded)
    deg = _check_inputs(cloud, camera, sh_degree)
    bg = np.asarray(background, dtype=np.float32).reshape(-1)
    if bg.shape != (3,) or not np.isfinite(bg).all():
        raise GszError(f"render: background must be 3 finite numbers, got {background!r}")
    if not (math.isfinite(scale_modifier) and scale_modifier > 0):
        raise GszError(f"render: scale_modifier must be positive, got {scale_modifier}")
    with torch.no_grad():
        img, trans, importance = _render_arrays(cloud, camera, deg, scale_modifier, want_color,
                                                return_importance, backend or _backend(), colour)
    trans_np = trans.numpy()
    image = img.numpy() + trans_np[..., None] * bg[None, None, :]
    return RenderOutput(image=np.ascontiguousarray(image, dtype=np.float32),
                        alpha=(1.0 - trans_np).astype(np.float32), importance=importance)


def render(cloud: GaussianCloud, camera: Camera, *, background=(0.0, 0.0, 0.0),
           sh_degree: int | None = None, return_importance: bool = False,
           scale_modifier: float = 1.0) -> RenderOutput:
    """Render ``cloud`` from ``camera`` with graphdeco 3DGS forward semantics (see module doc).

    background        3 floats, composited as ``C + T * background``
    sh_degree         SH degree to evaluate (default: the cloud's), must be <= cloud.sh_degree
    return_importance also return per-Gaussian ``sum over pixels of alpha*T`` ([N] float64)
    scale_modifier    multiplies every scale (graphdeco's ``scaling_modifier``)

    Raises :class:`GszError` for a malformed cloud/camera or bad options.
    """
    return _render(cloud, camera, background=background, sh_degree=sh_degree,
                   return_importance=return_importance, scale_modifier=scale_modifier)


def accumulate_importance(cloud: GaussianCloud, cameras: list[Camera], *,
                          progress: Callable[[int, int], None] | None = None) -> np.ndarray:
    """[N] float64: sum over ``cameras`` (in list order) of each view's render importance.

    Colour does not influence alpha, so SH is not evaluated.  ``progress(i, n)`` is called
    after view i (1-based) of n.
    """
    cams = list(cameras)
    total = np.zeros(len(cloud), dtype=np.float64)
    for i, cam in enumerate(cams):
        out = _render(cloud, cam, sh_degree=0, return_importance=True, want_color=False)
        total += out.importance
        if progress is not None:
            progress(i + 1, len(cams))
    return total


def framing_camera(positions: np.ndarray, width: int, height: int, *,
                   direction=(0.3, -0.5, -1.0), distance_factor: float = 2.0,
                   fov_x_deg: float = 60.0) -> Camera:
    """A camera that frames a scene: looks at the median position from ``distance_factor``
    times the 1-99 percentile extent (largest side of that box), from ``direction`` (world,
    +y down, so the default looks slightly from above)."""
    pos = np.asarray(positions, np.float64)
    centre = np.median(pos, axis=0)
    lo, hi, _ = robust_bounds(pos)
    extent = float(np.max(hi - lo))
    d = np.asarray(direction, np.float64)
    d /= np.linalg.norm(d)
    fx = width / (2.0 * math.tan(math.radians(fov_x_deg) / 2.0))
    return look_at(centre + d * distance_factor * extent, centre, (0.0, -1.0, 0.0), fx=fx, fy=fx,
                   width=width, height=height, name="framing")
