"""Quaternion <-> Euler (ZYX) conversion: decoded rotations must reproduce the covariance."""
import numpy as np
import pytest

from gsz.decoder.rotation import (euler_to_matrix, euler_to_quaternion, quaternion_to_euler,
                                  quaternion_to_matrix, wrap_to_reference)


def covariance(rot_matrix, log_scales):
    s2 = np.exp(2.0 * np.asarray(log_scales, np.float64))
    return np.einsum("nij,nj,nkj->nik", rot_matrix, s2, rot_matrix)


def roundtrip_cov_error(quats, log_scales, angle_dtype=np.float64):
    """Max covariance error relative to the Gaussian's largest variance."""
    euler = quaternion_to_euler(quats).astype(angle_dtype)
    q2 = euler_to_quaternion(euler)
    c1 = covariance(quaternion_to_matrix(quats), log_scales)
    c2 = covariance(quaternion_to_matrix(q2), log_scales)
    rel = np.abs(c1 - c2).max(axis=(1, 2)) / np.exp(2.0 * np.asarray(log_scales, np.float64)).max(axis=1)
    return rel.max()


@pytest.mark.parametrize("fixture", ["sample_sh0", "sample_sh3"])
def test_real_samples_reproduce_covariance(fixture, request):
    cloud = request.getfixturevalue(fixture)
    assert roundtrip_cov_error(cloud.rotations, cloud.scales) < 1e-9
    # Stored as float32 angles (what a decoder may see before quantisation): still far below 1e-5.
    assert roundtrip_cov_error(cloud.rotations, cloud.scales, np.float32) < 1e-5


def _gimbal_quats(rng, n):
    """Quaternions at and within 1e-12 .. 1e-4 rad of pitch = +-90 degrees."""
    roll = rng.uniform(-np.pi, np.pi, n)
    yaw = rng.uniform(-np.pi, np.pi, n)
    sign = rng.choice([-1.0, 1.0], n)
    offs = rng.choice([0.0, 1e-12, 1e-9, 1e-7, 1e-6, 1e-4], n) * rng.choice([-1.0, 1.0], n)
    pitch = sign * (np.pi / 2 - np.abs(offs))
    return euler_to_quaternion(np.stack([roll, pitch, yaw], 1))


def test_random_and_hard_quaternions():
    rng = np.random.default_rng(7)
    n = 4000
    q = rng.standard_normal((n, 4))
    q[: n // 4, 0] = -np.abs(q[: n // 4, 0])                 # negative w
    q[n // 4: n // 2] *= 1e-30                               # tiny
    q[n // 2: n // 2 + 100] *= 1e-200                        # underflows a naive norm
    q[n // 2 + 100: n // 2 + 200] *= 1e150                   # overflows a naive norm
    q = np.concatenate([q, _gimbal_quats(rng, 2000), -_gimbal_quats(rng, 500)])
    # Axis-aligned and exactly-gimbal corner cases.
    h = np.sqrt(0.5)
    q = np.concatenate([q, [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1],
                            [h, 0, h, 0], [h, 0, -h, 0], [0.5, 0.5, 0.5, 0.5], [0.5, -0.5, 0.5, -0.5]]])
    log_s = rng.uniform(-6, 1, (q.shape[0], 3))
    euler = quaternion_to_euler(q)
    assert np.all(np.isfinite(euler))
    assert np.all(np.abs(euler[:, 1]) <= np.pi / 2 + 1e-12)
    assert roundtrip_cov_error(q, log_s) < 1e-5
    # Stronger: the rotation itself is reproduced (float64 path) to ~1e-7 even at gimbal lock.
    r1 = quaternion_to_matrix(q)
    assert np.abs(r1 - euler_to_matrix(euler)).max() < 1e-6
    assert np.abs(r1 - quaternion_to_matrix(euler_to_quaternion(euler))).max() < 1e-6


def test_euler_to_quaternion_convention_and_canonical_sign():
    rng = np.random.default_rng(3)
    e = rng.uniform(-4, 4, (500, 3))           # beyond +-pi on purpose: any real angles decode
    q = euler_to_quaternion(e)
    assert np.allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-12)
    assert np.all(q[:, 0] >= 0)
    assert np.abs(quaternion_to_matrix(q) - euler_to_matrix(e)).max() < 1e-12
    # Single-axis checks of R = Rz(yaw) Ry(pitch) Rx(roll).
    a = 0.3
    assert np.allclose(euler_to_quaternion([a, 0, 0]), [np.cos(a / 2), np.sin(a / 2), 0, 0])
    assert np.allclose(euler_to_quaternion([0, a, 0]), [np.cos(a / 2), 0, np.sin(a / 2), 0])
    assert np.allclose(euler_to_quaternion([0, 0, a]), [np.cos(a / 2), 0, 0, np.sin(a / 2)])


def test_degenerate_inputs_never_give_nan():
    q = np.array([[0, 0, 0, 0], [np.nan, 1, 0, 0], [np.inf, 0, 0, 0]], np.float64)
    e = quaternion_to_euler(q)
    assert np.array_equal(e, np.zeros((3, 3)))
    q2 = euler_to_quaternion(np.array([[np.nan, 0, 0], [0, np.inf, 0], [0, 0, -np.inf]]))
    assert np.array_equal(q2, np.tile([1.0, 0, 0, 0], (3, 1)))


def test_wrap_to_reference_keeps_rotation(sample_sh0):
    e = quaternion_to_euler(sample_sh0.rotations)
    ref = np.random.default_rng(0).uniform(-3, 3, e.shape)
    w = wrap_to_reference(e, ref)
    assert np.all(w >= ref - np.pi - 1e-12) and np.all(w < ref + np.pi + 1e-12)
    assert np.abs(quaternion_to_matrix(euler_to_quaternion(w))
                  - quaternion_to_matrix(euler_to_quaternion(e))).max() < 1e-9
