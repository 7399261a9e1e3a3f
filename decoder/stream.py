"""Streaming, progressive decoding: feed bytes as they arrive, get an update per completed part.

    dec = StreamDecoder()
    for piece in response.iter_content(65536):          # any sizes, down to 1 byte
        for update in dec.feed(piece):
            show(update.cloud)                          # cumulative: every part so far
    result = dec.finish()                               # result.truncated: did the file end early?

A layered .gsz (GSZ.md §4.1) stores importance-ordered layers one after the other, and a tiled
one (§4.2) every layer as one part per spatial tile (layer 0 of every tile first); a part is
decodable as soon as the header, the chunk table and its chunks have arrived, and an update
says which layer of which tile completed.  Every chunk's CRC-32 is verified the moment it is complete, before it is
interpreted, so a stream that is cut anywhere yields exactly its complete layers: truncation is
never an exception here, only ``StreamResult.truncated`` plus one :class:`GszTruncatedWarning`
from :meth:`StreamDecoder.finish`.  Corrupt bytes (checksum mismatch, bad magic, malformed
payloads) raise :class:`GszFormatError` as in :func:`gsz.decoder.decode`.

The cumulative cloud after the last layer is identical (array for array) to what
:func:`gsz.decoder.decode` returns for the whole file.  A .glb that carries a .gsz
(``EXT_gaussian_splatting_compression_gsz``, GLTF.md §3) streams the same way: its JSON chunk
precedes the payload, and byte counts (``bytes_received``, ``layer_ends``) are then the .glb's.
numpy only.
"""
from __future__ import annotations

import os
import warnings
import zlib
from dataclasses import dataclass

import numpy as np

from .cloud import GaussianCloud
from .container import CHUNK_REQUIRED, HEADER_SIZE, MAGIC, parse_header, parse_table, table_size
from .layer import (GAUSSIANS_PER_BYTE, LayerState, check_header_counts, check_max_gaussians, check_tile_complete,
                    concat_clouds, decode_layer, guard, open_gsz, plan_parts, tile_table)
from .errors import GszError, GszFormatError, GszTruncatedWarning
from .glb import GLB_MAGIC, GlbUnwrapper, is_glb
from .layout import KNOWN_CHUNKS


class StreamUpdate:
    """One completed part: a layer of a spatial tile (a file without tiles has one tile, so
    there every update is a whole layer).

    cloud            cumulative GaussianCloud of every part decoded so far (decoded order:
                     layer after layer, tile after tile within a layer); built on first access
    part             the Gaussians this update added (layer ``layer`` of tile ``tile``)
    layer, tile      which part just completed
    layers_total     number of layers in the file; tiles_total: number of tiles
    layer_complete   every tile of ``layer`` is now decoded
    bytes_received   stream bytes consumed when it completed
    complete         True for the last part asked for
    """

    def __init__(self, *, cumulative, part, layer, tile, layers_total, tiles_total, layer_complete,
                 bytes_received, complete):
        self._cumulative = cumulative
        self.part, self.layer, self.tile = part, layer, tile
        self.layers_total, self.tiles_total = layers_total, tiles_total
        self.layer_complete, self.bytes_received, self.complete = layer_complete, bytes_received, complete

    @property
    def cloud(self) -> GaussianCloud:
        return self._cumulative()

    def __repr__(self) -> str:
        return (f"StreamUpdate(layer={self.layer}, tile={self.tile}, gaussians={len(self.part)}, "
                f"bytes_received={self.bytes_received}, complete={self.complete})")


@dataclass
class StreamResult:
    """State at :meth:`StreamDecoder.finish`.

    cloud            cumulative cloud of every decoded layer (None when no layer completed)
    layers_decoded   layers decoded
    layers_total     layers in the file (None when the chunk table never arrived)
    bytes_received   bytes fed
    bytes_expected   total file length from the chunk table, or the .glb's declared length for a
                     wrapped .gsz (None when it never arrived)
    truncated        the stream ended before every (requested) layer was complete, or (when
                     all layers were asked for) before the file's last byte
    next_layer_end   bytes needed to complete the next layer (None when not known / none left)
    """

    cloud: GaussianCloud | None
    layers_decoded: int
    layers_total: int | None
    bytes_received: int
    bytes_expected: int | None
    truncated: bool
    next_layer_end: int | None


