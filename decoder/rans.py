"""Interleaved rANS entropy decoder of the .gsz bitstream (numpy only).

Normative description: ``format_spec/ENTROPY.md``.  This module is the shared truth for the
encoder (``gsz.encoder.rans``), which imports its constants, the model-parameter container
:class:`ModelSet`, the frequency normalisation :func:`normalise_weights` and the table builders.

Summary of the scheme
---------------------
* A *model set* holds M frequency tables (models).  Model m has precision ``n_m`` in 0..16
  (total ``T_m = 2**n_m``) and integer frequencies over a contiguous value range; symbols are
  signed integers.
* Symbol j (0-based) is coded on lane ``j % L``; 32-bit states in ``[2**16, 2**32)``; one shared
  stream of 16-bit words, read in symbol order: after decoding symbol j, if the state of its lane
  is below ``2**16`` the next word is shifted in.  At most one word per symbol.
* The decoder processes one *row* of up to L consecutive symbols (= L lanes) per numpy step, so a
  row of symbols costs ~10 vectorised operations.
"""
from __future__ import annotations

import threading
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from . import native
from .errors import GszFormatError

# ---- constants (normative, see ENTROPY.md) ---------------------------------------------------
STATE_LOW = 1 << 16          # lower bound of a normalised state; also the encoder's start state
STATE_BITS = 32              # states are < 2**32
WORD_BITS = 16               # renormalisation words are 16-bit
MAX_PRECISION = 16           # n_m <= 16 keeps every renormalisation to at most one word
MAX_SPAN = 1 << 16           # hi - lo <= 65536, i.e. alphabets of at most 2**16 + 1 values
VALUE_LIMIT = 1 << 31        # every lo and hi lies in [-2**31, 2**31)
MAX_MODELS = 1 << 20
MAX_TABLE_BYTES = 1 << 24    # decompressed model-set body limit (hostile zstd frames)
MIN_LUT_BUDGET = 1 << 16     # sum over used models of 2**n_m <= max(MIN_LUT_BUDGET, 4 * N)
LUT_PER_SYMBOL = 4
# Lanes a payload of N symbols needs: L >= min(LANES_REQUIRED_CAP, ceil(N / max_rows)), so that
# the decoder steps through at most max_rows rows of lanes (a one-lane stream of millions of free
# SINGLE symbols forced the NumPy decoder into a per-symbol loop: issue 19); max_rows is
# MAX_ROWS for a RansStream, OCTREE_MAX_ROWS for the octree payload (its encoder's 16384 symbols
# per lane round down).
MAX_ROWS = 8192
OCTREE_MAX_ROWS = 32768
LANES_REQUIRED_CAP = 4096

# model types
EMPTY, SINGLE, COARSE, LAPLACE = 0, 1, 2, 3
TYPE_NAMES = {EMPTY: "empty", SINGLE: "single", COARSE: "coarse", LAPLACE: "laplace"}

# COARSE weight levels: q >= 1 -> ((2**g + m) << e) with e = (q-1) >> g, m = (q-1) & (2**g-1)
MAX_LEVEL_GROUPS = 4         # g in 0..3
MAX_LEVEL_EXP = 24           # e <= 24, so weights < 2**28 and all products fit in int64
LAPLACE_SCALE_BITS = 24      # LAPLACE weights are floor(v_d * 2**24)
RATIO_ONE = 1 << 16          # LAPLACE ratios are r / 2**16 with r in 0..65535


def max_level_code(g: int) -> int:
    """Largest valid COARSE level code q for level-group exponent g."""
    return (MAX_LEVEL_EXP + 1) << g


def level_weights(q: np.ndarray, g: int) -> np.ndarray:
    """COARSE level codes -> integer weights; q == 0 maps to 0 (symbol absent).

    q: int64 array with 0 <= q <= max_level_code(g).  Returns int64 weights < 2**28.
    """
    q = np.asarray(q, dtype=np.int64)
    qm = np.maximum(q - 1, 0)
    w = ((np.int64(1) << g) + (qm & ((1 << g) - 1))) << (qm >> g)
    return np.where(q > 0, w, 0).astype(np.int64)


def ratio_from_code(u: int) -> int:
    """LAPLACE ratio code u (0..255) -> ratio numerator r (ratio r / 2**16), integer only:
    r = 65536 - (((16 + (u & 15)) << 16) >> ((u >> 4) + 5)); covers 1 - r/65536 from ~0.97
    down to 2**-16 in steps of 1/16..1/32 relative."""
    return RATIO_ONE - (((16 + (u & 15)) << 16) >> ((u >> 4) + 5))


def laplace_weights(span: int, centre: int, r_left: int, r_right: int) -> np.ndarray:
    """LAPLACE model weights over offsets 0..span (value lo + i), int64 in [0, 2**24].

    v_0 = 1.0, v_d = v_{d-1} * (r / 65536) as sequential IEEE-754 binary64 products (exact
    specification: every language reproduces a sequential product of correctly rounded
    multiplications), w = floor(v_d * 2**24); d = |i - centre|, r = r_left left of the centre,
    r_right right of it.
    """
    def side(length: int, r: int) -> np.ndarray:
        if length <= 0:
            return np.zeros(0, dtype=np.int64)
        steps = np.full(length, r / RATIO_ONE, dtype=np.float64)
        v = np.multiply.accumulate(steps)            # sequential left-to-right products
        return np.floor(v * float(1 << LAPLACE_SCALE_BITS)).astype(np.int64)

    left = side(centre, r_left)[::-1]                # offsets centre-1 .. 0 -> reversed
    right = side(span - centre, r_right)
    return np.concatenate([left, np.array([1 << LAPLACE_SCALE_BITS], dtype=np.int64), right])


def normalise_weights(w: np.ndarray, n: int) -> np.ndarray:
    """Normative integer normalisation of weights to frequencies summing to 2**n.

    w: int64 array (length K >= 1, K <= 2**n, every entry 0 <= w < 2**40).  Every entry gets
    frequency >= 1 (the caller passes only the symbols that must be codable).  Procedure:
    if sum(w) == 0 every w is taken as 1; then with R = 2**n - K:
    f_i = 1 + (R * w_i) // W, remainder r_i = (R * w_i) % W; the d = 2**n - sum(f) symbols with
    the largest r_i (ties: lower index first) get +1.  Returns int64 frequencies.
    """
    w = np.asarray(w, dtype=np.int64)
    k = w.size
    total = 1 << n
    if k < 1 or k > total:
        raise GszFormatError(f"rANS model: {k} symbols do not fit precision {n}")
    big_w = int(w.sum())
    if big_w == 0:
        w = np.ones(k, dtype=np.int64)
        big_w = k
    r = total - k
    prod = w * r                                      # < 2**56: no overflow
    f = 1 + prod // big_w
    d = total - int(f.sum())
    if d > 0:
        rem = prod % big_w
        order = np.argsort(-rem, kind="stable")       # descending remainder, ties by index
        f[order[:d]] += 1
    return f


# ---- byte helpers ------------------------------------------------------------------------------
def read_varint(buf: np.ndarray, pos: int, what: str) -> tuple[int, int]:
    """Read one unsigned LEB128 varint (at most 9 bytes, value < 2**63)."""
    value = 0
    for i in range(9):
        if pos >= buf.size:
            raise GszFormatError(f"rANS: truncated varint ({what})")
        b = int(buf[pos])
        pos += 1
        value |= (b & 0x7F) << (7 * i)
        if b < 0x80:
            return value, pos
    raise GszFormatError(f"rANS: varint too long ({what})")


