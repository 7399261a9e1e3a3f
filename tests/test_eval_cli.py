"""gsz-eval: the CLI end to end (subprocess) and the evaluate() API, on the tests/data samples."""
import json
import os
import subprocess
import sys

import numpy as np
import pytest

import gsz
from conftest import ROOT, SAMPLE_SH0, SAMPLE_SH3
from gsz.decoder.errors import GszError

# The CLI renders, so these tests need the renderer; they skip (naming why) until it exists.
render_mod = pytest.importorskip("gsz.encoder.render", reason="renderer gsz.encoder.render not available")

FAST = ["--width", "160", "--views", "2"]


def run_eval(*args, check_rc=None):
    proc = subprocess.run([sys.executable, "-m", "gsz.encoder.evaluate", *map(str, args)],
                          capture_output=True, text=True, cwd=ROOT, timeout=300)
    if check_rc is not None:
        assert proc.returncode == check_rc, proc.stderr
    return proc


def _nudged(cloud, delta):
    b = cloud.copy()
    b.opacities = b.opacities + np.float32(delta)
    return b


def test_identical_scene_gives_cap_and_writes_pngs(tmp_path):
    out = tmp_path / "imgs"
    proc = run_eval(SAMPLE_SH3, SAMPLE_SH3, *FAST, "--json", "--out", out, check_rc=0)
    res = json.loads(proc.stdout)  # exactly one JSON object on stdout
    assert res["psnr"] == res["psnr_cap_db"] == 100
    assert res["ssim"] == 1.0
    assert [v["psnr"] for v in res["views"]] == [100.0, 100.0]
    assert len({v["name"] for v in res["views"]}) == 2
    assert "cap" in res["note"]
    assert res["num_gaussians"] == {"original": 12000, "compressed": 12000}
    size = os.path.getsize(SAMPLE_SH3)
    assert res["bytes"]["original"] == res["bytes"]["compressed"] == size
    assert res["original"] == str(SAMPLE_SH3) and res["compressed"] == str(SAMPLE_SH3)
    # One progress line per view on stderr.
    assert proc.stderr.count("gsz-eval: view ") == 2
    # --out: a side-by-side (2W x H) and an error map (W x H) per view, nothing else left.
    from PIL import Image
    files = sorted(os.listdir(out))
    assert len(files) == 4 and not any(f.startswith(".tmp") for f in files)
    sbs = [f for f in files if f.endswith("_side_by_side.png")]
    err = [f for f in files if f.endswith("_error.png")]
    assert len(sbs) == len(err) == 2
    with Image.open(out / sbs[0]) as im:
        assert im.size == (320, 120)
        a = np.asarray(im)
    assert np.array_equal(a[:, :160], a[:, 160:])          # identical halves
    assert a.max() > 50                                     # and something was rendered
    with Image.open(out / err[0]) as im:
        assert im.size == (160, 120) and np.asarray(im).max() == 0  # no error anywhere


def test_psnr_falls_as_opacity_perturbation_grows(tmp_path, sample_sh0):
    psnrs, ssims = [], []
    for delta in (0.1, 0.4, 1.6):
        b = tmp_path / f"nudged_{delta}.ply"
        gsz.write_ply(_nudged(sample_sh0, delta), b)
        res = json.loads(run_eval(SAMPLE_SH0, b, *FAST, "--json", check_rc=0).stdout)
        psnrs.append(res["psnr"])
        ssims.append(res["ssim"])
    assert all(np.isfinite(p) and 10 < p < 100 for p in psnrs), psnrs
    assert psnrs[0] > psnrs[1] > psnrs[2], psnrs
    assert ssims[0] >= ssims[1] >= ssims[2] and ssims[2] < 1.0, ssims


def test_cameras_file_and_text_output(tmp_path, sample_sh3):
    from gsz.encoder.cameras import default_cameras, write_cameras_json
    cs = default_cameras(sample_sh3, n_train=7, n_test=2, width=320, height=240)
    cams = cs.train + cs.test                      # 9 cameras -> protocol test views #0 and #8
    for i, c in enumerate(cams):
        c.name = f"frame_{i:02d}"
    write_cameras_json(cams, tmp_path / "cameras.json")
    b = tmp_path / "b.ply"
    gsz.write_ply(_nudged(sample_sh3, 0.3), b)
    proc = run_eval(SAMPLE_SH3, b, "--cameras", tmp_path / "cameras.json", "--width", "160",
                    "--background", "1,1,1", check_rc=0)
    assert "frame_00" in proc.stdout and "frame_08" in proc.stdout and "frame_01" not in proc.stdout
    mean_line = [ln for ln in proc.stdout.splitlines() if ln.startswith("mean")]
    assert len(mean_line) == 1 and 10 < float(mean_line[0].split()[1]) < 100


@pytest.mark.parametrize("case", ["missing", "bad_ply", "bad_cameras", "bad_background", "bad_gsz"])
def test_bad_input_exits_2_with_one_line(tmp_path, case):
    bad = tmp_path / "broken.ply"
    bad.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 5\nend_header\n\x00")
    args = {
        "missing": ([SAMPLE_SH0, tmp_path / "nothere.ply"], "nothere.ply"),
        "bad_ply": ([bad, SAMPLE_SH0], "broken.ply"),
        "bad_cameras": ([SAMPLE_SH0, SAMPLE_SH0, "--cameras", bad], "broken.ply"),
        "bad_background": ([SAMPLE_SH0, SAMPLE_SH0, "--background", "red"], "background"),
        "bad_gsz": ([SAMPLE_SH0, tmp_path / "junk.gsz"], "junk.gsz"),
    }[case]
    if case == "bad_gsz":
        (tmp_path / "junk.gsz").write_bytes(b"\x00not a gsz file" * 4)
    proc = run_eval(*args[0], "--json")
    assert proc.returncode == 2, proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if not ln.startswith("gsz-eval: warning")]
    assert len(lines) == 1 and lines[0].startswith("gsz-eval: ") and args[1] in lines[0], proc.stderr
    assert "Traceback" not in proc.stderr and proc.stdout == ""


def test_evaluate_api_reuses_reference_images(sample_sh3):
    from gsz.encoder.cameras import default_cameras
    from gsz.encoder.evaluate import evaluate, render_views
    cams = default_cameras(sample_sh3, n_train=0, n_test=2, width=96, height=72).test
    b = _nudged(sample_sh3, -0.5)
    full = evaluate(sample_sh3, b, cams)
    refs = render_views(sample_sh3, cams)
    again = evaluate(refs, b, cams)
    assert again["views"] == full["views"] and 10 < full["psnr"] < 100
    assert full["num_gaussians"] == {"original": 12000, "compressed": 12000}
    with pytest.raises(GszError, match="reference images"):
        evaluate(refs[:1], b, cams)
