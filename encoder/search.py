"""Size-aware search: hit a byte budget (never above it, within a tolerance below it) with the
best fidelity the codec can reach.

    result = encode_to_budget(cloud, 5_000_000)       # .data <= 5 MB, >= 99.5 % of it

Method (MesonGS++'s, with the measured improvements noted):

* Outer loop over the reserve ratio tau (a grid).  A tau whose size range cannot contain the
  budget (even all-16-bit stays below it, or all-1-bit stays above it) is skipped, as in the
  paper; of the rest, up to ``max_candidates`` spread over the feasible range are encoded for
  real and the one with the best PSNR on **train** views wins (test views are never used).
* Inner loop per tau: the SH keep-count P is chosen jointly with the bit allocation: for each P
  on a geometric grid, the bits left after geometry and SH go to the attribute groups by the
  multiple-choice-knapsack solver, and the P with the smallest total loss (attribute SSE Omega +
  SH SSE) wins.  Rates are entropy-coded-size estimates per (group, bit-width)
  (``gsz.encoder.rate``), not q*n, so calibration needs few rounds.
* Calibration: encode the attributes for real, measure, shift the solver budget by the
  observed error (secant steps), until the file is within ``tolerance`` below the target; the
  best file at or below the target is kept, so the result is never over budget.
"""
from __future__ import annotations

import contextlib
import math
import threading
import time
from dataclasses import dataclass

import numpy as np

from gsz.decoder.errors import GszError
from gsz.decoder.groups import blocks_for

from .pipeline import (DEFAULT_FIRST_LAYER, DEFAULT_LAYERS, EncodeOptions, EncodeOptionsError,
                       EncodeResult, MANY_BLOCKS, ShPayloads, Stage, assemble, attribute_chunks, check_layer_options,
                       sh_set_blocks,
                       compute_train_importance, default_codebook_size, layer_report, prepare_stage,
                       sh_chunk, stage_source, train_sh_codebook, voxelize_stage)
from .cameras import DEFAULT_VIEW_WIDTH, load_cameras
from .progress import Progress

SH_BITS = 8          # codebook and kept SH vectors (the paper's setting)
#: The depth walk tries a deeper octree first when the best allocation's mean bit-width is at
#: least this (attributes near their useful precision: position error is what is left), and a
#: shallower one first otherwise.
DEPTH_DEEPER_FIRST_BITS = 8.0
#: Levels deeper than the default the walk may go while the best file stays below the budget at
#: full quality (saturated), or while at least MERGED_FRACTION_EXTRA_DEPTH of its Gaussians
#: still share a voxel with another; otherwise it stops at max_extra_depth.  Past
#: max_extra_depth a level must gain SATURATED_MIN_GAIN_DB of train PSNR for the walk to go on.
SATURATED_EXTRA_DEPTH = 8
SATURATED_MIN_GAIN_DB = 0.1
MERGED_FRACTION_EXTRA_DEPTH = 0.01
#: A first depth step that improves train PSNR by less than this does not commit the walk to
#: its direction: the other direction is tried as well (houseplant noised 40x: depth 11 -> 12
#: gained 0.02 dB, and depth 9 was the better side).
DEPTH_STEP_MIN_GAIN_DB = 0.05
KEEP_FRACTIONS = (0.0, 0.0025, 0.005, 0.01, 0.02, 0.04, 0.08, 0.16, 0.32)
#: Keep fractions tried only when the largest of KEEP_FRACTIONS wins (budgets near or above the
#: scene's quality ceiling): their statistics cover every vector and cost ~3x more to compute.
KEEP_FRACTIONS_HIGH = (0.64, 1.0)


class BudgetError(GszError, ValueError):
    """The requested budget cannot be met (names the smallest reachable size)."""

    def __init__(self, target: int, minimum: int, path=None):
        self.target = int(target)
        self.minimum = int(minimum)
        super().__init__(f"size budget {self.target:,} bytes is below the smallest reachable file "
                         f"for this scene, {self.minimum:,} bytes", path)


@dataclass
class SearchOptions:
    """Knobs of the search (defaults are what the benchmarks use).

    reserves        tau grid, descending
    max_candidates  taus spread over the feasible range, encoded and compared by train PSNR
    refine_steps    rounds of also trying the grid neighbours of the best tau so far
    depth_steps     octree levels away from the position-error default the search may go
                    (either way); after the tau search at the default depth it walks the depth
                    from the best candidate while train PSNR improves, then refines tau there
    max_extra_depth cap on levels deeper than the default (the budget-saturated case)
    weight_channels weight Omega per channel by measured rendering sensitivity (channel_weights)
    tolerance       accepted shortfall below the target (fraction)
    max_rounds      calibration rounds per tau
    solver          "fast" (convex hull + repair) or "cbc" (PuLP, the paper's ILP)
    eval_views      train views rendered to compare candidates: generated ones, or as many of
                    the caller's cameras spread evenly over them; eval_width their width at
                    most.  The default is gsz-eval's view width: at lower resolutions the
                    loss of small Gaussians hides below a pixel, and candidates that prune
                    more win on train views and lose on test views (plaza 12x, flowers 27x at
                    640 px: about 1 dB of test PSNR; bench/RESULTS.md)
    layers          importance-ordered layers of the file (progressive streaming); the bit
                    allocation runs over the groups of every layer at once
    first_layer     fraction of the Gaussians in layer 0 (when layers > 1)
    layer0_share    wanted fraction of the file bytes before layer 0 is decodable: when the
                    chosen file's layer 0 ends after more than 1.5x this, the layers are
                    re-split with a proportionally smaller layer 0 and that candidate re-encoded
    screen          before encoding a tau below the best so far, render its exact-attribute
                    (pruned + voxelised) cloud and skip the tau when that bound is no better
                    than the best candidate's train PSNR
    overlap         train the SH codebooks on a worker thread during the set-up
    beta            exponent of the importance's volume term (EncodeOptions.beta)
    """

    reserves: tuple = (1.0, 0.9, 0.8, 0.7, 0.6, 0.5, 0.4, 0.3, 0.2)
    max_candidates: int = 3
    depth_steps: int = 3
    max_extra_depth: int = 3
    refine_steps: int = 3
    weight_channels: bool = True
    tolerance: float = 0.005
    max_rounds: int = 8
    solver: str = "fast"
    blocks: int = MANY_BLOCKS
    codebook: int | None = None
    eval_views: int = 6
    eval_width: int = DEFAULT_VIEW_WIDTH
    train_views: int = 24
    importance_width: int = DEFAULT_VIEW_WIDTH
    vq_iters: int | None = None
    layers: int = DEFAULT_LAYERS
    first_layer: float = DEFAULT_FIRST_LAYER
    layer0_share: float = 0.1
    screen: bool = True
    overlap: bool = True
    seed: int = 0
    beta: float = 0.1


@dataclass
class _TauPlan:
    stage: Stage
    loss: np.ndarray          # [G, 16] attribute SSE (RAHT groups then scale groups)
    rate: np.ndarray          # [G, 16] estimated coded bits
    shapes: tuple             # ((7, B_raht), (3, B_scale))
    fixed_bytes: int          # everything but the two attribute channel sets' coded streams
    min_bytes: float
    max_bytes: float


#: Perturbation (std) per channel used to measure rendering sensitivity; small enough for the
#: image error to grow ~quadratically, large enough to rise above float noise.
_SENS_SIGMA = {"opacity": 0.05, "euler": 0.02, "f_dc": 0.02, "scale": 0.02, "sh": 0.01}


