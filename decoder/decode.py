"""Whole-file decoding: ``decode(path_or_bytes) -> GaussianCloud`` and ``inspect`` for gsz-info.

numpy only.  Every failure on bad input is a :class:`GszFormatError` (or :class:`GszError` for
I/O problems) whose message names the file.
"""
from __future__ import annotations

import json
import struct

import numpy as np

from .cloud import GaussianCloud
from .container import DEFAULT_MAX_GAUSSIANS, Container, read_container
from .errors import GszError, GszFormatError, GszTruncatedError
# LAYER_DATA_CHUNKS, open_gsz and the layer names stay importable from here (their old home)
from .layer import (LAYER_DATA_CHUNKS, LayerState, check_header_counts, concat_clouds,  # noqa: F401
                    decode_layer, guard, load_bytes, open_gsz, plan_layers)
from .layout import CHUNK_ATTR, CHUNK_GEOM, CHUNK_META, CHUNK_SHVQ, KNOWN_CHUNKS
from .stream import StreamDecoder

#: Chunk type names for reports.
CHUNK_NAMES = {CHUNK_GEOM: "geometry (octree)", CHUNK_ATTR: "attributes (RAHT + scales)",
               CHUNK_SHVQ: "SH (codebook + kept + indices)", CHUNK_META: "metadata (JSON)"}


def read_meta(container: Container) -> dict:
    """The informative META chunk as a dict ({} when absent or unreadable: it is optional)."""
    c = container.find(CHUNK_META)
    if c is None:
        return {}
    import zstandard
    try:
        raw = zstandard.ZstdDecompressor().decompress(bytes(c.data), max_output_size=1 << 24)
        meta = json.loads(raw.decode("utf-8"))
        return meta if isinstance(meta, dict) else {}
    except (zstandard.ZstdError, ValueError, UnicodeDecodeError):
        return {}


def decode_container(container: Container, *, max_gaussians: int = DEFAULT_MAX_GAUSSIANS,
                     layers: int | None = None) -> GaussianCloud:
    """Decode the first ``layers`` layers (all when None) of a parsed, verified container."""
    h = container.header
    check_header_counts(h, max_gaussians)
    plan = plan_layers(container.chunks, h.sh_degree)
    count = len(plan) if layers is None else int(layers)
    if not 1 <= count <= len(plan):
        raise GszFormatError(f"asked for {count} layers, the file has {len(plan)}")
    state = LayerState()
    parts = [decode_layer({t: container.chunks[i].data for t, i in plan[li].items()}, h, state)
             for li in range(count)]
    if count == len(plan) and state.decoded_points != h.num_gaussians:
        raise GszFormatError(f"layers hold {state.decoded_points} Gaussians, header says {h.num_gaussians}")
    return concat_clouds(parts)


def decode(src, *, layers: int | None = None, partial: bool = False,
           max_gaussians: int = DEFAULT_MAX_GAUSSIANS) -> GaussianCloud:
    """Decode a .gsz file (path or bytes) into a :class:`GaussianCloud`.

    layers      decode only the first ``layers`` importance layers (None: all); the Gaussians
                come out layer after layer, each layer in Morton order
    partial     accept a truncated file: decode its complete layers and emit one
                :class:`GszTruncatedWarning` (the default raises GszFormatError instead)

    Raises GszFormatError for corrupt, truncated, hostile or unsupported files (checksums are
    verified before any payload is interpreted) and GszError when the file cannot be read.
    ``max_gaussians`` bounds what a hostile header can make the decoder allocate.
    """
    data, path = load_bytes(src)
    if layers is not None and int(layers) < 1:
        raise GszError(f"layers must be >= 1, got {layers}", path)
    if partial:
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
                                    max_gaussians=max_gaussians, layers=layers)
    return guard(run, path)


def inspect(src) -> dict:
    """Header fields, chunk table and metadata of a .gsz file (checksums verified), as a dict."""
    data, path = load_bytes(src)

    def run():
        c = read_container(data)
        h = c.header
        return {
            "file": path, "bytes": len(data), "version": f"{h.version[0]}.{h.version[1]}",
            "num_gaussians": h.num_gaussians, "sh_degree": h.sh_degree, "frame": h.frame,
            "flags": h.flags, "bbox_min": list(h.bbox_min), "bbox_max": list(h.bbox_max),
            "chunks": [{"type": ch.type.decode("ascii"), "name": CHUNK_NAMES.get(ch.type, "unknown"),
                        "offset": ch.offset, "bytes": len(ch.data), "layer": ch.layer,
                        "required": bool(ch.flags & 1)} for ch in c.chunks],
            "layers": layer_table(c),
            "meta": read_meta(c),
        }
    return guard(run, path)


def layer_table(container: Container) -> list[dict]:
    """Per layer: Gaussians, byte range of its chunks, and ``decodable_at`` -- the file prefix
    (bytes) after which this layer and every layer before it can be decoded."""
    h = container.header
    plan = plan_layers(container.chunks, h.sh_degree)
    rows, total = [], 0
    for li, got in enumerate(plan):
        chs = [container.chunks[i] for i in got.values()]
        geom = container.chunks[got[CHUNK_GEOM]].data
        m = struct.unpack_from("<Q", geom, 33)[0] if len(geom) >= 41 else 0
        total += m
        start = min(ch.offset for ch in chs)
        end = max(ch.offset + len(ch.data) for ch in chs)
        rows.append({"layer": li, "gaussians": int(m), "cumulative_gaussians": int(total),
                     "offset": int(start), "bytes": int(sum(len(ch.data) for ch in chs)),
                     "decodable_at": int(end)})
    return rows
