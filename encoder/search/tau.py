"""One candidate stage (a tau at a depth and layer split): the SH codebook and keep-count chosen
jointly with the bit allocation, then calibration, then -- when every attribute group is at its
best width and bytes are left -- spending the rest on the SH."""
from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from ...decoder.sh import SH_COLOUR_KLT
from ..pipeline import SH_CLASS_MIN_SIZE, SH_CLASSES, Stage, sh_colour_payload_bytes
from .calibration import Calibrated, calibrate, solve, solve_max, with_kept
from .candidate import Encoded
from .options import SH_BITS, SearchOptions
from .sh_model import KEEP_FRACTIONS_HIGH, ShModel, ShPlan, kept_tables
from .tables import attribute_tables, container_overhead, group_meta_bytes, num_chunks


def encode_tau(stage: Stage, target: int, sopts: SearchOptions, sh_models: list, progress,
               log: list, weights: dict | None = None, min_keep: int = 0,
               codebook: bool = True, errors: dict | None = None,
               widths_lead: bool = False, codebook_far_behind: bool = False) -> Iterator[Encoded]:
    """Allocate + calibrate one tau.  Yields its encodes at or below target, none when the
    budget is unreachable at this tau (one at a time: the caller scores and releases each scene
    before the next is made): the codebook path's, and the scalar SH path's too when
    its estimate beats the codebook's -- the caller renders both and keeps the better (the two
    estimates are not the same kind of number; docs/design/sh-scalar.md) -- and, in KLT axes,
    the refined codebook's (every vector a codeword plus an allocated correction;
    docs/design/sh-refine.md).  ``min_keep``: keep at least
    this many exact SH vectors (the most important ones).  ``codebook`` False: the codebook path
    lost to another SH path as rendered earlier in the search, so where most vectors are kept
    exact it is encoded only when no other path fits (and the scalar path is weighed without
    its estimate).  ``errors``: the search's rate-estimate errors per SH path
    (:func:`calibration.calibrate`), read and updated.  ``widths_lead``: the search's best
    candidate so far allocates its kept vectors' widths (a classes- or scalar-path file), so the
    scalar path is encoded here too, whatever the codebook's keep-count and estimate say (they
    are the codebook model's view, which the renders overruled; the scalar path is where
    allocated widths end, every vector kept).  ``codebook_far_behind``: the codebook path
    rendered EVAL_DROP_MARGIN_DB or more below another path once, so with ``codebook`` False it
    is encoded only when no other path fits, whatever the keep-count."""
    with progress.stage("tables", f"tau {stage.reserve}: loss + rate matrices"):
        loss, rate, shapes = attribute_tables(stage, sopts.blocks, weights)
    meta_guess = 400
    base_fixed = (container_overhead(num_chunks(stage)) + stage.geometry_bytes + meta_guess
                  + (2 + 8 * 7) * len(stage.layers) + sh_colour_payload_bytes(stage)
                  + group_meta_bytes(shapes))
    args = (stage, target, sopts, progress, loss, rate, shapes, base_fixed)
    if not sh_models:
        res = calibrate(*args, None, errors=errors, path=None)
        if res is not None:
            yield _finish(stage, res, res.left_over(target, sopts.tolerance), "vq", log)
        return
    with progress.stage("sh-plan", "codebook size and keep-count vs bit allocation"):
        sh_model, keep, vq_total = choose_sh(sh_models, loss, rate, target - base_fixed, weights, min_keep,
                                             sopts.codebook_bits)
    # corrections are scalar-coded, which pays in the file's own axes (the KLT) and not in
    # luma/chroma (trained tiny at 12x: -0.5 dB there, +0.1 in KLT axes; docs/design/sh-refine.md)
    refine_model = (refine_codebook(sh_models, target - base_fixed)
                    if sopts.sh_refine and stage.sh_colour & SH_COLOUR_KLT else None)
    sh_models = None        # the other codebooks' models go (16 bytes a voxel each)
    m, w_sh, keep_estimate = sh_model.m, 1.0 if weights is None else weights["sh"], keep
    # the codebook path is skipped (after it lost) only where the estimate keeps most vectors
    # exact: below that, which path renders better changes with the depth (flowers 12x: the
    # scalar path 0.3 dB better at depth 11, the codebook 0.6 dB better at 13) -- unless it was
    # a whole drop margin behind, which no depth step was seen to turn around (the 1.2 M noised
    # bench scene: 2.2 dB behind at depth 14, dropped at 15, 17 and 18: ~10 s an encode)
    codebook = codebook or (keep < CODEBOOK_SKIP_MIN_KEEP * m and not codebook_far_behind)
    plans: dict = {}

    def classes_plan(k: int) -> tuple:
        """(plan, kept tables) of ``k`` kept vectors in importance classes, made once (every
        vector kept in classes is the scalar path's plan too)."""
        if k not in plans:
            with progress.stage("sh-plan", f"{k:,} kept SH vectors in importance classes, widths allocated"):
                plan = sh_model.encode(k, code=False, classes=SH_CLASSES)
                plans[k] = (plan, kept_tables(plan, w_sh, min_bits=1))
        return plans[k]
    scalar = None
    if sopts.sh_scalar and (SCALAR_MIN_KEEP * m <= keep or widths_lead) and (keep < m or not codebook):
        scalar = scalar_sh(classes_plan(m), loss, rate, target - base_fixed,
                           vq_total if codebook and not widths_lead else None)
        if scalar is not None and codebook and not widths_lead:
            progress.log(f"tau {stage.reserve}: the scalar SH path (every vector quantised "
                         f"group-wise, 1-16 bits in the allocation) is estimated better than the "
                         f"codebook: both are encoded and rendered")
    saturated, found = False, False
    if codebook:
        res, saturated = _codebook_path(args, sh_model, keep, weights, errors)
        if res is not None:
            keep = res.sh_plan.keep
            found = True
            yield _finish(stage, res, saturated, "vq", log)
            res = None      # its plan and best round (scene recipe), before the next path's
    # the codebook path again with its kept vectors in importance classes, their widths
    # allocated (1-16 bits or constant): at the chosen keep-count, or once spend_saturated keeps
    # every vector (its 8-16-bit widths would otherwise cap the SH where classes pay most)
    if not saturated:
        # in classes a kept vector costs far less than at 8 bits, which the keep-count estimate
        # assumes: at low rates keeping the most important few pays even where that says none
        keep = min(m, max(keep, int(round(CLASSES_MIN_KEEP * m))))
    if (sopts.sh_classes and keep >= SH_CLASS_MIN_SIZE * SH_CLASSES
            and not (saturated and keep < m)):
        res = calibrate(*args, *classes_plan(keep), errors=errors, path="classes")
        if res is not None and not codebook and keep < m and res.left_over(target, sopts.tolerance):
            # without the codebook path's spend_saturated: every group at its best width and
            # bytes left, so every vector kept (the allocation then trades their widths)
            keep = m
            res = calibrate(*args, *classes_plan(m), errors=errors, path="classes") or res
        if keep >= m:
            scalar = None           # every vector kept in classes is the scalar path's file
        if res is not None:
            found = True
            yield _finish(stage, res, _attributes_at_max(res, loss, rate), "classes", log)
            res = None
    if scalar is not None:
        res = calibrate(*args, scalar[0], kept=scalar[1], errors=errors, path="scalar")
        if res is not None:
            found = True
            # the SH take every byte the attributes leave: what the depth walk reads is whether
            # every attribute group sits at its best width (as the codebook path's saturation)
            yield _finish(stage, res, _attributes_at_max(res, loss, rate), "scalar", log)
            res = None
    if refine_model is not None and m >= SH_CLASS_MIN_SIZE * SH_CLASSES:
        # every vector its codeword plus a correction in importance classes, the corrections'
        # widths allocated (width 0: the class's mean shift only): the codebook takes the
        # coarse shape, the allocation what it misses (docs/design/sh-refine.md)
        with progress.stage("sh-plan", f"every SH vector one of {refine_model.codebook.shape[0]:,} codewords "
                                       f"+ its correction, widths allocated"):
            plan = refine_model.encode(m, code=False, classes=SH_CLASSES, refine=True)
            refined = (plan, kept_tables(plan, w_sh, min_bits=1))
        plan = None         # held by ``refined`` only, so both go before the yield (the caller renders)
        res = calibrate(*args, *refined, errors=errors, path="refine")
        refined = None
        if res is not None:
            found = True
            yield _finish(stage, res, _attributes_at_max(res, loss, rate), "refine", log)
    if not codebook and not found:
        res, saturated = _codebook_path(args, sh_model, keep_estimate, weights, errors)
        if res is not None:
            yield _finish(stage, res, saturated, "vq", log)


