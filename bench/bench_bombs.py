"""Time and peak RSS of decoding each hostile file of tests/data/bombs/ on both decoder paths
(issue 19: each must be decoded or rejected within 5 s and 1.5 GB, with default limits).

    .venv/bin/python bench/bench_bombs.py [more.gsz ...]

One fresh process per (file, path), so the peak RSS is that decode's own; each runs under an
8 GiB address-space cap and a 120 s timeout, so a regression shows as a row, not a dead machine.
Exits 1 if any row misses the 5 s / 1.5 GB bound.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
LIMIT_S, LIMIT_MB = 5.0, 1536
CHILD = r"""
import json, resource, sys, time
resource.setrlimit(resource.RLIMIT_AS, (8 << 30, 8 << 30))
from gsz.decoder import GszError, decode
from gsz.decoder.native import active_path
t = time.perf_counter()
try:
    out = f"decoded {len(decode(sys.argv[1])):,} Gaussians"
except GszError as e:
    out = f"{type(e).__name__}: {str(e).split(': ', 1)[-1]}"
except MemoryError:
    out = "MemoryError"
print(json.dumps({"path": active_path(), "seconds": time.perf_counter() - t, "outcome": out,
                  "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def run(path: Path, native: bool) -> dict:
    env = {**os.environ, "GSZ_NATIVE": "1" if native else "0"}
    try:
        p = subprocess.run([sys.executable, "-c", CHILD, str(path)], capture_output=True, text=True,
                           env=env, timeout=120)
        return json.loads(p.stdout.strip().splitlines()[-1])
    except (subprocess.TimeoutExpired, IndexError, ValueError):
        return {"path": "native" if native else "numpy", "seconds": float("inf"), "peak_mb": float("nan"),
                "outcome": "timeout or crash"}


def main(argv=None) -> int:
    files = [Path(a) for a in (argv if argv is not None else sys.argv[1:])] or \
        sorted((ROOT / "tests" / "data" / "bombs").glob("*.gsz"))
    ok = True
    print(f"{'file':34} {'bytes':>6} {'path':7} {'seconds':>8} {'peak MB':>8}  outcome")
    for f in files:
        for native in (True, False):
            r = run(f, native)
            good = r["seconds"] <= LIMIT_S and r["peak_mb"] <= LIMIT_MB
            ok &= good
            print(f"{f.name:34} {f.stat().st_size:>6} {r['path']:7} {r['seconds']:8.3f} {r['peak_mb']:8.0f}  "
                  f"{r['outcome'][:70]}{'' if good else '  <-- over the bound'}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
