"""Rate model: estimated coded size (bits) of every quantisation group at every bit-width.

    rate_matrix(x [C, L] float32, num_blocks) -> float64 [C, B, 16]

rate[c, b, q-1] predicts what the group (c, b) costs in the rANS stream of a channel set written
with one model per group (``gsz.encoder.groups``, model_mode 0) when quantised at q bits by the
normative quantiser (``gsz.decoder.quant``: float32 min/max, float64 step, rint) -- the payload
and the group's share of the model table and lane states.  The sum over groups of a chosen
allocation plus :func:`channel_set_overhead_bits` predicts the channel set's size; the writer
also tries shared per-(channel, bits) models and keeps the smaller stream, so the prediction is
an upper bound there (equal in practice wherever groups are large).

How (one sort per channel, no per-q sorting): the quantiser is monotone in x, so sorting every
block's values once makes the symbols of every bit-width sorted too; distinct values and their
counts are then run lengths (a compare + flatnonzero per bit-width).  Per (group, q):

* payload of an exact COARSE table (h = 0): sum over distinct values v of
  c_v * (n - log2(1 + (2^n - K) c_v / N)), the coder's own frequency normalisation
  (``gsz.decoder.rans.normalise_weights``: +1 per present value, the rest proportional), with its
  precision rule n = min(16, max(ceil log2 K, ceil log2 N));
* table bits = a linear predictor in the table's serialised content (present values, their gaps),
  fitted to real ``encode_stream`` sizes (zstd-19 tables) on real scenes (see TABLE_COEFFS);
* binned COARSE tables (bin width 2^h, h = 1..5; what the fitter picks at mid bit-widths): bins
  approximated by the (q - h)-bit grid's distinct values (their counts and table features), the
  payload with the coder's normalisation at this q's precision where every value of a present
  bin gets the +1 (K_v = bins * 2^h), times BINNED_FACTOR;
* LAPLACE (two-sided geometric around the mode, ratios from each side's mean distance, allowed
  where span + 1 <= 2^n): exact per-run cross-entropy under the coder's normalisation;
* SINGLE models (one distinct value): no payload, a few table bits;
* the cheapest candidate per (group, q) is taken (the fitter's own choice, up to its proxies);
* lane final states: 32 bits per min(N / 1024, payload / 8192) symbols (``choose_lanes``).

Speed: the work is chunked per channel and block part (one NumPy sort each); the loop over
bit-widths runs in C where the accelerator is built (``_native.rate_group_stats``, the same
arithmetic: C=10, B=80, L=542k, bits 1..16 in ~0.3 s against ~0.85 s for the NumPy reference,
which stays the fallback, ``GSZ_NATIVE=0``).
"""
from __future__ import annotations

import math

import numpy as np

from ..decoder import native
from ..decoder.errors import GszError
from ..decoder.quant import MAX_BITS, MIN_BITS
from ..decoder.rans import MAX_PRECISION
from ..decoder.threads import thread_map
from .rans import (COARSE_BINSHIFTS, ModelSet, _coder_tables, _value_index, choose_lanes,
                   fit_model_set, write_model_set)

__all__ = ["rate_matrix", "rate_from_stats", "group_stats", "channel_set_overhead_bits",
           "RateModelError", "TABLE_COEFFS"]

MAX_BINSHIFT = max(COARSE_BINSHIFTS)   # the coder's largest bin shift (csrc/stages.h RATE_SHIFTS mirrors it)
# Table bits of one group's model, linear in its serialised content: COARSE = coarse + values * K
# + gap_bits * sum log2(1 + value step) + long_gaps * #(steps > 128) (+ level_bits * level
# steps, fitted to 0); SINGLE and LAPLACE a constant.  Fitted (non-negative least squares on the
# relative error of the whole stream, iterated with the candidate choice) to encode_stream sizes
# of the RAHT-AC and scale sets of houseplant (20k sample, 113k), jug (12k sample, 101k) and
# tiny_graphdeco (8k) at 16 and 80 blocks, uniform and random allocations of mean <= 10 bits:
# rms error 1.6 % over 152 streams (max 8 %, on groups of ~150 symbols at ~10 bits).
TABLE_COEFFS = {"coarse": 2.06, "values": 3.96, "gap_bits": 0.78, "level_bits": 0.0,
                "long_gaps": 2.78, "single": 0.0, "laplace": 27.0}
