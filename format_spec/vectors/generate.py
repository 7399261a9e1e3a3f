"""Expected decoded values of the .gsz test vectors (and, with --encode, the vectors themselves).

    .venv/bin/python format_spec/vectors/generate.py            # rewrite the .json files (and
                                                                # encode vectors not yet committed)
    .venv/bin/python format_spec/vectors/generate.py --encode   # re-encode the .gsz files too
    .venv/bin/python format_spec/vectors/generate.py --rewrap   # rewrite the .glb vectors too

The .gsz files are the fixed bitstream of the format: the default mode reads the committed files
and only rewrites the JSON beside each (run it after changing what the JSON lists; `git diff
--stat` must then show only .json files); a vector listed below whose .gsz does not exist yet is
encoded once.  ``--encode`` re-encodes every vector from tests/data
with the current encoder and overwrites the .gsz files -- the bytes change whenever the encoder's
choices change, so only use it when the format version changes.

Each vector is a tiny real scene cut from tests/data, encoded with fixed options.  The JSON
beside each file lists what an independent decoder must produce: the count, the SH degree, the
SHA-256 of every decoded field as float32 little-endian bytes (fields in the order positions,
scales, rotations, opacities, sh_dc, sh_rest; arrays C-contiguous with the shapes given), the
first decoded values in readable form, and per layer its Gaussian count, ``decodable_at`` and
intermediate values of each chunk (GSZ.md §12), so that a decoder can find which stage is wrong.
"""
from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent.parent
FIELDS = ("positions", "scales", "rotations", "opacities", "sh_dc", "sh_rest")

