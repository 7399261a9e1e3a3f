"""Plain KHR_gaussian_splatting glTF: conventions, round trips within the stated float bounds
(format_spec/GLTF.md §1.3), what gsz writes, what it reads (quantised attributes, COLOR_0
fallbacks, node transforms) and its one-line errors."""
import json
import struct
import sys

import numpy as np
import pytest

import gsz
from conftest import SAMPLE_SH0, SAMPLE_SH3
from gsz.decoder import khr
from gsz.decoder.errors import GltfFormatError, GszError
from gsz.decoder.glb import parse_glb

pygltflib = pytest.importorskip("pygltflib")
from gsz.decoder.gltf import gltf_bytes, read_gltf_bytes, write_gltf  # noqa: E402

F32_EPS = 2.0 ** -24
SAMPLES = {"sh0": SAMPLE_SH0, "sh3": SAMPLE_SH3}


def ulp(v):
    return np.spacing(np.abs(np.asarray(v, np.float32))).astype(np.float64)


def accessor(data: bytes, name: str) -> np.ndarray:
    """An attribute's values straight from a gsz-written .glb (tightly packed float32 or
    uint8 views): an independent reading of the bytes, not through gsz's reader."""
    glb = parse_glb(data)
    doc = glb.doc
    acc = doc["accessors"][doc["meshes"][0]["primitives"][0]["attributes"][name]]
    view = doc["bufferViews"][acc["bufferView"]]
    width = {"SCALAR": 1, "VEC3": 3, "VEC4": 4}[acc["type"]]
    dtype = np.uint8 if acc["componentType"] == 5121 else np.dtype("<f4")
    start = glb.bin_offset + view.get("byteOffset", 0)
    return np.frombuffer(data, dtype, acc["count"] * width, start).reshape(acc["count"], width)


def assert_within_bounds(back, cloud):
    """GLTF.md §1.3: the round-trip bounds of PLY -> glTF -> PLY."""
    for f in ("positions", "sh_dc", "sh_rest"):
        np.testing.assert_array_equal(getattr(back, f), getattr(cloud, f), err_msg=f)
    q = cloud.rotations.astype(np.float64)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    assert (np.abs(back.rotations - q) <= ulp(q)).all()
    v = cloud.scales.astype(np.float64)
    assert (np.abs(back.scales - v) <= F32_EPS + ulp(v)).all()
    v = cloud.opacities.astype(np.float64)
    sig = khr.sigmoid(v)
    assert (np.abs(back.opacities - v) <= F32_EPS / (1 - sig) + 2 * ulp(v)).all()


@pytest.mark.parametrize("name", ["sh0", "sh3"])
@pytest.mark.parametrize("ext", [".glb", ".gltf"])
def test_ply_glb_ply_round_trip_is_exact_up_to_the_float_conventions(name, ext, tmp_path):
    cloud = gsz.read_ply(SAMPLES[name])
    path = tmp_path / f"scene{ext}"
    gsz.save(cloud, path)
    back = gsz.load(path)
    assert back.sh_degree == cloud.sh_degree and len(back) == len(cloud)
    assert_within_bounds(back, cloud)
    # the PLY written from the glTF reads back as the same cloud, bit for bit
    gsz.save(back, tmp_path / "back.ply")
    assert gsz.read_ply(tmp_path / "back.ply").equals(back)
    # the normalisation is the only change to rotations: the sample's are not unit length
    assert np.abs(np.linalg.norm(cloud.rotations, axis=1) - 1).max() > 1e-3


