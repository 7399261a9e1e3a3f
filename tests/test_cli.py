"""gsz-encode / gsz-decode / gsz-info as a user runs them."""
import json
import os
import subprocess
import sys

import numpy as np
import pytest

import gsz
from conftest import SAMPLE_SH0

FAST = ["--codebook", "64", "--train-views", "4", "--importance-width", "120"]


def run(*args, check=True):
    code = ("import sys; from gsz.encoder.cli import main as e; from gsz.decoder.cli import decode_main as d, "
            "info_main as i; sys.exit({'encode': e, 'decode': d, 'info': i}[sys.argv[1]](sys.argv[2:]))")
    p = subprocess.run([sys.executable, "-c", code, *map(str, args)], capture_output=True, text=True)
    if check:
        assert p.returncode == 0, p.stderr
    return p


@pytest.fixture(scope="module")
def gsz_file(tmp_path_factory):
    out = tmp_path_factory.mktemp("cli") / "plant.gsz"
    p = run("encode", SAMPLE_SH0, "-o", out, "--bits", "10", "--json", *FAST)
    report = json.loads(p.stdout)
    return out, report, p.stderr


def test_encode_reports_sizes_stages_and_progress(gsz_file):
    out, report, stderr = gsz_file
    assert report["bytes"] == os.path.getsize(out)
    assert report["ratio"] > 4   # SH-0 sample at 10 uniform bits; the size search does better
    assert report["options"]["blocks"] == 1          # the fixed configuration's default
    for k in ("geometry", "attributes", "metadata"):
        assert report["components"][k] > 0
    for stage in ("importance", "prune", "voxelize", "geometry", "attributes", "container"):
        assert stage in report["seconds"]
        assert f"[gsz] {stage}" in stderr


def test_decode_and_info(gsz_file, tmp_path):
    out, report, _ = gsz_file
    ply = tmp_path / "back.ply"
    p = run("decode", out, "-o", ply, "--json")
    assert json.loads(p.stdout)["num_gaussians"] == report["voxels"]
    cloud = gsz.read_ply(ply)
    assert len(cloud) == report["voxels"] and cloud.sh_degree == 0
    info = json.loads(run("info", out, "--json").stdout)
    assert info["num_gaussians"] == report["voxels"]
    types = [c["type"] for c in info["chunks"]]
    assert types[0] == "GEOM" and types[1:3] in (["ATTR", "META"], ["RWGT", "ATTR"])
    assert sum(c["bytes"] for c in info["chunks"]) < info["bytes"]
    text = run("info", out).stdout
    assert "GEOM" in text and "gaussians" in text


def test_bad_inputs_give_one_line_errors_and_no_output(tmp_path):
    junk = tmp_path / "junk.ply"
    junk.write_bytes(b"not a ply at all")
    out = tmp_path / "x.gsz"
    p = run("encode", junk, "-o", out, *FAST, check=False)
    assert p.returncode == 1 and "junk.ply" in p.stderr and "Traceback" not in p.stderr
    assert not out.exists()
    p = run("encode", SAMPLE_SH0, "-o", out, "--bits", "17", check=False)
    assert p.returncode == 2 and "--bits" in p.stderr and not out.exists()
    bad = tmp_path / "bad.gsz"
    bad.write_bytes(b"\x89GSZ\r\n\x1a\n" + b"\x00" * 100)
    p = run("decode", bad, "-o", tmp_path / "y.ply", check=False)
    assert p.returncode == 1 and "bad.gsz" in p.stderr and "Traceback" not in p.stderr
    assert not (tmp_path / "y.ply").exists()
    p = run("info", tmp_path / "missing.gsz", check=False)
    assert p.returncode == 1 and "not found" in p.stderr
    # a size target with knobs only a fixed configuration has: one line naming them, no file
    p = run("encode", SAMPLE_SH0, "-o", out, "--ratio", "20", "--rel-error", "0.01", "--sh-bits", "8",
            check=False)
    assert p.returncode == 2 and "--rel-error/--sh-bits" in p.stderr and "Traceback" not in p.stderr
    assert not out.exists()
    p = run("encode", SAMPLE_SH0, "-o", out, "--ratio", "20", "--beta", "-1", *FAST, check=False)
    assert p.returncode == 2 and "--beta" in p.stderr and not out.exists()


