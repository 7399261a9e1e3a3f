"""Size-aware search: the file never exceeds the budget, lands within 0.5 % below it, errors
name the smallest reachable size, and more bytes never buy less fidelity."""
import dataclasses
import json
import subprocess
import sys

import numpy as np
import pytest

from gsz.decoder import decode
from gsz.encoder.search import BudgetError, SearchOptions, encode_to_budget
from codec_util import sample

FAST = SearchOptions(max_candidates=2, refine_steps=0, eval_views=3, eval_width=96, train_views=4,
                     importance_width=96, vq_iters=10)


@pytest.fixture(scope="module")
def imp_cache():
    return {}


def _search(name, n, target, imp_cache):
    from gsz.encoder.pipeline import EncodeOptions, compute_train_importance
    c = sample(name, n)
    key = (name, n)
    if key not in imp_cache:
        imp_cache[key] = compute_train_importance(c, EncodeOptions(train_views=4, importance_width=96))
    return c, encode_to_budget(c, target, options=FAST, importance=imp_cache[key])


@pytest.mark.parametrize("name,n,target", [("sh0", 6000, 40_000), ("sh0", 6000, 90_000),
                                           ("sh3", 4000, 60_000), ("sh3", 4000, 120_000)])
def test_budget_is_hit_from_below(name, n, target, imp_cache):
    c, res = _search(name, n, target, imp_cache)
    assert len(res.data) <= target
    assert len(res.data) >= 0.995 * target, res.report.search.calibration
    out = decode(res.data)
    assert out.equals(res.cloud)
    r = res.report
    assert r.bytes == len(res.data) and r.target_bytes == target
    assert len(r.bits["raht"]) == 7 and len(r.bits["scales"]) == 3
    assert all(1 <= b <= 16 for row in r.bits["raht"] + r.bits["scales"] for b in row)
    assert r.search.calibration and all("predicted_bytes" in x and "actual_bytes" in x for x in r.search.calibration)


def test_candidates_are_compared_on_the_callers_train_cameras(imp_cache):
    """With real train cameras (--cameras) the search judges candidates on them, spread over
    the set and downscaled to eval_width; without, on generated views at eval_width."""
    from gsz.evaluation.cameras import load_cameras
    c = sample("sh0", 6000)
    mine = [dataclasses.replace(cam, name=f"mine_{i:02d}")
            for i, cam in enumerate(load_cameras(None, c, n_train=12, n_test=1, width=160).train)]
    res = encode_to_budget(c, 60_000, options=FAST, cameras=mine)
    r = res.report
    assert r.search.eval_views == ["mine_00", "mine_06", "mine_11"]
    assert r.search.eval_size == [96, 72]
    assert len(res.data) <= 60_000
    gen = _search("sh0", 6000, 60_000, imp_cache)[1].report
    assert gen.search.eval_size == [96, 72] and not any(n.startswith("mine") for n in gen.search.eval_views)


def test_unreachable_budget_names_the_minimum(imp_cache):
    with pytest.raises(BudgetError) as e:
        _search("sh3", 4000, 3000, imp_cache)
    assert e.value.minimum > 3000
    assert f"{e.value.minimum:,}" in str(e.value)


def test_more_bytes_never_lower_fidelity(imp_cache):
    """Monotone RD on held-out (test) views of a small sample."""
    from gsz.evaluation.cameras import load_cameras
    from gsz.evaluation.evaluate import evaluate, render_views
    c = sample("sh0", 6000)
    cams = load_cameras(None, c, n_test=3, width=128).test
    refs = render_views(c, cams)
    psnrs = []
    for target in (30_000, 50_000, 80_000, 120_000):
        _, res = _search("sh0", 6000, target, imp_cache)
        psnrs.append(evaluate(refs, res.cloud, cams)["psnr"])
    assert all(b >= a - 1e-9 for a, b in zip(psnrs, psnrs[1:])), psnrs


