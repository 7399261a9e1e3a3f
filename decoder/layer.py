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
from .attributes import (attributes_from_coefficients, direct_in_point_order, leaf_weights_of,
                         native_half_angles, native_opacity_dc, native_rotations, native_scales,
                         native_tree, numpy_colour, numpy_half_angles, parse_attributes,
                         parse_direct_part, parse_raht_part, read_raht_weights)
from .cloud import FRESH, GaussianCloud, OutputRows
from .container import DEFAULT_MAX_GAUSSIANS, LAYER_SHIFT, TILE_SHIFT, Chunk
from .errors import GszError, GszFormatError, GszLimitError
from .geometry import read_geometry_header
from .io_util import check_input_file
from .layout import (CHUNK_ATTR, CHUNK_GEOM, CHUNK_RWGT, CHUNK_SHCL, CHUNK_SHRF, CHUNK_SHVQ, CHUNK_SHXF,
                     CHUNK_TILE)
from .pages import small_pages
from .raht import build_raht_tree
from .rotation import quaternion_f32_from_trig
from .sh import part_klt, read_sh_checked, turn_dc
from .threads import cores


def open_gsz(path: str):
    """Open a .gsz file for reading; a GszError naming the file when it cannot be opened or is
    not a regular file of bounded size (a device or FIFO would be read forever)."""
    check_input_file(path)
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
        except MemoryError:
            raise GszError("too large to read into memory", path) from None


def guard(fn, path):
    """Run fn() on the decoder path in force now (pinned for this thread, whatever other threads
    switch meanwhile); turn any low-level error on malformed data into one GszFormatError naming
    the file."""
    try:
        with native.pinned():
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


#: Chunk types that carry one part's data (GSZ.md §4.1); SHCL (1.3), RWGT (1.5), SHXF (1.6) and
#: SHRF (1.9) are optional.
LAYER_DATA_CHUNKS = (CHUNK_GEOM, CHUNK_ATTR, CHUNK_SHVQ, CHUNK_SHCL, CHUNK_RWGT, CHUNK_SHXF, CHUNK_SHRF)


@dataclass
class Part:
    """The data chunks of one (layer, tile) pair: {type: entry index}."""
    layer: int
    tile: int
    chunks: dict

    @property
    def last(self) -> int:
        """Entry index of the part's last data chunk (the part is decodable after it)."""
        return max(self.chunks.values())


@dataclass
class Plan:
    """The checked part structure of a chunk table.

    parts        [Part] in file order, which is the decoded order: (layer, tile) ascending
    num_layers   L; num_tiles T (1 without a TILE chunk)
    tile_chunk   entry index of the TILE chunk, None when the file has none
    """
    parts: list
    num_layers: int
    num_tiles: int
    tile_chunk: int | None

    def layer_parts(self, layer: int) -> list:
        return [p for p in self.parts if p.layer == layer]

    def layer_ends(self) -> list:
        """Per layer, the entry index after which every part of it has arrived."""
        return [max(p.last for p in self.layer_parts(li)) for li in range(self.num_layers)]


def _where(layer: int, tile: int, tiled: bool) -> str:
    return f"layer {layer}, tile {tile}" if tiled else f"layer {layer}"


