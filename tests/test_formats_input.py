"""Scene formats users have, read by gsz.load: each fixture in tests/data/formats was written by
the tool users write it with (splat-transform 3.10.2, the official SPZ library, GaussianSplats3D,
or a reference exporter re-implemented; see its README) from a fixed subset of a committed
sample, and must come back as that sample within the format's own quantisation."""
import io
import json
import os
import shutil
import subprocess
import sys
import warnings
import zipfile

import numpy as np
import pytest

import gsz
from conftest import DATA, SAMPLE_SH0, SAMPLE_SH3
from gsz.decoder.errors import (GszError, KsplatFormatError, MissingExtraError, PlyFormatError, SceneFormatError,
                                SogFormatError, SplatFormatError, SpzFormatError)
from gsz.decoder.formats import sniff_file
from gsz.decoder.frames import FRAME_SIGNS, flip_axes, sh_rest_signs

FORMATS = DATA / "formats"
C0 = 0.28209479177387814
BYTE = 1.0 / 255.0


@pytest.fixture(scope="module")
def sources():
    """The subsets the fixtures were written from (make_fixtures.subsets)."""
    jug, plant = gsz.read_ply(SAMPLE_SH3), gsz.read_ply(SAMPLE_SH0)
    return {"jug": jug.subset(np.arange(0, len(jug), 12)), "plant": plant.subset(np.arange(0, len(plant), 10))}


def _unit(q):
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def _sigmoid(v):
    return 1.0 / (1.0 + np.exp(-np.asarray(v, np.float64)))


def _match(cloud, src, tol):
    """``src`` reordered to ``cloud``'s order by nearest position (formats that sort or bucket
    their Gaussians); every Gaussian must find its own within ``tol``."""
    d2 = ((cloud.positions[:, None, :].astype(np.float64) - src.positions[None, :, :]) ** 2).sum(axis=2)
    idx = np.argmin(d2, axis=1)
    assert len(np.unique(idx)) == len(src), "decoded Gaussians do not pair one-to-one with the source"
    return src.subset(idx)


def check(cloud, src, *, pos, scale, rot, alpha, dc, rest=None, rest_mean=None, reorder=False, dc_outliers=0.0):
    """Per-field error bounds of a decoded cloud against its source.  Positions: Euclidean
    distance; rotations: 1 - |<q, q'>| of unit quaternions (the same rotation gives 0);
    opacities compared as alphas; colours only where the source colour is inside [0, 1] (the
    byte formats clamp it); ``dc_outliers`` is the fraction allowed past ``dc``."""
    assert len(cloud) == len(src)
    if reorder:
        src = _match(cloud, src, pos)
    k = cloud.sh_rest.shape[1]
    assert k <= src.sh_rest.shape[1]
    e_pos = np.linalg.norm(cloud.positions.astype(np.float64) - src.positions, axis=1).max()
    assert e_pos <= pos, f"positions off by {e_pos:.3g} > {pos:.3g}"
    e_scale = np.abs(cloud.scales - src.scales).max()
    assert e_scale <= scale, f"log-scales off by {e_scale:.3g} > {scale:.3g}"
    e_rot = (1.0 - np.abs((_unit(cloud.rotations.astype(np.float64)) * _unit(src.rotations.astype(np.float64))).sum(1))).max()
    assert e_rot <= rot, f"rotations off by {e_rot:.3g} > {rot:.3g}"
    e_alpha = np.abs(_sigmoid(cloud.opacities) - _sigmoid(src.opacities)).max()
    assert e_alpha <= alpha, f"alphas off by {e_alpha:.3g} > {alpha:.3g}"
    colour = 0.5 + C0 * src.sh_dc
    inside = ((colour >= 0) & (colour <= 1)).all(axis=1)
    e_dc = np.abs(cloud.sh_dc - src.sh_dc)[inside]
    assert np.mean(e_dc > dc) <= dc_outliers, f"{np.mean(e_dc > dc):.2%} of SH DC off by more than {dc:.3g}"
    if k:
        e = np.abs(cloud.sh_rest - src.sh_rest[:, :k])
        if rest is not None:
            assert e.max() <= rest, f"SH rest off by {e.max():.3g} > {rest:.3g}"
        if rest_mean is not None:
            bound = rest_mean * np.abs(src.sh_rest[:, :k]).mean()
            assert e.mean() <= bound, f"SH rest off by {e.mean():.3g} on average > {bound:.3g}"


