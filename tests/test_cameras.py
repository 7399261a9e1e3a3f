"""Cameras: graphdeco cameras.json, COLMAP text/binary models, protocol split, default views."""
import json
import struct
import warnings

import numpy as np
import pytest

import gsz
from conftest import SAMPLE_SH0, SAMPLE_SH3, shared_scene
from gsz.decoder.errors import CameraFormatError
from gsz.evaluation.cameras import (Camera, default_cameras, detect_up, load_cameras, look_at, qvec_to_rotmat,
                                    read_cameras_json, read_colmap, robust_bounds, rotmat_to_qvec,
                                    write_cameras_json)


def _random_rotation(rng):
    q = rng.standard_normal(4)
    return qvec_to_rotmat(q / np.linalg.norm(q))


def _project(cam, x):
    """(u, v, z) of world points x [N,3] in pixel coordinates of cam."""
    xc = x @ cam.R.T + cam.t
    z = xc[:, 2]
    return cam.fx * xc[:, 0] / z + cam.cx, cam.fy * xc[:, 1] / z + cam.cy, z


# --- graphdeco cameras.json ---------------------------------------------------------------------

def test_cameras_json_uses_graphdeco_c2w_convention(tmp_path):
    # A camera 5 units out on -x looking along +x, world y down: its axes in world coordinates
    # are the COLUMNS of graphdeco's 'rotation' (right = -z, down = +y, forward = +x).
    right, down, fwd = np.array([0, 0, -1.0]), np.array([0, 1.0, 0]), np.array([1.0, 0, 0])
    c2w = np.stack([right, down, fwd], axis=1)
    entry = {"id": 0, "img_name": "v0", "width": 640, "height": 480,
             "position": [-5.0, 0.0, 0.0], "rotation": c2w.tolist(), "fx": 500.0, "fy": 510.0}
    p = tmp_path / "cameras.json"
    p.write_text(json.dumps([entry]))
    (cam,) = read_cameras_json(p)
    assert np.allclose(cam.center, [-5, 0, 0])
    assert (cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height) == (500, 510, 320, 240, 640, 480)
    u, v, z = _project(cam, np.array([[0.0, 0, 0], [0, 0, -1.0], [0, -1.0, 0]]))
    assert np.allclose(z, 5) and np.allclose([u[0], v[0]], [320, 240])  # origin dead ahead
    assert u[1] > 320 and np.isclose(v[1], 240)   # world -z is camera right
    assert v[2] < 240 and np.isclose(u[2], 320)   # world -y is image up


def test_cameras_json_round_trip(tmp_path, sample_sh3):
    cams = default_cameras(sample_sh3, n_train=5, n_test=2, width=320, height=200)
    cams = cams.train + cams.test
    p = tmp_path / "out" / "cameras.json"
    write_cameras_json(cams, p)
    back = read_cameras_json(p)
    assert [c.name for c in back] == [c.name for c in cams]
    for a, b in zip(cams, back):
        assert np.allclose(a.R, b.R, atol=1e-12) and np.allclose(a.t, b.t, atol=1e-12)
        assert (a.fx, a.fy, a.width, a.height) == (b.fx, b.fy, b.width, b.height)
        assert (b.cx, b.cy) == (a.width / 2, a.height / 2)
    # What graphdeco itself would read: rotation columns are camera axes, position = centre.
    raw = json.loads(p.read_text())
    assert np.allclose(np.array(raw[0]["rotation"])[:, 2], cams[0].R[2])
    assert np.allclose(raw[0]["position"], cams[0].center)


@pytest.mark.parametrize("content, problem", [
    ("not json", "not valid JSON"),
    ('{"a": 1}', "expected a JSON list"),
    ('[{"id": 0, "width": 10}]', "lacks"),
    ('[{"width": 4, "height": 3, "position": [0,0], "rotation": [[1,0,0],[0,1,0],[0,0,1]],'
     ' "fx": 1, "fy": 1}]', "position"),
    ('[{"width": 4, "height": 3, "position": [0,0,0], "rotation": [[1,0,0],[0,1,0],[0,0,1]],'
     ' "fx": -1, "fy": 1}]', "focal"),
    ('[{"width": 4, "height": 3, "position": [0,0,0], "rotation": [[2,0,0],[0,1,0],[0,0,1]],'
     ' "fx": 1, "fy": 1}]', "rotation"),
])
def test_cameras_json_errors_name_file_and_problem(tmp_path, content, problem):
    p = tmp_path / "bad_cameras.json"
    p.write_text(content)
    with pytest.raises(CameraFormatError) as ei:
        read_cameras_json(p)
    assert "bad_cameras.json" in str(ei.value) and problem in str(ei.value)


