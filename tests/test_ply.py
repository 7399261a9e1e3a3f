"""PLY reading/writing: exact round trips, every SH degree, clear errors naming file and property."""
import os
import warnings

import numpy as np
import pytest

import gsz
from gsz.decoder import PlyFormatError
from conftest import SAMPLE_SH0, SAMPLE_SH3, shared_scene


def _random_cloud(n, degree, seed=0):
    rng = np.random.default_rng(seed)
    k = {0: 0, 1: 3, 2: 8, 3: 15}[degree]
    return gsz.GaussianCloud(
        positions=rng.normal(size=(n, 3)), scales=rng.normal(-5, 1, size=(n, 3)),
        rotations=rng.normal(size=(n, 4)), opacities=rng.normal(size=n),
        sh_dc=rng.normal(size=(n, 3)), sh_rest=rng.normal(scale=0.1, size=(n, k, 3)), sh_degree=degree)


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_round_trip_exact_every_degree(tmp_path, degree):
    c = _random_cloud(257, degree, seed=degree)
    p = tmp_path / f"d{degree}.ply"
    gsz.write_ply(c, p)
    d = gsz.read_ply(p)
    assert d.sh_degree == degree
    assert d.equals(c)


@pytest.mark.parametrize("path", [SAMPLE_SH0, SAMPLE_SH3])
def test_real_sample_round_trip_is_byte_identical_in_values(tmp_path, path):
    c = gsz.read_ply(path)
    c.validate()
    gsz.write_ply(c, tmp_path / "x.ply")
    assert gsz.read_ply(tmp_path / "x.ply").equals(c)


@pytest.mark.parametrize("order", ["graphdeco", "shuffled"])
def test_read_in_blocks_is_the_same_cloud(tmp_path, monkeypatch, order):
    # blocks of a few records (a file read through the buffer, or converted from its records
    # when the columns are in another order or mixed): the same arrays as one block
    import gsz.decoder.ply as ply
    c = _random_cloud(1000, 3, seed=7)
    p = tmp_path / "x.ply"
    gsz.write_ply(c, p)
    if order == "shuffled":     # properties in reverse order, one of them float64
        from plyfile import PlyData, PlyElement
        v = PlyData.read(str(p))["vertex"].data
        names = list(v.dtype.names)[::-1]
        rec = np.empty(len(v), [(n, "<f8" if n == "opacity" else "<f4") for n in names])
        for n in names:
            rec[n] = v[n]
        PlyData([PlyElement.describe(rec, "vertex")]).write(str(p))
    whole = gsz.read_ply(p)
    monkeypatch.setattr(ply, "READ_ROWS", 64)
    assert gsz.read_ply(p).equals(whole) and whole.equals(c)


def test_channel_major_f_rest_layout(tmp_path):
    # f_rest_i in the file is channel-major: index = channel*K + coefficient
    c = _random_cloud(3, 3)
    gsz.write_ply(c, tmp_path / "x.ply")
    from plyfile import PlyData
    v = PlyData.read(str(tmp_path / "x.ply"))["vertex"].data
    assert np.float32(v["f_rest_16"][1]) == c.sh_rest[1, 1, 1]   # G channel (1), coefficient 1
    assert np.float32(v["f_rest_44"][2]) == c.sh_rest[2, 14, 2]


def test_shared_flowers_reads(tmp_path):
    c = gsz.read_ply(shared_scene("flowers_daffodils_sh2.ply"))
    assert len(c) == 542104 and c.sh_degree == 2 and c.sh_rest.shape == (542104, 8, 3)


def _write_raw_ply(path, names, rows):
    header = "ply\nformat binary_little_endian 1.0\nelement vertex %d\n" % len(rows)
    header += "".join(f"property float {n}\n" for n in names) + "end_header\n"
    with open(path, "wb") as f:
        f.write(header.encode())
        f.write(np.asarray(rows, "<f4").tobytes())


BASE = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity",
        "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]


def test_missing_property_names_file_and_property(tmp_path):
    p = tmp_path / "nodc.ply"
    names = [n for n in BASE if n != "scale_1"]
    _write_raw_ply(p, names, np.ones((4, len(names))))
    with pytest.raises(PlyFormatError) as e:
        gsz.read_ply(p)
    assert "scale_1" in str(e.value) and "nodc.ply" in str(e.value)


