"""Benchmark of the rate model and the bit-allocation solvers on a real scene.

Usage:  python bench/bench_bit_allocation.py [--scene ../shared/data/flowers_daffodils_sh2.ply]
            [--keep 0.8] [--blocks 80] [--cbc-time 60] [--budgets 2,4,6]

Channels: the codec's RAHT AC (opacity, Euler, DC: 7 channels) and log-scales (3 channels) of the
voxelised scene, every Gaussian of a seeded random `keep` fraction (a stand-in for pruning).
Reports
1. time of quantize_all_bits (loss) and rate_matrix (rate) for both channel sets;
2. for each budget (average predicted bits per coefficient): allocate_fast time, CBC (flat,
   cold start) time / status / objective gap, hierarchical CBC objective gap;
3. the rate model's error on the allocations the solver picked: predicted vs real encode_stream
   bits (per-group models).
One process, ~1-2 GB peak on the 542k scene; keep it short-lived.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

import gsz
from gsz.decoder.groups import group_model_ids
from gsz.encoder.bit_allocation import _solve_ilp, allocate_cbc, allocate_fast, objective, total_rate
from gsz.encoder.rans import encode_stream
from gsz.encoder.rate import rate_matrix
from gsz.kernels.quantize import quantize_all_bits

ROOT = Path(__file__).resolve().parent.parent


def channel_sets(path: Path, keep: float):
    cloud = gsz.read_ply(path)
    if keep < 1:
        idx = np.sort(np.random.default_rng(0).choice(len(cloud), int(keep * len(cloud)), replace=False))
        cloud = cloud.subset(idx)
    from gsz.encoder.pipeline import prepare_stage
    stage = prepare_stage(cloud, np.ones(len(cloud)), 1.0)   # every Gaussian kept
    return [stage.layers[0].raht_ac, stage.layers[0].scales], len(cloud)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--scene", default=str(ROOT.parent / "shared/data/flowers_daffodils_sh2.ply"))
    ap.add_argument("--keep", type=float, default=0.8)
    ap.add_argument("--blocks", type=int, default=80)
    ap.add_argument("--cbc-time", type=float, default=60.0)
    ap.add_argument("--budgets", default="2,4,6")
    a = ap.parse_args()

    sets, n_gauss = channel_sets(Path(a.scene), a.keep)
    print(f"scene {Path(a.scene).name}: {n_gauss} Gaussians kept, channel sets "
          f"{[tuple(x.shape) for x in sets]}, {a.blocks} blocks")
    losses, rates, fns, t_loss, t_rate = [], [], [], 0.0, 0.0
    for x in sets:
        t = time.perf_counter()
        fn, _, _, loss = quantize_all_bits(x, a.blocks)
        t_loss += time.perf_counter() - t
        t = time.perf_counter()
        r = rate_matrix(x, a.blocks)
        t_rate += time.perf_counter() - t
        losses.append(loss.reshape(-1, 16))
        rates.append(r.reshape(-1, 16))
        fns.append(fn)
    loss, rate = np.concatenate(losses), np.concatenate(rates)
    n_coef = sum(x.size for x in sets)
    print(f"loss tables {t_loss:.2f} s, rate_matrix {t_rate:.2f} s  (G = {loss.shape[0]} groups)")

    for avg in [float(v) for v in a.budgets.split(",")]:
        budget = avg * n_coef
        allocate_fast(loss, rate, budget)                        # warm-up
        t = time.perf_counter()
        fast = allocate_fast(loss, rate, budget)
        t_fast = time.perf_counter() - t
        t = time.perf_counter()
        cbc, status = _solve_ilp(loss, rate, budget, time_limit=a.cbc_time)
        t_cbc = time.perf_counter() - t
        t = time.perf_counter()
        c_ac = sets[0].shape[0]
        g_ac = c_ac * a.blocks
        # hierarchical: per channel set (channels are channel-major inside each set)
        hier = np.concatenate([
            allocate_cbc(loss[:g_ac], rate[:g_ac], budget * sets[0].size / n_coef, channels=c_ac,
                         time_limit=a.cbc_time / 2, warm_start=False),
            allocate_cbc(loss[g_ac:], rate[g_ac:], budget * sets[1].size / n_coef,
                         channels=sets[1].shape[0], time_limit=a.cbc_time / 2, warm_start=False)])
        t_hier = time.perf_counter() - t
        of, oc, oh = objective(loss, fast), objective(loss, cbc), objective(loss, hier)
        # rate model error on the chosen allocation (real per-group-model streams)
        real = pred = 0.0
        g0 = 0
        for x, fn in zip(sets, fns):
            c, length = x.shape
            g = c * a.blocks
            bits = fast[g0:g0 + g].reshape(c, a.blocks) + 1
            mids, count = group_model_ids(c, length, a.blocks)
            real += 8 * len(encode_stream(fn(bits).ravel(), mids, count))
            pred += total_rate(rate[g0:g0 + g], fast[g0:g0 + g])
            g0 += g
        print(f"avg {avg:g} bit/coef (budget {budget / 8e6:.3f} MB): fast {1e3 * t_fast:.1f} ms "
              f"obj {of:.6g} used {total_rate(rate, fast) / budget:.5f} | CBC {t_cbc:.1f} s [{status}] "
              f"obj {oc:.6g} fast-vs-CBC {100 * (of - oc) / oc:+.4f} % | hierarchical CBC {t_hier:.1f} s "
              f"{100 * (oh - oc) / oc:+.3f} % | rate model: pred {pred / 8e6:.4f} MB real "
              f"{real / 8e6:.4f} MB ({100 * (pred - real) / real:+.2f} %)", flush=True)


if __name__ == "__main__":
    main()
