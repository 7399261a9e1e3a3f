"""Read antimatter15 .splat files (numpy only).

A .splat has no header: one 32-byte row per Gaussian, ``x y z`` (float32), the linear scales
``sx sy sz`` (float32), colour and alpha bytes (``0.5 + SH_C0 * dc`` and the sigmoid, times
255) and the unit quaternion (w, x, y, z) as bytes ``q * 128 + 128``; SH degree 0, PLY (RDF)
frame.  Lacking a magic number, a file is taken for a .splat when its size is a multiple of 32
and its rows hold finite positions and positive finite scales (:func:`splat_problem`).
"""
from __future__ import annotations

import os

import numpy as np

from .cloud import GaussianCloud
from .delivery import dc_of_colour_bytes, logit_of_alpha_bytes, unit_quaternions
from .io_util import read_all
from .errors import SplatFormatError

ROW = 32
_ROW_DTYPE = np.dtype([("pos", "<f4", 3), ("scale", "<f4", 3), ("rgba", "u1", 4), ("rot", "u1", 4)])
#: rows checked by the content test (a file's first rows; the reader checks them all)
SNIFF_ROWS = 64


def splat_problem(head: bytes, size: int) -> str | None:
    """Why a file of ``size`` bytes starting with ``head`` is not a .splat, or None when its
    size and first rows fit one."""
    if size == 0 or size % ROW:
        return f"its size, {size:,} bytes, is not a positive multiple of the 32-byte .splat row"
    rows = np.frombuffer(head[:min(len(head), SNIFF_ROWS * ROW) // ROW * ROW], _ROW_DTYPE)
    return _rows_problem(rows)


def _rows_problem(rows: np.ndarray, first: int = 0) -> str | None:
    bad = ~np.isfinite(rows["pos"]).all(axis=1)
    if bad.any():
        return f"row {first + int(np.argmax(bad))} holds a non-finite position"
    s = rows["scale"]
    bad = ~(np.isfinite(s).all(axis=1) & (s > 0).all(axis=1))
    if bad.any():
        return f"row {first + int(np.argmax(bad))} holds a scale that is not positive and finite"
    return None


def read_splat(path) -> GaussianCloud:
    """The scene in the .splat file ``path`` as a graphdeco cloud; :class:`SplatFormatError`
    naming the file when its size or a row is not a .splat's."""
    path = os.fspath(path)
    data = read_all(path, SplatFormatError)
    if len(data) == 0 or len(data) % ROW:
        raise SplatFormatError(f"not a .splat: its size, {len(data):,} bytes, is not a positive "
                               "multiple of the 32-byte row (truncated?)", path)
    rows = np.frombuffer(data, _ROW_DTYPE)
    problem = _rows_problem(rows)
    if problem:
        raise SplatFormatError(f"corrupt .splat: {problem}", path)
    rot = (rows["rot"].astype(np.float64) - 128.0) / 128.0
    return GaussianCloud(
        positions=rows["pos"], scales=np.log(rows["scale"].astype(np.float64)).astype(np.float32),
        rotations=unit_quaternions(rot), opacities=logit_of_alpha_bytes(rows["rgba"][:, 3]),
        sh_dc=dc_of_colour_bytes(rows["rgba"][:, :3]), sh_rest=np.zeros((len(rows), 0, 3), np.float32),
        sh_degree=0)

