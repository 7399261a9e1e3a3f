"""SHVQ chunk: higher-degree SH as a vector-quantised codebook plus kept exact vectors (GSZ.md §8).

Syntax (D = 3K, K = (d+1)^2 - 1 coefficients per colour)::

    u32  K_cb               codebook entries, 1..65536 in the one layer that carries the
                            codebook (the first with codeword indices, see GSZ.md §4.1), else 0
    u32  P                  kept vectors, 0..M
    u16  D                  vector length, must equal 3K of the header's SH degree
    if K_cb > 0:
      ChannelSet codebook   C = D, L = K_cb  (channel j = vector component j)
    if P > 0:
      ChannelSet kept       C = D, L = P     (kept vectors in Morton order of their Gaussians)
      u64 n, byte[n]        rANS stream of M flags (0/1, one model): 1 = the Gaussian uses the
                            next kept vector
    u64 n, byte[n]          rANS stream of M - P codeword indices (one model), in Morton order of
                            the Gaussians whose flag is 0

A vector's components are the Gaussian's sh_rest[K, 3] flattened coefficient-major (RGB last).

SHCL chunk (format 1.3, optional per part): the kept vectors' importance classes, so that the
kept ChannelSet's blocks can be classes and the encoder's bit allocation can give important
Gaussians finer SH than unimportant ones::

    u8   Q                  number of classes, 2..16
    u64 n, byte[n]          rANS stream of P class ids (0..Q-1, one model), one per kept vector
                            in Morton order of their Gaussians

With SHCL, the kept ChannelSet stores the kept vectors ordered by (class, Morton order):
:func:`class_order` is that order, the one truth the encoder codes in.
"""
from __future__ import annotations

import numpy as np

from .bytesio import Reader
from .cloud import sh_rest_count
from .groups import read_channel_set
from . import native
from .rans import decode_stream_single

MAX_CODEBOOK = 1 << 16
#: most importance classes an SHCL chunk may declare
MAX_SH_CLASSES = 16


def class_order(classes: np.ndarray) -> np.ndarray:
    """Coding order of the kept vectors [P] from their classes [P] (Morton order): class 0
    first, Morton order within a class (a stable sort)."""
    c = np.asarray(classes)
    if c.size and c.dtype != np.uint8 and c.min() >= 0 and c.max() < 256:
        c = c.astype(np.uint8)         # the same order: NumPy's stable sort of bytes is a radix sort (10x)
    return np.argsort(c, kind="stable")


def read_sh_classes(data, num_kept: int) -> np.ndarray:
    """Decode an SHCL chunk: the class [P] of each kept vector, in Morton order."""
    r = Reader(data, "SHCL chunk")
    q = r.u8()
    r.check(2 <= q <= MAX_SH_CLASSES, f"SH class count {q} outside 2..{MAX_SH_CLASSES}")
    r.check(num_kept > 0, "SH classes for a part without kept SH vectors")
    classes = decode_stream_single(r.blob(), num_kept)
    r.check(bool(np.all((classes >= 0) & (classes < q))), f"SH class outside 0..{q - 1}")
    r.expect_end()
    return classes


def _stored_column(classes: np.ndarray | None, p: int) -> np.ndarray:
    """[P] the stored column of each kept vector, in point order (class order when ``classes``)."""
    col = np.empty(p, np.int64)
    col[class_order(classes) if classes is not None else slice(None)] = np.arange(p)
    return col


