"""Decode PlayCanvas's compressed PLY (``.compressed.ply``, SuperSplat and splat-transform
write it) from its parsed elements (numpy only; :func:`gsz.decoder.ply.read_ply` parses the
file and calls this when it sees the layout).

Elements: ``chunk`` (one row per 256 Gaussians: float min/max of position and log-scale, and
optionally of the base colour), ``vertex`` (four uint32 per Gaussian: ``packed_position``
11/10/11 bits over the chunk's box, ``packed_rotation`` 2 bits naming the largest of
(w, x, y, z) and three 10-bit smaller components over +-1/sqrt 2, ``packed_scale`` 11/10/11 bits
over the chunk's log-scale range, ``packed_color`` RGBA bytes) and optionally ``sh`` (``f_rest_*``
bytes, graphdeco channel-major order, ``(b + 0.5) / 256`` over -4..4).  PLY (RDF) frame.
"""
from __future__ import annotations

import numpy as np

from .cloud import GaussianCloud
from .delivery import dc_of_colour, logit_of_alpha, smallest_three, unit_quaternions
from .errors import PlyFormatError

CHUNK = 256
_PACKED = ("packed_position", "packed_rotation", "packed_scale", "packed_color")
_BOUNDS = ("min_x", "min_y", "min_z", "max_x", "max_y", "max_z",
           "min_scale_x", "min_scale_y", "min_scale_z", "max_scale_x", "max_scale_y", "max_scale_z")
_COLOUR_BOUNDS = ("min_r", "min_g", "min_b", "max_r", "max_g", "max_b")
_REST_TO_K = {0: 0, 9: 3, 24: 8, 45: 15}


def is_compressed_ply(ply) -> bool:
    """True for a parsed PLY laid out as PlayCanvas's compressed PLY."""
    names = [el.name for el in ply.elements]
    return "chunk" in names and "vertex" in names and "packed_position" in (ply["vertex"].data.dtype.names or ())


def _unorm(v: np.ndarray, shift: int, bits: int) -> np.ndarray:
    return ((v >> np.uint32(shift)) & np.uint32((1 << bits) - 1)).astype(np.float64) / ((1 << bits) - 1)


def decode_compressed_ply(ply, path: str) -> GaussianCloud:
    """The cloud held by a parsed compressed PLY; :class:`PlyFormatError` naming the file and
    the element or property at fault."""
    vertex, chunk = ply["vertex"].data, ply["chunk"].data
    vnames, cnames = set(vertex.dtype.names or ()), set(chunk.dtype.names or ())
    for p in _PACKED:
        if p not in vnames:
            raise PlyFormatError(f"compressed PLY: vertex element lacks '{p}'", path)
    for p in _BOUNDS:
        if p not in cnames:
            raise PlyFormatError(f"compressed PLY: chunk element lacks '{p}'", path)
    n = len(vertex)
    if len(chunk) < (n + CHUNK - 1) // CHUNK:
        raise PlyFormatError(f"compressed PLY: {len(chunk):,} chunks cannot hold {n:,} Gaussians "
                             f"({CHUNK} per chunk)", path)
    ci = np.arange(n) // CHUNK

    def bound(name):
        b = np.asarray(chunk[name], np.float64)
        if not np.isfinite(b).all():
            raise PlyFormatError(f"compressed PLY: chunk property '{name}' has non-finite values", path)
        return b[ci]

    def lerp(lo, hi, t):
        return bound(lo) * (1 - t) + bound(hi) * t

    pp, pr, ps, pc = (np.asarray(vertex[p]).astype(np.uint32) for p in _PACKED)
    positions = np.stack([lerp("min_x", "max_x", _unorm(pp, 21, 11)), lerp("min_y", "max_y", _unorm(pp, 11, 10)),
                          lerp("min_z", "max_z", _unorm(pp, 0, 11))], axis=1)
    scales = np.stack([lerp("min_scale_x", "max_scale_x", _unorm(ps, 21, 11)),
                       lerp("min_scale_y", "max_scale_y", _unorm(ps, 11, 10)),
                       lerp("min_scale_z", "max_scale_z", _unorm(ps, 0, 11))], axis=1)
    abc = [(_unorm(pr, shift, 10) - 0.5) * np.sqrt(2.0) for shift in (20, 10, 0)]
    rotations = smallest_three((pr >> np.uint32(30)).astype(np.int64), *abc)
    colour = np.stack([_unorm(pc, shift, 8) for shift in (24, 16, 8)], axis=1)
    if all(p in cnames for p in _COLOUR_BOUNDS):
        colour = np.stack([lerp(f"min_{c}", f"max_{c}", colour[:, i]) for i, c in enumerate("rgb")], axis=1)
    opacities = logit_of_alpha(_unorm(pc, 0, 8))
    rest = np.zeros((n, 0, 3), np.float32)
    degree = 0
    if "sh" in [el.name for el in ply.elements]:
        rest, degree = _sh(ply["sh"].data, n, path)
    return GaussianCloud(positions.astype(np.float32), scales.astype(np.float32), unit_quaternions(rotations),
                         opacities, dc_of_colour(colour), rest, degree)


def _sh(sh, n: int, path: str):
    names = list(sh.dtype.names or ())
    if len(sh) != n:
        raise PlyFormatError(f"compressed PLY: the sh element has {len(sh):,} rows for {n:,} Gaussians", path)
    if len(names) not in _REST_TO_K:
        raise PlyFormatError(f"compressed PLY: the sh element has {len(names)} properties; expected "
                             "9, 24 or 45 (SH degree 1-3)", path)
    k = _REST_TO_K[len(names)]
    rest = np.empty((n, k, 3), np.float32)
    for c in range(3):
        for j in range(k):
            name = f"f_rest_{c * k + j}"
            if name not in names:
                raise PlyFormatError(f"compressed PLY: the sh element lacks '{name}'", path)
            b = np.asarray(sh[name]).astype(np.float64)
            t = np.where(b == 0, 0.0, np.where(b == 255, 1.0, (b + 0.5) / 256.0))
            rest[:, j, c] = (t - 0.5) * 8.0
    return rest, {3: 1, 8: 2, 15: 3}[k]
