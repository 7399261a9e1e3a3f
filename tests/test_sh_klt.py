"""The SH rest in its own principal axes (SHXF bit 2, format 1.8): the integer inverse is the
spec's bit for bit on both decoder paths, "auto" takes the KLT where the SH rest's components are
correlated and keeps luma/chroma where they are not (or where the matrix would not pay for
itself), the matrix travels once per tile, and a search with it stays within its budget."""
import dataclasses
from pathlib import Path

import numpy as np
import pytest

from gsz.decoder import decode, native
from gsz.decoder.container import read_container
from gsz.decoder.errors import GszFormatError, GszUsageError
from gsz.decoder.layout import CHUNK_SHXF
from gsz.decoder.sh import SH_COLOUR_DC, SH_COLOUR_KLT, SH_COLOUR_LUMA_CHROMA, klt_to_rgb
from gsz.encoder.pipeline import EncodeOptions, encode
from gsz.encoder.sh_colour import choose_sh_colour, klt_gain_db, klt_matrix, rgb_to_klt

from codec_util import FAST, decoded_on_both_paths, lowest_version, render_psnr, sample, sh3_off_grid

TINY = Path(__file__).resolve().parents[2] / "shared" / "data" / "tiny_graphdeco_iter7000_sh3.ply"


def _correlated(n=6000, seed=5):
    """The jug sample's Gaussians with an SH rest like a trained capture's: every component a
    mix of a few shared latent factors (one view-dependent effect moves many coefficients and
    all three colours together) plus a little independent noise."""
    c = sample("sh3", n)
    rng = np.random.default_rng(seed)
    latent = rng.normal(0, 1, (len(c), 4))
    mix = rng.normal(0, 0.08, (4, 45))
    rest = latent @ mix + rng.normal(0, 0.004, (len(c), 45))
    return dataclasses.replace(c, sh_rest=rest.reshape(len(c), 15, 3).astype(np.float32))


def test_inverse_is_the_spec_integer_formula_bit_for_bit():
    # GSZ.md §8.2 transform 2 in int64 (exact: every sum below 2^53), then one rounding to f32
    rng = np.random.default_rng(3)
    d = 45
    klt = rng.integers(-(1 << 14), 1 << 14, (d, d)).astype(np.int16)
    y = np.concatenate([rng.normal(0, 0.5, (300, d)), rng.uniform(-255.9, 255.9, (20, d)),
                        rng.normal(0, 1e-9, (5, d))]).astype(np.float32)
    y[0, :4] = np.float32(0.5 / (1 << 24)), np.float32(1.5 / (1 << 24)), np.float32(-2.5 / (1 << 24)), -0.0
    got = klt_to_rgb(y, klt)
    ints = np.rint(y.astype(np.float64) * 2.0 ** 24).astype(np.int64)       # ties to even
    assert ints[0, :3].tolist() == [0, 2, -2]
    exact = ints @ klt.astype(np.int64)
    assert np.all(np.abs(exact) < 2 ** 53)
    want = (exact.astype(np.float64) * 2.0 ** -38).astype(np.float32)
    assert got.tobytes() == want.tobytes()
    # in place gives the same values
    z = y.copy()
    assert klt_to_rgb(z, klt, out=z) is z and z.tobytes() == want.tobytes()


def test_a_stored_value_beyond_the_exact_range_is_rejected():
    klt = np.eye(9, dtype=np.int16) * (1 << 14)
    for bad in (256.0, -300.0, np.inf, np.nan):
        y = np.zeros((3, 9), np.float32)
        y[1, 4] = bad
        with pytest.raises(GszFormatError, match="KLT-coded SH value outside"):
            klt_to_rgb(y, klt)


def test_forward_then_inverse_gives_the_colours_back():
    sh = _correlated(2000).sh_rest
    klt = klt_matrix(sh)
    back = klt_to_rgb(rgb_to_klt(sh, klt).reshape(len(sh), -1), klt).reshape(sh.shape)
    np.testing.assert_allclose(back, sh, rtol=0, atol=1e-6 * float(np.abs(sh).max()))
    # the axes are near orthonormal (each a unit vector on the 2^-14 grid), largest variance first
    m = klt.astype(np.float64) / (1 << 14)
    np.testing.assert_allclose(m @ m.T, np.eye(45), atol=1e-3)
    var = rgb_to_klt(sh, klt).reshape(len(sh), -1).var(axis=0)
    assert var[0] == var.max() and var[:4].sum() > 0.95 * var.sum()


def test_the_matrix_is_a_function_of_the_data():
    sh = _correlated(3000).sh_rest
    a, b = klt_matrix(sh), klt_matrix(sh.copy())
    assert a.tobytes() == b.tobytes()
    # every axis's largest entry positive: the eigen-solver's sign choice does not reach the file
    big = np.abs(a).argmax(axis=1)
    assert np.all(a[np.arange(45), big] > 0)


