"""The optional C accelerator (decoder/csrc/) against the NumPy reference: identical clouds
and identical encoder bytes, the same accept/reject decision on hostile input, the GSZ_NATIVE=0
switch and a working package when the extension is missing."""
import contextlib
import json
import os
import shutil
import subprocess
import sys
import sysconfig
import textwrap
import threading
from pathlib import Path

import numpy as np
import pytest

import gsz
from gsz.decoder import GszFormatError, decode, native
from gsz.decoder.container import read_container
from gsz.decoder.morton import morton_encode
from gsz.decoder.octree import decode_octree, decode_octree_codes
from gsz.decoder.rans import decode_stream, read_model_set
from gsz.encoder.octree import encode_octree, octree_symbols
from gsz.encoder.rans import encode_stream
from codec_util import encoded, sample
from conftest import ROOT, SHARED, shared_scene
from test_codec_errors import _fix_crcs

VEC = ROOT / "format_spec" / "vectors"
FIELDS = ("positions", "scales", "rotations", "opacities", "sh_dc", "sh_rest")

needs_native = pytest.mark.skipif(not native.native_available(),
                                  reason="native accelerator not built (" + native.unavailable_reason() + ")")


def _compiler_available() -> bool:
    cc = (sysconfig.get_config_var("CC") or "").split()
    return bool(cc) and shutil.which(cc[0]) is not None


def test_extension_is_built_where_a_compiler_exists():
    """pip install compiles the extension whenever a C compiler is present (setup.py marks it
    optional only for machines without one)."""
    if os.environ.get("GSZ_NATIVE", "1").strip() == "0":
        pytest.skip("GSZ_NATIVE=0 in the environment")
    if not _compiler_available():
        pytest.skip("no C compiler: the NumPy path is expected")
    assert native.native_available(), native.unavailable_reason()
    assert gsz.decoder.native_available() and gsz.decoder.decoder_path() == "native"


def both(fn):
    """(native result, numpy result) of fn(); each is ('ok', value) or ('error', exception)."""
    out = []
    for use_native in (True, False):
        old = native.set_enabled(use_native)
        try:
            out.append(("ok", fn()))
        except GszFormatError as e:
            out.append(("error", e))
        finally:
            native.set_enabled(old)
    return out


def assert_same_cloud(a, b):
    assert len(a) == len(b) and a.sh_degree == b.sh_degree
    for f in FIELDS:
        x, y = getattr(a, f), getattr(b, f)
        assert x.dtype == y.dtype == np.float32 and x.shape == y.shape, f
        assert np.array_equal(x.view(np.uint32), y.view(np.uint32)), f   # bit for bit


def assert_same_decode(data):
    (ka, a), (kb, b) = both(lambda: decode(data))
    assert ka == kb, (ka, a, kb, b)
    if ka == "ok":
        assert_same_cloud(a, b)
    return ka


# ------------------------------------------------------------------ identical clouds
@needs_native
@pytest.mark.parametrize("name", sorted(p.stem for p in VEC.glob("*.gsz")))
def test_vectors_identical(name):
    data = (VEC / f"{name}.gsz").read_bytes()
    assert assert_same_decode(data) == "ok"
    exp = json.loads((VEC / f"{name}.json").read_text())
    assert len(decode(data)) == exp["num_gaussians"]


@needs_native
@pytest.mark.parametrize("name,n,kw", [
    ("sh0", None, dict(bits=12)),
    ("sh3", None, dict(bits=10)),
    ("sh3", 3000, dict(bits=8, layers=3)),
    ("sh0", 5000, dict(bits=6, blocks=7)),
])
def test_committed_samples_identical(name, n, kw):
    assert assert_same_decode(encoded(name, n, **kw).data) == "ok"


SHARED_SCENES = ["houseplant_sh0.ply", "measuring_jug_sh3.ply", "flowers_daffodils_sh2.ply",
                 "plaza_taebak_crop_sh0.ply", "showroom_lacadiere_crop_sh0.ply",
                 "tiny_graphdeco_iter7000_sh3.ply"]


def _voxels(cloud, depth):
    p = cloud.positions.astype(np.float64)
    lo = p.min(axis=0)
    side = float((p.max(axis=0) - lo).max())
    q = np.floor((p - lo) / side * (1 << depth))
    return np.unique(np.clip(q, 0, (1 << depth) - 1).astype(np.int64), axis=0)


@needs_native
@pytest.mark.shared
@pytest.mark.slow
@pytest.mark.parametrize("scene", SHARED_SCENES)
def test_shared_scene_geometry_identical(scene):
    """The whole scene's octree at the operating depth (11; the smaller scenes also one level
    deeper): identical payload bytes from both encoders, identical voxels from both decoders."""
    cloud = gsz.read_ply(shared_scene(scene))
    for depth in ((11,) if len(cloud) > 200_000 else (11, 12)):
        ijk = _voxels(cloud, depth)
        (ka, pa), (kb, pb) = both(lambda: encode_octree(ijk, depth))
        assert ka == kb == "ok" and pa == pb
        (ka, ca), (kb, cb) = both(lambda: decode_octree_codes(pa, depth, len(ijk)))
        assert ka == kb == "ok" and np.array_equal(ca, cb)
        assert np.array_equal(ca, np.sort(morton_encode(ijk)))


@needs_native
@pytest.mark.shared
@pytest.mark.slow
@pytest.mark.parametrize("scene", SHARED_SCENES)
def test_shared_scene_file_identical(scene):
    """A whole .gsz of a real scene (up to 60k of its Gaussians, 12 bits): identical clouds."""
    from gsz.encoder.pipeline import EncodeOptions, encode
    from codec_util import FAST
    cloud = gsz.read_ply(shared_scene(scene))
    if len(cloud) > 60_000:
        cloud = cloud.subset(np.sort(np.random.default_rng(3).choice(len(cloud), 60_000, replace=False)))
    data = encode(cloud, EncodeOptions(**{**FAST, "bits": 12})).data
    assert assert_same_decode(data) == "ok"