def test_layered_encode_decode_first_layers_and_partial(tmp_path):
    out = tmp_path / "layered.gsz"
    p = run("encode", SAMPLE_SH0, "-o", out, "--bits", "8", "--layers", "3", "--json", *FAST)
    report = json.loads(p.stdout)
    layers = report["layers"]
    assert len(layers) == 3 and "geometry - layer 2" not in p.stderr    # -v shows every part
    text = run("info", out).stdout
    assert "decodable at" in text and f"{layers[0]['gaussians']:,}" in text
    info = json.loads(run("info", out, "--json").stdout)
    assert [r["cumulative_gaussians"] for r in info["layers"]] == [r["cumulative_gaussians"] for r in layers]
    first = tmp_path / "first.ply"
    run("decode", out, "-o", first, "--layers", "1")
    assert len(gsz.read_ply(first)) == layers[0]["gaussians"]
    cut = tmp_path / "cut.gsz"
    cut.write_bytes(out.read_bytes()[:layers[1]["decodable_at"] + 3])
    bad = run("decode", cut, "-o", tmp_path / "x.ply", check=False)
    assert bad.returncode == 1 and "truncated" in bad.stderr and "--partial" in bad.stderr
    assert not (tmp_path / "x.ply").exists()
    part = run("decode", cut, "-o", tmp_path / "part.ply", "--partial", "--json")
    assert "warning: " in part.stderr and "decoded 2 of 3 layers" in part.stderr
    assert json.loads(part.stdout)["num_gaussians"] == layers[1]["cumulative_gaussians"]
    assert run("encode", SAMPLE_SH0, "-o", tmp_path / "y.gsz", "--layers", "0", check=False).returncode == 2


def test_layers_flag_without_a_number_means_the_measured_streaming_default():
    from gsz.encoder.cli import build_parser
    from gsz.encoder.pipeline import STREAMING_LAYERS
    p = build_parser()
    assert p.parse_args(["in.ply", "-o", "o.gsz"]).layers == 1
    assert p.parse_args(["in.ply", "-o", "o.gsz", "--layers"]).layers == STREAMING_LAYERS == 3
    assert p.parse_args(["in.ply", "-o", "o.gsz", "--layers", "5"]).layers == 5


# ---------------------------------------------------------------- issue 19: paths and signals
TINY = ["--bits", "8", "--codebook", "16", "--train-views", "1", "--importance-width", "32", "-q"]


@pytest.fixture(scope="module")
def small_pair(tmp_path_factory):
    """A 300-Gaussian PLY and its .gsz (encodes in well under a second)."""
    import numpy as np
    d = tmp_path_factory.mktemp("small")
    c = gsz.read_ply(SAMPLE_SH0)
    gsz.write_ply(c.subset(np.arange(300)), d / "s.ply")
    from gsz.encoder.cli import main
    assert main([str(d / "s.ply"), "-o", str(d / "s.gsz"), *TINY]) == 0
    return d / "s.ply", d / "s.gsz"


def _one_line_error(capsys, *names):
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err and ".tmp-" not in err, err
    for name in names:
        assert str(name) in err, err
    return err


def test_output_that_is_the_input_is_refused(small_pair, tmp_path, capsys):
    from gsz.decoder.cli import decode_main
    from gsz.encoder.cli import main
    ply, g = (tmp_path / "a.ply", tmp_path / "a.gsz")
    ply.write_bytes(small_pair[0].read_bytes())
    g.write_bytes(small_pair[1].read_bytes())
    os.symlink(ply, tmp_path / "alias.ply")
    os.link(g, tmp_path / "hard.gsz")
    before = (ply.read_bytes(), g.read_bytes())
    for out in (ply, tmp_path / "alias.ply", f"{tmp_path}/./a.ply"):
        assert main([str(ply), "-o", str(out), *TINY, "-w"]) == 1      # never the input, even with -w
        assert "is the input file" in _one_line_error(capsys, out)
    for out in (g, tmp_path / "hard.gsz"):
        assert decode_main([str(g), "-o", str(out), "-w"]) == 1
        assert "is the input file" in _one_line_error(capsys, out)
    assert (ply.read_bytes(), g.read_bytes()) == before