PAYLOAD_FACTOR = 1.002       # COARSE level quantisation of the counts (measured ~0.1-0.3 %)
# the (q - h)-bit grid's histogram is smoother than the q-bit one binned by 2^h (different
# rounding), so its payload is optimistic; measured on jug/houseplant AC and scales at 3-6 bits
BINNED_FACTOR = 1.03
LANE_STATE_BITS = 32.0


class RateModelError(GszError, ValueError):
    """Bad input to the rate model."""


def _check(x, num_blocks, bit_range):
    x = np.asarray(x)
    if x.ndim != 2:
        raise RateModelError(f"rate_matrix needs x [C, L], got shape {x.shape}")
    if not np.issubdtype(x.dtype, np.floating):
        raise RateModelError(f"rate_matrix needs floating-point x, got {x.dtype}")
    x = np.ascontiguousarray(x, dtype=np.float32)
    # a channel at a time: a whole-array mask is 1 byte a value (~100 MB at 6 M SH vectors)
    if not all(np.isfinite(row).all() for row in x):
        raise RateModelError("rate_matrix input contains NaN or infinity")
    if not isinstance(num_blocks, (int, np.integer)) or int(num_blocks) < 1:
        raise RateModelError(f"num_blocks must be a positive integer, got {num_blocks!r}")
    lo, hi = int(bit_range[0]), int(bit_range[1])
    if not (MIN_BITS <= lo <= hi <= MAX_BITS):
        raise RateModelError(f"bit_range must satisfy {MIN_BITS} <= lo <= hi <= {MAX_BITS}, got {bit_range}")
    return x, int(num_blocks), lo, hi


def _parts(length: int, num_blocks: int):
    """(first block, number of blocks, block length, element offset) of the <= 2 regular parts
    of split_lengths(length, num_blocks) (gsz.decoder.quant): extra blocks of base+1, then base."""
    base, extra = divmod(length, num_blocks)
    out = []
    if extra:
        out.append((0, extra, base + 1, 0))
    if base and num_blocks - extra:
        out.append((extra, num_blocks - extra, base, extra * (base + 1)))
    return out


def _precision(k: np.ndarray, n: np.ndarray) -> np.ndarray:
    """The fitter's precision rule n = min(16, max(ceil log2 K, ceil log2 N, 1))."""
    ck = np.ceil(np.log2(np.maximum(k, 1)))
    cn = np.ceil(np.log2(np.maximum(n, 1)))
    return np.clip(np.maximum(ck, cn), 1, MAX_PRECISION)


def group_stats(x, num_blocks: int, bit_range: tuple[int, int] = (MIN_BITS, MAX_BITS)) -> dict:
    """Per (channel, block, bit-width) statistics of the quantised symbols (float64 [C, B, 16]
    each, zeros outside bit_range and for empty groups):

    n        symbols in the group
    k        distinct symbols
    payload  ideal coded bits under an exact per-value table (coder's normalisation)
    gap      sum over consecutive distinct values of log2(1 + value step)
    gap2     number of value steps > 128 (two-byte varints in the serialised table)
    level    sum over consecutive distinct values of log2(1 + |round(2 log2(c_i / c_{i-1}))|)
             (COARSE level codes step twice per octave of count at the default level group)

    The per-part loop runs in C (``_native.rate_group_stats``) when the accelerator is enabled
    (``gsz.decoder.native``), else in NumPy (:func:`_part_stats_numpy`, the reference); they
    agree to ~1e-15 relative (NumPy's SIMD log2/pow differ from libm's in the last bit).
    """
    x, nb_total, lo, hi = _check(x, num_blocks, bit_range)
    c_count, length = x.shape
    shape = (c_count, nb_total, MAX_BITS)
    out = {key: np.zeros(shape) for key in ("n", "k", "payload", "gap", "gap2", "level", "laplace")}
    out["binned"] = np.full(shape + (MAX_BINSHIFT,), np.inf)
    if length == 0:
        return out
    # widths up to 5 below the range too: the binned candidates at q use the q - h grids
    q_first = max(MIN_BITS, lo - MAX_BINSHIFT)
    parts = _parts(length, nb_total)
    use_native = native.enabled()
    # log2 of run lengths 0..blen and of the value steps + 1 (lookup instead of a log per run)
    tab_len = max(parts[0][2], 1 << MAX_BITS) + 1          # parts[0] has the longest blocks
    log_tab = np.log2(np.maximum(np.arange(tab_len, dtype=np.float64), 1.0))
    jobs = [(part, ci) for part in parts for ci in range(c_count)]

    def one(j: int) -> None:
        # each (part, channel) writes only its own slices of out: the same on any thread
        (b0, nb, blen, off), ci = jobs[j]
        srt = np.sort(x[ci, off:off + nb * blen].reshape(nb, blen), axis=1)
        out["n"][ci, b0:b0 + nb, q_first - 1:hi] = blen
        dst = {key: out[key][ci, b0:b0 + nb] for key in _STAT_KEYS}
        if use_native:
            _part_stats_native(srt, q_first, hi, log_tab, dst)
        else:
            _part_stats_numpy(srt, q_first, hi, log_tab, dst)
    thread_map(one, len(jobs))
    return out


