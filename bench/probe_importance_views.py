"""Does an importance pass over more (or smaller) default views prune better?

    .venv/bin/python bench/probe_importance_views.py SCENE [--noise] [--sets 24@800,48@800,48@560]
        [--taus 0.7,0.8,0.9] [--alt 13] [--combine sum,max,sqrt] [--out bench/out/importance_views.jsonl]

For a shared scene (``../shared/data/SCENE.ply``; ``--noise``: bench_codec.add_noise, the RD
bench's noised variant), the importance I = I_d * I_v is computed over each default train view
set (count@width: ``load_cameras(None, cloud, n_train=count, n_test=8, width=width).train``, the
set the encoder builds with ``--train-views count --importance-width width``), the cloud is
pruned at each tau with nothing else changed, and rendered against the original from gsz-eval's
8 test views and from ``--alt`` views of another spiral (``default_cameras(n_train=0,
n_test=alt)``: directions that belong to no train spiral, so a set whose spiral happens to
interleave with the test views' gets no credit for it).  ``--combine``: the first set's views
rendered one at a time and their view terms combined by each rule instead of summed (``sum``,
MesonGS++'s; ``max`` over views; ``sqrt``, the sum of square roots), times the same volume term.
Prints one line per tau and appends the rows to ``--out``.  What it does not measure: the size search picks tau per budget, so a better
ranking shows at a fixed tau here and only through the search's choices in the codec.
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
from bench_codec import add_noise, git_commit  # noqa: E402


def parse_set(text: str) -> tuple[int, int]:
    count, _, width = text.partition("@")
    return int(count), int(width or 800)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene", help="shared scene name (../shared/data/SCENE.ply)")
    ap.add_argument("--noise", action="store_true", help="the RD bench's noised variant")
    ap.add_argument("--sets", default="24@800,48@800,48@560", help="train view sets count@width, comma separated")
    ap.add_argument("--taus", default="0.7,0.8,0.9")
    ap.add_argument("--alt", type=int, default=13, help="views of the independent spiral (0: none)")
    ap.add_argument("--combine", default="", help="rules over the first set's views: sum, max, sqrt (comma separated)")
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "out" / "importance_views.jsonl")
    a = ap.parse_args(argv)
    path = SHARED / f"{a.scene}.ply"
    if not path.exists():
        print(f"{path}: not found (the shared data sits beside the checkout)", file=sys.stderr)
        return 1
    from gsz.decoder.ply import read_ply
    from gsz.encoder.importance import compute_importance, prune, volume_term
    from gsz.evaluation.render import accumulate_importance
    from gsz.evaluation.cameras import default_cameras, load_cameras
    from gsz.evaluation.evaluate import evaluate, render_views

    cloud = read_ply(path)
    if a.noise:
        cloud = add_noise(cloud)
    views = {"test": load_cameras(None, cloud).test}
    if a.alt:
        views[f"alt{a.alt}"] = default_cameras(cloud, n_train=0, n_test=a.alt).test
    refs = {k: render_views(cloud, v) for k, v in views.items()}
    sets = [parse_set(s) for s in a.sets.split(",") if s]
    importance, seconds = {}, {}
    for count, width in sets:
        cams = load_cameras(None, cloud, n_train=count, n_test=8, width=width).train
        t = time.perf_counter()
        importance[(count, width)] = compute_importance(cloud, cams)
        seconds[(count, width)] = time.perf_counter() - t
    rules = [r for r in a.combine.split(",") if r]
    if rules:
        count, width = sets[0]
        cams = load_cameras(None, cloud, n_train=count, n_test=8, width=width).train
        per = np.stack([np.asarray(accumulate_importance(cloud, [c]), np.float64) for c in cams])
        combine = {"sum": lambda v: v.sum(0), "max": lambda v: v.max(0), "sqrt": lambda v: np.sqrt(v).sum(0)}
        for rule in rules:
            if rule not in combine:
                print(f"--combine: unknown rule {rule!r} (sum, max, sqrt)", file=sys.stderr)
                return 2
            importance[(count, width, rule)] = combine[rule](per) * volume_term(cloud)
    variant = "noised" if a.noise else "grid"
    a.out.parent.mkdir(parents=True, exist_ok=True)
    with a.out.open("a") as f:
        for tau in (float(x) for x in a.taus.split(",") if x):
            cells = []
            for key, imp in importance.items():
                sub = cloud.subset(prune(imp, tau))
                psnr = {k: evaluate(refs[k], sub, views[k])["psnr"] for k in views}
                label = f"{key[0]}@{key[1]}" + (f" {key[2]}" if len(key) > 2 else "")
                cells.append(f"{label}: " + " / ".join(f"{k} {v:.2f}" for k, v in psnr.items()))
                f.write(json.dumps({"scene": a.scene, "variant": variant, "tau": tau, "views": key[0],
                                    "width": key[1], "rule": key[2] if len(key) > 2 else "sum",
                                    "importance_s": round(seconds[key], 2) if key in seconds else None, "psnr": psnr,
                                    "commit": git_commit()}) + "\n")
            print(f"{a.scene} {variant} tau {tau}: " + " | ".join(cells), flush=True)
    print("importance seconds: " + ", ".join(f"{c}@{w} {s:.1f}" for (c, w), s in seconds.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
