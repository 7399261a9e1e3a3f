"""Bit allocation (gsz.encoder.bit_allocation) on real loss / rate tables of the committed samples."""
import functools

import numpy as np
import pytest

import gsz
from conftest import SAMPLE_SH0, SAMPLE_SH3
from gsz.decoder.errors import GszError
from gsz.encoder.bit_allocation import (AllocationError, InfeasibleBudgetError, allocate,
                                        allocate_cbc, allocate_fast, minimum_rate, objective,
                                        total_rate, _solve_ilp)
from gsz.encoder.rate import rate_matrix
from gsz.kernels.quantize import quantize_all_bits


@functools.lru_cache(maxsize=None)
def channel_sets(which: str):
    """The codec's two quantised channel sets of a sample: RAHT AC of opacity / Euler / DC
    (7 channels) and the log-scales (3 channels), float32 [C, L]."""
    cloud = gsz.read_ply({"sh0": SAMPLE_SH0, "sh3": SAMPLE_SH3}[which])
    from gsz.encoder.pipeline import prepare_stage
    stage = prepare_stage(cloud, np.ones(len(cloud)), 1.0)   # every Gaussian kept
    return stage.layers[0].raht_ac, stage.layers[0].scales


@functools.lru_cache(maxsize=None)
def tables(which: str, blocks: int):
    """Real (loss [G, 16], rate [G, 16], coefficient count) for both channel sets, channel-major."""
    losses, rates, n = [], [], 0
    for x in channel_sets(which):
        _, _, _, loss = quantize_all_bits(x, blocks)
        losses.append(loss.reshape(-1, 16))
        rates.append(rate_matrix(x, blocks).reshape(-1, 16))
        n += x.size
    return np.concatenate(losses), np.concatenate(rates), n


def exact_dp(loss, rate_int, budget):
    """Exact MCKP optimum by dynamic programming over integer rates (small problems only)."""
    g, q = loss.shape
    best = np.full(budget + 1, np.inf)
    best[0] = 0.0
    choice = []
    for a in range(g):
        new = np.full(budget + 1, np.inf)
        arg = np.full(budget + 1, -1)
        for j in range(q):
            r = rate_int[a, j]
            if not np.isfinite(loss[a, j]) or r > budget:
                continue
            cand = np.full(budget + 1, np.inf)
            cand[r:] = best[:budget + 1 - r] + loss[a, j]
            better = cand < new
            new[better] = cand[better]
            arg[better] = j
        best = new
        choice.append(arg)
    return float(best.min())


@pytest.mark.parametrize("which, blocks, avg_bits", [("sh0", 8, 2.0), ("sh0", 8, 6.0), ("sh3", 8, 3.0),
                                                     ("sh3", 16, 6.0)])
def test_fast_matches_cbc_optimum_on_real_tables(which, blocks, avg_bits):
    loss, rate, n = tables(which, blocks)
    budget = avg_bits * n
    fast = allocate_fast(loss, rate, budget)
    # independent CBC run (no warm start from the fast solution)
    cbc, status = _solve_ilp(loss, rate, budget, time_limit=15)
    assert total_rate(rate, fast) <= budget and total_rate(rate, cbc) <= budget * (1 + 1e-9)
    of, oc = objective(loss, fast), objective(loss, cbc)
    assert of <= oc * 1.001, (of, oc, status)


def test_allocate_cbc_never_worse_than_fast_and_within_budget():
    loss, rate, n = tables("sh0", 8)
    budget = 6.0 * n
    p = allocate(loss, rate, budget, method="cbc", time_limit=5)
    assert total_rate(rate, p) <= budget
    assert objective(loss, p) <= objective(loss, allocate_fast(loss, rate, budget))


def test_hierarchical_cbc_is_feasible_and_beats_channel_uniform_widths():
    x = channel_sets("sh0")[0]
    _, _, _, loss3 = quantize_all_bits(x, 8)
    rate3 = rate_matrix(x, 8)
    c, b, _ = loss3.shape
    loss, rate = loss3.reshape(-1, 16), rate3.reshape(-1, 16)
    budget = 3.0 * x.size
    hier = allocate(loss, rate, budget, method="cbc-hierarchical", channels=c, time_limit=10)
    assert total_rate(rate, hier) <= budget
    # best allocation with ONE width per channel (exhaustive over the flat solver on channel sums)
    lc, rc = loss3.sum(axis=1), rate3.sum(axis=1)
    uni = allocate_fast(lc, rc, budget)
    assert objective(loss, hier) <= objective(lc, uni) * (1 + 1e-12)
    flat = allocate_fast(loss, rate, budget)
    assert objective(loss, flat) <= objective(loss, hier) * 1.001
    with pytest.raises(AllocationError, match="channels"):
        allocate(loss, rate, budget, method="cbc-hierarchical")
    with pytest.raises(AllocationError, match="cannot be split"):
        allocate_cbc(loss, rate, budget, channels=5)


def test_budget_sweep_never_over_budget_and_monotone():
    loss, rate, n = tables("sh0", 16)
    lo = minimum_rate(rate)
    hi = float(rate.max(axis=1).sum())
    prev = np.inf
    for budget in np.linspace(lo, hi * 1.01, 41):
        p = allocate_fast(loss, rate, budget)
        used = total_rate(rate, p)
        assert used <= budget
        obj = objective(loss, p)
        assert obj <= prev, "a larger budget gave a larger loss"
        prev = obj
        if budget >= hi:
            assert np.all(p == np.argmin(loss, axis=1)) or obj <= objective(loss, np.argmin(loss, axis=1))


