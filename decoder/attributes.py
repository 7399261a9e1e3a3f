"""ATTR chunk: opacity, rotation, SH DC (through RAHT) and log-scales (direct) (GSZ.md §7).

Syntax::

    u8   rotation_mode      0 = Euler ZYX (roll, pitch, yaw), TRANSFORMS.md §1
    u8   R                  number of RAHT channels (= 7: opacity, roll, pitch, yaw, f_dc_0..2)
    f64  dc[R]              RAHT root coefficients, exact
    ChannelSet ac           C = R, L = M - 1: RAHT AC coefficients in level order (TRANSFORMS.md §2)
    ChannelSet direct       C = 3, L = M: log-scales in Morton point order

M is the GEOM chunk's voxel count.

RWGT chunk (format 1.5, optional per part, GSZ.md §7.1): integer leaf weights of the part's RAHT
tree, so that the transform's coefficient errors are importance-weighted errors (TRANSFORMS.md
§2.1)::

    u8   Q                  classes, 2..16
    u16  weights[Q]         1..65535
    blob classes            RansStream of M symbols (model id 0), values 0..Q-1, point order

With RWGT the ATTR chunk's direct set (log-scales) is stored in class order (class_order of the
classes), so its blocks can follow the classes.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from . import native
from .bytesio import Reader
from .cloud import FRESH, OutputRows
from .groups import read_channel_set
from .rans import decode_stream_single
from .layout import DIRECT_CHANNELS, RAHT_CHANNELS, ROTATION_EULER_ZYX
from .raht import RahtTree, build_raht_tree, raht_inverse, raht_inverse_planes
from .rotation import euler_to_quaternion, half_angle_trig, quaternion_f32_from_trig


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


def _attributes_from_planes(v: np.ndarray, direct: np.ndarray, dest: OutputRows = FRESH) -> Attributes:
    """:func:`attributes_from_channels` of ``v.T``, from the channel-major values v float64
    [7, M] (``raht_inverse_planes``): the same values bit for bit, with cos/sin on the same
    contiguous [3, M] half angles as :func:`euler_to_quaternion`; the fields go to ``dest``."""
    ang = v[1:4]
    half = np.where(np.isfinite(ang), ang, 0.0)
    half *= 0.5
    c, s = half_angle_trig(half)
    m = v.shape[1]
    return Attributes(opacities=_f32(dest.empty("opacities", (m,)), v[0]),
                      rotations=quaternion_f32_from_trig(c, s, dest.empty("rotations", (m, 4))),
                      sh_dc=_f32(dest.empty("sh_dc", (m, 3)), v[4:7].T),
                      scales=_f32(dest.empty("scales", (m, 3)), direct.T))


def _f32(out: np.ndarray, values: np.ndarray) -> np.ndarray:
    """``values`` cast to float32 into ``out`` (the same rounding as ``astype``)."""
    out[...] = values
    return out


def numpy_colour(dc: np.ndarray, ac: np.ndarray, tree: RahtTree,
                 dest: OutputRows = FRESH) -> tuple[np.ndarray, np.ndarray]:
    """(opacities float32 [M], sh_dc float32 [M, 3]) of :func:`_attributes_from_planes`, from
    the inverse RAHT of those four channels only (each channel's values are the same)."""
    v = raht_inverse_planes(dc, ac, tree, channels=(0, 4, 5, 6))
    m = v.shape[1]
    return _f32(dest.empty("opacities", (m,)), v[0]), _f32(dest.empty("sh_dc", (m, 3)), v[1:4].T)


def numpy_half_angles(dc: np.ndarray, ac: np.ndarray, tree: RahtTree) -> np.ndarray:
    """The half angles float64 [3, M] (contiguous) of :func:`_attributes_from_planes`, from
    the inverse RAHT of the three angle channels only; NumPy's cos and sin of this array (on
    any thread, :func:`half_angle_trig`) and ``quaternion_f32_from_trig`` give its rotations."""
    ang = raht_inverse_planes(dc, ac, tree, channels=(1, 2, 3))
    half = np.where(np.isfinite(ang), ang, 0.0)
    half *= 0.5
    return half


def parse_attributes(data, m: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Entropy-decode an ATTR chunk of ``m`` points (no geometry needed yet): returns the RAHT
    DC float64 [R], AC float64 [R, m - 1] (stream order) and direct channels float64 [3, m]."""
    dc, ac, r = parse_raht_part(data, m)
    return dc, ac, parse_direct_part(r, m)


def parse_raht_part(data, m: int) -> tuple[np.ndarray, np.ndarray, Reader]:
    """:func:`parse_attributes` up to the direct channel set: (DC, AC, the reader at the direct
    set), so that another thread can decode that set (:func:`parse_direct_part`)."""
    r = Reader(data, "ATTR chunk")
    mode = r.u8()
    r.check(mode == ROTATION_EULER_ZYX, f"unknown rotation mode {mode}")
    nr = r.u8()
    r.check(nr == len(RAHT_CHANNELS), f"expected {len(RAHT_CHANNELS)} RAHT channels, got {nr}")
    dc = r.array(np.float64, nr)
    r.check(bool(np.all(np.isfinite(dc))), "non-finite RAHT DC coefficient")
    ac = read_channel_set(r, max_length=m, shape=(nr, m - 1), name="RAHT AC set")
    return dc, ac, r


def parse_direct_part(r: Reader, m: int) -> np.ndarray:
    """The rest of :func:`parse_attributes` from ``r`` (:func:`parse_raht_part`'s reader): the
    direct channels float64 [3, m], then nothing after them."""
    direct = read_channel_set(r, max_length=m, shape=(len(DIRECT_CHANNELS), m), name="direct channel set")
    r.expect_end()
    return direct


def attributes_from_coefficients(dc: np.ndarray, ac: np.ndarray, direct: np.ndarray,
                                 codes: np.ndarray, depth: int, tree=None,
                                 leaf_weights: np.ndarray | None = None,
                                 dest: OutputRows = FRESH) -> Attributes:
    """Inverse RAHT over the voxels with Morton codes ``codes`` (ascending) and the mapping to
    Gaussian fields.  With the native accelerator: the tree, the inverse transform and the
    float32 conversions in C, cos/sin still NumPy's on the same arrays (bit-identical).
    ``tree``: the NumPy path's ``build_raht_tree(codes, depth, leaf_weights)`` when made already;
    ``leaf_weights``: the part's RWGT leaf weights (None: all 1); the fields go to ``dest``."""
    if not native.enabled():
        tree = build_raht_tree(codes, depth, leaf_weights) if tree is None else tree
        return _attributes_from_planes(raht_inverse_planes(dc, ac, tree), direct, dest)
    tree = native_tree(codes, depth, leaf_weights)
    half = native_half_angles(tree, dc, ac)
    opacities, sh_dc, _ = native_opacity_dc(tree, dc, ac, dest)
    c, s = half_angle_trig(half)
    rotations, _ = native_rotations(c, s, dest)
    scales, _ = native_scales(direct, dest)
    return Attributes(opacities=opacities, rotations=rotations, sh_dc=sh_dc, scales=scales)


#: most classes an RWGT chunk may declare
MAX_RAHT_CLASSES = 16


@dataclass
class RahtWeights:
    """A part's RWGT chunk: ``classes`` int64 [M] (point order), ``weights`` int64 [Q]."""
    classes: np.ndarray
    weights: np.ndarray

    @property
    def leaf_weights(self) -> np.ndarray:
        """int64 [M]: each point's RAHT leaf weight."""
        return self.weights[self.classes]

    @functools.cached_property
    def order(self) -> np.ndarray:
        """int64 [M]: the point of each stored element of the part's direct set (class order:
        classes ascending, point order within a class; GSZ.md §7.1)."""
        from .sh import class_order
        return class_order(self.classes)


def direct_in_point_order(direct: np.ndarray, rwgt) -> np.ndarray:
    """The direct channels [3, M] as decoded (class order when the part has an RWGT chunk) in
    point order."""
    if rwgt is None:
        return direct
    out = np.empty_like(direct)
    out[:, rwgt.order] = direct
    return out


def read_raht_weights(data, num_points: int) -> RahtWeights:
    """Decode an RWGT chunk (GSZ.md §7.1) of a part of ``num_points`` voxels."""
    r = Reader(data, "RWGT chunk")
    q = r.u8()
    r.check(2 <= q <= MAX_RAHT_CLASSES, f"RAHT weight class count {q} outside 2..{MAX_RAHT_CLASSES}")
    weights = r.array(np.dtype("<u2"), q).astype(np.int64)
    r.check(bool(np.all(weights >= 1)), "RAHT class weight 0 (must be 1..65535)")
    classes = decode_stream_single(r.blob(), num_points)
    r.check(bool(np.all((classes >= 0) & (classes < q))), f"RAHT weight class outside 0..{q - 1}")
    r.expect_end()
    return RahtWeights(classes=classes.astype(np.int64, copy=False), weights=weights)


def leaf_weights_of(rwgt) -> np.ndarray | None:
    """int64 [M] leaf weights of a part's decoded RWGT (None: no chunk, every leaf weighs 1)."""
    return None if rwgt is None else np.ascontiguousarray(rwgt.leaf_weights, dtype=np.int64)


# ---- native stages (decode.decode_layer runs them on two threads) ---------------------------
# RAHT channel layout: 0 opacity, 1..3 roll/pitch/yaw, 4..6 f_dc_0..2 (RAHT_CHANNELS).
def native_tree(codes: np.ndarray, depth: int, leaf_weights: np.ndarray | None = None):
    """The C RAHT tree of the voxels with Morton codes ``codes`` (opaque, for the stages below);
    ``leaf_weights`` int64 [M] of an RWGT chunk, or None."""
    w = None if leaf_weights is None else np.ascontiguousarray(leaf_weights, dtype=np.int64)
    return native.module().raht_tree(np.ascontiguousarray(codes, dtype=np.uint64), int(depth), w)


def native_half_angles(tree, dc: np.ndarray, ac: np.ndarray) -> np.ndarray:
    """Inverse RAHT of the three angle channels -> their half angles float64 [3, M] (non-finite
    angles replaced by 0, as euler_to_quaternion does), in a fresh array (cos/sin then run on
    the same kind of array as on the NumPy path)."""
    half = np.empty((3, tree_points(ac)), np.float64)
    native.module().raht_apply(tree, dc, ac, 1, 4, half, True)
    return half


def native_opacity_dc(tree, dc: np.ndarray, ac: np.ndarray, dest: OutputRows = FRESH):
    """Inverse RAHT of the opacity and DC colour channels -> (opacities float32 [M], sh_dc
    float32 [M, 3], all finite?)."""
    nat = native.module()
    m = tree_points(ac)
    v = np.empty((4, m), np.float64)
    nat.raht_apply(tree, dc, ac, 0, 1, v[:1], False)
    nat.raht_apply(tree, dc, ac, 4, 7, v[1:], False)
    opacities = dest.empty("opacities", (m,))
    sh_dc = dest.empty("sh_dc", (m, 3))
    ok = nat.planes_to_f32(v, 0, 1, opacities)
    ok = nat.planes_to_f32(v, 1, 4, sh_dc) and ok
    return opacities, sh_dc, ok


def native_rotations(c: np.ndarray, s: np.ndarray, dest: OutputRows = FRESH):
    """Quaternions float32 [M, 4] from cos/sin of the half angles, and whether all are finite."""
    rotations = dest.empty("rotations", (c.shape[1], 4))
    ok = native.module().quat_from_trig(c, s, rotations)
    return rotations, ok


def native_scales(direct: np.ndarray, dest: OutputRows = FRESH):
    """The log-scales float32 [M, 3] from the direct channels float64 [3, M], all finite?"""
    scales = dest.empty("scales", (direct.shape[1], 3))
    ok = native.module().planes_to_f32(np.ascontiguousarray(direct, dtype=np.float64), 0, 3, scales)
    return scales, ok


def tree_points(ac: np.ndarray) -> int:
    return int(ac.shape[1]) + 1


def read_attributes(data, tree: RahtTree) -> Attributes:
    dc, ac, direct = parse_attributes(data, tree.num_points)
    return attributes_from_channels(raht_inverse(dc, ac.T, tree), direct)
