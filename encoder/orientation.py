"""Each Gaussian's orientation as the one of its 24 equivalent forms nearest the identity.

A Gaussian's covariance ``R diag(exp(2 s)) R^T`` does not change when its local axes are
relabelled: ``R -> R G`` for any of the 24 rotations ``G`` that map the coordinate axes onto
themselves (the cube's rotation group), with the log-scales ``s`` permuted to match.  A trained
scene's rotations use all of SO(3); taken nearest the identity (the largest ``|w|``) every Euler
angle stays within about +-63 degrees instead of +-180 (roll, yaw) and +-90 (pitch), far from the
gimbal lock and from the +-pi wrap.  The same rotation precision then costs 3-4.6 bits a Gaussian
less (docs/design/orientation.md).  Nothing changes for a decoder: it decodes the rotation and
scales the file holds, which describe the same Gaussian.

numpy only; deterministic (elementwise arithmetic, the identity first on a tie), mapped over the
cores by row ranges.
"""
from __future__ import annotations

import itertools

import numpy as np

from ..decoder.rotation import quat_mul, quaternion_to_matrix
from ..decoder.threads import for_ranges

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
#: [24, 3]: local axis i of R G is local axis AXIS_SOURCE[g, i] of R (its log-scale moves with it)
AXIS_SOURCE = np.argmax(np.abs(quaternion_to_matrix(CUBE_ROTATIONS)), axis=1)
_HALF_TURN_PAIRS = ((1, 2), (1, 3), (2, 3))


def nearest_form(q: np.ndarray) -> np.ndarray:
    """int64 [N]: the index into CUBE_ROTATIONS of the form of each quaternion (float [N, 4],
    any length) nearest the identity, i.e. the G maximising |w(q G)|.

    Closed form from |q|'s components (elementwise, so the same on every machine; no BLAS):
    the identity and the half turns about an axis give |q_i|, the 8 third turns at best
    (|q_w|+|q_x|+|q_y|+|q_z|)/2, a quarter turn about axis a (|q_w|+|q_a|)/sqrt 2, a half turn
    about a face diagonal (|q_a|+|q_b|)/sqrt 2; the signs that reach these follow from q's.
    A tie between families goes to the earlier one in that order, between the identity and the
    half turns to the lower index; a zero component counts as positive when the signs are
    read (either sign reaches the same |w| there).  A row that is all zero or has a non-finite
    component keeps the identity."""
    q = np.asarray(q, dtype=np.float64)
    a = np.abs(q)
    r = 1.0 / np.sqrt(2.0)
    cand = np.empty((q.shape[0], 11))
    cand[:, 0:4] = a                                             # identity, half turns: index i
    cand[:, 4] = 0.5 * (((a[:, 0] + a[:, 1]) + a[:, 2]) + a[:, 3])   # third turns
    for k in (1, 2, 3):
        cand[:, 4 + k] = r * (a[:, 0] + a[:, k])                 # quarter turns about axis k
    for k, (i, j) in enumerate(_HALF_TURN_PAIRS):
        cand[:, 8 + k] = r * (a[:, i] + a[:, j])                 # half turns, face diagonals
    family = np.argmax(cand, axis=1)
    sign = np.where(q < 0, -1, 1)                                # sign(0) taken as +
    out = family.copy()                                          # 0..3: the index itself
    third = family == 4
    # w(q G) = (q_w - s_x q_x - s_y q_y - s_z q_z) / 2 for G = (1, s_x, s_y, s_z) / 2: |.| is
    # largest with s_k = -sign(q_w) sign(q_k); CUBE_ROTATIONS lists the signs (+, -) per axis
    # in itertools.product order
    s = -sign[third, :1] * sign[third, 1:]
    out[third] = 4 + ((s[:, 0] < 0) * 4 + (s[:, 1] < 0) * 2 + (s[:, 2] < 0))
    for k in (1, 2, 3):
        # G = (r, .. s r at k ..): w = r (q_w - s q_k), largest with s = -sign(q_w) sign(q_k)
        rows = family == 4 + k
        s = -sign[rows, 0] * sign[rows, k]
        out[rows] = 12 + 2 * (k - 1) + (s < 0)
    for k, (i, j) in enumerate(_HALF_TURN_PAIRS):
        # G = (0, .. r at i, s r at j ..): w = -r (q_i + s q_j), largest with s = sign(q_i) sign(q_j)
        rows = family == 8 + k
        s = sign[rows, i] * sign[rows, j]
        out[rows] = 18 + 2 * k + (s < 0)
    out[~np.isfinite(q).all(axis=1)] = 0
    return out


def canonical_orientations(rotations: np.ndarray, scales: np.ndarray, *, out=None) -> tuple:
    """The nearest-identity form of every Gaussian's (rotation, log-scales).

    rotations  float32 [N, 4] (w, x, y, z), any non-zero length
    scales     float32 [N, 3] log-scales
    out        None: new arrays; ``(rotations, scales)``: written there (may be the inputs)
    returns    (rotations float32 [N, 4], scales float32 [N, 3]); a row that is already nearest
               the identity keeps its values bit for bit, a moved one is q G (the same length
               as q) with w >= 0 and its scales permuted
    """
    n = rotations.shape[0]
    if out is None:
        out = (np.array(rotations, dtype=np.float32), np.array(scales, dtype=np.float32))
    else:
        for a, b in zip(out, (rotations, scales)):
            if a is not b:
                a[...] = b
    rot, sc = out

    def rows(s: int, e: int) -> None:             # each range writes its own rows
        q = rot[s:e].astype(np.float64)
        best = nearest_form(q)
        moved = np.flatnonzero(best)
        if moved.size == 0:
            return
        g = best[moved]
        qn = quat_mul(q[moved], CUBE_ROTATIONS[g])
        qn *= np.where(qn[:, :1] < 0, -1.0, 1.0)
        rot[s + moved] = qn.astype(np.float32)
        sc[s + moved] = np.take_along_axis(sc[s + moved], AXIS_SOURCE[g], axis=1)
    for_ranges(n, _ROWS, rows)
    return rot, sc
