"""The colour space the encoder codes the SH rest and the DC colour in (SHXF chunk, GSZ.md §8.2).

A view-dependent change in a real capture is mostly a change of brightness, so the three colour
channels of one SH rest coefficient are strongly correlated.  Rotated to luma and two chroma
differences by an orthonormal matrix (squared errors, VQ distances and the size of a rendered
error stay those of RGB), the chroma channels are small and code in fewer bits: +0.6 to +1.8 dB
at the peers' bytes on trained and noised scenes (docs/design/sh-colour.md).  Inputs whose SH
rest sit on a coarse grid (converted from SPZ, SOG, compressed.ply) are coded exactly by the
RGB groups and a rotation smears the grid, so "auto" keeps RGB for them.  The DC colour (format
1.7) is RAHT-coded, which no grid helps, and its channels are as correlated: "auto" codes it as
luma/chroma always (+0.7 to +1.05 dB on the houseplant at 8x and SOG's bytes, measured by
bench/bench_dc_colour_probe.py before the format carried it).

The forward transform is the encoder's own; the inverse is the decoder's
(:func:`gsz.decoder.sh.luma_chroma_to_rgb`), the truth both sides reconstruct with.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from ..decoder.cloud import ColourRows, GaussianCloud
from ..decoder.sh import SH_COLOUR_DC, SH_COLOUR_LUMA_CHROMA, SH_COLOUR_RGB, luma_chroma_to_rgb

#: --sh-colour values: "auto" picks per input, the others force a space
SH_COLOUR_CHOICES = ("auto", "rgb", "luma-chroma")
#: "auto" keeps RGB when the median SH rest component has at most this many distinct values
#: among the sampled Gaussians: a delivery format's grid (SPZ's few-bit SH: 3-14; the shared
#: flowers' finer grid 507-942 and trained or noised scenes nearly every value gain from luma/chroma)
GRID_DISTINCT_MAX = 64
#: Gaussians sampled (evenly spaced) for the distinct-value count: the count is a few sorts
DISTINCT_SAMPLE = 1 << 16
#: rows of the forward matrix: luma (R+G+B)/sqrt3, (R-G)/sqrt2, (R+G-2B)/sqrt6
_FORWARD = np.array([[1, 1, 1], [1, -1, 0], [1, 1, -2]], np.float64)
_FORWARD /= np.linalg.norm(_FORWARD, axis=1, keepdims=True)
#: rows converted per step (a [65536, 15, 3] float64 block: 24 MB)
_ROWS = 1 << 16


def on_coarse_grid(sh_rest: np.ndarray) -> bool:
    """Whether the SH rest [N, K, 3] sits on a delivery format's coarse grid: the median of the
    3K components' distinct-value counts, over at most DISTINCT_SAMPLE evenly spaced Gaussians,
    is at most GRID_DISTINCT_MAX."""
    n = sh_rest.shape[0]
    step = max(1, -(-n // DISTINCT_SAMPLE))
    sample = np.asarray(sh_rest[::step], np.float32).reshape(-1, sh_rest.shape[1] * 3)
    if sample.shape[0] == 0 or sample.shape[1] == 0:
        return False
    s = np.sort(sample, axis=0)
    distinct = 1 + np.count_nonzero(s[1:] != s[:-1], axis=0)
    return float(np.median(distinct)) <= GRID_DISTINCT_MAX


def sh_colour_name(colour: int) -> str:
    """The report's name of SHXF transform bits: "rgb", "luma-chroma" (whatever the file has:
    the SH rest and the DC), "luma-chroma DC" (the DC only: its SH rest on a grid)."""
    if colour & SH_COLOUR_LUMA_CHROMA:
        return "luma-chroma" if colour & SH_COLOUR_DC else "luma-chroma SH rest"
    return "luma-chroma DC" if colour & SH_COLOUR_DC else "rgb"


def choose_sh_colour(cloud: GaussianCloud, mode: str = "auto") -> int:
    """The SHXF transform bits to code ``cloud`` in (0: RGB, no chunk): SH_COLOUR_DC unless
    ``mode`` is "rgb", SH_COLOUR_LUMA_CHROMA for an SH rest unless "rgb" or, with "auto", on a
    coarse grid; ``mode`` one of SH_COLOUR_CHOICES."""
    if mode not in SH_COLOUR_CHOICES:
        raise ValueError(f"sh_colour must be one of {', '.join(SH_COLOUR_CHOICES)}, got {mode!r}")
    if mode == "rgb":
        return SH_COLOUR_RGB
    if cloud.sh_degree == 0:
        return SH_COLOUR_DC
    if mode == "luma-chroma" or not on_coarse_grid(cloud.sh_rest):
        return SH_COLOUR_DC | SH_COLOUR_LUMA_CHROMA
    return SH_COLOUR_DC


def rgb_to_luma_chroma(sh_rest: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """float32 [N, K, 3] RGB triplets -> float32 [N, K, 3] (luma, chroma, chroma): the matrix
    product in float64, rounded once; made _ROWS Gaussians at a time (``out`` may be
    ``sh_rest`` itself: each step reads its rows before writing them)."""
    out = np.empty(sh_rest.shape, np.float32) if out is None else out
    for s in range(0, sh_rest.shape[0], _ROWS):
        out[s:s + _ROWS] = np.asarray(sh_rest[s:s + _ROWS], np.float64) @ _FORWARD.T
    return out


def coded_cloud(cloud: GaussianCloud, colour: int, in_place: bool = False) -> GaussianCloud:
    """``cloud`` with its SH rest and DC colour in the colour space the bits ``colour`` code them
    in (itself for RGB).  ``in_place``: the caller no longer needs ``cloud``'s values, so a
    writable float32 field is overwritten rather than copied (the SH rest's copy is 1 GB at 6 M
    SH-3 Gaussians)."""
    fields = {}
    for name, bit in (("sh_rest", SH_COLOUR_LUMA_CHROMA), ("sh_dc", SH_COLOUR_DC)):
        v = getattr(cloud, name)
        if not colour & bit or (name == "sh_rest" and cloud.sh_degree == 0):
            continue
        if in_place and isinstance(v, np.ndarray) and v.dtype == np.float32 and v.flags.writeable \
                and v.flags.c_contiguous:
            rgb_to_luma_chroma(v.reshape(len(v), -1, 3), out=v.reshape(len(v), -1, 3))
        else:
            fields[name] = rgb_to_luma_chroma(v.reshape(len(v), -1, 3)).reshape(v.shape)
    return dataclasses.replace(cloud, **fields) if fields else cloud


def rgb_view(cloud: GaussianCloud, colour: int) -> GaussianCloud:
    """``cloud`` (coded in the SHXF bits ``colour``) as the renders the search compares should
    see it: its DC colour turned back by the decoder's exact inverse (N x 3 values, cheap), its
    SH rest as :class:`ColourRows` -- the renderer reads the coded field as it is and turns each
    Gaussian's view-dependent colour (float32: within an ulp or so of the decoder's exact
    inverse, which a render's PSNR cannot tell apart; no second copy of the field, and a whole
    one keeps the renderer's whole-array path).  Rendering the rotated colours instead
    misjudges saturated pixels (the clamps at 0 and 1 fall elsewhere): tiny at 12x scored
    0.2 dB above its true PSNR."""
    fields = {}
    if colour & SH_COLOUR_DC:
        fields["sh_dc"] = luma_chroma_to_rgb(cloud.sh_dc)
    if colour & SH_COLOUR_LUMA_CHROMA and cloud.sh_degree:
        # orthonormal: the inverse is the transpose, and a row triplet c turns to c @ _FORWARD
        fields["sh_rest"] = ColourRows(cloud.sh_rest, _FORWARD)
    return dataclasses.replace(cloud, **fields) if fields else cloud


def coded_weights(weights: dict | None, colour: int) -> dict | None:
    """Rendering weights of the RAHT channels (:func:`gsz.encoder.search.channel_weights`, the
    DC's measured in RGB) for a DC coded as luma/chroma: coded channel j's error e becomes the
    RGB error e * F[j], so its weight is sum_k F[j, k]^2 w_k (independent errors: no cross
    terms)."""
    if weights is None or not colour & SH_COLOUR_DC:
        return weights
    raht = list(weights["raht"])
    raht[4:7] = [float(v) for v in (_FORWARD ** 2) @ np.asarray(raht[4:7], np.float64)]
    return {**weights, "raht": raht}