def channel_weights(cloud, cameras, *, seed: int = 0, base_images=None) -> dict:
    """Rendering sensitivity of every quantised channel: image MSE added per unit of parameter
    SSE, measured by perturbing one channel of every Gaussian with Gaussian noise and rendering
    the given (train) views.  Returns {"raht": [7], "scales": [3], "sh": float}, normalised so the
    mean RAHT/scale weight is 1.  The size search multiplies the loss matrix Omega by these, so
    the allocation minimises (approximately) rendered error instead of raw parameter SSE.
    ``base_images``: the unperturbed renders (``render(cloud, camera).image``) when the caller
    has them."""
    from gsz.decoder.cloud import GaussianCloud
    from gsz.decoder.rotation import euler_to_quaternion, quaternion_to_euler

    from .render import render
    rng = np.random.default_rng(seed)
    base = [render(cloud, c).image.astype(np.float64) for c in cameras] if base_images is None \
        else [np.asarray(b, np.float64) for b in base_images]
    euler = quaternion_to_euler(cloud.rotations.astype(np.float64))
    n = len(cloud)

    def mse_of(sq):
        return float(np.mean([e.mean() for e in sq]))

    def sensitivity(mod, sigma, count):
        img = [render(mod, c).image.astype(np.float64) for c in cameras]
        return max(mse_of([(a - b) ** 2 for a, b in zip(img, base)]), 1e-30) / (sigma ** 2 * count)

    def variant(**kw):
        f = dict(positions=cloud.positions, scales=cloud.scales, rotations=cloud.rotations,
                 opacities=cloud.opacities, sh_dc=cloud.sh_dc, sh_rest=cloud.sh_rest,
                 sh_degree=cloud.sh_degree)
        f.update(kw)
        return GaussianCloud(**f)

    def noisy(a, col, sigma):
        a = a.astype(np.float64).copy()
        a[:, col] += rng.normal(0, sigma, n)
        return a

    raht = []
    sg = _SENS_SIGMA["opacity"]
    raht.append(sensitivity(variant(opacities=cloud.opacities + rng.normal(0, sg, n)), sg, n))
    sg = _SENS_SIGMA["euler"]
    for k in range(3):
        q = euler_to_quaternion(noisy(euler, k, sg))
        raht.append(sensitivity(variant(rotations=q), sg, n))
    # Image channel k depends on DC colour channel k only (geometry, alpha and T do not involve
    # colour; the 0-clamp is per channel), so one render with all three perturbed gives each
    # channel's error image exactly as three renders would (the other channels' errors are
    # exact zeros there): the same weights for a third of the renders.
    sg = _SENS_SIGMA["f_dc"]
    dc = cloud.sh_dc.astype(np.float64).copy()
    for k in range(3):
        dc[:, k] += rng.normal(0, sg, n)
    sq = [(render(variant(sh_dc=dc), c).image.astype(np.float64) - b) ** 2 for c, b in zip(cameras, base)]
    for k in range(3):
        only = []
        for e in sq:
            ek = np.zeros_like(e)
            ek[..., k] = e[..., k]
            only.append(ek)
        raht.append(max(mse_of(only), 1e-30) / (sg ** 2 * n))
    sg = _SENS_SIGMA["scale"]
    scales = [sensitivity(variant(scales=noisy(cloud.scales, k, sg)), sg, n) for k in range(3)]
    sh = 0.0
    if cloud.sh_degree > 0:
        sg = _SENS_SIGMA["sh"]
        rest = cloud.sh_rest + rng.normal(0, sg, cloud.sh_rest.shape)
        sh = sensitivity(variant(sh_rest=rest), sg, cloud.sh_rest[0].size * n)
    norm = float(np.mean(raht + scales))
    return {"raht": [w / norm for w in raht], "scales": [w / norm for w in scales], "sh": sh / norm}


def _attribute_sets(stage: Stage, blocks: int):
    """(x [C, L], blocks) of every attribute channel set of the stage, in the solver's group
    order (layer 0 RAHT, layer 0 scales, layer 1 RAHT, ...)."""
    return [(x, blocks_for(x.shape[1], lb)) for layer, lb in zip(stage.layers, stage.layer_blocks(blocks))
            for x in (layer.raht_ac, layer.scales)]


def _raw_tables(stage: Stage, blocks: int):
    """Unweighted loss [C, B, 16] and rate [C, B, 16] of every channel set, computed once per
    stage (the size bounds, every calibration round and every re-run of a tau share them)."""
    from gsz.kernels.quantize import quantize_all_bits

    from .rate import rate_matrix
    key = ("tables", blocks)
    if key not in stage.cache:
        out = []
        for x, b in _attribute_sets(stage, blocks):
            if x.shape[1]:
                _, _, _, loss = quantize_all_bits(x, b)
                rate = rate_matrix(x, b)
            else:
                loss = np.zeros((x.shape[0], b, 16))
                rate = np.zeros((x.shape[0], b, 16))
            out.append((loss, rate))
        stage.cache[key] = out
    return stage.cache[key]


def _attribute_tables(stage: Stage, blocks: int, weights: dict | None = None):
    losses, rates, shapes = [], [], []
    w_sets = (None, None) if weights is None else (weights["raht"], weights["scales"])
    for i, (loss, rate) in enumerate(_raw_tables(stage, blocks)):
        w = w_sets[i % 2]
        if w is not None:
            loss = loss * np.asarray(w, np.float64)[:, None, None]
        losses.append(loss.reshape(-1, 16))
        rates.append(rate.reshape(-1, 16))
        shapes.append(loss.shape[:2])
    return np.concatenate(losses), np.concatenate(rates), tuple(shapes)


def _group_meta_bytes(shapes) -> int:
    # per channel set: C u8, L u32, B u16, model_mode u8, blob length u64; per group: u8 + 2 f32
    return sum(16 + 9 * c * b for c, b in shapes)


def _split_bits(pick: np.ndarray, shapes) -> list:
    """Per layer, (raht_bits [7, B_l], scale_bits [3, B_l]) from the solver's pick over every
    layer's groups (order: layer 0 RAHT, layer 0 scales, layer 1 RAHT, ...)."""
    bits = pick.astype(np.int64) + 1
    out, pos = [], 0
    for c, b in shapes:
        out.append(bits[pos:pos + c * b].reshape(c, b))
        pos += c * b
    return [(out[i], out[i + 1]) for i in range(0, len(out), 2)]


def _split_kept_bits(pick: np.ndarray, shapes, kept_layers: list, num_layers: int) -> list:
    """Per layer, the kept SH vectors' group bit-widths [D, B_l] from the solver's pick over
    their groups (layers in ``kept_layers`` order); None for a layer whose kept vectors are not
    in the allocation (none kept, or all at SH_BITS)."""
    out, pos = [None] * num_layers, 0
    for li, (c, b) in zip(kept_layers, shapes):
        out[li] = pick[pos:pos + c * b].astype(np.int64).reshape(c, b) + 1
        pos += c * b
    return out


def _concat_bits(bits: list) -> tuple[np.ndarray, np.ndarray]:
    """Every layer's blocks side by side: ([7, sum B_l], [3, sum B_l]) for reports/heatmaps."""
    return (np.concatenate([r for r, _ in bits], axis=1), np.concatenate([s for _, s in bits], axis=1))


@dataclass
class _ShPlan:
    keep: int
    chunk: list               # SHVQ payloads with every kept vector at SH_BITS
    sh_rest: np.ndarray
    stats: dict
    est_bytes: float
    est_loss: float
    payloads: ShPayloads      # the same with the kept vectors' widths open (_spend_saturated)


def _row_sse(x: np.ndarray, ref, step: int = 16384) -> np.ndarray:
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


