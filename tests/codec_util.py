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


def lowest_version(data: bytes) -> str:
    """The version a file's features call for (GSZ.md: the lowest minor they need): 1.9 with an
    SHRF chunk, else 1.8 with an
    SHXF chunk that sets the KLT bit (bit 2), 1.7 with one that turns the DC colour (bit 1), 1.6
    with another SHXF chunk, else 1.5 with an RWGT chunk, else 1.4 with a direct-coded octree (scheme 1), else 1.3 with an SHCL chunk,
    else 1.2 with tiles, else 1.1."""
    from gsz.decoder.container import read_container
    from gsz.decoder.geometry import octree_scheme
    c = read_container(data)
    types = {ch.type for ch in c.chunks}
    if b"SHRF" in types:
        return "1.9"
    if b"SHXF" in types:
        bits = [ch.data[0] for ch in c.chunks if ch.type == b"SHXF"]
        return "1.8" if any(b & 4 for b in bits) else "1.7" if any(b & 2 for b in bits) else "1.6"
    if b"RWGT" in types:
        return "1.5"
    if any(ch.type == b"GEOM" and octree_scheme(ch.data) == 1 for ch in c.chunks):
        return "1.4"
    return "1.3" if b"SHCL" in types else "1.2" if b"TILE" in types else "1.1"


def sh3_off_grid(n: int = 3000, sigma: float = 0.002):
    """The jug sample moved off its SPZ grid as the RD bench's noised variants are (``sigma`` on
    the SH rest): what a trained capture's SH look like to the colour detectors."""
    import dataclasses
    c = sample("sh3", n)
    rng = np.random.default_rng(11)
    return dataclasses.replace(c, sh_rest=(c.sh_rest + rng.normal(0, sigma, c.sh_rest.shape)).astype(np.float32))


def render_psnr(ref, cloud) -> float:
    """gsz-eval's PSNR of ``cloud`` against ``ref`` on 3 default test views at 320 px."""
    from gsz.evaluation.cameras import load_cameras
    from gsz.evaluation.evaluate import evaluate
    return evaluate(ref, cloud, load_cameras(None, ref, n_test=3, width=320).test)["psnr"]


def decoded_on_both_paths(res):
    """The NumPy decode of an encode result's file, asserted equal to the encoder's
    reconstruction and, where the native accelerator is built, to the native decode."""
    from gsz.decoder import decode, native
    with native.numpy_only():
        ref = decode(res.data)
    assert ref.equals(res.cloud)                 # the encoder's reconstruction is the decoder's
    if native.enabled():
        assert decode(res.data).equals(ref)
    return ref

