"""A *quantised channel set*: C channels of equal length L, cut into B blocks, each (channel,
block) group with its own bit-width and float32 min/max, symbols entropy-coded with one rANS
model per group.  Used by the ATTR chunk (RAHT AC and scale channels) and the SHVQ chunk
(codebook and kept SH vectors).  Normative text: ``format_spec/GSZ.md`` §5.

Syntax (little-endian)::

    u8   C            number of channels (1..255)
    u32  L            channel length (0..num_gaussians)
    u16  B            blocks per channel (1..65535)
    u8   bits[C*B]    group bit-widths 1..16, channel-major
    f32  mins[C*B]    group minima
    f32  maxs[C*B]    group maxima
    u64  n, byte[n]   rANS stream (ENTROPY.md §5) of C*L symbols, channel-major then element;
                      the symbol of channel c, element e uses model c*B + block(e)
"""
from __future__ import annotations

import numpy as np

from .bytesio import Reader
from .quant import dequantize_groups, split_lengths, validate_group_params
from .rans import decode_stream
from .errors import GszFormatError


def group_model_ids(num_channels: int, length: int, num_blocks: int) -> np.ndarray:
    """Model id (c*B + block) of every symbol of a [C, L] channel set, channel-major (int64 [C*L])."""
    per_channel = np.repeat(np.arange(num_blocks, dtype=np.int64), split_lengths(length, num_blocks))
    return (np.arange(num_channels, dtype=np.int64)[:, None] * num_blocks + per_channel[None, :]).ravel()


def read_channel_set(r: Reader, *, max_length: int) -> np.ndarray:
    """Parse one quantised channel set from ``r``; returns the dequantised float64 [C, L]."""
    c = r.u8()
    length = r.u32()
    b = r.u16()
    r.check(c >= 1, "channel set with zero channels")
    r.check(b >= 1, "channel set with zero blocks")
    r.check(length <= max_length, f"channel length {length} exceeds the point count {max_length}")
    bits = r.array(np.uint8, c * b).reshape(c, b)
    mins = r.array(np.float32, c * b).reshape(c, b)
    maxs = r.array(np.float32, c * b).reshape(c, b)
    validate_group_params(mins, maxs, bits)
    blob = r.blob()
    symbols = decode_stream(blob, group_model_ids(c, length, b)).reshape(c, length)
    return dequantize_groups(symbols, mins, maxs, bits, split_lengths(length, b))


def blocks_for(length: int, requested: int) -> int:
    """Blocks actually used for a channel of ``length``: never more blocks than elements
    (empty groups would only cost metadata), at least 1."""
    if requested < 1 or requested > 65535:
        raise GszFormatError(f"blocks per channel must be 1..65535, got {requested}")
    return max(1, min(int(requested), int(length)))