def test_odd_f_rest_count_is_rejected(tmp_path):
    p = tmp_path / "odd.ply"
    names = BASE + [f"f_rest_{i}" for i in range(10)]
    _write_raw_ply(p, names, np.ones((2, len(names))))
    with pytest.raises(PlyFormatError, match="10 f_rest"):
        gsz.read_ply(p)


def test_extra_properties_warn_and_are_ignored(tmp_path):
    p = tmp_path / "extra.ply"
    names = BASE + ["nx", "ny", "nz", "red", "confidence"]
    _write_raw_ply(p, names, np.ones((3, len(names))))
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        c = gsz.read_ply(p)
    assert len(c) == 3 and c.sh_degree == 0
    assert any("red" in str(x.message) and "confidence" in str(x.message) for x in w)
    assert not any("nx" in str(x.message) for x in w)


def test_non_finite_value_is_reported(tmp_path):
    p = tmp_path / "nan.ply"
    rows = np.ones((5, len(BASE)))
    rows[3, BASE.index("opacity")] = np.nan
    _write_raw_ply(p, BASE, rows)
    with pytest.raises(PlyFormatError, match=r"'opacity'.*vertex 3"):
        gsz.read_ply(p)


def test_truncated_and_garbage_files(tmp_path):
    good = tmp_path / "g.ply"
    gsz.write_ply(_random_cloud(100, 1), good)
    raw = good.read_bytes()
    (tmp_path / "t.ply").write_bytes(raw[: len(raw) - 37])
    with pytest.raises(PlyFormatError, match="t.ply"):
        gsz.read_ply(tmp_path / "t.ply")
    (tmp_path / "junk.ply").write_bytes(b"hello world\n" * 10)
    with pytest.raises(PlyFormatError, match="not a PLY"):
        gsz.read_ply(tmp_path / "junk.ply")
    with pytest.raises(PlyFormatError, match="not found"):
        gsz.read_ply(tmp_path / "missing.ply")


def test_write_is_atomic_on_failure(tmp_path, monkeypatch):
    p = tmp_path / "out.ply"
    p.write_bytes(b"previous")
    import gsz.decoder.io_util as io_util

    def boom(*a, **k):
        raise OSError("disk full")
    monkeypatch.setattr(io_util.os, "fsync", boom)
    with pytest.raises(OSError):
        gsz.write_ply(_random_cloud(10, 0), p)
    assert p.read_bytes() == b"previous"
    assert [x.name for x in tmp_path.iterdir()] == ["out.ply"]


def test_validate_reports_bad_shapes():
    c = _random_cloud(10, 1)
    c.scales = c.scales[:5]
    with pytest.raises(gsz.decoder.CloudValidationError, match="scales"):
        c.validate()


def test_written_files_get_normal_permissions(tmp_path):
    import os
    p = tmp_path / "perm.ply"
    gsz.write_ply(_random_cloud(4, 0), p)
    umask = os.umask(0)
    os.umask(umask)
    assert (p.stat().st_mode & 0o777) == (0o666 & ~umask)


def test_zero_vertex_ply_reads_as_an_empty_cloud(tmp_path):
    # A region decode can write one; reading it back must not crash in a reshape.
    for degree in (0, 3):
        p = tmp_path / f"empty{degree}.ply"
        gsz.write_ply(_random_cloud(5, degree).subset([]), p)
        c = gsz.read_ply(p)
        assert len(c) == 0 and c.sh_degree == degree and c.sh_rest.shape == (0, 15 if degree else 0, 3)


def test_device_fifo_and_huge_inputs_are_refused_before_reading(tmp_path):
    from gsz.decoder.io_util import MAX_INPUT_BYTES
    with pytest.raises(PlyFormatError, match=r"/dev/zero: is not a regular file"):
        gsz.read_ply("/dev/zero")
    fifo = tmp_path / "pipe.ply"
    os.mkfifo(fifo)                         # opening it would block: refused from its stat
    with pytest.raises(PlyFormatError, match="pipe.ply: is not a regular file"):
        gsz.read_ply(fifo)
    huge = tmp_path / "huge.ply"
    with open(huge, "wb") as f:             # sparse: no disk space used
        f.truncate(MAX_INPUT_BYTES + 1)
    with pytest.raises(PlyFormatError, match="huge.ply: is .* bytes, more than"):
        gsz.read_ply(huge)
