"""Bit allocation: pick one bit-width per quantisation group to minimise the total loss under a
size budget -- a multiple-choice knapsack (MCKP) with one capacity row.

    minimise   sum_g loss[g, j_g]     subject to   sum_g rate[g, j_g] <= budget

loss [G, Q] (float64; e.g. SSE from ``gsz.kernels.quantize.quantize_all_bits`` reshaped to
[C*B, 16]) and rate [G, Q] (bits; e.g. ``gsz.encoder.rate.rate_matrix``).  Option j means
bit-width j + 1.  +inf (or NaN) in loss or rate marks an option as unavailable, as does
``allowed[g, j] == False``.  Neither loss nor rate needs to be monotone in j.

Solvers
    allocate_fast  per-group lower convex hull + greedy over hull upgrades by slope (the LP
                   optimum rounded down), then an exact local search that spends the leftover
                   budget (single-group moves, pairs "upgrade one group, downgrade another", and
                   "downgrade one group, refill with the best fitting upgrades of others").
                   Fully vectorised numpy; ~10-30 ms for 800 groups x 16 widths.
    allocate_cbc   the paper's 0-1 ILP with PuLP/CBC (one-hot binaries per group, one knapsack
                   row), warm-started from allocate_fast; ``channels=C`` gives the paper's
                   hierarchical variant (a channel-level ILP over uniform widths, then one ILP
                   per channel over its blocks within the channel's share of the budget).
    allocate       dispatch on ``method``.
All return int64 [G] option indices (bits = index + 1) whose total rate never exceeds the budget;
an infeasible budget raises :class:`InfeasibleBudgetError` naming the minimum.
"""
from __future__ import annotations

import warnings

import numpy as np

from ..decoder.errors import GszError

__all__ = ["AllocationError", "InfeasibleBudgetError", "allocate", "allocate_fast", "allocate_cbc",
           "objective", "total_rate", "minimum_rate"]


class AllocationError(GszError, ValueError):
    """Bad inputs to a bit-allocation solver (shapes, a group with no usable option...)."""


class InfeasibleBudgetError(AllocationError):
    """Even the cheapest option of every group exceeds the budget."""

    def __init__(self, budget: float, minimum: float):
        self.budget = float(budget)
        self.minimum = float(minimum)
        super().__init__(f"size budget of {self.budget:.0f} bits ({self.budget / 8:.0f} bytes) is "
                         f"below the smallest achievable {self.minimum:.0f} bits "
                         f"({self.minimum / 8:.0f} bytes) for these groups")


# ---- helpers -----------------------------------------------------------------------------------
def _prepare(loss, rate, allowed):
    """float64 copies with unavailable options at +inf; validity mask [G, Q]."""
    loss = np.array(loss, dtype=np.float64, copy=True)
    rate = np.array(rate, dtype=np.float64, copy=True)
    if loss.ndim != 2 or loss.shape != rate.shape:
        raise AllocationError(f"loss and rate must both be [G, Q], got {loss.shape} and {rate.shape}")
    valid = np.isfinite(loss) & np.isfinite(rate)
    if allowed is not None:
        allowed = np.asarray(allowed, dtype=bool)
        if allowed.shape != loss.shape:
            raise AllocationError(f"allowed must be {loss.shape}, got {allowed.shape}")
        valid &= allowed
    if np.any(rate[valid] < 0):
        raise AllocationError("rates must be non-negative")
    bad = ~valid.any(axis=1)
    if bad.any():
        raise AllocationError(f"{int(bad.sum())} group(s) have no usable option (first: group "
                              f"{int(np.flatnonzero(bad)[0])})")
    loss[~valid] = np.inf
    rate[~valid] = np.inf
    return loss, rate, valid


def _cheapest(loss, rate):
    """Per group the minimum-rate option, lowest loss among equal rates: int64 [G]."""
    g = loss.shape[0]
    rmin = rate.min(axis=1, keepdims=True)
    cand = np.where(rate == rmin, loss, np.inf)
    pick = np.argmin(cand, axis=1)
    # all-inf loss at the min rate cannot happen for valid options; argmin returns the first
    return pick.astype(np.int64) if g else np.zeros(0, np.int64)


def objective(loss, pick) -> float:
    """Total loss of an allocation (pick int [G] option indices)."""
    loss = np.asarray(loss, dtype=np.float64)
    return float(loss[np.arange(loss.shape[0]), np.asarray(pick)].sum())


