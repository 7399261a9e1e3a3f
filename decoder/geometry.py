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

from . import native
from .bytesio import Reader
from .errors import GszFormatError
from .morton import MAX_DEPTH, morton_decode, morton_decode_planes
from .octree import decode_octree_codes


@dataclass
class Geometry:
    ijk: np.ndarray        # [M, 3] int64, ascending Morton order
    origin: np.ndarray     # [3] float64
    side: float
    depth: int
    codes: np.ndarray | None = None   # [M] uint64 Morton codes of ijk (ascending), when known

    @property
    def positions(self) -> np.ndarray:
        return centres_float32(self.ijk.T, self.origin, self.side, self.depth)


@dataclass
class GeometryHeader:
    """The GEOM chunk's fields before its octree payload is decoded."""
    depth: int
    origin: np.ndarray     # [3] float64
    side: float
    num_points: int
    payload: memoryview

    def decode_codes(self, helper=None) -> np.ndarray:
        """Morton codes (uint64 [M], ascending) of the voxels (OCTREE.md); ``helper``: see
        :func:`gsz.decoder.octree.decode_octree_codes`."""
        return decode_octree_codes(self.payload, self.depth, self.num_points, helper)

    def positions(self, codes: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """Decoded float32 centres [M, 3] of the voxels with Morton codes ``codes`` (into
        ``out`` when given)."""
        if native.enabled():
            return self.native_positions(codes, out)[0]
        return centres_float32(morton_decode_planes(codes), self.origin, self.side, self.depth, out)

    def native_positions(self, codes: np.ndarray, out: np.ndarray | None = None) -> tuple[np.ndarray, bool]:
        """:meth:`positions` in C, and whether every coordinate is finite (native only)."""
        if out is None:
            out = np.empty((codes.shape[0], 3), np.float32)
        ok = native.module().voxel_positions(np.ascontiguousarray(codes, dtype=np.uint64),
                                             self.depth, *(float(v) for v in self.origin),
                                             float(self.side), out)
        return out, ok


def voxel_centres(ijk: np.ndarray, origin, side: float, depth: int) -> np.ndarray:
    """Decoded positions ``origin + (ijk + 0.5) * side / 2^d`` as [M, 3] float64 (normative)."""
    pitch = float(side) / float(1 << int(depth))
    return np.asarray(origin, np.float64) + (np.asarray(ijk, np.float64) + 0.5) * pitch


def centres_float32(axes, origin, side: float, depth: int, out: np.ndarray | None = None) -> np.ndarray:
    """:func:`voxel_centres` as float32 [M, 3] (into ``out`` when given), axis by axis: the same
    float64 operations per element, with one [M] float64 at a time instead of an [M, 3] float64
    beside the output.  ``axes``: the three integer coordinate rows, [3, M] (Morton-decoded
    planes, or ``ijk.T``)."""
    pitch = float(side) / float(1 << int(depth))
    if out is None:
        out = np.empty((len(axes[0]), 3), dtype=np.float32)
    for axis in range(3):
        v = np.asarray(axes[axis]).astype(np.float64)
        v += 0.5
        v *= pitch
        v += float(origin[axis])
        out[:, axis] = v
    return out


def read_geometry_header(data, *, max_points: int) -> GeometryHeader:
    r = Reader(data, "GEOM chunk")
    depth = r.u8()
    r.check(1 <= depth <= MAX_DEPTH, f"octree depth {depth} outside 1..{MAX_DEPTH}")
    origin = np.array([r.f64(), r.f64(), r.f64()])
    side = r.f64()
    r.check(all(math.isfinite(v) for v in origin) and math.isfinite(side) and side > 0,
            "non-finite grid origin or non-positive side")
    m = r.u64()
    r.check(1 <= m <= max_points, f"voxel count {m} outside 1..{max_points}")
    return GeometryHeader(depth=depth, origin=origin, side=side, num_points=m,
                          payload=r.bytes(r.remaining))


def octree_scheme(data) -> int:
    """The coding scheme byte of a GEOM chunk's octree payload (OCTREE.md section 2)."""
    payload = read_geometry_header(data, max_points=1 << 63).payload
    if len(payload) < 1:
        raise GszFormatError("octree payload is empty")
    return payload[0]


def read_geometry(data, *, max_points: int) -> Geometry:
    h = read_geometry_header(data, max_points=max_points)
    codes = h.decode_codes()
    return Geometry(ijk=morton_decode(codes), origin=h.origin, side=h.side, depth=h.depth,
                    codes=codes)