#: The refined path's codebook is the largest of the search's whose estimated bytes stay within
#: this share of the stage's room: its words are paid once, the corrections per vector, and a
#: codebook sized for the codebook path alone (trained tiny at 12x: 1,066 words, a quarter of
#: the room) leaves the corrections too little (docs/design/sh-refine.md)
REFINE_CODEBOOK_SHARE = 0.1


def refine_codebook(sh_models: list, room: float) -> ShModel | None:
    """The codebook model of the refined SH path (REFINE_CODEBOOK_SHARE), None when none fits."""
    fits = [mdl for mdl in sh_models if mdl.codebook_bytes <= REFINE_CODEBOOK_SHARE * room]
    return max(fits, key=lambda mdl: mdl.codebook.shape[0]) if fits else None


def _codebook_path(args, sh_model: ShModel, keep: int, weights, errors=None) -> tuple[Calibrated | None, bool]:
    """(calibrated, saturated) of the codebook path: a codebook for the SH and ``keep`` vectors
    exact at SH_BITS, the rest spent on more exact vectors when the attributes saturate."""
    stage, target, sopts, progress, loss, rate, shapes, base_fixed = args
    with progress.stage("sh-plan", "codebook path: codebook indices and kept vectors"):
        sh_plan = sh_model.encode(keep)
        progress.log(f"tau {stage.reserve}: keep {sh_plan.keep} exact SH vectors "
                     f"(SH chunks {sum(map(len, sh_plan.chunk)):,} B)")
    res = calibrate(*args, sh_plan, errors=errors, path="vq")
    # every attribute group at its best width and the file still short of the budget (the depth
    # walk reads this, whether or not the SH then spend the rest)
    saturated = res is not None and res.left_over(target, sopts.tolerance)
    if saturated:
        res = spend_saturated(*args, sh_model, sh_plan, res, weights)
    return res, saturated


