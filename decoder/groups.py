"""A *quantised channel set*: C channels of equal length L, cut into B blocks, each (channel,
block) group with its own bit-width and float32 min/max, symbols entropy-coded with one rANS
model per group.  Used by the ATTR chunk (RAHT AC and scale channels) and the SHVQ chunk
(codebook and kept SH vectors).  Normative text: ``format_spec/GSZ.md`` §5.

Syntax (little-endian)::

    u8   C            number of channels (1..255)
    u32  L            channel length (0..num_gaussians)
    u16  B            blocks per channel (1..65535)
    u8   model_mode   0: one rANS model per group (model id c*B + b);
                      1: one model per (channel, bit-width) (model id c*16 + bits - 1)
    u8   bits[C*B]    group bit-widths 1..16, channel-major
    f32  mins[C*B]    group minima
    f32  maxs[C*B]    group maxima
    u64  n, byte[n]   rANS stream (ENTROPY.md §5) of C*L symbols, channel-major then element,
                      each with the model its group's model_mode gives
"""
from __future__ import annotations

import numpy as np

from . import native
from .bytesio import Reader
from .errors import GszFormatError
from .quant import dequantize_groups, split_lengths, step_sizes, validate_group_params
from .rans import RansDecoder, read_model_set


MODEL_PER_GROUP = 0
MODEL_PER_CHANNEL_BITS = 1
MODEL_MODES = (MODEL_PER_GROUP, MODEL_PER_CHANNEL_BITS)


def group_model_ids(num_channels: int, length: int, num_blocks: int, bits=None,
                    mode: int = MODEL_PER_GROUP) -> tuple[np.ndarray, int]:
    """Model id of every symbol of a [C, L] channel set, channel-major (int64 [C*L]), and the
    number of models.  Mode 0: c*B + block; mode 1: c*16 + bits[c, block] - 1 (groups of one
    channel with equal bit-widths share a model, which saves the model tables of small groups)."""
    block_of = np.repeat(np.arange(num_blocks, dtype=np.int64), split_lengths(length, num_blocks))
    table, count = group_model_table(num_channels, num_blocks, bits, mode)
    return table[:, block_of].ravel(), count


def group_model_table(num_channels: int, num_blocks: int, bits=None,
                      mode: int = MODEL_PER_GROUP) -> tuple[np.ndarray, int]:
    """Model id of every (channel, block) group (int64 [C, B]) and the number of models
    (see :func:`group_model_ids`)."""
    if mode == MODEL_PER_GROUP:
        table = np.arange(num_channels * num_blocks, dtype=np.int64).reshape(num_channels, num_blocks)
        return table, num_channels * num_blocks
    table = (np.arange(num_channels, dtype=np.int64)[:, None] * 16
             + np.asarray(bits, dtype=np.int64).reshape(num_channels, num_blocks) - 1)
    return table, num_channels * 16


def model_count(num_channels: int, num_blocks: int, mode: int) -> int:
    """The most models a channel set's stream may hold: the ids its model mode can name
    (GSZ.md §5; a stream with more only costs the decoder work)."""
    return num_channels * (num_blocks if mode == MODEL_PER_GROUP else 16)


def _read_header(r: Reader, max_length: int, shape: tuple | None, name: str):
    """A channel set's fields up to its rANS stream, checked (see :func:`read_channel_set`):
    (C, L, B, model_mode, bits, mins, maxs, stream blob)."""
    c = r.u8()
    length = r.u32()
    b = r.u16()
    r.check(c >= 1, f"{name} with zero channels")
    if shape is not None:
        r.check(c == shape[0], f"{name} has {c} channels, expected {shape[0]}")
    r.check(length <= max_length, f"{name}: channel length {length} exceeds the point count {max_length}")
    if shape is not None:
        r.check(length == shape[1], f"{name} has channel length {length}, expected {shape[1]}")
    r.check(b >= 1, f"{name} with zero blocks")
    mode = r.u8()
    r.check(mode in MODEL_MODES, f"unknown model mode {mode}")
    bits = r.array(np.uint8, c * b).reshape(c, b)
    mins = r.array(np.float32, c * b).reshape(c, b)
    maxs = r.array(np.float32, c * b).reshape(c, b)
    validate_group_params(mins, maxs, bits)
    return c, length, b, mode, bits, mins, maxs, r.blob()


