"""RAHT tree, forward and inverse: exactness, orthonormality, layout, speed, bad input."""

import numpy as np
import pytest

from gsz.decoder.errors import GszFormatError
from gsz.decoder.morton import morton_encode
from gsz.decoder.raht import build_raht_tree, raht_inverse
from gsz.decoder.rotation import quaternion_to_euler
from gsz.encoder.raht import leaf_interleaved_order, raht_forward


def voxelise(cloud, depth):
    """(sorted unique Morton codes, per-voxel mean of the 7 RAHT channels) -- test helper."""
    p = cloud.positions.astype(np.float64)
    lo, hi = p.min(0), p.max(0)
    ijk = np.minimum(((p - lo) / (hi - lo) * 2 ** depth).astype(np.int64), 2 ** depth - 1)
    codes, inv = np.unique(morton_encode(ijk), return_inverse=True)
    attrs = np.concatenate([cloud.opacities[:, None], quaternion_to_euler(cloud.rotations),
                            cloud.sh_dc], axis=1).astype(np.float64)
    sums = np.zeros((codes.size, attrs.shape[1]))
    np.add.at(sums, inv, attrs)
    return codes, sums / np.bincount(inv)[:, None]


def naive_raht(codes, depth, attrs):
    """Per-node Python implementation of the normative text (independent of the vectorised one)."""
    nodes = [(int(c), 1.0, attrs[i].copy(), i) for i, c in enumerate(codes)]  # code, w, value, slot
    highs = []  # (level, slot, H)
    for level in range(3 * depth):
        out, i = [], 0
        while i < len(nodes):
            c, w, v, s = nodes[i]
            if i + 1 < len(nodes) and nodes[i + 1][0] >> 1 == c >> 1:
                _, w2, v2, s2 = nodes[i + 1]
                a = np.sqrt(w + w2)
                low = (np.sqrt(w) * v + np.sqrt(w2) * v2) / a
                highs.append((level, s2, (-np.sqrt(w2) * v + np.sqrt(w) * v2) / a))
                out.append((c >> 1, w + w2, low, s))
                i += 2
            else:
                out.append((c >> 1, w, v, s))
                i += 1
        nodes = out
    assert len(nodes) == 1
    highs.sort(key=lambda h: (-h[0], h[1]))  # stream order: coarse level first, then slot
    ac = np.array([h[2] for h in highs]).reshape(len(highs), attrs.shape[1])
    return nodes[0][2], ac


@pytest.mark.parametrize("n,depth,seed", [(1, 3, 0), (2, 2, 1), (37, 3, 2), (300, 4, 3), (200, 6, 4)])
def test_matches_naive_reference(n, depth, seed):
    rng = np.random.default_rng(seed)
    codes = np.sort(rng.choice(2 ** (3 * depth), size=n, replace=False)).astype(np.uint64)
    x = rng.standard_normal((n, 3))
    tree = build_raht_tree(codes, depth)
    dc, ac = raht_forward(x, tree)
    dc_ref, ac_ref = naive_raht(codes, depth, x)
    assert np.allclose(dc, dc_ref, atol=1e-12) and np.allclose(ac, ac_ref, atol=1e-12)
    assert np.allclose(raht_inverse(dc, ac, tree), x, atol=1e-12)