def _spz_bounds():
    # 12 fractional position bits, log-scale (s + 10) * 16, colour 0.5 + 0.15 dc, SH 5 / 4 bits
    return dict(pos=np.sqrt(3) * 0.5 / 4096 + 1e-7, scale=1 / 32 + 1e-6, rot=5e-4, alpha=0.5 * BYTE + 1e-6,
                dc=0.5 * BYTE / 0.15 + 1e-5, rest=1 / 16 + 1e-6)


def _bounds(name, src):
    """The quantisation of each fixture's format, from the format's definition."""
    ext = float(np.ptp(src.positions, axis=0).max())
    if name.endswith(".spz"):
        return _spz_bounds()
    if name.endswith(".compressed.ply"):
        # 11/10/11 bits over each 256-Gaussian chunk's box and log-scale range, colour bytes over
        # its colour range, SH bytes over -4..4; the writer sorts the Gaussians (Morton order)
        colour = 0.5 + C0 * src.sh_dc
        return dict(pos=np.sqrt(3) * 0.5 * ext / 1023, scale=0.5 * float(np.ptp(src.scales, axis=0).max()) / 1023,
                    rot=1e-4, alpha=0.5 * BYTE + 1e-6, dc=0.5 * BYTE * max(1.0, float(np.ptp(colour))) / C0 + 1e-5,
                    rest=0.5 * 8 / 256 + 1e-6, reorder=True)
    if name.startswith(("jug.sog", "plant_sog")):
        # 16-bit log-warped positions, 256-entry k-means codebooks, 8-bit smallest-three, SH palette.
        # splat-transform 3.10.2's writer gives 4 of the plant's 2,000 colours its codebook's first
        # entry (its own reader decodes them the same): at most 0.5 % outliers
        return dict(pos=1e-4 * ext, scale=0.05, rot=3e-4, alpha=BYTE + 1e-6, dc=0.02, dc_outliers=0.005,
                    rest=0.25, rest_mean=0.5, reorder=True)
    if name.endswith(".ksplat"):
        level = int(name.split("_l")[1][0])
        # colour and alpha bytes truncated (floor); level 0 float32, levels 1-2 half floats and
        # 16-bit offsets from bucket centres, level 2 SH as bytes over the file's SH range
        b = dict(pos=1e-6 if level == 0 else 1e-4, scale=1e-5 if level == 0 else 2e-3, rot=1e-5,
                 alpha=BYTE + 1e-6, dc=BYTE / C0 + 1e-5, rest=[1e-6, 1e-3, 0.01][level], reorder=True)
        return b
    if name.endswith(".splat"):
        # float32 position and scale, truncated colour and alpha bytes, rotation bytes q * 128 + 128
        return dict(pos=1e-6, scale=1e-5, rot=3e-4, alpha=BYTE + 1e-6, dc=BYTE / C0 + 1e-5, reorder=True)
    if name.endswith("_rgb.ply"):
        # nerfstudio's rgb mode: the colour truncated to bytes, everything else float32
        return dict(pos=0, scale=0, rot=1e-7, alpha=1e-7, dc=BYTE / C0 + 1e-5)
    raise AssertionError(name)


FIXTURES = ["jug_v2.spz", "jug_v3.spz", "jug_v4.spz", "plant_v4.spz", "jug.compressed.ply",
            "plant.compressed.ply", "jug.sog", "plant_sog/meta.json", "plant_l0.ksplat", "jug_l1_sh1.ksplat",
            "jug_l2_sh2.ksplat", "plant.splat", "jug_rgb.ply"]
