"""The size search's driver: one :class:`BudgetSearch` per call of ``encode_to_budget``.

Order of work: importance once; the SH codebooks (worker thread) beside the largest tau's stage,
the train-view references and the channel weights; up to ``max_candidates`` taus spread over the
feasible range; the depth walk from the best; tau refined at the walk's depth; layer 0 re-split
for layered files; the best candidate on train views wins.
"""
from __future__ import annotations

import contextlib
import dataclasses
import math
import time
from collections import OrderedDict

import numpy as np

from ...decoder.pages import small_pages
from ..executor import in_order
from ..pipeline import (EncodeOptionsError, EncodeResult, Stage, attribute_chunks, compute_train_importance,
                        prepare_stage, raht_classes_for, sh_chunk, sh_set_blocks, voxelize_stage, write_file)
from ..progress import Progress
from ...decoder.sh import SH_COLOUR_DC, ShColour
from ..sh_colour import choose_sh_colour, coded_cloud
from .candidate import TAU_PREFERENCE_DB, Candidate, best_of
from .codebooks import Codebooks
from .depth_walk import depth_range, first_depth, rewalk_depth, start_depth, walk_depth
from .judge import EVAL_DROP_MARGIN_DB, Judge
from .layers import finalists, resplit_layer0
from .options import SH_BITS, BudgetError, SearchOptions
from .report import search_report
from .sh_model import Assigner, ShModel, ShStageStats
from .tables import search_meta, size_bounds
from .tau import encode_tau


def encode_to_budget(cloud, target_bytes: int, *, options: SearchOptions | None = None,
                     importance: np.ndarray | None = None, cameras=None,
                     progress: Progress | None = None, source: str | None = None,
                     reuse_input: bool = False) -> EncodeResult:
    """Encode ``cloud`` into at most ``target_bytes`` bytes with the best train-view fidelity.

    Returns EncodeResult(data, cloud, report); the EncodeReport has target, actual bytes, the chosen
    reserve/codebook/keep, the bit-width of every group, predicted vs actual size per calibration
    round, candidates with their train PSNR, and seconds per stage.  Raises BudgetError with the
    smallest reachable size when the budget cannot be met.  Absurd input values are bounded and
    far-away Gaussians dropped first, as :func:`gsz.encoder.pipeline.encode` does (``source``
    names the scene in the warnings).  ``reuse_input``: the caller is done with ``cloud`` (the
    CLI, which read it): its arrays may be overwritten instead of copied (the colour
    transform, :func:`gsz.encoder.sh_colour.coded_cloud`).
    """
    from concurrent.futures import ThreadPoolExecutor

    from ..sanitize import fixes_report, sanitize_cloud
    cloud.validate()
    if importance is not None:
        importance = np.asarray(importance, np.float64)
        if importance.shape != (len(cloud),):
            raise EncodeOptionsError(f"importance must be {len(cloud)} finite values")
    cloud, fixes, kept = sanitize_cloud(cloud, source)
    if importance is not None and kept is not None:
        importance = importance[kept]
    from .bound import check_reachable
    check_reachable(cloud, target_bytes, options)      # before the importance pass: fails fast
    sopts = options or SearchOptions()

    # every candidate's octree is coded on this thread while the caller computes the candidate's
    # SH statistics and rate tables (flowers: ~1.4 s of each ~10 s candidate)
    from ..executor import make_executor
    executor = make_executor(sopts.executor, sopts.workers)
    try:
        with _search_threads(), small_pages(), \
                ThreadPoolExecutor(max_workers=1, thread_name_prefix="gsz-geom") as pool:
            search = BudgetSearch(cloud, target_bytes, sopts, progress, pool, executor,
                                  reuse_input=reuse_input)
            result = search.run(importance, cameras)
    finally:
        executor.close()
    if fixes:                  # only then: the reports of clean scenes stay as they were
        result.report.input_fixes = fixes_report(fixes)
    return result