def total_rate(rate, pick) -> float:
    """Total rate (bits) of an allocation."""
    rate = np.asarray(rate, dtype=np.float64)
    return float(rate[np.arange(rate.shape[0]), np.asarray(pick)].sum())


def minimum_rate(rate, loss=None, allowed=None) -> float:
    """Smallest achievable total rate (every group at its cheapest usable option)."""
    rate = np.asarray(rate, dtype=np.float64)
    loss = np.zeros_like(rate) if loss is None else loss
    _, r, _ = _prepare(loss, rate, allowed)
    return float(r.min(axis=1).sum())


def _check_budget(rate, pick, budget):
    base = float(rate[np.arange(rate.shape[0]), pick].sum())
    if not base <= budget:
        raise InfeasibleBudgetError(budget, base)
    return base


# ---- convex hull greedy -------------------------------------------------------------------------
def _hull_segments(loss, rate, start):
    """Lower-convex-hull upgrade steps of every group, vectorised by gift wrapping.

    From each group's start point repeatedly move to the point with larger rate that has the most
    negative slope (ties: the nearer point, so collinear points stay separate steps).  At most
    Q - 1 steps.  Returns (group, step, from, to, drate, dloss) arrays of all steps.
    """
    g, q = loss.shape
    rows = np.arange(g)
    cur = start.copy()
    active = np.ones(g, bool)
    out = []
    for step in range(q - 1):
        r0 = rate[rows, cur][:, None]
        l0 = loss[rows, cur][:, None]
        dr = rate - r0
        dl = loss - l0
        ok = (dr > 0) & (dl < 0) & np.isfinite(dr) & active[:, None]
        if not ok.any():
            break
        with np.errstate(divide="ignore", invalid="ignore"):
            slope = np.where(ok, dl / np.where(ok, dr, 1.0), np.inf)
        best = slope.min(axis=1, keepdims=True)
        # nearest among ties (relative tolerance keeps float noise from splitting ties)
        tie = ok & (slope <= best + 1e-12 * np.abs(best))
        nxt = np.argmin(np.where(tie, dr, np.inf), axis=1)
        has = ok.any(axis=1)
        idx = np.flatnonzero(has)
        out.append((idx, np.full(idx.size, step), cur[idx], nxt[idx], dr[idx, nxt[idx]], dl[idx, nxt[idx]]))
        cur = np.where(has, nxt, cur)
        active = has
    if not out:
        e = np.zeros(0, np.int64)
        return e, e, e, e, np.zeros(0), np.zeros(0)
    cols = [np.concatenate(c) for c in zip(*out)]
    return (cols[0].astype(np.int64), cols[1].astype(np.int64), cols[2].astype(np.int64),
            cols[3].astype(np.int64), cols[4], cols[5])


def _greedy_hull(loss, rate, start, budget):
    """Take hull upgrades in order of decreasing efficiency while they fit (prefix), then
    continue down the list taking every later step that still fits and whose group's previous
    step was taken (the classic MCKP greedy).  Vectorised: the prefix by cumsum; the continuation
    by a few vectorised passes over the remainder."""
    grp, step, _, to, dr, dl = _hull_segments(loss, rate, start)
    pick = start.copy()
    left = budget - float(rate[np.arange(rate.shape[0]), pick].sum())
    if grp.size == 0:
        return pick
    eff = dl / dr                                      # most negative = best
    order = np.lexsort((step, grp, eff))
    grp, step, to, dr = grp[order], step[order], to[order], dr[order]
    cum = np.cumsum(dr)
    n_take = int(np.searchsorted(cum, left, side="right"))
    taken = np.zeros(grp.size, bool)
    taken[:n_take] = True
    # hull steps of a group have strictly increasing slopes, so a prefix respects group order
    left -= float(cum[n_take - 1]) if n_take else 0.0
    # continuation: steps after the first misfit, in order, that fit and follow their group's
    # last taken step.  A group whose step was skipped is frozen.
    frozen = np.zeros(loss.shape[0], bool)
    pos = n_take
    while pos < grp.size and left > 0:
        rest = np.arange(pos, grp.size)
        # steps of frozen groups can never be taken
        rest = rest[~frozen[grp[rest]]]
        if rest.size == 0:
            break
        fits = dr[rest] <= left
        first = int(np.argmax(fits)) if fits.any() else -1
        if first < 0:
            break
        # everything before `first` in rest misfits: freeze those groups
        frozen[grp[rest[:first]]] = True
        i = rest[first]
        if frozen[grp[i]]:
            pos = i + 1
            continue
        taken[i] = True
        left -= float(dr[i])
        pos = i + 1
    # apply: the last taken step of every group (steps are in increasing order within a group)
    ti = np.flatnonzero(taken)
    if ti.size:
        last = np.zeros(loss.shape[0], np.int64) - 1
        # order by (group, step) so the final write per group is its highest step
        o = np.lexsort((step[ti], grp[ti]))
        last[grp[ti][o]] = to[ti][o]
        pick = np.where(last >= 0, last, pick)
    return pick


