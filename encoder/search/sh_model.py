"""The SH side of a candidate: estimated bytes and SSE of the higher-degree SH as functions of the
codebook and the count of most important vectors kept exact, and the exact payloads of a choice."""
from __future__ import annotations

import copy
import math
import weakref
from dataclasses import dataclass

import numpy as np

from ...decoder.cloud import MadeRows
from ...decoder.groups import blocks_for

from ..groups import vector_tables
from ..pipeline import ROW_CHUNK, ShPayloads, Stage, gather_columns, sh_set_blocks, tile_assignment
from .options import SH_BITS

#: Fractions of the Gaussians whose SH vectors are kept exact (most important first), tried
#: jointly with the bit allocation.
KEEP_FRACTIONS = (0.0, 0.0025, 0.005, 0.01, 0.02, 0.04, 0.08, 0.16, 0.32)
#: Keep fractions tried only when the largest of KEEP_FRACTIONS wins (budgets near or above the
#: scene's quality ceiling): their statistics cover every vector and cost ~3x more to compute.
KEEP_FRACTIONS_HIGH = (0.64, 1.0)


@dataclass
class ShPlan:
    """The SH payloads of one (codebook, keep-count) choice and what they were estimated at."""

    keep: int
    chunk: list | None        # SHVQ payloads with every kept vector at SH_BITS (None: not coded)
    stats: dict
    est_bytes: float
    est_loss: float
    payloads: ShPayloads      # the same with the kept vectors' widths open (calibration.spend_saturated)

    def decoded_sh(self, kept_bits=None) -> MadeRows:
        """[M, K, 3] the SH a decoder reconstructs (``kept_bits``: ShPayloads.payloads'), made a
        row range at a time as the renderer reads them (ShPayloads.decoded_rows): no plan or
        render holds such an array (1 GB at 6 M voxels)."""
        return self.payloads.decoded_rows(kept_bits)




def row_sse(x: np.ndarray, ref, step: int = 16384) -> np.ndarray:
    """float64 [N]: sum over each row of (x - ref)^2, x float32 [N, D], ``ref(s, e)`` the float64
    rows s..e of the reference.  In row chunks: the same values as the whole-array expression
    (each row's sum is its own) at ~1/3 of the time (no N x D float64 temporaries; flowers:
    0.33 -> 0.12 s per codebook and stage)."""
    out = np.empty(x.shape[0], np.float64)
    for s in range(0, x.shape[0], step):
        d = x[s:s + step].astype(np.float64)
        d -= ref(s, s + d.shape[0])
        d *= d
        d.sum(1, out=out[s:s + d.shape[0]])
    return out


class ShStageStats:
    """What the SH estimates need from a stage whatever the codebook: importance order, the
    error and rate of the kept (exact, SH_BITS) vectors for every keep-count up to the largest
    on the KEEP_FRACTIONS grid (:meth:`extend` covers every vector, for KEEP_FRACTIONS_HIGH).
    Computed once per stage and shared by its codebooks."""

    def __init__(self, stage: Stage, blocks: int):
        x = stage.sh
        self.stage, self.blocks = stage, blocks
        self.order = np.lexsort((np.arange(x.shape[0]), -stage.importance))   # importance rank
        self._compute(max(1, int(round(KEEP_FRACTIONS[-1] * x.shape[0]))))

    def extend(self) -> None:
        """Statistics for every keep-count up to all vectors (idempotent)."""
        m = self.stage.sh.shape[0]
        if len(self.cum_keep) <= m:
            # the error of every vector; the rate per kept vector stays the estimate from the
            # most important 32 % (the costly part, and the bits per vector barely move)
            self._compute(max(1, m), rate=False)

    def _compute(self, p_max: int, rate: bool = True) -> None:
        from ...decoder.quant import dequantize_groups, split_lengths
        from ...kernels.quantize import quantize_groups

        from ..rate import rate_matrix
        x = self.stage.sh
        d, blocks = x.shape[1], self.blocks
        bk = blocks_for(p_max, sh_set_blocks(p_max, blocks))
        # block by block (a group's range is its block's): the same values as quantising the
        # whole [D, P] set at once, without its float64 copies (2 GB at 1.2 M Gaussians)
        err_keep = np.empty(p_max, np.float64)
        bits1 = np.full((d, 1), SH_BITS)
        s = 0
        for length in split_lengths(p_max, bk):
            if length:
                rows = x[self.order[s:s + length]]
                sym, mn, mx = quantize_groups(rows.T, 1, bits1)
                q = dequantize_groups(sym, mn, mx, bits1, np.array([length])).T
                err_keep[s:s + length] = row_sse(rows, lambda a, b: q[a:b])
            s += length
        self.cum_keep = np.concatenate([[0.0], np.cumsum(err_keep)])
        if not rate:
            return
        # the most important vectors straight into the [D, P] layout the rate model reads
        top = gather_columns(x, self.order[:p_max])
        # only the SH_BITS column is used: computing that width alone (plus the coarser grids
        # its binned-table candidates read) gives the same value at ~1/3 of the cost
        self.bits_per_kept = float(rate_matrix(top, bk, (SH_BITS, SH_BITS))[:, :, SH_BITS - 1].sum()) / p_max


