"""The SH colour transform (SHXF chunk, formats 1.6 and 1.7): the encoder codes the SH rest and
the DC colour as luma/chroma where that pays, both decoder paths turn them back bit for bit, and
"auto" leaves an SH rest on a grid RGB."""
import dataclasses
import struct

import numpy as np
import pytest

from gsz.decoder import decode, native
from gsz.decoder.container import read_container
from gsz.decoder.layout import CHUNK_SHXF, KNOWN_CHUNKS
from gsz.decoder.sh import luma_chroma_to_rgb
from gsz.encoder.pipeline import EncodeOptions, encode
from gsz.encoder.sh_colour import choose_sh_colour, on_coarse_grid, rgb_to_luma_chroma

from codec_util import FAST, decoded_on_both_paths, lowest_version, render_psnr, sample, sh3_off_grid


def _f32(x: float) -> float:
    return struct.unpack("<f", struct.pack("<f", x))[0]


def test_inverse_is_the_spec_formula_bit_for_bit():
    # GSZ.md §8.2 in plain binary64 Python floats, one triplet at a time: an independent reading
    s3, s2, s6 = (float.fromhex(h) for h in ("0x1.279a74590331dp-1", "0x1.6a09e667f3bccp-1",
                                             "0x1.a20bd700c2c3fp-2"))
    rng = np.random.default_rng(3)
    v = np.concatenate([rng.normal(0, 0.3, (500, 3)), rng.normal(0, 1e-30, (20, 3)),
                        rng.uniform(-3e37, 3e37, (20, 3))]).astype(np.float32)
    got = luma_chroma_to_rgb(v)
    for (a, b, c), row in zip(v.tolist(), got.tolist()):
        a, b, c = a * s3, b * s2, c * s6
        assert row == [_f32((a + b) + c), _f32((a - b) + c), _f32(a - 2.0 * c)]


def test_forward_then_inverse_gives_the_colours_back():
    sh = sample("sh3", 2000).sh_rest
    back = luma_chroma_to_rgb(rgb_to_luma_chroma(sh))
    np.testing.assert_allclose(back, sh, rtol=0, atol=4e-7 * float(np.abs(sh).max()))


def test_auto_keeps_rgb_on_a_grid_and_picks_luma_chroma_off_it():
    grid = sample("sh3", 3000)                 # SPZ-delivered: a few values per component
    # bits: 1 the SH rest, 2 the DC (RAHT-coded: no grid to keep, so auto always turns it)
    assert on_coarse_grid(grid.sh_rest) and choose_sh_colour(grid) == 2
    assert not on_coarse_grid(sh3_off_grid().sh_rest) and choose_sh_colour(sh3_off_grid()) == 3
    assert choose_sh_colour(grid, "luma-chroma") == 3 and choose_sh_colour(sh3_off_grid(), "rgb") == 0
    assert choose_sh_colour(sample("sh0", 500)) == 2 and choose_sh_colour(sample("sh0", 500), "rgb") == 0


def test_fixed_encode_reports_the_dc_colour_space_of_an_sh0_file():
    """An SH-0 file has no SH rest, but its DC colour is coded as luma/chroma: the fixed
    configuration's JSON says so, as the search's does."""
    cloud = sample("sh0", 800)
    for option, name in (("auto", "luma-chroma DC"), ("rgb", "rgb")):
        js = encode(cloud, EncodeOptions(**FAST, sh_colour=option)).report.to_json()
        assert js["sh_colour"] == name and js["sh"] == {}


@pytest.mark.parametrize("n,layers,tiles", [(3000, 1, None), (9000, 2, 4096)])
def test_round_trip_on_both_decoder_paths(n, layers, tiles):
    cloud = sh3_off_grid(n)
    res = encode(cloud, EncodeOptions(**FAST, keep=700, layers=layers, tile_gaussians=tiles))
    c = read_container(res.data, known_types=KNOWN_CHUNKS)
    parts = sum(ch.type == b"GEOM" for ch in c.chunks)
    assert sum(ch.type == CHUNK_SHXF for ch in c.chunks) == parts > 0     # one per part
    assert lowest_version(res.data) == "1.7" and c.header.version == (1, 7)
    assert res.report.to_json()["sh"]["colour"] == "luma-chroma"
    ref = decoded_on_both_paths(res)
    # the decoded SH are RGB again: the file renders like the RGB file
    rgb = encode(cloud, EncodeOptions(**FAST, keep=700, layers=layers, tile_gaussians=tiles, sh_colour="rgb"))
    assert not any(ch.type == CHUNK_SHXF for ch in read_container(rgb.data, known_types=KNOWN_CHUNKS).chunks)
    assert render_psnr(cloud, ref) > render_psnr(cloud, decode(rgb.data)) - 0.2


