"""Tests of gsz.evaluation.render against hand-computed cases (graphdeco 3DGS semantics).

The expected values are computed here in float64 from the published formulas, with an
independent quaternion convention (scipy's Rotation), not by calling the renderer's helpers.
Every hand case runs on both rasterisers: the compiled C++ kernel and the pure-torch reference.
"""
import math
import warnings

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from gsz.decoder.cloud import GaussianCloud
from gsz.decoder.errors import GszError
from gsz.evaluation import render as R
from gsz.evaluation.cameras import Camera, look_at

C0 = 0.28209479177387814
C1 = 0.4886025119029199
BACKENDS = ["cpp", "torch"]
TOL = 1e-5


def logit(p):
    return math.log(p / (1.0 - p))


def make_cloud(pos, log_scale, quat, opacity, dc, rest=None, deg=0):
    n = len(pos)
    k = (deg + 1) ** 2 - 1
    rest = np.zeros((n, k, 3)) if rest is None else np.asarray(rest)
    return GaussianCloud(positions=np.asarray(pos), scales=np.asarray(log_scale),
                         rotations=np.asarray(quat),
                         opacities=np.array([logit(o) for o in opacity]),
                         sh_dc=np.asarray(dc), sh_rest=rest, sh_degree=deg)


def iso(n, sigma):
    return np.full((n, 3), math.log(sigma)), np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))


def eye_camera(W, H, f, cx=None, cy=None):
    """Identity pose; for odd W, H the optical axis hits the centre of pixel (W // 2, H // 2)."""
    return Camera(np.eye(3), np.zeros(3), f, f, W / 2 if cx is None else cx,
                  H / 2 if cy is None else cy, W, H)


def ref_splat(cloud, i, cam, clamp=True):
    """(mean [2], conic [2,2], radius) of Gaussian i in graphdeco pixel coords, float64."""
    p = cloud.positions[i].astype(np.float64)
    t = cam.R @ p + cam.t
    w, x, y, z = cloud.rotations[i].astype(np.float64)
    Rq = Rotation.from_quat([x, y, z, w]).as_matrix()          # scipy normalises, scalar last
    sig = Rq @ np.diag(np.exp(2.0 * cloud.scales[i].astype(np.float64))) @ Rq.T
    tx, ty, tz = t
    if clamp:
        limx, limy = 1.3 * cam.width / (2 * cam.fx), 1.3 * cam.height / (2 * cam.fy)
        tx = np.clip(tx / tz, -limx, limx) * tz
        ty = np.clip(ty / tz, -limy, limy) * tz
    J = np.array([[cam.fx / tz, 0, -cam.fx * tx / tz ** 2], [0, cam.fy / tz, -cam.fy * ty / tz ** 2]])
    cov = J @ cam.R @ sig @ cam.R.T @ J.T + 0.3 * np.eye(2)
    mean = np.array([cam.fx * t[0] / t[2] + cam.cx - 0.5, cam.fy * t[1] / t[2] + cam.cy - 0.5])
    mid = 0.5 * (cov[0, 0] + cov[1, 1])
    lam = mid + math.sqrt(max(0.1, mid * mid - np.linalg.det(cov)))
    return mean, np.linalg.inv(cov), math.ceil(3 * math.sqrt(lam)), t[2]


def ref_alpha(mean, conic, o, px, py):
    dx, dy = mean[0] - px, mean[1] - py
    power = -0.5 * (conic[0, 0] * dx * dx + conic[1, 1] * dy * dy) - conic[0, 1] * dx * dy
    if power > 0:
        return 0.0
    a = min(0.99, o * math.exp(power))
    return a if a >= 1 / 255 else 0.0


