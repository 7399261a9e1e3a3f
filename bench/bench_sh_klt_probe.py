"""Probe: would a per-file KLT (principal axes) of the SH rest pay in gsz's scalar SH path?

    .venv/bin/python bench/bench_sh_klt_probe.py ../shared/data/tiny_graphdeco_iter7000_sh3.ply [--noise]

Outside the codec and without rendering: the SH rest of every Gaussian as one vector of D = 3K
values in the codec's luma/chroma space (``encoder.sh_colour``), and the same vectors turned by
the eigenvectors of their covariance (an orthonormal D x D matrix, so squared errors are the
same in both spaces).  For each space the codec's own tables -- ``kernels.quantize.
quantize_all_bits`` (SSE of every (component, block) group at 1-16 bits), the constant group's
SSE (width 0) and ``encoder.rate.rate_matrix`` (its entropy-coded bits) -- go to the size
search's allocator (``bit_allocation.allocate``, fast) at several budgets in bits a vector.
Prints, per budget, the SH rest's SNR (dB, signal = its own power) in both spaces, and the bits a
vector the KLT needs for luma/chroma's SNR (interpolated).  Vectors in file order, blocks as the
codec's kept sets (one per 128 vectors, at most 80).  Importance is not used (every Gaussian
weighs the same), the KLT matrix's own bytes (D^2 float32) are not counted, nor is what the
decoder's inverse would cost: a screen, not the codec.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "bench"))


def tables(x: np.ndarray, blocks: int):
    """(loss [D*B, 17], rate [D*B, 17]) of x [D, N]: width 0 (the group's mean) then 1..16 bits."""
    from gsz.encoder.groups import constant_sse
    from gsz.encoder.rate import rate_matrix
    from gsz.kernels.quantize import quantize_all_bits
    x = np.ascontiguousarray(x, np.float32)
    loss = quantize_all_bits(x, blocks)[3]
    rate = rate_matrix(x, blocks, (1, 16))
    const = constant_sse(x, blocks)
    d, b = loss.shape[:2]
    loss = np.concatenate([const[:, :, None], loss], axis=2).reshape(d * b, 17)
    rate = np.concatenate([np.zeros((d, b, 1)), rate], axis=2).reshape(d * b, 17)
    return loss, rate


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("scene", type=Path)
    p.add_argument("--noise", action="store_true", help="bench_codec's noise first (the RD bench's noised variant)")
    p.add_argument("--bits", default="10,20,40,60,90,130,180", help="budgets, bits a vector")
    p.add_argument("--sample", type=int, default=0,
                   help="evenly spaced Gaussians only (the size of a per-file decision's sample)")
    p.add_argument("--out", type=Path, help="append the result as a JSON line")
    a = p.parse_args(argv)
    from gsz.encoder.bit_allocation import allocate
    from gsz.decoder.ply import read_ply
    from gsz.encoder.sh_colour import _FORWARD
    cloud = read_ply(a.scene)
    if a.noise:
        from bench_codec import add_noise
        cloud = add_noise(cloud)
    sh = np.asarray(cloud.sh_rest, np.float64)
    if a.sample and a.sample < sh.shape[0]:
        sh = sh[np.linspace(0, sh.shape[0] - 1, a.sample).astype(np.int64)]
    n, k, _ = sh.shape
    if k == 0:
        raise SystemExit(f"{a.scene}: no SH rest")
    lc = (sh @ _FORWARD.T).reshape(n, 3 * k)             # the codec's luma/chroma space
    cov = np.cov(lc.T)
    _, vec = np.linalg.eigh(cov)
    klt = lc @ vec[:, ::-1]                               # largest variance first
    blocks = max(1, min(80, n // 128))
    power = float((lc ** 2).sum())
    budgets = [float(b) for b in a.bits.split(",")]
    res = {}
    for name, x in (("luma-chroma", lc), ("klt", klt)):
        loss, rate = tables(x.T, blocks)
        rows = []
        for b in budgets:
            pick = allocate(loss, rate, b * n, method="fast")
            sse = float(loss[np.arange(len(pick)), pick].sum())
            rows.append(10 * np.log10(power / max(sse, 1e-30)))
        res[name] = rows
    # bits a vector the KLT needs for each luma/chroma SNR (log-linear between its points)
    need = []
    for snr in res["luma-chroma"]:
        kb = np.interp(snr, res["klt"], np.log(budgets), left=np.nan, right=np.nan)
        need.append(float(np.exp(kb)))
    print(f"{a.scene.name}{' noised' if a.noise else ''}: {n:,} Gaussians{' (sample)' if a.sample else ''}, "
          f"D {3 * k}, {blocks} blocks")
    print("| bits/vector | luma/chroma SNR dB | KLT SNR dB | gain dB | KLT bits for luma/chroma's SNR |")
    print("|---|---|---|---|---|")
    for b, s0, s1, nb in zip(budgets, res["luma-chroma"], res["klt"], need):
        print(f"| {b:g} | {s0:.2f} | {s1:.2f} | {s1 - s0:+.2f} | {nb:.1f} ({nb / b:.2f}x) |")
    if a.out:
        with open(a.out, "a") as f:
            f.write(json.dumps({"scene": a.scene.stem, "noise": a.noise, "gaussians": n, "sample": bool(a.sample), "dims": 3 * k,
                                "bits_per_vector": budgets, **res, "klt_bits_for_same_snr": need}) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
