"""Read and write SPZ (.spz), Niantic's (now Adobe's) packed splat format, versions 2, 3 and 4
(numpy + zstandard; gzip from the standard library).

Layout: a 16-byte header (``NGSP`` magic, version, count, SH degree, fractional bits, flags)
then, attribute by attribute, 24-bit fixed-point positions, alpha bytes, colour bytes
(``0.5 + 0.15 * dc``), log-scale bytes (``(s + 10) * 16``), rotations (v2: x, y, z bytes with
w >= 0; v3+: the smallest three components in 10 bits each) and SH bytes (``(b - 128) / 128``,
coefficient-major, RGB inner).  Versions 1-3 gzip all of it; version 4 has a plain 32-byte
header (stream count, table-of-contents offset), optional extension records, the table of
contents and one zstd stream per attribute.

Frame: the SPZ README calls the stored frame RUB, but neither splat-transform (3.x, and so
SuperSplat) nor Niantic's own PLY converter convert when writing: most files in circulation hold
the PLY's RDF values as they were.  gsz follows splat-transform: a file is read as RDF unless it
carries Adobe's coordinate-system extension (``0xADBE0003``), which then says its frame;
``read_spz(path, frame="RUB")`` reads a file known to be RUB.  gsz writes RDF, no extension,
so splat-transform and gsz read each other's files unchanged.
"""
from __future__ import annotations

import gzip
import os
import struct
import warnings
import zlib

import numpy as np

from .cloud import GaussianCloud
from .container import DEFAULT_MAX_GAUSSIANS
from .delivery import logit_of_alpha_bytes, sigmoid, unit_quaternions
from .errors import GszError, GszInputWarning, SpzFormatError
from .frames import FRAME_SIGNS, flip_axes
from .io_util import atomic_write, read_all

MAGIC = b"NGSP"
HEADER_BYTES = 16
HEADER_V4_BYTES = 32
FLAG_ANTIALIASED, FLAG_EXTENSIONS = 0x1, 0x2
COLOR_SCALE = 0.15
#: SH bytes per Gaussian (all three channels) by degree; SPZ goes to degree 4
SH_BYTES = {0: 0, 1: 9, 2: 24, 3: 45, 4: 72}
#: Adobe's extension that names the stored frame (payload: one u32, an index of COORDINATE_SYSTEMS)
EXT_COORDINATE_SYSTEM = 0xADBE0003
COORDINATE_SYSTEMS = ("UNSPECIFIED", "LDB", "RDB", "LUB", "RUB", "LDF", "RDF", "LUF", "RUF",
                      "LFD", "RFD", "LFU", "RFU", "LBD", "RBD", "LBU", "RBU")
#: gzip expands by at most ~1032:1; a header declaring more than this many bytes per input byte
#: is corrupt (or a bomb) and is refused before any inflating
_GZIP_MAX_RATIO = 1100
#: a v4 file holds at least this many Gaussians per byte only when it is hostile (real SPZ files
#: spend 4-40 bytes per Gaussian); pass max_gaussians= to read a trusted one anyway
_V4_MAX_GAUSSIANS_PER_BYTE = 1024


def is_spz(head: bytes) -> bool:
    """True when the first bytes of a file (a few kB for a gzip-wrapped one) are an SPZ's."""
    if head[:4] == MAGIC:
        return True
    if head[:2] != b"\x1f\x8b":
        return False
    try:
        return zlib.decompressobj(16 + zlib.MAX_WBITS).decompress(head, 4) == MAGIC
    except zlib.error:
        return False


def read_spz(path, *, frame: str | None = None, max_gaussians: int | None = None) -> GaussianCloud:
    """The scene in the .spz file ``path`` (versions 2-4) as a graphdeco cloud (RDF frame).

    ``frame`` names the frame of a file without a coordinate-system extension (default RDF, see
    the module notes; "RUB" for files written by Niantic's converters with a RUB target).
    ``max_gaussians`` bounds what a header may declare (default 2^28, and for a version-4 file
    1024 per byte of the file).  Raises :class:`SpzFormatError` naming the file and the problem.
    """
    path = os.fspath(path)
    return spz_from_bytes(read_all(path, SpzFormatError), path, frame=frame, max_gaussians=max_gaussians)


