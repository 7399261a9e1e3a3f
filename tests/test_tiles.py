"""Spatial tiles (format 1.2): encoding, decoding a tile or a region alone, streaming, rejects."""
import warnings
from pathlib import Path

import numpy as np
import pytest

from gsz.decoder import GszError, GszFormatError, StreamDecoder, decode, inspect
from gsz.decoder.container import (CHUNK_REQUIRED, LAYER_SHIFT, TILE_SHIFT, Chunk, read_container,
                                   write_container)
from gsz.decoder.layout import CHUNK_TILE
from gsz.decoder.tiles import TileInfo, pack_tile_table

from codec_util import FAST, lowest_version, sample

FIELDS = ("positions", "scales", "rotations", "opacities", "sh_dc", "sh_rest")

VEC = Path(__file__).resolve().parent.parent / "format_spec" / "vectors" / "sh1_jug_12k_tiles.gsz"


@pytest.fixture(scope="module")
def tiled():
    """(cloud, EncodeResult) of the 12k jug sample in tiles of at most 4096 voxels, 2 layers."""
    from gsz.encoder.pipeline import EncodeOptions, encode
    cloud = sample("sh3")
    return cloud, encode(cloud, EncodeOptions(**{**FAST, "layers": 2, "tile_gaussians": 4096}))


def _part_rows(info):
    """Row ranges of every (layer, tile) part in the full decode."""
    parts = sorted((p["layer"], r["tile"], p["gaussians"]) for r in info["tiles"] for p in r["parts"])
    rows, start = {}, 0
    for layer, tile, n in parts:
        rows[(layer, tile)] = np.arange(start, start + n)
        start += n
    return rows


def test_tiled_encode_decodes_to_what_the_encoder_predicted(tiled, monkeypatch):
    _, res = tiled
    info = inspect(res.data)
    assert info["version"] == lowest_version(res.data) >= "1.2" and len(info["tiles"]) >= 3
    assert all(r["gaussians"] <= 4096 for r in info["tiles"])
    assert sum(r["gaussians"] for r in info["tiles"]) == info["num_gaussians"] == len(res.cloud)
    assert all(len(r["parts"]) == 2 for r in info["tiles"])
    for native in ("1", "0"):
        monkeypatch.setenv("GSZ_NATIVE", native)
        assert decode(res.data).equals(res.cloud)


@pytest.mark.parametrize("native", ["1", "0"])
@pytest.mark.parametrize("overlap", [False, True])
def test_parts_decode_in_place_into_the_whole_cloud(tiled, monkeypatch, native, overlap):
    """Every field of every (layer, tile) part is written into its rows of the whole cloud: no
    concatenation afterwards and no part decoded into fresh memory and copied (both paths,
    with and without each tile's geometry/attribute overlap); the same cloud."""
    import sys
    from gsz.decoder import cloud as cloud_module
    D, L = sys.modules["gsz.decoder.decode"], sys.modules["gsz.decoder.layer"]
    _, res = tiled
    monkeypatch.setenv("GSZ_NATIVE", native)
    if overlap:                       # as on a machine with a core per tile
        monkeypatch.setattr(D, "cores", lambda: 8)
        monkeypatch.setattr(L, "cores", lambda: 8)
    monkeypatch.setattr(L, "OVERLAP_MIN_POINTS", 1 if overlap else 1 << 40)
    monkeypatch.setattr(D, "concat_clouds", lambda *a, **k: pytest.fail("parts concatenated"))
    copied, holds = [], cloud_module.OutputRows.holds
    monkeypatch.setattr(cloud_module.OutputRows, "holds",
                        lambda self, name, a: holds(self, name, a) or copied.append(name))
    assert decode(res.data).equals(res.cloud)
    assert copied == []


def test_tile_bounding_boxes_hold_their_gaussians(tiled):
    _, res = tiled
    info = inspect(res.data)
    full = decode(res.data)
    rows = _part_rows(info)
    for r in info["tiles"]:
        sel = np.concatenate([rows[(p["layer"], r["tile"])] for p in r["parts"]])
        p = full.positions[sel]
        np.testing.assert_array_equal(p.min(0), np.float32(r["bbox_min"]))
        np.testing.assert_array_equal(p.max(0), np.float32(r["bbox_max"]))


