"""Rotation parameterisations: quaternion (w, x, y, z) <-> Euler angles (roll, pitch, yaw).

Convention (normative, ``format_spec/TRANSFORMS.md`` section 1): ZYX / aerospace,

    R = Rz(yaw) @ Ry(pitch) @ Rx(roll)

acting on column vectors, with Rx/Ry/Rz the right-handed elementary rotations.  Only this
composite rotation matters to a renderer (the covariance is R diag(s^2) R^T), so the decoder's
half of this module -- :func:`euler_to_quaternion` -- is the shared truth; the encoder may hand
it *any* angle triple whose composite rotation is the wanted one (for example angles shifted by
2*pi to keep neighbours close before RAHT, see :func:`wrap_to_reference`).

numpy only; all arithmetic is float64 internally.
"""
from __future__ import annotations

import numpy as np

from .errors import CloudValidationError

# Below this |cos(pitch)| the roll/yaw split is numerically meaningless (gimbal lock): only
# roll - yaw (pitch = +90 deg) or roll + yaw (pitch = -90 deg) is determined.  We then put the
# whole in-plane angle into roll and set yaw = 0.  At 1e-7 the error this choice makes in R is
# O(1e-7) and the error of the general branch is O(eps / 1e-7) = O(1e-9): both far below float32.
_GIMBAL_EPS = 1e-7


def quaternion_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices of quaternions.

    q: [..., 4] (w, x, y, z), any non-zero length (normalised here).  A zero or non-finite
    quaternion gives the identity (a 3DGS renderer normalises and such a Gaussian is garbage
    anyway; the identity keeps every downstream value finite).
    Returns float64 [..., 3, 3].
    """
    q = _normalise(q)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    r = np.empty(q.shape[:-1] + (3, 3), dtype=np.float64)
    r[..., 0, 0] = 1 - 2 * (y * y + z * z)
    r[..., 0, 1] = 2 * (x * y - w * z)
    r[..., 0, 2] = 2 * (x * z + w * y)
    r[..., 1, 0] = 2 * (x * y + w * z)
    r[..., 1, 1] = 1 - 2 * (x * x + z * z)
    r[..., 1, 2] = 2 * (y * z - w * x)
    r[..., 2, 0] = 2 * (x * z - w * y)
    r[..., 2, 1] = 2 * (y * z + w * x)
    r[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return r


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of (w, x, y, z) quaternions (broadcasting over leading axes)."""
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack([aw * bw - ax * bx - ay * by - az * bz,
                     aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw], axis=-1)


def _normalise(q: np.ndarray) -> np.ndarray:
    """float64 unit quaternions [..., 4]; zero / non-finite rows become (1, 0, 0, 0)."""
    q = np.asarray(q, dtype=np.float64)
    if q.shape[-1:] != (4,):
        raise CloudValidationError(f"quaternions must have shape [..., 4], got {q.shape}")
    # Divide by the largest |component| first so tiny (or huge) quaternions neither underflow
    # nor overflow in the sum of squares.
    big = np.max(np.abs(q), axis=-1, keepdims=True)
    bad = ~np.isfinite(big) | (big == 0)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        q = q / np.where(bad, 1.0, big)
        q = q / np.sqrt(np.sum(q * q, axis=-1, keepdims=True))
    if np.any(bad):
        q = np.where(bad, np.array([1.0, 0.0, 0.0, 0.0]), q)
    return q


def quaternion_to_euler(q: np.ndarray) -> np.ndarray:
    """Euler angles (roll, pitch, yaw) in radians of quaternions (w, x, y, z).

    q: [..., 4], any non-zero length (normalised first; zero / non-finite -> identity).
    Returns float64 [..., 3] with roll, yaw in [-pi, pi] and pitch in [-pi/2, pi/2] such that
    Rz(yaw) Ry(pitch) Rx(roll) equals the quaternion's rotation to ~1e-9 everywhere, including at
    and near gimbal lock (pitch = +-pi/2) -- no NaN for any finite input.

    Method: from the rotation matrix, pitch = atan2(-R20, hypot(R00, R10)) (never an asin of a
    value that rounding pushed past 1); away from gimbal lock roll = atan2(R21, R22),
    yaw = atan2(R10, R00); at gimbal lock yaw = 0 and roll = atan2(-R12, R11).
    """
    r = quaternion_to_matrix(q)
    cos_p = np.hypot(r[..., 0, 0], r[..., 1, 0])
    pitch = np.arctan2(-r[..., 2, 0], cos_p)
    regular = cos_p > _GIMBAL_EPS
    roll = np.where(regular, np.arctan2(r[..., 2, 1], r[..., 2, 2]), np.arctan2(-r[..., 1, 2], r[..., 1, 1]))
    yaw = np.where(regular, np.arctan2(r[..., 1, 0], r[..., 0, 0]), 0.0)
    return np.stack([roll, pitch, yaw], axis=-1)


