"""The size search's SH coding paths: the codebook at low rates, the scalar path at high rates,
kept vectors in importance classes (SHCL) in between."""
import contextlib

import pytest

from gsz.decoder import decode
from gsz.encoder.sh_colour import rgb_view

from codec_util import sample

FAST_SEARCH = dict(train_views=8, eval_views=3, eval_width=240, importance_width=240)


def _search(target, **kw):
    from gsz.encoder.search import SearchOptions, encode_to_budget
    return encode_to_budget(sample("sh3"), target, options=SearchOptions(**FAST_SEARCH, **kw))


def _test_psnr(cloud):
    from gsz.evaluation.cameras import load_cameras
    from gsz.evaluation.evaluate import evaluate
    cams = load_cameras(None, sample("sh3"), n_test=3, width=320).test
    return evaluate(sample("sh3"), cloud, cams)["psnr"]


def test_high_rate_uses_the_scalar_path_and_beats_the_codebook():
    target = 240_000
    scalar = _search(target)
    codebook = _search(target, sh_scalar=False, sh_classes=False)
    assert scalar.report.search.sh_path == "scalar" and codebook.report.search.sh_path == "vq"
    assert scalar.report.sh_keep == scalar.report.voxels          # every vector coded
    assert len(scalar.data) <= target and decode(scalar.data).equals(scalar.cloud)
    assert _test_psnr(scalar.cloud) > _test_psnr(codebook.cloud) + 1.0


def test_kept_vectors_in_importance_classes_beat_fixed_width_kept_vectors():
    """The codebook path with its kept vectors in importance classes (SHCL, format 1.3), their
    widths allocated, renders better than the same path with every kept vector at 8 bits."""
    from gsz.decoder.container import read_container
    target = 220_000            # the classes keep ~2/3 of the vectors (at 240 kB: all of them)
    classes = _search(target, sh_scalar=False)
    fixed = _search(target, sh_scalar=False, sh_classes=False)
    assert classes.report.search.sh_path == "classes" and fixed.report.search.sh_path == "vq"
    assert 0 < classes.report.sh_keep < classes.report.voxels
    c = read_container(classes.data)
    assert c.header.version >= (1, 3) and any(ch.type == b"SHCL" for ch in c.chunks)
    assert len(classes.data) <= target and decode(classes.data).equals(classes.cloud)
    assert _test_psnr(classes.cloud) > _test_psnr(fixed.cloud) + 0.5


@pytest.mark.parametrize("target", [120_000])
def test_low_rate_keeps_the_codebook(target):
    res = _search(target)
    assert res.report.search.sh_path == "vq" and res.report.codebook_size > 1


def test_tiny_budget_drops_the_sh_rest_when_the_views_say_so():
    """At 40 kB the jug sample's SH get no exact vector; without the SH rest its bytes buy
    attributes and Gaussians, which renders better (the search judges it on the train views)."""
    target = 40_000
    flat = _search(target)
    with_sh = _search(target, sh_drop=False)
    assert flat.report.sh_degree == 0 and flat.cloud.sh_degree == 0
    assert with_sh.report.sh_degree == 3 and with_sh.report.sh_keep == 0
    assert len(flat.data) <= target and decode(flat.data).equals(flat.cloud)
    assert flat.report.search.train_psnr > with_sh.report.search.train_psnr
    assert _test_psnr(flat.cloud) > _test_psnr(with_sh.cloud) + 1.0


