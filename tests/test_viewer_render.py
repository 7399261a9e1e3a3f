"""gsz-view's OpenGL renderer agrees with the CPU reference renderer, and its headless CLI.

Runs on Mesa llvmpipe through EGL (no GPU, no display); skipped only when no OpenGL 4.3
context can be created at all.  Images are small (200x150) so the file stays fast.
"""
import os

import numpy as np
import pytest

from gsz.evaluation.cameras import load_cameras
from gsz.evaluation.metrics import psnr, quantize_8bit

from conftest import SAMPLE_SH0, SAMPLE_SH3

PIL = pytest.importorskip("PIL.Image")
gl = pytest.importorskip("gsz.viewer.gl_renderer")

W = 200


@pytest.fixture(scope="module")
def ctx():
    try:
        c = gl.create_headless_context()
    except gl.GLUnavailable as e:
        pytest.skip(f"no OpenGL 4.3 context: {e}")
    yield c
    c.release()


def _cpu(cloud, cam, **kw):
    from gsz.evaluation.render import render
    return render(cloud, cam, **kw).image


def _cams(cloud, width=W):
    return load_cameras(None, cloud, width=width).test


@pytest.mark.parametrize("sample", ["sample_sh0", "sample_sh3"])
@pytest.mark.parametrize("view", [0, 5])
def test_gl_frame_matches_cpu_reference(ctx, request, sample, view):
    cloud = request.getfixturevalue(sample)
    cam = _cams(cloud)[view]
    ref = quantize_8bit(_cpu(cloud, cam))
    img = quantize_8bit(gl.render_image(cloud, cam, ctx=ctx))
    assert img.shape == (150, 200, 3)
    assert ref.mean() > 0.02, "the view should show the scene"
    p = psnr(ref, img)
    assert p >= 30.0, f"GL vs CPU reference: {p:.2f} dB"
    # Same maths, so nearly every pixel is identical after 8-bit rounding.
    assert np.mean(np.abs(ref - img) > 1.5 / 255) < 0.01


def test_gl_options_match_reference(ctx, sample_sh3):
    """SH-degree switch, splat-scale modifier and background colour mean what they mean in
    the reference renderer."""
    cam = _cams(sample_sh3)[2]
    for kw in ({"sh_degree": 0}, {"sh_degree": 1, "background": (1.0, 1.0, 1.0)},
               {"scale_modifier": 0.6, "background": (0.2, 0.4, 0.9)}):
        ref = quantize_8bit(_cpu(sample_sh3, cam, **kw))
        img = quantize_8bit(gl.render_image(sample_sh3, cam, ctx=ctx, **kw))
        assert psnr(ref, img) >= 30.0, kw
    # ... and they change the picture (the options are not ignored)
    full = gl.render_image(sample_sh3, cam, ctx=ctx)
    deg0 = gl.render_image(sample_sh3, cam, ctx=ctx, sh_degree=0)
    assert np.abs(full - deg0).max() > 0.05


def test_chunked_preprocess_is_identical(ctx, sample_sh3):
    """Scenes larger than one storage block are preprocessed in chunks bound at offsets;
    forcing tiny chunks must not change a single pixel."""
    cam = _cams(sample_sh3)[1]
    r = gl.SplatRenderer(ctx, sample_sh3)
    t = gl.FloatTarget(ctx, cam.width, cam.height)
    try:
        r.render(cam, t)
        whole = t.read()
        r.chunk = 1024
        assert len(sample_sh3) > 4 * r.chunk
        r.render(cam, t)
        np.testing.assert_array_equal(whole, t.read())
    finally:
        t.release()
        r.release()


def test_depth_order_back_to_front():
    from gsz.evaluation.cameras import Camera
    cam = Camera(np.eye(3), np.zeros(3), 100, 100, 50, 50, 100, 100)
    pos = np.array([[0, 0, 5], [0, 0, 1], [0, 0, 0.1], [0, 0, 5], [0, 0, 3], [0, 0, -2]], np.float32)
    order = gl.depth_order(pos, cam)
    # behind the near plane (0.2) and behind the camera are dropped; far first; ties in
    # REVERSED index order so they composite like the reference's stable front-to-back sort
    assert order.tolist() == [3, 0, 4, 1]
    assert order.dtype == np.uint32


def test_sorter_thread_settles_on_the_resting_camera(sample_sh0):
    from gsz.viewer.sorter import DepthSorter
    cams = _cams(sample_sh0)
    s = DepthSorter(sample_sh0.positions)
    try:
        for cam in cams:            # a burst of camera moves: only the newest matters
            s.request(cam)
        assert s.wait_current(timeout=30)
        np.testing.assert_array_equal(s.order(), gl.depth_order(sample_sh0.positions, cams[-1]))
        s.request(cams[0])
        assert s.wait_current(timeout=30) and s.is_current
        np.testing.assert_array_equal(s.order(), gl.depth_order(sample_sh0.positions, cams[0]))
    finally:
        s.close()


# ---------------------------------------------------------------------------------------------
# CLI: gsz-view FILE --screenshot OUT.png
# ---------------------------------------------------------------------------------------------

def _run_cli(args, capsys):
    from gsz.viewer.cli import main
    rc = main([str(a) for a in args])
    out = capsys.readouterr()
    return rc, out.out, out.err


def _read_png(path):
    return np.asarray(PIL.open(path).convert("RGB"), np.float64) / 255.0


