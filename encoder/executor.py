"""Where the per-tile work of an encode runs: here, in local worker processes, or on Ray.

    ex = make_executor("local")          # or "inline", "ray", "ray://head:10001"
    results = ex.map(code_part, jobs)    # in order, whatever ran where

An executor only decides *where* a pure function runs: every job carries all its inputs and
the results come back in job order, so the file is byte-identical whichever executor and
however many workers (tests/test_executor.py).  Ray is an optional extra (``gsz[cluster]``).
"""
from __future__ import annotations

from ..decoder.errors import GszError
from ..decoder.threads import cores, thread_map

#: what ``--executor`` accepts besides ``ray://HOST:PORT``
EXECUTORS = ("local", "inline", "ray")


class ExecutorError(GszError, ValueError):
    """An executor cannot be used (unknown name, Ray missing or unreachable)."""


#: Parts of a stage of at most this many Gaussians in all are coded side by side on threads
#: where the work runs in this process: what they hold at once is then bounded like one full
#: tile's (two tiles' worth), while larger stages code one part at a time.
SIDE_BY_SIDE_MAX_GAUSSIANS = 1 << 21


def in_order(ex, fn, jobs, gaussians: int | None = None):
    """Iterator over fn(job) for the iterable ``jobs``, in order.  Where the work runs in this
    process (no executor, or one that would run it inline) each job is made only when its turn
    comes and its result can go before the next is made (a part's inputs and outputs are
    hundreds of MB at 1.2 M Gaussians) -- unless the jobs' ``gaussians`` in all are at most
    SIDE_BY_SIDE_MAX_GAUSSIANS: then they run side by side on threads (``thread_map``: the same
    results); else ``ex.map`` of all of them."""
    if ex is None or ex.runs_inline:
        if gaussians is not None and gaussians <= SIDE_BY_SIDE_MAX_GAUSSIANS:
            jobs = list(jobs)
            return iter(thread_map(lambda i: fn(jobs[i]), len(jobs)))
        return map(fn, jobs)
    return iter(ex.map(fn, list(jobs)))


class InlineExecutor:
    """Runs every job in the calling process, one after the other."""
    name = "inline"
    workers = 1
    runs_inline = True

    def map(self, fn, jobs: list) -> list:
        return [fn(j) for j in jobs]

    def close(self) -> None:
        pass


class LocalExecutor:
    """Worker processes on this machine, started on first use.  ``spawn``ed: a forked child
    inherits the parent's locks (torch's and the decoder's thread pools) and can hang on them.
    A script that calls the encoder without an ``if __name__ == "__main__"`` guard cannot start
    spawned workers (Python re-runs it in each); then the work runs here, with a warning."""
    name = "local"

    def __init__(self, workers: int | None = None):
        # one core stays with the calling process (it renders and solves between the maps): on
        # 2 cores the workers' pickling and start-up cost more than they save (a 106k-Gaussian
        # search: 0.9 s per map against 0.15 s inline), so there it runs inline
        self.workers = max(1, int(workers or cores() - 1))
        self._pool = None
        self._broken = False

    @property
    def runs_inline(self) -> bool:
        return self.workers == 1 or self._broken

    def map(self, fn, jobs: list) -> list:
        if len(jobs) <= 1 or self.workers == 1 or self._broken:
            return [fn(j) for j in jobs]
        from concurrent.futures.process import BrokenProcessPool
        if self._pool is None:
            import multiprocessing
            from concurrent.futures import ProcessPoolExecutor
            self._pool = ProcessPoolExecutor(max_workers=self.workers,
                                             mp_context=multiprocessing.get_context("spawn"))
        try:
            return list(self._pool.map(fn, jobs))
        except BrokenProcessPool:
            import warnings
            self.close()
            self._broken = True
            warnings.warn("gsz: worker processes could not start (a calling script without an "
                          "'if __name__ == \"__main__\"' guard?); encoding in this process",
                          RuntimeWarning, stacklevel=2)
            return [fn(j) for j in jobs]

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(cancel_futures=True)
            self._pool = None


class RayExecutor:
    """Jobs as Ray tasks: a local Ray started on demand (``address`` None) or an existing
    cluster (``ray://HOST:PORT``); every node needs gsz installed (the tasks import it)."""

    def __init__(self, address: str | None = None, workers: int | None = None):
        try:
            import ray
        except ImportError:
            raise ExecutorError("--executor ray needs Ray: pip install 'gsz[cluster]' "
                                "(or pip install ray)") from None
        self._ray = ray
        self.name = address or "ray"
        self.address = address
        self._workers = workers
        self._remote = {}

    runs_inline = False

    def _start(self) -> None:
        """Start or join Ray on first use (a scene of one tile never needs it)."""
        ray = self._ray
        if not ray.is_initialized():
            kw = dict(include_dashboard=False, log_to_driver=False, ignore_reinit_error=True)
            try:
                if self.address is None:
                    ray.init(num_cpus=int(self._workers or cores()), **kw)
                else:
                    ray.init(address=self.address, **kw)
            except Exception as e:  # noqa: BLE001 - Ray raises many types for an unreachable cluster
                raise ExecutorError(f"cannot start or reach Ray at {self.address or 'a local instance'}: "
                                    f"{type(e).__name__}: {e}") from None

    @property
    def workers(self) -> int:
        self._start()
        return int(self._ray.cluster_resources().get("CPU", 1))

    def map(self, fn, jobs: list) -> list:
        self._start()
        remote = self._remote.get(fn)
        if remote is None:
            remote = self._remote[fn] = self._ray.remote(fn)
        return self._ray.get([remote.remote(j) for j in jobs])

    def close(self) -> None:
        pass        # a Ray started here ends with the process; a cluster is not ours to stop


def check_executor(spec, workers, bad) -> None:
    """``bad(message)`` for an executor name make_executor would refuse, or workers < 1 (before
    any work: Ray itself is only imported when used)."""
    if not (spec in EXECUTORS or (isinstance(spec, str) and spec.startswith("ray://"))):
        bad(f"--executor must be local, inline, ray or ray://HOST:PORT, got {spec!r}")
    if workers is not None and int(workers) < 1:
        bad(f"--workers must be >= 1, got {workers}")
    if spec == "ray" or str(spec).startswith("ray://"):
        try:
            import ray  # noqa: F401
        except ImportError:
            bad("--executor ray needs Ray: pip install 'gsz[cluster]' (or pip install ray)")


def make_executor(spec: str | None = None, workers: int | None = None):
    """The executor named by ``spec`` (see EXECUTORS; None: local worker processes)."""
    spec = (spec or "local").strip()
    if spec == "local":
        return LocalExecutor(workers)
    if spec == "inline":
        return InlineExecutor()
    if spec == "ray":
        return RayExecutor(None, workers)
    if spec.startswith("ray://"):
        return RayExecutor(spec, workers)
    raise ExecutorError(f"unknown executor {spec!r}: use local, inline, ray or ray://HOST:PORT")
