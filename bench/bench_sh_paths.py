"""The size search with and without the scalar SH path, at the same budgets, on SH scenes.

    .venv/bin/python bench/bench_sh_paths.py --scene tests/data/measuring_jug_sh3_12k.ply --noise \
        --targets 120000,200000,300000,450000 [--views 4 --width 400] [--out bench/out/sh_paths.json]

For every target: ``encode_to_budget`` with ``sh_scalar`` off (codebook + kept exact vectors
only) and on (the search may pick the scalar path), each file's bytes, the SH path and keep
count the search chose, train PSNR, and test PSNR on ``--views`` default test views against the
original (``--noise``: bench_codec's noise first, the delivery grid left).  Appends to --out.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "bench"))
from bench_codec import git_commit  # noqa: E402


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scene", type=Path, required=True)
    p.add_argument("--noise", action="store_true")
    p.add_argument("--targets", required=True, help="comma-separated byte budgets")
    p.add_argument("--views", type=int, default=4)
    p.add_argument("--width", type=int, default=400)
    p.add_argument("--out", type=Path, default=ROOT / "bench" / "out" / "sh_paths.json")
    a = p.parse_args(argv)
    from bench_codec import add_noise
    from gsz.decoder import decode, read_ply
    from gsz.evaluation.cameras import load_cameras
    from gsz.evaluation.evaluate import evaluate, render_views
    from gsz.encoder.search import SearchOptions, encode_to_budget

    cloud = read_ply(a.scene)
    if a.noise:
        cloud = add_noise(cloud)
    cams = load_cameras(None, cloud, n_test=a.views, width=a.width).test
    refs = render_views(cloud, cams)
    rows = []
    for target in (int(t) for t in a.targets.split(",")):
        for scalar in (False, True):
            t0 = time.perf_counter()
            r = encode_to_budget(cloud, target, options=SearchOptions(sh_scalar=scalar))
            ev = evaluate(refs, decode(r.data), cams)
            row = {"target": target, "sh_scalar": scalar, "bytes": len(r.data), "sh_path": r.report.search.sh_path,
                   "sh_keep": r.report.sh_keep, "codebook_size": r.report.codebook_size,
                   "train_psnr": round(r.report.search.train_psnr, 2), "test_psnr": round(ev["psnr"], 2),
                   "seconds": round(time.perf_counter() - t0, 1)}
            rows.append(row)
            print(json.dumps(row), flush=True)
    commit = git_commit()
    entry = {"scene": a.scene.name, "noised": a.noise, "views": a.views, "width": a.width, "commit": commit,
             "command": "bench/bench_sh_paths.py " + " ".join(argv if argv is not None else sys.argv[1:]),
             "rows": rows}
    old = json.loads(a.out.read_text()) if a.out.exists() else []
    old = [e for e in old if not (e["scene"] == entry["scene"] and e["noised"] == entry["noised"])]
    a.out.write_text(json.dumps(old + [entry], indent=1) + "\n")
    print("| target | scalar path allowed | bytes | path | keep | test PSNR |\n|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['target']:,} | {r['sh_scalar']} | {r['bytes']:,} | {r['sh_path']} | {r['sh_keep']} | {r['test_psnr']:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
