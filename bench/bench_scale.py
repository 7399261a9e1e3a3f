"""Real-size scenes: size-targeted encodes of 1-6 M Gaussians, single-tile vs tiled, local vs Ray.

    .venv/bin/python bench/bench_scale.py --scene bench/.cache/big_1.2M_sh3.ply --ratio 12 \
        [--variants single,tiled,ray] [--tile-gaussians 300000] [--eval] [--out bench/out/scale.json]
    .venv/bin/python bench/bench_scale.py --add-eval bench/out/scale_6M.json   # its test scores later
    .venv/bin/python bench/bench_scale.py --scene ... --ratios 18,12,8 --eval   # cost of tiling

Generate the scenes with bench/big_scene.py (e.g. ``--gaussians 1.2M --sh 3 [--noise]``).
Every variant runs ``gsz-encode SCENE --ratio R --json`` in its own process under
``/usr/bin/time -v``, one after the other (time it on an idle machine), and records: wall and
CPU seconds, peak RSS, bytes against the target, the chosen reserve/depth, train PSNR, seconds
and peak RSS per stage (the report's ``seconds`` / ``memory``), tiles; then decodes each file
with ``gsz-decode --json`` on the native and the NumPy path (Gaussians per second, best of 2).
``--eval`` adds gsz-eval's test-view PSNR/SSIM (8 views at 800 px: minutes per file on 2
cores).  Variants: ``single`` (--tile-gaussians 0), ``tiled`` (--tile-gaussians N, local
worker processes), ``ray`` (the same with --executor ray: its bytes must equal ``tiled``'s).
Prints a markdown table and writes the JSON.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

from bench_codec import git_commit     # bench/ is the script's folder, first on sys.path

ROOT = Path(__file__).resolve().parent.parent
BIN = Path(sys.executable).parent
OUT_DIR = ROOT / "bench" / ".cache" / "scale"


def timed(cmd: list, env=None) -> tuple[subprocess.CompletedProcess, dict]:
    """Run ``cmd`` under /usr/bin/time -v: (process, {wall_s, cpu_s, peak_rss_mb})."""
    t0 = time.perf_counter()
    p = subprocess.run(["/usr/bin/time", "-v", *cmd], capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    def field(name):
        m = re.search(rf"{re.escape(name)}: ([0-9.:]+)", p.stderr)
        return float(m.group(1)) if m else float("nan")
    return p, {"wall_s": round(wall, 1), "cpu_s": round(field("User time (seconds)") + field("System time (seconds)"), 1),
               "peak_rss_mb": round(field("Maximum resident set size (kbytes)") / 1024)}


def decode_speed(path: Path, native: bool) -> float:
    env = dict(os.environ, GSZ_NATIVE="1" if native else "0")
    best = 0.0
    for _ in range(2):
        p = subprocess.run([str(BIN / "gsz-decode"), str(path), "-o", os.devnull, "--json"],
                           capture_output=True, text=True, env=env)
        if p.returncode != 0:
            raise SystemExit(f"gsz-decode failed: {p.stderr.strip()}")
        best = max(best, json.loads(p.stdout)["gaussians_per_second"] or 0)
    return best


def run_variant(name: str, scene: Path, ratio: float, args) -> dict:
    # one ratio: the name the decode benchmark reads; several: each ratio's own file
    out = output_path(name, scene, ratio, bool(args.ratios), args.sh_colour)
    extra = {"single": ["--tile-gaussians", "0"],
             "tiled": ["--tile-gaussians", str(args.tile_gaussians)],
             "ray": ["--tile-gaussians", str(args.tile_gaussians), "--executor", "ray"]}[name]
    if args.sh_colour:
        extra += ["--sh-colour", args.sh_colour]
    cmd = [str(BIN / "gsz-encode"), str(scene), "-o", str(out), "--ratio", f"{ratio:g}", "--json", "-w", *extra]
    print(f"[{name}] {' '.join(cmd[1:])}", file=sys.stderr, flush=True)
    p, t = timed(cmd)
    if p.returncode != 0:
        raise SystemExit(f"{name}: gsz-encode failed:\n{p.stderr[-2000:]}")
    r = json.loads(p.stdout)
    data = out.read_bytes()
    row = {"variant": name, "ratio": ratio, "sh_colour": r.get("sh_colour"), **t, "bytes": r["bytes"], "target": r.get("target_bytes"),
           "of_target_pct": round(100 * r["bytes"] / r["target_bytes"], 2) if r.get("target_bytes") else None,
           "reserve": r.get("reserve"), "depth": r.get("depth"), "train_psnr": r.get("train_psnr"),
           "voxels": r.get("voxels"),
           "sha256": hashlib.sha256(data).hexdigest()[:16],
           "stage_seconds": {k: round(v, 1) for k, v in r.get("seconds", {}).items()},
           "stage_peak_mb": r.get("memory", {})}
    info = subprocess.run([str(BIN / "gsz-info"), str(out), "--json"], capture_output=True, text=True)
    row["tiles"] = len(json.loads(info.stdout)["tiles"])
    row["decode_native_gps"] = round(decode_speed(out, True))
    row["decode_numpy_gps"] = round(decode_speed(out, False))
    if args.eval:
        row.update(test_scores(scene, out))
    return row


def output_path(name: str, scene: Path, ratio: float, per_ratio: bool, sh_colour: str | None) -> Path:
    """Where run_variant writes a variant's file (``per_ratio``: the run named --ratios)."""
    out = OUT_DIR / f"{scene.stem}_{name}{f'_{ratio:g}x' if per_ratio else ''}.gsz"
    return out.with_name(f"{out.stem}_{sh_colour}.gsz") if sh_colour else out


