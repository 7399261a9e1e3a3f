"""Rendering sensitivity of each quantised channel: the weights that turn the allocation's
parameter error Omega into (approximately) rendered error."""
from __future__ import annotations

import numpy as np

from ...decoder.cloud import MadeRows

#: Perturbation (std) per channel used to measure rendering sensitivity; small enough for the
#: image error to grow ~quadratically, large enough to rise above float noise.
_SENS_SIGMA = {"opacity": 0.05, "euler": 0.02, "f_dc": 0.02, "scale": 0.02, "sh": 0.01}
_NOISE_ROWS = 65536


def noised_rows(x: np.ndarray, rng: np.random.Generator, sigma: float) -> MadeRows:
    """float32 [N, ...] ``x + rng.normal(0, sigma, x.shape)`` (the sum in float64, then
    rounded) as :class:`MadeRows`, made a row range at a time as a render reads them (the whole
    noised SH rest is 1 GB at 6 M Gaussians of degree 3).  Every read replays the generator
    from its state now (a read that does not continue the last one starts again from row 0),
    so each row gets the draws one call in row order gives (the generator fills in C order);
    ``rng`` itself is not advanced."""
    start = rng.bit_generator.state
    at = {"row": None, "gen": None}

    def rows(a: int, b: int) -> np.ndarray:
        if at["row"] is None or a < at["row"]:
            gen = np.random.Generator(type(rng.bit_generator)())
            gen.bit_generator.state = start
            at.update(row=0, gen=gen)
        for s in range(at["row"], a, _NOISE_ROWS):            # skip to row a: the same draws
            at["gen"].normal(0, sigma, (min(a, s + _NOISE_ROWS) - s,) + x.shape[1:])
        at["row"] = b
        return x[a:b] + at["gen"].normal(0, sigma, (b - a,) + x.shape[1:])
    return MadeRows(x.shape, rows)


def channel_weights(cloud, cameras, *, seed: int = 0, base_images=None) -> dict:
    """Rendering sensitivity of every quantised channel: image MSE added per unit of parameter
    SSE, measured by perturbing one channel of every Gaussian with Gaussian noise and rendering
    the given (train) views.  Returns {"raht": [7], "scales": [3], "sh": float}, normalised so the
    mean RAHT/scale weight is 1.  The size search multiplies the loss matrix Omega by these, so
    the allocation minimises (approximately) rendered error instead of raw parameter SSE.
    ``base_images``: the unperturbed renders (``render(cloud, camera).image``) when the caller
    has them."""
    from ...decoder.cloud import GaussianCloud
    from ...decoder.rotation import euler_to_quaternion, quaternion_to_euler

    from ...evaluation.render import render
    from ..orientation import canonical_orientations
    rng = np.random.default_rng(seed)
    base = [render(cloud, c).image.astype(np.float64) for c in cameras] if base_images is None \
        else [np.asarray(b, np.float64) for b in base_images]
    n = len(cloud)

    def mse_of(sq):
        return float(np.mean([e.mean() for e in sq]))

    def sensitivity(mod, sigma, count):
        img = [render(mod, c).image.astype(np.float64) for c in cameras]
        return max(mse_of([(a - b) ** 2 for a, b in zip(img, base)]), 1e-30) / (sigma ** 2 * count)

    def variant(**kw):
        f = dict(positions=cloud.positions, scales=cloud.scales, rotations=cloud.rotations,
                 opacities=cloud.opacities, sh_dc=cloud.sh_dc, sh_rest=cloud.sh_rest,
                 sh_degree=cloud.sh_degree)
        f.update(kw)
        return GaussianCloud(**f)

    def noisy(a, col, sigma, to=lambda rows: rows.astype(np.float64), back=lambda rows: rows):
        """float32 back(to(a) with rng.normal(0, sigma, n) added to column col), _NOISE_ROWS
        rows at a time: the draws of one call (C order), and every step works row by row (the
        same values; NumPy's cos/sin do not depend on an element's place in the array), without
        whole float64 temporaries (the rotations' Euler round trip: ~1 GB at 6 M Gaussians)."""
        out = None
        for s in range(0, n, _NOISE_ROWS):
            rows = to(a[s:s + _NOISE_ROWS])
            rows[:, col] += rng.normal(0, sigma, rows.shape[0])
            rows = back(rows)
            if out is None:
                out = np.empty((n,) + rows.shape[1:], np.float32)
            out[s:s + rows.shape[0]] = rows
        return a.astype(np.float32) if out is None else out

    raht = []
    sg = _SENS_SIGMA["opacity"]
    raht.append(sensitivity(variant(opacities=cloud.opacities + rng.normal(0, sg, n)), sg, n))
    sg = _SENS_SIGMA["euler"]
    # the angles the file codes: those of the nearest-identity form (voxelize makes it)
    rot_c, scales_c = canonical_orientations(cloud.rotations, cloud.scales)
    for k in range(3):
        rot = noisy(rot_c, k, sg, lambda q: quaternion_to_euler(q.astype(np.float64)),
                    euler_to_quaternion)
        raht.append(sensitivity(variant(rotations=rot, scales=scales_c), sg, n))
        del rot                 # full-scene temporaries go once used (6 M Gaussians: 0.1 GB each)
    del rot_c, scales_c
    # Image channel k depends on DC colour channel k only (geometry, alpha and T do not involve
    # colour; the 0-clamp is per channel), so one render with all three perturbed gives each
    # channel's error image exactly as three renders would (the other channels' errors are
    # exact zeros there): the same weights for a third of the renders.
    sg = _SENS_SIGMA["f_dc"]
    dc = cloud.sh_dc.astype(np.float64).copy()
    for k in range(3):
        dc[:, k] += rng.normal(0, sg, n)
    sq = [(render(variant(sh_dc=dc), c).image.astype(np.float64) - b) ** 2 for c, b in zip(cameras, base)]
    del dc
    for k in range(3):
        only = []
        for e in sq:
            ek = np.zeros_like(e)
            ek[..., k] = e[..., k]
            only.append(ek)
        raht.append(max(mse_of(only), 1e-30) / (sg ** 2 * n))
    sg = _SENS_SIGMA["scale"]
    scales = [sensitivity(variant(scales=noisy(cloud.scales, k, sg)), sg, n) for k in range(3)]
    sh = 0.0
    if cloud.sh_degree > 0:
        sg = _SENS_SIGMA["sh"]
        per_gaussian = int(np.prod(cloud.sh_rest.shape[1:]))     # (a MadeRows is not made whole)
        sh = sensitivity(variant(sh_rest=noised_rows(cloud.sh_rest, rng, sg)), sg, per_gaussian * n)
    norm = float(np.mean(raht + scales))
    return {"raht": [w / norm for w in raht], "scales": [w / norm for w in scales], "sh": sh / norm}
