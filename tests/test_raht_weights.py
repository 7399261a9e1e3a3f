"""RAHT leaf weights (RWGT chunk, format 1.5): the weighted transform, the encoder's classes and
weights, the SHCL form that takes RWGT's classes, both decoder paths, and what a user gains."""
import numpy as np
import pytest

import gsz
from gsz.decoder import decode, native
from gsz.decoder.container import read_container
from gsz.decoder.errors import GszFormatError
from gsz.decoder.layout import CHUNK_RWGT, CHUNK_SHCL, KNOWN_CHUNKS
from gsz.decoder.raht import build_raht_tree, raht_inverse
from gsz.encoder.pipeline import (EncodeOptions, EncodeOptionsError, compute_train_importance, encode,
                                  raht_weights)
from gsz.encoder.raht import raht_forward

from test_raht import voxelise

OPTS = dict(train_views=4, importance_width=96)


@pytest.fixture(scope="module")
def jug2k(sample_sh3):
    """2,000 Gaussians of the jug sample at SH degree 1 and their importance."""
    idx = np.sort(np.random.default_rng(3).choice(len(sample_sh3), 2000, replace=False))
    cloud = sample_sh3.subset(idx).with_sh_degree(1)
    return cloud, compute_train_importance(cloud, EncodeOptions(**OPTS))


def test_weighted_transform_roundtrip_and_weighted_energy(sample_sh0):
    codes, attrs = voxelise(sample_sh0, 10)
    w = np.random.default_rng(0).integers(1, 65536, codes.size)
    tree = build_raht_tree(codes, 10, w)
    dc, ac = raht_forward(attrs, tree)
    np.testing.assert_allclose(raht_inverse(dc, ac, tree), attrs, rtol=0, atol=1e-9)
    # coefficient energy is the weighted energy of the values: coefficient errors are weighted errors
    np.testing.assert_allclose(dc ** 2 + (ac ** 2).sum(0), (w[:, None] * attrs ** 2).sum(0), rtol=1e-9)


def test_unit_weights_give_the_plain_tree(sample_sh0):
    codes, attrs = voxelise(sample_sh0, 9)
    plain, ones = build_raht_tree(codes, 9), build_raht_tree(codes, 9, np.ones(codes.size, np.int64))
    np.testing.assert_array_equal(plain.ac_slots, ones.ac_slots)
    for a, b in zip(plain.levels, ones.levels):
        np.testing.assert_array_equal(a.left, b.left)
        np.testing.assert_array_equal(a.w_left, b.w_left)
        np.testing.assert_array_equal(a.w_right, b.w_right)
    dc, ac = raht_forward(attrs, plain)
    np.testing.assert_array_equal(raht_inverse(dc, ac, plain), raht_inverse(dc, ac, ones))


@pytest.mark.parametrize("bad", [0, 65536, -3])
def test_leaf_weights_outside_range_are_rejected(bad):
    codes = np.arange(8, dtype=np.uint64)
    w = np.ones(8, np.int64)
    w[3] = bad
    with pytest.raises(GszFormatError, match="1..65535"):
        build_raht_tree(codes, 1, w)
    if native.enabled():
        with pytest.raises(GszFormatError, match="1..65535"):
            native.module().raht_tree(codes, 1, w)


@pytest.mark.skipif(not native.enabled(), reason="native accelerator not built")
def test_native_weighted_inverse_is_bit_identical():
    rng = np.random.default_rng(1)
    codes = np.unique(rng.integers(0, 2 ** 36, 6000).astype(np.uint64))
    n = codes.size
    w = rng.integers(1, 65536, n).astype(np.int64)
    dc, ac = rng.normal(size=7) * 50, rng.normal(size=(7, n - 1))
    want = raht_inverse(dc, ac.T, build_raht_tree(codes, 12, w)).T
    got = np.empty((7, n))
    native.module().raht_apply(native.module().raht_tree(codes, 12, w), dc, ac, 0, 7, got, False)
    np.testing.assert_array_equal(got, want)


def test_encoder_weights_follow_importance(jug2k):
    cloud, imp = jug2k
    rw = raht_weights(imp, 8)
    assert rw.weights[0] == 65535 and np.all(np.diff(rw.weights) <= 0)    # class 0 = most important
    means = [imp[rw.classes == k].mean() for k in range(8)]
    assert np.all(np.diff(means) <= 0)
    assert np.bincount(rw.classes).min() >= len(imp) // 8
    # nothing to weight: every voxel alike, or too few voxels for the classes
    assert raht_weights(np.ones(5000), 8) is None
    assert raht_weights(imp[:100], 8) is None


