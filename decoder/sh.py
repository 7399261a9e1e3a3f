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

SHXF chunk (format 1.6, optional per part): the colour space the part's SH coefficients are
coded in (GSZ.md §8.2)::

    u8   transforms         bit 0 (1.6): the SH vectors are luma/chroma: every stored (a, b, c)
                            triplet of one coefficient is turned back into (R, G, B) by
                            :func:`luma_chroma_to_rgb`; bit 1 (1.7): so is the DC colour, after
                            the inverse RAHT (:func:`turn_dc`); bit 2 (1.8): the SH vectors are
                            in the file's own axes (KLT, :func:`klt_to_rgb`), not with bit 0;
                            other bits 0, not all 0
    if bit 2:
      u8  D                 0: the matrix of an earlier layer of the tile; else 3K
      i16 klt[D][D]         (D > 0) row i: stored component i in RGB components, times 2^-14

SHRF chunk (format 1.9, optional per part): the part's kept vectors are residuals of a codeword
each (GSZ.md §8.3)::

    u64 n, byte[n]          rANS stream of P codeword indices (one model), one per kept vector in
                            the order the kept ChannelSet stores them; the codebook is this
                            layer's or an earlier layer's of the tile

A stored kept vector j is then the f32 sum of its dequantised values and codeword ``indices[j]``
(both rounded to f32 first), before any SHXF transform: a codebook takes the coarse shape of a
trained capture's SH, and the kept set quantises only what it misses, where a codebook alone
leaves the upper-mid rates short (docs/design/sh-refine.md).

