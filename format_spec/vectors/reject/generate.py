"""Must-reject vectors: small .gsz files that break one rule each, and what a decoder says.

    .venv/bin/python format_spec/vectors/reject/generate.py     # rewrite the files and manifest.json

Each file is a small valid base with one field changed and its checksums recomputed (so the
fault reaches the parser it is about), or a resource bomb of ``tests/data/bombs`` (made by its
own generator).  The base (:func:`base_chunks`, ~1 kB, SH degree 1) takes its GEOM chunk from
the committed vector ``../sh1_jug_150.gsz`` (135 voxels) and builds ATTR and SHVQ byte by byte
from the spec with SINGLE models (every value 0, codeword 0 for every Gaussian); a two-layer
base repeats it with the codebook in layer 0.  Nothing comes from the encoder, so the files
stay what they are.  ``manifest.json`` lists per file the rule it breaks (GSZ.md / ENTROPY.md /
OCTREE.md section), the reference decoder's exception class, a fragment of its message and,
the arguments to decode with (``max_gaussians`` where a rule lies behind the default
Gaussians-per-byte limit, ``layers`` where a rule holds for chunks a decode does not use).  A conforming decoder must reject every file (the message and class are the reference's;
another decoder only has to reject).  ``tests/test_reject_vectors.py`` checks both reference
paths and that this script rewrites the committed files byte for byte.
"""
from __future__ import annotations

import importlib.util
import json
import struct
import sys
import zlib
from pathlib import Path

HERE = Path(__file__).resolve().parent
VECTORS = HERE.parent
ROOT = VECTORS.parent.parent
BOMBS = ROOT / "tests" / "data" / "bombs"
HEADER, ENTRY = 64, 24


def varint(v: int) -> bytes:
    out = bytearray()
    while True:
        b, v = v & 0x7F, v >> 7
        out.append(b | (0x80 if v else 0))
        if not v:
            return bytes(out)


def zigzag(v: int) -> int:
    return 2 * v if v >= 0 else -2 * v - 1


# ---- container ------------------------------------------------------------------------------
def split(data: bytes) -> tuple[bytearray, list]:
    """(64-byte header, [[type, flags, data] per chunk]) of a file."""
    n = struct.unpack_from("<I", data, 28)[0]
    off = HEADER + ENTRY * n + 4
    chunks = []
    for i in range(n):
        ctype, flags, length = struct.unpack_from("<4sIQ", data, HEADER + ENTRY * i)
        chunks.append([ctype, flags, bytes(data[off:off + length])])
        off += length
    return bytearray(data[:HEADER]), chunks


def join(header: bytes, chunks: list, *, fix_header: bool = True) -> bytes:
    """A file from a header and chunks, every length and checksum recomputed (the header's CRC
    too, unless ``fix_header`` is False)."""
    h = bytearray(header)
    struct.pack_into("<I", h, 28, len(chunks))
    if fix_header:
        struct.pack_into("<I", h, 60, zlib.crc32(bytes(h[:60])))
    table = b"".join(struct.pack("<4sIQII", t, f, len(d), zlib.crc32(d), 0) for t, f, d in chunks)
    return bytes(h) + table + struct.pack("<I", zlib.crc32(table)) + b"".join(d for _, _, d in chunks)


def with_header(data: bytes, fmt: str, offset: int, value) -> bytes:
    h, chunks = split(data)
    struct.pack_into(fmt, h, offset, value)
    return join(h, chunks)


def replace_chunk(data: bytes, ctype: bytes, new: bytes, layer: int = 0) -> bytes:
    h, chunks = split(data)
    for c in chunks:
        if c[0] == ctype and (c[1] >> 8) & 0xFF == layer:
            c[2] = new
            return join(h, chunks)
    raise KeyError(ctype)


def twice(data: bytes, ctype: bytes) -> bytes:
    """``data`` with its first ``ctype`` chunk written twice in a row (one part, two of a kind)."""
    h, chunks = split(data)
    i = next(k for k, c in enumerate(chunks) if c[0] == ctype)
    return join(h, chunks[:i + 1] + chunks[i:])


def chunk(data: bytes, ctype: bytes, layer: int = 0) -> bytes:
    return next(d for t, f, d in split(data)[1] if t == ctype and (f >> 8) & 0xFF == layer)


def poke(buf: bytes, offset: int, fmt: str, value) -> bytes:
    b = bytearray(buf)
    struct.pack_into(fmt, b, offset, value)
    return bytes(b)


# ---- chunk payloads -------------------------------------------------------------------------
def channel_set_fields(data: bytes, off: int) -> dict:
    """Offsets of one ChannelSet's fields (GSZ.md §5) starting at ``off``, and its end."""
    c, length, b, mode = struct.unpack_from("<BIHB", data, off)
    f = {"C": off, "L": off + 1, "B": off + 5, "mode": off + 7, "bits": off + 8}
    f["mins"] = f["bits"] + c * b
    f["maxs"] = f["mins"] + 4 * c * b
    f["blob"] = f["maxs"] + 4 * c * b
    f["stream"] = f["blob"] + 8
    f["end"] = f["stream"] + struct.unpack_from("<Q", data, f["blob"])[0]
    f["c"], f["b"] = c, b
    return f


def attr_sets(attr: bytes) -> tuple[dict, dict]:
    """(AC set fields, direct set fields) of an ATTR chunk (GSZ.md §7)."""
    ac = channel_set_fields(attr, 2 + 56)
    return ac, channel_set_fields(attr, ac["end"])