@needs_native
def test_raht_tree_and_transform_identical():
    """raht_tree + raht_apply (one octree level per pass, gains cached for small weights, two
    channel groups transformed separately) against build_raht_tree + raht_inverse, bit for bit:
    sparse and dense voxel sets (weights far above the gain cache), every depth extreme, one
    voxel, and the rejection of codes the tree cannot take."""
    from gsz.decoder.attributes import native_half_angles, native_opacity_dc, native_tree
    from gsz.decoder.raht import build_raht_tree, raht_inverse
    rng = np.random.default_rng(11)
    cases = [(np.array([[0, 0, 0]]), 1), (np.array([[1, 1, 1]]), 1),
             (np.stack(np.meshgrid(*[np.arange(8)] * 3, indexing="ij"), -1).reshape(-1, 3), 3),
             (np.stack(np.meshgrid(*[np.arange(16)] * 3, indexing="ij"), -1).reshape(-1, 3), 6),
             (np.unique(rng.integers(0, 1 << 21, size=(3000, 3)), axis=0), 21),
             (np.unique(rng.integers(0, 40, size=(20000, 3)), axis=0), 6),
             (_voxels(sample("sh0"), 11), 11)]
    for ijk, depth in cases:
        codes = np.sort(morton_encode(ijk)).astype(np.uint64)
        n = codes.size
        dc = rng.normal(0, 5, 7)
        ac = np.ascontiguousarray(rng.normal(0, 2, (7, n - 1)))
        ac[1, :: 7] = np.inf                          # non-finite angles become 0 half angles
        with np.errstate(invalid="ignore", over="ignore"):
            ref = raht_inverse(dc, ac.T, build_raht_tree(codes, depth))
        tree = native_tree(codes, depth)
        half = native_half_angles(tree, dc, ac)
        e = ref[:, 1:4]
        np.testing.assert_array_equal(half, (0.5 * np.where(np.isfinite(e), e, 0.0)).T)
        op, sh_dc, _ = native_opacity_dc(tree, dc, ac)
        assert np.array_equal(op.view(np.uint32), ref[:, 0].astype(np.float32).view(np.uint32))
        assert np.array_equal(sh_dc.view(np.uint32), ref[:, 4:7].astype(np.float32).view(np.uint32))
    with pytest.raises(GszFormatError, match="ascending"):
        native_tree(np.array([3, 2], np.uint64), 2)
    with pytest.raises(GszFormatError, match="ascending"):
        native_tree(np.array([2, 2], np.uint64), 2)
    with pytest.raises(GszFormatError, match="3\\*depth"):
        native_tree(np.array([1, 1 << 6], np.uint64), 2)


# ------------------------------------------------------------------ hostile input
def _fuzzed_files(count: int, seed: int = 20):
    """``count`` corrupted variants of two small files, CRCs fixed up so that the payload
    parsers see the corruption."""
    rng = np.random.default_rng(seed)
    bases = [encoded("sh3", 250, bits=8, codebook=32).data,
             encoded("sh0", 1500, bits=7, layers=2).data]
    for i in range(count):
        src = bases[i % len(bases)]
        c = read_container(src)
        spans = [(ch.offset, ch.offset + len(ch.data)) for ch in c.chunks if ch.type != b"META"]
        a, b = spans[int(rng.integers(len(spans)))]
        buf = bytearray(src)
        kind = rng.random()
        if kind < 0.7:      # overwrite a few bytes, biased towards the counts at a chunk's start
            for _ in range(int(rng.integers(1, 4))):
                pos = a + int(rng.integers(min(b - a, 48))) if rng.random() < 0.5 else int(rng.integers(a, b))
                buf[pos] = int(rng.integers(256))
        elif kind < 0.85:   # flip one bit anywhere in the payload
            pos = int(rng.integers(a, b))
            buf[pos] ^= 1 << int(rng.integers(8))
        else:               # a chunk truncated or grown (its table length fixed up as well)
            # (a one-byte chunk, SHXF, is truncated to nothing)
            delta = -int(rng.integers(1, min(64, b - a) if b - a > 1 else 2)) if rng.random() < 0.7 \
                else int(rng.integers(1, 16))
            idx = [k for k, ch in enumerate(c.chunks) if ch.offset == a][0]
            buf = buf[:b + min(delta, 0)] + (bytes(rng.integers(0, 256, max(delta, 0), dtype=np.uint8))) + buf[b:]
            import struct
            from gsz.decoder.container import HEADER_SIZE, CHUNK_ENTRY_SIZE
            e = HEADER_SIZE + CHUNK_ENTRY_SIZE * idx
            struct.pack_into("<Q", buf, e + 8, len(c.chunks[idx].data) + delta)
        yield _fix_crcs(buf)


@needs_native
def test_fuzzed_files_same_outcome():
    """>= 300 corrupted variants: both paths reject with GszFormatError, or both decode to the
    identical cloud."""
    outcomes = {"ok": 0, "error": 0}
    for data in _fuzzed_files(360):
        outcomes[assert_same_decode(data)] += 1
    assert sum(outcomes.values()) == 360 and outcomes["error"] > 50 and outcomes["ok"] > 0, outcomes


def _decode_outcome(data):
    try:
        return "ok", decode(data)
    except GszFormatError as e:
        return "error", str(e)


@needs_native
def test_fuzzed_files_overlapped_decode_same_outcome(monkeypatch):
    """The two-thread layer decode (forced on for these small files) gives the sequential
    native decode's outcome: the identical cloud, or the same error message (errors keep the
    sequential order: geometry, attributes, SH, then the first non-finite field)."""
    D = sys.modules["gsz.decoder.layer"]
    if D.cores() < 2:
        pytest.skip("the overlap needs two CPUs")
    outcomes = {"ok": 0, "error": 0}
    monkeypatch.setattr(D, "OVERLAP_MAX_POINTS_PER_BYTE", 1 << 40)   # overlap hostile M values too
    for data in _fuzzed_files(240, seed=21):
        monkeypatch.setattr(D, "OVERLAP_MIN_POINTS", 1 << 40)
        ka, a = _decode_outcome(data)
        monkeypatch.setattr(D, "OVERLAP_MIN_POINTS", 1)
        kb, b = _decode_outcome(data)
        assert ka == kb, (a, b)
        if ka == "ok":
            assert_same_cloud(a, b)
        else:
            assert a == b
        outcomes[ka] += 1
    assert outcomes["error"] > 30 and outcomes["ok"] > 0, outcomes


