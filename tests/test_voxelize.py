"""Voxelisation on the cubic octree grid, depth choice and per-voxel merge."""

import numpy as np
import pytest

from conftest import shared_scene
from gsz.decoder.cloud import GaussianCloud
from gsz.decoder.geometry import voxel_centres
from gsz.decoder.morton import morton_encode
from gsz.decoder.rotation import quaternion_to_matrix
from gsz.encoder.orientation import canonical_orientations
from gsz.encoder.voxelize import (VoxelizeError, bounding_cube, choose_depth, merge_fraction,
                                  position_error, robust_diagonal, voxel_coords, voxelize)


def _cloud(pos, rot=None, ls=None, op=None, dc=None, rest=None, degree=1):
    n = len(pos)
    rng = np.random.default_rng(7)
    return GaussianCloud(
        positions=np.asarray(pos, np.float32),
        scales=rng.normal(-3, 0.5, (n, 3)) if ls is None else ls,
        rotations=rng.normal(size=(n, 4)) if rot is None else rot,
        opacities=rng.normal(size=n) if op is None else op,
        sh_dc=rng.normal(size=(n, 3)) if dc is None else dc,
        sh_rest=rng.normal(size=(n, 3, 3)) if rest is None else rest, sh_degree=degree)


def _cov(q, ls):
    r = quaternion_to_matrix(np.asarray(q, np.float64))
    return np.einsum("nij,nj,nkj->nik", r, np.exp(2 * np.asarray(ls, np.float64)), r)


def test_no_merge_when_points_are_in_distinct_voxels(sample_sh3):
    # The SPZ-sourced sample has a few exactly duplicated centres: drop them first.
    _, first = np.unique(sample_sh3.positions, axis=0, return_index=True)
    c = sample_sh3.subset(np.sort(first))
    d = 16
    v = voxelize(c, np.ones(len(c)), d)
    assert v.merged_fraction == 0.0 and len(v.ijk) == len(c)
    # Attributes are unchanged bit for bit (permuted into Morton order), rotation and scales in
    # their nearest-identity form (encoder/orientation.py)
    p = np.argsort(v.index_of_point)
    assert np.array_equal(v.index_of_point[p], np.arange(len(c)))
    rot, scales = canonical_orientations(c.rotations, c.scales)
    expect = dict(rotations=rot, scales=scales)
    for f in ("scales", "rotations", "opacities", "sh_dc", "sh_rest"):
        assert np.array_equal(getattr(v.cloud, f), expect.get(f, getattr(c, f))[p]), f
    # Positions within half a voxel diagonal (+ float32 rounding of the output).
    err = np.linalg.norm(v.cloud.positions.astype(np.float64)
                         - c.positions.astype(np.float64)[p], axis=1)
    tol = position_error(v.side, d) + 4 * np.finfo(np.float32).eps * np.abs(c.positions).max()
    assert err.max() <= tol
    # Morton order, unique.
    codes = morton_encode(v.ijk)
    assert np.all(np.diff(codes.astype(np.float64)) > 0) and np.all(codes[1:] > codes[:-1])
    np.testing.assert_array_equal(v.cloud.positions,
                                  voxel_centres(v.ijk, v.origin, v.side, d).astype(np.float32))
    assert np.array_equal(v.importance, np.ones(len(c)))


