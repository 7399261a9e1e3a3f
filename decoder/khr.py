"""``KHR_gaussian_splatting`` conventions <-> gsz's graphdeco ones (numpy only).

:class:`GaussianCloud` holds what a graphdeco PLY holds: log scales, opacity logits, (w, x, y, z)
quaternions, SH in graphdeco order, in the RDF frame of a COLMAP capture (x right, y down,
z forward).  The ratified ``KHR_gaussian_splatting`` stores what a renderer uses: linear scales,
opacity after the sigmoid in [0, 1], unit (x, y, z, w) quaternions, in the glTF frame (+Y up,
+Z front, +X left: "LUF", the frame the Khronos SPZ sub-extension names).  The mapping, its
float32 rounding and its edge cases are specified in ``format_spec/GLTF.md`` §2.

RDF -> LUF is the rotation by 180 degrees about z, (x, y, z) -> (-x, -y, z): positions change
sign, quaternions are multiplied by that rotation's quaternion, and every SH coefficient of
order m is multiplied by (-1)^m -- all exact in float32.  General rotations (glTF node
transforms) rotate the SH bands with matrices found from the basis itself (:func:`sh_rotation`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .cloud import GaussianCloud
from .container import FRAME_RDF, FRAME_RUB, FRAME_UNSPECIFIED
from .errors import GltfFormatError
from .rotation import quat_mul

#: degree-0 SH basis constant: colour = 0.5 + SH_C0 * f_dc
SH_C0 = 0.28209479177387814
#: Rotation from a .gsz frame code to the glTF frame (LUF).  An unspecified frame is taken as
#: RDF: every graphdeco-trained scene is in it, and the reference encoder writes RDF.
FRAME_TO_GLTF = {
    FRAME_RDF: np.diag([-1.0, -1.0, 1.0]),          # 180 degrees about z
    FRAME_UNSPECIFIED: np.diag([-1.0, -1.0, 1.0]),
    FRAME_RUB: np.diag([-1.0, 1.0, -1.0]),          # 180 degrees about y
}
#: Log-scale / logit given to a linear scale of 0 and an opacity of 0 (-104), and the logit
#: given to an opacity of 1 (18): the values nearest 0 whose exp / sigmoid round to exactly those
#: float32 values, so writing them back reproduces the file's values.
LOG_FLOOR = -104.0
LOGIT_CEIL = 18.0
#: largest float32: a log-scale above log(FLT_MAX) ~ 88.72 has no float32 linear scale
_F32_MAX = float(np.finfo(np.float32).max)


@dataclass
class KhrSplats:
    """Splats as the ``KHR_gaussian_splatting`` attributes hold them (glTF frame, float32).

    positions [N, 3] POSITION; scales [N, 3] linear (SCALE); rotations [N, 4] unit (x, y, z, w)
    (ROTATION); opacities [N] in [0, 1] (OPACITY); sh_dc [N, 3] (SH_DEGREE_0_COEF_0); sh_rest
    [N, K, 3] with K = (d+1)^2 - 1, coefficient k = l^2 - 1 + n holding SH_DEGREE_l_COEF_n."""

    positions: np.ndarray
    scales: np.ndarray
    rotations: np.ndarray
    opacities: np.ndarray
    sh_dc: np.ndarray
    sh_rest: np.ndarray

    @property
    def sh_degree(self) -> int:
        return {0: 0, 3: 1, 8: 2, 15: 3}[self.sh_rest.shape[1]]

    def __len__(self) -> int:
        return int(self.positions.shape[0])


# --------------------------------------------------------------------------- SH and quaternions
_C1 = 0.4886025119029199
_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396)
_C3 = (-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
       -0.4570457994644658, 1.445305721320277, -0.5900435899266435)


def sh_basis(degree: int, dirs: np.ndarray) -> np.ndarray:
    """[M, 2l+1] real SH basis of band ``degree`` (1..3) at unit directions ``dirs`` [M, 3], in
    the graphdeco / KHR order (m = -l..l, KHR Appendix A constants)."""
    x, y, z = (dirs[:, i] for i in range(3))
    if degree == 1:
        cols = (-_C1 * y, _C1 * z, -_C1 * x)
    elif degree == 2:
        cols = (_C2[0] * x * y, _C2[1] * y * z, _C2[2] * (2 * z * z - x * x - y * y), _C2[3] * x * z,
                _C2[4] * (x * x - y * y))
    elif degree == 3:
        cols = (_C3[0] * y * (3 * x * x - y * y), _C3[1] * x * y * z, _C3[2] * y * (4 * z * z - x * x - y * y),
                _C3[3] * z * (2 * z * z - 3 * x * x - 3 * y * y), _C3[4] * x * (4 * z * z - x * x - y * y),
                _C3[5] * z * (x * x - y * y), _C3[6] * x * (x * x - 3 * y * y))
    else:
        raise ValueError(f"SH band must be 1..3, got {degree}")
    return np.stack(cols, axis=1)


def _sphere(n: int = 64) -> np.ndarray:
    """n well-spread unit directions (a Fibonacci sphere): enough to fit a band's rotation."""
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    r = np.sqrt(1 - z * z)
    phi = i * np.pi * (3 - np.sqrt(5))
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def sh_rotation(degree: int, rot: np.ndarray) -> np.ndarray:
    """[2l+1, 2l+1] matrix X with which band ``degree``'s coefficients c of a splat become X @ c
    when the scene is rotated by ``rot`` (3x3 orthogonal): the colour seen from direction d' after
    the rotation is the one seen from rot^T d' before.  Each band is closed under rotation, so X
    is the least-squares solution of Y(rot^T d')^T = Y(d')^T X over many directions d' (exact to
    ~1e-15): then Y(rot^T d') . c = Y(d') . (X c)."""
    dirs = _sphere()
    a = sh_basis(degree, dirs)
    b = sh_basis(degree, dirs @ rot)           # rows (rot^T d')^T
    x, *_ = np.linalg.lstsq(a, b, rcond=None)
    # the fit leaves ~1e-16 where the exact matrix has 0 or +-1 (axis-aligned rotations): snap
    # those, so a quarter turn or a flip moves coefficients without rounding noise
    x[np.abs(x) < 1e-12] = 0.0
    unit = np.abs(np.abs(x) - 1.0) < 1e-12
    x[unit] = np.sign(x[unit])
    return x


