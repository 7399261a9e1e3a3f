"""Image fidelity metrics: PSNR and SSIM, following the MesonGS++ / 3DGS evaluation protocol.

Protocol (reference notes §11, ``splatwizard/pipeline/evaluation.py``):

* Images are [H, W, 3] float arrays; both are **clamped to [0, 1]** first (renders are linear
  and unclamped).  :func:`quantize_8bit` then rounds to 8 bits, ``round(255 x) / 255``: the
  reference rounds its render to 8 bits and compares it with 8-bit ground-truth images.  Here
  both images are renders (original vs compressed), so :func:`gsz.evaluation.evaluate.evaluate`
  rounds *both*, exactly as if the original render had been saved as the PNG ground truth.
  :func:`psnr` and :func:`ssim` themselves only clamp, so they also serve float comparisons.
* **PSNR** per image: ``10 log10(max_val^2 / MSE)`` over all pixels and channels, capped at
  ``cap`` (100 dB).  Identical images (MSE = 0) are reported AS THE CAP, never +inf, so means
  over views stay finite; with 8-bit rounding, differences below half a level also read as the
  cap.  Averaging over views is the caller's (mean of per-view dB values, as the reference).
* **SSIM**: 11x11 Gaussian window, sigma 1.5, C1 = 0.01^2, C2 = 0.03^2, computed per channel
  and averaged over channels and all pixels.  Like the reference's ``F.conv2d(..., padding=5)``
  the local statistics use **zero padding** at the borders and the mean includes the border
  pixels, so values match published 3DGS numbers.

Why our own SSIM: no well-kept SSIM library is a dependency (scikit-image, torchmetrics and
pytorch-msssim are not installed; the reference's is a 30-line conv2d function), and their
border handling differs from the reference (scikit-image crops 3 px and uses a sample-covariance
correction).  This is the reference formula on torch's ``conv2d`` in float64 (separable: one
11x1 and one 1x11 pass); ``tests/test_metrics.py`` cross-checks it against an independent
``scipy.ndimage.gaussian_filter`` implementation (mode='constant' = zero padding, truncate so
the radius is 5) to ~1e-12.
"""
from __future__ import annotations

import math

import numpy as np

#: PSNR reported for identical images (dB).
PSNR_CAP_DB = 100.0
SSIM_WINDOW = 11
SSIM_SIGMA = 1.5
SSIM_C1 = 0.01 ** 2
SSIM_C2 = 0.03 ** 2


def _as_image(a, name: str) -> np.ndarray:
    """[H, W, C] float64 clamped to [0, 1] (NaN -> 0, so a broken render scores badly, not NaN)."""
    if hasattr(a, "detach"):  # torch tensor
        a = a.detach().cpu().numpy()
    a = np.asarray(a, dtype=np.float64)
    if a.ndim == 2:
        a = a[:, :, None]
    if a.ndim != 3:
        raise ValueError(f"{name}: expected an [H, W, 3] image, got shape {a.shape}")
    return np.clip(np.nan_to_num(a, nan=0.0, posinf=1.0, neginf=0.0), 0.0, 1.0)


def _check_pair(a, b):
    a, b = _as_image(a, "a"), _as_image(b, "b")
    if a.shape != b.shape:
        raise ValueError(f"image shapes differ: {a.shape} vs {b.shape}")
    return a, b


def quantize_8bit(img) -> np.ndarray:
    """[H, W, C] float64: ``round(255 * clamp(img, 0, 1)) / 255`` (the protocol's 8-bit step)."""
    return np.round(_as_image(img, "img") * 255.0) / 255.0


def to_uint8(img) -> np.ndarray:
    """[H, W, C] uint8 of a float image (clamped, rounded): what a PNG of the render holds."""
    return np.round(_as_image(img, "img") * 255.0).astype(np.uint8)


def mse(a, b) -> float:
    """Mean squared error over all pixels and channels of two clamped images."""
    a, b = _check_pair(a, b)
    return float(np.mean((a - b) ** 2))


def psnr(a, b, *, max_val: float = 1.0, cap: float = PSNR_CAP_DB) -> float:
    """PSNR in dB of two [H, W, 3] images in [0, 1] (clamped first); identical -> ``cap``."""
    m = mse(a, b)
    if m <= 0.0:
        return float(cap)
    return float(min(cap, 10.0 * math.log10(max_val * max_val / m)))


def gaussian_window_1d(size: int = SSIM_WINDOW, sigma: float = SSIM_SIGMA) -> np.ndarray:
    """[size] float64 normalised Gaussian, centred on the middle tap (the reference window)."""
    x = np.arange(size, dtype=np.float64) - size // 2
    g = np.exp(-(x * x) / (2.0 * sigma * sigma))
    return g / g.sum()


def ssim_map(a, b) -> np.ndarray:
    """[H, W, C] float64 per-pixel SSIM (zero-padded 11x11 Gaussian statistics)."""
    import torch
    import torch.nn.functional as F

    a, b = _check_pair(a, b)
    h, w, c = a.shape
    g = torch.from_numpy(gaussian_window_1d())
    k = g.numel()
    pad = k // 2
    # Five statistics x C channels stacked as a batch of single-channel images.
    x = torch.from_numpy(np.ascontiguousarray(a.transpose(2, 0, 1)))
    y = torch.from_numpy(np.ascontiguousarray(b.transpose(2, 0, 1)))
    stack = torch.cat([x, y, x * x, y * y, x * y], dim=0)[:, None]  # [5C, 1, H, W]
    # Separable zero-padded filtering == the reference's 2-D conv2d(padding=5) with g g^T.
    out = F.conv2d(stack, g.view(1, 1, k, 1), padding=(pad, 0))
    out = F.conv2d(out, g.view(1, 1, 1, k), padding=(0, pad))[:, 0]
    mu_x, mu_y, exx, eyy, exy = out.split(c, dim=0)
    var_x = exx - mu_x * mu_x
    var_y = eyy - mu_y * mu_y
    cov = exy - mu_x * mu_y
    num = (2.0 * mu_x * mu_y + SSIM_C1) * (2.0 * cov + SSIM_C2)
    den = (mu_x * mu_x + mu_y * mu_y + SSIM_C1) * (var_x + var_y + SSIM_C2)
    return (num / den).numpy().transpose(1, 2, 0)


def ssim(a, b) -> float:
    """Mean SSIM of two [H, W, 3] images in [0, 1] (clamped first); identical -> 1.0."""
    return float(np.mean(ssim_map(a, b)))
