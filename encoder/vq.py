"""Importance-weighted vector quantisation of the higher-degree SH (MesonGS++ §6, reference
notes §6.1 -- with its weaknesses fixed).

Objective: minimise the weighted distortion ``sum_i w_i ||x_i - c_{a(i)}||^2``.

* Seeding: weighted k-means++ (D^2 sampling with probability proportional to ``w_i * D_i^2``) on a
  random subsample, in rounds of several centres at a time (a k-means||-style batching: one
  GEMM per round instead of one pass per centre), so K = 4096 seeds cost well under a second.
  The reference seeds every entry uniformly in one global scalar range.
* Training: mini-batch k-means (Sculley 2010) with per-codeword learning rate
  ``w_batch_k / W_k`` (W_k = the codeword's accumulated weight), which converges instead of the
  reference's fixed EMA(0.8).  Batches are drawn uniformly (every point can be seen) and the
  updates are weighted by ``w``.
* Dead codewords (no weight after a refresh window) are re-seeded to the batch points with the
  largest weighted error (the reference lets them drift to the zero vector).
* Finish: ``lloyd`` full weighted Lloyd passes over all points (exact centroid updates),
  re-seeding empty clusters from the worst-fit points.
* Distances use one GEMM per chunk: ``||x||^2 - 2 x c^T + ||c||^2`` (only ``||c||^2 - 2 x c^T``
  for the argmin), in chunks of ~8 MB into one preallocated buffer (platform-notes §6: fresh
  tensors of 32 MB+ cost ~30 ms of page faults here), with a two-level argmin (torch's
  min-with-index is slower than the GEMM itself).  One torch thread by default (``threads``).
* Determinism: a seeded numpy Generator drives every random choice; torch runs the maths on
  the CPU with fixed chunking, so the same input and options give a bit-identical codebook on
  the same machine and thread count.
* Fewer distinct vectors than K: the codebook holds every distinct vector (exact), padded with
  copies of the first one to K rows (unused rows; :func:`compact` drops them).
"""
from __future__ import annotations

import contextlib
import math
import threading
from typing import Callable, Iterator

import numpy as np
import torch

from ..decoder.errors import GszError
from ..decoder.threads import for_ranges

#: Defaults chosen by measurement: docs/design/vq.md.
DEFAULT_ITERS = 50
DEFAULT_BATCH = 16384
DEFAULT_LLOYD = 1
#: torch intra-op threads used by the VQ maths (see :func:`_threads`).
DEFAULT_THREADS = 1
#: Subsample size for the seeding (points).
SEED_SAMPLE = 65536
#: Elements per distance chunk (rows * K'): 8 MB, allocated once per search and reused (fresh
#: big tensors cost page faults here, platform-notes §6; small chunks stay cache-resident).
_CHUNK_ELEMS = 1 << 21
#: From this K on, the argmin is done in two levels (see :func:`_nearest`).
_TWO_LEVEL_MIN_K = 256
#: vectors per block of :func:`assign` (about 12 MB of SH-3 vectors)
ASSIGN_BLOCK_ROWS = 65536


class VQError(GszError, ValueError):
    """Bad input to vector quantisation (shapes, non-finite values, invalid K or options)."""


def _check_x(x) -> np.ndarray:
    a = np.asarray(x)
    if a.ndim != 2:
        raise VQError(f"vectors must be a 2-D [N, D] array, got shape {a.shape}")
    a = np.ascontiguousarray(a, dtype=np.float32)
    # row blocks: a whole [N, D] mask was 270 MB at 6 M SH-3 vectors
    if any(not np.isfinite(a[s:s + ASSIGN_BLOCK_ROWS]).all() for s in range(0, a.shape[0], ASSIGN_BLOCK_ROWS)):
        raise VQError("vectors contain non-finite values")
    return a


def _check_weights(weights, n: int) -> np.ndarray:
    w = np.asarray(weights, dtype=np.float64).reshape(-1) if weights is not None else np.ones(n)
    if w.shape != (n,):
        raise VQError(f"weights must have shape ({n},), got {w.shape}")
    if not np.all(np.isfinite(w)) or (w < 0).any():
        raise VQError("weights must be finite and >= 0")
    total = w.sum()
    if total <= 0:
        # Every point invisible: nothing to prefer; fall back to plain (unweighted) k-means.
        return np.ones(n)
    return w / total * n          # mean 1: keeps the float32 maths well scaled


