"""The default Gaussians-per-byte limit and max_gaussians (issue 19 item 3, GSZ.md §11) on every
entry point: decode, StreamDecoder, inspect, gsz-decode, gsz-info, gsz-view."""
import importlib.util
import warnings
from pathlib import Path

import numpy as np
import pytest

from gsz.decoder import GszError, GszFormatError, GszLimitError, StreamDecoder, decode, inspect
from gsz.decoder.container import Chunk, read_container, write_container
from gsz.decoder.layer import GAUSSIANS_PER_BYTE

BOMBS = Path(__file__).parent / "data" / "bombs"


def _builders():
    spec = importlib.util.spec_from_file_location("make_bombs", BOMBS / "make_bombs.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def dense():
    """A valid file of a full depth-5 octree (32,768 Gaussians) with constant attributes:
    ~60 Gaussians per byte, over the default limit."""
    b = _builders()
    d, m = 5, 8 ** 5
    return b.gsz(m, b.geom_chunk(d, m, b.full_octree(d)), b.attr_chunk(m, valid=True))


@pytest.fixture(scope="module")
def padded(dense):
    """``dense`` with a 1 MiB optional chunk after it: the file's length allows its count, its
    one part's bytes do not (the per-part limit of GSZ.md §11)."""
    c = read_container(dense)
    chunks = [Chunk(ch.type, bytes(ch.data), ch.flags) for ch in c.chunks] + [Chunk(b"PADD", bytes(1 << 20), 0)]
    return write_container(c.header, chunks)


@pytest.mark.usefixtures("each_decoder_path")
def test_default_limit_is_per_byte_of_file_and_of_each_part(dense, padded):
    assert len(dense) * GAUSSIANS_PER_BYTE < 8 ** 5 < len(padded) * GAUSSIANS_PER_BYTE
    with pytest.raises(GszLimitError, match=r"declares 32,768 Gaussians in a \d+-byte file"):
        decode(dense)
    with pytest.raises(GszLimitError, match=r"^layer 0: 32,768 Gaussians in \d+ bytes of chunks"):
        decode(padded)
    for data in (dense, padded):
        for mg in (8 ** 5, 1 << 28):
            cloud = decode(data, max_gaussians=mg)
            assert len(cloud) == 8 ** 5 and np.all(cloud.scales == 0)
        with pytest.raises(GszLimitError, match="above the decoder limit 32,767"):
            decode(data, max_gaussians=8 ** 5 - 1)


@pytest.mark.usefixtures("each_decoder_path")
def test_streaming_reader_checks_before_decoding_any_part(dense, padded):
    dec = StreamDecoder(source="net.gsz")
    with pytest.raises(GszLimitError, match=r"^net.gsz: declares 32,768 Gaussians"):
        dec.feed(dense[:200])                 # the chunk table alone is enough
    # a table that declares a long file passes the file-level check; the part itself is refused
    # when its chunks are in, whatever the rest of the stream would have been
    dec = StreamDecoder(source="net.gsz")
    part_end = max(ch.offset + len(ch.data) for ch in read_container(padded).chunks if ch.type != b"PADD")
    with pytest.raises(GszLimitError, match=r"^net.gsz: layer 0: 32,768 Gaussians"):
        dec.feed(padded[:part_end])
    dec = StreamDecoder(max_gaussians=8 ** 5)
    assert [len(u.part) for u in dec.feed(padded)] == [8 ** 5] and not dec.finish().truncated
    with pytest.raises(GszLimitError):
        decode(padded[:part_end + 10], partial=True)


def test_bad_max_gaussians_values_are_a_clear_error(dense):
    for bad in (0, -5, 2.5, "many", True):
        with pytest.raises(GszError, match="max_gaussians must be a positive integer"):
            decode(dense, max_gaussians=bad)
    with pytest.raises(GszError, match="max_gaussians must be a positive integer"):
        StreamDecoder(max_gaussians=0)


def test_real_files_are_far_below_the_limit():
    # GSZ.md §11: the densest real files hold ~0.4 Gaussians per byte; the vectors ~0.01-0.24
    vectors = sorted((Path(__file__).parents[1] / "format_spec" / "vectors").glob("*.gsz"))
    for p in vectors:
        info = inspect(p)
        assert info["limit"]["exceeded"] is None
        assert info["num_gaussians"] * 4 < info["bytes"] * GAUSSIANS_PER_BYTE / 32, p.name
        for t in info["tiles"]:
            for part in t["parts"]:
                assert part["gaussians"] < part["bytes"], p.name


def test_inspect_reports_what_decode_would_decide(dense, padded):
    info = inspect(dense)
    assert info["num_gaussians"] == 8 ** 5 and "per byte" in info["limit"]["exceeded"]
    assert info["limit"]["max_gaussians"] == GAUSSIANS_PER_BYTE * len(dense)
    assert "layer 0: 32,768 Gaussians" in inspect(padded)["limit"]["exceeded"]
    ok = inspect(dense, max_gaussians=8 ** 5)["limit"]
    assert ok == {"max_gaussians": 8 ** 5, "per_byte": None, "exceeded": None}


def test_gsz_decode_and_gsz_info_take_max_gaussians(dense, tmp_path, capsys):
    from gsz.decoder.cli import decode_main, info_main
    src = tmp_path / "dense.gsz"
    src.write_bytes(dense)
    out = tmp_path / "dense.ply"
    assert decode_main([str(src), "-o", str(out)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(src) in err and "--max-gaussians" in err and "Traceback" not in err
    assert not out.exists()
    assert decode_main([str(src), "-o", str(out), "--max-gaussians", str(8 ** 5)]) == 0
    import gsz
    assert len(gsz.read_ply(out)) == 8 ** 5
    capsys.readouterr()
    assert info_main([str(src)]) == 0
    got = capsys.readouterr()
    assert "limit" in got.out and "gsz-decode would reject this file" in got.err and str(src) in got.err
    assert info_main([str(src), "--max-gaussians", "40000"]) == 0
    got = capsys.readouterr()
    assert "40,000 Gaussians (--max-gaussians)" in got.out and got.err == ""
    assert decode_main([str(src), "-o", str(out), "--max-gaussians", "-1", "-w"]) == 2     # usage
    assert "--max-gaussians must be a positive integer" in capsys.readouterr().err


def test_gsz_view_takes_max_gaussians(dense, tmp_path, capsys):
    pytest.importorskip("gsz.viewer.app")
    from gsz.viewer.cli import _load_scenes, build_parser, main
    src = tmp_path / "dense.gsz"
    src.write_bytes(dense)
    assert main([str(src), "--screenshot", str(tmp_path / "x.png")]) == 1
    err = capsys.readouterr().err
    assert err.startswith("gsz-view: error: ") and "per byte" in err and err.count("\n") == 1
    a, b, jobs = _load_scenes(build_parser().parse_args([str(src), "--max-gaussians", str(8 ** 5)]))
    assert len(a.cloud) == 8 ** 5 and a.max_gaussians == 8 ** 5 and b is None