_STAT_KEYS = ("k", "payload", "gap", "gap2", "level", "laplace", "binned")


def _part_stats_native(srt, q_first, hi, log_tab, dst):
    """:func:`_part_stats_numpy` in C (the out views are C-contiguous slices of group_stats'
    arrays, written in place)."""
    native.module().rate_group_stats(srt, srt.shape[1], log_tab, q_first, hi, _RHO_MIN, _RHO_MAX,
                                     *(dst[key] for key in _STAT_KEYS))


def _part_stats_numpy(srt, q_first, hi, log_tab, dst):
    """Statistics of one channel's part of equal blocks at bit-widths q_first..hi: srt float32
    [nb, blen] (each block sorted), dst the views [nb, 16] ([nb, 16, 5] binned) of group_stats'
    arrays, written at columns q_first-1..hi-1.  log_tab[i] = log2(max(i, 1)), i <= blen."""
    nb, blen = srt.shape
    starts = np.empty((nb, blen), dtype=bool)
    starts[:, 0] = True
    k = np.empty((nb, blen), dtype=np.float64)
    m = srt[:, :1].astype(np.float64)             # the group minimum (float32 exact)
    span = srt[:, -1:].astype(np.float64) - m      # max - min of the stored float32s
    d = srt.astype(np.float64)
    d -= m
    runs = {}
    for q in range(q_first, hi + 1):
        levels = float((1 << q) - 1)
        s = np.where(span > 0, span / levels, 1.0)
        np.divide(d, s, out=k)
        np.rint(k, out=k)
        np.minimum(k, levels, out=k)
        np.not_equal(k[:, 1:], k[:, :-1], out=starts[:, 1:])
        idx = np.flatnonzero(starts)
        cnt = np.diff(np.append(idx, nb * blen))
        row = idx // blen
        kk = np.bincount(row, minlength=nb).astype(np.float64)
        prec = _precision(kk, np.full(nb, float(blen)))
        tot = np.exp2(prec)
        # coder normalisation: f = 1 + (T - K) * c / N  (proportional share after the +1)
        f = 1.0 + (tot[row] - kk[row]) * (cnt / blen)
        pay = cnt * (prec[row] - np.log2(f))
        same = row[1:] == row[:-1]
        vals = k.ravel()[idx]
        gapv = np.where(same, np.log2(1.0 + np.maximum(vals[1:] - vals[:-1], 0.0)), 0.0)
        lc = log_tab[cnt]
        lvl = np.where(same, np.log2(1.0 + np.abs(np.rint(2.0 * (lc[1:] - lc[:-1])))), 0.0)
        col = q - 1
        dst["k"][:, col] = kk
        dst["payload"][:, col] = np.where(kk > 1, np.bincount(row, weights=pay, minlength=nb), 0.0)
        dst["gap"][:, col] = np.bincount(row[1:], weights=gapv, minlength=nb)
        # steps >= 128 need a second varint byte in the serialised bin gaps
        dst["gap2"][:, col] = np.bincount(row[1:], weights=same & (vals[1:] - vals[:-1] > 128),
                                          minlength=nb)
        dst["level"][:, col] = np.bincount(row[1:], weights=lvl, minlength=nb)
        dst["laplace"][:, col] = _laplace_payload(vals, cnt, row, nb, blen, kk, prec, tot)
        # binned COARSE at this precision: bins of 2^h values ~ the (q - h)-bit grid's
        # distinct values; every value of a present bin gets the +1 (Kv = bins * 2^h)
        runs[q] = (row, cnt, kk)
        runs.pop(q - MAX_BINSHIFT - 1, None)
        for h in range(1, MAX_BINSHIFT + 1):
            if q - h not in runs:
                continue
            row_h, cnt_h, kk_h = runs[q - h]
            kv = kk_h * float(1 << h)
            fh = 1.0 + (tot[row_h] - kv[row_h]) * (cnt_h / (blen * float(1 << h)))
            bh = np.bincount(row_h, weights=cnt_h * (prec[row_h] - np.log2(np.maximum(fh, 1.0))),
                             minlength=nb)
            dst["binned"][:, col, h - 1] = np.where((kv <= tot) & (kk > 1), bh, np.inf)