class StreamDecoder:
    """Incremental .gsz decoder (see module docstring).

    max_gaussians   None (default): the default limits of :func:`gsz.decoder.decode` (2^28, and
                    GAUSSIANS_PER_BYTE per byte of the file once its chunk table has arrived and
                    per byte of each part's chunks); an int: accept up to that many Gaussians
    max_layers      decode only the first ``max_layers`` layers (None: all); later bytes are
                    still checksum-verified but not decoded
    source          name used in messages (a file name or URL)
    """

    def __init__(self, *, max_gaussians: int | None = None, max_layers: int | None = None,
                 source: str | None = None):
        if max_layers is not None and int(max_layers) < 1:
            raise GszError(f"max_layers must be >= 1, got {max_layers}", source)
        self.max_gaussians = check_max_gaussians(max_gaussians, source)
        self.max_layers = None if max_layers is None else int(max_layers)
        self.source = source
        self.header = None
        self._buf = bytearray()
        self._base = 0              # absolute file offset of self._buf[0]
        self._received = 0
        self._entries = None        # [(type, flags, length, crc, offset)]
        self._expected = None
        self._plan = None           # layer.Plan
        self._next = 0              # next chunk table entry to complete
        self._payloads = {}         # entry index -> bytes (chunks of parts not yet decoded)
        self._states = None         # tile -> LayerState (once the tile table is known)
        self._tiles = None          # [TileInfo]
        self._parts = []            # decoded parts' clouds, decoded order
        self._joined = (0, None)    # (parts, cloud): the last cumulative cloud built
        self._layers_done = 0
        self._fed = 0               # stream bytes fed (the .glb's when the .gsz comes wrapped)
        self._sniff = bytearray()   # the first bytes, until they say .gsz or .glb
        self._glb = None            # GlbUnwrapper of a .glb-wrapped stream (GLTF.md §3)

    # ------------------------------------------------------------------ public API
    @property
    def layers_total(self) -> int | None:
        return None if self._plan is None else self._plan.num_layers

    @property
    def tiles_total(self) -> int | None:
        return None if self._plan is None else self._plan.num_tiles

    @property
    def tiles(self) -> list | None:
        """[TileInfo] (bounding box, Gaussians) once the tile table has arrived."""
        return self._tiles

    @property
    def layers_decoded(self) -> int:
        return self._layers_done

    @property
    def cloud(self) -> GaussianCloud | None:
        """Cumulative cloud of the parts decoded so far."""
        return self._cumulative(len(self._parts)) if self._parts else None

    @property
    def bytes_received(self) -> int:
        """Stream bytes fed so far (of the .glb, for a .glb-wrapped .gsz)."""
        return self._fed

    def _stream_expected(self) -> int | None:
        """The stream's total length once known (the GLB's declared length when wrapped)."""
        return self._glb.length if self._glb is not None else self._expected

    def layer_ends(self) -> list[int] | None:
        """Per layer, the stream length after which it is decodable (None before the table)."""
        if self._plan is None:
            return None
        base = self._glb.payload[0] if self._glb is not None else 0
        return [base + self._entries[i][4] + self._entries[i][2] for i in self._plan.layer_ends()]

    def feed(self, data) -> list[StreamUpdate]:
        """Consume the next bytes of the stream; returns one update per layer completed by them
        (often none).  Raises GszFormatError on corrupt data, never on a short stream."""
        piece = memoryview(data).cast("B")
        if not len(piece):
            return []
        self._fed += len(piece)
        return guard(lambda: self._feed(piece), self.source)

    def finish(self, *, warn: bool = True, source: str | None = None) -> StreamResult:
        """Declare the end of the stream.  When it ended before every (requested) layer was
        decoded, the result says ``truncated=True`` and (``warn``) one GszTruncatedWarning is
        emitted naming what was decoded."""
        wanted = self._wanted_layers()
        expected = self._stream_expected()
        truncated = (wanted is None or self._layers_done < wanted
                     or (self.max_layers is None and (expected is None or self._fed < expected)))
        ends = self.layer_ends()
        nxt = ends[self._layers_done] if ends is not None and self._layers_done < len(ends) else None
        res = StreamResult(cloud=self.cloud, layers_decoded=self._layers_done,
                           layers_total=self.layers_total, bytes_received=self._fed,
                           bytes_expected=expected, truncated=truncated, next_layer_end=nxt)
        if truncated and warn:
            name = source or self.source
            total = "?" if expected is None else f"{expected:,}"
            layers = "?" if self.layers_total is None else self.layers_total
            got = sum(len(p) for p in self._parts)
            warnings.warn(GszTruncatedWarning(
                f"{name + ': ' if name else ''}truncated .gsz stream: {self._fed:,} of {total} bytes; "
                f"decoded {self._layers_done} of {layers} layers ({got:,} Gaussians)"), stacklevel=2)
        return res

    # ------------------------------------------------------------------ internals
    def _wanted_layers(self) -> int | None:
        if self._plan is None:
            return None
        n = self._plan.num_layers
        return n if self.max_layers is None else min(n, self.max_layers)

    def _cumulative(self, k: int) -> GaussianCloud:
        """The first k decoded parts as one cloud (the newest such cloud is kept)."""
        if self._joined[0] != k:
            self._joined = (k, concat_clouds(self._parts[:k], self.header.sh_degree))
        return self._joined[1]

    def _read_table(self) -> None:
        n = int.from_bytes(self._buf[28:32], "little")
        if len(self._buf) < HEADER_SIZE + table_size(n):
            return
        entries, end = parse_table(self._buf, n)
        for ctype, cflags, *_rest in entries:
            if ctype not in KNOWN_CHUNKS and cflags & CHUNK_REQUIRED:
                raise GszFormatError(f"required chunk type {ctype.decode()} is not supported by this decoder")
        self._plan = plan_parts(entries, self.header.sh_degree)
        self._entries = entries
        self._expected = entries[-1][4] + entries[-1][2] if entries else end
        check_header_counts(self.header, self.max_gaussians, self._expected)
        if self._plan.tile_chunk is None:
            self._set_tiles(None)
        del self._buf[:end]
        self._base = end

    def _set_tiles(self, data) -> None:
        self._tiles = tile_table(data, self._plan, self.header)
        tiled = self._plan.tile_chunk is not None
        per_byte = GAUSSIANS_PER_BYTE if self.max_gaussians is None else None
        self._states = {t: LayerState(limit=info.num_gaussians, what=f"tile {t}'s" if tiled else "the header's",
                                      per_byte=per_byte) for t, info in enumerate(self._tiles)}

    def _feed(self, piece) -> list[StreamUpdate]:
        """Route a piece through the GLB unwrapper when the stream is a .glb (told by its first
        4 bytes), then into the .gsz buffer."""
        if self._sniff is not None:
            self._sniff += piece
            if len(self._sniff) < len(GLB_MAGIC):
                return []
            if is_glb(self._sniff):
                self._glb = GlbUnwrapper()
            piece, self._sniff = memoryview(bytes(self._sniff)), None
        if self._glb is not None:
            piece = self._glb.feed(piece)
            if not len(piece):
                return []
        self._buf += piece
        self._received += len(piece)
        return self._advance()

    def _advance(self) -> list[StreamUpdate]:
        if self.header is None:
            if len(self._buf) >= len(MAGIC) and bytes(self._buf[:len(MAGIC)]) != MAGIC:
                raise GszFormatError("not a .gsz file (bad magic)")
            if len(self._buf) < HEADER_SIZE:
                return []
            self.header = parse_header(self._buf)
            check_header_counts(self.header, self.max_gaussians)
        if self._entries is None:
            self._read_table()
            if self._entries is None:
                return []
        if self._received > self._expected:
            raise GszFormatError(f"{self._received - self._expected} unexpected trailing bytes after the last chunk")
        wanted = self._wanted_layers()
        parts = [p for p in self._plan.parts if p.layer < wanted]
        needed = {i for p in parts for i in p.chunks.values()}
        updates = []
        while self._next < len(self._entries):
            ctype, _flags, length, crc, offset = self._entries[self._next]
            stop = offset + length
            if self._base + len(self._buf) < stop:
                break
            piece = bytes(self._buf[offset - self._base:stop - self._base])
            if zlib.crc32(piece) != crc:
                raise GszFormatError(f"chunk {self._next} ({ctype.decode()}) checksum mismatch (file corrupt)")
            if self._next == self._plan.tile_chunk:
                self._set_tiles(piece)
            elif self._next in needed:
                self._payloads[self._next] = piece
            del self._buf[:stop - self._base]
            self._base = stop
            done = self._next
            self._next += 1
            k = len(self._parts)
            if k < len(parts) and done == parts[k].last:
                updates.append(self._decode_part(parts, k))
        return updates

    def _decode_part(self, parts: list, k: int) -> StreamUpdate:
        part = parts[k]
        state = self._states[part.tile]
        chunks = {t: self._payloads.pop(i) for t, i in part.chunks.items()}
        tiled = self._plan.tile_chunk is not None
        with np.errstate(over="ignore", invalid="ignore"):
            cloud = decode_layer(chunks, self.header, state,
                                 label=f"layer {part.layer}, tile {part.tile}" if tiled else f"layer {part.layer}")
        tile_layers = sum(1 for p in self._plan.parts if p.tile == part.tile)
        if part.layer == tile_layers - 1:
            check_tile_complete(state, part.tile, self._plan.tile_chunk is not None)
        self._parts.append(cloud)
        layer_complete = k + 1 == len(parts) or parts[k + 1].layer != part.layer
        if layer_complete:
            self._layers_done += 1
        n = len(self._parts)
        return StreamUpdate(cumulative=lambda n=n: self._cumulative(n), part=cloud, layer=part.layer,
                            tile=part.tile, layers_total=self._plan.num_layers,
                            tiles_total=self._plan.num_tiles, layer_complete=layer_complete,
                            bytes_received=self._fed, complete=n == len(parts))