def test_scores(scene: Path, out: Path) -> dict:
    """gsz-eval's test PSNR / SSIM of ``out`` against ``scene`` (empty when it fails)."""
    e = subprocess.run([str(BIN / "gsz-eval"), str(scene), str(out), "--json"], capture_output=True, text=True)
    if e.returncode != 0:
        print(f"gsz-eval failed on {out}: {e.stderr.strip()[-500:]}", file=sys.stderr)
        return {}
    ev = json.loads(e.stdout)
    return {"test_psnr": ev.get("psnr"), "test_ssim": ev.get("ssim")}


def add_eval(path: Path) -> int:
    """--add-eval: test scores for the rows of an earlier run's JSON, from its files (which must
    still be that run's: same sha256); its command gains the step."""
    res = json.loads(path.read_text())
    scene, cmd = Path(res["scene"]), res.get("command", "")
    for r in res["rows"]:
        if r.get("test_psnr") is not None:
            continue
        out = output_path(r["variant"], scene, r.get("ratio", res["ratio"]), "--ratios" in cmd,
                          r.get("sh_colour") if "--sh-colour" in cmd else None)
        if not out.exists() or hashlib.sha256(out.read_bytes()).hexdigest()[:16] != r["sha256"]:
            raise SystemExit(f"{out}: missing, or not the file of this run (sha256 {r['sha256']})")
        print(f"[eval] {out}", file=sys.stderr, flush=True)
        r.update(test_scores(scene, out))
    name = path.relative_to(ROOT) if path.is_relative_to(ROOT) else path
    res["command"] = f"{cmd} && bench/bench_scale.py --add-eval {name}"
    path.write_text(json.dumps(res, indent=1) + "\n")
    return 0


DEFAULT_OUT = ROOT / "bench" / "out" / "scale.json"


def held_scene(path: Path):
    """The scene whose rows the JSON at ``path`` holds, or None (no file, or not a scale JSON)."""
    try:
        return json.loads(path.read_text()).get("scene")
    except (OSError, ValueError, AttributeError):
        return None


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scene", type=Path)
    p.add_argument("--ratio", type=float, default=12.0)
    p.add_argument("--ratios", default=None, help="comma-separated ratios, each run for every variant "
                   "(default: --ratio alone)")
    p.add_argument("--variants", default="single,tiled")
    p.add_argument("--tile-gaussians", type=int, default=300_000)
    p.add_argument("--eval", action="store_true")
    p.add_argument("--sh-colour", default=None, help="gsz-encode's --sh-colour (default: its own, auto)")
    p.add_argument("--out", type=Path, default=None,
                   help="JSON to write (default bench/out/scale.json, which a run of another scene "
                        "may not replace: the results page lists the per-scene JSONs' commands "
                        "without their --out)")
    p.add_argument("--add-eval", type=Path, metavar="JSON",
                   help="add test scores to an earlier run's JSON from its files (nothing is encoded)")
    a = p.parse_args(argv)
    if a.add_eval:
        return add_eval(a.add_eval.resolve())
    if a.scene is None:
        p.error("--scene is required (or --add-eval JSON)")
    if a.out is None:
        a.out = DEFAULT_OUT
        held = held_scene(a.out)
        if held is not None and Path(held).name != a.scene.name:
            p.error(f"{a.out} holds the rows of {held}, not {a.scene}: pass --out (the results page "
                    f"names each scene's JSON) so a run does not replace another scene's rows")
    OUT_DIR.mkdir(parents=True, exist_ok=True)
    uptime = subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()
    ratios = [float(x) for x in a.ratios.split(",")] if a.ratios else [a.ratio]
    rows = [run_variant(v.strip(), a.scene, ratio, a)
            for ratio in ratios for v in a.variants.split(",") if v.strip()]
    commit = git_commit()
    res = {"scene": str(a.scene), "ratio": a.ratio, "tile_gaussians": a.tile_gaussians, "commit": commit,
           "cores": os.cpu_count(), "uptime_before": uptime, "rows": rows,
           "command": "bench/bench_scale.py " + " ".join(argv if argv is not None else sys.argv[1:])}
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(res, indent=1) + "\n")
    cols = ["variant", "ratio", "tiles", "wall_s", "cpu_s", "peak_rss_mb", "bytes", "of_target_pct", "reserve", "depth",
            "train_psnr", "test_psnr", "decode_native_gps", "decode_numpy_gps", "sha256"]
    print("| " + " | ".join(cols) + " |\n|" + "---|" * len(cols))
    for r in rows:
        print("| " + " | ".join(f"{r.get(c):.2f}" if isinstance(r.get(c), float) else str(r.get(c, ""))
                                for c in cols) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
