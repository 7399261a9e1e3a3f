"""Decode .gsz files with the NumPy reference (GSZ_NATIVE=0's path) and the native accelerator
and check that every field is bit-identical.

    .venv/bin/python bench/compare_paths.py bench/.cache/big.gsz [more.gsz ...]

Prints one line per field and the NumPy decode time; exits 1 if any field differs.
"""
from __future__ import annotations

import sys
import time

import numpy as np

FIELDS = ("positions", "scales", "rotations", "opacities", "sh_dc", "sh_rest")


def compare(path: str) -> bool:
    from gsz.decoder import decode, native
    data = open(path, "rb").read()
    old = native.set_enabled(True)
    try:
        ref = decode(data)
        native.set_enabled(False)
        t = time.perf_counter()
        got = decode(data)
        dt = time.perf_counter() - t
    finally:
        native.set_enabled(old)
    print(f"{path}: {len(got):,} Gaussians, NumPy decode {dt:.3f} s (first in this process)")
    ok = True
    for f in FIELDS:
        a, b = getattr(ref, f), getattr(got, f)
        same = a.dtype == b.dtype and a.shape == b.shape and np.array_equal(
            a.view(np.uint32), b.view(np.uint32))          # bit for bit (NaN and -0 included)
        ok &= same
        print(f"  {f:10s} {'identical' if same else 'DIFFERENT'}")
    return ok


def main(argv=None) -> int:
    paths = (argv if argv is not None else sys.argv[1:])
    if not paths:
        print(__doc__)
        return 2
    return 0 if all([compare(p) for p in paths]) else 1


if __name__ == "__main__":
    sys.exit(main())
