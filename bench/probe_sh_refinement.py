"""Whole-render estimate of refining SH codewords with the scalar path (issue 18; docs/design/
high-rate-gap.md), outside the format: at a file's own SH bytes, the SH rest its Gaussians
would get from (a) the scalar path alone, (b) an importance-weighted codebook alone and
(c) a codebook plus the scalar path on the residual (every vector: codeword + refinement) and
(d) a codebook with the most important vectors kept (today's classes path, ``--kept``) and, with
``--bands``, (e) band 1 (or bands 1-2) by the scalar path and the higher bands a codebook, each put into the decoded file in place of its SH and rendered (gsz-eval's protocol, 8 default
test views) against the original.

    .venv/bin/python bench/probe_sh_refinement.py ORIGINAL.ply FILE.gsz [--sizes 64,256,1024,4096]

The targets are the original SH of the Gaussians the file kept (matched as bench_attribution.py
does), in their principal axes (the codec's KLT); the scalar parts use the codec's own group
tables (``bench_sh_klt_probe.tables``: width 0 and 1-16 bits, ``rate_matrix``) with the vectors
in 8 importance classes, one block a class, each block's loss weighted by its mean importance
(as the codec's SHCL classes), and the size search's allocator.  A codebook costs its labels'
entropy plus 8 bits a component (codewords not quantised here: slightly optimistic for (b) and
(c) alike).  The budget is the file's SHVQ + SHCL chunk bytes.  Row "file": the file as it is.
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_attribution import match  # noqa: E402
from bench_sh_klt_probe import tables  # noqa: E402

CLASSES = 8
CODEWORD_BITS = 8


def _entropy_bits(p: float) -> float:
    return 0.0 if p <= 0 or p >= 1 else float(-(p * np.log2(p) + (1 - p) * np.log2(1 - p)))


def _label_bits(idx: np.ndarray, k: int) -> float:
    """Zeroth-order entropy of the labels idx (values below k), in bits for all of them."""
    cnt = np.bincount(idx, minlength=k)
    cnt = cnt[cnt > 0]
    return float(-(cnt * np.log2(cnt / max(idx.size, 1))).sum())


def reconstruct(x: np.ndarray, blocks: int, pick: np.ndarray) -> np.ndarray:
    """x [C, L] quantised group-wise at the picked widths (0: the group's mean; q: the format's
    min-max grid), float64."""
    from gsz.decoder.quant import split_lengths
    out = np.empty_like(x, dtype=np.float64)
    lens = split_lengths(x.shape[1], blocks)
    ends = np.cumsum(lens)
    for c in range(x.shape[0]):
        for b, (s, e) in enumerate(zip((ends - lens).tolist(), ends.tolist())):
            v = x[c, s:e].astype(np.float64)
            q = int(pick[c * blocks + b])
            if v.size == 0:
                continue
            if q == 0:
                out[c, s:e] = np.float32(v.mean())
                continue
            lo, hi = float(np.float32(v.min())), float(np.float32(v.max()))
            step = (hi - lo) / (2 ** q - 1) if hi > lo else 1.0
            out[c, s:e] = lo + step * np.clip(np.rint((v - lo) / step), 0, 2 ** q - 1)
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("original")
    p.add_argument("file")
    p.add_argument("--sizes", default="64,256,1024,4096", help="codebook sizes")
    p.add_argument("--bands", action="store_true",
                   help="also the low band(s) by the scalar path and the higher bands a codebook")
    p.add_argument("--kept", default="0.1,0.25,0.5",
                   help="shares of the most important vectors kept beside a codebook (the classes path)")
    a = p.parse_args(argv)
    a.kept = [float(v) for v in a.kept.split(",") if v.strip()]
    from gsz.decoder import decode, read_ply
    from gsz.decoder.container import read_container
    from gsz.encoder.bit_allocation import allocate
    from gsz.encoder.importance import compute_importance
    from gsz.encoder.vq import assign, train_codebook
    from gsz.evaluation.cameras import load_cameras
    from gsz.evaluation.evaluate import evaluate, render_views

    original, decoded = read_ply(a.original), decode(a.file)
    if not original.sh_degree or decoded.sh_degree != original.sh_degree:
        raise SystemExit(f"{a.file}: needs the original's SH degree (file {decoded.sh_degree})")
    data = Path(a.file).read_bytes()
    budget = 8.0 * sum(len(ch.data) for ch in read_container(data).chunks if ch.type in (b"SHVQ", b"SHCL"))
    oi, di = match(original, decoded)
    n = len(oi)
    kk = original.sh_rest.shape[1]
    rgb = np.asarray(original.sh_rest[oi], np.float64).reshape(n, -1)
    mean = rgb.mean(axis=0)
    _, axes = np.linalg.eigh(np.cov(rgb.T))
    axes = axes[:, ::-1]
    cams = load_cameras(None, original, n_test=8)
    imp = np.asarray(compute_importance(original, cams.train), np.float64)[oi]
    order = np.argsort(-imp, kind="stable")          # importance classes, one block each
    x = ((rgb - mean) @ axes)[order]                 # [n, D] in class order
    refs = render_views(original, cams.test)
    print(f"{n:,} Gaussians matched; SH budget {budget / 8:,.0f} B = {budget / n:.1f} bits a vector")

    def scalar(v: np.ndarray, bits: float):
        """The scalar path on v, the first len(v) vectors in importance order: its classes are
        blocks of them, each block's loss weighted by its mean importance."""
        loss, rate = tables(np.ascontiguousarray(v.T), CLASSES)
        ranked = imp[order][:len(v)]
        w = np.array([ranked[c * len(v) // CLASSES:(c + 1) * len(v) // CLASSES].mean()
                      for c in range(CLASSES)]) / max(imp.mean(), 1e-30)
        loss = loss * np.tile(w, v.shape[1])[:, None]
        pick = allocate(loss, rate, bits, method="fast")
        return reconstruct(np.ascontiguousarray(v.T), CLASSES, pick).T

    def codebook(v: np.ndarray, k: int):
        """(codewords of v's rows, labels, their cost in bits: labels' entropy + codewords)."""
        cb = np.asarray(train_codebook(v.astype(np.float32), imp[order], k, seed=0), np.float64)
        idx = np.asarray(assign(v.astype(np.float32), cb.astype(np.float32)))
        return cb, idx, _label_bits(idx, k) + k * v.shape[1] * CODEWORD_BITS

    def row(name: str, xhat: np.ndarray, bits: float) -> None:
        back = np.empty_like(xhat)
        back[order] = xhat
        sh = decoded.sh_rest.copy()
        sh[di] = (back @ axes.T + mean).astype(np.float32).reshape(n, kk, 3)
        res = evaluate(refs, dataclasses.replace(decoded, sh_rest=sh), cams.test)
        snr = 10 * np.log10(float((x ** 2).sum()) / max(float(((x - xhat) ** 2).sum()), 1e-30))
        print(f"| {name} | {bits / n:.1f} | {snr:.2f} | {res['psnr']:.2f} |", flush=True)

    print("| SH coding | bits a vector | SH SNR (dB) | test PSNR (dB) |\n|---|---|---|---|")
    res = evaluate(refs, decoded, cams.test)
    print(f"| file | {budget / n:.1f} | – | {res['psnr']:.2f} |", flush=True)
    row("scalar path", scalar(x, budget), budget)
    for k in [int(s) for s in a.sizes.split(",")]:
        cb, idx, cost = codebook(x, k)
        if cost <= budget:
            row(f"codebook {k}", cb[idx], cost)
            if budget - cost > 0:
                row(f"codebook {k} + scalar residual", cb[idx] + scalar(x - cb[idx], budget - cost), budget)
            for share in a.kept:
                # today's classes path: the most important share kept (the scalar path on their
                # own vectors), the rest codewords; labels of the rest and a flag a vector paid
                top = int(round(share * n))
                paid = _label_bits(idx[top:], k) + k * x.shape[1] * CODEWORD_BITS + n * _entropy_bits(share)
                if 0 < top and paid < budget:
                    xhat = cb[idx].copy()
                    xhat[:top] = scalar(x[:top], budget - paid)
                    row(f"codebook {k} + top {100 * share:g} % kept (classes path)", xhat, budget)
        else:
            print(f"| codebook {k} | {cost / n:.1f} (over the budget) | | |")
    if a.bands:
        # issue 18's per-band choice: the low band(s) by the scalar path (in their own
        # principal axes), the higher bands a codebook
        src = rgb[order]
        for split, name in ((9, "band 1"), (24, "bands 1-2")):
            if split >= src.shape[1]:
                continue
            low, high = src[:, :split], src[:, split:]
            mu = low.mean(axis=0)
            _, ax = np.linalg.eigh(np.cov(low.T))
            ax = ax[:, ::-1]
            for k in [int(v) for v in a.sizes.split(",")]:
                cb, idx, cost = codebook(high, k)
                if cost >= budget:
                    continue
                low_hat = scalar((low - mu) @ ax, budget - cost) @ ax.T + mu
                rgb_hat = np.concatenate([low_hat, cb[idx]], axis=1)
                row(f"{name} scalar path + codebook {k} on the higher bands", (rgb_hat - mean) @ axes, budget)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
