"""Benchmark of gsz.encoder.vq: seconds and importance-weighted MSE per K / iterations.

Usage:  python bench/bench_vq.py [scene.ply ...] [--K 4096] [--iters 0,50,100,200] [--lloyd 0,2]

Weights: the real importance needs the renderer and the scene's cameras; this bench uses the
camera-free proxy sigmoid(opacity) * (V / V_ref)^0.1 (heavy-tailed like the real one).
MSE is per vector (sum over the D dims), weighted, over ALL points after a full assignment.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch

import gsz
from gsz.encoder.importance import volume_term
from gsz.encoder.vq import assign, train_codebook, weighted_distortion

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("scenes", nargs="*", default=[str(SHARED / "flowers_daffodils_sh2.ply"),
                                                 str(SHARED / "measuring_jug_sh3.ply")])
    ap.add_argument("--K", default="4096")
    ap.add_argument("--iters", default="0,50,100,200")
    ap.add_argument("--batch", default="16384")
    ap.add_argument("--lloyd", default="0,2")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    print(f"torch threads {torch.get_num_threads()}")
    print("| scene | N | D | K | iters | batch | lloyd | train s | assign s | weighted MSE | "
          "random-cb MSE |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for path in args.scenes:
        cloud = gsz.read_ply(path)
        x = cloud.sh_rest.reshape(len(cloud), -1)
        w = volume_term(cloud) / (1 + np.exp(-cloud.opacities.astype(np.float64)))
        for k in map(int, args.K.split(",")):
            rng = np.random.default_rng(1)
            rand_cb = x[rng.choice(len(x), size=k, replace=False)]
            rand_mse = weighted_distortion(x, w, rand_cb)
            for iters in map(int, args.iters.split(",")):
                for batch in map(int, args.batch.split(",")):
                    for lloyd in map(int, args.lloyd.split(",")):
                        t0 = time.perf_counter()
                        cb = train_codebook(x, w, k, iters=iters, batch=batch, lloyd=lloyd,
                                            seed=args.seed)
                        t1 = time.perf_counter()
                        idx = assign(x, cb)
                        t2 = time.perf_counter()
                        mse = weighted_distortion(x, w, cb, idx)
                        print(f"| {Path(path).stem} | {len(x)} | {x.shape[1]} | {k} | {iters} | "
                              f"{batch} | {lloyd} | {t1 - t0:.2f} | {t2 - t1:.2f} | {mse:.5f} | "
                              f"{rand_mse:.5f} |", flush=True)


if __name__ == "__main__":
    main()