def spz_from_bytes(data: bytes, name=None, *, frame: str | None = None,
                   max_gaussians: int | None = None) -> GaussianCloud:
    """:func:`read_spz` of the bytes of a file (``name`` is used in messages)."""
    if frame is not None and frame.upper() not in FRAME_SIGNS:
        raise GszError(f"frame must be one of {', '.join(sorted(FRAME_SIGNS))}, got {frame!r}")

    def fail(message):
        return SpzFormatError(message, name)

    data = memoryview(data)
    if bytes(data[:4]) == MAGIC:
        parts = _unpack_v4(data, fail, max_gaussians)
    elif bytes(data[:2]) == b"\x1f\x8b":
        parts = _unpack_gzip(data, fail, max_gaussians)
    else:
        raise fail("not an SPZ file: neither a gzip stream nor the NGSP magic")
    n, degree, version, frac, flags, streams, stored = parts
    cloud = _decode(n, degree, version, frac, streams)
    if flags & FLAG_ANTIALIASED:
        cloud.extra["antialiased"] = True     # trained with mip-splatting's filter (not applied here)
    if stored is None:
        stored = (frame or "RDF").upper()
    return flip_axes(cloud, FRAME_SIGNS[stored])


def _header(head: bytes, fail):
    """(version, count, SH degree, fractional bits, flags) of the first 16 bytes."""
    if len(head) < HEADER_BYTES:
        raise fail(f"truncated: only {len(head)} bytes of the 16-byte SPZ header")
    magic, version, n, degree, frac, flags = struct.unpack_from("<4sIIBBB", head)
    if magic != MAGIC:
        raise fail("not an SPZ file (no NGSP magic in its header)")
    if version == 1:
        raise fail("SPZ version 1 (float16 positions, never released) is not supported; re-save it as version 3")
    if not 2 <= version <= 4:
        raise fail(f"SPZ version {version} is not one gsz reads (2, 3 or 4)")
    if degree not in SH_BYTES:
        raise fail(f"SH degree {degree} is not 0-4")
    if frac > 23:
        raise fail(f"{frac} fractional bits do not fit a 24-bit position")
    return version, n, degree, frac, flags


def _sizes(n: int, degree: int, version: int) -> list:
    """Bytes of each attribute block in file order: positions, alphas, colours, scales,
    rotations, SH."""
    return [9 * n, n, 3 * n, 3 * n, (3 if version == 2 else 4) * n, SH_BYTES[degree] * n]


def _check_count(n: int, limit: int, fail, explicit: bool):
    if n > limit:
        why = "more than the limit of" if explicit else "more than the default limit of"
        raise fail(f"declares {n:,} Gaussians, {why} {limit:,}; if the file is trusted pass max_gaussians=")


def _unpack_gzip(data, fail, max_gaussians):
    """Versions 2-3: one gzip stream holding the header and the attribute blocks."""
    d = zlib.decompressobj(16 + zlib.MAX_WBITS)
    try:
        head = d.decompress(data, HEADER_BYTES)
        version, n, degree, frac, flags = _header(head, fail)
        if version == 4:
            raise fail("a gzip-wrapped file declares SPZ version 4, whose header is never compressed")
        _check_count(n, max_gaussians or DEFAULT_MAX_GAUSSIANS, fail, max_gaussians is not None)
        sizes = _sizes(n, degree, version)
        need = sum(sizes)
        if need > _GZIP_MAX_RATIO * len(data) + (1 << 20):
            raise fail(f"declares {n:,} Gaussians ({need:,} bytes) but holds only {len(data):,} "
                       "compressed bytes, which gzip cannot expand that far: truncated or corrupt")
        cap = need + (1 << 16) + 1             # room for extension records, and one byte to spot excess
        body = d.decompress(d.unconsumed_tail, cap)
        while len(body) < cap and d.unconsumed_tail and not d.eof:
            body += d.decompress(d.unconsumed_tail, cap - len(body))
    except zlib.error as e:                  # includes a CRC or length mismatch at the stream's end
        raise fail(f"corrupt gzip data: {e}") from None
    if len(body) < need:
        raise fail(f"truncated: the gzip stream holds {len(body):,} of the {need:,} data bytes its header "
                   f"declares ({n:,} Gaussians, SH degree {degree})")
    if len(body) == cap:
        raise fail(f"holds more data than its header declares ({n:,} Gaussians, SH degree {degree}): corrupt")
    if not d.eof:
        raise fail("truncated: the gzip stream stops before its end (its checksum is missing)")
    start = 0
    stored = None
    if flags & FLAG_EXTENSIONS and len(body) > need:
        # the extension records sit between the header and the positions (Niantic's writer)
        start = len(body) - need
        stored = _extensions(bytes(body[:start]), fail, strict=False)
    streams, o = [], start
    for size in sizes:
        streams.append(np.frombuffer(body, np.uint8, size, o))
        o += size
    return n, degree, version, frac, flags, streams, stored