VECTORS = [
    # name, sample, count, sh degree, options
    ("sh0_plant_200", "houseplant_sh0_20k.ply", 200, 0, dict(blocks=80, reserve=1.0, bits=10)),
    ("sh1_jug_150", "measuring_jug_sh3_12k.ply", 150, 1, dict(blocks=80, reserve=0.9, bits=8, codebook=16, keep=10)),
    ("sh3_jug_300", "measuring_jug_sh3_12k.ply", 300, 3, dict(blocks=80, reserve=0.8, bits=12, codebook=32, keep=20)),
    # three importance layers (GSZ.md §4.1): per-layer GEOM/ATTR/SHVQ; layer 0's Gaussians all
    # keep their exact SH vectors, so the codebook travels with layer 1
    ("sh2_jug_400_layers3", "measuring_jug_sh3_12k.ply", 400, 2,
     dict(blocks=80, reserve=0.9, bits=10, codebook=24, keep=90, layers=3, first_layer=0.2)),
    # entropy-coder coverage: log-scales and opacities moved off the sample's delivery grid
    # (NOISE_SIGMA) and 12-bit groups of ~40 symbols, where a LAPLACE model (two parameters) is
    # cheaper than a frequency table; 3000 voxels give every rANS stream several lanes
    ("sh0_plant_3000_laplace", "houseplant_sh0_20k.ply", 3000, 0, dict(raht_classes=1, blocks=80, reserve=1.0, bits=12)),
    # octree coverage: the whole 20k sample on a depth-13 grid, where coarse contexts pass
    # COUNT_LIMIT within a level, so a decoder that skips the count halving (OCTREE.md §4)
    # decodes different occupancy; 1-bit attributes keep the file small
    ("sh0_plant_20k_d13_halving", "houseplant_sh0_20k.ply", 20_000, 0,
     dict(raht_classes=1, blocks=80, reserve=1.0, bits=1, depth=13)),
    # spatial tiles (GSZ.md §4.2, format 1.2): the whole 12k jug in tiles of at most 4096 voxels,
    # two layers each, every tile with its own codebook
    ("sh1_jug_12k_tiles", "measuring_jug_sh3_12k.ply", 12_000, 1,
     dict(raht_classes=1, blocks=80, reserve=1.0, bits=6, codebook=64, keep=200, layers=2, tile_gaussians=4096)),
    # octree scheme 1 (OCTREE.md §4.1, format 1.4): the 20k sample on a depth-16 grid, where
    # most voxels leave the tree at a level near 9 and the rest are coded down to the leaves
    ("sh0_plant_20k_d16_direct", "houseplant_sh0_20k.ply", 20_000, 0,
     dict(raht_classes=1, blocks=80, reserve=1.0, bits=1, depth=16)),
    # the same scheme on sh1_jug_150's Gaussians at depth 16: the GEOM chunk the scheme-1
    # must-reject vectors (vectors/reject) are built on
    ("sh1_jug_150_d16_direct", "measuring_jug_sh3_12k.ply", 150, 1,
     dict(blocks=80, reserve=0.9, bits=8, codebook=16, keep=10, depth=16)),
    # SH classes (GSZ.md §8.1, format 1.3): the 1100 most important of 2000 Gaussians keep their
    # vectors, stored in 4 importance classes (an SHCL chunk), one block per class
    ("sh1_jug_2k_shclasses", "measuring_jug_sh3_12k.ply", 2000, 1,
     dict(raht_classes=1, reserve=1.0, bits=8, codebook=32, keep=1100, sh_classes=4)),
    # RAHT leaf weights (GSZ.md §7.1, TRANSFORMS.md §2.5, format 1.5): 2000 Gaussians in 4
    # importance classes (an RWGT chunk), every SH vector kept in the same 4 classes, so the
    # SHCL chunk takes RWGT's classes (its Q byte 0, GSZ.md §8.1)
    ("sh1_jug_2k_rwgt", "measuring_jug_sh3_12k.ply", 2000, 1,
     dict(reserve=1.0, bits=8, codebook=32, keep=2000, sh_classes=4, raht_classes=4)),
    # the SH colour transform (GSZ.md §8.2, format 1.6): 2000 Gaussians at SH degree 2 whose
    # vectors, 600 kept and the rest codewords, are stored as luma/chroma (an SHXF chunk)
    ("sh2_jug_2k_shxf", "measuring_jug_sh3_12k.ply", 2000, 2,
     dict(raht_classes=1, reserve=1.0, bits=10, codebook=32, keep=600, sh_colour="luma-chroma")),
    # format 1.7: the DC colour as luma/chroma too (SHXF bit 1), alone (SH degree 0) and with the
    # SH vectors' transform (bits 1 and 0)
    ("sh0_plant_2k_dcxf", "houseplant_sh0_20k.ply", 2000, 0,
     dict(reserve=1.0, bits=10, sh_colour="auto")),
    ("sh1_jug_2k_dcxf", "measuring_jug_sh3_12k.ply", 2000, 1,
     dict(reserve=1.0, bits=10, codebook=32, keep=600, sh_colour="luma-chroma")),
    # format 1.8: the SH vectors in their principal axes (SHXF bit 2, with the DC's bit 1), two
    # layers: the matrix in layer 0's chunk, layer 1's names it with D = 0; kept vectors and
    # codewords alike turned by the integer inverse
    ("sh3_jug_2k_klt", "measuring_jug_sh3_12k.ply", 2000, 3,
     dict(reserve=1.0, bits=10, codebook=32, keep=600, layers=2, first_layer=0.3, sh_colour="klt")),
    # format 1.9: the kept vectors as residuals of a codeword each (SHRF chunks), two layers (the
    # codebook in layer 0: both layers' kept vectors refer to it; layer 0 keeps every vector,
    # layer 1 600 of 1400), each part's kept vectors in 2 classes (SHCL: SHRF names the
    # codewords in that stored order), KLT
    ("sh3_jug_2k_refine", "measuring_jug_sh3_12k.ply", 2000, 3,
     dict(reserve=1.0, bits=8, codebook=32, keep=1200, layers=2, first_layer=0.3, sh_classes=2,
          sh_refine=True, sh_colour="klt")),
]
#: vectors whose scales and opacities get seeded Gaussian noise of this sigma before encoding
NOISED = {"sh0_plant_3000_laplace": 0.05}


def sha(a, dtype) -> str:
    return hashlib.sha256(np.ascontiguousarray(a, dtype=np.dtype(dtype)).tobytes()).hexdigest()


def expected_values(cloud) -> dict:
    out = {"num_gaussians": len(cloud), "sh_degree": cloud.sh_degree, "fields": {}}
    for f in FIELDS:
        a = np.ascontiguousarray(getattr(cloud, f), dtype="<f4")
        out["fields"][f] = {"shape": list(a.shape), "sha256": hashlib.sha256(a.tobytes()).hexdigest(),
                            "first": a.reshape(len(cloud), -1)[:2].tolist()}
    return out


