"""Per-Gaussian importance and importance-based pruning (MesonGS++ §2, reference notes §2).

    I_i = I_d(i) * I_v(i)

* ``I_d`` (view-dependent term): sum over every training view and pixel of alpha_i(p) * T_i(p),
  the Gaussian's contribution weight in front-to-back compositing.  It comes from the reference
  renderer :func:`gsz.evaluation.render.accumulate_importance` (deterministic accumulation, unlike
  the authors' racy ``+=`` kernel).
* ``I_v`` (volume term): ``(V_i / V_ref) ** beta`` with ``V_i`` the product of the three
  *activated* scales ``exp(s_ik)`` (no 4/3 pi: it cancels in the ratio).  ``V_ref`` is a fixed
  low quantile of ``V``.  The reference code sorts V descending and takes the element at
  ``floor(0.9 N)``, i.e. the value exceeded by 90 % of the Gaussians (~10th percentile), although
  its variable name suggests the 90th.  We keep that behaviour: ``ref_quantile=0.1`` means the
  ascending element at index ``floor(0.1 * (N - 1))`` (numpy ``method="lower"``), which is the
  same element up to one rank.  ``V_ref`` only rescales all importances by a common factor
  ``V_ref ** -beta``, so it changes no ranking; it only keeps the numbers O(1).

The volume term is computed in log space (``beta * (sum(s) - log V_ref)``), so huge or tiny
scales cannot overflow float32/float64 before the power is applied.
"""
from __future__ import annotations

import math
from typing import Callable, Sequence

import numpy as np

from ..decoder.cloud import GaussianCloud
from ..decoder.errors import GszError

#: Default exponent of the volume term (the reference's default and most scenes' value).
DEFAULT_BETA = 0.1
#: Default quantile of V used as V_ref (the reference: value exceeded by 90 % of Gaussians).
DEFAULT_REF_QUANTILE = 0.1


class ImportanceError(GszError, ValueError):
    """Bad input to the importance / pruning stage (invalid options or non-finite values)."""


def _check_beta_quantile(beta: float, ref_quantile: float) -> None:
    if not (isinstance(beta, (int, float, np.floating, np.integer)) and math.isfinite(beta)
            and beta >= 0):
        raise ImportanceError(f"beta must be a finite number >= 0, got {beta!r}")
    if not (isinstance(ref_quantile, (int, float, np.floating, np.integer))
            and 0.0 <= ref_quantile <= 1.0):
        raise ImportanceError(f"ref_quantile must be in [0, 1], got {ref_quantile!r}")


def volume_term(cloud: GaussianCloud, beta: float = DEFAULT_BETA,
                ref_quantile: float = DEFAULT_REF_QUANTILE) -> np.ndarray:
    """The volume factor ``(V / V_ref) ** beta`` of every Gaussian.

    cloud        GaussianCloud with N Gaussians (``scales`` [N, 3] are natural-log std devs)
    beta         exponent >= 0 (0 turns the factor into all ones)
    ref_quantile V_ref = the ascending element of V at index floor(ref_quantile * (N - 1))
    returns      [N] float64, > 0 and finite for finite scales

    Raises :class:`ImportanceError` for invalid options or non-finite scales.
    """
    _check_beta_quantile(beta, ref_quantile)
    scales = np.asarray(cloud.scales)
    if scales.ndim != 2 or scales.shape[1] != 3:
        raise ImportanceError(f"cloud.scales must be [N, 3], got shape {scales.shape}")
    n = scales.shape[0]
    if n == 0:
        return np.zeros(0, np.float64)
    log_v = scales.astype(np.float64).sum(axis=1)
    if not np.all(np.isfinite(log_v)):
        bad = int(np.argmax(~np.isfinite(log_v)))
        raise ImportanceError(f"non-finite log-scale at Gaussian {bad}; cannot compute volume")
    # method="lower" picks an actual element (no interpolation), as the reference does.
    log_vref = float(np.quantile(log_v, ref_quantile, method="lower"))
    return np.exp(beta * (log_v - log_vref))


