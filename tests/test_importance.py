"""Importance (I = I_d * (V / V_ref)^beta) and pruning."""
import math

import numpy as np
import pytest

from gsz.decoder.cloud import GaussianCloud
from gsz.decoder.errors import GszError
from gsz.encoder.importance import (ImportanceError, compute_importance, keep_count, prune, top_k_mask,
                                   volume_term)


def _cloud(positions, log_scales, opacity_logits, rotations=None):
    n = len(positions)
    rot = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1)) if rotations is None else rotations
    return GaussianCloud(positions=np.asarray(positions, np.float32),
                         scales=np.asarray(log_scales, np.float32), rotations=rot,
                         opacities=np.asarray(opacity_logits, np.float32),
                         sh_dc=np.zeros((n, 3), np.float32), sh_rest=np.zeros((n, 0, 3)),
                         sh_degree=0)


def test_volume_term_hand_values():
    # log V = sum of log-scales = 0, ln2, ln4, ln8, ln16 -> V = 1, 2, 4, 8, 16.
    ls = np.zeros((5, 3))
    ls[:, 0] = np.log([1, 2, 4, 8, 16])
    c = _cloud(np.zeros((5, 3)), ls, np.zeros(5))
    # ref_quantile 0.1 -> ascending index floor(0.1 * 4) = 0 -> V_ref = 1.
    np.testing.assert_allclose(volume_term(c, beta=0.5), np.sqrt([1, 2, 4, 8, 16]), rtol=1e-6)
    # ref_quantile 0.5 -> index 2 -> V_ref = 4.
    np.testing.assert_allclose(volume_term(c, beta=1.0, ref_quantile=0.5),
                               np.array([1, 2, 4, 8, 16]) / 4.0, rtol=1e-6)
    assert np.array_equal(volume_term(c, beta=0.0), np.ones(5))
    # The volume multiplies the three axes: scales split across axes give the same V.
    ls2 = np.tile(np.log([1, 2, 4, 8, 16])[:, None] / 3.0, (1, 3))
    np.testing.assert_allclose(volume_term(_cloud(np.zeros((5, 3)), ls2, np.zeros(5)), beta=0.5),
                               np.sqrt([1, 2, 4, 8, 16]), rtol=1e-5)


def test_volume_reference_matches_authors_rule(sample_sh3):
    # Reference: sort V descending, V_ref = element at floor(0.9 N).
    v = np.exp(sample_sh3.scales.astype(np.float64).sum(axis=1))
    n = len(v)
    v_ref = np.sort(v)[::-1][int(math.floor(0.9 * n))]
    ours = volume_term(sample_sh3, beta=1.0)
    theirs = v / v_ref
    # Same element up to one rank: ratio within the gap between adjacent sorted values.
    ratio = ours / theirs
    assert np.allclose(ratio, ratio[0], rtol=1e-9)
    sv = np.sort(v)
    k = int(np.searchsorted(sv, v_ref))
    assert sv[max(k - 1, 0)] / v_ref - 1e-9 <= 1 / ratio[0] <= sv[min(k + 1, n - 1)] / v_ref + 1e-9
    assert np.all(np.isfinite(ours)) and (ours > 0).all()


def test_volume_term_extreme_scales_do_not_overflow():
    ls = np.array([[40.0, 40.0, 40.0], [-40.0, -40.0, -40.0], [0, 0, 0]])
    t = volume_term(_cloud(np.zeros((3, 3)), ls, np.zeros(3)), beta=0.1)
    assert np.all(np.isfinite(t)) and t[0] > t[2] > t[1] > 0


@pytest.mark.parametrize("beta, q", [(-0.1, 0.1), (float("nan"), 0.1), (0.1, 1.5), (0.1, -0.01)])
def test_volume_term_rejects_bad_options(sample_sh0, beta, q):
    with pytest.raises(ImportanceError):
        volume_term(sample_sh0, beta=beta, ref_quantile=q)


def test_prune_counts_and_order():
    imp = np.array([5.0, 1.0, 9.0, 3.0, 7.0, 0.0, 2.0, 8.0, 6.0, 4.0])
    kept = prune(imp, 0.3)
    assert kept.tolist() == [2, 4, 7]                # 9, 7, 8 -> sorted indices
    assert kept.dtype == np.int64
    assert prune(imp, 1.0).tolist() == list(range(10))
    assert prune(imp, 0.01).tolist() == [2]          # at least one kept
    # ceil(reserve * N) without float rounding surprises (0.7 * 10 = 7.000000000000001).
    assert len(prune(imp, 0.7)) == 7
    assert len(prune(imp, 0.1)) == 1
    assert len(prune(imp, 0.71)) == 8
    assert keep_count(3, 0.5) == 2 and keep_count(0, 0.5) == 0


