"""PLY read/write speed on the largest shared scene.

    .venv/bin/python bench/bench_ply.py [--scene flowers_daffodils_sh2] [--repeat 3]
"""
import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

SHARED = Path(__file__).resolve().parent.parent.parent / "shared" / "data"


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--scene", default="flowers_daffodils_sh2")
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args()
    path = SHARED / f"{a.scene}.ply"
    if not path.exists():
        print(f"SKIP: {path} not present")
        return 0
    import gsz
    reads, writes = [], []
    with tempfile.TemporaryDirectory() as d:
        for _ in range(a.repeat):
            t = time.perf_counter()
            c = gsz.read_ply(path)
            reads.append(time.perf_counter() - t)
            t = time.perf_counter()
            gsz.write_ply(c, os.path.join(d, "x.ply"))
            writes.append(time.perf_counter() - t)
    print(f"{a.scene}: {len(c):,} Gaussians, {path.stat().st_size / 1e6:.1f} MB, SH {c.sh_degree}")
    print(f"read_ply  best {min(reads):.3f} s  median {sorted(reads)[len(reads) // 2]:.3f} s  (target <= 1 s)")
    print(f"write_ply best {min(writes):.3f} s  median {sorted(writes)[len(writes) // 2]:.3f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
