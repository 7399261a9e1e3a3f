"""The GLB container (binary glTF 2.0) and the ``EXT_gaussian_splatting_compression_gsz``
payload inside it (``format_spec/GLTF.md``), read without any glTF library.

Reading the .gsz payload out of a .glb is container parsing only, so it lives in the decoder
core: a numpy-only application decodes a .glb-wrapped .gsz with ``gsz.decoder.decode`` and
streams it with ``StreamDecoder`` without installing a glTF package.  (Writing glTF and reading
plain ``KHR_gaussian_splatting`` attributes go through pygltflib: ``gsz.decoder.gltf``.)

GLB layout (glTF 2.0 §4.4), little-endian::

    u32 magic 'glTF' | u32 version 2 | u32 total length
    u32 length | u32 type 'JSON' | JSON text (UTF-8, space-padded to 4 bytes)
    u32 length | u32 type 'BIN\\0' | binary buffer 0 (zero-padded to 4 bytes)   -- optional
"""
from __future__ import annotations

import json
import struct
from dataclasses import dataclass

from .errors import GszFormatError, GszTruncatedError

GLB_MAGIC = b"glTF"
GLB_VERSION = 2
GLB_HEADER_SIZE = 12
CHUNK_HEADER_SIZE = 8
CHUNK_JSON = 0x4E4F534A
CHUNK_BIN = 0x004E4942
#: the base extension and gsz's compression sub-extension (GLTF.md)
KHR_GAUSSIAN_SPLATTING = "KHR_gaussian_splatting"
EXT_GSZ = "EXT_gaussian_splatting_compression_gsz"
#: Largest JSON chunk read: the JSON of a splat scene is a few kB; a hostile length field must
#: not make the decoder buffer gigabytes before it can say the file is bad.
MAX_JSON_BYTES = 1 << 26


def is_glb(prefix) -> bool:
    """True when ``prefix`` (the first bytes of a file) starts with the GLB magic."""
    return bytes(prefix[:4]) == GLB_MAGIC


@dataclass
class Glb:
    """A parsed GLB: the JSON document, the declared total length and the BIN chunk's place."""
    doc: dict
    length: int                  # total length from the GLB header
    bin_offset: int | None       # file offset of the BIN chunk's data (None: no BIN chunk)
    bin_length: int              # the BIN chunk's length (0 without one)


def _json_chunk_length(mv) -> int:
    """Length of the JSON chunk from the first 20 bytes (header + JSON chunk header)."""
    magic, version, length = struct.unpack_from("<4sII", mv, 0)
    if magic != GLB_MAGIC:
        raise GszFormatError("not a .glb file (bad magic)")
    if version != GLB_VERSION:
        raise GszFormatError(f"unsupported GLB container version {version} (glTF 2.0 binaries are version 2)")
    json_len, json_type = struct.unpack_from("<II", mv, GLB_HEADER_SIZE)
    if json_type != CHUNK_JSON:
        raise GszFormatError("GLB's first chunk is not its JSON chunk")
    if json_len > MAX_JSON_BYTES:
        raise GszFormatError(f"GLB JSON chunk of {json_len:,} bytes exceeds the {MAX_JSON_BYTES:,}-byte limit")
    if GLB_HEADER_SIZE + CHUNK_HEADER_SIZE + json_len > length:
        raise GszFormatError(f"GLB JSON chunk ({json_len:,} bytes) runs past the declared length {length:,}")
    return json_len


def _parse_json(raw) -> dict:
    try:
        doc = json.loads(bytes(raw).decode("utf-8"))
    except (UnicodeDecodeError, ValueError, RecursionError) as e:
        raise GszFormatError(f"GLB JSON chunk is not valid UTF-8 JSON ({type(e).__name__})") from None
    if not isinstance(doc, dict):
        raise GszFormatError("GLB JSON chunk is not a JSON object")
    return doc


def _bin_chunk(mv, start: int, length: int) -> tuple:
    """(BIN data offset or None, BIN length) of the chunk header at ``start`` (the byte after
    the JSON chunk); ``mv`` holds at least the 8 header bytes when ``start < length``."""
    if start >= length:
        return None, 0
    if start + CHUNK_HEADER_SIZE > length:
        raise GszFormatError("GLB ends inside a chunk header")
    bin_len, bin_type = struct.unpack_from("<II", mv, start)
    if bin_type != CHUNK_BIN:
        raise GszFormatError(f"GLB's second chunk has type 0x{bin_type:08x}, not BIN")
    if start + CHUNK_HEADER_SIZE + bin_len > length:
        raise GszFormatError(f"GLB BIN chunk ({bin_len:,} bytes) runs past the declared length {length:,}")
    return start + CHUNK_HEADER_SIZE, bin_len


