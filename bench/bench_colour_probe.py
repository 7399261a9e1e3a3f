"""The SH colour transform (SHXF, format 1.6) against RGB at one budget, both through gsz-encode.

    .venv/bin/python bench/bench_colour_probe.py SCENE.ply --size BYTES [--noise]
        [--out bench/out/colour_probe.json]

Each SH rest coefficient's (R, G, B) triplet is highly correlated in real captures (a view-
dependent change is mostly a change of brightness).  The probe encodes, with the size search
at ``--size`` bytes:

* ``rgb``: ``gsz-encode --sh-colour rgb`` (every SH rest coefficient as R, G, B);
* ``ycc``: ``gsz-encode --sh-colour luma-chroma``: every SH rest triplet rotated by the fixed
  orthonormal luma/chroma matrix (:mod:`gsz.encoder.sh_colour`), the decoder turning it back.
  (Before the format carried it, this probe rotated the scene outside the codec; the rows
  since then come from the codec itself.  Since format 1.7 ``luma-chroma`` also turns the DC
  colour and ``rgb`` does not: bench_dc_colour_probe.py measures the DC alone.)

Both are scored with gsz-eval's protocol against the scene (8 default test views at 800 px).
Also printed: the zeroth-order entropy of the SH rest quantised at a few uniform steps, per
vector, in both spaces (what the transform can save before any search choice).  ``--noise``:
the RD bench's noised variant (bench_codec.add_noise), which is then the reference.  Results
accumulate in the JSON, one row per (scene, noised, size); ``auto`` says which of the two
``--sh-colour auto`` picks for the scene.
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(Path(__file__).resolve().parent))
from rd import gsz_source, machine  # noqa: E402

ENTROPY_STEPS = (0.005, 0.01, 0.02, 0.04)


def probe_scene(path: str, noise: bool):
    """(scene, test cameras, their reference renders): the scene read (with the RD bench's noise
    when ``noise``) and gsz-eval's 8 default test views -- what both colour probes score on."""
    from gsz.decoder import read_ply
    from gsz.evaluation.cameras import load_cameras
    from gsz.evaluation.evaluate import render_views
    scene = read_ply(path)
    if noise:
        from bench_codec import add_noise
        scene = add_noise(scene)
    cams = load_cameras(None, scene, n_test=8).test
    return scene, cams, render_views(scene, cams)


def keep_row(out: Path, row: dict, script: str, argv) -> list:
    """Stamp ``row`` (commit, machine, time, the command) and write it into ``out``'s rows in
    place of an earlier row of the same (scene, noised, size); returns every row."""
    import gsz
    row.update(commit=(gsz_source(gsz).get("commit") or "")[:7] or None, machine=machine(),
               when=time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
               command=f"bench/{script} " + " ".join(argv if argv is not None else sys.argv[1:]))
    rows = json.loads(out.read_text())["rows"] if out.exists() else []
    key = (row["scene"], row["noised"], row["size"])
    rows = [r for r in rows if (r["scene"], r["noised"], r["size"]) != key] + [row]
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"rows": rows}, indent=1) + "\n")
    return rows


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
    from gsz.decoder import decode, write_ply
    from gsz.encoder.cli import main as encode_main
    from gsz.evaluation.evaluate import evaluate

    scene, cams, refs = probe_scene(a.scene, a.noise)
    if not scene.sh_degree:
        p.error(f"{a.scene}: no SH rest to transform (SH degree 0)")
    row = {"scene": Path(a.scene).stem, "noised": a.noise, "size": a.size, "gaussians": len(scene)}
    sh = np.asarray(scene.sh_rest, np.float64)
    from gsz.encoder.sh_colour import rgb_to_luma_chroma
    ycc = rgb_to_luma_chroma(scene.sh_rest).astype(np.float64)
    row["entropy"] = [{"step": s, "rgb_bits": round(entropy_bits(sh, s), 1),
                       "ycc_bits": round(entropy_bits(ycc, s), 1)} for s in ENTROPY_STEPS]
    for e in row["entropy"]:
        print(f"step {e['step']}: {e['rgb_bits']} -> {e['ycc_bits']} bits a vector", file=sys.stderr)
    from gsz.decoder.sh import SH_COLOUR_LUMA_CHROMA
    from gsz.encoder.sh_colour import choose_sh_colour
    row["auto"] = "ycc" if choose_sh_colour(scene) & SH_COLOUR_LUMA_CHROMA else "rgb"     # the SH rest's
    with tempfile.TemporaryDirectory(prefix="gsz-colour-") as tmp:
        ply = Path(tmp) / "scene.ply"
        write_ply(scene, ply)
        for space, flag in (("rgb", "rgb"), ("ycc", "luma-chroma")):
            out = Path(tmp) / f"{space}.gsz"
            print(f"{space}: encoding to {a.size:,} B", file=sys.stderr, flush=True)
            if encode_main([str(ply), "-o", str(out), "--size", str(a.size), "--sh-colour", flag, "-q"]):
                raise SystemExit(f"gsz-encode failed on the {space} run")
            dec = decode(str(out))
            res = evaluate(refs, dec, cams)
            row[space] = {"bytes": out.stat().st_size, "psnr": round(res["psnr"], 2), "ssim": round(res["ssim"], 5)}
            print(f"{space}: {row[space]['bytes']:,} B, {res['psnr']:.2f} dB", file=sys.stderr, flush=True)
    row["gain_db"] = round(row["ycc"]["psnr"] - row["rgb"]["psnr"], 2)
    rows = keep_row(a.out, row, "bench_colour_probe.py", argv)
    print("| scene | noised | budget B | RGB dB | luma/chroma dB | gain dB |\n|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['scene']} | {'yes' if r['noised'] else 'no'} | {r['size']:,} | {r['rgb']['psnr']:.2f} | "
              f"{r['ycc']['psnr']:.2f} | {r['gain_db']:+.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
