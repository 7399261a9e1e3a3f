"""Shared helpers of the codec tests: small, fast encodes of the committed real samples."""
import functools

import numpy as np

import gsz
from gsz.encoder.pipeline import EncodeOptions, encode
from conftest import SAMPLE_SH0, SAMPLE_SH3

FAST = dict(codebook=128, vq_iters=20, train_views=6, importance_width=160)


@functools.lru_cache(maxsize=None)
def sample(name: str, n: int | None = None):
    path = {"sh0": SAMPLE_SH0, "sh3": SAMPLE_SH3}[name]
    c = gsz.read_ply(path)
    if n is not None and n < len(c):
        idx = np.sort(np.random.default_rng(7).choice(len(c), n, replace=False))
        c = c.subset(idx)
    return c


@functools.lru_cache(maxsize=None)
def encoded(name: str, n: int | None = None, **kw):
    opts = EncodeOptions(**{**FAST, **kw})
    return encode(sample(name, n), opts)
