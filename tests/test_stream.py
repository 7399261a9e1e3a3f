"""Importance-ordered layers and the streaming decoder: layers arrive in order and refine the
picture, any cut yields exactly the complete layers (documented signal, no exception), and the
streaming and single-shot decoders agree array for array."""
import io
import warnings

import numpy as np
import pytest

from gsz.decoder import (GszFormatError, GszTruncatedError, GszTruncatedWarning, StreamDecoder,
                         decode, inspect, iter_layers)
from gsz.decoder.container import LAYER_SHIFT, read_container, write_container
from codec_util import encoded, sample

FIELDS = ("positions", "scales", "rotations", "opacities", "sh_dc", "sh_rest")


def same(a, b):
    assert len(a) == len(b) and a.sh_degree == b.sh_degree
    for f in FIELDS:
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f), err_msg=f)


def prefix(cloud, n):
    return cloud.subset(np.arange(n))


@pytest.fixture(scope="module")
def sh3_layered():
    return encoded("sh3", 2500, bits=10, layers=3)


@pytest.fixture(scope="module")
def sh3_klt_layered():
    # the SH KLT (format 1.8): the matrix in layer 0's SHXF chunk, later layers use it
    return encoded("sh3", 2500, bits=10, layers=3, sh_colour="klt")


@pytest.fixture(scope="module")
def sh0_layered():
    return encoded("sh0", 4000, bits=10, layers=4, first_layer=0.15)


@pytest.fixture(scope="module")
def small_layered():
    # small enough for a decode at every one of many cut points
    return encoded("sh3", 300, bits=8, codebook=32, layers=3).data


def feed_in_pieces(data, size):
    dec = StreamDecoder()
    updates = []
    for s in range(0, len(data), size):
        updates += dec.feed(data[s:s + size])
    return dec, updates


@pytest.mark.parametrize("which", ["sh3_layered", "sh0_layered", "sh3_klt_layered"])
def test_layers_stream_in_order_and_match_single_shot(which, request):
    res = request.getfixturevalue(which)
    data = res.data
    full = decode(data)
    same(full, res.cloud)                       # the encoder's prediction is what decoders produce
    table = inspect(data)["layers"]
    n_layers = res.report.fixed.options["layers"]
    assert len(table) == n_layers
    for piece in (65536, 4096, 777):
        dec, ups = feed_in_pieces(data, piece)
        assert [u.layer for u in ups] == list(range(n_layers))
        assert [len(u.cloud) for u in ups] == [r["cumulative_gaussians"] for r in table]
        assert all(u.layers_total == n_layers for u in ups) and ups[-1].complete
        # a layer completes as soon as its bytes are in, not later
        assert all(u.bytes_received - r["decodable_at"] < piece for u, r in zip(ups, table))
        for u in ups:
            same(u.cloud, prefix(full, len(u.cloud)))
        same(ups[-1].cloud, full)
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            r = dec.finish()
        assert not r.truncated and r.layers_decoded == n_layers and r.bytes_received == len(data)


def test_layer_shares_grow_geometrically(sh0_layered):
    table = sh0_layered.report.layers
    counts = [r["gaussians"] for r in table]
    m = sum(counts)
    # cumulative shares 0.15 ** (3/3, 2/3, 1/3, 0): every layer multiplies the count by ~1.9
    for r, e in zip(table, (0.15, 0.15 ** (2 / 3), 0.15 ** (1 / 3), 1.0)):
        assert abs(r["cumulative_gaussians"] - e * m) <= 1
    ends = [r["decodable_at"] for r in table]
    assert all(b > a for a, b in zip(ends, ends[1:]))
    assert ends[0] < 0.3 * len(sh0_layered.data)


def test_psnr_rises_with_every_layer(sh3_layered):
    from gsz.evaluation.cameras import load_cameras
    from gsz.evaluation.evaluate import evaluate, render_views

    original = sample("sh3", 2500)
    cams = load_cameras(None, original, n_train=4, n_test=3, width=160).test
    refs = render_views(original, cams)
    psnr = [evaluate(refs, u.cloud, cams)["psnr"] for u in iter_layers(sh3_layered.data, chunk_size=65536)]
    assert len(psnr) == 3
    assert all(b > a + 0.5 for a, b in zip(psnr, psnr[1:])), psnr


