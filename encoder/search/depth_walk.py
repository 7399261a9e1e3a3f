"""The octree depth walk: after the tau search at the position-error default depth, walk the depth
from the best candidate one level at a time while train PSNR improves.

The default is right only in the middle of the RD range.  Each level costs about 3 bits per voxel
and halves the position error: at high budgets a deeper grid is worth far more than those bits,
at low budgets the bits are better spent on attributes (docs/design/depth-walk.md).  The walk
goes first in the direction the best allocation suggests; tau is refined
afterwards, at the depth the walk ends on (refining before the walk as well cost one encode
whenever the walk moved, and the grid neighbour's verdict at the old depth is not the one needed).
"""
from __future__ import annotations

import math

from .candidate import Candidate

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
#: ... or while the last level deeper gained at least this much train PSNR: position error still
#: dominates there, and the next level halves it again (houseplant at SOG's bytes: depths 11-14
#: gained 4.4, 3.2, 2.0 dB and the walk stopped at its range's end; the 1.2 M bench at 12×:
#: 3.8, 3.3, 2.7 dB at depths 12-15)
STRONG_GAIN_EXTRA_DEPTH_DB = 1.0
#: While the last level gained at least this much train PSNR the walk steps two levels at a
#: time (a gain that large says the next level will gain too: the 1.2 M bench at 12x gained
#: 3.8, 3.3, 2.7, 1.8 dB at depths 13-16); a double step that does not pay, or gains less
#: than STRONG_GAIN_EXTRA_DEPTH_DB a level, tries the level it stepped over.
STRIDE_GAIN_DB = 2.0
#: A first depth step that improves train PSNR by less than this does not commit the walk to
#: its direction: the other direction is tried as well (houseplant noised 40x: depth 11 -> 12
#: gained 0.02 dB, and depth 9 was the better side).
DEPTH_STEP_MIN_GAIN_DB = 0.05
MAX_DEPTH = 21
#: About what one octree level costs, in bits per voxel (docs/design/depth-walk.md).
LEVEL_BITS_PER_VOXEL = 3.0
#: The first stage's depth below the walk's anchor: RATE_START_LEVELS_PER_DOUBLING levels per
#: doubling of the budget's bits per Gaussian over RATE_START_BITS (docs/design/rate-start.md:
#: on the shared scenes' 84 RD points the walk ended 1.5-3 levels deeper per doubling; this is
#: the lower edge, so the walk still has a level to go and both directions stay open).
RATE_START_BITS = 48.0
RATE_START_LEVELS_PER_DOUBLING = 1.5


def start_depth(positions, target_bytes: int) -> int:
    """The depth the search starts at: the position-error default, deepened while one more level
    separates a larger share of the Gaussians (merged into one voxel before) than its bits would
    buy at the file's bytes per Gaussian.  A scene whose extent dwarfs its detail (objects side
    by side, a city capture) merges a tenth of its Gaussians at the default, and the walk from
    there cost one candidate per level."""
    from ..voxelize import DEFAULT_REL_ERROR, bounding_cube, choose_depth, merge_fraction
    d = choose_depth(positions, rel_error=DEFAULT_REL_ERROR)
    pays = LEVEL_BITS_PER_VOXEL / 8 / (max(1, target_bytes) / len(positions))
    cube = bounding_cube(positions)
    merged = merge_fraction(positions, d, cube)
    while d < MAX_DEPTH and merged > pays:
        deeper = merge_fraction(positions, d + 1, cube)
        if merged - deeper < pays:
            break
        d, merged = d + 1, deeper
    return d


def first_depth(anchor: int, target_bytes: int, gaussians: int, sopts) -> int:
    """The depth of the search's first stage: ``anchor`` (:func:`start_depth`), deeper at high
    rates, where the walk would otherwise spend its first stages (each a full encode per SH path)
    on levels whose position error every candidate there shares (the 1.2 M bench at 12x walked
    12, 13, 15, 17, 18).  Within the walk's range (:func:`depth_range`)."""
    bits = 8.0 * max(1, target_bytes) / max(1, gaussians)
    extra = math.floor(RATE_START_LEVELS_PER_DOUBLING * math.log2(max(1.0, bits / RATE_START_BITS)))
    return min(MAX_DEPTH, anchor + max(0, min(extra, sopts.depth_steps, sopts.max_extra_depth)))


def depth_range(search) -> tuple[int, int]:
    """(lo, hi): the depths the walk visits without a reason to go further: ``depth_steps``
    shallower than its anchor (the position-error start depth), at most ``max_extra_depth``
    deeper than its first stage (:func:`first_depth`; measured from the anchor, a first stage
    at the range's end could not take its first step deeper without a gain to show: the jug
    noised at SOG's bytes stopped at depth 14, 7 dB below depth 19)."""
    sopts = search.sopts
    return (max(1, search.anchor - sopts.depth_steps),
            min(MAX_DEPTH, search.depth + min(sopts.depth_steps, sopts.max_extra_depth)))


def walk_depth(search) -> None:
    """Walk the depth of ``search`` (a BudgetSearch) from its best candidate, in the direction its
    allocation suggests first; the other direction only when the first did not move."""
    if not search.candidates or search.sopts.depth_steps <= 0:
        return
    best = search.best()
    lo_d, hi_d = depth_range(search)
    deeper_first = (best.encoded.attributes_saturated
                    or best.encoded.mean_attribute_bits() >= DEPTH_DEEPER_FIRST_BITS)
    for step in ((1, -1) if deeper_first else (-1, 1)):
        if _walk(search, best, step, lo_d, hi_d):
            break


