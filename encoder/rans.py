"""Interleaved rANS encoder: model fitting, model-set serialisation, payload encoding.

The decoder module ``gsz.decoder.rans`` is the shared truth: constants, the ModelSet container,
level/laplace weight rules, the normative normalisation and the decoding tables are imported from
there; this module only decides parameters and produces bytes (ENTROPY.md).
"""
from __future__ import annotations

import math

import numpy as np
import zstandard

from ..decoder import native
from ..decoder.errors import GszFormatError
from ..decoder.rans import (COARSE, EMPTY, LAPLACE, LAPLACE_SCALE_BITS, MAX_LEVEL_EXP,
                              MAX_PRECISION, MAX_ROWS, MAX_SPAN, RATIO_ONE, SINGLE, STATE_LOW, VALUE_LIMIT,
                              WORD_BITS, ModelSet,
                              laplace_weights, level_weights, lut_budget, max_level_code,
                              ratio_from_code)
from ..decoder.threads import thread_map

#: zstd level of model-set tables: on a search's 77 distinct tables (jug 12x) level 16 made
#: them 1.8 % smaller than 19 in half the time (19's long-match search does not pay on them)
ZSTD_LEVEL = 16
MAX_LANES = 4096
SYMBOLS_PER_LANE = 1024
# MAX_ROWS (the decoder's): at most that many symbols per lane, so choose_lanes never writes a
# lane count the decoder rejects (ENTROPY.md 4.1)
BITS_PER_LANE = 8192         # a lane's final state costs ~32 bits: <= ~0.4 % of the payload