def matrix_quaternion(rot: np.ndarray) -> np.ndarray:
    """(w, x, y, z) unit quaternion of a proper rotation matrix (Shepperd's method: the branch of
    the largest diagonal term keeps it exact for the frames' 180-degree rotations)."""
    m = np.asarray(rot, np.float64)
    t = np.trace(m)
    k = int(np.argmax([t, m[0, 0], m[1, 1], m[2, 2]]))
    if k == 0:
        s = 2.0 * np.sqrt(1.0 + t)
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    else:
        i = k - 1
        j, l = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * np.sqrt(1.0 + m[i, i] - m[j, j] - m[l, l])
        q = [0.0] * 4
        q[0] = (m[l, j] - m[j, l]) / s
        q[1 + i] = 0.25 * s
        q[1 + j] = (m[j, i] + m[i, j]) / s
        q[1 + l] = (m[l, i] + m[i, l]) / s
    return np.asarray(q, np.float64)


def _rotate_sh(rest: np.ndarray, rot: np.ndarray, exact_signs: bool) -> np.ndarray:
    """sh_rest [N, K, 3] of a scene rotated by ``rot``; with ``exact_signs`` ``rot`` is a
    coordinate-sign flip, whose band matrices are diagonal +-1 and are applied as sign changes."""
    out = np.empty_like(rest)
    for band in range(1, {0: 0, 3: 1, 8: 2, 15: 3}[rest.shape[1]] + 1):
        lo, hi = band * band - 1, (band + 1) * (band + 1) - 1
        x = sh_rotation(band, rot)
        if exact_signs:
            signs = np.rint(np.diag(x))
            assert np.allclose(x, np.diag(signs), atol=1e-9), "a frame flip's SH matrix is a sign diagonal"
            out[:, lo:hi] = rest[:, lo:hi] * signs.astype(rest.dtype)[None, :, None]
        else:
            out[:, lo:hi] = np.einsum("ij,njc->nic", x, rest[:, lo:hi].astype(np.float64)).astype(rest.dtype)
    return out


