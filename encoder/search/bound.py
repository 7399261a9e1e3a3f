"""A provable lower bound on the smallest file the size search can make, before any rendering.

The exact smallest file (the smallest reserve, 1 bit everywhere, the smallest codebook, no kept
SH vector) needs the importance pass -- which Gaussians survive pruning decides the octree and the
entropy-coded bytes.  What does not depend on it is counted here, and only that:

* the container: header, chunk table (GEOM, ATTR, SHVQ with SH, META) and a META zstd frame;
* every chunk's fixed fields and every rANS stream's smallest form (model-set envelope, lane and
  word counts, 4 bytes per lane, a lane per 8192 symbols: ENTROPY.md §4.1);
* the quantisation groups' parameters, 9 bytes each (a u8 width and two f32 bounds per (channel,
  block), stored raw: GSZ.md §5), for the blocks the search uses over at least ``V`` voxels;
* with SH: the smallest codebook's channel set (or, if cheaper, every vector kept exact).

``V``, the fewest voxels the smallest candidate can have: it keeps ``ceil(tau_min * N)``
Gaussians; at the shallowest depth the search visits, its voxels (cubes of side at most the
whole scene's cube / 2^d, whatever subset they hold) each lie in at most 8 cells of the whole
scene's grid at that depth, so each holds at most 8x the fullest cell's Gaussians.

Entropy-coded bytes are counted as zero (an adaptive coder can make a stream of one repeated
symbol nearly free), so the bound is loose -- about a third of the true minimum on the bundled
samples -- but never above it: a budget below it is unreachable, and saying so takes a fraction
of a second instead of the importance pass.  More layers or tiles only add parts, each costing
more fixed bytes than the (at most one per set) blocks it can save, so one part is the minimum.
"""
from __future__ import annotations

import math

import numpy as np

from ...decoder.groups import blocks_for

from .options import BudgetError, SearchOptions

#: RansStream: R (symbols per lane) of ENTROPY.md §4.1, and the octree payload's
RANS_LANE_SYMBOLS = 8192
OCTREE_LANE_SYMBOLS = 32768
MAX_LANES = 4096
#: smallest zstd frame: magic (4), frame header descriptor (1), window or size byte (1), block
#: header (3); the META JSON is never empty, so at least one content byte more would follow
ZSTD_FRAME_MIN = 9


class BudgetBelowBoundError(BudgetError):
    """The budget is below :func:`smallest_file_bound`: unreachable, found before the importance
    pass (``minimum`` is the bound; the exact smallest file is at least that)."""

    def __init__(self, target: int, bound: int, path=None, *, sh: bool = False):
        super().__init__(target, bound, path)
        what = "container, group parameters" + (" and SH codebook" if sh else "")
        msg = (f"size budget {self.target:,} bytes is below the smallest reachable file for this scene: "
               f"at least {self.minimum:,} bytes ({what} of the smallest candidate, bounded before "
               "the importance pass)")
        self.args = (f"{self.path}: {msg}" if self.path else msg,)


def _lanes(symbols: int, per_lane: int = RANS_LANE_SYMBOLS) -> int:
    return max(1, min(MAX_LANES, math.ceil(symbols / per_lane)))


def _stream(symbols: int, per_lane: int = RANS_LANE_SYMBOLS) -> int:
    """Smallest RansStream of ``symbols`` symbols: a model set (envelope varint + at least one
    body byte), the lane and word varints and 4 bytes per lane."""
    return 2 + 2 + 4 * _lanes(symbols, per_lane)


def _channel_set(channels: int, length: int, blocks: int) -> int:
    """Smallest ChannelSet of ``channels`` x ``length`` in ``blocks`` blocks (GSZ.md §5)."""
    b = blocks_for(length, blocks)
    return 8 + 9 * channels * b + 8 + _stream(channels * length)


def fewest_voxels(positions: np.ndarray, kept: int, depth: int) -> int:
    """The fewest voxels ``kept`` of these Gaussians can occupy at ``depth`` on any cube no larger
    than the whole scene's (see the module doc)."""
    from ...decoder.morton import morton_encode
    from ..voxelize import bounding_cube, voxel_coords
    origin, side = bounding_cube(positions)
    _, counts = np.unique(morton_encode(voxel_coords(positions, depth, origin, side)), return_counts=True)
    return max(1, math.ceil(kept / (8 * int(counts.max()))))


def smallest_file_bound(cloud, options: SearchOptions | None = None) -> tuple[int, dict]:
    """(bytes, parts): a lower bound on every file :func:`encode_to_budget` can make of ``cloud``
    with ``options``, and its terms.  Costs one voxelisation of the centres (no rendering)."""
    from ...decoder.morton import morton_encode
    from ..pipeline import default_codebook_size, sh_set_blocks
    from ..voxelize import DEFAULT_REL_ERROR, bounding_cube, choose_depth, voxel_coords
    sopts = options or SearchOptions()
    x = cloud.positions
    n = len(cloud)
    depth = choose_depth(x, rel_error=DEFAULT_REL_ERROR)
    d_min = max(1, depth - max(0, int(sopts.depth_steps)))
    taus = sorted(float(t) for t in sopts.reserves)
    kept = math.ceil(taus[0] * n)
    v = fewest_voxels(x, kept, d_min)
    blocks = int(sopts.blocks)
    sh = cloud.sh_degree > 0
    chunks = 4 if sh else 3                    # GEOM, ATTR, (SHVQ,) META
    parts = {
        "container": 64 + 24 * chunks + 4,
        # GEOM fields (depth, origin, side, M), scheme, S, the payload's L and W, one lane (its model
        # set is not transmitted)
        "geometry": 41 + 2 + 2 + 4 * _lanes(0, OCTREE_LANE_SYMBOLS),
        "attributes": 2 + 8 * 7 + _channel_set(7, v - 1, blocks) + _channel_set(3, v, blocks),
        "metadata": ZSTD_FRAME_MIN,
    }
    if sh:
        d = 3 * ((cloud.sh_degree + 1) ** 2 - 1)
        if taus[-1] >= 1.0:                    # the codebooks train on every Gaussian's voxel
            origin, side = bounding_cube(x)
            m1 = int(np.unique(morton_encode(voxel_coords(x, depth, origin, side))).size)
        else:
            m1 = fewest_voxels(x, math.ceil(taus[-1] * n), depth)
        k_max = default_codebook_size(m1, sopts.codebook)
        k_min = k_max if sopts.codebook is not None else min(k_max, max(16, k_max // 4), max(16, k_max // 16))
        codebook = _channel_set(d, k_min, sh_set_blocks(k_min, blocks))
        # the scalar path keeps every vector exact instead: no codebook, a kept set and flags
        scalar = 8 + 9 * d * sh_set_blocks(v, blocks) + 8 + _stream(d * v) + 8 + _stream(v)
        parts["sh"] = 10 + min(codebook, scalar) + 8 + _stream(0)
    parts.update(voxels_at_least=v, depth=d_min, reserve=taus[0])
    total = sum(val for key, val in parts.items() if key in ("container", "geometry", "attributes", "metadata", "sh"))
    return int(total), parts


def check_reachable(cloud, target: int, options: SearchOptions | None = None) -> None:
    """BudgetBelowBoundError when ``target`` is below :func:`smallest_file_bound`."""
    bound, parts = smallest_file_bound(cloud, options)
    if int(target) < bound:
        raise BudgetBelowBoundError(int(target), bound, sh="sh" in parts)