def read_channel_set(r: Reader, *, max_length: int, shape: tuple | None = None,
                     name: str = "channel set", dtype=np.float64) -> np.ndarray:
    """Parse one quantised channel set from ``r``; returns the dequantised values [C, L]
    (float64, or ``dtype``).

    shape   the (C, L) its use prescribes (GSZ.md §5): C, then L's bound ``max_length``, then
            L are checked as soon as they are read, before anything is allocated or decoded
            (a hostile C or L would otherwise cost C * L symbols of work first)
    dtype   np.float32: the float64 values rounded to float32 (what a float32 field keeps)"""
    c, length, b, mode, bits, mins, maxs, blob = _read_header(r, max_length, shape, name)
    if native.enabled():
        return _decode_native(blob, c, length, b, bits, mins, maxs, mode).astype(dtype, copy=False)
    # decode_stream(blob, group_model_ids(...)) one group (a run of one model) at a time
    lengths = split_lengths(length, b)
    models, pos = read_model_set(blob, 0, max_models=model_count(c, b, mode), num_symbols=c * length)
    dec = RansDecoder(memoryview(blob)[pos:], c * length, models, use_native=False)
    table, _ = group_model_table(c, b, bits, mode)
    run_models, run_lengths = table.ravel(), np.tile(lengths, c)
    qmax = (np.int64(1) << bits.astype(np.int64)) - 1
    if dec.runs_within(run_models, run_lengths, qmax):
        # no symbol can fail dequantize_groups' checks: every group's symbols come out of its
        # model's value table mapped to m_g + s_g * k (the same float64 products and sums),
        # no [C, L] integer array and no second pass over it
        lo = np.asarray(mins, dtype=np.float32).astype(np.float64)
        out = dec.decode_runs(run_models, run_lengths, step_sizes(mins, maxs, bits).ravel(),
                              lo.ravel(), dtype).reshape(c, length)
        dec.finish()
        return out
    symbols = dec.decode_runs(run_models, run_lengths).reshape(c, length)
    dec.finish()
    return dequantize_groups(symbols, mins, maxs, bits, lengths).astype(dtype, copy=False)


def _native_decoder(blob, c: int, length: int, b: int, bits, mins, maxs, mode: int):
    """The native decoder of a channel set's stream, its model table [C*B] and the groups'
    (steps, lo, qmax) [C*B] (float64, float64, int64)."""
    models, pos = read_model_set(blob, 0, max_models=model_count(c, b, mode), num_symbols=c * length)
    dec = RansDecoder(memoryview(blob)[pos:], c * length, models, use_native=True)
    bits = np.asarray(bits, dtype=np.int64)
    if mode == MODEL_PER_GROUP:
        table = np.arange(c * b, dtype=np.int64)
    else:
        table = (np.arange(c, dtype=np.int64)[:, None] * 16 + bits - 1).ravel()
    steps = np.ascontiguousarray(step_sizes(mins, maxs, bits), dtype=np.float64).ravel()
    lo = np.asarray(mins, dtype=np.float32).astype(np.float64).ravel()
    qmax = ((np.int64(1) << bits) - 1).ravel()
    return dec, table, (steps, lo, qmax)


def _decode_native(blob, c: int, length: int, b: int, bits, mins, maxs, mode: int) -> np.ndarray:
    """read_channel_set's decode and dequantisation in one C pass (no per-symbol model-id or
    symbol arrays); same model ids, checks and float64 arithmetic as the NumPy path."""
    dec, table, (steps, lo, qmax) = _native_decoder(blob, c, length, b, bits, mins, maxs, mode)
    out = np.empty((c, length), dtype=np.float64)
    dec.decode_blocks(table, c, length, b, out, steps, lo, qmax)
    dec.finish()
    return out


def read_channel_set_symbols(r: Reader, *, max_length: int, shape: tuple | None = None,
                             name: str = "channel set"):
    """Native only: :func:`read_channel_set` without the dequantisation, for a caller that
    dequantises where it copies the values anyway (a float64 [C, L] set of 1 M kept SH vectors
    is 390 MB of fresh pages).  Returns (symbols uint16 [C, L], steps float64 [C, B], lo
    float64 [C, B]): the set's values are lo + step * k per (channel, block), as
    ``dequantize_groups`` computes them; symbols are checked against 2^q - 1."""
    c, length, b, mode, bits, mins, maxs, blob = _read_header(r, max_length, shape, name)
    dec, table, (steps, lo, qmax) = _native_decoder(blob, c, length, b, bits, mins, maxs, mode)
    out = np.empty((c, length), dtype=np.uint16)
    dec.decode_blocks(table, c, length, b, out, qmax=qmax)
    dec.finish()
    return out, steps.reshape(c, b), lo.reshape(c, b)


def blocks_for(length: int, requested: int) -> int:
    """Blocks actually used for a channel of ``length``: never more blocks than elements
    (empty groups would only cost metadata), at least 1."""
    if requested < 1 or requested > 65535:
        raise GszFormatError(f"blocks per channel must be 1..65535, got {requested}")
    return max(1, min(int(requested), int(length)))
