"""Writes the hostile files of this folder (issue 19): tiny, CRC-valid .gsz files that declare
far more work than their bytes hold.  Run from the repository root:

    python tests/data/bombs/make_bombs.py

Built byte by byte from format_spec/ (GSZ.md, ENTROPY.md, OCTREE.md), not by the encoder, so
that the files stay what they are whatever the encoder does.  Every entropy stream here uses
SINGLE models (ENTROPY.md §3.3): their symbols cost no bytes, so any symbol count fits.
"""
from __future__ import annotations

import struct
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[3]))

from gsz.decoder.container import Chunk, FileHeader, write_container  # noqa: E402
from gsz.decoder.layout import CHUNK_ATTR, CHUNK_GEOM  # noqa: E402


def varint(v: int) -> bytes:
    out = bytearray()
    while True:
        b, v = v & 0x7F, v >> 7
        out.append(b | (0x80 if v else 0))
        if not v:
            return bytes(out)


def single_models_stream(num_models: int) -> bytes:
    """A RansStream whose models are all SINGLE at value 0, on one lane with no words: it decodes
    any number of zero symbols (ENTROPY.md §3, §4)."""
    body = varint(num_models) + varint(1) * num_models + varint(0) * num_models
    return varint(len(body) << 1) + body + varint(1) + varint(0) + struct.pack("<I", 1 << 16)


def channel_set(channels: int, length: int) -> bytes:
    """GSZ.md §5: one block per channel, 1 bit, min = max = 0, model mode 0."""
    blob = single_models_stream(channels)
    return (struct.pack("<BIHB", channels, length, 1, 0) + bytes([1]) * channels
            + struct.pack(f"<{channels}f", *[0.0] * channels) * 2
            + struct.pack("<Q", len(blob)) + blob)


def attr_chunk(m: int, ac_channels: int = 7) -> bytes:
    """GSZ.md §7: Euler mode, 7 RAHT DC values 0, the AC set (L = m - 1), the scale set (L = m)."""
    return (bytes([0, 7]) + struct.pack("<7d", *[0.0] * 7)
            + channel_set(ac_channels, m - 1) + channel_set(3, m))


def geom_chunk(depth: int, m: int, payload: bytes) -> bytes:
    return struct.pack("<B3ddQ", depth, 0.0, 0.0, 0.0, 1.0, m) + payload


def broken_octree() -> bytes:
    """OCTREE.md §2: scheme 0, S = 1 decision, one lane, no words: far too few decisions for
    the declared M, found as soon as the traversal starts."""
    return bytes([0]) + varint(1) + varint(1) + varint(0) + struct.pack("<I", 1 << 16)


def full_octree(depth: int) -> bytes:
    """A valid payload of all 8^depth voxels (the reference octree coder)."""
    import numpy as np

    from gsz.decoder.morton import morton_decode
    from gsz.encoder.octree import encode_octree
    return encode_octree(morton_decode(np.arange(8 ** depth, dtype=np.uint64)), depth)


def gsz(m: int, geom: bytes, attr: bytes) -> bytes:
    return write_container(FileHeader(num_gaussians=m, sh_degree=0),
                           [Chunk(CHUNK_GEOM, geom), Chunk(CHUNK_ATTR, attr)])


def bombs() -> dict:
    """{file name: bytes}."""
    out = {}
    # Issue 19 item 1: M = 2^24 in the GEOM header, an octree that fails at once, attributes
    # that decode 10 x 2^24 zeros for free: the octree must confirm M before they are decoded.
    m = 1 << 24
    out["attr_before_octree_2e24.gsz"] = gsz(m, geom_chunk(8, m, broken_octree()), attr_chunk(m))
    m = 1 << 28
    out["attr_before_octree_2e28.gsz"] = gsz(m, geom_chunk(10, m, broken_octree()), attr_chunk(m))
    # Item 2: a valid full octree of 8^6 = 262144 voxels, then an AC set of 255 channels where
    # GSZ.md §5 prescribes 7: C must be checked before the set is decoded.
    d, m = 6, 8 ** 6
    out["channelset_255_channels.gsz"] = gsz(m, geom_chunk(d, m, full_octree(d)), attr_chunk(m, 255))
    # ... and its length: L = 2^28 where M - 1 is prescribed (bound: M).
    a = bytearray(attr_chunk(m))
    struct.pack_into("<I", a, 2 + 56 + 1, (1 << 28))
    out["channelset_length_above_m.gsz"] = gsz(m, geom_chunk(d, m, full_octree(d)), bytes(a))
    return out


if __name__ == "__main__":
    for name, data in bombs().items():
        (HERE / name).write_bytes(data)
        print(f"{name}: {len(data)} bytes")
