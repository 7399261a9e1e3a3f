"""The committed format test vectors decode to their documented values (format stability)."""
import hashlib
import json
from pathlib import Path

import numpy as np
import pytest

from gsz.decoder import decode
from gsz.decoder.container import read_container

VEC = Path(__file__).resolve().parent.parent / "format_spec" / "vectors"
NAMES = sorted(p.stem for p in VEC.glob("*.gsz"))


def test_vectors_exist():
    assert len(NAMES) >= 3


@pytest.mark.parametrize("name", NAMES)
def test_vector_decodes_to_expected_values(name):
    exp = json.loads((VEC / f"{name}.json").read_text())
    data = (VEC / f"{name}.gsz").read_bytes()
    assert hashlib.sha256(data).hexdigest() == exp["file_sha256"]
    cloud = decode(data)
    assert len(cloud) == exp["num_gaussians"] and cloud.sh_degree == exp["sh_degree"]
    for f, e in exp["fields"].items():
        a = np.ascontiguousarray(getattr(cloud, f), dtype="<f4")
        assert list(a.shape) == e["shape"], f
        assert hashlib.sha256(a.tobytes()).hexdigest() == e["sha256"], f
        np.testing.assert_array_equal(a.reshape(len(cloud), -1)[:2], np.asarray(e["first"], "<f4").reshape(2, -1))


@pytest.mark.parametrize("name", NAMES)
def test_vector_layers_decode_as_prefixes(name):
    from gsz.decoder import StreamDecoder
    exp = json.loads((VEC / f"{name}.json").read_text())
    data = (VEC / f"{name}.gsz").read_bytes()
    full = decode(data)
    dec = StreamDecoder()
    got = []
    for row in exp["layers"]:
        got += dec.feed(data[dec.bytes_received:row["decodable_at"]])
        assert dec.layers_decoded == row["layer"] + 1 and got[-1].layer_complete
        assert len(dec.cloud) == row["cumulative_gaussians"]
        np.testing.assert_array_equal(got[-1].cloud.positions, full.positions[:row["cumulative_gaussians"]])
    assert exp["layers"][-1]["cumulative_gaussians"] == exp["num_gaussians"]


def test_halving_vector_needs_the_count_halving(monkeypatch):
    # the vector is only worth its bytes if a decoder without OCTREE.md §4's halving fails on it
    import gsz.decoder.octree as octree
    from gsz.decoder import GszFormatError, native
    data = (VEC / "sh0_plant_20k_d13_halving.gsz").read_bytes()
    with native.numpy_only():
        right = decode(data)
        monkeypatch.setattr(octree, "COUNT_LIMIT", 1 << 60)
        try:
            wrong = decode(data)
        except GszFormatError:
            return                      # the occupancy went wrong far enough to be rejected
    assert not np.array_equal(wrong.positions, right.positions)


def test_sh_classes_vector_needs_the_class_order(monkeypatch):
    # the SHCL vector is only worth its bytes if a decoder that ignores the class order fails
    import gsz.decoder.sh as sh
    from gsz.decoder import GszFormatError, native
    data = (VEC / "sh1_jug_2k_shclasses.gsz").read_bytes()
    right = decode(data)
    with native.numpy_only():
        assert decode(data).equals(right)
        monkeypatch.setattr(sh, "class_order", lambda classes: np.arange(len(classes)))
        wrong = decode(data)
    assert not np.array_equal(wrong.sh_rest, right.sh_rest)
    np.testing.assert_array_equal(wrong.positions, right.positions)
    monkeypatch.undo()
    if native.enabled():                        # the native path orders by class itself, checked
        assert decode(data).equals(right)
        with pytest.raises(GszFormatError, match="class outside"):
            native.module().sh_assemble(np.ones(2, np.int64), np.zeros((9, 2), np.uint16), np.ones((9, 1)),
                                        np.zeros((9, 1)), np.zeros(0, np.int64), np.zeros((9, 0)),
                                        np.empty((2, 9), np.float32), np.array([0, 16]))


def _decoded_on_each_path(data):
    """``data`` decoded by the NumPy path, then by the native one where it is built."""
    from gsz.decoder import native
    with native.numpy_only():
        yield decode(data)
    if native.enabled():
        yield decode(data)


def test_rwgt_vector_needs_the_leaf_weights(monkeypatch):
    # the RWGT vector is only worth its bytes if a decoder that ignores the weights (plain RAHT)
    # or the class order of the log-scales fails it
    import gsz.decoder.layer as layer
    from gsz.decoder import native
    data = (VEC / "sh1_jug_2k_rwgt.gsz").read_bytes()
    right = decode(data)
    with native.numpy_only():
        assert decode(data).equals(right)
    monkeypatch.setattr(layer, "leaf_weights_of", lambda rwgt: None)
    for wrong in _decoded_on_each_path(data):
        assert not np.array_equal(wrong.opacities, right.opacities)
        assert not np.array_equal(wrong.sh_dc, right.sh_dc)
        np.testing.assert_array_equal(wrong.positions, right.positions)
        np.testing.assert_array_equal(wrong.sh_rest, right.sh_rest)
    monkeypatch.undo()
    # ... and one that reads the log-scales in point order instead of class order
    monkeypatch.setattr(layer, "direct_in_point_order", lambda direct, rwgt: direct)
    for wrong in _decoded_on_each_path(data):
        assert not np.array_equal(wrong.scales, right.scales)
        np.testing.assert_array_equal(wrong.opacities, right.opacities)


def test_shxf_vector_needs_the_colour_transform(monkeypatch):
    # the SHXF vector is only worth its bytes if a decoder that ignores the transform fails it
    import gsz.decoder.sh as sh
    data = (VEC / "sh2_jug_2k_shxf.gsz").read_bytes()
    right = decode(data)
    for other in _decoded_on_each_path(data):
        assert other.equals(right)                  # both paths turn it back bit for bit
    monkeypatch.setattr(sh, "read_sh_colour", lambda chunk, sh_degree=None: 0)
    for wrong in _decoded_on_each_path(data):
        assert not np.array_equal(wrong.sh_rest, right.sh_rest)
        np.testing.assert_array_equal(wrong.sh_dc, right.sh_dc)


@pytest.mark.parametrize("name,bits", [("sh0_plant_2k_dcxf", 2), ("sh1_jug_2k_dcxf", 3)])
def test_dc_colour_vectors_need_the_dc_turn(monkeypatch, name, bits):
    # format 1.7: a decoder that ignores SHXF's DC bit returns luma/chroma as the DC colour
    import gsz.decoder.layer as layer
    data = (VEC / f"{name}.gsz").read_bytes()
    c = read_container(data)
    assert c.header.version == (1, 7)
    assert [ch.data for ch in c.chunks if ch.type == b"SHXF"] == [bytes([bits])]
    right = decode(data)
    for other in _decoded_on_each_path(data):
        assert other.equals(right)
    monkeypatch.setattr(layer, "turn_dc", lambda chunk, sh_dc, degree: True)
    for wrong in _decoded_on_each_path(data):
        assert not np.array_equal(wrong.sh_dc, right.sh_dc)
        np.testing.assert_array_equal(wrong.sh_rest, right.sh_rest)
        np.testing.assert_array_equal(wrong.opacities, right.opacities)
