"""Benchmark of the native SH assembly of kept vectors (``_native.sh_assemble``), with and without
the KLT turn (SHXF bit 2), by each product the CPU has (``_native.klt_simd`` levels: portable,
AVX2/FMA, AVX-512), and with the kept vectors as residuals of a 4,096-word codebook (SHRF), in
point order and in 8 interleaved importance classes (SHCL: the rows scatter).

    .venv/bin/python bench/bench_sh_assemble.py [--n 1200000] [--repeat 7]

Data: N vectors of D = 9, 24 and 45 components (SH degrees 1-3) every one kept, 80 blocks,
uint16 symbols below 1024 and a random integer matrix (the speed depends on neither's values).
Prints best-of---repeat wall seconds of the whole call: RGB (no turn), KLT by each product level
the CPU has ("-" where it lacks one; at D = 9 the AVX-512 level runs the AVX2 loop), and the turn's share (KLT by the widest minus RGB); then
RGB and KLT (widest) with every vector's codeword added (SHRF: what a refined file pays for its
codewords), and the same in 8 classes (a refined file's layout).  What the decode of a
scalar-path or refined file pays for its KLT.
"""
from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from gsz.decoder import native


def best(fn, repeat: int) -> float:
    out = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t)
    return min(out)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--n", type=int, default=1_200_000, help="kept vectors")
    p.add_argument("--repeat", type=int, default=7)
    a = p.parse_args(argv)
    if not native.enabled():
        print("native accelerator not built: nothing to measure", file=sys.stderr)
        return 1
    mod = native.module()
    rng = np.random.default_rng(0)
    print(f"{a.n:,} kept vectors, 80 blocks, best of {a.repeat}")
    levels = ("portable", "AVX2", "AVX-512")
    print("| D | RGB s | " + " | ".join(f"KLT {n} s" for n in levels)
          + " | turn s | RGB + codewords s | KLT + codewords s | KLT + codewords, 8 classes s |")
    print("|---|---|" + "---|" * len(levels) + "---|---|---|---|")
    was = mod.klt_simd(None)
    try:
        for d in (9, 24, 45):
            flags = np.ones(a.n, np.int64)
            kept = rng.integers(0, 1024, (d, a.n)).astype(np.uint16)
            steps, lo = rng.uniform(1e-4, 3e-3, (d, 80)), rng.uniform(-1.5, -0.5, (d, 80))
            cb, idx = np.zeros((d, 1)), np.zeros(0, np.int64)
            klt = rng.integers(-(1 << 14), 1 << 14, (d, d)).astype(np.float64)
            out = np.empty((a.n, d), np.float32)

            words = rng.normal(0, 0.1, (d, 4096))
            refine = rng.integers(0, 4096, a.n).astype(np.int64)
            classes = (np.arange(a.n) % 8).astype(np.int64)

            def run(m, book=cb, r=None, c=None):
                return lambda: mod.sh_assemble(flags, kept, steps, lo, idx, book, out, c, 0, m, r)
            rgb = best(run(None), a.repeat)
            times = []
            for level in range(len(levels)):
                mod.klt_simd(level)
                times.append(best(run(klt), a.repeat) if mod.klt_simd(None) == level else None)
            mod.klt_simd(True)
            rgb_ref = best(run(None, words, refine), a.repeat)
            klt_ref = best(run(klt, words, refine), a.repeat)
            klt_cls = best(run(klt, words, refine, classes), a.repeat)
            mod.klt_simd(was)
            widest = [t for t in times if t is not None][-1]
            print(f"| {d} | {rgb:.3f} | " + " | ".join("-" if t is None else f"{t:.3f}" for t in times)
                  + f" | {widest - rgb:.3f} | {rgb_ref:.3f} | {klt_ref:.3f} | {klt_cls:.3f} |")
    finally:
        mod.klt_simd(was)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