class _ShStageStats:
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
        from gsz.decoder.quant import dequantize_groups, split_lengths
        from gsz.kernels.quantize import quantize_groups

        from .rate import rate_matrix
        x = self.stage.sh
        d, blocks = x.shape[1], self.blocks
        top = x[self.order[:p_max]]
        bk = blocks_for(p_max, sh_set_blocks(p_max, blocks))
        sym, mn, mx = quantize_groups(top.T, bk, np.full((d, bk), SH_BITS))
        top_q = dequantize_groups(sym, mn, mx, np.full((d, bk), SH_BITS), split_lengths(p_max, bk)).T
        err_keep = _row_sse(top, lambda s, e: top_q[s:e])
        self.cum_keep = np.concatenate([[0.0], np.cumsum(err_keep)])
        if not rate:
            return
        # only the SH_BITS column is used: computing that width alone (plus the coarser grids
        # its binned-table candidates read) gives the same value at ~1/3 of the cost
        self.bits_per_kept = float(rate_matrix(top.T, bk, (SH_BITS, SH_BITS))[:, :, SH_BITS - 1].sum()) / p_max


class _Assigner:
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
        self._last = None                     # (source, x, reusable) of the last stage asked about

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
        if last is not None and last[0] is source and last[1] is x:
            return last[2]
        single = np.flatnonzero(source >= 0)
        out = single[np.all(x[single] == self.sh[source[single]], axis=1)]
        self._last = (source, x, out)
        return out

    def _known(self, src: np.ndarray, codebook: np.ndarray) -> np.ndarray:
        """index[src] after assigning those of the Gaussians src not assigned yet."""
        from .vq import assign
        _, index, known = self._entry(codebook)
        need = src[~known[src]]
        if need.size:
            index[need] = assign(self.sh[need], codebook)
            known[need] = True
        return index[src]

    def prime(self, source: np.ndarray, x: np.ndarray, codebook: np.ndarray) -> None:
        """Do now what a stage with these ``source`` / ``x`` (Stage.source, Stage.sh) will need
        (the worker thread that trained the codebook calls it while the main thread codes
        that stage); the same Gaussians in the same order, so the same indices."""
        self._known(source[self._reusable(source, x)], codebook)

    def __call__(self, stage: Stage, codebook: np.ndarray) -> np.ndarray:
        from .vq import assign
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
            out[fresh] = assign(x[fresh], codebook)
        return out


class _ShModel:
    """Estimated SH bytes and SSE as functions of the keep-count P (one VQ assignment, cumulative
    sums over importance order), and exact encoding of the chosen P."""

    def __init__(self, stage: Stage, codebook: np.ndarray, blocks: int, base: _ShStageStats,
                 index: np.ndarray):
        from gsz.decoder.quant import dequantize_groups, split_lengths
        from gsz.kernels.quantize import quantize_groups

        from .rate import rate_matrix
        from .vq import compact
        self.stage, self.blocks = stage, blocks
        self.raw_codebook, self.index = codebook, index
        x = stage.sh
        m, d = x.shape
        cb, idx = compact(codebook, index)
        self.codebook = cb
        b = blocks_for(cb.shape[0], sh_set_blocks(cb.shape[0], blocks))
        self.cb_blocks = b
        sym, mn, mx = quantize_groups(cb.T, b, np.full((d, b), SH_BITS))
        cb_q = dequantize_groups(sym, mn, mx, np.full((d, b), SH_BITS), split_lengths(cb.shape[0], b)).T
        err_vq = _row_sse(x, lambda s, e: cb_q[idx[s:e]])
        self.order = base.order
        self.cum_vq = np.concatenate([[0.0], np.cumsum(err_vq[base.order])])
        self.base = base
        counts = np.bincount(idx, minlength=cb.shape[0]).astype(np.float64)
        p = counts[counts > 0] / m
        self.index_bits = float(-(p * np.log2(p)).sum())
        self.codebook_bytes = (float(rate_matrix(cb.T, b, (SH_BITS, SH_BITS))[:, :, SH_BITS - 1].sum()) / 8
                               + 9 * d * b + 32)
        self.m, self.d = m, d

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

    def encode(self, keep: int) -> _ShPlan:
        # the compacted codebook's row order is the raw one's, so the raw codebook with the
        # stage's assignment gives exactly what sh_chunk would compute itself
        payloads = ShPayloads(self.stage, self.raw_codebook, keep, SH_BITS, self.blocks,
                              cb_blocks=self.cb_blocks, index=self.index)
        chunk, sh_rest, stats = payloads.payloads()
        nb, loss = self.estimate(keep)
        return _ShPlan(keep, chunk, sh_rest, stats, nb, loss, payloads)


def _container_overhead(num_chunks: int) -> int:
    return 64 + 24 * num_chunks + 4


def _num_chunks(stage: Stage) -> int:
    return len(stage.layers) * (3 if stage.sh.shape[1] else 2) + 1


def _meta(stage: Stage, sopts: SearchOptions, target: int, extra: dict) -> dict:
    return {"encoder": "gsz 0.1.0", "codec": "mesongs++", "mode": "size-search",
            "target_bytes": int(target), "reserve": stage.reserve, "depth": stage.depth,
            "input_gaussians": stage.input_gaussians, "voxels": stage.num_points, **extra}


def _solve(loss, rate, budget_bits, solver):
    from .bit_allocation import allocate
    return allocate(loss, rate, budget_bits, method=solver)


def _encode_tau(stage: Stage, target: int, sopts: SearchOptions, sh_models: list,
                progress: Progress, log: list, weights: dict | None = None, min_keep: int = 0):
    """Allocate + calibrate one tau.  Returns the best (data, cloud, info) at or below target, or
    None when the budget is unreachable at this tau.  ``min_keep``: keep at least this many
    exact SH vectors (the most important ones)."""
    from .bit_allocation import InfeasibleBudgetError

    with progress.stage("tables", f"tau {stage.reserve}: loss + rate matrices"):
        loss, rate, shapes = _attribute_tables(stage, sopts.blocks, weights)
    meta_guess = 400
    base_fixed = (_container_overhead(_num_chunks(stage)) + stage.geometry_bytes + meta_guess
                  + (2 + 8 * 7) * len(stage.layers) + _group_meta_bytes(shapes))

    # --- joint choice of the SH keep-count and the attribute allocation ---------------------
    sh_plan = sh_model = None
    if sh_models:
        with progress.stage("sh-plan", "codebook size and keep-count vs bit allocation"):
            best = None

            def consider(model, keeps):
                nonlocal best
                for keep in keeps:
                    sh_bytes, sh_loss = model.estimate(keep)
                    budget_bits = 8.0 * (target - base_fixed - sh_bytes)
                    try:
                        pick = _solve(loss, rate, budget_bits, "fast")
                    except InfeasibleBudgetError:
                        continue
                    w_sh = 1.0 if weights is None else weights["sh"]
                    total = float(loss[np.arange(len(pick)), pick].sum()) + w_sh * sh_loss
                    if best is None or total < best[0]:
                        best = (total, model, keep)
            for model in sh_models:
                consider(model, model.keeps(min_keep))
            # the largest regular keep-count won: the budget may afford still more exact vectors
            if best is not None and best[2] == max(best[1].keeps(min_keep)) and best[2] < best[1].m:
                model = best[1]
                consider(model, [k for k in model.keeps(min_keep, KEEP_FRACTIONS_HIGH) if k > best[2]])
            # estimates say nothing fits: try the cheapest SH anyway, calibration decides
            sh_model, keep = (sh_models[-1], min_keep) if best is None else (best[1], best[2])
            sh_plan = sh_model.encode(keep)
            progress.log(f"tau {stage.reserve}: keep {sh_plan.keep} exact SH vectors "
                         f"(SH chunks {sum(map(len, sh_plan.chunk)):,} B)")
    res = _calibrate(stage, target, sopts, progress, loss, rate, shapes, base_fixed, sh_plan)
    # every attribute group at its best width and the file still short of the budget (the depth
    # walk reads this, whether or not the SH then spend the rest)
    saturated = res is not None and res.left_over(target, sopts.tolerance)
    if saturated and sh_plan is not None:
        res = _spend_saturated(stage, target, sopts, progress, loss, rate, shapes, base_fixed,
                               sh_model, sh_plan, res, weights)
    if res is None:
        return None                   # _calibrate logged why
    data, cloud, info = res.best
    info = dict(info, rounds=res.history, sh_plan=res.sh_plan, shapes=shapes, fixed_bytes=res.fixed,
                attributes_saturated=saturated)
    log.append({"reserve": stage.reserve, "bytes": len(data), "rounds": res.history})
    return data, cloud, info