def half_angle_trig(half: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """cos and sin of the half angles ``half`` [3, ...] (roll, pitch, yaw first).

    The one place the decoder calls libm: the angles are made contiguous first, so the NumPy
    reference and the native path (``gsz.decoder.attributes``) evaluate cos/sin on identical
    arrays and get identical bits."""
    h = np.ascontiguousarray(half, dtype=np.float64)
    return np.cos(h), np.sin(h)


def euler_to_quaternion(euler: np.ndarray) -> np.ndarray:
    """Unit quaternions (w, x, y, z) of Euler angles (roll, pitch, yaw) -- normative decoder step.

    euler: [..., 3] radians, any real values (angles are 2*pi-periodic up to the quaternion
    sign, which does not change the rotation).  Non-finite angles are replaced by 0 so a decoder
    never emits NaN.
    Returns float64 [..., 4] with w >= 0 (sign canonicalised; q and -q are the same rotation).
    """
    e = np.asarray(euler, dtype=np.float64)
    if e.shape[-1:] != (3,):
        raise CloudValidationError(f"Euler angles must have shape [..., 3], got {e.shape}")
    e = np.where(np.isfinite(e), e, 0.0)
    c, s = half_angle_trig(np.moveaxis(0.5 * e, -1, 0))
    cr, cp, cy = c
    sr, sp, sy = s
    q = np.stack([
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    ], axis=-1)
    return np.where(q[..., :1] < 0, -q, q)


def quaternion_f32_from_trig(c: np.ndarray, s: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """``euler_to_quaternion(...).astype(float32)`` from the cos and sin of the half angles
    (float64 [3, M], :func:`half_angle_trig`): the same products in the same order (the four
    shared two-factor products computed once), the same sign rule, as float32 [M, 4] (into
    ``out`` when given)."""
    cr, cp, cy = c
    sr, sp, sy = s
    # in place where a product is last needed (fewer fresh [M] arrays: page faults)
    crcp, srsp, srcp, crsp = cr * cp, sr * sp, sr * cp, cr * sp
    t = np.empty_like(crcp)
    q0 = crcp * cy
    q0 += np.multiply(srsp, sy, out=t)         # cr cp cy + sr sp sy
    q3 = np.multiply(crcp, sy, out=crcp)
    q3 -= np.multiply(srsp, cy, out=srsp)      # cr cp sy - sr sp cy
    q1 = srcp * cy
    q1 -= np.multiply(crsp, sy, out=t)         # sr cp cy - cr sp sy
    q2 = np.multiply(crsp, cy, out=crsp)
    q2 += np.multiply(srcp, sy, out=srcp)      # cr sp cy + sr cp sy
    neg = q0 < 0
    if out is None:
        out = np.empty((q0.shape[0], 4), dtype=np.float32)
    for i, q in enumerate((q0, q1, q2, q3)):
        np.negative(q, out=q, where=neg)
        out[:, i] = q
    return out


def euler_to_matrix(euler: np.ndarray) -> np.ndarray:
    """Rz(yaw) Ry(pitch) Rx(roll) as float64 [..., 3, 3] (reference form of the convention)."""
    e = np.asarray(euler, dtype=np.float64)
    cr, sr = np.cos(e[..., 0]), np.sin(e[..., 0])
    cp, sp = np.cos(e[..., 1]), np.sin(e[..., 1])
    cy, sy = np.cos(e[..., 2]), np.sin(e[..., 2])
    r = np.empty(e.shape[:-1] + (3, 3), dtype=np.float64)
    r[..., 0, 0] = cy * cp
    r[..., 0, 1] = cy * sp * sr - sy * cr
    r[..., 0, 2] = cy * sp * cr + sy * sr
    r[..., 1, 0] = sy * cp
    r[..., 1, 1] = sy * sp * sr + cy * cr
    r[..., 1, 2] = sy * sp * cr - cy * sr
    r[..., 2, 0] = -sp
    r[..., 2, 1] = cp * sr
    r[..., 2, 2] = cp * cr
    return r


def wrap_to_reference(angles: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Shift angles by multiples of 2*pi into [reference - pi, reference + pi).

    angles, reference: broadcastable float arrays (radians).  Returns float64.  Because
    :func:`euler_to_quaternion` is 2*pi-periodic per angle (up to the quaternion sign), the
    result decodes to exactly the same rotation; it only removes the +-pi seam between
    neighbours before a smoothing transform (RAHT).
    """
    a = np.asarray(angles, dtype=np.float64)
    ref = np.asarray(reference, dtype=np.float64)
    return a - 2 * np.pi * np.floor((a - ref + np.pi) / (2 * np.pi))
