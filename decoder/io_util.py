"""Small file helpers shared by every reader and writer in gsz.

Inputs are checked before they are opened (:func:`check_input_file`: a regular file of bounded
size, so ``/dev/zero`` or a FIFO cannot make a read run forever); outputs before the work that
produces them (:func:`check_output_path`) and written atomically (:func:`atomic_write`), every
failure a one-line :class:`GszError` naming the file the user gave.
"""
from __future__ import annotations

import contextlib
import errno
import os
import re
import stat
import tempfile
import time

from .errors import GszError, GszOutputError

#: Largest input file gsz reads: the PLY of 2^28 (the default Gaussian limit) SH-3 Gaussians is
#: 2^28 x 248 B < 2^36; twice that leaves room for extra properties.  Bounds a read of a
#: mistaken path (a disk image, a sparse file) to one clear error instead of a MemoryError.
MAX_INPUT_BYTES = 1 << 37
#: Temporary files of :func:`atomic_write`: ``.tmp-<pid>-<random>-<name>``.
_TMP_PREFIX = ".tmp-"
#: A temporary file without a live writer's pid (an older gsz's) is stale after this long.
_STALE_SECONDS = 24 * 3600


def check_input_file(path, error=GszError, max_bytes: int = MAX_INPUT_BYTES) -> int:
    """Size in bytes of the input file ``path``; ``error(message, path)`` unless it is a
    regular file of at most ``max_bytes`` (checked before opening: opening a FIFO blocks)."""
    path = os.fspath(path)
    if path == "":
        raise error("input path is empty")
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise error("file not found", path) from None
    except OSError as e:
        raise error(f"cannot read: {e.strerror or e}", path) from None
    if stat.S_ISDIR(st.st_mode):
        raise error("is a directory, expected a file", path)
    if not stat.S_ISREG(st.st_mode):
        raise error("is not a regular file (a device, pipe or socket); gsz reads files of known "
                    "size only", path)
    if st.st_size > max_bytes:
        raise error(f"is {st.st_size:,} bytes, more than the {max_bytes:,} bytes gsz reads", path)
    return st.st_size


def read_all(path, error) -> bytes:
    """The whole of the input file ``path`` (a regular file of bounded size, checked before it
    is opened); ``error(message, path)`` when it cannot be read."""
    path = os.fspath(path)
    check_input_file(path, error)
    try:
        with open(path, "rb") as f:
            return f.read()
    except OSError as e:
        raise error(f"cannot read: {e.strerror or e}", path) from None


def same_file(a, b) -> bool:
    """True when paths ``a`` and ``b`` name one file (hard links and symlinks included)."""
    try:
        return os.path.samefile(a, b)
    except OSError:            # one of them does not exist (yet): compare resolved paths
        return os.path.realpath(a) == os.path.realpath(b)


def _is_stream(path: str) -> bool:
    """True for an existing character device or FIFO (``/dev/null``, ``/dev/stdout``, a named
    pipe): replacing such a file by a regular one (as root) would break the system."""
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return False
    return stat.S_ISCHR(mode) or stat.S_ISFIFO(mode)


def _refuse_special(path: str) -> None:
    """GszOutputError when ``path`` is a block device or socket (never an output)."""
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return
    if stat.S_ISBLK(mode) or stat.S_ISSOCK(mode):
        kind = "block device" if stat.S_ISBLK(mode) else "socket"
        raise GszOutputError(f"is a {kind}; refusing to write there", path)


def _write_stream(path: str, data: bytes) -> None:
    """Write ``data`` into a character device or FIFO in place (no temporary file, no fsync:
    devices need neither and some refuse fsync)."""
    try:
        with open(path, "wb") as f:
            f.write(data)
    except OSError as e:
        raise GszOutputError(f"cannot write: {_reason(e)}", path) from None


def _nearest_existing(folder: str) -> str:
    while not os.path.exists(folder) and os.path.dirname(folder) != folder:
        folder = os.path.dirname(folder)
    return folder


#: What the tools say when an output exists and -w/--overwrite was not given.
EXISTS_MESSAGE = "exists; refusing to overwrite it (-w/--overwrite replaces it)"