def test_exact_duplicates_keep_every_gaussian_at_a_fine_depth(sample_sh3):
    # The SPZ-sourced sample has exactly duplicated centres: merged at every depth, they capped
    # the fidelity of any budget.  Where a voxel is far below the Gaussians' size, the less
    # important twin moves to a free neighbouring voxel with its attributes bit for bit.
    c = sample_sh3
    dup = len(c) - np.unique(c.positions, axis=0).shape[0]
    assert dup > 0
    imp = 1 / (1 + np.exp(-c.opacities.astype(np.float64)))
    d = 16
    v = voxelize(c, imp, d)
    assert len(v.ijk) == len(c) and v.merged_fraction == 0.0 and v.relocated == dup
    p = np.argsort(v.index_of_point)
    rot, scales = canonical_orientations(c.rotations, c.scales)
    for f, want in (("scales", scales), ("rotations", rot), ("opacities", c.opacities),
                    ("sh_dc", c.sh_dc), ("sh_rest", c.sh_rest)):
        assert np.array_equal(getattr(v.cloud, f), want[p]), f
    # a moved Gaussian lands in a neighbouring voxel: at most 1.5 voxels from its centre an axis
    pitch = v.side / (1 << d)
    err = np.abs(v.cloud.positions.astype(np.float64) - c.positions.astype(np.float64)[p])
    assert err.max() <= 1.5 * pitch + 4 * np.finfo(np.float32).eps * np.abs(c.positions).max()
    # of each duplicated pair the more important Gaussian keeps its own voxel
    home = voxel_coords(c.positions, d, v.origin, v.side)
    stayed = np.all(v.ijk[v.index_of_point] == home, axis=1)
    assert (~stayed).sum() == dup
    _, inv = np.unique(c.positions, axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    for g in np.unique(inv[~stayed]):
        members = np.flatnonzero(inv == g)
        assert stayed[members[np.argmax(imp[members])]]
    # without relocation they merge, as at a depth where a voxel is not small against them
    assert len(voxelize(c, imp, d, relocate=False).ijk) == len(c) - dup
    assert voxelize(c, imp, d).cloud.equals(v.cloud)                 # deterministic


def test_duplicates_merge_where_a_voxel_is_not_small_against_them():
    # scales e^-3 = 0.05 against a voxel of 0.25: moving one would displace it by several sizes
    pos = np.array([[0.1, 0.1, 0.1], [0.1, 0.1, 0.1], [0.9, 0.9, 0.9]])
    c = _cloud(pos, ls=np.full((3, 3), -3.0))
    assert len(voxelize(c, np.ones(3), 2).ijk) == 2
    # at depth 12 the voxel (2.4e-4) is far below them: the twin moves, towards its own centre
    pos = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [1.0, 1.0, 1.0]])
    pos[:2] = np.array([100.9, 100.5, 100.5]) / (1 << 12)     # near its voxel's +x face
    c = _cloud(pos, ls=np.full((4, 3), -3.0))
    v = voxelize(c, np.array([2.0, 1.0, 1.0, 1.0]), 12)
    assert len(v.ijk) == 4
    moved = v.ijk[v.index_of_point[1]] - v.ijk[v.index_of_point[0]]
    assert moved.tolist() == [1, 0, 0]


def test_every_point_inside_the_cube_including_extremes():
    # The reference's edge bug: a point exactly at the axis max landed in voxel 2^d.
    pos = np.array([[0, 0, 0], [1, 1, 1], [1, 0, 0.5], [0.999999, 1, 0], [0.25, 0.5, 1]])
    for d in (1, 5, 10, 21):
        origin, side = bounding_cube(pos)
        ijk = voxel_coords(pos, d, origin, side)
        assert ijk.min() >= 0 and ijk.max() == (1 << d) - 1
        assert ijk[1].tolist() == [(1 << d) - 1] * 3
        # The floor rule holds without the clip for every point: the cube really contains them.
        raw = np.floor((pos - origin) * ((1 << d) / side))
        assert raw.max() <= (1 << d) - 1 and raw.min() >= 0
    # Far from the origin, where the padding is below float spacing.
    far = pos * 1e-3 + 1e6
    origin, side = bounding_cube(far)
    assert np.all(origin + side > far.max(axis=0))
    # A degenerate cloud (one point) still gets a positive side.
    o, s = bounding_cube(np.array([[3.0, 4.0, 5.0]]))
    assert s > 0 and np.all(voxel_coords(np.array([[3.0, 4.0, 5.0]]), 8, o, s) == 0)


