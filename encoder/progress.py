"""Stage-by-stage progress on stderr: stage names, elapsed seconds, and bars for long loops."""
from __future__ import annotations

import sys
import threading
import time
from contextlib import contextmanager


def memory_mb() -> tuple[float, float]:
    """(resident, peak resident) MB of this process: /proc/self/status where it exists (the
    peak is VmHWM), else getrusage's peak for both; (0, 0) where neither is available."""
    try:
        with open("/proc/self/status") as f:
            fields = dict(line.split(":", 1) for line in f if line.startswith(("VmRSS", "VmHWM")))
        return int(fields["VmRSS"].split()[0]) / 1024, int(fields["VmHWM"].split()[0]) / 1024
    except (OSError, KeyError, ValueError):
        try:
            import resource
            peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
            peak /= 1024 * 1024 if sys.platform == "darwin" else 1024     # bytes there, kB here
            return peak, peak
        except (ImportError, OSError):
            return 0.0, 0.0


class Progress:
    """Prints ``[gsz] stage ...`` lines and tqdm bars to stderr; ``quiet=True`` prints nothing.

    Records either way, per stage name: the seconds (``self.seconds``) and what the stage did to
    the process's peak resident memory (``self.memory``: ``peak_mb`` the peak at its last end,
    ``rise_mb`` how far the peak rose while it ran -- summed over its runs; stages on worker
    threads share the process, so a rise is the process's while that stage ran).
    """

    def __init__(self, quiet: bool = False, stream=None):
        self.quiet = quiet
        self.stream = stream or sys.stderr
        self.seconds: dict[str, float] = {}
        self.memory: dict[str, dict] = {}
        self._lock = threading.Lock()      # stages also run on worker threads (size search)

    def log(self, msg: str) -> None:
        if not self.quiet:
            print(f"[gsz] {msg}", file=self.stream, flush=True)

    @contextmanager
    def stage(self, name: str, detail: str = ""):
        self.log(f"{name}{' - ' + detail if detail else ''} ...")
        t0 = time.perf_counter()
        peak0 = memory_mb()[1]
        yield
        dt = time.perf_counter() - t0
        rss, peak = memory_mb()
        with self._lock:
            self.seconds[name] = self.seconds.get(name, 0.0) + dt
            m = self.memory.setdefault(name, {"peak_mb": 0.0, "rise_mb": 0.0})
            m["peak_mb"] = round(peak, 1)
            m["rise_mb"] = round(m["rise_mb"] + peak - peak0, 1)
        self.log(f"{name} done in {dt:.2f} s (resident {rss:,.0f} MB, peak {peak:,.0f} MB)")

    def memory_report(self) -> dict:
        """{"peak_rss_mb": process peak so far, "stages": {name: {"peak_mb", "rise_mb"}}}."""
        with self._lock:
            stages = {k: dict(v) for k, v in self.memory.items()}
        return {"peak_rss_mb": round(memory_mb()[1], 1), "stages": stages}

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
