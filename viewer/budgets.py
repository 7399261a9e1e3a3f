"""Encode the original at several byte budgets on a background thread (``--budgets``).

:class:`BudgetJobs` runs ``encode_to_budget(cloud, target_bytes, progress=..., importance=...)``
(default: :func:`gsz.encoder.search.encode_to_budget`, imported lazily; tests inject their
own) for each budget in turn on one daemon thread, so the viewer's UI thread never blocks.
The train-view importance is computed once and shared by all budgets.  The UI thread polls
:meth:`BudgetJobs.snapshot` for progress text and finished results; GL uploads of finished
clouds happen on the UI thread (the app's job), never here.
"""
from __future__ import annotations

import threading
import time
import traceback
from dataclasses import dataclass, field

from ..decoder.errors import GszError

__all__ = ["BudgetResult", "BudgetJobs", "parse_budgets"]


def parse_budgets(text: str, parse_size=None) -> list:
    """``"2MB,5MB,10MB"`` -> [(label, bytes), ...] in the given order (labels as typed).

    ``parse_size(str) -> int`` defaults to :func:`gsz.decoder.sizes.parse_size`.
    Raises GszError (from the parser) for a bad size, or for an empty list.
    """
    if parse_size is None:
        from ..decoder.sizes import parse_size
    items = [s.strip() for s in str(text).split(",") if s.strip()]
    if not items:
        raise GszError(f"--budgets: expected sizes like 2MB,5MB, got {text!r}")
    out = []
    for s in items:
        try:
            out.append((s, int(parse_size(s))))
        except GszError:
            raise
        except (ValueError, TypeError) as e:
            raise GszError(f"--budgets: cannot read size {s!r}: {e}") from None
    return out


@dataclass
class BudgetResult:
    label: str            # as the user typed it, e.g. "2MB"
    target_bytes: int
    data: bytes = field(repr=False)     # the .gsz file
    cloud: object = field(repr=False)   # decoded GaussianCloud
    report: object = field(default=None, repr=False)   # the encode's EncodeReport (None: none given)
    seconds: float = 0.0


class _ProgressSink:
    """Stands in for :class:`gsz.encoder.progress.Progress` (log / stage / bar / seconds) and
    also accepts being called like a plain callback; it only records the newest message."""

    def __init__(self, jobs: "BudgetJobs", label: str):
        self._jobs, self._label = jobs, label
        self.quiet = True
        self.seconds = {}

    def _set(self, text: str):
        self._jobs._set_status(f"{self._label}: {text}")

    def log(self, msg: str) -> None:
        self._set(str(msg))

    def memory_report(self) -> dict:
        """The process peak only (this sink does not track stages)."""
        from ..encoder.progress import memory_mb
        return {"peak_rss_mb": round(memory_mb()[1], 1), "stages": {}}

    def stage(self, name: str, detail: str = ""):
        from contextlib import contextmanager

        @contextmanager
        def cm():
            self._set(f"{name}{' - ' + detail if detail else ''}")
            t0 = time.perf_counter()
            yield
            self.seconds[name] = self.seconds.get(name, 0.0) + time.perf_counter() - t0
        return cm()

    def bar(self, total: int, desc: str):
        def update(done, total_=None, *_):
            if isinstance(done, str):
                done = total_
            self._set(f"{desc} {int(done)}/{int(total)}")
        return update

    def __call__(self, *args, **kwargs):
        self._set(" ".join(str(a) for a in args))


class BudgetJobs:
    """Background encodes of ``cloud`` at each ``(label, bytes)`` budget, in order.

    encode_fn   ``fn(cloud, target_bytes, *, progress=None, importance=None) -> result`` with
                ``.data`` (bytes), ``.cloud`` (GaussianCloud), ``.report`` (EncodeReport); default
                ``gsz.encoder.search.encode_to_budget``
    importance_fn ``fn(cloud) -> [N] float64`` computed once before the first budget
                (default: the pipeline's train-view importance); None-returning or
                raising falls back to letting ``encode_fn`` compute its own.
    """

    def __init__(self, cloud, budgets, *, encode_fn=None, importance_fn="default", start=True):
        self.cloud = cloud
        self.budgets = list(budgets)
        self._encode_fn = encode_fn
        self._importance_fn = importance_fn
        self._lock = threading.Lock()
        self._status = "waiting"
        self._results: list = []
        self._errors: list = []
        self._done = False
        self._current = None
        self._thread = threading.Thread(target=self._run, name="gsz-view-budgets", daemon=True)
        if start:
            self._thread.start()

    def start(self):
        self._thread.start()

    def _set_status(self, text: str):
        with self._lock:
            self._status = text

    def snapshot(self) -> dict:
        """{"status": str, "results": [BudgetResult...] (finished, in budget order),
        "errors": [(label, message)], "done": bool, "current": label or None}"""
        with self._lock:
            return {"status": self._status, "results": list(self._results),
                    "errors": list(self._errors), "done": self._done, "current": self._current}

    def wait(self, count: int = None, timeout: float = 3600.0) -> bool:
        """Block until ``count`` results (default all) are finished or failed, or timeout."""
        want = len(self.budgets) if count is None else int(count)
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            s = self.snapshot()
            if s["done"] or len(s["results"]) + len(s["errors"]) >= want:
                return True
            time.sleep(0.05)
        return False

    def _resolve(self):
        fn = self._encode_fn
        if fn is None:
            try:
                from ..encoder.search import encode_to_budget as fn
            except ImportError as e:
                raise GszError(f"the size-targeted encoder is unavailable ({e})") from None
        return fn

    def _importance(self):
        f = self._importance_fn
        if f is None:
            return None
        if f == "default":
            from ..encoder.pipeline import EncodeOptions, compute_train_importance
            from ..encoder.progress import Progress
            return compute_train_importance(self.cloud, EncodeOptions(), progress=Progress(quiet=True))
        return f(self.cloud)

    def _run(self):
        try:
            fn = self._resolve()
            self._set_status("computing importance (train views)")
            try:
                importance = self._importance()
            except Exception as e:  # fall back: let the encoder compute its own
                importance = None
                self._set_status(f"importance failed ({e}); encoder computes its own")
        except Exception as e:
            with self._lock:
                self._errors = [(label, str(e)) for label, _ in self.budgets]
                self._status = f"error: {e}"
                self._done = True
            return
        for label, nbytes in self.budgets:
            with self._lock:
                self._current = label
                self._status = f"{label}: encoding"
            t0 = time.perf_counter()
            try:
                kwargs = {"progress": _ProgressSink(self, label)}
                if importance is not None:
                    kwargs["importance"] = importance
                res = fn(self.cloud, nbytes, **kwargs)
                item = BudgetResult(label, nbytes, bytes(res.data), res.cloud,
                                    getattr(res, "report", None),
                                    time.perf_counter() - t0)
                with self._lock:
                    self._results.append(item)
                    self._status = f"{label}: done ({len(item.data):,} B in {item.seconds:.1f} s)"
            except Exception as e:
                msg = str(e) if isinstance(e, GszError) else f"{type(e).__name__}: {e}"
                if not isinstance(e, GszError):
                    traceback.print_exc()
                with self._lock:
                    self._errors.append((label, msg))
                    self._status = f"{label}: failed: {msg}"
        with self._lock:
            self._current = None
            self._done = True