def _attributes_at_max(res: Calibrated, loss, rate) -> bool:
    """Every attribute group at its best width (what the depth walk reads as saturated)."""
    return bool(np.array_equal(res.best.pick[:loss.shape[0]], solve_max(loss, rate)))


def _finish(stage: Stage, res: Calibrated, saturated: bool, path: str, log: list) -> Encoded:
    """The calibrated encode with what the search reads about it: ``res.best`` itself, so that
    the caller's release() of its decoded scene (1.4 GB at 6 M) is the only one held."""
    log.append({"reserve": stage.reserve, "depth": stage.depth, "bytes": res.best.size, "rounds": res.history,
                **({"sh_path": path} if res.sh_plan is not None else {})})
    plan = res.sh_plan
    enc = res.best
    enc.rounds, enc.attributes_saturated = res.history, saturated
    enc.sh_keep = None if plan is None else int(plan.keep)
    enc.sh_path = None if plan is None else path
    enc.codebook_size = 0 if plan is None else int(plan.stats["codebook_size"])
    enc.codebook_bits = int(plan.stats["codebook_bits"]) if enc.codebook_size else None
    enc.depth, enc.num_points = stage.depth, stage.num_points
    enc.layer0_points, enc.geometry_bytes = stage.layer0_points, stage.geometry_bytes
    return enc


#: The search may stop encoding the codebook path once it lost (driver._note_lost_paths) only
#: where the keep-count estimate keeps at least this share of the SH vectors exact.
CODEBOOK_SKIP_MIN_KEEP = 0.5

#: The classes candidate keeps at least this share of the vectors exact (docs/design/sh-classes.md).
CLASSES_MIN_KEEP = 0.04


#: The scalar SH path is weighed only when the codebook path keeps at least this share of the
#: vectors exact (high rates, where a codebook is the wrong tool); below it the codebook wins
#: and the scalar tables (every vector at every width) would cost time for nothing.  When the
#: codebook path already keeps every vector, spend_saturated covers the rest.
SCALAR_MIN_KEEP = 0.08


def scalar_sh(plan_kept: tuple, loss, rate, room: float, vq_total: float | None):
    """``plan_kept`` -- (plan, kept tables) of the scalar SH path: every vector kept, its
    (component, block) groups in the allocation at 1..16 bits, no codebook -- when its estimated
    total loss (SH plus attributes in ``room`` bytes) is below the codebook path's ``vq_total``
    (always when that is None); else None."""
    from ..bit_allocation import InfeasibleBudgetError
    from .tables import group_meta_bytes
    plan, kept = plan_kept
    if not kept:
        return None
    all_loss, all_rate, kept_shapes = with_kept(loss, rate, (), kept)
    fixed = plan.payloads.fixed_bytes + group_meta_bytes(kept_shapes)
    try:
        pick = solve(all_loss, all_rate, 8.0 * (room - fixed), "fast")
    except InfeasibleBudgetError:
        return None
    total = float(all_loss[np.arange(len(pick)), pick].sum())
    return plan_kept if vq_total is None or total < vq_total else None


