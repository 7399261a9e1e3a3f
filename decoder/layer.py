"""One layer's decoding and the helpers both whole-file and streaming decoding share.

:func:`decode_layer` turns one layer's chunk payloads into a :class:`GaussianCloud` (on two
threads with the native accelerator); :func:`plan_layers` checks a chunk table's layer
structure; :func:`guard` turns low-level errors on malformed data into one GszFormatError.
Used by :mod:`gsz.decoder.decode` (whole files) and :mod:`gsz.decoder.stream` (progressive).
numpy only.
"""
from __future__ import annotations

import os
import struct
import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from . import native
from .attributes import (attributes_from_coefficients, native_half_angles, native_opacity_dc,
                         native_rotations, native_scales, native_tree, parse_attributes)
from .cloud import GaussianCloud
from .container import LAYER_SHIFT, Chunk
from .errors import GszError, GszFormatError
from .geometry import read_geometry_header
from .layout import CHUNK_ATTR, CHUNK_GEOM, CHUNK_SHVQ
from .sh import read_sh


def open_gsz(path: str):
    """Open a .gsz file for reading; a GszError naming the file when it cannot be opened."""
    try:
        return open(path, "rb")
    except FileNotFoundError:
        raise GszError("file not found", path) from None
    except IsADirectoryError:
        raise GszError("is a directory, expected a .gsz file", path) from None
    except OSError as e:
        raise GszError(f"cannot read: {e.strerror or e}", path) from None


def load_bytes(src):
    """(bytes view, path or None) of a .gsz given as a path or bytes-like; GszError when unreadable."""
    if isinstance(src, (bytes, bytearray, memoryview)):
        return memoryview(src), None
    path = os.fspath(src)
    with open_gsz(path) as f:
        try:
            return memoryview(f.read()), path
        except OSError as e:
            raise GszError(f"cannot read: {e.strerror or e}", path) from None


def guard(fn, path):
    """Run fn(); turn any low-level error on malformed data into one GszFormatError naming the file."""
    try:
        return fn()
    except GszError as e:
        if path and not e.path:
            raise type(e)(str(e), path) from None
        raise
    except MemoryError:
        raise GszFormatError("file declares more data than can be allocated", path) from None
    except (ValueError, IndexError, KeyError, TypeError, OverflowError, ZeroDivisionError,
            struct.error, FloatingPointError) as e:
        raise GszFormatError(f"malformed data ({type(e).__name__}: {e})", path) from None


#: Chunk types that carry one layer's data (GSZ.md §5).
LAYER_DATA_CHUNKS = (CHUNK_GEOM, CHUNK_ATTR, CHUNK_SHVQ)


def plan_layers(entries, sh_degree: int) -> list[dict]:
    """Check the layer structure of a chunk table and return, per layer, {type: entry index}.

    entries     [(type, flags, ...)] in file order (``Container.chunks`` or ``parse_table`` rows)
    rules       every layer 0..L-1 has exactly one GEOM and one ATTR, and one SHVQ iff the SH
                degree is > 0; data chunks appear in non-decreasing layer order, so a layer is
                complete once its last data chunk has arrived (GSZ.md §5).
    """
    layers: list[dict] = []
    last = 0
    for i, e in enumerate(entries):
        ctype, flags = (e.type, e.flags) if isinstance(e, Chunk) else (e[0], e[1])
        if ctype not in LAYER_DATA_CHUNKS:
            continue
        name = ctype.decode("ascii")
        layer = (flags >> LAYER_SHIFT) & 0xFF
        if ctype == CHUNK_SHVQ and sh_degree == 0:
            raise GszFormatError(f"SHVQ chunk in a file of SH degree 0 (chunk {i})")
        if layer < last:
            raise GszFormatError(f"chunk {i} ({name}) of layer {layer} follows a chunk of layer {last}")
        if layer > len(layers):
            raise GszFormatError(f"chunk {i} ({name}) belongs to layer {layer}, but layer {len(layers)} "
                                 "has no chunks")
        if layer == len(layers):
            layers.append({})
        if ctype in layers[layer]:
            raise GszFormatError(f"layer {layer} has two {name} chunks")
        layers[layer][ctype] = i
        last = layer
    if not layers:
        raise GszFormatError(f"missing required chunk {CHUNK_GEOM.decode()}")
    need = LAYER_DATA_CHUNKS if sh_degree > 0 else (CHUNK_GEOM, CHUNK_ATTR)
    for li, got in enumerate(layers):
        for ctype in need:
            if ctype not in got:
                raise GszFormatError(f"missing required chunk {ctype.decode()}"
                                     + (f" for layer {li}" if li else ""))
    return layers


