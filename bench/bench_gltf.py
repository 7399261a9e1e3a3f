"""glTF check and benchmark: gsz's KHR_gaussian_splatting files against independent tools.

    .venv/bin/python bench/bench_gltf.py [--install] [--scenes houseplant,jug,...]
                                         [--out bench/out/gltf.json]

--install first runs ``npm install --prefix bench/.peers`` of the pinned tools
(bench/gltf_checks.py: Khronos gltf-validator, three.js, PlayCanvas splat-transform; needs node
and npm, and the npm registry or a cache); without it the tools already there are used and the
missing ones are reported as such.  Per scene (the two samples in tests/data, plus any named
scene of ../shared/data):

* sizes: PLY, plain .glb (float32 + COLOR_0), .gsz and the .glb carrying it (a fixed 12-bit
  encode) -- the wrapper's overhead in bytes;
* times: write / read of the plain .glb (best of 3), decode of the .gsz vs the .glb;
* round trip PLY -> .glb -> PLY: the largest differences (GLTF.md §1.3);
* validator: errors, warnings, and those not explained by its known limitation
  (KhronosGroup/glTF-Validator#252), for the plain .glb/.gltf, the gsz .glb and splat-transform's .glb;
* three.js: centres / covariances / 8-bit colours / SH bytes against the PLY's;
* splat-transform: its .glb of the PLY read by gsz against the PLY.
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "bench"))
import gltf_checks  # noqa: E402

SAMPLES = {"houseplant": ROOT / "tests" / "data" / "houseplant_sh0_20k.ply",
           "jug": ROOT / "tests" / "data" / "measuring_jug_sh3_12k.ply"}


def best_of(fn, n=3):
    best, out = float("inf"), None
    for _ in range(n):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def scene_row(name: str, ply: Path, work: Path, tools: bool) -> dict:
    import gsz
    from gsz.decoder import decode
    from gsz.decoder.gltf import gltf_bytes, gsz_glb_bytes, read_gltf_bytes
    from gsz.encoder.pipeline import EncodeOptions, encode
    cloud = gsz.read_ply(ply)
    t_write, plain = best_of(lambda: gltf_bytes(cloud))
    t_read, back = best_of(lambda: read_gltf_bytes(plain))
    (work / f"{name}.glb").write_bytes(plain)
    gsz.save(cloud, work / f"{name}.gltf")
    payload = encode(cloud, EncodeOptions(bits=12)).data
    wrapped = gsz_glb_bytes(payload)
    (work / f"{name}_gsz.glb").write_bytes(wrapped)
    t_gsz, a = best_of(lambda: decode(payload))
    t_glb, b = best_of(lambda: decode(wrapped))
    row = {"scene": name, "gaussians": len(cloud), "sh_degree": cloud.sh_degree,
           "bytes": {"ply": ply.stat().st_size, "plain_glb": len(plain),
                     "plain_gltf": (work / f"{name}.gltf").stat().st_size,
                     "gsz": len(payload), "gsz_glb": len(wrapped), "glb_overhead": len(wrapped) - len(payload)},
           "seconds": {"plain_glb_write": round(t_write, 4), "plain_glb_read": round(t_read, 4),
                       "decode_gsz": round(t_gsz, 4), "decode_gsz_glb": round(t_glb, 4)},
           "round_trip": gltf_checks.compare_clouds(back, cloud),
           "glb_decodes_as_gsz": bool(a.equals(b))}
    if not tools:
        return row
    st = gltf_checks.splat_transform_glb(ply, work / f"{name}_splat_transform.glb")
    files = [work / f"{name}.glb", work / f"{name}.gltf", work / f"{name}_gsz.glb", st]
    row["validator"] = {Path(r["file"]).name: {"errors": r["numErrors"], "warnings": r["numWarnings"],
                                               "known_limitation": sum(map(gltf_checks.known_limitation, r["messages"])),
                                               "unexplained": [m["code"] for m in gltf_checks.unexplained(r)]}
                        for r in gltf_checks.validate(files)}
    row["three_js"] = gltf_checks.compare_three(gltf_checks.three_load(files[0], work / f"{name}_three"), cloud)
    row["splat_transform_read_by_gsz"] = gltf_checks.compare_clouds(gsz.load(st), cloud)
    return row


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--install", action="store_true", help="npm install the pinned tools into bench/.peers first")
    p.add_argument("--scenes", default="houseplant,jug",
                   help="comma-separated: houseplant, jug, or PLY names in ../shared/data")
    p.add_argument("--out", default=str(ROOT / "bench" / "out" / "gltf.json"))
    a = p.parse_args(argv)
    install = None
    if a.install:
        ok, log = gltf_checks.install()
        install = {"ok": ok, "log_tail": log[-600:]}
        print(f"npm install into bench/.peers: {'ok' if ok else 'FAILED'}", file=sys.stderr)
    missing = gltf_checks.missing()
    tools = not missing
    if missing:
        print(f"independent tools missing ({', '.join(missing)}): sizes, times and round trips only",
              file=sys.stderr)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name in a.scenes.split(","):
            ply = SAMPLES.get(name) or ROOT.parent / "shared" / "data" / name
            if not ply.exists():
                print(f"{name}: not found, skipped", file=sys.stderr)
                continue
            rows.append(scene_row(name if name in SAMPLES else ply.stem, ply, Path(tmp), tools))
            print(json.dumps(rows[-1]), file=sys.stderr)
    result = {"tools": {k: v for k, v in gltf_checks.PINS.items()} if tools else {"missing": missing},
              "install": install, "scenes": rows}
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(result, indent=1) + "\n")
    print(f"wrote {a.out}", file=sys.stderr)
    bad = [r["scene"] for r in rows if not r["glb_decodes_as_gsz"] or r["round_trip"]["logits_over_bound"] > 1
           or any(v["unexplained"] for v in r.get("validator", {}).values())]
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
