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
from gsz.encoder.rans import varint_bytes  # noqa: E402


def varint(v: int) -> bytes:
    return varint_bytes([v])


def single_models_stream(num_models: int, *, lanes: int = 1, empty: int = 0, zstd: bool = False) -> bytes:
    """A RansStream whose models are all SINGLE at value 0 (then ``empty`` EMPTY models), on
    ``lanes`` lanes with no words: it decodes any number of zero symbols (ENTROPY.md §3, §4);
    ``zstd``: the body as one zstd frame (level 19, content size declared)."""
    body = varint(num_models + empty) + varint(1) * num_models + varint(0) * empty + varint(0) * num_models
    if zstd:
        import zstandard
        body = zstandard.ZstdCompressor(level=19, write_content_size=True).compress(body)
    return (varint(len(body) << 1 | int(zstd)) + body + varint(lanes) + varint(0)
            + struct.pack("<I", 1 << 16) * lanes)


def valid_lanes(symbols: int) -> int:
    """The fewest lanes ENTROPY.md §4.1 allows for a RansStream of ``symbols`` symbols."""
    return max(1, min(4096, -(-symbols // 8192)))


def channel_set(channels: int, length: int, stream: bytes | None = None, mode: int = 0,
                lanes: int = 1) -> bytes:
    """GSZ.md §5: one block per channel, 1 bit, min = max = 0, model mode ``mode``; ``stream``
    (default: SINGLE models on ``lanes`` lanes) its RansStream."""
    if stream is None:
        stream = single_models_stream(channels if mode == 0 else 16 * channels, lanes=lanes)
    blob = stream
    return (struct.pack("<BIHB", channels, length, 1, mode) + bytes([1]) * channels
            + struct.pack(f"<{channels}f", *[0.0] * channels) * 2
            + struct.pack("<Q", len(blob)) + blob)


def attr_chunk(m: int, ac_channels: int = 7, scales: bytes | None = None, valid: bool = False) -> bytes:
    """GSZ.md §7: Euler mode, 7 RAHT DC values 0, the AC set (L = m - 1), the scale set (L = m;
    ``scales``: its RansStream instead of the default).  The default streams have one lane, or
    (``valid``) as many as ENTROPY.md §4.1 requires."""
    lanes = (lambda n: valid_lanes(n) if valid else 1)
    return (bytes([0, 7]) + struct.pack("<7d", *[0.0] * 7)
            + channel_set(ac_channels, m - 1, lanes=lanes(ac_channels * (m - 1)))
            + channel_set(3, m, scales, lanes=lanes(3 * m)))


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


def gsz(m: int, geom: bytes, attr: bytes, layers: int = 1) -> bytes:
    """A file of SH degree 0 whose ``layers`` layers each hold these GEOM and ATTR chunks."""
    chunks = [Chunk(t, data, 1 | (li << 8)) for li in range(layers) for t, data in ((CHUNK_GEOM, geom), (CHUNK_ATTR, attr))]
    return write_container(FileHeader(num_gaussians=m * layers, sh_degree=0), chunks)


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
    # Item 3, a legitimate decompression bomb: a valid file whose full octree and constant
    # attributes cost almost nothing -- 8^7 = 2,097,152 Gaussians (a 56 MB cloud) in 11 kB, most
    # of it the lane states ENTROPY.md §4.1 requires.  Rejected by the default Gaussians-per-byte
    # limit (GSZ.md §11); decoded with an explicit max_gaussians.
    d, m = 7, 8 ** 7
    out["full_octree_2e21.gsz"] = gsz(m, geom_chunk(d, m, full_octree(d)), attr_chunk(m, valid=True))
    # Item 4, CPU bombs inside the default limit (4096 Gaussians in a few hundred bytes):
    # 2^20 models in a scale set whose ids name 3 (ENTROPY.md §3.2 / GSZ.md §5: at most C*B) ...
    d, m = 4, 8 ** 4
    full4 = geom_chunk(d, m, full_octree(d))
    models = single_models_stream(3, empty=(1 << 20) - 3, zstd=True, lanes=2)
    out["models_2e20_for_3_ids.gsz"] = gsz(m, full4, attr_chunk(m, scales=models, valid=True))
    # ... a 16 MiB zstd model-set body for a stream of 12,288 symbols and 3 model ids (no valid
    # body is longer than ~1.2 MB there: ENTROPY.md §3.1) ...
    bomb_body = varint(3) + varint(1) * 3 + varint(0) * 3
    bomb_body += b"\x00" * ((1 << 24) - len(bomb_body))           # trailing bytes: never valid
    import zstandard
    frame = zstandard.ZstdCompressor(level=19, write_content_size=True).compress(bomb_body)
    stream = varint(len(frame) << 1 | 1) + frame + varint(2) + varint(0) + struct.pack("<I", 1 << 16) * 2
    out["model_set_body_16mib.gsz"] = gsz(m, full4, attr_chunk(m, scales=stream, valid=True))
    # ... and 3 x 4096 scale symbols on one lane (ENTROPY.md §4.1: at least ceil(N / 8192) = 2
    # lanes), what made the NumPy decoder loop per symbol.
    out["one_lane_12288_symbols.gsz"] = gsz(m, full4, attr_chunk(m, scales=single_models_stream(3, lanes=1), valid=True))
    return out


def amplified() -> dict:
    """{file name: bytes} of larger bombs, built on demand (``bench/bench_bombs.py --amplified``),
    not committed: 256 layers of 8 Gaussians whose two ATTR streams declare 2^20 models each
    (106 kB; before issue 19's model-count rule: 30 s native, 50 s NumPy), and the issue's
    965-byte full octree of 2^21 Gaussians with one-lane streams (NumPy: 6.8 s)."""
    geom = geom_chunk(1, 8, full_octree(1))
    ac = single_models_stream(7, empty=(1 << 20) - 7, zstd=True)
    sc = single_models_stream(3, empty=(1 << 20) - 3, zstd=True)
    attr = bytes([0, 7]) + struct.pack("<7d", *[0.0] * 7) + channel_set(7, 7, ac) + channel_set(3, 8, sc)
    d, m = 7, 8 ** 7
    return {"models_2e20_x512_streams.gsz": gsz(8, geom, attr, layers=256),
            "one_lane_full_octree_2e21.gsz": gsz(m, geom_chunk(d, m, full_octree(d)), attr_chunk(m))}


if __name__ == "__main__":
    # python make_bombs.py [--amplified DIR]: this folder's bombs, or the larger ones into DIR
    amp = sys.argv[1:2] == ["--amplified"]
    out_dir = Path(sys.argv[2]) if amp else HERE
    for name, data in (amplified() if amp else bombs()).items():
        (out_dir / name).write_bytes(data)
        print(f"{name}: {len(data)} bytes")