def chunk_types(data):
    return [c.type for c in read_container(data, known_types=KNOWN_CHUNKS).chunks]


@pytest.mark.usefixtures("each_decoder_path")
def test_weighted_file_roundtrip_on_each_path(jug2k):
    cloud, imp = jug2k
    # RGB: the colour transform's SHXF chunk would make the file 1.7 (this is about 1.5's RWGT)
    res = encode(cloud, EncodeOptions(reserve=1.0, bits=8, codebook=32, keep=200, sh_colour="rgb", **OPTS),
                 importance=imp)
    types = chunk_types(res.data)
    assert CHUNK_RWGT in types and types.index(CHUNK_RWGT) == types.index(b"GEOM") + 1
    assert read_container(res.data).header.version == (1, 5)
    assert decode(res.data).equals(res.cloud)


def test_shcl_takes_rwgt_classes_when_every_vector_is_kept(jug2k):
    cloud, imp = jug2k
    opts = dict(reserve=1.0, bits=8, codebook=32, keep=len(cloud), sh_classes=4, raht_classes=4, **OPTS)
    res = encode(cloud, EncodeOptions(**opts), importance=imp)
    c = read_container(res.data, known_types=KNOWN_CHUNKS)
    shcl = next(ch for ch in c.chunks if ch.type == CHUNK_SHCL)
    assert bytes(shcl.data) == b"\x00"                # 1 byte instead of the 3-bit-a-vector stream
    with native.numpy_only():
        assert decode(res.data).equals(res.cloud)
    assert decode(res.data).equals(res.cloud)
    # with fewer SH classes than RAHT classes the SHCL chunk carries its own
    res4 = encode(cloud, EncodeOptions(**{**opts, "sh_classes": 2}), importance=imp)
    shcl4 = next(ch for ch in read_container(res4.data, known_types=KNOWN_CHUNKS).chunks if ch.type == CHUNK_SHCL)
    assert shcl4.data[0] == 2 and len(shcl4.data) > 1
    assert decode(res4.data).equals(res4.cloud)


def test_weights_cut_the_important_gaussians_error(jug2k):
    """At the same bit-width, the weighted file's opacity/colour error falls on the Gaussians
    that matter: lower importance-weighted error than plain RAHT for no more attribute bytes
    (the classes themselves cost the RWGT chunk)."""
    cloud, imp = jug2k
    base = dict(reserve=1.0, bits=6, codebook=32, keep=0, **OPTS)
    plain = encode(cloud, EncodeOptions(raht_classes=1, **base), importance=imp)
    weighted = encode(cloud, EncodeOptions(**base), importance=imp)
    assert CHUNK_RWGT not in chunk_types(plain.data) and CHUNK_RWGT in chunk_types(weighted.data)

    def weighted_error(res):
        out = res.cloud
        # voxel order differs from input order: compare per decoded Gaussian with its nearest input
        d2 = ((out.positions[:, None, :] - cloud.positions[None, :, :]) ** 2).sum(-1)
        src = d2.argmin(1)
        e = ((out.sh_dc - cloud.sh_dc[src]) ** 2).sum(1) + (out.opacities - cloud.opacities[src]) ** 2
        return float((imp[src] * e).sum() / imp[src].sum())
    assert weighted_error(weighted) < 0.8 * weighted_error(plain)

    def attr_bytes(res):
        return sum(len(c.data) for c in read_container(res.data, known_types=KNOWN_CHUNKS).chunks
                   if c.type == b"ATTR")
    assert attr_bytes(weighted) <= 1.01 * attr_bytes(plain)


def test_raht_classes_option_is_checked():
    with pytest.raises(EncodeOptionsError, match="--raht-classes must be 1..16"):
        EncodeOptions(raht_classes=17).validate()
    with pytest.raises(EncodeOptionsError, match="--raht-classes must be 1..16"):
        EncodeOptions(raht_classes=0).validate()


def test_a_1_4_decoder_meets_rwgt_as_unknown_required_chunk(jug2k):
    cloud, imp = jug2k
    res = encode(cloud, EncodeOptions(reserve=1.0, bits=8, codebook=32, keep=200, **OPTS), importance=imp)
    older = tuple(t for t in KNOWN_CHUNKS if t != CHUNK_RWGT)
    with pytest.raises(GszFormatError, match="required chunk type RWGT is not supported"):
        read_container(res.data, known_types=older)
