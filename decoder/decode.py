"""Whole-file decoding: ``decode(path_or_bytes) -> GaussianCloud`` and ``inspect`` for gsz-info.

numpy only.  Every failure on bad input is a :class:`GszFormatError` (or :class:`GszError` for
I/O problems) whose message names the file.
"""
from __future__ import annotations

import json
import os
import struct

import numpy as np

from . import native
from .cloud import FRESH, GaussianCloud, OutputRows, sh_rest_count
from .container import Container, read_container
from .errors import GszError, GszFormatError, GszTruncatedError
from .glb import gsz_payload, is_glb
# LAYER_DATA_CHUNKS, open_gsz and the layer names stay importable from here (their old home)
from .layer import (FIELDS, GAUSSIANS_PER_BYTE, LAYER_DATA_CHUNKS, LayerState,  # noqa: F401
                    check_header_counts, check_max_gaussians, check_part_density, check_tile_complete,
                    concat_clouds, decode_layer, guard, load_bytes, open_gsz, plan_layers, plan_parts,
                    tile_table)
from .threads import cores
from .geometry import read_geometry_header
from .layout import (CHUNK_ATTR, CHUNK_GEOM, CHUNK_META, CHUNK_RWGT, CHUNK_SHCL, CHUNK_SHRF, CHUNK_SHVQ, CHUNK_SHXF,
                     CHUNK_TILE, KNOWN_CHUNKS)
from .pages import small_pages
from .tiles import check_region, select_tiles
from .stream import StreamDecoder

#: Chunk type names for reports.
CHUNK_NAMES = {CHUNK_GEOM: "geometry (octree)", CHUNK_ATTR: "attributes (RAHT + scales)",
               CHUNK_SHVQ: "SH (codebook + kept + indices)", CHUNK_META: "metadata (JSON)",
               CHUNK_TILE: "tile table", CHUNK_SHCL: "SH importance classes",
               CHUNK_RWGT: "RAHT leaf weights (importance classes)",
               CHUNK_SHXF: "SH colour transform (luma/chroma, KLT)",
               CHUNK_SHRF: "SH codeword refinement (indices of the kept vectors)"}


def read_meta(container: Container) -> dict:
    """The informative META chunk as a dict ({} when absent, unreadable or nested deeper than
    MAX_META_NESTING: it is optional); an ``options`` entry that is not an object is dropped."""
    c = container.find(CHUNK_META)
    if c is None:
        return {}
    import zstandard
    try:
        raw = zstandard.ZstdDecompressor().decompress(bytes(c.data), max_output_size=1 << 24)
        meta = json.loads(raw.decode("utf-8"))
    except (zstandard.ZstdError, ValueError, UnicodeDecodeError, RecursionError):
        return {}                 # RecursionError: JSON nested deeper than Python's stack
    if not isinstance(meta, dict) or _nesting(meta) > MAX_META_NESTING:
        return {}                 # printing or re-serialising deep nesting would recurse too
    if not isinstance(meta.get("options", {}), dict):
        meta = {k: v for k, v in meta.items() if k != "options"}   # gsz-info reads it as an object
    return meta


#: Deepest JSON nesting of a META object gsz reports (the reference encoder writes 3 levels).
MAX_META_NESTING = 64


def _nesting(obj) -> int:
    """Nesting depth of a parsed JSON value, without recursion."""
    deepest, stack = 0, [(obj, 1)]
    while stack:
        o, d = stack.pop()
        if isinstance(o, (dict, list)):
            deepest = max(deepest, d)
            if d <= MAX_META_NESTING:
                stack.extend((v, d + 1) for v in (o.values() if isinstance(o, dict) else o))
    return deepest


def _decode_tile(container: Container, parts: list, header, state: LayerState, overlap: bool,
                 tiled: bool, pool=None, rows: dict | None = None) -> list:
    """The clouds of one tile's ``parts`` (its layers in order; they share the tile's codebook);
    ``rows``: {(layer, tile): OutputRows} where the parts' fields go (None: fresh arrays)."""
    with np.errstate(over="ignore", invalid="ignore"):     # errstate is per thread
        return [decode_layer({t: container.chunks[i].data for t, i in p.chunks.items()}, header, state,
                             overlap=overlap, label=part_label(p, tiled), pool=pool,
                             dest=FRESH if rows is None else rows[(p.layer, p.tile)]) for p in parts]