@pytest.mark.parametrize("fixture,depth", [("sample_sh0", 10), ("sample_sh3", 12)])
def test_real_sample_roundtrip_and_energy(fixture, depth, request):
    codes, attrs = voxelise(request.getfixturevalue(fixture), depth)
    assert codes.size > 5000
    tree = build_raht_tree(codes, depth)
    dc, ac = raht_forward(attrs, tree)
    assert ac.shape == (codes.size - 1, 7)
    assert np.abs(raht_inverse(dc, ac, tree) - attrs).max() < 1e-9
    energy = dc ** 2 + (ac ** 2).sum(0)
    assert np.allclose(energy, (attrs ** 2).sum(0), rtol=1e-12)
    assert np.allclose(dc, np.sqrt(codes.size) * attrs.mean(0), rtol=1e-12)
    # Layout: ac_slots is a permutation of 1..N-1, grouped by level, coarse first.
    assert np.array_equal(np.sort(tree.ac_slots), np.arange(1, codes.size))
    sizes = tree.level_sizes()
    assert sum(s for _, s in sizes) == codes.size - 1
    assert [lv for lv, _ in sizes] == sorted((lv for lv, _ in sizes), reverse=True)
    assert sizes[0][1] == 1  # the root merge: exactly one coefficient, first in the stream
    # Smooth real attributes: most energy sits in the coarse levels.
    coarse = ac[: ac.shape[0] // 100]
    assert (coarse ** 2).mean() > 10 * (ac ** 2).mean()
    # The leaf-interleave permutation maps stream order to slots 1..N-1.
    assert np.array_equal(tree.ac_slots[leaf_interleaved_order(tree)], np.arange(1, codes.size))


def test_constant_attributes_have_zero_ac(sample_sh0):
    codes, _ = voxelise(sample_sh0, 10)
    tree = build_raht_tree(codes, 10)
    dc, ac = raht_forward(np.full((codes.size, 2), 3.5), tree)
    assert np.abs(ac).max() < 1e-9
    assert np.allclose(dc, 3.5 * np.sqrt(codes.size))


def test_small_trees():
    t1 = build_raht_tree(np.array([5], np.uint64), 2)
    dc, ac = raht_forward(np.array([[2.0, -1.0]]), t1)
    assert ac.shape == (0, 2) and np.array_equal(dc, [2.0, -1.0])
    assert np.array_equal(raht_inverse(dc, ac, t1), [[2.0, -1.0]])
    # Siblings at the finest level: plain Haar.
    t2 = build_raht_tree(np.array([6, 7], np.uint64), 1)
    dc, ac = raht_forward(np.array([[1.0], [3.0]]), t2)
    assert np.allclose(dc, [4 / np.sqrt(2)]) and np.allclose(ac, [[2 / np.sqrt(2)]])
    # Far apart: merged only at the top level, weights 1 and 1 again.
    t3 = build_raht_tree(np.array([0, 63], np.uint64), 2)
    assert [lv.level for lv in t3.levels] == [5]
    # Unequal weights: 3 leaves -> (w1, w2) = (2, 1) at the second merge.
    t4 = build_raht_tree(np.array([0, 1, 2], np.uint64), 1)
    x = np.array([[1.0], [2.0], [4.0]])
    dc, ac = raht_forward(x, t4)
    assert np.allclose(dc, [7 / np.sqrt(3)])
    low01 = 3 / np.sqrt(2)
    assert np.allclose(ac[0], (-1 * low01 + np.sqrt(2) * 4.0) / np.sqrt(3))
    assert np.allclose(raht_inverse(dc, ac, t4), x)


def test_bad_codes_are_rejected():
    with pytest.raises(GszFormatError):
        build_raht_tree(np.array([3, 1], np.uint64), 2)
    with pytest.raises(GszFormatError):
        build_raht_tree(np.array([1, 1], np.uint64), 2)
    with pytest.raises(GszFormatError):
        build_raht_tree(np.array([64], np.uint64), 2)          # needs more than 3*depth bits
    with pytest.raises(GszFormatError):
        build_raht_tree(np.zeros(0, np.uint64), 2)
    with pytest.raises(GszFormatError):
        build_raht_tree(np.array([0], np.uint64), 22)
    tree = build_raht_tree(np.array([0, 1, 2], np.uint64), 1)
    with pytest.raises(GszFormatError):
        raht_inverse(np.zeros(2), np.zeros((3, 2)), tree)


def test_round_trip_500k_points():
    rng = np.random.default_rng(11)
    ijk = rng.integers(0, 2 ** 20, (500_000, 3))
    ijk[:250_000] //= 4096  # half clustered: real trees have many merges at the fine levels
    codes = np.unique(morton_encode(ijk))
    x = rng.standard_normal((codes.size, 7))
    tree = build_raht_tree(codes, 20)          # (its speed: bench/bench_decode.py's finish stage)
    dc, ac = raht_forward(x, tree)
    y = raht_inverse(dc, ac, tree)
    assert np.abs(y - x).max() < 1e-9