class Assigner:
    """Nearest-codeword index of every voxel's SH vector, per codebook, reused across taus.

    Nearly every voxel holds a single input Gaussian (flowers: 99.5 %) whose vector is that
    Gaussian's own, so the index is computed once per input Gaussian and codebook (on first
    need) and looked up for every later stage; merged voxels (and any vector that is not
    bit-identical to its source's) are assigned afresh.  Deterministic: the same stages in the
    same order give the same indices."""

    def __init__(self, cloud):
        n = len(cloud)
        self.sh = np.ascontiguousarray(cloud.sh_rest.reshape(n, -1), dtype=np.float32)
        self.known = {}                       # id(codebook) -> (codebook, index [N], known [N])
        # (source, x, reusable) of the last stage asked about; weak references, so that the
        # stage's SH rows (1 GB at 6 M voxels) go with the stage, not with the next one's models
        self._last = None

    def _entry(self, codebook):
        entry = self.known.get(id(codebook))
        if entry is None or entry[0] is not codebook:
            entry = (codebook, np.zeros(self.sh.shape[0], np.int32), np.zeros(self.sh.shape[0], bool))
            self.known[id(codebook)] = entry
        return entry

    def _reusable(self, source: np.ndarray, x: np.ndarray) -> np.ndarray:
        """Voxels (ascending) whose vector is bit-identical to their single source Gaussian's
        (remembered for the last stage asked about: each stage asks once per codebook)."""
        last = self._last
        if last is not None and last[0]() is source and last[1]() is x:
            return last[2]
        single = np.flatnonzero(source >= 0)
        same = np.empty(single.size, bool)
        # in row chunks: two gathered [M, D] copies and their comparison were 2.4 GB at 6 M voxels
        for s in range(0, single.size, ROW_CHUNK):
            rows = single[s:s + ROW_CHUNK]
            np.all(x[rows] == self.sh[source[rows]], axis=1, out=same[s:s + rows.size])
        out = single[same]
        self._last = (weakref.ref(source), weakref.ref(x), out)
        return out

    def _known(self, src: np.ndarray, codebook: np.ndarray) -> np.ndarray:
        """index[src] after assigning those of the Gaussians src not assigned yet."""
        from ..vq import assign
        _, index, known = self._entry(codebook)
        need = src[~known[src]]
        if need.size:
            index[need] = assign(self.sh, codebook, rows=need)
            known[need] = True
        return index[src]

    def prime(self, source: np.ndarray, x: np.ndarray, codebook: np.ndarray) -> None:
        """Do now what a stage with these ``source`` / ``x`` (Stage.source, Stage.sh) will need
        (the worker thread that trained the codebook calls it while the main thread codes
        that stage); the same Gaussians in the same order, so the same indices."""
        self._known(source[self._reusable(source, x)], codebook)

    def __call__(self, stage: Stage, codebook: np.ndarray) -> np.ndarray:
        from ..vq import assign
        x = stage.sh
        out = np.empty(x.shape[0], np.int32)
        if stage.source is None or x.shape[1] != self.sh.shape[1]:
            out[:] = assign(x, codebook)
            return out
        reuse = self._reusable(stage.source, x)
        out[reuse] = self._known(stage.source[reuse], codebook)
        fresh = np.ones(x.shape[0], bool)
        fresh[reuse] = False
        if fresh.any():
            out[fresh] = assign(x, codebook, rows=np.flatnonzero(fresh))
        return out