SH_DEGREE = {"jug_l1_sh1.ksplat": 1, "jug_l2_sh2.ksplat": 2, "jug_rgb.ply": 0}


@pytest.mark.parametrize("name", FIXTURES)
def test_fixture_loads_as_its_source(name, sources):
    src = sources[name.split("_")[0].split(".")[0]]
    cloud = gsz.load(FORMATS / name)
    assert cloud.sh_degree == SH_DEGREE.get(name, src.sh_degree)
    cloud.validate()
    check(cloud, src, **_bounds(name, src))


def test_every_fixture_is_small_and_listed():
    """Fixtures stay small (well under 200 kB) and each is exercised above."""
    files = {p.relative_to(FORMATS).as_posix() for p in FORMATS.rglob("*")
             if p.is_file() and p.suffix not in (".py", ".mjs", ".md")}
    assert all((FORMATS / f).stat().st_size < 120_000 for f in files)
    listed = set(FIXTURES) | {"jug_v3_rub.spz"} | {f"plant_sog/{t}.webp" for t in ("means_l", "means_u", "quats",
                                                                                       "scales", "sh0")}
    assert files == listed


def test_checks_catch_wrong_conventions(sources):
    """The bounds above fail a reader that gets a convention wrong: the frame, the quaternion's
    component order, the SH layout, log vs linear scales, logit vs alpha."""
    jug = sources["jug"]
    good = gsz.load(FORMATS / "jug_v3.spz")
    b = _spz_bounds()
    check(good, jug, **b)
    n, k = len(good), good.sh_rest.shape[1]
    wrong = {
        "frame (RUB read as RDF)": flip_axes(good, FRAME_SIGNS["RUB"]),
        "quaternion (x, y, z, w)": gsz.GaussianCloud(good.positions, good.scales, good.rotations[:, [1, 2, 3, 0]],
                                                     good.opacities, good.sh_dc, good.sh_rest, 3),
        "SH channel-major": gsz.GaussianCloud(good.positions, good.scales, good.rotations, good.opacities, good.sh_dc,
                                              good.sh_rest.transpose(0, 2, 1).reshape(n, k, 3), 3),
        "linear scales": gsz.GaussianCloud(good.positions, np.exp(good.scales), good.rotations, good.opacities,
                                           good.sh_dc, good.sh_rest, 3),
        "alpha as logit": gsz.GaussianCloud(good.positions, good.scales, good.rotations, _sigmoid(good.opacities),
                                            good.sh_dc, good.sh_rest, 3),
    }
    for what, cloud in wrong.items():
        with pytest.raises(AssertionError):
            check(cloud, jug, **b)
            pytest.fail(f"a reader with the wrong {what} would pass")
    sog = gsz.load(FORMATS / "jug.sog")             # a reordered format: the frame breaks the pairing
    with pytest.raises(AssertionError):
        check(flip_axes(sog, FRAME_SIGNS["RUB"]), jug, **_bounds("jug.sog", jug))


def test_spz_frames(sources):
    """A .spz converted to SPZ's documented RUB frame (the official library, from=RDF) reads back
    with frame="RUB", and a coordinate-system extension names the frame by itself."""
    from gsz.decoder.spz import read_spz, spz_bytes, spz_from_bytes
    jug = sources["jug"]
    check(read_spz(FORMATS / "jug_v3_rub.spz", frame="RUB"), jug, **_spz_bounds())
    with pytest.raises(AssertionError):              # read as RDF it is upside down
        check(read_spz(FORMATS / "jug_v3_rub.spz"), jug, **_spz_bounds())
    # Adobe's extension 0xADBE0003 (RUB = 4), in a version-4 header zone
    data = bytearray(spz_bytes(flip_axes(jug, FRAME_SIGNS["RUB"]), version=4))
    ext = (0xADBE0003).to_bytes(4, "little") + (4).to_bytes(4, "little") + (4).to_bytes(4, "little")
    data[14] |= 0x2
    data[16:20] = (32 + len(ext)).to_bytes(4, "little")
    data[32:32] = ext
    check(spz_from_bytes(bytes(data)), jug, **_spz_bounds())
    check(spz_from_bytes(bytes(data), frame="RDF"), jug, **_spz_bounds())       # the extension wins
    with pytest.raises(GszError, match="frame must be one of"):
        spz_from_bytes(bytes(data), frame="up")


