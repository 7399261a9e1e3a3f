"""Writer of the GEOM chunk (syntax: ``gsz.decoder.geometry``)."""
from __future__ import annotations

import numpy as np

from ..decoder.bytesio import Writer
from .octree import encode_octree


def write_geometry(ijk: np.ndarray, origin, side: float, depth: int) -> bytes:
    w = Writer()
    w.u8(depth)
    for v in np.asarray(origin, np.float64):
        w.f64(v)
    w.f64(side).u64(len(ijk))
    w.bytes(encode_octree(ijk, depth))
    return w.getvalue()
