"""Stage-by-stage progress on stderr: stage names, elapsed seconds, and bars for long loops."""
from __future__ import annotations

import sys
import threading
import time
from contextlib import contextmanager


class Progress:
    """Prints ``[gsz] stage ...`` lines and tqdm bars to stderr; ``quiet=True`` prints nothing.

    Records the seconds of every stage in ``self.seconds`` (stage name -> seconds) either way.
    """

    def __init__(self, quiet: bool = False, stream=None):
        self.quiet = quiet
        self.stream = stream or sys.stderr
        self.seconds: dict[str, float] = {}
        self._lock = threading.Lock()      # stages also run on worker threads (size search)

    def log(self, msg: str) -> None:
        if not self.quiet:
            print(f"[gsz] {msg}", file=self.stream, flush=True)

    @contextmanager
    def stage(self, name: str, detail: str = ""):
        self.log(f"{name}{' - ' + detail if detail else ''} ...")
        t0 = time.perf_counter()
        yield
        dt = time.perf_counter() - t0
        with self._lock:
            self.seconds[name] = self.seconds.get(name, 0.0) + dt
        self.log(f"{name} done in {dt:.2f} s")

    def bar(self, total: int, desc: str):
        """A callback ``(done, total)`` driving a tqdm bar (a no-op when quiet)."""
        if self.quiet:
            return lambda *a, **k: None
        from tqdm import tqdm
        pbar = tqdm(total=total, desc=f"[gsz] {desc}", file=self.stream, leave=False,
                    dynamic_ncols=True, mininterval=0.5)
        state = {"n": 0}

        def update(done, total_=None, *_):
            # accepts (done, total) or (stage, done, total)
            if isinstance(done, str):
                done = total_
            done = int(done)
            if done > state["n"]:
                pbar.update(done - state["n"])
                state["n"] = done
            if done >= total:
                pbar.close()
        return update
