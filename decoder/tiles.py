"""Spatial tiles (format 1.2, GSZ.md §4.2): the TILE chunk and the choice of tiles to decode.

A tiled file splits its scene into T spatial tiles; every (layer, tile) pair that holds
Gaussians is a *part* with its own GEOM, ATTR and SHVQ, so one tile decodes without the others.
The TILE chunk gives each tile's bounding box (what ``decode(region=...)`` selects by) and its
Gaussian count (what bounds the tile's allocations before its octree is decoded).  numpy-free.
"""
from __future__ import annotations

import math
import struct
from dataclasses import dataclass

from .errors import GszFormatError

#: tiles a file may declare: the 16 tile bits of a chunk's flags (GSZ.md §4)
MAX_TILES = 1 << 16
_COUNT = struct.Struct("<I")
_ENTRY = struct.Struct("<6fQ")


@dataclass(frozen=True)
class TileInfo:
    """One row of the TILE chunk: the tile's bounding box (of its decoded positions) and the
    number of Gaussians its parts hold in all layers."""
    bbox_min: tuple
    bbox_max: tuple
    num_gaussians: int

    def intersects(self, lo, hi) -> bool:
        return all(self.bbox_min[a] <= hi[a] and lo[a] <= self.bbox_max[a] for a in range(3))


def pack_tile_table(tiles: list) -> bytes:
    """The TILE chunk payload for ``tiles`` ([TileInfo]), deterministic."""
    out = [_COUNT.pack(len(tiles))]
    for t in tiles:
        out.append(_ENTRY.pack(*[float(v) for v in t.bbox_min], *[float(v) for v in t.bbox_max],
                               int(t.num_gaussians)))
    return b"".join(out)


def parse_tile_table(data, num_gaussians: int) -> list:
    """[TileInfo] of a TILE chunk payload; rejects a count outside 1..65536, a payload of the
    wrong length, a tile of zero Gaussians and counts that do not sum to the header's."""
    mv = memoryview(data)
    if len(mv) < 4:
        raise GszFormatError("TILE chunk: truncated (no tile count)")
    (t,) = _COUNT.unpack_from(mv, 0)
    if not 1 <= t <= MAX_TILES:
        raise GszFormatError(f"TILE chunk: tile count {t} outside 1..{MAX_TILES}")
    if len(mv) != 4 + _ENTRY.size * t:
        raise GszFormatError(f"TILE chunk: {len(mv)} bytes, {t} tiles need {4 + _ENTRY.size * t}")
    tiles, total = [], 0
    for i in range(t):
        *box, n = _ENTRY.unpack_from(mv, 4 + _ENTRY.size * i)
        if n < 1:
            raise GszFormatError(f"TILE chunk: tile {i} holds no Gaussians")
        total += n
        tiles.append(TileInfo(tuple(box[:3]), tuple(box[3:]), int(n)))
    if total != num_gaussians:
        raise GszFormatError(f"TILE chunk: the tiles hold {total} Gaussians, header says {num_gaussians}")
    return tiles


def check_region(region) -> tuple:
    """``region`` = (min_xyz, max_xyz) as two float triples with min <= max; ValueError otherwise."""
    try:
        lo, hi = (tuple(float(v) for v in region[0]), tuple(float(v) for v in region[1]))
    except (TypeError, ValueError, IndexError):
        raise ValueError("region must be ((min_x, min_y, min_z), (max_x, max_y, max_z))") from None
    if len(region) != 2 or len(lo) != 3 or len(hi) != 3 or not all(map(math.isfinite, lo + hi)) \
            or any(a > b for a, b in zip(lo, hi)):
        raise ValueError("region must be ((min_x, min_y, min_z), (max_x, max_y, max_z)) of finite "
                         "values with min <= max")
    return lo, hi


def select_tiles(tiles: list, wanted=None, region=None) -> list:
    """Indices (ascending) of the tiles to decode: ``wanted`` (tile indices; None: all) whose
    bounding box meets ``region`` (None: any).  ValueError for an index outside the file."""
    if wanted is None:
        chosen = list(range(len(tiles)))
    else:
        chosen = sorted({int(i) for i in wanted})
        bad = [i for i in chosen if not 0 <= i < len(tiles)]
        if bad:
            raise ValueError(f"tile {bad[0]} does not exist (the file has {len(tiles)} tiles: "
                             f"0..{len(tiles) - 1})")
    if region is not None:
        lo, hi = check_region(region)
        chosen = [i for i in chosen if tiles[i].intersects(lo, hi)]
    return chosen
