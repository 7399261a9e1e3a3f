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

from . import native
from .bytesio import Reader
from .groups import read_channel_set
from .layout import DIRECT_CHANNELS, RAHT_CHANNELS, ROTATION_EULER_ZYX
from .raht import RahtTree, build_raht_tree, raht_inverse
from .rotation import euler_to_quaternion, half_angle_trig


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


def parse_attributes(data, m: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Entropy-decode an ATTR chunk of ``m`` points (no geometry needed yet): returns the RAHT
    DC float64 [R], AC float64 [R, m - 1] (stream order) and direct channels float64 [3, m]."""
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
    return dc, ac, direct


def attributes_from_coefficients(dc: np.ndarray, ac: np.ndarray, direct: np.ndarray,
                                 codes: np.ndarray, depth: int) -> Attributes:
    """Inverse RAHT over the voxels with Morton codes ``codes`` (ascending) and the mapping to
    Gaussian fields.  With the native accelerator: the tree, the inverse transform and the
    float32 conversions in C, cos/sin still NumPy's on the same arrays (bit-identical)."""
    if not native.enabled():
        tree = build_raht_tree(codes, depth)
        return attributes_from_channels(raht_inverse(dc, ac.T, tree), direct)
    nat = native.module()
    m = int(codes.shape[0])
    v = np.empty((m, len(RAHT_CHANNELS)), np.float64)
    nat.raht_inverse(np.ascontiguousarray(codes, dtype=np.uint64), int(depth),
                     np.ascontiguousarray(dc, dtype=np.float64),
                     np.ascontiguousarray(ac, dtype=np.float64), v)
    opacities = np.empty(m, np.float32)
    sh_dc = np.empty((m, 3), np.float32)
    half = np.empty((3, m), np.float64)
    nat.attr_split(v, opacities, sh_dc, half)
    c, s = half_angle_trig(half)
    rotations = np.empty((m, 4), np.float32)
    nat.quat_from_trig(c, s, rotations)
    return Attributes(opacities=opacities, rotations=rotations, sh_dc=sh_dc,
                      scales=np.ascontiguousarray(direct.T, dtype=np.float32))


def read_attributes(data, tree: RahtTree) -> Attributes:
    dc, ac, direct = parse_attributes(data, tree.num_points)
    return attributes_from_channels(raht_inverse(dc, ac.T, tree), direct)
