"""EXT_gaussian_splatting_compression_gsz: a .glb carrying a .gsz decodes to exactly what the
.gsz decodes to -- whole, by tiles, streamed, truncated -- with the numpy-only decoder (no glTF
library), and the tools write and read it (format_spec/GLTF.md §3)."""
import hashlib
import json
import os
import struct
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

import gsz
from conftest import SAMPLE_SH3
from gsz.decoder import GszFormatError, GszTruncatedError, StreamDecoder, decode, inspect, iter_layers
from gsz.decoder.glb import EXT_GSZ, parse_glb

VEC = Path(__file__).resolve().parent.parent / "format_spec" / "vectors"
SCHEMA = VEC.parent / "schema" / "mesh.primitive.KHR_gaussian_splatting.EXT_gaussian_splatting_compression_gsz.schema.json"
NAME = "sh2_jug_400_layers3"
FIELDS = ("positions", "scales", "rotations", "opacities", "sh_dc", "sh_rest")


def wrap(payload: bytes) -> bytes:
    pytest.importorskip("pygltflib")
    from gsz.decoder.gltf import gsz_glb_bytes
    return gsz_glb_bytes(payload)


def test_vector_decodes_to_the_values_of_its_gsz():
    exp = json.loads((VEC / f"{NAME}.glb.json").read_text())
    values = json.loads((VEC / exp["decodes_as"]).read_text())
    data = (VEC / f"{NAME}.glb").read_bytes()
    payload = (VEC / f"{NAME}.gsz").read_bytes()
    assert hashlib.sha256(data).hexdigest() == exp["file_sha256"] and len(data) == exp["bytes"]
    p = exp["payload"]
    assert data[p["offset"]:p["offset"] + p["bytes"]] == payload
    assert p["sha256"] == values["file_sha256"]
    cloud = decode(data)
    for f in FIELDS:
        a = np.ascontiguousarray(getattr(cloud, f), "<f4")
        assert hashlib.sha256(a.tobytes()).hexdigest() == values["fields"][f]["sha256"], f
    # streamed one byte at a time: each layer completes exactly at its documented .glb offset
    dec, done = StreamDecoder(), []
    for i in range(len(data)):
        done += [(u.layer, u.bytes_received) for u in dec.feed(data[i:i + 1])]
    assert done == [(r["layer"], r["decodable_at"]) for r in exp["layers"]]
    assert dec.layer_ends() == [r["decodable_at"] for r in exp["layers"]]
    res = dec.finish()
    assert not res.truncated and res.cloud.equals(cloud) and res.bytes_expected == len(data)
    info = inspect(data)
    assert info["container"] == "glb" and info["payload"] == {"offset": p["offset"], "bytes": p["bytes"]}
    assert [r["decodable_at"] for r in info["layers"]] == [r["decodable_at"] for r in exp["layers"]]