def _pieces(source, chunk_size: int):
    if isinstance(source, (bytes, bytearray, memoryview)):
        mv = memoryview(source).cast("B")
        for s in range(0, len(mv), chunk_size):
            yield mv[s:s + chunk_size]
        return
    if isinstance(source, (str, os.PathLike)):
        with open_gsz(os.fspath(source)) as f:
            yield from _pieces(f, chunk_size)
        return
    if hasattr(source, "read"):
        while True:
            piece = source.read(chunk_size)
            if not piece:
                return
            yield piece
        return
    yield from source         # any iterable of byte pieces (e.g. an HTTP response iterator)


def iter_layers(source, *, chunk_size: int = 65536, max_layers: int | None = None,
                max_gaussians: int | None = None):
    """Yield a :class:`StreamUpdate` per completed layer of ``source``: a path, bytes, a file
    object / HTTP-like reader (``read(n)``), or an iterable of byte pieces.  A source that ends
    early emits one GszTruncatedWarning after its last complete layer."""
    name = os.fspath(source) if isinstance(source, (str, os.PathLike)) else getattr(source, "name", None)
    dec = StreamDecoder(max_gaussians=max_gaussians, max_layers=max_layers,
                        source=name if isinstance(name, str) else None)
    for piece in _pieces(source, int(chunk_size)):
        yield from dec.feed(piece)
        if dec.layers_total is not None and dec.layers_decoded == dec._wanted_layers():
            return
    dec.finish(warn=True)