def plan_parts(entries, sh_degree: int) -> Plan:
    """Check the layer and tile structure of a chunk table (GSZ.md §4.1, §4.2).

    entries     [(type, flags, ...)] in file order (``Container.chunks`` or ``parse_table`` rows)
    rules       data chunks in non-decreasing (layer, tile) order; every part has one GEOM, one
                ATTR and one SHVQ iff the SH degree is > 0; layers 0..L-1 without gaps; layer 0
                holds every tile 0..T-1 and a tile in layer k was in layer k-1; a TILE chunk
                (at most one) precedes every data chunk, and tile bits are 0 without it.
    """
    parts: list = []
    tile_chunk = None
    for i, e in enumerate(entries):
        ctype, flags = (e.type, e.flags) if isinstance(e, Chunk) else (e[0], e[1])
        if ctype == CHUNK_TILE:
            if tile_chunk is not None:
                raise GszFormatError(f"two TILE chunks (chunks {tile_chunk} and {i})")
            if parts:
                raise GszFormatError(f"the TILE chunk (chunk {i}) follows a data chunk")
            tile_chunk = i
            continue
        if ctype not in LAYER_DATA_CHUNKS:
            continue
        name = ctype.decode("ascii")
        layer, tile = (flags >> LAYER_SHIFT) & 0xFF, (flags >> TILE_SHIFT) & 0xFFFF
        tiled = tile_chunk is not None
        if ctype in (CHUNK_SHVQ, CHUNK_SHCL, CHUNK_SHRF) and sh_degree == 0:
            raise GszFormatError(f"{name} chunk in a file of SH degree 0 (chunk {i})")
        if tile and not tiled:
            raise GszFormatError(f"chunk {i} ({name}) belongs to tile {tile}, but the file has no TILE chunk")
        prev = parts[-1] if parts else Part(0, 0, {})
        if layer < prev.layer:
            raise GszFormatError(f"chunk {i} ({name}) of layer {layer} follows a chunk of layer {prev.layer}")
        if layer > prev.layer + (1 if parts else 0):
            raise GszFormatError(f"chunk {i} ({name}) belongs to layer {layer}, but layer "
                                 f"{prev.layer + (1 if parts else 0)} has no chunks")
        if layer == prev.layer and tile < prev.tile:
            raise GszFormatError(f"chunk {i} ({name}) of tile {tile} follows a chunk of tile {prev.tile} "
                                 f"in layer {layer}")
        if not parts or (layer, tile) != (prev.layer, prev.tile):
            parts.append(Part(layer, tile, {}))
        got = parts[-1].chunks
        if ctype in got:
            raise GszFormatError(f"{_where(layer, tile, tiled)} has two {name} chunks")
        got[ctype] = i
    if not parts:
        raise GszFormatError(f"missing required chunk {CHUNK_GEOM.decode()}")
    tiled = tile_chunk is not None
    need = (CHUNK_GEOM, CHUNK_ATTR, CHUNK_SHVQ) if sh_degree > 0 else (CHUNK_GEOM, CHUNK_ATTR)
    for p in parts:
        for ctype in need:
            if ctype not in p.chunks:
                raise GszFormatError(f"missing required chunk {ctype.decode()}"
                                     + (f" for {_where(p.layer, p.tile, tiled)}" if p.layer or tiled else ""))
    num_layers = parts[-1].layer + 1
    present = [{p.tile for p in parts if p.layer == li} for li in range(num_layers)]
    num_tiles = len(present[0])
    if present[0] != set(range(num_tiles)):
        missing = min(set(range(max(present[0]) + 1)) - present[0])
        raise GszFormatError(f"tile {missing} has no chunks in layer 0")
    for li in range(1, num_layers):
        extra = present[li] - present[li - 1]
        if extra:
            raise GszFormatError(f"tile {min(extra)} has chunks in layer {li} but none in layer {li - 1}")
    return Plan(parts=parts, num_layers=num_layers, num_tiles=num_tiles, tile_chunk=tile_chunk)


def plan_layers(entries, sh_degree: int) -> list[dict]:
    """Per layer {type: entry index} of a file without tiles (what the test-vector and bench
    tools walk); a tiled file is rejected here -- use :func:`plan_parts`."""
    plan = plan_parts(entries, sh_degree)
    if plan.num_tiles > 1:
        raise GszFormatError("the file has several tiles: plan its parts with plan_parts")
    return [p.chunks for p in plan.parts]


def tile_table(container_or_tile_data, plan: Plan, header) -> list:
    """[TileInfo] of a planned file: its TILE chunk (checked against the plan), or one tile
    spanning the header's bounding box when the file has none."""
    from .tiles import TileInfo, parse_tile_table
    if plan.tile_chunk is None:
        return [TileInfo(tuple(header.bbox_min), tuple(header.bbox_max), int(header.num_gaussians))]
    tiles = parse_tile_table(container_or_tile_data, header.num_gaussians)
    if len(tiles) != plan.num_tiles:
        raise GszFormatError(f"TILE chunk lists {len(tiles)} tiles, the chunk table has {plan.num_tiles}")
    return tiles


@dataclass
class LayerState:
    """What decoding the next layer of one tile needs from the layers before it.

    limit      Gaussians this tile's parts may hold in all (the header's count without tiles)
    what       how messages name the limit ("the header's", "tile 3's")
    per_byte   the default Gaussians-per-byte limit of each part (None: the caller gave
               max_gaussians, which replaces the default limits)"""
    limit: int
    what: str = "the header's"
    per_byte: int | None = None
    decoded_points: int = 0
    codebook: np.ndarray | None = None      # the tile's SH codebook [D, K_cb], once seen
    sh_klt: np.ndarray | None = None        # the tile's SH KLT matrix int16 [D, D], once seen


