"""Which attribute group costs the fidelity: the original with exactly one group replaced by the
decoded file's values, rendered against the original (gsz-eval's protocol).

    .venv/bin/python bench/bench_attribution.py ORIGINAL.ply COMPRESSED.gsz [--views 8] [--width 800]
        [--out bench/out/attribution_<scene>.json]

Decoded Gaussians are matched to original ones by position (the nearest original Gaussian of
each decoded one; where several decoded Gaussians pick the same original, the first in decoded
order wins); the original's unmatched (pruned or merged) Gaussians keep their values, so each
row isolates one group's quantisation: positions, scales, rotations, opacities, DC colour, the
higher SH as a whole and per degree band.  ``pruning`` replaces nothing but drops the unmatched
Gaussians (what pruning and merging alone cost).  The lowest PSNR row is the weakest group.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent


def match(original, decoded) -> tuple[np.ndarray, np.ndarray]:
    """(original index, decoded index) pairs, one per matched original Gaussian."""
    from scipy.spatial import cKDTree
    _, nearest = cKDTree(original.positions.astype(np.float64)).query(decoded.positions.astype(np.float64))
    orig_idx, first = np.unique(nearest, return_index=True)
    return orig_idx, first


def replaced(original, decoded, oi, di, group: str):
    """The original with ``group`` of the matched Gaussians taken from the decoded cloud."""
    if group == "pruning":
        return original.subset(oi)
    if group.startswith("sh_band"):
        band = int(group[-1])
        lo, hi = band * band - 1, (band + 1) ** 2 - 1            # rows of f_rest for that band
        rest = original.sh_rest.copy()
        rest[oi, lo:hi] = decoded.sh_rest[di, lo:hi]
        return dataclasses.replace(original, sh_rest=rest)
    values = getattr(original, group).copy()
    values[oi] = getattr(decoded, group)[di]
    return dataclasses.replace(original, **{group: values})


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("original")
    p.add_argument("compressed")
    p.add_argument("--views", type=int, default=8)
    p.add_argument("--width", type=int, default=None)
    p.add_argument("--out", type=Path, default=None)
    a = p.parse_args(argv)
    from gsz.decoder import decode, read_ply
    from gsz.evaluation.cameras import load_cameras
    from gsz.evaluation.evaluate import evaluate, render_views

    original, decoded = read_ply(a.original), decode(a.compressed)
    # the file holds each Gaussian's nearest-identity form (its axes relabelled, the scales
    # permuted with them): the original in that form is the same scene, and only then do its
    # rotations and scales replace one at a time
    from gsz.encoder.orientation import canonical_orientations
    rot, scales = canonical_orientations(original.rotations, original.scales)
    original = dataclasses.replace(original, rotations=rot, scales=scales)
    if decoded.sh_degree < original.sh_degree:
        decoded = decoded.with_sh_degree(original.sh_degree)
    oi, di = match(original, decoded)
    cams = load_cameras(None, original, n_test=a.views, width=a.width).test
    refs = render_views(original, cams)
    groups = ["pruning", "positions", "scales", "rotations", "opacities", "sh_dc"]
    if original.sh_degree:
        groups += ["sh_rest"] + [f"sh_band{b}" for b in range(1, original.sh_degree + 1)]
    rows = []
    for g in groups:
        res = evaluate(refs, replaced(original, decoded, oi, di, g), cams)
        rows.append({"group": g, "psnr": round(res["psnr"], 2), "ssim": round(res["ssim"], 4)})
        print(f"{g:12s} {res['psnr']:7.2f} dB  SSIM {res['ssim']:.4f}", file=sys.stderr, flush=True)
    full = evaluate(refs, decoded, cams)
    out = {"original": a.original, "compressed": a.compressed, "matched": int(oi.size),
           "original_gaussians": len(original), "decoded_gaussians": len(decoded),
           "whole_file_psnr": round(full["psnr"], 2), "rows": rows,
           "weakest": min((r for r in rows if r["group"] != "pruning"), key=lambda r: r["psnr"])["group"],
           "command": "bench/bench_attribution.py " + " ".join(argv if argv is not None else sys.argv[1:])}
    path = a.out or ROOT / "bench" / "out" / f"attribution_{Path(a.original).stem}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(out, indent=1) + "\n")
    print("| group | PSNR (dB) | SSIM |\n|---|---|---|")
    for r in rows:
        print(f"| {r['group']} | {r['psnr']:.2f} | {r['ssim']:.4f} |")
    print(f"| whole file | {out['whole_file_psnr']:.2f} | |\n\nweakest group: {out['weakest']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
