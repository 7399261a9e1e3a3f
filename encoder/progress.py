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
    """Prints ``[gsz] ...`` lines and progress bars to stderr at one of three levels, and
    records the seconds and memory of every stage whatever it prints.

    verbosity  0 (``-q``): nothing.  1 (default): the run's story -- each stage name the first
               time the main thread enters it, and every message logged on the main thread
               outside a stage (the size search's candidates, the result).  2 (``-v``): every
               stage's start and end with its time and memory, on every thread (worker threads'
               lines carry the thread's name), and every message.
    Bars (tqdm) are drawn only when the stream is a terminal, and only for the main thread.
    ``quiet=True`` is verbosity 0 (the API's old switch).

    Records, per stage name: the seconds (``self.seconds``) and what the stage did to the
    process's peak resident memory (``self.memory``: ``peak_mb`` the peak at its last end,
    ``rise_mb`` how far the peak rose while it ran -- summed over its runs; stages on worker
    threads share the process, so a rise is the process's while that stage ran).
    """

    def __init__(self, quiet: bool = False, stream=None, verbosity: int | None = None):
        self.verbosity = (0 if quiet else 1) if verbosity is None else int(verbosity)
        self.quiet = self.verbosity == 0
        self.stream = stream or sys.stderr
        self.seconds: dict[str, float] = {}
        self.memory: dict[str, dict] = {}
        self._lock = threading.Lock()      # stages also run on worker threads (size search)
        self._local = threading.local()    # per thread: how many stages are open
        self._named: set = set()           # stage names already announced at level 1

    def _depth(self) -> int:
        return getattr(self._local, "depth", 0)

    @staticmethod
    def _main() -> bool:
        return threading.current_thread() is threading.main_thread()

    def _print(self, msg: str) -> None:
        who = "" if self._main() else f" {threading.current_thread().name}"
        print(f"[gsz{who}] {msg}", file=self.stream, flush=True)

    def log(self, msg: str, level: int | None = None) -> None:
        """Print ``msg`` at ``level`` (default: 1 on the main thread outside any stage, else 2)."""
        if level is None:
            level = 1 if (self._main() and self._depth() == 0) else 2
        if self.verbosity >= level:
            self._print(msg)

    def _announce(self, name: str) -> bool:
        """Level 1 shows a stage the first time the main thread enters it outside another."""
        if not (self._main() and self._depth() == 0):
            return False
        with self._lock:
            first = name not in self._named
            self._named.add(name)
        return first

    @contextmanager
    def stage(self, name: str, detail: str = ""):
        line = f"{name}{' - ' + detail if detail else ''} ..."
        if self.verbosity >= 2 or (self.verbosity == 1 and self._announce(name)):
            self._print(line)
        t0 = time.perf_counter()
        peak0 = memory_mb()[1]
        self._local.depth = self._depth() + 1
        try:
            yield
        finally:
            self._local.depth -= 1
        dt = time.perf_counter() - t0
        rss, peak = memory_mb()
        with self._lock:
            self.seconds[name] = self.seconds.get(name, 0.0) + dt
            m = self.memory.setdefault(name, {"peak_mb": 0.0, "rise_mb": 0.0})
            m["peak_mb"] = round(peak, 1)
            m["rise_mb"] = round(m["rise_mb"] + peak - peak0, 1)
        self.log(f"{name} done in {dt:.2f} s (resident {rss:,.0f} MB, peak {peak:,.0f} MB)", level=2)

    def memory_report(self) -> dict:
        """{"peak_rss_mb": process peak so far, "stages": {name: {"peak_mb", "rise_mb"}}}."""
        with self._lock:
            stages = {k: dict(v) for k, v in self.memory.items()}
        return {"peak_rss_mb": round(memory_mb()[1], 1), "stages": stages}

    def bars(self) -> bool:
        """Whether :meth:`bar` draws: not quiet, on the main thread, into a terminal."""
        try:
            tty = self.stream.isatty()
        except (AttributeError, ValueError):
            tty = False
        return self.verbosity >= 1 and tty and self._main()

    def bar(self, total: int, desc: str):
        """A callback ``(done, total)`` driving a tqdm bar (a no-op unless :meth:`bars`)."""
        if not self.bars():
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
