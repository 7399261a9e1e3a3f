"""What one encode of the search produced: a calibration round's file (:class:`Encoded`) and a
compared candidate (:class:`Candidate`, the encode plus its train-view score)."""
from __future__ import annotations

import tempfile
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ...decoder.cloud import GaussianCloud

from .tables import concat_bits

#: An encode's file of at least this many bytes waits in an anonymous temporary file until it is
#: asked for (the chosen one, once): a search holds the best candidate's file and the one being
#: judged, 2 x 124 MB at 6 M Gaussians, beside the judged render that is its memory peak.
SPILL_BYTES = 32 << 20

#: dB of train PSNR a unit of tau is worth in a candidate's rank: the train views choose what
#: pruning removes (the importance pass) and then judge the result, so a candidate that prunes
#: more wins them by a margin it does not keep on other views (docs/design/tau-preference.md)
TAU_PREFERENCE_DB = 2.0


@dataclass(eq=False)
class Encoded:
    """One real encode of a stage under one bit allocation."""

    data: bytes | None = field(repr=False)   # the file; None once it can no longer be chosen
    #                                          (drop_data()); at SPILL_BYTES+ kept on disk
    scene: Callable | None        # makes the decoded scene (.cloud); None once released (release())
    pick: np.ndarray              # the solver's choice per group (bit-width - 1)
    layer_bits: list              # per layer (raht_bits [7, B_l], scale_bits [3, B_l])
    kept_bits: list               # per layer the kept SH vectors' widths [D, B_l], or None (SH_BITS)
    sh_bytes: int
    attr_stats: dict
    attr_bytes: int
    meta_bytes: int
    predicted_bytes: float
    loss: float
    # set on the round a tau's calibration settles on (tau.encode_tau)
    rounds: list = field(default_factory=list)
    attributes_saturated: bool = False   # every attribute group at its best width, bytes left
    sh_keep: int | None = None    # exact SH vectors kept; None without SH
    codebook_size: int = 0
    codebook_bits: int | None = None  # the codebook's width a component (SearchOptions.codebook_bits)
    sh_path: str | None = None    # "vq" (codebook + kept vectors at 8 bits), "classes" (the same, kept vectors in
    #                               importance classes, widths allocated), "scalar" or "refine" (every vector
    #                               its codeword + an allocated correction); None without SH
    depth: int = 0
    num_points: int = 0           # Gaussians (voxels) in the file
    layer0_points: int = 0
    geometry_bytes: int = 0
    size: int = -1                # len(data), kept when the bytes go

    def __post_init__(self):
        if self.size < 0:
            self.size = self._len
        self._cloud = None

    @property
    def cloud(self) -> GaussianCloud | None:
        """The decoded scene, made when first asked for (None once released)."""
        if self._cloud is None and self.scene is not None:
            self._cloud = self.scene()
        return self._cloud

    def release(self) -> None:
        """Drop the decoded scene: a search keeps many encodes, and the file's bytes decode
        to it again where it is needed (the chosen one)."""
        self.scene = self._cloud = None

    def drop_data(self) -> None:
        """Drop the decoded scene and the file's bytes (an encode that can no longer be chosen:
        at 6 M Gaussians each file is ~120 MB, and a search makes dozens)."""
        self.release()
        self.data = None

    def _get_data(self) -> bytes | None:
        if self._spill is not None:
            self._spill.seek(0)
            return self._spill.read()
        return self._bytes

    def _set_data(self, value: bytes | None) -> None:
        spill = getattr(self, "_spill", None)
        if spill is not None:
            spill.close()                       # the temporary file goes with it
        self._spill, self._bytes = None, None
        self._len = 0 if value is None else len(value)
        if value is not None and len(value) >= SPILL_BYTES:
            try:
                f = tempfile.TemporaryFile(prefix="gsz-candidate-")
                f.write(value)
                self._spill = f
                return
            except OSError:                     # no room for it on disk: held in memory
                self._spill = None
        self._bytes = value

    @property
    def raht_bits(self) -> np.ndarray:
        """[7, sum B_l]: every layer's RAHT groups side by side."""
        return concat_bits(self.layer_bits)[0]

    @property
    def scale_bits(self) -> np.ndarray:
        """[3, sum B_l]: every layer's scale groups side by side."""
        return concat_bits(self.layer_bits)[1]

    def mean_attribute_bits(self) -> float:
        return float(np.mean(np.concatenate([self.raht_bits.ravel(), self.scale_bits.ravel()])))


# the file's bytes live behind a property (set by the dataclass __init__ like any field)
Encoded.data = property(Encoded._get_data, Encoded._set_data)


@dataclass(eq=False)
class Candidate:
    """An encoded (reserve, depth, layer split) and its score on the train views."""

    train_psnr: float
    reserve: float
    depth: int
    first_layer: float
    view_psnr: list               # per train view
    encoded: Encoded
    layer0_too_late: bool = False  # a re-split variant of it was tried (layers.resplit_layer0)

    @property
    def score(self) -> float:
        """Train PSNR with the larger reserve's preference (TAU_PREFERENCE_DB a unit of tau)."""
        return self.train_psnr + TAU_PREFERENCE_DB * self.reserve

    @property
    def rank(self) -> tuple:
        """Candidates compare by :attr:`score`, ties to the larger reserve."""
        return (self.score, self.reserve)

    @property
    def data(self) -> bytes | None:
        return self.encoded.data

    @property
    def size(self) -> int:
        """The file's bytes (kept when the bytes themselves are dropped)."""
        return self.encoded.size


def best_of(candidates) -> Candidate:
    """The best candidate (the first of equals, as max() picks)."""
    return max(candidates, key=lambda c: c.rank)