@needs_native
def test_overlapped_decode_reports_the_scales_error_before_the_sh_error(monkeypatch):
    """The overlapped decode decodes the ATTR chunk's direct set (scales) on the worker, after
    the octree, while the calling thread decodes the SH: a file broken in both reports the
    scales' error, as the sequential decode and the NumPy path do."""
    import struct
    from gsz.decoder.container import read_container
    from gsz.decoder.layout import KNOWN_CHUNKS
    D = sys.modules["gsz.decoder.layer"]
    if D.cores() < 2:
        pytest.skip("the overlap needs two CPUs")
    data = encoded("sh3", 6000).data
    c = read_container(data, known_types=KNOWN_CHUNKS)
    attr = next(x for x in c.chunks if x.type == b"ATTR")
    shvq = next(x for x in c.chunks if x.type == b"SHVQ")
    # the direct set follows the AC set: u8 C, u32 L, u16 B, u8 mode, bits, mins, maxs, u64 n, n bytes
    off = 2 + 56
    cc, _, b = struct.unpack_from("<BIH", attr.data, off)
    off += 8 + 9 * cc * b
    off += 8 + struct.unpack_from("<Q", attr.data, off)[0]
    buf = bytearray(data)
    buf[attr.offset + off] = 2                     # the direct set: 2 channels instead of 3
    only_scales = _fix_crcs(bytearray(buf))
    struct.pack_into("<H", buf, shvq.offset + 8, 10)   # SH vector length 10: wrong too
    both_broken = _fix_crcs(buf)
    for broken, want in ((only_scales, "direct channel set has 2 channels"),
                         (both_broken, "direct channel set has 2 channels")):
        monkeypatch.setattr(D, "OVERLAP_MIN_POINTS", 1 << 40)
        sequential = _decode_outcome(broken)
        monkeypatch.setattr(D, "OVERLAP_MIN_POINTS", 1)
        overlapped = _decode_outcome(broken)
        with native.numpy_only():
            reference = _decode_outcome(broken)
        assert sequential == overlapped == reference
        assert overlapped[0] == "error" and want in overlapped[1]


@needs_native
@pytest.mark.parametrize("overlap", [False, True])
def test_non_finite_fields_reported_in_order(monkeypatch, overlap):
    """Hostile parameters that overflow float32 (a huge grid origin, huge RAHT DC
    coefficients): the first non-finite field in the order positions, scales, rotations,
    opacities, sh_dc, sh_rest is named, with the same message on every path."""
    import struct
    D = sys.modules["gsz.decoder.layer"]
    if overlap and D.cores() < 2:
        pytest.skip("the overlap needs two CPUs")
    monkeypatch.setattr(D, "OVERLAP_MIN_POINTS", 1 if overlap else 1 << 40)
    data = encoded("sh3", 300, bits=8, codebook=16).data
    c = read_container(data)
    geom = [x for x in c.chunks if x.type == b"GEOM"][0].offset
    attr = [x for x in c.chunks if x.type == b"ATTR"][0].offset

    def hostile(origin=False, dc=()):
        buf = bytearray(data)
        if origin:
            struct.pack_into("<d", buf, geom + 1, 1e300)
        for ch in dc:                  # RAHT channel: 0 opacity, 1..3 angles, 4..6 f_dc
            struct.pack_into("<d", buf, attr + 2 + 8 * ch, 1e300)
        return _fix_crcs(buf)

    cases = [(dict(origin=True, dc=(0, 4)), "positions"), (dict(dc=(0, 5)), "opacities"),
             (dict(dc=(6,)), "sh_dc"), (dict(dc=(2,)), None)]   # angles: replaced, finite
    for kw, name in cases:
        bad = hostile(**kw)
        (ka, a), (kb, b) = both(lambda: decode(bad))
        assert ka == kb == ("ok" if name is None else "error"), (a, b)
        if name is not None:
            assert str(a) == str(b) and f"decoded {name} contain non-finite" in str(a), (a, b)
        else:
            assert_same_cloud(a, b)


@needs_native
def test_truncated_octree_payloads_same_outcome():
    ijk = _voxels(sample("sh3", 4000), 10)
    payload = encode_octree(ijk, 10)
    for cut in sorted(set(np.linspace(0, len(payload) - 1, 80).astype(int))):
        res = both(lambda: decode_octree(payload[:cut], 10, len(ijk)))
        assert res[0][0] == res[1][0] == "error"
    rng = np.random.default_rng(4)
    for _ in range(60):
        bad = bytearray(payload)
        bad[int(rng.integers(1, len(bad)))] = int(rng.integers(256))
        (ka, a), (kb, b) = both(lambda: decode_octree(bytes(bad), 10, len(ijk)))
        assert ka == kb, (a, b)
        if ka == "ok":
            assert np.array_equal(a, b)


def _helped_decode(payload, depth, m):
    """decode_octree_codes on a thread with a helper that the calling thread joins at once:
    ('ok', codes) or ('error', message)."""
    nat = native.module()
    helper = nat.octree_helper()
    out = []

    def work():
        try:
            out.append(("ok", decode_octree_codes(payload, depth, m, helper)))
        except GszFormatError as e:
            out.append(("error", str(e)))
        finally:
            nat.octree_helper_close(helper)
    th = threading.Thread(target=work)
    th.start()
    nat.octree_help(helper)                 # returns when the traversal ends
    th.join(timeout=60)
    assert not th.is_alive() and len(out) == 1
    return out[0]