def test_unwritable_output_fails_before_the_encode(small_pair, tmp_path, capsys):
    from gsz.encoder.cli import main
    ply = small_pair[0]
    (tmp_path / "afile").write_bytes(b"x")
    cases = [("", "output path is empty"), (str(tmp_path), "is a directory"),
             (str(tmp_path / "afile" / "x.gsz"), "is a file, not a folder"),
             (str(tmp_path / "new") + os.sep, "path separator")]
    if os.path.isdir("/sys"):
        cases.append(("/sys/gsz-out.gsz", "Permission denied"))     # even root cannot write there
    for out, words in cases:
        assert main([str(ply), "-o", out, *TINY[:-1]]) == 1        # not quiet: stages would show
        err = capsys.readouterr().err
        assert words in err and "[gsz] importance" not in err and "Traceback" not in err, err
        assert len(err.strip().splitlines()) == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile"]


def test_write_failure_after_the_encode_names_the_output(small_pair, tmp_path, capsys, monkeypatch):
    import errno

    import gsz.decoder.io_util as io_util
    from gsz.encoder.cli import main

    def full(fd):
        raise OSError(errno.ENOSPC, "No space left on device")
    monkeypatch.setattr(io_util.os, "fsync", full)
    out = tmp_path / "o.gsz"
    assert main([str(small_pair[0]), "-o", str(out), *TINY]) == 1
    assert "No space left on device" in _one_line_error(capsys, out)
    assert list(tmp_path.iterdir()) == []


def test_zero_vertex_ply_and_device_inputs(tmp_path, capsys):
    from gsz.decoder.cli import decode_main, info_main
    from gsz.decoder.ply import cloud_to_ply_bytes
    from gsz.encoder.cli import main
    empty = tmp_path / "empty.ply"
    empty.write_bytes(cloud_to_ply_bytes(gsz.read_ply(SAMPLE_SH0).subset([])))
    assert main([str(empty), "-o", str(tmp_path / "e.gsz"), *TINY]) == 1
    assert "0 vertices" in _one_line_error(capsys, empty)
    bad_q = tmp_path / "zero_q.ply"
    c = gsz.read_ply(SAMPLE_SH0).subset(list(range(50)))
    c.rotations[[7, 9]] = 0.0
    gsz.write_ply(c, bad_q)
    assert main([str(bad_q), "-o", str(tmp_path / "q.gsz"), *TINY]) == 1
    assert "2 vertices have an all-zero rotation quaternion" in _one_line_error(capsys, bad_q, "vertex 7")
    assert main(["/dev/zero", "-o", str(tmp_path / "z.gsz"), *TINY]) == 1
    assert "not a regular file" in _one_line_error(capsys, "/dev/zero")
    assert decode_main(["/dev/zero", "-o", str(tmp_path / "z.ply")]) == 1
    assert "not a regular file" in _one_line_error(capsys, "/dev/zero")
    assert info_main(["/dev/zero"]) == 1
    assert "not a regular file" in _one_line_error(capsys, "/dev/zero")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["empty.ply", "zero_q.ply"]


@pytest.fixture
def sigint_raises():
    """SIGINT raising KeyboardInterrupt, as in a terminal: a process started in the background of
    a non-interactive shell inherits SIGINT ignored, and Python then leaves it ignored."""
    import signal
    old = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, old)


@pytest.mark.parametrize("sig", ["SIGINT", "SIGTERM"])
@pytest.mark.parametrize("when", ["decode", "write"])
def test_interrupted_decode_exits_130_with_one_line_and_no_output(small_pair, tmp_path, capsys,
                                                                  monkeypatch, sig, when, sigint_raises):
    import signal
    import time

    import gsz.decoder.io_util as io_util
    from gsz.decoder.cli import decode_main
    decode_mod = sys.modules["gsz.decoder.decode"]      # gsz.decoder.decode is the function
    real_decode = decode_mod.decode

    def hit(*a, **k):                   # a real signal, delivered to this process
        os.kill(os.getpid(), getattr(signal, sig))
        time.sleep(2)
        raise AssertionError("the signal did not interrupt")
    if when == "decode":
        monkeypatch.setattr(decode_mod, "decode", lambda *a, **k: (hit(), real_decode(*a, **k)))
    else:
        monkeypatch.setattr(io_util.os, "fsync", hit)
    out = tmp_path / "o.ply"
    assert decode_main([str(small_pair[1]), "-o", str(out)]) == 130
    assert "interrupted; no output written" in _one_line_error(capsys)
    assert list(tmp_path.iterdir()) == []