def test_one_tile_decodes_alone_to_its_rows_of_the_full_decode():
    info = inspect(VEC)
    full = decode(VEC)
    rows = _part_rows(info)
    for t in (0, len(info["tiles"]) - 1):
        sel = np.concatenate([rows[(p["layer"], t)] for p in info["tiles"][t]["parts"]])
        for src in (VEC, VEC.read_bytes()):
            assert decode(src, tiles=[t]).equals(full.subset(sel))
    # first layer of two tiles: their layer-0 parts, tile order
    sel = np.concatenate([rows[(0, 0)], rows[(0, 1)]])
    assert decode(VEC, tiles=[1, 0], layers=1).equals(full.subset(sel))


def test_a_tile_decodes_from_a_file_whose_other_tiles_are_corrupt(tmp_path):
    """From a path, decode(tiles=...) reads and checks only the chosen tile's chunks."""
    data = bytearray(VEC.read_bytes())
    c = read_container(bytes(data))
    victim = next(ch for ch in c.chunks if ch.type == b"ATTR" and ch.tile == 1)
    data[victim.offset + 10] ^= 0xFF
    bad = tmp_path / "bad.gsz"
    bad.write_bytes(bytes(data))
    assert decode(bad, tiles=[0]).equals(decode(VEC, tiles=[0]))
    with pytest.raises(GszFormatError, match="checksum"):
        decode(bad, tiles=[1])
    with pytest.raises(GszFormatError, match="checksum"):
        decode(bad)


def test_region_decode_returns_exactly_the_gaussians_inside():
    full = decode(VEC)
    lo, hi = (-0.05, -0.02, -0.05), (0.02, 0.05, 0.05)
    inside = np.all((full.positions >= np.float32(lo)) & (full.positions <= np.float32(hi)), axis=1)
    got = decode(VEC, region=(lo, hi))
    assert 0 < len(got) < len(full)
    assert got.equals(full.subset(np.flatnonzero(inside)))
    assert len(decode(VEC, region=((5, 5, 5), (6, 6, 6)))) == 0


def test_bad_tile_requests_are_clear_errors():
    with pytest.raises(GszError, match="tile 99 does not exist"):
        decode(VEC, tiles=[99])
    with pytest.raises(GszError, match="region must be"):
        decode(VEC, region=((1, 1, 1), (0, 0, 0)))


def test_stream_reports_each_tile_and_layer_zero_of_every_tile_first():
    data = VEC.read_bytes()
    info = inspect(data)
    dec = StreamDecoder()
    ups = []
    for s in range(0, len(data), 4096):
        ups += dec.feed(data[s:s + 4096])
    t = len(info["tiles"])
    assert [(u.layer, u.tile) for u in ups] == [(l, i) for l in range(2) for i in range(t)]
    assert [u.layer_complete for u in ups] == [i == t - 1 for l in range(2) for i in range(t)]
    assert ups[-1].complete and dec.finish().truncated is False
    assert ups[-1].cloud.equals(decode(data))
    assert sum(len(u.part) for u in ups) == info["num_gaussians"]
    # cut inside layer 0: the parts that arrived, flagged truncated
    cut = info["tiles"][1]["parts"][0]["decodable_at"]
    dec = StreamDecoder()
    got = dec.feed(data[:cut])
    assert [(u.layer, u.tile) for u in got] == [(0, 0), (0, 1)]
    with warnings.catch_warnings(record=True):
        warnings.simplefilter("always")
        res = dec.finish()
    assert res.truncated and len(res.cloud) == sum(len(u.part) for u in got)


def _tiny_tiled(tile_rows=None, tile_first=True, flags_tile=1, counts=None):
    """A two-tile file built from two one-tile files' chunks (hand-made structure variants)."""
    data = VEC.read_bytes()
    c = read_container(data)
    geo = [ch for ch in c.chunks if ch.type in (b"GEOM", b"ATTR", b"SHVQ") and ch.layer == 0 and ch.tile < 2]
    info = inspect(data)
    m = [p["gaussians"] for r in info["tiles"][:2] for p in r["parts"] if p["layer"] == 0]
    rows = tile_rows or [TileInfo((0, 0, 0), (1, 1, 1), counts[i] if counts else m[i]) for i in range(2)]
    tile = Chunk(CHUNK_TILE, pack_tile_table(rows), CHUNK_REQUIRED)
    data_chunks = [Chunk(ch.type, bytes(ch.data), CHUNK_REQUIRED | (min(ch.tile, flags_tile) << TILE_SHIFT))
                   for ch in geo]
    chunks = [tile] + data_chunks if tile_first else data_chunks[:3] + [tile] + data_chunks[3:]
    h = c.header
    h.num_gaussians = sum(m)
    return write_container(h, chunks)


def test_hand_made_two_tile_file_decodes():
    data = _tiny_tiled()
    cloud = decode(data)
    assert len(cloud) == len(decode(data, tiles=[0])) + len(decode(data, tiles=[1]))