# LAPLACE ratios the format can express: rho = r / 2^16, r = ratio_from_code(0..255)
_RHO_MIN = (65536 - ((31 << 16) >> 5)) / 65536.0
_RHO_MAX = 65535 / 65536.0


def _laplace_payload(vals, cnt, row, nb, blen, kk, prec, tot):
    """Bits of each group under the fitter's two-sided geometric (LAPLACE) model: centre at the
    most frequent value, each side's ratio from its mean distance (rho = 1 - 1 / mean, what
    gsz.encoder.rans._fit_one starts its small search from), the coder's +1-per-value
    normalisation over the whole span.  +inf where LAPLACE is not allowed (span + 1 > 2^n) or
    the group has fewer than two distinct values.

    Only the allowed groups are computed (at high bit-widths the span outgrows the precision
    in most groups, and the powers below are the costliest part of the rate model); every
    group's value depends on its own runs only, so the result is the same."""
    if vals.size == 0:
        return np.full(nb, np.inf)
    first = np.searchsorted(row, np.arange(nb))
    span = vals[np.append(first[1:], vals.size) - 1]   # lo is 0: the minimum maps to symbol 0
    ok = (span + 1.0 <= tot) & (kk > 1)
    if not ok.any():
        return np.full(nb, np.inf)
    if ok.all():
        return _laplace_core(vals, cnt, row, nb, kk, prec, tot)
    sel = ok[row]
    new_row = (np.cumsum(ok) - 1)[row[sel]]
    out = np.full(nb, np.inf)
    out[ok] = _laplace_core(vals[sel], cnt[sel], new_row, int(ok.sum()), kk[ok], prec[ok], tot[ok])
    return out


def _laplace_core(vals, cnt, row, nb, kk, prec, tot):
    """_laplace_payload over groups that all have runs (row sorted, every row present)."""
    first = np.searchsorted(row, np.arange(nb))
    maxc = np.maximum.reduceat(cnt, first)
    # centre: the FIRST value with the maximum count (np.argmax in the fitter)
    pos = np.where(cnt == maxc[row], np.arange(cnt.size), cnt.size)
    centre = vals[np.minimum.reduceat(pos, first)]
    last = np.append(first[1:], vals.size) - 1
    span = vals[last]                                 # lo is 0: the minimum maps to symbol 0
    d = vals - centre[row]
    left, right = d < 0, d > 0
    n_l = np.bincount(row, weights=cnt * left, minlength=nb)
    n_r = np.bincount(row, weights=cnt * right, minlength=nb)
    s_l = np.bincount(row, weights=cnt * np.where(left, -d, 0.0), minlength=nb)
    s_r = np.bincount(row, weights=cnt * np.where(right, d, 0.0), minlength=nb)
    with np.errstate(divide="ignore", invalid="ignore"):
        rho_l = np.clip(1.0 - n_l / np.maximum(s_l, 1e-300), _RHO_MIN, _RHO_MAX)
        rho_r = np.clip(1.0 - n_r / np.maximum(s_r, 1e-300), _RHO_MIN, _RHO_MAX)
    dl, dr = centre, span - centre
    w_sum = 1.0 + rho_l * (1 - rho_l ** dl) / (1 - rho_l) + rho_r * (1 - rho_r ** dr) / (1 - rho_r)
    rho = np.where(d < 0, rho_l[row], rho_r[row])
    p = rho ** np.abs(d) / w_sum[row]
    f = 1.0 + (tot[row] - (span[row] + 1.0)) * p
    bits = np.bincount(row, weights=cnt * (prec[row] - np.log2(np.maximum(f, 1.0))), minlength=nb)
    ok = (span + 1.0 <= tot) & (kk > 1)
    return np.where(ok, bits, np.inf)