def test_attributes_follow_the_khr_conventions(sample_sh3):
    c = sample_sh3
    data = gltf_bytes(c)
    pos, scale = accessor(data, "POSITION"), accessor(data, "KHR_gaussian_splatting:SCALE")
    rot, opac = accessor(data, "KHR_gaussian_splatting:ROTATION"), accessor(data, "KHR_gaussian_splatting:OPACITY")
    np.testing.assert_array_equal(pos, c.positions * np.float32([-1, -1, 1]))        # RDF -> LUF
    np.testing.assert_allclose(scale, np.exp(c.scales.astype(np.float64)), rtol=F32_EPS)
    np.testing.assert_allclose(opac[:, 0], 1 / (1 + np.exp(-c.opacities.astype(np.float64))), rtol=F32_EPS)
    assert np.abs(np.linalg.norm(rot.astype(np.float64), axis=1) - 1).max() < 1e-6
    # the covariance a renderer builds from SCALE and the (x, y, z, w) ROTATION is the PLY's
    # covariance (from exp(scale) and the (w, x, y, z) quaternion) seen in the glTF frame
    def cov(q_xyzw, s):
        x, y, z, w = (q_xyzw[:, i] for i in range(4))
        r = np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
                      2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                      2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], 1).reshape(-1, 3, 3)
        m = r * s[:, None, :]
        return m @ m.transpose(0, 2, 1)
    q = c.rotations.astype(np.float64)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    flip = np.diag([-1.0, -1.0, 1.0])
    want = flip @ cov(q[:, [1, 2, 3, 0]], np.exp(c.scales.astype(np.float64))) @ flip
    got = cov(rot.astype(np.float64), scale.astype(np.float64))
    assert np.abs(got - want).max() <= 1e-6 * np.abs(want).max()
    # SH: DC unchanged, order m coefficients times (-1)^m
    np.testing.assert_array_equal(accessor(data, "KHR_gaussian_splatting:SH_DEGREE_0_COEF_0"), c.sh_dc)
    for band in (1, 2, 3):
        for n in range(2 * band + 1):
            got = accessor(data, f"KHR_gaussian_splatting:SH_DEGREE_{band}_COEF_{n}")
            np.testing.assert_array_equal(got, c.sh_rest[:, band * band - 1 + n] * (-1) ** (n - band))
    rgba = accessor(data, "COLOR_0").astype(np.int64)
    want = np.rint(255 * np.clip(np.c_[0.5 + khr.SH_C0 * c.sh_dc.astype(np.float64), khr.sigmoid(c.opacities)], 0, 1))
    assert np.abs(rgba - want).max() == 0
    doc = parse_glb(data).doc
    prim = doc["meshes"][0]["primitives"][0]
    assert prim["mode"] == 0 and doc["extensionsUsed"] == ["KHR_gaussian_splatting"]
    assert prim["extensions"]["KHR_gaussian_splatting"] == {
        "kernel": "ellipse", "colorSpace": "srgb_rec709_display", "projection": "perspective",
        "sortingMethod": "cameraDistance"}
    acc = doc["accessors"][prim["attributes"]["POSITION"]]
    assert acc["min"] == pos.min(0).tolist() and acc["max"] == pos.max(0).tolist()
    assert "extensionsRequired" not in doc


def test_same_cloud_same_bytes(sample_sh0, tmp_path):
    a, b = tmp_path / "a.glb", tmp_path / "b.glb"
    write_gltf(sample_sh0, a)
    write_gltf(sample_sh0.copy(), b)
    assert a.read_bytes() == b.read_bytes() == gltf_bytes(sample_sh0)
    assert gltf_bytes(sample_sh0, binary=False) == gltf_bytes(sample_sh0.copy(), binary=False)
    doc = json.loads(gltf_bytes(sample_sh0, binary=False))      # one file: the buffer is embedded
    assert doc["buffers"][0]["uri"].startswith("data:application/octet-stream;base64,")