def part_label(part, tiled: bool) -> str:
    """How messages name a part: "layer 2", or "layer 2, tile 5" in a tiled file."""
    return f"layer {part.layer}, tile {part.tile}" if tiled else f"layer {part.layer}"


def decode_parts(container: Container, plan, tiles: list, chosen: list, count: int,
                 threads: int | None = None, per_byte: int | None = GAUSSIANS_PER_BYTE,
                 whole: bool = False):
    """Decode the first ``count`` layers of the ``chosen`` tiles; the parts' clouds in decoded
    order ((layer, tile) ascending), or with ``whole`` the one cloud of them all.  Tiles decode
    in parallel threads on the native path (it releases the GIL); the error reported is the one of
    the first failing tile, as a sequential decode would report it.  ``per_byte``: the default
    per-part limit (None: the caller's max_gaussians)."""
    h = container.header
    tiled = plan.tile_chunk is not None
    states = {t: LayerState(limit=tiles[t].num_gaussians, what=f"tile {t}'s" if tiled else "the header's",
                            per_byte=per_byte) for t in chosen}
    by_tile = {t: [p for p in plan.parts if p.tile == t and p.layer < count] for t in chosen}
    out = _output_rows(container, by_tile, states, h.sh_degree) if whole else None
    rows = None if out is None else out[1]
    # tiles decode in parallel threads on the native path only: the NumPy path's row loops hold
    # the GIL, and two tiles (each overlapping its geometry with its attributes) contending for
    # it were slower than one after the other (1.2 M, 2 tiles: 2.65 s against 2.05 s)
    workers = min(len(chosen), threads or cores()) if native.enabled() else 1
    if workers <= 1:
        clouds = {t: _decode_tile(container, by_tile[t], h, states[t], True, tiled, rows=rows) for t in chosen}
    else:
        from concurrent.futures import ThreadPoolExecutor
        # no more tiles than cores: each tile also overlaps its geometry with its attributes (a
        # large tile's traversal is the critical path) on a worker of its own (the decoder's
        # one worker would run one tile's jobs at a time); else the tiles fill the cores
        overlap = len(chosen) <= (threads or cores())
        with ThreadPoolExecutor(max_workers=workers, thread_name_prefix="gsz-tile") as pool, \
                ThreadPoolExecutor(max_workers=workers if overlap else 1, thread_name_prefix="gsz-decode") as inner:
            futures = {t: pool.submit(native.carry(_decode_tile), container, by_tile[t], h, states[t], overlap,
                                      tiled, inner, rows) for t in chosen}
            for t in chosen:                        # the first failing tile's error
                if futures[t].exception() is not None:
                    raise futures[t].exception()
            clouds = {t: futures[t].result() for t in chosen}
    if count == plan.num_layers:
        for t in chosen:
            check_tile_complete(states[t], t, tiled)
    order = sorted(((p.layer, p.tile), k) for t in chosen for k, p in enumerate(by_tile[t]))
    parts = [clouds[t][k] for (_, t), k in order]
    if not whole:
        return parts
    if out is None:
        return concat_clouds(parts, h.sh_degree)
    arrays, rows = out
    for (key, _), cloud in zip(order, parts):
        dest = rows[key]
        if len(cloud) != dest.stop - dest.start:          # pragma: no cover - the same header bytes
            raise GszFormatError("a part decoded to another count than its GEOM header declares")
        for name in FIELDS:
            a = getattr(cloud, name)
            if not dest.holds(name, a):                   # a field decoded into a fresh array
                arrays[name][dest.start:dest.stop] = a
    return GaussianCloud(**arrays, sh_degree=h.sh_degree)


def _output_rows(container: Container, by_tile: dict, states: dict, sh_degree: int):
    """(the whole cloud's arrays, uninitialised; {(layer, tile): OutputRows}) when several parts
    decode and their GEOM headers declare counts within their tiles' limits, else None (the
    parts then decode into fresh arrays and are concatenated; their decoding reports the
    errors, in order)."""
    parts = sorted((p for ps in by_tile.values() for p in ps), key=lambda p: (p.layer, p.tile))
    if len(parts) < 2:
        return None
    room = {t: s.limit for t, s in states.items()}
    counts = []
    for p in parts:
        chunks = {t: container.chunks[i].data for t, i in p.chunks.items()}
        try:
            m = read_geometry_header(chunks[CHUNK_GEOM], max_points=room[p.tile]).num_points
            check_part_density(m, chunks, states[p.tile], "")
        except GszError:
            return None
        room[p.tile] -= m
        counts.append(m)
    n, k = sum(counts), sh_rest_count(sh_degree)
    shapes = dict(positions=(n, 3), scales=(n, 3), rotations=(n, 4), opacities=(n,), sh_dc=(n, 3),
                  sh_rest=(n, k, 3))
    arrays = {name: np.empty(shapes[name], np.float32) for name in FIELDS}
    rows, start = {}, 0
    for p, m in zip(parts, counts):
        rows[(p.layer, p.tile)] = OutputRows(arrays, start, start + m)
        start += m
    return arrays, rows


