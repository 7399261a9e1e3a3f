"""What-if probe of the size search's loss weights: encode shared scenes to budgets with one of
the allocation's weights changed, score the files with gsz-eval's protocol (test PSNR, 8 views
at 800 px).  A probe for design records (docs/design/error-coherence.md), not a product path:
it patches the search's internals in this process only.

    .venv/bin/python bench/probe_allocation_weights.py SCENE --sizes B1,B2 [--noise]
        [--sh-weight F] [--vq-factor F] [--raht-bands EXP [--raht-channels 0,...,6]]
        [--scalar-everywhere] [--opt FIELD=VALUE ...] [-v]

* ``--sh-weight F``: the SH channel weight (channel_weights' "sh") times F;
* ``--vq-factor F``: the codebook path's estimated VQ error times F (ShModel), as if codebook
  errors rendered F times worse than i.i.d. errors of the same SSE;
* ``--raht-bands EXP``: each RAHT block's loss times f(s)**EXP, f the rendered-error factor of
  a coefficient spanning s ~ N / (i + 1) Gaussians (stream index i; the houseplant's
  bench_coherence.py curve), on the channels of ``--raht-channels`` (0 opacity, 1-3 Euler
  angles, 4-6 DC colour);
* ``--scalar-everywhere``: the scalar SH path weighed at every stage, its estimate ignored;
* ``--opt``: any SearchOptions field (``--opt sh_colour=klt --opt codebook=16384``).
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(Path(__file__).resolve().parent))

#: bench_coherence.py on houseplant_sh0 (depth 14): Gaussians a RAHT coefficient spans -> its
#: rendered error per unit SSE over the i.i.d. weight
BAND_SPAN = (1.4, 3.2, 9.2, 33.0, 125.0, 500.0, 2000.0)
BAND_FACTOR = (0.28, 0.66, 1.94, 4.67, 9.76, 16.05, 17.72)


def patch(a) -> None:
    """Apply the requested what-ifs to the search modules (this process only)."""
    import gsz.encoder.search.judge as judge
    if a.sh_weight != 1.0:
        weights_of = judge.channel_weights

        def channel_weights(*args, **kw):
            w = dict(weights_of(*args, **kw))
            w["sh"] *= a.sh_weight
            return w
        judge.channel_weights = channel_weights
    if a.vq_factor != 1.0:
        import gsz.encoder.search.sh_model as sh_model
        init = sh_model.ShModel.__init__

        def scaled_init(self, *args, **kw):
            init(self, *args, **kw)
            self.cum_vq = self.cum_vq * a.vq_factor
        sh_model.ShModel.__init__ = scaled_init
    if a.raht_bands is not None:
        import gsz.encoder.search.tables as tables
        from gsz.decoder.quant import split_lengths
        channels = [int(c) for c in a.raht_channels.split(",")]

        def block_factors(length: int, blocks: int) -> np.ndarray:
            span = (length + 1) / (np.arange(length, dtype=np.float64) + 1)
            f = np.interp(np.log(span), np.log(BAND_SPAN), BAND_FACTOR) ** a.raht_bands
            lens = split_lengths(length, blocks)
            return np.add.reduceat(f, np.cumsum(lens) - lens) / np.maximum(lens, 1)
        raw = tables.raw_tables

        def raw_tables(stage, blocks):
            key = ("probe_raht_bands", blocks)
            if key not in stage.cache:
                out = list(raw(stage, blocks))
                for i, (x, b) in enumerate(tables.attribute_sets(stage, blocks)):
                    if i % 2 == 0 and x.shape[1]:
                        loss, rate = out[i]
                        loss = loss.copy()
                        loss[channels] *= block_factors(x.shape[1], b)[None, :, None]
                        out[i] = (loss, rate)
                stage.cache[key] = out
            return stage.cache[key]
        tables.raw_tables = raw_tables
    if a.scalar_everywhere:
        import gsz.encoder.search.tau as tau
        tau.SCALAR_MIN_KEEP = 0.0
        scalar_sh = tau.scalar_sh
        tau.scalar_sh = lambda plan_kept, loss, rate, room, vq_total: scalar_sh(plan_kept, loss, rate, room, None)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scene", help="a shared scene's name (../shared/data/NAME.ply) or a PLY path")
    ap.add_argument("--sizes", required=True, help="comma-separated byte budgets")
    ap.add_argument("--noise", action="store_true", help="the RD bench's noised variant")
    ap.add_argument("--sh-weight", type=float, default=1.0)
    ap.add_argument("--vq-factor", type=float, default=1.0)
    ap.add_argument("--raht-bands", type=float, default=None)
    ap.add_argument("--raht-channels", default="0,1,2,3,4,5,6")
    ap.add_argument("--scalar-everywhere", action="store_true")
    ap.add_argument("--opt", action="append", default=[], help="SearchOptions FIELD=VALUE (JSON values)")
    ap.add_argument("-v", action="store_true", help="the search's progress log")
    a = ap.parse_args(argv)

    import gsz
    from bench_codec import add_noise
    from gsz.decoder import decode
    from gsz.encoder.pipeline import EncodeOptions, compute_train_importance
    from gsz.encoder.progress import Progress
    from gsz.encoder.search import SearchOptions, encode_to_budget
    from gsz.evaluation.cameras import load_cameras
    from gsz.evaluation.evaluate import evaluate, render_views

    patch(a)
    path = Path(a.scene)
    if not path.suffix:
        path = ROOT.parent / "shared" / "data" / f"{a.scene}.ply"
    cloud = gsz.read_ply(path)
    if a.noise:
        cloud = add_noise(cloud)
    cams = load_cameras(None, cloud, n_test=8, width=800).test
    refs = render_views(cloud, cams)
    kw = {}
    for o in a.opt:
        k, v = o.split("=", 1)
        try:
            kw[k] = json.loads(v)
        except json.JSONDecodeError:
            kw[k] = v
    sopts = SearchOptions(**kw)
    imp = compute_train_importance(cloud, EncodeOptions(train_views=sopts.train_views,
                                                        importance_width=sopts.importance_width, seed=sopts.seed))
    for s in a.sizes.split(","):
        t0 = time.perf_counter()
        res = encode_to_budget(cloud, int(s), options=sopts, importance=imp, progress=Progress(quiet=not a.v))
        dt = time.perf_counter() - t0
        dec = decode(res.data)
        ev = evaluate(refs, getattr(dec, "cloud", dec), cams)
        r = res.report
        print(f"{path.stem}{' noised' if a.noise else ''} {int(s):,} B -> {len(res.data):,} B: test PSNR "
              f"{ev['psnr']:.2f} dB (train {r.search.train_psnr:.2f}); tau {r.reserve}, depth {r.depth}, "
              f"codebook {r.codebook_size} at {(r.bits or {}).get('sh_codebook')} bits, kept {r.sh_keep}; {dt:.0f} s", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
