"""The in-memory form of a 3DGS scene: :class:`GaussianCloud` (numpy only)."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .errors import CloudValidationError

#: Number of higher-order SH coefficients per colour channel for SH degree 0..3.
SH_REST_COUNT = {0: 0, 1: 3, 2: 8, 3: 15}


def sh_rest_count(degree: int) -> int:
    """K = (d+1)^2 - 1 coefficients per colour channel beyond the DC term."""
    if degree not in SH_REST_COUNT:
        raise CloudValidationError(f"SH degree must be 0..3, got {degree}")
    return SH_REST_COUNT[degree]


class OutputRows:
    """Where a decoded part's float32 fields go: rows [start, stop) of a whole cloud's arrays
    {field: array}, or fresh arrays (:data:`FRESH`).  Decoding a tiled or layered file straight
    into the final arrays spares concatenating its parts afterwards: a serial copy of every
    field into memory touched for the first time."""

    def __init__(self, arrays: dict | None = None, start: int = 0, stop: int = 0):
        self.arrays, self.start, self.stop = arrays, start, stop

    def empty(self, name: str, shape: tuple) -> np.ndarray:
        """An uninitialised float32 array of ``shape`` for field ``name``: these rows when they
        have that many elements per row (a view, reshaped), else a fresh array."""
        a = None if self.arrays is None else self.arrays.get(name)
        if a is not None and shape and shape[0] == self.stop - self.start \
                and int(np.prod(shape[1:])) == int(np.prod(a.shape[1:])):
            return a[self.start:self.stop].reshape(shape)
        return np.empty(shape, np.float32)

    def holds(self, name: str, arr: np.ndarray) -> bool:
        """Is ``arr`` these rows of field ``name`` (written in place)?"""
        a = None if self.arrays is None else self.arrays.get(name)
        if a is None:
            return False
        rows = a[self.start:self.stop]
        return (arr.dtype == rows.dtype and arr.size == rows.size and arr.flags.c_contiguous
                and arr.__array_interface__["data"][0] == rows.__array_interface__["data"][0])


#: fresh arrays for every field
FRESH = OutputRows()

#: rows per step where a :class:`MadeRows` is made whole (np.asarray)
MADE_ROWS_STEP = 1 << 16


class MadeRows:
    """A read-only float32 array [N, ...] made a row range at a time: ``rows(start, stop)``
    gives rows start..stop as an ndarray.  A field its consumer reads in row steps -- the
    renderer's SH colours (:func:`gsz.evaluation.render.render`) -- so never exists whole (a
    candidate's decoded SH rest: 1 GB at 6 M Gaussians).  A plain row slice makes those rows;
    any other index, and ``np.asarray``, makes the whole array first."""

    dtype = np.dtype(np.float32)

    def __init__(self, shape: tuple, rows):
        self.shape = tuple(int(v) for v in shape)
        self.ndim = len(self.shape)
        self.size = int(np.prod(self.shape))
        self._rows = rows

    def __len__(self) -> int:
        return self.shape[0]

    def rows(self, start: int, stop: int) -> np.ndarray:
        """float32 [stop - start, ...]: rows start..stop (clipped to the array)."""
        start, stop = max(0, int(start)), min(self.shape[0], int(stop))
        stop = max(start, stop)
        out = np.asarray(self._rows(start, stop), dtype=np.float32)
        if out.shape != (stop - start,) + self.shape[1:]:
            raise ValueError(f"MadeRows: rows({start}, {stop}) gave shape {out.shape}, expected "
                             f"{(stop - start,) + self.shape[1:]}")
        return out

    def __getitem__(self, key) -> np.ndarray:
        if isinstance(key, slice) and key.step in (None, 1):
            start, stop, _ = key.indices(self.shape[0])
            return self.rows(start, stop)
        return np.asarray(self)[key]

    def __array__(self, dtype=None, copy=None):
        out = np.empty(self.shape, np.float32)
        for s in range(0, self.shape[0], MADE_ROWS_STEP):
            out[s:s + MADE_ROWS_STEP] = self.rows(s, s + MADE_ROWS_STEP)
        return out if dtype is None else out.astype(dtype, copy=False)


class ColourRows(MadeRows):
    """An SH rest [N, K, 3] held in another colour space: its rows are ``coded``'s rows (an
    array or a :class:`MadeRows` of the same shape) times ``matrix`` (float32 [3, 3], a row
    triplet ``c`` becomes ``c @ matrix``).  SH colour is linear in the SH rest, so the renderer
    turns each Gaussian's view-dependent colour instead and reads ``coded`` as it is: no row
    range is made, and a whole ``coded`` takes the renderer's whole-array path."""

    def __init__(self, coded, matrix):
        self.coded = coded
        self.matrix = np.ascontiguousarray(matrix, np.float32)
        if self.matrix.shape != (3, 3) or coded.ndim != 3 or coded.shape[2] != 3:
            raise ValueError(f"ColourRows: a [N, K, 3] field and a [3, 3] matrix expected, got "
                             f"{coded.shape} and {self.matrix.shape}")

        def rows(s: int, e: int) -> np.ndarray:
            r = np.asarray(coded[s:e], np.float32)
            return (r.reshape(-1, 3) @ self.matrix).reshape(r.shape)
        super().__init__(coded.shape, rows)


