"""What one encode of the search produced: a calibration round's file (:class:`Encoded`) and a
compared candidate (:class:`Candidate`, the encode plus its train-view score)."""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ...decoder.cloud import GaussianCloud

from .tables import concat_bits


@dataclass(eq=False)
class Encoded:
    """One real encode of a stage under one bit allocation."""

    data: bytes | None            # the file; None once it can no longer be chosen (drop_data())
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
    sh_path: str | None = None    # "vq" (codebook + kept vectors at 8 bits), "classes" (the same, kept vectors in
    #                               importance classes, widths allocated) or "scalar"; None without SH
    depth: int = 0
    num_points: int = 0           # Gaussians (voxels) in the file
    layer0_points: int = 0
    geometry_bytes: int = 0
    size: int = -1                # len(data), kept when the bytes go

    def __post_init__(self):
        if self.size < 0:
            self.size = len(self.data)
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
    def rank(self) -> tuple:
        """Candidates compare by train PSNR, ties to the larger reserve."""
        return (self.train_psnr, self.reserve)

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
