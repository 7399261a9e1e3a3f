"""Which train views should the size search compare its candidates on?

    .venv/bin/python bench/bench_eval_views.py [--points scene:variant:ratio,...]
                                               [--search-width W] [--importance-width W]
                                               [--train-sets 6@800,...] [--margins 0,0.5,1,2]
                                               [--out bench/out/eval_views.json]

For each point the size search runs once (``SearchOptions(eval_width=--search-width)``); every
candidate it fully encodes is kept and afterwards rendered from several view sets: the 8
default *test* views at 800 px (gsz-eval's protocol, never seen by the search) and a few
*train* view sets (count @ width).  For each train set the table says which candidate it would
pick and how much test PSNR that pick loses against the test-best candidate of the same run
("regret").  A train set whose picks have no regret predicts the test ranking.  The candidates
are the ones this run's walk produced; a different comparison set could also steer the walk to
other candidates, which this does not measure.

``--margins`` weighs the search's own rule with a preference for pruning less: each candidate
ranks by its search train PSNR + m x tau (m dB a unit of tau), and the table gives each m's
regret -- among this run's candidates, so again not where such a rule would steer the walk.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
SHARED = Path(os.environ.get("GSZ_SHARED", ROOT.parent / "shared")) / "data"
sys.path.insert(0, str(ROOT / "bench"))
from bench_codec import add_noise  # noqa: E402

DEFAULT_POINTS = ("plaza_taebak_crop_sh0:grid:12,flowers_daffodils_sh2:grid:27,houseplant_sh0:noised:40,"
                  "showroom_lacadiere_crop_sh0:grid:12,measuring_jug_sh3:noised:18,"
                  "tiny_graphdeco_iter7000_sh3:grid:18")
#: name -> (views, width): generated train views (a spiral of views + 1, as the search makes them)
TRAIN_SETS = {"6@640": (6, 640), "6@800": (6, 800), "6@1024": (6, 1024), "4@800": (4, 800),
              "8@800": (8, 800), "12@640": (12, 640), "12@800": (12, 800), "24@800": (24, 800)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--points", default=DEFAULT_POINTS, help="scene:variant:ratio, comma separated")
    ap.add_argument("--search-width", type=int, default=None,
                    help="eval_width of the search itself (default: SearchOptions' default)")
    ap.add_argument("--importance-width", type=int, default=None,
                    help="importance_width of the search (default: SearchOptions' default)")
    ap.add_argument("--train-sets", default=",".join(TRAIN_SETS),
                    help="train view sets to render (count@width, comma separated, of: " + ", ".join(TRAIN_SETS) + ")")
    ap.add_argument("--margins", default="0,0.5,1,2",
                    help="dB of train PSNR per unit of tau a candidate's rank gains (comma separated): "
                         "the pick of each such rule among the search's own candidates and train scores")
    ap.add_argument("--out", default=str(ROOT / "bench" / "out" / "eval_views.json"))
    a = ap.parse_args(argv)
    margins = [float(x) for x in a.margins.split(",") if x]
    if not SHARED.exists():
        print(f"SKIP: {SHARED} not present")
        return 0
    import gsz
    from gsz.encoder import search as S
    from gsz.evaluation.cameras import load_cameras
    from gsz.evaluation.evaluate import render_views
    from gsz.evaluation.metrics import psnr
    from gsz.encoder.pipeline import EncodeOptions, compute_train_importance
    from gsz.encoder.progress import Progress

    # keep every candidate's decoded cloud and what the search knew of it (the search keeps
    # only the winner's bytes); captured as it is added, before add_candidate drops the others'
    from gsz.decoder import decode
    from gsz.encoder.search import driver as D
    kept = []
    original = D.BudgetSearch.add_candidate

    def keeping(self, cand):
        kept.append(({"reserve": cand.reserve, "depth": cand.depth, "search_train": cand.train_psnr,
                      "sh_path": cand.encoded.sh_path}, decode(cand.data)))
        return original(self, cand)
    D.BudgetSearch.add_candidate = keeping

    sopts = S.SearchOptions()
    if a.search_width:
        sopts.eval_width = a.search_width
    if a.importance_width:
        sopts.importance_width = a.importance_width
    results = []
    for point in a.points.split(","):
        scene, variant, ratio = point.split(":")
        path = SHARED / f"{scene}.ply"
        if not path.exists():
            print(f"SKIP {scene}: not present")
            continue
        cloud = gsz.read_ply(path)
        if variant == "noised":
            cloud = add_noise(cloud)
        target = int(os.path.getsize(path) / float(ratio))
        kept.clear()
        imp = compute_train_importance(cloud, EncodeOptions(train_views=sopts.train_views,
                                                             importance_width=sopts.importance_width))
        t0 = time.perf_counter()
        res = S.encode_to_budget(cloud, target, options=sopts, importance=imp, progress=Progress(quiet=True))
        seconds = time.perf_counter() - t0
        sets = {"test 8@800": load_cameras(None, cloud, n_test=8, width=800).test}
        for name in filter(None, a.train_sets.split(",")):
            v, w = TRAIN_SETS[name]
            sets[f"train {name}"] = load_cameras(None, cloud, n_train=v, n_test=1, width=w).train[:v]
        refs = {k: render_views(cloud, cams) for k, cams in sets.items()}
        rows = []
        for meta, cand in kept:
            rows.append(meta | {k: float(np.mean([psnr(x, y) for x, y in zip(refs[k], render_views(cand, cams))]))
                                for k, cams in sets.items()})
        best_test = max(r["test 8@800"] for r in rows)
        picks = {}
        for k in sets:
            if k.startswith("train"):
                pick = max(rows, key=lambda r: r[k])
                picks[k] = {"test_psnr": pick["test 8@800"], "regret": best_test - pick["test 8@800"]}
        for m in margins:
            pick = max(rows, key=lambda r: (r["search_train"] + m * r["reserve"], r["reserve"]))
            picks[f"margin {m:g}"] = {"test_psnr": pick["test 8@800"], "regret": best_test - pick["test 8@800"],
                                      "reserve": pick["reserve"], "depth": pick["depth"]}
        print(f"== {scene} {variant} {ratio}x: {len(rows)} candidates, search {seconds:.1f} s "
              f"(eval_width {sopts.eval_width}, importance_width {sopts.importance_width}); chosen: tau {res.report.reserve} depth {res.report.depth}",
              flush=True)
        for r in rows:
            print("   " + "  ".join(f"{k} {v:.2f}" if isinstance(v, float) else f"{k} {v}" for k, v in r.items()))
        for k, p in picks.items():
            print(f"   pick by {k:14s}: test {p['test_psnr']:.2f} dB (regret {p['regret']:.2f})", flush=True)
        results.append({"scene": scene, "variant": variant, "ratio": float(ratio), "search_seconds": seconds,
                        "eval_width": sopts.eval_width,
                        "importance_width": sopts.importance_width, "candidates": rows, "picks": picks})
    D.BudgetSearch.add_candidate = original
    if results:
        print("\n| train views | points with regret 0 | mean regret dB | max regret dB |\n|---|---|---|---|")
        for k in results[0]["picks"]:
            reg = [r["picks"][k]["regret"] for r in results]
            print(f"| {k} | {sum(x < 1e-9 for x in reg)} / {len(reg)} | {np.mean(reg):.2f} | {max(reg):.2f} |")
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(results, indent=1))
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