def test_merge_hand_case_with_antipodal_quaternions():
    # Two Gaussians in one voxel, a third elsewhere.  Quaternion 1 is -(quaternion 0) rotated a
    # little: a naive mean would nearly cancel.
    q0 = np.array([0.9, 0.1, 0.3, 0.2])
    q1 = -np.array([0.88, 0.12, 0.33, 0.18])
    pos = np.array([[0.1, 0.1, 0.1], [0.12, 0.11, 0.1], [0.9, 0.9, 0.9]])
    ls = np.array([[-2.0, -2.5, -3.0], [-2.2, -2.1, -3.3], [-1.0, -1.0, -1.0]])
    op = np.array([1.0, -1.0, 0.5])
    dc = np.array([[1.0, 2.0, 3.0], [3.0, 2.0, 1.0], [0, 0, 0]])
    rest = np.arange(27, dtype=np.float64).reshape(3, 3, 3)
    c = _cloud(pos, rot=np.stack([q0, q1, [1, 0, 0, 0]]), ls=ls, op=op, dc=dc, rest=rest)
    imp = np.array([3.0, 1.0, 5.0])
    v = voxelize(c, imp, depth=2, rotation="average")
    assert len(v.ijk) == 2 and v.merged_fraction == pytest.approx(1 / 3)
    assert v.index_of_point[0] == v.index_of_point[1] != v.index_of_point[2]
    j = v.index_of_point[0]
    w = imp[:2] / imp[:2].sum()
    np.testing.assert_allclose(v.cloud.opacities[j], w @ op[:2], rtol=1e-6)
    np.testing.assert_allclose(v.cloud.sh_dc[j], w @ dc[:2], rtol=1e-6)
    np.testing.assert_allclose(v.cloud.sh_rest[j], np.tensordot(w, rest[:2], 1), rtol=1e-6)
    np.testing.assert_allclose(v.cloud.scales[j], w @ ls[:2], rtol=1e-6)
    qa = q0 / np.linalg.norm(q0)
    qb = -q1 / np.linalg.norm(q1)                       # sign-aligned to the more important q0
    qm = w[0] * qa + w[1] * qb
    qm /= np.linalg.norm(qm)
    np.testing.assert_allclose(v.cloud.rotations[j], qm, atol=1e-6)
    assert v.importance[j] == pytest.approx(4.0) and v.importance[1 - j] == pytest.approx(5.0)
    # The lone Gaussian is untouched.
    k = v.index_of_point[2]
    assert np.array_equal(v.cloud.scales[k], c.scales[2])
    assert np.array_equal(v.cloud.rotations[k], c.rotations[2])

    # "max" keeps the most important member's (normalised) rotation.
    vm = voxelize(c, imp, depth=2, rotation="max")
    np.testing.assert_allclose(vm.cloud.rotations[j], qa, atol=1e-6)
    # "moment" (default) reproduces the weighted mean covariance.
    vd = voxelize(c, imp, depth=2)
    target = np.tensordot(w, _cov(c.rotations[:2], ls[:2]), 1)
    got = _cov(vd.cloud.rotations[j:j + 1], vd.cloud.scales[j:j + 1])[0]
    np.testing.assert_allclose(got, target, rtol=1e-5, atol=1e-9)
    assert abs(np.linalg.norm(vd.cloud.rotations[j]) - 1) < 1e-6
    # Invisible members only: equal weights.
    v0 = voxelize(c, np.array([0.0, 0.0, 1.0]), depth=2, rotation="average")
    np.testing.assert_allclose(v0.cloud.opacities[j], op[:2].mean(), atol=1e-6)