def check_tile_complete(state: LayerState, tile: int, tiled: bool) -> None:
    """After a tile's last layer: its parts must hold exactly its count (the TILE chunk's, or
    the header's without tiles)."""
    if state.decoded_points != state.limit:
        raise GszFormatError(
            f"tile {tile}: layers hold {state.decoded_points} Gaussians, the TILE chunk says {state.limit}"
            if tiled else f"layers hold {state.decoded_points} Gaussians, header says {state.limit}")


#: Layers with at least this many Gaussians decode their geometry on a worker thread while the
#: attribute and SH streams decode on the calling one (both paths; below it the hand-off costs
#: more than it saves).
OVERLAP_MIN_POINTS = 4096
#: ... and only when the layer's chunks hold at least one byte per this many declared points: the
#: overlap allocates and decodes M-sized attribute arrays before the octree has confirmed M, so a
#: hostile M must first be plausible for the bytes (real files: <= 1 point per byte); beyond it
#: the octree decodes first, as on the NumPy path (GSZ.md §11).
OVERLAP_MAX_POINTS_PER_BYTE = 4
_pool = None
_pool_lock = threading.Lock()


def _worker():
    """The decoder's one worker thread (geometry runs there, the attributes here)."""
    global _pool
    with _pool_lock:
        if _pool is None:
            _pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="gsz-decode")
        return _pool


FIELDS = ("positions", "scales", "rotations", "opacities", "sh_dc", "sh_rest")


def _check_finite(ok: dict) -> None:
    """Well-formed streams always decode to finite float32 values; hostile parameters (huge
    min/max, DC) can overflow float32, which is rejected rather than returned.  ``ok``: field ->
    all finite?; the first failing field in FIELDS order is reported."""
    for name in FIELDS:
        if not ok[name]:
            raise GszFormatError(f"decoded {name} contain non-finite values (corrupt parameters)")


def _read_weights(chunks: dict, m: int):
    """The part's RWGT chunk decoded (RahtWeights), or None."""
    data = chunks.get(CHUNK_RWGT)
    return None if data is None else read_raht_weights(data, m)


def _read_sh(chunks: dict, header, state: LayerState, m: int, dest: OutputRows, rwgt=None):
    """(sh_rest, the codebook, all finite? or None when not known) of a part: its SHVQ chunk,
    or nothing at SH degree 0."""
    if header.sh_degree > 0:
        klt, state.sh_klt = part_klt(chunks.get(CHUNK_SHXF), header.sh_degree, state.sh_klt)
        return read_sh_checked(chunks[CHUNK_SHVQ], m, header.sh_degree, state.codebook,
                               chunks.get(CHUNK_SHCL), dest,
                               voxel_classes=None if rwgt is None else rwgt.classes,
                               colour_chunk=chunks.get(CHUNK_SHXF), klt=klt,
                               refine_chunk=chunks.get(CHUNK_SHRF))
    return np.zeros((m, 0, 3), np.float32), state.codebook, True


def _read_attributes_and_sh(chunks: dict, header, state: LayerState, m: int, dest: OutputRows,
                            rwgt=None):
    dc, ac, direct = parse_attributes(chunks[CHUNK_ATTR], m)
    return (dc, ac, direct_in_point_order(direct, rwgt), *_read_sh(chunks, header, state, m, dest, rwgt)[:2])


class _Weights:
    """A part's RAHT leaf weights, decoded by the calling thread first and handed to the worker
    that builds the tree (``ready`` set also when the decode failed: ``ok`` False)."""

    def __init__(self):
        self.rwgt = None
        self.ok = False
        self.ready = threading.Event()

    def decode(self, chunks: dict, m: int):
        try:
            self.rwgt = _read_weights(chunks, m)
            self.ok = True
        finally:
            self.ready.set()                    # never leave the worker waiting
        return self.rwgt

    def leaf_weights(self):
        """The worker's wait: the leaf weights, or None when there are none or their decode
        failed (the calling thread reports that error)."""
        self.ready.wait()
        return leaf_weights_of(self.rwgt) if self.ok else None


