"""The chunked .gsz container: fixed header, chunk table, checksummed chunks (numpy-free).

Byte layout (normative text: ``format_spec/GSZ.md``)::

    FileHeader   64 bytes  magic, version, counts, SH degree, frame, bbox, CRC-32
    ChunkTable   24 bytes per chunk (type, flags, length, CRC-32) + CRC-32 of the table
    Chunk data   back to back, in table order

Everything is little-endian.  Every byte of the file is covered by a CRC-32
(``zlib.crc32``, the ISO-HDLC polynomial), so corruption is detected before any payload is
interpreted.
"""
from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass, field

from .errors import GszFormatError, GszTruncatedError

MAGIC = b"\x89GSZ\r\n\x1a\n"
VERSION_MAJOR = 1
#: the newest minor version this decoder knows (1.2 added spatial tiles, 1.3 SH classes, 1.4
#: direct-coded octree points, 1.5 RAHT leaf weights, 1.6 the SH colour transform, 1.7 its DC
#: colour bit, 1.8 its SH KLT bit, 1.9 SH codeword refinement); an encoder writes the lowest minor
#: whose features the file uses
VERSION_MINOR = 9
MINOR_LAYERS = 1
MINOR_TILES = 2
MINOR_SH_CLASSES = 3
MINOR_DIRECT = 4
MINOR_RAHT_WEIGHTS = 5
MINOR_SH_COLOUR = 6
MINOR_DC_COLOUR = 7
MINOR_SH_KLT = 8
MINOR_SH_REFINE = 9
HEADER_SIZE = 64
CHUNK_ENTRY_SIZE = 24

#: Limits a decoder enforces so that a hostile header cannot make it allocate unbounded memory.
MAX_CHUNKS = 4096
DEFAULT_MAX_GAUSSIANS = 1 << 28

#: Coordinate frame codes (header byte 25).
FRAME_UNSPECIFIED = 0
FRAME_RDF = 1      # x right, y down, z forward (graphdeco / COLMAP PLY convention)
FRAME_RUB = 2      # x right, y up, z back (OpenGL / SPZ)

#: Chunk flag bits.
CHUNK_REQUIRED = 0x1       # a decoder that does not know this type must reject the file
LAYER_SHIFT = 8            # bits 8..15: layer index (0 = base layer)
TILE_SHIFT = 16            # bits 16..31: tile index (1.2; 0 in a file without a TILE chunk)

_HEADER = struct.Struct("<8sHHIQBBHI6fII")
assert _HEADER.size == HEADER_SIZE
_ENTRY = struct.Struct("<4sIQII")
assert _ENTRY.size == CHUNK_ENTRY_SIZE


@dataclass
class FileHeader:
    num_gaussians: int
    sh_degree: int
    frame: int = FRAME_RDF
    flags: int = 0
    bbox_min: tuple = (0.0, 0.0, 0.0)
    bbox_max: tuple = (0.0, 0.0, 0.0)
    version: tuple = (VERSION_MAJOR, MINOR_LAYERS)


@dataclass
class Chunk:
    type: bytes            # 4 ASCII bytes, e.g. b"GEOM"
    data: bytes
    flags: int = CHUNK_REQUIRED
    offset: int = field(default=0, compare=False)   # absolute file offset (set when parsed)

    @property
    def layer(self) -> int:
        return (self.flags >> LAYER_SHIFT) & 0xFF

    @property
    def tile(self) -> int:
        return (self.flags >> TILE_SHIFT) & 0xFFFF


@dataclass
class Container:
    header: FileHeader
    chunks: list
    #: the file length its chunk table declares (the end of the last chunk, 0 when unknown)
    size: int = 0

    def get(self, ctype: bytes, layer: int = 0) -> Chunk:
        for c in self.chunks:
            if c.type == ctype and c.layer == layer:
                return c
        raise GszFormatError(f"missing required chunk {ctype.decode('ascii', 'replace')}"
                             + (f" for layer {layer}" if layer else ""))

    def find(self, ctype: bytes, layer: int = 0):
        for c in self.chunks:
            if c.type == ctype and c.layer == layer:
                return c
        return None


def write_container(header: FileHeader, chunks: list) -> bytes:
    """Serialise a header and chunks to bytes (deterministic)."""
    if len(chunks) > MAX_CHUNKS:
        raise ValueError(f"too many chunks ({len(chunks)} > {MAX_CHUNKS})")
    major, minor = header.version
    head = _HEADER.pack(MAGIC, int(major), int(minor), HEADER_SIZE, int(header.num_gaussians),
                        int(header.sh_degree), int(header.frame), int(header.flags), len(chunks),
                        *[float(v) for v in header.bbox_min], *[float(v) for v in header.bbox_max], 0, 0)
    head = head[:-4] + struct.pack("<I", zlib.crc32(head[:-4]))
    table = b"".join(
        _ENTRY.pack(c.type, int(c.flags), len(c.data), zlib.crc32(c.data), 0) for c in chunks)
    table += struct.pack("<I", zlib.crc32(table))
    return head + table + b"".join(bytes(c.data) for c in chunks)


