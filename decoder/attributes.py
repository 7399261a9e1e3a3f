"""ATTR chunk: opacity, rotation, SH DC (through RAHT) and log-scales (direct) (GSZ.md §7).

Syntax::

    u8   rotation_mode      0 = Euler ZYX (roll, pitch, yaw), TRANSFORMS.md §1
    u8   R                  number of RAHT channels (= 7: opacity, roll, pitch, yaw, f_dc_0..2)
    f64  dc[R]              RAHT root coefficients, exact
    ChannelSet ac           C = R, L = M - 1: RAHT AC coefficients in level order (TRANSFORMS.md §2)
    ChannelSet direct       C = 3, L = M: log-scales in Morton point order

M is the GEOM chunk's voxel count.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .bytesio import Reader
from .groups import read_channel_set
from .layout import DIRECT_CHANNELS, RAHT_CHANNELS, ROTATION_EULER_ZYX
from .raht import RahtTree, raht_inverse
from .rotation import euler_to_quaternion


@dataclass
class Attributes:
    opacities: np.ndarray   # [M] float32 logits
    rotations: np.ndarray   # [M, 4] float32 unit quaternions (w, x, y, z)
    sh_dc: np.ndarray       # [M, 3] float32
    scales: np.ndarray      # [M, 3] float32 log-scales


def attributes_from_channels(raht_values: np.ndarray, direct: np.ndarray) -> Attributes:
    """Map decoded channels to Gaussian fields: raht_values [M, 7] (RAHT_CHANNELS order),
    direct [3, M] (log-scales).  The encoder uses the same mapping to predict its output."""
    return Attributes(
        opacities=raht_values[:, 0].astype(np.float32),
        rotations=euler_to_quaternion(raht_values[:, 1:4]).astype(np.float32),
        sh_dc=raht_values[:, 4:7].astype(np.float32),
        scales=np.ascontiguousarray(direct.T, dtype=np.float32))


def read_attributes(data, tree: RahtTree) -> Attributes:
    m = tree.num_points
    r = Reader(data, "ATTR chunk")
    mode = r.u8()
    r.check(mode == ROTATION_EULER_ZYX, f"unknown rotation mode {mode}")
    nr = r.u8()
    r.check(nr == len(RAHT_CHANNELS), f"expected {len(RAHT_CHANNELS)} RAHT channels, got {nr}")
    dc = r.array(np.float64, nr)
    r.check(bool(np.all(np.isfinite(dc))), "non-finite RAHT DC coefficient")
    ac = read_channel_set(r, max_length=m)
    r.check(ac.shape == (nr, m - 1), f"RAHT AC set has shape {ac.shape}, expected ({nr}, {m - 1})")
    direct = read_channel_set(r, max_length=m)
    r.check(direct.shape == (len(DIRECT_CHANNELS), m),
            f"direct channel set has shape {direct.shape}, expected ({len(DIRECT_CHANNELS)}, {m})")
    r.expect_end()
    return attributes_from_channels(raht_inverse(dc, ac.T, tree), direct)