class _CodesAndTree:
    """The NumPy path's worker: the octree (then ``codes_ready`` is set: the calling thread
    makes the positions meanwhile), then the RAHT tree of its voxels (returned)."""

    def __init__(self, gh, weights: _Weights):
        self.gh = gh
        self.weights = weights
        self.codes = None
        self.codes_ready = threading.Event()

    def __call__(self):
        with np.errstate(over="ignore", invalid="ignore"):   # errstate is per thread
            try:
                self.codes = self.gh.decode_codes()
            finally:
                self.codes_ready.set()          # also on an error: never leave the caller waiting
            w = self.weights.leaf_weights()
            if not self.weights.ok:
                return None
            return build_raht_tree(self.codes, self.gh.depth, w)


def decode_layer(chunks: dict, header, state: LayerState, *, overlap: bool = True,
                 label: str = "layer", pool=None, dest: OutputRows = FRESH) -> GaussianCloud:
    """Decode one part (a layer of a tile) from its chunk payloads {type: bytes-like}; updates
    ``state``.

    The geometry and the attribute/SH entropy decoding are independent until the inverse RAHT
    (which needs the voxels' Morton codes): they run on two threads (the C loops release the
    GIL, see :func:`_decode_layer_overlapped`; so do NumPy's array loops, see
    :func:`_decode_layer_threaded`); ``overlap=False`` when the caller already decodes several
    tiles at once.  Errors are raised in the sequential order: a corrupt geometry is reported
    before a corrupt attribute chunk.  ``pool``: the executor of the worker's jobs (None: the
    decoder's one worker); ``dest``: where the part's fields go (rows of the whole cloud when
    the caller allocated it; the fields that do not fit are fresh arrays)."""
    with small_pages():
        return _decode_layer(chunks, header, state, overlap, label, pool, dest)


def _decode_layer(chunks: dict, header, state: LayerState, overlap: bool, label: str, pool,
                  dest: OutputRows) -> GaussianCloud:
    room = state.limit - state.decoded_points
    if room <= 0:
        raise GszFormatError(f"layers hold more Gaussians than {state.what} {state.limit}")
    gh = read_geometry_header(chunks[CHUNK_GEOM], max_points=room)
    m = gh.num_points
    check_part_density(m, chunks, state, label)
    if (overlap and m >= OVERLAP_MIN_POINTS and cores() >= 2
            and m <= OVERLAP_MAX_POINTS_PER_BYTE * sum(len(v) for v in chunks.values())):
        overlapped = _decode_layer_overlapped if native.enabled() else _decode_layer_threaded
        cloud = overlapped(chunks, header, state, gh, pool or _worker(), dest)
    else:
        codes = gh.decode_codes()
        rwgt = _read_weights(chunks, m)
        cloud = _finish_layer(gh, codes, _read_attributes_and_sh(chunks, header, state, m, dest, rwgt),
                              header, state, dest, leaf_weights=leaf_weights_of(rwgt))
    # the DC colour's SHXF transform (1.7), on the f32 values every path made alike
    if not turn_dc(chunks.get(CHUNK_SHXF), cloud.sh_dc, header.sh_degree):
        _check_finite({name: name != "sh_dc" for name in FIELDS})
    state.decoded_points += m
    return cloud


def _finish_layer(gh, codes: np.ndarray, decoded: tuple, header, state: LayerState,
                  dest: OutputRows, tree=None, leaf_weights=None) -> GaussianCloud:
    """decode_layer after the entropy decoding: ``decoded`` is _read_attributes_and_sh's result;
    the inverse RAHT (over ``tree`` when built already), positions and the finiteness checks."""
    dc, ac, direct, sh_rest, codebook = decoded
    state.codebook = codebook
    attrs = attributes_from_coefficients(dc, ac, direct, codes, gh.depth, tree=tree,
                                         leaf_weights=leaf_weights, dest=dest)
    cloud = GaussianCloud(positions=gh.positions(codes, dest.empty("positions", (gh.num_points, 3))),
                          scales=attrs.scales,
                          rotations=attrs.rotations, opacities=attrs.opacities,
                          sh_dc=attrs.sh_dc, sh_rest=sh_rest, sh_degree=header.sh_degree)
    finite = native.module().all_finite if native.enabled() else (lambda a: np.isfinite(a).all())
    _check_finite({name: finite(getattr(cloud, name)) for name in FIELDS})
    return cloud