def test_auto_takes_the_klt_for_correlated_sh_and_keeps_luma_chroma_otherwise():
    corr, noised = _correlated(), sh3_off_grid(6000)
    assert klt_gain_db(corr.sh_rest, klt_matrix(corr.sh_rest)) > 3.0
    # the jug's sparse, grid-shaped SH (noised too): a rotation spreads them, it loses
    assert klt_gain_db(noised.sh_rest, klt_matrix(noised.sh_rest)) < 0.5
    c = choose_sh_colour(corr, "auto", budget=2_000_000)
    assert c == SH_COLOUR_DC | SH_COLOUR_KLT and c.klt.shape == (45, 45)
    assert choose_sh_colour(noised, "auto", budget=2_000_000) == SH_COLOUR_DC | SH_COLOUR_LUMA_CHROMA
    # where the matrix (4 kB a tile) would be more than 1 % of the budget, it does not pay
    assert choose_sh_colour(corr, "auto", budget=200_000) == SH_COLOUR_DC | SH_COLOUR_LUMA_CHROMA
    assert choose_sh_colour(corr, "auto", budget=2_000_000, tile_gaussians=1024) == \
        SH_COLOUR_DC | SH_COLOUR_LUMA_CHROMA
    # forced, and never for a file without SH rest
    assert choose_sh_colour(noised, "klt") == SH_COLOUR_DC | SH_COLOUR_KLT
    assert choose_sh_colour(sample("sh0", 300), "klt") == SH_COLOUR_DC


def test_forcing_the_klt_on_huge_sh_values_is_a_clear_error():
    c = _correlated(500)
    c = dataclasses.replace(c, sh_rest=c.sh_rest * 400)
    with pytest.raises(GszUsageError, match="too large for the KLT"):
        choose_sh_colour(c, "klt")
    assert choose_sh_colour(c, "auto", budget=10 ** 9) == SH_COLOUR_DC | SH_COLOUR_LUMA_CHROMA


@pytest.mark.parametrize("n,layers,tiles", [(3000, 1, None), (9000, 2, 4096)])
def test_round_trip_on_both_decoder_paths_with_one_matrix_a_tile(n, layers, tiles):
    cloud = _correlated(n)
    res = encode(cloud, EncodeOptions(**FAST, keep=700, layers=layers, tile_gaussians=tiles, sh_colour="klt"))
    c = read_container(res.data)
    assert lowest_version(res.data) == "1.8" and c.header.version == (1, 8)
    xf = [ch for ch in c.chunks if ch.type == CHUNK_SHXF]
    assert len(xf) == sum(ch.type == b"GEOM" for ch in c.chunks)              # one per part
    with_matrix = [ch for ch in xf if len(ch.data) > 2]
    tiles_in_file = len({ch.flags >> 16 & 0xFFFF for ch in xf}) if tiles else 1
    assert len(with_matrix) == tiles_in_file and all(len(ch.data) == 2 + 2 * 45 * 45 for ch in with_matrix)
    assert all(ch.data == b"\x06\x00" for ch in xf if ch not in with_matrix)
    assert res.report.to_json()["sh"]["colour"] == "klt"
    ref = decoded_on_both_paths(res)
    if tiles:       # a tile decoded alone finds its matrix in its own layer 0
        last = tiles_in_file - 1
        alone = decode(res.data, tiles=[last])
        key = lambda c: np.lexsort(c.positions.T)
        rows = np.isin(ref.positions.view("V12").ravel(), alone.positions.view("V12").ravel())
        sub = ref.subset(np.flatnonzero(rows))
        assert len(sub) == len(alone) > 0
        np.testing.assert_array_equal(sub.sh_rest[key(sub)], alone.sh_rest[key(alone)])
    # the decoded SH are RGB again: the file renders at least like the luma/chroma one
    lc = encode(cloud, EncodeOptions(**FAST, keep=700, layers=layers, tile_gaussians=tiles, sh_colour="luma-chroma"))
    assert render_psnr(cloud, ref) > render_psnr(cloud, decode(lc.data)) - 0.2


def test_same_input_and_options_give_the_same_bytes():
    a = encode(_correlated(2000), EncodeOptions(**FAST, keep=300, sh_colour="klt"))
    b = encode(_correlated(2000), EncodeOptions(**FAST, keep=300, sh_colour="klt"))
    assert a.data == b.data


