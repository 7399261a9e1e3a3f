"""The CPUs this process may use, and a map over them for work that releases the GIL (the C
accelerator's loops, NumPy's sorts): one place for both, so encoder and decoder agree."""
from __future__ import annotations

import os
import threading
from concurrent.futures import ThreadPoolExecutor, wait

_pool = None
_pool_lock = threading.Lock()
_inside = threading.local()


def cores() -> int:
    """CPUs this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def _helping(work):
    _inside.active = True
    try:
        work()
    finally:
        _inside.active = False


def thread_map(fn, n: int) -> list:
    """[fn(0), ..., fn(n - 1)], the items taken in turn by the caller and up to ``cores() - 1``
    pool threads; results in order, so callers whose items write disjoint outputs get the same
    result whatever the thread count.  Runs in the caller's thread alone where there is one core
    or one item, and inside a pool thread's item (a fixed pool waiting on itself would
    deadlock; the caller's own items may map again)."""
    global _pool
    if n <= 1 or cores() < 2 or getattr(_inside, "active", False):
        return [fn(i) for i in range(n)]
    with _pool_lock:
        if _pool is None:
            _pool = ThreadPoolExecutor(max_workers=cores(), thread_name_prefix="gsz-map")
    results = [None] * n
    state = {"next": 0, "failed": False}
    lock = threading.Lock()

    def work():
        while True:
            with lock:
                i = state["next"]
                if i >= n or state["failed"]:
                    return
                state["next"] = i + 1
            try:
                results[i] = fn(i)
            except BaseException:
                state["failed"] = True
                raise
    helpers = [_pool.submit(_helping, work) for _ in range(min(cores(), n) - 1)]
    try:
        work()
    finally:
        # a helper not started yet (the pool busy with another map's items) has nothing left to
        # do: it is cancelled, not waited for (wait() would wait until a pool thread dequeues it)
        started = [h for h in helpers if not h.cancel()]
        wait(started)                   # none still writes once this returns or raises
    for h in started:
        h.result()                      # a helper's exception, raised here
    return results


def for_ranges(n: int, step: int, fn) -> None:
    """fn(start, stop) for every ``step``-row range of [0, n), mapped over the cores
    (:func:`thread_map`): for callers whose ranges each write their own rows."""
    starts = range(0, n, step)
    thread_map(lambda i: fn(starts[i], min(starts[i] + step, n)), len(starts))


def spans(n: int, parts: int | None = None) -> list:
    """[(start, stop)]: [0, n) cut into at most ``parts`` (default: :func:`cores`) contiguous
    non-empty spans of nearly equal length."""
    parts = max(1, min(int(parts or cores()), n))
    if n <= 0:
        return []
    step, extra = divmod(n, parts)
    out, a = [], 0
    for i in range(parts):
        b = a + step + (1 if i < extra else 0)
        out.append((a, b))
        a = b
    return out