def _decode_layer_threaded(chunks: dict, header, state: LayerState, gh, pool,
                           dest: OutputRows) -> GaussianCloud:
    """decode_layer's NumPy path on two threads, the same arrays bit for bit: the octree and
    its RAHT tree on the worker while the calling thread decodes the attribute and SH streams
    (NumPy releases the GIL inside its array loops, so the two overlap), then the positions
    while the worker builds the tree, then :func:`_finish_layer_threaded`.  Errors keep the
    sequential order: the geometry's comes first."""
    # carry: the worker follows this thread's path (inside numpy_only() too)
    weights = _Weights()
    job = _CodesAndTree(gh, weights)
    pending = pool.submit(native.carry(job))
    try:
        rwgt = weights.decode(chunks, gh.num_points)
        decoded = _read_attributes_and_sh(chunks, header, state, gh.num_points, dest, rwgt)
    except BaseException:
        if pending.exception() is not None:
            raise pending.exception() from None        # the geometry's error comes first
        raise
    job.codes_ready.wait()
    if job.codes is None:
        pending.result()                               # raises the geometry's error
    # while the worker builds the tree
    positions = gh.positions(job.codes, dest.empty("positions", (gh.num_points, 3)))
    tree = pending.result()
    return _finish_layer_threaded(gh, job.codes, tree, positions, decoded, header, state, pool, dest)


def _finish_layer_threaded(gh, codes: np.ndarray, tree, positions: np.ndarray, decoded: tuple,
                           header, state: LayerState, pool, dest: OutputRows) -> GaussianCloud:
    """:func:`_finish_layer` on two threads (NumPy path), the same arrays bit for bit, once the
    calling thread has made the ``positions``:

    worker                                  calling thread
    RAHT opacity + DC, float32              RAHT angle channels -> half angles
    sin (NumPy's) of the half angles        cos (NumPy's) of the half angles, scales
                                            quaternions

    (as the native path splits it); the finiteness checks report the first failing field in
    FIELDS order, as there."""
    dc, ac, direct, sh_rest, codebook = decoded
    state.codebook = codebook
    finite = (lambda a: bool(np.isfinite(a).all()))
    err = np.geterr()                   # errstate is per thread: the worker follows this one
    published = threading.Event()
    half = []                           # the calling thread's half angles, once published

    def colour():
        with np.errstate(**err):
            opacities, sh_dc = numpy_colour(dc, ac, tree, dest)
            ok = dict(opacities=finite(opacities), sh_dc=finite(sh_dc))
            published.wait()
            s = np.sin(half[0]) if half else None    # the whole array, as half_angle_trig
            return opacities, sh_dc, ok, s
    pending = pool.submit(native.carry(colour))
    try:
        try:
            half.append(numpy_half_angles(dc, ac, tree))
        finally:
            published.set()             # never leave the worker waiting
        c = np.cos(half[0])
        scales = dest.empty("scales", (gh.num_points, 3))
        scales[...] = direct.T          # the float32 rounding of astype
        opacities, sh_dc, ok_colour, s = pending.result()
    except BaseException:
        pending.exception()             # the worker is done with this layer before we leave
        raise
    rotations = quaternion_f32_from_trig(c, s, dest.empty("rotations", (gh.num_points, 4)))
    ok = dict(positions=finite(positions), scales=finite(scales), rotations=finite(rotations),
              sh_rest=finite(sh_rest))
    _check_finite({**ok, **ok_colour})
    return GaussianCloud(positions=positions, scales=scales, rotations=rotations,
                         opacities=opacities, sh_dc=sh_dc, sh_rest=sh_rest,
                         sh_degree=header.sh_degree)