@dataclass
class _Calibrated:
    best: tuple               # (data, cloud, info) of the largest file at or below the target
    history: list             # per round: solver budget, predicted and actual bytes
    saturated: bool           # stopped because more budget bought nothing more
    sh_plan: _ShPlan | None
    fixed: float

    def left_over(self, target: int, tolerance: float) -> bool:
        """Saturated and still more than ``tolerance`` below the target: bytes no attribute
        group can use."""
        return self.saturated and len(self.best[0]) < target * (1 - tolerance)


def _spend_saturated(stage, target, sopts, progress, loss, rate, shapes, base_fixed, sh_model,
                     sh_plan, res, weights):
    """A file below the budget with every attribute group at its best width: spend the rest on
    the SH.  While not every vector is kept exact, keep more (the keep-count grid and its
    estimate are coarse there: tiny_graphdeco at SOG's size stopped 2.5 % short with 32 % kept,
    the estimate 14 % above the real SH bytes): the count from the measured shortfall and the
    measured bytes per kept vector, twice at most.  Once all are exact, their groups join the
    allocation at SH_BITS..16 bits (below a scene's maximum quality they would trade against the
    attributes, which measured worse: jug noised 8x -0.4 dB).  Returns the best result."""
    m = sh_model.m
    for _ in range(2):
        if sh_plan.keep >= m or not res.left_over(target, sopts.tolerance):
            break
        short = target * (1 - 0.5 * sopts.tolerance) - len(res.best[0])
        est_per_vector = max(1e-3, (sh_model.base.bits_per_kept - sh_model.index_bits) / 8)
        real_over_est = sum(map(len, sh_plan.chunk)) / max(1.0, sh_plan.est_bytes)
        keep = min(m, sh_plan.keep + max(1, int(short / (est_per_vector * real_over_est))))
        progress.log(f"tau {stage.reserve}: {short:,.0f} B left with every group at its best width: "
                     f"keeping {keep:,} SH vectors exact instead of {sh_plan.keep:,}")
        plan = sh_model.encode(keep)
        more = _calibrate(stage, target, sopts, progress, loss, rate, shapes, base_fixed, plan)
        if more is None or len(more.best[0]) <= len(res.best[0]):
            break
        sh_plan, res = plan, more
    if sh_plan.keep >= m and res.left_over(target, sopts.tolerance):
        progress.log(f"tau {stage.reserve}: every SH vector exact and bytes left: their groups join "
                     f"the allocation at {SH_BITS}-16 bits")
        with progress.stage("tables", f"tau {stage.reserve}: kept SH vectors' loss + rate"):
            kept = _kept_tables(sh_plan, 1.0 if weights is None else weights["sh"])
        more = _calibrate(stage, target, sopts, progress, loss, rate, shapes, base_fixed, sh_plan,
                          kept=kept)
        if more is not None and len(more.best[0]) > len(res.best[0]):
            res = more
    return res


def _kept_tables(plan: _ShPlan, weight: float) -> list:
    """Per layer with kept exact SH vectors: (layer, loss [D, B, 16] = SSE times the SH
    channel weight, rate [D, B, 16] with +inf below SH_BITS) of their groups."""
    from gsz.kernels.quantize import quantize_all_bits

    from .rate import rate_matrix
    out = []
    for li, (sel, kb) in enumerate(plan.payloads.kept_sets):
        if sel.size:
            x = plan.payloads.kept_vectors(li)
            b = blocks_for(sel.size, kb)
            loss = quantize_all_bits(x, b)[3] * weight
            rate = rate_matrix(x, b, (SH_BITS, 16))
            out.append((li, loss, rate))
    return out


def _calibrate(stage, target, sopts, progress, loss, rate, shapes, base_fixed, sh_plan,
               kept=None) -> _Calibrated | None:
    """Find the largest solver budget whose real file fits (the attributes' allocation; with
    ``kept`` -- :func:`_kept_tables` -- the kept SH vectors' groups are allocated with them).
    None when no allocation fits."""
    from .bit_allocation import InfeasibleBudgetError

    n_attr, attr_shapes = loss.shape[0], shapes
    kept_layers = []
    if kept:
        kept_layers = [li for li, _, _ in kept]
        loss = np.concatenate([loss] + [l.reshape(-1, 16) for _, l, _ in kept])
        rate = np.concatenate([rate] + [r.reshape(-1, 16) for _, _, r in kept])
        shapes = attr_shapes + tuple(l.shape[:2] for _, l, _ in kept)
        sh_fixed = sh_plan.payloads.fixed_bytes
    else:
        sh_fixed = sum(map(len, sh_plan.chunk)) if sh_plan else 0
    fixed = base_fixed - _group_meta_bytes(attr_shapes) + sh_fixed

    # The estimate's error (actual - predicted) drifts slowly, so the first step corrects by the
    # observed offset; afterwards the solver budget is bracketed between the largest budget
    # known to fit and the smallest known to overflow, and the next budget interpolated between
    # them (regula falsi, kept 10 % away from either end): the real size grows faster or slower
    # than the predicted one (jug 12x: 1.25 bytes per predicted byte), which a 1:1 step misses
    # and plain bisection needs more rounds to absorb.
    lo_ok = target * (1.0 - sopts.tolerance)
    group_meta = _group_meta_bytes(shapes)
    budget_bytes = float(target - fixed - group_meta)
    fit = over = None          # (solver budget, real bytes): largest budget that fit, smallest that overflowed
    pts = []                   # (solver budget, real bytes) of the rounds before a bracket exists
    aim = target * (1 - 0.5 * sopts.tolerance)
    best = None
    tried = {}
    history = []
    saturated = False
    cheapest = np.argmin(np.where(np.isfinite(rate), rate, np.inf), axis=1)
    prev_key = None
    for rnd in range(sopts.max_rounds):
        try:
            pick = _solve(loss, rate, 8.0 * budget_bytes, sopts.solver)
        except InfeasibleBudgetError:
            pick = cheapest                      # measure the cheapest allocation for real
        key = pick.tobytes()
        if key in tried:
            data, cloud, info = tried[key]
        else:
            layer_bits = _split_bits(pick[:n_attr], attr_shapes)
            raht_bits, scale_bits = _concat_bits(layer_bits)
            kept_bits = _split_kept_bits(pick[n_attr:], shapes[len(attr_shapes):], kept_layers,
                                         len(stage.layers))
            with progress.stage("calibrate", f"tau {stage.reserve} round {rnd + 1}"):
                attr, decoded, attr_stats = attribute_chunks(stage, layer_bits, sopts.blocks)
                if sh_plan is None:
                    sh_chunk_ = sh_rest = None
                elif kept:
                    sh_chunk_, sh_rest, _ = sh_plan.payloads.payloads(kept_bits)
                else:
                    sh_chunk_, sh_rest = sh_plan.chunk, sh_plan.sh_rest
                extra = {"sh_keep": sh_plan.keep if sh_plan else 0}
                data, cloud, meta_len = assemble(stage, attr, decoded, sh_chunk_, sh_rest,
                                                 _meta(stage, sopts, target, extra))
            info = {"pick": pick, "raht_bits": raht_bits, "scale_bits": scale_bits, "layer_bits": layer_bits,
                    "kept_bits": kept_bits, "sh_bytes": sum(map(len, sh_chunk_)) if sh_plan else 0,
                    "attr_stats": attr_stats, "attr_bytes": sum(map(len, attr)), "meta_bytes": meta_len,
                    "predicted_bytes": fixed + group_meta + float(rate[np.arange(len(pick)), pick].sum()) / 8,
                    "loss": float(loss[np.arange(len(pick)), pick].sum())}
            tried[key] = (data, cloud, info)
        actual = len(data)
        history.append({"round": rnd + 1, "solver_budget_bytes": round(budget_bytes),
                        "predicted_bytes": round(info["predicted_bytes"]), "actual_bytes": actual})
        if actual <= target and (best is None or actual > len(best[0])):
            best = (data, cloud, info)
        if lo_ok <= actual <= target:
            break
        if actual > target:
            if key == cheapest.tobytes():
                break                            # even the cheapest allocation overflows
            if over is None or budget_bytes < over[0]:
                over = (budget_bytes, actual)
        else:
            if key == _solve_max(loss, rate).tobytes() or (over is None and history[:-1] and key == prev_key):
                saturated = True
                break                            # more budget buys nothing more: saturated
            if fit is None or budget_bytes > fit[0]:
                fit = (budget_bytes, actual)
        prev_key = key
        if fit is not None and over is not None:
            if over[0] - fit[0] < 1.0:
                break
            t = (aim - fit[1]) / (over[1] - fit[1]) if over[1] > fit[1] else 0.5
            budget_bytes = fit[0] + min(0.9, max(0.1, t)) * (over[0] - fit[0])
        else:
            pts.append((budget_bytes, actual))
            slope = 0.0
            if len(pts) >= 2 and pts[-1][0] != pts[-2][0]:
                slope = (pts[-1][1] - pts[-2][1]) / (pts[-1][0] - pts[-2][0])
            if slope > 0:
                # two rounds on the same side: secant through them (the real size may grow
                # well below 1:1 with the predicted one -- flowers 8x: 0.6 -- where 1:1 steps
                # close only part of the gap each round)
                budget_bytes += (aim - actual) / min(4.0, max(0.25, slope))
            else:
                # correct by the observed error, starting from what this allocation was
                # predicted to need (a saturated allocation may sit far below its budget)
                pred_attr = float(rate[np.arange(len(pick)), pick].sum()) / 8
                budget_bytes = min(budget_bytes, pred_attr) + (aim - actual)
    if best is None:
        progress.log(f"tau {stage.reserve}: no allocation fits; calibration {history}")
        return None
    return _Calibrated(best, history, saturated, sh_plan, fixed)


