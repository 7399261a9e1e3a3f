"""RAHT (region-adaptive Haar transform) tree and inverse transform -- numpy only.

Normative text: ``format_spec/TRANSFORMS.md`` section 2.  Summary:

* Leaves are the N occupied voxels in ascending Morton order (``gsz.decoder.morton``), each of
  weight 1.  The tree has 3*depth binary levels.  At level l = 0 .. 3*depth-1 every node carries
  a code (its leaves' Morton code >> l), a weight (its leaf count) and a *slot* (the Morton
  index of its first leaf).  Two consecutive nodes whose codes differ only in bit 0 are siblings
  and are merged by the orthonormal butterfly (a = sqrt(w1 + w2))

      L = ( sqrt(w1) C1 + sqrt(w2) C2) / a        (kept in the left node's slot)
      H = (-sqrt(w2) C1 + sqrt(w1) C2) / a        (written to the right node's slot)

  unpaired nodes pass up unchanged; then codes are shifted right by one.  After 3*depth levels a
  single root remains in slot 0; its low-pass value is the DC = sqrt(N) * mean.
* AC layout in the stream ("level order"): the N-1 high-pass coefficients grouped by level,
  COARSEST level first (l = 3*depth-1 down to 0), ascending slot (= Morton) order within a
  level.  Coefficients of one level have similar variance, so contiguous quantisation blocks
  stay homogeneous (against the Morton-leaf interleave: docs/design/raht-layout.md).

The encoder's forward transform (``gsz.encoder.raht``) uses this module's tree.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import GszFormatError

MAX_DEPTH = 21


@dataclass(frozen=True)
class RahtLevel:
    """The sibling pairs merged at one tree level.

    left, right: int64 [P] slots (Morton leaf indices) of the left / right sibling, ascending.
    w_left, w_right: float64 [P] leaf counts of the two siblings.
    """

    level: int
    left: np.ndarray
    right: np.ndarray
    w_left: np.ndarray
    w_right: np.ndarray

    def butterfly(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(sqrt(w1)/a, sqrt(w2)/a) per pair as float64 [P, 1] columns (and a, [P])."""
        a = np.sqrt(self.w_left + self.w_right)
        return (np.sqrt(self.w_left) / a)[:, None], (np.sqrt(self.w_right) / a)[:, None], a


@dataclass(frozen=True)
class RahtTree:
    """The RAHT tree of one geometry (built once, used by forward and inverse).

    num_points: N leaves.  depth: octree depth (3*depth binary levels).
    levels: the non-empty levels (at least one pair), FINEST first (level index ascending).
    ac_slots: int64 [N-1] the slot of every AC coefficient in stream order (coarse level first,
      ascending slot within a level) -- a permutation of 1..N-1.
    leaf_weights: int64 [N] integer leaf weights (an RWGT chunk, GSZ.md §7.1), or None (all 1).
    """

    num_points: int
    depth: int
    levels: tuple
    ac_slots: np.ndarray
    leaf_weights: np.ndarray | None = None

    def leaf_scale(self) -> np.ndarray | None:
        """sqrt(leaf weight) float64 [N] of a weighted tree (None: every leaf weighs 1): the
        transform runs on sqrt(w) * value, so its coefficients' squared error is the
        weight-weighted squared error of the values (TRANSFORMS.md §2.5)."""
        return None if self.leaf_weights is None else np.sqrt(self.leaf_weights.astype(np.float64))

    def level_sizes(self) -> list[tuple[int, int]]:
        """[(level index, number of AC coefficients)] in stream order (coarse first)."""
        return [(lv.level, lv.left.shape[0]) for lv in reversed(self.levels)]


