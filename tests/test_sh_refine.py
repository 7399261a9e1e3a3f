"""Kept SH vectors as residuals of a codeword each (SHRF, format 1.9): both decoder paths add
the codeword back bit for bit as the encoder reconstructed it, in the colour space the vectors
are stored in; a refined vector is finer than the same vector kept at the same width; and a
file without its codebook, or with a bad index, is rejected with the chunk named."""
import dataclasses

import numpy as np
import pytest

from gsz.decoder import decode, native
from gsz.decoder.container import read_container
from gsz.decoder.errors import GszFormatError
from gsz.decoder.layout import CHUNK_SHRF, CHUNK_SHVQ
from gsz.encoder.pipeline import EncodeOptions, encode

from codec_util import FAST, decoded_on_both_paths, lowest_version, render_psnr, sample, sh3_off_grid


def _rmse(a, b) -> float:
    return float(np.sqrt(((np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2).mean()))


@pytest.mark.parametrize("colour", ["rgb", "luma-chroma", "klt"])
@pytest.mark.parametrize("classes", [1, 2])
def test_refined_file_decodes_bit_for_bit_on_both_paths(colour, classes):
    cloud = sh3_off_grid(3000)
    res = encode(cloud, EncodeOptions(**{**FAST, "codebook": 64}, reserve=1.0, bits=8, keep=1800,
                                      sh_refine=True, sh_classes=classes, sh_colour=colour, layers=2,
                                      first_layer=0.3))
    assert lowest_version(res.data) == "1.9" and res.data[8:12] == bytes([1, 0, 9, 0])
    types = [ch.type for ch in read_container(res.data).chunks]
    assert CHUNK_SHRF in types and types.index(CHUNK_SHRF) < types.index(CHUNK_SHVQ)
    # with classes the kept vectors are stored class by class, and SHRF names them in that order
    assert types.count(b"SHCL") == (2 if classes > 1 else 0)
    decoded_on_both_paths(res)


def test_refinement_is_finer_than_the_kept_vector_at_the_same_width():
    # the residual spans a fraction of the vector's range, so the same width quantises it finer:
    # what lets the size search spend fewer bits for the same SH error
    cloud = sh3_off_grid(3000)
    common = dict(**{**FAST, "codebook": 64}, reserve=1.0, bits=6, keep=3000, blocks=16)
    plain = encode(cloud, EncodeOptions(**common))
    refined = encode(cloud, EncodeOptions(**common, sh_refine=True))
    assert np.array_equal(plain.cloud.positions, refined.cloud.positions)
    src = cloud.sh_rest[_nearest(cloud.positions, plain.cloud.positions)]
    e_plain, e_ref = _rmse(plain.cloud.sh_rest, src), _rmse(refined.cloud.sh_rest, src)
    assert e_ref < 0.95 * e_plain, (e_ref, e_plain)        # measured 0.86x


def _nearest(points: np.ndarray, queries: np.ndarray) -> np.ndarray:
    """Index of the point nearest each query (the input Gaussian of each voxel centre)."""
    p = points.astype(np.float64)
    out = np.empty(len(queries), np.int64)
    for s in range(0, len(queries), 512):
        q = queries[s:s + 512].astype(np.float64)
        out[s:s + 512] = (((q[:, None, :] - p[None]) ** 2).sum(-1)).argmin(1)
    return out


def test_tiled_refined_file_and_its_stream():
    from gsz.decoder.stream import StreamDecoder
    cloud = sh3_off_grid(9000)
    res = encode(cloud, EncodeOptions(**FAST, reserve=1.0, bits=8, keep=5000, sh_refine=True,
                                      sh_classes=4, sh_colour="klt", layers=2, tile_gaussians=4096))
    ref = decoded_on_both_paths(res)
    sd = StreamDecoder()
    for s in range(0, len(res.data), 5000):
        sd.feed(res.data[s:s + 5000])
    assert sd.finish().cloud.equals(ref)


def _with_refine_payload(data: bytes, payload: bytes) -> bytes:
    """``data`` (one layer) with its SHRF chunk's payload replaced (CRCs recomputed)."""
    from gsz.decoder.container import write_container
    c = read_container(data)
    chunks = [dataclasses.replace(ch, data=payload) if ch.type == CHUNK_SHRF else ch for ch in c.chunks]
    return write_container(c.header, chunks)


def test_bad_refinement_indices_are_rejected_naming_the_chunk(tmp_path):
    from gsz.encoder.rans import encode_stream
    from gsz.decoder.bytesio import Writer
    res = encode(sample("sh3", 2000), EncodeOptions(**{**FAST, "codebook": 16}, reserve=1.0, bits=8,
                                                    keep=500, sh_refine=True))
    c = read_container(res.data)
    p = int(np.frombuffer(c.chunks[[ch.type for ch in c.chunks].index(CHUNK_SHVQ)].data[4:8], "<u4")[0])
    k = int(np.frombuffer(c.chunks[[ch.type for ch in c.chunks].index(CHUNK_SHVQ)].data[0:4], "<u4")[0])
    idx = np.zeros(p, np.int64)
    idx[p // 2] = k                                 # one past the codebook
    bad = _with_refine_payload(res.data, Writer().blob(encode_stream(idx, np.zeros(p, np.int64), 1)).getvalue())
    path = tmp_path / "bad.gsz"
    path.write_bytes(bad)
    for numpy_only in (False, True):
        with (native.numpy_only() if numpy_only else _nothing()):
            with pytest.raises(GszFormatError, match="SHRF chunk: codeword index out of range") as e:
                decode(str(path))
            assert "bad.gsz" in str(e.value)


class _nothing:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


def test_native_assembly_checks_the_refinement_indices():
    if not native.enabled():
        pytest.skip("native accelerator not built")
    d, m = 9, 4
    flags = np.ones(m, np.int64)
    kept = np.zeros((d, m), np.uint16)
    args = (flags, kept, np.ones((d, 1)), np.zeros((d, 1)), np.zeros(0, np.int64), np.ones((d, 2)),
            np.empty((m, d), np.float32), None, 0, None)
    assert native.module().sh_assemble(*args, np.array([0, 1, 1, 0], np.int64))
    with pytest.raises(GszFormatError, match="codeword index out of range"):
        native.module().sh_assemble(*args, np.array([0, 2, 1, 0], np.int64))
    with pytest.raises(GszFormatError, match="refine length"):
        native.module().sh_assemble(*args, np.array([0, 1], np.int64))


def test_refine_is_a_fixed_configuration_option(tmp_path):
    from gsz.encoder.cli import main
    from conftest import SAMPLE_SH3
    out = tmp_path / "o.gsz"
    assert main([str(SAMPLE_SH3), "-o", str(out), "--size", "200kB", "--sh-refine", "-q"]) == 2
    assert not out.exists()
    assert main([str(SAMPLE_SH3), "-o", str(out), "--sh-refine", "--bits", "8", "--codebook", "64",
                 "--keep", "2000", "-q"]) == 0
    assert out.read_bytes()[8:12] == bytes([1, 0, 9, 0]) and len(decode(str(out))) > 0


def test_search_refines_the_codebook_where_the_sh_are_continuous():
    """SH like a trained capture's (a few shared factors, no palette) in KLT axes: at a budget
    where the codebook path keeps few vectors exact, every vector as its codeword plus an
    allocated correction renders far better, within the budget, and decodes on both paths."""
    from gsz.encoder.search import SearchOptions, encode_to_budget
    from test_sh_klt import _correlated
    fast = dict(train_views=8, eval_views=3, eval_width=240, importance_width=240, sh_colour="klt")
    cloud, target = _correlated(6000), 100_000
    refined = encode_to_budget(cloud, target, options=SearchOptions(**fast))
    plain = encode_to_budget(cloud, target, options=SearchOptions(**fast, sh_refine=False))
    assert refined.report.search.sh_path == "refine" and plain.report.search.sh_path == "vq"
    assert refined.report.sh_keep == refined.report.voxels
    assert len(refined.data) <= target and lowest_version(refined.data) == "1.9"
    decoded_on_both_paths(refined)
    assert render_psnr(cloud, refined.cloud) > render_psnr(cloud, plain.cloud) + 3.0   # measured +9 dB


def test_search_does_not_weigh_refinement_in_luma_chroma():
    """Corrections are scalar-coded; outside the file's own axes they lost (trained tiny at 12x),
    so a search in luma/chroma never encodes the refined path."""
    from gsz.encoder.search import SearchOptions, encode_to_budget
    from test_sh_klt import _correlated
    fast = dict(train_views=8, eval_views=3, eval_width=240, importance_width=240, sh_colour="luma-chroma")
    res = encode_to_budget(_correlated(6000), 100_000, options=SearchOptions(**fast))
    assert "refine" not in {c.get("sh_path") for c in res.report.search.calibration_all}
