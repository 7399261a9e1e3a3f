"""GEOM chunk: voxel grid + octree occupancy -> Gaussian centres (GSZ.md §6).

Syntax::

    u8   depth d          1..21
    f64  origin[3]        cube corner
    f64  side             cube edge length (> 0, finite)
    u64  M                number of occupied voxels (= Gaussians of this geometry)
    byte payload[...]     octree occupancy (OCTREE.md), to the end of the chunk

Decoded centre of voxel (i, j, k): origin + (ijk + 0.5) * side / 2^d, computed in float64 and
rounded to float32.  Voxels come out in ascending Morton order, the order of every per-point stream.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .bytesio import Reader
from .morton import MAX_DEPTH
from .octree import decode_octree


@dataclass
class Geometry:
    ijk: np.ndarray        # [M, 3] int64, ascending Morton order
    origin: np.ndarray     # [3] float64
    side: float
    depth: int

    @property
    def positions(self) -> np.ndarray:
        return voxel_centres(self.ijk, self.origin, self.side, self.depth).astype(np.float32)


def voxel_centres(ijk: np.ndarray, origin, side: float, depth: int) -> np.ndarray:
    """Decoded positions ``origin + (ijk + 0.5) * side / 2^d`` as [M, 3] float64 (normative)."""
    pitch = float(side) / float(1 << int(depth))
    return np.asarray(origin, np.float64) + (np.asarray(ijk, np.float64) + 0.5) * pitch


def read_geometry(data, *, max_points: int) -> Geometry:
    r = Reader(data, "GEOM chunk")
    depth = r.u8()
    r.check(1 <= depth <= MAX_DEPTH, f"octree depth {depth} outside 1..{MAX_DEPTH}")
    origin = np.array([r.f64(), r.f64(), r.f64()])
    side = r.f64()
    r.check(all(math.isfinite(v) for v in origin) and math.isfinite(side) and side > 0,
            "non-finite grid origin or non-positive side")
    m = r.u64()
    r.check(1 <= m <= max_points, f"voxel count {m} outside 1..{max_points}")
    ijk = decode_octree(r.bytes(r.remaining), depth, m)
    return Geometry(ijk=ijk, origin=origin, side=side, depth=depth)
