"""Lossless octree geometry decoder (numpy-only): context-adaptive binary occupancy coding.

The normative description is ``format_spec/OCTREE.md``; this module is the shared truth: the
encoder (``gsz.encoder.octree``) imports :func:`walk_octree` and the tables below and runs the very
same traversal, so encoder and decoder cannot drift apart.

Coding order (why it is vectorisable).  The octree of the ``M`` occupied voxels is walked level by
level from the root (level 0, one node) to level ``depth - 1``; the nodes of a level are in
ascending Morton order.  Within a level the eight child-occupancy bits of all nodes are coded
*bit-plane by bit-plane*: first child 0 of every node, then child 1 of every node, ..., child 7.
The context of child ``k`` depends only on the node set of the level and on child bits ``< k`` of
the node *and of its 26 neighbours*, all known before bit-plane ``k`` starts, so a whole bit-plane's
contexts are computed in one vectorised step.

Context of child ``k`` (child position ``c`` at level ``l + 1``), from its 26 neighbours at
level ``l + 1``, split into the 6 face neighbours (``_f``) and the 20 edge/corner ones (``_o``):

* ``kn_f, kn_o`` -- how many are known to be occupied (they lie in neighbour nodes and have child
  index ``< k``, in *any* direction, also across parent boundaries),
* ``unk_f, unk_o`` -- how many are still unknown but lie in an occupied node (child index ``>= k``),
* ``sib`` -- min(3, number of this node's children ``< k`` already occupied),
* ``k`` itself and the level bucket ``lb = min(3, depth - 1 - l)`` (distance from the leaves).

The *coarse* context is (k, kn_f + kn_o, unk_f + unk_o, sib); the *fine* one adds the face split
and ``lb``.

Probability estimate (integer arithmetic only, so it is bit-exact on every platform): the coarse
and the fine context keep counts ``(n0, n1)``;

    p_coarse = ((2*c1 + 1) << 16) // (2*(c0 + c1) + 2)             # KT estimate, 16-bit
    p_fine   = ((f1 << 16) + MIX_WEIGHT * p_coarse) // (f0 + f1 + MIX_WEIGHT)

``p_fine`` (probability of a 1, 16-bit) is mapped to the nearest of ``len(BANK_F1)`` fixed binary
models, and the bit is entropy-coded with that model.  Counts are updated after each *chunk* of a
bit-plane (chunks of ``min(CHUNK_MAX, max(CHUNK_MIN, symbols already coded in the bit-plane))``
symbols), which keeps the adaptation near-sequential while every chunk stays vectorised.
After each level, every count pair whose total exceeds ``COUNT_LIMIT`` is halved (rounding up),
which tracks drift.

The last child of a node whose first seven child bits are all 0 is 1 and is not coded.
"""
from __future__ import annotations

import functools
from typing import Callable

import numpy as np

from . import native
from .errors import GszFormatError
from .morton import MAX_DEPTH, morton_decode
from .rans import (COARSE, OCTREE_MAX_ROWS, ModelSet, RansDecoder, lut_budget, parse_payload_header,
                              read_varint)

# ---------------------------------------------------------------- model constants (normative)
#: Coding precision of the binary probability bank (frequencies out of 2**BANK_BITS).
BANK_BITS = 12
#: Chunk schedule of the adaptive counts (symbols per vectorised update).
CHUNK_MIN = 64
CHUNK_MAX = 4096
COUNT_LIMIT = 1 << 14
MIX_WEIGHT = 16
NUM_LEVEL_BUCKETS = 4
NUM_SIB = 4
#: 26 neighbours -> kn, unk in 0..26
NUM_COARSE = 8 * 27 * 27 * NUM_SIB
#: face neighbours kn_f, unk_f in 0..6; edge/corner neighbours kn_o, unk_o in 0..20
NUM_FINE = 8 * 7 * 7 * 21 * 21 * NUM_SIB * NUM_LEVEL_BUCKETS
#: contexts of the direct flag (scheme 1): occupied neighbours (0..7, 7 = 7 or more) x the
#: parent's children (1..4, 4 = 4 or more) x level bucket
NUM_DIRECT = 8 * 4 * NUM_LEVEL_BUCKETS


