"""Where per-tile work runs never changes the file: inline, local worker processes and Ray."""
import hashlib
import sys

import pytest

from gsz.decoder import decode
from gsz.encoder.executor import ExecutorError, make_executor
from gsz.encoder.pipeline import EncodeOptions, EncodeOptionsError, encode

from codec_util import FAST, sample

TILED = {**FAST, "layers": 2, "tile_gaussians": 4096}


def _digest(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


@pytest.fixture(scope="module")
def inline_file():
    return encode(sample("sh3"), EncodeOptions(**TILED, executor="inline")).data


def test_local_workers_give_the_same_bytes(inline_file):
    for workers in (2, 3):
        res = encode(sample("sh3"), EncodeOptions(**TILED, executor="local", workers=workers))
        assert _digest(res.data) == _digest(inline_file)
        assert decode(res.data).equals(res.cloud)


def test_local_ray_with_two_cpus_gives_the_same_bytes(inline_file):
    ray = pytest.importorskip("ray")
    try:
        res = encode(sample("sh3"), EncodeOptions(**TILED, executor="ray", workers=2))
        assert _digest(res.data) == _digest(inline_file)
    finally:
        ray.shutdown()


def test_size_search_bytes_do_not_depend_on_the_executor():
    from gsz.encoder.search import SearchOptions, encode_to_budget
    kw = dict(tile_gaussians=4096, train_views=6, eval_views=2, eval_width=160, importance_width=160)
    a = encode_to_budget(sample("sh3"), 120_000, options=SearchOptions(**kw, executor="inline"))
    b = encode_to_budget(sample("sh3"), 120_000, options=SearchOptions(**kw, executor="local", workers=2))
    assert _digest(a.data) == _digest(b.data)


def test_unknown_executor_is_refused_before_any_work():
    with pytest.raises(EncodeOptionsError, match="--executor must be local, inline, ray or ray://"):
        EncodeOptions(executor="spark").validate()
    with pytest.raises(ExecutorError, match="unknown executor"):
        make_executor("dask")


def test_ray_missing_says_how_to_install(monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)     # import ray -> ImportError
    with pytest.raises(EncodeOptionsError, match=r"pip install 'gsz\[cluster\]'"):
        EncodeOptions(executor="ray").validate()
    with pytest.raises(ExecutorError, match=r"pip install 'gsz\[cluster\]'"):
        make_executor("ray://head:10001")


def test_cli_reports_a_bad_executor_in_one_line(tmp_path, capsys):
    from gsz.encoder.cli import main
    rc = main([str(tmp_path / "missing.ply"), "-o", str(tmp_path / "x.gsz"), "--executor", "spark"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "--executor" in err[0]


def test_work_run_here_makes_each_job_only_when_its_turn_comes():
    """Inline work is lazy: at 1.2 M Gaussians every part's inputs at once cost hundreds of MB."""
    from gsz.encoder.executor import in_order
    made = []

    def jobs():
        for j in range(3):
            made.append(j)
            yield j

    for ex in (None, make_executor("inline"), make_executor("local", workers=1)):
        made.clear()
        it = in_order(ex, lambda j: (j, len(made)), jobs())
        assert made == []
        assert list(it) == [(0, 1), (1, 2), (2, 3)]