def intermediates(data: bytes) -> list[dict]:
    """Per part (a layer of a tile; per layer without tiles), the values between the stages of
    GSZ.md §6-§8 (see GSZ.md §12 for their layout).

    Computed with the reference decoder's modules, stage by stage, from the committed bytes."""
    from gsz.decoder.bytesio import Reader
    from gsz.decoder.container import read_container
    from gsz.decoder.decode import plan_parts
    from gsz.decoder.geometry import read_geometry
    from gsz.decoder.groups import read_channel_set
    from gsz.decoder.attributes import read_raht_weights
    from gsz.decoder.layout import (CHUNK_ATTR, CHUNK_GEOM, CHUNK_RWGT, CHUNK_SHCL, CHUNK_SHRF, CHUNK_SHVQ,
                                    CHUNK_SHXF, KNOWN_CHUNKS)
    from gsz.decoder.octree import read_scheme
    from gsz.decoder.sh import read_sh_classes, read_sh_colour, read_sh_refine
    from gsz.decoder.morton import morton_encode
    from gsz.decoder.raht import build_raht_tree, raht_inverse
    from gsz.decoder.rans import decode_stream

    c = read_container(data, known_types=KNOWN_CHUNKS)
    degree = c.header.sh_degree
    rows = []
    codebook_size = {}
    plan = plan_parts(c.chunks, degree)
    for part in plan.parts:
        got = part.chunks
        row = {"layer": part.layer, "tile": part.tile} if plan.tile_chunk is not None else {}
        gdata = c.chunks[got[CHUNK_GEOM]].data
        geom = read_geometry(gdata, max_points=c.header.num_gaussians)
        m = len(geom.ijk)
        codes = morton_encode(geom.ijk)
        scheme, decisions, direct_from, raw, _ = read_scheme(np.frombuffer(gdata, np.uint8)[41:], geom.depth, m)
        row["geom"] = {"depth": geom.depth, "origin": [float(v) for v in geom.origin],
                       "side": float(geom.side), "voxels": m, "octree_decisions": int(decisions),
                       "morton_sha256": sha(codes, "<u8"), "first_voxels": geom.ijk[:2].tolist()}
        if scheme:          # OCTREE.md section 4.1
            row["geom"].update(octree_scheme=scheme, direct_level=direct_from, raw_bytes=int(raw.size))
        rwgt = None
        if CHUNK_RWGT in got:           # GSZ.md section 7.1
            rwgt = read_raht_weights(c.chunks[got[CHUNK_RWGT]].data, m)
            row["rwgt"] = {"Q": int(rwgt.weights.size), "weights": rwgt.weights.tolist(),
                           "classes_sha256": sha(rwgt.classes, "u1"), "classes_first": rwgt.classes[:8].tolist()}
        tree = build_raht_tree(codes, geom.depth, None if rwgt is None else rwgt.leaf_weights)
        r = Reader(c.chunks[got[CHUNK_ATTR]].data)
        r.u8(), r.u8()
        dc = r.array(np.float64, 7)
        ac = read_channel_set(r, max_length=m)
        direct = read_channel_set(r, max_length=m)
        raht = raht_inverse(dc, ac.T, tree)
        row["attr"] = {"dc": [float(v) for v in dc],
                       "ac_sha256": sha(ac, "<f8"), "ac_first": ac[:, :2].tolist(),
                       "raht_sha256": sha(raht, "<f8"), "raht_first": raht[:2].tolist(),
                       "direct_sha256": sha(direct, "<f8")}
        if degree > 0:
            r = Reader(c.chunks[got[CHUNK_SHVQ]].data)
            kcb, p, d = r.u32(), r.u32(), r.u16()
            sh = {"K_cb": kcb, "P": p, "D": d}
            if kcb:
                cb = read_channel_set(r, max_length=kcb)
                codebook_size[part.tile] = kcb
                sh["codebook_sha256"] = sha(cb, "<f8")
            if p:
                kept = read_channel_set(r, max_length=p)
                flags = decode_stream(r.blob(), np.zeros(m, np.int64))
                sh["kept_sha256"] = sha(kept, "<f8")
                sh["flags_sha256"] = sha(flags, "u1")
            if CHUNK_SHCL in got:
                cdata = c.chunks[got[CHUNK_SHCL]].data
                classes = read_sh_classes(cdata, p, None if rwgt is None else rwgt.classes)
                if isinstance(classes, str):    # the kept points' RWGT classes (Q byte 0)
                    classes = rwgt.classes[flags == 1]
                row["shcl"] = {"Q": int(cdata[0]), "classes_sha256": sha(classes, "u1"),
                               "classes_first": classes[:8].tolist()}
            if CHUNK_SHRF in got:       # GSZ.md section 8.3: the stored kept vectors' codewords
                ref = read_sh_refine(c.chunks[got[CHUNK_SHRF]].data, p, codebook_size.get(part.tile, 0))
                row["shrf"] = {"indices_sha256": sha(ref, "<u4"), "indices_first": ref[:8].tolist()}
            idx = decode_stream(r.blob(), np.zeros(m - p, np.int64))
            sh["codebook_size_used"] = codebook_size.get(part.tile, 0)
            sh["indices_sha256"] = sha(idx, "<u4")
            sh["indices_first"] = idx[:8].tolist()
            row["shvq"] = sh
        if CHUNK_SHXF in got:           # GSZ.md section 8.2: "raht" and "shvq" are stored values
            row["shxf"] = {"transform": read_sh_colour(c.chunks[got[CHUNK_SHXF]].data, degree)}
        rows.append(row)
    return rows


