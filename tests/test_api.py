"""The one-call Python API: gsz.encode / gsz.encode_file / gsz.load, frames and the cloud's repr."""
import numpy as np
import pytest

import gsz
from gsz.encoder.pipeline import EncodeOptions
from gsz.encoder.search import SearchOptions

from codec_util import FAST, sample
from conftest import SAMPLE_SH0

FAST_SEARCH = SearchOptions(train_views=6, eval_views=2, eval_width=160, importance_width=160)


def test_encode_to_a_size_gives_bytes_within_it_that_decode():
    cloud = sample("sh0", 3000)
    data = gsz.encode(cloud, size="60kB", options=FAST_SEARCH)
    assert isinstance(data, bytes) and 0.95 * 60_000 <= len(data) <= 60_000
    back = gsz.decoder.decode(data)
    assert len(back) <= len(cloud) and back.sh_degree == cloud.sh_degree


def test_encode_without_a_target_is_the_fixed_configuration():
    cloud = sample("sh0", 2000)
    a = gsz.encode(cloud, options=EncodeOptions(bits=10, reserve=1.0, **FAST))
    b = gsz.encode(cloud, options=EncodeOptions(bits=10, reserve=1.0, **FAST))
    assert a == b and gsz.decoder.decode(a).sh_degree == 0


def test_encode_file_with_a_ratio_measures_the_input_ply(tmp_path):
    out = tmp_path / "plant.gsz"
    res = gsz.encode_file(SAMPLE_SH0, out, ratio=20, options=FAST_SEARCH)
    size = SAMPLE_SH0.stat().st_size
    assert out.read_bytes() == res.data and len(res.data) <= size // 20
    assert gsz.load(out).equals(res.cloud)


def test_encode_refuses_two_targets():
    with pytest.raises(gsz.GszError, match="exactly one"):
        gsz.encode(sample("sh0", 500), size="10kB", ratio=10)


def test_convert_frame_round_trips_and_flips_y_and_z():
    c = sample("sh3", 300)
    rub = gsz.convert_frame(c, "RDF", "RUB")
    np.testing.assert_array_equal(rub.positions, c.positions * np.array([1, -1, -1], np.float32))
    assert gsz.convert_frame(rub, "RUB", "RDF").equals(c)
    assert not np.array_equal(rub.sh_rest, c.sh_rest)          # odd SH bands change sign
    with pytest.raises(ValueError, match="unknown frame"):
        gsz.convert_frame(c, "RDF", "XYZ")


def test_cloud_repr_is_short():
    r = repr(sample("sh3"))
    assert r.startswith("GaussianCloud(") and "SH degree 3" in r and len(r) < 200


@pytest.mark.parametrize("app_setting", [True, False])
def test_decoding_in_threads_leaves_numpys_huge_page_setting_as_the_app_had_it(app_setting):
    """The decoder turns NumPy's huge-page advice off while it runs (decoder/pages.py); tiles
    decode in several threads at once, and the app's own setting must come back after them."""
    from concurrent.futures import ThreadPoolExecutor
    pages = pytest.importorskip("numpy._core.multiarray")
    old = pages._set_madvise_hugepage(app_setting)
    try:
        data = gsz.encode(sample("sh0", 1500), options=EncodeOptions(bits=10, reserve=1.0, **FAST))
        with ThreadPoolExecutor(4) as pool:
            clouds = list(pool.map(lambda _: gsz.decoder.decode(data), range(8)))
        assert all(c.equals(clouds[0]) for c in clouds)
        assert pages._set_madvise_hugepage(app_setting) is app_setting
    finally:
        pages._set_madvise_hugepage(old)