@needs_native
def test_octree_helper_identical_and_same_errors():
    """A second thread joining the traversal (context ids, neighbour rows) changes nothing:
    the same codes, the same error on corrupt payloads (also when the traversal stops in the
    middle of a phase the helper works on), and a helper cannot be used twice."""
    def alone(payload, depth, m):
        try:
            return "ok", decode_octree_codes(payload, depth, m)
        except GszFormatError as e:
            return "error", str(e)
    rng = np.random.default_rng(8)
    cases = [(_voxels(sample("sh0"), d), d) for d in (9, 12)]
    cases.append((np.unique(rng.integers(0, 1 << 14, size=(30000, 3)), axis=0), 14))
    for ijk, depth in cases:
        payload = encode_octree(ijk, depth)
        a, b = alone(payload, depth, len(ijk)), _helped_decode(payload, depth, len(ijk))
        assert a[0] == b[0] == "ok" and np.array_equal(a[1], b[1])
        for _ in range(12):
            bad = bytearray(payload)
            bad[int(rng.integers(len(bad) // 2, len(bad)))] ^= 1 << int(rng.integers(8))
            a, b = alone(bytes(bad), depth, len(ijk)), _helped_decode(bytes(bad), depth, len(ijk))
            assert a[0] == b[0] and (np.array_equal(a[1], b[1]) if a[0] == "ok" else a[1] == b[1])
        cut = payload[:len(payload) * 3 // 4]
        a, b = alone(cut, depth, len(ijk)), _helped_decode(cut, depth, len(ijk))
        assert a[0] == b[0] == "error" and a[1] == b[1]
    nat = native.module()
    h = nat.octree_helper()
    decode_octree_codes(payload, depth, len(ijk), h)
    nat.octree_help(h)                      # closed: returns at once
    with pytest.raises(ValueError, match="used already"):
        decode_octree_codes(payload, depth, len(ijk), h)


@needs_native
def test_hostile_declared_count_allocates_nothing_large():
    """A one-voxel payload declaring 10^8 voxels at depth 21: rejected after the traversal,
    which only ever holds the nodes actually decoded."""
    import resource
    payload = encode_octree(np.array([[5, 6, 7]]), 21)
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    with pytest.raises(GszFormatError, match="points"):
        decode_octree(payload, 21, 10 ** 8)
    grown_mb = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before) / 1024
    assert grown_mb < 200, grown_mb


# ------------------------------------------------------------------ rANS streams and tables
def _model_sets():
    rng = np.random.default_rng(9)
    out = []
    for seed, (n, m, scale) in enumerate([(20_000, 5, 2.0), (50_000, 40, 30.0), (5_000, 3, 900.0),
                                           (30_000, 2, 6000.0), (400, 7, 0.2)]):
        mids = rng.integers(0, m, n)
        sym = np.round(rng.laplace(0, scale * rng.uniform(0.2, 1.0, m)[mids])).astype(np.int64)
        sym[mids == 0] = 17                     # a SINGLE model
        out.append((sym, mids, m + 1))          # model m stays EMPTY
    return out


@needs_native
@pytest.mark.parametrize("case", range(5))
def test_rans_streams_and_tables_identical(case):
    sym, mids, m = _model_sets()[case]
    blob = encode_stream(sym, mids, m)
    (ka, a), (kb, b) = both(lambda: decode_stream(blob, mids))
    assert ka == kb == "ok" and np.array_equal(a, b) and np.array_equal(a, sym)
    models, _ = read_model_set(blob, 0)
    ref = models.build()
    lut, fc, val, lut_base, sym_base, mprec = models.native_tables(1 << 40)
    fc = np.frombuffer(fc, np.uint32).astype(np.int64)
    np.testing.assert_array_equal((fc & 0xFFFF) + 1, ref["freq"])
    np.testing.assert_array_equal(fc >> 16, ref["cum"])
    np.testing.assert_array_equal(np.frombuffer(val, np.int32), ref["value"])
    np.testing.assert_array_equal(np.frombuffer(lut_base, np.int64), ref["lut_base"])
    # every slot of the native LUT names the value the NumPy LUT names
    g = np.frombuffer(sym_base, np.int64)[np.repeat(np.arange(models.num_models), ref["total"])] \
        + np.frombuffer(lut, np.uint16)
    np.testing.assert_array_equal(g, models.slot_symbols())


@needs_native
def test_varint_arrays_identical():
    """The C varint reader gives NumPy's values, end position and error (truncated / too
    long) on random, partly terminated byte strings."""
    from gsz.decoder.rans import read_varints
    rng = np.random.default_rng(12)
    oks = 0
    for _ in range(4000):
        buf = rng.integers(0, 256, int(rng.integers(0, 40))).astype(np.uint8)
        if rng.random() < 0.5:
            buf[rng.random(buf.size) < 0.6] &= 0x7F
        pos, count = int(rng.integers(0, buf.size + 1)), int(rng.integers(0, 8))

        def run():
            v, p = read_varints(buf, pos, count, "test")
            return v.tolist(), p
        (ka, a), (kb, b) = both(run)
        assert ka == kb and (a == b if ka == "ok" else str(a) == str(b)), (a, b)
        oks += ka == "ok"
    assert 500 < oks < 3900


def _model_set_bodies(monkeypatch) -> list[bytes]:
    """Decompressed model-set bodies of every test vector and of the _model_sets streams."""
    import gsz.decoder.rans as R
    bodies, parse = [], R._parse_model_set_body

    def record(raw):
        bodies.append(bytes(raw))
        return parse(raw)
    monkeypatch.setattr(R, "_parse_model_set_body", record)
    old = native.set_enabled(False)
    try:
        for p in sorted(VEC.glob("*.gsz")):
            decode(p.read_bytes())
        for sym, mids, m in _model_sets():
            read_model_set(encode_stream(sym, mids, m), 0)
    finally:
        native.set_enabled(old)
    monkeypatch.setattr(R, "_parse_model_set_body", parse)
    return bodies


@needs_native
def test_model_set_parser_identical(monkeypatch):
    """The C model-set parser accepts exactly the bodies the NumPy parser accepts (real bodies
    and 6000 mutated ones: bit flips, byte changes, truncations, insertions) and gives the same
    parameter and COARSE arrays; on a reject read_model_set raises the NumPy parser's message."""
    import gsz.decoder.rans as R
    bodies = _model_set_bodies(monkeypatch)
    kinds = {int(t) for b in bodies for t in R._parse_model_set_body(b).types}
    assert kinds == {0, 1, 2, 3}                 # every model type is exercised
    rng = np.random.default_rng(5)
    accepted = rejected = 0
    for it in range(6000 + len(bodies)):
        raw = bytearray(bodies[it % len(bodies)])
        for _ in range(int(rng.integers(1, 3)) if it >= len(bodies) else 0):
            op, at = int(rng.integers(4)), int(rng.integers(max(1, len(raw))))
            if op == 0 and raw:
                raw[at] ^= 1 << int(rng.integers(8))
            elif op == 1 and raw:
                raw[at] = int(rng.integers(256))
            elif op == 2:
                del raw[at:]
            else:
                raw.insert(at, int(rng.integers(256)))
        raw = bytes(raw)
        got = native.module().model_set_parse(raw)
        try:
            ref = R._parse_model_set_body(raw)
        except GszFormatError:
            assert got is None, f"C parser accepted a body NumPy rejects (case {it})"
            rejected += 1
            continue
        assert got is not None, f"C parser rejected a valid body (case {it})"
        accepted += 1
        ms = R._model_set_from_native(got)
        for f in ("types", "lo", "span", "prec", "group", "binshift", "centre", "r_left", "r_right"):
            assert np.array_equal(getattr(ms, f), getattr(ref, f)), (it, f)
        for x, y in zip(ms.coarse_flat(), ref.coarse_flat()):
            assert np.array_equal(x, y), it
        assert [b.tolist() for b in ms.bins] == [b.tolist() for b in ref.bins]
    assert accepted > len(bodies) and rejected > 3000
    # a rejected body surfaces the NumPy parser's message through read_model_set
    bad = bytes([2]) + bytes([9, 9])             # 2 models of type 9
    assert native.module().model_set_parse(bad) is None
    with pytest.raises(GszFormatError, match="unknown model type"):
        read_model_set(bytes([len(bad) << 1]) + bad, 0)


@needs_native
def test_laplace_and_wide_models_identical():
    """LAPLACE models (float64 product chains), spans up to 65536 and every precision: the C
    normalisation (radix select of the remainders) equals the NumPy one."""
    from gsz.decoder.rans import ModelSet
    rng = np.random.default_rng(1)
    for _ in range(12):
        m = 6
        types = rng.choice([1, 2, 3], m)
        span = np.where(types == 1, 0, rng.integers(1, 3000, m))
        span[0] = 65535 if types[0] != 1 else 0
        prec = np.where(types == 1, 0, np.maximum(16, 0))
        bins, levels, binshift, group = [], [], np.zeros(m, np.int64), np.zeros(m, np.int64)
        centre = np.where(types == 3, rng.integers(0, span + 1), 0)
        rl = np.where(types == 3, rng.integers(0, 256, m), 0)
        rr = np.where(types == 3, rng.integers(0, 256, m), 0)
        for i in np.flatnonzero(types == 2):
            h = int(rng.integers(0, 6))
            binshift[i], group[i] = h, int(rng.integers(0, 4))
            nb = (int(span[i]) >> h) + 1
            keep = np.flatnonzero(rng.random(nb) < 0.6)
            b = np.unique(np.concatenate([[0, nb - 1], keep])).astype(np.int64)
            bins.append(b)
            levels.append(rng.integers(1, (25 << int(group[i])) + 1, b.size).astype(np.int64))
        ms = ModelSet(types=types.astype(np.int64), lo=rng.integers(-1000, 1000, m).astype(np.int64),
                      span=span.astype(np.int64), prec=prec.astype(np.int64), group=group,
                      centre=centre.astype(np.int64), r_left=rl.astype(np.int64),
                      r_right=rr.astype(np.int64), binshift=binshift, bins=tuple(bins),
                      levels=tuple(levels))
        ms.validate()
        ref = ms.build()
        _, fc, val, *_ = ms.native_tables(1 << 40)
        fc = np.frombuffer(fc, np.uint32).astype(np.int64)
        np.testing.assert_array_equal((fc & 0xFFFF) + 1, ref["freq"])
        np.testing.assert_array_equal(np.frombuffer(val, np.int32), ref["value"])


@needs_native
def test_rans_hostile_streams_same_outcome():
    sym, mids, m = _model_sets()[1]
    blob = encode_stream(sym, mids, m)
    rng = np.random.default_rng(5)
    for cut in sorted(set(np.linspace(0, len(blob) - 1, 40).astype(int))):
        res = both(lambda: decode_stream(blob[:cut], mids))
        assert res[0][0] == res[1][0] == "error"
    for _ in range(80):
        bad = bytearray(blob)
        bad[int(rng.integers(len(bad)))] ^= 1 << int(rng.integers(8))
        (ka, a), (kb, b) = both(lambda: decode_stream(bytes(bad), mids))
        assert ka == kb, (a, b)
        if ka == "ok":
            assert np.array_equal(a, b)
    bad_mids = mids.copy()
    bad_mids[7] = m + 5                          # a model id outside the set
    assert [k for k, _ in both(lambda: decode_stream(blob, bad_mids))] == ["error", "error"]
    empty_mids = mids.copy()
    empty_mids[3] = m - 1                        # the EMPTY model
    assert [k for k, _ in both(lambda: decode_stream(blob, empty_mids))] == ["error", "error"]


@needs_native
def test_channel_set_symbols_and_range_checks_in_every_loop():
    """A channel set decodes to the same values as symbols (dequantised later, the SH path) and
    dequantised (the attributes): and a symbol above its group's width is rejected by the loop
    without per-symbol word checks (a group far from the stream's end), by the checked loop
    (the last group) and by the NumPy path alike."""
    from gsz.decoder.bytesio import Reader
    from gsz.decoder.groups import read_channel_set, read_channel_set_symbols
    from gsz.encoder.groups import write_channel_set
    rng = np.random.default_rng(11)
    x = (rng.standard_normal((3, 20000)) * 0.1).astype(np.float32)
    data, _ = write_channel_set(x, 4, 8)
    sym, steps, lo = read_channel_set_symbols(Reader(data), max_length=20000)
    values = read_channel_set(Reader(data), max_length=20000)
    assert sym.dtype == np.uint16
    blocks = np.repeat(np.arange(8), 2500)
    np.testing.assert_array_equal(lo[:, blocks] + steps[:, blocks] * sym, values)
    for group in (8 + 0, 3 * 8 - 1):        # channel 1's first group; the last group
        bad = bytearray(data)
        bad[8 + group] = 2                  # width 4 -> 2: most of its symbols exceed 3
        res = both(lambda: read_channel_set(Reader(bytes(bad)), max_length=20000))
        assert [k for k, _ in res] == ["error", "error"]
        assert all("quantisation symbol" in str(e) for _, e in res)
        with pytest.raises(GszFormatError, match="quantisation symbol"):
            read_channel_set_symbols(Reader(bytes(bad)), max_length=20000)


@needs_native
def test_block_decoding_makes_each_models_lut_itself():
    """Channel sets decode with tables made without the set's LUT (the C loop makes one model's
    LUT when a block needs it, kept while the next blocks use the same model): the values are
    those of the whole-LUT tables, a per-symbol decode on the same decoder still works, and the
    per-symbol C loop refuses LUT-less tables instead of reading past them."""
    from gsz.decoder.rans import RansDecoder
    rng = np.random.default_rng(21)
    C, L, B, m = 3, 4001, 5, 7
    tab = rng.integers(0, m - 1, C * B).astype(np.int64)
    tab[1] = tab[0]                                  # consecutive blocks sharing a model
    block = np.sort(np.concatenate([np.arange(L % B), np.repeat(np.arange(B), L // B)]))
    mids = tab[(np.arange(C)[:, None] * B + block[None, :]).ravel()]
    sym = np.round(rng.laplace(0, 40 * rng.uniform(0.2, 1.0, m)[mids])).astype(np.int64)
    extra = rng.integers(0, m - 1, 300)              # a per-symbol tail after the blocks
    tail = np.round(rng.laplace(0, 5, extra.size)).astype(np.int64)
    blob = encode_stream(np.concatenate([sym, tail]), np.concatenate([mids, extra]), m)
    models, pos = read_model_set(blob, 0)
    dec = RansDecoder(memoryview(blob)[pos:], mids.size + extra.size, models, use_native=True)
    assert dec._nt[0] is None                        # made without the LUT
    out = np.empty(C * L, np.int64)
    dec.decode_blocks(tab, C, L, B, out)
    np.testing.assert_array_equal(out, sym)
    np.testing.assert_array_equal(dec.decode(extra), tail)
    dec.finish()
    assert models.native_tables(1 << 40)[0] is not None
    lutless = models.native_tables(1 << 40, lut=False)
    assert lutless[0] is not None                    # the whole-LUT tables serve blocks too
    models._ntables = None
    lutless = models.native_tables(1 << 40, lut=False)
    with pytest.raises(GszFormatError, match="LUT"):
        native.module().rans_decode(mids[:4].copy(), np.empty(4, np.int64),
                                    np.full(4, 1 << 16, np.int64), np.zeros(8, np.uint8), 0, 0,
                                    lutless)


@needs_native
@pytest.mark.parametrize("lanes", [2, 7, 8, 13, 64, 4096])
def test_block_loop_avx2_and_scalar_identical(lanes):
    """The AVX2 block loop (eight lanes at a time, words handed out in lane order) gives the
    scalar loop's values, dequantised values, lane states and word position -- with lane counts
    below 8, not a multiple of 8, or larger than the stream, precisions 1..16 and the blocks'
    ends falling anywhere -- and both flag a symbol above its group's width."""
    from gsz.decoder.rans import RansDecoder
    from gsz.encoder.rans import encode_symbols, fit_model_set
    mod = native.module()
    rng = np.random.default_rng(lanes)
    C, L, B = 4, 3001, 7
    m = C * B
    tab = np.arange(m, dtype=np.int64)
    block = np.sort(np.concatenate([np.arange(L % B), np.repeat(np.arange(B), L // B)]))
    mids = tab[(np.arange(C)[:, None] * B + block[None, :]).ravel()]
    scale = np.exp(rng.uniform(-2, 7, m))
    sym = np.abs(np.round(rng.laplace(0, scale[mids]))).astype(np.int64)
    sym[mids == 3] = 5                               # a one-value model (a single slot run)
    # models of 2, 3 (with gaps), 8 and 9 present values: up to 8 the AVX2 loop finds a value by
    # comparing cumulative frequencies in registers, beyond it by gathers from the LUT
    for g, values in ((6, [0, 1]), (9, [0, 3, 7]), (10, range(8)), (12, range(9))):
        sym[mids == g] = rng.choice(np.asarray(values), int(np.count_nonzero(mids == g)), p=None)
    models = fit_model_set(sym, mids, m)
    payload = encode_symbols(sym, mids, models, lanes=lanes)
    qmax = np.array([int(sym[mids == g].max()) for g in range(m)], np.int64)
    steps = rng.uniform(0.001, 0.1, m)
    lo = rng.uniform(-1, 1, m)
    results = []
    for simd in (False, True):
        old = mod.rans_simd(simd)
        try:
            outs = []
            for kind in ("sym16", "deq", "bad"):
                dec = RansDecoder(payload, sym.size, models, use_native=True)
                if kind == "sym16":
                    out = np.empty(C * L, np.uint16)
                    dec.decode_blocks(tab, C, L, B, out, qmax=qmax)
                elif kind == "deq":
                    out = np.empty(C * L, np.float64)
                    dec.decode_blocks(tab, C, L, B, out, steps=steps, lo=lo, qmax=qmax)
                else:
                    q = qmax.copy()
                    q[5] -= 1                        # one group's width too small
                    out = np.empty(C * L, np.uint16)
                    with pytest.raises(GszFormatError, match="quantisation symbol"):
                        dec.decode_blocks(tab, C, L, B, out, qmax=q)
                    continue
                dec.finish()
                outs.append((out, dec._states.copy(), dec._wpos))
            results.append(outs)
        finally:
            mod.rans_simd(old)
    (a16, ast, aw), (adq, _, _) = results[0]
    (b16, bst, bw), (bdq, _, _) = results[1]
    np.testing.assert_array_equal(a16, sym)
    np.testing.assert_array_equal(b16, a16)
    np.testing.assert_array_equal(bst, ast)
    assert aw == bw
    np.testing.assert_array_equal(adq, lo[mids] + steps[mids] * sym)
    assert adq.tobytes() == bdq.tobytes()


# ------------------------------------------------------------------ encoder: identical bytes
@needs_native
@pytest.mark.parametrize("case", range(5))
def test_rans_encoder_identical_bytes(case):
    from gsz.encoder.rans import _payload, encode_symbols, fit_model_set
    sym, mids, m = _model_sets()[case]
    models = fit_model_set(sym, mids, m)
    for lanes in (None, 1, 7, max(1, sym.size // 3)):
        (ka, a), (kb, b) = both(lambda: encode_symbols(sym, mids, models, lanes=lanes))
        assert ka == kb == "ok" and a == b, lanes
    # no symbols at all: only the lane header and start states
    z = np.zeros(0, np.int64)
    (ka, a), (kb, b) = both(lambda: _payload(z, z, z, None))
    assert ka == kb == "ok" and a == b
    # an out-of-range lane count is the same error on both paths
    for use_native in (True, False):
        with native.numpy_only() if not use_native else contextlib.nullcontext():
            with pytest.raises(ValueError, match="lane count"):
                encode_symbols(sym, mids, models, lanes=sym.size + 1)


@needs_native
def test_rans_encoder_takes_int32_or_int64_entries():
    """The channel-set writer hands the C encoder int32 symbol entries (half the memory): the
    same bytes as int64 ones, and other index types are refused with a clear error."""
    rng = np.random.default_rng(5)
    freq = np.array([3, 5, 8], np.int64)
    cum = np.array([0, 3, 8], np.int64)
    shift = np.full(3, 4, np.uint8)
    entry = rng.integers(0, 3, 5000)
    mod = native.module()
    a = mod.rans_encode(freq, cum, shift, 16, entry.astype(np.int64))
    assert a == mod.rans_encode(freq, cum, shift, 16, entry.astype(np.int32))
    with pytest.raises(TypeError, match="4- or 8-byte integer"):
        mod.rans_encode(freq, cum, shift, 16, entry.astype(np.int16))


@needs_native
@pytest.mark.parametrize("case", range(5))
def test_stream_encoders_identical_bytes(case):
    """encode_stream / encode_stream_pair (the C encoder reading each symbol's table entry
    itself) make the NumPy reference's bytes, both model layouts."""
    from gsz.encoder.rans import encode_stream, encode_stream_pair
    sym, mids, m = _model_sets()[case]
    (ka, a), (kb, b) = both(lambda: encode_stream(sym, mids, m))
    assert ka == kb == "ok" and a == b
    merge = np.arange(m) // 2
    (ka, a), (kb, b) = both(lambda: encode_stream_pair(sym, mids, m, merge, m // 2 + 1))
    assert ka == kb == "ok" and a == b
    assert a[0] == encode_stream(sym, mids, m) and a[1] == encode_stream(sym, merge[mids], m // 2 + 1)


@needs_native
def test_octree_encoder_identical_bits_models_and_payload():
    rng = np.random.default_rng(2)
    cases = [(_voxels(sample("sh0"), d), d) for d in (8, 11, 13)]
    cases += [(np.array([[3, 1, 2]]), 2), (np.array([[0, 0, 0]]), 1),
              (np.stack(np.meshgrid(*[np.arange(4)] * 3, indexing="ij"), -1).reshape(-1, 3), 2),
              (np.unique(rng.integers(0, 1 << 21, size=(500, 3)), axis=0), 21),
              (np.zeros((0, 3), np.int64), 4)]
    for ijk, depth in cases:
        (ka, a), (kb, b) = both(lambda: octree_symbols(ijk, depth)[:3])
        assert ka == kb == "ok"
        for x, y in zip(a, b):
            assert x.dtype == y.dtype and np.array_equal(x, y)
        (ka, pa), (kb, pb) = both(lambda: encode_octree(ijk, depth))
        assert pa == pb, depth
        for level in sorted({1, depth // 2, depth - 1} - {0}) if depth > 1 else ():   # scheme 1
            (ka, a), (kb, b) = both(lambda: octree_symbols(ijk, depth, level)[:4])
            assert ka == kb == "ok"
            for x, y in zip(a[:3], b[:3]):
                assert x.dtype == y.dtype and np.array_equal(x, y)
            assert a[3] == b[3], (depth, level)


@needs_native
def test_whole_file_encode_identical():
    from gsz.encoder.pipeline import EncodeOptions, encode
    from codec_util import FAST
    cloud = sample("sh3", 2500)
    (ka, a), (kb, b) = both(lambda: encode(cloud, EncodeOptions(**{**FAST, "bits": 9})).data)
    assert ka == kb == "ok" and a == b


@needs_native
def test_encoder_reconstruction_identical():
    """The encoder's own picture of the decoded attributes (what the size search measures and
    renders) comes from the C inverse RAHT when the accelerator is on: same bytes and the same
    float32 fields as the NumPy reference, every layer, several widths."""
    from gsz.encoder.pipeline import EncodeOptions, attribute_chunks, compute_train_importance, prepare_stage
    cloud = sample("sh0", 3000)
    imp = compute_train_importance(cloud, EncodeOptions(train_views=4, importance_width=64))
    stage = prepare_stage(cloud, imp, 0.8, layers=3, first_layer=0.1)
    for bits in (2, 9, 16):
        (ka, a), (kb, b) = both(lambda: attribute_chunks(stage, bits, 8))
        assert ka == kb == "ok" and a[0] == b[0]
        for f in ("opacities", "rotations", "sh_dc", "scales"):
            x, y = getattr(a[1], f), getattr(b[1], f)
            assert x.dtype == y.dtype == np.float32 and np.array_equal(x, y), (bits, f)


@pytest.mark.parametrize("use_native", [True, False])
def test_round_attributes_parsed_from_their_payloads_are_the_coded_ones(use_native):
    """A size-search round keeps only its ATTR payloads and parses them again when it is
    rendered (calibration.py): what that parse makes must be, bit for bit, the attributes the
    coding reconstructed -- tiles, importance layers and class-ordered scales included."""
    from gsz.encoder.pipeline import (EncodeOptions, attribute_chunks, compute_train_importance,
                                      payload_attributes, prepare_stage)
    if use_native and not native.native_available():
        pytest.skip("native accelerator not built")
    cloud = sample("sh3", 8000)
    imp = compute_train_importance(cloud, EncodeOptions(train_views=6, importance_width=160))
    stage = prepare_stage(cloud, imp, 0.8, layers=2, first_layer=0.4, tile_gaussians=2666)
    assert stage.num_tiles > 1 and any(l.scale_order is not None for l in stage.layers)
    old = native.set_enabled(use_native)
    try:
        for bits in (3, 11):
            payloads, coded, _ = attribute_chunks(stage, bits, 8)
            bare, none, _ = attribute_chunks(stage, bits, 8, decode=False)
            assert none is None and bare == payloads
            parsed = payload_attributes(stage, payloads)
            for f in ("opacities", "rotations", "sh_dc", "scales"):
                x, y = getattr(coded, f), getattr(parsed, f)
                assert x.dtype == y.dtype == np.float32 and np.array_equal(x, y), (bits, f)
    finally:
        native.set_enabled(old)


# ------------------------------------------------------------------ switches and fallbacks
def _run(code: str, env_extra: dict) -> str:
    env = {**os.environ, **env_extra}
    out = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True,
                         text=True, env=env, cwd=str(ROOT / "tests"))
    assert out.returncode == 0, out.stderr
    return out.stdout.strip()


def test_gsz_native_0_really_uses_numpy():
    vec = str(VEC / "sh1_jug_150.gsz")
    out = _run(f"""
        import sys
        import gsz.decoder as d
        c = d.decode({vec!r})
        print(d.decoder_path(), d.native_available(), 'gsz.decoder._native' in sys.modules, len(c))
    """, {"GSZ_NATIVE": "0"})
    assert out == "numpy False False 135", out


def test_package_works_without_the_extension():
    """As on a machine without a C compiler: importing gsz.decoder._native fails; the package
    imports, decodes a test vector to its documented hashes and reports the NumPy path."""
    vec = str(VEC / "sh3_jug_300.gsz")
    exp = str(VEC / "sh3_jug_300.json")
    out = _run(f"""
        import hashlib, json, sys
        import importlib.abc
        class Block(importlib.abc.MetaPathFinder):
            def find_spec(self, name, path=None, target=None):
                if name == 'gsz.decoder._native':
                    raise ImportError('blocked: no C compiler on this machine')
        sys.meta_path.insert(0, Block())
        import numpy as np
        import gsz.decoder as d
        c = d.decode({vec!r})
        e = json.load(open({exp!r}))
        ok = all(hashlib.sha256(np.ascontiguousarray(getattr(c, f), '<f4').tobytes()).hexdigest()
                 == v['sha256'] for f, v in e['fields'].items())
        print(d.decoder_path(), d.native_available(), ok, 'not built' in d.native.unavailable_reason())
    """, {"GSZ_NATIVE": "1"})
    assert out == "numpy False True True", out


@needs_native
def test_concurrent_decodes_are_independent():
    data = encoded("sh3", 3000, bits=8, layers=3).data
    ref = decode(data)
    results, errors = [], []

    def work():
        try:
            for _ in range(3):
                results.append(decode(data))
        except Exception as e:  # pragma: no cover - reported below
            errors.append(e)
    threads = [threading.Thread(target=work) for _ in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors and len(results) == 9
    for r in results:
        assert_same_cloud(r, ref)


def test_info_and_decode_cli_report_the_path(tmp_path):
    vec = str(VEC / "sh1_jug_150.gsz")
    from gsz.decoder.cli import decode_main, info_main
    import contextlib
    import io
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        assert info_main([vec, "--json"]) == 0
    assert json.loads(buf.getvalue())["decoder"]["path"] == native.active_path()
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        assert decode_main([vec, "-o", str(tmp_path / "o.ply"), "--json"]) == 0
    assert json.loads(buf.getvalue())["decoder"] == native.active_path()


@needs_native
def test_sh_assemble_reports_finiteness():
    """sh_assemble checks the values as it writes them (decode_layer then skips a pass over
    sh_rest): a used codeword or a kept vector that overflows float32 makes it False, an
    unused non-finite codeword does not."""
    sh_assemble = native.module().sh_assemble
    d = 3
    cb = np.array([[1.0, 1e300], [2.0, 0.5], [3.0, 0.25]])        # codeword 1 overflows float32
    kept = np.array([[1, 2], [3, 4], [5, 6]], np.uint16)           # 2 kept vectors, 1 block
    flags = np.array([1, 0, 1, 0], np.int64)

    def run(idx, lo=0.0):
        out = np.empty((4, d), np.float32)
        ok = sh_assemble(flags, kept, np.full((d, 1), 0.5), np.full((d, 1), lo), np.asarray(idx, np.int64), cb, out)
        assert ok == bool(np.isfinite(out).all())
        return ok

    assert run([0, 0]) is True
    assert run([0, 1]) is False                 # the non-finite codeword is used
    assert run([0, 0], lo=1e300) is False       # kept values overflow
    assert run([0, 0], lo=-1e39) is False
