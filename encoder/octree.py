"""Lossless octree geometry encoder (the decoder's traversal run with known occupancy bits).

The payload format and the context model are defined by ``gsz.decoder.octree`` (and
``format_spec/OCTREE.md``); this module only computes the true occupancy bytes of every level,
runs :func:`gsz.decoder.octree.walk_octree` with them as the bit source -- so the model ids are
by construction the ones the decoder will compute -- and entropy-codes the recorded bits.  With
the native accelerator (``gsz.decoder.native``) the same traversal and the binary rANS coder run
in C; the payload bytes are identical (tests/test_native.py).
"""
from __future__ import annotations

import numpy as np

from ..decoder import native
from ..decoder.errors import CloudValidationError
from ..decoder.morton import MAX_DEPTH, morton_decode, morton_encode
from ..decoder.octree import (FLAG_PLANE, SCHEME_ADAPTIVE_BITWISE, SCHEME_DIRECT, bank_model_set,
                              bank_precision, octree_tables, pack_direct_bits, walk_octree)
from .rans import encode_symbols, varint_bytes


def occupancy_levels(codes: np.ndarray, depth: int) -> list[np.ndarray]:
    """Occupancy bytes of every internal level of the octree of sorted unique Morton codes.

    codes: uint64 [M] ascending, unique, < 2^(3 depth).  Returns a list of ``depth`` int64
    arrays; entry l holds, for each node of level l in Morton order, the byte whose bit k says
    child k is occupied.
    """
    out = []
    child = codes
    for level in range(depth - 1, -1, -1):
        parent = child >> np.uint64(3)
        first = np.ones(parent.shape[0], dtype=bool)
        first[1:] = parent[1:] != parent[:-1]
        starts = np.flatnonzero(first)
        bits = np.int64(1) << (child & np.uint64(7)).astype(np.int64)
        out.append(np.bitwise_or.reduceat(bits, starts) if starts.size else bits[:0])
        child = parent[starts]
    return out[::-1]


#: Binary decisions per rANS lane.  Each lane ends with a 32-bit state and the decisions cost
#: ~0.5 bit each, so the default rANS policy (2048 symbols per lane) would add ~3 %; 16384 keeps
#: the state overhead near 0.3 % while the decoder handles at most ~16k rows per stream.
SYMBOLS_PER_LANE = 16384