@dataclass
class GaussianCloud:
    """A 3D Gaussian Splatting scene as float32 numpy arrays, in pre-activation form.

    Shapes and dtypes (N Gaussians, K = (d+1)^2 - 1):

    ========== ========== ===============================================================
    field      shape      meaning
    ========== ========== ===============================================================
    positions  [N, 3] f32 centres x, y, z
    scales     [N, 3] f32 natural log of the per-axis standard deviation
    rotations  [N, 4] f32 quaternion (w, x, y, z), not necessarily unit length
    opacities  [N]    f32 logit of alpha
    sh_dc      [N, 3] f32 SH degree-0 coefficient per colour channel (RGB)
    sh_rest    [N,K,3]f32 higher-order SH, coefficient-major, RGB last
    sh_degree  int        0..3
    ========== ========== ===============================================================

    ``sh_rest`` may be a :class:`MadeRows` (kept as it is): a scene made to be rendered, whose
    SH rest is made row range by row range as the renderer reads it.
    """

    positions: np.ndarray
    scales: np.ndarray
    rotations: np.ndarray
    opacities: np.ndarray
    sh_dc: np.ndarray
    sh_rest: np.ndarray
    sh_degree: int
    extra: dict = field(default_factory=dict, compare=False, repr=False)

    def __repr__(self) -> str:
        # short: a cloud's arrays would print millions of numbers
        n = len(self.positions)
        box = ""
        if n:
            lo, hi = self.positions.min(0), self.positions.max(0)
            box = f", bbox [{lo[0]:.3g} {lo[1]:.3g} {lo[2]:.3g}] .. [{hi[0]:.3g} {hi[1]:.3g} {hi[2]:.3g}]"
        return f"GaussianCloud({n:,} Gaussians, SH degree {self.sh_degree}{box})"

    def __post_init__(self):
        self.positions = np.ascontiguousarray(self.positions, dtype=np.float32)
        self.scales = np.ascontiguousarray(self.scales, dtype=np.float32)
        self.rotations = np.ascontiguousarray(self.rotations, dtype=np.float32)
        self.opacities = np.ascontiguousarray(self.opacities, dtype=np.float32).reshape(-1)
        self.sh_dc = np.ascontiguousarray(self.sh_dc, dtype=np.float32)
        k = sh_rest_count(int(self.sh_degree))
        self.sh_degree = int(self.sh_degree)
        if isinstance(self.sh_rest, MadeRows):
            return
        sr = np.asarray(self.sh_rest, dtype=np.float32)
        if sr.size == 0 and k == 0:
            sr = np.zeros((self.positions.shape[0], 0, 3), np.float32)
        self.sh_rest = np.ascontiguousarray(sr)

    def __len__(self) -> int:
        return int(self.positions.shape[0])

    @property
    def num_gaussians(self) -> int:
        return len(self)

    def validate(self, check_finite: bool = True, name: str | None = None) -> "GaussianCloud":
        """Check shapes, degree and (optionally) that every value is finite.

        Raises :class:`CloudValidationError` naming the offending field; returns ``self``.
        """
        n = self.positions.shape[0] if self.positions.ndim == 2 else -1
        k = sh_rest_count(self.sh_degree)
        expected = {
            "positions": (n, 3),
            "scales": (n, 3),
            "rotations": (n, 4),
            "opacities": (n,),
            "sh_dc": (n, 3),
            "sh_rest": (n, k, 3),
        }
        for fname, shape in expected.items():
            arr = getattr(self, fname)
            if arr.shape != shape:
                raise CloudValidationError(
                    f"field '{fname}' has shape {arr.shape}, expected {shape} "
                    f"(N={n}, SH degree {self.sh_degree})", name)
        if check_finite:
            for fname in expected:
                arr = getattr(self, fname)
                bad = ~np.isfinite(arr)
                if bad.any():
                    idx = int(np.argwhere(bad.reshape(len(arr), -1).any(axis=1))[0, 0]) if len(arr) else 0
                    raise CloudValidationError(
                        f"field '{fname}' has {int(bad.sum())} non-finite values (first at Gaussian {idx})",
                        name)
            zero_q = ~(np.abs(self.rotations).sum(axis=1) > 0)
            if zero_q.any():
                raise CloudValidationError(
                    f"{int(zero_q.sum())} Gaussians have an all-zero quaternion "
                    f"(first at {int(np.argmax(zero_q))})", name)
        return self

    def subset(self, index) -> "GaussianCloud":
        """A new cloud holding the Gaussians selected by ``index`` (mask or integer array)."""
        return GaussianCloud(
            positions=self.positions[index], scales=self.scales[index],
            rotations=self.rotations[index], opacities=self.opacities[index],
            sh_dc=self.sh_dc[index], sh_rest=self.sh_rest[index], sh_degree=self.sh_degree)

    def with_sh_degree(self, degree: int) -> "GaussianCloud":
        """A copy truncated (or zero-padded) to SH degree ``degree``."""
        k_new = sh_rest_count(degree)
        k_old = self.sh_rest.shape[1]
        if k_new <= k_old:
            rest = self.sh_rest[:, :k_new]
        else:
            rest = np.zeros((len(self), k_new, 3), np.float32)
            rest[:, :k_old] = self.sh_rest
        return GaussianCloud(self.positions, self.scales, self.rotations, self.opacities,
                             self.sh_dc, rest, degree)

    def copy(self) -> "GaussianCloud":
        return GaussianCloud(self.positions.copy(), self.scales.copy(), self.rotations.copy(),
                             self.opacities.copy(), self.sh_dc.copy(), self.sh_rest.copy(),
                             self.sh_degree)

    def equals(self, other: "GaussianCloud") -> bool:
        """Bit-exact equality of every array and the SH degree."""
        return (self.sh_degree == other.sh_degree and len(self) == len(other) and all(
            np.array_equal(getattr(self, f), getattr(other, f))
            for f in ("positions", "scales", "rotations", "opacities", "sh_dc", "sh_rest")))
