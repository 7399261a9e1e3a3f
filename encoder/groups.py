"""Writer of a quantised channel set (syntax: ``gsz.decoder.groups``)."""
from __future__ import annotations

import numpy as np

from ..decoder.bytesio import Writer
from ..decoder.groups import (MODEL_MODES, MODEL_PER_CHANNEL_BITS, MODEL_PER_GROUP,
                                blocks_for, group_model_ids)
from ..decoder.quant import dequantize_groups, split_lengths
from .rans import encode_stream_pair


def write_channel_set(x: np.ndarray, bits, num_blocks: int) -> tuple[bytes, np.ndarray]:
    """Quantise x [C, L] (float) group-wise and serialise it.

    bits: int (uniform) or int array [C, B] with B = blocks_for(L, num_blocks).
    Returns (bytes, dequantised float64 [C, L] exactly as the decoder will reconstruct it).
    """
    from ..kernels.quantize import quantize_groups   # torch: not needed to build the CLI's parser
    x = np.ascontiguousarray(x, dtype=np.float32)
    c, length = x.shape
    b = blocks_for(length, num_blocks)
    bits_arr = np.broadcast_to(np.asarray(bits, dtype=np.int64), (c, b)).copy()
    if length:
        symbols, mins, maxs = quantize_groups(x, b, bits_arr)
    else:
        symbols = np.zeros((c, 0), np.int32)
        mins = np.zeros((c, b), np.float32)
        maxs = np.zeros((c, b), np.float32)
    # Both model layouts are coded and the smaller kept (the first on a tie): per-group tables
    # win for large groups and low bit-widths, shared per-(channel, bits) tables for small
    # groups at high bit-widths.  The per-(channel, bits) histograms are merged from the
    # per-group ones (group c*B + k -> model c*16 + bits[c, k] - 1, as group_model_ids).
    assert MODEL_MODES == (MODEL_PER_GROUP, MODEL_PER_CHANNEL_BITS)
    mids, count = group_model_ids(c, length, b, bits_arr, MODEL_PER_GROUP)
    merge = (np.arange(c, dtype=np.int64)[:, None] * 16 + bits_arr - 1).ravel()
    streams = encode_stream_pair(symbols.ravel(), mids, count, merge, c * 16)
    best = (MODEL_PER_CHANNEL_BITS, streams[1]) if len(streams[1]) < len(streams[0]) \
        else (MODEL_PER_GROUP, streams[0])
    w = Writer()
    w.u8(c).u32(length).u16(b).u8(best[0])
    w.array(bits_arr, np.uint8).array(mins, np.float32).array(maxs, np.float32)
    w.blob(best[1])
    recon = dequantize_groups(symbols, mins, maxs, bits_arr, split_lengths(length, b))
    return w.getvalue(), recon