def _solve_max(loss, rate) -> np.ndarray:
    """The allocation with the smallest loss per group (what any large budget converges to)."""
    l2 = np.where(np.isfinite(rate), loss, np.inf)
    return np.argmin(l2, axis=1)


def _size_bounds(stage: Stage, blocks: int) -> tuple[float, float]:
    """Rough (min, max) file bytes at this tau: all groups at 1 bit / at 16 bits."""
    lo = hi = stage.geometry_bytes + 400.0
    for (x, b), (_, r) in zip(_attribute_sets(stage, blocks), _raw_tables(stage, blocks)):
        if x.shape[1]:
            lo += r[:, :, 0].sum() / 8 + 9 * r.shape[0] * b
            hi += r[:, :, 15].sum() / 8 + 9 * r.shape[0] * b
    if stage.sh.shape[1]:
        m, d = stage.sh.shape
        lo += m * 12 / 8 + 64
        hi += m * d * 16 / 8
    return lo, hi


def eval_cameras(cloud, sopts: SearchOptions, cameras=None) -> list:
    """The train views candidates are compared on: ``eval_views`` of the caller's train cameras
    spread evenly over them (downscaled to ``eval_width`` where wider), or generated views at
    ``eval_width`` when there are none."""
    from .evaluate import pick_evenly
    if cameras:
        return [c.scaled(sopts.eval_width) if c.width > sopts.eval_width else c
                for c in pick_evenly(list(cameras), max(sopts.eval_views, 1))]
    return load_cameras(None, cloud, n_train=max(sopts.eval_views, 1), n_test=1,
                        width=sopts.eval_width).train[:sopts.eval_views]


def _search_setup(cloud, sopts, taus, stage_for, progress, cameras=None):
    """The main thread's share of the set-up while the codebooks train: the largest tau's stage
    (geometry, tables, size bounds), the train-view references and the channel weights."""
    from .metrics import quantize_8bit
    from .render import render
    top = stage_for(taus[0])
    with progress.stage("tables", f"tau {taus[0]}: size bounds"):
        lo1, hi1 = _size_bounds(top, sopts.blocks)
    eval_cams = eval_cameras(cloud, sopts, cameras)
    with progress.stage("eval-reference", f"{len(eval_cams)} train views"):
        # float renders (the first two also serve as the sensitivity's base), 8-bit as
        # render_views makes them
        ref_float = [render(cloud, c).image for c in eval_cams]
        refs = [quantize_8bit(np.asarray(img)) for img in ref_float]
    weights = None
    if sopts.weight_channels:
        with progress.stage("sensitivity", "per-channel rendering weights of Omega"):
            weights = channel_weights(cloud, eval_cams[:2], seed=sopts.seed, base_images=ref_float[:2])
    return refs, eval_cams, weights, lo1, hi1, top


@dataclass
class _ShSource:
    """The SH vectors and importance a codebook is trained on (a Stage's fields)."""
    sh: np.ndarray
    importance: np.ndarray
    num_points: int


def encode_to_budget(cloud, target_bytes: int, *, options: SearchOptions | None = None,
                     importance: np.ndarray | None = None, cameras=None,
                     progress: Progress | None = None) -> EncodeResult:
    """Encode ``cloud`` into at most ``target_bytes`` bytes with the best train-view fidelity.

    Returns EncodeResult(data, cloud, report); report has target, actual bytes, the chosen
    reserve/codebook/keep, the bit-width of every group, predicted vs actual size per calibration
    round, candidates with their train PSNR, and seconds per stage.  Raises BudgetError with the
    smallest reachable size when the budget cannot be met.
    """
    from concurrent.futures import ThreadPoolExecutor

    # every candidate's octree is coded on this thread while the caller computes the candidate's
    # SH statistics and rate tables (flowers: ~1.4 s of each ~10 s candidate)
    with _search_threads(), ThreadPoolExecutor(max_workers=1, thread_name_prefix="gsz-geom") as pool:
        return _encode_to_budget(cloud, target_bytes, options, importance, cameras, progress, pool)


@contextlib.contextmanager
def _search_threads():
    """torch's own maths single-threaded for the search, the renderer on every core.

    The search's torch work is many small ops (quantising one channel set block by block, SH
    k-means chunks); on the shared 2-core machine two OpenMP threads stall at every barrier
    when another job holds a core (measured: quantize_groups of a 24 x 170k SH set 1.1 s with 2
    threads vs 0.03-0.05 s with 1; 47 such calls cost 32 s of a flowers search).  The renderer
    hands out tiles dynamically, so it keeps the cores torch had.  Results do not depend on
    either thread count."""
    import torch

    from .render import render_threads
    old = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        with render_threads(old):
            yield
    finally:
        torch.set_num_threads(old)


