"""Back-to-front depth sorting on a worker thread, so the UI never waits for a sort.

How the viewer keeps the order right (the "stale sort" problem of web viewers):

* Every frame the app asks for the order of the camera it is about to draw
  (:meth:`DepthSorter.request` with the camera and a hashable key of its pose).  Requests
  overwrite each other: the worker always sorts the NEWEST pose, never a backlog.
* The frame is drawn with the newest finished order (possibly one sorted for a pose a frame
  or two old while the camera moves -- the same lag Spark and SuperSplat accept).
* :attr:`DepthSorter.is_current` tells whether the finished order belongs to the pose last
  requested.  While it is False the app keeps redrawing; once the camera rests, the worker
  finishes the sort of the resting pose and the next frame is exactly sorted.  So a stale
  order can never survive after the camera stops.  Screenshots wait for it
  (:meth:`DepthSorter.wait_current`).

The sort itself is :func:`gsz.viewer.gl_renderer.depth_order` (numpy stable argsort of
view-space depth, reversed; ~12 ms / 100k, ~0.15 s / 1M splats on one core; numpy releases
the GIL while sorting, so the UI thread keeps running).
"""
from __future__ import annotations

import threading
import time

import numpy as np

from .gl_renderer import depth_order

__all__ = ["DepthSorter", "camera_key"]


def camera_key(camera) -> bytes:
    """Hashable identity of a camera pose (R, t): the sort depends on nothing else."""
    return np.concatenate([camera.R.reshape(-1), camera.t]).astype(np.float64).tobytes()


class DepthSorter:
    """Sorts one cloud's positions for the newest requested camera on a daemon thread.

    positions  [N, 3] float32 (kept by reference; must not change)
    """

    def __init__(self, positions: np.ndarray, *, threaded: bool = True):
        self.positions = positions
        self._cond = threading.Condition()
        self._pending = None          # (key, camera) waiting to be sorted
        self._result = None           # (key, order)
        self._requested_key = None
        self.last_sort_s = 0.0
        self.sorts_done = 0
        self._stop = False
        self._thread = None
        if threaded:
            self._thread = threading.Thread(target=self._run, name="gsz-view-sort", daemon=True)
            self._thread.start()

    # -- API used by the render thread ---------------------------------------------------------
    def request(self, camera) -> None:
        """Ask for the order of ``camera`` (no-op if it is the pose already requested)."""
        key = camera_key(camera)
        with self._cond:
            if key == self._requested_key:
                return
            self._requested_key = key
            if self._thread is None:
                self._pending = None
                self._sort(key, camera)
                return
            self._pending = (key, camera)
            self._cond.notify_all()

    def order(self):
        """The newest finished order ([M] uint32, back to front) or None before the first."""
        with self._cond:
            return None if self._result is None else self._result[1]

    @property
    def is_current(self) -> bool:
        """True when the finished order was sorted for the pose last requested."""
        with self._cond:
            return self._result is not None and self._result[0] == self._requested_key

    def wait_current(self, timeout: float = 30.0) -> bool:
        """Block until :attr:`is_current` (True) or ``timeout`` seconds pass (False)."""
        end = time.monotonic() + timeout
        with self._cond:
            while not (self._result is not None and self._result[0] == self._requested_key):
                left = end - time.monotonic()
                if left <= 0:
                    return False
                self._cond.wait(left)
            return True

    def close(self) -> None:
        with self._cond:
            self._stop = True
            self._cond.notify_all()
        if self._thread is not None:
            self._thread.join(timeout=5.0)

    # -- worker ----------------------------------------------------------------------------------
    def _sort(self, key, camera):
        t0 = time.perf_counter()
        order = depth_order(self.positions, camera)
        dt = time.perf_counter() - t0
        # Called with the condition held in the synchronous case, without it in the thread.
        self._result = (key, order)
        self.last_sort_s = dt
        self.sorts_done += 1

    def _run(self):
        while True:
            with self._cond:
                while self._pending is None and not self._stop:
                    self._cond.wait()
                if self._stop:
                    return
                key, camera = self._pending
                self._pending = None
            t0 = time.perf_counter()
            order = depth_order(self.positions, camera)
            dt = time.perf_counter() - t0
            with self._cond:
                self._result = (key, order)
                self.last_sort_s = dt
                self.sorts_done += 1
                self._cond.notify_all()
