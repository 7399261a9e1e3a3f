"""Voxelisation of Gaussian centres on a cubic octree grid, and merge of Gaussians that share a
voxel (MesonGS++ §3; reference notes §3 -- with its bugs fixed).

Grid
    A cube ``(origin [3] float64, side float64)`` split into ``2^d`` voxels per axis (isotropic,
    unlike the reference's per-axis bins).  Voxel ``ijk`` spans
    ``origin + ijk * pitch .. origin + (ijk + 1) * pitch`` with ``pitch = side / 2^d`` and is
    decoded at its CENTRE ``origin + (ijk + 0.5) * pitch`` (the reference decodes the lower
    corner: a half-voxel bias).  The cube is the bounding cube of ALL centres -- no point is
    ever dropped -- with a relative 2^-30 of padding (far below a voxel even at d = 21) so the
    maximum lands strictly inside voxel 2^d - 1, and indices are clipped to ``[0, 2^d - 1]`` as
    a second guard (the reference's edge bug put a point at the axis maximum into voxel 2^d,
    corrupting the key).  Positions are reconstructed by the decoder's normative
    :func:`gsz.decoder.geometry.voxel_centres`.

Depth
    :func:`choose_depth` takes the smallest ``d`` whose worst-case position error, the half
    voxel diagonal ``sqrt(3)/2 * side / 2^d``, is within a budget ``rel_error * D_robust``, where
    ``D_robust`` is the diagonal of the 1st..99th-percentile box of the centres (outliers do not
    inflate the budget; they do widen the cube and so push d up).  Default
    ``rel_error = 5e-4``: the G-PCC anchor's operating depth on most shared scenes
    (docs/design/depth-choice.md).  ``max_merge`` optionally also demands a merged fraction
    (above the exact-duplicate floor).

Relocation
    Where a voxel is far below a Gaussian's size (its diagonal at most RELOCATE_MAX_DIAGONAL of
    the Gaussian's thinnest axis), a Gaussian that shares its voxel with a more important one
    moves to the nearest free neighbouring voxel, attributes untouched, instead of merging
    (:func:`relocate_extras`): exact duplicates share a voxel at every depth.  At coarse depths
    nothing moves and the merge below is the MesonGS++ one.

Merge
    Gaussians whose centres (still) share a voxel become one Gaussian at the voxel centre:

    * opacity logit, SH DC and SH rest: importance-weighted mean in the raw (pre-activation)
      parameter space, as the reference does (its mean is unweighted);
    * covariance (log-scales + rotation), ``rotation=`` one of
      - ``"moment"`` (default): moment matching -- the importance-weighted mean of the members'
        covariances R diag(e^2s) R^T, re-factorised by a symmetric eigendecomposition into
        log-scales and a rotation.  It reproduces the mean covariance exactly;
      - ``"average"``: weighted mean of log-scales; quaternions normalised, sign-aligned to the
        most important member's (q and -q are the same rotation; a plain mean of antipodal
        quaternions cancels), weighted-averaged and renormalised;
      - ``"max"``: weighted mean of log-scales, the most important member's rotation.
      Both averaging options are far from the weighted mean covariance, which moment
      matching reproduces exactly (docs/design/depth-choice.md);
    * importance: the SUM of the members' importances (the merged Gaussian now carries all
      their rendered contribution; the reference takes the max).  Downstream weights (VQ,
      kept-SH ranking) then see the voxel's total weight;
    * a voxel whose members all have zero importance uses equal weights.

    A voxel with a single Gaussian copies its attributes bit-exactly (only its position moves).
    The whole merge is vectorised: one np.unique over Morton codes plus segment sums
    (np.add.reduceat) over the few multi-member voxels; no Python loop over voxels.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..decoder.cloud import GaussianCloud, MadeRows
from ..decoder.errors import GszError
# The decoder's reconstruction rule is the normative one; re-exported for encoder callers.
from ..decoder.geometry import centres_float32, voxel_centres  # noqa: F401  (origin + (ijk + 0.5) * pitch)
from ..decoder.morton import MAX_DEPTH, morton_encode
from ..decoder.rotation import quaternion_to_matrix
from .orientation import canonical_orientations

#: Default relative position-error budget of :func:`choose_depth` (see module docstring).
DEFAULT_REL_ERROR = 5e-4
#: Relative padding of the bounding cube, so the maximum centre falls strictly inside.
CUBE_PAD = 2.0 ** -30
#: Padding steps of (1 + CUBE_PAD) tried before the cube grows by doubling float64 spacings.
PAD_STEPS = 4096
#: Largest cube side / scene extent accepted when float64 precision forces a bigger cube: the
#: finest grid (depth 21) then still puts >= 2^10 voxels across the scene.
MAX_CUBE_GROWTH = float(1 << (MAX_DEPTH - 10))
#: Percentiles of the robust box used for the error budget.
ROBUST_PERCENTILES = (1.0, 99.0)


class VoxelizeError(GszError, ValueError):
    """Bad input to voxelisation (non-finite positions, invalid depth or cube, bad importance)."""


class SourcedRows:
    """Read-only [M, D] float32 rows kept as references: row i is ``base[source[i]]`` where
    ``source[i] >= 0`` (a voxel holding one input Gaussian keeps its vector bit for bit) and the
    next row of ``own`` where it is -1 (merged voxels, in voxel order) -- a stage's SH vectors
    without a copy of the input's (180 bytes a voxel at SH degree 3).  Indexing with an int
    array, a bool mask or a slice gives the ndarray the materialised rows would; ``np.asarray``
    materialises them."""

    ndim = 2
    dtype = np.dtype(np.float32)

    def __init__(self, base: np.ndarray, source: np.ndarray, own: np.ndarray):
        self.base, self.source, self.own = base, source, own
        self.merged = np.flatnonzero(source < 0)          # voxel of each row of own
        self.shape = (source.shape[0], base.shape[1])

    @classmethod
    def of_grid(cls, base: np.ndarray, source: np.ndarray, vox) -> "SourcedRows":
        """The SH vectors of a voxel grid (Voxelized) whose Stage.source is ``source``, as rows
        of the input cloud's SH ``base`` [N, D] (the grid's own when it holds them so)."""
        if vox.sh is not None:
            return vox.sh
        m = len(vox.ijk)
        return cls(base, source, vox.cloud.sh_rest.reshape(m, -1)[source < 0])

    def __len__(self) -> int:
        return self.shape[0]

    def __getitem__(self, key) -> np.ndarray:
        src = self.source[key]
        if src.ndim != 1:
            raise IndexError("SourcedRows takes a slice, an int array or a bool mask of rows")
        out = np.take(self.base, np.maximum(src, 0), axis=0)
        neg = np.flatnonzero(src < 0)
        if neg.size:
            out[neg] = self.own[np.searchsorted(self.merged, self._voxels(key, neg))]
        return out

    def _voxels(self, key, at: np.ndarray) -> np.ndarray:
        """The voxel indices of the rows ``at`` of the selection ``key``."""
        if isinstance(key, slice):
            start, _, step = key.indices(self.shape[0])
            return start + step * at
        key = np.asarray(key)
        sel = np.flatnonzero(key)[at] if key.dtype == bool else key[at]
        return np.where(sel < 0, sel + self.shape[0], sel)

    def __array__(self, dtype=None, copy=None):
        out = self[:]
        return out if dtype is None else out.astype(dtype, copy=False)


@dataclass
class Voxelized:
    """Result of :func:`voxelize` (M occupied voxels out of N input Gaussians).

    ijk             [M, 3] int64  unique voxel coordinates, ascending Morton order
    cloud           GaussianCloud with M Gaussians, positions = voxel centres (float32)
    importance      [M] float64   summed importance of each voxel's members
    origin          [3] float64   cube corner
    side            float         cube side length
    depth           int           octree depth d (2^d voxels per axis)
    merged_fraction float         1 - M / N  (share of Gaussians merged away)
    index_of_point  [N] int64     voxel (row of ijk) of every input Gaussian
    sh              [M, D] SH rest as :class:`SourcedRows` of the input's, or None: the SH rest
                    is ``cloud``'s (see ``voxelize(sourced_sh=)``; then ``cloud`` is SH degree 0
                    and :meth:`full_cloud` has the SH)
    sh_degree       the voxels' SH degree
    relocated       how many Gaussians moved to a neighbouring voxel instead of merging
    """

    ijk: np.ndarray
    cloud: GaussianCloud
    importance: np.ndarray
    origin: np.ndarray
    side: float
    depth: int
    merged_fraction: float
    index_of_point: np.ndarray
    sh: SourcedRows | None = None
    sh_degree: int = 0
    relocated: int = 0

    @property
    def pitch(self) -> float:
        """Voxel edge length ``side / 2^depth``."""
        return self.side / float(1 << self.depth)

    def full_cloud(self) -> GaussianCloud:
        """``cloud`` with its SH rest: when the grid holds its SH as rows of the input's, a
        :class:`MadeRows` gathering them a row range at a time as a render reads them (whole,
        1 GB at 6 M voxels)."""
        if self.sh is None:
            return self.cloud
        c, m, sh = self.cloud, len(self.ijk), self.sh
        rest = MadeRows((m, sh.shape[1] // 3, 3), lambda a, b: sh[a:b].reshape(b - a, -1, 3))
        return GaussianCloud(positions=c.positions, scales=c.scales, rotations=c.rotations,
                             opacities=c.opacities, sh_dc=c.sh_dc, sh_rest=rest,
                             sh_degree=self.sh_degree)


# --------------------------------------------------------------------------------------- grid
def _check_positions(positions) -> np.ndarray:
    x = np.asarray(positions)
    if x.ndim != 2 or x.shape[1] != 3:
        raise VoxelizeError(f"positions must be [N, 3], got shape {x.shape}")
    x = x.astype(np.float64)
    if x.size and not np.all(np.isfinite(x)):
        bad = int(np.argmax(~np.isfinite(x).all(axis=1)))
        raise VoxelizeError(f"non-finite Gaussian centre at index {bad}; cannot voxelise")
    return x


def _check_depth(depth) -> int:
    if isinstance(depth, bool) or not isinstance(depth, (int, np.integer)):
        raise VoxelizeError(f"octree depth must be an integer, got {depth!r}")
    if not 1 <= int(depth) <= MAX_DEPTH:
        raise VoxelizeError(f"octree depth must be in [1, {MAX_DEPTH}], got {depth}")
    return int(depth)


def bounding_cube(positions: np.ndarray) -> tuple[np.ndarray, float]:
    """The cube ``(origin [3] float64, side float)`` holding every centre.

    origin = per-axis minimum; side = largest per-axis extent * (1 + 2^-30).  A degenerate cloud
    (a single point, all points equal) gets side 1.0 (any positive side holds it), grown where
    float64 spacing at the centres needs more.  Raises VoxelizeError when float64 cannot hold a
    grid fine enough for the scene there (|coordinate| >> extent, e.g. a scene moved to x = 3e38).
    """
    x = _check_positions(positions)
    if x.shape[0] == 0:
        raise VoxelizeError("cannot build a bounding cube of zero points")
    lo, hi = x.min(axis=0), x.max(axis=0)
    extent = float((hi - lo).max())
    side = extent * (1.0 + CUBE_PAD) if extent > 0 else 1.0
    # Guard: at huge |origin| the padding could vanish in rounding; make sure max lands inside.
    # The small steps keep every cube that ever ended this way (same encoder bytes) ...
    for _ in range(PAD_STEPS):
        if not np.any(lo + side <= hi):
            return lo, side
        side = math.nextafter(side * (1.0 + CUBE_PAD), math.inf)
    # ... and past them, doubling steps of the coordinates' float64 spacing end in < 2100 steps.
    step = float(np.spacing(np.abs(np.concatenate([lo, hi])).max()))
    while np.any(lo + side <= hi):
        side += step
        step *= 2.0
        if not math.isfinite(side):
            raise VoxelizeError("Gaussian centres too large for a float64 voxel grid "
                                f"(|coordinate| up to {np.abs(x).max():.3g})")
    if extent > 0 and side > MAX_CUBE_GROWTH * extent:
        raise VoxelizeError(
            f"Gaussian centres span only {extent:.3g} at coordinates up to {np.abs(x).max():.3g}: "
            f"float64 needs a voxel cube of side {side:.3g} there, too coarse to keep the scene; "
            "move the scene near the origin (subtract its centre) and encode again")
    return lo, side


#: Rows of :func:`voxel_coords`' float64 temporaries at a time.
VOXEL_COORD_ROWS = 1 << 18


def voxel_coords(positions: np.ndarray, depth: int, origin: np.ndarray, side: float) -> np.ndarray:
    """Integer voxel coordinates ``floor((p - origin) / side * 2^d)`` clipped to [0, 2^d - 1].

    positions [N, 3]; returns [N, 3] int64.  Points outside the cube are clipped to its border
    voxels (the cube from :func:`bounding_cube` holds every point, so nothing is clipped then).
    """
    d = _check_depth(depth)
    x = _check_positions(positions)
    n = float(1 << d)
    origin, scale = np.asarray(origin, np.float64), n / float(side)
    out = np.empty(x.shape, np.int64)
    # in row steps: the float64 temporaries of a whole 6 M-Gaussian scene were 3 x 144 MB at
    # the search's memory peak (the next depth's voxelisation)
    for s in range(0, x.shape[0], VOXEL_COORD_ROWS):
        q = x[s:s + VOXEL_COORD_ROWS] - origin
        q *= scale
        np.floor(q, out=q)
        np.clip(q, 0, n - 1, out=q)
        out[s:s + VOXEL_COORD_ROWS] = q
    return out


def merge_fraction(positions: np.ndarray, depth: int, cube=None) -> float:
    """Share ``1 - M / N`` of Gaussians merged away when voxelising at ``depth``."""
    x = _check_positions(positions)
    if x.shape[0] == 0:
        return 0.0
    origin, side = bounding_cube(x) if cube is None else cube
    codes = morton_encode(voxel_coords(x, depth, origin, side))
    return 1.0 - np.unique(codes).size / x.shape[0]


def robust_diagonal(positions: np.ndarray) -> float:
    """Diagonal of the 1st..99th-percentile box of the centres (outlier-insensitive extent)."""
    x = _check_positions(positions)
    if x.shape[0] == 0:
        raise VoxelizeError("robust extent of zero points is undefined")
    lo, hi = np.percentile(x, ROBUST_PERCENTILES, axis=0)
    return float(np.linalg.norm(hi - lo))


def position_error(side: float, depth: int) -> float:
    """Worst-case decode error of a centre: half the voxel diagonal, sqrt(3)/2 * side / 2^d."""
    return math.sqrt(3.0) / 2.0 * float(side) / float(1 << depth)


def choose_depth(positions: np.ndarray, *, max_error: float | None = None,
                 rel_error: float = DEFAULT_REL_ERROR, max_merge: float | None = None,
                 min_depth: int = 6, max_depth: int = MAX_DEPTH, cube=None) -> int:
    """Smallest octree depth meeting the position-error budget.

    positions  [N, 3] centres (N >= 1)
    max_error  absolute budget on the half voxel diagonal (world units); overrides rel_error
    rel_error  budget relative to :func:`robust_diagonal` (default 5e-4, see module docstring)
    max_merge  optional extra requirement: merged fraction above the exact-duplicate floor
               (the fraction at max_depth) must be <= max_merge; depth grows until it is
    min_depth, max_depth  clamp of the result (1 <= min_depth <= max_depth <= 21)
    cube       (origin, side) of the grid; default :func:`bounding_cube`
    returns    int depth in [min_depth, max_depth]; max_depth if the budget is unreachable
    """
    x = _check_positions(positions)
    if x.shape[0] == 0:
        raise VoxelizeError("cannot choose an octree depth for zero points")
    lo_d, hi_d = _check_depth(min_depth), _check_depth(max_depth)
    if lo_d > hi_d:
        raise VoxelizeError(f"min_depth {lo_d} > max_depth {hi_d}")
    origin, side = bounding_cube(x) if cube is None else cube
    if max_error is not None:
        budget = float(max_error)
    else:
        if not (math.isfinite(rel_error) and rel_error > 0):
            raise VoxelizeError(f"rel_error must be a positive number, got {rel_error!r}")
        budget = rel_error * robust_diagonal(x)
    if not (math.isfinite(budget) and budget >= 0):
        raise VoxelizeError(f"position error budget must be finite and >= 0, got {budget!r}")
    depth = hi_d
    for d in range(lo_d, hi_d + 1):
        if position_error(side, d) <= budget:
            depth = d
            break
    if max_merge is not None:
        if not (0.0 <= max_merge <= 1.0):
            raise VoxelizeError(f"max_merge must be in [0, 1], got {max_merge!r}")
        floor = merge_fraction(x, hi_d, (origin, side))
        while depth < hi_d and merge_fraction(x, depth, (origin, side)) - floor > max_merge:
            depth += 1
    return depth


# -------------------------------------------------------------------------------------- merge
#: A Gaussian that shares its voxel with a more important one moves to a free neighbouring
#: voxel instead of merging where the voxel diagonal is at most this share of its thinnest
#: axis (e^min log-scale): there the shift (at most 1.5 voxels an axis, 3x the position error
#: every voxel has) is far below its size, while a merge drops a whole Gaussian.  Exact
#: duplicates are common (3.5 % of a graphdeco 7k-iteration scene, 0.3 % of an SPZ-grid one)
#: and merge at every depth, which capped the fidelity of any budget (docs/design/relocation.md).
RELOCATE_MAX_DIAGONAL = 0.25
#: The 26 neighbouring voxel offsets, in a fixed order (ties of distance keep it).
_NEIGHBOURS = np.array([(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)
                        if (i, j, k) != (0, 0, 0)], np.int64)


def _holds(sorted_codes: np.ndarray, c: np.ndarray) -> np.ndarray:
    """[len(c)] bool: which of ``c`` occur in the ascending ``sorted_codes``."""
    if sorted_codes.size == 0:
        return np.zeros(c.shape, bool)
    at = np.minimum(np.searchsorted(sorted_codes, c), sorted_codes.size - 1)
    return sorted_codes[at] == c


def relocate_extras(x: np.ndarray, ijk: np.ndarray, occupied: np.ndarray, inv: np.ndarray,
                    imp: np.ndarray, scales_of, depth: int, origin, side: float) -> int:
    """Move, in place in ``ijk`` [N, 3], every Gaussian that shares its voxel with a more
    important one (importance ``imp`` descending, then index) to the free neighbouring voxel
    whose centre is nearest its centre ``x``, where the voxel diagonal is at most
    RELOCATE_MAX_DIAGONAL of its thinnest axis (``scales_of(rows)`` gives their log-scales).
    Voxels are claimed in the order (voxel's Morton code, importance descending, index), one
    preference rank at a time, so the result is deterministic.  Gaussians left without a free
    neighbour stay (they merge).  ``occupied`` [M]: the ascending distinct Morton codes of
    ``ijk``, ``inv`` [N] each Gaussian's row of them; returns how many moved."""
    counts = np.bincount(inv, minlength=occupied.size)
    members = np.flatnonzero(counts[inv] > 1)
    members = members[np.lexsort((members, -imp[members], inv[members]))]
    grp = inv[members]
    extra = members[np.r_[False, grp[1:] == grp[:-1]]]       # all but each voxel's first
    pitch = float(side) / float(1 << depth)
    thinnest = np.exp(np.asarray(scales_of(extra), np.float64).min(axis=1))
    extra = extra[math.sqrt(3.0) * pitch <= RELOCATE_MAX_DIAGONAL * thinnest]
    if extra.size == 0:
        return 0
    # neighbours by the distance of their centre from the Gaussian's (in voxels)
    frac = (x[extra] - np.asarray(origin, np.float64)) / pitch - ijk[extra]
    dist = (((_NEIGHBOURS[None, :, :] + 0.5 - frac[:, None, :]) ** 2).sum(axis=2))
    prefs = np.argsort(dist, axis=1, kind="stable")
    left = np.arange(extra.size)
    claimed = np.zeros(0, np.uint64)         # voxels taken by moves (the occupied stay as given)
    top = (1 << depth) - 1
    for rank in range(_NEIGHBOURS.shape[0]):
        cand = ijk[extra[left]] + _NEIGHBOURS[prefs[left, rank]]
        inside = np.flatnonzero(((cand >= 0) & (cand <= top)).all(axis=1))
        c = morton_encode(cand[inside])
        open_ = ~_holds(occupied, c) & ~_holds(claimed, c)
        free, c = inside[open_], c[open_]
        _, win = np.unique(c, return_index=True)            # the first claim of a voxel wins
        win = np.sort(win)
        won = free[win]
        ijk[extra[left[won]]] = cand[won]
        claimed = np.union1d(claimed, c[win])
        left = np.delete(left, won)
        if left.size == 0:
            break
    return int(extra.size - left.size)


def _normalised_quaternions(q: np.ndarray) -> np.ndarray:
    q = q.astype(np.float64)
    norm = np.linalg.norm(q, axis=1, keepdims=True)
    # A zero quaternion is invalid input (validate() rejects it); treat it as identity so the
    # merge stays finite rather than spreading NaN into the voxel.
    ident = (norm[:, 0] == 0) | ~np.isfinite(norm[:, 0])
    norm[ident] = 1.0
    q = q / norm
    q[ident] = (1.0, 0.0, 0.0, 0.0)
    return q


def _matrix_to_quaternion(r: np.ndarray) -> np.ndarray:
    """Unit quaternions (w, x, y, z), w >= 0, of rotation matrices [M, 3, 3] (Shepperd's method:
    take the largest of 4w^2, 4x^2, 4y^2, 4z^2 as the pivot for stability)."""
    m00, m11, m22 = r[:, 0, 0], r[:, 1, 1], r[:, 2, 2]
    t = np.stack([1 + m00 + m11 + m22, 1 + m00 - m11 - m22,
                  1 - m00 + m11 - m22, 1 - m00 - m11 + m22], axis=1)
    k = np.argmax(t, axis=1)
    s = 2.0 * np.sqrt(np.maximum(t[np.arange(len(k)), k], 1e-300))
    a, b = r[:, 2, 1] - r[:, 1, 2], r[:, 0, 2] - r[:, 2, 0]
    c = r[:, 1, 0] - r[:, 0, 1]
    p01, p02, p12 = r[:, 0, 1] + r[:, 1, 0], r[:, 0, 2] + r[:, 2, 0], r[:, 1, 2] + r[:, 2, 1]
    cand = np.stack([
        np.stack([s / 4, a / s, b / s, c / s], 1),
        np.stack([a / s, s / 4, p01 / s, p02 / s], 1),
        np.stack([b / s, p01 / s, s / 4, p12 / s], 1),
        np.stack([c / s, p02 / s, p12 / s, s / 4], 1)], axis=1)
    q = cand[np.arange(len(k)), k]
    q *= np.where(q[:, :1] < 0, -1.0, 1.0)
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def voxelize(cloud: GaussianCloud, importance: np.ndarray, depth: int, cube=None,
             *, rotation: str = "moment", rows: np.ndarray | None = None,
             sourced_sh: bool = False, relocate: bool = True) -> Voxelized:
    """Snap every Gaussian to its voxel and merge Gaussians that share one.

    cloud       GaussianCloud, N >= 1 Gaussians
    rows        voxelise only these Gaussians of ``cloud`` (int [N] indices): the same result as
                ``voxelize(cloud.subset(rows), ...)`` without the subset's copy of every field
                (a pruned copy of a 6 M-Gaussian cloud is 1.4 GB)
    importance  [N] finite, >= 0 (merge weights; summed per voxel)
    depth       octree depth d in [1, 21]
    cube        (origin [3], side) grid; default :func:`bounding_cube` of the centres.  Points
                outside a user cube are clipped to the border voxels.
    rotation    "average" (sign-aligned weighted quaternion mean) or "max" (most important
                member's rotation)
    relocate    move a Gaussian that shares its voxel with a more important one to a free
                neighbouring voxel where that shift is small against its thinnest axis
                (:func:`relocate_extras`) instead of merging it
    sourced_sh  keep the voxels' SH rest as rows of ``cloud``'s (``Voxelized.sh``: a voxel
                holding one Gaussian refers to its row, only merged voxels own theirs) instead
                of gathering them into ``Voxelized.cloud`` (180 bytes a voxel at SH degree 3)
    returns     :class:`Voxelized`; deterministic (no RNG, order-stable reductions); every
                voxel's rotation and log-scales in their nearest-identity form
                (:mod:`gsz.encoder.orientation`: the same covariance, narrower Euler angles)
    """
    d = _check_depth(depth)
    x = _check_positions(cloud.positions if rows is None else cloud.positions[rows])
    n = x.shape[0]
    # row of cloud of each voxelised Gaussian (identity when rows is None)
    take = (lambda a, i: a[i]) if rows is None else (lambda a, i: a[rows[i]])
    if n == 0:
        raise VoxelizeError("cannot voxelise an empty cloud")
    imp = np.asarray(importance, dtype=np.float64)
    if imp.shape != (n,):
        raise VoxelizeError(f"importance must have shape ({n},), got {imp.shape}")
    if not np.all(np.isfinite(imp)) or (imp < 0).any():
        raise VoxelizeError("importance must be finite and >= 0")
    if rotation not in ("moment", "average", "max"):
        raise VoxelizeError(
            f"rotation merge must be 'moment', 'average' or 'max', got {rotation!r}")
    if cube is None:
        origin, side = bounding_cube(x)
    else:
        origin = np.asarray(cube[0], np.float64).reshape(3)
        side = float(cube[1])
        if not (np.all(np.isfinite(origin)) and math.isfinite(side) and side > 0):
            raise VoxelizeError(f"cube must have a finite origin and a side > 0, got {cube!r}")

    ijk_pt = voxel_coords(x, d, origin, side)
    codes = morton_encode(ijk_pt)
    # np.unique sorts: voxel rows come out in ascending Morton order.
    uniq, first, inv = np.unique(codes, return_index=True, return_inverse=True)
    del codes
    inv = inv.reshape(-1).astype(np.int64)
    moved = 0
    if relocate and first.size < n:
        moved = relocate_extras(x, ijk_pt, uniq, inv, imp, lambda i: take(cloud.scales, i), d, origin, side)
    if moved:
        _, first, inv = np.unique(morton_encode(ijk_pt), return_index=True, return_inverse=True)
        inv = inv.reshape(-1).astype(np.int64)
    # the per-Gaussian coordinates go before the per-voxel fields are made: at 6 M Gaussians
    # they are ~300 MB, and the next depth's voxelisation is the search's memory peak
    del x, uniq
    m = first.shape[0]
    ijk = ijk_pt[first]
    del ijk_pt
    counts = np.bincount(inv, minlength=m)

    # Singletons (the vast majority at a sensible depth) are copied bit-exactly (an index array
    # gathers into a fresh array: no second copy); their rotation and scales then change form
    # only where another form is nearer the identity.
    sourced = bool(sourced_sh) and cloud.sh_rest.shape[1] > 0
    out = {name: take(getattr(cloud, name), first)
           for name in ("scales", "rotations", "opacities", "sh_dc") + (() if sourced else ("sh_rest",))}
    own = np.zeros((0,) + cloud.sh_rest.shape[1:], np.float32)     # merged voxels' SH rest
    vox_imp = np.bincount(inv, weights=imp, minlength=m)

    multi = counts > 1
    if multi.any():
        # Members of multi-member voxels, grouped by voxel; within a voxel by importance
        # descending then index ascending, so the group's first row is its most important member.
        members = np.flatnonzero(multi[inv])
        order = np.lexsort((members, -imp[members], inv[members]))
        members = members[order]
        grp = inv[members]
        starts = np.flatnonzero(np.r_[True, grp[1:] != grp[:-1]])
        gvox = grp[starts]                              # voxel id of each group
        w = imp[members]
        wsum = np.add.reduceat(w, starts)
        # Voxels whose members are all invisible: equal weights.
        zero = np.repeat(wsum <= 0, np.diff(np.r_[starts, members.size]))
        w = np.where(zero, 1.0, w)
        wsum = np.add.reduceat(w, starts)

        def wmean(a: np.ndarray) -> np.ndarray:
            a = take(a, members).astype(np.float64).reshape(members.size, -1)
            return np.add.reduceat(a * w[:, None], starts, axis=0) / wsum[:, None]

        out["opacities"][gvox] = wmean(cloud.opacities).reshape(-1).astype(np.float32)
        out["scales"][gvox] = wmean(cloud.scales).astype(np.float32)
        out["sh_dc"][gvox] = wmean(cloud.sh_dc).astype(np.float32)
        if cloud.sh_rest.shape[1]:
            rest = wmean(cloud.sh_rest).reshape(-1, *cloud.sh_rest.shape[1:]).astype(np.float32)
            if sourced:
                own = rest             # gvox ascend: the merged voxels in voxel order
            else:
                out["sh_rest"][gvox] = rest

        q = _normalised_quaternions(take(cloud.rotations, members))
        ref = q[starts]                                 # most important member per voxel
        if rotation == "moment":
            # Moment matching: the weighted mean covariance, re-factorised as R diag(e^2s) R^T.
            r = quaternion_to_matrix(q)
            var = np.exp(2.0 * take(cloud.scales, members).astype(np.float64))
            cov = np.einsum("nij,nj,nkj->nik", r, var * w[:, None], r)
            cov = np.add.reduceat(cov, starts, axis=0) / wsum[:, None, None]
            evals, evecs = np.linalg.eigh(cov)
            evecs[np.linalg.det(evecs) < 0, :, 0] *= -1.0   # proper rotation (det +1)
            # lambda_min of a convex combination of PSD matrices is >= the combination of their
            # lambda_min: clamping there removes only rounding error (a flat member would
            # otherwise give a log of ~0 or a negative eigenvalue -> an extreme log-scale that
            # would wreck the scale channel's min-max quantiser range).
            floor = np.add.reduceat(var.min(axis=1) * w, starts) / wsum
            evals = np.maximum(evals, floor[:, None])
            out["scales"][gvox] = (0.5 * np.log(evals)).astype(np.float32)
            qm = _matrix_to_quaternion(evecs)
        elif rotation == "max":
            qm = ref
        else:
            ref_row = np.repeat(ref, np.diff(np.r_[starts, members.size]), axis=0)
            sign = np.where((q * ref_row).sum(axis=1) < 0, -1.0, 1.0)
            qm = np.add.reduceat(q * (sign * w)[:, None], starts, axis=0)
            # Every aligned member has a non-negative dot with ref, and ref's own weight is
            # > 0, so the sum cannot vanish; normalise.
            qm /= np.linalg.norm(qm, axis=1, keepdims=True)
        out["rotations"][gvox] = qm.astype(np.float32)

    # the Euler angles coded later are those of the nearest-identity form: a narrower range
    canonical_orientations(out["rotations"], out["scales"], out=(out["rotations"], out["scales"]))
    sh = None
    if sourced:
        # a voxel of one Gaussian refers to its row of the input (Stage.source), -1 when merged
        source = np.full(m, -1, np.int64)
        single = counts == 1
        source[single] = first[single] if rows is None else rows[first[single]]
        d_sh = 3 * cloud.sh_rest.shape[1]
        sh = SourcedRows(cloud.sh_rest.reshape(len(cloud), d_sh), source, own.reshape(len(own), d_sh))
        out["sh_rest"] = np.zeros((m, 0, 3), np.float32)
    merged = GaussianCloud(positions=centres_float32(ijk.T, origin, side, d),
                           sh_degree=0 if sourced else cloud.sh_degree, **out)
    return Voxelized(ijk=ijk, cloud=merged, importance=vox_imp, origin=np.asarray(origin, np.float64),
                     side=float(side), depth=d, merged_fraction=1.0 - m / n, index_of_point=inv,
                     sh=sh, sh_degree=cloud.sh_degree, relocated=moved)
