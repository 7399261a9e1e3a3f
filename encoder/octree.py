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
from ..decoder.octree import (SCHEME_ADAPTIVE_BITWISE, bank_model_set, bank_precision, octree_tables,
                                walk_octree)
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


def octree_symbols(ijk: np.ndarray, depth: int):
    """Validate ``ijk`` and run the normative traversal with its true occupancy.

    Returns (sorted Morton codes uint64 [M], coded bits int64 [S], bank model ids int64 [S]).
    """
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
    occ = occupancy_levels(codes, depth) if codes.size else []
    if native.enabled() and codes.size <= native.module().MAX_POINTS:
        bits, mods = _native_symbols(codes, occ, int(depth))
        return codes, bits.astype(np.int64), mods.astype(np.int64)
    syms, mods = [], []

    def true_bits(level, k, idx, model):
        b = (occ[level][idx] >> k) & 1
        syms.append(b)
        mods.append(model)
        return b

    leaves = walk_octree(int(depth), int(codes.size), true_bits)
    if not np.array_equal(leaves, codes):     # the traversal must rebuild exactly the input
        raise AssertionError("octree traversal did not reproduce the input voxels")
    cat = (lambda xs: np.concatenate(xs) if xs else np.zeros(0, np.int64))
    return codes, cat(syms), cat(mods)


def _native_symbols(codes: np.ndarray, occ: list, depth: int) -> tuple[np.ndarray, np.ndarray]:
    """The traversal with known occupancy in C (``_native.octree_encode``): the same decisions
    and bank model ids as walk_octree with the true_bits source, as uint8 arrays."""
    # the model ids do not depend on the bank precision; any precision's tables will do
    tables = octree_tables(bank_precision(0))
    known = np.concatenate(occ).astype(np.uint8) if occ else np.zeros(0, np.uint8)
    sizes = np.array([o.size for o in occ], dtype=np.int64)
    bits, mods, leaves = native.module().octree_encode(tables, depth, int(codes.size), known, sizes)
    if not np.array_equal(np.frombuffer(leaves, dtype="<u8"), codes):
        raise AssertionError("octree traversal did not reproduce the input voxels")
    return np.frombuffer(bits, dtype=np.uint8), np.frombuffer(mods, dtype=np.uint8)


def encode_octree(ijk: np.ndarray, depth: int) -> bytes:
    """Geometry payload of unique voxels (``format_spec/OCTREE.md``).

    ijk: int [M, 3] unique voxel coordinates in [0, 2^depth); depth: 1..21.
    Returns bytes; ``gsz.decoder.octree.decode_octree(payload, depth, M)`` gives the voxels back
    in ascending Morton order (``gsz.decoder.morton``).  Deterministic.
    Raises CloudValidationError (a GszError and ValueError) on duplicates, out-of-range
    coordinates, a bad shape or a bad depth.
    """
    codes, syms, mods = octree_symbols(ijk, depth)
    n = int(syms.size)
    if native.enabled():
        # binary rANS in C: the bytes encode_symbols writes for the bank (ENTROPY.md 6)
        tables = octree_tables(bank_precision(n))
        body = native.module().bank_encode(syms.astype(np.uint8), mods.astype(np.uint8),
                                           tables[5], tables[6], choose_lanes(n))
    else:
        body = encode_symbols(syms, mods, bank_model_set(n), lanes=choose_lanes(n))
    return bytes([SCHEME_ADAPTIVE_BITWISE]) + varint_bytes([n]) + body
