"""Calibration: encode a tau's attributes for real and move the solver budget until the file lands
within the tolerance below the target.  The best file at or below the target is kept, so the
result is never over budget."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...decoder.pages import trim_heap

from ..pipeline import attribute_chunks, decoded_cloud, payload_attributes, write_file
from .candidate import Encoded
from .sh_model import ShPlan
from .tables import group_meta_bytes, search_meta, split_bits, split_kept_bits


def solve(loss, rate, budget_bits, solver):
    from ..bit_allocation import allocate
    return allocate(loss, rate, budget_bits, method=solver)


def solve_max(loss, rate) -> np.ndarray:
    """The allocation with the smallest loss per group (what any large budget converges to)."""
    l2 = np.where(np.isfinite(rate), loss, np.inf)
    return np.argmin(l2, axis=1)


@dataclass
class Calibrated:
    best: Encoded             # the largest file at or below the target
    history: list             # per round: solver budget, predicted and actual bytes
    saturated: bool           # stopped because more budget bought nothing more
    sh_plan: ShPlan | None
    fixed: float

    def left_over(self, target: int, tolerance: float) -> bool:
        """Saturated and still more than ``tolerance`` below the target: bytes no attribute
        group can use."""
        return self.saturated and self.best.size < target * (1 - tolerance)


class _BudgetSteps:
    """Where the next round puts the solver budget.

    The estimate's error (actual - predicted) drifts slowly, so the first step corrects by the
    observed offset; afterwards the solver budget is bracketed between the largest budget known
    to fit and the smallest known to overflow, and the next budget interpolated between them
    (regula falsi, kept 10 % away from either end): the real size grows faster or slower than
    the predicted one (jug 12x: 1.25 bytes per predicted byte), which a 1:1 step misses and plain
    bisection needs more rounds to absorb."""

    def __init__(self, aim: float):
        self.aim = aim
        self.fit = self.over = None   # (solver budget, real bytes): largest that fit, smallest that overflowed
        self.pts = []                 # (solver budget, real bytes) of the rounds before a bracket exists

    def observe(self, budget: float, actual: int, overflowed: bool) -> None:
        if overflowed:
            if self.over is None or budget < self.over[0]:
                self.over = (budget, actual)
        elif self.fit is None or budget > self.fit[0]:
            self.fit = (budget, actual)

    def next(self, budget: float, actual: int, predicted_attr: float) -> float | None:
        """The next solver budget, None when the bracket has closed."""
        fit, over, aim = self.fit, self.over, self.aim
        if fit is not None and over is not None:
            if over[0] - fit[0] < 1.0:
                return None
            t = (aim - fit[1]) / (over[1] - fit[1]) if over[1] > fit[1] else 0.5
            return fit[0] + min(0.9, max(0.1, t)) * (over[0] - fit[0])
        pts = self.pts
        pts.append((budget, actual))
        slope = 0.0
        if len(pts) >= 2 and pts[-1][0] != pts[-2][0]:
            slope = (pts[-1][1] - pts[-2][1]) / (pts[-1][0] - pts[-2][0])
        if slope > 0:
            # two rounds on the same side: secant through them (the real size may grow well
            # below 1:1 with the predicted one -- flowers 8x: 0.6 -- where 1:1 steps close only
            # part of the gap each round)
            return budget + (aim - actual) / min(4.0, max(0.25, slope))
        # correct by the observed error, starting from what this allocation was predicted to
        # need (a saturated allocation may sit far below its budget)
        return min(budget, predicted_attr) + (aim - actual)


def with_kept(loss, rate, shapes: tuple, kept: list) -> tuple:
    """(loss, rate, group shapes) of the attribute groups followed by the kept SH vectors'
    groups (:func:`sh_model.kept_tables`): one allocation over both."""
    return (np.concatenate([loss] + [l.reshape(-1, 16) for _, l, _ in kept]),
            np.concatenate([rate] + [r.reshape(-1, 16) for _, _, r in kept]),
            tuple(shapes) + tuple(l.shape[:2] for _, l, _ in kept))


class _Rounds:
    """The fixed inputs of one tau's calibration and the real encode of one allocation."""

    def __init__(self, stage, target, sopts, progress, loss, rate, shapes, base_fixed, sh_plan, kept):
        self.stage, self.target, self.sopts, self.progress = stage, target, sopts, progress
        self.sh_plan, self.kept = sh_plan, kept
        self.n_attr, self.attr_shapes = loss.shape[0], shapes
        self.kept_layers = []
        if kept:
            self.kept_layers = [li for li, _, _ in kept]
            loss, rate, shapes = with_kept(loss, rate, shapes, kept)
            sh_fixed = sh_plan.payloads.fixed_bytes
        else:
            sh_fixed = sum(map(len, sh_plan.chunk)) if sh_plan else 0
        self.loss, self.rate, self.shapes = loss, rate, shapes
        self.fixed = base_fixed - group_meta_bytes(self.attr_shapes) + sh_fixed
        self.group_meta = group_meta_bytes(shapes)

    def encode(self, pick: np.ndarray, rnd: int) -> Encoded:
        stage, sh_plan = self.stage, self.sh_plan
        layer_bits = split_bits(pick[:self.n_attr], self.attr_shapes)
        kept_bits = split_kept_bits(pick[self.n_attr:], self.shapes[len(self.attr_shapes):],
                                    self.kept_layers, len(stage.layers))
        trim_heap()         # a round's coding (every kept SH vector on the scalar path) peaks a stage
        with self.progress.stage("calibrate", f"tau {stage.reserve} round {rnd + 1}"):
            # the decoded attributes are made from the payloads when the round is rendered (only
            # the round a calibration settles on is): held from here, they sat under every
            # round's SH coding (~240 MB at 6 M voxels)
            attr, _, attr_stats = attribute_chunks(stage, layer_bits, self.sopts.blocks, decode=False)
            if sh_plan is None:
                sh_chunk_ = None
            elif self.kept:
                sh_chunk_ = sh_plan.payloads.payloads(kept_bits, decoded=False)[0]
            else:
                sh_chunk_ = sh_plan.chunk
            extra = {"sh_keep": sh_plan.keep if sh_plan else 0}
            classes = sh_plan.payloads.class_chunks if sh_plan else None
            refine = sh_plan.payloads.refine_chunks if sh_plan else None
            positions = stage.positions()
            data, meta_len = write_file(stage, positions, attr, sh_chunk_,
                                        search_meta(stage, self.target, extra), classes, refine)
        g = np.arange(len(pick))
        sh_bytes = (sum(map(len, sh_chunk_)) + sum(len(c) for c in classes + refine if c)
                    if sh_plan else 0)
        # the decoded scene is made when the round is rendered: its SH (1 GB at 6 M voxels) is
        # coded again then, its attributes parsed from the payloads, rather than held by every
        # round and plan
        sh_bits = kept_bits if self.kept else None
        del positions

        def scene():
            return decoded_cloud(stage, stage.positions(), payload_attributes(stage, attr),
                                 None if sh_plan is None else sh_plan.decoded_sh(sh_bits))
        return Encoded(data=data, scene=scene, pick=pick, layer_bits=layer_bits, kept_bits=kept_bits,
                       sh_bytes=sh_bytes, attr_stats=attr_stats,
                       attr_bytes=sum(map(len, attr)), meta_bytes=meta_len,
                       predicted_bytes=self.fixed + self.group_meta + float(self.rate[g, pick].sum()) / 8,
                       loss=float(self.loss[g, pick].sum()))


