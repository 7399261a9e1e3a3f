"""Writer of a quantised channel set (syntax: ``gsz.decoder.groups``)."""
from __future__ import annotations

import numpy as np

from ..decoder.bytesio import Writer
from ..decoder.groups import (MODEL_MODES, MODEL_PER_CHANNEL_BITS, MODEL_PER_GROUP,
                                blocks_for)
from ..decoder.quant import dequantize_groups, split_lengths
from .rans import encode_group_streams


#: Channels quantised at a time where only a channel set's bytes are wanted (no [C, L] symbols:
#: 180 MB for 45 SH components of a part of 2^20 kept vectors)
QUANT_CHANNELS = 8


def write_channel_set(x: np.ndarray, bits, num_blocks: int,
                      recon_dtype=np.float64) -> tuple[bytes, np.ndarray]:
    """Quantise x [C, L] (float) group-wise and serialise it.

    bits: int (uniform) or int array [C, B] with B = blocks_for(L, num_blocks); width 0 makes
    a group constant (:func:`constant_groups`).
    Returns (bytes, dequantised [C, L] exactly as the decoder will reconstruct it), float64 or
    ``recon_dtype`` (float32: the float64 values rounded, made a few channels at a time, for
    callers that store float32 anyway: half the memory at 1.2 M kept SH vectors; None: no
    reconstruction, None instead, for callers that want the bytes only -- their symbols are then
    made QUANT_CHANNELS channels at a time, as the coder reads them).
    """
    if recon_dtype is None:
        symbols = _ChannelSymbols(x, bits, num_blocks)
        bits_arr = symbols.bits
    else:
        symbols, mins, maxs, bits_arr = quantize_channel_set(x, bits, num_blocks)
    c, length = symbols.shape
    b = bits_arr.shape[1]
    # Both model layouts are coded and the smaller kept (the first on a tie): per-group tables
    # win for large groups and low bit-widths, shared per-(channel, bits) tables for small
    # groups at high bit-widths.  The per-(channel, bits) histograms are merged from the
    # per-group ones (group c*B + k -> model c*16 + bits[c, k] - 1, as group_model_ids).
    assert MODEL_MODES == (MODEL_PER_GROUP, MODEL_PER_CHANNEL_BITS)
    merge = (np.arange(c, dtype=np.int64)[:, None] * 16 + bits_arr - 1).ravel()
    streams = encode_group_streams(symbols, split_lengths(length, b), merge, c * 16)
    if recon_dtype is None:
        mins, maxs = symbols.params()
    best = (MODEL_PER_CHANNEL_BITS, streams[1]) if len(streams[1]) < len(streams[0]) \
        else (MODEL_PER_GROUP, streams[0])
    w = Writer()
    w.u8(c).u32(length).u16(b).u8(best[0])
    w.array(bits_arr, np.uint8).array(mins, np.float32).array(maxs, np.float32)
    w.blob(best[1])
    if recon_dtype is None:
        return w.getvalue(), None
    return w.getvalue(), _dequantized(symbols, mins, maxs, bits_arr, split_lengths(length, b),
                                      np.dtype(recon_dtype))


class _ChannelSymbols:
    """:func:`quantize_channel_set`'s symbols of x [C, L] by channel (``[c]``), quantised
    QUANT_CHANNELS channels at a time as they are read (groups are per channel: the same
    symbols and parameters); ``params()``: (mins, maxs) once every channel was read."""

    def __init__(self, x: np.ndarray, bits, num_blocks: int):
        x = np.asarray(x)
        self.x, self.num_blocks = x, num_blocks
        c, length = x.shape
        self.shape = (c, length)
        self.bits = _group_widths(bits, c, blocks_for(length, num_blocks))
        self._bits_in = np.broadcast_to(np.asarray(bits, dtype=np.int64), self.bits.shape)
        self._at, self._rows = None, None
        self._mins, self._maxs = {}, {}

    def __getitem__(self, ci: int) -> np.ndarray:
        a = ci - ci % QUANT_CHANNELS
        if self._at != a:
            self._rows = None               # the chunk before goes first
            sym, mn, mx, _ = quantize_channel_set(self.x[a:a + QUANT_CHANNELS],
                                                  self._bits_in[a:a + QUANT_CHANNELS], self.num_blocks)
            self._at, self._rows = a, sym
            self._mins[a], self._maxs[a] = mn, mx
        return self._rows[ci - a]

    def params(self) -> tuple[np.ndarray, np.ndarray]:
        c = self.shape[0]
        for a in range(0, c, QUANT_CHANNELS):
            if a not in self._mins:
                self[a]
        self._rows = None
        keys = range(0, c, QUANT_CHANNELS)
        b = self.bits.shape[1]
        if not c:
            return np.zeros((0, b), np.float32), np.zeros((0, b), np.float32)
        return (np.concatenate([self._mins[a] for a in keys]), np.concatenate([self._maxs[a] for a in keys]))


def _group_widths(bits, c: int, b: int) -> np.ndarray:
    """int64 [C, B] widths as coded: width 0 (a constant group) is stored as 1 bit."""
    bits_arr = np.broadcast_to(np.asarray(bits, dtype=np.int64), (c, b)).copy()
    bits_arr[bits_arr == 0] = 1
    return bits_arr


