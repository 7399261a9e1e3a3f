"""Benchmark of the group-wise quantiser loss table + the RAHT AC-layout / angle-wrap study.

Usage:  python bench/bench_quant.py [--scene ../shared/data/flowers_daffodils_sh2.ply] [--depth 16]
                                    [--blocks 80] [--repeats 3]

1. Loss table timing (CPU path, or CUDA when available): channels = 7 RAHT-AC channels
   (opacity, roll, pitch, yaw, DC RGB) + 3 log-scale channels of the voxelised scene, 80 blocks.
2. AC layout: level order (coarse first, the gsz format) vs the reference code's Morton-leaf
   interleave.  For each layout a Lagrangian bit allocation over the loss table is solved at
   equal raw bits (avg 2 / 4 / 6 bits per coefficient); reported: SSE and the empirical
   zeroth-order entropy of the resulting symbols (per group histogram) -- lower is better.
3. Euler-angle wrap: plain [-pi, pi] angles vs angles shifted by 2*pi towards the circular mean
   of their depth-6 octree cell (gsz.decoder.rotation.wrap_to_reference) -- AC energy.
Keep it short-lived: one process, ~1 GB peak for the 542k scene.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch

import gsz
from gsz.decoder.morton import morton_encode
from gsz.decoder.quant import split_lengths
from gsz.decoder.raht import build_raht_tree
from gsz.decoder.rotation import quaternion_to_euler, wrap_to_reference
from gsz.encoder.raht import leaf_interleaved_order, raht_forward
from gsz.kernels.quantize import quantize_all_bits

ROOT = Path(__file__).resolve().parent.parent


def voxelise(cloud, depth):
    p = cloud.positions.astype(np.float64)
    lo, hi = p.min(0), p.max(0)
    ijk = np.minimum(((p - lo) / np.maximum(hi - lo, 1e-12) * 2 ** depth).astype(np.int64), 2 ** depth - 1)
    codes, first, inv = np.unique(morton_encode(ijk), return_index=True, return_inverse=True)
    cnt = np.bincount(inv)
    attrs = np.concatenate([cloud.opacities[:, None], quaternion_to_euler(cloud.rotations),
                            cloud.sh_dc, cloud.scales], 1).astype(np.float64)
    sums = np.zeros((codes.size, attrs.shape[1]))
    np.add.at(sums, inv, attrs)
    return codes, sums / cnt[:, None]


def allocate(loss, lengths, avg_bits):
    """Lagrangian MCKP: per group argmin loss + lam * q * n, lam bisected to the raw-bit budget."""
    q = np.arange(1, 17)
    n = lengths[None, :, None].astype(np.float64)
    budget = avg_bits * lengths.sum() * loss.shape[0]
    lo, hi = 1e-30, 1e30
    for _ in range(200):
        lam = np.sqrt(lo * hi)
        pick = np.argmin(loss + lam * q * n, axis=2)
        if ((pick + 1) * n[..., 0]).sum() > budget:
            lo = lam
        else:
            hi = lam
    pick = np.argmin(loss + hi * q * n, axis=2)
    return pick + 1


def group_entropy_bits(sym, lengths):
    total = 0.0
    starts = np.concatenate([[0], np.cumsum(lengths)])
    for c in range(sym.shape[0]):
        for b in range(lengths.shape[0]):
            seg = sym[c, starts[b]:starts[b + 1]]
            if seg.size:
                p = np.bincount(seg) / seg.size
                p = p[p > 0]
                total += -seg.size * np.sum(p * np.log2(p))
    return total


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--scene", default=str(ROOT.parent / "shared" / "data" / "flowers_daffodils_sh2.ply"))
    ap.add_argument("--depth", type=int, default=16)
    ap.add_argument("--blocks", type=int, default=80)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--threads", type=int, default=0, help="torch CPU threads (0 = torch default)")
    ap.add_argument("--timing-only", action="store_true")
    args = ap.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    scene = Path(args.scene)
    if not scene.exists():
        scene = ROOT / "tests" / "data" / "houseplant_sh0_20k.ply"
    cloud = gsz.read_ply(scene)
    t0 = time.perf_counter()
    codes, attrs = voxelise(cloud, args.depth)
    t_vox = time.perf_counter() - t0
    t0 = time.perf_counter()
    tree = build_raht_tree(codes, args.depth)
    t_tree = time.perf_counter() - t0
    t0 = time.perf_counter()
    dc, ac = raht_forward(attrs[:, :7], tree)
    t_fwd = time.perf_counter() - t0
    n = codes.size
    print(f"scene {scene.name}: {cloud.positions.shape[0]} Gaussians -> {n} voxels at depth {args.depth} "
          f"(voxelise {t_vox:.2f} s, RAHT tree {t_tree:.3f} s, forward 7 ch {t_fwd:.3f} s)")

    x = np.ascontiguousarray(np.concatenate([ac.T, attrs[1:, 7:].T]).astype(np.float32))  # [10, N-1]
    xt = torch.from_numpy(x)
    times = []
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        fn, mins, maxs, loss = quantize_all_bits(xt, args.blocks)
        times.append(time.perf_counter() - t0)
    print(f"loss table [{x.shape[0]} ch, {args.blocks} blocks, {x.shape[1]} elements/ch, 16 bit-widths]: "
          f"best {min(times):.3f} s, median {np.median(times):.3f} s over {args.repeats} "
          f"(torch threads {torch.get_num_threads()})")
    bits = np.full((x.shape[0], args.blocks), 8)
    t0 = time.perf_counter()
    fn(bits)
    print(f"symbols for one allocation: {time.perf_counter() - t0:.3f} s")

    if args.timing_only:
        return
    lengths = split_lengths(x.shape[1], args.blocks)
    perm = leaf_interleaved_order(tree)
    layouts = {"level (gsz)": ac, "leaf interleave (ref)": ac[perm]}
    print("AC layout, 7 RAHT channels: Lagrangian allocation over the loss table at avg 1..8 raw "
          "bit/coef; SSE interpolated (log-linear) at equal zeroth-order symbol entropy:")
    curves = {}
    for name, arr in layouts.items():
        xa = np.ascontiguousarray(arr.T.astype(np.float32))
        f2, _, _, l2 = quantize_all_bits(xa, args.blocks)
        pts = []
        for avg in range(1, 9):
            b = allocate(l2, lengths, avg)
            sse = np.take_along_axis(l2, b[..., None] - 1, 2).sum()
            pts.append((group_entropy_bits(f2(b), lengths) / xa.size, sse))
        curves[name] = np.array(pts)
        print(f"  {name:22s} (entropy bit/coef, SSE): " + ", ".join(f"({h:.2f}, {e:.4g})" for h, e in pts))
    a, b = curves["level (gsz)"], curves["leaf interleave (ref)"]
    for h in (0.5, 1.0, 2.0, 3.0, 4.0):
        if a[0, 0] <= h <= a[-1, 0] and b[0, 0] <= h <= b[-1, 0]:
            sa = np.exp(np.interp(h, a[:, 0], np.log(a[:, 1])))
            sb = np.exp(np.interp(h, b[:, 0], np.log(b[:, 1])))
            print(f"  at {h:.1f} bit/coef: SSE level {sa:.4g} vs leaf {sb:.4g} (level/leaf = {sa / sb:.3f})")

    # Angle wrap towards the circular mean of each depth-6 cell.
    e = attrs[:, 1:4]
    cell = codes >> np.uint64(3 * (args.depth - 6))
    _, cidx = np.unique(cell, return_inverse=True)
    ref = np.empty_like(e)
    for k in range(3):
        s = np.bincount(cidx, np.sin(e[:, k]))
        c = np.bincount(cidx, np.cos(e[:, k]))
        ref[:, k] = np.arctan2(s, c)[cidx]
    wrapped = wrap_to_reference(e, ref)
    _, ac_plain = raht_forward(e, tree)
    _, ac_wrap = raht_forward(wrapped, tree)
    print("Euler AC energy (roll, pitch, yaw): plain", np.round((ac_plain ** 2).sum(0), 1),
          " wrapped to cell mean", np.round((ac_wrap ** 2).sum(0), 1))


if __name__ == "__main__":
    main()