def _unpack_v4(data, fail, max_gaussians):
    """Version 4: a plain 32-byte header, extension records, a table of contents, then one zstd
    stream per attribute."""
    import zstandard

    if len(data) < HEADER_V4_BYTES:
        raise fail(f"truncated: {len(data)} bytes, less than the 32-byte SPZ v4 header")
    version, n, degree, frac, flags = _header(bytes(data[:HEADER_BYTES]), fail)
    if version != 4:
        raise fail(f"an uncompressed header declares SPZ version {version}; versions 2-3 are gzip-wrapped")
    num_streams = data[15]
    toc_offset = struct.unpack_from("<I", data, 16)[0]
    limit = max_gaussians or min(DEFAULT_MAX_GAUSSIANS, _V4_MAX_GAUSSIANS_PER_BYTE * len(data) + 65536)
    _check_count(n, limit, fail, max_gaussians is not None)
    sizes = _sizes(n, degree, 4)
    want = 6 if degree > 0 else 5
    if num_streams != want:
        raise fail(f"has {num_streams} attribute streams; SH degree {degree} needs {want}")
    if not HEADER_V4_BYTES <= toc_offset <= len(data) - 16 * num_streams:
        raise fail(f"truncated or corrupt: its table of contents at byte {toc_offset:,} does not fit "
                   f"the file's {len(data):,} bytes")
    stored = None
    if flags & FLAG_EXTENSIONS:
        stored = _extensions(bytes(data[HEADER_V4_BYTES:toc_offset]), fail, strict=True)
    toc = np.frombuffer(data, "<u8", 2 * num_streams, toc_offset).reshape(num_streams, 2)
    o = toc_offset + 16 * num_streams
    names = ("positions", "alphas", "colours", "scales", "rotations", "SH")
    dctx = zstandard.ZstdDecompressor()
    streams = []
    for i in range(num_streams):
        packed, size = int(toc[i, 0]), int(toc[i, 1])
        if size != sizes[i]:
            raise fail(f"its {names[i]} stream declares {size:,} bytes; {n:,} Gaussians need {sizes[i]:,}")
        if o + packed > len(data):
            raise fail(f"truncated: the {names[i]} stream ends at byte {o + packed:,} of a "
                       f"{len(data):,}-byte file")
        try:
            raw = dctx.decompress(bytes(data[o:o + packed]), max_output_size=size) if size else b""
        except zstandard.ZstdError as e:
            raise fail(f"corrupt zstd data in the {names[i]} stream: {e}") from None
        if len(raw) != size:
            raise fail(f"its {names[i]} stream decompresses to {len(raw):,} bytes, not {size:,}")
        streams.append(np.frombuffer(raw, np.uint8))
        o += packed
    if degree == 0:
        streams.append(np.zeros(0, np.uint8))
    return n, degree, 4, frac, flags, streams, stored


