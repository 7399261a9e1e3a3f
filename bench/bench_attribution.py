"""Which attribute group costs the fidelity: the original with exactly one group replaced by the
decoded file's values, rendered against the original (gsz-eval's protocol).

    .venv/bin/python bench/bench_attribution.py ORIGINAL.ply COMPRESSED.gsz [--views 8] [--width 800]
        [--out bench/out/attribution_<scene>.json]
    .venv/bin/python bench/bench_attribution.py ORIGINAL.ply OUT.gsz --size BYTES [--noise]
        (encodes OUT.gsz first, as ``gsz-encode --size BYTES`` would; ``--noise``: of the
        original with bench_codec.add_noise, the RD bench's noised variant, which is then also
        the reference)

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
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(Path(__file__).resolve().parent))
from rd import gsz_source, machine  # noqa: E402


def _attribute_rows(cloud, idx: np.ndarray) -> np.ndarray:
    """[len(idx), 7] opacity, DC colour and log-scales: what tells exact twins apart."""
    return np.concatenate([cloud.opacities[idx].reshape(len(idx), -1), cloud.sh_dc[idx].reshape(len(idx), -1),
                           np.sort(cloud.scales[idx], axis=1)], axis=1).astype(np.float64)


def match(original, decoded) -> tuple[np.ndarray, np.ndarray]:
    """(original index, decoded index) pairs, one per matched original Gaussian.  Original
    Gaussians at one position (exact twins, which the encoder may keep in neighbouring voxels)
    are matched to the decoded Gaussians that chose that position by their attributes, nearest
    pairs first; everywhere else the first decoded Gaussian to pick an original wins."""
    from scipy.spatial import cKDTree
    _, nearest = cKDTree(original.positions.astype(np.float64)).query(decoded.positions.astype(np.float64))
    _, spot, twins = np.unique(original.positions, axis=0, return_inverse=True, return_counts=True)
    spot = spot.reshape(-1)
    shared = twins[spot[nearest]] > 1
    orig_idx, first = np.unique(nearest[~shared], return_index=True)
    first = np.flatnonzero(~shared)[first]
    pairs_o, pairs_d = [orig_idx], [first]
    dec = np.flatnonzero(shared)
    if dec.size:
        groups = spot[nearest[dec]]
        order = np.argsort(groups, kind="stable")
        members = np.argsort(spot, kind="stable")
        starts = np.searchsorted(spot[members], np.arange(twins.size + 1))
        for g in np.unique(groups):
            d = dec[order][groups[order] == g]
            o = members[starts[g]:starts[g + 1]]
            cost = np.linalg.norm(_attribute_rows(decoded, d)[:, None] - _attribute_rows(original, o)[None], axis=2)
            for flat in np.argsort(cost, axis=None, kind="stable"):
                i, j = divmod(int(flat), o.size)
                if np.isfinite(cost[i, j]):
                    pairs_o.append(o[j:j + 1])
                    pairs_d.append(d[i:i + 1])
                    cost[i, :] = np.inf
                    cost[:, j] = np.inf
    oi, di = np.concatenate(pairs_o), np.concatenate(pairs_d)
    keep = np.argsort(oi, kind="stable")
    return oi[keep], di[keep]


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


def encode_first(original: str, out: str, size: int, noise: bool) -> str:
    """Encode ``out`` from ``original`` (noised first with ``noise``) as ``gsz-encode --size``
    does; the PLY the file was encoded from (the reference the groups are measured against)."""
    from gsz.decoder import read_ply, write_ply
    from gsz.encoder.cli import main as encode_main
    src = original
    if noise:
        from bench_codec import add_noise
        src = str(Path(out).with_suffix("")) + "_noised.ply"
        write_ply(add_noise(read_ply(original)), src)
    print(f"encoding {src} to {size:,} B -> {out}", file=sys.stderr, flush=True)
    rc = encode_main([src, "-o", out, "--size", str(size), "-q"])
    if rc:
        raise SystemExit(f"gsz-encode failed ({rc}) on {src}")
    return src


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("original")
    p.add_argument("compressed")
    p.add_argument("--views", type=int, default=8)
    p.add_argument("--width", type=int, default=None)
    p.add_argument("--out", type=Path, default=None)
    p.add_argument("--size", type=int, default=None, help="encode COMPRESSED first, to this many bytes")
    p.add_argument("--noise", action="store_true", help="with --size: of the noised original (bench_codec)")
    a = p.parse_args(argv)
    import gsz
    from gsz.decoder import decode, read_ply
    if a.noise and a.size is None:
        p.error("--noise goes with --size (the file is encoded from the noised original)")
    original_path = a.original
    if a.size is not None:
        original_path = encode_first(a.original, a.compressed, a.size, a.noise)
    from gsz.evaluation.cameras import load_cameras
    from gsz.evaluation.evaluate import evaluate, render_views

    original, decoded = read_ply(original_path), decode(a.compressed)
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
           "command": "bench/bench_attribution.py " + " ".join(argv if argv is not None else sys.argv[1:]),
           "commit": (gsz_source(gsz).get("commit") or "")[:7] or None, "machine": machine(),
           "when": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), "noised": a.noise, "size": a.size,
           "bytes": Path(a.compressed).stat().st_size}
    stem = Path(a.original).stem + ("_noised" if a.noise else "")
    path = a.out or ROOT / "bench" / "out" / f"attribution_{stem}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(out, indent=1) + "\n")
    print("| group | PSNR (dB) | SSIM |\n|---|---|---|")
    for r in rows:
        print(f"| {r['group']} | {r['psnr']:.2f} | {r['ssim']:.4f} |")
    print(f"| whole file | {out['whole_file_psnr']:.2f} | |\n\nweakest group: {out['weakest']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
