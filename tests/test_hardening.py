"""Issue 19 hardening of the encoder's grid and of gsz's file writing (io_util)."""
import os
import time

import numpy as np
import pytest

import gsz
from gsz.decoder import GszError
from gsz.decoder.decode import decode
from gsz.decoder.io_util import GszOutputError, atomic_write, check_output_path
from gsz.encoder.pipeline import EncodeOptions, encode
from gsz.encoder.voxelize import VoxelizeError, bounding_cube, voxel_coords
from codec_util import sample

TINY = dict(codebook=16, train_views=1, importance_width=32, bits=8)
#: A pid above Linux's largest pid_max (2^22): no process ever has it.
DEAD_PID = (1 << 22) + 1


def _within(seconds, fn, *a):
    """fn(*a), run on a daemon thread so that a hang fails the test instead of stalling it."""
    import threading
    box = {}

    def target():
        try:
            box["out"] = fn(*a)
        except BaseException as e:       # re-raised on the test's thread
            box["err"] = e
    t = threading.Thread(target=target, daemon=True)
    t.start()
    t.join(seconds)
    assert not t.is_alive(), f"{fn.__name__} still running after {seconds} s"
    if "err" in box:
        raise box["err"]
    return box["out"]


@pytest.mark.parametrize("far", [1e17, -4e20, 1e300])
def test_bounding_cube_terminates_far_from_the_origin(far):
    # |coordinate| >> extent: the padding vanishes in rounding (this looped for ever).
    pts = np.array([[far, 0.0, 0.0], [far, 1.0, 0.5]])
    try:
        origin, side = _within(5, bounding_cube, pts)
    except VoxelizeError as e:      # where float64 cannot hold a fine enough grid: say so
        assert "move the scene near the origin" in str(e) and abs(far) > 1e18
        return
    assert np.all(origin + side > pts.max(axis=0))
    ijk = voxel_coords(pts, 21, origin, side)
    assert ijk[0, 1] != ijk[1, 1]            # the two points stay apart on y
    o1, s1 = _within(5, bounding_cube, np.array([[far, 2.0, 3.0]]))     # one point there: a valid cube too
    assert s1 > 0 and np.all(o1 + s1 > [far, 2.0, 3.0])


def test_scene_moved_to_3e38_is_a_clear_error_not_a_hang():
    c = sample("sh0", 300)
    moved = c.subset(np.arange(len(c)))
    moved.positions = (moved.positions.astype(np.float64) + [3e38, 0, 0]).astype(np.float32)
    t0 = time.perf_counter()
    with pytest.raises(VoxelizeError, match="too coarse to keep the scene"):
        encode(moved, EncodeOptions(**TINY))
    assert time.perf_counter() - t0 < 30


def test_scene_at_1e17_encodes_and_keeps_its_shape():
    c = sample("sh0", 300)
    moved = c.subset(np.arange(len(c)))
    moved.positions = (moved.positions.astype(np.float64) + [1e17, 0, 0]).astype(np.float32)
    out = decode(encode(moved, EncodeOptions(**{**TINY, "reserve": 1.0})).data)
    # x is one float32 value, as in the input; y and z keep a fine grid's precision
    assert np.all(out.positions[:, 0] == np.float32(1e17)) and len(out) > 0.9 * len(moved)
    yz_in, yz_out = moved.positions[:, 1:].astype(np.float64), out.positions[:, 1:].astype(np.float64)
    nearest = np.sqrt(((yz_out[:, None, :] - yz_in[None, :, :]) ** 2).sum(-1)).min(axis=1)
    assert nearest.max() < 2e-3 * np.ptp(yz_in, axis=0).max()


def test_atomic_write_errors_name_the_output_never_the_temp_file(tmp_path, monkeypatch):
    import errno

    import gsz.decoder.io_util as io_util
    out = tmp_path / "scene.gsz"

    def full(fd):
        raise OSError(errno.ENOSPC, "No space left on device", str(tmp_path / ".tmp-1-xxxxxxxx-scene.gsz"))
    monkeypatch.setattr(io_util.os, "fsync", full)
    with pytest.raises(GszOutputError) as e:
        atomic_write(out, b"data")
    msg = str(e.value)
    assert msg.startswith(str(out)) and "No space left" in msg and ".tmp-" not in msg
    assert isinstance(e.value, OSError) and "\n" not in msg
    assert list(tmp_path.iterdir()) == []
    monkeypatch.undo()
    (tmp_path / "file").write_bytes(b"x")
    for bad, words in ((tmp_path / "file" / "sub" / "a.gsz", "is a file, not a folder"),
                       ("", "output path is empty"), (tmp_path, "is a directory")):
        with pytest.raises(GszOutputError, match=words):
            atomic_write(bad, b"data")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]


