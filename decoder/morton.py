"""Morton (Z-order) codes of integer voxel coordinates -- THE canonical point order of gsz.

Every per-point stream of the format is stored in ascending Morton order of the points' voxel
coordinates (see ``format_spec/OCTREE.md``), so this module is the single definition of that order.

Bit interleave (normative): for a voxel ``(i, j, k)`` = (x, y, z), each axis at most 21 bits,

    code bit 3*b + 2 = bit b of x
    code bit 3*b + 1 = bit b of y
    code bit 3*b + 0 = bit b of z          (b = 0 .. 20)

so the three bits of level ``b`` form the octree child index ``4*x_b + 2*y_b + z_b`` and the
ascending code order equals the depth-first octree order with children visited 0..7.
Codes fit in 63 bits of a uint64.
"""
from __future__ import annotations

import numpy as np

from .errors import GszFormatError

MAX_DEPTH = 21
_MASK21 = np.uint64((1 << 21) - 1)


def _spread3(v: np.ndarray) -> np.ndarray:
    """Insert two zero bits between each of the low 21 bits of ``v`` (uint64 [M] -> uint64 [M])."""
    v = v & _MASK21
    v = (v | (v << np.uint64(32))) & np.uint64(0x1F00000000FFFF)
    v = (v | (v << np.uint64(16))) & np.uint64(0x1F0000FF0000FF)
    v = (v | (v << np.uint64(8))) & np.uint64(0x100F00F00F00F00F)
    v = (v | (v << np.uint64(4))) & np.uint64(0x10C30C30C30C30C3)
    v = (v | (v << np.uint64(2))) & np.uint64(0x1249249249249249)
    return v


def _compact3(v: np.ndarray) -> np.ndarray:
    """Inverse of :func:`_spread3`: gather every third bit (bits 0, 3, 6, ...) into the low 21 bits."""
    v = v & np.uint64(0x1249249249249249)
    v = (v | (v >> np.uint64(2))) & np.uint64(0x10C30C30C30C30C3)
    v = (v | (v >> np.uint64(4))) & np.uint64(0x100F00F00F00F00F)
    v = (v | (v >> np.uint64(8))) & np.uint64(0x1F0000FF0000FF)
    v = (v | (v >> np.uint64(16))) & np.uint64(0x1F00000000FFFF)
    v = (v | (v >> np.uint64(32))) & _MASK21
    return v


def morton_encode(ijk: np.ndarray) -> np.ndarray:
    """Morton codes of voxel coordinates.

    ijk: int or uint array [M, 3] (x, y, z), every value in [0, 2^21).
    Returns uint64 [M] with x in the highest bit of each 3-bit group (module docstring).
    Raises ValueError on a wrong shape or out-of-range coordinates (encoder-side input error).
    """
    a = np.asarray(ijk)
    if a.ndim != 2 or a.shape[1] != 3:
        raise ValueError(f"morton_encode expects an [M, 3] array, got shape {a.shape}")
    if not np.issubdtype(a.dtype, np.integer):
        raise ValueError(f"morton_encode expects integer coordinates, got dtype {a.dtype}")
    if a.size and (a.min() < 0 or a.max() >= (1 << MAX_DEPTH)):
        raise ValueError(f"voxel coordinates must lie in [0, 2^{MAX_DEPTH}), got range "
                         f"[{a.min()}, {a.max()}]")
    u = a.astype(np.uint64, copy=False)
    return (_spread3(u[:, 0]) << np.uint64(2)) | (_spread3(u[:, 1]) << np.uint64(1)) | _spread3(u[:, 2])


def _checked_codes(codes) -> np.ndarray:
    """uint64 [M] view of ``codes``; GszFormatError unless 1-D and below 2^63."""
    c = np.asarray(codes)
    if c.ndim != 1:
        raise GszFormatError(f"morton_decode expects a 1-D code array, got shape {c.shape}")
    c = c.astype(np.uint64, copy=False)
    if c.size and int(c.max()) >= (1 << (3 * MAX_DEPTH)):
        raise GszFormatError("Morton code out of range (more than 63 bits)")
    return c


def morton_decode(codes: np.ndarray) -> np.ndarray:
    """Voxel coordinates of Morton codes (inverse of :func:`morton_encode`).

    codes: uint64 [M] (values >= 2^63 are rejected: they cannot come from 21-bit coordinates).
    Returns int64 [M, 3] (x, y, z).
    """
    c = _checked_codes(codes)
    out = np.empty((c.shape[0], 3), dtype=np.int64)
    out[:, 0] = _compact3(c >> np.uint64(2))
    out[:, 1] = _compact3(c >> np.uint64(1))
    out[:, 2] = _compact3(c)
    return out


def morton_decode_planes(codes: np.ndarray) -> np.ndarray:
    """:func:`morton_decode` as three rows: int64 [3, M] (x, y, z), the same checks."""
    c = _checked_codes(codes)
    out = np.empty((3, c.shape[0]), dtype=np.int64)
    out[0] = _compact3(c >> np.uint64(2))
    out[1] = _compact3(c >> np.uint64(1))
    out[2] = _compact3(c)
    return out
