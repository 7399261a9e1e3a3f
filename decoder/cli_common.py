"""What every gsz command-line tool shares: exit codes, the error line, ``-q``/``-v``, ``-w``,
``-o -`` and the help layout (numpy-free; importing this module imports nothing heavy).

Exit codes (the same for gsz-encode, gsz-decode, gsz-info, gsz-eval and gsz-view):

    0    success
    1    the work failed: unreadable or invalid input, an unreachable size, an output that exists
         (without -w) or cannot be written, a missing optional extra, no display or OpenGL
    2    usage: an unknown option, a bad option value or combination (argparse's code too)
    130  interrupted (Ctrl-C or SIGTERM); no output file is left behind

Every failure is one line on stderr, ``gsz-xxx: error: <file>: <problem>``; warnings are
``gsz-xxx: warning: ...``.  Only the data a tool was asked for goes to stdout (``--json``, the
output of ``-o -``, gsz-info's table); logs and progress go to stderr.
"""
from __future__ import annotations

import argparse
import os
import sys

from .errors import GszError, GszOutputError, GszUsageError

EXIT_OK = 0
EXIT_ERROR = 1
EXIT_USAGE = 2
EXIT_INTERRUPTED = 130

#: ``-o -``: write the output file to stdout
STDOUT = "-"

#: verbosity levels of ``-q`` / default / ``-v``
QUIET, NORMAL, VERBOSE = 0, 1, 2

#: optional dependency (top-level import name) -> the extra that installs it
EXTRA_OF = {"torch": "encoder", "pulp": "encoder", "PIL": "encoder", "tqdm": "encoder",
            "moderngl": "viewer", "glfw": "viewer", "imgui_bundle": "viewer",
            "matplotlib": "plots", "pygltflib": "gltf", "ray": "cluster"}
#: what the import name is called on PyPI, where it differs
_DIST = {"PIL": "Pillow", "imgui_bundle": "imgui-bundle"}


def exit_code(e: BaseException) -> int:
    """EXIT_USAGE for a bad option (:class:`GszUsageError`), EXIT_ERROR for anything else."""
    return EXIT_USAGE if isinstance(e, GszUsageError) else EXIT_ERROR


def fail(prog: str, e, code: int | None = None) -> int:
    """Print ``prog: error: e`` on stderr; returns the exit code (``code``, or the error's)."""
    print(f"{prog}: error: {e}", file=sys.stderr, flush=True)
    return exit_code(e) if code is None else code


def warn(prog: str, message, verbosity: int = NORMAL) -> None:
    """``prog: warning: message`` on stderr, unless quiet."""
    if verbosity > QUIET:
        print(f"{prog}: warning: {message}", file=sys.stderr, flush=True)


def missing_extra(e: ImportError, what: str) -> GszError | None:
    """A one-line error for ``e`` when it is an optional dependency gsz names in its extras (the
    package and the ``pip install "gsz[extra]"`` that brings it), else None."""
    name = (getattr(e, "name", None) or "").split(".")[0]
    extra = EXTRA_OF.get(name)
    if extra is None:
        return None
    return GszError(f"{what} needs {_DIST.get(name, name)}, which is not installed: "
                    f'pip install "gsz[{extra}]"')


def run_guarded(prog: str, fn, interrupted: str = "interrupted"):
    """(None, fn()) or, when it fails, (exit code, None) after one error line: a GszError, a
    missing optional dependency (the extra to install), Ctrl-C.  Other errors propagate."""
    try:
        return None, fn()
    except GszError as e:
        return fail(prog, e), None
    except ImportError as e:                  # a core-only install: name the extra, no traceback
        err = missing_extra(e, prog)
        if err is None:
            raise
        return fail(prog, err), None
    except KeyboardInterrupt:
        print(f"{prog}: {interrupted}", file=sys.stderr)
        return EXIT_INTERRUPTED, None


class HelpFormatter(argparse.HelpFormatter):
    """argparse's help with " (default: X)" added only where the help text does not say its
    default itself and there is one worth saying (not None, not a flag's: -q, --json)."""

    def _get_help_string(self, action):
        text = action.help or ""
        if ("default" in text or action.default in (None, False, argparse.SUPPRESS) or action.nargs == 0
                or action.option_strings == [] or "%(default)" in text):
            return text
        return text + " (default: %(default)s)"


def add_version_flag(parser: argparse.ArgumentParser) -> None:
    """``--version``: "PROG VERSION" (every gsz tool)."""
    from .. import __version__
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")


def add_verbosity(parser, *, quiet_help: str = "errors only", verbose_help: str = "more detail") -> None:
    """``-q``/``--quiet`` and ``-v``/``--verbose`` into ``verbosity`` (QUIET, NORMAL, VERBOSE)."""
    g = parser.add_mutually_exclusive_group()
    g.add_argument("-q", "--quiet", dest="verbosity", action="store_const", const=QUIET,
                   default=NORMAL, help=quiet_help)
    g.add_argument("-v", "--verbose", dest="verbosity", action="store_const", const=VERBOSE,
                   help=verbose_help)


def add_overwrite(parser) -> None:
    """``-w``/``--overwrite``: replace existing output files (never an input file)."""
    parser.add_argument("-w", "--overwrite", action="store_true",
                        help="replace output files that exist (an input file is never replaced)")


def check_output(path, inputs=(), *, overwrite: bool, stdout: bool = False) -> str:
    """The output checks of a tool before its work: ``-`` (when the tool writes to stdout)
    must not be a terminal; a file must be writable, none of ``inputs``, and new unless
    ``overwrite``.  Raises GszOutputError / GszUsageError naming the path."""
    from .io_util import check_output_path
    if path == STDOUT:
        if not stdout:
            raise GszUsageError("-o -: this output cannot go to stdout")
        if sys.stdout.isatty():
            raise GszUsageError("-o -: stdout is a terminal; redirect it to a file or a pipe")
        return path
    return check_output_path(path, inputs=inputs, overwrite=overwrite)


def write_output(path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically, or to stdout (binary, nothing else) for ``-``."""
    from .io_util import atomic_write
    if path != STDOUT:
        atomic_write(path, data)
        return
    try:
        out = sys.stdout.buffer
        out.write(data)
        out.flush()
    except BrokenPipeError:
        # the reader went away: the output is incomplete; keep the interpreter's final flush quiet
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        raise GszOutputError("the reader closed stdout before the output was written", "-") from None


def parse_background(text: str) -> tuple:
    """``--background R,G,B`` (each in [0, 1]) as a float tuple; GszUsageError otherwise."""
    import math
    try:
        vals = [float(v) for v in text.split(",")]
    except ValueError:
        vals = []
    if len(vals) != 3 or not all(math.isfinite(v) and 0.0 <= v <= 1.0 for v in vals):
        raise GszUsageError(f"--background must be three numbers in [0,1] like 0,0,0 or 1,1,1, got {text!r}")
    return tuple(vals)