#: A codeword's coding error is shared by every vector of the word, which render it alike
#: (docs/design/error-coherence.md: such errors render worse than i.i.d. ones of equal SSE)
WORD_ERROR_FACTOR = 2.0


class ShModel:
    """Estimated SH bytes and SSE as functions of the keep-count P (one VQ assignment, cumulative
    sums over importance order), and exact encoding of the chosen P."""

    def __init__(self, stage: Stage, codebook: np.ndarray, blocks: int, base: ShStageStats,
                 index: np.ndarray):
        from ..vq import assign, compact
        self.stage, self.blocks = stage, blocks
        # a tiled stage's tiles carry their share of the codewords each (ShPayloads does the same)
        index = tile_assignment(stage, codebook, index, assign)
        self.raw_codebook, self.index = codebook, index
        m, d = stage.sh.shape
        cb, idx = compact(codebook, index)
        self.codebook, self._compact_index = cb, idx
        self.cb_blocks = blocks_for(cb.shape[0], sh_set_blocks(cb.shape[0], blocks))
        self.order = base.order
        self.base = base
        counts = np.bincount(idx, minlength=cb.shape[0]).astype(np.float64)
        p = counts[counts > 0] / m
        self.index_bits = float(-(p * np.log2(p)).sum())
        self.m, self.d = m, d
        self.cb_bits, self._tile_words = SH_BITS, None
        cb_q, self._word_sse = self._coded_codebook(SH_BITS)
        err_vq = row_sse(stage.sh, lambda s, e: cb_q[idx[s:e]])
        self.cum_vq = np.concatenate([[0.0], np.cumsum(err_vq[self.order])])
        self.codebook_bytes = self._codebook_bytes(SH_BITS)

    def _coded_codebook(self, bits: int) -> tuple[np.ndarray, np.ndarray]:
        """(the codebook as decoded at ``bits`` a component [K, D], each word's squared error)."""
        from ...decoder.quant import dequantize_groups, split_lengths
        from ...kernels.quantize import quantize_groups
        cb, b, d = self.codebook, self.cb_blocks, self.d
        sym, mn, mx = quantize_groups(cb.T, b, np.full((d, b), bits))
        cb_q = dequantize_groups(sym, mn, mx, np.full((d, b), bits), split_lengths(cb.shape[0], b)).T
        return cb_q, ((cb_q.astype(np.float64) - cb) ** 2).sum(axis=1)

    def _codebook_bytes(self, bits: int) -> float:
        from ..rate import rate_matrix
        if self._tile_words is None:          # once: every width codes the same words per tile
            self._tile_words = list(self._tile_codebooks(self.codebook, self._compact_index, self.blocks))
        return sum(float(rate_matrix(c.T, bt, (bits, bits))[:, :, bits - 1].sum()) / 8 + 9 * self.d * bt + 32
                   for c, bt in self._tile_words)

    def with_codebook_bits(self, bits: int) -> "ShModel":
        """This model with its codebook coded at ``bits`` a component instead (the assignment
        shared): at low rates a cheaper codebook buys a larger one.  A vector's error changes
        by its word's change of squared error (the cross term with the vector's own residual
        dropped: the residuals of a word's vectors sum to ~0, the word being their centroid),
        so no pass over the [M, D] vectors."""
        other = copy.copy(self)
        _, word_sse = self._coded_codebook(bits)
        delta = (word_sse - self._word_sse)[self._compact_index]
        other.cum_vq = self.cum_vq + WORD_ERROR_FACTOR * np.concatenate([[0.0],
                                                                         np.cumsum(delta[self.order])])
        other.cb_bits, other._word_sse = int(bits), word_sse
        other.codebook_bytes = self._codebook_bytes(bits)
        return other

    def _tile_codebooks(self, cb: np.ndarray, idx: np.ndarray, blocks: int):
        """(codebook [K_t, D], blocks) that each tile carries (the compacted one without tiles)."""
        if self.stage.num_tiles == 1:
            yield cb, self.cb_blocks
            return
        for t in range(self.stage.num_tiles):
            members = np.concatenate([l.index for l in self.stage.layers if l.tile == t])
            c = cb[np.unique(idx[members])]
            yield c, blocks_for(c.shape[0], sh_set_blocks(c.shape[0], blocks))

    def keeps(self, min_keep: int = 0, fractions=KEEP_FRACTIONS):
        """Keep-counts to try: the ``fractions`` grid at or above ``min_keep``, and min_keep."""
        lo = min(self.m, int(min_keep))
        return sorted({lo} | {k for k in (min(self.m, int(round(f * self.m))) for f in fractions)
                              if k >= lo})

    def estimate(self, keep: int) -> tuple[float, float]:
        m = self.m
        q = keep / m
        h2 = 0.0 if q in (0.0, 1.0) else -(q * math.log2(q) + (1 - q) * math.log2(1 - q))
        base = self.base
        if keep >= len(base.cum_keep):
            base.extend()
        nbytes = (self.codebook_bytes + (keep * base.bits_per_kept + (m - keep) * self.index_bits
                  + (m * h2 if keep else 0)) / 8 + (9 * self.d * sh_set_blocks(keep, self.blocks) if keep else 0)
                  + 64 * len(self.stage.layers))
        loss = (self.cum_vq[-1] - self.cum_vq[keep]) + base.cum_keep[min(keep, len(base.cum_keep) - 1)]
        return nbytes, loss

    def encode(self, keep: int, code: bool = True, classes: int = 1, refine: bool = False) -> ShPlan:
        """The plan of ``keep``; ``code=False`` leaves chunk None (the kept vectors' widths are
        allocated later: coding them all at SH_BITS first would be wasted, and at 1.2 M vectors
        it is the largest transient of the search).  ``refine``: the kept vectors as residuals
        of their codewords (ShPayloads)."""
        # the compacted codebook's row order is the raw one's, so the raw codebook with the
        # stage's assignment gives exactly what sh_chunk would compute itself
        payloads = ShPayloads(self.stage, self.raw_codebook, keep, SH_BITS, self.blocks,
                              cb_blocks=self.cb_blocks, index=self.index, classes=classes,
                              cb_bits=self.cb_bits, refine=refine)
        chunk, _, stats = payloads.payloads(decoded=False) if code else (None, None, dict(payloads.stats))
        nb, loss = self.estimate(keep)
        return ShPlan(keep, chunk, stats, nb, loss, payloads)


@dataclass
class ShSource:
    """The SH vectors and importance a codebook is trained on (a Stage's fields)."""
    sh: object                # [M, D] rows: an array or a pipeline.SourcedRows
    importance: np.ndarray
    num_points: int


def kept_tables(plan: ShPlan, weight: float, min_bits: int = SH_BITS) -> list:
    """Per layer with kept exact SH vectors: (layer, loss [D, B, 16] = SSE times the SH
    channel weight, rate [D, B, 16] with +inf below ``min_bits``) of their groups
    (:func:`vector_tables`), the loss weighed by the blocks' importance where they are classes."""
    out = []
    for li, (sel, kb) in enumerate(plan.payloads.kept_sets):
        if sel.size:
            bw = plan.payloads.block_weights[li]
            loss, rate = vector_tables(plan.payloads.kept_vectors(li), blocks_for(sel.size, kb), int(min_bits))
            loss *= weight
            if bw is not None:          # blocks are importance classes: weigh their SSE by it
                loss *= bw[None, :, None]
            out.append((li, loss, rate))
    return out
