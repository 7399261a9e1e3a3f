"""The size search's early bound: never above the smallest file the search really makes, and a
budget below it fails before the importance pass (in milliseconds, not minutes)."""
import time

import numpy as np
import pytest

import gsz
from conftest import SAMPLE_SH0, SAMPLE_SH3
from gsz.encoder.search import BudgetError, SearchOptions, encode_to_budget
from gsz.encoder.search.bound import BudgetBelowBoundError, smallest_file_bound

FAST = SearchOptions(max_candidates=2, refine_steps=0, eval_views=2, eval_width=64, train_views=2,
                     importance_width=64, vq_iters=5, depth_steps=1)


@pytest.mark.parametrize("path,n", [(SAMPLE_SH0, 3000), (SAMPLE_SH3, 2000)])
def test_bound_is_below_the_exact_smallest_file(path, n):
    """Just above the bound the search runs; it either makes a file (then that file is above
    the bound) or names the exact smallest file, which is above the bound."""
    cloud = gsz.read_ply(path).subset(np.arange(n))
    bound, parts = smallest_file_bound(cloud, FAST)
    assert parts["attributes"] > 0 and parts["voxels_at_least"] >= 1
    assert bound == sum(parts[k] for k in ("container", "geometry", "attributes", "metadata", "sh")
                        if k in parts)
    try:
        res = encode_to_budget(cloud, bound + 1, options=FAST)
        assert bound < len(res.data) <= bound + 1
    except BudgetError as e:
        assert not isinstance(e, BudgetBelowBoundError)
        assert e.minimum >= bound, (e.minimum, bound)
    with pytest.raises(BudgetBelowBoundError, match=f"at least {bound:,} bytes"):
        encode_to_budget(cloud, bound - 1, options=FAST)


def test_below_the_bound_fails_before_any_rendering(sample_sh3, monkeypatch):
    import gsz.encoder.pipeline as pipeline

    def no_importance(*a, **k):
        raise AssertionError("the importance pass ran")
    monkeypatch.setattr(pipeline, "compute_train_importance", no_importance)
    import gsz.encoder.search.driver as driver
    monkeypatch.setattr(driver, "compute_train_importance", no_importance)
    t0 = time.perf_counter()
    with pytest.raises(BudgetBelowBoundError) as e:
        encode_to_budget(sample_sh3, 5_000)
    assert time.perf_counter() - t0 < 2.0
    assert e.value.minimum > 5_000 and "smallest reachable file" in str(e.value)


def test_bound_grows_with_the_scene_and_the_blocks(sample_sh0):
    small = smallest_file_bound(sample_sh0.subset(np.arange(300)))[0]
    full = smallest_file_bound(sample_sh0)[0]
    fewer_blocks = smallest_file_bound(sample_sh0, SearchOptions(blocks=8))[0]
    assert small < full and fewer_blocks < full