def test_missing_camera_file(tmp_path):
    with pytest.raises(CameraFormatError, match="nope.json.*not found"):
        load_cameras(tmp_path / "nope.json", None)
    with pytest.raises(CameraFormatError, match="no cameras.json and no COLMAP model"):
        load_cameras(tmp_path, None)


# --- COLMAP ------------------------------------------------------------------------------------

# (camera id, model, model id, width, height, params, expected fx, fy, cx, cy)
_COLMAP_CAMS = [
    (1, "PINHOLE", 1, 640, 480, [500.0, 505.0, 321.5, 239.5], (500, 505, 321.5, 239.5)),
    (2, "SIMPLE_PINHOLE", 0, 800, 600, [700.0, 400.0, 300.0], (700, 700, 400, 300)),
    (3, "SIMPLE_RADIAL", 2, 1000, 500, [900.0, 500.0, 250.0, 0.0], (900, 900, 500, 250)),
    (4, "RADIAL", 3, 320, 240, [300.0, 160.0, 120.0, 0.0, 0.0], (300, 300, 160, 120)),
    (5, "OPENCV", 4, 1920, 1080, [1500.0, 1490.0, 960.0, 540.0, 0, 0, 0, 0], (1500, 1490, 960, 540)),
]


def _colmap_scene(n_images=5, seed=7):
    rng = np.random.default_rng(seed)
    # Names deliberately not in id order, to check sorting by name.
    names = [f"img_{k:02d}.png" for k in rng.permutation(n_images)]
    images = []
    for i in range(n_images):
        R = _random_rotation(rng)
        images.append((i + 1, rotmat_to_qvec(R), rng.standard_normal(3) * 3, _COLMAP_CAMS[i % 5][0], names[i], R))
    return images


def _write_colmap_text(folder, images, empty_points_lines=True):
    folder.mkdir(parents=True, exist_ok=True)
    with open(folder / "cameras.txt", "w") as f:
        f.write("# Camera list with one line of data per camera:\n# CAMERA_ID, MODEL, ...\n")
        for cid, model, _, w, h, params, _ in _COLMAP_CAMS:
            f.write(f"{cid} {model} {w} {h} " + " ".join(repr(p) for p in params) + "\n")
    with open(folder / "images.txt", "w") as f:
        f.write("# Image list with two lines of data per image:\n# IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n")
        for iid, q, t, cid, name, _ in images:
            f.write(f"{iid} " + " ".join(repr(float(v)) for v in (*q, *t)) + f" {cid} {name}\n")
            f.write("\n" if empty_points_lines else "12.5 20.25 -1 30.0 40.0 7\n")


def _write_colmap_binary(folder, images, n_cameras_override=None):
    folder.mkdir(parents=True, exist_ok=True)
    b = struct.pack("<Q", len(_COLMAP_CAMS) if n_cameras_override is None else n_cameras_override)
    for cid, _, mid, w, h, params, _ in _COLMAP_CAMS:
        b += struct.pack("<iiQQ", cid, mid, w, h) + struct.pack(f"<{len(params)}d", *params)
    (folder / "cameras.bin").write_bytes(b)
    b = struct.pack("<Q", len(images))
    for iid, q, t, cid, name, _ in images:
        b += struct.pack("<i4d3di", iid, *q, *t, cid) + name.encode() + b"\0"
        b += struct.pack("<Q", 2) + struct.pack("<ddq", 1.0, 2.0, -1) + struct.pack("<ddq", 3.0, 4.0, 5)
    (folder / "images.bin").write_bytes(b)


def _check_colmap(cams, images):
    by_name = {name: (R, t, cid) for _, _, t, cid, name, R in images}
    assert [c.name for c in cams] == sorted(by_name)
    intr = {c[0]: c[6] for c in _COLMAP_CAMS}
    size = {c[0]: (c[3], c[4]) for c in _COLMAP_CAMS}
    for c in cams:
        R, t, cid = by_name[c.name]
        assert np.allclose(c.R, R, atol=1e-12) and np.allclose(c.t, t, atol=1e-12)
        assert (c.fx, c.fy, c.cx, c.cy) == intr[cid]
        assert (c.width, c.height) == size[cid]


def test_colmap_text_model(tmp_path):
    images = _colmap_scene()
    _write_colmap_text(tmp_path / "scene" / "sparse" / "0", images)
    # The scene root, sparse/ and sparse/0 all resolve to the model.
    for p in (tmp_path / "scene", tmp_path / "scene" / "sparse", tmp_path / "scene" / "sparse" / "0"):
        _check_colmap(read_colmap(p), images)


def test_colmap_text_with_points_lines(tmp_path):
    images = _colmap_scene(n_images=4, seed=3)
    _write_colmap_text(tmp_path / "m", images, empty_points_lines=False)
    _check_colmap(read_colmap(tmp_path / "m"), images)