def test_same_input_and_options_give_the_same_bytes():
    a = encode(sh3_off_grid(), EncodeOptions(**FAST, keep=300))
    b = encode(sh3_off_grid(), EncodeOptions(**FAST, keep=300))
    assert a.data == b.data and any(ch.type == CHUNK_SHXF for ch in read_container(a.data).chunks)


def test_size_search_codes_luma_chroma_within_budget_and_judges_the_colours_a_decoder_shows():
    from gsz.encoder.search import SearchOptions, encode_to_budget
    from gsz.encoder.search.judge import eval_cameras, train_psnr
    from gsz.evaluation.evaluate import render_views
    target, cloud = 120_000, sh3_off_grid()
    sopts = SearchOptions(train_views=8, eval_views=3, eval_width=240, importance_width=240)
    res = encode_to_budget(cloud, target, options=sopts)
    assert target * 0.995 <= len(res.data) <= target
    assert any(ch.type == CHUNK_SHXF for ch in read_container(res.data).chunks)
    assert res.report.to_json()["sh_colour"] == "luma-chroma"
    with native.numpy_only():
        assert decode(res.data).equals(res.cloud)
    # the PSNR the search chose by is the decoded RGB file's against the input (rendering the
    # rotated colours put the clamps elsewhere: 0.2 dB off on tiny at 12x)
    cams = eval_cameras(cloud, sopts)
    true, _, _ = train_psnr(render_views(cloud, cams), res.cloud, cams)
    assert abs(true - res.report.search.train_psnr) < 0.02


def test_a_bad_sh_colour_option_is_a_clear_error(tmp_path, capsys):
    from gsz.encoder.cli import main
    from gsz.encoder.pipeline import EncodeOptionsError
    with pytest.raises(EncodeOptionsError, match="sh-colour must be one of auto, rgb, luma-chroma"):
        EncodeOptions(sh_colour="ycc").validate()
    with pytest.raises(SystemExit):
        main([str(tmp_path / "x.ply"), "-o", str(tmp_path / "x.gsz"), "--sh-colour", "ycc"])
    assert "invalid choice: 'ycc'" in capsys.readouterr().err
    assert not (tmp_path / "x.gsz").exists()


def test_the_callers_cloud_is_left_alone_unless_it_is_handed_over():
    cloud = sh3_off_grid(2000)
    before = cloud.sh_rest.copy()
    a = encode(cloud, EncodeOptions(**FAST, keep=300))
    np.testing.assert_array_equal(cloud.sh_rest, before)          # an API caller's scene
    b = encode(cloud, EncodeOptions(**FAST, keep=300), reuse_input=True)   # the CLI's: reused
    assert a.data == b.data and not np.array_equal(cloud.sh_rest, before)


def test_sh0_scene_codes_its_dc_as_luma_chroma_and_the_search_judges_it_in_rgb():
    # format 1.7: an SH-0 scene's DC colour as luma/chroma (SHXF byte 2), within the budget,
    # decoded bit for bit on both paths, its report's train PSNR the decoded file's, and better
    # than the RGB file at the same budget (the probe: +0.5 to +1.2 dB on real scenes)
    from gsz.encoder.search import SearchOptions, encode_to_budget
    from gsz.encoder.search.judge import eval_cameras, train_psnr
    from gsz.evaluation.evaluate import render_views
    cloud = sample("sh0", 6000)
    target = 60_000
    sopts = SearchOptions(train_views=8, eval_views=3, eval_width=240, importance_width=240)
    res = encode_to_budget(cloud, target, options=sopts)
    c = read_container(res.data)
    assert target * 0.995 <= len(res.data) <= target and c.header.version == (1, 7)
    assert [ch.data for ch in c.chunks if ch.type == CHUNK_SHXF] == [b"\x02"] * sum(ch.type == b"GEOM" for ch in c.chunks)
    assert res.report.to_json()["sh_colour"] == "luma-chroma DC"
    with native.numpy_only():
        assert decode(res.data).equals(res.cloud)
    if native.enabled():
        assert decode(res.data).equals(res.cloud)
    cams = eval_cameras(cloud, sopts)
    refs = render_views(cloud, cams)
    true, _, _ = train_psnr(refs, res.cloud, cams)
    assert abs(true - res.report.search.train_psnr) < 0.02
    rgb = encode_to_budget(cloud, target, options=dataclasses.replace(sopts, sh_colour="rgb"))
    assert not any(ch.type == CHUNK_SHXF for ch in read_container(rgb.data).chunks)
    assert true > train_psnr(refs, rgb.cloud, cams)[0] + 0.5          # measured: +1.4 dB