def test_the_extension_object_follows_its_schema_and_the_wrapper_is_deterministic():
    jsonschema = pytest.importorskip("jsonschema")
    referencing = pytest.importorskip("referencing")
    payload = (VEC / f"{NAME}.gsz").read_bytes()
    data = wrap(payload)
    assert data == wrap(payload)
    doc = parse_glb(data).doc
    prim = doc["meshes"][0]["primitives"][0]
    ext = prim["extensions"]["KHR_gaussian_splatting"]["extensions"][EXT_GSZ]
    # glTF's own property schemas, reduced to what they say of these two fields
    registry = referencing.Registry().with_resources([
        ("glTFProperty.schema.json", referencing.Resource.from_contents(
            {"$schema": "https://json-schema.org/draft/2020-12/schema", "type": "object"})),
        ("glTFid.schema.json", referencing.Resource.from_contents(
            {"$schema": "https://json-schema.org/draft/2020-12/schema", "type": "integer", "minimum": 0}))])
    schema = json.loads(SCHEMA.read_text())
    validator = jsonschema.Draft202012Validator(schema, registry=registry)
    validator.validate(ext)
    assert not validator.is_valid({"bufferView": -1}) and not validator.is_valid({})
    # GLTF.md §3: both extensions required, data-less FLOAT accessors of the header's count
    assert doc["extensionsRequired"] == doc["extensionsUsed"] == ["KHR_gaussian_splatting", EXT_GSZ]
    n = inspect(payload)["num_gaussians"]
    for acc in doc["accessors"]:
        assert acc["count"] == n and acc["componentType"] == 5126
        assert not {"bufferView", "byteOffset", "sparse"} & set(acc)
    attrs = prim["attributes"]
    assert sum(a.startswith("KHR_gaussian_splatting:SH_DEGREE_") for a in attrs) == 1 + 3 + 5
    assert "COLOR_0" not in attrs and prim["mode"] == 0
    pos = doc["accessors"][attrs["POSITION"]]
    want = decode(payload).positions * np.float32([-1, -1, 1])
    assert pos["min"] == want.min(0).tolist() and pos["max"] == want.max(0).tolist()
    view = doc["bufferViews"][ext["bufferView"]]
    assert view == {"buffer": 0, "byteOffset": 0, "byteLength": len(payload)}     # first in BIN


def test_tiles_regions_layers_and_load_match_the_gsz(tmp_path):
    payload = (VEC / "sh1_jug_12k_tiles.gsz").read_bytes()
    raw, glb = tmp_path / "t.gsz", tmp_path / "t.glb"
    raw.write_bytes(payload)
    glb.write_bytes(wrap(payload))
    for kw in ({}, {"tiles": [1, 3]}, {"region": ((-0.05, -0.05, -0.05), (0.05, 0.05, 0.05))}, {"layers": 1}):
        assert decode(glb, **kw).equals(decode(raw, **kw)), kw
    assert gsz.load(glb).equals(decode(raw))
    ups_glb = [u.cloud for u in iter_layers(glb, chunk_size=4096)]     # one per tile part: 4 tiles x 2 layers
    ups_raw = [u.cloud for u in iter_layers(raw, chunk_size=4096)]
    assert len(ups_glb) == len(ups_raw) == 8 and all(a.equals(b) for a, b in zip(ups_glb, ups_raw))


def test_truncated_and_malformed_containers(tmp_path):
    data = (VEC / f"{NAME}.glb").read_bytes()
    exp = json.loads((VEC / f"{NAME}.glb.json").read_text())
    cut = data[:exp["layers"][1]["decodable_at"] + 5]
    with pytest.raises(GszTruncatedError, match="truncated"):
        decode(cut)
    with pytest.warns(gsz.decoder.GszTruncatedWarning):
        two = decode(cut, partial=True)
    assert len(two) == exp["layers"][1]["cumulative_gaussians"]
    glb = parse_glb(data)

    def rebuilt(edit=None, tail=b""):
        doc = json.loads(json.dumps(glb.doc))
        if edit:
            edit(doc)
        text = json.dumps(doc).encode()
        text += b" " * (-len(text) % 4)
        rest = data[glb.bin_offset - 8:] + tail
        return struct.pack("<4sII", b"glTF", 2, 20 + len(text) + len(rest)) + struct.pack("<II", len(text), 0x4E4F534A) + text + rest
    assert decode(rebuilt()).equals(decode(data))              # the rebuild itself is sound
    ext = lambda d: d["meshes"][0]["primitives"][0]["extensions"]["KHR_gaussian_splatting"]["extensions"][EXT_GSZ]  # noqa: E731
    bad = {
        "without an EXT_gaussian_splatting_compression_gsz": lambda d: d["meshes"][0]["primitives"][0].pop("extensions"),
        "not an index": lambda d: ext(d).update(bufferView=7),
        "outside the": lambda d: d["bufferViews"][0].update(byteOffset=64),
        "holds 2": lambda d: d["meshes"].append(d["meshes"][0]),
        "must lie in buffer 0": lambda d: d["buffers"][0].update(uri="x.bin"),
    }
    for message, edit in bad.items():
        with pytest.raises(GszFormatError, match=message):
            decode(rebuilt(edit))
        dec = StreamDecoder()
        with pytest.raises(GszFormatError, match=message):
            dec.feed(rebuilt(edit))
    grown = bytearray(rebuilt())
    struct.pack_into("<I", grown, 8, len(grown) - 4)             # declared length shorter than the file
    with pytest.raises(GszFormatError, match="unexpected bytes after"):
        decode(bytes(grown))
    (tmp_path / "x.glb").write_bytes(data[:12] + b"\xff" * 40)
    with pytest.raises(GszFormatError):
        decode(tmp_path / "x.glb")


