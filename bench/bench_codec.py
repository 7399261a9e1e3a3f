"""Codec benchmark at fixed configurations on every shared scene (and a noised variant).

    .venv/bin/python bench/bench_codec.py [--scenes a,b] [--bits 8,12] [--reserve 0.8]
                                          [--blocks 1,80] [--noise] [--width 800]
                                          [--out bench/out/codec.json]

Prints, per scene and bit-width: bytes, bytes/Gaussian, ratio to the PLY, component breakdown,
fidelity PSNR/SSIM vs the original on the default test views (gsz-eval's protocol), encode seconds
per stage, decode seconds and Gaussians/s.  Importance is computed once per scene variant and
reused for every bit-width (it does not depend on the bits).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
SHARED = ROOT.parent / "shared" / "data"
SCENES = ["houseplant_sh0", "measuring_jug_sh3", "flowers_daffodils_sh2", "plaza_taebak_crop_sh0",
          "showroom_lacadiere_crop_sh0", "tiny_graphdeco_iter7000_sh3"]


def git_commit() -> str | None:
    """The checkout's short commit (None outside git): what every bench JSON records."""
    out = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True, text=True)
    return out.stdout.strip() or None


def add_noise(cloud, seed=0):
    """Small Gaussian noise that moves every attribute off its delivery-format grid."""
    from gsz.decoder.cloud import GaussianCloud
    rng = np.random.default_rng(seed)
    lo, hi = np.percentile(cloud.positions, [1, 99], axis=0)
    ext = float((hi - lo).max())

    def nz(a, s):
        return (a + rng.normal(0, s, a.shape)).astype(np.float32)
    return GaussianCloud(nz(cloud.positions, 1e-4 * ext), nz(cloud.scales, 0.01), nz(cloud.rotations, 0.005),
                         nz(cloud.opacities, 0.01), nz(cloud.sh_dc, 0.005), nz(cloud.sh_rest, 0.002),
                         cloud.sh_degree)


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--scenes", default=",".join(SCENES))
    ap.add_argument("--bits", default="8,12")
    ap.add_argument("--reserve", type=float, default=0.8)
    ap.add_argument("--blocks", default=None,
                    help="comma-separated blocks per channel, or 'default' (the fixed configuration's "
                         "default for the bit-width; the default)")
    ap.add_argument("--noise", action="store_true", help="also run the noised variant of each scene")
    ap.add_argument("--width", type=int, default=800)
    ap.add_argument("--views", type=int, default=8)
    ap.add_argument("--out", default=str(ROOT / "bench" / "out" / "codec.json"))
    a = ap.parse_args(argv)
    if not SHARED.exists():
        print(f"SKIP: {SHARED} not present")
        return 0
    import gsz
    from gsz.evaluation.cameras import load_cameras
    from gsz.evaluation.evaluate import evaluate, render_views
    from gsz.encoder.pipeline import EncodeOptions, compute_train_importance, encode
    from gsz.decoder import decode

    rows = []
    for scene in a.scenes.split(","):
        path = SHARED / f"{scene}.ply"
        if not path.exists():
            print(f"SKIP {scene}: not present")
            continue
        base = gsz.read_ply(path)
        variants = [("grid", base)] + ([("noised", add_noise(base))] if a.noise else [])
        for variant, cloud in variants:
            ply_bytes = os.path.getsize(path)
            cams = load_cameras(None, cloud, n_test=a.views, width=a.width).test
            t0 = time.perf_counter()
            refs = render_views(cloud, cams)
            t_ref = time.perf_counter() - t0
            opts0 = EncodeOptions(reserve=a.reserve)
            t0 = time.perf_counter()
            imp = compute_train_importance(cloud, opts0)
            t_imp = time.perf_counter() - t0
            for bits, blocks in [(int(b), None if k == "default" else int(k)) for b in a.bits.split(",")
                                 for k in (a.blocks or "default").split(",")]:
                opts = EncodeOptions(reserve=a.reserve, bits=bits, blocks=blocks)
                res = encode(cloud, opts, importance=imp)
                t0 = time.perf_counter()
                dec = decode(res.data)
                t_dec = time.perf_counter() - t0
                assert dec.equals(res.cloud)
                ev = evaluate(refs, dec, cams)
                r = res.report
                row = {"scene": scene, "variant": variant, "bits": bits, "blocks": r.fixed.options["blocks"],
                       "reserve": a.reserve,
                       "gaussians": len(cloud), "voxels": r.voxels, "depth": r.depth,
                       "bytes": r.bytes, "bytes_per_gaussian": r.bytes / len(cloud),
                       "ratio_vs_ply": ply_bytes / r.bytes, "components": r.components,
                       "psnr": ev["psnr"], "ssim": ev["ssim"],
                       "encode_seconds": {"importance": t_imp, **r.seconds},
                       "decode_seconds": t_dec, "decode_gaussians_per_s": r.voxels / t_dec,
                       "reference_render_seconds": t_ref}
                rows.append(row)
                c = r.components
                print(f"{scene:30s} {variant:6s} {bits:2d} bit {row['blocks']:2d} blk: {r.bytes:>10,} B  "
                      f"{row['bytes_per_gaussian']:6.2f} B/G  {row['ratio_vs_ply']:5.1f}x  "
                      f"PSNR {ev['psnr']:6.2f}  SSIM {ev['ssim']:.4f}  geom {c['geometry']:,} "
                      f"attr {c['attributes']:,} sh {c.get('sh', 0):,}  "
                      f"enc {t_imp + r.total_seconds:.1f}s dec {t_dec:.2f}s "
                      f"({row['decode_gaussians_per_s'] / 1e6:.2f} MG/s)", flush=True)
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(rows, indent=1))
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