def test_cli_size_units_json_and_report(tmp_path):
    from conftest import SAMPLE_SH0
    out = tmp_path / "p.gsz"
    code = "import sys; from gsz.encoder.cli import main; sys.exit(main(sys.argv[1:]))"
    p = subprocess.run([sys.executable, "-c", code, str(SAMPLE_SH0), "-o", str(out), "--size", "150kB",
                        "--train-views", "4", "--importance-width", "96", "--beta", "0", "--json", "--report",
                        str(tmp_path / "rep")],
                       capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    r = json.loads(p.stdout)
    assert r["target"] == "150 kB" and 0.995 * 150_000 <= r["bytes"] <= 150_000
    assert r["layer_blocks"] == [80]    # --blocks left out: the search's default, not the fixed one
    assert r["beta"] == 0.0              # --beta reaches the search's importance pass
    assert out.stat().st_size == r["bytes"]
    assert (tmp_path / "rep" / "bits.png").stat().st_size > 500
    p = subprocess.run([sys.executable, "-c", code, str(SAMPLE_SH0), "-o", str(tmp_path / "q.gsz"),
                        "--size", "5 parsecs"], capture_output=True, text=True)
    assert p.returncode == 2 and "parsecs" in p.stderr and not (tmp_path / "q.gsz").exists()
    p = subprocess.run([sys.executable, "-c", code, str(SAMPLE_SH0), "-o", str(tmp_path / "q.gsz"),
                        "--size", "2kB", "--train-views", "4", "--importance-width", "96"],
                       capture_output=True, text=True)
    assert p.returncode == 1 and "smallest reachable" in p.stderr and not (tmp_path / "q.gsz").exists()


def test_channel_weights_are_measured_sensitivities():
    from gsz.evaluation.cameras import load_cameras
    from gsz.encoder.search import channel_weights
    c = sample("sh3", 3000)
    cams = load_cameras(None, c, n_train=2, n_test=1, width=96).train
    w = channel_weights(c, cams)
    vals = np.array(w["raht"] + w["scales"])
    assert vals.shape == (10,) and np.all(np.isfinite(vals)) and np.all(vals > 0)
    assert abs(vals.mean() - 1.0) < 1e-9
    assert w["sh"] > 0
    # deterministic for a seed (the search's allocation depends on it)
    assert channel_weights(c, cams) == w


def test_noised_rows_are_one_draw_in_row_order():
    """The sensitivity's noised SH, made a row range at a time for its renders, are the rows of
    one whole draw, whatever the reads' order and sizes; the caller's generator is not moved."""
    from gsz.encoder.search.sensitivity import noised_rows
    x = np.random.default_rng(1).normal(0, 1, (150_000, 15, 3)).astype(np.float32)
    rng = np.random.default_rng(9)
    rows = noised_rows(x, rng, 0.01)
    want = (x + np.random.default_rng(9).normal(0, 0.01, x.shape)).astype(np.float32)
    assert np.array_equal(np.asarray(rows), want)
    assert np.array_equal(rows[70_000:140_001], want[70_000:140_001])
    assert np.array_equal(rows[5:9], want[5:9]) and np.array_equal(rows[9:20], want[9:20])
    assert rng.random() == np.random.default_rng(9).random()


def test_budget_above_full_quality_buys_a_deeper_octree(imp_cache):
    """When every group is at its best width and the file is still below the budget, the
    position error of the voxel grid limits fidelity: the search tries deeper octrees, keeps the
    better one, and never goes over the budget."""
    c = sample("sh3", 3000)
    from gsz.encoder.voxelize import DEFAULT_REL_ERROR, choose_depth
    d0 = choose_depth(c.positions, rel_error=DEFAULT_REL_ERROR)
    c, res = _search("sh3", 3000, 2_000_000, imp_cache)
    r = res.report
    assert len(res.data) <= 2_000_000
    depths = {cand["depth"] for cand in r.search.candidates}
    first = min(depths)                 # at this rate the first stage already lies below d0
    assert d0 <= first < max(depths)
    at_first = max(cand["train_psnr"] for cand in r.search.candidates if cand["depth"] == first)
    assert r.depth > first and r.search.train_psnr > at_first
    assert decode(res.data).equals(res.cloud)


def test_budget_above_the_8_bit_sh_ceiling_is_filled(tmp_path):
    """Off a delivery grid (noise added), a budget above what every attribute group at its best
    width plus every SH vector exact at SH_BITS can use is still hit within 0.5 %: the kept
    vectors' groups join the allocation at SH_BITS..16 bits (reported per group)."""
    from gsz.encoder.pipeline import EncodeOptions, compute_train_importance
    from gsz.encoder.search import SH_BITS
    import dataclasses
    c = sample("sh3", 3000)
    rng = np.random.default_rng(0)
    # a new cloud: the cached sample stays as other tests read it (on its delivery grid)
    c = dataclasses.replace(c, sh_rest=(c.sh_rest + rng.normal(0, 0.002, c.sh_rest.shape)).astype(np.float32),
                            scales=(c.scales + rng.normal(0, 0.01, c.scales.shape)).astype(np.float32))
    imp = compute_train_importance(c, EncodeOptions(train_views=4, importance_width=96))
    target = 250_000                  # the 16-bit ceiling of this sample is ~345 kB
    res = encode_to_budget(c, target, options=FAST, importance=imp)
    r = res.report
    assert 0.995 * target <= len(res.data) <= target, r.search.calibration
    assert r.sh_keep == r.voxels
    kept = [np.asarray(b) for b in r.bits["sh_kept"] if b is not None]
    assert kept and all(b.min() >= SH_BITS and b.max() <= 16 for b in kept)
    assert np.mean(np.concatenate([b.ravel() for b in kept])) > SH_BITS
    assert decode(res.data).equals(res.cloud)
    # the heatmap shows them: one row per SH coefficient below the 10 attribute channels
    from PIL import Image
    from gsz.encoder.report import write_search_report
    png = write_search_report(r, tmp_path)[0]
    assert Image.open(png).height >= 10 * (10 + kept[0].shape[0])


def test_screening_and_overlap_never_change_the_file(imp_cache):
    """Skipping taus whose exact-attribute bound cannot beat the best candidate, and training
    the codebooks on a worker thread, save time only: the same file comes out without them."""
    from dataclasses import replace
    from gsz.encoder.pipeline import EncodeOptions, compute_train_importance
    c = sample("sh3", 4000)
    key = ("sh3", 4000)
    if key not in imp_cache:
        imp_cache[key] = compute_train_importance(c, EncodeOptions(train_views=4, importance_width=96))
    opts = replace(FAST, max_candidates=3, refine_steps=2)
    a = encode_to_budget(c, 60_000, options=opts, importance=imp_cache[key])
    b = encode_to_budget(c, 60_000, options=replace(opts, screen=False, overlap=False),
                         importance=imp_cache[key])
    assert a.data == b.data
    assert b.report.search.screened == []
    # a skipped tau's bound could not outrank the best candidate then, hence not the winner
    from gsz.encoder.search.candidate import TAU_PREFERENCE_DB
    winner = a.report.search.train_psnr + TAU_PREFERENCE_DB * a.report.reserve
    for s in a.report.search.screened:
        if s["skipped"]:
            assert s["bound_psnr"] <= s["needed_psnr"]
            assert s["needed_psnr"] + TAU_PREFERENCE_DB * s["reserve"] <= winner + 1e-9


def test_a_candidate_that_prunes_more_must_win_the_train_views_clearly():
    """The train views choose what pruning removes and then judge the result, so a smaller tau
    outranks a larger one only by more than TAU_PREFERENCE_DB a unit of tau (flowers 12x: tau
    0.9 won the train views by 0.05 dB and lost the test views by 1.2 dB)."""
    from gsz.encoder.search.candidate import TAU_PREFERENCE_DB, Candidate, best_of
    assert TAU_PREFERENCE_DB > 0

    def cand(psnr, tau):
        return Candidate(psnr, tau, 14, 0.1, [psnr] * 6, encoded=None)
    whole = cand(47.50, 1.0)
    by_a_hair = cand(47.50 + 0.5 * TAU_PREFERENCE_DB * 0.1, 0.9)
    clearly = cand(47.50 + 1.5 * TAU_PREFERENCE_DB * 0.1, 0.9)
    assert best_of([by_a_hair, whole]) is whole and best_of([whole, by_a_hair]) is whole
    assert best_of([whole, clearly]) is clearly
    # at one tau the train PSNR alone decides, ties to the first
    deeper = cand(47.51, 1.0)
    assert best_of([whole, deeper]) is deeper and best_of([whole, cand(47.50, 1.0)]) is whole


def test_candidate_files_kept_on_disk_give_the_same_file(imp_cache, monkeypatch):
    """Large candidate files wait in temporary files (memory at 6 M Gaussians): with every
    candidate's file spilled the search returns the same bytes, and a dropped one is gone."""
    from gsz.encoder.search import candidate
    from gsz.encoder.pipeline import EncodeOptions, compute_train_importance
    c = sample("sh3", 4000)
    key = ("sh3", 4000)
    if key not in imp_cache:
        imp_cache[key] = compute_train_importance(c, EncodeOptions(train_views=4, importance_width=96))
    held = encode_to_budget(c, 60_000, options=FAST, importance=imp_cache[key]).data
    monkeypatch.setattr(candidate, "SPILL_BYTES", 1)
    spilled = encode_to_budget(c, 60_000, options=FAST, importance=imp_cache[key]).data
    assert spilled == held
    enc = candidate.Encoded(data=held, scene=None, pick=np.zeros(1), layer_bits=[], kept_bits=[],
                            sh_bytes=0, attr_stats={}, attr_bytes=0, meta_bytes=0,
                            predicted_bytes=0.0, loss=0.0)
    assert enc.size == len(held) and enc.data == held and enc.data == held
    enc.drop_data()
    assert enc.data is None and enc.size == len(held)


def test_dc_colour_channels_render_independently():
    """channel_weights measures the three DC colour channels with one render: image channel k
    must depend on DC channel k only (bit-exactly)."""
    from gsz.decoder.cloud import GaussianCloud
    from gsz.evaluation.cameras import load_cameras
    from gsz.evaluation.render import render
    c = sample("sh3", 2000)
    cam = load_cameras(None, c, n_train=1, n_test=1, width=96).train[0]
    rng = np.random.default_rng(1)
    noise = rng.normal(0, 0.05, (len(c), 3))

    def with_dc(dc):
        return GaussianCloud(positions=c.positions, scales=c.scales, rotations=c.rotations,
                             opacities=c.opacities, sh_dc=dc, sh_rest=c.sh_rest, sh_degree=c.sh_degree)
    both = render(with_dc(c.sh_dc + noise), cam).image
    for k in range(3):
        one = c.sh_dc.astype(np.float64).copy()
        one[:, k] += noise[:, k]
        img = render(with_dc(one), cam).image
        assert np.array_equal(img[..., k], both[..., k])


def test_assigner_gives_nearest_codewords():
    """Codeword indices reused across taus are nearest codewords of each voxel's own vector."""
    from gsz.encoder.pipeline import prepare_stage
    from gsz.encoder.search.sh_model import Assigner
    from gsz.encoder.vq import assign
    c = sample("sh3", 3000)
    imp = np.random.default_rng(0).random(len(c))
    cb = np.random.default_rng(2).normal(0, 0.3, (64, c.sh_rest[0].size)).astype(np.float32)
    a = Assigner(c)
    for tau in (1.0, 0.7, 0.4):
        st = prepare_stage(c, imp, tau)
        idx = a(st, cb)
        d_got = ((st.sh - cb[idx]) ** 2).sum(1)
        d_best = ((st.sh - cb[assign(st.sh, cb)]) ** 2).sum(1)
        assert np.allclose(d_got, d_best, rtol=1e-5, atol=1e-7)


def test_search_starts_deeper_where_a_large_extent_merges_gaussians():
    """Copies of a scene side by side (as a city capture's blocks) merge Gaussians into shared
    voxels at the position-error default depth: the search starts a level deeper where that
    level separates more Gaussians than its bits would buy, and not at a low rate."""
    from gsz.encoder.search.depth_walk import start_depth
    from gsz.encoder.voxelize import DEFAULT_REL_ERROR, bounding_cube, choose_depth, merge_fraction
    x = sample("sh3").positions
    d0 = choose_depth(x, rel_error=DEFAULT_REL_ERROR)
    assert start_depth(x, 20 * len(x)) == d0                 # one object: the default stands
    ext = x.max(0) - x.min(0)
    big = np.concatenate([x + np.array([i, j, 0]) * ext * 1.2 for i in range(8) for j in range(8)])
    d0 = choose_depth(big, rel_error=DEFAULT_REL_ERROR)
    cube = bounding_cube(big)
    assert merge_fraction(big, d0, cube) > 0.02
    d = start_depth(big, 20 * len(big))                      # 20 bytes per Gaussian
    assert d > d0 and merge_fraction(big, d, cube) < merge_fraction(big, d0, cube) / 4
    assert start_depth(big, 6 * len(big)) == d0              # 6: the level's bits cost more


def _path_notes():
    """A search stand-in with what _note_lost_paths reads and writes."""
    from types import SimpleNamespace

    from gsz.encoder.progress import Progress
    return SimpleNamespace(lost_paths=set(), far_behind=set(), narrow_losses={}, progress=Progress(quiet=True))


def _stage_paths(**psnr):
    """One stage's candidates: train PSNR per SH path."""
    from types import SimpleNamespace

    from gsz.encoder.search.candidate import Candidate
    return [Candidate(p, 1.0, 12, 0.0, [], SimpleNamespace(sh_path=k)) for k, p in psnr.items()]


def test_sh_paths_stop_being_weighed_after_a_clear_or_a_second_narrow_loss():
    """The search stops weighing an SH path that rendered 0.1+ dB below a stage's best, was
    dropped after its hardest views, or lost narrowly twice; a single tie keeps it."""
    from gsz.encoder.search.driver import PATH_LOST_MARGIN_DB, BudgetSearch

    s = _path_notes()
    note = BudgetSearch._note_lost_paths
    narrow = 50.0 - PATH_LOST_MARGIN_DB / 2
    note(s, ["vq", "classes", "scalar"], _stage_paths(vq=narrow, classes=50.0, scalar=narrow))
    assert s.lost_paths == set()                               # one tie says nothing
    note(s, ["vq", "classes", "scalar"], _stage_paths(vq=50.0 - 2 * PATH_LOST_MARGIN_DB, classes=50.0,
                                                      scalar=narrow))
    assert s.lost_paths == {"vq", "scalar"}                    # a clear loss; a second narrow one
    s = _path_notes()
    note(s, ["vq", "classes"], _stage_paths(vq=50.0))          # classes dropped after its hardest views
    assert s.lost_paths == {"classes"}


def test_how_far_a_lost_path_rendered_behind_is_remembered():
    """A path a whole drop margin (1 dB) behind a stage's best, or dropped after its hardest
    views, is also far behind -- noted even when it had lost before (the codebook path is then
    encoded only where no other path fits, whatever the keep-count)."""
    from gsz.encoder.search.driver import BudgetSearch

    s = _path_notes()
    note = BudgetSearch._note_lost_paths
    note(s, ["vq", "scalar"], _stage_paths(vq=40.5, scalar=41.0))
    assert s.lost_paths == {"vq"} and not s.far_behind
    note(s, ["vq", "classes", "scalar"], _stage_paths(classes=41.5, scalar=42.2))     # vq dropped
    assert s.lost_paths == {"vq", "classes"} and s.far_behind == {"vq"}
    note(s, ["scalar", "classes"], _stage_paths(scalar=43.0, classes=41.9))
    assert s.far_behind == {"vq", "classes"}


class _WalkScene:
    """A search stand-in for the depth walk: train PSNR per depth from a table, nothing merged."""

    def __init__(self, psnr: dict, start: int):
        from types import SimpleNamespace
        self.psnr, self.depth, self.evaluated, self.candidates = psnr, start, set(), []
        self.anchor = start
        self.near_ties = set()
        self.sopts = SimpleNamespace(depth_steps=3, max_extra_depth=3)
        self.progress = SimpleNamespace(log=lambda msg: None)
        self.try_tau(1.0, start)

    def best(self):
        from gsz.encoder.search.candidate import best_of
        return best_of(self.candidates)

    def merged_fraction(self, tau, d) -> float:
        return 0.001

    def score(self, tau, d) -> float:
        return self.psnr[d]

    def try_tau(self, tau, d) -> None:
        from types import SimpleNamespace

        from gsz.encoder.search.candidate import Candidate
        self.evaluated.add((tau, d))
        enc = SimpleNamespace(attributes_saturated=False, mean_attribute_bits=lambda: 10.0)
        self.candidates.append(Candidate(self.score(tau, d), tau, d, 0.0, [], enc))


def test_depth_walk_goes_past_its_range_while_each_level_gains_a_lot():
    """Where position error still dominates at the end of the walk's range (each level gaining
    dB, as the 1.2 M bench at 12x: 3.8, 3.3, 2.7 dB), the walk goes on while a level gains at
    least STRONG_GAIN_EXTRA_DEPTH_DB; where the gains are small it stops at the range's end."""
    from gsz.encoder.search.depth_walk import STRONG_GAIN_EXTRA_DEPTH_DB, walk_depth
    assert STRONG_GAIN_EXTRA_DEPTH_DB <= 1.5
    strong = _WalkScene({12: 47.0, 13: 50.5, 14: 53.7, 15: 56.4, 16: 57.6, 17: 57.75, 18: 57.5}, 12)
    walk_depth(strong)
    # 16 gained 1.2 dB, so 17 was tried and won; 17 gained 0.15 dB: 18 is not tried
    assert strong.best().depth == 17 and (1.0, 18) not in strong.evaluated
    weak = _WalkScene({12: 47.0, 13: 48.0, 14: 48.8, 15: 49.3, 16: 49.6}, 12)
    walk_depth(weak)
    assert weak.best().depth == 15 and (1.0, 16) not in weak.evaluated


def test_depth_walk_steps_two_levels_while_levels_gain_a_lot():
    """While a level gains STRIDE_GAIN_DB or more the walk steps two levels (fewer encodes on
    the way down); a double step that does not pay tries the level it stepped over."""
    from gsz.encoder.search.depth_walk import STRIDE_GAIN_DB, walk_depth
    assert STRIDE_GAIN_DB >= 1.5
    walk = _WalkScene({12: 47.0, 13: 50.5, 14: 53.7, 15: 56.4, 16: 57.6, 17: 57.75, 18: 57.5}, 12)
    walk_depth(walk)
    # 13 gained 3.5 dB: 15 next (2.95 dB a level), then 17 (0.68 a level: 16, the level
    # between, is tried too and loses): 14 not encoded
    assert walk.best().depth == 17
    assert {d for _, d in walk.evaluated} == {12, 13, 15, 16, 17}
    # the gain falls inside a double step and the level between is the peak
    peak = _WalkScene({11: 53.6, 12: 58.0, 13: 61.0, 14: 63.2, 15: 63.97, 16: 63.9}, 11)
    walk_depth(peak)
    assert peak.best().depth == 15 and {d for _, d in peak.evaluated} == {11, 12, 14, 15, 16}
    # 13 gained 3 dB, the double step to 15 lost: 14, the level between, wins
    over = _WalkScene({12: 47.0, 13: 50.0, 14: 51.0, 15: 49.5}, 12)
    walk_depth(over)
    assert over.best().depth == 14 and {d for _, d in over.evaluated} == {12, 13, 14, 15}


def test_depth_walk_notes_the_depths_as_good_as_its_best():
    """A level that renders within DEPTH_STEP_MIN_GAIN_DB of the best is noted (refine_tau
    tries it again where tau moves: which of two such depths wins can change with tau)."""
    from gsz.encoder.search.depth_walk import walk_depth
    tie = _WalkScene({9: 35.0, 10: 35.89, 11: 35.89, 12: 35.36}, 11)
    walk_depth(tie)
    assert tie.best().depth == 11 and tie.near_ties == {10}


class _TauWalkScene(_WalkScene):
    """_WalkScene with train PSNR per (tau, depth)."""

    def score(self, tau, d) -> float:
        return self.psnr[(tau, d)]


def test_depth_is_walked_again_where_tau_moved():
    """The walk's verdict holds at the tau it ran at: where the tau refinement then prunes more,
    deeper levels are tried again, and where it prunes less, shallower ones (showroom crop at
    18x: depth 13 lost at tau 0.6; at tau 0.5 it wins by 0.02 dB and 14 by 0.13 dB).  A tau
    that did not move walks nothing."""
    from gsz.encoder.search.depth_walk import rewalk_depth
    table = {(0.6, 12): 48.79, (0.6, 11): 47.90, (0.6, 13): 48.16,
             (0.5, 12): 49.58, (0.5, 13): 49.60, (0.5, 14): 49.71, (0.5, 15): 49.26,
             (0.7, 12): 47.0, (0.7, 11): 49.3, (0.7, 10): 49.1, (1.0, 12): 23.41}
    s = _TauWalkScene(table, 12)
    s.try_tau(0.6, 12)
    assert not rewalk_depth(s, 0.6) and len(s.candidates) == 2
    s.try_tau(0.5, 12)                      # the refinement moved tau down: deeper pays
    assert rewalk_depth(s, 0.6)
    assert (s.best().reserve, s.best().depth) == (0.5, 14)
    assert {d for t, d in s.evaluated if t == 0.5} == {12, 13, 14, 15}
    up = _TauWalkScene(table, 12)
    up.try_tau(0.6, 12)
    up.psnr[(0.7, 12)] = 49.0
    up.try_tau(0.7, 12)                     # tau moved up (prunes less): shallower
    assert rewalk_depth(up, 0.6) and up.best().depth == 11
    assert (0.7, 13) not in up.evaluated


def _refined(table, start_depth, first):
    """A _TauWalkScene of ``table`` (walk started at ``start_depth``) after its ``first``
    (tau, depth) candidate and the tau refinement (4 steps over the usual tau grid)."""
    from gsz.encoder.search.driver import BudgetSearch
    s = _TauWalkScene(table, start_depth)
    s.taus = [1.0, 0.9, 0.8, 0.7, 0.6, 0.5, 0.4, 0.3, 0.2]
    s.sopts.refine_steps = 4
    s.try_tau(*first)
    BudgetSearch.refine_tau(s)
    return s


def test_tau_refinement_tries_the_smaller_tau_a_level_deeper():
    """Where the next smaller tau loses at the best depth, it is tried a level deeper (it leaves
    more bytes for each Gaussian, which a deeper octree can use: showroom noised 18x, tau 0.4
    dropped at depth 12 and 1 dB better at depth 13-15); within the walk's range only."""
    table = {(1.0, 12): 23.0, (0.6, 12): 48.74, (0.7, 12): 47.0, (0.5, 12): 49.45,
             (0.4, 12): 47.5, (0.4, 13): 50.23, (0.5, 13): 49.38, (0.3, 13): 49.0,
             (0.3, 14): 49.9}
    s = _refined(table, 12, (0.6, 12))
    assert (s.best().reserve, s.best().depth) == (0.4, 13)
    assert (0.4, 13) in s.evaluated and (0.3, 14) in s.evaluated
    # at the end of the walk's range (start 12, 3 levels) no deeper level is tried
    edge = _refined({(1.0, 12): 23.0, (0.6, 15): 48.0, (0.7, 15): 47.0, (0.5, 15): 47.5,
                     (0.7, 14): 47.2}, 12, (0.6, 15))
    assert edge.best().reserve == 0.6 and {d for _, d in edge.evaluated} == {12, 14, 15}


def test_tau_refinement_tries_the_larger_tau_a_level_shallower():
    """Where neither tau neighbour wins at the best depth, the larger tau is also tried a level
    shallower (more Gaussians, each with fewer bytes, which a coarser octree pays for): the
    houseplant at 27x, train PSNR of the search's candidates."""
    table = {(1.0, 10): 11.0, (0.5, 10): 32.17, (0.6, 10): 31.92, (0.4, 10): 29.75,
             (0.4, 11): 29.80, (0.6, 9): 33.43, (0.7, 9): 33.19, (0.5, 9): 32.15, (0.7, 8): 31.0}
    s = _refined(table, 10, (0.5, 10))
    assert (s.best().reserve, s.best().depth) == (0.6, 9)
    assert (0.7, 8) in s.evaluated           # from the new best, the same step again


def test_tau_refinement_moves_a_level_away_where_both_neighbours_already_lost():
    """After the depth was walked again, both tau neighbours of the best may already have lost
    at its new depth; the refinement still tries them a level away (plaza noised 40x, train
    PSNR of the search's candidates: tau 0.3 best at depth 11, tau 0.4 wins at 10 and 9)."""
    from collections import defaultdict
    table = defaultdict(lambda: 20.0)       # anything else the refinement tries loses
    table.update({(1.0, 11): 8.0, (0.3, 11): 27.71, (0.2, 11): 24.96, (0.4, 11): 27.33,
             (0.4, 10): 28.29, (0.5, 10): 26.85, (0.5, 9): 28.58, (0.4, 9): 28.71,
             (0.6, 9): 27.68, (0.3, 10): 27.67, (0.2, 12): 24.97})
    from gsz.encoder.search.driver import BudgetSearch
    s = _TauWalkScene(table, 11)
    s.taus = [1.0, 0.9, 0.8, 0.7, 0.6, 0.5, 0.4, 0.3, 0.2]
    s.sopts.refine_steps = 4
    for first in ((0.2, 11), (0.4, 11), (0.3, 11)):
        s.try_tau(*first)
    BudgetSearch.refine_tau(s)
    assert (0.4, 10) in s.evaluated
    assert s.best().reserve >= 0.4 and s.best().depth <= 10


def test_high_rate_budgets_start_the_depth_walk_deeper_within_its_range():
    """At high rates the walk ends several levels below the position-error start (1.5-3 levels
    per doubling of the bits per Gaussian on the shared scenes): the first stage starts part of
    the way there, never past the walk's range; low rates start at the anchor."""
    from types import SimpleNamespace

    from gsz.encoder.search.depth_walk import first_depth
    sopts = SimpleNamespace(depth_steps=3, max_extra_depth=3)
    n = 100_000
    depths = [first_depth(11, int(bpg * n / 8), n, sopts) for bpg in (13.6, 45, 73, 110, 165, 250, 400, 4000)]
    assert depths[:3] == [11, 11, 11]                         # 40x-18x of a plain PLY: no change
    assert depths == sorted(depths) and depths[3] > 11        # deeper as the rate grows
    assert max(depths) == 14                                  # the range's end (depth_steps)
    assert first_depth(11, 10**9, n, SimpleNamespace(depth_steps=1, max_extra_depth=3)) == 12
    assert first_depth(20, 10**9, n, sopts) == 21             # never past the octree's deepest level


def test_a_first_stage_below_the_position_error_start_still_walks_deeper():
    """A high-rate first stage three levels below the position-error start (the end of the walk's
    range measured from there) still steps deeper with no gain shown yet, and goes on while the
    levels gain (the jug noised at SOG's bytes: 65.0 dB train at depth 14, 72.7 at 19)."""
    from gsz.encoder.search.depth_walk import walk_depth
    s = _WalkScene({13: 62.0, 14: 65.0, 15: 67.1, 16: 69.0, 17: 71.7, 18: 72.6, 19: 72.7, 20: 72.5}, 14)
    s.anchor = 11
    walk_depth(s)
    assert s.best().depth == 19
