"""Each Gaussian's orientation as the one of its 24 equivalent forms nearest the identity.

A Gaussian's covariance ``R diag(exp(2 s)) R^T`` does not change when its local axes are
relabelled: ``R -> R G`` for any of the 24 rotations ``G`` that map the coordinate axes onto
themselves (the cube's rotation group), with the log-scales ``s`` permuted to match.  A trained
scene's rotations use all of SO(3); taken nearest the identity (the largest ``|w|``) every Euler
angle stays within about +-63 degrees instead of +-180 (roll, yaw) and +-90 (pitch), far from the
gimbal lock and from the +-pi wrap.  The same rotation precision then costs 3-4.6 bits a Gaussian
less (docs/design/orientation.md).  Nothing changes for a decoder: it decodes the rotation and
scales the file holds, which describe the same Gaussian.

numpy only; deterministic (the identity comes first, so a tie keeps the input's form).
"""
from __future__ import annotations

import itertools

import numpy as np

from ..decoder.rotation import _normalise, quat_mul, quaternion_to_matrix

#: rows processed at a time (the [rows, 24] score matrix stays small at any scene size)
_ROWS = 1 << 16


def _cube_rotations() -> np.ndarray:
    """float64 [24, 4]: (w, x, y, z) of the rotations mapping the axes onto themselves, the
    identity first."""
    h, r = 0.5, 1.0 / np.sqrt(2.0)
    g = [(1.0, 0.0, 0.0, 0.0), (0.0, 1.0, 0.0, 0.0), (0.0, 0.0, 1.0, 0.0), (0.0, 0.0, 0.0, 1.0)]
    g += [(h, sx * h, sy * h, sz * h) for sx, sy, sz in itertools.product((1.0, -1.0), repeat=3)]
    for axis in (1, 2, 3):                      # quarter turns about one axis
        for sign in (1.0, -1.0):
            v = [r, 0.0, 0.0, 0.0]
            v[axis] = sign * r
            g.append(tuple(v))
    for a, b in ((1, 2), (1, 3), (2, 3)):       # half turns about a face diagonal
        for sign in (1.0, -1.0):
            v = [0.0, 0.0, 0.0, 0.0]
            v[a], v[b] = r, sign * r
            g.append(tuple(v))
    return np.array(g, dtype=np.float64)


CUBE_ROTATIONS = _cube_rotations()
#: w of q * G is q . (G_w, -G_x, -G_y, -G_z): one product per row scores all 24
_W_OF_PRODUCT = (CUBE_ROTATIONS * np.array([1.0, -1.0, -1.0, -1.0])).T
#: [24, 3]: local axis i of R G is local axis AXIS_SOURCE[g, i] of R (its log-scale moves with it)
AXIS_SOURCE = np.argmax(np.abs(quaternion_to_matrix(CUBE_ROTATIONS)), axis=1)


def canonical_orientations(rotations: np.ndarray, scales: np.ndarray, *, out=None) -> tuple:
    """The nearest-identity form of every Gaussian's (rotation, log-scales).

    rotations  float32 [N, 4] (w, x, y, z), any non-zero length
    scales     float32 [N, 3] log-scales
    out        None: new arrays; ``(rotations, scales)``: written there (may be the inputs)
    returns    (rotations float32 [N, 4], scales float32 [N, 3]); a row that is already nearest
               the identity keeps its values bit for bit, a moved one is a unit quaternion with
               w >= 0 and its scales permuted
    """
    n = rotations.shape[0]
    if out is None:
        out = (np.array(rotations, dtype=np.float32), np.array(scales, dtype=np.float32))
    else:
        for a, b in zip(out, (rotations, scales)):
            if a is not b:
                a[...] = b
    rot, sc = out
    for s in range(0, n, _ROWS):
        q = _normalise(rot[s:s + _ROWS])
        best = np.argmax(np.abs(q @ _W_OF_PRODUCT), axis=1)
        moved = np.flatnonzero(best)
        if moved.size == 0:
            continue
        g = best[moved]
        qn = quat_mul(q[moved], CUBE_ROTATIONS[g])
        qn *= np.where(qn[:, :1] < 0, -1.0, 1.0)
        rot[s + moved] = qn.astype(np.float32)
        sc[s + moved] = np.take_along_axis(sc[s + moved], AXIS_SOURCE[g], axis=1)
    return rot, sc
