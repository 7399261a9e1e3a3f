"""Benchmark of the lossless octree geometry coder against the G-PCC (tmc3) anchor.

Usage:  python bench/bench_octree.py [--scenes flowers_daffodils_sh2,houseplant_sh0,...]
                                     [--depth D] [--shared ../shared/data]

Per scene at its operating depth (geometry-anchor.md: first d with merge < 1 %), voxelised
exactly as the anchor did (per-axis min of the centres, cube side = largest extent,
q = floor((p - min) / side * 2^d) clipped to [0, 2^d - 1], duplicates removed), prints:
voxels M, payload bytes, bits per occupied voxel, ratio to tmc3-best (the anchor's bytes),
ratio to zstd-19 over the occupancy bytes (one byte per internal node, breadth-first, Morton
order within a level), encode / decode seconds (wall clock and process CPU time -- the latter is
the fairer figure on a shared, oversubscribed machine; no PLY I/O), and a lossless check.  One scene at a time keeps the peak memory < 1 GB.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import zstandard
from plyfile import PlyData

from gsz.decoder.morton import morton_encode
from gsz.decoder.octree import decode_octree
from gsz.encoder.octree import encode_octree, occupancy_levels

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"

#: geometry-anchor.md, "Anchor at the operating depth": (op. depth, M, tmc3-best bytes, config).
#: Reference measurements of the external tool, used only as the ratio's denominator.
ANCHOR = {
    "flowers_daffodils_sh2": (11, 539_350, 710_734, "CTC"),
    "houseplant_sh0": (11, 113_071, 155_079, "CTC"),
    "measuring_jug_sh3": (10, 101_076, 135_071, "CTC"),
    "plaza_taebak_crop_sh0": (11, 298_436, 389_882, "CTC"),
    "showroom_lacadiere_crop_sh0": (13, 168_944, 283_264, "P+I"),
    "bouquet_sh3": (10, 115_849, 153_644, "CTC"),
    "hexagonal_box_sh3": (11, 78_385, 121_230, "CTC"),
    "tiny_graphdeco_iter7000_sh3": (10, 8_197, 14_237, "CTC"),
}


def anchor_voxels(path: Path, depth: int) -> np.ndarray:
    """int64 [M, 3] unique voxels of a PLY's centres, the anchor's voxelisation."""
    v = PlyData.read(str(path))["vertex"]
    p = np.stack([np.asarray(v[a], dtype=np.float64) for a in ("x", "y", "z")], axis=1)
    lo = p.min(axis=0)
    side = float((p.max(axis=0) - lo).max())
    q = np.clip(np.floor((p - lo) / side * (1 << depth)), 0, (1 << depth) - 1).astype(np.int64)
    return np.unique(q, axis=0)


def bench_scene(name: str, path: Path, depth: int | None) -> dict:
    op_depth, anchor_m, anchor_bytes, cfg = ANCHOR.get(name, (None, None, None, None))
    d = depth or op_depth or 11
    ijk = anchor_voxels(path, d)
    m = len(ijk)
    t0, c0 = time.perf_counter(), time.process_time()
    payload = encode_octree(ijk, d)
    t1, c1 = time.perf_counter(), time.process_time()
    out = decode_octree(payload, d, m)
    t2, c2 = time.perf_counter(), time.process_time()
    codes = np.sort(morton_encode(ijk))
    lossless = bool(np.array_equal(morton_encode(out), codes))
    occ = np.concatenate(occupancy_levels(codes, d)).astype(np.uint8).tobytes()
    zstd = len(zstandard.ZstdCompressor(level=19).compress(occ))
    comparable = anchor_bytes is not None and d == op_depth and m == anchor_m
    return dict(scene=name, d=d, M=m, bytes=len(payload), bpv=8 * len(payload) / m,
                tmc3=(len(payload) / anchor_bytes) if comparable else float("nan"),
                tmc3_bpv=(8 * anchor_bytes / anchor_m) if comparable else float("nan"),
                zstd=len(payload) / zstd, enc=t1 - t0, dec=t2 - t1, enc_cpu=c1 - c0, dec_cpu=c2 - c1,
                ok=lossless, cfg=cfg or "-")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", default=",".join(ANCHOR))
    ap.add_argument("--depth", type=int, default=None, help="override every scene's depth")
    ap.add_argument("--shared", type=Path, default=SHARED)
    args = ap.parse_args()
    print(f"{'scene':30s} {'d':>2s} {'M':>8s} {'bytes':>9s} {'bits/vox':>8s} {'tmc3 b/v':>8s} "
          f"{'/tmc3':>6s} {'/zstd19':>7s} {'enc s':>6s} {'dec s':>6s} {'cpu e/d s':>11s} lossless")
    rows = []
    for name in args.scenes.split(","):
        path = args.shared / f"{name}.ply"
        if not path.exists():
            print(f"{name:30s} (absent: {path})")
            continue
        r = bench_scene(name, path, args.depth)
        rows.append(r)
        print(f"{r['scene']:30s} {r['d']:2d} {r['M']:8d} {r['bytes']:9d} {r['bpv']:8.3f} "
              f"{r['tmc3_bpv']:8.2f} {r['tmc3']:6.3f} {r['zstd']:7.3f} {r['enc']:6.2f} "
              f"{r['dec']:6.2f} {r['enc_cpu']:5.2f}/{r['dec_cpu']:5.2f} {r['ok']}", flush=True)
    ratios = [r["tmc3"] for r in rows if np.isfinite(r["tmc3"]) and r["M"] > 50_000]
    if ratios:
        print(f"ratio to tmc3-best over scenes with an operating depth: median {np.median(ratios):.3f}, "
              f"max {max(ratios):.3f}")


if __name__ == "__main__":
    main()