def test_decode_to_dev_null_keeps_it_a_device(small_pair, capsys):
    import stat
    from gsz.decoder.cli import decode_main
    before = os.stat(os.devnull)
    if not stat.S_ISCHR(before.st_mode):
        pytest.skip(f"{os.devnull} is not a character device on this machine")
    assert decode_main([str(small_pair[1]), "-o", os.devnull, "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["num_gaussians"] > 0
    after = os.stat(os.devnull)
    assert stat.S_ISCHR(after.st_mode) and after.st_ino == before.st_ino


def test_ctrl_c_during_encode_start_up_is_one_line(tmp_path, capsys, monkeypatch, sigint_raises):
    import signal
    import time

    import gsz.encoder.cli as cli
    real = cli.build_parser

    def slow_imports():                  # Ctrl-C while torch and the pipeline import
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(2)
        return real()
    monkeypatch.setattr(cli, "build_parser", slow_imports)
    assert cli.main([str(SAMPLE_SH0), "-o", str(tmp_path / "x.gsz")]) == 130
    assert "interrupted; no output written" in _one_line_error(capsys)
    assert list(tmp_path.iterdir()) == []


def test_gsz_info_into_a_closed_pipe_exits_quietly(monkeypatch, tmp_path):
    """`gsz-info f.gsz | head -1`: the reader closing the pipe is not an error (no traceback)."""
    import io
    from pathlib import Path
    from gsz.decoder.cli import info_main
    vec = Path(__file__).resolve().parent.parent / "format_spec" / "vectors" / "sh1_jug_12k_tiles.gsz"
    fd = os.open(tmp_path / "sink", os.O_WRONLY | os.O_CREAT)

    class ClosedPipe(io.TextIOBase):
        def write(self, s):
            raise BrokenPipeError(32, "Broken pipe")

        def fileno(self):
            return fd

    monkeypatch.setattr(sys, "stdout", ClosedPipe())
    try:
        assert info_main([str(vec)]) == 0
    finally:
        os.close(fd)


@pytest.mark.parametrize("tool,module,fn", [("gsz-encode", "gsz.encoder.cli", "main"),
                                            ("gsz-decode", "gsz.decoder.cli", "decode_main"),
                                            ("gsz-info", "gsz.decoder.cli", "info_main"),
                                            ("gsz-eval", "gsz.encoder.eval_cli", "main"),
                                            ("gsz-view", "gsz.viewer.cli", "main")])
def test_every_tool_has_version_and_help_without_torch(tool, module, fn):
    """`--version` prints the package version; `--help` answers without importing torch (seconds)."""
    code = (f"import sys, importlib; m = importlib.import_module('{module}')\n"
            f"try:\n    getattr(m, '{fn}')([sys.argv[1]])\nexcept SystemExit as e:\n    assert e.code == 0, e.code\n"
            "print('TORCH' if 'torch' in sys.modules else 'NO-TORCH')")
    v = subprocess.run([sys.executable, "-c", code, "--version"], capture_output=True, text=True)
    assert v.returncode == 0 and v.stdout.startswith(f"{tool} {gsz.__version__}\n"), v.stdout + v.stderr
    h = subprocess.run([sys.executable, "-c", code, "--help"], capture_output=True, text=True)
    assert h.returncode == 0 and "usage:" in h.stdout and h.stdout.rstrip().endswith("NO-TORCH"), h.stdout[-300:] + h.stderr


# ---------------------------------------------------------------- issue 20: CLI conventions
def test_existing_outputs_are_kept_unless_overwrite(small_pair, tmp_path, capsys):
    """An existing output is refused (exit 1, one line naming it, the file untouched) before any
    work; -w/--overwrite replaces it; the input is never replaced, not even with -w."""
    from gsz.decoder.cli import decode_main
    from gsz.encoder.cli import main
    ply, g = small_pair
    out = tmp_path / "o.gsz"
    out.write_bytes(b"keep me")
    assert main([str(ply), "-o", str(out), *TINY[:-1]]) == 1
    err = _one_line_error(capsys, out)
    assert err.startswith("gsz-encode: error: ") and "exists" in err and "-w/--overwrite" in err
    assert out.read_bytes() == b"keep me"
    assert main([str(ply), "-o", str(out), *TINY, "-w"]) == 0
    assert out.read_bytes() == g.read_bytes()              # the same encode, deterministic
    back = tmp_path / "back.ply"
    back.write_bytes(b"keep me too")
    assert decode_main([str(g), "-o", str(back), "-q"]) == 1
    assert "exists" in _one_line_error(capsys, back) and back.read_bytes() == b"keep me too"
    assert decode_main([str(g), "-o", str(back), "-q", "--overwrite"]) == 0
    assert len(gsz.read_ply(back)) == len(gsz.load(str(g)))
    rep = tmp_path / "rep"
    rep.mkdir()
    (rep / "report.json").write_text("{}")
    assert main([str(ply), "-o", str(tmp_path / "r.gsz"), *TINY, "--report", str(rep)]) == 1
    assert "exists" in _one_line_error(capsys, rep / "report.json")
    assert (rep / "report.json").read_text() == "{}" and not (tmp_path / "r.gsz").exists()


def test_dash_output_writes_the_file_to_stdout_and_nothing_else(small_pair, tmp_path):
    ply, g = small_pair
    p = subprocess.run([sys.executable, "-m", "gsz.encoder.cli", str(ply), "-o", "-", *TINY[:-1]],
                       capture_output=True)
    assert p.returncode == 0, p.stderr
    assert p.stdout == g.read_bytes()                      # exactly the .gsz bytes
    assert b"[gsz] importance" in p.stderr and b"wrote stdout" in p.stderr
    p = subprocess.run([sys.executable, "-m", "gsz.decoder.cli", str(g), "-o", "-"], capture_output=True)
    assert p.returncode == 0, p.stderr
    (tmp_path / "back.ply").write_bytes(p.stdout)
    assert gsz.read_ply(tmp_path / "back.ply").equals(gsz.load(str(g)))
    assert b"decoded" in p.stderr
    p = run("encode", ply, "-o", "-", "--json", *TINY, check=False)
    assert p.returncode == 2 and "--json" in p.stderr and p.stdout == ""


def test_dash_output_refuses_a_terminal(small_pair):
    import pty
    master, slave = pty.openpty()
    try:
        p = subprocess.run([sys.executable, "-m", "gsz.decoder.cli", str(small_pair[1]), "-o", "-"],
                           stdout=slave, stderr=subprocess.PIPE, text=True)
    finally:
        os.close(slave)
        os.close(master)
    assert p.returncode == 2 and "stdout is a terminal" in p.stderr


def test_quiet_default_and_verbose_levels(small_pair, tmp_path):
    """-q: nothing on stderr; default: stage names without times; -v: every stage's time."""
    ply = small_pair[0]
    args = [sys.executable, "-m", "gsz.encoder.cli", str(ply), *TINY[:-1]]
    q = subprocess.run(args + ["-o", str(tmp_path / "q.gsz"), "-q"], capture_output=True, text=True)
    n = subprocess.run(args + ["-o", str(tmp_path / "n.gsz")], capture_output=True, text=True)
    v = subprocess.run(args + ["-o", str(tmp_path / "v.gsz"), "-v"], capture_output=True, text=True)
    assert q.returncode == n.returncode == v.returncode == 0
    assert q.stderr == "" and q.stdout == n.stdout == v.stdout == ""
    assert "[gsz] importance" in n.stderr and "done in" not in n.stderr and "it/s" not in n.stderr
    assert "importance done in" in v.stderr and len(v.stderr.splitlines()) > len(n.stderr.splitlines()) + 5
    assert "{'" not in n.stderr + v.stderr                 # no Python dicts in the log
    same = {(tmp_path / f).read_bytes() for f in ("q.gsz", "n.gsz", "v.gsz")}
    assert len(same) == 1


def test_usage_and_data_errors_have_one_format_and_their_exit_codes(small_pair, tmp_path):
    """2 for a bad option (as argparse), 1 for bad data; 'gsz-xxx: error: ...' either way."""
    ply, g = small_pair
    junk = tmp_path.parent / f"{tmp_path.name}-junk.ply"
    junk.write_bytes(b"ply\nnot really")
    cases = [(("encode", ply, "-o", tmp_path / "a.gsz", "--bits", "0"), 2, "gsz-encode: error: "),
             (("encode", ply, "-o", tmp_path / "a.gsz", "--size", "12 parsecs"), 2, "gsz-encode: error: "),
             (("encode", ply, "-o", tmp_path / "a.gsz", "--nonsense"), 2, "gsz-encode: error: "),
             (("encode", junk, "-o", tmp_path / "a.gsz"), 1, "gsz-encode: error: "),
             (("decode", g, "-o", tmp_path / "a.ply", "--layers", "0"), 2, "gsz-decode: error: "),
             (("decode", ply, "-o", tmp_path / "a.ply"), 1, "gsz-decode: error: "),
             (("info", ply), 1, "gsz-info: error: ")]
    for args, code, prefix in cases:
        p = run(*args, check=False)
        assert p.returncode == code and p.stderr.splitlines()[-1].startswith(prefix), (args, p.stderr)
        assert "Traceback" not in p.stderr
    assert sorted(os.listdir(tmp_path)) == []


def test_help_shows_real_defaults_in_the_right_groups():
    from gsz.encoder.cli import build_parser
    text = build_parser().format_help()
    assert "(default: None)" not in text and "default: False" not in text and "(default: 1)" not in text
    assert "(default: 1) (default" not in text
    groups = {g.title: [a.dest for a in g._group_actions] for g in build_parser()._action_groups}
    assert "report" in groups["output"] and "overwrite" in groups["output"]
    target = next(t for t in groups if t.startswith("size target"))
    assert "solver" in groups[target] and "report" not in groups[target]
    assert "reserve" in groups["fixed configuration (without a size target)"]
    assert "--train-views TRAIN_VIEWS" in text and "(default: 24)" in text


def test_unreachable_size_fails_before_the_importance_pass(tmp_path):
    """A budget below the provable bound is refused in well under a second of work, with the
    bound named; nothing is written."""
    import time
    from conftest import SAMPLE_SH3
    t0 = time.perf_counter()
    p = run("encode", SAMPLE_SH3, "-o", tmp_path / "x.gsz", "--size", "5kB", check=False)
    took = time.perf_counter() - t0
    assert p.returncode == 1 and "at least 7,983 bytes" in p.stderr and "smallest reachable" in p.stderr
    assert "[gsz] importance" not in p.stderr and not (tmp_path / "x.gsz").exists()
    assert took < 20, took              # the importance pass alone takes longer on 2 cores


def test_report_works_with_a_fixed_configuration(small_pair, tmp_path):
    from PIL import Image
    from gsz.encoder.cli import main
    rep = tmp_path / "rep"
    assert main([str(small_pair[0]), "-o", str(tmp_path / "f.gsz"), *TINY, "--report", str(rep), "--blocks", "4"]) == 0
    r = json.loads((rep / "report.json").read_text())
    assert r["bits"]["raht"] == [[8] * 4] * 7 and r["bits"]["scales"] == [[8] * 4] * 3
    with Image.open(rep / "bits.png") as im:
        assert im.size[0] > 300 and im.size[1] > 150
        px = np.asarray(im.convert("RGB"))
    assert len(np.unique(px.reshape(-1, 3), axis=0)) > 50     # a plot: axes, text, colour bar


@pytest.mark.parametrize("tool,module", [("gsz-encode", "gsz.encoder.cli"), ("gsz-eval", "gsz.encoder.eval_cli")])
def test_core_only_install_names_the_extra(small_pair, tmp_path, tool, module):
    """Without torch (a core-only install, simulated by an import blocker) the encoder tools
    say which extra to install, in one line, instead of a traceback."""
    code = ("import sys\n"
            "class Block:\n"
            "    def find_spec(self, name, path=None, target=None):\n"
            "        if name == 'torch' or name.startswith('torch.'):\n"
            "            raise ModuleNotFoundError(\"No module named 'torch'\", name='torch')\n"
            "sys.meta_path.insert(0, Block())\n"
            f"import runpy; sys.argv[0] = '{tool}'\n"
            f"runpy.run_module('{module}', run_name='__main__')\n")
    ply, g = small_pair
    args = ([str(ply), "-o", str(tmp_path / "x.gsz")] if tool == "gsz-encode" else [str(ply), str(g)])
    p = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True)
    assert p.returncode == 1, p.stderr
    assert p.stderr.strip() == f'{tool}: error: {tool} needs torch, which is not installed: pip install "gsz[encoder]"'
    assert os.listdir(tmp_path) == []
