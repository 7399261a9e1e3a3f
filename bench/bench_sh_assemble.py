"""Benchmark of the native SH assembly of kept vectors (``_native.sh_assemble``), with and without
the KLT turn (SHXF bit 2), by the AVX2/FMA product and the portable one (``_native.klt_simd``), and
with the kept vectors as residuals of a 4,096-word codebook (SHRF).

    .venv/bin/python bench/bench_sh_assemble.py [--n 1200000] [--repeat 7]

Data: N vectors of D = 9, 24 and 45 components (SH degrees 1-3) every one kept, 80 blocks,
uint16 symbols below 1024 and a random integer matrix (the speed depends on neither's values).
Prints best-of---repeat wall seconds of the whole call: RGB (no turn), KLT by each product, and
the turn's share (KLT minus RGB); then RGB and KLT (AVX2) with every vector's codeword added
(SHRF: what a refined file pays for its codewords).  What the decode of a scalar-path file pays
for its KLT.
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
    print("| D | RGB s | KLT AVX2 s | KLT portable s | turn (AVX2) s | turn (portable) s | RGB + codewords s | KLT + codewords s |")
    print("|---|---|---|---|---|---|---|---|")
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

            def run(m, book=cb, r=None):
                return lambda: mod.sh_assemble(flags, kept, steps, lo, idx, book, out, None, 0, m, r)
            rgb = best(run(None), a.repeat)
            mod.klt_simd(True)
            fast = best(run(klt), a.repeat) if mod.klt_simd(None) else float("nan")
            mod.klt_simd(False)
            port = best(run(klt), a.repeat)
            mod.klt_simd(was)
            rgb_ref = best(run(None, words, refine), a.repeat)
            klt_ref = best(run(klt, words, refine), a.repeat)
            print(f"| {d} | {rgb:.3f} | {fast:.3f} | {port:.3f} | {fast - rgb:.3f} | {port - rgb:.3f} "
                  f"| {rgb_ref:.3f} | {klt_ref:.3f} |")
    finally:
        mod.klt_simd(was)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