#: A coarser codebook is taken only where its estimated total loss is at least this share below
#: the best at full width: near a tie the estimate's noise decides, and a coarser codebook of
#: the same size then loses (trained tiny noised at 191 kB: 6 bits at 1,134 words, -0.5 dB)
CODEBOOK_BITS_MARGIN = 0.05


def choose_sh(sh_models: list, loss, rate, room: float, weights, min_keep: int,
              codebook_bits=(SH_BITS,)) -> tuple[ShModel, int, float | None]:
    """(codebook model, keep-count, estimated total loss) whose estimated SH loss plus the loss
    of the attribute allocation in the bytes the SH leave (``room`` minus the SH estimate) is
    smallest (total None when no estimate fits).  The models' own width (SH_BITS) is always
    weighed; another of ``codebook_bits`` wins only by CODEBOOK_BITS_MARGIN."""
    from ..bit_allocation import InfeasibleBudgetError
    best = None
    w_sh = 1.0 if weights is None else weights["sh"]

    def consider(model, keeps):
        nonlocal best
        for keep in keeps:
            sh_bytes, sh_loss = model.estimate(keep)
            try:
                pick = solve(loss, rate, 8.0 * (room - sh_bytes), "fast")
            except InfeasibleBudgetError:
                continue
            total = float(loss[np.arange(len(pick)), pick].sum()) + w_sh * sh_loss
            if best is None or total < best[0]:
                best = (total, model, keep)
    for model in sh_models:
        consider(model, model.keeps(min_keep))
    # a coarser codebook only where the estimate gains clearly (CODEBOOK_BITS_MARGIN)
    at_full = best
    for model in sh_models:
        for bits in codebook_bits:
            if bits != model.cb_bits:
                consider(model.with_codebook_bits(bits), model.keeps(min_keep))
    if at_full is not None and best[0] > (1.0 - CODEBOOK_BITS_MARGIN) * at_full[0]:
        best = at_full
    # the largest regular keep-count won: the budget may afford still more exact vectors
    if best is not None and best[2] == max(best[1].keeps(min_keep)) and best[2] < best[1].m:
        model = best[1]
        consider(model, [k for k in model.keeps(min_keep, KEEP_FRACTIONS_HIGH) if k > best[2]])
    # estimates say nothing fits: try the cheapest SH anyway, calibration decides
    return (sh_models[-1], min_keep, None) if best is None else (best[1], best[2], best[0])


def spend_saturated(stage, target, sopts, progress, loss, rate, shapes, base_fixed, sh_model: ShModel,
                    sh_plan: ShPlan, res: Calibrated, weights) -> Calibrated:
    """A file below the budget with every attribute group at its best width: spend the rest on
    the SH (docs/design/sh-spend.md).  While not every vector is kept exact, keep more (the
    keep-count grid and its estimate are coarse there): the count from the measured shortfall
    and the measured bytes per kept vector, twice at most.  Once all are exact, their groups join
    the allocation at SH_BITS..16 bits (below a scene's maximum quality they would trade against
    the attributes, which did worse).  Returns the best result."""
    m = sh_model.m
    for _ in range(2):
        if sh_plan.keep >= m or not res.left_over(target, sopts.tolerance):
            break
        short = target * (1 - 0.5 * sopts.tolerance) - res.best.size
        est_per_vector = max(1e-3, (sh_model.base.bits_per_kept - sh_model.index_bits) / 8)
        real_over_est = sum(map(len, sh_plan.chunk)) / max(1.0, sh_plan.est_bytes)
        keep = min(m, sh_plan.keep + max(1, int(short / (est_per_vector * real_over_est))))
        progress.log(f"tau {stage.reserve}: {short:,.0f} B left with every group at its best width: "
                     f"keeping {keep:,} SH vectors exact instead of {sh_plan.keep:,}")
        plan = sh_model.encode(keep)
        more = calibrate(stage, target, sopts, progress, loss, rate, shapes, base_fixed, plan)
        if more is None or more.best.size <= res.best.size:
            break
        sh_plan, res = plan, more
    if sh_plan.keep >= m and res.left_over(target, sopts.tolerance):
        progress.log(f"tau {stage.reserve}: every SH vector exact and bytes left: their groups join "
                     f"the allocation at {SH_BITS}-16 bits")
        with progress.stage("tables", f"tau {stage.reserve}: kept SH vectors' loss + rate"):
            kept = kept_tables(sh_plan, 1.0 if weights is None else weights["sh"])
        more = calibrate(stage, target, sopts, progress, loss, rate, shapes, base_fixed, sh_plan,
                         kept=kept)
        if more is not None and more.best.size > res.best.size:
            res = more
    return res