#: A candidate's train views are rendered hardest first (lowest PSNR of the best candidate so
#: far); once at least EVAL_MIN_VIEWS of them trail the best's renders of the same views by more
#: than EVAL_DROP_MARGIN_DB on average, the candidate is dropped without rendering the rest (the
#: remaining, easier views would have to make up that deficit).  This mostly saves the renders of
#: the depth walk's losing steps.
EVAL_MIN_VIEWS = 3
EVAL_DROP_MARGIN_DB = 1.0


def _train_psnr(refs, cloud, cameras, best_views=None) -> tuple[float, list, int]:
    """(mean PSNR over the views rendered, per-view PSNRs (None where not rendered), 0 when every
    view was rendered else how many were) with gsz-eval's protocol (8-bit renders, per-view PSNR,
    plain mean) -- all the search compares candidates by; SSIM would cost more than the renders.
    With ``best_views`` (the best candidate's per-view PSNRs) the candidate may be dropped early,
    see EVAL_DROP_MARGIN_DB."""
    from .evaluate import render_views
    from .metrics import psnr
    if best_views is None:
        imgs = render_views(cloud, cameras)
        views = [psnr(r, i) for r, i in zip(refs, imgs)]
        return float(np.mean(views)), views, 0
    views = [None] * len(cameras)
    diffs = []
    for i in np.argsort(np.asarray(best_views), kind="stable"):
        views[i] = psnr(refs[i], render_views(cloud, [cameras[i]])[0])
        diffs.append(views[i] - best_views[i])
        if EVAL_MIN_VIEWS <= len(diffs) < len(cameras) and float(np.mean(diffs)) < -EVAL_DROP_MARGIN_DB:
            return float(np.mean([v for v in views if v is not None])), views, len(diffs)
    return float(np.mean(views)), views, 0


#: Screening stops rendering a tau's exact-attribute bound, and lets the tau through, once the
#: views rendered so far (at least SCREEN_MIN_VIEWS) beat the best candidate's renders of the
#: same views by SCREEN_PASS_MARGIN_DB on average (per-view differences: the views' own
#: difficulty, which spreads their PSNRs over 10+ dB, cancels).  A let-through tau is encoded
#: and compared as usual, and a tau that screening would skip cannot win anyway, so this only
#: trades render time against encodes; it never changes which file is chosen.
SCREEN_MIN_VIEWS = 2
SCREEN_PASS_MARGIN_DB = 1.5


def _screen_psnr(refs, cloud, cameras, best_views) -> tuple[float, int]:
    """(mean PSNR over the views rendered, 0 when all were rendered, else how many): renders
    view by view and stops early when the tau clearly passes (see SCREEN_PASS_MARGIN_DB).
    The views go hardest first (lowest PSNR of the best candidate): there pruning error, which
    the bound keeps, dominates quantisation error, which it drops, so the bound is tightest."""
    from .evaluate import render_views
    from .metrics import psnr
    order = np.argsort(np.asarray(best_views), kind="stable")
    vals, diffs = [], []
    for i in order:
        vals.append(psnr(refs[i], render_views(cloud, [cameras[i]])[0]))
        diffs.append(vals[-1] - best_views[i])
        if SCREEN_MIN_VIEWS <= len(vals) < len(cameras) and float(np.mean(diffs)) > SCREEN_PASS_MARGIN_DB:
            return float(np.mean(vals)), len(vals)
    return float(np.mean(vals)), 0