def test_frame_flips_keep_the_scene():
    """flip_axes is a change of coordinates: covariances become S Sigma S (mirrors included) and
    the SH colour seen along S d equals the old one along d."""
    from gsz.decoder.khr import sh_basis
    rng = np.random.default_rng(3)
    n = 40
    cloud = gsz.GaussianCloud(rng.normal(size=(n, 3)), rng.normal(size=(n, 3)) - 3, rng.normal(size=(n, 4)),
                              rng.normal(size=n), rng.normal(size=(n, 3)), rng.normal(size=(n, 15, 3)), 3)

    def cov(c):
        q = _unit(c.rotations.astype(np.float64))
        w, x, y, z = q.T
        r = np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
                      2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                      2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], 1).reshape(-1, 3, 3)
        s = np.exp(2 * c.scales.astype(np.float64))
        return r @ (s[:, :, None] * r.transpose(0, 2, 1))

    dirs = _unit(rng.normal(size=(64, 3)))
    basis = np.concatenate([sh_basis(band, dirs) for band in (1, 2, 3)], axis=1)
    for name, signs in FRAME_SIGNS.items():
        s = np.array(signs, np.float64)
        out = flip_axes(cloud, signs)
        assert np.allclose(out.positions, cloud.positions * s)
        assert np.allclose(cov(out), s[None, :, None] * cov(cloud) * s[None, None, :], atol=1e-6), name
        moved = np.concatenate([sh_basis(band, dirs * s) for band in (1, 2, 3)], axis=1)
        assert np.allclose(np.einsum("mk,nkc->nmc", moved, out.sh_rest),
                           np.einsum("mk,nkc->nmc", basis, cloud.sh_rest), atol=1e-5), name
    assert list(sh_rest_signs(1, FRAME_SIGNS["RUB"])) == [-1, -1, 1]


@pytest.mark.parametrize("name", ["jug_v3.spz", "jug_v4.spz", "jug.sog", "plant_l0.ksplat", "plant.splat",
                                  "jug.compressed.ply", "plant_sog/meta.json"])
def test_detection_is_by_content(name, tmp_path):
    src = FORMATS / name
    if name.endswith("meta.json"):                  # the unbundled form: textures beside it
        shutil.copytree(src.parent, tmp_path / "scene")
        renamed = tmp_path / "scene" / "scene.bin"
        os.rename(tmp_path / "scene" / "meta.json", renamed)
    else:
        renamed = tmp_path / "scene.bin"
        shutil.copyfile(src, renamed)
    assert gsz.load(renamed).equals(gsz.load(src))
    assert sniff_file(renamed) == sniff_file(src)


def _expect_error(path, error=GszError, match=None):
    with pytest.raises(error, match=match) as e:
        gsz.load(path)
    msg = str(e.value)
    assert str(path) in msg and "\n" not in msg, msg
    return msg