@contextlib.contextmanager
def _first_stage(target, deeper: int = 0):
    """(encode_tau's SH paths at the search's first stage, tau 1.0), as a function of
    ``encode_tau`` keyword arguments (``opts``: other SearchOptions) that checks every file
    is within ``target`` and decodes to its cloud.  ``deeper``: octree levels below the
    default depth."""
    from concurrent.futures import ThreadPoolExecutor

    from gsz.encoder.pipeline import compute_train_importance
    from gsz.encoder.progress import Progress
    from gsz.encoder.search import SearchOptions
    from gsz.encoder.search.driver import BudgetSearch
    from gsz.encoder.search.tau import encode_tau
    from gsz.encoder.voxelize import DEFAULT_REL_ERROR, choose_depth

    cloud = sample("sh3")
    sopts = SearchOptions(**FAST_SEARCH)
    with ThreadPoolExecutor(max_workers=1) as pool:
        search = BudgetSearch(cloud, target, sopts, None, pool)
        search.importance = compute_train_importance(cloud, sopts)
        if deeper:
            search.depth = choose_depth(cloud.positions, rel_error=DEFAULT_REL_ERROR) + deeper
        search._set_up(None)
        stage = search.stage_for(1.0)

        def paths(opts=sopts, **kw):
            encs = list(encode_tau(stage, target, opts, search.sh_models(stage), Progress(quiet=True),
                                   [], search.judge.weights, **kw))
            # a candidate's cloud is in the colour space the search codes (the DC as luma/chroma;
            # this sample's SH rest, on SPZ's grid, stays RGB): the decoder's is its RGB view
            assert all(len(e.data) <= target and decode(e.data).equals(rgb_view(e.cloud, search.sh_colour))
                       for e in encs)
            return [e.sh_path for e in encs]
        yield paths


def test_a_stage_without_the_codebook_path_still_yields_a_file():
    """Once another SH path rendered clearly better, the search stops encoding the codebook
    path; a stage where no other path fits still gets the codebook path's file."""
    from gsz.encoder.search import SearchOptions

    with _first_stage(240_000, deeper=2) as paths:
        assert "vq" in paths(codebook=True)
        others = paths(codebook=False)
        assert others and "vq" not in others
        flat = SearchOptions(**FAST_SEARCH, sh_scalar=False, sh_classes=False)
        assert paths(flat, codebook=False) == ["vq"]


def test_once_allocated_kept_widths_lead_every_stage_encodes_the_scalar_path():
    """Where the codebook's keep-count estimate is below SCALAR_MIN_KEEP the scalar path is not
    weighed -- unless the search's best candidate so far allocates its kept vectors' widths (a
    classes- or scalar-path file): the renders have overruled the codebook model's estimate
    (noised jug at 27x: an estimate 0.04 vectors short of the gate hid the scalar path, 1.5 dB
    better than every file the search had)."""
    with _first_stage(120_000) as paths:
        assert "scalar" not in paths(widths_lead=False)
        assert "scalar" in paths(widths_lead=True)


def test_a_codebook_path_far_behind_is_not_encoded_again_where_few_vectors_are_kept():
    """Where the keep-count estimate keeps fewer than half the vectors, a codebook path that lost
    is still encoded (which path renders better changes with the depth there) -- until it
    renders a whole drop margin below another path: then only where no other path fits (the
    1.2 M noised bench scene re-encoded and dropped it at four depths, ~10 s each)."""
    with _first_stage(120_000) as paths:
        assert "vq" in paths(codebook=False, widths_lead=True, codebook_far_behind=False)
        others = paths(codebook=False, widths_lead=True, codebook_far_behind=True)
        assert others and "vq" not in others


@pytest.mark.usefixtures("each_decoder_path")
@pytest.mark.parametrize("keep, classes, widths", [(0, 1, None), (700, 1, 12), (3000, 8, "mixed"), (3000, 1, None)])
def test_decoded_rows_are_the_coded_sh_bit_for_bit(keep, classes, widths):
    """The SH a render of a candidate reads a row range at a time (ShPayloads.decoded_rows) are
    the coded payloads' reconstruction bit for bit: codewords, kept vectors at any width (0 =
    constant groups, more than 8 bits), importance classes, several tiles and layers; made by
    the C kernel and by the NumPy rows."""
    import numpy as np

    from gsz.decoder.groups import blocks_for
    from gsz.encoder.pipeline import ShPayloads, prepare_stage
    c = sample("sh3", 3000)
    imp = np.random.default_rng(0).random(len(c))
    st = prepare_stage(c, imp, 0.9, layers=2, tile_gaussians=1024)
    assert st.num_tiles > 1 and len(st.layers) > st.num_tiles
    cb = np.random.default_rng(2).normal(0, 0.3, (64, c.sh_rest[0].size)).astype(np.float32)
    pay = ShPayloads(st, cb, keep, 8, 16, classes=classes)
    bits = None
    if widths is not None:
        rng = np.random.default_rng(3)
        bits = []
        for sel, kb in pay.kept_sets:
            shape = (st.sh.shape[1], blocks_for(sel.size, kb) if sel.size else 1)
            bits.append(np.full(shape, widths) if widths != "mixed" else rng.integers(0, 11, shape))
    want = pay.payloads(bits)[1]
    got = pay.decoded_rows(bits)
    assert got.shape == want.shape
    assert np.array_equal(np.asarray(got), want)
    assert np.array_equal(got[1000:1100], want[1000:1100])