def single_stream(models: int = 3, *, lanes: int = 1, states=None, words: bytes = b"",
                  body: bytes | None = None, compressed: bool = False) -> bytes:
    """A RansStream (ENTROPY.md §5): ``models`` SINGLE models at 0 (or the given ``body``),
    ``lanes`` lanes with the given initial ``states`` (default 2^16) and 16-bit ``words``."""
    if body is None:
        body = varint(models) + varint(1) * models + varint(0) * models
    states = [1 << 16] * lanes if states is None else states
    return (varint(len(body) << 1 | int(compressed)) + body + varint(lanes) + varint(len(words) // 2)
            + b"".join(struct.pack("<I", s) for s in states) + words)


# ---- the base files -------------------------------------------------------------------------
def base_chunks(layers: int = 1, source: str = "sh1_jug_150.gsz") -> tuple[bytes, list]:
    """(header, chunks) of the valid base: ``layers`` copies of one part (GEOM of sh1_jug_150,
    or of ``source``, hand-built ATTR and SHVQ), the SH codebook in layer 0."""
    geom = chunk((VECTORS / source).read_bytes(), b"GEOM")
    m = struct.unpack_from("<Q", geom, 33)[0]
    attr = bytes([0, 7]) + struct.pack("<7d", *[0.0] * 7) + simple_set(7, m - 1) + simple_set(3, m)
    chunks = []
    for li in range(layers):
        shvq = struct.pack("<IIH", 0 if li else 1, 0, 9) + (b"" if li else simple_set(9, 1))
        shvq += struct.pack("<Q", len(single_stream(1))) + single_stream(1)       # indices: all 0
        chunks += [[b"GEOM", 1 | li << 8, geom], [b"ATTR", 1 | li << 8, attr], [b"SHVQ", 1 | li << 8, shvq]]
    h = bytearray(HEADER)
    struct.pack_into("<8sHHIQBBHI6fII", h, 0, b"\x89GSZ\r\n\x1a\n", 1, 1, 64, m * layers, 1, 1, 0, 0,
                     *struct.unpack_from("<6f", (VECTORS / source).read_bytes(), 32), 0, 0)
    return bytes(h), chunks


def simple_set(c: int, length: int, stream: bytes | None = None, *, b: int = 1, mode: int = 0,
               bits: int = 1, lo: float = 0.0, hi: float = 0.0) -> bytes:
    """A ChannelSet (GSZ.md §5) of ``c`` channels of ``length``: ``b`` blocks of ``bits`` bits
    over [lo, hi], its stream (default: c SINGLE models at 0, one lane)."""
    stream = single_stream(c if mode == 0 else 16 * c) if stream is None else stream
    return (struct.pack("<BIHB", c, length, b, mode) + bytes([bits]) * (c * b)
            + struct.pack(f"<{c * b}f", *[lo] * (c * b)) + struct.pack(f"<{c * b}f", *[hi] * (c * b))
            + struct.pack("<Q", len(stream)) + stream)


def with_direct_set(base: bytes, stream: bytes, *, c: int = 3, b: int = 1, mode: int = 0, **kw) -> bytes:
    """``base`` with its ATTR's direct (log-scale) ChannelSet replaced by one with ``stream``."""
    attr = chunk(base, b"ATTR")
    _, direct = attr_sets(attr)
    m = struct.unpack_from("<Q", chunk(base, b"GEOM"), 33)[0]
    return replace_chunk(base, b"ATTR", attr[:direct["C"]] + simple_set(c, m, stream, b=b, mode=mode, **kw)
                         + attr[direct["end"]:])


def with_shvq(base: bytes, kcb: int, p: int, *, kept: bytes = b"", flags: bytes | None = None,
              indices: bytes | None = None, layer: int = 0) -> bytes:
    """``base`` with a hand-built SHVQ chunk (GSZ.md §8, D = 9) in ``layer``."""
    m = struct.unpack_from("<Q", chunk(base, b"GEOM"), 33)[0]
    out = struct.pack("<IIH", kcb, p, 9) + (simple_set(9, kcb) if kcb else b"") + kept
    if flags is not None:
        out += struct.pack("<Q", len(flags)) + flags
    indices = single_stream(1) if indices is None else indices
    return replace_chunk(base, b"SHVQ", out + struct.pack("<Q", len(indices)) + indices, layer)


def model_body(types: list, *, lo=None, span=(), prec=(), shape=(), centre=(), rl=(), rr=(),
               nbins=(), gaps=(), dlevels=(), m_count: int | None = None) -> bytes:
    """A model-set body (ENTROPY.md §3.2), column by column."""
    lo = [0] * sum(t != 0 for t in types) if lo is None else lo
    out = varint(len(types) if m_count is None else m_count) + b"".join(map(varint, types))
    out += b"".join(varint(zigzag(v)) for v in lo)
    for col in (span, prec, shape, centre):
        out += b"".join(map(varint, col))
    out += bytes(rl) + bytes(rr)
    out += b"".join(map(varint, nbins)) + b"".join(map(varint, gaps))
    return out + b"".join(varint(zigzag(v)) for v in dlevels)


def coarse01(n: int = 1) -> dict:
    """One COARSE model over {0, 1}: bins [0, 1], level codes 1, 1 (equal weights)."""
    return dict(span=[1], prec=[n], shape=[0], nbins=[2], gaps=[0, 0], dlevels=[1, 0])


def _bombs() -> dict:
    spec = importlib.util.spec_from_file_location("make_bombs", BOMBS / "make_bombs.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.bombs()


# ---- the vectors ----------------------------------------------------------------------------
def vectors() -> list:
    """[(file name, bytes, rule, error class, message fragment, decode arguments)]."""
    base = join(*base_chunks())
    lay2 = join(*base_chunks(2))
    out = []

    def add(name, data, rule, message, error="GszFormatError", **decode_args):
        out.append((name + ".gsz", data, rule, error, message, decode_args))

    _header_vectors(base, add)
    _table_vectors(base, lay2, add)
    _part_vectors(base, lay2, add)
    _direct_vectors(add)
    _entropy_vectors(base, add)
    for name, data in sorted(_bombs().items()):
        rule, message, mg = BOMB_RULES[name]
        add("bomb_" + name[:-4], data, rule, message, "GszLimitError" if "per byte" in message else "GszFormatError",
            **({"max_gaussians": mg} if mg else {}))
    return out


def _header_vectors(sh1: bytes, add) -> None:
    h, chunks = split(sh1)
    add("header_bad_magic", b"\x89GSY" + sh1[4:], "GSZ.md §3 magic", "not a .gsz file (bad magic)")
    add("header_crc_mismatch", join(poke(h, 40, "<f", 1.5), chunks, fix_header=False),
        "GSZ.md §3 header_crc", "header checksum mismatch")
    add("header_version_2", with_header(sh1, "<H", 8, 2), "GSZ.md §3 version_major", "unsupported format version 2.1")
    add("header_size_65", with_header(sh1, "<I", 12, 65), "GSZ.md §3 header_size", "unexpected header size 65")
    add("header_zero_gaussians", with_header(sh1, "<Q", 16, 0), "GSZ.md §3 num_gaussians = 0",
        "declares zero Gaussians")
    add("header_above_2e28", with_header(sh1, "<Q", 16, (1 << 28) + 1), "GSZ.md §3/§11 num_gaussians above the limit",
        "268,435,457 Gaussians, above the decoder limit 268,435,456", "GszLimitError")
    add("header_sh_degree_4", with_header(sh1, "<B", 24, 4), "GSZ.md §3 sh_degree", "invalid SH degree 4")
    big = poke(h, 28, "<I", 4097)
    big = poke(big, 60, "<I", zlib.crc32(big[:60]))
    add("header_4097_chunks", big + sh1[HEADER:], "GSZ.md §3 num_chunks", "chunk count 4097 exceeds the limit 4096")


def _table_vectors(sh1: bytes, lay2: bytes, add) -> None:
    h, chunks = split(sh1)
    n = len(chunks)
    m = struct.unpack_from("<Q", sh1, 16)[0]
    bad = bytearray(sh1)
    bad[HEADER + ENTRY * n] ^= 1                                  # the table CRC itself
    add("table_crc_mismatch", bytes(bad), "GSZ.md §4 table_crc", "chunk table checksum mismatch")
    add("table_type_not_printable", join(h, [[b"GE\x01M", f, d] if t == b"GEOM" else [t, f, d] for t, f, d in chunks]),
        "GSZ.md §4 type bytes 0x20..0x7E", "chunk 0 has an invalid type code")
    meta = [b"META", 0, b"not even zstd"]
    bad = bytearray(join(h, chunks + [meta]))
    bad[-1] ^= 0x40
    add("chunk_crc_mismatch_in_meta", bytes(bad), "GSZ.md §4 chunk crc: every chunk, META too",
        "chunk 3 (META) checksum mismatch")
    bad = bytearray(join(h, chunks + [[b"XTRA", 0, b"optional"]]))
    bad[-1] ^= 0x40
    add("chunk_crc_mismatch_in_unknown_optional", bytes(bad), "GSZ.md §4 chunk crc: unknown optional chunks too",
        "chunk 3 (XTRA) checksum mismatch")
    lh, lc = split(lay2)
    bad = bytearray(join(lh, lc))
    bad[-1] ^= 0x40
    add("chunk_crc_mismatch_in_layer_1", bytes(bad), "GSZ.md §4 chunk crc: also chunks a layers=1 decode leaves out",
        "chunk 5 (SHVQ) checksum mismatch", layers=1)
    add("truncated_last_byte", sh1[:-1], "GSZ.md §4 truncated", "truncated: chunk 2 (SHVQ) ends at byte",
        "GszTruncatedError")
    add("trailing_byte", sh1 + b"\x00", "GSZ.md §4 bytes after the last chunk", "1 unexpected trailing bytes")
    add("unknown_required_chunk", join(h, chunks + [[b"XTRA", 1, b"x"]]), "GSZ.md §4 unknown required chunk",
        "required chunk type XTRA is not supported")
    add("missing_geom", join(h, [c for c in chunks if c[0] != b"GEOM"]), "GSZ.md §4 missing GEOM",
        "missing required chunk GEOM")
    add("missing_shvq", join(h, [c for c in chunks if c[0] != b"SHVQ"]), "GSZ.md §4 missing SHVQ for sh_degree > 0",
        "missing required chunk SHVQ")
    add("shvq_in_sh0_file", with_header(sh1, "<B", 24, 0), "GSZ.md §4 SHVQ when sh_degree = 0",
        "SHVQ chunk in a file of SH degree 0")
    add("two_geom_in_a_layer", join(h, chunks[:1] + chunks), "GSZ.md §4 one GEOM per layer", "layer 0 has two GEOM chunks")
    add("layer_gap", join(h, [[t, f | (1 << 8), d] for t, f, d in chunks]),
        "GSZ.md §4.1 layers 0..L-1 without gaps", "belongs to layer 1, but layer 0 has no chunks")
    back = [[t, f & ~0xFF00 if t == b"SHVQ" else f, d] for t, f, d in lc]       # layer 1's SHVQ -> layer 0
    add("layers_out_of_order", join(lh, back), "GSZ.md §4.1 non-decreasing layer order",
        "chunk 5 (SHVQ) of layer 0 follows a chunk of layer 1")
    add("layers_sum_below_header", with_header(sh1, "<Q", 16, m + 1), "GSZ.md §4.1 M sum to num_gaussians",
        f"layers hold {m} Gaussians, header says {m + 1}")
    add("layer_m_above_header", with_header(sh1, "<Q", 16, m - 1), "GSZ.md §4.1/§6 M above the Gaussians left",
        f"voxel count {m} outside 1..{m - 1}")
    add("second_layer_m_above_header", with_header(lay2, "<Q", 16, 2 * m - 1), "GSZ.md §4.1 M above the Gaussians left",
        f"voxel count {m} outside 1..{m - 1}")
    add("tile_bits_without_tile_chunk", join(h, [[t, f | (1 << 16) if t == b"ATTR" else f, d] for t, f, d in chunks]),
        "GSZ.md §4.2 tile bits without a TILE chunk", "belongs to tile 1, but the file has no TILE chunk")
    tile = struct.pack("<I", 1) + h[32:56] + struct.pack("<Q", m)
    add("tile_chunk_after_data", join(h, chunks[:1] + [[b"TILE", 1, tile]] + chunks[1:]),
        "GSZ.md §4.2 TILE precedes every data chunk", "the TILE chunk (chunk 1) follows a data chunk")
    add("tile_chunk_twice", join(h, [[b"TILE", 1, tile]] * 2 + chunks), "GSZ.md §4.2 at most one TILE chunk",
        "two TILE chunks")
    add("tile_chunk_length", join(h, [[b"TILE", 1, tile + b"\x00"]] + chunks), "GSZ.md §4.2 TILE length 4 + 32 T",
        "TILE chunk: 37 bytes, 1 tiles need 36")
    add("tile_counts_not_summing", join(h, [[b"TILE", 1, tile[:-8] + struct.pack("<Q", m + 1)]] + chunks),
        "GSZ.md §4.2 tile counts sum to num_gaussians", f"the tiles hold {m + 1} Gaussians, header says {m}")


def _part_vectors(sh1: bytes, lay2: bytes, add) -> None:
    geom, attr = chunk(sh1, b"GEOM"), chunk(sh1, b"ATTR")
    m = struct.unpack_from("<Q", geom, 33)[0]
    for name, off, fmt, value, rule, msg in (
            ("geom_depth_0", 0, "<B", 0, "GSZ.md §6 depth 1..21", "octree depth 0 outside 1..21"),
            ("geom_depth_22", 0, "<B", 22, "GSZ.md §6 depth 1..21", "octree depth 22 outside 1..21"),
            ("geom_side_negative", 25, "<d", -1.0, "GSZ.md §6 side > 0", "non-finite grid origin or non-positive side"),
            ("geom_origin_nan", 1, "<d", float("nan"), "GSZ.md §6 origin finite", "non-finite grid origin"),
            ("geom_octree_scheme_2", 41, "<B", 2, "OCTREE.md §2 scheme 0 or 1", "unknown coding scheme 2")):
        add(name, replace_chunk(sh1, b"GEOM", poke(geom, off, fmt, value)), rule, msg)
    small = poke(poke(geom, 0, "<B", 2), 33, "<Q", 65)
    add("geom_m_above_8_to_the_d", replace_chunk(with_header(sh1, "<Q", 16, 65), b"GEOM", small),
        "GSZ.md §6 / OCTREE.md §2 M <= 8^d", "octree point count 65 impossible at depth 2")
    add("geom_truncated_field", replace_chunk(sh1, b"GEOM", geom[:30]), "GSZ.md §10 a field past its chunk's end",
        "GEOM chunk: truncated")
    fewer = poke(geom, 33, "<Q", m - 1)
    add("geom_octree_more_voxels_than_m", replace_chunk(with_header(sh1, "<Q", 16, m - 1), b"GEOM", fewer),
        "OCTREE.md §4 a level with more nodes than M", "decodes to 135 nodes, more than the 134 points declared")
    most = 8 * geom[0] * m
    many = geom[:42] + varint(most + 1) + geom[42 + _varint_len(geom, 42):]
    add("geom_octree_too_many_decisions", replace_chunk(sh1, b"GEOM", many), "OCTREE.md §2 S <= 8 d M",
        f"declares {most + 1} symbols, more than {most} possible")
    add("attr_rotation_mode_1", replace_chunk(sh1, b"ATTR", poke(attr, 0, "<B", 1)), "GSZ.md §7 rotation_mode 0",
        "unknown rotation mode 1")
    add("attr_r_6", replace_chunk(sh1, b"ATTR", poke(attr, 1, "<B", 6)), "GSZ.md §7 R = 7",
        "expected 7 RAHT channels, got 6")
    add("attr_dc_infinite", replace_chunk(sh1, b"ATTR", poke(attr, 2, "<d", float("inf"))), "GSZ.md §7 dc finite",
        "non-finite RAHT DC coefficient")
    add("attr_trailing_byte", replace_chunk(sh1, b"ATTR", attr + b"\x00"), "GSZ.md §7 nothing after",
        "ATTR chunk: 1 unexpected trailing bytes")
    add("output_not_finite", replace_chunk(sh1, b"ATTR", poke(attr, 2, "<d", 1e300)),
        "GSZ.md §7 decoded float32 values finite", "decoded opacities contain non-finite values")
    ac, _ = attr_sets(attr)
    for name, off, fmt, value, rule, msg in (
            ("channelset_c_6", ac["C"], "<B", 6, "GSZ.md §5 C as prescribed", "RAHT AC set has 6 channels, expected 7"),
            ("channelset_l_wrong", ac["L"], "<I", m, "GSZ.md §5 L as prescribed",
             f"RAHT AC set has channel length {m}, expected {m - 1}"),
            ("channelset_l_above_bound", ac["L"], "<I", m + 1, "GSZ.md §5 L within its bound",
             f"channel length {m + 1} exceeds the point count {m}"),
            ("channelset_b_0", ac["B"], "<H", 0, "GSZ.md §5 B >= 1", "RAHT AC set with zero blocks"),
            ("channelset_model_mode_2", ac["mode"], "<B", 2, "GSZ.md §5 model_mode 0 or 1", "unknown model mode 2"),
            ("channelset_bits_0", ac["bits"], "<B", 0, "GSZ.md §5 bits 1..16", "quantiser bit-width outside 1..16"),
            ("channelset_bits_17", ac["bits"], "<B", 17, "GSZ.md §5 bits 1..16", "quantiser bit-width outside 1..16"),
            ("channelset_min_nan", ac["mins"], "<f", float("nan"), "GSZ.md §5 mins finite",
             "quantiser min/max contains a non-finite value"),
            ("channelset_max_below_min", ac["maxs"], "<f", -1e30, "GSZ.md §5 maxs >= mins", "quantiser group has max < min")):
        add(name, replace_chunk(sh1, b"ATTR", poke(attr, off, fmt, value)), rule, msg)
    add("symbol_above_group_bits", with_direct_set(sh1, single_stream(body=model_body([1, 1, 1], lo=[0, 2, 0]))),
        "GSZ.md §5 symbol within 0..2^bits-1", "quantisation symbol")
    shvq = chunk(sh1, b"SHVQ")
    for name, off, fmt, value, rule, msg in (
            ("shvq_d_wrong", 8, "<H", 10, "GSZ.md §8 D = 3K", "SH vector length 10 does not match SH degree 1"),
            ("shvq_p_above_m", 4, "<I", m + 1, "GSZ.md §8 P <= M", f"{m + 1} kept SH vectors for {m} Gaussians"),
            ("shvq_codebook_above_65536", 0, "<I", 65537, "GSZ.md §8 K_cb <= 65536", "codebook size 65537 outside 1..65536"),
            ("shvq_indices_without_codebook", 0, "<I", 0, "GSZ.md §8 indices need a codebook",
             "codeword indices but no SH codebook")):
        add(name, replace_chunk(sh1, b"SHVQ", poke(shvq, off, fmt, value)), rule, msg)
    add("shvq_trailing_byte", replace_chunk(sh1, b"SHVQ", shvq + b"\x00"), "GSZ.md §8 nothing after",
        "SHVQ chunk: 1 unexpected trailing bytes")
    add("shvq_second_codebook", with_shvq(lay2, 1, 0, layer=1), "GSZ.md §4.1/§8 at most one codebook",
        "a second SH codebook (1 entries)")
    add("shvq_index_above_codebook", with_shvq(sh1, 1, 0, indices=single_stream(body=model_body([1], lo=[1]))),
        "GSZ.md §8 index < K_cb", "codeword index out of range")
    kept = simple_set(9, 1)
    add("shvq_flag_2", with_shvq(sh1, 1, 1, kept=kept, flags=single_stream(body=model_body([1], lo=[2]))),
        "GSZ.md §8 flags 0/1", "kept flag outside 0/1")
    add("shvq_flag_count", with_shvq(sh1, 1, 1, kept=kept, flags=single_stream(body=model_body([1], lo=[1]))),
        "GSZ.md §8 exactly P flags set", "kept flags set")
    add("shvq_flags_two_models", with_shvq(sh1, 1, 1, kept=kept, flags=single_stream(2)),
        "GSZ.md §8 flag stream: one model (model id 0)", "2 models, more than the 1 its use can name")
    # every vector kept, channel 1's symbols 2 in a 1-bit group (decoders that keep the kept set
    # as symbols until they transpose it check them there)
    kept_high = simple_set(9, m, single_stream(body=model_body([1] * 9, lo=[0, 2] + [0] * 7)))
    add("shvq_kept_symbol_above_group_bits",
        with_shvq(sh1, 0, m, kept=kept_high, flags=single_stream(body=model_body([1], lo=[1]))),
        "GSZ.md §5 symbol within 0..2^bits-1 (kept SH set)", "quantisation symbol")
    _shcl_vectors(sh1, m, add)
    _rwgt_vectors(sh1, m, add)
    _shxf_vectors(sh1, add)
    _shrf_vectors(sh1, m, add)


def every_vector_kept(base: bytes, m: int, kcb: int = 0) -> bytes:
    """``base`` with a ``kcb``-word codebook and every one of its ``m`` SH vectors kept (flags all
    1, no indices)."""
    return with_shvq(base, kcb, m, kept=simple_set(9, m), flags=single_stream(body=model_body([1], lo=[1])),
                     indices=single_stream(0))


def before_shvq(base: bytes, ctype: bytes, payload: bytes, flags: int = 1) -> bytes:
    """``base`` with a ``ctype`` chunk of ``payload`` right before its first SHVQ."""
    h, chunks = split(base)
    i = next(k for k, c in enumerate(chunks) if c[0] == b"SHVQ")
    return join(h, chunks[:i] + [[ctype, flags, payload]] + chunks[i:])


def with_shcl(base: bytes, m: int, payload: bytes, *, kept_all: bool = True, flags: int = 1) -> bytes:
    """``base`` with every one of its ``m`` SH vectors kept (when ``kept_all``) and an SHCL chunk
    (GSZ.md §8.1) of ``payload`` before its SHVQ."""
    return before_shvq(every_vector_kept(base, m) if kept_all else base, b"SHCL", payload, flags)


def shcl(q: int, stream: bytes) -> bytes:
    return struct.pack("<B", q) + struct.pack("<Q", len(stream)) + stream


def _shcl_vectors(sh1: bytes, m: int, add) -> None:
    """SHCL (GSZ.md §8.1): the valid form is every vector kept, classes from one SINGLE model."""
    ok = shcl(2, single_stream(body=model_body([1], lo=[1])))
    add("shcl_q_1", with_shcl(sh1, m, shcl(1, single_stream(1))), "GSZ.md §8.1 Q in 2..16",
        "SH class count 1 outside 2..16")
    add("shcl_q_17", with_shcl(sh1, m, shcl(17, single_stream(1))), "GSZ.md §8.1 Q in 2..16",
        "SH class count 17 outside 2..16")
    add("shcl_class_not_below_q", with_shcl(sh1, m, shcl(2, single_stream(body=model_body([1], lo=[2])))),
        "GSZ.md §8.1 classes 0..Q-1", "SH class outside 0..1")
    add("shcl_two_models", with_shcl(sh1, m, shcl(2, single_stream(2))), "GSZ.md §8.1 one model (model id 0)",
        "2 models, more than the 1 its use can name")
    add("shcl_trailing_byte", with_shcl(sh1, m, ok + b"\x00"), "GSZ.md §8.1 nothing after",
        "SHCL chunk: 1 unexpected trailing bytes")
    add("shcl_without_kept_vectors", with_shcl(sh1, m, ok, kept_all=False), "GSZ.md §8.1 P > 0",
        "SH classes for a part without kept SH vectors")
    two = with_shcl(sh1, m, ok)
    add("shcl_twice_in_a_layer", twice(two, b"SHCL"), "GSZ.md §4 one SHCL per part",
        "layer 0 has two SHCL chunks")
    add("shcl_in_sh0_file", with_header(two, "<B", 24, 0), "GSZ.md §4 SHCL when sh_degree = 0",
        "SHCL chunk in a file of SH degree 0")


def with_shrf(base: bytes, m: int, payload: bytes, *, kcb: int = 1, kept_all: bool = True,
              flags: int = 1) -> bytes:
    """``base`` with a ``kcb``-word codebook, every one of its ``m`` SH vectors kept (when
    ``kept_all``; else none) and an SHRF chunk (GSZ.md §8.3) of ``payload`` before its SHVQ."""
    base = every_vector_kept(base, m, kcb) if kept_all else with_shvq(base, kcb, 0)
    return before_shvq(base, b"SHRF", payload, flags)


def _shrf_vectors(sh1: bytes, m: int, add) -> None:
    """SHRF (GSZ.md §8.3): the valid form is a 1-word codebook, every vector kept, each the
    residual of word 0 (one SINGLE model)."""
    ok = blob(single_stream(body=model_body([1], lo=[0])))
    add("shrf_index_above_codebook", with_shrf(sh1, m, blob(single_stream(body=model_body([1], lo=[1])))),
        "GSZ.md §8.3 index < K_cb", "SHRF chunk: codeword index out of range")
    add("shrf_without_codebook", with_shrf(sh1, m, ok, kcb=0), "GSZ.md §8.3 needs a codebook",
        "SH codeword refinement but no SH codebook")
    add("shrf_without_kept_vectors", with_shrf(sh1, m, ok, kept_all=False), "GSZ.md §8.3 P > 0",
        "SH codeword refinement for a part without kept SH vectors")
    add("shrf_two_models", with_shrf(sh1, m, blob(single_stream(2))), "GSZ.md §8.3 one model (model id 0)",
        "2 models, more than the 1 its use can name")
    add("shrf_trailing_byte", with_shrf(sh1, m, ok + b"\x00"), "GSZ.md §8.3 nothing after",
        "SHRF chunk: 1 unexpected trailing bytes")
    two = with_shrf(sh1, m, ok)
    add("shrf_twice_in_a_layer", twice(two, b"SHRF"), "GSZ.md §4 one SHRF per part",
        "layer 0 has two SHRF chunks")
    add("shrf_in_sh0_file", with_header(two, "<B", 24, 0), "GSZ.md §4 SHRF when sh_degree = 0",
        "SHRF chunk in a file of SH degree 0")


def blob(data: bytes) -> bytes:
    """A u64-length-prefixed blob (GSZ.md §1)."""
    return struct.pack("<Q", len(data)) + data


def with_rwgt(base: bytes, payload: bytes, *, flags: int = 1) -> bytes:
    """``base`` with an RWGT chunk (GSZ.md §7.1) of ``payload`` right after layer 0's GEOM."""
    h, chunks = split(base)
    i = next(k for k, c in enumerate(chunks) if c[0] == b"GEOM")
    return join(h, chunks[:i + 1] + [[b"RWGT", flags, payload]] + chunks[i + 1:])


def rwgt(q: int, weights, stream: bytes) -> bytes:
    return struct.pack(f"<B{len(weights)}H", q, *weights) + struct.pack("<Q", len(stream)) + stream


def _rwgt_vectors(sh1: bytes, m: int, add) -> None:
    """RWGT (GSZ.md §7.1) and SHCL's RWGT form (§8.1): the valid chunk is 2 classes, weights
    1 and 3, every point in class 1 (one SINGLE model)."""
    every1 = single_stream(body=model_body([1], lo=[1]))
    ok = rwgt(2, [1, 3], every1)
    add("rwgt_q_1", with_rwgt(sh1, rwgt(1, [1], every1)), "GSZ.md §7.1 Q in 2..16",
        "RAHT weight class count 1 outside 2..16")
    add("rwgt_q_17", with_rwgt(sh1, rwgt(17, [1] * 17, every1)), "GSZ.md §7.1 Q in 2..16",
        "RAHT weight class count 17 outside 2..16")
    add("rwgt_weight_0", with_rwgt(sh1, rwgt(2, [0, 3], every1)), "GSZ.md §7.1 weights 1..65535",
        "RAHT class weight 0")
    add("rwgt_class_not_below_q", with_rwgt(sh1, rwgt(2, [1, 3], single_stream(body=model_body([1], lo=[2])))),
        "GSZ.md §7.1 classes 0..Q-1", "RAHT weight class outside 0..1")
    add("rwgt_two_models", with_rwgt(sh1, rwgt(2, [1, 3], single_stream(2))), "GSZ.md §7.1 one model (model id 0)",
        "2 models, more than the 1 its use can name")
    add("rwgt_trailing_byte", with_rwgt(sh1, ok + b"\x00"), "GSZ.md §7.1 nothing after",
        "RWGT chunk: 1 unexpected trailing bytes")
    add("rwgt_twice_in_a_layer", twice(with_rwgt(sh1, ok), b"RWGT"), "GSZ.md §4 one RWGT per part",
        "layer 0 has two RWGT chunks")
    add("shcl_from_rwgt_without_rwgt", with_shcl(sh1, m, b"\x00"), "GSZ.md §8.1 Q = 0 needs the part's RWGT",
        "SH classes taken from an RWGT chunk the part does not have")
    add("shcl_from_rwgt_trailing_byte", with_shcl(with_rwgt(sh1, ok), m, b"\x00\x00"),
        "GSZ.md §8.1 nothing after the Q byte 0", "SHCL chunk: 1 unexpected trailing bytes")


def with_shxf(base: bytes, payload: bytes, *, flags: int = 1) -> bytes:
    """``base`` with an SHXF chunk (GSZ.md §8.2) of ``payload`` right before layer 0's SHVQ (where
    the encoder puts it)."""
    h, chunks = split(base)
    i = next(k for k, c in enumerate(chunks) if c[0] == b"SHVQ")
    return join(h, chunks[:i] + [[b"SHXF", flags, payload]] + chunks[i:])


def _shxf_vectors(sh1: bytes, add) -> None:
    """SHXF (GSZ.md §8.2): a valid chunk is the one byte 1, 2 or 3 (luma/chroma SH vectors,
    DC colour or both; the base's SH vectors are all 0, so any transform decodes them), or bit 2
    (KLT) with its matrix in the tile's first layer."""
    ok = bytes([1])
    add("shxf_transform_0", with_shxf(sh1, b"\x00"), "GSZ.md §8.2 transform bits 0, 1 and 2",
        "unknown SH colour transform 0")
    add("shxf_transform_8", with_shxf(sh1, b"\x08"), "GSZ.md §8.2 transform bits 0, 1 and 2",
        "unknown SH colour transform 8")
    add("shxf_klt_and_luma_chroma", with_shxf(sh1, b"\x05\x00"), "GSZ.md §8.2 not both bits 0 and 2",
        "SH vectors both luma/chroma (bit 0) and KLT (bit 2)")
    add("shxf_klt_truncated", with_shxf(sh1, b"\x04"), "GSZ.md §8.2 D after the KLT bit",
        "SHXF chunk: truncated")
    add("shxf_klt_matrix_truncated", with_shxf(sh1, b"\x04\x09" + bytes(2 * 80)), "GSZ.md §8.2 D x D int16",
        "SHXF chunk: truncated")
    add("shxf_klt_wrong_size", with_shxf(sh1, b"\x04\x03" + bytes(2 * 9)), "GSZ.md §8.2 D = 3K",
        "KLT matrix of size 3 for SH degree 1 (expected 9)")
    add("shxf_klt_no_matrix", with_shxf(sh1, b"\x04\x00"), "GSZ.md §8.2 the tile's first KLT part carries the matrix",
        "KLT bit but no matrix in this or an earlier layer of the tile")
    add("shxf_empty", with_shxf(sh1, b""), "GSZ.md §8.2 one byte (no transform id)", "SHXF chunk: truncated")
    add("shxf_trailing_byte", with_shxf(sh1, ok + b"\x00"), "GSZ.md §8.2 nothing after",
        "SHXF chunk: 1 unexpected trailing bytes")
    add("shxf_twice_in_a_layer", twice(with_shxf(sh1, ok), b"SHXF"), "GSZ.md §4 one SHXF per part",
        "layer 0 has two SHXF chunks")
    # SH degree 0 without the SHVQ chunk, so that the SHXF chunk is the one rule broken
    h, chunks = split(with_header(with_shxf(sh1, ok), "<B", 24, 0))
    add("shxf_in_sh0_file", join(h, [c for c in chunks if c[0] != b"SHVQ"]),
        "GSZ.md §8.2 the SH vector bit when sh_degree = 0",
        "SH vector transform (bit 0 or 2) in a file of SH degree 0")
    # a two-layer KLT file whose layer 1 carries a matrix again
    h, chunks = split((VECTORS / "sh3_jug_2k_klt.gsz").read_bytes())
    xf = [c for c in chunks if c[0] == b"SHXF"]
    assert len(xf) == 2 and xf[0][2][1] == 45 and xf[1][2] == b"\x06\x00", "the source vector's SHXF chunks moved"
    xf[1][2] = xf[0][2]
    add("shxf_klt_second_matrix", join(h, chunks), "GSZ.md §8.2 one matrix a tile",
        "a second KLT matrix in one tile")


def _direct_vectors(add) -> None:
    """Octree scheme 1 (OCTREE.md §2, §4.1), on the GEOM of sh1_jug_150_d16_direct (135 voxels,
    depth 16, the same Gaussians as the base)."""
    base = join(*base_chunks(source="sh1_jug_150_d16_direct.gsz"))
    geom = chunk(base, b"GEOM")
    depth, m = geom[0], struct.unpack_from("<Q", geom, 33)[0]
    assert geom[41] == 1, "the source vector's octree is not scheme 1"
    pos = 42
    num_symbols = _varint_value(geom, pos)
    pos += _varint_len(geom, pos)
    level = geom[pos]
    pos += 1
    raw_len = _varint_value(geom, pos)
    pos += _varint_len(geom, pos)
    raw, body = geom[pos:pos + raw_len], geom[pos + raw_len:]

    def with_payload(s=num_symbols, d=level, raw=raw, declared=None):
        n = len(raw) if declared is None else declared
        return replace_chunk(base, b"GEOM", geom[:41] + bytes([1]) + varint(s) + bytes([d]) + varint(n) + raw + body)

    add("geom_direct_level_0", with_payload(d=0), "OCTREE.md §2 1 <= D <= d - 1",
        f"direct level 0 outside 1..{depth - 1}")
    add("geom_direct_level_d", with_payload(d=depth), "OCTREE.md §2 1 <= D <= d - 1",
        f"direct level {depth} outside 1..{depth - 1}")
    most = 9 * depth * m
    add("geom_direct_too_many_decisions", with_payload(s=most + 1), "OCTREE.md §2 S <= 9 d M (scheme 1)",
        f"declares {most + 1} symbols, more than {most} possible")
    add("geom_direct_raw_past_payload", with_payload(declared=len(raw) + len(body) + 1),
        "OCTREE.md §2 the raw section within the payload", f"raw section of {len(raw) + len(body) + 1} bytes does not fit")
    add("geom_direct_raw_short", with_payload(raw=raw[:-1]), "OCTREE.md §4.1 a level's direct bits within the raw section",
        "left in the raw section")
    add("geom_direct_raw_left_over", with_payload(raw=raw + b"\x00"), "OCTREE.md §4.1 the raw section read to its end",
        "1 bytes of the raw section left unread")
    # a set padding bit after the last level's direct bits: the highest clear bit of the last
    # byte that the reference decoder reports as padding (found by decoding, so the file does
    # not depend on the level structure being recomputed here)
    from gsz.decoder import decode
    for bit in range(7, 0, -1):
        if raw[-1] >> bit & 1:
            continue
        bad = with_payload(raw=raw[:-1] + bytes([raw[-1] | 1 << bit]))
        try:
            decode(bad)
        except Exception as e:          # noqa: BLE001 - any other outcome: try the next bit
            if "padding" in str(e):
                add("geom_direct_raw_padding", bad, "OCTREE.md §4.1 zero padding after a level's direct bits",
                    "non-zero padding after the direct points of level")
                break
    else:
        raise AssertionError("no padding bit in the last byte of the source vector's raw section")


def _varint_value(buf: bytes, pos: int) -> int:
    v, shift = 0, 0
    while True:
        b = buf[pos]
        v |= (b & 0x7F) << shift
        if not b & 0x80:
            return v
        pos, shift = pos + 1, shift + 7


def _varint_len(buf: bytes, pos: int) -> int:
    n = 1
    while buf[pos + n - 1] & 0x80:
        n += 1
    return n


def _entropy_vectors(sh1: bytes, add) -> None:
    def stream_case(name, stream, rule, msg, **kw):
        add("rans_" + name, with_direct_set(sh1, stream, **kw), rule, msg)

    e = "ENTROPY.md "
    stream_case("varint_10_bytes", varint(len(b"\x80" * 9 + b"\x01") << 1) + b"\x80" * 9 + b"\x01",
                e + "§1 varint at most 9 bytes", "varint too long")
    stream_case("truncated_varint", b"\x80", e + "§1 a varint running past its data",
                "truncated varint (model-set length)")
    stream_case("column_past_the_body", single_stream(body=varint(3) + varint(1) * 3 + b"\x80"),
                e + "§3.2 a column longer than the bytes left", "3 varints (lo) cannot fit in 1 bytes")
    stream_case("model_count_above_bytes", single_stream(body=varint(1000) + bytes(10)),
                e + "§3.2 M <= bytes left in the body", "1000 models do not fit the table", b=400)
    stream_case("type_4", single_stream(body=model_body([1, 1, 4])), e + "§3.2 type 0..3", "unknown model type")
    stream_case("span_above_65536", single_stream(body=model_body([1, 1, 2], span=[65537], prec=[16], shape=[0],
                                                                  nbins=[1], gaps=[0], dlevels=[1])),
                e + "§3.2 span <= 65536", "out of range")
    stream_case("precision_17", single_stream(body=model_body([1, 1, 2], **{**coarse01(17)})),
                e + "§3.2 n <= 16", "out of range")
    stream_case("bin_shift_17", single_stream(body=model_body([1, 1, 2], **{**coarse01(), "shape": [17 << 2]})),
                e + "§3.2 h <= 16", "out of range")
    stream_case("lo_below_int32", single_stream(body=model_body([1, 1, 1], lo=[0, 0, -(1 << 31) - 1])),
                e + "§3.2 values in [-2^31, 2^31)", "value range outside")
    stream_case("laplace_centre_above_span", single_stream(body=model_body([1, 1, 3], span=[3], prec=[2], centre=[4],
                                                                           rl=[0], rr=[0])),
                e + "§3.2 centre <= span", "laplace centre outside the range")
    stream_case("laplace_support_above_2n", single_stream(body=model_body([1, 1, 3], span=[4], prec=[2], centre=[0],
                                                                          rl=[0], rr=[0])),
                e + "§3.2 LAPLACE span + 1 <= 2^n", "laplace support larger than 2**n")
    stream_case("coarse_zero_bins", single_stream(body=model_body([1, 1, 2], **{**coarse01(), "nbins": [0],
                                                                               "gaps": [], "dlevels": []})),
                e + "§3.2 nbins >= 1", "coarse bin count outside 1..bins")
    stream_case("coarse_first_bin_not_0", single_stream(body=model_body([1, 1, 2], **{**coarse01(), "nbins": [1],
                                                                                     "gaps": [1], "dlevels": [1]})),
                e + "§3.2 b_0 = 0 and last bin = span >> h", "coarse bins not increasing over the range")
    stream_case("coarse_level_0", single_stream(body=model_body([1, 1, 2], **{**coarse01(), "dlevels": [0, 1]})),
                e + "§3.2 level codes 1..25 << g", "coarse level code out of range")
    stream_case("coarse_gap_2e62", single_stream(body=model_body([1, 1, 2], **{**coarse01(), "gaps": [0, 1 << 62]})),
                e + "§3.2 gaps bounded as read (no int64 overflow)", "coarse bin gap or level step out of range")
    stream_case("coarse_dlevel_sum_overflow",
                single_stream(body=model_body([1, 1, 2], **{**coarse01(), "dlevels": [(1 << 62) - 1, (1 << 62) - 1]})),
                e + "§3.2 dlevel sums bounded as read (no int64 overflow)", "coarse bin gap or level step out of range")
    stream_case("body_trailing_byte", single_stream(body=model_body([1, 1, 1]) + b"\x00"),
                e + "§3.2 body ends after column 12", "trailing bytes")
    import zstandard
    frame = zstandard.ZstdCompressor(write_content_size=False).compress(model_body([1, 1, 1]))
    stream_case("zstd_without_content_size", single_stream(body=frame, compressed=True),
                e + "§3.1 zstd frame declares its content size", "content size")
    skippable = struct.pack("<II", 0x184D2A50, 4) + b"gsz!"
    stream_case("zstd_skippable_frame", single_stream(body=skippable, compressed=True),
                e + "§3.1 a skippable frame is not a body", "rANS model set")
    frame = zstandard.ZstdCompressor(write_content_size=True).compress(model_body([1, 1, 1]))
    stream_case("zstd_bytes_after_frame", single_stream(body=frame + b"\x00", compressed=True),
                e + "§3.1 nothing after the frame", "bytes after the zstd frame")
    stream_case("models_above_use_mode_1", single_stream(body=model_body([1] * 49)),
                e + "§3.2 / GSZ.md §5 M <= 16 C in model mode 1", "49 models, more than the 48 its use can name",
                mode=1)
    lut = model_body([1, 1, 2] + [2] * 8, lo=[0] * 11, span=[1] * 9, prec=[14] * 9, shape=[0] * 9,
                     nbins=[2] * 9, gaps=[0] * 18, dlevels=[1, 0] * 9)
    stream_case("lut_budget", single_stream(11, body=lut), e + "§7 LUT budget (SINGLE models count 1 each)",
                "needs 147458 LUT entries, more than the 65536", b=4)
    stream_case("lanes_0", single_stream(lanes=0, states=[]), e + "§4.1 L >= 1", "lane count 0 invalid")
    stream_case("lanes_above_n", single_stream(lanes=500), e + "§4.1 L <= max(1, N)", "lane count 500 invalid")
    stream_case("payload_length", single_stream() + b"\x00", e + "§4.1 exactly 4 L + 2 W bytes", "payload holds")
    stream_case("state_below_2e16", single_stream(states=[(1 << 16) - 1]), e + "§4.1 X[l] >= 2^16",
                "initial state below 2**16")
    stream_case("final_state_not_2e16", single_stream(states=[(1 << 16) + 1]), e + "§4.4 final states 2^16",
                "final states differ from 2**16")
    stream_case("words_left", single_stream(words=b"\x00\x00"), e + "§4.4 every word consumed", "1 words left unread")
    stream_case("word_stream_exhausted", single_stream(body=model_body([1, 1, 2], **coarse01())),
                e + "§4.3 renormalisation with no word left", "payload truncated (word stream exhausted)")
    stream_case("empty_model_used", single_stream(body=model_body([1, 0, 1])), e + "§4.3 model of type EMPTY",
                "symbol refers to an empty model")


#: What each bomb of tests/data/bombs breaks: (rule, message, max_gaussians to reach the rule).
BOMB_RULES = {
    "attr_before_octree_2e24.gsz": ("GSZ.md §11 Gaussians per byte of file", "above the default limit of 32 per byte", None),
    "attr_before_octree_2e28.gsz": ("GSZ.md §11 Gaussians per byte of file", "above the default limit of 32 per byte", None),
    "channelset_255_channels.gsz": ("GSZ.md §5 C checked before the set is decoded", "RAHT AC set has 255 channels, expected 7",
                                    1 << 28),
    "channelset_length_above_m.gsz": ("GSZ.md §5 L checked against its bound first",
                                      "channel length 268435456 exceeds the point count 262144", 1 << 28),
    "full_octree_2e21.gsz": ("GSZ.md §11 Gaussians per byte of file (a valid file: decodes with max_gaussians >= 2^21)",
                             "2,097,152 Gaussians in a 11,199-byte file", None),
    "model_set_body_16mib.gsz": ("ENTROPY.md §3.1 body no longer than a valid one", "content size 16777216 above 1179852",
                                 None),
    "models_2e20_for_3_ids.gsz": ("ENTROPY.md §3.2 / GSZ.md §5 M <= C B", "1048576 models, more than the 3 its use can name",
                                  None),
    "one_lane_12288_symbols.gsz": ("ENTROPY.md §4.1 L >= min(4096, ceil(N / 8192))",
                                   "1 lanes for 12288 symbols, fewer than the 2 required", None),
}


def write() -> list:
    """Write every vector and manifest.json; returns the manifest."""
    for old in HERE.glob("*.gsz"):
        old.unlink()
    manifest = []
    for name, data, rule, error, message, args in vectors():
        (HERE / name).write_bytes(data)
        manifest.append({"file": name, "rule": rule, "error": error, "message": message,
                         **({"decode": args} if args else {})})
    (HERE / "manifest.json").write_text(json.dumps(manifest, indent=1) + "\n")
    return manifest


if __name__ == "__main__":
    sys.path.insert(0, str(ROOT.parent))
    rows = write()
    print(f"{len(rows)} vectors, {sum((HERE / r['file']).stat().st_size for r in rows):,} bytes")
