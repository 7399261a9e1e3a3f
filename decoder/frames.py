"""Axis conventions of scene files and the conversion between them (numpy only).

gsz holds every cloud in the graphdeco PLY frame, RDF: x right, y down, z forward.  A frame is
named by three letters, one per axis, saying where +x, +y and +z point: R/L, D/U, F/B for the
y-up family (RUB is OpenGL's and three.js's, LUF glTF's, RUF Unity's).  Changing between two of
them negates some axes; with an odd number of negations that is a mirror, which a Gaussian
survives too (its covariance is mirrored, its quaternion re-expressed).
"""
from __future__ import annotations

import numpy as np

from .cloud import GaussianCloud

#: sign of each axis of a frame in RDF terms (x_RDF = sign * x_frame)
FRAME_SIGNS = {name: (1 if name[0] == "R" else -1, 1 if name[1] == "D" else -1, 1 if name[2] == "F" else -1)
               for name in ("RDF", "RUB", "LUF", "RUF", "LDB", "RDB", "LUB", "LDF")}


def sh_rest_signs(degree: int, signs) -> np.ndarray:
    """[K] sign of each higher-order SH coefficient (graphdeco order, m = -l..l within band l)
    when the axes are negated by ``signs``: a real SH basis function of band l, order m is a
    polynomial whose x, y and z degrees have the parities |m| - [m<0], [m<0] and l - |m|."""
    sx, sy, sz = signs
    out = []
    for band in range(1, degree + 1):
        for m in range(-band, band + 1):
            neg = 1 if m < 0 else 0
            out.append(sx ** ((abs(m) - neg) % 2) * sy ** neg * sz ** ((band - abs(m)) % 2))
    return np.array(out, np.float32)


def flip_axes(cloud: GaussianCloud, signs) -> GaussianCloud:
    """``cloud`` with its axes negated by ``signs`` (three of +-1): positions, rotations (a
    rotation R becomes S R S, i.e. q = (w, v) -> (w, det(S) S v)) and view-dependent colour."""
    s = np.asarray(signs, np.float32)
    if s.shape != (3,) or not np.all(np.abs(s) == 1):
        raise ValueError(f"axis signs must be three of +1/-1, got {signs!r}")
    if np.all(s == 1):
        return cloud
    det = float(np.prod(s))
    rot = cloud.rotations.copy()
    rot[:, 1:] *= det * s
    rest = cloud.sh_rest * sh_rest_signs(cloud.sh_degree, s.astype(int))[None, :, None]
    return GaussianCloud(cloud.positions * s, cloud.scales, rot, cloud.opacities, cloud.sh_dc, rest,
                         cloud.sh_degree, extra=dict(cloud.extra))


def to_rdf(cloud: GaussianCloud, frame: str) -> GaussianCloud:
    """``cloud``, held in ``frame`` (a name of :data:`FRAME_SIGNS`), converted to RDF."""
    return flip_axes(cloud, FRAME_SIGNS[frame.upper()])


def from_rdf(cloud: GaussianCloud, frame: str) -> GaussianCloud:
    """``cloud`` (RDF) converted to ``frame``: axis negations are their own inverse."""
    return flip_axes(cloud, FRAME_SIGNS[frame.upper()])


def convert_frame(cloud: GaussianCloud, src: str, dst: str) -> GaussianCloud:
    """``cloud`` held in frame ``src`` re-expressed in frame ``dst`` (names of
    :data:`FRAME_SIGNS`, e.g. "RDF" for graphdeco PLY / COLMAP, "RUB" for OpenGL / three.js)."""
    for f in (src, dst):
        if str(f).upper() not in FRAME_SIGNS:
            raise ValueError(f"unknown frame {f!r}; one of {', '.join(FRAME_SIGNS)}")
    return from_rdf(to_rdf(cloud, src), dst)