def read_sh(data, num_points: int, sh_degree: int, codebook: np.ndarray | None = None,
            classes_chunk=None):
    """Decode one layer's SHVQ chunk.

    codebook    the [D, K_cb] float64 codebook an earlier layer carried, or None
    classes_chunk  the part's SHCL chunk, or None (kept vectors stored in Morton order)
    returns     (sh_rest float32 [M, K, 3], codebook [D, K_cb] float64 or None): the codebook
                of this layer when it carries one, else the one passed in

    The codebook sits in exactly one layer; a layer that carries one when an earlier layer did,
    or that has codeword indices while no layer so far carried a codebook, is rejected.
    """
    k = sh_rest_count(sh_degree)
    m = num_points
    r = Reader(data, "SHVQ chunk")
    kcb = r.u32()
    p = r.u32()
    d = r.u16()
    r.check(d == 3 * k, f"SH vector length {d} does not match SH degree {sh_degree} (expected {3 * k})")
    r.check(p <= m, f"{p} kept SH vectors for {m} Gaussians")
    if kcb:
        r.check(codebook is None, f"a second SH codebook ({kcb} entries): an earlier layer carried one")
        r.check(kcb <= MAX_CODEBOOK, f"codebook size {kcb} outside 1..{MAX_CODEBOOK}")
        codebook = read_channel_set(r, max_length=kcb, shape=(d, kcb), name="codebook")
    else:
        r.check(codebook is not None or p == m,
                "codeword indices but no SH codebook in this or an earlier layer")
        kcb = 0 if codebook is None else codebook.shape[1]
    classes = None if classes_chunk is None else read_sh_classes(classes_chunk, p)
    if native.enabled():
        return _assemble_native(r, m, k, d, p, kcb, codebook, classes), codebook
    kept = None
    if p:
        # float32: the values the float32 output keeps (half the bytes to decode into and move)
        kept = read_channel_set(r, max_length=p, shape=(d, p), name="kept SH set", dtype=np.float32)
        flags = decode_stream_single(r.blob(), m)
        r.check(bool(np.all((flags == 0) | (flags == 1))), "kept flag outside 0/1")
        kept_mask = flags.astype(bool)
        r.check(int(kept_mask.sum()) == p, f"{int(kept_mask.sum())} kept flags set, header says {p}")
    idx = decode_stream_single(r.blob(), m - p)
    r.check(idx.size == 0 or (idx.min() >= 0 and idx.max() < kcb), "codeword index out of range")
    r.expect_end()
    # every Gaussian's vector is one row of [kept vectors; codebook] as float32 (the rounding
    # the float32 output applies anyway): one contiguous gather, not two masked scatters; the
    # rows are cast in place (no float32 copy of each part, then of their concatenation)
    rows = np.empty((p + (kcb if idx.size else 0), d), np.float32)
    if p:
        rows[:p] = kept.T
    if idx.size:
        rows[p:] = codebook.T
    # the row of [kept vectors as stored; codebook] each Gaussian takes (kept ones in point order)
    if p and idx.size:
        which = np.empty(m, np.int64)
        which[kept_mask] = _stored_column(classes, p)
        which[~kept_mask] = idx + p
    else:
        which = idx + p if idx.size else _stored_column(classes, m)
    # rows as single 4*D-byte items: a 1-D take copies each row in one piece
    item = np.dtype((np.void, 4 * d))
    out = np.ascontiguousarray(rows).view(item)[:, 0].take(which).view(np.float32)
    return out.reshape(m, k, 3), codebook


def _assemble_native(r: Reader, m: int, k: int, d: int, p: int, kcb: int, codebook, classes):
    """read_sh's kept vectors, flags and indices, assembled in one C pass (same checks)."""
    flags = None
    kept = np.zeros((d, 0), np.float64)
    if p:
        kept = read_channel_set(r, max_length=p, shape=(d, p), name="kept SH set")
        flags = decode_stream_single(r.blob(), m)
    idx = decode_stream_single(r.blob(), m - p)
    r.expect_end()
    cb = np.zeros((d, 0), np.float64) if codebook is None else codebook
    out = np.empty((m, d), np.float32)
    native.module().sh_assemble(flags, np.ascontiguousarray(kept, dtype=np.float64), idx,
                                np.ascontiguousarray(cb, dtype=np.float64), out,
                                None if classes is None else class_order(classes).astype(np.int64))
    return out.reshape(m, k, 3)