FEATURES = ("coarse", "values", "gap_bits", "level_bits", "long_gaps", "single", "laplace")


def _candidates(stats: dict):
    """Model candidates the fitter chooses between, per (group, q): a list of (payload bits,
    table features [C, B, 16, F]) -- exact COARSE, COARSE binned by 2^h (h = 1..5), LAPLACE,
    SINGLE.  Unavailable candidates have payload +inf."""
    k = stats["k"]
    f = len(FEATURES)
    multi = k > 1
    coarse_feat = np.zeros(k.shape + (f,))
    coarse_feat[..., 0] = multi
    coarse_feat[..., 1] = np.where(multi, k, 0.0)
    coarse_feat[..., 2] = np.where(multi, stats["gap"], 0.0)
    coarse_feat[..., 3] = np.where(multi, stats["level"], 0.0)
    coarse_feat[..., 4] = np.where(multi, stats["gap2"], 0.0)
    coarse_feat[..., 5] = k == 1                     # SINGLE: no payload, a tiny table
    out = [(np.where(multi, PAYLOAD_FACTOR * stats["payload"], np.where(k == 1, 0.0, np.inf)), coarse_feat)]
    for h in range(1, MAX_BINSHIFT + 1):
        pay = np.full(k.shape, np.inf)
        pay[:, :, h:] = BINNED_FACTOR * stats["binned"][:, :, h:, h - 1]
        feat = np.zeros_like(coarse_feat)
        feat[:, :, h:] = coarse_feat[:, :, :-h]      # the bins ~ the (q - h)-bit grid's values
        feat[..., 5] = 0.0
        out.append((np.where(multi & (feat[..., 0] > 0), pay, np.inf), feat))
    lap_feat = np.zeros_like(coarse_feat)
    lap_feat[..., 6] = 1.0
    out.append((np.where(multi, PAYLOAD_FACTOR * stats["laplace"], np.inf), lap_feat))
    return out