def decode_container(container: Container, *, max_gaussians: int | None = None,
                     layers: int | None = None, tiles=None, region=None) -> GaussianCloud:
    """Decode the first ``layers`` layers (all when None) of a parsed, verified container,
    only the ``tiles`` / the tiles meeting ``region`` when given (see :func:`decode`)."""
    h = container.header
    check_header_counts(h, max_gaussians, container.size)
    plan = plan_parts(container.chunks, h.sh_degree)
    count = plan.num_layers if layers is None else int(layers)
    if not 1 <= count <= plan.num_layers:
        raise GszFormatError(f"asked for {count} layers, the file has {plan.num_layers}")
    table = tile_table(container.chunks[plan.tile_chunk].data if plan.tile_chunk is not None else None,
                       plan, h)
    try:
        chosen = select_tiles(table, tiles, region)
    except ValueError as e:
        raise GszError(str(e)) from None
    per_byte = GAUSSIANS_PER_BYTE if max_gaussians is None else None
    with small_pages():      # the whole cloud (or the parts and their concatenation) is fresh memory
        cloud = decode_parts(container, plan, table, chosen, count, per_byte=per_byte, whole=True)
    if region is not None:
        lo, hi = (np.asarray(v, np.float32) for v in check_region(region))
        inside = np.all((cloud.positions >= lo) & (cloud.positions <= hi), axis=1)
        if not inside.all():
            cloud = cloud.subset(np.flatnonzero(inside))
    return cloud


def decode(src, *, layers: int | None = None, partial: bool = False,
           max_gaussians: int | None = None, tiles=None, region=None) -> GaussianCloud:
    """Decode a .gsz file (path or bytes) into a :class:`GaussianCloud`; a .glb carrying a .gsz
    (``EXT_gaussian_splatting_compression_gsz``, GLTF.md §3) decodes to its payload's cloud.

    layers      decode only the first ``layers`` importance layers (None: all); the Gaussians
                come out layer after layer, within a layer tile after tile, each part in
                Morton order
    tiles       decode only these spatial tiles (indices, see ``inspect(...)["tiles"]``; a file
                without tiles has the one tile 0); None: all
    region      ((min_x, min_y, min_z), (max_x, max_y, max_z)): decode only the tiles whose
                bounding box meets the box and return the Gaussians inside it
    partial     accept a truncated file: decode its complete layers and emit one
                :class:`GszTruncatedWarning` (the default raises GszFormatError instead)

    max_gaussians  None (default): reject a file declaring more than 2^28 Gaussians or more
                than GAUSSIANS_PER_BYTE per byte of file (or of a part's chunks: GSZ.md §11),
                which bounds the memory and time a small hostile file can cost; an int: accept
                up to that many Gaussians, whatever the file's size (a trusted file)

    Raises GszFormatError for corrupt, truncated, hostile or unsupported files (checksums are
    verified before any payload is interpreted; GszLimitError, a subclass, for a file above
    the limit) and GszError when the file cannot be read.
    """
    path = None if isinstance(src, (bytes, bytearray, memoryview)) else os.fspath(src)
    max_gaussians = check_max_gaussians(max_gaussians, path)
    if layers is not None and int(layers) < 1:
        raise GszError(f"layers must be >= 1, got {layers}", path)
    if region is not None:
        try:
            check_region(region)
        except ValueError as e:
            raise GszError(str(e), path) from None
    if path is not None and (tiles is not None or region is not None) and not partial and not _glb_file(path):
        return guard(lambda: _decode_tiles_from_file(path, layers=layers, tiles=tiles, region=region,
                                                     max_gaussians=max_gaussians), path)
    data, path = load_bytes(src)
    data = guard(lambda: unwrap_glb(data, partial=partial)[0], path)
    if partial:
        if tiles is not None or region is not None:
            raise GszError("partial decoding reads whole layers: it takes no tiles or region", path)

        def run_partial():
            dec = StreamDecoder(max_gaussians=max_gaussians, max_layers=layers)
            dec.feed(data)
            res = dec.finish(warn=False)
            if res.truncated and res.cloud is not None:
                dec.finish(warn=True, source=path)
            if res.cloud is None:
                raise GszTruncatedError(f"truncated: {len(data)} bytes hold no complete layer "
                                     f"(layer 0 ends at byte {res.next_layer_end or 'unknown'})")
            return res.cloud
        return guard(run_partial, path)

    def run():
        with np.errstate(over="ignore", invalid="ignore"):
            return decode_container(read_container(data, known_types=KNOWN_CHUNKS),
                                    max_gaussians=max_gaussians, layers=layers, tiles=tiles, region=region)
    return guard(run, path)


