"""Time and peak RSS of decoding each hostile file of tests/data/bombs/ on both decoder paths
(issue 19: each must be decoded or rejected within 5 s and 1.5 GB, with default limits).

    .venv/bin/python bench/bench_bombs.py [--max-gaussians N] [--amplified] [more.gsz ...]

One fresh process per (file, path, limit), so the peak RSS is that decode's own; each runs under
an 8 GiB address-space cap and a 120 s timeout, so a regression shows as a row, not a dead
machine.  ``--max-gaussians N`` adds a row per file and path decoded with that explicit limit,
which replaces the default Gaussians-per-byte limit (GSZ.md §11): the checks behind it (ChannelSet
C and L, octree before attributes, model counts, body sizes, lanes) then decide, and a valid bomb
decodes.  ``--amplified`` adds the larger bombs ``make_bombs.amplified()`` builds (written to a
temporary folder, not committed).  Exits 1 if any default-limit row misses the 5 s / 1.5 GB bound.
"""
from __future__ import annotations

import argparse
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
limit = int(sys.argv[2]) if len(sys.argv) > 2 else None
t = time.perf_counter()
try:
    out = f"decoded {len(decode(sys.argv[1], max_gaussians=limit) if limit else decode(sys.argv[1])):,} Gaussians"
except GszError as e:
    out = f"{type(e).__name__}: {str(e).split(': ', 1)[-1]}"
except MemoryError:
    out = "MemoryError"
print(json.dumps({"path": active_path(), "seconds": time.perf_counter() - t, "outcome": out,
                  "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def run(path: Path, native: bool, max_gaussians: int | None = None) -> dict:
    """One decode of ``path`` in a fresh process: path, seconds, peak_mb, outcome."""
    env = {**os.environ, "GSZ_NATIVE": "1" if native else "0"}
    args = [sys.executable, "-c", CHILD, str(path)] + ([str(max_gaussians)] if max_gaussians else [])
    try:
        p = subprocess.run(args, capture_output=True, text=True, env=env, timeout=120)
        return json.loads(p.stdout.strip().splitlines()[-1])
    except (subprocess.TimeoutExpired, IndexError, ValueError):
        return {"path": "native" if native else "numpy", "seconds": float("inf"), "peak_mb": float("nan"),
                "outcome": "timeout or crash"}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("files", nargs="*", type=Path, help="files to decode (default: tests/data/bombs/*.gsz)")
    p.add_argument("--max-gaussians", type=int, default=None, metavar="N",
                   help="also decode each file with this explicit limit")
    p.add_argument("--amplified", action="store_true", help="also the larger, uncommitted bombs")
    a = p.parse_args(argv)
    files = a.files or sorted((ROOT / "tests" / "data" / "bombs").glob("*.gsz"))
    if a.amplified:
        # built in a child process: building them here would raise this process's peak RSS,
        # which the decode children inherit in ru_maxrss
        import tempfile
        tmp = Path(tempfile.mkdtemp(prefix="gsz-bombs-"))
        subprocess.run([sys.executable, str(ROOT / "tests" / "data" / "bombs" / "make_bombs.py"), "--amplified",
                        str(tmp)], check=True, capture_output=True)
        files += sorted(tmp.glob("*.gsz"))
    limits = [None] + ([a.max_gaussians] if a.max_gaussians else [])
    ok = True
    print(f"{'file':32} {'bytes':>6} {'limit':>9} {'path':7} {'seconds':>8} {'peak MB':>8}  outcome")
    for f in files:
        for limit in limits:
            for native in (True, False):
                r = run(f, native, limit)
                good = r["seconds"] <= LIMIT_S and r["peak_mb"] <= LIMIT_MB
                ok &= good or limit is not None
                label = "default" if limit is None else f"2^{limit.bit_length() - 1}" if limit & (limit - 1) == 0 \
                    else f"{limit:,}"
                print(f"{f.name:32} {f.stat().st_size:>6} {label:>9} {r['path']:7} {r['seconds']:8.3f} "
                      f"{r['peak_mb']:8.0f}  {r['outcome'][:74]}{'' if good else '  <-- over the bound'}", flush=True)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