def _choose(stats: dict, coeffs) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(cost, payload, features) of the cheapest candidate per (group, q)."""
    w = np.array([coeffs[name] for name in FEATURES])
    best = pay_best = feat_best = None
    for pay, feat in _candidates(stats):
        cost = pay + feat @ w
        if best is None:
            best, pay_best, feat_best = cost, pay.copy(), feat.copy()
            continue
        better = cost < best
        best = np.where(better, cost, best)
        pay_best = np.where(better, pay, pay_best)
        feat_best = np.where(better[..., None], feat, feat_best)
    return best, pay_best, feat_best


def rate_from_stats(stats: dict, bit_range: tuple[int, int] = (MIN_BITS, MAX_BITS),
                    coeffs=TABLE_COEFFS) -> np.ndarray:
    """Combine :func:`group_stats` into rate bits [C, B, 16] (+inf outside bit_range)."""
    lo, hi = int(bit_range[0]), int(bit_range[1])
    best, pay, _ = _choose(stats, coeffs)
    n = stats["n"]
    lanes = LANE_STATE_BITS * np.minimum(n / 1024.0, np.where(np.isfinite(pay), pay, 0.0) / 8192.0)
    rate = np.where(n > 0, best + lanes, 0.0)
    rate[:, :, :lo - 1] = np.inf
    rate[:, :, hi:] = np.inf
    return rate


def rate_matrix(x, num_blocks: int, bit_range: tuple[int, int] = (MIN_BITS, MAX_BITS)) -> np.ndarray:
    """Estimated coded size in BITS of every (channel, block) group at every bit-width.

    x: float [C, L] (finite); blocks: split_lengths(L, num_blocks) as the codec cuts them.
    Returns float64 [C, B, 16]: rate[c, b, q-1] for q in bit_range, +inf outside it, 0 for empty
    groups.  Non-decreasing in q up to small table-cost wiggles.  See the module docstring.
    """
    x, nb, lo, hi = _check(x, num_blocks, bit_range)
    return rate_from_stats(group_stats(x, nb, (lo, hi)), (lo, hi))


def channel_set_overhead_bits(num_channels: int, num_blocks: int, length: int) -> float:
    """Bits of a channel set that no group's choice changes: header (C, L, B, mode), bits /
    mins / maxs arrays, stream length, model-set varints and lane/word counts."""
    c, b = int(num_channels), int(num_blocks)
    models = c * b
    return 8.0 * (1 + 4 + 2 + 1 + 9 * models + 8 + 6 + math.ceil(models / 64) + 4)


# ---- whole-stream size estimates (tests and tools: the search uses group_stats) ----------
def payload_cost_bits(symbols: np.ndarray, model_ids: np.ndarray, models: ModelSet) -> float:
    """Ideal payload size (bits) under ``models`` plus the lane states; no coding performed."""
    sym = np.asarray(symbols, dtype=np.int64).ravel()
    mid = np.asarray(model_ids, dtype=np.int64).ravel()
    if sym.size == 0:
        return 48.0
    t = _coder_tables(models)
    g = _value_index(models, t, mid, sym - models.lo[mid])
    bits = float((models.prec[mid] - np.log2(t["freq"][g])).sum())
    return bits + 32.0 * choose_lanes(sym.size, bits) + 16.0


FAST_TABLE_BITS_PER_VALUE = 4.0   # measured: ~4 bits per present value after zstd (real scenes)
FAST_TABLE_BITS_PER_MODEL = 24.0
FAST_PAYLOAD_FACTOR = 1.005       # level quantisation and the +1 floors of normalisation


def stream_cost_bits(symbols: np.ndarray, model_ids: np.ndarray, num_models: int,
                     fast: bool = False) -> float:
    """Estimated size in bits of ``encode_stream(symbols, model_ids, num_models)``.

    fast=False: fits the models and serialises the tables (exact table size, ideal payload
    plus lane states; within ~0.3 % of the real size), ~2-3 ms per model.
    fast=True: no fitting, fully vectorised: per-model empirical entropy * 1.005 + ~4 bits per
    distinct value + 24 bits per model + lane states (within a few % on real scenes; for the
    size search's many candidate evaluations).
    """
    if not fast:
        models = fit_model_set(symbols, model_ids, num_models)
        return 8.0 * len(write_model_set(models)) + payload_cost_bits(symbols, model_ids, models)
    sym = np.asarray(symbols, dtype=np.int64).ravel()
    mid = np.asarray(model_ids, dtype=np.int64).ravel()
    if sym.size != mid.size:
        raise ValueError(f"{sym.size} symbols but {mid.size} model ids")
    if sym.size == 0:
        return 8.0 * (2 + num_models) + 48.0
    key = mid * (1 << 33) + (sym - sym.min())
    uniq, cnt = np.unique(key, return_counts=True)
    owner = uniq >> 33
    n_m = np.bincount(owner, weights=cnt, minlength=num_models)
    k_m = np.bincount(owner, minlength=num_models)
    c = cnt.astype(np.float64)
    h = float((c * np.log2(n_m[owner] / c)).sum())
    used = k_m > 1
    table = FAST_TABLE_BITS_PER_VALUE * float(k_m[used].sum()) + \
        FAST_TABLE_BITS_PER_MODEL * float(np.count_nonzero(k_m))
    payload = FAST_PAYLOAD_FACTOR * h
    return payload + table + 32.0 * choose_lanes(sym.size, payload) + 8.0 * (2 + num_models / 8)
