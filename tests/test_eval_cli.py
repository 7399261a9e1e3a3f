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
render_mod = pytest.importorskip("gsz.evaluation.render", reason="renderer gsz.evaluation.render not available")

FAST = ["--width", "160", "--views", "2"]


def run_eval(*args, check_rc=None):
    proc = subprocess.run([sys.executable, "-m", "gsz.encoder.eval_cli", *map(str, args)],
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
    from gsz.evaluation.evaluate import CAPTION_PX, COLOUR_BAR_PX
    with Image.open(out / sbs[0]) as im:
        assert im.size == (320, CAPTION_PX + 120)
        a = np.asarray(im)
    pic, cap = a[CAPTION_PX:], a[:CAPTION_PX]
    assert np.array_equal(pic[:, :160], pic[:, 160:])      # identical halves
    assert pic.max() > 50                                   # and something was rendered
    assert not np.array_equal(cap[:, :160], cap[:, 160:])  # captions: original / decoded
    assert (cap > 200).sum() > 200                          # white text on the caption bar
    with Image.open(out / err[0]) as im:
        assert im.size == (160, 120 + COLOUR_BAR_PX)
        e = np.asarray(im)
    assert e[:120].max() == 0                               # no error anywhere
    bar = e[120 + 4:120 + 14, 6:-6]                         # the colour bar: black -> white
    assert bar[:, 0].max() == 0 and bar[:, -1].min() >= 250 and (bar[0, :, 0] > 0).sum() > 100


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
    from gsz.evaluation.cameras import default_cameras, write_cameras_json
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
    assert proc.returncode == (2 if case == "bad_background" else 1), proc.stderr   # usage / data
    lines = [ln for ln in proc.stderr.splitlines() if not ln.startswith("gsz-eval: warning")]
    assert len(lines) == 1 and lines[0].startswith("gsz-eval: error: ") and args[1] in lines[0], proc.stderr
    assert "Traceback" not in proc.stderr and proc.stdout == ""


def test_evaluate_api_reuses_reference_images(sample_sh3):
    from gsz.evaluation.cameras import default_cameras
    from gsz.evaluation.evaluate import evaluate, render_views
    cams = default_cameras(sample_sh3, n_train=0, n_test=2, width=96, height=72).test
    b = _nudged(sample_sh3, -0.5)
    full = evaluate(sample_sh3, b, cams)
    refs = render_views(sample_sh3, cams)
    again = evaluate(refs, b, cams)
    assert again["views"] == full["views"] and 10 < full["psnr"] < 100
    assert full["num_gaussians"] == {"original": 12000, "compressed": 12000}
    with pytest.raises(GszError, match="reference images"):
        evaluate(refs[:1], b, cams)


def test_existing_images_are_kept_unless_overwrite(tmp_path):
    out = tmp_path / "imgs"
    out.mkdir()
    victim = out / "000_test_000_side_by_side.png"
    victim.write_bytes(b"keep me")
    proc = run_eval(SAMPLE_SH3, SAMPLE_SH3, *FAST, "-o", out)
    assert proc.returncode == 1 and "exists" in proc.stderr and "-w/--overwrite" in proc.stderr
    assert "gsz-eval: view" not in proc.stderr                # refused before rendering
    assert victim.read_bytes() == b"keep me" and os.listdir(out) == [victim.name]
    run_eval(SAMPLE_SH3, SAMPLE_SH3, *FAST, "-o", out, "-w", "-q", check_rc=0)
    assert victim.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and len(os.listdir(out)) == 4


def test_rd_curve_of_a_scene_from_one_command(tmp_path):
    """--rd: every reachable budget is encoded (within 0.5 % below it) and scored exactly as
    gsz-eval scores the written file; an unreachable budget is listed, not fatal."""
    scene = tmp_path / "small.ply"
    c = gsz.read_ply(SAMPLE_SH0)
    gsz.write_ply(c.subset(np.arange(0, len(c), 20)), scene)
    out = tmp_path / "rd"
    args = ["--rd", scene, "--sizes", "20kB,10kB,500B", *FAST, "--train-views", "2",
            "--importance-width", "64", "-o", out]
    proc = run_eval(*args, "--json", check_rc=0)
    rd = json.loads(proc.stdout)
    assert [p["target"] for p in rd["points"]] == ["10kB", "20kB"]
    for p in rd["points"]:
        assert 0.995 * p["target_bytes"] <= p["bytes"] <= p["target_bytes"]
        assert os.path.getsize(p["file"]) == p["bytes"]
    assert rd["points"][0]["psnr"] < rd["points"][1]["psnr"] < 100
    (u,) = rd["unreachable"]
    assert u["target"] == "500B" and "at least" in u["error"]
    assert sorted(os.listdir(out)) == ["rd.json", "rd.png", "small-10kB.gsz", "small-20kB.gsz"]
    assert json.loads((out / "rd.json").read_text())["points"] == rd["points"]
    from PIL import Image
    with Image.open(out / "rd.png") as im:
        assert im.size[0] >= 500 and im.size[1] >= 400
    again = json.loads(run_eval(scene, rd["points"][0]["file"], *FAST, "--json", check_rc=0).stdout)
    assert again["psnr"] == rd["points"][0]["psnr"] and again["ssim"] == rd["points"][0]["ssim"]
    proc = run_eval(*args)                                     # outputs exist now
    assert proc.returncode == 1 and "exists" in proc.stderr
    proc = run_eval("--rd", scene, "--sizes", "1 parsec", "-o", out)
    assert proc.returncode == 2 and proc.stderr.startswith("gsz-eval: error: ")
