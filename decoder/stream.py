"""Streaming, progressive decoding: feed bytes as they arrive, get a cloud per completed layer.

    dec = StreamDecoder()
    for piece in response.iter_content(65536):          # any sizes, down to 1 byte
        for update in dec.feed(piece):
            show(update.cloud)                          # cumulative: layers 0..update.layer
    result = dec.finish()                               # result.truncated: did the file end early?

A layered .gsz (GSZ.md §5) stores importance-ordered layers one after the other; layer ``l`` is
decodable as soon as the header, the chunk table and every chunk up to layer ``l``'s last data
chunk have arrived.  Every chunk's CRC-32 is verified the moment it is complete, before it is
interpreted, so a stream that is cut anywhere yields exactly its complete layers: truncation is
never an exception here, only ``StreamResult.truncated`` plus one :class:`GszTruncatedWarning`
from :meth:`StreamDecoder.finish`.  Corrupt bytes (checksum mismatch, bad magic, malformed
payloads) raise :class:`GszFormatError` as in :func:`gsz.decoder.decode`.

The cumulative cloud after the last layer is identical (array for array) to what
:func:`gsz.decoder.decode` returns for the whole file.  numpy only.
"""
from __future__ import annotations

import os
import warnings
import zlib
from dataclasses import dataclass

import numpy as np

from .cloud import GaussianCloud
from .container import (CHUNK_REQUIRED, DEFAULT_MAX_GAUSSIANS, HEADER_SIZE, MAGIC, parse_header,
                        parse_table, table_size)
from .layer import (LayerState, check_header_counts, concat_clouds, decode_layer, guard, open_gsz,
                    plan_layers)
from .errors import GszError, GszFormatError, GszTruncatedWarning
from .layout import KNOWN_CHUNKS


@dataclass
class StreamUpdate:
    """One completed layer.

    cloud            cumulative GaussianCloud of layers 0..layer (layer order, Morton within)
    layer            index of the layer that just completed
    layers_total     number of layers in the file
    bytes_received   stream bytes consumed when it completed
    complete         True for the file's last layer (or the last one asked for)
    """

    cloud: GaussianCloud
    layer: int
    layers_total: int
    bytes_received: int
    complete: bool


