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

from ..decoder.cloud import ColourRows, GaussianCloud, MadeRows
from ..decoder.errors import GszUsageError
from ..decoder.sh import (KLT_MATRIX_SHIFT, KLT_MAX_ABS, SH_COLOUR_DC, SH_COLOUR_KLT, SH_COLOUR_LUMA_CHROMA,
                          SH_COLOUR_RGB, ShColour, klt_to_rgb, luma_chroma_to_rgb)

#: --sh-colour values: "auto" picks per input, the others force a space
SH_COLOUR_CHOICES = ("auto", "rgb", "luma-chroma", "klt")
#: "auto" codes the SH rest in its principal axes when that gains at least this much SNR of
#: the SH rest, on average over KLT_PROBE_BITS, against luma/chroma (trained tiny +4.8..+11.4
#: dB, the shared flowers +1.1..+1.7, the SPZ-grid jug below 0: docs/design/sh-klt.md)
KLT_MIN_GAIN_DB = 0.5
#: bits a vector at which the two spaces' group-wise allocations are compared
KLT_PROBE_BITS = (20, 40, 60, 90, 130, 180)
#: "auto" takes the KLT only where its matrices (one per tile) are at most this share of the
#: budget (a 2 + 2 D^2-byte matrix: 4 kB at SH 3, 8 % of a 9 k-Gaussian scene's 27x file)
KLT_MAX_MATRIX_SHARE = 0.01
#: the forward KLT's values must stay this far inside the decoder's KLT_MAX_ABS
_KLT_SAFE_ABS = KLT_MAX_ABS / 2
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
    sample = _sample(sh_rest)           # float64 of float32 values: the same distinct counts
    if sample.shape[0] == 0 or sample.shape[1] == 0:
        return False
    s = np.sort(sample, axis=0)
    distinct = 1 + np.count_nonzero(s[1:] != s[:-1], axis=0)
    return float(np.median(distinct)) <= GRID_DISTINCT_MAX


def sh_colour_name(colour: int) -> str:
    """The report's name of SHXF transform bits: "rgb", "luma-chroma" (whatever the file has:
    the SH rest and the DC), "klt" (the SH rest in its principal axes, the DC luma/chroma),
    "luma-chroma DC" (the DC only: its SH rest on a grid), "... SH rest" (the SH rest only)."""
    for bit, name in ((SH_COLOUR_LUMA_CHROMA, "luma-chroma"), (SH_COLOUR_KLT, "klt")):
        if colour & bit:
            return name if colour & SH_COLOUR_DC else f"{name} SH rest"
    return "luma-chroma DC" if colour & SH_COLOUR_DC else "rgb"