def parse_glb(buf, *, partial: bool = False) -> Glb:
    """Parse the header, the JSON chunk and the BIN chunk header of a GLB held in ``buf``.

    A ``buf`` shorter than the declared length raises :class:`GszTruncatedError` unless
    ``partial`` (the JSON and the BIN chunk header must still be complete); a longer one raises
    :class:`GszFormatError` (trailing bytes)."""
    mv = memoryview(buf).cast("B")
    if len(mv) < GLB_HEADER_SIZE + CHUNK_HEADER_SIZE:
        if len(mv) >= 4 and not is_glb(mv):
            raise GszFormatError("not a .glb file (bad magic)")
        raise GszTruncatedError(f"truncated: {len(mv)} bytes, a GLB header is {GLB_HEADER_SIZE + CHUNK_HEADER_SIZE}")
    json_len = _json_chunk_length(mv)
    length = struct.unpack_from("<I", mv, 8)[0]
    if len(mv) > length:
        raise GszFormatError(f"{len(mv) - length:,} unexpected bytes after the GLB's declared length {length:,}")
    json_end = GLB_HEADER_SIZE + CHUNK_HEADER_SIZE + json_len
    head_end = json_end + (CHUNK_HEADER_SIZE if json_end < length else 0)
    if len(mv) < length and (not partial or len(mv) < head_end):
        raise GszTruncatedError(f"truncated: {len(mv):,} of the GLB's {length:,} bytes")
    doc = _parse_json(mv[GLB_HEADER_SIZE + CHUNK_HEADER_SIZE:json_end])
    bin_offset, bin_length = _bin_chunk(mv, json_end, length)
    return Glb(doc, length, bin_offset, bin_length)