def _extensions(block: bytes, fail, strict: bool):
    """The frame named by a coordinate-system extension among the records in ``block``
    ([u32 type][u32 length][payload] each), or None.  Unknown records are skipped; ``strict``
    (version 4) refuses a block that does not parse, otherwise a warning says it was skipped."""
    o, stored = 0, None
    while o + 8 <= len(block):
        kind, length = struct.unpack_from("<II", block, o)
        if o + 8 + length > len(block):
            break
        if kind == EXT_COORDINATE_SYSTEM and length >= 4:
            code = struct.unpack_from("<I", block, o + 8)[0]
            if code >= len(COORDINATE_SYSTEMS):
                raise fail(f"its coordinate-system extension names unknown frame {code}")
            name = COORDINATE_SYSTEMS[code]
            if name == "UNSPECIFIED":
                name = "RUB"                   # what Adobe's reference reader falls back to
            if name not in FRAME_SIGNS:
                raise fail(f"is stored in the z-up frame {name}, which gsz does not convert yet "
                           "(y-up frames: " + ", ".join(sorted(FRAME_SIGNS)) + ")")
            stored = name
        o += 8 + length
    if o != len(block):
        if strict:
            raise fail(f"corrupt extension records: {len(block) - o} bytes left over before the table of contents")
        warnings.warn(GszInputWarning("SPZ extension records gsz cannot parse were skipped"), stacklevel=4)
    return stored


def _decode(n, degree, version, frac, streams) -> GaussianCloud:
    pos_b, alpha_b, colour_b, scale_b, rot_b, sh_b = streams
    p = pos_b.reshape(n, 3, 3).astype(np.int32)
    fixed = p[..., 0] | (p[..., 1] << 8) | (p[..., 2] << 16)
    fixed = np.where(fixed >= 1 << 23, fixed - (1 << 24), fixed)          # sign-extend 24 bits
    positions = fixed.astype(np.float64) / float(1 << frac)
    scales = scale_b.reshape(n, 3).astype(np.float32) / 16.0 - 10.0
    opacities = logit_of_alpha_bytes(alpha_b)
    sh_dc = ((colour_b.reshape(n, 3).astype(np.float64) / 255.0 - 0.5) / COLOR_SCALE).astype(np.float32)
    if version == 2:
        xyz = rot_b.reshape(n, 3).astype(np.float64) / 127.5 - 1.0
        w = np.sqrt(np.maximum(0.0, 1.0 - (xyz * xyz).sum(axis=1)))
        rotations = np.concatenate([w[:, None], xyz], axis=1)
    else:
        rotations = _smallest_three_10bit(rot_b.view("<u4").astype(np.uint32))
    k = SH_BYTES[degree] // 3
    rest = ((sh_b.reshape(n, k, 3).astype(np.float32) - 128.0) / 128.0) if k else np.zeros((n, 0, 3), np.float32)
    if degree == 4:
        warnings.warn(GszInputWarning("SH degree 4 of an SPZ file dropped to degree 3 (the highest "
                                      "gsz holds)"), stacklevel=4)
        rest, degree = rest[:, :15], 3
    return GaussianCloud(positions.astype(np.float32), scales, unit_quaternions(rotations), opacities,
                         sh_dc, rest, degree)


def _smallest_three_10bit(packed: np.ndarray) -> np.ndarray:
    """[N, 4] (w, x, y, z) of SPZ v3+ rotations: 2 bits naming the largest of (x, y, z, w),
    then three 10-bit values (a sign bit and 9 bits of |v| * sqrt 2), the last one lowest."""
    n = len(packed)
    largest = (packed >> 30).astype(np.int64)
    q = np.zeros((n, 4), np.float64)         # x, y, z, w as SPZ orders them
    rest = packed.copy()
    for j in (3, 2, 1, 0):
        take = largest != j
        mag = (rest & 511).astype(np.float64) / 511.0 * np.sqrt(0.5)
        neg = ((rest >> 9) & 1).astype(bool)
        q[take, j] = np.where(neg, -mag, mag)[take]
        rest = np.where(take, rest >> 10, rest)
    q[np.arange(n), largest] = np.sqrt(np.maximum(0.0, 1.0 - (q * q).sum(axis=1)))
    return q[:, [3, 0, 1, 2]]