class _GeometryJob:
    """The worker's part of one layer before the join: the octree (then ``codes_ready`` is
    set), the RAHT tree of its voxels, then the ATTR chunk's direct set (log-scales) once the
    calling thread has decoded the chunk up to it (``raht_part``; None if that failed).
    ``helper`` lets the calling thread join the octree traversal once its own work is done
    (``_native.octree_help``).  Returns (tree, (scales, scales finite) or None)."""

    def __init__(self, gh, dest: OutputRows, weights: _Weights):
        self.gh, self.dest = gh, dest
        self.weights = weights
        self.codes = None
        self.codes_ready = threading.Event()
        self.helper = native.module().octree_helper()
        self.raht_part = None
        self.raht_part_ready = threading.Event()

    def __call__(self):
        try:
            with np.errstate(over="ignore", invalid="ignore"):   # errstate is per thread
                self.codes = self.gh.decode_codes(helper=self.helper)
        finally:
            native.module().octree_helper_close(self.helper)  # also when it never started
            self.codes_ready.set()
        w = self.weights.leaf_weights()
        tree = native_tree(self.codes, self.gh.depth, w) if self.weights.ok else None
        self.raht_part_ready.wait()
        if self.raht_part is None:     # the calling thread's ATTR error is reported there
            return tree, None
        direct = parse_direct_part(self.raht_part[2], self.gh.num_points)
        return tree, native_scales(direct_in_point_order(direct, self.weights.rwgt), self.dest)


class _ColourJob:
    """The worker's part after the join: opacity and DC colour through the inverse RAHT, then
    sin of the half angles once the calling thread has published them (``half``)."""

    def __init__(self, tree, dc, ac, dest: OutputRows):
        self.tree, self.dc, self.ac, self.dest = tree, dc, ac, dest
        self.half = None
        self.half_ready = threading.Event()

    def __call__(self):
        opacities, sh_dc, ok = native_opacity_dc(self.tree, self.dc, self.ac, self.dest)
        self.half_ready.wait()
        if self.half is None:          # the calling thread failed: nothing left to do here
            return opacities, sh_dc, ok, None
        with np.errstate(over="ignore", invalid="ignore"):
            s = np.sin(self.half)      # the whole array, as half_angle_trig (NumPy's sin)
        return opacities, sh_dc, ok, s


def _decode_layer_overlapped(chunks: dict, header, state: LayerState, gh, pool,
                             dest: OutputRows) -> GaussianCloud:
    """decode_layer on two threads (native path), the same arrays bit for bit:

    worker                              calling thread
    octree -> codes                     ATTR up to its direct set (RAHT AC), SH (+ finiteness),
                                        then helps with the octree's context ids and
                                        neighbour rows
    RAHT tree, direct set -> scales     positions (+ finiteness), once the codes are there
    RAHT opacity + DC, float32          RAHT angles -> half angles, cos (NumPy's)
    sin (NumPy's) of the half angles    quaternions

    (The calling thread decodes the larger streams while the octree decodes, and joins its
    parallel phases when done: the octree's own decoding is the one sequential chain; the
    scales even the two threads out.)  Errors keep the sequential order: geometry, attributes,
    SH, then the first non-finite field in FIELDS order."""
    m = gh.num_points
    weights = _Weights()
    job = _GeometryJob(gh, dest, weights)
    pending = pool.submit(native.carry(job))
    try:
        try:
            rwgt = weights.decode(chunks, m)
            job.raht_part = parse_raht_part(chunks[CHUNK_ATTR], m)
        finally:
            job.raht_part_ready.set()                  # never leave the worker waiting
        dc, ac, _ = job.raht_part
        sh_rest, codebook, ok_sh = _read_sh(chunks, header, state, m, dest, rwgt)
    except BaseException:
        if pending.exception() is not None:
            raise pending.exception() from None        # the geometry's or scales' error first
        raise
    nat = native.module()
    if ok_sh is None:
        ok_sh = nat.all_finite(sh_rest)
    nat.octree_help(job.helper)                        # until the traversal ends
    job.codes_ready.wait()
    if job.codes is None:
        pending.result()                               # raises the geometry's error
    positions, ok_pos = gh.native_positions(job.codes, dest.empty("positions", (m, 3)))
    tree, (scales, ok_scales) = pending.result()       # raises the direct set's error
    colour = _ColourJob(tree, dc, ac, dest)
    pending = pool.submit(native.carry(colour))
    try:
        half = native_half_angles(tree, dc, ac)
        colour.half = half
    finally:
        colour.half_ready.set()                        # never leave the worker waiting
    c = np.cos(half)
    opacities, sh_dc, ok_colour, s = pending.result()
    rotations, ok_rot = native_rotations(c, s, dest)
    state.codebook = codebook
    ok = dict(positions=ok_pos, scales=ok_scales, rotations=ok_rot, opacities=ok_colour,
              sh_dc=ok_colour, sh_rest=ok_sh)
    if not ok_colour:      # which of the two (the first in FIELDS order is reported)
        ok["opacities"], ok["sh_dc"] = nat.all_finite(opacities), nat.all_finite(sh_dc)
    _check_finite(ok)
    return GaussianCloud(positions=positions, scales=scales, rotations=rotations,
                         opacities=opacities, sh_dc=sh_dc, sh_rest=sh_rest,
                         sh_degree=header.sh_degree)