def rewalk_depth(search, tau_before) -> bool:
    """Walk the depth again from the best candidate when the tau refinement moved tau away from
    ``tau_before`` (the tau the walk ran at): one direction only, deeper where tau now prunes
    more (fewer Gaussians, more bytes for each), shallower where it prunes less.  True when the
    depth moved.  The walk's verdict holds for the tau it ran at only (showroom crop at 18x:
    depths 11 and 13 lost at tau 0.6, the refinement then moved to 0.5, where deeper levels
    pay; the search stopped at depth 12)."""
    sopts = search.sopts
    if not search.candidates or sopts.depth_steps <= 0 or tau_before is None:
        return False
    best = search.best()
    if best.reserve == tau_before:
        return False
    lo_d, hi_d = depth_range(search)
    step = 1 if best.reserve < tau_before else -1
    search.progress.log(f"tau moved {tau_before} -> {best.reserve}: depth walked again "
                        f"({'deeper' if step > 0 else 'shallower'}) from depth {best.depth}")
    return _walk(search, best, step, lo_d, hi_d, again=True)


def _shares_voxels(search, tau, d) -> bool:
    return search.merged_fraction(tau, d) >= MERGED_FRACTION_EXTRA_DEPTH


def _room(search, step: int, d_next: int, lo_d: int, hi_d: int, gain: float | None = None) -> bool:
    """Whether the walk may visit depth ``d_next``; ``gain``: what its last level gained.

    Past the usual range a level pays in two cases: with every attribute group at its best width
    and bytes left over (saturated; spent on the SH where there are any) each further level costs
    only bytes that would buy little else; and where Gaussians still share voxels, each level
    separates more of them -- merging loses far more than the position error a level halves
    (tiny_graphdeco, whose positions sit on a delivery grid, at 8x: 6.7 % merged at depth 14,
    4.1 % at 19; test PSNR 49.8 -> 61.6 dB at the same bytes).  Where (almost) nothing merges
    (flowers: 0.02 % at depth 13) a level only halves an already small position error."""
    cap = hi_d
    cb = search.best()
    strong = gain is not None and gain >= STRONG_GAIN_EXTRA_DEPTH_DB
    if step > 0 and (strong or cb.encoded.attributes_saturated or _shares_voxels(search, cb.reserve, cb.depth)):
        cap = min(MAX_DEPTH, search.anchor + SATURATED_EXTRA_DEPTH)
    return lo_d <= d_next <= cap


def _walk(search, best: Candidate, step: int, lo_d: int, hi_d: int, again: bool = False) -> bool:
    """One direction of the walk from ``best``; True when it moved (found a better depth).
    ``again`` (:func:`rewalk_depth`, where the direction is not in question): a first step
    gaining less than DEPTH_STEP_MIN_GAIN_DB still commits the walk, and a level within that of
    the best is looked past (the curve is flat there: showroom noised 18x at tau 0.5, depths
    12-13 49.45, 49.44 dB train, tau 0.4 at depth 15 1 dB better)."""
    moved = looked_past = False
    d, gain, stride = best.depth, None, 1
    while True:
        nxt = d + stride * step
        if not _room(search, step, nxt, lo_d, hi_d, gain) or (best.reserve, nxt) in search.evaluated:
            if stride > 1:
                stride = 1          # no room for a double step: one level
                continue
            break
        before = search.best()
        search.progress.log(f"depth {nxt} at tau {before.reserve} (best so far: depth "
                            f"{before.depth}, {before.train_psnr:.2f} dB train PSNR)")
        search.try_tau(before.reserve, nxt)
        if search.best() is before:
            made = search.candidates[-1] if search.candidates else None
            near = (made is not None and made is not before and made.depth == nxt
                    and before.train_psnr - made.train_psnr < DEPTH_STEP_MIN_GAIN_DB)
            if near:
                search.near_ties.add(nxt)       # tried again where tau moves (refine_tau)
            if stride > 1:
                stride = 1          # the double step did not pay: the level it stepped over may
                continue
            # Where Gaussians still share voxels the gain per level is uneven (each level
            # separates a different share of them: tiny_graphdeco's exact-attribute PSNR over
            # depths 13-16 is 48.1, 48.3, 50.5, 51.7 dB), so a level that does not pay is looked
            # past (not two in a row).
            if (step > 0 and not looked_past and _room(search, step, d + 2 * step, lo_d, hi_d)
                    and (best.reserve, d + 2 * step) not in search.evaluated
                    and (_shares_voxels(search, before.reserve, d + step) or (again and near))):
                looked_past = True
                d += step
                continue
            break
        gain = (search.best().train_psnr - before.train_psnr) / stride       # per level
        if gain < DEPTH_STEP_MIN_GAIN_DB and not moved and not again:
            # a first step that gains only hundredths of a dB says little about this direction:
            # try the other one too (the new candidate stays in the pool)
            break
        if stride > 1 and gain < STRONG_GAIN_EXTRA_DEPTH_DB and (before.reserve, nxt - step) not in search.evaluated:
            # the gain fell inside the double step: the level it stepped over may be the peak
            # (houseplant at SOG's bytes, depths 14, 16: 63.22, 63.90 dB train; 15 won before)
            top = search.best()
            search.progress.log(f"depth {nxt - step} at tau {before.reserve} (the level between)")
            search.try_tau(before.reserve, nxt - step)
            if search.best() is not top:
                return True
        d = nxt
        moved, looked_past = True, False
        if d > hi_d and gain < SATURATED_MIN_GAIN_DB:
            break           # past the usual range, further levels no longer pay
        stride = 2 if gain >= STRIDE_GAIN_DB else 1
    return moved