def test_numpy_only_decoder_reads_it_without_pygltflib(tmp_path):
    code = textwrap.dedent(f"""
        import builtins, sys
        real = builtins.__import__
        def guard(name, *a, **k):
            if name.split('.')[0] in ('pygltflib', 'torch', 'dataclasses_json'):
                raise ImportError('blocked for this test: ' + name)
            return real(name, *a, **k)
        builtins.__import__ = guard
        import gsz
        from gsz.decoder import decode, inspect, StreamDecoder
        glb = open({str(VEC / (NAME + '.glb'))!r}, 'rb').read()
        raw = open({str(VEC / (NAME + '.gsz'))!r}, 'rb').read()
        assert decode(glb).equals(decode(raw))
        dec = StreamDecoder(); dec.feed(glb); assert dec.finish().cloud.equals(decode(raw))
        assert inspect(glb)['container'] == 'glb'
        assert gsz.load({str(VEC / (NAME + '.glb'))!r}).equals(decode(raw))
        try:
            gsz.save(decode(raw), {str(tmp_path / 'plain.glb')!r})
        except gsz.GszError as e:
            print(e)
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "glTF support needs pygltflib: pip install 'gsz[gltf]'"


def _cli(*args):
    code = ("import sys; from gsz.encoder.cli import main as e; from gsz.decoder.cli import decode_main as d, "
            "info_main as i; sys.exit({'encode': e, 'decode': d, 'info': i}[sys.argv[1]](sys.argv[2:]))")
    return subprocess.run([sys.executable, "-c", code, *map(str, args)], capture_output=True, text=True)


FAST = ["--codebook", "32", "--train-views", "4", "--importance-width", "96"]


def test_tools_write_and_read_the_glb(tmp_path):
    pytest.importorskip("pygltflib")
    src = tmp_path / "jug.ply"
    gsz.write_ply(gsz.read_ply(SAMPLE_SH3).subset(np.arange(0, 12000, 8)), src)
    glb, raw = tmp_path / "jug.glb", tmp_path / "jug.gsz"
    p = _cli("encode", src, "-o", glb, "--bits", "10", "--json", *FAST)
    assert p.returncode == 0, p.stderr
    report = json.loads(p.stdout)
    assert _cli("encode", src, "-o", raw, "--bits", "10", *FAST).returncode == 0
    assert report["bytes"] == os.path.getsize(glb) and report["gsz_bytes"] == os.path.getsize(raw)
    info = inspect(glb)
    assert glb.read_bytes()[info["payload"]["offset"]:][:info["payload"]["bytes"]] == raw.read_bytes()
    p = _cli("info", glb)
    assert p.returncode == 0 and "EXT_gaussian_splatting_compression_gsz" in p.stdout
    for out in ("a.ply", "b.glb", "c.gltf"):
        p = _cli("decode", glb, "-o", tmp_path / out)
        assert p.returncode == 0, p.stderr
    cloud = decode(raw)
    assert gsz.read_ply(tmp_path / "a.ply").equals(cloud)
    for plain in ("b.glb", "c.gltf"):
        back = gsz.load(tmp_path / plain)
        np.testing.assert_array_equal(back.positions, cloud.positions)
        np.testing.assert_array_equal(back.sh_rest, cloud.sh_rest)
    # a plain glTF is an input of gsz-encode, and not of gsz-decode (nothing to decode)
    p = _cli("encode", tmp_path / "b.glb", "-o", tmp_path / "again.gsz", "--bits", "10", *FAST)
    assert p.returncode == 0, p.stderr
    p = _cli("decode", tmp_path / "b.glb", "-o", tmp_path / "x.ply")
    assert p.returncode == 1 and p.stderr.count("\n") == 1 and "plain KHR_gaussian_splatting" in p.stderr
    p = _cli("encode", src, "-o", tmp_path / "x.gltf", "--bits", "10", *FAST)
    assert p.returncode == 2 and p.stderr.count("\n") == 1 and "writes .gsz or .glb" in p.stderr
    assert not (tmp_path / "x.ply").exists() and not (tmp_path / "x.gltf").exists()


@pytest.mark.slow
def test_size_budget_holds_for_the_glb(tmp_path):
    pytest.importorskip("pygltflib")
    src = tmp_path / "jug.ply"
    gsz.write_ply(gsz.read_ply(SAMPLE_SH3).subset(np.arange(0, 12000, 4)), src)
    out = tmp_path / "jug.glb"
    p = _cli("encode", src, "-o", out, "--size", "60kB", "--json", "--train-views", "4", "--importance-width", "96")
    assert p.returncode == 0, p.stderr
    r = json.loads(p.stdout)
    size = os.path.getsize(out)
    assert 0.995 * 60_000 <= size <= 60_000 and r["bytes"] == size and r["target_bytes"] == 60_000
    assert r["gsz_bytes"] <= r["gsz_target_bytes"] < 60_000


def test_viewer_scene_from_a_glb_is_a_compressed_scene(tmp_path):
    pytest.importorskip("moderngl")
    from gsz.viewer.app import layer_prefix_scenes, scene_from_file
    path = tmp_path / "v.glb"
    path.write_bytes((VEC / f"{NAME}.glb").read_bytes())
    scene = scene_from_file(path)
    assert scene.compressed and scene.cloud.equals(decode(path))
    exp = json.loads((VEC / f"{NAME}.glb.json").read_text())
    assert scene.components["glTF JSON + GLB framing"] == exp["bytes"] - exp["payload"]["bytes"]
    prefixes = layer_prefix_scenes(scene)
    assert [s.file_bytes for s in prefixes] == [r["decodable_at"] for r in exp["layers"][:-1]]
    plain = tmp_path / "p.glb"
    gsz.save(scene.cloud, plain)
    assert not scene_from_file(plain).compressed


def test_a_node_transform_on_the_gsz_primitive_is_baked_by_load_not_by_decode(tmp_path):
    pytest.importorskip("pygltflib")
    data = (VEC / f"{NAME}.glb").read_bytes()
    glb = parse_glb(data)
    doc = json.loads(json.dumps(glb.doc))
    doc["nodes"][0]["translation"] = [1.0, 2.0, 3.0]
    text = json.dumps(doc).encode()
    text += b" " * (-len(text) % 4)
    rest = data[glb.bin_offset - 8:]
    moved = tmp_path / "moved.glb"
    moved.write_bytes(struct.pack("<4sII", b"glTF", 2, 20 + len(text) + len(rest))
                      + struct.pack("<II", len(text), 0x4E4F534A) + text + rest)
    plain = decode(data)
    assert decode(moved).equals(plain)                  # the codec's output: the primitive's values
    loaded = gsz.load(moved)                            # the scene: translated (glTF +x, +y = RDF -x, -y)
    np.testing.assert_allclose(loaded.positions, plain.positions + np.float32([-1, -2, 3]), atol=1e-6)
    np.testing.assert_allclose(loaded.scales, plain.scales, atol=1e-6)
    np.testing.assert_array_equal(loaded.sh_rest, plain.sh_rest)