def parse_header(buf) -> FileHeader:
    """Parse and verify the 64-byte fixed header; raise GszFormatError on any problem."""
    mv = memoryview(buf)
    if len(mv) < HEADER_SIZE:
        if len(mv) >= 4 and bytes(mv[:4]) != MAGIC[:4]:
            raise GszFormatError("not a .gsz file (bad magic)")
        raise GszTruncatedError(f"truncated: {len(mv)} bytes, the fixed header alone is {HEADER_SIZE}")
    (magic, major, minor, hsize, n, degree, frame, flags, nchunks, *rest) = _HEADER.unpack_from(mv, 0)
    bbox, _reserved, crc = rest[:6], rest[6], rest[7]
    if magic != MAGIC:
        raise GszFormatError("not a .gsz file (bad magic)")
    if zlib.crc32(mv[:HEADER_SIZE - 4]) != crc:
        raise GszFormatError("header checksum mismatch (file corrupt)")
    if major != VERSION_MAJOR:
        raise GszFormatError(f"unsupported format version {major}.{minor} (this decoder reads {VERSION_MAJOR}.x)")
    if hsize != HEADER_SIZE:
        raise GszFormatError(f"unexpected header size {hsize}")
    if degree > 3:
        raise GszFormatError(f"invalid SH degree {degree}")
    if nchunks > MAX_CHUNKS:
        raise GszFormatError(f"chunk count {nchunks} exceeds the limit {MAX_CHUNKS}")
    return FileHeader(num_gaussians=n, sh_degree=degree, frame=frame, flags=flags,
                      bbox_min=tuple(bbox[:3]), bbox_max=tuple(bbox[3:]), version=(major, minor))


def _num_chunks(buf) -> int:
    return struct.unpack_from("<I", buf, 28)[0]


def table_size(num_chunks: int) -> int:
    return CHUNK_ENTRY_SIZE * num_chunks + 4


def parse_table(buf, num_chunks: int):
    """Parse the chunk table that follows the header: [(type, flags, length, crc, offset)]."""
    mv = memoryview(buf)
    end = HEADER_SIZE + table_size(num_chunks)
    if len(mv) < end:
        raise GszTruncatedError(f"truncated: chunk table needs {end} bytes, file has {len(mv)}")
    tbl = mv[HEADER_SIZE:end - 4]
    if zlib.crc32(tbl) != struct.unpack_from("<I", mv, end - 4)[0]:
        raise GszFormatError("chunk table checksum mismatch (file corrupt)")
    entries = []
    offset = end
    for i in range(num_chunks):
        ctype, cflags, length, crc, _res = _ENTRY.unpack_from(tbl, i * CHUNK_ENTRY_SIZE)
        if not all(0x20 <= b < 0x7F for b in ctype):
            raise GszFormatError(f"chunk {i} has an invalid type code {ctype!r}")
        entries.append((ctype, cflags, length, crc, offset))
        offset += length
    return entries, end


def read_container(buf, *, known_types=None, strict_length: bool = True) -> Container:
    """Parse and checksum-verify a whole .gsz file held in memory.

    Unknown chunk types are skipped unless flagged required, in which case the file is
    rejected.  Raises GszFormatError on truncation, checksum mismatch or trailing bytes.
    """
    mv = memoryview(buf)
    header = parse_header(mv)
    entries, pos = parse_table(mv, _num_chunks(mv))
    chunks = []
    for i, (ctype, cflags, length, crc, offset) in enumerate(entries):
        if offset + length > len(mv):
            raise GszTruncatedError(
                f"truncated: chunk {i} ({ctype.decode()}) ends at byte {offset + length}, "
                f"file has {len(mv)} bytes")
        data = mv[offset:offset + length]
        if zlib.crc32(data) != crc:
            raise GszFormatError(f"chunk {i} ({ctype.decode()}) checksum mismatch (file corrupt)")
        if known_types is not None and ctype not in known_types:
            if cflags & CHUNK_REQUIRED:
                raise GszFormatError(f"required chunk type {ctype.decode()} is not supported by this decoder")
            continue
        chunks.append(Chunk(type=ctype, data=data, flags=cflags, offset=offset))
    end = entries[-1][4] + entries[-1][2] if entries else pos
    if strict_length and len(mv) != end:
        raise GszFormatError(f"{len(mv) - end} unexpected trailing bytes after the last chunk")
    return Container(header=header, chunks=chunks, size=end)


def read_container_from_file(f, size: int, *, wanted, known_types=None) -> Container:
    """Parse and checksum-verify the header, the chunk table and only the chunks for which
    ``wanted(type, flags)`` is true, reading them from the open binary file ``f`` of ``size``
    bytes with seeks (a region of a large tiled file costs its own bytes, not the file's).
    The table's declared end must equal ``size`` (truncation and trailing bytes are rejected as
    by :func:`read_container`); chunks not read are not checksummed."""
    head = f.read(HEADER_SIZE)
    header = parse_header(head)
    n = _num_chunks(head)
    table = head + f.read(table_size(n))
    entries, pos = parse_table(table, n)
    end = entries[-1][4] + entries[-1][2] if entries else pos
    if size < end:
        raise GszTruncatedError(f"truncated: the chunk table declares {end} bytes, file has {size}")
    if size > end:
        raise GszFormatError(f"{size - end} unexpected trailing bytes after the last chunk")
    chunks = []
    for i, (ctype, cflags, length, crc, offset) in enumerate(entries):
        if known_types is not None and ctype not in known_types:
            if cflags & CHUNK_REQUIRED:
                raise GszFormatError(f"required chunk type {ctype.decode()} is not supported by this decoder")
            continue
        if not wanted(ctype, cflags):
            chunks.append(Chunk(type=ctype, data=memoryview(b""), flags=cflags, offset=offset))
            continue
        f.seek(offset)
        data = f.read(length)
        if len(data) != length:
            raise GszTruncatedError(f"truncated: chunk {i} ({ctype.decode()}) ends past the end of the file")
        if zlib.crc32(data) != crc:
            raise GszFormatError(f"chunk {i} ({ctype.decode()}) checksum mismatch (file corrupt)")
        chunks.append(Chunk(type=ctype, data=memoryview(data), flags=cflags, offset=offset))
    return Container(header=header, chunks=chunks, size=end)
