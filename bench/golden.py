"""Byte-identity check for restructurings: encode a fixed set of configurations (fixed and
size-search, single and layered, SH-0 and SH-3, low budgets to budgets above the quality
ceiling) and record each file's SHA-256 and the search report's decisions (all but timings).

    .venv/bin/python bench/golden.py --write bench/out/golden.json     # before a change
    .venv/bin/python bench/golden.py --check bench/out/golden.json     # after: lists differences

A restructuring that claims "no behaviour change" must leave every line identical.  Scenes from
../shared/data are used when present (``--quick`` skips them: committed samples only).
"""
from __future__ import annotations

import argparse
import hashlib
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
SHARED = ROOT.parent / "shared" / "data"
sys.path.insert(0, str(ROOT / "bench"))
from bench_codec import add_noise  # noqa: E402

SAMPLES = ROOT / "tests" / "data"
#: (case name, PLY, noised, mode, arguments).  mode "fixed": EncodeOptions fields;
#: "search": (ratio to the PLY's bytes or absolute bytes, SearchOptions fields).  No --solver
#: cbc case: CBC runs under a wall-clock limit, so its picks depend on the machine's speed.
CASES = [
    ("plant20k-fixed", SAMPLES / "houseplant_sh0_20k.ply", False, "fixed", {}),
    ("jug12k-fixed-layers", SAMPLES / "measuring_jug_sh3_12k.ply", False, "fixed", {"layers": 3}),
    ("plant20k-150kB", SAMPLES / "houseplant_sh0_20k.ply", False, "search", (150_000, {})),
    ("plant20k-60kB-layers", SAMPLES / "houseplant_sh0_20k.ply", False, "search", (60_000, {"layers": 3})),
    ("jug12k-12x", SAMPLES / "measuring_jug_sh3_12k.ply", False, "search", (12.0, {})),
    ("jug12k-noised-2.5x", SAMPLES / "measuring_jug_sh3_12k.ply", True, "search", (2.5, {})),
    ("jug12k-10x-layers", SAMPLES / "measuring_jug_sh3_12k.ply", False, "search", (10.0, {"layers": 3})),
    ("jug12k-noised-27x", SAMPLES / "measuring_jug_sh3_12k.ply", True, "search", (27.0, {})),
    ("jug12k-noised-fixed-klt", SAMPLES / "measuring_jug_sh3_12k.ply", True, "fixed", {"sh_colour": "klt", "layers": 2}),
    ("tiny-8x", SHARED / "tiny_graphdeco_iter7000_sh3.ply", False, "search", (8.0, {})),
    ("tiny-sog-bytes", SHARED / "tiny_graphdeco_iter7000_sh3.ply", False, "search", (420_922, {})),
    ("tiny-noised-40x-layers", SHARED / "tiny_graphdeco_iter7000_sh3.ply", True, "search", (40.0, {"layers": 3})),
    ("jug-noised-12x", SHARED / "measuring_jug_sh3.ply", True, "search", (12.0, {})),
    ("showroom-27x", SHARED / "showroom_lacadiere_crop_sh0.ply", False, "search", (27.0, {})),
]
_TIMINGS = {"seconds", "total_seconds", "cpu_seconds", "memory"}   # machine-dependent


def _digest(obj) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True, default=_plain).encode()).hexdigest()[:16]


def _plain(x):
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, (np.integer, np.floating)):
        return x.item()
    return str(x)


def run_case(ply: Path, noised: bool, mode: str, args) -> dict:
    from gsz.decoder.ply import read_ply
    from gsz.encoder.pipeline import EncodeOptions, encode
    from gsz.encoder.search import SearchOptions, encode_to_budget
    cloud = read_ply(ply)
    if noised:
        cloud = add_noise(cloud)
    if mode == "fixed":
        res = encode(cloud, EncodeOptions(**args))
    else:
        target, kw = args
        target = int(ply.stat().st_size / target) if target < 1000 else int(target)
        res = encode_to_budget(cloud, target, options=SearchOptions(**kw))
    report = {k: v for k, v in res.report.to_json().items() if k not in _TIMINGS}
    return {"bytes": len(res.data), "sha256": hashlib.sha256(res.data).hexdigest()[:16],
            "report": _digest(report)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    g = ap.add_mutually_exclusive_group(required=True)
    g.add_argument("--write", metavar="JSON")
    g.add_argument("--check", metavar="JSON")
    ap.add_argument("--quick", action="store_true", help="committed samples only")
    ap.add_argument("--only", default=None, help="comma-separated case names")
    a = ap.parse_args(argv)
    want = set(a.only.split(",")) if a.only else None
    known = json.loads(Path(a.check).read_text()) if a.check else {}
    out, bad = {}, []
    for name, ply, noised, mode, args in CASES:
        if (want and name not in want) or not ply.exists() or (a.quick and ply.parent != SAMPLES):
            continue
        t = time.perf_counter()
        out[name] = run_case(ply, noised, mode, args)
        same = "" if not a.check else ("same" if known.get(name) == out[name] else "DIFFERENT")
        if same == "DIFFERENT":
            bad.append(name)
        print(f"{name:26s} {out[name]['bytes']:>10,} B  {out[name]['sha256']}  report {out[name]['report']}"
              f"  {time.perf_counter() - t:6.1f} s  {same}", flush=True)
    if a.write:
        path = Path(a.write)
        path.parent.mkdir(parents=True, exist_ok=True)
        old = json.loads(path.read_text()) if want and path.exists() else {}
        path.write_text(json.dumps({**old, **out}, indent=1) + "\n")
    if a.check:
        print(f"{len(out) - len(bad)} of {len(out)} identical" + (f"; different: {', '.join(bad)}" if bad else ""))
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
