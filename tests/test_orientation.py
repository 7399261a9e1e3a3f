"""The nearest-identity form of each Gaussian's orientation (encoder/orientation.py): the same
covariance, Euler angles in a narrow range, stable and deterministic."""
import numpy as np

from codec_util import sample
from gsz.decoder.rotation import quat_mul, quaternion_to_euler, quaternion_to_matrix
from gsz.encoder.orientation import AXIS_SOURCE, CUBE_ROTATIONS, canonical_orientations


def _cov(rotations, scales):
    r = quaternion_to_matrix(rotations.astype(np.float64))
    return np.einsum("nij,nj,nkj->nik", r, np.exp(2 * scales.astype(np.float64)), r)


def _random(n, seed=0):
    rng = np.random.default_rng(seed)
    return (rng.normal(size=(n, 4)).astype(np.float32),
            rng.normal(-4, 1, size=(n, 3)).astype(np.float32))


def test_the_24_rotations_are_the_cube_group():
    m = quaternion_to_matrix(CUBE_ROTATIONS)
    # signed permutation matrices with det +1, all different, closed under products
    assert np.allclose(np.abs(m).sum(axis=1), 1) and np.allclose(np.linalg.det(m), 1)
    keys = {tuple(np.rint(x).astype(int).ravel()) for x in m}
    assert len(keys) == 24
    for a in m[:6]:
        for b in m:
            assert tuple(np.rint(a @ b).astype(int).ravel()) in keys
    assert np.array_equal(CUBE_ROTATIONS[0], [1, 0, 0, 0]) and np.array_equal(AXIS_SOURCE[0], [0, 1, 2])


def test_same_covariance_and_narrow_angles():
    q, s = _random(50_000)
    rq, rs = canonical_orientations(q, s)
    c0, c1 = _cov(q, s), _cov(rq, rs)
    rel = np.abs(c1 - c0).max(axis=(1, 2)) / np.abs(c0).max(axis=(1, 2))
    assert rel.max() < 1e-5
    # the scales are the same set per Gaussian
    assert np.array_equal(np.sort(rs, 1), np.sort(s, 1))
    # nearest the identity: |w| >= cos(62.8 deg / 2) and every Euler angle within ~ +-63 deg
    # (the input uses all of SO(3): roll and yaw reach +-180 deg)
    unit = rq / np.linalg.norm(rq.astype(np.float64), axis=1, keepdims=True)
    assert np.abs(unit[:, 0]).min() >= np.cos(np.radians(62.8) / 2) - 1e-6
    e = np.degrees(quaternion_to_euler(rq.astype(np.float64)))
    assert np.abs(e).max() < 64
    assert np.abs(np.degrees(quaternion_to_euler(q.astype(np.float64)))).max() > 170


def test_no_other_form_is_nearer_the_identity():
    q, s = _random(2_000, seed=1)
    rq, _ = canonical_orientations(q, s)
    unit = rq.astype(np.float64) / np.linalg.norm(rq.astype(np.float64), axis=1, keepdims=True)
    others = quat_mul(unit[:, None, :], CUBE_ROTATIONS[None, :, :])
    assert np.all(np.abs(others[..., 0]).max(axis=1) <= np.abs(unit[:, 0]) + 1e-6)


def test_idempotent_and_rows_already_canonical_keep_their_bits():
    q, s = _random(10_000, seed=2)
    rq, rs = canonical_orientations(q, s)
    again = canonical_orientations(rq, rs)
    assert np.array_equal(again[0], rq) and np.array_equal(again[1], rs)
    kept = np.all(rq == q, axis=1)
    assert kept.any() and np.array_equal(rs[kept], s[kept])


def test_in_place_and_fresh_agree_and_inputs_untouched():
    q, s = _random(70_000, seed=3)          # more than one chunk of rows
    q0, s0 = q.copy(), s.copy()
    fresh = canonical_orientations(q, s)
    assert np.array_equal(q, q0) and np.array_equal(s, s0)
    out = canonical_orientations(q, s, out=(q, s))
    assert out[0] is q and np.array_equal(q, fresh[0]) and np.array_equal(s, fresh[1])


def test_zero_quaternion_left_alone():
    q = np.array([[0, 0, 0, 0], [0, 1, 0, 0]], np.float32)
    s = np.array([[-1, -2, -3], [-1, -2, -3]], np.float32)
    rq, rs = canonical_orientations(q, s)
    assert np.array_equal(rq[0], q[0]) and np.array_equal(rs[0], s[0])
    # a half turn about x is the identity with y and z relabelled (same scales, same order)
    assert np.allclose(rq[1], [1, 0, 0, 0]) and np.array_equal(rs[1], s[1])


def test_real_sample_angles_cost_fewer_bits():
    """On a real capture the angles' spread (what a quantiser's range pays for) shrinks."""
    c = sample("sh0")
    rq, rs = canonical_orientations(c.rotations, c.scales)
    before = np.ptp(quaternion_to_euler(c.rotations.astype(np.float64)), axis=0)
    after = np.ptp(quaternion_to_euler(rq.astype(np.float64)), axis=0)
    assert np.all(after < 0.7 * before)

    def bits(e, step=0.02):
        _, n = np.unique(np.rint(e / step), return_counts=True)
        p = n / n.sum()
        return -(p * np.log2(p)).sum()
    eb = quaternion_to_euler(c.rotations.astype(np.float64))
    ea = quaternion_to_euler(rq.astype(np.float64))
    assert sum(bits(ea[:, k]) for k in range(3)) < sum(bits(eb[:, k]) for k in range(3)) - 2.0


def test_exact_ties_on_a_grid_still_reach_the_nearest_form():
    """Delivery formats put quaternions on a grid, where forms tie exactly: the chosen one is
    still as near the identity as any, the covariance the same, the choice repeatable."""
    import itertools
    q = np.array([v for v in itertools.product((-2, -1, 0, 1, 2), repeat=4) if any(v)], np.float32)
    s = np.tile(np.array([[-3.0, -4.0, -5.0]], np.float32), (len(q), 1))
    rq, rs = canonical_orientations(q, s)
    unit = rq.astype(np.float64) / np.linalg.norm(rq.astype(np.float64), axis=1, keepdims=True)
    qn = q.astype(np.float64) / np.linalg.norm(q.astype(np.float64), axis=1, keepdims=True)
    best = np.abs(quat_mul(qn[:, None, :], CUBE_ROTATIONS[None, :, :])[..., 0]).max(axis=1)
    assert np.allclose(np.abs(unit[:, 0]), best, atol=1e-6)
    c0, c1 = _cov(q, s), _cov(rq, rs)
    assert np.abs(c1 - c0).max() / np.abs(c0).max() < 1e-5
    again = canonical_orientations(q, s)
    assert np.array_equal(again[0], rq) and np.array_equal(again[1], rs)
