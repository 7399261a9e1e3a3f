"""Probe: would a colour-decorrelating transform of the SH rest pay?  (Not in the format.)

    .venv/bin/python bench/bench_colour_probe.py SCENE.ply --size BYTES [--noise]
        [--out bench/out/colour_probe.json]

Each SH rest coefficient's (R, G, B) triplet is highly correlated in real captures (a view-
dependent change is mostly a change of brightness).  The probe encodes, with the size search
at ``--size`` bytes:

* ``rgb``: the scene as it is (what gsz-encode does today);
* ``ycc``: the scene with every SH rest triplet rotated by the fixed orthonormal luma/chroma
  matrix below, then the decoded file's SH rest rotated back (its transpose) -- what a decoder
  would do if the format carried the transform.  Orthonormal, so the search's squared errors,
  its VQ distances and the rendered error's size are those of the RGB values; the renders the
  search compares are of the rotated colours (a close stand-in: SH evaluation is linear per
  channel, only the clamp at 0 differs).

Both are scored with gsz-eval's protocol against the scene (8 default test views at 800 px).
Also printed: the zeroth-order entropy of the SH rest quantised at a few uniform steps, per
vector, in both spaces (what the transform can save before any search choice).  ``--noise``:
the RD bench's noised variant (bench_codec.add_noise), which is then the reference.  Results
accumulate in the JSON, one row per (scene, noised, size).
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(Path(__file__).resolve().parent))
from rd import gsz_source, machine  # noqa: E402

#: rows: luma (R+G+B)/sqrt3, (R-G)/sqrt2, (R+G-2B)/sqrt6
LUMA_CHROMA = np.array([[1, 1, 1], [1, -1, 0], [1, 1, -2]], np.float64)
LUMA_CHROMA /= np.linalg.norm(LUMA_CHROMA, axis=1, keepdims=True)
ENTROPY_STEPS = (0.005, 0.01, 0.02, 0.04)


def rotated(cloud, matrix: np.ndarray):
    """The cloud with each SH rest triplet x replaced by matrix @ x (float64, then float32)."""
    sh = np.asarray(cloud.sh_rest, np.float64) @ matrix.T
    return dataclasses.replace(cloud, sh_rest=sh.astype(np.float32))


def entropy_bits(sh: np.ndarray, step: float) -> float:
    """Zeroth-order entropy (bits per vector) of [N, K, 3] values rounded to multiples of step,
    summed over the 3K components."""
    total = 0.0
    for col in sh.reshape(sh.shape[0], -1).T:
        _, counts = np.unique(np.rint(col / step), return_counts=True)
        p = counts / counts.sum()
        total -= float((p * np.log2(p)).sum())
    return total


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("scene")
    p.add_argument("--size", type=int, required=True)
    p.add_argument("--noise", action="store_true")
    p.add_argument("--out", type=Path, default=ROOT / "bench" / "out" / "colour_probe.json")
    a = p.parse_args(argv)
    import gsz
    from gsz.decoder import decode, read_ply, write_ply
    from gsz.encoder.cli import main as encode_main
    from gsz.evaluation.cameras import load_cameras
    from gsz.evaluation.evaluate import evaluate, render_views

    scene = read_ply(a.scene)
    if a.noise:
        from bench_codec import add_noise
        scene = add_noise(scene)
    if not scene.sh_degree:
        p.error(f"{a.scene}: no SH rest to transform (SH degree 0)")
    row = {"scene": Path(a.scene).stem, "noised": a.noise, "size": a.size, "gaussians": len(scene)}
    sh = np.asarray(scene.sh_rest, np.float64)
    ycc = sh @ LUMA_CHROMA.T
    row["entropy"] = [{"step": s, "rgb_bits": round(entropy_bits(sh, s), 1),
                       "ycc_bits": round(entropy_bits(ycc, s), 1)} for s in ENTROPY_STEPS]
    for e in row["entropy"]:
        print(f"step {e['step']}: {e['rgb_bits']} -> {e['ycc_bits']} bits a vector", file=sys.stderr)
    cams = load_cameras(None, scene, n_test=8).test
    refs = render_views(scene, cams)
    with tempfile.TemporaryDirectory(prefix="gsz-colour-") as tmp:
        for space, src in (("rgb", scene), ("ycc", rotated(scene, LUMA_CHROMA))):
            ply, out = Path(tmp) / f"{space}.ply", Path(tmp) / f"{space}.gsz"
            write_ply(src, ply)
            print(f"{space}: encoding to {a.size:,} B", file=sys.stderr, flush=True)
            if encode_main([str(ply), "-o", str(out), "--size", str(a.size), "-q"]):
                raise SystemExit(f"gsz-encode failed on the {space} scene")
            dec = decode(str(out))
            if space == "ycc":
                dec = rotated(dec, LUMA_CHROMA.T)
            res = evaluate(refs, dec, cams)
            row[space] = {"bytes": out.stat().st_size, "psnr": round(res["psnr"], 2), "ssim": round(res["ssim"], 5)}
            print(f"{space}: {row[space]['bytes']:,} B, {res['psnr']:.2f} dB", file=sys.stderr, flush=True)
    row["gain_db"] = round(row["ycc"]["psnr"] - row["rgb"]["psnr"], 2)
    row.update(commit=(gsz_source(gsz).get("commit") or "")[:7] or None, machine=machine(),
               when=time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
               command="bench/bench_colour_probe.py " + " ".join(argv if argv is not None else sys.argv[1:]))
    rows = json.loads(a.out.read_text())["rows"] if a.out.exists() else []
    rows = [r for r in rows if (r["scene"], r["noised"], r["size"]) != (row["scene"], a.noise, a.size)] + [row]
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps({"rows": rows}, indent=1) + "\n")
    print("| scene | noised | budget B | RGB dB | luma/chroma dB | gain dB |\n|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['scene']} | {'yes' if r['noised'] else 'no'} | {r['size']:,} | {r['rgb']['psnr']:.2f} | "
              f"{r['ycc']['psnr']:.2f} | {r['gain_db']:+.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
