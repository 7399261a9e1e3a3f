"""gsz's glTF files against independent tools: the Khronos glTF-Validator, three.js's
KHR_gaussian_splatting loader and PlayCanvas splat-transform's writer.  The tools are npm
packages that ``bench/bench_gltf.py`` installs into bench/.peers; without node or without them
every test here skips (and says how to install them)."""
import json
import struct
import sys
from pathlib import Path

import pytest

import gsz
from conftest import SAMPLE_SH0, SAMPLE_SH3

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "bench"))
import gltf_checks  # noqa: E402

pytest.importorskip("pygltflib")
if gltf_checks.missing():
    pytest.skip(f"needs node and {', '.join(gltf_checks.missing())} in bench/.peers "
                "(.venv/bin/python bench/bench_gltf.py --install)", allow_module_level=True)

VECTOR = Path(__file__).resolve().parent.parent / "format_spec" / "vectors" / "sh2_jug_400_layers3.glb"


def test_validator_reports_nothing_but_its_known_attribute_name_limitation(tmp_path):
    cloud = gsz.read_ply(SAMPLE_SH3)
    files = [tmp_path / "plain.glb", tmp_path / "plain.gltf", VECTOR]
    for f in files[:2]:
        gsz.save(cloud, f)
    # a control the validator must catch: POSITION's max no longer the data's
    data = bytearray(files[0].read_bytes())
    n = struct.unpack_from("<I", data, 12)[0]
    doc = json.loads(bytes(data[20:20 + n]))
    doc["accessors"][0]["max"] = [9.0, 9.0, 9.0]
    text = json.dumps(doc, separators=(",", ":")).encode()     # as compact as gsz's: it fits
    text += b" " * (n - len(text))
    assert len(text) == n
    data[20:20 + n] = text
    (tmp_path / "broken.glb").write_bytes(bytes(data))
    reports = {Path(r["file"]).name: r for r in gltf_checks.validate(files + [tmp_path / "broken.glb"])}
    for f in files:
        r = reports[f.name]
        assert gltf_checks.unexplained(r) == [], (f.name, gltf_checks.unexplained(r))
        assert r["numWarnings"] == 0
    assert any(m["code"] == "ACCESSOR_MAX_MISMATCH" for m in gltf_checks.unexplained(reports["broken.glb"]))


@pytest.mark.parametrize("sample", [SAMPLE_SH0, SAMPLE_SH3])
def test_three_js_builds_the_splats_the_ply_describes(sample, tmp_path):
    cloud = gsz.read_ply(sample)
    path = tmp_path / "scene.glb"
    gsz.save(cloud, path)
    got = gltf_checks.three_load(path, tmp_path / "three")
    diff = gltf_checks.compare_three(got, cloud)
    assert diff["count"] == len(cloud) and diff["position_abs"] == 0.0
    assert diff["covariance_rel"] < 1e-6          # float32 inputs; 1e-6 of each splat's largest term
    assert diff["color_levels"] <= 0.5 + 1e-6 and diff["sh_levels"] <= 0.5 + 1e-6   # rounded to 8 bits


@pytest.mark.parametrize("sample", [SAMPLE_SH0, SAMPLE_SH3])
def test_gsz_reads_splat_transforms_glb_as_the_ply(sample, tmp_path):
    cloud = gsz.read_ply(sample)
    back = gsz.load(gltf_checks.splat_transform_glb(sample, tmp_path / "st.glb"))
    d = gltf_checks.compare_clouds(back, cloud)
    assert d["count"]
    assert d["positions"] <= 1e-15 and d["rotations"] <= 1e-15    # it rotates with cos(pi) = -1 + tiny
    assert d["log_scales"] <= 2.0 ** -24 + 1e-6 and d["logits_over_bound"] <= 1.0
    assert d["sh_dc"] == 0.0 and d["sh_rest"] <= 1e-7


def test_three_js_without_the_gsz_extension_shows_nothing_rather_than_garbage(tmp_path):
    got = gltf_checks.three_load(VECTOR, tmp_path / "three")
    assert 'Unknown extension "EXT_gaussian_splatting_compression_gsz"' in got["warnings"]
    assert len(got["position"]) == 360
    assert not got["covariance"].any() and not got["color"][:, 3].any()     # zero-size, transparent
