"""Switch between the NumPy reference decoder and the optional C accelerator ``_native``.

The NumPy modules (``octree``, ``rans``, ``raht``) are the normative reference; the C module
(``decoder/csrc/``, compiled by ``pip install`` when a C compiler exists) implements the same
integer arithmetic and gives bit-identical output, about 10x faster.  It is used when

* it was built and imports (a stale build with another ABI number is ignored), and
* the environment variable ``GSZ_NATIVE`` is not ``0`` when gsz is imported, and
* :func:`set_enabled` has not switched it off (tests compare both paths in one process), and
* the calling thread is not inside :func:`numpy_only`.

The choice is made once per decode: :func:`pinned` (entered by ``decode``, ``StreamDecoder.feed``
and the stream helpers) fixes it for the calling thread, and :func:`carry` hands it to the
decoder's worker threads, so a ``set_enabled`` or ``numpy_only`` in another thread never switches
paths in the middle of a decode (which mixed the two paths' objects: issue 19).

Nothing here changes the bitstream: both paths read and write identical bytes.
"""
from __future__ import annotations

import contextlib
import os
import threading

import numpy as np

#: ABI number the Python side expects (GSZ_NATIVE_ABI in csrc/gsz_common.h).
ABI = 20

_module = None
_why_not = ""
if os.environ.get("GSZ_NATIVE", "1").strip() == "0":
    _why_not = "disabled by GSZ_NATIVE=0"
else:
    try:
        from . import _native as _candidate
    except ImportError as exc:
        import importlib.util
        try:
            found = importlib.util.find_spec(__name__.rsplit(".", 1)[0] + "._native") is not None
        except (ImportError, ValueError):
            found = False
        # not compiled (no C compiler at install time), or present but unloadable
        _why_not = (f"extension failed to load ({exc})" if found
                    else "extension not built (no C compiler when gsz was installed?)")
    else:
        if getattr(_candidate, "ABI", None) == ABI:
            _module = _candidate
        else:
            _why_not = f"stale extension build (ABI {getattr(_candidate, 'ABI', None)}, want {ABI})"

_enabled = _module is not None
#: per-thread override of _enabled (``path``: None, or the bool in force for this thread)
_local = threading.local()


def native_available() -> bool:
    """True when the C accelerator is built, importable and not disabled by ``GSZ_NATIVE=0``."""
    return _module is not None


def enabled() -> bool:
    """True when decoding (and octree encoding) on this thread currently use the C accelerator."""
    own = getattr(_local, "path", None)
    return _enabled if own is None else own


def active_path() -> str:
    """``"native"`` or ``"numpy"``: which implementation decoding on this thread uses now."""
    return "native" if enabled() else "numpy"


def unavailable_reason() -> str:
    """Why the accelerator is not available ('' when it is)."""
    return _why_not


def set_enabled(flag: bool) -> bool:
    """Use the accelerator (if available) or force the NumPy reference, process-wide (threads
    inside :func:`numpy_only` or a pinned decode keep theirs); returns the old setting."""
    global _enabled
    old = _enabled
    _enabled = bool(flag) and _module is not None
    return old


@contextlib.contextmanager
def _thread_path(flag: bool | None):
    """This thread's override set to ``flag`` inside the block (None: no override)."""
    old = getattr(_local, "path", None)
    _local.path = flag
    try:
        yield
    finally:
        _local.path = old


def numpy_only():
    """Context manager: the NumPy reference path inside the block, on the calling thread only
    (other threads' decodes keep their path)."""
    return _thread_path(False)


def pinned():
    """Context manager: the path in force now stays in force on this thread for the block
    (a decode's entry point; nested pins keep the outer one)."""
    own = getattr(_local, "path", None)
    return _thread_path(_enabled if own is None else own)


def carry(fn):
    """``fn`` wrapped to run with the calling thread's current path on whatever thread calls
    it (the decoder's worker threads follow the decode that submitted the work)."""
    flag = enabled()

    def run(*args, **kwargs):
        with _thread_path(flag):
            return fn(*args, **kwargs)
    return run


def module():
    """The C module (only call when :func:`enabled`)."""
    return _module