def compute_importance(cloud: GaussianCloud, cameras: Sequence, *, beta: float = DEFAULT_BETA,
                       ref_quantile: float = DEFAULT_REF_QUANTILE,
                       progress: Callable | None = None) -> np.ndarray:
    """Global importance ``I = I_d * (V / V_ref) ** beta`` of every Gaussian.

    cloud    GaussianCloud, N Gaussians
    cameras  the training views (``gsz.evaluation.cameras.Camera``); at least one
    progress optional callback forwarded to the renderer
    returns  [N] float64 >= 0 (0 for Gaussians no training pixel sees)

    The view term is rendered once over all cameras by
    :func:`gsz.evaluation.render.accumulate_importance`; the volume term is :func:`volume_term`.
    """
    _check_beta_quantile(beta, ref_quantile)
    cameras = list(cameras)
    if not cameras:
        raise ImportanceError("compute_importance needs at least one training camera")
    # Imported here: the renderer pulls in torch, which this module otherwise does not need.
    from ..evaluation.render import accumulate_importance

    i_d = np.asarray(accumulate_importance(cloud, cameras, progress=progress), np.float64)
    if i_d.shape != (len(cloud),):
        raise ImportanceError(
            f"renderer returned importance of shape {i_d.shape}, expected ({len(cloud)},)")
    if not np.all(np.isfinite(i_d)) or (i_d < 0).any():
        raise ImportanceError("renderer returned negative or non-finite view importance")
    return i_d * volume_term(cloud, beta=beta, ref_quantile=ref_quantile)


def keep_count(n: int, reserve: float) -> int:
    """Number of Gaussians kept out of ``n`` at reserve ratio ``reserve``: ceil(reserve * n).

    The product is shrunk by a relative 1e-12 before the ceiling so that binary rounding of
    e.g. ``0.1 * 10`` (= 1.0000000000000002) does not keep one Gaussian too many.  At least one
    Gaussian is kept when ``n > 0``.
    """
    if isinstance(reserve, bool) or not isinstance(reserve, (int, float, np.floating, np.integer)):
        raise ImportanceError(f"reserve must be a number in (0, 1], got {reserve!r}")
    reserve = float(reserve)
    if not (0.0 < reserve <= 1.0):
        raise ImportanceError(
            f"reserve (fraction of Gaussians to keep) must be in (0, 1], got {reserve!r}")
    if n <= 0:
        return 0
    return int(min(n, max(1, math.ceil(reserve * n * (1.0 - 1e-12)))))


def prune(importance: np.ndarray, reserve: float) -> np.ndarray:
    """Indices of the Gaussians kept at reserve ratio ``reserve``.

    importance [N] finite, >= 0 is not required (any finite values rank)
    reserve    fraction kept, in (0, 1]; keeps exactly ceil(reserve * N) (>= 1 when N > 0)
    returns    [ceil(reserve * N)] int64, sorted ascending

    The top ``k`` by importance are kept; among equal importances the lower index wins
    (stable sort), so the result is fully deterministic.  Unlike the reference (which removes
    every Gaussian tied at the threshold) the count is exact, which the size search relies on.
    """
    imp = np.asarray(importance)
    if imp.ndim != 1:
        raise ImportanceError(f"importance must be a 1-D array, got shape {imp.shape}")
    if imp.size and not np.all(np.isfinite(imp)):
        bad = int(np.argmax(~np.isfinite(imp)))
        raise ImportanceError(f"importance has non-finite values (first at index {bad})")
    k = keep_count(imp.shape[0], reserve)
    if k == imp.shape[0]:
        return np.arange(k, dtype=np.int64)
    return np.flatnonzero(top_k_mask(imp, k)).astype(np.int64)


def top_k_mask(importance: np.ndarray, k: int) -> np.ndarray:
    """[N] bool: the ``k`` most important entries, ties at the threshold to the lower index (the
    set a stable sort by decreasing importance takes first).  Linear: the k-th largest value
    by partition, everything above it, then its ties in index order."""
    n = importance.shape[0]
    mask = np.zeros(n, bool)
    if k >= n:
        mask[:] = True
    elif k > 0:
        kth = np.partition(importance, n - k)[n - k]
        above = importance > kth
        mask[above] = True
        mask[np.flatnonzero(importance == kth)[:k - int(np.count_nonzero(above))]] = True
    return mask