def concat_clouds(parts: list, sh_degree: int | None = None) -> GaussianCloud:
    """The Gaussians of ``parts`` one after the other (decoded order); an empty cloud of
    ``sh_degree`` when there are none."""
    if not parts:
        k = (sh_degree + 1) ** 2 - 1
        z = lambda *shape: np.zeros(shape, np.float32)  # noqa: E731
        return GaussianCloud(positions=z(0, 3), scales=z(0, 3), rotations=z(0, 4), opacities=z(0),
                             sh_dc=z(0, 3), sh_rest=z(0, k, 3), sh_degree=sh_degree)
    if len(parts) == 1:
        return parts[0]
    return GaussianCloud(**{name: np.concatenate([getattr(p, name) for p in parts])
                            for name in ("positions", "scales", "rotations", "opacities", "sh_dc", "sh_rest")},
                         sh_degree=parts[0].sh_degree)


#: The default limit on declared Gaussians per byte (GSZ.md §11): applied to the header's count
#: against the file's length and to each part's M against its chunks' bytes.  Real files hold
#: at most ~0.7 Gaussians per byte (1-bit attributes, no pruning, a coarse grid; size-searched
#: files 0.01-0.18), while a full octree with constant attributes holds hundreds (an 11 kB valid
#: file decodes to 2.1 M Gaussians): 32 keeps a margin of ~45 over the densest real file.
GAUSSIANS_PER_BYTE = 32
_RAISE_IT = "if the file is trusted, pass max_gaussians= (--max-gaussians) to decode it"


def check_max_gaussians(max_gaussians, source=None):
    """``max_gaussians`` as given to decode/StreamDecoder/inspect: None (the default limits) or
    a positive int; GszError naming ``source`` otherwise."""
    if max_gaussians is None:
        return None
    if isinstance(max_gaussians, bool) or not isinstance(max_gaussians, (int, np.integer)) or max_gaussians < 1:
        raise GszError(f"max_gaussians must be a positive integer or None, got {max_gaussians!r}", source)
    return int(max_gaussians)


def check_header_counts(h, max_gaussians: int | None, file_bytes: int | None = None) -> None:
    """The header's num_gaussians: >= 1, then within ``max_gaussians`` when the caller gave
    one, else within DEFAULT_MAX_GAUSSIANS and (once ``file_bytes``, the length the chunk table
    declares, is known) GAUSSIANS_PER_BYTE per byte of file (GSZ.md §3, §11)."""
    n = h.num_gaussians
    if n == 0:
        raise GszFormatError("declares zero Gaussians")
    if max_gaussians is not None:
        if n > max_gaussians:
            raise GszLimitError(f"declares {n:,} Gaussians, above the decoder limit {max_gaussians:,} (max_gaussians)")
        return
    if n > DEFAULT_MAX_GAUSSIANS:
        raise GszLimitError(f"declares {n:,} Gaussians, above the decoder limit {DEFAULT_MAX_GAUSSIANS:,}; {_RAISE_IT}")
    if file_bytes is not None and n > GAUSSIANS_PER_BYTE * file_bytes:
        raise GszLimitError(
            f"declares {n:,} Gaussians in a {file_bytes:,}-byte file ({n / file_bytes:,.0f} per byte), above "
            f"the default limit of {GAUSSIANS_PER_BYTE} per byte ({GAUSSIANS_PER_BYTE * file_bytes:,}); {_RAISE_IT}")


def check_part_density(m: int, chunks: dict, state: "LayerState", label: str) -> None:
    """A part's M against its chunks' bytes under the default limit (GSZ.md §11), before its
    octree is decoded: a streaming reader decodes a part before the file's length is proven."""
    if state.per_byte is None:
        return
    nbytes = sum(len(v) for v in chunks.values())
    if m > state.per_byte * nbytes:
        raise GszLimitError(
            f"{label}: {m:,} Gaussians in {nbytes:,} bytes of chunks ({m / max(1, nbytes):,.0f} per byte), above "
            f"the default limit of {state.per_byte} per byte; {_RAISE_IT}")
