"""Whole-file decoding: ``decode(path_or_bytes) -> GaussianCloud`` and ``inspect`` for gsz-info.

numpy only.  Every failure on bad input is a :class:`GszFormatError` (or :class:`GszError` for
I/O problems) whose message names the file.
"""
from __future__ import annotations

import json
import os
import struct

import numpy as np

from .attributes import read_attributes
from .cloud import GaussianCloud
from .container import DEFAULT_MAX_GAUSSIANS, Container, read_container
from .errors import GszError, GszFormatError
from .geometry import read_geometry
from .layout import CHUNK_ATTR, CHUNK_GEOM, CHUNK_META, CHUNK_SHVQ, KNOWN_CHUNKS
from .morton import morton_encode
from .raht import build_raht_tree
from .sh import read_sh

#: Chunk type names for reports.
CHUNK_NAMES = {CHUNK_GEOM: "geometry (octree)", CHUNK_ATTR: "attributes (RAHT + scales)",
               CHUNK_SHVQ: "SH (codebook + kept + indices)", CHUNK_META: "metadata (JSON)"}


def _load_bytes(src):
    if isinstance(src, (bytes, bytearray, memoryview)):
        return memoryview(src), None
    path = os.fspath(src)
    try:
        with open(path, "rb") as f:
            return memoryview(f.read()), path
    except FileNotFoundError:
        raise GszError("file not found", path) from None
    except IsADirectoryError:
        raise GszError("is a directory, expected a .gsz file", path) from None
    except OSError as e:
        raise GszError(f"cannot read: {e.strerror or e}", path) from None


def _guard(fn, path):
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


def decode_container(container: Container, *, max_gaussians: int = DEFAULT_MAX_GAUSSIANS) -> GaussianCloud:
    h = container.header
    if h.num_gaussians > max_gaussians:
        raise GszFormatError(f"declares {h.num_gaussians} Gaussians, above the decoder limit {max_gaussians}")
    if h.num_gaussians == 0:
        raise GszFormatError("declares zero Gaussians")
    geom = read_geometry(container.get(CHUNK_GEOM).data, max_points=h.num_gaussians)
    m = len(geom.ijk)
    if m != h.num_gaussians:
        raise GszFormatError(f"geometry holds {m} points, header says {h.num_gaussians}")
    tree = build_raht_tree(morton_encode(geom.ijk), geom.depth)
    attrs = read_attributes(container.get(CHUNK_ATTR).data, tree)
    if h.sh_degree > 0:
        sh_rest = read_sh(container.get(CHUNK_SHVQ).data, m, h.sh_degree)
    else:
        sh_rest = np.zeros((m, 0, 3), np.float32)
    cloud = GaussianCloud(positions=geom.positions, scales=attrs.scales, rotations=attrs.rotations,
                          opacities=attrs.opacities, sh_dc=attrs.sh_dc, sh_rest=sh_rest,
                          sh_degree=h.sh_degree)
    # Well-formed streams always decode to finite float32 values; hostile parameters (huge
    # min/max, DC) can overflow float32, which is rejected rather than returned.
    for name in ("positions", "scales", "rotations", "opacities", "sh_dc", "sh_rest"):
        if not np.isfinite(getattr(cloud, name)).all():
            raise GszFormatError(f"decoded {name} contain non-finite values (corrupt parameters)")
    return cloud


def decode(src, *, max_gaussians: int = DEFAULT_MAX_GAUSSIANS) -> GaussianCloud:
    """Decode a .gsz file (path or bytes) into a :class:`GaussianCloud`.

    Raises GszFormatError for corrupt, truncated, hostile or unsupported files (checksums are
    verified before any payload is interpreted) and GszError when the file cannot be read.
    ``max_gaussians`` bounds what a hostile header can make the decoder allocate.
    """
    data, path = _load_bytes(src)
    def run():
        with np.errstate(over="ignore", invalid="ignore"):
            return decode_container(read_container(data, known_types=KNOWN_CHUNKS),
                                    max_gaussians=max_gaussians)
    return _guard(run, path)


def inspect(src) -> dict:
    """Header fields, chunk table and metadata of a .gsz file (checksums verified), as a dict."""
    data, path = _load_bytes(src)

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
            "meta": read_meta(c),
        }
    return _guard(run, path)