def test_check_output_path_refuses_inputs_and_unwritable_places(tmp_path):
    src = tmp_path / "a.ply"
    src.write_bytes(b"ply")
    os.link(src, tmp_path / "hard.ply")
    os.symlink(src, tmp_path / "soft.ply")
    for same in (src, tmp_path / "hard.ply", tmp_path / "soft.ply", tmp_path / "." / "a.ply"):
        with pytest.raises(GszOutputError, match="is the input file"):
            check_output_path(same, inputs=[src])
    assert src.read_bytes() == b"ply"
    import socket
    sock = socket.socket(socket.AF_UNIX)
    sock.bind(str(tmp_path / "s.sock"))
    with pytest.raises(GszOutputError, match="is a socket"):
        check_output_path(tmp_path / "s.sock")
    sock.close()
    os.unlink(tmp_path / "s.sock")
    with pytest.raises(GszOutputError, match="path separator"):
        check_output_path(str(tmp_path / "new") + os.sep)
    if os.path.isdir("/sys"):        # sysfs refuses new files even to root
        with pytest.raises(GszOutputError, match="cannot write in /sys"):
            check_output_path("/sys/gsz-out.gsz")
    assert check_output_path(tmp_path / "new" / "deeper" / "x.gsz") == str(tmp_path / "new" / "deeper" / "x.gsz")
    assert not (tmp_path / "new").exists()          # a check creates nothing
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.ply", "hard.ply", "soft.ply"]


def test_stale_temp_files_of_a_killed_write_are_removed(tmp_path):
    live = tmp_path / f".tmp-{os.getppid()}-abcd1234-out.ply"      # a running writer's: kept
    dead = tmp_path / f".tmp-{DEAD_PID}-abcd1234-out.ply"          # its writer is gone
    old = tmp_path / ".tmp-k2j4h5g6out.ply"                        # an older gsz's, 2 days old
    fresh_old = tmp_path / ".tmp-q1w2e3r4out.ply"                  # an older gsz's, just written
    other = tmp_path / f".tmp-{DEAD_PID}-abcd1234-other.ply"       # another output's
    for p in (live, dead, old, fresh_old, other):
        p.write_bytes(b"partial")
    two_days = time.time() - 2 * 86400
    os.utime(old, (two_days, two_days))
    gsz.write_ply(sample("sh0", 10), tmp_path / "out.ply")
    left = sorted(p.name for p in tmp_path.iterdir())
    assert left == sorted([live.name, fresh_old.name, other.name, "out.ply"])
    assert len(gsz.read_ply(tmp_path / "out.ply")) == 10


def test_sigterm_during_a_write_leaves_no_file(tmp_path, monkeypatch):
    import signal

    import gsz.decoder.io_util as io_util
    from gsz.decoder.io_util import sigterm_as_interrupt

    def killed(fd):
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(1)                                  # the handler raises during this sleep
    monkeypatch.setattr(io_util.os, "fsync", killed)
    before = signal.getsignal(signal.SIGTERM)
    with pytest.raises(KeyboardInterrupt), sigterm_as_interrupt():
        atomic_write(tmp_path / "out.gsz", b"data")
    assert list(tmp_path.iterdir()) == []
    assert signal.getsignal(signal.SIGTERM) is before     # the CLI's handler does not leak


def test_gsz_error_types_stay_catchable():
    assert issubclass(GszOutputError, GszError) and issubclass(GszOutputError, OSError)


def test_devices_and_pipes_are_written_in_place_never_replaced(tmp_path):
    # `gsz-decode x.gsz -o /dev/null` (a timing run): atomic_write's os.replace used to turn
    # /dev/null into a regular file when run as root.
    import stat
    import threading
    null = os.stat(os.devnull)
    if stat.S_ISCHR(null.st_mode):
        check_output_path(os.devnull)
        atomic_write(os.devnull, b"discarded")
        after = os.stat(os.devnull)
        assert stat.S_ISCHR(after.st_mode) and after.st_ino == null.st_ino
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    got = []
    reader = threading.Thread(target=lambda: got.append(open(fifo, "rb").read()), daemon=True)
    reader.start()
    assert check_output_path(fifo) == str(fifo)
    atomic_write(fifo, b"through the pipe")
    reader.join(5)
    assert got == [b"through the pipe"] and stat.S_ISFIFO(os.stat(fifo).st_mode)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["pipe"]