@dataclass
class LayerState:
    """What decoding layer l+1 needs from the layers before it."""
    decoded_points: int = 0
    codebook: np.ndarray | None = None      # layer 0's SH codebook [D, K_cb]


#: Layers with at least this many Gaussians decode their geometry on a worker thread while the
#: attribute and SH streams decode on the calling one (native path; below it the hand-off costs
#: more than it saves).
OVERLAP_MIN_POINTS = 4096
_pool = None
_pool_lock = threading.Lock()


def _cores() -> int:
    """CPUs this process may run on (the overlap needs two)."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def _worker():
    """The decoder's one worker thread (geometry runs there, the attributes here)."""
    global _pool
    with _pool_lock:
        if _pool is None:
            _pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="gsz-decode")
        return _pool


def _decode_codes(gh):
    with np.errstate(over="ignore", invalid="ignore"):   # errstate is per thread
        return gh.decode_codes()


FIELDS = ("positions", "scales", "rotations", "opacities", "sh_dc", "sh_rest")


def _check_finite(ok: dict) -> None:
    """Well-formed streams always decode to finite float32 values; hostile parameters (huge
    min/max, DC) can overflow float32, which is rejected rather than returned.  ``ok``: field ->
    all finite?; the first failing field in FIELDS order is reported."""
    for name in FIELDS:
        if not ok[name]:
            raise GszFormatError(f"decoded {name} contain non-finite values (corrupt parameters)")


def _read_attributes_and_sh(chunks: dict, header, state: LayerState, m: int):
    dc, ac, direct = parse_attributes(chunks[CHUNK_ATTR], m)
    if header.sh_degree > 0:
        sh_rest, codebook = read_sh(chunks[CHUNK_SHVQ], m, header.sh_degree, state.codebook)
    else:
        sh_rest, codebook = np.zeros((m, 0, 3), np.float32), state.codebook
    return dc, ac, direct, sh_rest, codebook


def decode_layer(chunks: dict, header, state: LayerState) -> GaussianCloud:
    """Decode one layer from its chunk payloads {type: bytes-like}; updates ``state``.

    The geometry and the attribute/SH entropy decoding are independent until the inverse RAHT
    (which needs the voxels' Morton codes): with the native accelerator they run on two threads
    (the C loops release the GIL, see :func:`_decode_layer_overlapped`).  Errors are raised in
    the sequential order: a corrupt geometry is reported before a corrupt attribute chunk."""
    room = header.num_gaussians - state.decoded_points
    if room <= 0:
        raise GszFormatError(f"layers hold more Gaussians than the header's {header.num_gaussians}")
    gh = read_geometry_header(chunks[CHUNK_GEOM], max_points=room)
    m = gh.num_points
    if native.enabled() and m >= OVERLAP_MIN_POINTS and _cores() >= 2:
        cloud = _decode_layer_overlapped(chunks, header, state, gh)
    else:
        codes = gh.decode_codes()
        dc, ac, direct, sh_rest, codebook = _read_attributes_and_sh(chunks, header, state, m)
        state.codebook = codebook
        attrs = attributes_from_coefficients(dc, ac, direct, codes, gh.depth)
        cloud = GaussianCloud(positions=gh.positions(codes), scales=attrs.scales,
                              rotations=attrs.rotations, opacities=attrs.opacities,
                              sh_dc=attrs.sh_dc, sh_rest=sh_rest, sh_degree=header.sh_degree)
        finite = native.module().all_finite if native.enabled() else (lambda a: np.isfinite(a).all())
        _check_finite({name: finite(getattr(cloud, name)) for name in FIELDS})
    state.decoded_points += m
    return cloud


