"""The encoder's maps over cores never change the file: the same bytes on one thread and on
several, and a failing item's exception reaches the caller."""
import hashlib

import numpy as np
import pytest

from gsz.decoder import threads
from gsz.encoder.pipeline import EncodeOptions, encode
from gsz.encoder.search import SearchOptions, encode_to_budget

from codec_util import FAST, sample


QUICK_SEARCH = SearchOptions(max_candidates=2, refine_steps=0, depth_steps=1, eval_views=2,
                             eval_width=96, train_views=4, importance_width=96, vq_iters=10)


def _with_cores(monkeypatch, n):
    monkeypatch.setattr(threads, "cores", lambda: n)


def test_thread_map_keeps_order_nests_and_raises(monkeypatch):
    _with_cores(monkeypatch, 4)
    assert threads.thread_map(lambda i: i * i, 9) == [i * i for i in range(9)]
    nested = threads.thread_map(lambda i: threads.thread_map(lambda j: (i, j), 3), 5)
    assert nested == [[(i, j) for j in range(3)] for i in range(5)]

    def fails_at_3(i):
        if i == 3:
            raise ValueError("item 3")
        return i
    with pytest.raises(ValueError, match="item 3"):
        threads.thread_map(fails_at_3, 8)


def test_a_map_does_not_wait_for_another_maps_items(monkeypatch):
    """With the pool's threads busy with other maps' items, a map whose caller has done all its
    items returns at once (its queued helper is not needed): it never waits on work it does not
    own (here that work waits for this map, so waiting would never end)."""
    import threading
    _with_cores(monkeypatch, 2)
    threads.thread_map(lambda i: i, 2)           # the pool exists (2 threads)
    release, busy = threading.Event(), threading.Barrier(3)

    def blocked(i):
        if threading.current_thread().name.startswith("gsz-map"):
            busy.wait(10)                         # the item a pool thread took
        release.wait(10)
        return i
    others = [threading.Thread(target=threads.thread_map, args=(blocked, 2)) for _ in range(2)]
    for t in others:
        t.start()
    busy.wait(10)                                 # both pool threads now hold a blocked item
    out = {}
    mine = threading.Thread(target=lambda: out.update(r=threads.thread_map(lambda i: i * 2, 3)))
    mine.start()
    mine.join(5)
    waited = mine.is_alive()                      # still waiting on the busy pool
    release.set()
    for t in others + [mine]:
        t.join(10)
    assert not waited and out["r"] == [0, 2, 4]


def test_spans_cover_the_range_once():
    for n, parts in ((10, 3), (2, 4), (7, 1), (5, 5)):
        cut = threads.spans(n, parts)
        assert [a for a, _ in cut] == [0] + [b for _, b in cut[:-1]]
        assert cut[-1][1] == n and all(b > a for a, b in cut) and len(cut) <= parts
    assert threads.spans(0, 3) == []


@pytest.mark.parametrize("search", [False, True])
def test_file_does_not_depend_on_the_thread_count(monkeypatch, search):
    cloud = sample("sh3")

    def run(n):
        _with_cores(monkeypatch, n)
        if search:
            data = encode_to_budget(cloud, 60_000, options=QUICK_SEARCH).data
        else:
            data = encode(cloud, EncodeOptions(**FAST)).data
        return hashlib.sha256(data).hexdigest()
    one = run(1)
    assert run(2) == one and run(3) == one


def test_loss_tables_and_symbols_do_not_depend_on_the_thread_count(monkeypatch):
    from gsz.kernels.quantize import quantize_groups
    from gsz.encoder.rate import group_stats
    rng = np.random.default_rng(3)
    x = rng.normal(size=(9, 5000)).astype(np.float32)
    bits = rng.integers(1, 17, size=(9, 7))
    got = []
    for n in (1, 3):
        _with_cores(monkeypatch, n)
        sym, mn, mx = quantize_groups(x, 7, bits)
        stats = group_stats(x, 7)
        got.append((sym, mn, mx, stats))
    (s1, a1, b1, t1), (s3, a3, b3, t3) = got
    assert np.array_equal(s1, s3) and np.array_equal(a1, a3) and np.array_equal(b1, b3)
    assert all(np.array_equal(t1[k], t3[k]) for k in t1)


def test_parts_side_by_side_give_the_same_file(monkeypatch):
    """A small tiled stage codes its parts on threads; one part at a time gives the same bytes."""
    from gsz.encoder import executor
    opts = EncodeOptions(**FAST, layers=2, tile_gaussians=4096, executor="inline")
    _with_cores(monkeypatch, 2)
    side = encode(sample("sh3"), opts).data
    monkeypatch.setattr(executor, "SIDE_BY_SIDE_MAX_GAUSSIANS", 0)
    assert encode(sample("sh3"), opts).data == side