def test_colmap_binary_model(tmp_path):
    images = _colmap_scene(n_images=6, seed=11)
    _write_colmap_binary(tmp_path / "sparse" / "0", images)
    _check_colmap(read_colmap(tmp_path), images)


def test_colmap_distortion_is_dropped_with_warning(tmp_path):
    images = _colmap_scene(n_images=5)
    _write_colmap_text(tmp_path, images)
    txt = (tmp_path / "cameras.txt").read_text().replace(
        "1500.0 1490.0 960.0 540.0 0 0 0 0", "1500.0 1490.0 960.0 540.0 0.1 0 0 0")
    (tmp_path / "cameras.txt").write_text(txt)
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        cams = read_colmap(tmp_path)
    assert any("distortion" in str(x.message) for x in w)
    assert len(cams) == 5


def test_colmap_errors(tmp_path):
    images = _colmap_scene(n_images=3)
    # Unsupported (fisheye) model.
    _write_colmap_text(tmp_path / "a", images)
    p = tmp_path / "a" / "cameras.txt"
    p.write_text(p.read_text().replace("SIMPLE_RADIAL 1000 500 900.0 500.0 250.0 0.0",
                                       "OPENCV_FISHEYE 1000 500 1 2 3 4 5 6 7 8"))
    with pytest.raises(CameraFormatError, match="cameras.txt.*OPENCV_FISHEYE is not supported"):
        read_colmap(tmp_path / "a")
    # Image referring to a missing camera id.
    _write_colmap_text(tmp_path / "b", images)
    p = tmp_path / "b" / "images.txt"
    lines = p.read_text().split("\n")
    lines[2] = " ".join(lines[2].split()[:8] + ["99"] + lines[2].split()[9:])
    p.write_text("\n".join(lines))
    with pytest.raises(CameraFormatError, match="images.txt.*camera id 99"):
        read_colmap(tmp_path / "b")
    # Truncated binary and a hostile camera count: clear errors, no huge allocation or hang.
    _write_colmap_binary(tmp_path / "c", images)
    data = (tmp_path / "c" / "images.bin").read_bytes()
    (tmp_path / "c" / "images.bin").write_bytes(data[:-30])
    with pytest.raises(CameraFormatError, match="images.bin"):
        read_colmap(tmp_path / "c")
    _write_colmap_binary(tmp_path / "d", images, n_cameras_override=2 ** 62)
    with pytest.raises(CameraFormatError, match="cameras.bin.*claims"):
        read_colmap(tmp_path / "d")


def test_load_cameras_protocol_split_and_rescale(tmp_path):
    rng = np.random.default_rng(0)
    cams = []
    for i in range(17):
        R = _random_rotation(rng)
        cams.append(Camera(R, rng.standard_normal(3), 1000, 1000, 1000, 500, 2000, 1000, f"im{i:03d}"))
    rng.shuffle(cams)
    write_cameras_json(cams, tmp_path / "cameras.json")
    cs = load_cameras(tmp_path / "cameras.json", None, width=400)
    assert [c.name for c in cs.test] == ["im000", "im008", "im016"]
    assert len(cs.train) == 14 and "im001" in [c.name for c in cs.train]
    c = cs.test[1]
    assert (c.width, c.height, c.fx, c.cx, c.cy) == (400, 200, 200, 200, 100)
    # No width: the protocol caps images at 1600 px wide; a folder holding cameras.json works.
    cs = load_cameras(tmp_path, None)
    assert cs.test[0].width == 1600 and cs.test[0].height == 800


# --- default viewpoints ------------------------------------------------------------------------