def unwrap_glb(data, *, partial: bool = False) -> tuple:
    """(the .gsz bytes, their file offset) of ``data``: itself for a .gsz, the payload of its
    ``EXT_gaussian_splatting_compression_gsz`` primitive for a .glb (GLTF.md §3)."""
    if is_glb(data):
        return gsz_payload(data, partial=partial)
    return data, 0


def payload_frame(src) -> int:
    """The coordinate-frame code of a .gsz (or a .glb carrying one) from its header alone, so a
    truncated file has one too."""
    from .container import parse_header
    data, path = load_bytes(src)
    return guard(lambda: parse_header(unwrap_glb(data, partial=True)[0]).frame, path)


def _glb_file(path: str) -> bool:
    """True when the file at ``path`` starts with the GLB magic (its tiles are then read from
    the whole file in memory, not with seeks)."""
    with open_gsz(path) as f:
        try:
            return is_glb(f.read(4))
        except OSError as e:
            raise GszError(f"cannot read: {e.strerror or e}", path) from None


def _decode_tiles_from_file(path: str, *, layers, tiles, region, max_gaussians) -> GaussianCloud:
    """decode() of some tiles of a file on disk: reads the header, the chunk table, the TILE
    chunk and the chosen parts' chunks only (their checksums verified), not the rest."""
    import os

    from .container import TILE_SHIFT, read_container_from_file

    with open_gsz(path) as f:
        size = os.fstat(f.fileno()).st_size

        def chosen_tiles():
            f.seek(0)
            c = read_container_from_file(f, size, wanted=lambda t, fl: t == CHUNK_TILE, known_types=KNOWN_CHUNKS)
            check_header_counts(c.header, max_gaussians, c.size)
            plan = plan_parts(c.chunks, c.header.sh_degree)
            table = tile_table(c.chunks[plan.tile_chunk].data if plan.tile_chunk is not None else None,
                               plan, c.header)
            try:
                return set(select_tiles(table, tiles, region))
            except ValueError as e:
                raise GszError(str(e)) from None
        keep = chosen_tiles()
        f.seek(0)
        c = read_container_from_file(
            f, size, known_types=KNOWN_CHUNKS,
            wanted=lambda t, fl: t == CHUNK_TILE or (t in LAYER_DATA_CHUNKS and (fl >> TILE_SHIFT) & 0xFFFF in keep))
    with np.errstate(over="ignore", invalid="ignore"):
        return decode_container(c, max_gaussians=max_gaussians, layers=layers, tiles=sorted(keep), region=region)


def inspect(src, *, max_gaussians: int | None = None) -> dict:
    """Header fields, chunk table, layers, tiles and metadata of a .gsz file or a .glb carrying
    one (checksums verified), as a dict.  Offsets (chunks, ``decodable_at``) are the file's;
    ``container`` is "gsz" or "glb", ``payload`` the .gsz's place in the file; ``limit`` says
    whether :func:`decode` with ``max_gaussians`` would accept its counts (the file is still
    inspected when it would not)."""
    data, path = load_bytes(src)
    max_gaussians = check_max_gaussians(max_gaussians, path)

    def run():
        payload, base = unwrap_glb(data)
        c = read_container(payload)
        for ch in c.chunks:                  # file offsets, also inside a .glb
            ch.offset += base
        h = c.header
        plan = plan_parts(c.chunks, h.sh_degree)
        return {
            "file": path, "bytes": len(data), "container": "glb" if base else "gsz",
            "payload": {"offset": base, "bytes": len(payload)}, "version": f"{h.version[0]}.{h.version[1]}",
            "num_gaussians": h.num_gaussians, "sh_degree": h.sh_degree, "frame": h.frame,
            "flags": h.flags, "bbox_min": list(h.bbox_min), "bbox_max": list(h.bbox_max),
            "chunks": [{"type": ch.type.decode("ascii"), "name": CHUNK_NAMES.get(ch.type, "unknown"),
                        "offset": ch.offset, "bytes": len(ch.data), "layer": ch.layer, "tile": ch.tile,
                        "required": bool(ch.flags & 1)} for ch in c.chunks],
            "layers": layer_table(c, plan),
            "tiles": tile_rows(c, plan),
            "meta": read_meta(c),
            "limit": limit_verdict(c, plan, max_gaussians),
        }
    return guard(run, path)