#: Bound of the estimate error carried from one calibration to the next (a fraction of the
#: allocated bytes).
MAX_CARRIED_ERROR = 0.2


def calibrate(stage, target, sopts, progress, loss, rate, shapes, base_fixed, sh_plan,
              kept=None, errors: dict | None = None, path=None) -> Calibrated | None:
    """Find the largest solver budget whose real file fits (the attributes' allocation; with
    ``kept`` -- :func:`sh_model.kept_tables` -- the kept SH vectors' groups are allocated with
    them).  None when no allocation fits.

    ``errors``: {path: how much the rate estimate over-predicted the allocated bytes, as a
    fraction, in the last calibration of that SH path}; the first round corrects by it and this
    one's is stored.  The error drifts slowly from one depth or tau to the next, so the first
    round often lands within the tolerance (docs/design/search-speed.md)."""
    from ..bit_allocation import InfeasibleBudgetError

    r = _Rounds(stage, target, sopts, progress, loss, rate, shapes, base_fixed, sh_plan, kept)
    loss, rate = r.loss, r.rate
    lo_ok = target * (1.0 - sopts.tolerance)
    budget_bytes = float(target - r.fixed - r.group_meta)
    steps = _BudgetSteps(target * (1 - 0.5 * sopts.tolerance))
    carried = None if errors is None else errors.get(path)
    if carried is not None and steps.aim > r.fixed + r.group_meta:
        budget_bytes = (steps.aim - r.fixed - r.group_meta) / (1.0 - carried)
    best, tried, history = None, {}, []
    saturated = False
    cheapest = np.argmin(np.where(np.isfinite(rate), rate, np.inf), axis=1)
    prev_key = None
    for rnd in range(sopts.max_rounds):
        try:
            pick = solve(loss, rate, 8.0 * budget_bytes, sopts.solver)
        except InfeasibleBudgetError:
            pick = cheapest                      # measure the cheapest allocation for real
        key = pick.tobytes()
        if key not in tried:
            tried[key] = r.encode(pick, rnd)
        enc = tried[key]
        actual = enc.size
        history.append({"round": rnd + 1, "solver_budget_bytes": round(budget_bytes),
                        "predicted_bytes": round(enc.predicted_bytes), "actual_bytes": actual})
        if actual <= target and (best is None or actual > best.size):
            if best is not None:
                best.drop_data()             # only the best round's file is kept (its size only grows)
            best = enc
        elif enc is not best:
            enc.drop_data()
        if lo_ok <= actual <= target:
            break
        if actual > target:
            if key == cheapest.tobytes():
                break                            # even the cheapest allocation overflows
        elif key == solve_max(loss, rate).tobytes() or (steps.over is None and history[:-1] and key == prev_key):
            saturated = True
            break                                # more budget buys nothing more: saturated
        steps.observe(budget_bytes, actual, actual > target)
        prev_key = key
        budget_bytes = steps.next(budget_bytes, actual, float(rate[np.arange(len(pick)), pick].sum()) / 8)
        if budget_bytes is None:
            break
    if best is None:
        smallest = min((h["actual_bytes"] for h in history if h.get("actual_bytes")), default=None)
        progress.log(f"tau {stage.reserve}: no allocation fits ({len(history)} calibration round(s)"
                     + (f", smallest {smallest:,} bytes)" if smallest else ")"))
        return None
    if errors is not None:
        allocated = best.predicted_bytes - r.fixed - r.group_meta
        if allocated > 0:
            errors[path] = min(MAX_CARRIED_ERROR, max(-MAX_CARRIED_ERROR,
                                                      (best.predicted_bytes - best.size) / allocated))
    return Calibrated(best, history, saturated, sh_plan, r.fixed)