def build_raht_tree(morton_codes: np.ndarray, depth: int,
                    leaf_weights: np.ndarray | None = None) -> RahtTree:
    """Build the RAHT tree from voxel Morton codes.

    morton_codes: uint64 [N], N >= 1, strictly ascending, every code < 2^(3*depth).
    depth: 1 .. 21 bits per axis.
    leaf_weights: None (every leaf weighs 1) or integers [N] in 1 .. 65535 (TRANSFORMS.md §2.5);
      node weights are their exact integer sums.
    Raises GszFormatError when the codes violate this contract (e.g. corrupt geometry).
    Cost: O(N) per level with early exit once a single node remains; ~0.1 s for 500k points.
    """
    codes = np.asarray(morton_codes)
    if not (isinstance(depth, (int, np.integer)) and 1 <= int(depth) <= MAX_DEPTH):
        raise GszFormatError(f"RAHT depth must be an integer in 1..{MAX_DEPTH}, got {depth!r}")
    depth = int(depth)
    if codes.ndim != 1 or codes.shape[0] < 1:
        raise GszFormatError(f"RAHT needs a non-empty 1-D Morton code array, got shape {codes.shape}")
    if not (np.issubdtype(codes.dtype, np.unsignedinteger) or np.issubdtype(codes.dtype, np.signedinteger)):
        raise GszFormatError(f"Morton codes must be integers, got dtype {codes.dtype}")
    if np.issubdtype(codes.dtype, np.signedinteger) and codes.min() < 0:
        raise GszFormatError("Morton codes must be non-negative")
    codes = codes.astype(np.uint64)
    n = codes.shape[0]
    if n > 1 and not np.all(codes[1:] > codes[:-1]):
        raise GszFormatError("Morton codes must be strictly ascending (sorted, unique)")
    if int(codes[-1]) >> (3 * depth):
        raise GszFormatError(f"Morton code {int(codes[-1])} exceeds 3*depth = {3 * depth} bits")

    if n >= 1 << 31:
        raise GszFormatError(f"RAHT tree of {n} points: more than 2^31")
    if leaf_weights is not None:
        return _build_weighted(codes, depth, _check_leaf_weights(leaf_weights, n))
    # every node's slot and weight (both < 2^31) in one int64: slot << 32 | weight -- one
    # gather and one compaction per level for both.  The first m entries of ``codes`` (a copy,
    # shifted in place) and ``node`` are the level's nodes: compacted in place, into memory
    # already touched (fresh arrays per level cost page faults on 45 levels of ~N entries)
    node = (np.arange(n, dtype=np.int64) << 32) | 1
    low32 = np.int64(0xFFFFFFFF)
    levels = []
    one = np.uint64(1)
    same = np.empty(max(n - 1, 0), dtype=bool)
    keep = np.empty(n, dtype=bool)
    m = n
    for level in range(3 * depth):
        if m == 1:
            break
        # Sorted unique codes: siblings are adjacent, left one even, right one = left + 1.
        parent = codes[:m]
        np.right_shift(parent, one, out=parent)
        eq = same[:m - 1]
        np.equal(parent[:-1], parent[1:], out=eq)
        pos = np.flatnonzero(eq)
        if pos.size:
            nodes = node[:m]
            a, b = nodes.take(pos), nodes.take(pos + 1)
            wl, wr = a & low32, b & low32
            levels.append(RahtLevel(level, a >> 32, b >> 32,
                                    wl.astype(np.float64), wr.astype(np.float64)))
            nodes[pos] = a + wr
            k = keep[:m]
            k.fill(True)
            k[pos + 1] = False
            m -= pos.size
            codes[:m] = parent[k]
            node[:m] = nodes[k]
    codes = codes[:m]
    if codes.shape[0] != 1:  # unreachable given the bit-length check; kept as a hard guard
        raise GszFormatError("RAHT tree did not reduce to a single root")
    ac_slots = (np.concatenate([lv.right for lv in reversed(levels)]) if levels
                else np.zeros(0, dtype=np.int64))
    return RahtTree(num_points=n, depth=depth, levels=tuple(levels), ac_slots=ac_slots)


MAX_LEAF_WEIGHT = 65535


def _check_leaf_weights(w, n: int) -> np.ndarray:
    w = np.asarray(w)
    if w.shape != (n,) or not np.issubdtype(w.dtype, np.integer):
        raise GszFormatError(f"RAHT leaf weights must be integers [{n}], got {w.dtype} {w.shape}")
    w = w.astype(np.int64)
    if n and (int(w.min()) < 1 or int(w.max()) > MAX_LEAF_WEIGHT):
        raise GszFormatError(f"RAHT leaf weights must lie in 1..{MAX_LEAF_WEIGHT}")
    return w