def write_json(name: str, data: bytes, opts: dict) -> None:
    from gsz.decoder import decode, inspect

    dec = decode(data)
    exp = expected_values(dec)
    info = inspect(data)
    exp.update(file=f"{name}.gsz", file_sha256=hashlib.sha256(data).hexdigest(),
               bytes=len(data), encoder_options=opts,
               layers=[{k: r[k] for k in ("layer", "gaussians", "cumulative_gaussians", "decodable_at")}
                       for r in info["layers"]])
    if len(info["tiles"]) > 1:
        exp["tiles"] = [{k: r[k] for k in ("tile", "bbox_min", "bbox_max", "gaussians")} for r in info["tiles"]]
        ends = {(r["tile"], p["layer"]): p for r in info["tiles"] for p in r["parts"]}
        exp["parts"] = intermediates(data)
        for row in exp["parts"]:
            p = ends[(row["tile"], row["layer"])]
            row.update(gaussians=p["gaussians"], decodable_at=p["decodable_at"])
    else:
        for row, extra in zip(exp["layers"], intermediates(data)):
            row.update(extra)
    (HERE / f"{name}.json").write_text(json.dumps(exp, indent=1) + "\n")
    print(f"{name}: {len(data)} bytes, {len(dec)} Gaussians")


#: .gsz vectors also committed wrapped in a .glb (EXT_gaussian_splatting_compression_gsz,
#: GLTF.md §3): the layered one, so a loader's streaming through the JSON chunk is covered too
GLB_VECTORS = ["sh2_jug_400_layers3"]


def write_glb_vector(name: str, rewrap: bool) -> None:
    """``<name>.glb`` (written when missing or ``rewrap``: its bytes name the gsz version in
    ``asset.generator``) and ``<name>.glb.json``: its hash, the payload's place and hash (the
    committed ``<name>.gsz`` byte for byte), and each layer's ``decodable_at`` in .glb offsets.
    The decoded values are those listed in ``<name>.json``."""
    from gsz.decoder import decode, inspect
    from gsz.decoder.gltf import gsz_glb_bytes
    payload = (HERE / f"{name}.gsz").read_bytes()
    path = HERE / f"{name}.glb"
    if rewrap or not path.exists():
        path.write_bytes(gsz_glb_bytes(payload))
    data = path.read_bytes()
    info = inspect(data)
    start, size = info["payload"]["offset"], info["payload"]["bytes"]
    assert data[start:start + size] == payload and decode(data).equals(decode(payload))
    exp = {"file": f"{name}.glb", "file_sha256": hashlib.sha256(data).hexdigest(), "bytes": len(data),
           "decodes_as": f"{name}.json",
           "payload": {"offset": start, "bytes": size, "sha256": hashlib.sha256(payload).hexdigest()},
           "layers": [{k: r[k] for k in ("layer", "cumulative_gaussians", "decodable_at")} for r in info["layers"]]}
    (HERE / f"{name}.glb.json").write_text(json.dumps(exp, indent=1) + "\n")
    print(f"{name}.glb: {len(data)} bytes, payload at {start}")


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    reencode = "--encode" in argv
    for name, sample, n, degree, opts in VECTORS:
        if reencode or not (HERE / f"{name}.gsz").exists():
            import gsz
            from gsz.decoder import decode
            from gsz.encoder.pipeline import EncodeOptions, encode
            src = gsz.read_ply(ROOT / "tests" / "data" / sample)
            idx = np.sort(np.random.default_rng(2024).choice(len(src), n, replace=False))
            cloud = src.subset(idx).with_sh_degree(degree)
            if name in NOISED:
                import dataclasses
                rng = np.random.default_rng(7)
                sigma = NOISED[name]
                cloud = dataclasses.replace(
                    cloud,
                    scales=(cloud.scales + rng.normal(0, sigma, cloud.scales.shape)).astype(np.float32),
                    opacities=(cloud.opacities + rng.normal(0, sigma, cloud.opacities.shape)).astype(np.float32))
            res = encode(cloud, EncodeOptions(train_views=4, importance_width=96, **opts))
            (HERE / f"{name}.gsz").write_bytes(res.data)
            assert decode(res.data).equals(res.cloud)
        write_json(name, (HERE / f"{name}.gsz").read_bytes(), opts)
    for name in GLB_VECTORS:
        write_glb_vector(name, rewrap=reencode or "--rewrap" in argv)


if __name__ == "__main__":
    main()