def test_prune_ties_lower_index_wins():
    imp = np.array([1.0, 2.0, 2.0, 2.0, 0.5, 2.0])
    assert prune(imp, 0.5).tolist() == [1, 2, 3]
    assert prune(np.zeros(7), 3 / 7).tolist() == [0, 1, 2]
    # Deterministic: same call twice gives the same array.
    rng = np.random.default_rng(0)
    r = rng.integers(0, 5, size=1000).astype(np.float64)
    a, b = prune(r, 0.37), prune(r.copy(), 0.37)
    assert np.array_equal(a, b) and len(a) == 370
    # Every kept importance >= every dropped one.
    dropped = np.setdiff1d(np.arange(1000), a)
    assert r[a].min() >= r[dropped].max()


def test_top_k_mask_is_the_stable_sorts_first_k():
    rng = np.random.default_rng(1)
    for _ in range(200):
        n = int(rng.integers(1, 50))
        imp = rng.integers(0, 4, n) * rng.choice([1.0, 0.25])
        for k in (0, 1, int(rng.integers(0, n + 1)), n, n + 2):
            want = np.zeros(n, bool)
            want[np.argsort(-imp, kind="stable")[:k]] = True
            assert np.array_equal(top_k_mask(imp, k), want)


@pytest.mark.parametrize("reserve", [0.0, -0.2, 1.0001, float("nan"), "0.5", None, True])
def test_prune_rejects_bad_reserve(reserve):
    with pytest.raises(ImportanceError, match="reserve"):
        prune(np.ones(4), reserve)


def test_prune_rejects_bad_importance():
    with pytest.raises(GszError, match="non-finite"):
        prune(np.array([1.0, np.nan, 2.0]), 0.5)
    with pytest.raises(GszError, match="1-D"):
        prune(np.ones((2, 2)), 0.5)
    assert prune(np.zeros(0), 0.5).size == 0


def test_prune_real_scene_keeps_the_most_important(sample_sh0):
    imp = volume_term(sample_sh0) / (1 + np.exp(-sample_sh0.opacities.astype(np.float64)))
    kept = prune(imp, 0.6)
    assert len(kept) == math.ceil(0.6 * len(sample_sh0))
    assert np.all(np.diff(kept) > 0)
    mask = np.zeros(len(imp), bool)
    mask[kept] = True
    assert imp[mask].min() >= imp[~mask].max()


# ---------------------------------------------------------------- with the reference renderer
def _camera():
    from gsz.evaluation.cameras import Camera
    return Camera(R=np.eye(3), t=np.zeros(3), fx=60.0, fy=60.0, cx=32.0, cy=32.0,
                  width=64, height=64, name="front")


def test_importance_hidden_gaussian_gets_almost_nothing():
    pytest.importorskip("gsz.evaluation.render")
    # 0: big opaque Gaussian on the optical axis; 1: small one right behind it;
    # 2: small one off to the side, unoccluded; 3: behind the camera.
    pos = [[0, 0, 2.0], [0, 0, 4.0], [1.2, 0, 4.0], [0, 0, -3.0]]
    ls = np.log([[0.5] * 3, [0.05] * 3, [0.05] * 3, [0.5] * 3])
    c = _cloud(pos, ls, [12.0, 12.0, 12.0, 12.0])
    imp = compute_importance(c, [_camera()], beta=0.0)
    assert imp.shape == (4,) and imp.dtype == np.float64
    assert imp[0] > 0 and imp[2] > 0
    assert imp[3] == 0.0
    # The front Gaussian saturates at alpha 0.99 -> T <= 0.01 behind it.
    assert imp[1] < 0.02 * imp[2]
    # beta scales by the volume term exactly.
    imp_b = compute_importance(c, [_camera()], beta=0.1)
    np.testing.assert_allclose(imp_b, imp * volume_term(c, beta=0.1), rtol=1e-12)
    # More views add up.
    imp2 = compute_importance(c, [_camera(), _camera()], beta=0.0)
    np.testing.assert_allclose(imp2, 2 * imp, rtol=1e-12)


def test_importance_needs_cameras(sample_sh0):
    with pytest.raises(ImportanceError, match="camera"):
        compute_importance(sample_sh0, [])