def _assert_views_show_content(cloud, label):
    x = cloud.positions.astype(np.float64)
    lo, hi, inside = robust_bounds(x)
    x = x[inside]
    if len(x) > 20000:  # a seeded sample keeps the 32-view check fast on the 542k-point scene
        x = x[np.random.default_rng(0).choice(len(x), 20000, replace=False)]
    cs = default_cameras(cloud)
    assert len(cs.train) == 24 and len(cs.test) == 8
    centres = np.array([c.center for c in cs.train + cs.test])
    # All viewpoints distinct (train and test interleaved, never the same place).
    d = np.linalg.norm(centres[:, None] - centres[None], axis=-1)
    assert d[~np.eye(len(d), dtype=bool)].min() > 1e-3 * np.linalg.norm(hi - lo), label
    for cam in cs.train + cs.test:
        assert np.allclose(cam.R @ cam.R.T, np.eye(3), atol=1e-9) and np.isclose(np.linalg.det(cam.R), 1)
        u, v, z = _project(cam, x)
        # In view AND beyond the renderer's near plane (graphdeco culls depth <= 0.2).
        seen = (z > 0.2) & (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
        assert seen.mean() >= 0.8, f"{label} {cam.name}: only {seen.mean():.1%} of the content in view"
        # The content is not a speck: it spans at least a third of the frame.
        span = max((np.percentile(u, 95) - np.percentile(u, 5)) / cam.width,
                   (np.percentile(v, 95) - np.percentile(v, 5)) / cam.height)
        assert span > 1 / 3, f"{label} {cam.name}: content spans only {span:.0%} of the frame"
        # The robust centre is dead ahead.
        uc, vc, zc = _project(cam, ((lo + hi) / 2)[None])
        assert zc[0] > 0 and np.allclose([uc[0], vc[0]], [cam.cx, cam.cy])


@pytest.mark.parametrize("path", [SAMPLE_SH0, SAMPLE_SH3], ids=lambda p: p.name)
def test_default_cameras_show_content_samples(path):
    _assert_views_show_content(gsz.read_ply(path), path.name)


@pytest.mark.shared
@pytest.mark.parametrize("name", [
    "houseplant_sh0.ply", "measuring_jug_sh3.ply", "plaza_taebak_crop_sh0.ply",
    "showroom_lacadiere_crop_sh0.ply", "tiny_graphdeco_iter7000_sh3.ply",
    "flowers_daffodils_sh2.ply"])
def test_default_cameras_show_content_shared(name):
    _assert_views_show_content(gsz.read_ply(shared_scene(name)), name)


def test_default_cameras_deterministic_upright_and_robust_to_outliers(sample_sh0):
    a = default_cameras(sample_sh0, n_train=6, n_test=3, width=160, height=120)
    b = default_cameras(sample_sh0.copy(), n_train=6, n_test=3, width=160, height=120)
    assert detect_up(sample_sh0.positions) == "-y"
    assert [c.name for c in a.test] == ["test_000", "test_001", "test_002"]
    for x, y in zip(a.train + a.test, b.train + b.test):
        assert np.array_equal(x.R, y.R) and np.array_equal(x.t, y.t)
    for c in a.train + a.test:
        # Up is -y: the camera's down axis (R row 1) points along world +y, never sideways.
        assert c.R[1] @ np.array([0, 1.0, 0]) > 0.3
        assert (c.width, c.height, c.cx, c.cy) == (160, 120, 80, 60)
    # A handful of far floaters (0.5 % of points, 1000x away) do not move the cameras.
    far = sample_sh0.copy()
    n = len(far) // 200
    far.positions[:n] = np.random.default_rng(1).standard_normal((n, 3)) * 1000
    c = default_cameras(far, n_train=6, n_test=3, width=160, height=120)
    dist = [np.linalg.norm(x.center - y.center) for x, y in zip(a.test, c.test)]
    assert max(dist) < 0.1 * np.linalg.norm(a.test[0].center - a.train[0].center) + 0.05
    # A z-up request gives z-up cameras.
    z = default_cameras(sample_sh0, n_train=4, n_test=2, up="+z")
    assert all(cam.R[1] @ np.array([0, 0, -1.0]) > 0.3 for cam in z.train + z.test)


def test_look_at_degenerate_direction():
    cam = look_at([0, -5.0, 0], [0, 0, 0], [0, -1.0, 0], fx=100, fy=100, width=64, height=64)
    assert np.allclose(cam.R @ cam.R.T, np.eye(3)) and np.isclose(np.linalg.det(cam.R), 1)
    u, v, z = _project(cam, np.zeros((1, 3)))
    assert np.isclose(z[0], 5) and np.allclose([u[0], v[0]], [32, 32])


def test_load_cameras_default_width_and_aspect(sample_sh3):
    cs = load_cameras(None, sample_sh3, n_train=3, n_test=2, width=160)
    assert len(cs.train) == 3 and len(cs.test) == 2
    assert (cs.test[0].width, cs.test[0].height) == (160, 120)


def test_detect_up_reads_the_ground_plane(sample_sh0, sample_sh3):
    # houseplant: pot on the ground at +y (y down, as its source states); jug: its file is
    # y-up, the blue table it stands on is at low y.
    assert detect_up(sample_sh0.positions) == "-y"
    assert detect_up(sample_sh3.positions) == "+y"
    flipped = sample_sh0.positions * np.array([1, -1, 1], np.float32)
    assert detect_up(flipped) == "+y"
    cams = default_cameras(sample_sh3, n_train=3, n_test=1)
    assert all(c.R[1] @ np.array([0, -1.0, 0]) > 0.3 for c in cams.train + cams.test)


@pytest.mark.shared
@pytest.mark.parametrize("name", ["houseplant_sh0.ply", "flowers_daffodils_sh2.ply",
                                  "plaza_taebak_crop_sh0.ply", "measuring_jug_sh3.ply"])
def test_detect_up_shared(name):
    expected = "+y" if name.startswith("measuring_jug") else "-y"
    assert detect_up(gsz.read_ply(shared_scene(name)).positions) == expected
