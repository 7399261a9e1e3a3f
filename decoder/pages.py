"""Small pages for NumPy's large arrays while gsz decodes or searches.

NumPy asks the kernel for transparent huge pages on its large arrays.  With THP defrag
"madvise" (a common Linux default) the first touch of each fresh 2 MB page may compact memory
synchronously: on the 2-core VM the decoder's first run in a process spent 1-2 s of kernel time
on it for a 1 M-Gaussian file (docs/design/memory.md), the search a third of its CPU time.
"""
from __future__ import annotations

import contextlib
import threading

try:        # NumPy's switch is private: without it nothing changes
    from numpy._core.multiarray import _set_madvise_hugepage
except ImportError:         # pragma: no cover - older or future NumPy
    _set_madvise_hugepage = None

_lock = threading.Lock()
_depth = 0          # how many small_pages() blocks are open (threads decode tiles at once)
_saved = None       # NumPy's setting before the outermost block


@contextlib.contextmanager
def small_pages():
    """NumPy allocates without huge-page advice inside the block; the setting the application
    had is restored when the last open block (of any thread) ends."""
    global _depth, _saved
    if _set_madvise_hugepage is None:
        yield
        return
    with _lock:
        if _depth == 0:
            _saved = _set_madvise_hugepage(False)
        _depth += 1
    try:
        yield
    finally:
        with _lock:
            _depth -= 1
            if _depth == 0:
                _set_madvise_hugepage(_saved)


_trim = False       # glibc's malloc_trim once looked up; None where there is none


def trim_heap() -> None:
    """Hand the C heap's free pages back to the system (glibc ``malloc_trim(0)``; nothing
    elsewhere).  Arrays under glibc's mmap threshold -- which rises to 32 MB as large blocks are
    freed, so most of a search's row-chunk temporaries -- come from the heap, and pages freed
    there stay resident: 0.4 GB of a 3 M-Gaussian search's 3.0 GB.  A caller about to make its
    largest arrays (a render of a whole scene) calls this first; it changes no value."""
    global _trim
    if _trim is False:
        try:
            import ctypes
            _trim = ctypes.CDLL(None).malloc_trim
            _trim.argtypes, _trim.restype = [ctypes.c_size_t], ctypes.c_int
        except (OSError, AttributeError):       # not glibc
            _trim = None
    if _trim is not None:
        _trim(0)
