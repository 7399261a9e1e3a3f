"""Regenerate the .gsz test vectors and their expected decoded values.

    .venv/bin/python format_spec/vectors/generate.py

Each vector is a tiny real scene cut from tests/data, encoded with fixed options.  The JSON
beside each file lists what an independent decoder must produce: the count, the SH degree, the
SHA-256 of every decoded field as float32 little-endian bytes (fields in the order positions,
scales, rotations, opacities, sh_dc, sh_rest; arrays C-contiguous with the shapes given), and the
first decoded values in readable form.  Only rerun this when the format version changes.
"""
from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent.parent
FIELDS = ("positions", "scales", "rotations", "opacities", "sh_dc", "sh_rest")

VECTORS = [
    # name, sample, count, sh degree, options
    ("sh0_plant_200", "houseplant_sh0_20k.ply", 200, 0, dict(reserve=1.0, bits=10)),
    ("sh1_jug_150", "measuring_jug_sh3_12k.ply", 150, 1, dict(reserve=0.9, bits=8, codebook=16, keep=10)),
    ("sh3_jug_300", "measuring_jug_sh3_12k.ply", 300, 3, dict(reserve=0.8, bits=12, codebook=32, keep=20)),
    # three importance layers (GSZ.md §4.1): per-layer GEOM/ATTR/SHVQ; layer 0's Gaussians all
    # keep their exact SH vectors, so the codebook travels with layer 1
    ("sh2_jug_400_layers3", "measuring_jug_sh3_12k.ply", 400, 2,
     dict(reserve=0.9, bits=10, codebook=24, keep=90, layers=3, first_layer=0.2)),
]


def expected_values(cloud) -> dict:
    out = {"num_gaussians": len(cloud), "sh_degree": cloud.sh_degree, "fields": {}}
    for f in FIELDS:
        a = np.ascontiguousarray(getattr(cloud, f), dtype="<f4")
        out["fields"][f] = {"shape": list(a.shape), "sha256": hashlib.sha256(a.tobytes()).hexdigest(),
                            "first": a.reshape(len(cloud), -1)[:2].tolist()}
    return out


def main():
    import gsz
    from gsz.decoder import decode, inspect
    from gsz.encoder.pipeline import EncodeOptions, encode

    for name, sample, n, degree, opts in VECTORS:
        src = gsz.read_ply(ROOT / "tests" / "data" / sample)
        idx = np.sort(np.random.default_rng(2024).choice(len(src), n, replace=False))
        cloud = src.subset(idx).with_sh_degree(degree)
        res = encode(cloud, EncodeOptions(train_views=4, importance_width=96, **opts))
        (HERE / f"{name}.gsz").write_bytes(res.data)
        dec = decode(res.data)
        assert dec.equals(res.cloud)
        exp = expected_values(dec)
        exp.update(file=f"{name}.gsz", file_sha256=hashlib.sha256(res.data).hexdigest(),
                   bytes=len(res.data), encoder_options=opts,
                   layers=[{k: r[k] for k in ("layer", "gaussians", "cumulative_gaussians", "decodable_at")}
                           for r in inspect(res.data)["layers"]])
        (HERE / f"{name}.json").write_text(json.dumps(exp, indent=1) + "\n")
        print(f"{name}: {len(res.data)} bytes, {len(dec)} Gaussians")


if __name__ == "__main__":
    main()