def check_output_path(path, inputs=(), *, overwrite: bool = True) -> str:
    """Check, before any long work, that ``path`` can be written as an output file and is none
    of ``inputs`` (never, whatever ``overwrite`` says); with ``overwrite=False`` an existing
    file is refused too (the command-line tools without ``-w``; a device or pipe is not a file
    to keep).  Returns the path.  Raises :class:`GszOutputError` naming ``path``."""
    if path is None or os.fspath(path) == "":
        raise GszOutputError("output path is empty")
    path = os.fspath(path)
    for src in inputs:
        if src is not None and os.fspath(src) != "" and same_file(src, path):
            raise GszOutputError(f"is the input file {os.fspath(src)}; refusing to overwrite the input "
                                 "(choose another output path)", path)
    if os.path.isdir(path):
        raise GszOutputError("is a directory; give an output file name", path)
    if path.endswith(os.sep) or (os.altsep and path.endswith(os.altsep)):
        raise GszOutputError("ends with a path separator; give an output file name", path)
    if _is_stream(path):                    # -o /dev/null, a FIFO: written straight through
        return path
    if not overwrite and os.path.lexists(path):
        raise GszOutputError(EXISTS_MESSAGE, path)
    _refuse_special(path)
    folder = os.path.dirname(os.path.abspath(path))
    base = _nearest_existing(folder)
    if not os.path.isdir(base):
        raise GszOutputError(f"cannot write: {base} is a file, not a folder", path)
    if base != folder:                       # atomic_write creates the missing folders
        if not os.access(base, os.W_OK | os.X_OK):
            raise GszOutputError(f"cannot write: folder {base} is not writable", path)
        return path
    try:                                     # the real test (os.access is blind to read-only mounts)
        fd, probe = tempfile.mkstemp(prefix=f"{_TMP_PREFIX}{os.getpid()}-", suffix="-probe", dir=folder)
        os.close(fd)
        os.unlink(probe)
    except OSError as e:
        raise GszOutputError(f"cannot write in {folder}: {e.strerror or e}", path) from None
    return path


def _remove_stale_temps(folder: str, name: str) -> None:
    """Delete temporary files for ``name`` left in ``folder`` by a killed writer (its pid is
    gone, or an old-style name past a day); a live writer's are left alone."""
    pat = re.compile(re.escape(_TMP_PREFIX) + r"(?:(\d+)-)?[A-Za-z0-9_]{8}-?" + re.escape(name) + "$")
    try:
        entries = os.listdir(folder)
    except OSError:
        return
    for entry in entries:
        m = pat.match(entry)
        if not m:
            continue
        full = os.path.join(folder, entry)
        try:
            if m.group(1) is not None:
                pid = int(m.group(1))
                if pid == os.getpid():
                    continue
                try:
                    os.kill(pid, 0)
                    continue                  # its writer still runs
                except ProcessLookupError:
                    pass
                except PermissionError:
                    continue                  # a live process of another user
            elif time.time() - os.lstat(full).st_mtime < _STALE_SECONDS:
                continue
            os.unlink(full)
        except OSError:
            pass


def atomic_write(path, data: bytes) -> None:
    """Write ``data`` to ``path`` via a temporary file in the same folder and ``os.replace``.

    A crash or error half-way leaves either the old file or none, never a partial one; stale
    temporary files of a killed earlier write are removed.  A character device or FIFO
    (``/dev/null``, a named pipe) is written in place instead of being replaced.  Failures raise
    :class:`GszOutputError` naming ``path`` (never the temporary file).
    """
    if path is None or os.fspath(path) == "":
        raise GszOutputError("output path is empty")
    path = os.fspath(path)
    if _is_stream(path):
        return _write_stream(path, data)
    folder = os.path.dirname(os.path.abspath(path))
    name = os.path.basename(path)
    _refuse_special(path)
    if not name or os.path.isdir(path):
        raise GszOutputError("is a directory; give an output file name", path)
    try:
        os.makedirs(folder, exist_ok=True)
    except (FileExistsError, NotADirectoryError):        # a file where a folder should be
        raise GszOutputError(f"cannot write: {_nearest_existing(folder)} is a file, not a folder", path) from None
    except OSError as e:
        raise GszOutputError(f"cannot create folder {folder}: {e.strerror or e}", path) from None
    _remove_stale_temps(folder, name)
    try:
        fd, tmp = tempfile.mkstemp(prefix=f"{_TMP_PREFIX}{os.getpid()}-", suffix="-" + name, dir=folder)
    except OSError as e:
        raise GszOutputError(f"cannot write in {folder}: {e.strerror or e}", path) from None
    try:
        # mkstemp creates 0600; give the file the mode a plain open() would (0666 & ~umask)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException as e:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        if isinstance(e, OSError) and not isinstance(e, GszError):
            raise GszOutputError(f"cannot write: {_reason(e)}", path) from None
        raise


def _reason(e: OSError) -> str:
    """The OS's words for ``e`` without the temporary file's name."""
    if e.errno == errno.EISDIR:
        return "is a directory"
    return e.strerror or str(e)


@contextlib.contextmanager
def sigterm_as_interrupt():
    """Within the block SIGTERM raises KeyboardInterrupt in the main thread, so a killed CLI
    still removes its temporary output file and exits with one line (no-op off the main thread)."""
    import signal
    import threading
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum, frame):
        raise KeyboardInterrupt
    old = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, old)