def test_infeasible_budget_reports_the_minimum():
    loss, rate, n = tables("sh3", 8)
    need = minimum_rate(rate)
    with pytest.raises(InfeasibleBudgetError) as e:
        allocate_fast(loss, rate, need * 0.9)
    assert e.value.minimum == pytest.approx(need)
    assert f"{need:.0f} bits" in str(e.value) and isinstance(e.value, GszError)
    with pytest.raises(InfeasibleBudgetError):
        allocate_cbc(loss, rate, need * 0.5)
    # exactly the minimum is feasible: every group at its cheapest width
    p = allocate_fast(loss, rate, need)
    assert total_rate(rate, p) <= need


def test_matches_exact_dp_on_nonmonotone_problems_with_forbidden_widths():
    rng = np.random.default_rng(5)
    gaps = []
    for trial in range(40):
        g, q = int(rng.integers(3, 25)), int(rng.integers(2, 9))
        rate = rng.integers(1, 30, (g, q)).astype(np.float64)
        loss = rng.lognormal(0, 2, (g, q))                 # no relation to rate: non-monotone
        forbid = rng.random((g, q)) < 0.25
        forbid[np.arange(g), rng.integers(0, q, g)] = False
        loss[forbid] = np.inf
        lo = float(np.where(forbid, np.inf, rate).min(axis=1).sum())
        budget = int(lo + rng.integers(0, 20 * g))
        p = allocate_fast(loss, rate, budget)
        assert not np.any(forbid[np.arange(g), p])
        assert total_rate(rate, p) <= budget
        opt = exact_dp(loss, rate.astype(np.int64), budget)
        gaps.append(objective(loss, p) / opt - 1)
    gaps = np.array(gaps)
    # adversarial random tables: the hull greedy + local search is exact on most of them
    assert np.mean(gaps < 1e-12) >= 0.6 and gaps.max() < 0.10, gaps


def test_refill_step_is_the_argmin_over_every_move_against_the_current_pick():
    # _Refills scans pick's sorted upgrades and recomputes only the changed rows: it must pick
    # exactly what the argmin over the whole [G, Q] move matrix picks, ties included
    from gsz.encoder.bit_allocation import _moves, _prepare, _Refills
    rng = np.random.default_rng(3)
    for trial in range(60):
        g, q = int(rng.integers(2, 60)), 16
        loss = rng.random((g, 1)) * np.exp2(-2.0 * np.arange(q)) * rng.uniform(0.5, 1.5, (g, q))
        rate = np.cumsum(rng.uniform(0, 3, (g, q)), axis=1) * rng.integers(1, 50, (g, 1))
        if trial % 2:
            loss, rate = np.round(loss, 2), np.round(rate)         # many equal scores
        loss[rng.random((g, q)) < 0.1] = np.inf
        loss[:, 0] = np.where(np.isfinite(loss[:, 0]), loss[:, 0], 1.0)
        loss, rate, _ = _prepare(loss, rate, None)
        pick = rng.integers(0, q, g)
        pick = np.where(np.isfinite(loss[np.arange(g), pick]), pick, 0)
        dr, dl, fin = _moves(loss, rate, pick)
        for per_bit in (False, True):
            refill = _Refills(loss, rate, dr, dl, fin, per_bit)
            new, changed = pick.copy(), [int(rng.integers(0, g))]
            new[changed[0]] = int(rng.integers(0, q))
            for _ in range(4):
                room = float(rng.uniform(-5, 200))
                up_dr, up_dl, ok = _moves(loss, rate, new)
                ok &= (up_dr <= room) & (up_dl < 0)
                ok[changed[0]] = False
                score = np.where(ok, up_dl, np.inf)
                if per_bit:
                    score = np.divide(score, np.maximum(up_dr, 1e-9), out=score, where=ok)
                k, k_dl, k_dr = refill.best(new, changed, room)
                if not ok.any():
                    assert k == -1
                    break
                assert k == int(np.argmin(score))
                assert (k_dl, k_dr) == (up_dl.flat[k], up_dr.flat[k])
                new[k // q] = k % q
                if k // q not in changed:
                    changed.append(k // q)


def test_allowed_mask_and_bad_inputs():
    loss, rate, n = tables("sh3", 8)
    allowed = np.zeros_like(loss, bool)
    allowed[:, 3:10] = True                                  # 4..10 bits only
    p = allocate_fast(loss, rate, 6.0 * n, allowed=allowed)
    assert p.min() >= 3 and p.max() <= 9
    with pytest.raises(AllocationError, match="no usable option"):
        allocate_fast(loss, rate, 1e12, allowed=np.zeros_like(loss, bool))
    with pytest.raises(AllocationError, match=r"\[G, Q\]"):
        allocate_fast(loss, rate[:, :5], 1e9)
    with pytest.raises(AllocationError, match="unknown allocation method"):
        allocate(loss, rate, 1e9, method="genetic")


def test_fast_solver_on_800_groups_spends_the_budget():
    rng = np.random.default_rng(0)
    n = rng.integers(4000, 6000, 800)[:, None].astype(np.float64)
    q = np.arange(1, 17)[None, :]
    loss = rng.lognormal(0, 1, (800, 1)) * n * 4.0 ** -q * rng.uniform(0.8, 1.2, (800, 16))
    rate = n * q * rng.uniform(0.3, 0.6, (800, 1))
    budget = 0.35 * float(rate.sum(axis=0)[-1])
    # (its speed: bench/bench_bit_allocation.py) within budget, and the leftover smaller than
    # any single upgrade that would still lower the loss
    p = allocate_fast(loss, rate, budget)
    assert total_rate(rate, p) <= budget
    rows = np.arange(800)
    left = budget - total_rate(rate, p)
    up = (rate - rate[rows, p][:, None] <= left) & (loss < loss[rows, p][:, None])
    assert not up.any()