A view-dependent change in a real capture is mostly a change of brightness, so its three colour
channels are strongly correlated; coded as luma and two chroma differences they take fewer bits
(docs/design/sh-colour.md).  In a trained capture the components of one vector are correlated
too (one luma coefficient with another): turned by their principal axes, the same SNR takes
0.3-0.6x the bits (docs/design/sh-klt.md).
"""
from __future__ import annotations

import numpy as np

from .bytesio import Reader
from .cloud import FRESH, OutputRows, sh_rest_count
from .errors import GszFormatError
from .groups import read_channel_set, read_channel_set_symbols
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
        c = c.astype(np.uint8)         # the same order; NumPy sorts bytes by radix sort (10x)
    return np.argsort(c, kind="stable")


#: SHXF transform bits (GSZ.md §8.2): 1 = the SH vectors as luma/chroma (1.6), 2 = the DC
#: colour as luma/chroma (1.7), 4 = the SH vectors in the file's own axes (KLT, 1.8); 0 = no
#: SHXF chunk (RGB)
SH_COLOUR_RGB = 0
SH_COLOUR_LUMA_CHROMA = 1
SH_COLOUR_DC = 2
SH_COLOUR_KLT = 4
SH_COLOUR_BITS = SH_COLOUR_LUMA_CHROMA | SH_COLOUR_DC | SH_COLOUR_KLT
#: the KLT matrix's entries are int16 times 2^-KLT_MATRIX_SHIFT
KLT_MATRIX_SHIFT = 14
#: stored values are taken as integers times 2^-KLT_VALUE_SHIFT before the matrix product
KLT_VALUE_SHIFT = 24
#: a stored value must be below this in magnitude: then every product and partial sum of the
#: KLT inverse is an integer below 2^53 (2^32 * 2^15 * 45 < 2^53), exact in binary64
KLT_MAX_ABS = 256.0
#: rows per step of the KLT inverse (a [16384, 45] float64 block: 6 MB)
_KLT_ROWS = 1 << 14


class ShColour(int):
    """An SHXF chunk's transform bits (an int: ``colour & SH_COLOUR_DC`` as before) with the
    KLT matrix bit 2 needs: ``klt`` int16 [D, D] (row i: stored component i in RGB components,
    times 2^-KLT_MATRIX_SHIFT), or None (no KLT, or a later layer's chunk that uses its tile's
    matrix).  Bit operations give plain ints: a DC-only colour carries no matrix."""

    klt: np.ndarray | None

    def __new__(cls, bits: int, klt: np.ndarray | None = None):
        obj = super().__new__(cls, int(bits))
        obj.klt = None if klt is None else np.ascontiguousarray(klt, np.int16)
        return obj

    def __repr__(self) -> str:
        klt = "" if self.klt is None else f", klt {self.klt.shape[0]}x{self.klt.shape[1]}"
        return f"ShColour({int(self)}{klt})"


#: the inverse's float64 constants 1/sqrt(3), 1/sqrt(2), 1/sqrt(6), exactly as the spec gives them
_S3 = float.fromhex("0x1.279a74590331dp-1")
_S2 = float.fromhex("0x1.6a09e667f3bccp-1")
_S6 = float.fromhex("0x1.a20bd700c2c3fp-2")


def read_sh_colour(data, sh_degree: int | None = None) -> ShColour:
    """Decode an SHXF chunk: its transform bits and, with bit 2 in the first layer that has it,
    the KLT matrix.  ``sh_degree`` 0: the SH vector bits are rejected (the part has none);
    given, a matrix's D must be that degree's 3K."""
    r = Reader(data, "SHXF chunk")
    t = r.u8()
    r.check(t != 0 and not t & ~SH_COLOUR_BITS,
            f"unknown SH colour transform {t} (this decoder knows bits 0, 1 and 2)")
    r.check(not (t & SH_COLOUR_LUMA_CHROMA and t & SH_COLOUR_KLT),
            "SH vectors both luma/chroma (bit 0) and KLT (bit 2)")
    r.check(sh_degree != 0 or not t & (SH_COLOUR_LUMA_CHROMA | SH_COLOUR_KLT),
            "SH vector transform (bit 0 or 2) in a file of SH degree 0")
    klt = None
    if t & SH_COLOUR_KLT:
        d = r.u8()
        if d:
            r.check(sh_degree is None or d == 3 * sh_rest_count(sh_degree),
                    f"KLT matrix of size {d} for SH degree {sh_degree} (expected {3 * sh_rest_count(sh_degree or 0)})")
            klt = r.array(np.int16, d * d).reshape(d, d)
    r.expect_end()
    return ShColour(t, klt)


def klt_to_rgb(v: np.ndarray, klt: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """float32 [n, D] stored KLT vectors -> float32 [n, D] RGB vectors (GSZ.md §8.2, bit 2),
    bit for bit: each stored value y as the integer rint(y * 2^24) (ties to even), times the
    integer matrix ``klt`` [D, D], times 2^-38, rounded once to f32.  Every product and partial
    sum is an integer below 2^53, so a BLAS matmul gives the exact value whatever its order or
    fused multiply-adds.  ``out`` may be ``v``.  A stored value at or beyond KLT_MAX_ABS (or not
    finite) raises GszFormatError."""
    x = np.asarray(v, np.float32)
    n, d = x.shape
    if klt.shape != (d, d):
        raise GszFormatError(f"KLT matrix {klt.shape[0]}x{klt.shape[1]} for SH vectors of length {d}")
    out = np.empty(x.shape, np.float32) if out is None else out
    m = klt.astype(np.float64)
    scale = 2.0 ** -(KLT_VALUE_SHIFT + KLT_MATRIX_SHIFT)
    for s in range(0, n, _KLT_ROWS):
        t = x[s:s + _KLT_ROWS].astype(np.float64)
        if not bool((np.abs(t) < KLT_MAX_ABS).all()):
            raise GszFormatError(f"KLT-coded SH value outside +-{KLT_MAX_ABS:g} (corrupt parameters)")
        t *= 2.0 ** KLT_VALUE_SHIFT
        np.rint(t, out=t)
        r = t @ m
        r *= scale
        out[s:s + _KLT_ROWS] = r
    return out


def part_klt(colour_chunk, sh_degree: int, tile_klt: np.ndarray | None) -> tuple:
    """(the KLT matrix int16 [D, D] a part's SH vectors are turned by, or None; the tile's
    matrix after this part) from its SHXF chunk (or None) and ``tile_klt``, the matrix an earlier
    layer of the tile carried (GSZ.md §8.2, 1.8: the tile's first KLT part carries it, no later
    part may)."""
    if colour_chunk is None:
        return None, tile_klt
    colour = read_sh_colour(colour_chunk, sh_degree)
    if not colour & SH_COLOUR_KLT:
        return None, tile_klt
    if colour.klt is not None:
        if tile_klt is not None:
            raise GszFormatError("SHXF chunk: a second KLT matrix in one tile (an earlier layer carried one)")
        return colour.klt, colour.klt
    if tile_klt is None:
        raise GszFormatError("SHXF chunk: KLT bit but no matrix in this or an earlier layer of the tile")
    return tile_klt, tile_klt


def turn_dc(colour_chunk, sh_dc: np.ndarray, sh_degree: int) -> bool:
    """A part's decoded DC colour float32 [M, 3] turned back to RGB in place when its SHXF
    chunk (or None) sets the DC bit (GSZ.md §8.2, 1.7); returns whether every value is finite
    (True when nothing was turned: the caller checked the stored values)."""
    if colour_chunk is None or not read_sh_colour(colour_chunk, sh_degree) & SH_COLOUR_DC:
        return True
    _luma_chroma_inverse(sh_dc[:, 0], sh_dc[:, 1], sh_dc[:, 2], sh_dc[:, 0], sh_dc[:, 1], sh_dc[:, 2])
    return bool(np.isfinite(sh_dc).all())


def _luma_chroma_inverse(a, b, c, r, g, bl) -> None:
    """The GSZ.md §8.2 inverse, bit for bit (as the native sh_assemble computes it), from the
    float32 stored components a, b, c into the float32 r, g, bl (arrays of one shape; the
    outputs may be the inputs): in float64, R = (a*S3 + b*S2) + c*S6,
    G = (a*S3 - b*S2) + c*S6, B = a*S3 - 2*(c*S6), each rounded once."""
    a = a.astype(np.float64)
    a *= _S3
    b = b.astype(np.float64)
    b *= _S2
    c = c.astype(np.float64)
    c *= _S6
    t = np.add(a, b)
    t += c
    r[...] = t
    np.subtract(a, b, out=t)
    t += c
    g[...] = t
    c += c
    np.subtract(a, c, out=t)
    bl[...] = t


def luma_chroma_to_rgb(v: np.ndarray) -> np.ndarray:
    """float32 [..., 3] stored (a, b, c) triplets -> float32 [..., 3] (R, G, B) (GSZ.md §8.2)."""
    x = np.asarray(v, np.float32)
    out = np.empty(x.shape, np.float32)
    _luma_chroma_inverse(x[..., 0], x[..., 1], x[..., 2], out[..., 0], out[..., 1], out[..., 2])
    return out


def luma_chroma_planes_to_rgb(v: np.ndarray) -> None:
    """The same inverse in place on channel-major stored vectors: float32 [D, n] (D = 3K rows,
    component-major as stored), each row a contiguous run -- the layout a ChannelSet decodes
    to, where the three planes of a coefficient are read without strides."""
    p = v.view()
    p.shape = (v.shape[0] // 3, 3, v.shape[1])       # a view or an error, never a silent copy
    _luma_chroma_inverse(p[:, 0], p[:, 1], p[:, 2], p[:, 0], p[:, 1], p[:, 2])


#: SHCL's class count byte that means "the classes of the part's RWGT chunk" (GSZ.md §8.1, 1.5)
SH_CLASSES_FROM_RWGT = 0


def read_sh_classes(data, num_kept: int, voxel_classes=None):
    """Decode an SHCL chunk: the class [P] of each kept vector, in Morton order, or the string
    "rwgt" when its classes are the kept points' RWGT classes (Q = 0, decided once the kept
    flags are known)."""
    r = Reader(data, "SHCL chunk")
    q = r.u8()
    r.check(num_kept > 0, "SH classes for a part without kept SH vectors")
    if q == SH_CLASSES_FROM_RWGT:
        r.check(voxel_classes is not None, "SH classes taken from an RWGT chunk the part does not have")
        r.expect_end()
        return "rwgt"
    r.check(2 <= q <= MAX_SH_CLASSES, f"SH class count {q} outside 2..{MAX_SH_CLASSES}")
    classes = decode_stream_single(r.blob(), num_kept)
    r.check(bool(np.all((classes >= 0) & (classes < q))), f"SH class outside 0..{q - 1}")
    r.expect_end()
    return classes


def read_sh_refine(data, num_kept: int, codebook_size: int) -> np.ndarray:
    """Decode an SHRF chunk: int64 [P] the codeword index of each stored kept vector."""
    r = Reader(data, "SHRF chunk")
    r.check(num_kept > 0, "SH codeword refinement for a part without kept SH vectors")
    r.check(codebook_size > 0, "SH codeword refinement but no SH codebook in this or an earlier layer")
    idx = decode_stream_single(r.blob(), num_kept)
    r.check(bool(np.all((idx >= 0) & (idx < codebook_size))), "SHRF chunk: codeword index out of range")
    r.expect_end()
    return idx


def read_sh(data, num_points: int, sh_degree: int, codebook: np.ndarray | None = None,
            classes_chunk=None, dest: OutputRows = FRESH, voxel_classes=None, colour_chunk=None,
            klt: np.ndarray | None = None, refine_chunk=None):
    """Decode one layer's SHVQ chunk: (sh_rest, codebook) of :func:`read_sh_checked`."""
    sh_rest, codebook, _ = read_sh_checked(data, num_points, sh_degree, codebook, classes_chunk, dest,
                                           voxel_classes, colour_chunk, klt, refine_chunk)
    return sh_rest, codebook


