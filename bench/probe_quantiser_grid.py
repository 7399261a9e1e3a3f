"""Probe for issue 18's high-rate gap (docs/design/high-rate-gap.md): would a different scalar
quantiser grid, or a codebook under the SH's scalar path, buy what the format's min-max grid does
not?  Outside the codec and without rendering: SNR of a channel set (its own power over the SSE)
after the size search's allocator (``bit_allocation.allocate``, fast) at budgets in bits, rate =
each group's zeroth-order entropy + 10 bits a present value + 40 (the same estimate for every
grid, so the rows compare with each other, not with the codec's own rate model).

    .venv/bin/python bench/probe_quantiser_grid.py SCENE [--noise] [--vq 256,1024,4096]

Grids (per (channel, block) group, q = 1..16 and width 0 = the group's mean):
* ``minmax``: the format's normative grid, m + k (M - m) / (2^q - 1);
* ``anchor``: a grid through the group's median with step (M - m) / (2^q - 2) (so the 2^q
  levels still cover [m, M]); a decoder reads it as min-max parameters (no format change);
* ``anchor dz``: the same with a dead zone (|offset| rounded down by 0.15 of a step).
Sets: the SH rest in the codec's luma/chroma space and in its KLT axes (``sh lc``, ``sh klt``),
and the RAHT AC and scales of ``prepare_stage(cloud, ones, 1.0, layers=1)``.

With ``--vq K,...``: the SH rest (KLT axes) as a K-word codebook (``encoder.vq``, unweighted)
plus the scalar path on the residual, the labels' entropy and the codewords (10 bits a
component) taken off each budget, against the scalar path alone.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "bench"))

DEAD_ZONE = 0.15


def grid_tables(x: np.ndarray, blocks: int, mode: str, dz: float = 0.0):
    """(loss [C*B, 17], rate [C*B, 17]) of x [C, L] on one grid: width 0, then q = 1..16."""
    from gsz.decoder.quant import split_lengths
    c_n, length = x.shape
    lens = split_lengths(length, blocks)
    ends = np.cumsum(lens)
    loss = np.zeros((c_n * blocks, 17))
    rate = np.zeros((c_n * blocks, 17))
    g = 0
    for c in range(c_n):
        for s, e in zip((ends - lens).tolist(), ends.tolist()):
            v = x[c, s:e].astype(np.float64)
            if v.size == 0:
                g += 1
                continue
            m, big = float(v.min()), float(v.max())
            span = big - m
            loss[g, 0], rate[g, 0] = float(((v - v.mean()) ** 2).sum()), 32.0
            med = float(np.median(v))
            for q in range(1, 17):
                levels = 2 ** q - 1
                if span == 0:
                    loss[g, q], rate[g, q] = 0.0, 40.0
                    continue
                if mode == "minmax" or q == 1:
                    step, lo = span / levels, m
                    k = np.clip(np.rint((v - lo) / step), 0, levels)
                else:
                    step = span / (levels - 1)
                    lo = med - step * np.ceil((med - m) / step)
                    k0 = round((med - lo) / step)
                    off = (v - lo) / step - k0
                    k = np.clip(k0 + np.sign(off) * np.floor(np.abs(off) + 0.5 - dz), 0, levels)
                loss[g, q] = float(((v - (lo + step * k)) ** 2).sum())
                _, cnt = np.unique(k, return_counts=True)
                rate[g, q] = float(-(cnt * np.log2(cnt / v.size)).sum()) + 10 * len(cnt) + 40
            g += 1
    return loss, rate


def snr(x: np.ndarray, loss, rate, bits: float) -> float:
    from gsz.encoder.bit_allocation import allocate
    if bits <= 0:
        return float("nan")
    power = float(((x - x.mean(axis=1, keepdims=True)) ** 2).sum())
    pick = allocate(loss, rate, bits, method="fast")
    return 10 * np.log10(power / max(float(loss[np.arange(len(pick)), pick].sum()), 1e-30))


def compare(name: str, x: np.ndarray, blocks: int, budgets) -> None:
    print(f"{name} [{x.shape[0]} x {x.shape[1]}], budgets (bits a column): "
          + " ".join(f"{b:g}" for b in budgets))
    for mode, dz in (("minmax", 0.0), ("anchor", 0.0), ("anchor dz", DEAD_ZONE)):
        loss, rate = grid_tables(x, blocks, mode.split()[0], dz)
        print(f"  {mode:10s}" + " ".join(f"{snr(x, loss, rate, b * x.shape[1]):7.2f}" for b in budgets),
              flush=True)


def vq_rows(x: np.ndarray, blocks: int, budgets, sizes) -> None:
    """x [N, D]: scalar path alone against codebook + scalar residual."""
    from bench_sh_klt_probe import tables
    from probe_sh_refinement import _label_bits
    from gsz.encoder.vq import assign, train_codebook
    n, d = x.shape
    print(f"sh klt: codebook + scalar residual, budgets (bits a vector): " + " ".join(f"{b:g}" for b in budgets))
    loss, rate = tables(x.T, blocks)
    print("  scalar only      " + " ".join(f"{snr(x.T, loss, rate, b * n):7.2f}" for b in budgets), flush=True)
    for k in sizes:
        cb = np.asarray(train_codebook(x.astype(np.float32), None, k, seed=0), np.float64)
        idx = np.asarray(assign(x.astype(np.float32), cb.astype(np.float32)))
        label_bits = _label_bits(idx, k) + k * d * 10
        res = x - cb[idx]
        l2, r2 = tables(res.T, blocks)
        print(f"  K={k:<5d} ({label_bits / n:5.2f} b)" + " ".join(
            f"{snr(x.T, l2, r2, b * n - label_bits):7.2f}" for b in budgets), flush=True)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("scene", type=Path)
    p.add_argument("--noise", action="store_true", help="bench_codec's noise first (the RD bench's noised variant)")
    p.add_argument("--vq", default="", help="codebook sizes for the codebook + residual rows")
    a = p.parse_args(argv)
    from gsz.decoder.ply import read_ply
    from gsz.encoder.pipeline import prepare_stage
    from gsz.encoder.sh_colour import _FORWARD
    cloud = read_ply(a.scene)
    if a.noise:
        from bench_codec import add_noise
        cloud = add_noise(cloud)
    sh = np.asarray(cloud.sh_rest, np.float64)
    n, k, _ = sh.shape
    if k:
        lc = (sh @ _FORWARD.T).reshape(n, 3 * k)
        _, vec = np.linalg.eigh(np.cov(lc.T))
        klt = lc @ vec[:, ::-1]
        blocks = max(1, min(80, n // 128))
        per_vector = [c * 3 * k for c in (0.25, 0.5, 1, 1.5, 2, 3)]
        if a.vq:
            vq_rows(klt, blocks, per_vector, [int(v) for v in a.vq.split(",")])
        compare("sh klt", np.ascontiguousarray(klt.T), blocks, per_vector)
        compare("sh lc", np.ascontiguousarray(lc.T), blocks, per_vector)
    stage = prepare_stage(cloud, np.ones(len(cloud)), 1.0, layers=1)
    layer = stage.layers[0]
    ac = np.asarray(layer.raht_ac, np.float64)
    compare("raht", ac, 80, [c * ac.shape[0] for c in (1, 2, 3, 4, 6)])
    scales = np.asarray(layer.scales, np.float64)
    compare("scales", scales, 80, [c * scales.shape[0] for c in (1, 2, 3, 4, 6)])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
