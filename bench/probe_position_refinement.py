"""Probe for issue 18's high-rate gap (docs/design/high-rate-gap.md): what would refinement bits
under the octree's voxel centres buy, spent on the most important Gaussians?

    .venv/bin/python bench/probe_position_refinement.py ORIGINAL.ply FILE.gsz

Outside the codec: the original with the positions of the Gaussians the file kept (matched as
``bench_attribution.py`` does) replaced by the file's voxel centres plus each one's offset to its
original position quantised to q bits an axis (2^q equal cells of the voxel, cell centres;
q = 0: the voxel centre, today's file), every other attribute exact, rendered with gsz-eval's
protocol (8 default test views).  Rows: uniform q for all, for a random share, and by rank of
importance (``compute_importance`` on the 24 default train views) or opacity, with their mean
bits a voxel (uncoded: a uniform offset costs its q bits).  The voxel side is taken from the
offsets' spread (twice the largest), per axis.
"""
from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_attribution import match  # noqa: E402


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) != 2:
        print(__doc__, file=sys.stderr)
        return 2
    from gsz.decoder import decode, read_ply
    from gsz.encoder.importance import compute_importance
    from gsz.evaluation.cameras import load_cameras
    from gsz.evaluation.evaluate import evaluate, render_views
    original, decoded = read_ply(argv[0]), decode(argv[1])
    oi, di = match(original, decoded)
    centres = decoded.positions[di].astype(np.float64)
    off = original.positions[oi].astype(np.float64) - centres
    side = 2 * np.abs(off).max(axis=0)
    print(f"{len(oi):,} of {len(original):,} Gaussians matched; voxel side ~{side.max():.3g}")
    cell = np.clip(off / side + 0.5, 0.0, np.nextafter(1.0, 0.0))
    cams = load_cameras(None, original, n_test=8)
    refs = render_views(original, cams.test)
    rank_imp = np.argsort(np.argsort(-np.asarray(compute_importance(original, cams.train))[oi])) / len(oi)
    opacity = 1.0 / (1.0 + np.exp(-original.opacities[oi].reshape(-1).astype(np.float64)))
    rank_opa = np.argsort(np.argsort(-opacity)) / len(oi)

    def row(name: str, q) -> None:
        q = np.asarray(q, np.int64)
        levels = np.ldexp(1.0, q)[:, None]
        r = np.where(q[:, None] > 0, (np.floor(cell * levels) + 0.5) / levels - 0.5, 0.0)
        pos = original.positions.copy()
        pos[oi] = (centres + r * side).astype(np.float32)
        res = evaluate(refs, dataclasses.replace(original, positions=pos), cams.test)
        print(f"| {name} | {3 * q.mean():.2f} | {res['psnr']:.2f} |", flush=True)

    n = len(oi)
    print("| refinement | bits a voxel | positions-only PSNR (dB) |\n|---|---|---|")
    row("none (voxel centres)", np.zeros(n))
    row("1 bit, every voxel", np.ones(n))
    row("1 bit, a random half", (np.random.default_rng(0).random(n) < 0.5).astype(np.int64))
    row("1 bit, top 50 % importance", (rank_imp < 0.5).astype(np.int64))
    row("2 bits, top 25 % importance", 2 * (rank_imp < 0.25))
    row("2 bits, top 25 % opacity", 2 * (rank_opa < 0.25))
    row("3/2/1 bits, top 12.5/12.5/25 % importance",
        np.select([rank_imp < 0.125, rank_imp < 0.25, rank_imp < 0.5], [3, 2, 1], 0))
    row("2 bits, every voxel", 2 * np.ones(n))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