@contextlib.contextmanager
def _search_threads():
    """torch's own maths single-threaded for the search, the renderer on every core.

    The search's torch work is many small ops, whose OpenMP threads stall at every barrier when
    another job holds a core (docs/design/torch-threads.md).  The renderer hands out tiles
    dynamically, so it keeps the cores torch had.  Results do not depend on either thread
    count."""
    import torch

    from ...evaluation.render import render_threads
    old = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        with render_threads(old):
            yield
    finally:
        torch.set_num_threads(old)


#: How much better (train PSNR) another SH path must render for the search to stop weighing
#: one (a tie says nothing: at a too-shallow depth every path renders the same).
PATH_LOST_MARGIN_DB = 0.1
#: Rounds of (refine tau, walk the depth again where tau moved) after the first walk.
REWALK_ROUNDS = 3

#: The SH paths as the search's log names them (tau.encode_tau).
SH_PATH_NAMES = {"vq": "codebook", "classes": "classes", "scalar": "scalar", "refine": "refined codebook"}

#: Prepared stages and voxel grids the search keeps: the stage being encoded, and the grid
#: screened last (the stage made next needs it).  A stage keeps what it needs of its grid, so
#: the grid goes once its stage is made, and a new grid means the stage before is done.  Both
#: are recomputed, identically, if asked for again (at 6 M Gaussians a grid is 1.7 GB).
STAGES_KEPT = 1
VOXELIZED_KEPT = 1


class _Lru:
    """The ``capacity`` most recently used values by key."""

    def __init__(self, capacity: int):
        self.capacity, self._items = capacity, OrderedDict()

    def get_or_make(self, key, make):
        """The value of ``key``, made by ``make()`` when missing -- after the least recently
        used values beyond ``capacity - 1`` went, so that they are not held while it is made."""
        if key in self._items:
            self._items.move_to_end(key)
            return self._items[key]
        while len(self._items) >= self.capacity:
            self._items.popitem(last=False)
        self._items[key] = value = make()
        return value

    def pop(self, key) -> None:
        self._items.pop(key, None)

    def clear(self) -> None:
        self._items.clear()