def choose_lanes(num_symbols: int, payload_bits: float | None = None) -> int:
    """Encoder policy for the lane count L (any 1 <= L <= max(1, N) is valid for the decoder).

    More lanes = fewer numpy steps when decoding, but 4 bytes of final state each: L is
    min(N // 1024, payload_bits // 8192) but at least ceil(N / 8192) (at most 8192 decoder
    steps), clipped to 1..4096.
    """
    lanes = num_symbols // SYMBOLS_PER_LANE
    if payload_bits is not None:
        lanes = min(lanes, int(payload_bits) // BITS_PER_LANE)
    lanes = max(lanes, -(-num_symbols // MAX_ROWS))
    return int(min(MAX_LANES, max(1, lanes)))


# ---- byte writers ------------------------------------------------------------------------------
def varint_bytes(values: np.ndarray) -> bytes:
    """Unsigned LEB128 encoding of a non-negative integer array, vectorised."""
    a = np.asarray(values).ravel()
    if a.size == 0:
        return b""
    if not np.issubdtype(a.dtype, np.integer) or (a.dtype.kind == "i" and a.min() < 0):
        raise ValueError("varints take non-negative integers")
    v = a.astype(np.uint64)
    nbytes = np.ones(v.size, dtype=np.int64)
    t = v >> np.uint64(7)
    while np.any(t):
        nbytes += (t > 0)
        t >>= np.uint64(7)
    starts = np.cumsum(nbytes) - nbytes
    out = np.empty(int(nbytes.sum()), dtype=np.uint8)
    idx = np.repeat(np.arange(v.size), nbytes)
    k = np.arange(out.size) - starts[idx]
    chunk = (v[idx] >> (k.astype(np.uint64) * np.uint64(7))) & np.uint64(0x7F)
    cont = (k < nbytes[idx] - 1).astype(np.uint8) << 7
    out[:] = chunk.astype(np.uint8) | cont
    return out.tobytes()


def zigzag(v: np.ndarray) -> np.ndarray:
    v = np.asarray(v, dtype=np.int64)
    return (v << 1) ^ (v >> 63)


# ---- fitting -----------------------------------------------------------------------------------
class _Hist:
    """Sparse per-model histograms of a symbol stream.

    Entries e (distinct (model, value) pairs that occur) sorted by model then value:
    ``em`` model, ``eo`` value - lo[model], ``ec`` count.  Per model (length M): ``lo``, ``span``
    (hi - lo), ``total`` (symbols), ``k`` (distinct values), ``start`` (first entry).
    ``sym_entry`` (optional): the entry of every symbol.
    """

    __slots__ = ("num_models", "em", "eo", "ec", "lo", "span", "total", "k", "start", "sym_entry")


# dense (model, value) counting when the models' ranges hold at most this many cells
_DENSE_CELLS_PER_SYMBOL = 4
_DENSE_CELLS_MIN = 1 << 22


def _histograms(symbols: np.ndarray, model_ids: np.ndarray, num_models: int,
                symbol_entries: bool = False) -> _Hist:
    """Sparse histograms of (symbols, model_ids); ValueError on mismatched sizes, ids outside
    0..num_models-1, and per model (first offending model first) a span above 65536 or values
    outside int32."""
    sym = np.asarray(symbols, dtype=np.int64).ravel()
    mid = np.asarray(model_ids, dtype=np.int64).ravel()
    if sym.size != mid.size:
        raise ValueError(f"{sym.size} symbols but {mid.size} model ids")
    if mid.size and (mid.min() < 0 or mid.max() >= num_models):
        raise ValueError(f"model ids must lie in 0..{num_models - 1}")
    m_count = int(num_models)
    h = _Hist()
    h.num_models = m_count
    total = np.bincount(mid, minlength=m_count).astype(np.int64) if mid.size \
        else np.zeros(m_count, np.int64)
    lo = np.zeros(m_count, np.int64)
    hi = np.zeros(m_count, np.int64)
    if mid.size:
        if mid.size > 1 and np.all(mid[1:] >= mid[:-1]):       # sorted ids: segment reductions
            starts = np.flatnonzero(np.r_[True, mid[1:] != mid[:-1]])
            ids = mid[starts]
            lo[ids] = np.minimum.reduceat(sym, starts)
            hi[ids] = np.maximum.reduceat(sym, starts)
        else:
            lo_all = np.full(m_count, np.iinfo(np.int64).max)
            hi_all = np.full(m_count, np.iinfo(np.int64).min)
            np.minimum.at(lo_all, mid, sym)
            np.maximum.at(hi_all, mid, sym)
            used = total > 0
            lo[used] = lo_all[used]
            hi[used] = hi_all[used]
    span = hi - lo
    bad = (span > MAX_SPAN) | (lo < -VALUE_LIMIT) | (hi >= VALUE_LIMIT)
    if np.any(bad):
        m = int(np.flatnonzero(bad)[0])
        if span[m] > MAX_SPAN:
            raise ValueError(f"model {m}: value span {int(span[m])} exceeds 65536")
        raise ValueError(f"model {m}: values outside int32")
    size = np.where(total > 0, span + 1, 0)
    ends = np.cumsum(size)
    dstart = ends - size
    cells = int(ends[-1]) if m_count else 0
    h.sym_entry = None
    if sym.size == 0:
        pos = np.zeros(0, np.int64)
        cnt = np.zeros(0, np.int64)
    else:
        key = lo[mid]                       # dstart[mid] + (sym - lo[mid]), two temporaries fewer
        np.subtract(sym, key, out=key)
        key += dstart[mid]
        if cells <= max(_DENSE_CELLS_MIN, _DENSE_CELLS_PER_SYMBOL * sym.size):
            dense = np.bincount(key, minlength=cells)
            pos = np.flatnonzero(dense)
            cnt = dense[pos].astype(np.int64)
            if symbol_entries:
                rank = np.zeros(cells, np.int64)
                rank[pos] = np.arange(pos.size, dtype=np.int64)
                h.sym_entry = rank[key]
        else:
            if symbol_entries:
                pos, inv, cnt = np.unique(key, return_inverse=True, return_counts=True)
                h.sym_entry = inv.astype(np.int64).ravel()
            else:
                pos, cnt = np.unique(key, return_counts=True)
            cnt = cnt.astype(np.int64)
    em = np.searchsorted(ends, pos, side="right").astype(np.int64)
    h.em, h.eo, h.ec = em, pos - dstart[em], cnt
    h.lo, h.span, h.total = lo, span, total
    h.k = np.bincount(em, minlength=m_count).astype(np.int64) if em.size \
        else np.zeros(m_count, np.int64)
    h.start = np.cumsum(h.k) - h.k
    return h


def _histograms_rows(symbols, lens: np.ndarray) -> _Hist:
    """``_histograms(symbols.ravel(), ids, C * B, symbol_entries=True)`` of a [C, L] channel
    set whose model ids are its (channel, block) groups, c * B + block (blocks of ``lens``
    symbols, contiguous along L): the same histograms, one channel at a time, with neither a
    per-symbol model-id array nor [C * L]-sized temporaries besides the symbols' entries (at
    1.2 M kept SH vectors those passes over 34 M int64 values took most of a calibration round).
    ``symbols``: the [C, L] array, or any object with its ``shape`` whose ``[c]`` gives channel
    c's symbols (read once each, in channel order: groups.write_channel_set makes them a few
    channels at a time)."""
    sym2 = symbols if hasattr(symbols, "shape") else np.asarray(symbols)
    c, length = sym2.shape
    lens = np.asarray(lens, dtype=np.int64)
    b = lens.size
    m_count = c * b
    h = _Hist()
    h.num_models = m_count
    h.total = np.tile(lens, c)
    h.lo, hi = np.zeros(m_count, np.int64), np.zeros(m_count, np.int64)
    # int32 where it can hold every entry (a stream has fewer entries than symbols)
    h.sym_entry = np.empty(c * length, np.int32 if c * length < 2 ** 31 else np.int64)
    block_of = np.repeat(np.arange(b, dtype=np.int64), lens)
    full = lens > 0
    first = (np.cumsum(lens) - lens)[full]
    parts, base = [], 0
    for ci in range(c):
        x = sym2[ci].astype(np.int64)
        lo_r, hi_r = np.zeros(b, np.int64), np.zeros(b, np.int64)
        if length:
            lo_r[full] = np.minimum.reduceat(x, first)
            hi_r[full] = np.maximum.reduceat(x, first)
        span_r = hi_r - lo_r
        if np.any((span_r > MAX_SPAN) | (lo_r < -VALUE_LIMIT) | (hi_r >= VALUE_LIMIT)):
            whole = np.stack([np.asarray(sym2[i]) for i in range(c)])
            return _histograms(whole.ravel(), np.arange(m_count, dtype=np.int64).reshape(c, b)[:, block_of].ravel(),
                               m_count, symbol_entries=True)     # its error names the model
        size = np.where(full, span_r + 1, 0)
        ends = np.cumsum(size)
        dstart = ends - size
        key = x - (lo_r - dstart)[block_of]
        cells = int(ends[-1]) if b else 0
        if cells <= max(_DENSE_CELLS_MIN, _DENSE_CELLS_PER_SYMBOL * length):
            dense = np.bincount(key, minlength=cells)
            pos = np.flatnonzero(dense)
            cnt = dense[pos].astype(np.int64)
            rank = np.zeros(cells, np.int64)
            rank[pos] = np.arange(base, base + pos.size, dtype=np.int64)
            h.sym_entry[ci * length:(ci + 1) * length] = rank[key]
        else:
            pos, inv, cnt = np.unique(key, return_inverse=True, return_counts=True)
            cnt = cnt.astype(np.int64)
            h.sym_entry[ci * length:(ci + 1) * length] = inv.ravel() + base
        em = np.searchsorted(ends, pos, side="right").astype(np.int64)
        parts.append((em + ci * b, pos - dstart[em], cnt))
        h.lo[ci * b:(ci + 1) * b] = lo_r
        hi[ci * b:(ci + 1) * b] = hi_r
        base += pos.size
    h.span = hi - h.lo
    h.em, h.eo, h.ec = (np.concatenate([p[i] for p in parts]) if parts else np.zeros(0, np.int64)
                        for i in range(3))
    h.k = np.bincount(h.em, minlength=m_count).astype(np.int64) if h.em.size \
        else np.zeros(m_count, np.int64)
    h.start = np.cumsum(h.k) - h.k
    return h


def _dense_counts(h: _Hist, m: int) -> np.ndarray:
    a, b = int(h.start[m]), int(h.start[m] + h.k[m])
    counts = np.zeros(int(h.span[m]) + 1, np.int64)
    counts[h.eo[a:b]] = h.ec[a:b]
    return counts


def _approx_bits(counts: np.ndarray, w: np.ndarray, n: int) -> float:
    """Ideal code length under the real-valued version of normalise_weights (1 + R*w/W):
    ranks candidate models without the exact remainder distribution (an argsort each)."""
    total = float(1 << n)
    big_w = float(w.sum())
    f = 1.0 + (total - w.size) * (w / big_w if big_w > 0 else 1.0 / w.size)
    nz = counts > 0
    return float((counts[nz] * np.log2(total / f[nz])).sum())


def _coarse_codes(counts: np.ndarray, n: int, g: int, h: int) -> np.ndarray:
    """Level codes q per bin of 2**h values (0 = absent) approximating ``counts``.

    Normalisation gives every present value f = 1 + a share of (T - K); the shares are aimed
    at the bin's mean count scaled to T, minus that 1.
    """
    if h:
        nbins = ((counts.size - 1) >> h) + 1
        edges = np.arange(nbins) << h
        bin_counts = np.add.reduceat(counts, edges).astype(np.float64)
        bin_sizes = np.minimum(edges + (1 << h), counts.size) - edges
    else:
        nbins, bin_counts, bin_sizes = counts.size, counts.astype(np.float64), 1.0
    present = bin_counts > 0
    total = float(counts.sum())
    target = np.maximum(bin_counts / bin_sizes * ((1 << n) / total) - 1.0, 0.0)
    top = target.max()
    q = np.zeros(nbins, dtype=np.int64)
    if top <= 0:
        q[present] = 1
        return q
    scaled = target * ((2.0 ** (MAX_LEVEL_EXP + g)) / top)  # largest weight at the top level
    with np.errstate(divide="ignore"):
        e = np.floor(np.log2(np.maximum(scaled, 1e-300))) - g
    np.clip(e, 0, MAX_LEVEL_EXP, out=e)
    m = np.rint(scaled / np.exp2(e)) - (1 << g)
    carry = m >= (1 << g)
    e[carry] += 1
    m[carry] = 0
    qv = 1 + (e.astype(np.int64) << g) + np.maximum(m, 0).astype(np.int64)
    qv = np.minimum(np.maximum(qv, 1), max_level_code(g))
    q[present] = qv[present]
    return q


def _table_cost_bits(q: np.ndarray) -> float:
    """Proxy for the zstd-coded size of a coarse table: Elias-gamma lengths of the level
    deltas and of the nonzero gaps between present bins, ~0.3 bit per zero gap."""
    b = np.flatnonzero(q)
    qb = q[b]
    d = np.abs(qb[1:] - qb[:-1])
    gaps = b[1:] - b[:-1] - 1
    gap_bits = np.where(gaps == 0, 0.3, 1 + 2 * np.floor(np.log2(gaps + 1)))
    return float((1 + 2 * np.floor(np.log2(2 * d + 1))).sum() + gap_bits.sum()) \
        + 1 + 2 * math.floor(math.log2(2 * int(qb[0]) + 1))


COARSE_GROUPS = (0, 1, 2)
# LAPLACE ratio codes: 1 - r/65536 per code, and the codes sorted by it (for neighbour search)
_RATIO_GAP = np.array([RATIO_ONE - ratio_from_code(u) for u in range(256)], dtype=np.float64)
_RATIO_BY_GAP = np.argsort(_RATIO_GAP, kind="stable")
_RATIO_RANK = np.argsort(_RATIO_BY_GAP, kind="stable")
COARSE_BINSHIFTS = (0, 1, 2, 3, 4, 5)


def _fit_one(lo: int, hi: int, counts: np.ndarray):
    """Choose the cheapest model for one histogram; returns a dict of ModelSet fields.

    Cost = exact ideal payload bits under the normalised table + a proxy of the table bits.
    """
    span = hi - lo
    present = counts > 0
    k = int(present.sum())
    if k == 1:
        return dict(type=SINGLE, lo=lo + int(np.flatnonzero(present)[0]), span=0, prec=0)
    c_total = int(counts.sum())
    if k > (1 << MAX_PRECISION):
        raise ValueError(f"{k} distinct symbols in one model: at most 65536 are codable")
    # 2**n < 2 * N_m keeps the decoder's LUT (and its build time) within 2 entries per symbol,
    # well inside the budget of 4; more precision than the counts' own resolution buys ~nothing
    # (measured on real scenes: 2**n ~ 2 N_m gives the same size as ~N_m)
    n_cap = min(MAX_PRECISION, max(math.ceil(math.log2(k)), math.ceil(math.log2(c_total))))
    n = max(1, n_cap)

    def coarse(h: int, g: int):
        q = _coarse_codes(counts, n, g, h)
        per_value = np.repeat(q, 1 << h)[:span + 1] if h else q
        idx = np.flatnonzero(per_value)
        if idx.size > (1 << n):
            return None
        bits = _approx_bits(counts[idx], level_weights(per_value[idx], g), n) \
            + _table_cost_bits(q) + 16
        return bits, dict(type=COARSE, lo=lo, span=span, prec=n, group=g, binshift=h, q=q)

    # bin width at the middle level resolution, then the level resolution at that width
    best = None
    for h in COARSE_BINSHIFTS:
        if h and (span >> (h - 1)) == 0:
            break
        cand = coarse(h, 1)
        if cand is not None and (best is None or cand[0] < best[0]):
            best = cand
    h_best = best[1]["binshift"]
    for g in COARSE_GROUPS:
        if g != 1:
            cand = coarse(h_best, g)
            if cand is not None and cand[0] < best[0]:
                best = cand
    if span + 1 <= (1 << n):
        # two-sided geometric around the mode; ratios from the mean distance on each side
        centre = int(np.argmax(counts))
        d = np.arange(counts.size) - centre
        cands = []
        for side in (d < 0, d > 0):
            cs = counts[side]
            if cs.sum() == 0:
                cands.append([0])
                continue
            mean = float((np.abs(d[side]) * cs).sum() / cs.sum())
            # geometric tail on d >= 1: mean distance 1 / (1 - rho)
            one_minus = min(1.0, 1.0 / max(mean, 1.0))
            u0 = int(np.argmin(np.abs(np.log(_RATIO_GAP) - math.log(one_minus * RATIO_ONE))))
            cands.append(sorted({int(u) for u in _RATIO_BY_GAP[
                max(0, _RATIO_RANK[u0] - 4):_RATIO_RANK[u0] + 5:2]}))
        tbits = 8 * 6
        # coordinate search: the left ratio with the right one at its estimate, then the right
        rl_best, rr_best = cands[0][len(cands[0]) // 2], cands[1][len(cands[1]) // 2]
        for side in (0, 1):
            for r in cands[side]:
                rl, rr = (r, rr_best) if side == 0 else (rl_best, r)
                w = laplace_weights(span, centre, ratio_from_code(rl), ratio_from_code(rr))
                bits = _approx_bits(counts, w, n) + tbits
                if bits < best[0]:
                    best = (bits, dict(type=LAPLACE, lo=lo, span=span, prec=n, centre=centre,
                                       r_left=rl, r_right=rr))
                    rl_best, rr_best = rl, rr
    return best[1]


# ---- vectorised fitting ------------------------------------------------------------------------
# fit_model_set evaluates _fit_one's candidate models for all models at once, on the sparse
# histograms.  The discrete steps (level codes, ratio estimates, weights, precisions) repeat
# _fit_one's arithmetic element by element; only the cost sums are accumulated in another
# order, so they can differ from _fit_one's by rounding.  Every choice between candidates whose
# costs lie within _TIE_REL (relative) of each other is therefore left to _fit_one itself: the
# fitted model set is exactly the one _fit_one gives.
_TIE_REL = 1e-9
_TIE_ABS = 1e-6
_LOG_RATIO_GAP = np.log(_RATIO_GAP)
_DENSE_LAPLACE_TABLE = 1 << 23      # entries of the (ratio code, distance) weight table


def _floor_log2(x: np.ndarray) -> np.ndarray:
    """floor(log2(x)) of positive integers < 2**53, exact (int64)."""
    return np.frexp(np.asarray(x, dtype=np.float64))[1].astype(np.int64) - 1


def _segments(starts: np.ndarray, size: int) -> np.ndarray:
    """Segment index of every position 0..size-1 for the sorted segment starts (first is 0)."""
    seg = np.zeros(size, np.int64)
    if starts.size > 1:
        seg[starts[1:]] = 1
    return np.cumsum(seg)


def _near_tie(costs: np.ndarray) -> np.ndarray:
    """Rows whose smallest and second smallest finite costs lie within the tie tolerance."""
    if costs.shape[1] < 2:
        return np.zeros(costs.shape[0], bool)
    two = np.partition(costs, 1, axis=1)[:, :2]
    with np.errstate(invalid="ignore"):
        return np.isfinite(two[:, 1]) & (two[:, 1] - two[:, 0]
                                          <= _TIE_REL * np.abs(two[:, 0]) + _TIE_ABS)


class _Bins:
    """The present bins at bin shift ``shift`` of the models where ``sel`` (None: all with
    data), with what _coarse_codes and _fit_one's coarse() compute before the level group."""

    def __init__(self, h: _Hist, sel, prec: np.ndarray, shift: int):
        if sel is None:
            em, eo, ec = h.em, h.eo, h.ec
        else:
            e = sel[h.em]
            em, eo, ec = h.em[e], h.eo[e], h.ec[e]
        b = eo >> shift if shift else eo
        newbin = np.ones(em.size, bool)
        newbin[1:] = (b[1:] != b[:-1]) | (em[1:] != em[:-1])
        bs = np.flatnonzero(newbin)
        bm, bb = em[bs], b[bs]
        self.bc = np.add.reduceat(ec, bs).astype(np.float64) if shift else ec.astype(np.float64)
        self.ms = ms = np.flatnonzero(np.r_[True, bm[1:] != bm[:-1]])
        self.mm = mm = bm[ms]
        self.loc = loc = _segments(ms, bs.size)
        self.bb, self.shift = bb, shift
        self.total = total = (np.int64(1) << prec[mm]).astype(np.float64)
        if shift:
            first = bb << shift
            self.bsize = np.minimum(first + (1 << shift), h.span[bm] + 1) - first
            t = self.bc / self.bsize
            self.k = np.add.reduceat(self.bsize, ms)
        else:
            self.bsize = None
            t = self.bc
            self.k = np.diff(np.r_[ms, bs.size])
        self.target = np.maximum(t * (total / h.total[mm].astype(np.float64))[loc] - 1.0, 0.0)
        top = np.maximum.reduceat(self.target, ms)
        self.pos = top > 0
        self.top = np.where(self.pos, top, 1.0)
        self.valid = self.k <= (np.int64(1) << prec[mm])
        inner = np.ones(bs.size, bool)
        inner[ms] = False
        self.inner = inner
        gaps = np.diff(bb, prepend=0) - 1
        gap_bits = np.where(inner, np.where(gaps == 0, 0.3, 1 + 2 * _floor_log2(gaps + 1)), 0.0)
        self.gap_bits = np.add.reduceat(gap_bits, ms)

    def codes(self, g: int) -> np.ndarray:
        """Level codes of the present bins for level group g (_coarse_codes, per element)."""
        scaled = self.target * ((2.0 ** (MAX_LEVEL_EXP + g)) / self.top)[self.loc]
        e = np.floor(np.log2(np.maximum(scaled, 1e-300))) - g
        np.clip(e, 0, MAX_LEVEL_EXP, out=e)
        m = np.rint(scaled / np.exp2(e)) - (1 << g)
        carry = m >= (1 << g)
        e[carry] += 1
        m[carry] = 0
        q = 1 + (e.astype(np.int64) << g) + np.maximum(m, 0).astype(np.int64)
        q = np.minimum(np.maximum(q, 1), max_level_code(g))
        q[~self.pos[self.loc]] = 1
        return q

    def cost(self, q: np.ndarray, g: int) -> np.ndarray:
        """_fit_one's coarse() cost per model (up to rounding); inf where K > 2**n."""
        ms, loc, total = self.ms, self.loc, self.total
        w = level_weights(q, g)
        big_w = np.add.reduceat(w * self.bsize if self.shift else w, ms)
        f = 1.0 + ((total - self.k) * (1.0 / big_w.astype(np.float64)))[loc] * w
        with np.errstate(invalid="ignore", divide="ignore"):    # K > 2**n: no candidate
            bits = np.add.reduceat(self.bc * np.log2(total[loc] / f), ms)
        dq = np.abs(np.diff(q, prepend=0))
        dq_bits = np.where(self.inner, 1 + 2 * _floor_log2(2 * dq + 1), 0).astype(np.float64)
        tbits = np.add.reduceat(dq_bits, ms) + self.gap_bits + 1 + 2 * _floor_log2(2 * q[ms] + 1)
        return np.where(self.valid, bits + tbits + 16, np.inf)


class _LaplaceTables:
    """LAPLACE weights by ratio code and distance (laplace_weights' sequential products, so the
    values are identical): w(u, 0) = 2**24, w(u, d) and the prefix sums S(u, D) = sum_{1..D}."""

    def __init__(self, codes: np.ndarray, max_dist: int):
        self.codes = np.unique(codes)
        idx = np.zeros(256, np.int64)
        idx[self.codes] = np.arange(self.codes.size)
        self.idx = idx
        ws, ps, base, cap = [], [], [], []
        off = 0
        for u in self.codes:
            r = ratio_from_code(int(u))
            if max_dist > 0:
                v = np.multiply.accumulate(np.full(max_dist, r / RATIO_ONE, dtype=np.float64))
                w = np.floor(v * float(1 << LAPLACE_SCALE_BITS)).astype(np.int64)
                z = int(np.count_nonzero(w))       # nonincreasing: zero from index z on
            else:
                w, z = np.zeros(0, np.int64), 0
            arr = np.concatenate([[1 << LAPLACE_SCALE_BITS], w[:z], [0]]).astype(np.int64)
            pre = np.concatenate([[0], np.cumsum(w[:z]), [int(w[:z].sum())]]).astype(np.int64)
            ws.append(arr)
            ps.append(pre)
            base.append(off)
            cap.append(z + 1)
            off += arr.size
        self.w = np.concatenate(ws) if ws else np.zeros(0, np.int64)
        self.pre = np.concatenate(ps) if ps else np.zeros(0, np.int64)
        self.base = np.asarray(base, np.int64)
        self.cap = np.asarray(cap, np.int64)
        self.max_dist = max_dist
        self.dense = None
        if self.codes.size * (max_dist + 1) <= _DENSE_LAPLACE_TABLE:
            j = np.minimum(np.arange(max_dist + 1)[None, :], self.cap[:, None])
            self.dense = self.w[self.base[:, None] + j].astype(np.float64).ravel()

    def weight(self, code: np.ndarray, dist: np.ndarray) -> np.ndarray:
        i = self.idx[code]
        return self.w[self.base[i] + np.minimum(dist, self.cap[i])]

    def weight_f(self, code: np.ndarray, dist: np.ndarray) -> np.ndarray:
        """weight() as float64 (dist <= max_dist)."""
        if self.dense is None:
            return self.weight(code, dist).astype(np.float64)
        return self.dense[self.idx[code] * (self.max_dist + 1) + dist]

    def prefix(self, code: np.ndarray, dist: np.ndarray) -> np.ndarray:
        i = self.idx[code]
        return self.pre[self.base[i] + np.minimum(dist, self.cap[i])]


def _expand(starts: np.ndarray, lengths: np.ndarray):
    """Concatenated ranges start..start+length-1 and the segment starts of the result."""
    seg = np.cumsum(lengths) - lengths
    out = np.arange(int(lengths.sum()), dtype=np.int64)
    out += np.repeat(starts - seg, lengths)
    return out, seg


def _cand_table(cands: list) -> np.ndarray:
    """Ragged candidate lists -> int64 [rows, max length], -1 padded."""
    width = max(len(c) for c in cands)
    out = np.full((len(cands), width), -1, np.int64)
    for i, c in enumerate(cands):
        out[i, :len(c)] = c
    return out


class _Fit:
    """The model set under construction by :func:`_fit_vectorised` (one array per field, the
    COARSE models' bins and levels by model id, which models go to the reference search)."""

    def __init__(self, h: _Hist):
        m_count = h.num_models
        k = h.k
        self.types = np.where(k == 0, EMPTY, np.where(k == 1, SINGLE, COARSE)).astype(np.int64)
        z = np.zeros(m_count, np.int64)
        (self.lo, self.span, self.prec, self.group, self.binshift, self.centre, self.r_left,
         self.r_right) = (z.copy() for _ in range(8))
        self.fallback = np.zeros(m_count, bool)
        self.best = np.full(m_count, np.inf)
        self.bins_of, self.levels_of = {}, {}


def _fit_vectorised(h: _Hist, validate: bool = True) -> ModelSet:
    """fit_model_set's models from sparse histograms (the choices of _fit_one, see above)."""
    k = h.k
    over = np.flatnonzero(k > (1 << MAX_PRECISION))
    if over.size:
        raise ValueError(f"{int(k[over[0]])} distinct symbols in one model: at most 65536 are "
                         f"codable")
    f = _Fit(h)
    wide = k >= 2
    one = k == 1
    f.lo[one] = h.lo[one] + h.eo[h.start[one]]
    f.lo[wide] = h.lo[wide]
    f.span[wide] = h.span[wide]
    # precision: min(16, max(ceil(log2 K), ceil(log2 N_m))), at least 1
    nk = np.where(wide, _floor_log2(np.maximum(k - 1, 1)) + 1, 0)
    nt = np.where(wide, _floor_log2(np.maximum(h.total - 1, 1)) + 1, 0)
    f.prec[wide] = np.maximum(1, np.minimum(MAX_PRECISION, np.maximum(nk, nt)))[wide]
    if wide.any():
        _fit_coarse(h, f, wide)
    _fit_laplace(h, f, wide)
    _fit_near_ties(h, f)
    co_ids = np.flatnonzero(f.types == COARSE).tolist()
    models = ModelSet(types=f.types, lo=f.lo, span=f.span, prec=f.prec, group=f.group,
                      binshift=f.binshift, centre=f.centre, r_left=f.r_left, r_right=f.r_right,
                      bins=tuple(f.bins_of[m] for m in co_ids),
                      levels=tuple(f.levels_of[m] for m in co_ids))
    if validate:
        models.validate()
    return models


def _fit_coarse(h: _Hist, f: _Fit, wide: np.ndarray) -> None:
    """COARSE fits of the models with 2+ distinct values: the bin shift at the middle level
    group, then the level group at that shift (near ties marked for the reference search)."""
    m_count, k = h.num_models, h.k
    span, prec, fallback, best = f.span, f.prec, f.fallback, f.best
    w_idx = np.flatnonzero(wide)
    inf = np.inf
    all_wide = bool(np.all(wide[k > 0]))
    cost_h = np.full((m_count, len(COARSE_BINSHIFTS)), inf)
    for i, s in enumerate(COARSE_BINSHIFTS):
        sel = wide & ((span >> max(s - 1, 0)) != 0) if s else wide
        if not sel.any():
            break
        bins = _Bins(h, None if (s == 0 and all_wide) else sel, prec, s)
        cost_h[bins.mm, i] = bins.cost(bins.codes(1), 1)
    fallback[w_idx[_near_tie(cost_h[w_idx])]] = True
    h_best = np.asarray(COARSE_BINSHIFTS)[np.argmin(cost_h, axis=1)]
    # ... then the level group at that shift (order g = 1, 0, 2 as _fit_one)
    for s in COARSE_BINSHIFTS:
        sel = wide & (h_best == s)
        if not sel.any():
            continue
        bins = _Bins(h, sel, prec, s)
        qs = [bins.codes(g) for g in (1, 0, 2)]
        costs = np.stack([cost_h[bins.mm].min(axis=1), bins.cost(qs[1], 0),
                          bins.cost(qs[2], 2)], axis=1)
        fallback[bins.mm[_near_tie(costs)]] = True
        win = np.argmin(costs, axis=1)
        best[bins.mm] = costs.min(axis=1)
        f.group[bins.mm] = np.array([1, 0, 2])[win]
        f.binshift[bins.mm] = s
        wl = win[bins.loc]
        q = np.where(wl == 0, qs[0], np.where(wl == 1, qs[1], qs[2]))
        cuts = bins.ms[1:]
        for m, b_, q_ in zip(bins.mm.tolist(), np.split(bins.bb, cuts), np.split(q, cuts)):
            f.bins_of[m], f.levels_of[m] = b_, q_


def _laplace_candidates(li, lc, ad, side, n_models) -> list:
    """Per local model, the ratio indices to try on one side: around the one whose mean
    distance matches the side's mean distance ([0] for an empty side)."""
    cnt = np.bincount(li[side], weights=lc[side], minlength=n_models)
    dist = np.bincount(li[side], weights=(ad * lc)[side], minlength=n_models)
    # (float weights: exact, the sums stay far below 2**53)
    lists = []
    for cs, ds in zip(cnt.tolist(), dist.tolist()):
        if cs == 0:
            lists.append([0])
            continue
        mean = float(np.int64(ds) / np.int64(cs))
        one_minus = min(1.0, 1.0 / max(mean, 1.0))
        u0 = int(np.argmin(np.abs(_LOG_RATIO_GAP - math.log(one_minus * RATIO_ONE))))
        lists.append(sorted({int(u) for u in _RATIO_BY_GAP[
            max(0, _RATIO_RANK[u0] - 4):_RATIO_RANK[u0] + 5:2]}))
    return lists


def _fit_laplace(h: _Hist, f: _Fit, wide: np.ndarray) -> None:
    """LAPLACE fits where they beat the COARSE one: centre at the mode, ratios from the mean
    distances, a coordinate search over nearby ratios (near ties marked)."""
    m_count, inf = h.num_models, np.inf
    span, prec, fallback, best = f.span, f.prec, f.fallback, f.best
    lap = np.flatnonzero(wide & (span + 1 <= (np.int64(1) << prec)))
    if not lap.size:
        return
    lmask = np.zeros(m_count, bool)
    lmask[lap] = True
    e = lmask[h.em]
    le, lo_, lc = h.em[e], h.eo[e], h.ec[e]
    li_of = np.zeros(m_count, np.int64)
    li_of[lap] = np.arange(lap.size)
    li = li_of[le]                                    # local model index per entry
    starts = np.flatnonzero(np.r_[True, le[1:] != le[:-1]])
    maxc = np.maximum.reduceat(lc, starts)
    is_max = np.flatnonzero(lc == maxc[li])
    _, first = np.unique(li[is_max], return_index=True)   # first entry at the maximum
    cen = lo_[is_max[first]]
    d = lo_ - cen[li]
    ad = np.abs(d)
    left = d < 0
    cands = [_laplace_candidates(li, lc, ad, side, lap.size) for side in (left, d > 0)]
    c0, c1 = _cand_table(cands[0]), _cand_table(cands[1])
    n0 = (c0 >= 0).sum(axis=1)
    n1 = (c1 >= 0).sum(axis=1)
    rows = np.arange(lap.size)
    mid0, mid1 = c0[rows, n0 // 2], c1[rows, n1 // 2]
    sp = span[lap]
    tabs = _LaplaceTables(np.r_[c0[c0 >= 0], c1[c1 >= 0]], int(sp.max()))
    total = (np.int64(1) << prec[lap]).astype(np.float64)
    nbits = h.total[lap] * prec[lap].astype(np.float64)     # N * n: exact
    free = total - (sp + 1)
    lcf = lc.astype(np.float64)

    def lap_cost(rl: np.ndarray, rr: np.ndarray) -> np.ndarray:
        """Cost of LAPLACE(centre, rl, rr) for every local model: N n - sum c log2 f + 48."""
        big_w = (1 << LAPLACE_SCALE_BITS) + tabs.prefix(rl, cen) + tabs.prefix(rr, sp - cen)
        a = free / big_w.astype(np.float64)
        w = tabs.weight_f(np.where(left, rl[li], rr[li]), ad)
        fr = 1.0 + a[li] * w
        return nbits - np.add.reduceat(lcf * np.log2(fr), starts) + 8 * 6

    # side 0: the left ratio over its candidates, the right one at its estimate
    tab0 = np.full((lap.size, 1 + c0.shape[1]), inf)
    tab0[:, 0] = best[lap]
    for j in range(c0.shape[1]):
        has = n0 > j
        tab0[has, 1 + j] = lap_cost(np.where(has, c0[:, j], mid0), mid1)[has]
    fallback[lap[_near_tie(tab0)]] = True
    win0 = np.argmin(tab0, axis=1)
    rl_best = np.where(win0 > 0, c0[rows, np.maximum(win0 - 1, 0)], mid0)
    # side 1: the right ratio over its candidates (the estimate is costed already)
    c1x = np.where(c1 == mid1[:, None], -1, c1)
    tab1 = np.full((lap.size, 1 + c1.shape[1]), inf)
    tab1[:, 0] = tab0.min(axis=1)
    for j in range(c1.shape[1]):
        has = c1x[:, j] >= 0
        if has.any():
            tab1[has, 1 + j] = lap_cost(rl_best, np.where(has, c1x[:, j], mid1))[has]
    fallback[lap[_near_tie(tab1)]] = True
    win1 = np.argmin(tab1, axis=1)
    rr_best = np.where(win1 > 0, c1[rows, np.maximum(win1 - 1, 0)], mid1)
    is_lap = (win0 > 0) | (win1 > 0)
    lm = lap[is_lap]
    f.types[lm] = LAPLACE
    f.centre[lm] = cen[is_lap]
    f.r_left[lm] = rl_best[is_lap]
    f.r_right[lm] = rr_best[is_lap]
    f.group[lm] = 0
    f.binshift[lm] = 0


def _fit_near_ties(h: _Hist, f: _Fit) -> None:
    """Models whose vectorised choice was a near tie: the reference search (_fit_one) decides."""
    for m in np.flatnonzero(f.fallback).tolist():
        fit = _fit_one(int(h.lo[m]), int(h.lo[m] + h.span[m]), _dense_counts(h, m))
        f.types[m] = fit["type"]
        for key in ("lo", "span", "prec", "group", "binshift", "centre", "r_left", "r_right"):
            getattr(f, key)[m] = fit.get(key, 0)
        if fit["type"] == COARSE:
            q = np.asarray(fit["q"], dtype=np.int64)
            b_ = np.flatnonzero(q)
            f.bins_of[m], f.levels_of[m] = b_, q[b_]


def fit_model_set(symbols: np.ndarray, model_ids: np.ndarray, num_models: int) -> ModelSet:
    """Fit one model per model id (EMPTY for ids without symbols).

    symbols: int array (N,), values in int32 with a span <= 65536 per model and at most 65536
    distinct values per model; model_ids: int array (N,) in 0..num_models-1.
    Deterministic: the same input gives the same ModelSet.
    """
    return _fit_vectorised(_histograms(symbols, model_ids, int(num_models)))


# ---- serialisation -----------------------------------------------------------------------------
def write_model_set(models: ModelSet) -> bytes:
    """Serialise a ModelSet (ENTROPY.md section 3); the smaller of raw and zstd is written."""
    models.validate()
    t = models.types
    nonempty = t != EMPTY
    wide = (t == COARSE) | (t == LAPLACE)
    co = t == COARSE
    lap = t == LAPLACE
    body = b"".join([
        varint_bytes([models.num_models]),
        varint_bytes(t),
        varint_bytes(zigzag(models.lo[nonempty])),
        varint_bytes(models.span[wide]),
        varint_bytes(models.prec[wide]),
        varint_bytes(models.group[co] | (models.binshift[co] << 2)),
        varint_bytes(models.centre[lap]),
        models.r_left[lap].astype(np.uint8).tobytes(),
        models.r_right[lap].astype(np.uint8).tobytes(),
        varint_bytes([b.size for b in models.bins]),
        # varints are self-delimiting: one call over the concatenated columns
        varint_bytes(np.concatenate([np.diff(b, prepend=-1) - 1 for b in models.bins])
                     if models.bins else np.zeros(0, np.int64)),
        varint_bytes(zigzag(np.concatenate([np.diff(q, prepend=0) for q in models.levels]))
                     if models.levels else np.zeros(0, np.int64)),
    ])
    packed = zstandard.ZstdCompressor(level=ZSTD_LEVEL, write_content_size=True,
                                      write_checksum=False).compress(body)
    if len(packed) < len(body):
        return varint_bytes([(len(packed) << 1) | 1]) + packed
    return varint_bytes([len(body) << 1]) + body


# ---- encoding ----------------------------------------------------------------------------------
def _coder_tables(models: ModelSet) -> dict:
    """The encoder's part of ModelSet.build() (same frequencies, no decoding LUT), vectorised:
    per present value of every non-empty model, in model order, ``freq`` and ``cum``; per model
    ``sym_start``; for COARSE models the present bins (``bin_key`` = model << 17 | bin, sorted)
    and the index of each bin's first value (``bin_first``)."""
    t = models.types
    m_count = models.num_models
    span, prec = models.span, models.prec
    k = np.zeros(m_count, np.int64)
    k[t == SINGLE] = 1
    lap = np.flatnonzero(t == LAPLACE)
    k[lap] = span[lap] + 1
    co = np.flatnonzero(t == COARSE)
    nb = np.array([b.size for b in models.bins], np.int64)
    allb = np.concatenate(models.bins).astype(np.int64) if co.size else np.zeros(0, np.int64)
    allq = np.concatenate(models.levels).astype(np.int64) if co.size else np.zeros(0, np.int64)
    bm = np.repeat(co, nb)
    sh = models.binshift[bm]
    bsize = np.minimum((allb + 1) << sh, span[bm] + 1) - (allb << sh)
    if co.size:
        k[co] = np.add.reduceat(bsize, np.cumsum(nb) - nb)
    sym_start = np.cumsum(k) - k
    size = int(k.sum())
    w = np.zeros(size, np.int64)
    w[sym_start[t == SINGLE]] = 1
    if lap.size:
        pos, _ = _expand(sym_start[lap], k[lap])
        rep = np.repeat(lap, k[lap])
        d = pos - sym_start[rep] - models.centre[rep]
        tabs = _LaplaceTables(np.concatenate([models.r_left[lap], models.r_right[lap]]),
                              int(span[lap].max()))
        w[pos] = tabs.weight(np.where(d < 0, models.r_left[rep], models.r_right[rep]), np.abs(d))
    bin_first = np.zeros(allb.size, np.int64)
    if co.size:
        pos, _ = _expand(sym_start[co], k[co])
        g = models.group[bm]
        qm = np.maximum(allq - 1, 0)
        lw = ((np.int64(1) << g) + (qm & ((np.int64(1) << g) - 1))) << (qm >> g)
        w[pos] = np.repeat(lw, bsize)
        csz = np.cumsum(bsize) - bsize
        first_bin = np.cumsum(nb) - nb
        bin_first = sym_start[bm] + csz - np.repeat(csz[first_bin], nb)
    # normalise_weights, per model
    used = np.flatnonzero(k > 0)
    freq = np.zeros(size, np.int64)
    if used.size:
        starts = sym_start[used]
        rep = np.repeat(np.arange(used.size), k[used])
        big_w = np.add.reduceat(w, starts)
        zero = big_w == 0
        if zero.any():
            w[np.isin(rep, np.flatnonzero(zero))] = 1
            big_w = np.add.reduceat(w, starts)
        total = np.int64(1) << prec[used]
        if np.any(k[used] > total):
            raise GszFormatError("rANS model: more symbols than 2**n")
        prod = w * (total - k[used])[rep]
        wr = big_w[rep]
        freq = 1 + prod // wr
        short = total - np.add.reduceat(freq, starts)
        rem = prod % wr
        for i in np.flatnonzero(short > 0).tolist():
            a = int(starts[i])
            r = rem[a:a + int(k[used[i]])]
            order = np.argsort(-r, kind="stable")
            freq[a + order[:int(short[i])]] += 1
    csum = np.cumsum(freq) - freq
    cum = csum - np.repeat(csum[sym_start[used]], k[used]) if size else csum
    return dict(freq=freq, cum=cum, sym_start=sym_start,
                bin_key=(bm << 17) | allb, bin_first=bin_first)


def _value_index(models: ModelSet, tabs: dict, mid: np.ndarray, off: np.ndarray) -> np.ndarray:
    """Index into tabs['freq'] of the values lo + off of models mid (ValueErrors as before:
    empty model, outside the range, zero frequency)."""
    t = models.types[mid]
    if np.any(t == EMPTY):
        raise ValueError("a symbol refers to an empty model")
    if np.any((off < 0) | (off > models.span[mid])):
        raise ValueError("a symbol lies outside its model's range")
    g = tabs["sym_start"][mid] + np.where(t == LAPLACE, off, 0)
    c = np.flatnonzero(t == COARSE)
    if c.size:
        e, ok = _coarse_entries(models, tabs, mid[c], off[c])
        if not ok.all():
            raise ValueError("a symbol has zero frequency in its model")
        g[c] = e
    return g


def _coarse_entries(models: ModelSet, tabs: dict, mc: np.ndarray, oc: np.ndarray):
    """(entry, present) of values lo + oc of COARSE models mc: the index into tabs['freq'] (its
    bin's first entry + the offset inside the bin; meaningless where not present) and whether
    the value's bin is in the model at all."""
    sh = models.binshift[mc]
    b = oc >> sh
    key = (mc << 17) | b
    bk = tabs["bin_key"]
    if not bk.size:
        return np.zeros(mc.size, np.int64), np.zeros(mc.size, bool)
    i = np.minimum(np.searchsorted(bk, key), bk.size - 1)
    return tabs["bin_first"][i] + (oc - (b << sh)), bk[i] == key


def _payload(freq: np.ndarray, cum: np.ndarray, shift: np.ndarray, lanes: int | None,
             entry: np.ndarray | None = None) -> bytes:
    """Interleaved rANS payload of symbols with (freq, cum, precision) each, in order; with
    ``entry`` the three are tables and symbol j takes row entry[j] (the C encoder reads them
    through the index: no per-symbol copies, 2 GB for a 45 x 862 k channel set)."""
    n = freq.size if entry is None else entry.size
    if lanes is None:
        bits_each = shift - np.log2(freq)
        bits = float((bits_each if entry is None else bits_each[entry]).sum()) if n else 0.0
        big_l = choose_lanes(n, bits)
    else:
        big_l = int(lanes)
    if not 1 <= big_l <= max(1, n):
        raise ValueError(f"lane count {big_l} invalid for {n} symbols")
    if native.enabled():
        # the same steps symbol by symbol in C (the row loop below costs ~70 ms per million
        # symbols in NumPy, a third of a size-search round on the flowers scene)
        c64 = (lambda a: np.ascontiguousarray(a, dtype=np.int64))
        index = () if entry is None else (
            np.ascontiguousarray(entry) if entry.dtype in (np.int32, np.int64) else c64(entry),)
        return native.module().rans_encode(c64(freq), c64(cum), np.ascontiguousarray(shift, np.uint8),
                                           big_l, *index)
    if entry is not None:
        freq, cum, shift = freq[entry], cum[entry], shift[entry]
    return _payload_numpy(freq, cum, shift, big_l)


def _payload_numpy(freq: np.ndarray, cum: np.ndarray, shift: np.ndarray, big_l: int) -> bytes:
    """The reference of :func:`_payload`'s bytes with the lane count fixed."""
    n = freq.size
    # One row of lanes per step, in place; each row's states before renormalisation and its
    # emit flags are kept, and the words (their low 16 bits) gathered at the end.
    x = np.full(big_l, STATE_LOW, dtype=np.int64)
    word_arr = np.zeros(0, "<u2")
    if n:
        xmax = freq << (32 - shift)                    # x_max = f * 2**(32 - n)
        rows = (n + big_l - 1) // big_l
        before = np.empty((rows, big_l), np.uint32)
        emit = np.zeros((rows, big_l), bool)
        sh = np.empty(big_l, np.uint8)
        q = np.empty(big_l, np.int64)
        rem = np.empty(big_l, np.int64)
        for r in range(rows - 1, -1, -1):
            a = r * big_l
            b = min(a + big_l, n)
            k = b - a
            xs, ek, sk, qk, rk = x[:k], emit[r, :k], sh[:k], q[:k], rem[:k]
            np.greater_equal(xs, xmax[a:b], out=ek)
            np.copyto(before[r, :k], xs, casting="unsafe")   # states < 2**32
            np.multiply(ek.view(np.uint8), WORD_BITS, out=sk)
            np.right_shift(xs, sk, out=xs)                   # emit: x >>= 16
            np.divmod(xs, freq[a:b], out=(qk, rk))
            np.left_shift(qk, shift[a:b], out=xs)            # x = (x // f) << n + x % f + c
            xs += rk
            xs += cum[a:b]
        word_arr = (before[emit] & 0xFFFF).astype("<u2")
    return b"".join([varint_bytes([big_l, word_arr.size]), x.astype("<u4").tobytes(),
                     word_arr.tobytes()])


def encode_symbols(symbols: np.ndarray, model_ids: np.ndarray, models: ModelSet,
                   lanes: int | None = None) -> bytes:
    """Payload (ENTROPY.md section 4) of ``symbols`` coded with ``models``, for RansDecoder.

    symbols, model_ids: int arrays (N,).  lanes: override of the lane count policy.
    """
    sym = np.asarray(symbols, dtype=np.int64).ravel()
    mid = np.asarray(model_ids, dtype=np.int64).ravel()
    if sym.size != mid.size:
        raise ValueError(f"{sym.size} symbols but {mid.size} model ids")
    n = sym.size
    if n and (mid.min() < 0 or mid.max() >= models.num_models):
        raise ValueError("model id out of range")
    if models.lut_entries() > lut_budget(n):
        raise ValueError("model set too large for this stream (decoder LUT budget, ENTROPY.md)")
    if not n:
        return _payload(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64),
                        lanes)
    tabs = _coder_tables(models)
    off = sym - models.lo[mid]
    dense = _dense_cells(models, tabs, n)
    if dense is None:
        g = _value_index(models, tabs, mid, off)
        return _payload(tabs["freq"][g], tabs["cum"][g], models.prec[mid], lanes)
    # few (model, value) cells next to the symbol count (the octree's model bank): look every
    # symbol's frequency and cumulative frequency up directly -- four passes over the symbols
    # instead of _value_index's dozen (its temporaries cost more in page faults than in work)
    _check_symbols(models, mid, off)
    cell = dense["start"][mid]
    cell += off
    freq = dense["freq"][cell]
    if not freq.all():
        raise ValueError("a symbol has zero frequency in its model")
    return _payload(freq, dense["cum"][cell], models.prec[mid], lanes)


#: Largest (model, value) cell table the dense lookup of encode_symbols builds, relative to the
#: symbol count (and absolute floor): beyond it _value_index's bin search is cheaper.
_DENSE_LOOKUP_PER_SYMBOL = 1
_DENSE_LOOKUP_MIN = 1 << 16


def _check_symbols(models: ModelSet, mid: np.ndarray, off: np.ndarray) -> None:
    """_value_index's first two checks (same errors, same precedence)."""
    if np.any(models.types == EMPTY) and np.any(models.types[mid] == EMPTY):
        raise ValueError("a symbol refers to an empty model")
    if np.any(off < 0) or np.any(off > models.span[mid]):
        raise ValueError("a symbol lies outside its model's range")


def _dense_cells(models: ModelSet, tabs: dict, n: int):
    """Per model a run of cells, one per value lo..lo + span, holding the frequency and the
    cumulative frequency the coder uses for that value (0 frequency where the value has no
    entry), or None when the cells would outnumber max(n, _DENSE_LOOKUP_MIN).  Cached in tabs.
    The entries are those _value_index finds: LAPLACE value v at sym_start + v, SINGLE at
    sym_start, COARSE at its bin's first entry + the offset inside the bin."""
    if "dense" in tabs:
        return tabs["dense"]
    t = models.types
    cells = np.where(t == EMPTY, 0, models.span + 1).astype(np.int64)
    total = int(cells.sum())
    if total > max(_DENSE_LOOKUP_PER_SYMBOL * n, _DENSE_LOOKUP_MIN):
        tabs["dense"] = None
        return None
    start = np.cumsum(cells) - cells
    entry = np.full(total, -1, np.int64)
    rep = np.repeat(np.arange(t.size), cells)
    off = np.arange(total, dtype=np.int64) - start[rep]
    lap = t[rep] == LAPLACE
    entry[lap] = tabs["sym_start"][rep[lap]] + off[lap]
    sgl = t[rep] == SINGLE
    entry[sgl] = tabs["sym_start"][rep[sgl]]
    co = np.flatnonzero(t[rep] == COARSE)
    if co.size:
        e, hit = _coarse_entries(models, tabs, rep[co], off[co])
        entry[co[hit]] = e[hit]
    has = entry >= 0
    freq = np.zeros(total, np.int64)
    cum = np.zeros(total, np.int64)
    freq[has] = tabs["freq"][entry[has]]
    cum[has] = tabs["cum"][entry[has]]
    tabs["dense"] = {"start": start, "freq": freq, "cum": cum}
    return tabs["dense"]


def _lanes_for(n: int, h: _Hist, e_freq: np.ndarray, e_shift: np.ndarray) -> int | None:
    """choose_lanes(n, ideal bits) from the entry counts, or None when rounding could matter
    (the exact sum over the symbols then decides, as encode_symbols)."""
    bits = float((h.ec * (e_shift - np.log2(e_freq))).sum())
    tol = 1e-7 * bits + 1.0
    lanes = choose_lanes(n, bits - tol)
    return lanes if lanes == choose_lanes(n, bits + tol) else None


def _encode_hist(h: _Hist, n: int) -> bytes:
    """encode_stream from the histograms (with symbol entries) of its n symbols."""
    return _coded(h, n, _hist_models(h, n))


def _hist_models(h: _Hist, n: int) -> tuple:
    """(models, their serialised set, coder tables or None) fitted to the histograms of ``h``
    (its entries only: no per-symbol work, so it may run beside another layout's coding)."""
    models = _fit_vectorised(h, validate=False)      # write_model_set validates
    if models.lut_entries() > lut_budget(n):
        raise ValueError("model set too large for this stream (decoder LUT budget, ENTROPY.md)")
    return models, write_model_set(models), (_coder_tables(models) if n else None)


def _coded(h: _Hist, n: int, fitted: tuple) -> bytes:
    """The stream of ``h``'s n symbols (``h.sym_entry``) under ``fitted`` (:func:`_hist_models`)."""
    models, header, tabs = fitted
    if n:
        g = _value_index(models, tabs, h.em, h.eo + h.lo[h.em] - models.lo[h.em])
        e_freq, e_cum, e_shift = tabs["freq"][g], tabs["cum"][g], models.prec[h.em]
        lanes = _lanes_for(n, h, e_freq, e_shift)
        payload = _payload(e_freq, e_cum, e_shift, lanes, entry=h.sym_entry)
    else:
        payload = _payload(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64),
                           None)
    return header + payload


def encode_stream(symbols: np.ndarray, model_ids: np.ndarray,
                  num_models: int | None = None) -> bytes:
    """Self-contained stream: fitted model set followed by the payload (decode_stream's input)."""
    mid = np.asarray(model_ids, dtype=np.int64).ravel()
    if num_models is None:
        num_models = int(mid.max()) + 1 if mid.size else 0
    sym = np.asarray(symbols, dtype=np.int64).ravel()
    return _encode_hist(_histograms(sym, mid, num_models, symbol_entries=True), sym.size)


def _merge_histograms(h: _Hist, merge: np.ndarray, num_models: int, *, reuse: bool | str = False):
    """The histograms of the same symbols with model ids merge[model id] (as _histograms).
    ``reuse``: ``h.sym_entry`` is rewritten into the result's (h's own entries are then gone):
    a second per-symbol int64 array would be 276 MB at 1.2 M kept SH vectors.  ``reuse`` "later"
    (h with symbol entries): (result without them, the entry map) -- :func:`_remap_entries`
    makes them once h's are no longer read."""
    m_count = int(num_models)
    merge = np.asarray(merge, dtype=np.int64)
    used = np.flatnonzero(h.k > 0)
    nm = merge[used]
    if nm.size and (nm.min() < 0 or nm.max() >= m_count):
        raise ValueError(f"model ids must lie in 0..{m_count - 1}")
    out = _Hist()
    out.num_models = m_count
    out.total = np.bincount(nm, weights=h.total[used], minlength=m_count).astype(np.int64) \
        if nm.size else np.zeros(m_count, np.int64)
    lo_all = np.full(m_count, np.iinfo(np.int64).max)
    hi_all = np.full(m_count, np.iinfo(np.int64).min)
    np.minimum.at(lo_all, nm, h.lo[used])
    np.maximum.at(hi_all, nm, h.lo[used] + h.span[used])
    has = out.total > 0
    lo = np.where(has, lo_all, 0)
    hi = np.where(has, hi_all, 0)
    span = hi - lo
    bad = (span > MAX_SPAN) | (lo < -VALUE_LIMIT) | (hi >= VALUE_LIMIT)
    if np.any(bad):
        m = int(np.flatnonzero(bad)[0])
        if span[m] > MAX_SPAN:
            raise ValueError(f"model {m}: value span {int(span[m])} exceeds 65536")
        raise ValueError(f"model {m}: values outside int32")
    size = np.where(has, span + 1, 0)
    ends = np.cumsum(size)
    dstart = ends - size
    cells = int(ends[-1]) if m_count else 0
    em_new = merge[h.em]
    key = dstart[em_new] + (h.lo[h.em] + h.eo - lo[em_new])
    if cells <= max(_DENSE_CELLS_MIN, _DENSE_CELLS_PER_SYMBOL * h.em.size):
        dense = np.bincount(key, weights=h.ec, minlength=cells)    # exact: counts < 2**53
        pos = np.flatnonzero(dense)
        cnt = dense[pos].astype(np.int64)
        rank = np.zeros(cells, np.int64)
        rank[pos] = np.arange(pos.size, dtype=np.int64)
        emap = rank[key]
    else:
        pos, emap = np.unique(key, return_inverse=True)
        emap = emap.ravel()
        cnt = np.bincount(emap, weights=h.ec, minlength=pos.size).astype(np.int64)
    em = np.searchsorted(ends, pos, side="right").astype(np.int64)
    out.em, out.eo, out.ec = em, pos - dstart[em], cnt
    out.lo, out.span = lo, span
    out.k = np.bincount(em, minlength=m_count).astype(np.int64) if em.size \
        else np.zeros(m_count, np.int64)
    out.start = np.cumsum(out.k) - out.k
    out.sym_entry = None
    if h.sym_entry is not None:
        if reuse == "later":
            return out, emap
        _remap_entries(h, out, emap, reuse)
    return out


def _remap_entries(h: _Hist, out: _Hist, emap: np.ndarray, reuse) -> None:
    """``out.sym_entry``: every symbol's entry of ``h`` mapped by ``emap`` (its merged entry);
    ``reuse``: in h's own array, which h then loses."""
    if reuse:
        out.sym_entry, h.sym_entry = h.sym_entry, None
        for a in range(0, out.sym_entry.size, _REMAP_CHUNK):
            part = out.sym_entry[a:a + _REMAP_CHUNK]
            part[...] = emap[part]
    else:
        out.sym_entry = emap[h.sym_entry]


#: symbols remapped per step by _merge_histograms(reuse=True) (bounds its temporaries)
_REMAP_CHUNK = 1 << 20


def encode_stream_pair(symbols: np.ndarray, model_ids: np.ndarray, num_models: int,
                       merge: np.ndarray, merged_models: int) -> tuple[bytes, bytes]:
    """(encode_stream(symbols, model_ids, num_models),
    encode_stream(symbols, merge[model_ids], merged_models)): the same bytes, one pass over the
    symbols (the second layout's histograms are merged from the first's)."""
    mid = np.asarray(model_ids, dtype=np.int64).ravel()
    sym = np.asarray(symbols, dtype=np.int64).ravel()
    h = _histograms(sym, mid, num_models, symbol_entries=True)
    del sym, mid                      # the entries say all the rest needs
    return _encode_pair(h, merge, merged_models)


def encode_group_streams(symbols, lens: np.ndarray, merge: np.ndarray,
                         merged_models: int) -> tuple[bytes, bytes]:
    """:func:`encode_stream_pair` of a [C, L] channel set whose model ids are its (channel,
    block) groups c * B + block, blocks of ``lens`` symbols (GSZ.md §5 model mode 0): the same
    bytes, without a per-symbol model-id array.  ``symbols``: as :func:`_histograms_rows`."""
    return _encode_pair(_histograms_rows(symbols, lens), merge, merged_models)


def _encode_pair(h: _Hist, merge: np.ndarray, merged_models: int) -> tuple[bytes, bytes]:
    n = int(h.total.sum())
    if h.sym_entry is None:
        return _encode_hist(h, n), _encode_hist(_merge_histograms(h, merge, merged_models), n)
    # the merged layout's models are fitted while the first layout is coded (both read only
    # histogram entries); its symbols' entries then overwrite the first layout's
    merged, emap = _merge_histograms(h, merge, merged_models, reuse="later")
    first, fitted = thread_map(lambda i: _encode_hist(h, n) if i == 0 else _hist_models(merged, n), 2)
    _remap_entries(h, merged, emap, reuse=True)
    return first, _coded(merged, n, fitted)