def test_moment_merge_on_real_scene_matches_mean_covariance(sample_sh0):
    c = sample_sh0
    imp = 1 / (1 + np.exp(-c.opacities.astype(np.float64)))
    v = voxelize(c, imp, 8)
    assert 0.01 < v.merged_fraction < 0.9
    cnt = np.bincount(v.index_of_point)
    sel = np.flatnonzero(cnt[v.index_of_point] > 1)
    tgt = np.zeros((len(cnt), 3, 3))
    np.add.at(tgt, v.index_of_point[sel], _cov(c.rotations[sel], c.scales[sel]) * imp[sel, None, None])
    ws = np.bincount(v.index_of_point[sel], weights=imp[sel], minlength=len(cnt))
    mv = np.flatnonzero(cnt > 1)
    tgt = tgt[mv] / ws[mv, None, None]
    got = _cov(v.cloud.rotations[mv], v.cloud.scales[mv])
    rel = np.linalg.norm(got - tgt, axis=(1, 2)) / np.linalg.norm(tgt, axis=(1, 2))
    assert np.median(rel) < 1e-4 and rel.max() < 1e-2
    # Summed importance is conserved.
    assert v.importance.sum() == pytest.approx(imp.sum(), rel=1e-12)
    assert np.all(np.isfinite(v.cloud.scales)) and np.all(np.isfinite(v.cloud.rotations))


def test_voxelize_is_deterministic_and_order_independent_in_output(sample_sh0):
    c = sample_sh0
    imp = np.exp(c.scales.astype(np.float64).sum(1))
    a, b = voxelize(c, imp, 9), voxelize(c, imp.copy(), 9)
    assert a.cloud.equals(b.cloud) and np.array_equal(a.ijk, b.ijk)
    assert np.array_equal(a.index_of_point, b.index_of_point)
    # Reordering the input gives the same voxels (Morton-sorted) and the same merged values up
    # to float rounding of the weighted sums.
    p = np.random.default_rng(0).permutation(len(c))
    r = voxelize(c.subset(p), imp[p], 9)
    assert np.array_equal(r.ijk, a.ijk)
    np.testing.assert_allclose(r.cloud.opacities, a.cloud.opacities, rtol=1e-5, atol=1e-6)
    assert np.array_equal(r.index_of_point, a.index_of_point[p])