def choose_sh_colour(cloud: GaussianCloud, mode: str = "auto", budget: int | None = None,
                     tile_gaussians: int | None = None) -> ShColour:
    """The SHXF transform bits to code ``cloud`` in (0: RGB, no chunk), with the KLT matrix
    where bit 2 is chosen: SH_COLOUR_DC unless ``mode`` is "rgb"; for an SH rest (not "rgb",
    and with "auto" not on a coarse grid) SH_COLOUR_KLT where "klt" forces it or
    :func:`klt_pays` at ``budget`` bytes (None: a fixed configuration, judged against one byte a
    component) with a matrix per tile of at most ``tile_gaussians`` (None or 0: one tile), else
    SH_COLOUR_LUMA_CHROMA; ``mode`` one of SH_COLOUR_CHOICES."""
    if mode not in SH_COLOUR_CHOICES:
        raise ValueError(f"sh_colour must be one of {', '.join(SH_COLOUR_CHOICES)}, got {mode!r}")
    if mode == "rgb":
        return ShColour(SH_COLOUR_RGB)
    if cloud.sh_degree == 0:
        return ShColour(SH_COLOUR_DC)
    if mode == "klt":
        klt = klt_matrix(cloud.sh_rest)
        if not klt_in_range(cloud.sh_rest, klt):
            raise GszUsageError(f"--sh-colour klt: the SH rest values (largest magnitude "
                                f"{_max_abs(cloud.sh_rest):g}) are too large for the KLT's exact inverse "
                                f"(its coded values must stay below {_KLT_SAFE_ABS:g}); use --sh-colour auto")
        return ShColour(SH_COLOUR_DC | SH_COLOUR_KLT, klt)
    if mode == "luma-chroma":
        return ShColour(SH_COLOUR_DC | SH_COLOUR_LUMA_CHROMA)
    if on_coarse_grid(cloud.sh_rest):
        return ShColour(SH_COLOUR_DC)
    n, d = len(cloud.sh_rest), 3 * cloud.sh_rest.shape[1]
    room = KLT_MAX_MATRIX_SHARE * (n * d if budget is None else budget)
    tiles = -(-n // int(tile_gaussians)) if tile_gaussians else 1
    if tiles * klt_matrix_bytes(d) <= room:
        klt = klt_matrix(cloud.sh_rest)
        if klt_pays(cloud.sh_rest, klt) and klt_in_range(cloud.sh_rest, klt):
            return ShColour(SH_COLOUR_DC | SH_COLOUR_KLT, klt)
    return ShColour(SH_COLOUR_DC | SH_COLOUR_LUMA_CHROMA)


def klt_matrix_bytes(d: int) -> int:
    """Bytes of an SHXF chunk's KLT matrix: D and D x D int16."""
    return 1 + 2 * d * d


def _sample(sh_rest) -> np.ndarray:
    """float64 [n, D]: at most DISTINCT_SAMPLE evenly spaced Gaussians' SH rest vectors (the
    sample every per-file colour decision looks at)."""
    step = max(1, -(-sh_rest.shape[0] // DISTINCT_SAMPLE))
    x = np.asarray(sh_rest[::step], np.float64)
    return x.reshape(len(x), int(np.prod(sh_rest.shape[1:])))


def klt_matrix(sh_rest) -> np.ndarray:
    """int16 [D, D]: the principal axes of the SH rest vectors [N, K, 3] (their covariance over
    at most DISTINCT_SAMPLE evenly spaced Gaussians), largest variance first, row i axis i in
    RGB components times 2^14; each axis's sign puts its largest entry positive, so the
    matrix is a function of the data, not of the eigen-solver's choice."""
    x = _sample(sh_rest)
    cov = np.cov(x.T) if len(x) > 1 else np.eye(x.shape[1])
    _, vec = np.linalg.eigh(cov)
    axes = vec[:, ::-1].T.copy()
    big = np.argmax(np.abs(axes), axis=1)
    axes *= np.where(axes[np.arange(len(axes)), big] < 0, -1.0, 1.0)[:, None]
    return np.rint(axes * (1 << KLT_MATRIX_SHIFT)).astype(np.int16)


def _klt_forward(klt: np.ndarray) -> np.ndarray:
    """float64 [D, D] F with y = x @ F the stored vector of RGB vector x: the inverse of the
    decoder's matrix (not its transpose: the int16 rounding leaves it a hair off orthonormal)."""
    return np.linalg.inv(klt.astype(np.float64) * 2.0 ** -KLT_MATRIX_SHIFT)


def klt_in_range(sh_rest, klt: np.ndarray) -> bool:
    """Whether every stored value of ``sh_rest`` turned by ``klt`` stays below _KLT_SAFE_ABS
    (half the decoder's limit: decoded values lie within their groups' ranges)."""
    bound = np.abs(_klt_forward(klt)).sum(axis=0).max()       # |y_j| <= max|x| * sum_i |F_ij|
    return _max_abs(sh_rest) * bound < _KLT_SAFE_ABS


def _max_abs(sh_rest) -> float:
    """The largest |value| of a float32 field, _ROWS rows a step (no whole-field temporary)."""
    top = 0.0
    for s in range(0, sh_rest.shape[0], _ROWS):
        top = max(top, float(np.abs(np.asarray(sh_rest[s:s + _ROWS], np.float32)).max(initial=0.0)))
    return top


def klt_gain_db(sh_rest, klt: np.ndarray) -> float:
    """Mean SNR gain (dB) of the SH rest coded group-wise in the axes of ``klt`` over luma/chroma,
    on the same sample as :func:`klt_matrix`, each space's groups (one component, one of up
    to 80 blocks) allocated by the size search's allocator at KLT_PROBE_BITS bits a vector.
    Dense, correlated components (a trained scene) gain; sparse or gridded ones (most values
    one level, which width-0 groups code nearly free) lose: a rotation mixes them."""
    from .bit_allocation import InfeasibleBudgetError, allocate
    from .groups import vector_tables
    from ..decoder.groups import blocks_for
    x = _sample(sh_rest)
    n, d = x.shape
    if n < 2:
        return 0.0
    lc = (x.reshape(n, -1, 3) @ _FORWARD.T).reshape(n, d)
    blocks = blocks_for(n, max(1, min(80, n // 128)))
    power = float((x * x).sum())
    gains = []
    tables = [vector_tables(np.ascontiguousarray(v.T, np.float32), blocks, 1)
              for v in (lc, x @ _klt_forward(klt))]
    for bits in KLT_PROBE_BITS:
        snr = []
        for loss, rate in tables:
            loss, rate = loss.reshape(-1, loss.shape[2]), rate.reshape(-1, rate.shape[2])
            try:
                pick = allocate(loss, rate, bits * n, method="fast")
            except InfeasibleBudgetError:
                break
            sse = float(loss[np.arange(len(pick)), pick].sum())
            snr.append(10 * np.log10(max(power, 1e-30) / max(sse, 1e-30)))
        if len(snr) == 2:
            gains.append(snr[1] - snr[0])
    return float(np.mean(gains)) if gains else 0.0


def klt_pays(sh_rest, klt: np.ndarray) -> bool:
    """Whether "auto" codes the SH rest in the axes of ``klt``: :func:`klt_gain_db` at least
    KLT_MIN_GAIN_DB."""
    return klt_gain_db(sh_rest, klt) >= KLT_MIN_GAIN_DB


def rgb_to_luma_chroma(sh_rest: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """float32 [N, K, 3] RGB triplets -> float32 [N, K, 3] (luma, chroma, chroma): the matrix
    product in float64, rounded once; made _ROWS Gaussians at a time (``out`` may be
    ``sh_rest`` itself: each step reads its rows before writing them)."""
    out = np.empty(sh_rest.shape, np.float32) if out is None else out
    for s in range(0, sh_rest.shape[0], _ROWS):
        out[s:s + _ROWS] = np.asarray(sh_rest[s:s + _ROWS], np.float64) @ _FORWARD.T
    return out


def rgb_to_klt(sh_rest: np.ndarray, klt: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """float32 [N, K, 3] RGB -> float32 [N, K, 3] stored KLT components (flattened, component i
    of the vector is axis i): the product with the inverse of the decoder's matrix in float64,
    rounded once; _ROWS Gaussians a step (``out`` may be ``sh_rest``)."""
    out = np.empty(sh_rest.shape, np.float32) if out is None else out
    f = _klt_forward(klt)
    n = sh_rest.shape[0]
    for s in range(0, n, _ROWS):
        x = np.asarray(sh_rest[s:s + _ROWS], np.float64)
        out[s:s + _ROWS] = (x.reshape(len(x), -1) @ f).reshape(x.shape)
    return out


def coded_cloud(cloud: GaussianCloud, colour: int, in_place: bool = False) -> GaussianCloud:
    """``cloud`` with its SH rest and DC colour in the colour space the bits ``colour`` (with its
    KLT matrix, :class:`ShColour`) code them in (itself for RGB).  ``in_place``: the caller no
    longer needs ``cloud``'s values, so a writable float32 field is overwritten rather than
    copied (the SH rest's copy is 1 GB at 6 M SH-3 Gaussians)."""
    fields = {}
    for name, bit in (("sh_rest", SH_COLOUR_LUMA_CHROMA | SH_COLOUR_KLT), ("sh_dc", SH_COLOUR_DC)):
        v = getattr(cloud, name)
        if not colour & bit or (name == "sh_rest" and cloud.sh_degree == 0):
            continue
        turn = (rgb_to_luma_chroma if name == "sh_dc" or colour & SH_COLOUR_LUMA_CHROMA
                else lambda x, out=None: rgb_to_klt(x, colour.klt, out))
        if in_place and isinstance(v, np.ndarray) and v.dtype == np.float32 and v.flags.writeable \
                and v.flags.c_contiguous:
            turn(v.reshape(len(v), -1, 3), out=v.reshape(len(v), -1, 3))
        else:
            fields[name] = turn(v.reshape(len(v), -1, 3)).reshape(v.shape)
    return dataclasses.replace(cloud, **fields) if fields else cloud


def decoded_sh_rest(sh_rest: np.ndarray, colour: int) -> np.ndarray:
    """A coded SH rest float32 [M, K, 3] as a decoder outputs it (the decoder's own inverse of
    ``colour``'s SH vector transform, a new array; ``sh_rest`` itself without one)."""
    if colour & SH_COLOUR_LUMA_CHROMA:
        return luma_chroma_to_rgb(sh_rest)
    if colour & SH_COLOUR_KLT:
        m = len(sh_rest)
        return klt_to_rgb(np.asarray(sh_rest, np.float32).reshape(m, -1), colour.klt).reshape(sh_rest.shape)
    return sh_rest


def rgb_view(cloud: GaussianCloud, colour: int) -> GaussianCloud:
    """``cloud`` (coded in the SHXF bits ``colour``) as the renders the search compares should
    see it: its DC colour turned back by the decoder's exact inverse (N x 3 values, cheap), its
    SH rest as :class:`ColourRows` -- the renderer reads the coded field as it is and turns each
    Gaussian's view-dependent colour (float32: within an ulp or so of the decoder's exact
    inverse, which a render's PSNR cannot tell apart; no second copy of the field, and a whole
    one keeps the renderer's whole-array path) -- or, for the KLT (which mixes coefficients,
    not only a coefficient's colours), as :class:`MadeRows` the decoder's inverse makes a row
    range at a time.  Rendering the rotated colours instead misjudges saturated pixels (the
    clamps at 0 and 1 fall elsewhere): tiny at 12x scored 0.2 dB above its true PSNR."""
    fields = {}
    if colour & SH_COLOUR_DC:
        fields["sh_dc"] = luma_chroma_to_rgb(cloud.sh_dc)
    if colour & SH_COLOUR_LUMA_CHROMA and cloud.sh_degree:
        # orthonormal: the inverse is the transpose, and a row triplet c turns to c @ _FORWARD
        fields["sh_rest"] = ColourRows(cloud.sh_rest, _FORWARD)
    elif colour & SH_COLOUR_KLT and cloud.sh_degree:
        coded = cloud.sh_rest
        fields["sh_rest"] = MadeRows(coded.shape, lambda s, e: decoded_sh_rest(coded[s:e], colour))
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