def choose_lanes(num_symbols: int) -> int:
    """Lane count written in the payload (any value the rANS format allows would decode)."""
    return int(min(4096, max(1, int(num_symbols) // SYMBOLS_PER_LANE)))


class DirectTree:
    """What the traversal with direct coding from level ``start`` sees of a known voxel set
    (OCTREE.md section 4.1): per level, its nodes' occupancy bytes, direct flags and raw values.

    A node of level l >= start is direct when it holds one voxel; it is in the tree when no
    ancestor of level >= start was direct, i.e. (the voxel count only falls going down) when
    l <= start or its parent holds two voxels or more."""

    def __init__(self, codes: np.ndarray, depth: int, start: int):
        self.occ, self.flags, self.low = [], {}, {}
        m = codes.shape[0]
        par_count = None                    # per voxel: its level l-1 node's voxel count
        for level in range(depth):
            shift = np.uint64(3 * (depth - level))
            prefix = codes >> shift
            first = np.ones(m, dtype=bool)
            first[1:] = prefix[1:] != prefix[:-1]
            starts = np.flatnonzero(first)
            count = np.diff(np.append(starts, m))
            child = (codes >> (shift - np.uint64(3))) & np.uint64(7)
            occ = np.bitwise_or.reduceat(np.int64(1) << child.astype(np.int64), starts)
            in_tree = slice(None) if level <= start else par_count[starts] >= 2
            self.occ.append(occ[in_tree])
            if level >= start:
                one = count[in_tree] == 1
                self.flags[level] = one.astype(np.int64)
                firsts = starts[in_tree][one]
                self.low[level] = codes[firsts] & ((np.uint64(1) << shift) - np.uint64(1))
            par_count = np.repeat(count, count)

    def raw_section(self, depth: int) -> bytes:
        return b"".join(pack_direct_bits(v, 3 * (depth - level)) for level, v in sorted(self.low.items()))


def octree_symbols(ijk: np.ndarray, depth: int, direct_from: int | None = None):
    """Validate ``ijk`` and run the normative traversal with its true occupancy (and direct
    coding from level ``direct_from``: scheme 1).

    Returns (sorted Morton codes uint64 [M], coded bits int64 [S], bank model ids int64 [S],
    the raw section's bytes).
    """
    codes = _validated_codes(ijk, depth)
    return (codes, *_symbols(codes, int(depth), direct_from))


def _validated_codes(ijk: np.ndarray, depth: int) -> np.ndarray:
    """The sorted Morton codes of ``ijk`` after the checks encode_octree promises."""
    a = np.asarray(ijk)
    if a.ndim != 2 or a.shape[1] != 3 or not np.issubdtype(a.dtype, np.integer):
        raise CloudValidationError(f"encode_octree expects an integer [M, 3] array, got "
                                   f"{a.dtype} {a.shape}")
    if not 1 <= int(depth) <= MAX_DEPTH:
        raise CloudValidationError(f"octree depth {depth} outside [1, {MAX_DEPTH}]")
    if a.size and (a.min() < 0 or a.max() >= (1 << depth)):
        raise CloudValidationError(f"voxel coordinates must lie in [0, 2^{depth}) = [0, {1 << depth}), "
                                   f"got range [{a.min()}, {a.max()}]")
    codes = np.sort(morton_encode(a))
    if codes.size > 1:
        dup = np.flatnonzero(codes[1:] == codes[:-1])
        if dup.size:
            first = morton_decode(codes[dup[:1]])[0].tolist()
            raise CloudValidationError(f"encode_octree needs unique voxels: {dup.size} duplicate "
                                       f"coordinate(s), e.g. {first}; merge duplicates first")
    return codes


def _symbols(codes: np.ndarray, depth: int, direct_from: int | None, narrow: bool = False):
    """(coded bits int64 [S], bank model ids int64 [S], raw section bytes) of sorted codes;
    ``narrow``: uint8 where the C traversal makes them (as the C coder takes them: two int64
    copies are ~16 bytes a symbol, 80 MB for a tile of 845 k voxels)."""
    if direct_from is not None and not 1 <= direct_from < depth:
        raise ValueError(f"direct level {direct_from} outside 1..{depth - 1}")
    if direct_from is not None and codes.size:
        tree = DirectTree(codes, int(depth), int(direct_from))
        occ, raw = tree.occ, tree.raw_section(int(depth))
    else:
        tree, raw = None, b""
        occ = occupancy_levels(codes, depth) if codes.size else []
    if native.enabled() and codes.size <= native.module().MAX_POINTS:
        bits, mods = _native_symbols(codes, occ, int(depth), direct_from, tree)
        del tree, occ
        if narrow:
            return bits, mods, raw
        return bits.astype(np.int64), mods.astype(np.int64), raw
    syms, mods = [], []

    def true_bits(level, k, idx, model):
        b = tree.flags[level][idx] if k == FLAG_PLANE else (occ[level][idx] >> k) & 1
        syms.append(b)
        mods.append(model)
        return b

    leaves = walk_octree(int(depth), int(codes.size), true_bits, direct_from,
                         None if tree is None else (lambda level, idx, w: tree.low[level]))
    if not np.array_equal(leaves, codes):     # the traversal must rebuild exactly the input
        raise AssertionError("octree traversal did not reproduce the input voxels")
    cat = (lambda xs: np.concatenate(xs) if xs else np.zeros(0, np.int64))
    return cat(syms), cat(mods), raw


def _native_symbols(codes: np.ndarray, occ: list, depth: int, direct_from: int | None = None,
                    tree: DirectTree | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The traversal with known occupancy in C (``_native.octree_encode``): the same decisions
    and bank model ids as walk_octree with the true_bits source, as uint8 arrays."""
    # the model ids do not depend on the bank precision; any precision's tables will do
    tables = octree_tables(bank_precision(0))
    known = np.concatenate(occ).astype(np.uint8) if occ else np.zeros(0, np.uint8)
    sizes = np.array([o.size for o in occ], dtype=np.int64)
    extra = ()
    if tree is not None:
        levels = sorted(tree.flags)
        cat = (lambda xs, dt: np.ascontiguousarray(np.concatenate(xs) if xs else np.zeros(0), dtype=dt))
        extra = (int(direct_from), cat([tree.flags[lv] for lv in levels], np.uint8),
                 cat([tree.low[lv] for lv in levels], np.uint64))
    bits, mods, leaves = native.module().octree_encode(tables, depth, int(codes.size), known, sizes, *extra)
    if not np.array_equal(np.frombuffer(leaves, dtype="<u8"), codes):
        raise AssertionError("octree traversal did not reproduce the input voxels")
    return np.frombuffer(bits, dtype=np.uint8), np.frombuffer(mods, dtype=np.uint8)


#: Candidate start levels of direct coding: the first level where at least this share of the
#: nodes hold one voxel (earlier: a smaller tree for the decoder; later: usually fewer bytes).
DIRECT_SHARES = (0.5, 0.8, 0.95)
#: In a large tree, the earliest candidate whose payload is within this fraction of the
#: smallest is taken (a small tree takes the smallest): there the geometry is ~5 % of the file,
#: so 1.5 % of it is ~0.1 % of the file, while a start two or three levels later makes the
#: decoder's tree up to 3x slower (the 1.2 M bench's larger tile: D 12 for 0.65 % fewer bytes)
DIRECT_TOLERANCE = 0.015
#: Trees of at most this many voxels also try scheme 0.
SCHEME0_TRIED_BELOW = 1 << 18


def direct_candidates(codes: np.ndarray, depth: int) -> list:
    """Start levels worth trying for sorted unique codes, fastest to decode first: the first
    level reaching each of DIRECT_SHARES, then None (scheme 0) when the tree is small (its
    encode is cheap) or direct coding could only start in the last two levels (a dense or
    shallow grid, where the tree's contexts predict a lone voxel's position better than its
    raw bits).  A large deep tree is not coded without direct coding: that costs seconds per
    encode and per decode, for a payload within ~0.5 %."""
    if depth < 2 or codes.size == 0:
        return [None]
    share = []
    for level in range(1, depth):
        prefix = codes >> np.uint64(3 * (depth - level))
        first = np.ones(codes.shape[0], dtype=bool)
        first[1:] = prefix[1:] != prefix[:-1]
        starts = np.flatnonzero(first)
        share.append(np.count_nonzero(np.diff(np.append(starts, codes.shape[0])) == 1) / starts.size)
    out = []
    for x in DIRECT_SHARES:
        level = next((l for l, f in enumerate(share, start=1) if f >= x), None)
        if level is not None and level not in out:
            out.append(level)
    if not out or out[0] >= depth - 2 or codes.size <= SCHEME0_TRIED_BELOW:
        out.append(None)
    return out


def choose_direct_level(codes: np.ndarray, depth: int) -> int | None:
    """The scheme the encoder writes for sorted unique codes: the start level of direct coding
    (scheme 1) or None (scheme 0): of :func:`direct_candidates`, the smallest payload; in a
    tree of more than SCHEME0_TRIED_BELOW voxels, whose decode time matters, the first within
    DIRECT_TOLERANCE of the smallest (docs/design/octree-direct.md)."""
    return _choose(codes, depth)[0]


def _choose(codes: np.ndarray, depth: int) -> tuple:
    """(direct level or None, payload) per choose_direct_level."""
    tried = [(d, _payload(codes, depth, d)) for d in direct_candidates(codes, depth)]
    smallest = min(len(p) for _, p in tried)
    tolerance = DIRECT_TOLERANCE if codes.size > SCHEME0_TRIED_BELOW else 0.0
    return next((d, p) for d, p in tried if len(p) <= smallest * (1 + tolerance))


def encode_octree(ijk: np.ndarray, depth: int, direct_from: int | str | None = "auto") -> bytes:
    """Geometry payload of unique voxels (``format_spec/OCTREE.md``).

    ijk: int [M, 3] unique voxel coordinates in [0, 2^depth); depth: 1..21.
    direct_from: the level from which single-voxel nodes are coded directly (scheme 1), "auto"
    (:func:`choose_direct_level`: tries a few), or None for scheme 0.
    Returns bytes; ``gsz.decoder.octree.decode_octree(payload, depth, M)`` gives the voxels back
    in ascending Morton order (``gsz.decoder.morton``).  Deterministic.
    Raises CloudValidationError (a GszError and ValueError) on duplicates, out-of-range
    coordinates, a bad shape or a bad depth.
    """
    codes = _validated_codes(ijk, depth)
    if isinstance(direct_from, str):
        if direct_from != "auto":
            raise ValueError(f"direct_from must be a level, 'auto' or None, got {direct_from!r}")
        return _choose(codes, int(depth))[1]
    return _payload(codes, int(depth), direct_from)


def _payload(codes: np.ndarray, depth: int, direct_from: int | None) -> bytes:
    syms, mods, raw = _symbols(codes, depth, direct_from, narrow=True)
    n = int(syms.size)
    if native.enabled():
        # binary rANS in C: the bytes encode_symbols writes for the bank (ENTROPY.md 6)
        tables = octree_tables(bank_precision(n))
        u8 = (lambda a: np.ascontiguousarray(a, np.uint8))
        body = native.module().bank_encode(u8(syms), u8(mods), tables[5], tables[6], choose_lanes(n))
    else:
        body = encode_symbols(syms, mods, bank_model_set(n), lanes=choose_lanes(n))
    if direct_from is None:
        return bytes([SCHEME_ADAPTIVE_BITWISE]) + varint_bytes([n]) + body
    return bytes([SCHEME_DIRECT]) + varint_bytes([n]) + bytes([direct_from]) + varint_bytes([len(raw)]) + raw + body
