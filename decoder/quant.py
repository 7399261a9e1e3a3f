"""Group-wise (channel x block) min-max quantisation: normative parameters and dequantisation.

Normative text: ``format_spec/TRANSFORMS.md`` section 3.  A channel of length L is cut into B
contiguous blocks by :func:`split_lengths`; every (channel, block) group g carries a bit-width
q_g in 1..16 and a float32 minimum m_g and maximum M_g (the stored values).  With Q = 2^q - 1:

    s_g   = (float64(M_g) - float64(m_g)) / Q      if M_g > m_g, else 1.0     (float64)
    x_hat = float64(m_g) + s_g * k                                            k in 0..Q

The encoder (``gsz.kernels.quantize``) derives symbols with the SAME s_g:

    k = clamp(rint((float64(x) - float64(m_g)) / s_g), 0, Q)     (rint = round half to even)

numpy only.
"""
from __future__ import annotations

import numpy as np

from .errors import GszFormatError

MIN_BITS = 1
MAX_BITS = 16


def split_lengths(length: int, num_blocks: int) -> np.ndarray:
    """Block lengths of a channel of ``length`` elements cut into ``num_blocks`` contiguous blocks.

    The first (length mod B) blocks get floor(length / B) + 1 elements, the rest floor(length / B).
    Blocks may be empty when B > length.  Returns int64 [B] summing to ``length``.
    """
    length, num_blocks = int(length), int(num_blocks)
    if length < 0 or num_blocks < 1:
        raise GszFormatError(f"bad block split: length {length}, {num_blocks} blocks")
    base, extra = divmod(length, num_blocks)
    out = np.full(num_blocks, base, dtype=np.int64)
    out[:extra] += 1
    return out


def step_sizes(mins: np.ndarray, maxs: np.ndarray, bits: np.ndarray) -> np.ndarray:
    """Quantiser step s per group (float64, same shape as the inputs) -- the normative formula.

    mins, maxs: the STORED float32 values (other float dtypes are rounded to float32 first so the
    encoder cannot accidentally use a value the decoder never sees).  bits: integers 1..16.
    """
    m = np.asarray(mins, dtype=np.float32).astype(np.float64)
    big = np.asarray(maxs, dtype=np.float32).astype(np.float64)
    levels = np.ldexp(1.0, np.asarray(bits, dtype=np.int64)) - 1.0
    span = big - m
    return np.where(span > 0, span / levels, 1.0)


def validate_group_params(mins: np.ndarray, maxs: np.ndarray, bits: np.ndarray) -> None:
    """Raise GszFormatError unless shapes agree, values are finite, max >= min and bits in 1..16."""
    mins, maxs, bits = np.asarray(mins), np.asarray(maxs), np.asarray(bits)
    if not (mins.shape == maxs.shape == bits.shape):
        raise GszFormatError(f"quantiser parameter shapes differ: {mins.shape}, {maxs.shape}, {bits.shape}")
    if not (np.all(np.isfinite(mins)) and np.all(np.isfinite(maxs))):
        raise GszFormatError("quantiser min/max contains a non-finite value")
    if np.any(maxs < mins):
        raise GszFormatError("quantiser group has max < min")
    if bits.size and (bits.min() < MIN_BITS or bits.max() > MAX_BITS):
        raise GszFormatError(f"quantiser bit-width outside {MIN_BITS}..{MAX_BITS}")


def dequantize_groups(symbols: np.ndarray, mins: np.ndarray, maxs: np.ndarray, bits: np.ndarray,
                      lengths: np.ndarray) -> np.ndarray:
    """Dequantise all channels.

    symbols: integer [C, L] (k values, channel-major).  mins, maxs: float32 [C, B].
    bits: integer [C, B] in 1..16.  lengths: int [B] block lengths (normally split_lengths(L, B)).
    Returns float64 [C, L] = m_g + s_g * k.
    Raises GszFormatError on inconsistent shapes, bad parameters or a symbol > 2^q - 1.
    """
    sym = np.asarray(symbols)
    lengths = np.asarray(lengths, dtype=np.int64).reshape(-1)
    validate_group_params(mins, maxs, bits)
    if sym.ndim != 2 or np.asarray(mins).ndim != 2:
        raise GszFormatError(f"dequantize_groups: symbols must be [C, L] and params [C, B], got "
                             f"{sym.shape} and {np.asarray(mins).shape}")
    c, length = sym.shape
    if np.asarray(mins).shape != (c, lengths.shape[0]) or lengths.min(initial=0) < 0 or lengths.sum() != length:
        raise GszFormatError(f"dequantize_groups: params {np.asarray(mins).shape} / block lengths "
                             f"(sum {int(lengths.sum())}) do not fit symbols {sym.shape}")
    if not np.issubdtype(sym.dtype, np.integer):
        raise GszFormatError(f"symbols must be integers, got {sym.dtype}")
    steps = step_sizes(mins, maxs, bits)
    lo = np.asarray(mins, dtype=np.float32).astype(np.float64)
    if length == 0:
        return np.zeros((c, 0), dtype=np.float64)
    if sym.min() < 0:
        raise GszFormatError("negative quantisation symbol")
    # Per-group maximum symbol, checked against 2^q - 1 (reduceat needs non-empty groups).
    nonempty = lengths > 0
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])[nonempty]
    group_max = np.maximum.reduceat(sym, starts, axis=1)
    qmax = (np.left_shift(1, np.asarray(bits, dtype=np.int64)) - 1)[:, nonempty]
    if np.any(group_max > qmax):
        raise GszFormatError("quantisation symbol exceeds its group's 2^q - 1")
    if lengths.shape[0] <= 64 or length >= 256 * lengths.shape[0]:
        # few or long blocks: each block's step and minimum broadcast over its columns (the
        # same products and sums as below, without two [C, L] arrays of repeated parameters)
        out = np.empty((c, length), dtype=np.float64)
        ends = np.cumsum(lengths)
        for blk, (s, e) in enumerate(zip((ends - lengths).tolist(), ends.tolist())):
            if e > s:
                np.multiply(steps[:, blk:blk + 1], sym[:, s:e], out=out[:, s:e])
                out[:, s:e] += lo[:, blk:blk + 1]
        return out
    out = np.repeat(steps, lengths, axis=1)
    out *= sym
    out += np.repeat(lo, lengths, axis=1)
    return out