def _build_weighted(codes: np.ndarray, depth: int, leaf_w: np.ndarray) -> RahtTree:
    """build_raht_tree with integer leaf weights: the same pairs, level by level; a node's weight
    is the exact sum of its leaves' (< 2^47, exact in int64 and float64)."""
    n = codes.shape[0]
    # a node's weight lives at its slot (its first leaf's index): only the slots are compacted
    # per level, in place like build_raht_tree's (fresh arrays per level cost page faults)
    slot = np.arange(n, dtype=np.int64)
    wt = leaf_w.copy()
    levels = []
    one = np.uint64(1)
    same = np.empty(max(n - 1, 0), dtype=bool)
    keep = np.empty(n, dtype=bool)
    m = n
    for level in range(3 * depth):
        if m == 1:
            break
        parent = codes[:m]
        np.right_shift(parent, one, out=parent)
        eq = same[:m - 1]
        np.equal(parent[:-1], parent[1:], out=eq)
        pos = np.flatnonzero(eq)
        if pos.size:
            slots = slot[:m]
            sl, sr = slots.take(pos), slots.take(pos + 1)
            wl, wr = wt.take(sl), wt.take(sr)
            levels.append(RahtLevel(level, sl, sr, wl.astype(np.float64), wr.astype(np.float64)))
            wl += wr
            wt[sl] = wl
            k = keep[:m]
            k.fill(True)
            k[pos + 1] = False
            m -= pos.size
            codes[:m] = parent[k]
            slot[:m] = slots[k]
    if m != 1:
        raise GszFormatError("RAHT tree did not reduce to a single root")
    ac_slots = (np.concatenate([lv.right for lv in reversed(levels)]) if levels
                else np.zeros(0, dtype=np.int64))
    return RahtTree(num_points=n, depth=depth, levels=tuple(levels), ac_slots=ac_slots,
                    leaf_weights=leaf_w)


def raht_inverse(dc: np.ndarray, ac: np.ndarray, tree: RahtTree) -> np.ndarray:
    """Attributes of the N leaves (Morton order) from the RAHT coefficients.

    dc: float [C] root low-pass per channel (= sqrt(N) * mean).
    ac: float [N-1, C] high-pass coefficients in stream (level) order.
    Returns float64 [N, C].
    """
    dc = np.asarray(dc, dtype=np.float64).reshape(-1)
    ac = np.asarray(ac, dtype=np.float64)
    n = tree.num_points
    if ac.ndim != 2 or ac.shape != (n - 1, dc.shape[0]):
        raise GszFormatError(f"RAHT inverse: expected AC shape ({n - 1}, {dc.shape[0]}), got {ac.shape}")
    return np.ascontiguousarray(raht_inverse_planes(dc, ac.T, tree).T)


def raht_inverse_planes(dc: np.ndarray, ac: np.ndarray, tree: RahtTree,
                        channels=None) -> np.ndarray:
    """:func:`raht_inverse` channel-major: ac float [C, N-1] (stream order) -> float64 [C, N],
    the same values (every channel's butterflies are the same float64 operations, one
    channel's row at a time).  ``channels``: only these (indices), as rows in that order."""
    dc = np.asarray(dc, dtype=np.float64).reshape(-1)
    ac = np.asarray(ac, dtype=np.float64)
    n = tree.num_points
    if ac.ndim != 2 or ac.shape != (dc.shape[0], n - 1):
        raise GszFormatError(f"RAHT inverse: expected AC shape ({dc.shape[0]}, {n - 1}), got {ac.shape}")
    if channels is not None:
        dc, ac = dc[list(channels)], [ac[c] for c in channels]
    v = np.empty((dc.shape[0], n), dtype=np.float64)
    v[:, 0] = dc
    # the high-pass value of a pair is its AC coefficient, read in stream order: the right
    # slot of a level is first written by that level (no coarser node starts there), so the
    # AC coefficients need not be scattered into v first
    off = 0
    for lv in reversed(tree.levels):  # coarsest first: undo the merges top-down
        g1, g2, _ = lv.butterfly()
        g1, g2 = g1[:, 0], g2[:, 0]
        t, u = np.empty_like(g1), np.empty_like(g1)
        p = g1.shape[0]
        for row, coef in zip(v, ac):         # one channel at a time: 1-D gathers, in cache
            low = row[lv.left]
            high = coef[off:off + p]
            np.multiply(g1, low, out=t)
            np.multiply(g2, high, out=u)
            t -= u                           # L' = g1 low - g2 high
            row[lv.left] = t
            low *= g2
            np.multiply(g1, high, out=u)
            low += u                         # H' = g2 low + g1 high
            row[lv.right] = low
        off += p
    scale = tree.leaf_scale()
    if scale is not None:
        v /= scale                              # the leaves' values: v_p / sqrt(w_p)
    return v