@dataclass
class StreamResult:
    """State at :meth:`StreamDecoder.finish`.

    cloud            cumulative cloud of every decoded layer (None when no layer completed)
    layers_decoded   layers decoded
    layers_total     layers in the file (None when the chunk table never arrived)
    bytes_received   bytes fed
    bytes_expected   total file length from the chunk table (None when it never arrived)
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

    max_gaussians   bound on the header's count (what a hostile file can make it allocate)
    max_layers      decode only the first ``max_layers`` layers (None: all); later bytes are
                    still checksum-verified but not decoded
    source          name used in messages (a file name or URL)
    """

    def __init__(self, *, max_gaussians: int = DEFAULT_MAX_GAUSSIANS, max_layers: int | None = None,
                 source: str | None = None):
        if max_layers is not None and int(max_layers) < 1:
            raise GszError(f"max_layers must be >= 1, got {max_layers}", source)
        self.max_gaussians = int(max_gaussians)
        self.max_layers = None if max_layers is None else int(max_layers)
        self.source = source
        self.header = None
        self._buf = bytearray()
        self._base = 0              # absolute file offset of self._buf[0]
        self._received = 0
        self._entries = None        # [(type, flags, length, crc, offset)]
        self._expected = None
        self._plan = None           # per layer {type: entry index}
        self._layer_end = []        # per layer: index of its last data chunk
        self._next = 0              # next chunk table entry to complete
        self._payloads = {}         # entry index -> bytes (data chunks of layers not yet decoded)
        self._state = LayerState()
        self._cloud = None
        self._layers_done = 0

    # ------------------------------------------------------------------ public API
    @property
    def layers_total(self) -> int | None:
        return None if self._plan is None else len(self._plan)

    @property
    def layers_decoded(self) -> int:
        return self._layers_done

    @property
    def cloud(self) -> GaussianCloud | None:
        """Cumulative cloud of the layers decoded so far."""
        return self._cloud

    @property
    def bytes_received(self) -> int:
        return self._received

    def layer_ends(self) -> list[int] | None:
        """Per layer, the stream length after which it is decodable (None before the table)."""
        if self._plan is None:
            return None
        return [self._entries[i][4] + self._entries[i][2] for i in self._layer_end]

    def feed(self, data) -> list[StreamUpdate]:
        """Consume the next bytes of the stream; returns one update per layer completed by them
        (often none).  Raises GszFormatError on corrupt data, never on a short stream."""
        piece = memoryview(data).cast("B")
        if not len(piece):
            return []
        self._buf += piece
        self._received += len(piece)
        return guard(self._advance, self.source)

    def finish(self, *, warn: bool = True, source: str | None = None) -> StreamResult:
        """Declare the end of the stream.  When it ended before every (requested) layer was
        decoded, the result says ``truncated=True`` and (``warn``) one GszTruncatedWarning is
        emitted naming what was decoded."""
        wanted = self._wanted_layers()
        truncated = (wanted is None or self._layers_done < wanted
                     or (self.max_layers is None and self._received < self._expected))
        ends = self.layer_ends()
        nxt = ends[self._layers_done] if ends is not None and self._layers_done < len(ends) else None
        res = StreamResult(cloud=self._cloud, layers_decoded=self._layers_done,
                           layers_total=self.layers_total, bytes_received=self._received,
                           bytes_expected=self._expected, truncated=truncated, next_layer_end=nxt)
        if truncated and warn:
            name = source or self.source
            total = "?" if self._expected is None else f"{self._expected:,}"
            layers = "?" if self.layers_total is None else self.layers_total
            got = 0 if self._cloud is None else len(self._cloud)
            warnings.warn(GszTruncatedWarning(
                f"{name + ': ' if name else ''}truncated .gsz stream: {self._received:,} of {total} bytes; "
                f"decoded {self._layers_done} of {layers} layers ({got:,} Gaussians)"), stacklevel=2)
        return res

    # ------------------------------------------------------------------ internals
    def _wanted_layers(self) -> int | None:
        if self._plan is None:
            return None
        n = len(self._plan)
        return n if self.max_layers is None else min(n, self.max_layers)

    def _advance(self) -> list[StreamUpdate]:
        if self.header is None:
            if len(self._buf) >= len(MAGIC) and bytes(self._buf[:len(MAGIC)]) != MAGIC:
                raise GszFormatError("not a .gsz file (bad magic)")
            if len(self._buf) < HEADER_SIZE:
                return []
            self.header = parse_header(self._buf)
            check_header_counts(self.header, self.max_gaussians)
        if self._entries is None:
            n = int.from_bytes(self._buf[28:32], "little")
            if len(self._buf) < HEADER_SIZE + table_size(n):
                return []
            entries, end = parse_table(self._buf, n)
            for i, (ctype, cflags, *_rest) in enumerate(entries):
                if ctype not in KNOWN_CHUNKS and cflags & CHUNK_REQUIRED:
                    raise GszFormatError(f"required chunk type {ctype.decode()} is not supported by this decoder")
            self._plan = plan_layers(entries, self.header.sh_degree)
            self._layer_end = [max(got.values()) for got in self._plan]
            self._entries = entries
            self._expected = entries[-1][4] + entries[-1][2] if entries else end
            del self._buf[:end]
            self._base = end
        if self._received > self._expected:
            raise GszFormatError(f"{self._received - self._expected} unexpected trailing bytes after the last chunk")
        wanted = self._wanted_layers()
        needed = {i for li, got in enumerate(self._plan) if li < wanted for i in got.values()}
        updates = []
        while self._next < len(self._entries):
            ctype, _flags, length, crc, offset = self._entries[self._next]
            stop = offset + length
            if self._base + len(self._buf) < stop:
                break
            piece = bytes(self._buf[offset - self._base:stop - self._base])
            if zlib.crc32(piece) != crc:
                raise GszFormatError(f"chunk {self._next} ({ctype.decode()}) checksum mismatch (file corrupt)")
            if self._next in needed:
                self._payloads[self._next] = piece
            del self._buf[:stop - self._base]
            self._base = stop
            done = self._next
            self._next += 1
            li = self._layers_done
            if li < wanted and done == self._layer_end[li]:
                updates.append(self._decode_next_layer(wanted))
        return updates

    def _decode_next_layer(self, wanted: int) -> StreamUpdate:
        li = self._layers_done
        got = self._plan[li]
        chunks = {t: self._payloads.pop(i) for t, i in got.items()}
        with np.errstate(over="ignore", invalid="ignore"):
            part = decode_layer(chunks, self.header, self._state)
        last = li == len(self._plan) - 1
        if last and self._state.decoded_points != self.header.num_gaussians:
            raise GszFormatError(f"layers hold {self._state.decoded_points} Gaussians, "
                                 f"header says {self.header.num_gaussians}")
        self._cloud = part if self._cloud is None else concat_clouds([self._cloud, part])
        self._layers_done += 1
        return StreamUpdate(cloud=self._cloud, layer=li, layers_total=len(self._plan),
                            bytes_received=self._received, complete=self._layers_done == wanted)


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
                max_gaussians: int = DEFAULT_MAX_GAUSSIANS):
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