def read_varints(buf: np.ndarray, pos: int, count: int, what: str) -> tuple[np.ndarray, int]:
    """Read ``count`` consecutive unsigned LEB128 varints (each <= 9 bytes), vectorised.

    Returns (int64 array, new position).  Raises GszFormatError when truncated or overlong.
    """
    if count < 0 or count > buf.size - pos:
        raise GszFormatError(f"rANS: {count} varints ({what}) cannot fit in {buf.size - pos} bytes")
    if count == 0:
        return np.zeros(0, dtype=np.int64), pos
    if native.enabled():
        out = np.empty(count, dtype=np.int64)
        end = native.module().read_varints(buf, pos, count, out)
        if end == -1:
            raise GszFormatError(f"rANS: truncated varint array ({what})")
        if end == -2:
            raise GszFormatError(f"rANS: varint too long ({what})")
        return out, end
    window = buf[pos:pos + 9 * count]
    ends = np.flatnonzero(window < 0x80)
    if ends.size < count:
        raise GszFormatError(f"rANS: truncated varint array ({what})")
    ends = ends[:count]
    starts = np.empty(count, dtype=np.int64)
    starts[0] = 0
    starts[1:] = ends[:-1] + 1
    lengths = ends - starts + 1
    if lengths.max() > 9:
        raise GszFormatError(f"rANS: varint too long ({what})")
    used = window[:ends[-1] + 1].astype(np.uint64)
    grp = np.repeat(np.arange(count), lengths)
    shift = (np.arange(used.size) - starts[grp]).astype(np.uint64) * np.uint64(7)
    vals = np.add.reduceat((used & np.uint64(0x7F)) << shift, starts)
    return vals.astype(np.int64), pos + int(ends[-1]) + 1


def unzigzag(u: np.ndarray) -> np.ndarray:
    """Zigzag-decoded signed values: 0,1,2,3,4 -> 0,-1,1,-2,2 (int64)."""
    u = np.asarray(u, dtype=np.int64)
    return (u >> 1) ^ -(u & 1)