def test_sh_band_rotations_match_the_basis():
    rng = np.random.default_rng(3)
    rot = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    rot *= np.sign(np.linalg.det(rot))
    d = rng.normal(size=(50, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    for band in (1, 2, 3):
        x = khr.sh_rotation(band, rot)
        c = rng.normal(size=2 * band + 1)
        # the rotated scene seen from rot @ d looks as the original seen from d
        np.testing.assert_allclose(khr.sh_basis(band, d @ rot.T) @ (x @ c), khr.sh_basis(band, d) @ c, atol=1e-12)
        signs = np.diag(khr.sh_rotation(band, np.diag([-1.0, -1.0, 1.0])))
        np.testing.assert_allclose(signs, [(-1) ** abs(m) for m in range(-band, band + 1)], atol=1e-12)


def _rebuild(data: bytes, edit) -> bytes:
    """``data`` (a gsz-written .glb) with its pygltflib document changed by ``edit(doc)``."""
    doc = pygltflib.GLTF2.load_from_bytes(data)
    edit(doc)
    return b"".join(doc.save_to_bytes())


def test_node_transforms_are_baked_and_instances_concatenated(sample_sh3):
    c = sample_sh3.subset(np.arange(300))
    data = gltf_bytes(c)
    ang = 0.7
    q_node = [0.0, np.sin(ang / 2), 0.0, np.cos(ang / 2)]                 # about +y, (x, y, z, w)
    t, s = [1.0, -2.0, 0.5], 2.0

    def edit(doc):
        doc.nodes[0].rotation, doc.nodes[0].translation, doc.nodes[0].scale = q_node, t, [s] * 3
        doc.nodes.append(pygltflib.Node(mesh=0))                       # a second, untransformed instance
        doc.scenes[0].nodes = [0, 1]
    both = read_gltf_bytes(_rebuild(data, edit))
    assert len(both) == 2 * len(c)
    moved, plain = both.subset(np.arange(len(c))), both.subset(np.arange(len(c), 2 * len(c)))
    assert_within_bounds(plain, c)
    # positions: T R S in the glTF frame, read back into RDF
    rot = np.array([[np.cos(ang), 0, np.sin(ang)], [0, 1, 0], [-np.sin(ang), 0, np.cos(ang)]])
    flip = np.diag([-1.0, -1.0, 1.0])
    want = (flip @ (s * rot @ (flip @ c.positions.T.astype(np.float64)) + np.array(t)[:, None])).T
    np.testing.assert_allclose(moved.positions, want, atol=1e-6)
    np.testing.assert_allclose(moved.scales, c.scales + np.log(s), atol=1e-5)
    # colour seen from a direction is the original's from the direction rotated back
    d = np.random.default_rng(0).normal(size=(4, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    world = flip @ rot @ flip                                            # the node rotation in RDF
    for band in (1, 2, 3):
        lo, hi = band * band - 1, (band + 1) ** 2 - 1
        old = np.einsum("dk,nkc->ndc", khr.sh_basis(band, d), c.sh_rest[:, lo:hi])
        new = np.einsum("dk,nkc->ndc", khr.sh_basis(band, d @ world.T), moved.sh_rest[:, lo:hi])
        np.testing.assert_allclose(new, old, atol=1e-5)

    def shear(doc):
        doc.nodes[0].scale = [1.0, 2.0, 1.0]
    with pytest.raises(GltfFormatError, match="non-uniform scale"):
        read_gltf_bytes(_rebuild(data, shear))


def _hand_glb(columns: dict, n: int, extensions=("KHR_gaussian_splatting",)) -> bytes:
    """A .glb built with pygltflib from {attribute: (array, componentType, normalized, type)}."""
    doc = pygltflib.GLTF2(scene=0, scenes=[pygltflib.Scene(nodes=[0])], nodes=[pygltflib.Node(mesh=0)])
    blob, attrs = bytearray(), {}
    for i, (name, (arr, ctype, norm, kind)) in enumerate(columns.items()):
        raw = np.ascontiguousarray(arr).tobytes()
        doc.bufferViews.append(pygltflib.BufferView(buffer=0, byteOffset=len(blob), byteLength=len(raw)))
        doc.accessors.append(pygltflib.Accessor(bufferView=i, componentType=ctype, normalized=norm or None,
                                                count=n, type=kind))
        attrs[name] = i
        blob += raw + b"\0" * (-len(raw) % 4)
    doc.buffers.append(pygltflib.Buffer(byteLength=len(blob)))
    doc.meshes.append(pygltflib.Mesh(primitives=[pygltflib.Primitive(
        attributes=pygltflib.Attributes(**attrs), mode=0,
        extensions={"KHR_gaussian_splatting": {"kernel": "ellipse", "colorSpace": "srgb_rec709_display"}})]))
    doc.extensionsUsed = list(extensions)
    doc.set_binary_blob(bytes(blob))
    return b"".join(doc.save_to_bytes())


def test_quantised_attributes_and_color0_fallbacks():
    n = 5
    rng = np.random.default_rng(1)
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q16 = np.rint(q * 32767).astype("<i2")
    op8 = np.array([0, 1, 128, 254, 255], np.uint8)
    rgba = np.array([[0, 128, 255, 0], [10, 20, 30, 40], [255, 255, 255, 255], [1, 2, 3, 128], [7, 8, 9, 200]], np.uint8)
    data = _hand_glb({
        "POSITION": (rng.normal(size=(n, 3)).astype("<f4"), 5126, False, "VEC3"),
        "KHR_gaussian_splatting:SCALE": (rng.integers(1, 127, (n, 3)).astype("<i1"), 5120, True, "VEC3"),
        "KHR_gaussian_splatting:ROTATION": (q16, 5122, True, "VEC4"),
        "KHR_gaussian_splatting:OPACITY": (op8, 5121, True, "SCALAR"),
        "COLOR_0": (rgba, 5121, True, "VEC4")}, n)
    c = read_gltf_bytes(data)
    assert c.sh_degree == 0
    a = (op8 / 255.0).astype(np.float32).astype(np.float64)       # normalized values are float32
    with np.errstate(divide="ignore"):
        want = np.clip(np.log(a) - np.log1p(-a), khr.LOG_FLOOR, khr.LOGIT_CEIL)
    np.testing.assert_allclose(c.opacities, want, rtol=1e-6)
    assert c.opacities[0] == khr.LOG_FLOOR and c.opacities[4] == khr.LOGIT_CEIL
    rgb = (rgba[:, :3] / 255.0).astype(np.float32).astype(np.float64)
    np.testing.assert_allclose(c.sh_dc, (rgb - 0.5) / khr.SH_C0, rtol=1e-6)
    # without OPACITY, COLOR_0's alpha stands in
    data = _hand_glb({
        "POSITION": (rng.normal(size=(n, 3)).astype("<f4"), 5126, False, "VEC3"),
        "KHR_gaussian_splatting:SCALE": (np.full((n, 3), 0.5, "<f4"), 5126, False, "VEC3"),
        "KHR_gaussian_splatting:ROTATION": (q.astype("<f4"), 5126, False, "VEC4"),
        "COLOR_0": (rgba, 5121, True, "VEC4")}, n)
    c = read_gltf_bytes(data)
    np.testing.assert_allclose(khr.sigmoid(c.opacities[1:4]), rgba[1:4, 3] / 255.0, rtol=1e-6)
    np.testing.assert_allclose(c.scales, np.log(0.5), rtol=1e-7)


def test_sparse_accessors_substitute_their_values(sample_sh0):
    c = sample_sh0.subset(np.arange(6))
    idx, vals = np.array([1, 4], "<u2"), np.array([[1, 2, 3], [4, 5, 6]], "<f4")

    def edit(doc):
        blob = bytearray(doc.binary_blob())
        views = []
        for raw in (idx.tobytes() + b"\0" * 4, vals.tobytes()):
            views.append(len(doc.bufferViews))
            doc.bufferViews.append(pygltflib.BufferView(buffer=0, byteOffset=len(blob), byteLength=len(raw)))
            blob += raw
        doc.buffers[0].byteLength = len(blob)
        doc.set_binary_blob(bytes(blob))
        doc.accessors[0].sparse = pygltflib.Sparse(
            count=2, indices=pygltflib.AccessorSparseIndices(bufferView=views[0], componentType=5123),
            values=pygltflib.AccessorSparseValues(bufferView=views[1]))
    back = read_gltf_bytes(_rebuild(gltf_bytes(c), edit))
    want = c.positions.copy()
    want[idx] = vals * np.float32([-1, -1, 1])                        # glTF frame -> RDF
    np.testing.assert_array_equal(back.positions, want)


def test_edge_values_saturate_as_specified(sample_sh0):
    c = sample_sh0.subset(np.arange(4))
    c.opacities[:] = [30.0, -200.0, 17.0, 0.0]
    c.scales[0] = -200.0                                   # exp underflows to 0 in float32
    back = read_gltf_bytes(gltf_bytes(c))
    assert back.opacities[0] == khr.LOGIT_CEIL and back.opacities[1] == khr.LOG_FLOOR
    assert (back.scales[0] == khr.LOG_FLOOR).all()
    again = read_gltf_bytes(gltf_bytes(back))              # the saturated values are fixed points
    np.testing.assert_array_equal(again.opacities[:2], back.opacities[:2])
    np.testing.assert_array_equal(again.scales[0], back.scales[0])
    huge = c.copy()
    huge.scales[2, 1] = 100.0
    with pytest.raises(GltfFormatError, match="log-scale above"):
        gltf_bytes(huge)


def _with_json(data: bytes, edit) -> bytes:
    """``data`` with its JSON chunk edited as a dict (the BIN chunk kept)."""
    glb = parse_glb(data)
    doc = glb.doc
    edit(doc)
    text = json.dumps(doc).encode()
    text += b" " * (-len(text) % 4)
    binary = data[glb.bin_offset - 8:]
    return struct.pack("<4sII", b"glTF", 2, 12 + 8 + len(text) + len(binary)) + struct.pack("<II", len(text), 0x4E4F534A) + text + binary


def test_bad_files_are_one_line_errors(sample_sh0, tmp_path):
    good = gltf_bytes(sample_sh0.subset(np.arange(10)))
    prim = lambda d: d["meshes"][0]["primitives"][0]  # noqa: E731
    cases = {
        "requires extension EXT_meshopt_compression": lambda d: d.update(extensionsRequired=["EXT_meshopt_compression"]),
        "has no KHR_gaussian_splatting:SCALE": lambda d: prim(d)["attributes"].pop("KHR_gaussian_splatting:SCALE"),
        "must have mode POINTS": lambda d: prim(d).update(mode=4),
        "missing KHR_gaussian_splatting:SH_DEGREE_1_COEF_2": lambda d: prim(d)["attributes"].update(
            {"KHR_gaussian_splatting:SH_DEGREE_1_COEF_0": 0, "KHR_gaussian_splatting:SH_DEGREE_1_COEF_1": 0}),
        "run past the end": lambda d: d["bufferViews"][0].update(byteLength=10 ** 6),
        "not an integer": lambda d: prim(d)["attributes"].update(POSITION="zero"),
        "asset.version": lambda d: d["asset"].update(version="1.0"),
        "no KHR_gaussian_splatting primitive": lambda d: prim(d).pop("extensions"),
    }
    for message, edit in cases.items():
        path = tmp_path / "bad.glb"
        path.write_bytes(_with_json(good, edit))
        with pytest.raises(GltfFormatError, match=message) as e:
            gsz.load(path)
        assert str(path) in str(e.value) and "\n" not in str(e.value)
    neg = sample_sh0.subset(np.arange(10))
    data = bytearray(gltf_bytes(neg))
    scale = parse_glb(bytes(data)).doc["bufferViews"][1]
    struct.pack_into("<f", data, parse_glb(bytes(data)).bin_offset + scale["byteOffset"], -1.0)
    with pytest.raises(GltfFormatError, match="negative"):
        read_gltf_bytes(bytes(data))
    (tmp_path / "cut.glb").write_bytes(good[:500])
    with pytest.raises(GltfFormatError, match="truncated"):
        gsz.load(tmp_path / "cut.glb")
    (tmp_path / "junk.gltf").write_bytes(b'{"asset": ')
    with pytest.raises(GltfFormatError, match="not valid glTF JSON"):
        gsz.load(tmp_path / "junk.gltf")
    (tmp_path / "x.bin").write_bytes(b"\x00" * 100)
    with pytest.raises(GszError, match="not a 3DGS PLY, .gsz, .glb or .gltf"):
        gsz.load(tmp_path / "x.bin")
    with pytest.raises(GszError, match="writes .ply, .spz, .glb or .gltf"):
        gsz.save(sample_sh0, tmp_path / "x.gsz")


def test_another_color_space_is_read_with_a_warning(sample_sh0):
    data = gltf_bytes(sample_sh0.subset(np.arange(10)))
    lin = _with_json(data, lambda d: d["meshes"][0]["primitives"][0]["extensions"]["KHR_gaussian_splatting"]
                     .update(colorSpace="lin_rec709_display"))
    with pytest.warns(UserWarning, match="lin_rec709_display"):
        a = read_gltf_bytes(lin)
    assert a.equals(read_gltf_bytes(data))


def test_files_are_told_by_content_not_name(sample_sh0, tmp_path):
    c = sample_sh0.subset(np.arange(50))
    (tmp_path / "scene.ply").write_bytes(gltf_bytes(c))          # a .glb under a PLY name
    (tmp_path / "scene.glb").write_bytes(gltf_bytes(c, binary=False))
    gsz.write_ply(c, tmp_path / "scene.gltf")
    a, b, p = (gsz.load(tmp_path / n) for n in ("scene.ply", "scene.glb", "scene.gltf"))
    assert a.equals(b) and p.equals(c)


def test_missing_pygltflib_is_one_line_naming_the_extra(sample_sh0, tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "pygltflib", None)           # import pygltflib -> ImportError
    with pytest.raises(GszError, match=r"pip install 'gsz\[gltf\]'"):
        gsz.save(sample_sh0, tmp_path / "x.glb")
    assert not (tmp_path / "x.glb").exists()