def spz_bytes(cloud: GaussianCloud, *, version: int = 3) -> bytes:
    """``cloud`` (RDF) as the bytes of a .spz file of ``version`` 3 (gzip; what every SPZ reader,
    splat-transform's included, reads) or 4 (zstd streams), deterministic for a given cloud.
    Quantised as Niantic's reference packer does (12 fractional position bits unless the scene
    is too large for them, 5-bit SH band 1, 4-bit higher bands)."""
    import zstandard

    if version not in (3, 4):
        raise GszError(f"SPZ version must be 3 or 4, got {version}")
    cloud.validate(check_finite=True)
    n, degree = len(cloud), cloud.sh_degree
    pos = cloud.positions.astype(np.float64)
    span = float(np.abs(pos).max()) if n else 0.0
    frac = 12
    while frac > 0 and span * (1 << frac) > (1 << 23) - 1:
        frac -= 1                              # a large scene trades precision for range
    if span * (1 << frac) > (1 << 23) - 1:
        raise GszError(f"positions reach {span:,.0f}: beyond the +-8,388,607 an SPZ file holds")
    fixed = _round_half_away(pos * (1 << frac)).astype(np.int64) & 0xFFFFFF
    positions = np.stack([fixed & 255, (fixed >> 8) & 255, fixed >> 16], axis=-1).astype(np.uint8)
    alphas = _to_u8(sigmoid(cloud.opacities) * 255.0)
    colours = _to_u8(cloud.sh_dc.astype(np.float64) * (COLOR_SCALE * 255.0) + 127.5)
    scales = _to_u8((cloud.scales.astype(np.float64) + 10.0) * 16.0)
    rotations = _pack_smallest_three(cloud.rotations)
    k = cloud.sh_rest.shape[1]
    sh = np.zeros((n, k, 3), np.uint8)
    if k:
        q = _round_half_away(cloud.sh_rest.astype(np.float64) * 128.0) + 128.0
        bucket = np.where(np.arange(k) < 3, 8, 16)[None, :, None]       # 5 bits band 1, 4 bits above
        sh = np.clip((q + bucket // 2) // bucket * bucket, 0, 255).astype(np.uint8)
    blocks = [positions.tobytes(), alphas.tobytes(), colours.tobytes(), scales.tobytes(),
              rotations.tobytes(), sh.tobytes()]
    if version == 3:
        header = struct.pack("<4sIIBBBB", MAGIC, 3, n, degree, frac, 0, 0)
        return gzip.compress(header + b"".join(blocks), compresslevel=9, mtime=0)
    if degree == 0:
        blocks = blocks[:5]
    cctx = zstandard.ZstdCompressor(level=12)
    packed = [cctx.compress(b) for b in blocks]
    header = struct.pack("<4sIIBBBBI12x", MAGIC, 4, n, degree, frac, 0, len(blocks), HEADER_V4_BYTES)
    toc = b"".join(struct.pack("<QQ", len(c), len(b)) for c, b in zip(packed, blocks))
    return header + toc + b"".join(packed)


def write_spz(cloud: GaussianCloud, path, *, version: int = 3) -> None:
    """Write ``cloud`` as a .spz file (:func:`spz_bytes`), atomically."""
    atomic_write(path, spz_bytes(cloud, version=version))


def _round_half_away(v: np.ndarray) -> np.ndarray:
    """C's round(): halves away from zero (numpy rounds them to even)."""
    return np.sign(v) * np.floor(np.abs(v) + 0.5)


def _to_u8(v) -> np.ndarray:
    return np.clip(_round_half_away(np.asarray(v, np.float64)), 0, 255).astype(np.uint8)


def _pack_smallest_three(rotations: np.ndarray) -> np.ndarray:
    """uint32 [N] of (w, x, y, z) rotations in SPZ v3's smallest-three form (see
    :func:`_smallest_three_10bit`)."""
    q = rotations.astype(np.float64)[:, [1, 2, 3, 0]]                  # SPZ order: x, y, z, w
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    n = len(q)
    largest = np.argmax(np.abs(q), axis=1)
    q *= np.where(q[np.arange(n), largest] < 0, -1.0, 1.0)[:, None]    # the largest made positive
    comp = largest.astype(np.uint64)
    for i in range(4):
        take = largest != i
        mag = np.floor(511.0 * np.abs(q[:, i]) / np.sqrt(0.5) + 0.5).astype(np.uint64)
        bits = ((q[:, i] < 0).astype(np.uint64) << np.uint64(9)) | np.minimum(mag, 511)
        comp = np.where(take, (comp << np.uint64(10)) | bits, comp)
    return comp.astype(np.uint32)