@contextlib.contextmanager
def _threads(n: int | None) -> Iterator[None]:
    """Run the torch maths with ``n`` intra-op threads (None: leave torch's setting).

    Default 1: OpenMP barriers stall when another job holds a core, and a fixed thread count keeps
    the codebook identical from run to run (docs/design/torch-threads.md).  On a dedicated
    multi-core machine pass more.
    """
    if n is None:
        yield
        return
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise VQError(f"threads must be an integer >= 1 or None, got {n!r}")
    old = torch.get_num_threads()
    torch.set_num_threads(int(n))
    try:
        yield
    finally:
        torch.set_num_threads(old)


class _Prepared:
    """A codebook laid out for the chunked search (internal).

    c    [K', D] f32, K' = K rounded up to a multiple of the group width g; pad rows are zero
    c_sq [K'] f32 = ||c||^2, +inf on pad rows (so a pad row can never be nearest)
    g    group width of the two-level argmin (K' = G * g), or 0 for a plain argmin
    """

    def __init__(self, c: torch.Tensor):
        k, dim = c.shape
        # Group width: a multiple of 16 floats keeps the amin vectorised; 64 beat ~sqrt(K)
        # (docs/design/vq.md).
        g = 0 if k < _TWO_LEVEL_MIN_K else (32 if k < 2048 else 64)
        kp = int(math.ceil(k / g)) * g if g else k
        self.k, self.g = k, g
        self.c = torch.zeros((kp, dim), dtype=torch.float32)
        self.c[:k] = c
        self.c_sq = torch.full((kp,), math.inf, dtype=torch.float32)
        self.c_sq[:k] = (c * c).sum(dim=1)
        self.rows = max(64, min(4096, _CHUNK_ELEMS // kp))
        self._local = threading.local()
        self.ar = torch.arange(self.rows)

    @property
    def buf(self) -> torch.Tensor:
        """[rows, K'] f32 scores buffer, one per thread (chunks may run on several)."""
        b = getattr(self._local, "buf", None)
        if b is None:
            b = self._local.buf = torch.empty((self.rows, self.c.shape[0]), dtype=torch.float32)
        return b


def _nearest(x: torch.Tensor, x_sq: torch.Tensor, p: _Prepared) -> tuple[torch.Tensor, torch.Tensor]:
    """Nearest codeword and squared distance for every row of ``x`` (n <= p.rows rows).

    x [n, D] f32, x_sq [n] f32 = ||x||^2.  Returns (idx [n] int64, d2 [n] f32 >= 0); ties go to
    the lower index.  Scores ``||c||^2 - 2 x c^T`` come from one addmm into the reused buffer.
    torch's min-with-index over 4096 columns is ~2x slower than the GEMM itself, so for large K
    the argmin runs in two levels: a vectorised amin per group of g columns, the best group,
    then an argmin inside that group only (same result, first minimum wins at both levels).
    """
    n = x.shape[0]
    scores = p.buf[:n]
    torch.addmm(p.c_sq.unsqueeze(0), x, p.c.T, beta=1.0, alpha=-2.0, out=scores)
    if p.g:
        v = scores.view(n, -1, p.g)
        best, grp = torch.min(v.amin(dim=2), dim=1)
        idx = grp * p.g + torch.argmin(v[p.ar[:n], grp], dim=1)
    else:
        best, idx = torch.min(scores, dim=1)
    return idx, (best + x_sq).clamp_min_(0.0)


def _assign_all(x: torch.Tensor, c: torch.Tensor, x_sq: torch.Tensor | None = None
                ) -> tuple[torch.Tensor, torch.Tensor]:
    """Chunked nearest-codeword search over all rows of x: (idx [N] int64, d2 [N] f32)."""
    n = x.shape[0]
    p = _Prepared(c)
    if x_sq is None:
        x_sq = (x * x).sum(dim=1)
    idx = torch.empty(n, dtype=torch.int64)
    d2 = torch.empty(n, dtype=torch.float32)
    for s in range(0, n, p.rows):
        i, d = _nearest(x[s:s + p.rows], x_sq[s:s + p.rows], p)
        idx[s:s + p.rows] = i
        d2[s:s + p.rows] = d
    return idx, d2


def _nearest_blocks(a, p: _Prepared, rows: np.ndarray | None = None):
    """(start, block [B, D] float32, idx [B] int64, d2 [B] f32) over the vectors ``a`` (or
    ``a[rows]``), ASSIGN_BLOCK_ROWS at a time in blocks of whole ``p.rows`` chunks: the same
    chunks, and so the same results, as one pass over all of them, without their [N, D] copy
    (``a`` may be rows indexed like an array, pipeline.SourcedRows) or finiteness mask."""
    n = a.shape[0] if rows is None else len(rows)
    step = p.rows * max(1, ASSIGN_BLOCK_ROWS // p.rows)
    for s in range(0, n, step):
        blk = _check_x(a[s:s + step] if rows is None else a[rows[s:s + step]])
        xb = torch.from_numpy(blk)
        xb_sq = (xb * xb).sum(dim=1)           # each row's own sum: the same in any block
        idx = torch.empty(xb.shape[0], dtype=torch.int64)
        d2 = torch.empty(xb.shape[0], dtype=torch.float32)

        def chunk(t: int, e: int) -> None:   # the same chunks whatever thread runs each
            idx[t:e], d2[t:e] = _nearest(xb[t:e], xb_sq[t:e], p)
        if torch.get_num_threads() == 1:     # torch on one thread (the search): chunks on every core
            for_ranges(xb.shape[0], p.rows, chunk)
        else:
            for t in range(0, xb.shape[0], p.rows):
                chunk(t, min(t + p.rows, xb.shape[0]))
        yield s, blk, idx, d2


def _vectors(x):
    """The vectors as assign and train_codebook take them: rows indexed like an [N, D] array
    (pipeline.SourcedRows: a stage's SH without a copy) as they are, else a float32 array."""
    a = x if hasattr(x, "ndim") and not isinstance(x, np.ndarray) else np.asarray(x)
    if a.ndim != 2:
        raise VQError(f"vectors must be a 2-D [N, D] array, got shape {a.shape}")
    return a


def assign(x: np.ndarray, codebook: np.ndarray, *, rows: np.ndarray | None = None,
           threads: int | None = DEFAULT_THREADS) -> np.ndarray:
    """Index of the nearest codeword (squared L2) of every vector.

    x [N, D] float32 (or rows indexed like it: pipeline.SourcedRows), codebook [K, D] float32
    (K >= 1)  ->  [N] int32; with ``rows`` (int indices) the index of each vector ``x[rows]``
    ([len(rows)] int32).  Ties go to the lower codeword index.  The vectors are taken a block
    at a time (:func:`_nearest_blocks`: no [N, D] copy or mask, 1.4 GB at 6 M SH-3 vectors).
    """
    a = _vectors(x)
    cb = _check_x(codebook)
    if cb.shape[0] == 0:
        raise VQError("codebook is empty")
    if cb.shape[1] != a.shape[1]:
        raise VQError(f"dimension mismatch: vectors have D={a.shape[1]}, codebook D={cb.shape[1]}")
    n = a.shape[0] if rows is None else len(rows)
    out = np.empty(n, np.int32)
    if n == 0:
        return out
    with _threads(threads):
        for s, _, idx, _ in _nearest_blocks(a, _Prepared(torch.from_numpy(cb)), rows):
            out[s:s + idx.shape[0]] = idx.numpy()
    return out


def weighted_distortion(x: np.ndarray, weights: np.ndarray | None, codebook: np.ndarray,
                        index: np.ndarray | None = None) -> float:
    """Weighted mean squared error ``sum w ||x - c_a||^2 / sum w`` (per vector, not per dim).

    ``index`` defaults to :func:`assign`.  Computed exactly (float64) from the residuals.
    """
    a = _check_x(x)
    w = np.ones(a.shape[0]) if weights is None else np.asarray(weights, np.float64)
    idx = assign(a, codebook) if index is None else np.asarray(index)
    err = np.zeros(a.shape[0])
    cb = np.asarray(codebook, np.float32)
    step = 65536
    for s in range(0, a.shape[0], step):
        r = a[s:s + step].astype(np.float64) - cb[idx[s:s + step]]
        err[s:s + step] = (r * r).sum(axis=1)
    return float((w * err).sum() / max(w.sum(), 1e-300))


def _unique_if_few(x: np.ndarray, k: int) -> np.ndarray | None:
    """The distinct rows of x (sorted) when there are at most k of them, else None."""
    if x.shape[0] > 8 * k + 1024:
        # Cheap probe first: only a tiny-alphabet input is worth the full unique.
        probe = np.unique(x[:: max(1, x.shape[0] // (4 * k))], axis=0)
        if probe.shape[0] > k:
            return None
    u = np.unique(x, axis=0)
    return u if u.shape[0] <= k else None


def _seed(x: np.ndarray, w: np.ndarray, k: int, rng: np.random.Generator) -> np.ndarray:
    """Weighted k-means++ seeds (batched D^2 sampling) from a subsample: [k, D] float32."""
    n = x.shape[0]
    if n > SEED_SAMPLE:
        # Sample proportional to weight: the seeds should cover what the objective cares about.
        p = w / w.sum()
        sub = np.unique(rng.choice(n, size=SEED_SAMPLE, replace=True, p=p))
        xs, ws = x[sub], np.ones(sub.size)
    else:
        xs, ws = np.asarray(x), w
    m = xs.shape[0]
    xt = torch.from_numpy(np.ascontiguousarray(xs))
    xt_sq = (xt * xt).sum(dim=1)
    first = int(rng.choice(m, p=ws / ws.sum()))
    centres = [xs[first]]
    d2 = ((xs - xs[first]) ** 2).sum(axis=1).astype(np.float64)
    rounds = 32
    per_round = max(1, math.ceil((k - 1) / rounds))
    while len(centres) < k:
        mass = ws * d2
        total = mass.sum()
        want = min(per_round, k - len(centres))
        if total <= 0:
            # Every sample point coincides with a centre: fill the rest with random points.
            pick = rng.choice(m, size=want, replace=True)
        else:
            nz = int((mass > 0).sum())
            pick = rng.choice(m, size=min(want, nz), replace=False, p=mass / total)
        new = xs[pick]
        centres.extend(new)
        c = torch.from_numpy(np.ascontiguousarray(new))
        _, dn = _assign_all(xt, c, xt_sq)
        d2 = np.minimum(d2, dn.numpy().astype(np.float64))
    return np.stack(centres[:k]).astype(np.float32)


def _reseed(c: np.ndarray, dead: np.ndarray, cand_x: np.ndarray, cand_err: np.ndarray) -> None:
    """Move the ``dead`` codewords onto the candidates with the largest error (in place)."""
    if dead.size == 0 or cand_x.shape[0] == 0:
        return
    take = min(dead.size, cand_x.shape[0])
    # Stable sort: equal errors keep index order (determinism).
    worst = np.argsort(-cand_err, kind="stable")[:take]
    c[dead[:take]] = cand_x[worst]


def train_codebook(x: np.ndarray, weights: np.ndarray | None, K: int, *,
                   iters: int = DEFAULT_ITERS, batch: int = DEFAULT_BATCH,
                   lloyd: int = DEFAULT_LLOYD, seed: int = 0,
                   threads: int | None = DEFAULT_THREADS,
                   progress: Callable[[str, int, int], None] | None = None) -> np.ndarray:
    """Train an importance-weighted codebook.

    x        [N, D] float32 vectors (N >= 1, finite)
    weights  [N] >= 0 (None = uniform); only ratios matter.  All-zero -> uniform.
    K        number of codewords >= 1
    iters    mini-batch iterations; batch: points per mini-batch (uniform draw)
    lloyd    full weighted Lloyd passes after the mini-batches (each costs one full assignment)
    seed     RNG seed (numpy Generator); same input + options -> identical codebook
    threads  torch intra-op threads for the maths (default 1, see :func:`_threads`)
    progress optional callback(stage: str, done: int, total: int)
    returns  [K, D] float32 codebook
    """
    a = _vectors(x)
    if isinstance(a, np.ndarray):
        a = _check_x(a)
    elif any(not np.isfinite(a[s:s + ASSIGN_BLOCK_ROWS]).all() for s in range(0, a.shape[0], ASSIGN_BLOCK_ROWS)):
        raise VQError("vectors contain non-finite values")
    n, dim = a.shape
    if isinstance(K, bool) or not isinstance(K, (int, np.integer)) or K < 1:
        raise VQError(f"codebook size K must be an integer >= 1, got {K!r}")
    for name, v, lo in (("iters", iters, 0), ("batch", batch, 1), ("lloyd", lloyd, 0)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < lo:
            raise VQError(f"{name} must be an integer >= {lo}, got {v!r}")
    if n == 0:
        raise VQError("cannot train a codebook on zero vectors")
    K = int(K)
    w = _check_weights(weights, n)
    rng = np.random.default_rng(seed)

    few = _unique_if_few(a, K)
    if few is not None:
        pad = np.repeat(few[:1], K - few.shape[0], axis=0)
        return np.ascontiguousarray(np.concatenate([few, pad]), dtype=np.float32)

    with _threads(threads):
        return _train(a, w, K, iters, batch, lloyd, rng, progress)


def _train(a: np.ndarray, w: np.ndarray, K: int, iters: int, batch: int, lloyd: int,
           rng: np.random.Generator, progress) -> np.ndarray:
    """The k-means proper (inputs validated, thread count set): [K, D] float32."""
    n, dim = a.shape
    c = _seed(a, w, K, rng)
    if progress:
        progress("seed", 1, 1)
    acc_w = np.zeros(K)                    # accumulated weight per codeword (learning rates)
    last_hit = np.zeros(K, dtype=np.int64)
    refresh = 10                           # iterations without weight before a re-seed
    bsz = min(batch, n)
    for it in range(iters):
        bi = np.sort(rng.choice(n, size=bsz, replace=False))
        xb = torch.from_numpy(a[bi])            # gathered: ``a`` may be rows indexed like an array
        xb_sq = (xb * xb).sum(dim=1)
        wb = w[bi]
        p = _Prepared(torch.from_numpy(c))
        idx = np.empty(bsz, np.int64)
        d2 = np.empty(bsz, np.float64)
        for s in range(0, bsz, p.rows):
            i, d = _nearest(xb[s:s + p.rows], xb_sq[s:s + p.rows], p)
            idx[s:s + p.rows] = i.numpy()
            d2[s:s + p.rows] = d.numpy()
        bw = np.bincount(idx, weights=wb, minlength=K)
        xbn = xb.numpy()
        bsum = np.stack([np.bincount(idx, weights=wb * xbn[:, j], minlength=K)
                         for j in range(dim)], axis=1)
        hit = bw > 0
        acc_w[hit] += bw[hit]
        last_hit[hit] = it
        # c <- c + (bw / acc_w) * (batch mean - c): the per-codeword mini-batch step.
        eta = np.where(hit, bw / np.maximum(acc_w, 1e-300), 0.0)
        mean = bsum[hit] / bw[hit, None]
        c[hit] = (c[hit] + eta[hit, None] * (mean - c[hit])).astype(np.float32)
        dead = np.flatnonzero(it - last_hit >= refresh)
        if dead.size:
            _reseed(c, dead, xbn, wb * d2)
            acc_w[dead] = 0.0
            last_hit[dead] = it
        if progress:
            progress("minibatch", it + 1, iters)

    for p in range(lloyd):
        idx, d2 = np.empty(n, np.int64), np.empty(n, np.float32)
        sums = np.zeros((dim, K))
        for s, blk, bi_, bd in _nearest_blocks(a, _Prepared(torch.from_numpy(c))):
            e = s + blk.shape[0]
            idx[s:e], d2[s:e] = bi_.numpy(), bd.numpy()
            for j in range(dim):
                # added in row order, as one np.bincount over every row adds: the same sums
                np.add.at(sums[j], idx[s:e], w[s:e] * blk[:, j])
        cw = np.bincount(idx, weights=w, minlength=K)
        live = cw > 0
        c[live] = (sums.T[live] / cw[live, None]).astype(np.float32)
        _reseed(c, np.flatnonzero(~live), a, w * d2.astype(np.float64))
        if progress:
            progress("lloyd", p + 1, lloyd)
    return np.ascontiguousarray(c, dtype=np.float32)


def compact(codebook: np.ndarray, index: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Drop unused codewords: returns (codebook' [K', D], index' [N] int32) with the used rows
    in their original order (K' = number of distinct indices)."""
    cb = np.asarray(codebook)
    idx = np.asarray(index, np.int64)
    if idx.size and (idx.min() < 0 or idx.max() >= cb.shape[0]):
        raise VQError("index out of range of the codebook")
    used = np.unique(idx)
    remap = np.full(cb.shape[0], -1, np.int64)
    remap[used] = np.arange(used.size)
    return cb[used], remap[idx].astype(np.int32)