def test_any_cut_yields_exactly_the_complete_layers(small_layered):
    data = small_layered
    full = decode(data)
    table = inspect(data)["layers"]
    ends = [r["decodable_at"] for r in table]
    cuts = set(range(0, 200)) | set(range(0, len(data), 97))
    for e in ends:
        cuts |= {e - 1, e, e + 1}
    cuts = sorted(c for c in cuts if 0 <= c < len(data))
    for cut in cuts:
        dec = StreamDecoder()
        for s in range(0, cut, 64):
            dec.feed(data[s:min(s + 64, cut)])
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            r = dec.finish()
        assert r.truncated, cut
        assert [w.category for w in caught] == [GszTruncatedWarning], cut
        k = sum(e <= cut for e in ends)
        assert r.layers_decoded == k, cut
        if k == 0:
            assert r.cloud is None
        else:
            same(r.cloud, prefix(full, table[k - 1]["cumulative_gaussians"]))


def test_truncated_whole_file_decode_is_an_error_unless_partial(sh3_layered, tmp_path):
    data = sh3_layered.data
    table = inspect(data)["layers"]
    cut = data[:table[1]["decodable_at"] + 10]
    with pytest.raises(GszTruncatedError, match="truncated"):
        decode(cut)
    with pytest.warns(GszTruncatedWarning, match="decoded 2 of 3 layers"):
        part = decode(cut, partial=True)
    same(part, prefix(decode(data), table[1]["cumulative_gaussians"]))
    with pytest.raises(GszTruncatedError, match="no complete layer"):
        decode(data[:100], partial=True)


def test_decode_first_k_layers(sh0_layered):
    data = sh0_layered.data
    full = decode(data)
    table = inspect(data)["layers"]
    for k in range(1, len(table) + 1):
        same(decode(data, layers=k), prefix(full, table[k - 1]["cumulative_gaussians"]))
    with pytest.raises(GszFormatError, match="asked for 9 layers, the file has 4"):
        decode(data, layers=9)