def _index(value, count: int, what: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value < count:
        raise GszFormatError(f"{what} {value!r} is not an index below {count}")
    return value


def _non_negative(value, what: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise GszFormatError(f"{what} {value!r} is not a non-negative integer")
    return value


def gsz_primitives(doc: dict) -> list:
    """[(mesh index, primitive index, extension object)] of every primitive that carries
    ``EXT_gaussian_splatting_compression_gsz`` (inside its ``KHR_gaussian_splatting`` object)."""
    found = []
    meshes = doc.get("meshes", [])
    for mi, mesh in enumerate(meshes if isinstance(meshes, list) else []):
        prims = mesh.get("primitives", []) if isinstance(mesh, dict) else []
        for pi, prim in enumerate(prims if isinstance(prims, list) else []):
            ext = prim.get("extensions") if isinstance(prim, dict) else None
            khr = ext.get(KHR_GAUSSIAN_SPLATTING) if isinstance(ext, dict) else None
            sub = khr.get("extensions") if isinstance(khr, dict) else None
            if isinstance(sub, dict) and EXT_GSZ in sub:
                found.append((mi, pi, sub[EXT_GSZ]))
    return found


_IDENTITY = {"matrix": [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1], "translation": [0, 0, 0],
             "rotation": [0, 0, 0, 1], "scale": [1, 1, 1]}


def is_plain_gsz_scene(doc: dict) -> bool:
    """True when the scene is just its one gsz primitive, shown once without a transform: no
    other ``KHR_gaussian_splatting`` primitive, at most one node naming its mesh, and no node
    with a transform other than the identity.  Such a file loads as its decoded payload."""
    found = gsz_primitives(doc)
    meshes = doc.get("meshes") if isinstance(doc.get("meshes"), list) else []
    splats = sum(1 for m in meshes if isinstance(m, dict) and isinstance(m.get("primitives"), list)
                 for p in m["primitives"] if isinstance(p, dict) and isinstance(p.get("extensions"), dict)
                 and KHR_GAUSSIAN_SPLATTING in p["extensions"])
    nodes = doc.get("nodes") if isinstance(doc.get("nodes"), list) else []
    if len(found) != 1 or splats != 1 or not all(isinstance(n, dict) for n in nodes):
        return False
    if sum(1 for n in nodes if n.get("mesh") == found[0][0]) > 1:
        return False
    return all(n.get(k, v) == v for n in nodes for k, v in _IDENTITY.items())


def gsz_location(glb: Glb) -> tuple:
    """(file offset, length) of the .gsz payload of the GLB's one gsz primitive (GLTF.md §3).

    Raises GszFormatError when the GLB has no such primitive, several, or a payload reference
    that leaves the BIN chunk."""
    found = gsz_primitives(glb.doc)
    if not found:
        raise GszFormatError(f"is a glTF binary without an {EXT_GSZ} primitive (a plain "
                             f"{KHR_GAUSSIAN_SPLATTING} scene or another glTF: read it with gsz.load)")
    if len(found) > 1:
        raise GszFormatError(f"holds {len(found)} {EXT_GSZ} primitives; gsz decodes files with one "
                             "(its spatial tiles live inside the one .gsz payload)")
    mi, pi, ext = found[0]
    where = f"meshes[{mi}].primitives[{pi}] {EXT_GSZ}"
    if not isinstance(ext, dict) or "bufferView" not in ext:
        raise GszFormatError(f"{where} has no bufferView")
    views = glb.doc.get("bufferViews")
    views = views if isinstance(views, list) else []
    view = views[_index(ext["bufferView"], len(views), f"{where}.bufferView")]
    if not isinstance(view, dict):
        raise GszFormatError(f"{where}: bufferView is not an object")
    buffers = glb.doc.get("buffers")
    buffers = buffers if isinstance(buffers, list) else []
    b = _index(view.get("buffer"), len(buffers), f"{where}: bufferView.buffer")
    if b != 0 or not isinstance(buffers[0], dict) or "uri" in buffers[0] or glb.bin_offset is None:
        raise GszFormatError(f"{where}: the payload must lie in buffer 0, the GLB's BIN chunk")
    offset = _non_negative(view.get("byteOffset", 0), f"{where}: bufferView.byteOffset")
    length = _non_negative(view.get("byteLength"), f"{where}: bufferView.byteLength")
    declared = _non_negative(buffers[0].get("byteLength"), "buffers[0].byteLength")
    if offset + length > min(declared, glb.bin_length):
        raise GszFormatError(f"{where}: bytes {offset:,}..{offset + length:,} lie outside the "
                             f"{min(declared, glb.bin_length):,}-byte BIN buffer")
    return glb.bin_offset + offset, length


def gsz_payload(buf, *, partial: bool = False) -> tuple:
    """(payload view, file offset) of the .gsz inside the GLB ``buf``; with ``partial`` a
    truncated GLB yields the payload bytes it holds (the .gsz decoder then reports the
    truncation); without it a truncated GLB raises GszTruncatedError."""
    glb = parse_glb(buf, partial=partial)
    start, length = gsz_location(glb)
    mv = memoryview(buf).cast("B")
    return mv[start:min(start + length, len(mv))], start


class GlbUnwrapper:
    """Streaming counterpart of :func:`gsz_payload`: feed the GLB's bytes as they arrive, get
    back the payload bytes among them (the JSON chunk precedes the BIN chunk, so the payload's
    place is known before its first byte arrives).  Used by :class:`StreamDecoder`."""

    def __init__(self):
        self._head = bytearray()
        self._pos = 0                  # stream bytes consumed
        self.length = None             # declared GLB length
        self.payload = None            # (start, end) file offsets of the payload

    @property
    def received(self) -> int:
        return self._pos

    def feed(self, piece) -> bytes:
        """The payload bytes in ``piece`` (possibly b''); raises GszFormatError on a bad GLB."""
        piece = memoryview(piece).cast("B")
        start_pos = self._pos
        self._pos += len(piece)
        if self.length is not None and self._pos > self.length:
            raise GszFormatError(f"{self._pos - self.length:,} unexpected bytes after the GLB's "
                                 f"declared length {self.length:,}")
        if self.payload is None:
            self._head += piece
            if not self._locate():
                return b""
            start, end = self.payload
            out = bytes(self._head[start:end])
            self._head = bytearray()
            return out
        start, end = self.payload
        lo, hi = max(start, start_pos), min(end, self._pos)
        return bytes(piece[lo - start_pos:hi - start_pos]) if hi > lo else b""

    def _locate(self) -> bool:
        """Parse the header and JSON once they are complete; True when the payload is placed."""
        with memoryview(self._head) as head:       # released before the buffer grows again
            return self._locate_in(head)

    def _locate_in(self, head) -> bool:
        if len(head) >= 4 and not is_glb(head):
            raise GszFormatError("not a .glb file (bad magic)")
        if len(head) < GLB_HEADER_SIZE + CHUNK_HEADER_SIZE:
            return False
        json_len = _json_chunk_length(head)
        length = struct.unpack_from("<I", head, 8)[0]
        json_end = GLB_HEADER_SIZE + CHUNK_HEADER_SIZE + json_len
        need = json_end + (CHUNK_HEADER_SIZE if json_end < length else 0)
        if len(head) < need:
            return False
        self.length = length
        if self._pos > length:
            raise GszFormatError(f"{self._pos - length:,} unexpected bytes after the GLB's declared length {length:,}")
        doc = _parse_json(head[GLB_HEADER_SIZE + CHUNK_HEADER_SIZE:json_end])
        bin_offset, bin_length = _bin_chunk(head, json_end, length)
        start, size = gsz_location(Glb(doc, length, bin_offset, bin_length))
        self.payload = (start, start + size)
        return True