def ref_render(cloud, cam, colors, bg=(0, 0, 0), clamp=True):
    """Brute-force per-pixel graphdeco compositing in float64 -> image, alpha, importance."""
    W, H = cam.width, cam.height
    sig = 1.0 / (1.0 + np.exp(-cloud.opacities.astype(np.float64)))
    splats = []
    for i in range(len(cloud)):
        mean, conic, rad, depth = ref_splat(cloud, i, cam, clamp)
        if depth <= 0.2:
            continue
        gx, gy = (W + 15) // 16, (H + 15) // 16
        rect = (min(gx, max(0, int((mean[0] - rad) / 16))), min(gy, max(0, int((mean[1] - rad) / 16))),
                min(gx, max(0, int((mean[0] + rad + 15) / 16))), min(gy, max(0, int((mean[1] + rad + 15) / 16))))
        splats.append((depth, i, mean, conic, rect))
    splats.sort(key=lambda s: (s[0], s[1]))
    img = np.zeros((H, W, 3))
    alpha = np.zeros((H, W))
    imp = np.zeros(len(cloud))
    for py in range(H):
        for px in range(W):
            T, C = 1.0, np.zeros(3)
            for _, i, mean, conic, rect in splats:
                if not (rect[0] <= px // 16 < rect[2] and rect[1] <= py // 16 < rect[3]):
                    continue
                a = ref_alpha(mean, conic, sig[i], px, py)
                if a == 0.0:
                    continue
                if T * (1 - a) < 1e-4:
                    break
                C += colors[i] * a * T
                imp[i] += a * T
                T *= 1 - a
            img[py, px] = C + T * np.asarray(bg)
            alpha[py, px] = 1 - T
    return img, alpha, imp


def dc_color(dc):
    return np.maximum(C0 * np.asarray(dc, np.float64) + 0.5, 0.0)


@pytest.fixture(scope="module", autouse=True)
def _kernel_built():
    # The compiled kernel must build on a machine with a C++ compiler (CI has gcc + ninja).
    assert R.kernel_available(), "the C++ rasteriser failed to build"


@pytest.mark.parametrize("backend", BACKENDS)
def test_single_gaussian_centre_and_offset(backend):
    o, sigma, z, f = 0.7, 0.05, 4.0, 40.0
    ls, q = iso(1, sigma)
    cloud = make_cloud([[0, 0, z]], ls, q, [o], [[0.5, -0.2, 1.0]])
    cam = eye_camera(33, 33, f)                        # centre projects onto pixel (16, 16)
    out = R._render(cloud, cam, backend=backend, return_importance=True)
    var = (f * sigma / z) ** 2 + 0.3                   # EWA variance + 0.3 px dilation
    col = C0 * np.array([0.5, -0.2, 1.0]) + 0.5
    assert out.image.shape == (33, 33, 3) and out.image.dtype == np.float32
    assert out.alpha[16, 16] == pytest.approx(o, abs=TOL)
    np.testing.assert_allclose(out.image[16, 16], col * o, atol=TOL)
    for (px, py) in [(17, 16), (18, 17), (14, 19)]:
        a = o * math.exp(-0.5 * ((px - 16) ** 2 + (py - 16) ** 2) / var)
        expect = a if a >= 1 / 255 else 0.0
        assert out.alpha[py, px] == pytest.approx(expect, abs=TOL)
        np.testing.assert_allclose(out.image[py, px], col * expect, atol=TOL)
    assert out.alpha[16, 14 + 5] == 0.0                # 3 px away: alpha < 1/255 -> skipped


@pytest.mark.parametrize("backend", BACKENDS)
def test_anisotropic_rotated_offaxis_matches_ewa(backend):
    cloud = make_cloud([[0.3, -0.2, 3.0]], [np.log([0.08, 0.02, 0.05])], [[2.0, 0.4, -0.6, 1.0]],
                       [0.85], [[1.0, 0.2, -0.3]])
    cam = Camera(Rotation.from_euler("xyz", [0.1, -0.2, 0.05]).as_matrix(), [0.1, 0.05, 0.2],
                 50.0, 55.0, 24.3, 19.6, 48, 40)
    out = R._render(cloud, cam, backend=backend, return_importance=True)
    img, alpha, imp = ref_render(cloud, cam, [dc_color(cloud.sh_dc[0])])
    assert alpha.max() > 0.5                           # the Gaussian is really in view
    np.testing.assert_allclose(out.alpha, alpha, atol=TOL)
    np.testing.assert_allclose(out.image, img, atol=TOL)
    assert out.importance[0] == pytest.approx(imp[0], rel=TOL)


@pytest.mark.parametrize("backend", BACKENDS)
def test_jacobian_clamp_outside_frustum(backend):
    # x/z = 0.8 > 1.3 * tan(fov/2) = 0.65: the mean is off-image, its footprint reaches in.
    ls, q = iso(1, 0.2)
    cloud = make_cloud([[0.8, 0.0, 1.0]], ls, q, [0.9], [[0.3, 0.3, 0.3]])
    cam = eye_camera(32, 32, 32.0)
    out = R._render(cloud, cam, backend=backend)
    img, alpha, _ = ref_render(cloud, cam, [dc_color(cloud.sh_dc[0])])
    _, alpha_noclamp, _ = ref_render(cloud, cam, [dc_color(cloud.sh_dc[0])], clamp=False)
    assert alpha.max() > 0.05 and np.abs(alpha - alpha_noclamp).max() > 1e-3
    np.testing.assert_allclose(out.alpha, alpha, atol=TOL)


@pytest.mark.parametrize("backend", BACKENDS)
def test_two_gaussians_front_to_back(backend):
    # Index 0 is the BACK one: order must come from depth, not from the index.
    ls, q = iso(2, 0.05)
    dcs = [[1.5, -1.0, -1.0], [-1.0, -1.0, 1.5]]
    cloud = make_cloud([[0.0, 0.0, 6.0], [0.0, 0.0, 3.0]], ls, q, [0.6, 0.5], dcs)
    cam = eye_camera(33, 33, 40.0)
    out = R._render(cloud, cam, backend=backend, return_importance=True)
    cb, cf = dc_color(dcs[0]), dc_color(dcs[1])
    ab, af = 0.6, 0.5
    np.testing.assert_allclose(out.image[16, 16], cf * af + cb * ab * (1 - af), atol=TOL)
    assert out.alpha[16, 16] == pytest.approx(1 - (1 - af) * (1 - ab), abs=TOL)
    swapped = R._render(cloud.subset([1, 0]), cam, backend=backend)
    np.testing.assert_allclose(swapped.image, out.image, atol=1e-6)
    img, alpha, imp = ref_render(cloud, cam, [cb, cf])
    np.testing.assert_allclose(out.image, img, atol=TOL)
    np.testing.assert_allclose(out.importance, imp, rtol=TOL)


def sh_ref(deg, dc, rest, d):
    """graphdeco computeColorFromSH (+0.5, clamp >= 0) for one Gaussian, direction d."""
    x, y, z = d
    r = C0 * dc
    if deg > 0:
        r = r - C1 * y * rest[0] + C1 * z * rest[1] - C1 * x * rest[2]
    if deg > 1:
        xx, yy, zz, xy, yz, xz = x * x, y * y, z * z, x * y, y * z, x * z
        r = (r + 1.0925484305920792 * xy * rest[3] - 1.0925484305920792 * yz * rest[4]
             + 0.31539156525252005 * (2 * zz - xx - yy) * rest[5]
             - 1.0925484305920792 * xz * rest[6] + 0.5462742152960396 * (xx - yy) * rest[7])
    if deg > 2:
        r = (r - 0.5900435899266435 * y * (3 * xx - yy) * rest[8]
             + 2.890611442640554 * xy * z * rest[9]
             - 0.4570457994644658 * y * (4 * zz - xx - yy) * rest[10]
             + 0.3731763325901154 * z * (2 * zz - 3 * xx - 3 * yy) * rest[11]
             - 0.4570457994644658 * x * (4 * zz - xx - yy) * rest[12]
             + 1.445305721320277 * z * (xx - yy) * rest[13]
             - 0.5900435899266435 * x * (xx - 3 * yy) * rest[14])
    return np.maximum(r + 0.5, 0.0)


@pytest.mark.parametrize("backend", BACKENDS)
def test_sh_view_dependence(backend):
    rng = np.random.default_rng(3)
    pos = np.array([0.1, -0.05, 0.2])
    dc = np.array([0.4, 0.1, -0.2])
    rest3 = rng.uniform(-0.4, 0.4, (15, 3))
    ls, q = iso(1, 0.02)
    colors = {}
    for deg in (1, 3):
        cloud = make_cloud([pos], ls, q, [0.8], [dc], [rest3[:(deg + 1) ** 2 - 1]], deg=deg)
        for eye in ([0.0, 0.0, -3.0], [2.0, -1.0, -2.0], [-1.5, 0.5, 2.5]):
            cam = look_at(eye, pos, (0, -1, 0), fx=40.0, fy=40.0, width=33, height=33)  # -> (16, 16)
            d = (pos - np.array(eye)) / np.linalg.norm(pos - np.array(eye))
            out = R._render(cloud, cam, backend=backend)
            assert out.alpha[16, 16] == pytest.approx(0.8, abs=TOL)
            expect = sh_ref(deg, dc, rest3, d)
            np.testing.assert_allclose(out.image[16, 16], expect * 0.8, atol=TOL)
            colors[(deg, tuple(eye))] = expect
            dc_only = R._render(cloud, cam, backend=backend, sh_degree=0)
            np.testing.assert_allclose(dc_only.image[16, 16], dc_color(dc) * 0.8, atol=TOL)
    c1 = [v for k, v in colors.items() if k[0] == 1]
    assert np.abs(c1[0] - c1[2]).max() > 0.05          # the colour really depends on the view


@pytest.mark.parametrize("backend", BACKENDS)
def test_background_and_negative_colour_clamp(backend):
    ls, q = iso(1, 0.05)
    cloud = make_cloud([[0, 0, 4.0]], ls, q, [0.7], [[-3.0, 0.5, 1.0]])   # red SH < -0.5 -> 0
    cam = eye_camera(33, 33, 40.0)
    bg = (0.2, 0.4, 0.6)
    out = R._render(cloud, cam, backend=backend, background=bg)
    black = R._render(cloud, cam, backend=backend)
    col = dc_color([-3.0, 0.5, 1.0])
    assert col[0] == 0.0
    np.testing.assert_allclose(out.image[16, 16], col * 0.7 + 0.3 * np.array(bg), atol=TOL)
    np.testing.assert_allclose(out.image[0, 0], bg, atol=TOL)               # empty pixel
    np.testing.assert_array_equal(out.alpha, black.alpha)
    np.testing.assert_allclose(out.image - black.image,
                               (1 - black.alpha)[..., None] * np.array(bg, np.float32), atol=1e-6)


@pytest.mark.parametrize("backend", BACKENDS)
def test_alpha_cutoff(backend):
    ls, q = iso(1, 0.05)
    cam = eye_camera(33, 33, 40.0)
    below = make_cloud([[0, 0, 4.0]], ls, q, [0.98 / 255], [[1.0, 1.0, 1.0]])
    out = R._render(below, cam, backend=backend, return_importance=True)
    assert not out.alpha.any() and not out.image.any() and out.importance[0] == 0.0
    above = make_cloud([[0, 0, 4.0]], ls, q, [1.1 / 255], [[1.0, 1.0, 1.0]])
    out = R._render(above, cam, backend=backend, return_importance=True)
    # Only the centre pixel has alpha >= 1/255; the neighbours (alpha ~ 0.4/255) add nothing.
    assert np.count_nonzero(out.alpha) == 1
    assert out.alpha[16, 16] == pytest.approx(1.1 / 255, abs=1e-7)
    assert out.importance[0] == pytest.approx(1.1 / 255, rel=1e-5)


@pytest.mark.parametrize("backend", BACKENDS)
def test_early_stop_rule(backend):
    # Centre pixel: T = 1 -> 0.05 -> 5e-4; the third would give 5e-5 < 1e-4, so the pixel stops
    # and neither the third nor the fourth Gaussian is added there.
    ops = [0.95, 0.99, 0.9, 0.5]
    dcs = [[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0], [1.0, 1.0, 1.0]]
    ls = np.log([[0.05] * 3, [0.06] * 3, [0.08] * 3, [0.1] * 3])
    cloud = make_cloud([[0, 0, 2.0], [0, 0, 3.0], [0, 0, 4.0], [0, 0, 5.0]], ls,
                       np.tile([1.0, 0, 0, 0], (4, 1)), ops, dcs)
    cam = eye_camera(33, 33, 40.0)
    out = R._render(cloud, cam, backend=backend, background=(1.0, 1.0, 1.0),
                    return_importance=True)
    c = [dc_color(d) for d in dcs]
    expect = c[0] * 0.95 + c[1] * 0.99 * 0.05 + 5e-4            # + T * white background
    np.testing.assert_allclose(out.image[16, 16], expect, atol=TOL)
    assert out.alpha[16, 16] == pytest.approx(1 - 5e-4, abs=TOL)
    img, alpha, imp = ref_render(cloud, cam, c, bg=(1.0, 1.0, 1.0))
    np.testing.assert_allclose(out.image, img, atol=TOL)
    np.testing.assert_allclose(out.alpha, alpha, atol=TOL)
    np.testing.assert_allclose(out.importance, imp, rtol=TOL)


@pytest.mark.parametrize("backend", BACKENDS)
def test_importance_is_sum_of_alpha_T(backend):
    rng = np.random.default_rng(7)
    n = 12
    pos = np.column_stack([rng.uniform(-0.6, 0.6, n), rng.uniform(-0.5, 0.5, n), rng.uniform(2, 5, n)])
    ls = np.log(rng.uniform(0.03, 0.2, (n, 3)))
    q = rng.normal(size=(n, 4))
    ops = rng.uniform(0.2, 0.99, n)
    dcs = rng.uniform(-1, 1, (n, 3))
    cloud = make_cloud(pos, ls, q, ops, dcs)
    cam = eye_camera(40, 34, 30.0)
    out = R._render(cloud, cam, backend=backend, return_importance=True)
    img, alpha, imp = ref_render(cloud, cam, [dc_color(d) for d in dcs])
    assert (imp > 0).sum() >= 8
    np.testing.assert_allclose(out.importance, imp, rtol=TOL, atol=1e-9)
    np.testing.assert_allclose(out.image, img, atol=TOL)
    assert out.importance.sum() == pytest.approx(float(out.alpha.sum(dtype=np.float64)), rel=1e-5)
    # Views add up; a Gaussian behind the camera (z <= 0.2) gets nothing.
    behind = make_cloud(np.vstack([pos, [[0, 0, 0.1]]]), np.vstack([ls, [[0.0] * 3]]),
                        np.vstack([q, [[1, 0, 0, 0]]]), list(ops) + [0.9], np.vstack([dcs, [[0] * 3]]))
    cams = [cam, look_at([0.5, -0.3, -1.0], [0, 0, 3.5], (0, -1, 0), fx=25.0, fy=25.0, width=40,
                          height=34)]
    calls = []
    tot = R.accumulate_importance(behind, cams, progress=lambda i, n_: calls.append((i, n_)))
    assert calls == [(1, 2), (2, 2)]
    per = [R.render(behind, c_, return_importance=True).importance for c_ in cams]
    np.testing.assert_allclose(tot, per[0] + per[1], rtol=1e-12)
    assert per[0][-1] == 0.0


def test_backends_agree_on_real_scene(sample_sh3):
    cloud = sample_sh3.subset(np.arange(0, len(sample_sh3), 3))
    cam = R.framing_camera(cloud.positions, 96, 72, direction=(-0.4, -0.6, 1.0))
    a = R._render(cloud, cam, backend="cpp", return_importance=True, background=(0.1, 0.2, 0.3))
    b = R._render(cloud, cam, backend="torch", return_importance=True, background=(0.1, 0.2, 0.3))
    assert a.alpha.mean() > 0.05
    np.testing.assert_allclose(a.image, b.image, atol=TOL)
    np.testing.assert_allclose(a.alpha, b.alpha, atol=TOL)
    np.testing.assert_allclose(a.importance, b.importance, rtol=TOL, atol=1e-6)


def test_smoke_real_scene_sh3(sample_sh3):
    cam = R.framing_camera(sample_sh3.positions, 200, 150)
    out = R.render(sample_sh3, cam, return_importance=True)
    assert out.image.shape == (150, 200, 3) and out.alpha.shape == (150, 200)
    assert np.isfinite(out.image).all() and (out.image >= 0).all()
    assert 0.05 < out.alpha.mean() < 1.0 and (out.alpha <= 1.0).all()
    imp = out.importance
    assert imp.dtype == np.float64 and imp.shape == (len(sample_sh3),) and (imp >= 0).all()
    assert (imp > 0).sum() > len(imp) // 4
    assert imp.sum() == pytest.approx(float(out.alpha.sum(dtype=np.float64)), rel=1e-4)
    # Deterministic: byte-identical on a re-run and with a different thread count.
    again = R.render(sample_sh3, cam, return_importance=True)
    n = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        single = R.render(sample_sh3, cam, return_importance=True)
    finally:
        torch.set_num_threads(n)
    for o in (again, single):
        assert o.image.tobytes() == out.image.tobytes()
        assert o.importance.tobytes() == imp.tobytes()
    # scale_modifier < 1 shrinks the footprint.
    small = R.render(sample_sh3, cam, scale_modifier=0.5)
    assert small.alpha.sum() < out.alpha.sum()


@pytest.mark.parametrize("backend", BACKENDS)
def test_sh_rest_made_a_row_range_at_a_time_renders_the_same(sample_sh3, backend, monkeypatch):
    """A MadeRows SH rest (a candidate's decoded SH, made as the render reads them) renders
    bit for bit as the whole array, at every degree and with importance; a non-finite value in
    it raises like one in an array."""
    from gsz.decoder.cloud import MadeRows
    monkeypatch.setattr(R, "CHECK_ROWS", 300)          # several row ranges on the sample
    c = sample_sh3.subset(np.arange(0, len(sample_sh3), 3))
    rest = c.sh_rest.copy()
    made = GaussianCloud(c.positions, c.scales, c.rotations, c.opacities, c.sh_dc,
                         MadeRows(rest.shape, lambda a, b: rest[a:b].copy()), c.sh_degree)
    cam = R.framing_camera(c.positions, 96, 72)
    for deg in (None, 2, 0):
        a = R._render(c, cam, sh_degree=deg, return_importance=True, backend=backend)
        b = R._render(made, cam, sh_degree=deg, return_importance=True, backend=backend)
        assert a.image.tobytes() == b.image.tobytes() and a.importance.tobytes() == b.importance.tobytes()
    assert np.array_equal(R.accumulate_importance(made, [cam]), R.accumulate_importance(c, [cam]))
    rest[500, 4, 1] = np.inf
    with pytest.raises(GszError, match="sh_rest.*1 invalid.*Gaussian 500"):
        R._render(made, cam, backend=backend)
    with pytest.raises(GszError, match="sh_rest.*1 invalid.*Gaussian 500"):
        R._render(made, cam, sh_degree=0, backend=backend)


@pytest.mark.parametrize("backend", BACKENDS)
def test_sh_rest_in_another_colour_space_renders_as_turned_back(sample_sh3, backend):
    """A ColourRows SH rest (the search's luma/chroma clouds) renders as its rows turned back
    to RGB do, to float rounding, whether the coded field is whole or row-made, at every
    degree; the two coded forms render bit for bit alike (one kernel path turns both)."""
    from gsz.decoder.cloud import ColourRows, MadeRows
    c = sample_sh3.subset(np.arange(0, len(sample_sh3), 3))
    turn = np.linalg.qr(np.random.default_rng(5).normal(size=(3, 3)))[0].astype(np.float32)
    coded = np.ascontiguousarray((c.sh_rest.reshape(-1, 3) @ turn.T).reshape(c.sh_rest.shape))
    rgb = (coded.reshape(-1, 3).astype(np.float64) @ turn).astype(np.float32).reshape(coded.shape)

    def with_rest(rest):
        return GaussianCloud(c.positions, c.scales, c.rotations, c.opacities, c.sh_dc, rest,
                             c.sh_degree)
    whole = with_rest(ColourRows(coded, turn))
    made = with_rest(ColourRows(MadeRows(coded.shape, lambda a, b: coded[a:b].copy()), turn))
    assert np.allclose(np.asarray(whole.sh_rest), rgb, atol=1e-6)
    cam = R.framing_camera(c.positions, 96, 72)
    for deg in (None, 2, 0):
        ref = R._render(with_rest(rgb), cam, sh_degree=deg, backend=backend).image
        a = R._render(whole, cam, sh_degree=deg, backend=backend).image
        b = R._render(made, cam, sh_degree=deg, backend=backend).image
        assert a.tobytes() == b.tobytes()
        assert np.abs(a - ref).max() < 1e-5
    # the turn matters: the coded colours rendered as if RGB are far off
    full = R._render(with_rest(rgb), cam, backend=backend).image
    assert np.abs(R._render(with_rest(coded), cam, backend=backend).image - full).max() > 1e-2


def test_bad_input_raises_gsz_error(sample_sh0):
    cam = R.framing_camera(sample_sh0.positions, 32, 24)
    with pytest.raises(GszError, match="sh_degree"):
        R.render(sample_sh0, cam, sh_degree=2)
    with pytest.raises(GszError, match="background"):
        R.render(sample_sh0, cam, background=(0.0, 1.0))
    bad = Camera(np.eye(3), np.zeros(3), 0.0, 10.0, 16, 12, 32, 24)
    with pytest.raises(GszError, match="focal"):
        R.render(sample_sh0, bad)
    with pytest.raises(GszError, match="scale_modifier"):
        R.render(sample_sh0, cam, scale_modifier=-1.0)
    nan = sample_sh0.copy()
    nan.positions[5, 1] = np.nan
    with pytest.raises(GszError, match="positions.*Gaussian 5"):
        R.render(nan, cam)
    zq = sample_sh0.copy()
    zq.rotations[3] = 0.0
    with pytest.raises(GszError, match="quaternion"):
        R.render(zq, cam)
    # +-inf opacity logits are legal (alpha exactly 0 or 1 before the 0.99 cap).
    inf = sample_sh0.copy()
    inf.opacities[:10] = np.inf
    inf.opacities[10:20] = -np.inf
    assert np.isfinite(R.render(inf, cam).image).all()


def test_fallback_to_torch_when_kernel_cannot_build(monkeypatch):
    import torch.utils.cpp_extension as ext

    def broken(*a, **k):
        raise RuntimeError("no compiler")
    monkeypatch.setattr(ext, "load", broken)
    monkeypatch.setattr(R, "_KERNEL", None)
    monkeypatch.setattr(R, "_KERNEL_TRIED", False)
    ls, q = iso(1, 0.05)
    cloud = make_cloud([[0, 0, 4.0]], ls, q, [0.7], [[0.5, -0.2, 1.0]])
    with pytest.warns(RuntimeWarning, match="falling back"):
        out = R.render(cloud, eye_camera(33, 33, 40.0))
    assert out.alpha[16, 16] == pytest.approx(0.7, abs=TOL)
    with warnings.catch_warnings():
        warnings.simplefilter("error")                 # warned once, not per call
        R.render(cloud, eye_camera(33, 33, 40.0))


def test_kernel_cache_is_keyed_and_a_compile_is_announced_once(tmp_path, monkeypatch, capsys):
    """The compiled kernel's name (its cache folder) changes with the gsz version, torch's
    version and the source, so installs do not rebuild one shared build in turn; a compile
    prints one line, finding the build prints nothing."""
    import gsz
    import torch.utils.cpp_extension as cpp
    from gsz.evaluation import render as R
    src = tmp_path / "k.cpp"
    src.write_text("// kernel v1\n")
    name = R.kernel_build_name(src)
    assert name.startswith("gsz_render_cpu_") and name.isidentifier()
    assert R.kernel_build_name(src) == name                      # stable
    src.write_text("// kernel v2\n")
    assert R.kernel_build_name(src) != name
    src.write_text("// kernel v1\n")
    monkeypatch.setattr(gsz, "__version__", "9.9.9")
    assert R.kernel_build_name(src) != name
    monkeypatch.undo()
    monkeypatch.setattr(R.torch, "__version__", "0.0.1+other")
    assert R.kernel_build_name(src) != name
    monkeypatch.undo()

    calls = []

    def fake_load(name, sources, extra_cflags, verbose):        # records instead of compiling
        calls.append(name)
        return f"module {name}"
    monkeypatch.setenv("TORCH_EXTENSIONS_DIR", str(tmp_path / "ext"))
    monkeypatch.setattr(cpp, "load", fake_load)
    for built in (False, True):
        monkeypatch.setattr(R, "_KERNEL", None)
        monkeypatch.setattr(R, "_KERNEL_TRIED", False)
        assert R._load_kernel() == f"module {R.kernel_build_name()}"
        err = capsys.readouterr().err
        assert err.count(R.COMPILE_MESSAGE) == (0 if built else 1), err
        folder = tmp_path / "ext" / calls[-1]
        (folder / f"{calls[-1]}.so").write_bytes(b"")           # what a finished build leaves
    assert calls == [R.kernel_build_name()] * 2


def test_a_stale_build_lock_is_removed_not_waited_on(tmp_path, monkeypatch):
    """A compile killed while holding torch's build lock left the lock file behind, and every
    later encode waited on it forever; an old lock is removed (with a warning), a fresh one kept."""
    import os
    import time
    import torch.utils.cpp_extension as ext
    from gsz.evaluation import render
    monkeypatch.setattr(ext, "_get_build_directory", lambda name, verbose=False: str(tmp_path))
    lock = tmp_path / "lock"
    lock.touch()
    render._clear_stale_lock("x")                      # fresh: another process may be compiling
    assert lock.exists()
    old = time.time() - render.STALE_LOCK_S - 60
    os.utime(lock, (old, old))
    with pytest.warns(RuntimeWarning, match="stale rasteriser build lock"):
        render._clear_stale_lock("x")
    assert not lock.exists()