# ---- model set ---------------------------------------------------------------------------------
@dataclass
class ModelSet:
    """M frequency tables (the parameters as serialised, plus lazily built decoding tables).

    Parameters (one entry per model, int64 arrays of length M):
      types  : EMPTY / SINGLE / COARSE / LAPLACE
      lo     : smallest value of the model's range (0 for EMPTY)
      span   : hi - lo (0 for EMPTY and SINGLE), <= 65536
      prec   : precision n_m (0 for SINGLE and EMPTY), <= 16
      group  : COARSE level-group exponent g in 0..3 (0 otherwise)
      binshift : COARSE bin shift h in 0..16: one level code per bin of 2**h values (0 otherwise)
      centre : LAPLACE centre offset in 0..span (0 otherwise)
      r_left, r_right : LAPLACE ratio codes in 0..255 (see ratio_from_code; 0 otherwise)
      bins, levels : tuples (one entry per COARSE model, in model order) of int64 arrays: the
               indices of the present bins (strictly increasing, first 0, last span >> h) and
               their level codes (1..max_level_code(g)); absent bins are not stored

    Built tables (``build()``): per present symbol of every model, concatenated in model order:
      freq, cum (start within its model's [0, 2**n)), value, slot_start (= lut_base of its model
      + cum: its first global slot); ``sym_start[m]`` = first index of model m, ``sym_count[m]``;
      ``lut_base[m]`` = offset of model m's 2**n_m slots in the global slot range.
    ``slot_symbols()`` (on demand): ``lut[lut_base[m] + slot]`` = global symbol index.
    """

    types: np.ndarray
    lo: np.ndarray
    span: np.ndarray
    prec: np.ndarray
    group: np.ndarray
    centre: np.ndarray
    r_left: np.ndarray
    r_right: np.ndarray
    binshift: np.ndarray | None = None
    bins: tuple = ()
    levels: tuple = ()
    _tables: dict | None = field(default=None, repr=False, compare=False)
    _ntables: tuple | None = field(default=None, repr=False, compare=False)
    #: (bin counts, all bins, all levels) of the COARSE models as flat int64 arrays, when the
    #: parser has them (read_model_set); else built from ``bins``/``levels`` on demand
    _flat: tuple | None = field(default=None, repr=False, compare=False)

    @property
    def num_models(self) -> int:
        return int(self.types.size)

    def __post_init__(self):
        if self.binshift is None:
            self.binshift = np.zeros_like(self.types)

    def lut_entries(self) -> int:
        """Size of the decoding LUT, sum over non-empty models of 2**n_m."""
        used = self.types != EMPTY
        return int((np.int64(1) << self.prec[used]).sum())

    def model_weights(self, m: int) -> tuple[np.ndarray, np.ndarray]:
        """(offsets within [0, span] of the present symbols, their weights) of model m."""
        t = int(self.types[m])
        if t == SINGLE:
            return np.zeros(1, np.int64), np.ones(1, np.int64)
        if t == COARSE:
            i = int(self._coarse_index()[m])
            bins, q = self.bins[i], self.levels[i]
            h = int(self.binshift[m])
            sizes = np.minimum((bins + 1) << h, int(self.span[m]) + 1) - (bins << h)
            starts = np.repeat(bins << h, sizes)
            within = np.arange(starts.size) - np.repeat(np.cumsum(sizes) - sizes, sizes)
            return starts + within, np.repeat(level_weights(q, int(self.group[m])), sizes)
        if t == LAPLACE:
            span = int(self.span[m])
            return (np.arange(span + 1, dtype=np.int64),
                    laplace_weights(span, int(self.centre[m]),
                                    ratio_from_code(int(self.r_left[m])),
                                    ratio_from_code(int(self.r_right[m]))))
        raise ValueError(f"model {m} is empty")

    def _coarse_index(self) -> np.ndarray:
        return np.cumsum(self.types == COARSE) - 1

    def build(self, max_lut_entries: int | None = None) -> dict:
        """Build (once) the decoding tables; ``max_lut_entries`` bounds memory on hostile input."""
        lut_total = self.lut_entries()
        if max_lut_entries is not None and lut_total > max_lut_entries:
            raise GszFormatError(f"rANS: model set needs {lut_total} LUT entries, "
                                 f"more than the {max_lut_entries} this stream allows")
        if self._tables is not None:
            return self._tables
        m_count = self.num_models
        sym_count, off, w = _symbol_weights(self)
        freq = _normalise_all(w, sym_count, self.prec)
        value = off + np.repeat(self.lo, sym_count)
        sym_start = np.zeros(m_count, dtype=np.int64)
        if m_count:
            sym_start[1:] = np.cumsum(sym_count)[:-1]
        # exclusive prefix sum within each model
        csum = np.cumsum(freq) - freq
        cum = csum - np.repeat(csum[sym_start[sym_count > 0]], sym_count[sym_count > 0]) \
            if freq.size else csum
        total = np.where(self.types != EMPTY, np.int64(1) << self.prec, 0)
        lut_base = np.zeros(m_count, dtype=np.int64)
        if m_count:
            lut_base[1:] = np.cumsum(total)[:-1]
        # models' slot ranges are consecutive, so a symbol's first global slot is the running
        # total of the frequencies before it, and slot - cum = global slot - slot_start
        slot_start = np.cumsum(freq) - freq
        used = self.types != EMPTY
        uniform = bool(used.any()) and int(self.prec[used].min()) == int(self.prec[used].max())
        self._tables = dict(freq=freq, cum=cum, value=value, slot_start=slot_start,
                            sym_start=sym_start, sym_count=sym_count, lut_base=lut_base,
                            total=total, mask=total - 1,
                            uniform_prec=int(self.prec[used][0]) if uniform else None,
                            has_empty=bool((~used).any()))
        # binary models of one precision with values 0 and 1 (the octree bank, flag streams):
        # the row loop decides a symbol by one comparison with the frequency of the 0
        if (uniform and not self._tables["has_empty"] and np.all(sym_count == 2)
                and np.array_equal(value, np.tile(np.array([0, 1], np.int64), m_count))):
            self._tables["binary_f0"] = freq[sym_start]
        return self._tables

    def slot_symbols(self) -> np.ndarray:
        """The NumPy decoder's LUT (once, after :meth:`build`): the global symbol index of every
        global slot, int32 [lut_entries()] (int64 past 2**31 symbols).  One narrow entry per
        slot: symbols' freq/slot_start/value are read from the small per-symbol tables, which
        stay in cache while the per-slot table (2**16 slots per model) does not."""
        t = self._tables
        if "lut_symbol" not in t:
            freq = t["freq"]
            dtype = np.int32 if freq.size < (1 << 31) else np.int64
            t["lut_symbol"] = np.repeat(np.arange(freq.size, dtype=dtype), freq)
        return t["lut_symbol"]

    def model_slot_symbols(self, m: int) -> tuple[np.ndarray, dict]:
        """Model m's own LUT and tables (after :meth:`build`), for a run of its symbols: the
        index within the model of the symbol owning each of its slots 0 .. 2**n_m - 1 (int32),
        and its symbols' freq, slot_start (= cum, its slots counted from 0) and value.  Made
        per call (at most 2**16 entries, cache-resident), so a stream decoded in runs never
        needs the whole set's LUT."""
        t = self._tables
        first, count = int(t["sym_start"][m]), int(t["sym_count"][m])
        own = slice(first, first + count)
        lut = np.repeat(np.arange(count, dtype=np.int32), t["freq"][own])
        return lut, dict(freq=t["freq"][own], slot_start=t["cum"][own], value=t["value"][own])

    def native_tables(self, max_lut_entries: int, lut: bool = True) -> tuple:
        """Build (once) the compact decoding tables of the C decoder (``_native.rans_tables``:
        same frequencies as :meth:`build`); ``max_lut_entries`` as there.  ``lut=False``: without
        the set's LUT (None), enough for block decoding, which makes one model's LUT at a time
        (tables with a LUT serve both)."""
        lut_total = self.lut_entries()
        if lut_total > max_lut_entries:
            raise GszFormatError(f"rANS: model set needs {lut_total} LUT entries, "
                                 f"more than the {max_lut_entries} this stream allows")
        if self._ntables is None or (lut and self._ntables[0] is None):
            c64 = (lambda a: np.ascontiguousarray(a, dtype=np.int64))
            self._ntables = native.module().rans_tables(
                c64(self.types), c64(self.lo), c64(self.span), c64(self.prec), c64(self.group),
                c64(self.binshift), c64(self.centre), c64(self.r_left), c64(self.r_right),
                *(c64(a) for a in self.coarse_flat()),
                int(max_lut_entries), bool(lut))
        return self._ntables

    def coarse_flat(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(bins per COARSE model, every bin, every level code) as flat int64 arrays, in model
        order (``bins``/``levels`` concatenated)."""
        if self._flat is None:
            cat = (lambda xs: np.concatenate(xs).astype(np.int64, copy=False) if len(xs)
                   else np.zeros(0, np.int64))
            self._flat = (np.fromiter((b.size for b in self.bins), dtype=np.int64,
                                      count=len(self.bins)), cat(self.bins), cat(self.levels))
        return self._flat

    def validate(self) -> None:
        """Static constraints of ENTROPY.md section 3 (raises GszFormatError)."""
        t, lo, span, n = self.types, self.lo, self.span, self.prec
        if np.any((t < 0) | (t > 3)):
            raise GszFormatError("rANS model set: unknown model type")
        nonempty = t != EMPTY
        if np.any(nonempty & ((lo < -VALUE_LIMIT) | (lo + span >= VALUE_LIMIT))):
            raise GszFormatError("rANS model set: value range outside [-2**31, 2**31)")
        if np.any(span < 0) or np.any(span > MAX_SPAN):
            raise GszFormatError("rANS model set: alphabet span above 65536")
        if np.any(n < 0) or np.any(n > MAX_PRECISION):
            raise GszFormatError("rANS model set: precision above 16")
        single = t == SINGLE
        if np.any((single | (t == EMPTY)) & ((span != 0) | (n != 0))):
            raise GszFormatError("rANS model set: single/empty model with a span or precision")
        lap = t == LAPLACE
        if np.any(lap & (span + 1 > (np.int64(1) << n))):
            raise GszFormatError("rANS model set: laplace support larger than 2**n")
        if np.any(lap & ((self.centre < 0) | (self.centre > span))):
            raise GszFormatError("rANS model set: laplace centre outside the range")
        if np.any((self.r_left < 0) | (self.r_left > 255) | (self.r_right < 0)
                  | (self.r_right > 255)) or np.any((self.r_left | self.r_right)[~lap]):
            raise GszFormatError("rANS model set: laplace ratio code outside 0..255")
        if np.any(self.centre[~lap]):
            raise GszFormatError("rANS model set: centre on a non-laplace model")
        co = np.flatnonzero(t == COARSE)
        if np.any(self.group[co] >= MAX_LEVEL_GROUPS):
            raise GszFormatError("rANS model set: coarse level group above 3")
        if np.any((self.binshift < 0) | (self.binshift > 16)) or np.any(self.binshift[t != COARSE]):
            raise GszFormatError("rANS model set: coarse bin shift outside 0..16")
        if len(self.bins) != co.size or len(self.levels) != co.size:
            raise GszFormatError("rANS model set: coarse code arrays missing")
        if not co.size:
            return
        # every COARSE model at once (a per-model loop cost ~15 us per model: 50 ms for the
        # 3600 models of an SH-3 codebook); the same checks as model by model
        if self._flat is None:
            nq = np.fromiter((q.size for q in self.levels), dtype=np.int64, count=co.size)
            if np.any(self.coarse_flat()[0] != nq):
                raise GszFormatError("rANS model set: coarse model without bins")
        nb, allb, allq = self.coarse_flat()
        if np.any(nb == 0) or allb.size != allq.size:
            raise GszFormatError("rANS model set: coarse model without bins")
        first = np.cumsum(nb) - nb
        last = first + nb - 1
        h = self.binshift[co]
        step = np.diff(allb)
        inner = np.ones(step.size, dtype=bool)
        inner[last[:-1]] = False                     # differences across two models
        if (np.any(allb[first] != 0) or np.any(allb[last] != span[co] >> h)
                or np.any(step[inner] <= 0)):
            raise GszFormatError("rANS model set: coarse bins not increasing over the range")
        qmax = np.repeat((MAX_LEVEL_EXP + 1) << self.group[co], nb)
        if np.any(allq < 1) or np.any(allq > qmax):
            raise GszFormatError("rANS model set: coarse level code out of range")
        hb = np.repeat(h, nb)
        sizes = np.minimum((allb + 1) << hb, np.repeat(span[co], nb) + 1) - (allb << hb)
        if np.any(np.add.reduceat(sizes, first) > (np.int64(1) << n[co])):
            raise GszFormatError("rANS model set: more coarse symbols than 2**n")


def _expand(starts: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """Concatenated ranges start .. start + length - 1."""
    out = np.arange(int(lengths.sum()), dtype=np.int64)
    out += np.repeat(starts - (np.cumsum(lengths) - lengths), lengths)
    return out


def _symbol_weights(ms: ModelSet) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:meth:`ModelSet.model_weights` of every model at once: (present symbols per model,
    then per symbol in model order its offset within [0, span] and its weight).  The work is
    linear in the number of symbols, at most the LUT size (sum of 2**n) that build() bounds."""
    t, span = ms.types, ms.span
    k = np.zeros(ms.num_models, dtype=np.int64)
    k[t == SINGLE] = 1
    lap = np.flatnonzero(t == LAPLACE)
    k[lap] = span[lap] + 1
    co = np.flatnonzero(t == COARSE)
    nb, allb, allq = ms.coarse_flat() if co.size else (np.zeros(0, np.int64),) * 3
    bm = np.repeat(co, nb)                         # model of every COARSE bin
    h = ms.binshift[bm]
    bsize = np.minimum((allb + 1) << h, span[bm] + 1) - (allb << h)
    if co.size:
        k[co] = np.add.reduceat(bsize, np.cumsum(nb) - nb)
    start = np.cumsum(k) - k
    off = np.zeros(int(k.sum()), dtype=np.int64)
    w = np.zeros_like(off)
    w[start[t == SINGLE]] = 1
    if co.size:
        pos = _expand(start[co], k[co])
        off[pos] = _expand(allb << h, bsize)
        w[pos] = np.repeat(level_weights_groups(allq, ms.group[bm]), bsize)
    if lap.size:
        pos = _expand(start[lap], k[lap])
        rep = np.repeat(lap, k[lap])
        o = pos - start[rep]
        off[pos] = o
        d = o - ms.centre[rep]
        w[pos] = _laplace_table_weights(np.where(d < 0, ms.r_left[rep], ms.r_right[rep]),
                                        np.abs(d))
    return k, off, w


def level_weights_groups(q: np.ndarray, g: np.ndarray) -> np.ndarray:
    """:func:`level_weights` with a level-group exponent per code (q >= 1 here)."""
    qm = np.maximum(q - 1, 0)
    return ((np.int64(1) << g) + (qm & ((np.int64(1) << g) - 1))) << (qm >> g)


def _laplace_table_weights(code: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """LAPLACE weights floor(v_d * 2**24) of ratio codes ``code`` at distances ``dist`` (2**24 at
    0): per distinct code one sequential product up to the largest distance it is asked for
    (laplace_weights' exact products; their total length is at most the symbol count)."""
    out = np.full(code.shape[0], 1 << LAPLACE_SCALE_BITS, dtype=np.int64)
    far = dist > 0
    c, d = code[far], dist[far]
    if not c.size:
        return out
    longest = np.zeros(256, dtype=np.int64)
    np.maximum.at(longest, c, d)
    base = np.zeros(256, dtype=np.int64)
    tables = []
    pos = 0
    for u in np.flatnonzero(longest).tolist():
        steps = np.full(int(longest[u]), ratio_from_code(u) / RATIO_ONE, dtype=np.float64)
        tables.append(np.floor(np.multiply.accumulate(steps) * float(1 << LAPLACE_SCALE_BITS)))
        base[u] = pos
        pos += int(longest[u])
    out[far] = np.concatenate(tables).astype(np.int64)[base[c] + d - 1]
    return out


def _normalise_all(w: np.ndarray, k: np.ndarray, prec: np.ndarray) -> np.ndarray:
    """:func:`normalise_weights` of every model at once (k symbols of model m, its weights
    consecutive in ``w``; models with k = 0 are skipped): the same frequencies, the +1s going
    to the largest remainders of each model (ties: lower index first) through one sort."""
    used = np.flatnonzero(k > 0)
    if not used.size:
        return np.zeros(0, dtype=np.int64)
    ku = k[used]
    total = np.int64(1) << prec[used]
    bad = np.flatnonzero(ku > total)
    if bad.size:
        raise GszFormatError(f"rANS model: {int(ku[bad[0]])} symbols do not fit precision "
                             f"{int(prec[used[bad[0]]])}")
    starts = np.cumsum(ku) - ku
    rep = np.repeat(np.arange(used.size), ku)
    big_w = np.add.reduceat(w, starts)
    if np.any(big_w == 0):                       # every weight 0: all taken as 1
        w = np.where((big_w == 0)[rep], 1, w)
        big_w = np.add.reduceat(w, starts)
    prod = w * (total - ku)[rep]                 # < 2**56: no overflow
    wr = big_w[rep]
    f = 1 + prod // wr
    short = total - np.add.reduceat(f, starts)
    if np.any(short > 0):
        # within each model: descending remainder, ties by index (a stable sort of -rem)
        rem = prod % wr
        top = int(big_w.max())
        if top.bit_length() + int(used.size).bit_length() <= 62:
            # one stable sort of (model, top - 1 - rem) packed in an int64: the same order as
            # the lexsort below, ~6x faster (1.3 M symbols of 560 models: 48 -> 8 ms)
            order = np.argsort((rep.astype(np.int64) << top.bit_length()) | (top - 1 - rem),
                               kind="stable")
        else:
            order = np.lexsort((-rem, rep))
        rank = np.arange(f.size) - np.repeat(starts, ku)
        f[order[rank < short[rep]]] += 1
    return f


_ZSTD = threading.local()     # one decompression context per thread (~20 us to create)


def body_bound(max_models: int, num_symbols: int) -> int:
    """Longest valid model-set body with at most ``max_models`` models for a stream of
    ``num_symbols`` symbols (ENTROPY.md 3.1): every varint <= 9 bytes (7 varint columns per
    model, 2 ratio bytes) and Σ nbins <= lut_budget(N) (each bin holds >= 1 value of 2**n)."""
    return 9 + 65 * int(max_models) + 18 * lut_budget(num_symbols)


def _unzstd(frame: bytes, limit: int = MAX_TABLE_BYTES) -> bytes:
    """Decompress exactly one zstd frame that declares its content size (<= ``limit``), the
    size checked before anything is decompressed."""
    import zstandard
    dctx = getattr(_ZSTD, "dctx", None)
    if dctx is None:
        dctx = _ZSTD.dctx = zstandard.ZstdDecompressor()
    try:
        size = zstandard.get_frame_parameters(frame).content_size
        if size == zstandard.CONTENTSIZE_UNKNOWN or size > MAX_TABLE_BYTES:
            raise GszFormatError(f"rANS model set: zstd frame content size {size} missing or "
                                 f"above {MAX_TABLE_BYTES}")
        if size > limit:
            raise GszFormatError(f"rANS model set: zstd frame content size {size} above {limit}, "
                                 "the longest valid body for this stream")
        out = dctx.decompress(frame, max_output_size=MAX_TABLE_BYTES, allow_extra_data=False)
        if size == 0:
            # allow_extra_data=False does not see bytes after an empty frame (zstandard 0.25)
            obj = dctx.decompressobj()
            obj.decompress(frame)
            if not obj.eof or obj.unused_data:
                raise GszFormatError("rANS model set: bytes after the zstd frame")
    except zstandard.ZstdError as exc:
        if "unused data" in str(exc):
            raise GszFormatError("rANS model set: bytes after the zstd frame") from None
        raise GszFormatError(f"rANS model set: bad zstd frame ({exc})") from None
    if len(out) != size:
        raise GszFormatError("rANS model set: zstd content size mismatch")
    return out


def read_model_set(buf: memoryview | bytes, pos: int = 0, *, max_models: int | None = None,
                   num_symbols: int | None = None) -> tuple[ModelSet, int]:
    """Parse a model set (ENTROPY.md section 3) starting at ``pos``.

    max_models   the most models the stream's use can name (ChannelSet: C*B or 16*C; SHVQ
                 streams: 1), None: MAX_MODELS; more is rejected before the models are read
    num_symbols  the stream's N when known: a body longer than any valid one for N and
                 max_models (:func:`body_bound`) is rejected before it is decompressed
    Returns (ModelSet, position after it).  Decoding tables are built lazily by the decoder.
    """
    b = np.frombuffer(buf, dtype=np.uint8)
    head, pos = read_varint(b, pos, "model-set length")
    length, compressed = head >> 1, head & 1
    if length > b.size - pos:
        raise GszFormatError(f"rANS model set: {length} bytes declared, {b.size - pos} available")
    raw = bytes(b[pos:pos + length])
    pos += length
    cap = MAX_MODELS if max_models is None else min(MAX_MODELS, int(max_models))
    limit = MAX_TABLE_BYTES if num_symbols is None else body_bound(cap, num_symbols)
    if compressed:
        raw = _unzstd(raw, min(limit, MAX_TABLE_BYTES))
    elif len(raw) > limit:
        raise GszFormatError(f"rANS model set: body of {len(raw)} bytes, above {limit}, "
                             "the longest valid body for this stream")
    if max_models is not None:
        m_count = read_varint(np.frombuffer(raw, dtype=np.uint8), 0, "model count")[0]
        if m_count > max_models:
            raise GszFormatError(f"rANS model set: {m_count} models, more than the {max_models} "
                                 "its use can name")
    if native.enabled():
        # the C parser makes the same accept/reject decision and the same arrays; on a reject it
        # returns None and the NumPy parser below raises the normative message (~0.5 ms of
        # NumPy calls per set was a third of a small file's decode)
        parsed = native.module().model_set_parse(raw)
        if parsed is not None:
            return _model_set_from_native(parsed), pos
    return _parse_model_set_body(raw), pos


def _model_set_from_native(parsed: tuple) -> ModelSet:
    """ModelSet from ``_native.model_set_parse``'s 12 int64 byte strings (already validated)."""
    return _model_set(*(np.frombuffer(a, dtype=np.int64) for a in parsed))


def _model_set(types, lo, span, prec, group, binshift, centre, rl, rr, counts, bins_flat,
               levels_flat) -> ModelSet:
    """A ModelSet from parsed parameter arrays and the COARSE models' flat bin / level arrays
    (``counts`` bins per COARSE model).  The per-model views of the flat arrays are made when
    first asked for: the native path only uses the flat arrays, and a tuple of views cost
    1.5 us per model (6 ms for jug's SH sets)."""
    if counts.size:
        ends = np.cumsum(counts)
        first = ends - counts
        bins = CoarseSlices(bins_flat, first, ends)
        levels = CoarseSlices(levels_flat, first, ends)
    else:
        bins = levels = ()
    ms = ModelSet(types=types, lo=lo, span=span, prec=prec, group=group, binshift=binshift,
                  centre=centre, r_left=rl, r_right=rr, bins=bins, levels=levels)
    if counts.size:
        ms._flat = (counts, bins_flat, levels_flat)
    return ms


def _parse_model_set_body(raw: bytes) -> ModelSet:
    """The NumPy parser of a model set's (decompressed) body, ENTROPY.md 3.1-3.2, validated."""
    body = np.frombuffer(raw, dtype=np.uint8)
    p = 0
    m_count, p = read_varint(body, p, "model count")
    if m_count > MAX_MODELS or m_count > body.size - p:
        raise GszFormatError(f"rANS model set: {m_count} models do not fit the table")
    types, p = read_varints(body, p, m_count, "model types")
    if np.any(types > 3):
        raise GszFormatError("rANS model set: unknown model type")
    nonempty = types != EMPTY
    wide = (types == COARSE) | (types == LAPLACE)
    coarse = types == COARSE
    lap = types == LAPLACE
    z = np.zeros(m_count, dtype=np.int64)
    lo, span, prec, group, binshift, centre, rl, rr = (z.copy() for _ in range(8))
    v, p = read_varints(body, p, int(nonempty.sum()), "lo")
    lo[nonempty] = unzigzag(v)
    v, p = read_varints(body, p, int(wide.sum()), "span")
    span[wide] = v
    v, p = read_varints(body, p, int(wide.sum()), "precision")
    prec[wide] = v
    v, p = read_varints(body, p, int(coarse.sum()), "coarse shape")
    group[coarse] = v & 3
    binshift[coarse] = v >> 2
    n_lap = int(lap.sum())
    v, p = read_varints(body, p, n_lap, "centre")
    centre[lap] = v
    for arr in (rl, rr):
        if n_lap > body.size - p:
            raise GszFormatError("rANS model set: truncated laplace ratio codes")
        arr[lap] = body[p:p + n_lap]
        p += n_lap
    # bounds before the code arrays are allocated
    if np.any(span > MAX_SPAN) or np.any(prec > MAX_PRECISION) or np.any(binshift > 16):
        raise GszFormatError("rANS model set: span, precision or bin shift out of range")
    n_co = int(coarse.sum())
    counts, p = read_varints(body, p, n_co, "coarse bin counts")
    if np.any(counts < 1) or np.any(counts > (span[coarse] >> binshift[coarse]) + 1):
        raise GszFormatError("rANS model set: coarse bin count outside 1..bins")
    total = int(counts.sum())
    gaps, p = read_varints(body, p, total, "coarse bin gaps")
    deltas, p = read_varints(body, p, total, "coarse level deltas")
    if p != body.size:
        raise GszFormatError(f"rANS model set: {body.size - p} trailing bytes")
    if total and (gaps.max() > MAX_SPAN or np.abs(unzigzag(deltas)).max() > MAX_SPAN):
        # no valid model has such a gap or level step; bounding them keeps the sums below exact
        raise GszFormatError("rANS model set: coarse bin gap or level step out of range")
    if n_co:
        # per-model running sums, all models at once: bins b_i = b_{i-1} + gap_i + 1 from
        # b_{-1} = -1, levels q_i = q_{i-1} + delta_i from q_{-1} = 0 (ENTROPY.md 3.2)
        first = np.cumsum(counts) - counts
        g1 = gaps + 1
        cg = np.cumsum(g1)
        bins_flat = cg - np.repeat(cg[first] - g1[first], counts) - 1
        dz = unzigzag(deltas)
        cq = np.cumsum(dz)
        levels_flat = cq - np.repeat(cq[first] - dz[first], counts)
    else:
        bins_flat = levels_flat = np.zeros(0, np.int64)
    ms = _model_set(types, lo, span, prec, group, binshift, centre, rl, rr, counts, bins_flat,
                    levels_flat)
    ms.validate()
    return ms


class CoarseSlices(Sequence):
    """The per-model pieces ``flat[starts[i]:ends[i]]`` of a flat array as a read-only
    sequence of views (what a tuple of the views would give, without making them up front)."""

    def __init__(self, flat: np.ndarray, starts: np.ndarray, ends: np.ndarray):
        self._flat, self._starts, self._ends = flat, starts, ends

    def __len__(self) -> int:
        return int(self._starts.size)

    def __getitem__(self, i):
        if isinstance(i, slice):
            return tuple(self[j] for j in range(*i.indices(len(self))))
        if i < 0:
            i += len(self)
        if not 0 <= i < len(self):
            raise IndexError("model index out of range")
        return self._flat[int(self._starts[i]):int(self._ends[i])]

    def __add__(self, other):
        return tuple(self) + tuple(other)

    def __radd__(self, other):
        return tuple(other) + tuple(self)


# ---- payload decoding --------------------------------------------------------------------------
def lut_budget(num_symbols: int) -> int:
    """Largest LUT (sum of 2**n_m over non-empty models) a stream of N symbols may use."""
    return max(MIN_LUT_BUDGET, LUT_PER_SYMBOL * int(num_symbols))


def min_lanes(num_symbols: int, max_rows: int = MAX_ROWS) -> int:
    """Fewest lanes a payload of ``num_symbols`` may have (ENTROPY.md 4.1)."""
    return min(LANES_REQUIRED_CAP, -(-int(num_symbols) // int(max_rows)))


def parse_payload_header(b: np.ndarray, num_symbols: int, max_rows: int = MAX_ROWS) -> tuple[int, int, int]:
    """Lane count L, word count W and the offset of the initial states of a payload (ENTROPY.md
    section 4.1), with its checks: min_lanes(N, max_rows) <= L <= max(1, N), exactly 4 L + 2 W
    bytes after the two varints.  b: uint8 array of the whole payload."""
    n = int(num_symbols)
    if n < 0:
        raise GszFormatError("rANS: negative symbol count")
    lanes, p = read_varint(b, 0, "lane count")
    words, p = read_varint(b, p, "word count")
    if lanes < 1 or lanes > max(1, n):
        raise GszFormatError(f"rANS: lane count {lanes} invalid for {n} symbols")
    if lanes < min_lanes(n, max_rows):
        raise GszFormatError(f"rANS: {lanes} lanes for {n} symbols, fewer than the "
                             f"{min_lanes(n, max_rows)} required (at most {max_rows} symbols per lane)")
    if 4 * lanes + 2 * words != b.size - p:
        raise GszFormatError(f"rANS: payload holds {b.size - p} bytes after its header, "
                             f"expected {4 * lanes} state + {2 * words} word bytes")
    return lanes, words, p


class RansDecoder:
    """Incremental decoder of one interleaved-rANS payload (ENTROPY.md section 4).

    ``decode(model_ids)`` returns the next ``len(model_ids)`` symbols (int64); any batch sizes may
    be used and give the same result as one call.  ``finish()`` checks the end conditions.
    """

    def __init__(self, payload: bytes | memoryview, num_symbols: int, models: ModelSet, *,
                 use_native: bool | None = None, max_rows: int = MAX_ROWS):
        b = np.frombuffer(payload, dtype=np.uint8)
        n = int(num_symbols)
        lanes, words, p = parse_payload_header(b, n, max_rows)
        self._states = np.frombuffer(b, dtype="<u4", count=lanes, offset=p).astype(np.int64)
        if np.any(self._states < STATE_LOW):
            raise GszFormatError("rANS: initial state below 2**16")
        self._word_bytes = b[p + 4 * lanes:]    # the 16-bit words, little-endian
        self._nwords = words
        self._words_i64 = None                  # int64 copy for the NumPy row loop, on demand
        self._lanes = lanes
        self._n = n
        self._pos = 0            # index of the next symbol
        self._wpos = 0           # index of the next word
        self._models = models
        # the path is chosen once: a caller that checked native.enabled() passes its answer, so
        # a toggle in another thread cannot leave a native-only call on a NumPy decoder
        self._native = native.enabled() if use_native is None else bool(use_native) and native.native_available()
        if self._native:
            # without the LUT until a per-symbol decode asks for it: channel sets decode in
            # blocks of one model, whose LUT the C decoder makes when it gets there
            self._nt = models.native_tables(lut_budget(n), lut=False)
        else:
            self._t = models.build(lut_budget(n))

    @property
    def _words(self) -> np.ndarray:
        if self._words_i64 is None:
            self._words_i64 = self._word_bytes.view("<u2").astype(np.int64)
        return self._words_i64

    @property
    def position(self) -> int:
        """Number of symbols decoded so far."""
        return self._pos

    def decode(self, model_ids: np.ndarray, values: np.ndarray | None = None) -> np.ndarray:
        """Decode the next ``len(model_ids)`` symbols (model_ids: int array); returns int64.
        ``values`` (NumPy row loop only, :meth:`decode_runs`): one entry per symbol of every
        model, in :meth:`ModelSet.build` order, returned instead of the symbols' values."""
        mids = np.asarray(model_ids).ravel()
        if mids.size and not np.issubdtype(mids.dtype, np.integer):
            raise GszFormatError("rANS: model ids must be integers")
        mids = mids.astype(np.int64, copy=False)
        count = mids.size
        if count == 0:
            return np.zeros(0, dtype=np.int64)
        if self._pos + count > self._n:
            raise GszFormatError(f"rANS: asked for {self._pos + count} symbols, "
                                 f"stream has {self._n}")
        if self._native:
            # the C loop: same decode step and the same checks (model range, empty models,
            # word stream), one symbol at a time
            out = np.empty(count, dtype=np.int64)
            if self._nt[0] is None:
                self._nt = self._models.native_tables(lut_budget(self._n))
            self._wpos = native.module().rans_decode(np.ascontiguousarray(mids), out, self._states,
                                                     self._word_bytes, self._wpos, self._pos,
                                                     self._nt)
            self._pos += count
            return out
        self._check_models(mids)
        binary = "binary_f0" in self._t and self._lanes >= SCALAR_LANES
        if values is not None and (binary or self._lanes < SCALAR_LANES):
            raise ValueError("decode(values=) needs the NumPy row loop of a non-binary set")
        out = np.empty(count, dtype=np.bool_ if binary else np.int64 if values is None else values.dtype)
        # work in chunks of whole rows (~256k symbols) so the per-symbol arrays stay in cache
        chunk = max(1, (1 << 18) // self._lanes) * self._lanes
        j = 0
        while j < count:
            end = min(count, j + chunk - (self._pos % self._lanes))
            if binary:
                self._decode_chunk_binary(mids[j:end], out[j:end])
            else:
                self._decode_chunk(mids[j:end], out[j:end], values=values)
            j = end
        return out.astype(np.int64) if binary else out

    def _check_models(self, mids: np.ndarray) -> None:
        """Model ids within the set and of non-empty models (NumPy path)."""
        m_count = self._models.num_models
        if mids.min() < 0 or mids.max() >= m_count:
            raise GszFormatError(f"rANS: model id outside 0..{m_count - 1}")
        if self._t["has_empty"] and np.any(self._t["total"][mids] == 0):
            raise GszFormatError("rANS: symbol refers to an empty model")

    def _runs_direct(self, run_lengths: np.ndarray) -> bool:
        """Whether :meth:`decode_runs` decodes these runs one by one with their models' own
        LUTs (runs of 8192 symbols or more on average, on the NumPy row loop), not through
        :meth:`decode`: each run costs a partial row, but no per-symbol model id and no LUT of
        the whole set (fresh memory: a 7.5 M-symbol RAHT set's 100 MB cost more than its 560
        partial rows)."""
        return not (self._native or "binary_f0" in self._t or self._lanes < SCALAR_LANES
                    or int(run_lengths.sum()) < (1 << 13) * run_lengths.size)

    def runs_within(self, run_models: np.ndarray, run_lengths: np.ndarray, hi: np.ndarray) -> bool:
        """True (NumPy path) when every value the model of each non-empty run can give lies in
        0 .. hi[run] (valid, non-empty models): then no decoded symbol can fail a 0..hi range
        check, and :meth:`decode_runs` may map the symbols to floats as it decodes them
        (``scale``/``offset``).  False says nothing."""
        rm = np.asarray(run_models, dtype=np.int64).ravel()
        rl = np.asarray(run_lengths, dtype=np.int64).ravel()
        if self._native:
            return False
        used = rl > 0
        m = rm[used]
        if m.size == 0 or m.min() < 0 or m.max() >= self._models.num_models:
            return False
        t = self._t
        if np.any(t["sym_count"][m] == 0):
            return False
        if "value_range" not in t:          # per non-empty model its smallest and largest value
            some = t["sym_count"] > 0
            lo = np.zeros(self._models.num_models, np.int64)
            high = np.zeros(self._models.num_models, np.int64)
            lo[some] = np.minimum.reduceat(t["value"], t["sym_start"][some])
            high[some] = np.maximum.reduceat(t["value"], t["sym_start"][some])
            t["value_range"] = (lo, high)
        lo, high = t["value_range"]
        return bool(np.all(lo[m] >= 0) and np.all(high[m] <= np.asarray(hi).ravel()[used]))

    def decode_runs(self, run_models: np.ndarray, run_lengths: np.ndarray, scale=None,
                    offset=None, dtype=np.float64) -> np.ndarray:
        """``decode(np.repeat(run_models, run_lengths))`` (same symbols, checks and errors);
        long runs (a channel set's groups) are decoded with their model's scalars and own LUT
        (:meth:`ModelSet.model_slot_symbols`), no per-symbol model-id array and no LUT of the
        whole set.  With ``scale`` and ``offset`` (float64 per run) each symbol k of run r
        comes out as ``dtype(scale[r] * k + offset[r])`` (float64 products and sums, rounded
        once to ``dtype``): the models' value tables are mapped instead of every symbol."""
        rm = np.asarray(run_models, dtype=np.int64).ravel()
        rl = np.asarray(run_lengths, dtype=np.int64).ravel()
        count = int(rl.sum())
        if not self._runs_direct(rl):
            mids = np.repeat(rm, rl)
            if scale is None:
                return self.decode(mids)
            used = rl > 0
            m = rm[used]
            if (not self._native and "binary_f0" not in self._t and self._lanes >= SCALAR_LANES
                    and m.size and m.min() >= 0 and m.max() < self._models.num_models
                    and np.unique(m).size == m.size):
                # every model serves one run (one model per group): its value table mapped
                # once, and the row loop writes the floats
                t = self._t
                s, o = np.zeros(self._models.num_models), np.zeros(self._models.num_models)
                s[m] = np.asarray(scale, dtype=np.float64)[used]
                o[m] = np.asarray(offset, dtype=np.float64)[used]
                v = t["value"].astype(np.float64)
                v *= np.repeat(s, t["sym_count"])
                v += np.repeat(o, t["sym_count"])
                return self.decode(mids, values=v.astype(dtype, copy=False))
            vals = self.decode(mids)
            out = np.repeat(np.asarray(scale, dtype=np.float64), rl) * vals
            out += np.repeat(np.asarray(offset, dtype=np.float64), rl)
            return out.astype(dtype, copy=False)
        if self._pos + count > self._n:
            raise GszFormatError(f"rANS: asked for {self._pos + count} symbols, "
                                 f"stream has {self._n}")
        self._check_models(rm[rl > 0])
        out = np.empty(count, dtype=np.int64 if scale is None else dtype)
        own = {}                 # model -> its LUT and tables (runs of one channel share models)
        j = 0
        for r, (m, length) in enumerate(zip(rm.tolist(), rl.tolist())):
            if length:
                # the model's slots numbered from 0: mask and shift of its precision, base 0
                if m not in own:
                    own[m] = self._models.model_slot_symbols(m)
                lut, tables = own[m]
                if scale is not None:
                    v = tables["value"].astype(np.float64)
                    v *= scale[r]
                    v += offset[r]
                    tables = dict(tables, value=v.astype(dtype, copy=False))
                self._wpos = _decode_rows(out[j:j + length], int(self._t["mask"][m]),
                                          int(self._models.prec[m]), 0, lut, tables, self._words,
                                          self._states, self._lanes, self._pos, self._wpos)
                self._pos += length
                j += length
        return out

    def decode_blocks(self, table: np.ndarray, channels: int, length: int, blocks: int,
                      out: np.ndarray, steps=None, lo=None, qmax=None) -> None:
        """Native only: the next ``channels * length`` symbols of a channel set, symbol
        c*length + i with model ``table[c*blocks + block(i)]`` (``quant.split_lengths``), into
        ``out`` (int64 values; or, with ``steps``/``lo``/``qmax``, float64 ``lo + step * k``
        after checking 0 <= k <= qmax per group; or, with ``qmax`` alone, uint16 symbols k
        after the same check)."""
        count = channels * length
        if self._pos + count > self._n:
            raise GszFormatError(f"rANS: asked for {self._pos + count} symbols, "
                                 f"stream has {self._n}")
        c64 = (lambda a: np.ascontiguousarray(a, dtype=np.int64))
        if steps is not None:
            args = (np.ascontiguousarray(steps, dtype=np.float64),
                    np.ascontiguousarray(lo, dtype=np.float64), c64(qmax))
        else:
            args = () if qmax is None else (None, None, c64(qmax))
        self._wpos = native.module().rans_decode_blocks(
            self._states, self._word_bytes, self._wpos, self._pos, self._nt, c64(table),
            int(channels), int(length), int(blocks), out, *args)
        self._pos += count

    def _decode_chunk(self, mids: np.ndarray | None, out: np.ndarray, model=None, values=None) -> None:
        """Decode len(out) symbols with models ``mids`` (or all with ``model``); writes their
        values (or their entries of ``values``) to ``out``."""
        t = self._t
        count = out.size
        # per-symbol mask, shift and LUT base -- scalars where every model has one precision
        # or the chunk one model (the SH index streams, a channel's run of a channel set)
        if model is None and count > 8192 and mids[0] == mids[-1] and not np.any(mids != mids[0]):
            model = int(mids[0])
        if model is not None:
            m0 = model
            mask, shift, base = int(t["mask"][m0]), int(self._models.prec[m0]), int(t["lut_base"][m0])
        elif t["uniform_prec"] is not None:
            shift = t["uniform_prec"]
            mask, base = (1 << shift) - 1, t["lut_base"].take(mids)
        else:
            mask, shift, base = t["mask"].take(mids), self._models.prec.take(mids), t["lut_base"].take(mids)
        lanes = self._lanes
        if lanes < SCALAR_LANES:
            # rows of a few symbols: the same decode step on Python integers is ~10x faster
            # than a dozen NumPy calls per row (small streams, e.g. every stream of a tiny file)
            b = (lambda v: np.broadcast_to(v, (count,)))
            if "symbol_lists" not in t:          # once per model set: Python ints per symbol
                t["symbol_lists"] = (t["freq"].tolist(), t["slot_start"].tolist(), t["value"].tolist())
            self._wpos = _decode_scalar(out, b(mask), b(shift), b(base), self._models.slot_symbols(),
                                        *t["symbol_lists"], self._words, self._states, lanes,
                                        self._pos, self._wpos)
            self._pos += count
            return
        self._wpos = _decode_rows(out, mask, shift, base, self._models.slot_symbols(),
                                  t if values is None else dict(t, value=values),
                                  self._words, self._states, lanes, self._pos, self._wpos)
        self._pos += count

    def binary_reader(self):
        """A function ``read(model_ids) -> int64 bits``: :meth:`decode` for a binary model set
        (``ModelSet.build``'s ``binary_f0``, e.g. the octree bank) without its per-call model
        checks -- for callers whose model ids are valid by construction (an invalid one still
        raises IndexError) -- or :meth:`decode` itself on any other set or path."""
        if self._native or "binary_f0" not in self._t or self._lanes < SCALAR_LANES:
            return self.decode
        n = self._t["uniform_prec"]
        f0_of, total = self._t["binary_f0"], 1 << n

        def read(model_ids):
            mids = np.asarray(model_ids)
            count = mids.size
            if self._pos + count > self._n:
                raise GszFormatError(f"rANS: asked for {self._pos + count} symbols, "
                                     f"stream has {self._n}")
            out = np.empty(count, dtype=np.bool_)
            f0 = f0_of.take(mids)
            self._wpos = _decode_rows_binary(out, f0, total - f0, n, self._words, self._states,
                                             self._lanes, self._pos, self._wpos)
            self._pos += count
            return out.astype(np.int64)
        return read

    def _decode_chunk_binary(self, mids: np.ndarray, out: np.ndarray) -> None:
        """_decode_chunk for binary models (``binary_f0``): writes the bits (bool) to ``out``."""
        n = self._t["uniform_prec"]
        f0 = self._t["binary_f0"].take(mids)
        self._wpos = _decode_rows_binary(out, f0, (1 << n) - f0, n, self._words, self._states,
                                         self._lanes, self._pos, self._wpos)
        self._pos += mids.size

    def finish(self) -> None:
        """Check that all symbols were decoded, every word consumed and every state is 2**16."""
        if self._pos != self._n:
            raise GszFormatError(f"rANS: {self._n - self._pos} symbols left undecoded")
        if self._wpos != self._nwords:
            raise GszFormatError(f"rANS: {self._nwords - self._wpos} words left unread")
        if np.any(self._states != STATE_LOW):
            raise GszFormatError("rANS: final states differ from 2**16 (corrupt payload)")


def _decode_rows(out, mask, shift, base, lut_symbol, tables, words, states, lanes, pos,
                 wpos) -> int:
    """The NumPy row loop of RansDecoder._decode_chunk (ENTROPY.md 4.3): one row of up to
    ``lanes`` consecutive symbols (one per lane) per step.  mask, shift, base: per-symbol arrays
    or scalars; lut_symbol: :meth:`ModelSet.slot_symbols`; tables: :meth:`ModelSet.build`'s
    (freq, slot_start and value per symbol).  Writes each symbol's value to ``out`` (int64);
    returns the new word position."""
    count = out.size
    freq, slot_start, value = tables["freq"], tables["slot_start"], tables["value"]
    arr = [isinstance(v, np.ndarray) for v in (mask, shift, base)]
    if not arr[1] and int(shift) == 0:
        # precision-0 (SINGLE) models own one slot: the step keeps every state (x = 1 * x +
        # slot - slot_start) and none falls below 2**16, so the symbols are just their values
        # (SH coefficient groups of one value, all-set flag streams: ~10 % of a large file)
        if arr[2]:
            value.take(lut_symbol.take(base), out=out)
        else:
            out.fill(value[lut_symbol[int(base)]])
        return wpos
    with_base = arr[2] or base != 0          # decode_runs' own LUTs start at slot 0
    # scalars as 0-d int64 arrays: a Python int operand costs a ufunc call ~0.6 us more
    mask, shift, base = (v if a else np.array(v, np.int64) for v, a in zip((mask, shift, base), arr))
    width = min(lanes, count)
    flag = np.empty(width, dtype=np.bool_)
    slot_row = np.empty(width, dtype=np.int64)
    sym_row = np.empty(width, dtype=lut_symbol.dtype)
    # the symbols as intp once per row: take() converts narrower indices on every call
    wide = lut_symbol.dtype != np.intp
    symi_row = np.empty(width, dtype=np.intp) if wide else sym_row
    j = 0
    while j < count:
        lane0 = (pos + j) % lanes
        k = min(lanes - lane0, count - j)
        sl = slice(j, j + k)
        x = states[lane0:lane0 + k]
        slot, sym, symi = slot_row[:k], sym_row[:k], symi_row[:k]
        # decode step: x = freq * (x >> n) + (slot - cum), slot - cum = global slot - slot_start
        np.bitwise_and(x, mask[sl] if arr[0] else mask, out=slot)
        if with_base:
            np.add(slot, base[sl] if arr[2] else base, out=slot)
        np.right_shift(x, shift[sl] if arr[1] else shift, out=x)
        # slots are in range by construction (mask and base of a checked non-empty model), so
        # "clip" only skips take()'s buffered bounds check
        lut_symbol.take(slot, out=sym, mode="clip")
        if wide:
            np.copyto(symi, sym)
        np.multiply(x, freq.take(symi), out=x)
        np.add(x, slot, out=x)
        np.subtract(x, slot_start.take(symi), out=x)
        value.take(symi, out=out[sl], mode="clip")
        wpos = _renormalise(x, flag[:k], words, wpos)
        j += k
    return wpos


def _renormalise(x, flag, words, wpos: int) -> int:
    """Shift the next word into every state of the row ``x`` below 2**16, in lane order;
    ``flag``: a bool scratch array like x.  Returns the new word position."""
    np.less(x, _STATE_LOW, out=flag)
    r = np.count_nonzero(flag)
    if r:
        if wpos + r > words.size:
            raise GszFormatError("rANS: payload truncated (word stream exhausted)")
        # a boolean mask is cheaper for a few states, an index list for many (wide rows of
        # ~8-bit symbols renormalise half their lanes: masks cost 3x there)
        sel = flag if 16 * r < x.size else np.flatnonzero(flag)
        v = x[sel]
        v <<= _WORD_BITS
        v |= words[wpos:wpos + r]
        x[sel] = v
    return wpos + r


_STATE_LOW, _WORD_BITS = np.array(STATE_LOW, np.int64), np.array(WORD_BITS, np.int64)


def _decode_rows_binary(out, f0, f1, n, words, states, lanes, pos, wpos) -> int:
    """_decode_rows for binary models of precision n: symbol 0 owns slots [0, f0), symbol 1
    [f0, 2**n) (f0, f1 = 2**n - f0: per symbol), so the decode step needs no LUT.  With
    q = x >> n and b = (x & (2**n - 1)) >= f0 the step freq * q + slot - cum is
    x - (b ? f0 : f1) * (q + b) (expand x = q 2**n + slot), and q + b = (x + f1) >> n (the
    slot plus f1 carries into bit n iff slot >= f0).  Bits to ``out`` (bool)."""
    count = out.size
    nwords = words.size
    # scalars as 0-d int64 arrays: a Python int operand costs a ufunc call ~0.6 us more
    mask, n = np.array((1 << n) - 1, np.int64), np.array(n, np.int64)
    w = min(lanes, count)
    slot, q, flag = np.empty(w, np.int64), np.empty(w, np.int64), np.empty(w, np.bool_)
    j = 0
    while j < count:
        lane0 = (pos + j) % lanes
        k = min(lanes - lane0, count - j)
        x = states[lane0:lane0 + k]
        b, lo, hi = out[j:j + k], f0[j:j + k], f1[j:j + k]
        s, qq = (slot, q) if k == w else (slot[:k], q[:k])
        np.bitwise_and(x, mask, out=s)
        np.greater_equal(s, lo, out=b)
        np.add(x, hi, out=qq)
        np.right_shift(qq, n, out=qq)            # q + b
        fr = np.where(b, lo, hi)
        fr *= qq
        x -= fr
        # _renormalise inlined (few states per row renormalise here: a mask is cheapest)
        fl = flag if k == w else flag[:k]
        np.less(x, _STATE_LOW, out=fl)
        v = x[fl]
        r = v.size
        if r:
            if wpos + r > nwords:
                raise GszFormatError("rANS: payload truncated (word stream exhausted)")
            v <<= _WORD_BITS
            v |= words[wpos:wpos + r]
            x[fl] = v
            wpos += r
        j += k
    return wpos


#: Below this many lanes the NumPy decoder's row loop runs on Python integers instead.
SCALAR_LANES = 8


def _decode_scalar(out, mask, shift, base, lut_symbol, freqs, slot_starts, values, words, states,
                   lanes, pos, wpos) -> int:
    """RansDecoder._decode_chunk for streams with few lanes, one symbol at a time (ENTROPY.md
    4.3, identical arithmetic); freqs, slot_starts, values: the build() tables as lists.
    Writes the symbols' values to ``out``, returns the new word position."""
    st = states.tolist()
    masks, shifts, bases = mask.tolist(), shift.tolist(), base.tolist()
    nwords = words.size
    res = [0] * out.size
    lane = pos % lanes
    for j in range(out.size):
        x = st[lane]
        slot = (x & masks[j]) + bases[j]
        g = int(lut_symbol[slot])
        res[j] = values[g]
        x = freqs[g] * (x >> shifts[j]) + slot - slot_starts[g]
        if x < STATE_LOW:
            if wpos >= nwords:
                states[:] = st
                raise GszFormatError("rANS: payload truncated (word stream exhausted)")
            x = (x << WORD_BITS) | int(words[wpos])
            wpos += 1
        st[lane] = x
        lane = lane + 1 if lane + 1 < lanes else 0
    states[:] = st
    out[:] = res
    return wpos


def decode_stream_single(blob: bytes | memoryview, count: int) -> np.ndarray:
    """decode_stream of ``count`` symbols that all use model 0 (the SHVQ flag and index
    streams: their model set may hold one model), without a model-id array on the native path."""
    if not native.enabled():
        return decode_stream(blob, np.zeros(count, dtype=np.int64), max_models=1)
    models, pos = read_model_set(blob, 0, max_models=1, num_symbols=count)
    dec = RansDecoder(memoryview(blob)[pos:], count, models, use_native=True)
    out = np.empty(count, dtype=np.int64)
    if count:
        dec.decode_blocks(np.zeros(1, np.int64), 1, count, 1, out)
    dec.finish()
    return out


def decode_stream(blob: bytes | memoryview, model_ids: np.ndarray, max_models: int | None = None) -> np.ndarray:
    """Decode a self-contained stream (model set followed by payload) for the given model ids.

    blob: bytes of ENTROPY.md section 5; model_ids: int array (N,); max_models: the most models
    the stream's use can name (None: MAX_MODELS).  Returns int64 values (N,).
    """
    mids = np.asarray(model_ids).ravel()
    models, pos = read_model_set(blob, 0, max_models=max_models, num_symbols=mids.size)
    dec = RansDecoder(memoryview(blob)[pos:], mids.size, models)
    out = dec.decode(mids)
    dec.finish()
    return out