def _moves(loss, rate, pick):
    """(dr, dl, fin): every option's rate and loss change against ``pick`` [G, Q], and where
    both are finite (a usable move)."""
    rows = np.arange(loss.shape[0])
    with np.errstate(invalid="ignore"):     # inf - inf where a pick is unusable: masked by fin
        dr = rate - rate[rows, pick][:, None]
        dl = loss - loss[rows, pick][:, None]
    return dr, dl, np.isfinite(dr) & np.isfinite(dl)


def _local_search(loss, rate, pick, budget, max_rounds: int):
    """Improve a feasible allocation exactly: repeatedly apply the best single-group move that
    fits the leftover budget, else the best pair (upgrade one group, downgrade another) that
    fits; stop when neither lowers the loss.  Each round is vectorised over all groups."""
    g, q = loss.shape
    rows = np.arange(g)
    for _ in range(max_rounds):
        left = budget - float(rate[rows, pick].sum())
        dr, dl, fin = _moves(loss, rate, pick)
        # single moves
        single = np.where(fin & (dr <= left), dl, np.inf)
        k = int(np.argmin(single))
        best_single = single.flat[k]
        # pair moves: upgrade u (dl_u < 0, needs dr_u > left) + downgrade d in another group with
        # freed rate -dr_d >= dr_u - left and the smallest dl_d
        up = fin & (dl < 0) & (dr > left)
        dn = fin & (dl >= 0) & (dr < 0)
        best_pair = np.inf
        if up.any() and dn.any():
            dgi, dqi = np.nonzero(dn)
            freed = -dr[dgi, dqi]
            cost = dl[dgi, dqi]
            o = np.argsort(freed, kind="stable")
            freed, cost, dgi, dqi = freed[o], cost[o], dgi[o], dqi[o]
            # suffix minima of cost = the best downgrade freeing at least x; a pair whose best
            # downgrade sits in the upgraded group itself is skipped (conservative)
            n = cost.size
            # best_idx[j] = argmin of cost[j:]: a running argmin over the reversed array
            rev = cost[::-1]
            run_min = np.minimum.accumulate(rev)
            is_new = np.concatenate([[True], rev[1:] < run_min[:-1]])
            last_new = np.maximum.accumulate(np.where(is_new, np.arange(n), 0))
            best_idx = (n - 1 - last_new)[::-1]
            ugi, uqi = np.nonzero(up)
            need = dr[ugi, uqi] - left
            j = np.searchsorted(freed, need, side="left")
            okj = j < n
            ugi, uqi, j = ugi[okj], uqi[okj], j[okj]
            if ugi.size:
                bi = best_idx[j]
                same = dgi[bi] == ugi
                gain = dl[ugi, uqi] + cost[bi]
                gain = np.where(same, np.inf, gain)
                m = int(np.argmin(gain))
                if gain[m] < 0:
                    best_pair = float(gain[m])
                    pair = (int(ugi[m]), int(uqi[m]), int(dgi[bi[m]]), int(dqi[bi[m]]))
        new = pick.copy()
        if best_single < 0 and best_single <= best_pair:
            new[k // q] = k % q
        elif best_pair < 0:
            u, uq, d, dq = pair
            new[u] = uq
            new[d] = dq
        else:
            break
        if not float(rate[rows, new].sum()) <= budget:   # float rounding at the boundary
            break
        pick = new
    return pick


#: option cells a round of :func:`_drop_and_refill` may visit (downgrades tried x G x Q): every
#: downgrade of an 80-group problem, the ~65 cheapest per freed bit of a 1000-group one
DROP_CELLS = 1 << 20
#: upgrades that refill one downgrade's freed budget
REFILL_STEPS = 4
#: rounds of drop-and-refill (each followed by the local search)
DROP_ROUNDS = 16


def _drop_and_refill(loss, rate, pick, budget):
    """The best improving "downgrade one group, then refill": the downgrades with the least loss
    per freed bit (as many as DROP_CELLS allows), each followed by up to REFILL_STEPS fitting
    upgrades of other groups, one at a time (the largest gain, or the most gain per bit).
    Reaches what single and pair moves cannot (two upgrades paid by one downgrade).  Returns an
    improved feasible pick, or None."""
    q = loss.shape[1]
    rows = np.arange(loss.shape[0])
    left = budget - float(rate[rows, pick].sum())
    dr, dl, fin = _moves(loss, rate, pick)
    dn = fin & (dr < 0) & (dl >= 0)
    if not dn.any():
        return None
    dgi, dqi = np.nonzero(dn)
    per_bit = dl[dgi, dqi] / -dr[dgi, dqi]
    order = np.lexsort((dqi, dgi, per_bit))[:max(DROP_CELLS // loss.size, 1)]
    refills = (_Refills(loss, rate, dr, dl, fin, False), _Refills(loss, rate, dr, dl, fin, True))
    best_gain, best = 0.0, None
    for d, dq in zip(dgi[order].tolist(), dqi[order].tolist()):
        for refill in refills:                      # the largest gain first, or the steepest
            new = pick.copy()
            new[d] = dq
            gain, room = float(dl[d, dq]), left - float(dr[d, dq])
            changed = [d]
            for _ in range(REFILL_STEPS):
                k, up_dl, up_dr = refill.best(new, changed, room)
                if k < 0:
                    break
                g = k // q
                new[g] = k % q
                if g not in changed:
                    changed.append(g)
                gain += up_dl
                room -= up_dr
            if gain < best_gain and float(rate[rows, new].sum()) <= budget:
                best_gain, best = gain, new
    return best


class _Refills:
    """The refill step of :func:`_drop_and_refill` against one ``pick``: the fitting upgrade
    (rate change <= room, loss change < 0; moves as :func:`_moves` makes them against the
    current ``new``) with the least score -- its loss change, or with ``per_bit`` that over
    max(rate change, 1e-9) -- ties to the lowest flat index, as an argmin over the [G, Q]
    scores.  Rows where ``new`` still equals ``pick`` have ``pick``'s moves, so their upgrades
    are sorted by score once and a step scans them for the first that fits; only the few
    ``changed`` rows are recomputed (the whole-matrix step was most of the allocation's time at
    1.2 M Gaussians)."""

    def __init__(self, loss, rate, dr, dl, fin, per_bit: bool):
        self.loss, self.rate, self.per_bit, self.q = loss, rate, per_bit, loss.shape[1]
        up = np.flatnonzero(fin & (dl < 0))
        dl_up, dr_up = dl.ravel()[up], dr.ravel()[up]
        score = dl_up / np.maximum(dr_up, 1e-9) if per_bit else dl_up
        o = np.lexsort((up, score))
        self.cells, self.score, self.dl, self.dr = up[o], score[o], dl_up[o], dr_up[o]
        self.row = self.cells // self.q

    def best(self, new, changed: list, room: float) -> tuple[int, float, float]:
        """(flat index, loss change, rate change) of the best fitting upgrade, or (-1, 0, 0);
        ``changed``: the rows where ``new`` differs from ``pick`` (the first one, the
        downgraded row, is never upgraded)."""
        k, score, k_dl, k_dr = -1, np.inf, 0.0, 0.0
        fits = self.dr <= room
        i = 0
        while True:
            i += int(np.argmax(fits[i:])) if i < fits.size else 0
            if i >= fits.size or not fits[i]:
                break
            if int(self.row[i]) not in changed:
                k, score = int(self.cells[i]), float(self.score[i])
                k_dl, k_dr = float(self.dl[i]), float(self.dr[i])
                break
            i += 1
        q = self.q
        for g in changed[1:]:
            up_dr = self.rate[g] - self.rate[g, new[g]]
            up_dl = self.loss[g] - self.loss[g, new[g]]
            ok = np.isfinite(up_dr) & np.isfinite(up_dl) & (up_dr <= room) & (up_dl < 0)
            for j in np.flatnonzero(ok).tolist():
                s = float(up_dl[j] / max(up_dr[j], 1e-9)) if self.per_bit else float(up_dl[j])
                if s < score or (s == score and g * q + j < k):
                    k, score, k_dl, k_dr = g * q + j, s, float(up_dl[j]), float(up_dr[j])
        return k, k_dl, k_dr


def allocate_fast(loss, rate, budget_bits: float, *, allowed=None, max_rounds: int | None = None) -> np.ndarray:
    """Near-optimal MCKP solution in milliseconds (module docstring).

    loss, rate: [G, Q] (float; +inf/NaN = unavailable).  budget_bits: total rate allowed.
    allowed: optional bool [G, Q] mask.  max_rounds: cap on local-search moves (default 4 G + 64).
    Returns int64 [G] option indices with sum rate <= budget_bits (always).
    Raises InfeasibleBudgetError (with .minimum) when the budget is below the minimum rate,
    AllocationError on bad inputs.
    """
    loss, rate, _ = _prepare(loss, rate, allowed)
    budget = float(budget_bits)
    if not np.isfinite(budget):
        raise AllocationError(f"budget must be finite, got {budget_bits}")
    start = _cheapest(loss, rate)
    _check_budget(rate, start, budget)
    pick = _greedy_hull(loss, rate, start, budget)
    rounds = 4 * loss.shape[0] + 64 if max_rounds is None else int(max_rounds)
    pick = _local_search(loss, rate, pick, budget, rounds)
    for _ in range(DROP_ROUNDS):
        better = _drop_and_refill(loss, rate, pick, budget)
        if better is None:
            break
        pick = _local_search(loss, rate, better, budget, rounds)
    assert total_rate(rate, pick) <= budget
    return pick.astype(np.int64)


# ---- ILP (PuLP / CBC) ---------------------------------------------------------------------------
def _solve_ilp(loss, rate, budget, *, time_limit, warm=None, gap_rel=1e-7):
    """One-hot 0-1 ILP over the valid options; returns (pick int64 [G], status) with status
    "Optimal Solution Found" for a proven optimum (within gap_rel), "Solution Found" for an
    incumbent when the time limit hit."""
    import pulp

    g, q = loss.shape
    valid = np.isfinite(loss) & np.isfinite(rate)
    upper = objective(loss, warm) if warm is not None else None
    if upper is not None and np.all(loss[valid] >= 0):
        # with non-negative losses no option dearer than a known solution's total can be in an
        # optimum (the warm option of every group survives): fewer variables and a sane range
        valid &= loss <= upper
    gi, qi = np.nonzero(valid)
    # scale the objective to ~1e6 at the known solution: CBC's tolerances are absolute, and the
    # raw SSE spans ~1e-6..1e7
    ref = upper if upper else float(np.max(np.abs(loss[valid]))) if gi.size else 1.0
    scale = 1e6 / ref if ref > 0 else 1.0
    prob = pulp.LpProblem("bit_allocation", pulp.LpMinimize)
    names = [f"x_{a}_{b}" for a, b in zip(gi.tolist(), qi.tolist())]
    if hasattr(prob, "add_variable"):        # PuLP >= 3.3 (direct LpVariable is deprecated)
        xs = [prob.add_variable(nm, 0, 1, cat=pulp.LpBinary) for nm in names]
    else:
        xs = [pulp.LpVariable(nm, 0, 1, cat=pulp.LpBinary) for nm in names]
    lv = (loss[gi, qi] * scale).tolist()
    rv = rate[gi, qi].tolist()
    prob += pulp.LpAffineExpression(list(zip(xs, lv)))
    prob += pulp.LpAffineExpression(list(zip(xs, rv))) <= float(budget), "budget"
    bounds = np.searchsorted(gi, np.arange(g + 1))
    for a in range(g):
        s, e = bounds[a], bounds[a + 1]
        prob += pulp.LpAffineExpression([(x, 1.0) for x in xs[s:e]]) == 1, f"one_{a}"
    if warm is not None:
        for x, a, b in zip(xs, gi, qi):
            x.setInitialValue(1.0 if warm[a] == b else 0.0)
    with warnings.catch_warnings():
        # PULP_CBC_CMD (the bundled binary) is deprecated for PuLP 4.0; it is what ships here
        warnings.simplefilter("ignore", DeprecationWarning)
        solver = pulp.PULP_CBC_CMD(msg=False, timeLimit=float(time_limit), gapRel=gap_rel,
                                   warmStart=warm is not None)
        prob.solve(solver)
    # sol_status tells a proven optimum (1) from an incumbent at the time limit (2)
    status = pulp.LpSolution.get(prob.sol_status, str(prob.sol_status))
    vals = np.array([x.varValue if x.varValue is not None else 0.0 for x in xs])
    pick = np.full(g, -1, np.int64)
    on = vals > 0.5
    pick[gi[on]] = qi[on]
    if np.any(pick < 0):
        raise AllocationError(f"CBC returned no complete solution (status {status})")
    return pick, status


def allocate_cbc(loss, rate, budget_bits: float, *, channels: int | None = None, allowed=None,
                 time_limit: float = 60.0, warm_start: bool = True) -> np.ndarray:
    """The paper's 0-1 ILP solved with PuLP's bundled CBC.

    Flat (channels=None): x[g, j] in {0, 1}, sum_j x = 1 per group, sum rate x <= budget,
    minimise sum loss x; warm-started from allocate_fast (as the reference code warm-starts
    from its previous round), so the result is never worse than it.
    Hierarchical (channels=C, groups channel-major G = C * B, the paper's two-step solver):
    1) an ILP over a uniform width per channel (loss/rate summed over the channel's blocks);
    2) channel c gets budget rate_c(Q_c) plus a share of the leftover proportional to Q_c (the
       paper splits S_T by Q_c / sum Q_c; with entropy-coded rates the uniform-width rate is the
       sensible base), and an ILP per channel picks its blocks' widths within that share.
       Unused share of one channel is NOT passed on (that is the method's known weakness).
    Returns int64 [G]; never over budget (a timed-out CBC keeps its incumbent, which starts from
    the warm start); InfeasibleBudgetError as allocate_fast.
    """
    loss, rate, _ = _prepare(loss, rate, allowed)
    budget = float(budget_bits)
    start = _cheapest(loss, rate)
    _check_budget(rate, start, budget)
    if channels is None:
        warm = allocate_fast(loss, rate, budget) if warm_start else None
        pick, _ = _solve_ilp(loss, rate, budget, time_limit=time_limit, warm=warm)
        if warm is not None and objective(loss, warm) < objective(loss, pick):
            pick = warm          # a time-limited CBC may stop on a worse incumbent
        if total_rate(rate, pick) > budget:
            raise AllocationError("CBC solution exceeds the budget (solver tolerance)")
        return pick
    c = int(channels)
    g, q = loss.shape
    if c < 1 or g % c:
        raise AllocationError(f"{g} groups cannot be split into {channels} channels")
    b = g // c
    lc = loss.reshape(c, b, q).sum(axis=1)
    rc = rate.reshape(c, b, q).sum(axis=1)
    # channel step: a uniform width per channel; if even that is infeasible at every channel's
    # cheapest uniform width, fall back to per-group cheapest as the base
    if float(np.nanmin(np.where(np.isfinite(rc), rc, np.inf), axis=1).sum()) <= budget:
        qc, _ = _solve_ilp(lc, rc, budget, time_limit=time_limit / 2,
                           warm=allocate_fast(lc, rc, budget) if warm_start else None)
        base = rc[np.arange(c), qc]
        share = (qc + 1) / float((qc + 1).sum())
    else:
        base = rate.reshape(c, b, q).min(axis=2).sum(axis=1)
        share = np.full(c, 1.0 / c)
    leftover = budget - float(base.sum())
    pick = np.empty(g, np.int64)
    for ci in range(c):
        sl = slice(ci * b, (ci + 1) * b)
        cb = float(base[ci] + leftover * share[ci])
        cb = max(cb, float(rate[sl].min(axis=1).sum()))
        warm = allocate_fast(loss[sl], rate[sl], cb) if warm_start else None
        p, _ = _solve_ilp(loss[sl], rate[sl], cb, time_limit=time_limit / (2 * c), warm=warm)
        if warm is not None and objective(loss[sl], warm) < objective(loss[sl], p):
            p = warm
        pick[sl] = p
    if total_rate(rate, pick) > budget:
        # channel shares were clamped up to their minimum: repair with the flat fast solver
        pick = allocate_fast(loss, rate, budget)
    return pick


def allocate(loss, rate, budget_bits: float, method: str = "fast", **kw) -> np.ndarray:
    """Dispatch: method "fast" (allocate_fast), "cbc" (flat ILP) or "cbc-hierarchical"
    (allocate_cbc with channels=kw['channels'])."""
    if method == "fast":
        return allocate_fast(loss, rate, budget_bits, **kw)
    if method == "cbc":
        return allocate_cbc(loss, rate, budget_bits, **kw)
    if method == "cbc-hierarchical":
        if kw.get("channels") is None:
            raise AllocationError("method 'cbc-hierarchical' needs channels=C")
        return allocate_cbc(loss, rate, budget_bits, **kw)
    raise AllocationError(f"unknown allocation method {method!r}; use 'fast', 'cbc' or 'cbc-hierarchical'")