def quantize_channel_set(x: np.ndarray, bits, num_blocks: int):
    """The symbols and group parameters :func:`write_channel_set` codes x [C, L] with:
    (symbols int32 [C, L], mins float32 [C, B], maxs float32 [C, B], bits int64 [C, B]) with
    B = blocks_for(L, num_blocks), width-0 groups made constant (stored as 1 bit); they
    dequantise (``dequantize_groups(..., split_lengths(L, B))``) to its reconstruction."""
    from ..kernels.quantize import quantize_groups   # torch: not needed to build the CLI's parser
    x = np.ascontiguousarray(x, dtype=np.float32)
    c, length = x.shape
    b = blocks_for(length, num_blocks)
    const = np.broadcast_to(np.asarray(bits, dtype=np.int64), (c, b)) == 0
    bits_arr = _group_widths(bits, c, b)
    if length:
        symbols, mins, maxs = quantize_groups(x, b, bits_arr)
        if const.any():
            constant_groups(x, b, const, symbols, mins, maxs)
    else:
        symbols = np.zeros((c, 0), np.int32)
        mins = np.zeros((c, b), np.float32)
        maxs = np.zeros((c, b), np.float32)
    return symbols, mins, maxs, bits_arr


def _dequantized(symbols, mins, maxs, bits, lens, dtype: np.dtype, step: int = 8) -> np.ndarray:
    """dequantize_groups(...) as ``dtype``, ``step`` channels at a time when it is not float64."""
    if dtype == np.float64:
        return dequantize_groups(symbols, mins, maxs, bits, lens)
    out = np.empty(symbols.shape, dtype)
    for a in range(0, symbols.shape[0], step):
        out[a:a + step] = dequantize_groups(symbols[a:a + step], mins[a:a + step],
                                            maxs[a:a + step], bits[a:a + step], lens)
    return out


def group_means(x: np.ndarray, num_blocks: int) -> np.ndarray:
    """float32 [C, B]: each group's mean (0 for an empty block), the value of a constant group."""
    lens = split_lengths(x.shape[1], num_blocks)
    starts = np.concatenate([[0], np.cumsum(lens)[:-1]])
    sums = np.add.reduceat(np.asarray(x, np.float64), starts, axis=1) if x.shape[1] else np.zeros((x.shape[0], num_blocks))
    sums[:, lens == 0] = 0.0        # reduceat repeats the next element for an empty block
    return (sums / np.maximum(lens, 1)).astype(np.float32)


def constant_groups(x, num_blocks: int, const: np.ndarray, symbols, mins, maxs) -> None:
    """Make the groups where ``const`` [C, B] a constant, in place: min = max = the group mean
    and every symbol 0, which any conforming decoder reconstructs as the mean (GSZ.md §5: the
    step is 0) and which costs the entropy coder almost nothing.  Low-importance SH groups would
    otherwise pay a 1-bit code whose two levels, min and max, sit far from their values."""
    means = group_means(x, num_blocks)
    lens = split_lengths(x.shape[1], num_blocks)
    ends = np.cumsum(lens)
    for ci, bi in zip(*np.nonzero(const)):
        symbols[ci, ends[bi] - lens[bi]:ends[bi]] = 0
        mins[ci, bi] = maxs[ci, bi] = means[ci, bi]


def constant_sse(x: np.ndarray, blocks: int) -> np.ndarray:
    """[C, B] SSE of each group of ``x`` [C, L] against its (float32) mean, the constant
    group's error (width 0)."""
    lens = split_lengths(x.shape[1], blocks)
    mean = np.repeat(group_means(x, blocks).astype(np.float64), lens, axis=1)
    d = x.astype(np.float64) - mean
    starts = np.concatenate([[0], np.cumsum(lens)[:-1]])
    out = np.add.reduceat(d * d, starts, axis=1) if x.shape[1] else np.zeros((x.shape[0], blocks))
    out[:, lens == 0] = 0.0
    return out


#: channels per step of vector_tables
TABLE_ROWS = 6


def vector_tables(x: np.ndarray, blocks: int, min_bits: int) -> tuple:
    """(loss [D, B, 16] SSE, rate [D, B, 16] bits with +inf below ``min_bits``) of the groups
    (one channel, one of ``blocks`` blocks) of vectors ``x`` float32 [D, n] coded group-wise
    at 1..16 bits.  With ``min_bits`` = 1, column 0 is the constant group (width 0,
    :func:`constant_sse`), not 1 bit: a 1-bit code of values around zero reconstructs them
    at its extremes."""
    from ..kernels.quantize import quantize_all_bits   # torch: not needed to build the CLI's parser
    from .rate import rate_matrix
    # a few channels at a time: every group is one (channel, block), so the values are the
    # same, without [D, P] float64 temporaries per width (1.7 GB at 720 k vectors)
    rows = range(0, x.shape[0], TABLE_ROWS)
    loss = np.concatenate([quantize_all_bits(x[r:r + TABLE_ROWS], blocks)[3] for r in rows])
    rate = np.concatenate([rate_matrix(x[r:r + TABLE_ROWS], blocks, (int(min_bits), 16)) for r in rows])
    if min_bits <= 1:
        loss[:, :, 0] = np.concatenate([constant_sse(x[r:r + TABLE_ROWS], blocks) for r in rows])
        rate[:, :, 0] = 0.0
    return loss, rate