def limit_verdict(container: Container, plan, max_gaussians: int | None) -> dict:
    """What decode(max_gaussians=...) decides about a parsed file's counts, before decoding:
    {"max_gaussians": the limit on the header's count, "per_byte": the per-byte limit or None,
    "exceeded": the message decode would raise, or None}."""
    from .errors import GszLimitError
    from .layer import DEFAULT_MAX_GAUSSIANS, check_part_density
    h = container.header
    if max_gaussians is None:
        cap = min(DEFAULT_MAX_GAUSSIANS, GAUSSIANS_PER_BYTE * container.size)
        out = {"max_gaussians": cap, "per_byte": GAUSSIANS_PER_BYTE, "exceeded": None}
    else:
        out = {"max_gaussians": max_gaussians, "per_byte": None, "exceeded": None}
    tiled = plan.tile_chunk is not None
    try:
        if h.num_gaussians:
            check_header_counts(h, max_gaussians, container.size)
        for p in plan.parts:
            state = LayerState(limit=h.num_gaussians, per_byte=out["per_byte"])
            check_part_density(_part_points(container, p), {t: container.chunks[i].data for t, i in p.chunks.items()},
                               state, part_label(p, tiled))
    except GszLimitError as e:
        out["exceeded"] = str(e)
    return out


def _part_points(container: Container, part) -> int:
    geom = container.chunks[part.chunks[CHUNK_GEOM]].data
    return int(struct.unpack_from("<Q", geom, 33)[0]) if len(geom) >= 41 else 0


def layer_table(container: Container, plan=None) -> list[dict]:
    """Per layer (all tiles): Gaussians, byte range of its chunks, and ``decodable_at`` -- the
    file prefix (bytes) after which this layer and every layer before it can be decoded."""
    plan = plan or plan_parts(container.chunks, container.header.sh_degree)
    rows, total = [], 0
    for li in range(plan.num_layers):
        chs = [container.chunks[i] for p in plan.layer_parts(li) for i in p.chunks.values()]
        m = sum(_part_points(container, p) for p in plan.layer_parts(li))
        total += m
        rows.append({"layer": li, "gaussians": int(m), "cumulative_gaussians": int(total),
                     "offset": int(min(ch.offset for ch in chs)),
                     "bytes": int(sum(len(ch.data) for ch in chs)),
                     "decodable_at": int(max(ch.offset + len(ch.data) for ch in chs))})
    return rows


def tile_rows(container: Container, plan=None) -> list[dict]:
    """Per spatial tile: bounding box, Gaussians, bytes, and per layer its part's byte range
    (``decodable_at``: the prefix after which that part can be decoded)."""
    h = container.header
    plan = plan or plan_parts(container.chunks, h.sh_degree)
    table = tile_table(container.chunks[plan.tile_chunk].data if plan.tile_chunk is not None else None,
                       plan, h)
    rows = []
    for t, info in enumerate(table):
        parts = []
        for p in (p for p in plan.parts if p.tile == t):
            chs = [container.chunks[i] for i in p.chunks.values()]
            parts.append({"layer": p.layer, "gaussians": _part_points(container, p),
                          "offset": int(min(ch.offset for ch in chs)),
                          "bytes": int(sum(len(ch.data) for ch in chs)),
                          "decodable_at": int(max(ch.offset + len(ch.data) for ch in chs))})
        rows.append({"tile": t, "bbox_min": list(info.bbox_min), "bbox_max": list(info.bbox_max),
                     "gaussians": info.num_gaussians, "bytes": sum(r["bytes"] for r in parts),
                     "parts": parts})
    return rows