def _codebook_model(n=3000, k=64):
    import numpy as np

    from gsz.encoder.pipeline import prepare_stage
    from gsz.encoder.search.sh_model import ShModel, ShStageStats
    from gsz.encoder.vq import assign, train_codebook
    c = sample("sh3", n)
    st = prepare_stage(c, np.random.default_rng(0).random(len(c)), 1.0)
    x = np.asarray(st.sh, np.float32)
    cb = train_codebook(x, None, k, seed=0)
    return st, x, ShModel(st, cb, 16, ShStageStats(st, 16), assign(x, cb))


def test_a_coarser_codebook_costs_fewer_bytes_and_its_error_estimate_tracks_the_decoded_words():
    """with_codebook_bits: the codebook's bytes fall with its width, the estimated error of the
    vectors rises by (WORD_ERROR_FACTOR times) what decoding the coarser words really adds."""
    import numpy as np

    from gsz.encoder.search.sh_model import WORD_ERROR_FACTOR, row_sse
    st, x, m8 = _codebook_model()
    assert m8.cb_bits == 8
    prev = m8
    for bits in (6, 5, 3):
        m = m8.with_codebook_bits(bits)
        assert m.cb_bits == bits and m8.cb_bits == 8           # a copy; the model itself unchanged
        assert m.codebook_bytes < prev.codebook_bytes
        assert m.cum_vq[-1] > prev.cum_vq[-1]
        words, _ = m8._coded_codebook(bits)
        exact = float(row_sse(x, lambda s, e: words[m8._compact_index[s:e]]).sum())
        added = (m.cum_vq[-1] - m8.cum_vq[-1]) / WORD_ERROR_FACTOR
        assert added == pytest.approx(exact - m8.cum_vq[-1], rel=0.25)
        # the estimate of a keep-count: fewer bytes, no less error (the kept vectors are unchanged)
        for keep in (0, 300):
            (b, l), (b8, l8) = m.estimate(keep), m8.estimate(keep)
            assert b < b8 and l >= l8
        prev = m
    assert np.all(np.diff(m.cum_vq) >= -1e-9)


@pytest.mark.usefixtures("each_decoder_path")
@pytest.mark.parametrize("bits", [5, 3])
def test_a_codebook_below_8_bits_decodes_to_its_coded_words(bits):
    """ShModel.encode at a coarser codebook writes the codebook at that width; the file's SH
    are the plan's reconstruction bit for bit (C kernel and NumPy rows alike)."""
    import numpy as np
    st, _, m8 = _codebook_model()
    plan = m8.with_codebook_bits(bits).encode(100)
    assert plan.stats["codebook_bits"] == bits
    coarse = plan.payloads.decoded_rows(None)
    fine = m8.encode(100).payloads.decoded_rows(None)
    assert np.array_equal(np.asarray(plan.payloads.payloads(None)[1]), np.asarray(coarse))
    assert plan.payloads.stats["codebook_bytes"] < m8.encode(100).payloads.stats["codebook_bytes"]
    assert not np.array_equal(np.asarray(coarse), np.asarray(fine))


def test_the_search_reports_its_codebook_width_and_refuses_bad_ones():
    from gsz.encoder.search import SearchOptions, encode_to_budget
    from gsz.encoder.pipeline import EncodeOptionsError
    res = _search(120_000)
    assert res.report.bits["sh_codebook"] in SearchOptions().codebook_bits
    fixed = _search(120_000, codebook_bits=(8,))
    assert fixed.report.bits["sh_codebook"] == 8
    with pytest.raises(EncodeOptionsError, match="codebook_bits"):
        encode_to_budget(sample("sh3"), 120_000, options=SearchOptions(**FAST_SEARCH, codebook_bits=(0,)))