class _GeometryJob:
    """The worker's part of one layer before the join: the octree (then ``codes_ready`` is
    set) and the RAHT tree of its voxels.  ``helper`` lets the calling thread join the octree
    traversal once its own work is done (``_native.octree_help``)."""

    def __init__(self, gh):
        self.gh = gh
        self.codes = None
        self.codes_ready = threading.Event()
        self.helper = native.module().octree_helper()

    def __call__(self):
        try:
            with np.errstate(over="ignore", invalid="ignore"):   # errstate is per thread
                self.codes = self.gh.decode_codes(helper=self.helper)
        finally:
            native.module().octree_helper_close(self.helper)  # also when it never started
            self.codes_ready.set()
        return native_tree(self.codes, self.gh.depth)


class _ColourJob:
    """The worker's part after the join: opacity and DC colour through the inverse RAHT, then
    sin of the half angles once the calling thread has published them (``half``)."""

    def __init__(self, tree, dc, ac):
        self.tree, self.dc, self.ac = tree, dc, ac
        self.half = None
        self.half_ready = threading.Event()

    def __call__(self):
        opacities, sh_dc, ok = native_opacity_dc(self.tree, self.dc, self.ac)
        self.half_ready.wait()
        if self.half is None:          # the calling thread failed: nothing left to do here
            return opacities, sh_dc, ok, None
        with np.errstate(over="ignore", invalid="ignore"):
            s = np.sin(self.half)      # the whole array, as half_angle_trig (NumPy's sin)
        return opacities, sh_dc, ok, s


def _decode_layer_overlapped(chunks: dict, header, state: LayerState, gh) -> GaussianCloud:
    """decode_layer on two threads (native path), the same arrays bit for bit:

    worker                              calling thread
    octree -> codes                     attributes, SH, scales (+ finiteness), then helps
                                        with the octree's context ids and neighbour rows
    RAHT tree                           positions (+ finiteness), once the codes are there
    RAHT opacity + DC, float32          RAHT angles -> half angles, cos (NumPy's)
    sin (NumPy's) of the half angles    quaternions

    Errors keep the sequential order: geometry, attributes, SH, then the first non-finite
    field in FIELDS order."""
    m = gh.num_points
    pool = _worker()
    job = _GeometryJob(gh)
    pending = pool.submit(job)
    try:
        dc, ac, direct, sh_rest, codebook = _read_attributes_and_sh(chunks, header, state, m)
    except BaseException:
        if pending.exception() is not None:
            raise pending.exception() from None        # the geometry's error comes first
        raise
    nat = native.module()
    scales, ok_scales = native_scales(direct)
    ok_sh = nat.all_finite(sh_rest)
    nat.octree_help(job.helper)                        # until the traversal ends
    job.codes_ready.wait()
    if job.codes is None:
        pending.result()                               # raises the geometry's error
    positions, ok_pos = gh.native_positions(job.codes)
    tree = pending.result()
    colour = _ColourJob(tree, dc, ac)
    pending = pool.submit(colour)
    try:
        half = native_half_angles(tree, dc, ac)
        colour.half = half
    finally:
        colour.half_ready.set()                        # never leave the worker waiting
    c = np.cos(half)
    opacities, sh_dc, ok_colour, s = pending.result()
    rotations, ok_rot = native_rotations(c, s)
    state.codebook = codebook
    ok = dict(positions=ok_pos, scales=ok_scales, rotations=ok_rot, opacities=ok_colour,
              sh_dc=ok_colour, sh_rest=ok_sh)
    if not ok_colour:      # which of the two (the first in FIELDS order is reported)
        ok["opacities"], ok["sh_dc"] = nat.all_finite(opacities), nat.all_finite(sh_dc)
    _check_finite(ok)
    return GaussianCloud(positions=positions, scales=scales, rotations=rotations,
                         opacities=opacities, sh_dc=sh_dc, sh_rest=sh_rest,
                         sh_degree=header.sh_degree)


def concat_clouds(parts: list) -> GaussianCloud:
    """The Gaussians of ``parts`` one after the other (layer order)."""
    if len(parts) == 1:
        return parts[0]
    return GaussianCloud(**{name: np.concatenate([getattr(p, name) for p in parts])
                            for name in ("positions", "scales", "rotations", "opacities", "sh_dc", "sh_rest")},
                         sh_degree=parts[0].sh_degree)


def check_header_counts(h, max_gaussians: int) -> None:
    if h.num_gaussians > max_gaussians:
        raise GszFormatError(f"declares {h.num_gaussians} Gaussians, above the decoder limit {max_gaussians}")
    if h.num_gaussians == 0:
        raise GszFormatError("declares zero Gaussians")