def read_sh_checked(data, num_points: int, sh_degree: int, codebook: np.ndarray | None = None,
                    classes_chunk=None, dest: OutputRows = FRESH, voxel_classes=None,
                    colour_chunk=None, klt: np.ndarray | None = None, refine_chunk=None):
    """Decode one layer's SHVQ chunk.

    codebook    the [D, K_cb] float64 codebook an earlier layer carried, or None
    classes_chunk  the part's SHCL chunk, or None (kept vectors stored in Morton order)
    dest        where sh_rest goes (fresh by default)
    voxel_classes  the part's RWGT classes int [M] (point order), or None
    colour_chunk   the part's SHXF chunk, or None (vectors stored as RGB)
    klt         the part's KLT matrix int16 [D, D] (:func:`part_klt`: its own or its tile's), or
                None: the vectors are turned by it (kept vectors, and the codewords where
                indices use them), a stored value beyond KLT_MAX_ABS rejected
    refine_chunk   the part's SHRF chunk, or None: the kept vectors are residuals of the
                codewords it names (added back before the colour transform)
    returns     (sh_rest float32 [M, K, 3], codebook [D, K_cb] float64 or None, finite): the
                codebook of this layer when it carries one, else the one passed in; finite:
                whether every sh_rest value is finite when the native path assembled them
                (checked as they were written), None on the NumPy path

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
    classes = None if classes_chunk is None else read_sh_classes(classes_chunk, p, voxel_classes)
    colour = SH_COLOUR_RGB if colour_chunk is None else read_sh_colour(colour_chunk) & SH_COLOUR_LUMA_CHROMA
    refine = None if refine_chunk is None else read_sh_refine(refine_chunk, p, kcb)
    if native.enabled():
        sh_rest, finite = _assemble_native(r, m, k, d, p, kcb, codebook, classes, dest, voxel_classes,
                                           colour, klt, refine)
        return sh_rest, codebook, finite
    kept = None
    if p:
        # float32: the values the float32 output keeps (half the bytes to decode into and move)
        kept = read_channel_set(r, max_length=p, shape=(d, p), name="kept SH set", dtype=np.float32)
        flags = decode_stream_single(r.blob(), m)
        r.check(bool(np.all((flags == 0) | (flags == 1))), "kept flag outside 0/1")
        kept_mask = flags.astype(bool)
        r.check(int(kept_mask.sum()) == p, f"{int(kept_mask.sum())} kept flags set, header says {p}")
        if isinstance(classes, str):
            classes = voxel_classes[kept_mask]
    idx = decode_stream_single(r.blob(), m - p)
    r.check(idx.size == 0 or (idx.min() >= 0 and idx.max() < kcb), "codeword index out of range")
    r.expect_end()
    # every Gaussian's vector as one 4*D-byte item of the float32 output: the kept vectors
    # scattered to their Gaussians a block of stored columns at a time (the transposed block
    # stays in cache; no [P, D] copy of the whole set), the codeword rows gathered
    item = np.dtype((np.void, 4 * d))
    out = dest.empty("sh_rest", (m, d))
    items = out.view(item)[:, 0]
    coded = None if idx.size == 0 else ~kept_mask if p else slice(None)
    if p:
        # the Gaussian of every stored column: kept Gaussians in Morton order, reordered by
        # class when the kept set is stored by class (class_order)
        # (None: every Gaussian kept, in Morton order -- block j0:j1 goes to rows j0:j1)
        dest = np.flatnonzero(kept_mask) if idx.size else None
        if classes is not None:
            dest = (np.arange(m) if dest is None else dest)[class_order(classes)]
        cb32 = None if refine is None else codebook.astype(np.float32)
        for j0 in range(0, p, _KEPT_BLOCK):
            j1 = min(p, j0 + _KEPT_BLOCK)
            if cb32 is not None:   # the residuals' codewords added back, in float32
                kept[:, j0:j1] += cb32[:, refine[j0:j1]]
            if colour:             # on the stored planes: contiguous runs, the block in cache
                luma_chroma_planes_to_rgb(kept[:, j0:j1])
            block = np.ascontiguousarray(kept[:, j0:j1].T, dtype=np.float32)
            if klt is not None:
                klt_to_rgb(block, klt, out=block)
            items[slice(j0, j1) if dest is None else dest[j0:j1]] = block.view(item)[:, 0]
    if coded is not None:
        if colour:       # a codeword turned to RGB once: the same values as every use of it
            cb32 = codebook.astype(np.float32)
            luma_chroma_planes_to_rgb(cb32)
            rows = np.ascontiguousarray(cb32.T)
        else:
            rows = np.ascontiguousarray(codebook.T, dtype=np.float32)
            if klt is not None:         # so too the KLT: each codeword once
                klt_to_rgb(rows, klt, out=rows)
        items[coded] = rows.view(item)[:, 0].take(idx)
    return out.reshape(m, k, 3), codebook, None


#: stored kept-SH columns transposed and scattered per step (a 45 x 8192 float32 block: 1.5 MB)
_KEPT_BLOCK = 8192


def _assemble_native(r: Reader, m: int, k: int, d: int, p: int, kcb: int, codebook, classes,
                     dest: OutputRows = FRESH, voxel_classes=None, colour: int = SH_COLOUR_RGB,
                     klt: np.ndarray | None = None, refine: np.ndarray | None = None):
    """read_sh's kept vectors, flags and indices, assembled in one C pass (same checks): the
    kept set stays uint16 symbols until that pass dequantises them into the float32 rows."""
    flags = None
    kept = np.zeros((d, 0), np.uint16)
    steps = lo = np.zeros((d, 1), np.float64)
    if p:
        kept, steps, lo = read_channel_set_symbols(r, max_length=p, shape=(d, p), name="kept SH set")
        flags = decode_stream_single(r.blob(), m)
        if isinstance(classes, str):       # RWGT classes of the kept points: the flags' checks
            sel = flags == 1               # of the NumPy path first, in its order
            r.check(bool(np.all(sel | (flags == 0))), "kept flag outside 0/1")
            r.check(int(np.count_nonzero(sel)) == p, f"{int(np.count_nonzero(sel))} kept flags set, header says {p}")
            classes = voxel_classes[sel]
    idx = decode_stream_single(r.blob(), m - p)
    r.expect_end()
    cb = np.zeros((d, 0), np.float64) if codebook is None else codebook
    out = dest.empty("sh_rest", (m, d))
    finite = native.module().sh_assemble(flags, kept, steps, lo, idx, np.ascontiguousarray(cb, dtype=np.float64),
                                         out, None if classes is None else np.ascontiguousarray(classes, np.int64),
                                         colour, None if klt is None else klt.astype(np.float64),
                                         None if refine is None else np.ascontiguousarray(refine, np.int64))
    return out.reshape(m, k, 3), bool(finite)