# --------------------------------------------------------------------------- the two conventions
def sigmoid(v: np.ndarray) -> np.ndarray:
    """float64 sigmoid of any float array (no overflow warnings at +-inf logits)."""
    with np.errstate(over="ignore"):
        return 1.0 / (1.0 + np.exp(-np.asarray(v, np.float64)))


def to_khr(cloud: GaussianCloud, frame: int = FRAME_RDF, name=None) -> KhrSplats:
    """The ``KHR_gaussian_splatting`` attributes of ``cloud`` (whose values are in ``frame``,
    a .gsz frame code): glTF frame, exp of the log-scales, sigmoid of the logits, normalised
    (x, y, z, w) quaternions, float64 arithmetic rounded once to float32."""
    cloud.validate(check_finite=True, name=name)
    flip = FRAME_TO_GLTF.get(int(frame), FRAME_TO_GLTF[FRAME_RDF])
    signs = np.diag(flip).astype(np.float32)
    with np.errstate(over="ignore"):
        linear = np.exp(cloud.scales.astype(np.float64)).astype(np.float32)
    big = ~np.isfinite(linear)
    if big.any():
        raise GltfFormatError(f"{int(big.any(axis=1).sum())} Gaussians have a log-scale above "
                              f"{np.log(_F32_MAX):.2f}, whose linear scale float32 cannot hold", name)
    q = cloud.rotations.astype(np.float64)
    q = quat_mul(matrix_quaternion(flip), q / np.linalg.norm(q, axis=1, keepdims=True))
    return KhrSplats(
        positions=cloud.positions * signs,
        scales=linear,
        rotations=np.ascontiguousarray(q[:, [1, 2, 3, 0]], dtype=np.float32),
        opacities=sigmoid(cloud.opacities).astype(np.float32),
        sh_dc=cloud.sh_dc.copy(),
        sh_rest=_rotate_sh(cloud.sh_rest, flip, exact_signs=True))


def from_khr(s: KhrSplats, name=None) -> GaussianCloud:
    """The graphdeco cloud (RDF frame) of KHR attributes in the glTF frame: the inverse of
    :func:`to_khr` (log of the scales, logit of the opacities; a scale or opacity of exactly 0
    reads as :data:`LOG_FLOOR`, an opacity of 1 as :data:`LOGIT_CEIL`).  Out-of-range values
    (negative scales, opacities outside [0, 1], non-finite values) raise GltfFormatError."""
    for what, arr in (("POSITION", s.positions), ("SCALE", s.scales), ("ROTATION", s.rotations),
                      ("OPACITY", s.opacities), ("spherical harmonics", s.sh_dc), ("spherical harmonics", s.sh_rest)):
        bad = ~np.isfinite(arr)
        if bad.any():
            raise GltfFormatError(f"{what} has {int(bad.sum())} non-finite values", name)
    if (s.scales < 0).any():
        raise GltfFormatError(f"KHR_gaussian_splatting:SCALE has {int((s.scales < 0).sum())} negative "
                              "values (scales are linear and must not be negative)", name)
    out = (s.opacities < 0) | (s.opacities > 1)
    if out.any():
        raise GltfFormatError(f"KHR_gaussian_splatting:OPACITY has {int(out.sum())} values outside [0, 1]", name)
    zero = ~(np.abs(s.rotations).sum(axis=1) > 0)
    if zero.any():
        raise GltfFormatError(f"KHR_gaussian_splatting:ROTATION has {int(zero.sum())} all-zero quaternions "
                              f"(first at {int(np.argmax(zero))})", name)
    flip = FRAME_TO_GLTF[FRAME_RDF]          # its own inverse
    a = s.opacities.astype(np.float64)
    with np.errstate(divide="ignore"):
        log_scales = np.maximum(np.log(s.scales.astype(np.float64)), LOG_FLOOR)
        logits = np.clip(np.log(a) - np.log1p(-a), LOG_FLOOR, LOGIT_CEIL)
    q = s.rotations.astype(np.float64)[:, [3, 0, 1, 2]]
    conj = matrix_quaternion(flip) * np.array([1.0, -1.0, -1.0, -1.0])
    return GaussianCloud(
        positions=s.positions * np.diag(flip).astype(np.float32),
        scales=log_scales.astype(np.float32),
        rotations=quat_mul(conj, q).astype(np.float32),
        opacities=logits.astype(np.float32),
        sh_dc=s.sh_dc, sh_rest=_rotate_sh(s.sh_rest, flip, exact_signs=True),
        sh_degree=s.sh_degree)


