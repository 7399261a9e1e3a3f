"""Decode speed: NumPy reference vs the native accelerator, whole file and per stage.

    .venv/bin/python bench/bench_decode.py [--scenes a,b] [--files x.gsz ...] [--repeats 3]

Every shared scene (../shared/data/*.ply) is encoded once with ``gsz-encode --reserve 0.8
--bits 12 --blocks 1`` (cached in bench/.cache/decode/, keyed by the scene's size and mtime and ENCODE_ARGS; --files adds
any other .gsz).  For each file and each path (numpy = the reference decoder, what GSZ_NATIVE=0
gives; native = decoder/csrc/):

* whole ``gsz.decoder.decode(path)``: best wall time of --repeats runs and the process CPU time
  of that run (both threads; on an idle 2-core machine wall < CPU when geometry and attributes
  overlap), and Gaussians per second from the wall time;
* stages, run one after the other (no overlap) and timed by the CPU time of the calling thread,
  best of --repeats: container parse + CRCs, geometry (octree decode), attribute entropy
  decoding (RAHT coefficients and scales), SH (codebook, kept vectors, indices, with the
  part's KLT turn and codeword refinement as the decoder reads them), finish (inverse
  RAHT, rotations, float32 fields, positions, the DC colour turn, finiteness checks); with
  --encode also the octree encoder on the decoded voxels (it must reproduce the file's
  geometry payload byte for byte).

Prints a markdown table and writes bench/out/decode.json.  Also prints ``uptime`` before and
after: other jobs on the machine inflate wall times (compare the CPU columns).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from bench_codec import git_commit     # bench/ is the script's folder, first on sys.path

ROOT = Path(__file__).resolve().parent.parent
SHARED = Path(os.environ.get("GSZ_SHARED", ROOT.parent / "shared")) / "data"
CACHE = ROOT / "bench" / ".cache" / "decode"
OUT = ROOT / "bench" / "out" / "decode.json"
ENCODE_ARGS = ["--reserve", "0.8", "--bits", "12", "--blocks", "1"]   # the fixed default
#: the cached files' name tag: the encode arguments, so changing them never reuses a stale file
ENCODE_TAG = "_".join(x.lstrip("-").replace(".", "") for x in ENCODE_ARGS)    # reserve_08_bits_12_...


def uptime() -> str:
    try:
        return subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()
    except OSError:
        return "uptime unavailable"


def encoded_file(ply: Path) -> Path:
    st = ply.stat()
    out = CACHE / f"{ply.stem}_{ENCODE_TAG}_{st.st_size}_{int(st.st_mtime)}.gsz"
    if not out.exists():
        CACHE.mkdir(parents=True, exist_ok=True)
        exe = Path(sys.executable).with_name("gsz-encode")
        cmd = [str(exe), str(ply), "-o", str(out) + ".tmp", *ENCODE_ARGS, "-w"]
        print("encoding:", " ".join(cmd[1:]), file=sys.stderr, flush=True)
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        os.replace(str(out) + ".tmp", out)
    return out


def best_of(fn, repeats: int, clock=time.thread_time):
    best = None
    for _ in range(repeats):
        t = clock()
        r = fn()
        dt = clock() - t
        if best is None or dt < best[0]:
            best = (dt, r)
    return best


def measure(path: Path, repeats: int, encode_too: bool = False, paths=("numpy", "native")) -> dict:
    import gsz.decoder  # noqa: F401  (registers the submodules)
    D = sys.modules["gsz.decoder.decode"]
    from gsz.decoder import native
    from gsz.decoder.attributes import (attributes_from_coefficients, direct_in_point_order, leaf_weights_of,
                                        parse_attributes)
    from gsz.decoder.container import read_container
    from gsz.decoder.geometry import read_geometry_header
    from gsz.decoder.layer import _read_weights as read_weights      # the decoder's own
    from gsz.decoder.layout import CHUNK_ATTR, CHUNK_GEOM, CHUNK_SHCL, CHUNK_SHRF, CHUNK_SHVQ, CHUNK_SHXF, KNOWN_CHUNKS
    from gsz.decoder.pages import small_pages
    from gsz.decoder.sh import part_klt, read_sh, turn_dc

    data = path.read_bytes()
    rows = {}
    for mode in paths:
        if mode == "native" and not native.native_available():
            continue
        native.set_enabled(mode == "native")
        D.decode(data)                                        # warm-up (tables, imports)
        best_wall, best_cpu, n = None, None, 0
        for _ in range(repeats):
            t, c = time.perf_counter(), time.process_time()
            cloud = D.decode(data)
            wall, cpu = time.perf_counter() - t, time.process_time() - c
            if best_wall is None or wall < best_wall:
                best_wall, best_cpu = wall, cpu
            n = len(cloud)
        # stages, sequentially, on the calling thread
        stages = {}
        stages["container"], c = best_of(lambda: read_container(data, known_types=KNOWN_CHUNKS), repeats)
        plan = D.plan_parts(c.chunks, c.header.sh_degree).parts      # (layer, tile) parts
        totals = dict(geometry=0.0, attributes=0.0, sh=0.0, finish=0.0)
        codebooks, klts = {}, {}                                      # per tile
        pages = small_pages()                   # as decode() allocates (decoder/pages.py)
        pages.__enter__()
        for part in plan:
            codebook = codebooks.get(part.tile)
            ch = {t: c.chunks[i].data for t, i in part.chunks.items()}
            gh = read_geometry_header(ch[CHUNK_GEOM], max_points=c.header.num_gaussians)
            dt, codes = best_of(gh.decode_codes, repeats)
            totals["geometry"] += dt
            # the part's RAHT leaf weights (format 1.5): point order of the scales, SH classes
            rwgt = read_weights(ch, gh.num_points)

            def attributes():
                dc, ac, direct = parse_attributes(ch[CHUNK_ATTR], gh.num_points)
                return dc, ac, direct_in_point_order(direct, rwgt)
            dt, (dc, ac, direct) = best_of(attributes, repeats)
            totals["attributes"] += dt
            if c.header.sh_degree > 0:       # as the decoder's layer._read_sh: KLT and SHRF too
                klt, klts[part.tile] = part_klt(ch.get(CHUNK_SHXF), c.header.sh_degree, klts.get(part.tile))
                dt, (_, cb) = best_of(lambda: read_sh(ch[CHUNK_SHVQ], gh.num_points, c.header.sh_degree,
                                                      codebook, ch.get(CHUNK_SHCL), colour_chunk=ch.get(CHUNK_SHXF),
                                                      voxel_classes=None if rwgt is None else rwgt.classes,
                                                      klt=klt, refine_chunk=ch.get(CHUNK_SHRF)),
                                              repeats)
                totals["sh"] += dt
                codebooks[part.tile] = cb if codebook is None else codebook

            def finish():
                attrs = attributes_from_coefficients(dc, ac, direct, codes, gh.depth,
                                                     leaf_weights=leaf_weights_of(rwgt))
                pos = gh.positions(codes)
                turn_dc(ch.get(CHUNK_SHXF), attrs.sh_dc, c.header.sh_degree)
                ok = native.module().all_finite if native.enabled() else (lambda a: np.isfinite(a).all())
                return all(ok(a) for a in (pos, attrs.scales, attrs.rotations, attrs.opacities, attrs.sh_dc))
            dt, _ = best_of(finish, repeats)
            totals["finish"] += dt
            if encode_too:
                from gsz.decoder.morton import morton_decode
                from gsz.encoder.octree import encode_octree
                ijk = morton_decode(codes)
                dt, payload = best_of(lambda: encode_octree(ijk, gh.depth), repeats)
                assert payload == bytes(gh.payload), "octree encoder does not reproduce the file"
                totals["octree_encode"] = totals.get("octree_encode", 0.0) + dt
        pages.__exit__(None, None, None)
        stages.update(totals)
        rows[mode] = dict(seconds=best_wall, cpu_seconds=best_cpu, gaussians=n,
                          gaussians_per_second=n / best_wall, stages=stages)
    native.set_enabled(True)
    return dict(file=str(path), bytes=len(data), layers=1 + max(p.layer for p in plan), parts=len(plan),
                **{"paths": rows})


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", default=None, help="comma-separated scene stems (default: every shared scene)")
    ap.add_argument("--files", nargs="*", default=[], help="extra .gsz files to measure")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--encode", action="store_true",
                    help="also time the octree encoder on the decoded voxels (identical bytes checked)")
    ap.add_argument("--paths", default="numpy,native", help="comma-separated: numpy, native")
    ap.add_argument("--out", default=str(OUT))
    a = ap.parse_args(argv)
    files = []
    if SHARED.exists():
        plys = sorted(SHARED.glob("*.ply"))
        if a.scenes:
            want = set(a.scenes.split(","))
            plys = [p for p in plys if p.stem in want]
        files += [encoded_file(p) for p in plys]
    elif not a.files:
        print(f"no shared scenes in {SHARED} and no --files given", file=sys.stderr)
        return 2
    files += [Path(f) for f in a.files]
    from gsz.decoder import native
    before = uptime()
    print(f"machine: {os.cpu_count()} cores; {before}")
    print(f"native accelerator: {'available' if native.native_available() else native.unavailable_reason()}")
    results = []
    for f in files:
        results.append(measure(f, a.repeats, a.encode, tuple(a.paths.split(","))))
        print(f"measured {f.name}", file=sys.stderr, flush=True)
    after = uptime()
    print(f"after: {after}\n")
    hdr = ("| file | Gaussians | MB | path | decode s (wall) | CPU s | M Gaussians/s | container | "
           "geometry | attributes | SH | finish |" + (" octree encode |" if a.encode else ""))
    print(hdr)
    print("|" + "---|" * (hdr.count("|") - 1))
    for r in results:
        for mode, p in r["paths"].items():
            s = p["stages"]
            print(f"| {Path(r['file']).name.split('_' + ENCODE_TAG)[0]} | {p['gaussians']:,} | {r['bytes'] / 1e6:.2f} | "
                  f"{mode} | {p['seconds']:.3f} | {p['cpu_seconds']:.3f} | {p['gaussians_per_second'] / 1e6:.2f} | "
                  f"{s['container']:.3f} | {s['geometry']:.3f} | {s['attributes']:.3f} | {s['sh']:.3f} | "
                  f"{s['finish']:.3f} |" + (f" {s['octree_encode']:.3f} |" if a.encode else ""))
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    commit = git_commit()
    Path(a.out).write_text(json.dumps(dict(command=" ".join([Path(sys.argv[0]).name] + (argv or sys.argv[1:])),
                                           commit=commit, machine=f"{os.cpu_count()} cores",
                                           uptime_before=before, uptime_after=after, results=results), indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