def _make_bank() -> np.ndarray:
    """Frequencies of symbol 1 (out of 2**BANK_BITS) of the fixed binary models, ascending.

    Integer-only so that it is identical everywhere: v_0 = 2048, v_{i+1} = (7 * v_i) // 8 down to 1,
    mirrored to 4096 - v (geometric spacing: the loss from rounding a probability to its nearest
    bank entry is < 0.2 % of the coded size).
    """
    half = [1 << (BANK_BITS - 1)]
    while half[-1] > 1:
        half.append((half[-1] * 7) // 8)
    lo = sorted(set(half))
    hi = [(1 << BANK_BITS) - v for v in lo if v != 1 << (BANK_BITS - 1)]
    return np.array(sorted(set(lo + hi)), dtype=np.int64)


BANK_F1 = _make_bank()
NUM_MODELS = len(BANK_F1)


def _make_lut() -> np.ndarray:
    """Map a 16-bit probability of a 1 to the bank entry nearest in the linear domain (ties: lower)."""
    centres16 = BANK_F1 << (16 - BANK_BITS)
    mids = (centres16[:-1] + centres16[1:] + 1) // 2          # integer midpoints
    p = np.arange(1 << 16, dtype=np.int64)
    return np.searchsorted(mids, p, side="right").astype(np.int64)


P16_TO_MODEL = _make_lut()


def bank_precision(num_symbols: int) -> int:
    """rANS precision n of the bank models: as high as the decoder's LUT budget for a stream of
    ``num_symbols`` symbols allows (``rans.lut_budget``), between 9 and 15."""
    per_model = lut_budget(num_symbols) // NUM_MODELS
    return int(min(15, max(9, per_model.bit_length() - 1)))


def bank_model_set(num_symbols: int) -> ModelSet:
    """The fixed binary models for a stream of ``num_symbols`` decisions (see :func:`_bank_model_set`)."""
    return _bank_model_set(bank_precision(num_symbols))


def _level_code_g3(w: int) -> int:
    """COARSE level code (group g = 3, ENTROPY.md) whose weight ``m << e`` (8 <= m <= 15) is
    nearest to the integer ``w >= 16`` (ties round up)."""
    e = w.bit_length() - 4
    m = (w + (1 << (e - 1))) >> e
    if m == 16:
        m, e = 8, e + 1
    return 1 + (e << 3) + (m - 8)


@functools.lru_cache(maxsize=8)
def _bank_model_set(precision: int) -> ModelSet:
    """The fixed binary models (values 0/1) as an rANS :class:`ModelSet`.

    Bank entry i with v = BANK_F1[i] (probability of a 1 ~ v / 4096) is a COARSE model with
    lo = 0, span = 1, group 3, bin shift 0, bins [0, 1] and level codes
    [_level_code_g3(16 (4096 - v)), _level_code_g3(16 v)]: weights within 1/16 of 4096 - v and v,
    normalised by ENTROPY.md to 2**precision.
    Nothing of it is transmitted: encoder and decoder build it from the stream's symbol count
    (which fixes the precision).  Cached: the set and its decoding tables are read-only.
    """
    one = 1 << BANK_BITS
    m = NUM_MODELS
    z = np.zeros(m, dtype=np.int64)
    levels = tuple(np.array([_level_code_g3(16 * (one - int(v))), _level_code_g3(16 * int(v))],
                            dtype=np.int64) for v in BANK_F1)
    bins = tuple(np.array([0, 1], dtype=np.int64) for _ in range(m))
    ms = ModelSet(types=np.full(m, COARSE, dtype=np.int64), lo=z.copy(), span=np.ones(m, np.int64),
                  prec=np.full(m, precision, dtype=np.int64), group=np.full(m, 3, dtype=np.int64),
                  centre=z.copy(), r_left=z.copy(), r_right=z.copy(), binshift=z.copy(),
                  bins=bins, levels=levels)
    ms.validate()
    ms.build()
    return ms


# ---------------------------------------------------------------- neighbourhood plan
#: 27 parent-level offsets (dx, dy, dz) in {-1,0,1}^3, index (dx+1)*9 + (dy+1)*3 + (dz+1); 13 = self.
OFFSETS = np.array([(dx, dy, dz) for dx in (-1, 0, 1) for dy in (-1, 0, 1) for dz in (-1, 0, 1)],
                   dtype=np.int64)
SELF = 13


def _make_plan():
    """For child k and parent-level offset t: masks of the child bits (< k) of node t that are
    known 26-neighbours of child k, and counts of the unknown (>= k) 26-neighbours node t holds;
    split into face neighbours (index 0) and edge/corner neighbours (index 1)."""
    known = np.zeros((2, 8, 27), dtype=np.int64)
    unknown = np.zeros((2, 8, 27), dtype=np.int64)
    for k in range(8):
        b = np.array([(k >> 2) & 1, (k >> 1) & 1, k & 1])
        for d in OFFSETS:
            if not d.any():
                continue
            s = b + d
            o = s // 2                       # parent-level offset of the neighbour, in {-1,0,1}
            j = int((s[0] % 2) * 4 + (s[1] % 2) * 2 + (s[2] % 2))
            t = int((o[0] + 1) * 9 + (o[1] + 1) * 3 + (o[2] + 1))
            kind = 0 if int(np.abs(d).sum()) == 1 else 1
            if j < k:
                known[kind, k, t] |= 1 << j
            else:
                unknown[kind, k, t] += 1
    return known, unknown


PLAN_KNOWN, PLAN_UNKNOWN = _make_plan()
POPCOUNT8 = np.array([bin(v).count("1") for v in range(256)], dtype=np.int64)


def _make_child_plan():
    """For a node with child bits ``b`` (its index in its parent) and a neighbour offset ``t``:
    the parent-level offset (0..26) of the neighbour's parent and the neighbour's child index."""
    par = np.zeros((8, 27), dtype=np.int64)
    child = np.zeros((8, 27), dtype=np.int64)
    for k in range(8):
        b = np.array([(k >> 2) & 1, (k >> 1) & 1, k & 1])
        for t, d in enumerate(OFFSETS):
            s = b + d
            o = s // 2
            par[k, t] = (o[0] + 1) * 9 + (o[1] + 1) * 3 + (o[2] + 1)
            child[k, t] = (s[0] % 2) * 4 + (s[1] % 2) * 2 + (s[2] % 2)
    return par, child


CHILD_PAR, CHILD_IDX = _make_child_plan()
#: the 8 parent-level offsets holding the 26 neighbours of child k (its octant, self included)
_OCTANT = [[int(o) for o in np.unique(CHILD_PAR[k])] for k in range(8)]
_NOT_SELF = [t for t in range(27) if t != SELF]


#: NEIGHBOUR_COUNT[k][o]: per occupancy byte of the parent-level node at offset o, how many of
#: its children are 26-neighbours of child k (the present-neighbour count of a child is the sum
#: over the 8 nodes of its octant, _ChildLevel.present)
def _make_neighbour_count():
    masks = np.zeros((8, 27), dtype=np.int64)
    for k in range(8):
        for t in _NOT_SELF:
            masks[k, CHILD_PAR[k, t]] |= 1 << int(CHILD_IDX[k, t])
    return POPCOUNT8[np.arange(256)[None, None, :] & masks[:, :, None]].astype(np.uint8)


NEIGHBOUR_COUNT = _make_neighbour_count()


class _ChildLevel:
    """The next level's nodes as the children of this one, from which their 27-neighbour table
    is derived without any search: for all of them, or (scheme 1, from the direct level on)
    only for those left in the tree once the level's direct flags are known -- the direct ones
    (most nodes of the first direct levels) are never coded, so their rows are never read.

    nbr, col: this level's table (see :meth:`table`; col None: column = Morton index);
    occ: uint8 [N] the level's final occupancy bytes; bits: int64 [C] the set bits of ``occ``
    (8 p + j for child j of node p), in order -- the children in Morton order.  A neighbour
    of child c lies in a neighbour (or self) of c's parent, so it exists iff that node exists
    and has the corresponding child bit.
    """

    def __init__(self, nbr: np.ndarray, col: np.ndarray | None, occ: np.ndarray, bits: np.ndarray):
        n = occ.shape[0]
        self.num = bits.shape[0]
        # int32 where it fits: the table is the decoder's largest array, and fresh memory costs
        # page faults on every level
        self.dtype = np.int32 if self.num < (1 << 31) else np.int64
        # ch[j, p + 1]: Morton index of child j of node p, -1 if absent; column 0 (the absent
        # node that nbr's -1 entries reach once shifted by one) all -1, so that every lookup
        # index is non-negative (take's "clip" mode is ~2x faster than "wrap").  j-major: a
        # group's lookups for one neighbour read one row, in ascending parent order.  Filled
        # by one scatter of the children (the first direct levels have far fewer than nodes)
        ch = np.full((8, n + 1), -1, dtype=self.dtype)
        ch.reshape(-1)[(bits & 7) * (n + 1) + (bits >> 3) + 1] = np.arange(self.num,
                                                                           dtype=self.dtype)
        self.ch, self.nbr, self.col, self.occ = ch, nbr, col, occ
        # per child index k, the parents holding child k (ascending)
        # (bool arrays: NumPy's nonzero is ~7x faster on bools than on bytes)
        self.parents = [np.flatnonzero(((occ >> np.uint8(k)) & np.uint8(1)).view(np.bool_))
                        for k in range(8)]

    def _octant(self, k: int, r: np.ndarray) -> dict:
        """The 8 parent-level nodes of child k's octant of parents ``r``, plus one (0 where
        absent): ``ch``'s columns."""
        rc = r if self.col is None else self.col.take(r)
        return {o: r + 1 if o == SELF else np.add(self.nbr[o].take(rc), 1, dtype=np.intp)
                for o in _OCTANT[k]}

    def present(self) -> np.ndarray:
        """int64 [C] the number of present 26-neighbours of every child, in Morton order: per
        octant node the count of its children among them (NEIGHBOUR_COUNT), no table needed."""
        occ1 = np.zeros(self.occ.shape[0] + 1, dtype=np.uint8)
        occ1[1:] = self.occ
        out = np.empty(self.num, dtype=np.int64)
        for k, r in enumerate(self.parents):
            if r.size == 0:
                continue
            cnt = np.zeros(r.size, dtype=np.uint8)
            for o, p in self._octant(k, r).items():
                cnt += NEIGHBOUR_COUNT[k, o].take(occ1.take(p))
            out[self.ch[k].take(r + 1)] = cnt
        return out

    def table(self, keep: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(table, col) of the children (``keep``: bool [C], only those it marks).
        ``table[t, p]`` = Morton index of the neighbour at offset t of the child in column p,
        -1 where absent (int32 where it fits; row SELF is not filled), and ``col`` int64 [C]
        the column of every (kept) child.  Columns are grouped by child index k (the children
        with index k of ascending parents): within a group the parent-level offset and child
        index of each neighbour are scalars, and writing whole column runs beats scattering
        into Morton columns (every cache line of every row touched 8 times)."""
        ch = self.ch
        groups = []
        for k, r in enumerate(self.parents):
            if keep is not None and r.size:
                r = r[keep.take(ch[k].take(r + 1))]
            groups.append(r)
        table = np.empty((27, sum(r.size for r in groups)), dtype=self.dtype)
        new_col = (np.empty if keep is None else np.zeros)(self.num, dtype=np.int64)
        g0 = 0
        for k, r in enumerate(groups):
            if r.size == 0:
                continue
            g1 = g0 + r.size
            new_col[ch[k].take(r + 1)] = np.arange(g0, g1)
            par = self._octant(k, r)
            for t in _NOT_SELF:
                np.take(ch[int(CHILD_IDX[k, t])], par[int(CHILD_PAR[k, t])], out=table[t, g0:g1],
                        mode="clip")
            g0 = g1
        return table, new_col


def _make_plane_tables(level_bucket: int) -> list:
    """Per child index k: (the 8 parent-level offsets t of k's octant, SELF first, and a table
    int64 [8, 512]) such that the context of child k of a node is the sum over those t of
    ``table[i][v_t]``, v_t = the neighbour's state byte (256 | occupancy bits decoded so far,
    0 when absent), packed as ``coarse << 32 | fine slot`` -- both are linear in their terms
    (module docstring), so every neighbour's share is one lookup.  Absent neighbours add 0."""
    v = np.arange(512, dtype=np.int64)
    present, byte = v >> 8, v & 255
    # weights of the terms in coarse = ((k*27 + kn)*27 + unk)*NUM_SIB + sib and in the fine
    # count slot f + lb * (NUM_FINE / NUM_LEVEL_BUCKETS), f = ((((k*7 + kf)*7 + uf)*21 + ko)*21
    # + uo)*NUM_SIB + sib: the fine id (f * NUM_LEVEL_BUCKETS + lb) with the level bucket as the
    # outermost digit -- the same contexts, but one bit-plane's counts lie together (in cache)
    nl = 1
    wc_k, wc_kn, wc_un = 27 * 27 * NUM_SIB, 27 * NUM_SIB, NUM_SIB
    wf_uo = NUM_SIB * nl
    wf_ko = 21 * wf_uo
    wf_uf = 21 * wf_ko
    wf_kf = 7 * wf_uf
    wf_k = 7 * wf_kf
    out = []
    for k in range(8):
        ts = [SELF] + [int(t) for t in np.flatnonzero((PLAN_KNOWN[:, k] | PLAN_UNKNOWN[:, k])
                                                       .any(axis=0)) if t != SELF]
        tab = np.zeros((len(ts), 512), dtype=np.int64)
        for i, t in enumerate(ts):
            kf = POPCOUNT8[byte & PLAN_KNOWN[0, k, t]]
            ko = POPCOUNT8[byte & PLAN_KNOWN[1, k, t]]
            uf = present * PLAN_UNKNOWN[0, k, t]
            uo = present * PLAN_UNKNOWN[1, k, t]
            coarse = wc_kn * (kf + ko) + wc_un * (uf + uo)
            fine = wf_kf * kf + wf_uf * uf + wf_ko * ko + wf_uo * uo
            if t == SELF:
                sib = np.minimum(POPCOUNT8[byte & ((1 << k) - 1)], NUM_SIB - 1)
                coarse = coarse + wc_k * k + sib
                fine = fine + wf_k * k + sib + level_bucket * (NUM_FINE // NUM_LEVEL_BUCKETS)
            tab[i] = (coarse << 32) | fine
        out.append((np.array(ts, dtype=np.int64), tab))
    return out


_PLANE_TABLES = [_make_plane_tables(lb) for lb in range(NUM_LEVEL_BUCKETS)]


#: how a plane reads neighbour t (``_GATHER_PLAN``)
_PRESENCE, _GATHER, _HELD = 0, 1, 2


def _make_gather_plan() -> list:
    """Per child index k, for each non-self offset t of its plane table (in table order):
    (t, how, last).  how: _PRESENCE when the plane reads no known bit of t (its share is a
    constant for a present neighbour), _GATHER when it gathers t's state afresh, _HELD when it
    reuses the state gathered at an earlier plane g -- valid when every known bit the plane
    reads is < g (the table masks off the rest; presence never changes); last: whether no
    later plane reuses that gathered state."""
    plan, held, uses = [], {}, {}
    for k in range(8):
        row = []
        for t in _PLANE_TABLES[0][k][0][1:]:
            t = int(t)
            need = int(PLAN_KNOWN[0, k, t] | PLAN_KNOWN[1, k, t]).bit_length()
            if need == 0:
                row.append([t, _PRESENCE, False])
                continue
            fresh = t not in held or held[t] < need
            if fresh:
                held[t] = k
            row.append([t, _GATHER if fresh else _HELD, False])
            uses[t] = row[-1]
        plan.append(row)
    for entry in uses.values():
        entry[2] = True
    return [[tuple(e) for e in row] for row in plan]


_GATHER_PLAN = _make_gather_plan()


def plane_contexts(k: int, state: np.ndarray, nbr: np.ndarray, col: np.ndarray | None,
                   level_bucket: int, held: dict, nodes: np.ndarray | None = None) -> np.ndarray:
    """Packed context ids ``coarse << 32 | fine`` of child ``k`` of the nodes of a level.

    state: uint16 [N + 1] per node 256 | occupancy bits decoded so far (bits < k), slot N = 0
    (absent; the -1 entries of ``nbr`` reach it); nbr: from :meth:`_ChildLevel.table` (one
    column per node asked for); col: the column of each node asked for, in order (None: the
    column is its position); nodes: the Morton indices of the nodes asked for (None: all N);
    held: the neighbour states gathered and presence masks made by earlier planes of the
    level (``_GATHER_PLAN``, in column order), empty at k = 0, updated.
    Returns int64 [len(nodes) or N] in the order of ``nodes`` (Morton order).
    """
    ts, tab = _PLANE_TABLES[level_bucket][k]
    n = nbr.shape[1]
    acc = np.zeros(n, dtype=np.int64)
    tmp = np.empty(n, dtype=np.int64)
    for i, (t, how, last) in enumerate(_GATHER_PLAN[k], start=1):
        if how == _PRESENCE:
            present = held.get(-1 - t)
            if present is None:
                present = held[-1 - t] = nbr[t] >= 0
            np.multiply(present, tab[i][256], out=tmp)
            acc += tmp
            continue
        # fancy indexing with int64 indices: 2x faster than take() or int32 indices here (the
        # conversion included); -1 (absent) reads slot N
        g = state[nbr[t].astype(np.intp, copy=False)] if how == _GATHER else held[t]
        np.take(tab[i], g, out=tmp, mode="clip")
        acc += tmp
        if last:
            held.pop(t, None)
        elif how == _GATHER:
            held[t] = g
    if col is not None:
        acc = acc.take(col)                               # columns -> Morton order
    np.take(tab[0], state[:n] if nodes is None else state.take(nodes), out=tmp, mode="clip")
    acc += tmp
    return acc


def _chunk_bounds(n: int):
    """Start/end of the adaptive-update chunks of a bit-plane of ``n`` coded symbols."""
    s = 0
    while s < n:
        step = min(CHUNK_MAX, max(CHUNK_MIN, s))
        e = min(n, s + step)
        yield s, e
        s = e


_LOW32 = np.int64(0xFFFFFFFF)
# constants of the chunk arithmetic as 0-d int64 arrays (a Python int operand costs each
# ufunc call ~0.6 us; a chunk holds at most 4096 symbols)
_K1, _K16, _K32, _K2_15, _MIX = (np.array(v, np.int64) for v in (1, 16, 32, 1 << 15, MIX_WEIGHT))
#: count increment of a decoded bit: counts are packed zeros | ones << 32 per context
_INC = np.array([1, 1 << 32], dtype=np.int64)
#: levels with at least this many nodes mark their used fine contexts in a flag array (cheaper
#: than collecting and sorting them); smaller ones collect them (scanning the flags costs more)
_MARK_MIN_NODES = 4096

# A bit source: given (level, k, node indices of the chunk, model ids) return the chunk's bits.
BitSource = Callable[[int, int, np.ndarray, np.ndarray], np.ndarray]


#: ``bits``' plane index of the direct flags (scheme 1)
FLAG_PLANE = 8

# A raw source (scheme 1): given (level, node indices of the level's direct nodes, width w)
# return their leaves' low w Morton bits (uint64 [n]).
RawSource = Callable[[int, np.ndarray, int], np.ndarray]


def walk_octree(depth: int, num_points: int, bits: BitSource, direct_from: int | None = None,
                raw: RawSource | None = None) -> np.ndarray:
    """Run the normative traversal; return the uint64 Morton codes of the leaves, ascending.

    ``bits(level, k, node_idx, model_ids)`` supplies the occupancy bits (int64 0/1 [n]) of child
    ``k`` of nodes ``node_idx`` (indices into the level's Morton-ordered node list), coded with the
    given bank models: the decoder reads them from the rANS stream, the encoder looks them up.
    ``direct_from`` (scheme 1, OCTREE.md section 4.1): from that level on, nodes holding one voxel
    leave the tree with their remaining bits from ``raw``; k = FLAG_PLANE asks ``bits`` for
    their flags.
    Raises GszFormatError if a level would hold more than ``num_points`` nodes or the leaf count
    differs from ``num_points``.
    """
    if not 1 <= depth <= MAX_DEPTH:
        raise GszFormatError(f"octree depth {depth} outside [1, {MAX_DEPTH}]")
    if num_points == 0:
        return np.zeros(0, dtype=np.uint64)
    # counts packed per context as zeros | ones << 32 (one gather reads both): k is part of
    # every context, so within a level a total grows by at most one bit-plane's node count
    # (< 2^31) before the halving that follows the level
    cc_n = np.zeros(NUM_COARSE, dtype=np.int64)
    ff_n = np.zeros(NUM_FINE, dtype=np.int64)
    marks = None
    codes = np.zeros(1, dtype=np.uint64)
    root = (np.full((27, 1), -1, dtype=np.int64), None)       # the root has no neighbours
    children = None         # _ChildLevel: the level's nodes as the children of the one above
    # fine contexts that may exceed COUNT_LIMIT after a level: those used in it and those still
    # above the limit after the previous halving (scanning all 2.8 M pairs per level cost more
    # than the traversal itself on small files)
    carry = np.zeros(0, dtype=np.int64)
    decided = 0
    df_n = np.zeros(NUM_DIRECT, dtype=np.int64)
    direct_points = []      # per level: the leaf codes of its direct nodes
    num_direct = 0
    par_pop = None          # per node: its parent's child count
    for level in range(depth):
        n = codes.shape[0]
        if n == 0:          # every remaining voxel was coded directly
            break
        used = [carry]
        if n >= _MARK_MIN_NODES:
            if marks is None:
                marks = np.zeros(NUM_FINE, dtype=np.bool_)
            marks[carry] = True
            used = None
        state = np.full(n + 1, 256, dtype=np.uint16)     # 256 | occupancy; slot n: absent
        state[n] = 0
        lb = min(NUM_LEVEL_BUCKETS - 1, depth - 1 - level)
        held = {}
        kept = None         # the level's nodes left to code (None: all)
        if direct_from is not None and level >= direct_from:
            direct = _direct_flags(level, direct_from, lb, children.present(), par_pop, df_n,
                                   bits)
            decided += direct.shape[0]
            if direct.any():
                dn = np.flatnonzero(direct)
                w = 3 * (depth - level)
                low = np.asarray(raw(level, dn, w), dtype=np.uint64)
                direct_points.append((codes[dn] << np.uint64(w)) | low)
                num_direct += dn.size
                # its one child, known: neighbours' contexts see it; it is not coded
                state[dn] = np.uint16(256) | (np.uint16(1) << (low >> np.uint64(w - 3)).astype(np.uint16))
                kept = np.flatnonzero(~direct)
        # the neighbour table of the coded nodes only (a direct node is never coded)
        nbr, col = root if children is None else children.table(None if kept is None else ~direct)
        children = None
        order = col if kept is None or col is None else col.take(kept)
        for k in range(8):
            ctx = plane_contexts(k, state, nbr, order, lb, held, kept)
            coded = kept
            if k == 7:
                # no child yet: child 7 for free, not coded (a direct node has its child)
                if kept is None:
                    free = (state[:n] & 127) == 0
                    coded = np.flatnonzero(~free)
                    state[:n][free] |= np.uint16(128)
                    ctx = ctx.take(coded)
                else:
                    free = (state.take(kept) & 127) == 0
                    coded = kept[~free]
                    state[kept[free]] |= np.uint16(128)
                    ctx = ctx[~free]
            # every count total is at most the number of decisions so far (halving never
            # increases one)
            decided += ctx.shape[0]
            _code_plane(level, k, ctx, coded, state, cc_n, ff_n, bits, decided < (1 << 32))
            if used is None:
                marks[ctx & _LOW32] = True
            else:
                used.append(ctx & _LOW32)
        _halve_some(cc_n, np.arange(NUM_COARSE))
        if used is None:
            cand = np.flatnonzero(marks)
            marks[cand] = False
        else:
            cand = np.unique(np.concatenate(used))
        carry = _halve_some(ff_n, cand)
        occ = state[:n].astype(np.uint8)
        if kept is not None:
            occ[direct] = 0                 # a direct node has no children in the tree
        # children in Morton order: node-major, child index ascending
        pop = POPCOUNT8[occ]
        total = int(pop.sum())
        if total + num_direct > num_points:
            what = f"{total} nodes" + (f" and {num_direct} direct points" if num_direct else "")
            raise GszFormatError(f"octree level {level + 1} decodes to {what}, more than "
                                 f"the {num_points} points declared")
        # the bits as bools: NumPy's nonzero is ~7x faster on bools than on bytes
        nz = np.flatnonzero(np.unpackbits(occ, bitorder="little").view(np.bool_))
        codes = (codes.take(nz >> 3) << np.uint64(3)) | (nz & 7).astype(np.uint64)
        if level + 1 < depth:
            children = _ChildLevel(nbr, col, occ, nz)
            if direct_from is not None and level + 1 >= direct_from:
                par_pop = np.repeat(pop, pop)
    if codes.shape[0] + num_direct != num_points:
        raise GszFormatError(f"octree decodes to {codes.shape[0] + num_direct} points, header "
                             f"declares {num_points}")
    if direct_points:
        # sorted runs (the leaves, each level's direct points): the stable sort merges them
        codes = np.sort(np.concatenate([codes, *direct_points]), kind="stable")
    return codes


def _direct_flags(level: int, direct_from: int, lb: int, present: np.ndarray,
                  par_pop: np.ndarray, df_n: np.ndarray, bits: BitSource) -> np.ndarray:
    """The direct flags of a level's nodes (OCTREE.md section 4.1), bool [N] in Morton order;
    present: int64 [N] each node's present neighbours (of 26).
    Below ``direct_from`` a node whose parent has one child holds what its parent held (two
    voxels or more): its flag is 0, not coded."""
    ctx = (np.minimum(present, 7) * 4 + np.minimum(par_pop, 4) - 1) * NUM_LEVEL_BUCKETS + lb
    coded = np.arange(ctx.shape[0]) if level == direct_from else np.flatnonzero(par_pop > 1)
    ctx = ctx[coded]
    flags = np.zeros(par_pop.shape[0], dtype=np.bool_)
    out = np.empty(ctx.shape[0], dtype=np.int64)
    for s, e in _chunk_bounds(ctx.shape[0]):
        c = ctx[s:e]
        v = df_n.take(c)
        c1 = v >> _K32
        v &= _LOW32
        v += c1
        v += _K1                                           # c0 + c1 + 1
        c1 <<= _K16
        c1 += _K2_15                                       # (c1 << 16) + 2**15
        # ((2 c1 + 1) << 16) // (2 (c0 + c1) + 2), both halved (the same quotient)
        b = np.asarray(bits(level, FLAG_PLANE, coded[s:e], P16_TO_MODEL.take(c1 // v)),
                       dtype=np.int64)
        np.add.at(df_n, c, _INC.take(b))
        out[s:e] = b
    flags[coded] = out > 0
    _halve_some(df_n, np.arange(NUM_DIRECT))
    return flags


def _floor_div(a: np.ndarray, b: np.ndarray, exact_float: bool) -> np.ndarray:
    """a // b of positive int64 arrays.  With ``exact_float`` (b <= 2**33 + 16 and a / b < 2**16,
    true of both probability formulas while every count total is < 2**32) through float64,
    ~40 % faster and exact: a, b < 2**53 convert exactly, the rounding error of the quotient
    (<= 2**-37) is below its distance to the next integer (>= 1 / b) unless the quotient is
    an integer, which float64 then represents exactly."""
    if exact_float:
        return np.true_divide(a, b).astype(np.int64)
    return a // b


def _code_plane(level: int, k: int, ctx: np.ndarray, coded: np.ndarray | None,
                state: np.ndarray, cc_n: np.ndarray, ff_n: np.ndarray, bits: BitSource,
                exact_float: bool) -> None:
    """Bit-plane k of a level, chunk by chunk (OCTREE.md section 4, steps 2-3): the models from
    the counts before each chunk, the chunk's bits from ``bits``, then the counts.  ctx: the
    packed contexts of the coded nodes (``coded``: their node indices, None = all nodes);
    exact_float: see :func:`_floor_div`.
    The plane's bits go into ``state`` at the end (no context of this plane reads bit k)."""
    coarse, fine = ctx >> 32, ctx & _LOW32
    plane = np.empty(ctx.shape[0], dtype=np.int64)
    for s, e in _chunk_bounds(ctx.shape[0]):
        cc, ff = coarse[s:e], fine[s:e]
        v = cc_n.take(cc)                        # take: 2x faster than fancy indexing here
        c1 = v >> _K32
        v &= _LOW32
        v += c1
        v += _K1                                 # c0 + c1 + 1
        c1 <<= _K16
        c1 += _K2_15                             # (c1 << 16) + 2**15
        # ((2 c1 + 1) << 16) // (2 (c0 + c1) + 2), both halved (the same quotient)
        pc = _floor_div(c1, v, exact_float)
        v = ff_n.take(ff)
        f1 = v >> _K32
        v &= _LOW32
        v += f1
        v += _MIX                                # f0 + f1 + MIX_WEIGHT
        pc *= _MIX
        f1 <<= _K16
        pc += f1
        c1 = _floor_div(pc, v, exact_float)      # p16
        idx = np.arange(s, e) if coded is None else coded[s:e]
        b = np.asarray(bits(level, k, idx, P16_TO_MODEL.take(c1)), dtype=np.int64)
        inc = _INC.take(b)
        np.add.at(cc_n, cc, inc)
        np.add.at(ff_n, ff, inc)
        plane[s:e] = b
    plane <<= k
    if coded is None:
        np.bitwise_or(state[:-1], plane, out=state[:-1], casting="unsafe")
    else:
        state[coded] |= plane.astype(np.uint16)


def _halve_some(counts: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """Halve (rounding up both halves) the packed count pairs ``counts[ids]`` (unique ids) whose
    total exceeds COUNT_LIMIT, in place -- every other pair is known to be within the limit;
    returns the ids still above COUNT_LIMIT afterwards.  Applied after each level."""
    v = counts[ids]
    z, o = v & _LOW32, v >> 32
    over = (z + o) > COUNT_LIMIT
    if not over.any():
        return ids[:0]
    p = ids[over]
    z, o = (z[over] + 1) >> 1, (o[over] + 1) >> 1
    counts[p] = z | (o << 32)
    return p[(z + o) > COUNT_LIMIT]


# ---------------------------------------------------------------- payload
#: First payload byte: the coding scheme.  0: every voxel through the tree; 1: with direct
#: coding of single-voxel nodes from a signalled level on (OCTREE.md section 4.1).
SCHEME_ADAPTIVE_BITWISE = 0
SCHEME_DIRECT = 1


def max_symbols(depth: int, num_points: int, scheme: int = SCHEME_ADAPTIVE_BITWISE) -> int:
    """Upper bound on the coded binary decisions of a valid payload: every level holds at most
    ``num_points`` nodes and each node codes at most 8 child bits (and one direct flag)."""
    return (9 if scheme == SCHEME_DIRECT else 8) * depth * num_points


def pack_direct_bits(values: np.ndarray, width: int) -> bytes:
    """One level's direct values (uint64 [n], each < 2^width) as the raw section stores them:
    ``width`` bits each, least significant first, in a little-endian bit string padded with
    zero bits to a whole byte (OCTREE.md section 2)."""
    v = np.asarray(values, dtype=np.uint64)
    bits = ((v[:, None] >> np.arange(width, dtype=np.uint64)) & np.uint64(1)).astype(np.uint8)
    return np.packbits(bits.reshape(-1), bitorder="little").tobytes()


class DirectBits:
    """Reads the raw section of a scheme-1 payload level by level (the decoder's RawSource)."""

    def __init__(self, raw: np.ndarray):
        self.raw = raw
        self.pos = 0

    def __call__(self, level: int, nodes: np.ndarray, width: int) -> np.ndarray:
        n = int(nodes.shape[0])
        nbytes = (n * width + 7) // 8
        if self.pos + nbytes > self.raw.shape[0]:
            raise GszFormatError(f"octree payload: the direct points of level {level} need "
                                 f"{nbytes} bytes, {self.raw.shape[0] - self.pos} left in the raw section")
        seg = self.raw[self.pos:self.pos + nbytes]
        self.pos += nbytes
        tail = (n * width) & 7
        if tail and seg[-1] >> tail:
            raise GszFormatError(f"octree payload: non-zero padding after the direct points of level {level}")
        # value i: bits i*w .. i*w + w - 1 of the little-endian string, from the two aligned
        # little-endian u64 words holding them (two gathers and shifts, not a bit array)
        start = np.arange(n, dtype=np.uint64) * np.uint64(width)
        buf = np.zeros((nbytes + 15) // 8 * 8 + 8, dtype=np.uint8)
        buf[:nbytes] = seg
        words = buf.view("<u8")
        first = (start >> np.uint64(6)).astype(np.intp)
        shift = start & np.uint64(63)
        v = words.take(first) >> shift
        # the bits past the first word (a shift by 64 is undefined: masked where shift = 0)
        v |= np.where(shift > 0, words.take(first + 1) << (np.uint64(64) - shift), np.uint64(0))
        return (v & np.uint64((1 << width) - 1)).astype(np.uint64, copy=False)

    def finish(self) -> None:
        if self.pos != self.raw.shape[0]:
            raise GszFormatError(f"octree payload: {self.raw.shape[0] - self.pos} bytes of the raw "
                                 f"section left unread")


def read_scheme(buf: np.ndarray, depth: int, num_points: int) -> tuple:
    """The payload's header fields (OCTREE.md section 2): (scheme, S, direct_from or None,
    raw section uint8 [R], body uint8), validated."""
    if buf.size < 1:
        raise GszFormatError("octree payload is empty")
    scheme = int(buf[0])
    if scheme not in (SCHEME_ADAPTIVE_BITWISE, SCHEME_DIRECT):
        raise GszFormatError(f"octree payload: unknown coding scheme {scheme}")
    num_symbols, pos = read_varint(buf, 1, "octree symbol count")
    bound = max_symbols(depth, num_points, scheme)
    if num_symbols > bound:
        raise GszFormatError(f"octree payload declares {num_symbols} symbols, more than "
                             f"{bound} possible for {num_points} points")
    if scheme == SCHEME_ADAPTIVE_BITWISE:
        return scheme, num_symbols, None, buf[:0], buf[pos:]
    if pos >= buf.size:
        raise GszFormatError("octree payload truncated before its direct level")
    direct_from = int(buf[pos])
    if not 1 <= direct_from <= depth - 1:
        raise GszFormatError(f"octree payload: direct level {direct_from} outside 1..{depth - 1}")
    raw_len, pos = read_varint(buf, pos + 1, "octree raw section length")
    # each direct point has at most 3 * (depth - 1) raw bits
    if raw_len > buf.size - pos or raw_len > num_points * 8 + depth:
        raise GszFormatError(f"octree payload: raw section of {raw_len} bytes does not fit")
    return scheme, num_symbols, direct_from, buf[pos:pos + raw_len], buf[pos + raw_len:]


def decode_octree_codes(payload, depth: int, num_points: int, helper=None) -> np.ndarray:
    """Decode a geometry payload (``format_spec/OCTREE.md``) to the voxels' Morton codes.

    payload: bytes-like; depth: octree depth d in 1..21 (coordinates in [0, 2^d));
    num_points: the number of occupied voxels M declared by the container.
    Returns uint64 [M], strictly ascending.
    Raises GszFormatError on any corrupt, truncated or inconsistent payload.
    Uses the C traversal when ``gsz.decoder.native`` is enabled (identical output and checks);
    ``helper``: an unused ``_native.octree_helper()`` through which another thread may join
    that traversal (``_native.octree_help``), ignored on the NumPy path.
    """
    if not 1 <= depth <= MAX_DEPTH:
        raise GszFormatError(f"octree depth {depth} outside [1, {MAX_DEPTH}]")
    if num_points < 0 or num_points > (1 << (3 * depth)):
        raise GszFormatError(f"octree point count {num_points} impossible at depth {depth}")
    buf = np.frombuffer(payload, dtype=np.uint8)
    scheme, num_symbols, direct_from, raw, body = read_scheme(buf, depth, num_points)
    if native.enabled() and num_points <= native.module().MAX_POINTS:
        # the payload header is validated here exactly as RansDecoder does (ENTROPY.md 4.1);
        # the C code re-checks what it relies on
        lanes, _, p = parse_payload_header(body, num_symbols, OCTREE_MAX_ROWS)
        tables = octree_tables(bank_precision(num_symbols))
        out = native.module().octree_decode(tables, int(depth), int(num_points), int(num_symbols),
                                            int(lanes), body[p:], helper, direct_from or 0, raw)
        return np.frombuffer(out, dtype="<u8").astype(np.uint64, copy=False)
    dec = RansDecoder(body, num_symbols, bank_model_set(num_symbols), max_rows=OCTREE_MAX_ROWS)
    # the bank's binary row loop (model ids come from P16_TO_MODEL: valid by construction);
    # its symbols are 0/1 by construction too
    read = dec.binary_reader()

    def read_bits(level, k, idx, model):
        return read(model)

    direct = DirectBits(raw) if direct_from is not None else None
    codes = walk_octree(depth, num_points, read_bits, direct_from, direct)
    dec.finish()
    if direct is not None:
        direct.finish()
    return codes


def decode_octree(payload, depth: int, num_points: int) -> np.ndarray:
    """Decode a geometry payload (``format_spec/OCTREE.md``) to voxel coordinates.

    payload: bytes-like; depth: octree depth d in 1..21 (coordinates in [0, 2^d));
    num_points: the number of occupied voxels M declared by the container.
    Returns int64 [M, 3] (x, y, z), unique, in ascending Morton order.
    Raises GszFormatError on any corrupt, truncated or inconsistent payload.
    """
    return morton_decode(decode_octree_codes(payload, depth, num_points))


@functools.lru_cache(maxsize=8)
def octree_tables(precision: int) -> tuple:
    """The tables the C octree traversal takes, built from the normative Python definitions in
    this module: neighbourhood plans, child plans, P16_TO_MODEL, the frequency of a 0
    of every bank model at rANS ``precision`` (:func:`bank_precision`), the chunk schedule,
    COUNT_LIMIT and MIX_WEIGHT.  The C code hard-codes only the context layout, checked here."""
    if (NUM_COARSE, NUM_FINE) != (native.module().NUM_COARSE, native.module().NUM_FINE):
        raise AssertionError("octree context layout differs between Python and csrc/octree.h")
    ms = _bank_model_set(int(precision))
    t = ms.build()
    if not (np.all(t["sym_count"] == 2) and np.all(ms.prec == precision)
            and np.array_equal(t["value"], np.tile([0, 1], NUM_MODELS))):
        raise AssertionError("bank models are not binary models of one precision")
    freq0 = np.ascontiguousarray(t["freq"][t["sym_start"]], dtype=np.int64)
    c64 = (lambda a: np.ascontiguousarray(a, dtype=np.int64))
    return (c64(PLAN_KNOWN), c64(PLAN_UNKNOWN), c64(CHILD_PAR), c64(CHILD_IDX),
            c64(P16_TO_MODEL), freq0, int(precision), CHUNK_MIN, CHUNK_MAX,
            COUNT_LIMIT, MIX_WEIGHT)
