"""Importance-weighted vector quantisation of the higher SH."""
import numpy as np
import pytest

from gsz.encoder.importance import volume_term
from gsz.encoder.vq import VQError, assign, compact, train_codebook, weighted_distortion


def _sh(cloud):
    return cloud.sh_rest.reshape(len(cloud), -1)


def _proxy_importance(cloud):
    return volume_term(cloud) / (1 + np.exp(-cloud.opacities.astype(np.float64)))


def test_assign_is_the_exact_nearest_codeword():
    rng = np.random.default_rng(0)
    for k in (5, 300, 1000):                  # plain and two-level argmin (k >= 256, padded)
        x = rng.normal(size=(3000, 9)).astype(np.float32)
        cb = rng.normal(size=(k, 9)).astype(np.float32)
        idx = assign(x, cb)
        d = ((x.astype(np.float64)[:, None, :] - cb[None]) ** 2).sum(-1)
        best = d.min(axis=1)
        assert idx.dtype == np.int32 and idx.shape == (3000,)
        # Exact nearest up to float32 rounding of the GEMM form.
        assert np.all(d[np.arange(3000), idx] <= best + 1e-4 * (1 + best))
        assert (idx == d.argmin(axis=1)).mean() > 0.999
    # Ties go to the lower index.
    cb = np.array([[1.0, 0.0], [0.0, 0.0], [0.0, 0.0], [1.0, 0.0]], np.float32)
    assert assign(np.zeros((4, 2), np.float32), cb).tolist() == [1, 1, 1, 1]


@pytest.mark.parametrize("fixture, k", [("sample_sh3", 256), ("sample_sh3", 64)])
def test_distortion_beats_random_codebook_on_real_sh(request, fixture, k):
    cloud = request.getfixturevalue(fixture)
    x, w = _sh(cloud), _proxy_importance(cloud)
    assert x.shape[1] == 45
    cb = train_codebook(x, w, k, iters=30, batch=2048, seed=0)
    assert cb.shape == (k, 45) and cb.dtype == np.float32
    ours = weighted_distortion(x, w, cb)
    rng = np.random.default_rng(1)
    random_cb = x[rng.choice(len(x), k, replace=False)]
    rand = weighted_distortion(x, w, random_cb)
    assert ours < 0.8 * rand
    # More codewords fit better.
    cb2 = train_codebook(x, w, 2 * k, iters=30, batch=2048, seed=0)
    assert weighted_distortion(x, w, cb2) < ours


def test_weighted_points_are_fit_better(sample_sh3):
    x = _sh(sample_sh3)
    # The important 10 %: one region of SH space (largest first coefficient), as view-dependent
    # detail is concentrated in a few Gaussians.
    heavy = x[:, 0] >= np.quantile(x[:, 0], 0.9)
    w = np.where(heavy, 50.0, 1.0)
    k = 64
    cb_w = train_codebook(x, w, k, iters=30, batch=2048, seed=0)
    cb_u = train_codebook(x, None, k, iters=30, batch=2048, seed=0)
    err_w = weighted_distortion(x[heavy], None, cb_w)
    err_u = weighted_distortion(x[heavy], None, cb_u)
    assert err_w < 0.9 * err_u                    # measured ~0.82; ~1.0 if weights were ignored
    # ... and the weighted objective itself is lower with the weighted codebook.
    assert weighted_distortion(x, w, cb_w) < weighted_distortion(x, w, cb_u)


def test_deterministic(sample_sh0, sample_sh3):
    x = _sh(sample_sh3)
    w = _proxy_importance(sample_sh3)
    a = train_codebook(x, w, 128, iters=10, batch=1024, seed=5)
    b = train_codebook(x.copy(), w.copy(), 128, iters=10, batch=1024, seed=5)
    assert np.array_equal(a, b)
    assert np.array_equal(assign(x, a), assign(x, b))
    c = train_codebook(x, w, 128, iters=10, batch=1024, seed=6)
    assert not np.array_equal(a, c)


@pytest.mark.parametrize("dim", [9, 24, 45])
def test_dimensions_and_fewer_points_than_codewords(dim):
    rng = np.random.default_rng(dim)
    x = rng.normal(size=(50, dim)).astype(np.float32)
    cb = train_codebook(x, rng.random(50), 64, seed=0)
    assert cb.shape == (64, dim)
    idx = assign(x, cb)
    assert np.array_equal(cb[idx], x)              # every vector reproduced exactly
    assert weighted_distortion(x, None, cb, idx) == 0.0
    small, sidx = compact(cb, idx)
    assert small.shape == (50, dim) and np.array_equal(small[sidx], x)
    # Duplicates: 1000 points but only 7 distinct vectors, K = 16.
    x2 = np.repeat(x[:7], 143, axis=0)[:1000]
    cb2 = train_codebook(x2, None, 16, seed=0)
    assert np.array_equal(cb2[assign(x2, cb2)], x2)
    # Larger data with N > K: shape contract and a real improvement per D.
    x3 = rng.normal(size=(4000, dim)).astype(np.float32)
    cb3 = train_codebook(x3, None, 300, iters=20, batch=1024, seed=0)
    assert cb3.shape == (300, dim)
    assert weighted_distortion(x3, None, cb3) < 0.9 * weighted_distortion(x3, None, x3[:300])


def test_single_codeword_is_the_weighted_mean():
    rng = np.random.default_rng(0)
    x = rng.normal(size=(500, 9)).astype(np.float32)
    w = rng.random(500)
    cb = train_codebook(x, w, 1, iters=5, batch=128, lloyd=1, seed=0)
    np.testing.assert_allclose(cb[0], (w[:, None] * x).sum(0) / w.sum(), atol=1e-5)


def test_zero_weights_fall_back_to_uniform():
    rng = np.random.default_rng(0)
    x = rng.normal(size=(2000, 9)).astype(np.float32)
    a = train_codebook(x, np.zeros(2000), 16, iters=5, batch=512, seed=0)
    b = train_codebook(x, None, 16, iters=5, batch=512, seed=0)
    assert np.array_equal(a, b)


def test_bad_input_raises_clear_errors():
    x = np.zeros((10, 4), np.float32)
    with pytest.raises(VQError, match="K"):
        train_codebook(x, None, 0)
    with pytest.raises(VQError, match="2-D"):
        train_codebook(np.zeros(10, np.float32), None, 4)
    with pytest.raises(VQError, match="weights"):
        train_codebook(x, np.ones(9), 4)
    with pytest.raises(VQError, match="weights"):
        train_codebook(x, -np.ones(10), 4)
    bad = x.copy()
    bad[2, 1] = np.inf
    with pytest.raises(VQError, match="non-finite"):
        train_codebook(bad, None, 4)
    with pytest.raises(VQError, match="zero vectors"):
        train_codebook(np.zeros((0, 4), np.float32), None, 4)
    with pytest.raises(VQError, match="dimension"):
        assign(x, np.zeros((3, 5), np.float32))
    with pytest.raises(VQError, match="iters"):
        train_codebook(x, None, 4, iters=-1)
    with pytest.raises(VQError, match="range"):
        compact(np.zeros((3, 4)), np.array([0, 3]))
