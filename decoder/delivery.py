"""What the delivery-format readers (.spz, .splat, .ksplat, .sog, compressed PLY) share: the
8-bit conventions of web splat formats and a bounded whole-file read (numpy only).

Every one of these formats quantises alpha (after the sigmoid) and most the base colour (after
the SH DC term's ``0.5 + C0 * dc``) to bytes; the readers turn them back into the cloud's
pre-activation form here, one way for all of them.
"""
from __future__ import annotations


import numpy as np


#: graphdeco's degree-0 SH constant: colour = 0.5 + SH_C0 * dc
SH_C0 = 0.28209479177387814
#: alpha bytes 0 and 255 have no finite logit: they read as half a step inside the grid
#: (logit +-6.23), as the corpus decoders of shared/data do
ALPHA_EDGE = 0.5 / 255.0


def logit_of_alpha(alpha) -> np.ndarray:
    """float32 logit of alphas in [0, 1], kept finite at the ends (see :data:`ALPHA_EDGE`)."""
    a = np.clip(np.asarray(alpha, np.float64), ALPHA_EDGE, 1.0 - ALPHA_EDGE)
    return np.log(a / (1.0 - a)).astype(np.float32)


def logit_of_alpha_bytes(b) -> np.ndarray:
    """float32 logit of alpha bytes (alpha = b / 255)."""
    return logit_of_alpha(np.asarray(b, np.float64) / 255.0)


def dc_of_colour(c) -> np.ndarray:
    """float32 SH DC coefficient of a base colour in [0, 1] (inverse of 0.5 + SH_C0 * dc)."""
    return ((np.asarray(c, np.float64) - 0.5) / SH_C0).astype(np.float32)


def dc_of_colour_bytes(b) -> np.ndarray:
    """float32 SH DC coefficient of colour bytes (colour = b / 255)."""
    return dc_of_colour(np.asarray(b, np.float64) / 255.0)


def sigmoid(v) -> np.ndarray:
    """float64 logistic function, without overflow warnings for large |v|."""
    v = np.asarray(v, np.float64)
    return 0.5 * (1.0 + np.tanh(0.5 * v))


def unit_quaternions(q) -> np.ndarray:
    """float32 [N, 4] (w, x, y, z) of ``q`` scaled to unit length; an all-zero (or non-finite)
    row, which a byte grid can produce, becomes the identity rotation."""
    q = np.asarray(q, np.float64)
    n = np.linalg.norm(q, axis=1, keepdims=True)
    ok = (n[:, 0] > 0) & np.isfinite(n[:, 0])
    out = np.zeros_like(q)
    out[:, 0] = 1.0
    out[ok] = q[ok] / n[ok]
    return out.astype(np.float32)


def smallest_three(largest, a, b, c) -> np.ndarray:
    """[N, 4] (w, x, y, z) of quaternions stored as their three smaller components ``a, b, c``
    (in w, x, y, z order, the largest one skipped) and the index ``largest`` of the one left
    out, which is rebuilt non-negative so that the quaternion has unit length."""
    n = len(largest)
    q = np.zeros((n, 4), np.float64)
    small = np.stack([a, b, c], axis=1).astype(np.float64)
    # the column each of the three stored values goes to, for each position of the largest
    cols = np.array([[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]])[np.asarray(largest, np.int64)]
    rows = np.arange(n)[:, None]
    q[rows, cols] = small
    q[np.arange(n), largest] = np.sqrt(np.maximum(0.0, 1.0 - (small * small).sum(axis=1)))
    return q