class BudgetSearch:
    """The state of one search: its stages (cached per tau, depth and layer split), codebooks,
    judge and candidates, and the records the report shows."""

    def __init__(self, cloud, target_bytes: int, sopts: SearchOptions, progress: Progress | None,
                 geometry_pool, executor=None, reuse_input: bool = False, sh_colour: int | None = None):
        def bad(msg):
            raise EncodeOptionsError(msg)
        sopts.check_scene_options(bad)
        if not sopts.codebook_bits or not all(1 <= int(b) <= 16 for b in sopts.codebook_bits):
            bad(f"codebook_bits must be widths in 1..16, got {sopts.codebook_bits!r}")
        self.target = int(target_bytes)
        if self.target <= 0:
            raise BudgetError(self.target, 1)
        cloud.validate()
        # the search codes, quantises and allocates in the SH colour space the file will hold
        # (squared errors are RGB's: the rotation is orthonormal); the judge renders in RGB and
        # the result's cloud is the decoder's.  ``reuse_input``: ``cloud`` may be overwritten.
        # ``sh_colour``: the SHXF bits ``cloud`` is coded in already (the search without SH rest
        # another search starts), else None: chosen and applied here
        if sh_colour is None:
            with (progress or Progress(quiet=True)).stage("sh-colour", "colour space of the SH rest and DC"):
                self.sh_colour = choose_sh_colour(cloud, sopts.sh_colour, self.target, sopts.tile_gaussians)
                cloud = coded_cloud(cloud, self.sh_colour, in_place=reuse_input)
        else:
            self.sh_colour = sh_colour
        self.sopts, self.cloud, self.geometry_pool = sopts, cloud, geometry_pool
        self.executor = executor
        self.progress = progress or Progress(quiet=True)
        self.taus = sorted(set(float(t) for t in sopts.reserves), reverse=True)
        self.importance = self.depth = self.anchor = self.judge = None
        self.codebooks: list = []
        self.assigner = Assigner(cloud) if cloud.sh_degree > 0 else None
        # Stages and voxel grids are recomputed when needed again (deterministic, so the file does
        # not change): keeping every candidate's grew memory by ~1 GB per candidate at 1.2 M.
        self._stages = _Lru(STAGES_KEPT)
        self._voxelized = _Lru(VOXELIZED_KEPT)
        self._merged: dict = {}           # (tau, depth) -> fraction of Gaussians sharing a voxel
        self.candidates: list[Candidate] = []
        self.evaluated: set = set()       # (tau, depth) tried
        self.log: list = []               # every tau's calibration
        self.screened: list = []          # exact-attribute bounds rendered or inferred
        self.dropped: list = []           # candidates dropped after their hardest views
        self.lost_paths: set = set()      # SH paths not weighed again (_note_lost_paths)
        self.narrow_losses: dict = {}     # SH path -> stages it lost by < PATH_LOST_MARGIN_DB
        self.far_behind: set = set()      # SH paths that rendered EVAL_DROP_MARGIN_DB+ below a stage's best
        self.near_ties: set = set()       # depths the walk found within DEPTH_STEP_MIN_GAIN_DB of its best
        self.estimate_errors: dict = {}   # SH path -> the rate estimate's last error (calibrate)
        self.t0 = self.c0 = None

    # --- stages -------------------------------------------------------------------------------
    def vox_for(self, tau, d=None):
        """(kept, voxelized) of ``tau`` at depth ``d`` (default: the position-error depth)."""
        key = (tau, self.depth if d is None else d)

        def make():
            self._stages.clear()          # a new grid is for a new stage: the one before is done
            vox = voxelize_stage(self.cloud, self.importance, tau, depth=key[1], progress=self.progress)
            self._merged[key] = vox[1].merged_fraction
            return vox
        return self._voxelized.get_or_make(key, make)

    def merged_fraction(self, tau, d) -> float:
        """Fraction of the Gaussians kept at ``tau`` that share a voxel at depth ``d``."""
        if (tau, d) not in self._merged:
            self.vox_for(tau, d)
        return self._merged[(tau, d)]

    def stage_for(self, tau, d=None, fl=None) -> Stage:
        """The prepared stage (geometry coded) of ``tau`` at depth ``d`` with layer-0 share ``fl``."""
        d = self.depth if d is None else d
        fl = self.sopts.first_layer if fl is None else fl

        def make():
            vox = self.vox_for(tau, d)
            stage = prepare_stage(self.cloud, self.importance, tau, depth=d, layers=self.sopts.layers,
                                  first_layer=fl, progress=self.progress, voxelized=vox,
                                  pool=self.geometry_pool, tile_gaussians=self.sopts.tile_gaussians,
                                  executor=self.executor,
                                  raht_classes=raht_classes_for(self.sopts.raht_classes, self.target,
                                                                len(vox[1].ijk)),
                                  sh_colour=self.sh_colour)
            self._voxelized.pop((tau, d))     # the stage keeps what it needs of the grid
            return stage
        return self._stages.get_or_make((tau, d, fl), make)

    def forget_stages(self) -> None:
        """Drop the kept stage and grid (when the search moves on to work that needs neither)."""
        self._stages.clear()
        self._voxelized.clear()

    # --- the run ------------------------------------------------------------------------------
    def run(self, importance=None, cameras=None) -> EncodeResult:
        self.t0, self.c0 = time.perf_counter(), time.process_time()
        if importance is None:
            importance = compute_train_importance(self.cloud, self.sopts, cameras=cameras,
                                                  progress=self.progress)
        self.importance = importance
        # the walk's range is anchored at the position-error start, its first stage may lie deeper
        self.anchor = start_depth(self.cloud.positions, self.target)
        self.depth = first_depth(self.anchor, self.target, len(self.cloud), self.sopts)
        lo1, hi1 = self._set_up(cameras)
        for tau in self._feasible(lo1, hi1):
            self.try_tau(tau)
        walk_depth(self)
        # tau and depth interact (fewer Gaussians, more bytes for each: deeper pays): each
        # coordinate again while the other moved
        for _ in range(REWALK_ROUNDS):
            walked_at = self.best().reserve if self.candidates else None
            self.refine_tau()
            if not rewalk_depth(self, walked_at):
                break
        resplit_layer0(self)
        self.try_without_sh()
        return self._result()

    def _set_up(self, cameras) -> tuple[float, float]:
        """Codebooks (worker thread) beside the largest tau's stage and its size bounds, the
        judge's references and the channel weights.  Returns the size bounds."""
        codebooks = None
        if self.cloud.sh_degree > 0:
            # they keep the grid's SH rows only: the rest of the grid goes with the stage made next
            codebooks = Codebooks(self.sopts, *self.vox_for(self.taus[0]), self.assigner, self.progress)
        with codebooks or contextlib.nullcontext():
            top = self.stage_for(self.taus[0])
            with self.progress.stage("tables", f"tau {self.taus[0]}: size bounds"):
                bounds = size_bounds(top, self.sopts.blocks)
            self.judge = Judge(self.cloud, self.sopts, self.progress, cameras, sh_colour=self.sh_colour)
            if codebooks is not None:
                self.codebooks = codebooks.result()
        return bounds

    def _feasible(self, lo1: float, hi1: float) -> list:
        """The taus whose size range (scaled from the largest tau's) can contain the target,
        at most ``max_candidates`` spread over them."""
        taus, n, target = self.taus, len(self.cloud), self.target
        feasible = []
        for tau in taus:
            f = (math.ceil(tau * n) / n) / (math.ceil(taus[0] * n) / n)
            lo, hi = lo1 * f, hi1 * f
            if lo <= target and (hi >= target or not feasible):
                feasible.append(tau)
        if not feasible:
            # even the smallest tau at 1 bit is estimated above the target: check exactly
            feasible = [taus[-1]]
        if len(feasible) > self.sopts.max_candidates:
            pos = np.linspace(0, len(feasible) - 1, self.sopts.max_candidates).round().astype(int)
            feasible = [feasible[i] for i in sorted(set(pos))]
        self.progress.log(f"target {target:,} bytes; candidate reserve ratios {feasible}")
        return feasible

    def best(self) -> Candidate:
        return best_of(self.candidates)

    def cannot_win(self, tau, d) -> bool:
        """True when even exact attributes at (tau, depth d) cannot outrank the best candidate
        so far (train views, Candidate.score): then no allocation there can win and its encode is
        skipped.  Checked only below the best tau or shallower than the best depth (fewer
        Gaussians / coarser positions: the bound falls, and above the best it would almost
        never prune); monotone in tau at one depth, so a tau below one that failed at the same
        depth fails without a render."""
        if not self.sopts.screen or not self.candidates:
            return False
        best = self.best()
        if tau >= best.reserve and d >= best.depth:
            return False
        inferred, partial = False, 0
        for s in self.screened:
            if s["skipped"] and s["reserve"] >= tau and s["depth"] == d:
                bound, inferred = s["bound_psnr"], True     # an upper bound of tau's own
                break
        else:
            with self.progress.stage("screen", f"tau {tau}, depth {d}: exact-attribute bound"):
                # the grid's SH rest gathered for these renders only (1 GB at 6 M voxels)
                bound, partial = self.judge.screen(self.vox_for(tau, d)[1].full_cloud(), best.view_psnr)
        # what (tau, d) must render to outrank the best (Candidate.score)
        need = best.score - TAU_PREFERENCE_DB * tau
        skip = bound <= need and not partial         # a partial mean only ever lets through
        self.screened.append({"reserve": tau, "depth": d, "bound_psnr": bound, "inferred": inferred,
                              "views": 0 if inferred else (partial or len(self.judge.cameras)),
                              "best_psnr": best.train_psnr, "needed_psnr": need, "skipped": skip})
        if skip:
            what = "a larger tau's exact attributes reach" if inferred else "exact attributes reach"
            self.progress.log(f"tau {tau}, depth {d}: {what} only {bound:.2f} dB <= {need:.2f} dB, what it "
                              f"needs to outrank tau {best.reserve}, depth {best.depth} "
                              f"({best.train_psnr:.2f} dB): skipped")
        return skip

    def sh_models(self, stage: Stage) -> list:
        """One SH model per codebook of the stage (none without SH)."""
        if not self.codebooks:
            return []
        with self.progress.stage("sh-model", f"tau {stage.reserve}: kept-vector statistics"):
            base = ShStageStats(stage, self.sopts.blocks)
        sizes = ", ".join(str(len(cb)) for cb in self.codebooks)
        with self.progress.stage("sh-model", f"tau {stage.reserve}, codebooks {sizes}"):
            # the assignments one after the other (the assigner's cache is shared), then the
            # models by the parts' rule (in_order): side by side on threads where a stage's
            # parts are, else one at a time (their [M] arrays at once would raise a 6 M peak);
            # each reads only the stage and its own codebook and index
            index = [self.assigner(stage, cb) for cb in self.codebooks]
            return list(in_order(None, lambda i: ShModel(stage, self.codebooks[i], self.sopts.blocks, base, index[i]),
                                 range(len(self.codebooks)), gaussians=stage.num_points))

    def try_tau(self, tau, d=None, fl=None, min_keep: int = 0) -> None:
        """Encode (tau, depth d, layer split fl), score it on the train views and add it to the
        candidates (unless screening skips it or its hardest views drop it)."""
        sopts, progress = self.sopts, self.progress
        d = self.depth if d is None else d
        fl = sopts.first_layer if fl is None else fl
        self.evaluated.add((tau, d))
        regular = fl == sopts.first_layer and not min_keep
        if regular and self.cannot_win(tau, d):
            return
        stage = self.stage_for(tau, d, fl)
        # what a stage teaches the search (the rate estimate's errors, which SH path renders
        # better) is kept only where it beats every candidate so far: screening skips only
        # stages that cannot, so skipping them never changes the file
        errors = dict(self.estimate_errors)
        before = self.best() if self.candidates else None
        encs = encode_tau(stage, self.target,
                          dataclasses.replace(sopts, sh_scalar=sopts.sh_scalar and "scalar" not in self.lost_paths,
                                              sh_classes=sopts.sh_classes and "classes" not in self.lost_paths,
                                              sh_refine=sopts.sh_refine and "refine" not in self.lost_paths),
                          self.sh_models(stage), progress, self.log, self.judge.weights, min_keep=min_keep,
                          codebook="vq" not in self.lost_paths, errors=errors,
                          codebook_far_behind="vq" in self.far_behind,
                          widths_lead=before is not None and before.encoded.sh_path in ("scalar", "classes"))
        # re-split / kept-layer-0 variants may be chosen despite a lower PSNR: render them fully
        rival = self.best().view_psnr if self.candidates and regular else None
        scored, paths = [], []
        for enc in encs:
            paths.append(enc.sh_path)
            what = f"tau {tau}, depth {d}" + (f", {enc.sh_path} SH" if enc.sh_path in ("scalar", "classes", "refine")
                                              else "")
            with progress.stage("eval", what):
                p, views, partial = self.judge.score(enc.cloud, rival)
            enc.release()
            if partial:
                enc.drop_data()
                progress.log(f"{what}: {enc.size:,} bytes, {partial} hardest train views "
                             f"{EVAL_DROP_MARGIN_DB:g}+ dB below the best candidate's: dropped")
                self.dropped.append({"reserve": tau, "depth": d, "bytes": enc.size, "views": partial,
                                     "partial_psnr": p})
                continue
            progress.log(f"{what}: {enc.size:,} bytes, train PSNR {p:.2f} dB")
            scored.append(Candidate(p, tau, d, fl, views, enc))
            # only the stage's best path becomes a candidate, and best_of keeps the first of
            # equals, so a path beaten here is never that best: its bytes go before the next
            # path's render (~120 MB a file at 6 M Gaussians)
            top = best_of(scored)
            for c in scored:
                if c is not top:
                    c.encoded.drop_data()
        if not paths:
            progress.log(f"tau {tau}: budget not reachable")
            return
        if scored:
            # one candidate per (tau, depth, split): the better SH path as rendered
            self.add_candidate(best_of(scored))
        if self.candidates and self.best() is not before:
            self.estimate_errors = errors
            self._note_lost_paths(paths, scored)

    def add_candidate(self, cand: Candidate) -> None:
        """Add ``cand``; of a single-layer search only the best candidate's file can be chosen
        (layers.finalists), so the others drop their bytes (~120 MB each at 6 M Gaussians).
        Layered files are chosen by when layer 0 arrives too: there every candidate keeps them."""
        self.candidates.append(cand)
        if self.sopts.layers == 1:
            best = self.best()
            for c in self.candidates:
                if c is not best:
                    c.encoded.drop_data()

    def _note_lost_paths(self, paths: list, scored: list) -> None:
        """An SH path that rendered PATH_LOST_MARGIN_DB or more below the best of a stage (or
        was dropped after its hardest views), or narrowly below it twice, is not weighed again
        in this search: what decides it -- palette-like or continuous SH, the rate -- is the
        same at every stage.  The codebook path is then encoded only where no other path fits
        or (until it renders EVAL_DROP_MARGIN_DB below a stage's best: ``far_behind``) where
        fewer than half the vectors are kept exact."""
        if not scored:
            return
        best = best_of(scored)
        psnr = {c.encoded.sh_path: c.train_psnr for c in scored}
        for path in dict.fromkeys(paths):
            if path not in SH_PATH_NAMES or path == best.encoded.sh_path:
                continue
            far = path not in psnr or best.train_psnr >= psnr[path] + EVAL_DROP_MARGIN_DB
            if far and path not in self.far_behind:
                # dropped after its hardest views, or as far behind on all of them
                self.far_behind.add(path)
                if path == "vq" and path in self.lost_paths:
                    self.progress.log(f"the codebook SH path renders {EVAL_DROP_MARGIN_DB:g}+ dB below the "
                                      f"{SH_PATH_NAMES[best.encoded.sh_path]} path: encoded again only "
                                      f"where no other path fits")
            if path in self.lost_paths:
                continue
            narrow = path in psnr and best.train_psnr < psnr[path] + PATH_LOST_MARGIN_DB
            if narrow:
                # one narrow loss says little (at a too-shallow depth every path renders the
                # same); a second one says the path is never clearly better
                self.narrow_losses[path] = self.narrow_losses.get(path, 0) + 1
                if self.narrow_losses[path] < 2:
                    continue
            self.lost_paths.add(path)
            how = "narrowly, a second time," if narrow else f"{PATH_LOST_MARGIN_DB:g}+ dB"
            then = ("not weighed again in this search" if path != "vq" else
                    "encoded again only where no other path fits" if path in self.far_behind else
                    "encoded again only where fewer than half the vectors are kept exact or no "
                    "other path fits")
            self.progress.log(f"the {SH_PATH_NAMES[path]} SH path renders {how} below the "
                              f"{SH_PATH_NAMES[best.encoded.sh_path]} path: {then}")

    def refine_tau(self) -> None:
        """The grid neighbours of the best candidate's tau (at its depth), while they improve;
        where tau moved, also the depths the walk found (nearly) as good as its best at the
        tau before -- which of two such depths wins can change with tau (houseplant noised 18x:
        depths 10 and 11 both 35.89 dB train at tau 0.6; tau 0.7 at depth 11 36.58 dB)."""
        taus = self.taus
        start = self.best().reserve if self.candidates else None
        for _ in range(self.sopts.refine_steps):
            if not self.candidates:
                return
            best = self.best()
            i, d = taus.index(best.reserve), best.depth
            nbrs = [taus[j] for j in (i - 1, i + 1)
                    if 0 <= j < len(taus) and (taus[j], d) not in self.evaluated]
            tried = len(self.evaluated)
            for tau in nbrs:
                self.try_tau(tau, d)
            # where neither neighbour won, each once more a level away from the best depth:
            # the smaller tau a level deeper (more bytes for each Gaussian, which a deeper octree
            # can buy: showroom noised 18x, tau 0.4 lost at depth 12 after its hardest views and
            # renders 1 dB better than tau 0.5 at 15), the larger tau a level shallower (more
            # Gaussians, each with fewer bytes, which a coarser octree pays for: houseplant 27x,
            # tau 0.5 best at depth 10, tau 0.6 0.25 dB below it at depth 10, above it at 9)
            lo_d, hi_d = depth_range(self)
            for j, dj, way in ((i + 1, d + 1, "deeper"), (i - 1, d - 1, "shallower")):
                if (self.best() is best and 0 <= j < len(taus) and lo_d <= dj <= hi_d
                        and (taus[j], dj) not in self.evaluated):
                    self.progress.log(f"tau {taus[j]} a level {way}, at depth {dj}")
                    self.try_tau(taus[j], dj)
            # both neighbours may have lost at this depth in an earlier round (before the depth
            # was walked again), and the level-away moves are still to try (plaza noised 40x:
            # tau 0.3 best at depth 11 after the rewalk, tau 0.4 lost at 11, wins at 10 and 9)
            if len(self.evaluated) == tried:
                break
        if not self.candidates:
            return
        best = self.best()
        if best.reserve != start:
            for d in sorted(self.near_ties):
                if (best.reserve, d) not in self.evaluated:
                    self.progress.log(f"depth {d} at tau {best.reserve} (as good as the best depth "
                                      f"at tau {start})")
                    self.try_tau(best.reserve, d)

    def try_without_sh(self) -> None:
        """Where the best candidate keeps no SH vector exact, the same budget without the SH
        rest (degree 0: their bytes go to the attributes and more Gaussians) may render better
        on the train views (jug sample noised at 40 kB: +1.6 dB test PSNR; at 70 kB -0.8 dB).
        Tried at the best candidate's depth, its tau and the next larger one; judged as every
        candidate."""
        if not self.sopts.sh_drop or self.cloud.sh_degree == 0 or not self.candidates:
            return
        best = self.best()
        if best.encoded.sh_keep:
            return                       # exact vectors kept: the SH are worth their bytes
        self.progress.log(f"no SH vector kept exact: trying the file without SH rest at tau {best.reserve}")
        self.forget_stages()             # the search without SH makes its own
        flat = BudgetSearch(self.cloud.with_sh_degree(0), self.target, self.sopts, self.progress,
                            self.geometry_pool, self.executor, sh_colour=ShColour(self.sh_colour & SH_COLOUR_DC))
        flat.importance, flat.depth, flat.judge = self.importance, best.depth, self.judge
        flat.anchor = self.anchor
        i = self.taus.index(best.reserve)
        # both taus: without the SH rest's bytes a larger tau may win where the same one does
        # not (the jug sample at 40 kB: tau 0.4 no better than with SH, 0.5 +2.9 dB on the train
        # views)
        for tau in [best.reserve] + self.taus[max(0, i - 1):i]:
            flat.try_tau(tau, best.depth, best.first_layer)
        self.dropped.extend(flat.dropped)
        if flat.candidates and flat.best().rank > best.rank:
            f = flat.best()
            self.progress.log(f"without SH rest: train PSNR {f.train_psnr:.2f} dB at tau {f.reserve} outranks "
                              f"{best.train_psnr:.2f} dB at tau {best.reserve} with them")
            self.add_candidate(f)

    def _result(self) -> EncodeResult:
        if not self.candidates:
            raise BudgetError(self.target, self._smallest_file())
        chosen = finalists(self.candidates, self.sopts)
        chosen.sort(key=lambda c: c.rank, reverse=True)
        report = search_report(self, chosen[0])
        if report.search.note is not None:
            self.progress.log(report.search.note)
        # the decoder is the truth of what the file holds (candidates released their scenes):
        # the result decodes the bytes when its cloud is asked for, after the search has gone
        return EncodeResult(data=chosen[0].data, report=report)

    def _smallest_file(self) -> int:
        """Exact size of the smallest file the search can make (the smallest tau, 1 bit
        everywhere, the smallest codebook, no kept SH)."""
        stage = self.stage_for(self.taus[-1])
        codebook = self.codebooks[-1] if self.codebooks else None
        sh = None
        if codebook is not None:
            sh, _, _ = sh_chunk(stage, codebook, 0, SH_BITS, self.sopts.blocks,
                                cb_blocks=sh_set_blocks(len(codebook), self.sopts.blocks))
        attr, _, _ = attribute_chunks(stage, 1, self.sopts.blocks, decode=False)
        data, _ = write_file(stage, stage.positions(), attr, sh, search_meta(stage, 0, {"sh_keep": 0}))
        return len(data)
