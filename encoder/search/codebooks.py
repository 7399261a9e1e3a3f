"""The SH codebooks of one search, trained on the largest tau's voxels while the main thread does
the rest of the set-up."""
from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from ..pipeline import SourcedRows, default_codebook_size, stage_source, train_sh_codebook
from .options import SearchOptions
from .sh_model import Assigner, ShSource


class Codebooks:
    """Codebooks of several sizes (the default size, 1/4 and 1/16 of it; one when the caller
    fixed the size), each assigned to the largest stage's voxels right after training.

    The largest tau's voxels need no geometry coding, so a worker thread trains the codebooks
    (torch releases the GIL in its maths) largest first while the main thread codes that stage,
    computes its tables and renders the references; once done, the main thread takes the
    smallest codebooks not started yet instead of waiting (flowers: the three codebooks took
    ~18 s on the worker against ~12 s of set-up).  Every codebook is a deterministic function of
    its inputs, so who trains which changes timing only.

        with Codebooks(sopts, kept_top, vox_top, assigner, progress) as cbs:
            ...                                  # the main thread's set-up
            codebooks = cbs.result()
    """

    def __init__(self, sopts: SearchOptions, kept_top, vox_top, assigner: Assigner, progress):
        m1 = len(vox_top.ijk)
        k_max = default_codebook_size(m1, sopts.codebook)
        self.sizes = [k_max] if sopts.codebook is not None else sorted(
            {k_max, max(16, k_max // 4), max(16, k_max // 16)}, reverse=True)
        self.sopts, self.assigner, self.progress, self.m1 = sopts, assigner, progress, m1
        # the largest stage's voxels are the first the SH models need: assign them right after
        # each codebook is trained (Stage.source as prepare_stage will compute it)
        self.source_top = stage_source(kept_top, vox_top) if vox_top.sh is None else vox_top.sh.source
        # their SH as rows of the input's (the grid's own copy, 1 GB at 6 M, goes with the grid)
        self.src = ShSource(sh=SourcedRows.of_grid(assigner.sh, self.source_top, vox_top),
                            importance=vox_top.importance, num_points=m1)
        self._todo = list(range(len(self.sizes)))
        self._lock = threading.Lock()
        self._trained = [None] * len(self.sizes)
        self._pool = self._job = None

    def __enter__(self):
        if self.sopts.overlap:
            self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="gsz-vq")
            self._job = self._pool.submit(self._train_largest_first)
        return self

    def __exit__(self, *exc):
        if self._pool is not None:
            self._pool.shutdown(wait=True)
        return False

    def result(self) -> list:
        """Every codebook, largest first (the calling thread trains those not started yet)."""
        while self._train_next(True):
            pass
        if self._job is not None:
            self._job.result()
        return self._trained

    def _train_next(self, smallest: bool) -> bool:
        with self._lock:
            if not self._todo:
                return False
            i = self._todo.pop() if smallest else self._todo.pop(0)
        with self.progress.stage("vq", f"codebook {self.sizes[i]} on {self.m1} vectors, and its assignment"):
            self._trained[i] = train_sh_codebook(self.src, self.sizes[i], seed=self.sopts.seed,
                                                 iters=self.sopts.vq_iters, progress=self.progress)
            self.assigner.prime(self.source_top, self.src.sh, self._trained[i])
        return True

    def _train_largest_first(self) -> None:
        while self._train_next(False):
            pass