@pytest.mark.parametrize("kwargs, message", [
    (dict(tile_first=False), "follows a data chunk"),
    (dict(flags_tile=0), "has two GEOM chunks"),
    (dict(counts=[1, 10**6]), "tiles hold"),
])
def test_tile_structure_rejects(kwargs, message):
    data = _tiny_tiled(**kwargs)
    with pytest.raises(GszFormatError, match=message):
        decode(data)
    with pytest.raises(GszFormatError, match=message):
        StreamDecoder().feed(data)


def test_tile_bits_without_a_tile_chunk_are_rejected():
    data = VEC.read_bytes()
    c = read_container(data)
    chunks = [Chunk(ch.type, bytes(ch.data), ch.flags) for ch in c.chunks if ch.type != CHUNK_TILE]
    c.header.version = (1, 2)
    with pytest.raises(GszFormatError, match="no TILE chunk"):
        decode(write_container(c.header, chunks))


def test_untiled_files_have_no_tile_chunk_nor_its_version():
    from gsz.encoder.pipeline import EncodeOptions, encode
    res = encode(sample("sh0", 3000), EncodeOptions(**FAST))
    info = inspect(res.data)
    assert info["version"] == lowest_version(res.data) != "1.2" and len(info["tiles"]) == 1
    assert all(ch["type"] != "TILE" and ch["tile"] == 0 for ch in info["chunks"])


def test_layer_flag_bits_are_separate_from_tile_bits():
    assert LAYER_SHIFT + 8 == TILE_SHIFT


def test_fields_of_a_subset_keep_dtypes():
    got = decode(VEC, tiles=[0])
    for f in FIELDS:
        assert getattr(got, f).dtype == np.float32


def test_size_search_holds_one_budget_across_tiles():
    """One bit allocation over every tile's groups: the whole file meets the target."""
    from gsz.encoder.search import SearchOptions, encode_to_budget
    target = 150_000
    res = encode_to_budget(sample("sh3"), target, options=SearchOptions(
        tile_gaussians=4096, train_views=6, eval_views=2, eval_width=160, importance_width=160))
    info = inspect(res.data)
    # tiles make a 1.2 file; SH importance classes (SHCL chunks), which the search may choose,
    # 1.3; a direct-coded octree 1.4; RAHT leaf weights (RWGT chunks) 1.5
    assert len(info["tiles"]) >= 3 and info["version"] == lowest_version(res.data) >= "1.2"
    assert 0.99 * target <= len(res.data) <= target
    assert decode(res.data).equals(res.cloud)


def test_viewer_stream_playback_shows_tiles_as_they_decode():
    from gsz.viewer.streaming import StreamPlayback
    data = VEC.read_bytes()
    info = inspect(data)
    play = StreamPlayback(data, None, piece=8192)
    assert play.wait(timeout=60)
    snap = play.snapshot()
    assert snap["error"] is None and snap["layers"] == 2 and snap["tiles_total"] == len(info["tiles"])
    assert snap["tiles"] == sum(len(r["parts"]) for r in info["tiles"])
    assert snap["layer_bytes"] == [r["decodable_at"] if r["decodable_at"] % 8192 == 0 else
                                   min(len(data), (r["decodable_at"] // 8192 + 1) * 8192) for r in info["layers"]]
    assert snap["cloud"].equals(decode(data))


def test_cli_lists_tiles_and_decodes_a_region(tmp_path, capsys):
    import json

    from gsz.decoder.cli import decode_main, info_main
    from gsz.decoder.ply import read_ply
    assert info_main([str(VEC), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert [t["tile"] for t in info["tiles"]] == list(range(len(info["tiles"])))
    assert info_main([str(VEC)]) == 0
    text = capsys.readouterr().out
    assert "bounding box" in text and text.count("\n") > len(info["tiles"])
    out = tmp_path / "r.ply"
    assert decode_main([str(VEC), "-o", str(out), "--region", "-0.05", "-0.02", "-0.05", "0.02", "0.05", "0.05"]) == 0
    assert read_ply(out).equals(decode(VEC, region=((-0.05, -0.02, -0.05), (0.02, 0.05, 0.05))))
    assert decode_main([str(VEC), "-o", str(out), "--tiles", "1", "-w"]) == 0
    assert len(read_ply(out)) == info["tiles"][1]["gaussians"]
    assert decode_main([str(VEC), "-o", str(out), "--tiles", "x"]) == 2
    assert "--tiles must be" in capsys.readouterr().err