def test_size_search_with_the_klt_stays_within_budget_and_judges_what_a_decoder_shows():
    from gsz.encoder.search import SearchOptions, encode_to_budget
    from gsz.encoder.search.judge import eval_cameras, train_psnr
    from gsz.evaluation.evaluate import render_views
    cloud = _correlated(6000)
    target = 150_000                   # 12x: "auto" would not spend 4 kB on the matrix here
    sopts = SearchOptions(train_views=8, eval_views=3, eval_width=240, importance_width=240, sh_colour="klt")
    res = encode_to_budget(cloud, target, options=sopts)
    assert target * 0.995 <= len(res.data) <= target
    assert res.report.to_json()["sh_colour"] == "klt"
    with native.numpy_only():
        assert decode(res.data).equals(res.cloud)
    cams = eval_cameras(cloud, sopts)
    true, _, _ = train_psnr(render_views(cloud, cams), res.cloud, cams)
    assert abs(true - res.report.search.train_psnr) < 0.02
    # and it beats luma/chroma at the same budget on these correlated SH
    lc = encode_to_budget(cloud, target, options=dataclasses.replace(sopts, sh_colour="luma-chroma"))
    assert res.report.search.train_psnr > lc.report.search.train_psnr


@pytest.mark.skipif(not TINY.exists(), reason="needs ../shared (the trained tiny scene)")
def test_auto_takes_the_klt_on_a_trained_capture():
    import gsz
    cloud = gsz.read_ply(TINY)
    assert klt_gain_db(cloud.sh_rest, klt_matrix(cloud.sh_rest)) > 3.0
    assert choose_sh_colour(cloud, "auto", budget=420_922) == SH_COLOUR_DC | SH_COLOUR_KLT



@pytest.mark.skipif(not native.enabled(), reason="native accelerator not built")
@pytest.mark.parametrize("d", [9, 24, 45])
@pytest.mark.parametrize("simd", [0, 1, 2])
def test_native_assembly_turns_kept_vectors_and_codewords_as_the_reference_does(d, simd):
    # the C row loop's KLT (kept tiles, whole and partial, and codewords) against klt_to_rgb on
    # the same stored values, by the portable product, the AVX2/FMA one and the AVX-512 one
    # (each capped at what the CPU has: without AVX-512 level 2 runs the AVX2 loop)
    rng = np.random.default_rng(9 + d)
    m, k = 700, 5
    was = native.module().klt_simd(simd)
    try:
        _native_klt_case(rng, d, m, k)
    finally:
        native.module().klt_simd(was)


def _native_klt_case(rng, d, m, k):
    flags = (rng.random(m) < 0.6).astype(np.int64)
    p = int(flags.sum())
    kept = rng.integers(0, 1024, (d, p)).astype(np.uint16)
    steps, lo = rng.uniform(1e-4, 3e-3, (d, 1)), rng.uniform(-1.5, -0.5, (d, 1))
    cb = rng.normal(0, 0.4, (d, k))
    idx = rng.integers(0, k, m - p).astype(np.int64)
    klt = rng.integers(-(1 << 14), 1 << 14, (d, d)).astype(np.int16)
    out = np.empty((m, d), np.float32)
    assert native.module().sh_assemble(flags, kept, steps, lo, idx, cb, out, None, 0, klt.astype(np.float64))
    want = np.empty((m, d), np.float32)
    stored = (steps * kept.astype(np.float64) + lo).astype(np.float32).T
    want[flags == 1] = klt_to_rgb(stored, klt)
    want[flags == 0] = klt_to_rgb(cb.T.astype(np.float32), klt)[idx]
    assert out.tobytes() == want.tobytes()
    # a stored value beyond the exact range: the same error as the reference's
    with pytest.raises(GszFormatError, match=r"KLT-coded SH value outside \+-256"):
        native.module().sh_assemble(flags, kept, steps, lo + 300.0, idx, cb, out, None, 0, klt.astype(np.float64))
    with pytest.raises(GszFormatError, match=r"KLT-coded SH value outside \+-256"):
        native.module().sh_assemble(flags, kept, steps, lo, idx, cb * 1e3, out, None, 0, klt.astype(np.float64))
    # the kept vectors as residuals of a codeword each (SHRF): the sum in float32, then the KLT
    r = rng.integers(0, k, p).astype(np.int64)
    assert native.module().sh_assemble(flags, kept, steps, lo, idx, cb, out, None, 0, klt.astype(np.float64), r)
    summed = stored + cb.T.astype(np.float32)[r]
    want[flags == 1] = klt_to_rgb(summed, klt)
    assert out.tobytes() == want.tobytes()
    # a sum beyond the range, the residual and the codeword each within it: rejected
    far_cb = cb.copy()
    far_cb[:, r[p // 2]] = 200.0
    with pytest.raises(GszFormatError, match=r"KLT-coded SH value outside \+-256"):
        native.module().sh_assemble(flags, kept, steps, lo + 100.0, idx, far_cb, out, None, 0,
                                    klt.astype(np.float64), r)