def color0(s: KhrSplats) -> np.ndarray:
    """[N, 4] uint8 ``COLOR_0`` for point-cloud fallbacks: the degree-0 colour 0.5 + C0 * dc and
    the opacity, clamped to [0, 1] and rounded to 8 bits."""
    rgba = np.concatenate([0.5 + SH_C0 * s.sh_dc.astype(np.float64), s.opacities[:, None].astype(np.float64)], axis=1)
    return np.clip(np.rint(rgba * 255.0), 0, 255).astype(np.uint8)


def dc_from_color(rgb: np.ndarray) -> np.ndarray:
    """SH degree-0 coefficients of a ``COLOR_0`` colour in [0, 1] (the fallback when a file has
    no SH_DEGREE_0_COEF_0)."""
    return ((np.asarray(rgb, np.float64) - 0.5) / SH_C0).astype(np.float32)


def transform(s: KhrSplats, matrix: np.ndarray, name=None) -> KhrSplats:
    """Bake a glTF node's world matrix (4x4, column vectors) into the splats: rotation, uniform
    scale and translation.  A matrix with a mirror, shear or non-uniform scale has no exact
    Gaussian equivalent in this representation and raises GltfFormatError."""
    m = np.asarray(matrix, np.float64)
    lin, t = m[:3, :3], m[:3, 3]
    det = float(np.linalg.det(lin))
    if not np.allclose(m[3], [0, 0, 0, 1]) or det <= 0:
        raise GltfFormatError("a node transform that mirrors, projects or collapses the splats is not supported", name)
    scale = np.cbrt(det)
    rot = lin / scale
    if not np.allclose(rot @ rot.T, np.eye(3), atol=1e-5):
        raise GltfFormatError("a node transform with non-uniform scale or shear cannot be baked into "
                              "Gaussian splats exactly; gsz reads rotation, uniform scale and translation", name)
    if np.array_equal(rot, np.eye(3)):          # translation / uniform scale: orientation and SH as they are
        rotations, rest = s.rotations, s.sh_rest
    else:
        q = quat_mul(matrix_quaternion(rot), s.rotations.astype(np.float64)[:, [3, 0, 1, 2]])
        q /= np.linalg.norm(q, axis=1, keepdims=True)
        rotations = np.ascontiguousarray(q[:, [1, 2, 3, 0]], dtype=np.float32)
        rest = _rotate_sh(s.sh_rest, rot, exact_signs=False)
    return KhrSplats(
        positions=(s.positions.astype(np.float64) @ lin.T + t).astype(np.float32),
        scales=(s.scales.astype(np.float64) * scale).astype(np.float32),
        rotations=rotations, opacities=s.opacities, sh_dc=s.sh_dc, sh_rest=rest)