def _encode_to_budget(cloud, target_bytes, options, importance, cameras, progress,
                      geometry_pool) -> EncodeResult:
    sopts = options or SearchOptions()

    def bad(msg):
        raise EncodeOptionsError(msg)
    check_layer_options(sopts.layers, sopts.first_layer, bad)
    # the importance pass's options, checked by their own rules (beta, train views, width)
    eopts = EncodeOptions(train_views=sopts.train_views, importance_width=sopts.importance_width,
                          beta=sopts.beta, seed=sopts.seed).validate()
    progress = progress or Progress(quiet=True)
    target = int(target_bytes)
    if target <= 0:
        raise BudgetError(target, 1)
    cloud.validate()
    t0, c0 = time.perf_counter(), time.process_time()
    if importance is None:
        importance = compute_train_importance(cloud, eopts, cameras=cameras, progress=progress)
    from .voxelize import DEFAULT_REL_ERROR, choose_depth
    depth = choose_depth(cloud.positions, rel_error=DEFAULT_REL_ERROR)

    # --- tau grid: bounds from cheap estimates, then candidates spread over the feasible range --
    stages: dict[float, Stage] = {}
    voxelized: dict = {}

    def vox_for(tau, d=depth):
        if (tau, d) not in voxelized:
            voxelized[(tau, d)] = voxelize_stage(cloud, importance, tau, depth=d, progress=progress)
        return voxelized[(tau, d)]

    def stage_for(tau, d=depth, fl=sopts.first_layer):
        if (tau, d, fl) not in stages:
            stages[(tau, d, fl)] = prepare_stage(cloud, importance, tau, depth=d, layers=sopts.layers,
                                                 first_layer=fl, progress=progress,
                                                 voxelized=vox_for(tau, d), pool=geometry_pool)
        return stages[(tau, d, fl)]

    taus = sorted(set(float(t) for t in sopts.reserves), reverse=True)
    # The SH codebooks are trained on the largest tau's voxels, which need no geometry coding:
    # train them on a worker thread (torch releases the GIL in its maths) while this thread
    # codes that stage, computes its tables and renders the references and sensitivities, so
    # the second core is used.  Each codebook is a deterministic function of its inputs, so
    # the overlap changes timing only.
    kept_top, vox_top = vox_for(taus[0])
    m1 = len(vox_top.ijk)
    pool = vq_job = None
    assigner = _Assigner(cloud) if cloud.sh_degree > 0 else None
    if cloud.sh_degree > 0:
        from concurrent.futures import ThreadPoolExecutor
        k_max = default_codebook_size(m1, sopts.codebook)
        ks = [k_max] if sopts.codebook is not None else sorted({k_max, max(16, k_max // 4), max(16, k_max // 16)},
                                                               reverse=True)
        src = _ShSource(sh=vox_top.cloud.sh_rest.reshape(m1, -1).astype(np.float32),
                        importance=vox_top.importance, num_points=m1)

        # the largest stage's voxels are the first the SH models need: assign them right after
        # each codebook is trained (Stage.source as prepare_stage will compute it)
        source_top = stage_source(kept_top, vox_top)

        # Codebooks are trained largest first by the worker; the main thread, once its set-up
        # is done, takes the smallest ones not started yet instead of waiting (flowers: the
        # three codebooks took ~18 s on the worker against ~12 s of set-up).  Every codebook is
        # a deterministic function of its inputs, so who trains which changes timing only.
        todo = list(range(len(ks)))
        todo_lock = threading.Lock()
        trained = [None] * len(ks)

        def train_next(smallest: bool) -> bool:
            with todo_lock:
                if not todo:
                    return False
                i = todo.pop() if smallest else todo.pop(0)
            with progress.stage("vq", f"codebook {ks[i]} on {m1} vectors, and its assignment"):
                trained[i] = train_sh_codebook(src, ks[i], seed=sopts.seed, iters=sopts.vq_iters,
                                               progress=progress)
                assigner.prime(source_top, src.sh, trained[i])
            return True

        def train_largest_first():
            while train_next(False):
                pass
        if sopts.overlap:
            pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="gsz-vq")
            vq_job = pool.submit(train_largest_first)
    try:
        refs, eval_cams, weights, lo1, hi1, top = _search_setup(cloud, sopts, taus, stage_for, progress,
                                                                cameras)
        codebooks = []
        if cloud.sh_degree > 0:
            while train_next(True):
                pass
            if vq_job is not None:
                vq_job.result()
            codebooks = trained
    finally:
        if pool is not None:
            pool.shutdown(wait=True)
    feasible = []
    for tau in taus:
        f = (math.ceil(tau * len(cloud)) / len(cloud)) / (math.ceil(taus[0] * len(cloud)) / len(cloud))
        lo, hi = lo1 * f, hi1 * f
        if lo <= target and (hi >= target or not feasible):
            feasible.append(tau)
    if not feasible:
        # even the smallest tau at 1 bit is estimated above the target: check exactly
        feasible = [taus[-1]]
    if len(feasible) > sopts.max_candidates:
        pos = np.linspace(0, len(feasible) - 1, sopts.max_candidates).round().astype(int)
        feasible = [feasible[i] for i in sorted(set(pos))]
    progress.log(f"target {target:,} bytes; candidate reserve ratios {feasible}")

    candidates, log = [], []
    evaluated = set()
    screened = []
    dropped = []

    def cannot_win(tau, d) -> bool:
        """True when even exact attributes at (tau, depth d) render no better than the best
        candidate so far (train views): then no allocation there can win and its encode is
        skipped.  Checked only below the best tau or shallower than the best depth (fewer
        Gaussians / coarser positions: the bound falls, and above the best it would almost
        never prune); monotone in tau at one depth, so a tau below one that failed at the same
        depth fails without a render."""
        if not sopts.screen or not candidates:
            return False
        best = max(candidates, key=lambda c: (c[0], c[1]))
        if tau >= best[1] and d >= best[4]["depth"]:
            return False
        inferred, partial = False, 0
        for s in screened:
            if s["skipped"] and s["reserve"] >= tau and s["depth"] == d:
                bound, inferred = s["bound_psnr"], True     # an upper bound of tau's own
                break
        else:
            with progress.stage("screen", f"tau {tau}, depth {d}: exact-attribute bound"):
                bound, partial = _screen_psnr(refs, vox_for(tau, d)[1].cloud, eval_cams,
                                              best[4]["view_psnr"])
        skip = bound <= best[0] and not partial         # a partial mean only ever lets through
        screened.append({"reserve": tau, "depth": d, "bound_psnr": bound, "inferred": inferred,
                         "views": 0 if inferred else (partial or len(eval_cams)),
                         "best_psnr": best[0], "skipped": skip})
        if skip:
            what = "a larger tau's exact attributes reach" if inferred else "exact attributes reach"
            progress.log(f"tau {tau}, depth {d}: {what} only {bound:.2f} dB <= {best[0]:.2f} dB "
                         f"(tau {best[1]}, depth {best[4]['depth']}): skipped")
        return skip

    def try_tau(tau, d=depth, fl=sopts.first_layer, min_keep=0):
        evaluated.add((tau, d))
        if fl == sopts.first_layer and not min_keep and cannot_win(tau, d):
            return
        stage = stage_for(tau, d, fl)
        sh_models = []
        if codebooks:
            with progress.stage("sh-model", f"tau {tau}: kept-vector statistics"):
                base = _ShStageStats(stage, sopts.blocks)
        for cb in codebooks:
            with progress.stage("sh-model", f"tau {tau}, codebook {len(cb)}"):
                sh_models.append(_ShModel(stage, cb, sopts.blocks, base, assigner(stage, cb)))
        res = _encode_tau(stage, target, sopts, sh_models, progress, log, weights, min_keep=min_keep)
        if res is None:
            progress.log(f"tau {tau}: budget not reachable")
            return
        data, out, info = res
        # re-split / kept-layer-0 variants may be chosen despite a lower PSNR: render them fully
        rival = (best_candidate()[4]["view_psnr"]
                 if candidates and fl == sopts.first_layer and not min_keep else None)
        with progress.stage("eval", f"tau {tau}, depth {d}"):
            p, info["view_psnr"], partial = _train_psnr(refs, out, eval_cams, rival)
        info["depth"], info["first_layer"] = d, fl
        if partial:
            progress.log(f"tau {tau}, depth {d}: {len(data):,} bytes, {partial} hardest train views "
                         f"{EVAL_DROP_MARGIN_DB:g}+ dB below the best candidate's: dropped")
            dropped.append({"reserve": tau, "depth": d, "bytes": len(data), "views": partial,
                            "partial_psnr": p})
            return
        progress.log(f"tau {tau}, depth {d}: {len(data):,} bytes, train PSNR {p:.2f} dB")
        candidates.append((p, tau, data, out, info))

    def best_candidate():
        return max(candidates, key=lambda c: (c[0], c[1]))

    def refine_tau():
        """The grid neighbours of the best candidate's tau (at its depth), while they improve."""
        for _ in range(sopts.refine_steps):
            if not candidates:
                return
            best = best_candidate()
            i, d = taus.index(best[1]), best[4]["depth"]
            nbrs = [taus[j] for j in (i - 1, i + 1)
                    if 0 <= j < len(taus) and (taus[j], d) not in evaluated]
            if not nbrs:
                return
            for tau in nbrs:
                try_tau(tau, d)

    for tau in feasible:
        try_tau(tau)
    # octree depth: the position-error default is right only in the middle of the RD range.
    # Each level costs about 3 bits per voxel and halves the position error: at high budgets
    # (attributes near their best widths) a deeper grid is worth far more than those bits
    # (houseplant at 1.5 MB: depth 11 -> 13 is 53.7 -> 60.8 dB test PSNR), at low budgets the
    # bits are better spent on attributes (houseplant 27x: depth 10 beats 11 by ~1 dB).  Walk
    # the depth from the best candidate, first in the direction its allocation suggests, while
    # the train PSNR improves; then refine tau once, at the depth the walk ends on (refining
    # before the walk as well cost one encode whenever the walk moved -- flowers 8x: tau 0.9
    # at depth 11 -- and the grid neighbour's verdict at the old depth is not the one needed).
    if candidates and sopts.depth_steps > 0:
        best = best_candidate()
        d0 = best[4]["depth"]
        lo_d = max(1, depth - sopts.depth_steps)
        hi_d = min(21, depth + min(sopts.depth_steps, sopts.max_extra_depth))
        bits_all = np.concatenate([best[4]["raht_bits"].ravel(), best[4]["scale_bits"].ravel()])
        deeper_first = best[4]["attributes_saturated"] or float(np.mean(bits_all)) >= DEPTH_DEEPER_FIRST_BITS

        def shares_voxels(tau, d) -> bool:
            return vox_for(tau, d)[1].merged_fraction >= MERGED_FRACTION_EXTRA_DEPTH
        for step in ((1, -1) if deeper_first else (-1, 1)):
            moved = looked_past = False
            d = d0
            def room(d_next):
                # Past the usual range a level pays in two cases: with every attribute group at
                # its best width and bytes left over (saturated; spent on the SH where there are
                # any) each further level costs only bytes that would buy little else; and where Gaussians still share voxels, each level
                # separates more of them -- merging loses far more than the position error a
                # level halves (tiny_graphdeco, whose positions sit on a delivery grid, at 8x:
                # 6.7 % merged at depth 14, 4.1 % at 19; test PSNR 49.8 -> 61.6 dB at the same
                # bytes).  Where (almost) nothing merges (flowers: 0.02 % at depth 13) a level
                # only halves an already small position error.
                cap = hi_d
                cb = best_candidate()
                if step > 0 and (cb[4]["attributes_saturated"] or shares_voxels(cb[1], cb[4]["depth"])):
                    cap = min(21, depth + SATURATED_EXTRA_DEPTH)
                return lo_d <= d_next <= cap
            while room(d + step) and (best[1], d + step) not in evaluated:
                before = best_candidate()
                progress.log(f"depth {d + step} at tau {before[1]} (best so far: depth "
                             f"{before[4]['depth']}, {before[0]:.2f} dB train PSNR)")
                try_tau(before[1], d + step)
                if best_candidate() is before:
                    # Where Gaussians still share voxels the gain per level is uneven (each
                    # level separates a different share of them: tiny_graphdeco's exact-
                    # attribute PSNR over depths 13-16 is 48.1, 48.3, 50.5, 51.7 dB), so a
                    # level that does not pay is looked past (not two in a row).
                    if (step > 0 and not looked_past and room(d + 2 * step)
                            and (best[1], d + 2 * step) not in evaluated
                            and shares_voxels(before[1], d + step)):
                        looked_past = True
                        d += step
                        continue
                    break
                if best_candidate()[0] - before[0] < DEPTH_STEP_MIN_GAIN_DB and not moved:
                    # a first step that gains only hundredths of a dB says little about this
                    # direction: try the other one too (the new candidate stays in the pool)
                    break
                d += step
                moved, looked_past = True, False
                if d > hi_d and best_candidate()[0] - before[0] < SATURATED_MIN_GAIN_DB:
                    break           # past the usual range, further levels no longer pay
            if moved:
                break
    refine_tau()
    # layered files: layer 0 should arrive after about `layer0_share` of the bytes.  Kept exact
    # SH vectors make the most important Gaussians several times dearer than the rest, so on SH
    # scenes a Gaussian share of `first_layer` can cost far more bytes; re-split the chosen
    # configuration with a proportionally smaller layer 0 (at most twice).
    # A layer 0 that holds codeword indices also carries the whole SH codebook (GSZ.md §4.1),
    # which on small scenes outweighs everything else in it (tiny_graphdeco at 12x: a 47 kB
    # codebook for 87 Gaussians); keeping layer 0's vectors exact instead moves the codebook to
    # layer 1, so that variant is tried too.  Among the candidates, those whose layer 0 arrives
    # in time win over those that do not.
    rejected = set()

    def share_of(c) -> float:
        return layer_report(c[2])[0]["decodable_fraction"]

    def layer0_late(c) -> bool:
        return share_of(c) > 1.5 * sopts.layer0_share
    for _ in range(2 if sopts.layers > 1 else 0):
        pool = [c for c in candidates if id(c) not in rejected]
        if not pool:
            break
        best = max(pool, key=lambda c: (c[0], c[1]))
        share = share_of(best)
        if share <= 1.5 * sopts.layer0_share:
            break
        fl = best[4]["first_layer"] * sopts.layer0_share / share
        progress.log(f"layer 0 arrives after {100 * share:.1f} % of the file: re-splitting the layers "
                     f"with {100 * fl:.2f} % of the Gaussians in layer 0")
        n_before = len(candidates)
        try_tau(best[1], best[4]["depth"], fl)
        n0 = stage_for(best[1], best[4]["depth"], best[4]["first_layer"]).layers[0].num_points
        plan = best[4]["sh_plan"]
        if plan is not None and plan.keep < n0:
            progress.log(f"... and keeping layer 0's {n0:,} SH vectors exact (the codebook then "
                         f"travels with layer 1)")
            try_tau(best[1], best[4]["depth"], best[4]["first_layer"], min_keep=n0)
        if len(candidates) > n_before:
            rejected.add(id(best))
    if not candidates:
        smallest = _smallest_file(stage_for(taus[-1]), sopts, codebooks[-1] if codebooks else None)
        raise BudgetError(target, smallest)
    chosen = [c for c in candidates if id(c) not in rejected]
    if sopts.layers > 1 and any(not layer0_late(c) for c in chosen):
        chosen = [c for c in chosen if not layer0_late(c)]
    chosen.sort(key=lambda c: (-c[0], -c[1]))
    psnr, tau, data, out, info = chosen[0]
    stage = stage_for(tau, info["depth"], info["first_layer"])
    sh_plan = info["sh_plan"]
    report = {
        "mode": "size-search", "target_bytes": target, "bytes": len(data),
        "deviation": (len(data) - target) / target, "reserve": tau, "depth": stage.depth,
        "input_gaussians": len(cloud), "voxels": stage.num_points,
        "bytes_per_gaussian": len(data) / stage.num_points, "sh_degree": cloud.sh_degree,
        "codebook_size": int(sh_plan.stats["codebook_size"]) if sh_plan else 0,
        "sh_keep": int(sh_plan.keep) if sh_plan else 0,
        "layers": layer_report(data),
        "layer_blocks": [int(b.shape[1]) for b, _ in info["layer_bits"]],
        "bits": {"raht": info["raht_bits"].tolist(), "scales": info["scale_bits"].tolist(),
                 "raht_channels": ["opacity", "roll", "pitch", "yaw", "f_dc_0", "f_dc_1", "f_dc_2"],
                 "scale_channels": ["scale_0", "scale_1", "scale_2"], "sh": SH_BITS if sh_plan else None,
                 # per layer: the kept exact SH vectors' group widths [D][B_l] where they were
                 # allocated (budgets above the SH_BITS quality ceiling), else None (SH_BITS)
                 "sh_kept": [None if b is None else b.tolist() for b in info["kept_bits"]]},
        "calibration": info["rounds"],
        "calibration_all": log,
        "first_layer": info["first_layer"],
        "candidates": [{"reserve": c[1], "depth": c[4]["depth"], "first_layer": c[4]["first_layer"],
                        "bytes": len(c[2]), "train_psnr": c[0], "train_view_psnr": c[4]["view_psnr"],
                        "layer0_too_late": id(c) in rejected}
                       for c in sorted(candidates, key=lambda c: -c[1])],
        "screened": screened,
        "dropped": dropped,
        "train_psnr": psnr, "channel_weights": weights, "beta": float(sopts.beta),
        "eval_views": [c.name for c in eval_cams],
        "eval_size": [int(eval_cams[0].width), int(eval_cams[0].height)] if eval_cams else None,
        "components": {"geometry": stage.geometry_bytes, "attributes": info["attr_bytes"],
                       **info["attr_stats"], "sh": info["sh_bytes"],
                       "metadata": info["meta_bytes"]},
        "seconds": dict(progress.seconds), "total_seconds": time.perf_counter() - t0,
        # CPU seconds of this process (all its threads): on a shared machine the wall clock
        # depends on the other jobs, this mostly does not
        "cpu_seconds": time.process_time() - c0,
    }
    if len(data) < target * (1.0 - sopts.tolerance):
        bits_all = np.concatenate([info["raht_bits"].ravel(), info["scale_bits"].ravel()]
                                  + [b.ravel() for b in info["kept_bits"] if b is not None])
        report["note"] = (f"file is {100 * (1 - len(data) / target):.2f} % below the target: "
                          + ("the budget exceeds the maximum-quality size of this scene at the chosen reserve "
                             "ratio (every group at its best bit-width)" if bits_all.min() >= 12 or tau == 1.0
                             else "calibration did not reach the tolerance within the round limit"))
        progress.log(report["note"])
    return EncodeResult(data=data, cloud=out, report=report)


def _smallest_file(stage: Stage, sopts: SearchOptions, codebook) -> int:
    """Exact size of the smallest file the search can make at this tau (1 bit everywhere,
    no kept SH)."""
    sh = sh_rest = None
    if codebook is not None:
        sh, sh_rest, _ = sh_chunk(stage, codebook, 0, SH_BITS, sopts.blocks,
                                  cb_blocks=sh_set_blocks(len(codebook), sopts.blocks))
    attr, decoded, _ = attribute_chunks(stage, 1, sopts.blocks)
    data, _, _ = assemble(stage, attr, decoded, sh, sh_rest, _meta(stage, sopts, 0, {"sh_keep": 0}))
    return len(data)