@pytest.mark.parametrize("rotation", ["moment", "average", "max"])
def test_voxelizing_rows_of_a_cloud_equals_voxelizing_their_subset(sample_sh0, rotation):
    """rows= (the search's pruned Gaussians, without a pruned copy of the cloud) gives the
    very arrays a subset gives, merged voxels included (depth 7 merges a third)."""
    c = sample_sh0
    imp = np.exp(c.scales.astype(np.float64).sum(1))
    rows = np.sort(np.random.default_rng(3).choice(len(c), size=len(c) * 2 // 3, replace=False))
    a = voxelize(c.subset(rows), imp[rows], 7, rotation=rotation)
    b = voxelize(c, imp[rows], 7, rotation=rotation, rows=rows)
    assert a.merged_fraction > 0.3 and a.cloud.equals(b.cloud) and np.array_equal(a.ijk, b.ijk)
    assert np.array_equal(a.index_of_point, b.index_of_point) and np.array_equal(a.importance, b.importance)


@pytest.mark.parametrize("with_rows", [False, True])
def test_sourced_sh_grid_is_the_same_cloud(sample_sh3, with_rows):
    """sourced_sh= (the search's grids: the SH rest as rows of the input's, not gathered) gives
    the same voxels, and full_cloud() the same arrays, merged voxels included."""
    from gsz.encoder.pipeline import stage_source
    c = sample_sh3
    imp = np.exp(c.scales.astype(np.float64).sum(1))
    rows = np.sort(np.random.default_rng(5).choice(len(c), size=len(c) * 3 // 4, replace=False)) \
        if with_rows else None
    w = imp if rows is None else imp[rows]
    a = voxelize(c, w, 7, rows=rows)
    b = voxelize(c, w, 7, rows=rows, sourced_sh=True)
    assert a.merged_fraction > 0.1 and a.sh is None and b.cloud.sh_rest.shape[1] == 0
    assert b.full_cloud().equals(a.cloud) and a.full_cloud() is a.cloud
    kept = np.arange(len(c)) if rows is None else rows
    assert np.array_equal(b.sh.source, stage_source(kept, a))
    assert np.array_equal(np.asarray(b.sh), a.cloud.sh_rest.reshape(len(a.ijk), -1))


def test_voxelize_rejects_bad_input(sample_sh0):
    c = sample_sh0
    ones = np.ones(len(c))
    with pytest.raises(VoxelizeError, match="depth"):
        voxelize(c, ones, 22)
    with pytest.raises(VoxelizeError, match="depth"):
        voxelize(c, ones, 0)
    with pytest.raises(VoxelizeError, match="importance"):
        voxelize(c, ones[:-1], 10)
    with pytest.raises(VoxelizeError, match="importance"):
        voxelize(c, -ones, 10)
    bad = c.copy()
    bad.positions[3, 1] = np.nan
    with pytest.raises(VoxelizeError, match="index 3"):
        voxelize(bad, ones, 10)
    with pytest.raises(VoxelizeError, match="cube"):
        voxelize(c, ones, 10, cube=(np.zeros(3), 0.0))
    with pytest.raises(VoxelizeError, match="rotation"):
        voxelize(c, ones, 10, rotation="slerp")


def test_choose_depth_meets_the_budget(sample_sh0):
    x = sample_sh0.positions
    origin, side = bounding_cube(x)
    rd = robust_diagonal(x)
    for rel in (1e-2, 1e-3, 5e-4, 1e-4):
        d = choose_depth(x, rel_error=rel)
        assert position_error(side, d) <= rel * rd
        assert d == 6 or position_error(side, d - 1) > rel * rd
    # An absolute budget, clamps, and the extra merge requirement.
    assert choose_depth(x, max_error=position_error(side, 9)) == 9
    assert choose_depth(x, max_error=0.0) == 21
    assert choose_depth(x, rel_error=0.5, min_depth=7) == 7
    d_m = choose_depth(x, rel_error=1e-2, max_merge=0.01)
    assert merge_fraction(x, d_m) - merge_fraction(x, 21) <= 0.01
    assert merge_fraction(x, d_m - 1) - merge_fraction(x, 21) > 0.01
    # Outliers widen the cube but not the robust budget: the depth goes up, never down.
    far = np.concatenate([x, [[1e3, 1e3, 1e3]]]).astype(np.float32)
    assert choose_depth(far) > choose_depth(x)
    with pytest.raises(VoxelizeError):
        choose_depth(x, rel_error=-1.0)
    with pytest.raises(VoxelizeError):
        choose_depth(x, min_depth=12, max_depth=10)


def test_default_depth_keeps_merges_rare_on_shared_scene():
    import gsz
    c = gsz.read_ply(shared_scene("houseplant_sh0.ply"))
    d = choose_depth(c.positions)
    assert d == 11                           # the geometry anchor's operating depth
    assert merge_fraction(c.positions, d) < 0.01


def test_moment_merge_of_flat_gaussians_keeps_a_sane_thin_axis():
    # Two flat discs (thin axis e^-15) in one voxel: rounding in the eigendecomposition must not
    # turn the thin axis into log(1e-300) -- an outlier that would wreck the scale quantiser.
    ls = np.array([[-1.0, -1.0, -15.0], [-1.2, -1.0, -15.0], [0.0, 0.0, 0.0]])
    rot = np.array([[1.0, 0, 0, 0], [0.999, 0.02, -0.01, 0.03], [1.0, 0, 0, 0]])
    c = _cloud([[0, 0, 0], [0.01, 0, 0], [1, 1, 1]], rot=rot, ls=ls)
    v = voxelize(c, np.ones(3), 2)
    merged = v.cloud.scales[v.index_of_point[0]]
    assert merged.min() >= -15.0 - 1e-4 and merged.max() <= -0.9
    assert np.all(np.isfinite(v.cloud.rotations))