@pytest.mark.parametrize("path,view", [(SAMPLE_SH0, 3), (SAMPLE_SH3, 1)])
def test_cli_screenshot_matches_reference(ctx, tmp_path, capsys, path, view):
    from gsz import read_ply
    out = tmp_path / "shots" / "view.png"
    rc, so, se = _run_cli([path, "--screenshot", out, "--camera", view, "--width", W], capsys)
    assert rc == 0, se
    assert out.exists() and not [p for p in os.listdir(out.parent) if p != "view.png"]
    img = _read_png(out)
    assert img.shape == (150, 200, 3)
    cloud = read_ply(path)
    ref = quantize_8bit(_cpu(cloud, _cams(cloud)[view]))
    assert psnr(ref, img) >= 30.0


def test_cli_screenshot_size_and_background(ctx, tmp_path, capsys, sample_sh3):
    out = tmp_path / "tall.png"
    rc, _, se = _run_cli([SAMPLE_SH3, "--screenshot", out, "--width", 120, "--height", 160,
                          "--background", "1,1,1"], capsys)
    assert rc == 0, se
    img = _read_png(out)
    assert img.shape == (160, 120, 3)
    assert (img[0, 0] == 1.0).all() and img.mean() < 0.99   # white background, scene visible


def _one_line_error(rc, err, code=2):
    assert rc == code, err          # 2: a bad option, 1: bad data
    lines = [ln for ln in err.strip().splitlines() if ln]
    assert len(lines) == 1 and lines[0].startswith("gsz-view: error:"), err
    return lines[0]


def test_cli_errors(ctx, tmp_path, capsys):
    out = tmp_path / "x.png"
    line = _one_line_error(*_run_cli([tmp_path / "missing.ply", "--screenshot", out], capsys)[::2], code=1)
    assert "missing.ply" in line
    bad = tmp_path / "corrupt.gsz"
    bad.write_bytes(b"GSZ\x00" + os.urandom(200))
    line = _one_line_error(*_run_cli([bad, "--screenshot", out], capsys)[::2], code=1)
    assert "corrupt.gsz" in line
    line = _one_line_error(*_run_cli([SAMPLE_SH0, "--screenshot", out, "--camera", 99], capsys)[::2])
    assert "--camera" in line
    line = _one_line_error(*_run_cli([SAMPLE_SH0, "--screenshot", out, "--background", "red"],
                                     capsys)[::2])
    assert "--background" in line
    line = _one_line_error(*_run_cli([SAMPLE_SH0, "--screenshot", out, "--budgets", "5XB"], capsys)[::2])
    assert "5XB" in line
    assert not out.exists()
    with pytest.raises(SystemExit) as e:   # argparse: --compare and --budgets exclude each other
        _run_cli([SAMPLE_SH0, "--compare", SAMPLE_SH0, "--budgets", "1MB"], capsys)
    assert e.value.code == 2


def test_cli_screenshot_of_the_first_layers_of_a_layered_file(ctx, tmp_path, capsys):
    from gsz.decoder import decode, inspect
    from codec_util import encoded
    res = encoded("sh0", 3000, bits=10, layers=3)
    path = tmp_path / "layered.gsz"
    path.write_bytes(res.data)
    rows = inspect(res.data)["layers"]
    full = decode(res.data)
    shots = {}
    for k in (1, 3):
        out = tmp_path / f"k{k}.png"
        rc, _, se = _run_cli([path, "--screenshot", out, "--camera", 2, "--width", W, "--layers", k], capsys)
        assert rc == 0, se
        shots[k] = _read_png(out)
        part = full.subset(np.arange(rows[k - 1]["cumulative_gaussians"]))
        assert psnr(quantize_8bit(_cpu(part, _cams(full)[2])), shots[k]) >= 30.0
    assert psnr(shots[3], shots[1]) < 40.0          # layer 0 alone is visibly coarser
    line = _one_line_error(*_run_cli([path, "--screenshot", tmp_path / "x.png", "--layers", 4], capsys)[::2])
    assert "has 3 layer(s)" in line
    line = _one_line_error(*_run_cli([SAMPLE_SH0, "--screenshot", tmp_path / "x.png", "--layers", 1], capsys)[::2])
    assert "not a .gsz" in line


def test_cli_screenshot_keeps_an_existing_file_and_prints_frame_stats(ctx, tmp_path, capsys):
    out = tmp_path / "shot.png"
    out.write_bytes(b"keep me")
    line = _one_line_error(*_run_cli([SAMPLE_SH0, "--screenshot", out, "--width", 64], capsys)[::2], code=1)
    assert "exists" in line and "-w/--overwrite" in line and out.read_bytes() == b"keep me"
    line = _one_line_error(*_run_cli([SAMPLE_SH0, "--screenshot", SAMPLE_SH0, "-w"], capsys)[::2], code=1)
    assert "is the input file" in line
    rc, so, se = _run_cli([SAMPLE_SH0, "--screenshot", out, "--width", 64, "-w", "--stats"], capsys)
    assert rc == 0 and so == "", se
    assert _read_png(out).shape == (48, 64, 3)
    stats = [ln for ln in se.splitlines() if ln.startswith("gsz-view: frame ")]
    assert len(stats) == 1 and " ms" in stats[0] and "sort" in stats[0] and "20,000 splats" in stats[0], se
    rc, so, se = _run_cli([SAMPLE_SH0, "--screenshot", out, "--width", 64, "-w", "-q"], capsys)
    assert rc == 0 and so == se == ""