@pytest.mark.parametrize("name", [n for n in FIXTURES if not n.endswith("meta.json")])
def test_truncated_files_give_one_clear_error(name, tmp_path):
    data = (FORMATS / name).read_bytes()
    for cut in (len(data) - 3, len(data) * 2 // 3, 40, 3):
        path = tmp_path / name.replace("/", "_")
        path.write_bytes(data[:cut])
        _expect_error(path)


def test_truncated_and_corrupt_files_say_what_is_wrong(tmp_path):
    def write(name, data):
        p = tmp_path / name
        p.write_bytes(data)
        return p

    spz3, spz4 = (FORMATS / "jug_v3.spz").read_bytes(), (FORMATS / "jug_v4.spz").read_bytes()
    _expect_error(write("a.spz", spz3[:-9]), SpzFormatError, "truncated")
    _expect_error(write("b.spz", spz3[: len(spz3) // 2]), SpzFormatError, "truncated: the gzip stream holds")
    bad = bytearray(spz3)
    bad[len(bad) // 2] ^= 0x55
    _expect_error(write("c.spz", bytes(bad)), SpzFormatError, "corrupt gzip data")
    _expect_error(write("d.spz", spz4[: len(spz4) - 100]), SpzFormatError, "truncated: the SH stream")
    bad = bytearray(spz4)
    bad[15] = 3                                          # stream count
    _expect_error(write("e.spz", bytes(bad)), SpzFormatError, "attribute streams")
    bad = bytearray(spz4)
    bad[8:12] = (1 << 30).to_bytes(4, "little")           # a bomb's Gaussian count
    _expect_error(write("f.spz", bytes(bad)), SpzFormatError, "max_gaussians")
    bad = bytearray(spz4)
    bad[4] = 9
    _expect_error(write("g.spz", bytes(bad)), SpzFormatError, "version 9")

    ks = (FORMATS / "jug_l2_sh2.ksplat").read_bytes()
    _expect_error(write("a.ksplat", ks[:-100]), KsplatFormatError, "truncated: section 0")
    bad = bytearray(ks)
    bad[20] = 7                                          # compression level
    _expect_error(write("b.ksplat", bytes(bad)), GszError, "compression level 7")
    bad = bytearray(ks)
    bad[16:20] = (999).to_bytes(4, "little")             # the header's Gaussian count
    _expect_error(write("c.ksplat", bytes(bad)), KsplatFormatError, "declares 999")

    sp = (FORMATS / "plant.splat").read_bytes()
    _expect_error(write("a.splat", sp[:-5]), GszError, "not a positive multiple of the 32-byte")
    bad = bytearray(sp)
    bad[12:16] = np.float32(-1).tobytes()                 # a negative scale in row 0
    _expect_error(write("b.splat", bytes(bad)), GszError, "row 0 holds a scale")

    sog = (FORMATS / "jug.sog").read_bytes()
    _expect_error(write("a.sog", sog[: len(sog) // 2]), SogFormatError, "not a readable .sog bundle")
    buf = io.BytesIO()
    with zipfile.ZipFile(io.BytesIO(sog)) as z, zipfile.ZipFile(buf, "w") as out:
        for info in z.infolist():
            data = z.read(info)
            if info.filename == "quats.webp":
                data = data[:40]
            out.writestr(info, data)
    _expect_error(write("b.sog", buf.getvalue()), SogFormatError, "texture quats.webp is not a readable WebP")
    folder = tmp_path / "unbundled"
    shutil.copytree(FORMATS / "plant_sog", folder)
    (folder / "sh0.webp").unlink()
    _expect_error(folder / "meta.json", SogFormatError, "its texture sh0.webp: file not found")
    meta = json.loads((FORMATS / "plant_sog" / "meta.json").read_text())
    meta["means"]["files"][0] = "../../etc/passwd"
    (folder / "meta.json").write_text(json.dumps(meta))
    _expect_error(folder / "meta.json", SogFormatError, "outside the scene's folder")

    cply = (FORMATS / "jug.compressed.ply").read_bytes()
    _expect_error(write("a.compressed.ply", cply[: len(cply) // 2]), PlyFormatError)
    _expect_error(write("x.bin", b"\x1f\x8b" + bytes(100)), GszError, "gzip data, but not an SPZ")
    lod = {"lodLevels": 2, "counts": [1, 1], "filenames": ["0_0/meta.json"], "tree": {"bound": {}}}
    _expect_error(write("lod-meta.json", json.dumps(lod).encode()), GszError, "streamed SOG")


def test_sog_needs_pillow_and_says_which_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "PIL", None)
    with pytest.raises(MissingExtraError, match=r"gsz\[formats\]"):
        gsz.load(FORMATS / "jug.sog")


def test_sog_version_1(tmp_path):
    """A legacy SOG meta (no version): per-axis mins and maxs instead of codebooks, the opacity
    logit in sh0's alpha, the SH palette's width giving its bands."""
    from PIL import Image
    rng = np.random.default_rng(5)
    n, side = 6, (4, 2)

    def save(name, texels):
        img = np.zeros((side[1] * side[0], 4), np.uint8)
        img[:len(texels)] = texels
        Image.fromarray(img.reshape(side[1], side[0], 4), "RGBA").save(tmp_path / name, "WEBP", lossless=True,
                                                                       exact=True)

    means = rng.integers(0, 65536, (n, 3))
    save("means_l.webp", np.c_[means & 255, np.zeros(n)].astype(np.uint8))
    save("means_u.webp", np.c_[means >> 8, np.zeros(n)].astype(np.uint8))
    quats = np.c_[rng.integers(0, 256, (n, 3)), np.full(n, 252)]           # w largest
    save("quats.webp", quats.astype(np.uint8))
    sc = rng.integers(0, 256, (n, 4))
    save("scales.webp", sc.astype(np.uint8))
    c0 = rng.integers(0, 256, (n, 4))
    save("sh0.webp", c0.astype(np.uint8))
    meta = {"means": {"shape": [n, 3], "mins": [-1, -2, -3], "maxs": [1, 2, 3], "files": ["means_l.webp", "means_u.webp"]},
            "scales": {"mins": [-8, -7, -6], "maxs": [-2, -1, 0], "files": ["scales.webp"]},
            "quats": {"files": ["quats.webp"]},
            "sh0": {"mins": [-2, -2, -2, -6], "maxs": [2, 2, 2, 6], "files": ["sh0.webp"]}}
    (tmp_path / "meta.json").write_text(json.dumps(meta))
    cloud = gsz.load(tmp_path / "meta.json")
    warped = np.array([-1, -2, -3]) + np.array([2, 4, 6]) * means / 65535
    assert np.allclose(cloud.positions, np.sign(warped) * np.expm1(np.abs(warped)), atol=1e-5)
    assert np.allclose(cloud.scales, np.array([-8, -7, -6]) + 6 * sc[:, :3] / 255, atol=1e-5)
    assert np.allclose(cloud.sh_dc, -2 + 4 * c0[:, :3] / 255, atol=1e-5)
    assert np.allclose(cloud.opacities, -6 + 12 * c0[:, 3] / 255, atol=1e-5)
    xyz = (quats[:, :3] / 255 * 2 - 1) / np.sqrt(2)
    w = np.sqrt(np.maximum(0, 1 - (xyz ** 2).sum(1)))
    assert np.allclose(cloud.rotations, _unit(np.c_[w, xyz]), atol=1e-6)


def test_ply_variants(tmp_path, sources):
    """nerfstudio's rgb colour with float channels, and 2DGS surfels (two scales)."""
    from plyfile import PlyData, PlyElement
    jug = sources["jug"].subset(np.arange(50))
    names = ["x", "y", "z", "red", "green", "blue", "opacity", "scale_0", "scale_1", "rot_0", "rot_1", "rot_2", "rot_3"]
    v = np.zeros(len(jug), [(p, "<f4") for p in names])
    colour = np.clip(0.5 + C0 * jug.sh_dc, 0, 1)
    for i, p in enumerate("xyz"):
        v[p] = jug.positions[:, i]
    for i, p in enumerate(("red", "green", "blue")):
        v[p] = colour[:, i]
    v["opacity"] = jug.opacities
    for i in range(2):
        v[f"scale_{i}"] = jug.scales[:, i]
    for i in range(4):
        v[f"rot_{i}"] = jug.rotations[:, i]
    path = tmp_path / "surfels.ply"
    PlyData([PlyElement.describe(v, "vertex")]).write(str(path))
    with pytest.warns(UserWarning, match="2D Gaussian"):
        cloud = gsz.load(path)
    assert np.allclose(0.5 + C0 * cloud.sh_dc, colour, atol=1e-6)
    assert np.allclose(cloud.scales[:, 2], jug.scales[:, :2].min(axis=1) - np.log(100), atol=1e-5)
    assert np.array_equal(cloud.scales[:, :2], jug.scales[:, :2])


def test_compressed_ply_no_longer_says_missing_x():
    """The issue's symptom: a PlayCanvas compressed PLY once failed with "missing vertex
    property 'x'"."""
    assert len(gsz.read_ply(FORMATS / "jug.compressed.ply")) == 1000


def test_save_spz_round_trip(tmp_path, sources):
    """gsz.save writes SPZ 3 (or 4) that gsz reads back within SPZ's quantisation, unchanged on
    a second round (the values sit on SPZ's grid; a quaternion may come back as its negative or
    pick another largest component when two tie, the same rotation)."""
    plant = sources["plant"]
    for version in (3, 4):
        path = tmp_path / f"p{version}.spz"
        gsz.save(plant, path, spz_version=version)
        back = gsz.load(path)
        check(back, plant, **_spz_bounds())
        gsz.save(back, tmp_path / "again.spz", spz_version=version)
        again = gsz.load(tmp_path / "again.spz")
        for f in ("positions", "scales", "opacities", "sh_dc", "sh_rest"):
            assert np.array_equal(getattr(again, f), getattr(back, f)), f
        assert (1 - np.abs((again.rotations * back.rotations).sum(1))).max() < 1e-6
    assert (tmp_path / "p3.spz").read_bytes()[:2] == b"\x1f\x8b" and (tmp_path / "p4.spz").read_bytes()[:4] == b"NGSP"
    with pytest.raises(GszError, match="SPZ version must be 3 or 4"):
        gsz.save(plant, tmp_path / "x.spz", spz_version=2)


def _cli(*args, check=True):
    code = ("import sys; from gsz.encoder.cli import main as e; from gsz.decoder.cli import decode_main as d; "
            "sys.exit({'encode': e, 'decode': d}[sys.argv[1]](sys.argv[2:]))")
    p = subprocess.run([sys.executable, "-c", code, *map(str, args)], capture_output=True, text=True)
    if check:
        assert p.returncode == 0, p.stderr
    return p


@pytest.mark.slow
def test_encode_an_spz_by_ratio_and_decode_to_spz(tmp_path):
    """gsz-encode IN.spz --ratio 8 (the ratio of the scene's PLY: an .spz is already
    compressed), then gsz-decode OUT.gsz -o BACK.spz in either version."""
    src = FORMATS / "plant_v4.spz"
    out = tmp_path / "plant.gsz"
    report = json.loads(_cli("encode", src, "-o", out, "--ratio", "8", "--json", "--train-views", "4",
                             "--importance-width", "120").stdout)
    from gsz.decoder.ply import graphdeco_ply_bytes
    ply_bytes = graphdeco_ply_bytes(2000, 0)
    assert report["bytes"] <= ply_bytes // 8 and report["ratio"] >= 8
    assert report["input_bytes"] == os.path.getsize(src)
    decoded = gsz.decoder.decode(out)
    for version in ("3", "4"):
        back = tmp_path / f"back{version}.spz"
        _cli("decode", out, "-o", back, "--spz-version", version)
        check(gsz.load(back), decoded, **_spz_bounds())
    p = _cli("decode", out, "-o", tmp_path / "x.spz", "--spz-version", "2", check=False)
    assert p.returncode == 2 and "invalid choice" in p.stderr


def test_error_types_and_no_warning_on_clean_files():
    """SceneFormatError is a ValueError and a GszError, one base for every delivery format."""
    for cls in (SpzFormatError, SplatFormatError, KsplatFormatError, SogFormatError):
        assert issubclass(cls, SceneFormatError) and issubclass(cls, GszError) and issubclass(cls, ValueError)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for name in FIXTURES:                           # no warning on a clean file of any format
            gsz.load(FORMATS / name)