def test_iter_layers_over_paths_readers_and_piece_iterables(sh3_layered, tmp_path):
    data = sh3_layered.data
    path = tmp_path / "scene.gsz"
    path.write_bytes(data)
    expect = [r["cumulative_gaussians"] for r in inspect(data)["layers"]]
    for src in (str(path), path, io.BytesIO(data), [data[i:i + 5000] for i in range(0, len(data), 5000)]):
        assert [len(u.cloud) for u in iter_layers(src)] == expect
    assert [len(u.cloud) for u in iter_layers(data, max_layers=2)] == expect[:2]
    (tmp_path / "cut.gsz").write_bytes(data[:len(data) // 2])
    with pytest.warns(GszTruncatedWarning, match="cut.gsz"):
        got = list(iter_layers(tmp_path / "cut.gsz"))
    assert len(got) == sum(r["decodable_at"] <= len(data) // 2 for r in inspect(data)["layers"])
    from gsz.decoder import GszError
    with pytest.raises(GszError, match="missing.gsz: file not found"):
        list(iter_layers(tmp_path / "missing.gsz"))


def test_corruption_in_a_later_layer_raises_after_the_earlier_layers(sh3_layered):
    data = bytearray(sh3_layered.data)
    table = inspect(bytes(data))["layers"]
    data[table[1]["offset"] + 20] ^= 0x40
    dec = StreamDecoder()
    ups = dec.feed(bytes(data[:table[0]["decodable_at"]]))
    assert len(ups) == 1
    with pytest.raises(GszFormatError, match="checksum mismatch"):
        dec.feed(bytes(data[table[0]["decodable_at"]:]))
    with pytest.raises(GszFormatError, match="bad magic"):
        StreamDecoder().feed(b"PK\x03\x04 not a gsz file")
    with pytest.raises(GszFormatError, match="trailing"):
        StreamDecoder().feed(sh3_layered.data + b"\0")


def test_layer_order_is_validated(sh3_layered):
    c = read_container(sh3_layered.data)
    chunks = list(c.chunks)
    layer_of = [(ch.flags >> LAYER_SHIFT) & 0xFF for ch in chunks]
    # move layer 1's chunks behind layer 2's
    moved = [ch for ch, l in zip(chunks, layer_of) if l != 1] [:-1]
    moved += [ch for ch, l in zip(chunks, layer_of) if l == 1] + [chunks[-1]]
    bad = write_container(c.header, moved)
    with pytest.raises(GszFormatError, match="belongs to layer 2, but layer 1 has no chunks"):
        decode(bad)
    with pytest.raises(GszFormatError, match="belongs to layer 2, but layer 1 has no chunks"):
        StreamDecoder().feed(bad)
    # layer 0's SHVQ after layer 1's chunks: layer 0 would never be complete before layer 1
    shvq0 = next(ch for ch in chunks if ch.type == b"SHVQ" and ch.flags >> LAYER_SHIFT == 0)
    late = [ch for ch in chunks if ch is not shvq0]
    late.insert(5, shvq0)
    with pytest.raises(GszFormatError, match=r"\(SHVQ\) of layer 0 follows a chunk of layer 1"):
        decode(write_container(c.header, late))
    # a missing ATTR in layer 2
    missing = [ch for ch, l in zip(chunks, layer_of) if not (l == 2 and ch.type == b"ATTR")]
    with pytest.raises(GszFormatError, match="missing required chunk ATTR for layer 2"):
        decode(write_container(c.header, missing))


def test_single_layer_files_stream_as_one_layer():
    data = encoded("sh0", 1500, bits=8).data
    dec, ups = feed_in_pieces(data, 1000)
    assert len(ups) == 1 and ups[0].complete
    same(ups[0].cloud, decode(data))


def test_layered_encode_is_deterministic(sh0_layered):
    from gsz.encoder.pipeline import EncodeOptions, encode
    from codec_util import FAST
    again = encode(sample("sh0", 4000), EncodeOptions(**{**FAST, "bits": 10, "layers": 4, "first_layer": 0.15}))
    assert again.data == sh0_layered.data


def test_layered_file_costs_little_more_than_single_layer():
    one = len(encoded("sh0", 4000, bits=10).data)
    three = len(encoded("sh0", 4000, bits=10, layers=3).data)
    assert one < three < 1.10 * one


def test_size_search_over_all_layers_hits_the_budget():
    from gsz.encoder.search import SearchOptions, encode_to_budget
    cloud = sample("sh3", 3000)
    target = 60_000
    r = encode_to_budget(cloud, target, options=SearchOptions(
        layers=3, train_views=4, importance_width=120, eval_views=2, eval_width=120, codebook=64,
        vq_iters=10, max_candidates=1, refine_steps=0))
    assert target * 0.995 <= len(r.data) <= target
    assert len(r.report.layers) == 3
    assert sum(r.report.search.layer_blocks) == len(r.report.bits["raht"][0])
    same(decode(r.data), r.cloud)


def test_codebook_travels_with_the_first_layer_that_needs_it():
    """The layered test vector keeps every exact SH vector of layer 0, so the codebook is in
    layer 1; a second codebook or indices before any codebook are rejected."""
    import struct
    from pathlib import Path
    from gsz.decoder.sh import read_sh
    data = (Path(__file__).resolve().parent.parent / "format_spec" / "vectors" / "sh2_jug_400_layers3.gsz").read_bytes()
    c = read_container(data)
    sh = {ch.layer: ch.data for ch in c.chunks if ch.type == b"SHVQ"}
    heads = {l: struct.unpack_from("<IIH", d, 0) for l, d in sh.items()}
    m = [r["gaussians"] for r in inspect(data)["layers"]]
    assert heads[0][0] == 0 and heads[0][1] == m[0]          # layer 0: all kept, no codebook
    assert heads[1][0] > 0 and heads[2][0] == 0
    _, none = read_sh(sh[0], m[0], 2)
    assert none is None
    _, cb = read_sh(sh[1], m[1], 2)
    with pytest.raises(GszFormatError, match="second SH codebook"):
        read_sh(sh[1], m[1], 2, cb)
    with pytest.raises(GszFormatError, match="no SH codebook"):
        read_sh(sh[2], m[2], 2, None)
    read_sh(sh[2], m[2], 2, cb)


def test_search_resplits_layers_when_layer_zero_arrives_too_late():
    """When layer 0 ends after more than 1.5x the wanted share of the bytes (on SH scenes kept
    exact SH vectors make it dear), the chosen configuration is re-split with a smaller layer 0.
    (SH-0 sample with a deliberately small wanted share, so the SH codebook, which always
    travels early, does not bound what a re-split can reach.)"""
    from gsz.encoder.search import SearchOptions, encode_to_budget
    cloud = sample("sh0", 4000)
    target = 40_000
    r = encode_to_budget(cloud, target, options=SearchOptions(
        layers=3, layer0_share=0.04, train_views=4, importance_width=120, eval_views=2, eval_width=120,
        codebook=64, vq_iters=10, max_candidates=1, refine_steps=0, max_extra_depth=0))
    cands = r.report.search.candidates
    late = [c for c in cands if c["layer0_too_late"]]
    assert late and late[0]["first_layer"] == 0.1
    assert r.report.search.first_layer < 0.1
    assert target * 0.995 <= len(r.data) <= target
    share = r.report.layers[0]["decodable_fraction"]
    assert share < 0.07
    same(decode(r.data), r.cloud)
