"""Absurd values in an input scene, found and fixed before they ruin the rest of it (issue 19).

One opacity logit of 1e4, one f_dc of 1e3, one log-scale of 1e4 or one Gaussian at x = 1e6 used
to wreck every other Gaussian: the quantisation range of a RAHT channel (or of a block of
log-scales) spans the outlier, so the normal values share a handful of levels, and one far
centre widens the octree cube until the scene falls into a few voxels.  :func:`sanitize_cloud`
bounds what a renderer cannot show differently anyway and drops centres far outside the scene:

* opacity logits beyond ±OPACITY_LOGIT_LIMIT: sigmoid(±20) is 0 or 1 in float32 (and an opacity
  below 1/255 is skipped by the rasteriser), so they render as the bound does;
* f_dc and f_rest beyond ±COLOUR_LIMIT: one coefficient of 20 moves a colour by >= 5.6 (SH
  basis >= 0.28), far past the [0, 1] a pixel holds;
* log-scales outside ln(D) - SCALE_BELOW .. ln(D) + SCALE_ABOVE, D the robust scene diagonal
  (:func:`gsz.encoder.voxelize.robust_diagonal`): a Gaussian e^-30 of the scene is far below a
  pixel at any resolution, one e^7 ~ 1100 times the scene covers every view evenly;
* centres more than FAR_LIMIT robust diagonals outside the robust box (1st-99th percentile per
  axis, so up to 1 % of the Gaussians per side may lie anywhere): dropped.  At FAR_LIMIT the cube
  is at most ~1025 diagonals wide, within which the default position-error budget is met at
  depth <= 21 (one Gaussian at 1e6 collapsed 600 others into 2 voxels).

Each fix is reported (one :class:`GszInputWarning` naming the source, the property, the count and
the extreme value; ``EncodeReport.input_fixes``, present only when something was fixed).  No real scene measured comes near a bound (the
six scenes of ../shared/data and both test samples: opacity logits within ±6.3, f_dc -3.1..11.2,
f_rest ±1.1, log-scales 13.7 to 1.6 below ln D, every centre within 0.7 diagonals of the robust
box), so their encodes do not change.
"""
from __future__ import annotations

import math
import warnings
from dataclasses import asdict, dataclass

import numpy as np

from ..decoder.cloud import GaussianCloud
from ..decoder.errors import GszInputWarning

OPACITY_LOGIT_LIMIT = 20.0
COLOUR_LIMIT = 20.0
SCALE_BELOW, SCALE_ABOVE = 30.0, 7.0
FAR_LIMIT = 512.0


@dataclass
class InputFix:
    """One fix of :func:`sanitize_cloud`: ``count`` Gaussians whose ``prop`` was beyond ``bound``
    (``extreme``: the value furthest out, ``first``: the first such Gaussian's index)."""
    prop: str
    count: int
    action: str           # "clamped" or "dropped"
    bound: list
    extreme: float
    first: int

    def message(self, source: str) -> str:
        lo, hi = self.bound
        if self.action == "dropped":
            return (f"{source}: {self.count:,} Gaussian(s) more than {FAR_LIMIT:g} scene diagonals outside the "
                    f"scene's 1st-99th percentile box (up to {self.extreme:.3g} away, first at vertex "
                    f"{self.first}) dropped: they would widen the octree cube until the rest of the scene "
                    "merged into a few voxels")
        return (f"{source}: {self.count:,} Gaussian(s) with property '{self.prop}' outside "
                f"[{lo:.4g}, {hi:.4g}] (extreme {self.extreme:.4g}, first at vertex {self.first}) clamped to "
                "that range, which renders the same; left as they were, they would have widened its "
                "quantisation range for every other Gaussian")


def _clamp(values: np.ndarray, lo: float, hi: float, prop: str, fixes: list, index: np.ndarray) -> np.ndarray:
    """``values`` (any shape, first axis the Gaussians) clamped to [lo, hi]; the fix recorded
    (``index``: each row's vertex in the input)."""
    flat = values.reshape(values.shape[0], -1)
    out_of = (flat < lo) | (flat > hi)
    rows = np.flatnonzero(out_of.any(axis=1))
    if not rows.size:
        return values
    bad = flat[out_of]
    extreme = float(bad[np.argmax(np.abs(bad - (lo + hi) / 2))])
    fixes.append(InputFix(prop, int(rows.size), "clamped", [lo, hi], extreme, int(index[rows[0]])))
    return np.clip(values, np.float32(lo), np.float32(hi)).astype(np.float32)


def _far_from_the_scene(positions: np.ndarray, fixes: list) -> np.ndarray:
    """Mask of the centres kept (not more than FAR_LIMIT robust diagonals outside the robust box)."""
    from .voxelize import ROBUST_PERCENTILES
    x = positions.astype(np.float64)
    lo, hi = np.percentile(x, ROBUST_PERCENTILES, axis=0)
    diag = float(np.linalg.norm(hi - lo))
    outside = np.maximum(lo - x, x - hi).max(axis=1)
    limit = FAR_LIMIT * diag if diag > 0 else 0.0
    far = outside > limit
    if diag == 0 and far.all():
        return np.ones(len(x), bool)        # no scene to measure against: nothing is "far"
    if far.any():
        idx = np.flatnonzero(far)
        fixes.append(InputFix("x, y, z", int(idx.size), "dropped", [-limit, limit],
                              float(outside[idx].max()), int(idx[0])))
    return ~far


def sanitize_cloud(cloud: GaussianCloud, source: str | None = None, *, warn: bool = True):
    """(cloud with absurd values bounded and far centres dropped, [InputFix], kept mask or None
    when nothing was dropped).  The cloud is returned unchanged (the same object) when nothing
    needed fixing; every fix is warned about (GszInputWarning naming ``source``) when ``warn``."""
    fixes: list = []
    n = len(cloud)
    if n == 0:
        return cloud, fixes, None
    keep = _far_from_the_scene(cloud.positions, fixes)
    index = np.flatnonzero(keep)
    c = cloud if keep.all() else cloud.subset(index)
    from .voxelize import robust_diagonal
    diag = robust_diagonal(c.positions)
    log_d = math.log(diag) if diag > 0 and math.isfinite(diag) else 0.0
    opac = _clamp(c.opacities[:, None], -OPACITY_LOGIT_LIMIT, OPACITY_LOGIT_LIMIT, "opacity", fixes, index)[:, 0]
    dc = _clamp(c.sh_dc, -COLOUR_LIMIT, COLOUR_LIMIT, "f_dc", fixes, index)
    rest = _clamp(c.sh_rest, -COLOUR_LIMIT, COLOUR_LIMIT, "f_rest", fixes, index) if c.sh_rest.size else c.sh_rest
    scales = _clamp(c.scales, log_d - SCALE_BELOW, log_d + SCALE_ABOVE, "scale", fixes, index)
    if not fixes:
        return cloud, fixes, None
    out = GaussianCloud(positions=c.positions, scales=scales, rotations=c.rotations, opacities=opac,
                        sh_dc=dc, sh_rest=rest, sh_degree=c.sh_degree)
    if warn:
        for f in fixes:
            warnings.warn(GszInputWarning(f.message(source or "input scene")), stacklevel=2)
    return out, fixes, None if keep.all() else keep


def fixes_report(fixes: list) -> list[dict]:
    """The fixes as report rows."""
    return [asdict(f) for f in fixes]
