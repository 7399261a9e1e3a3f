"""Simulated network streaming of a .gsz into the viewer: the progressive build-up a web app sees.

``StreamPlayback(data, rate)`` feeds the file to :class:`gsz.decoder.StreamDecoder` on a worker
thread in pieces, pacing them to ``rate`` bytes per second (None: as fast as decoding goes),
and keeps the newest cumulative cloud; the app polls :meth:`snapshot` once per frame and swaps
the scene's splats when a new layer has arrived.  Decoding happens on the worker thread, so the
window stays responsive; GL uploads happen on the GL thread (the app's ``step``).
"""
from __future__ import annotations

import threading
import time

from ..decoder.errors import GszError

PIECE = 16384          # bytes per simulated network read


def parse_rate(text: str) -> float:
    """'2MB/s', '500kB', '1.5MiB/s' -> bytes per second (> 0)."""
    from ..decoder.sizes import parse_size
    t = str(text).strip()
    if t.lower().endswith("/s"):
        t = t[:-2]
    try:
        rate = float(parse_size(t))
    except GszError as e:
        raise GszError(f"network rate {text!r}: {e}") from None
    if not rate > 0:
        raise GszError(f"network rate {text!r} must be > 0")
    return rate


class StreamPlayback:
    """Replay ``data`` (a .gsz file's bytes) through the streaming decoder at ``rate`` B/s."""

    def __init__(self, data: bytes, rate: float | None, *, piece: int = PIECE, start: bool = True,
                 max_gaussians: int | None = None):
        self.data = bytes(data)
        self.max_gaussians = max_gaussians
        self.rate = None if rate is None else float(rate)
        self.piece = int(piece)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._state = {"bytes": 0, "total": len(self.data), "layers": 0, "layers_total": None,
                       "tiles": 0, "tiles_total": None,
                       "cloud": None, "version": 0, "done": False, "error": None,
                       "layer_bytes": []}
        self._thread = threading.Thread(target=self._run, name="gsz-view-stream", daemon=True)
        if start:
            self._thread.start()

    def start(self):
        self._thread.start()

    def stop(self, timeout: float = 5.0):
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout)

    def snapshot(self) -> dict:
        """{"bytes", "total", "layers", "layers_total", "tiles" (parts decoded: layers of tiles),
        "tiles_total", "cloud" (newest cumulative cloud or None), "version" (+1 per new cloud),
        "done", "error", "layer_bytes" (bytes received when each layer completed)}"""
        with self._lock:
            return dict(self._state, layer_bytes=list(self._state["layer_bytes"]))

    def wait(self, layers: int | None = None, timeout: float = 60.0) -> bool:
        """Block until ``layers`` layers (default: the whole file) are in, or timeout."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            s = self.snapshot()
            if s["done"] or s["error"] or (layers is not None and s["layers"] >= layers):
                return True
            time.sleep(0.01)
        return False

    def _run(self):
        from ..decoder.stream import StreamDecoder
        dec = StreamDecoder(max_gaussians=self.max_gaussians)
        t0 = time.monotonic()
        try:
            for start in range(0, len(self.data), self.piece):
                if self._stop.is_set():
                    return
                end = min(start + self.piece, len(self.data))
                if self.rate is not None:          # the network delivers `end` bytes at t0 + end/rate
                    delay = t0 + end / self.rate - time.monotonic()
                    if delay > 0 and self._stop.wait(delay):
                        return
                updates = dec.feed(self.data[start:end])
                with self._lock:
                    self._state["bytes"] = end
                    self._state["layers_total"] = dec.layers_total
                    self._state["tiles_total"] = dec.tiles_total
                    if updates:      # tiles show as they decode; one cumulative cloud per feed
                        u = updates[-1]
                        self._state.update(cloud=u.cloud, layers=dec.layers_decoded,
                                           tiles=self._state["tiles"] + len(updates),
                                           version=self._state["version"] + 1)
                    for u in updates:
                        if u.layer_complete:
                            self._state["layer_bytes"].append(end)
            dec.finish(warn=False)
        except GszError as e:
            with self._lock:
                self._state["error"] = str(e)
        finally:
            with self._lock:
                self._state["done"] = True
