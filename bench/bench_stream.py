"""Progressive streaming benchmark: what layers cost and what they give.

    .venv/bin/python bench/bench_stream.py [--scenes a,b] [--ratio 12] [--layers 3]
                                           [--first-layer 0.1] [--width 800] [--noise]
                                           [--out bench/out/stream.json]

Per scene (and noised variant), at the budget PLY size / ratio:
* a layered file (size search over every layer's groups at once) and single-layer files at the
  budget and at 95 % of it;
* bytes until layer 0 is decodable, as a fraction of the file (target <= 15 %);
* overhead: the single-layer size with the layered file's test PSNR, interpolated in log-bytes
  between the 95 % and 100 % single-layer files (target: layered <= 5 % more bytes);
* PSNR after each layer on the test views (bytes received -> PSNR curve, one PNG per scene in
  bench/out/stream_<scene>.png);
* decode throughput: whole-file ``decode`` vs ``StreamDecoder`` fed 64 KiB pieces (best of 3).
Rows are appended to --out as they finish (a rerun skips finished scene/variant pairs).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SHARED = ROOT.parent / "shared" / "data"
sys.path.insert(0, str(ROOT / "bench"))
from bench_codec import SCENES, add_noise  # noqa: E402


def plot(scene, rows, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(5.2, 3.6), dpi=110)
    for r in rows:
        xs = [l["decodable_at"] / 1e6 for l in r["layer_psnr"]]
        ys = [l["psnr"] for l in r["layer_psnr"]]
        ax.plot(xs, ys, "o-", label=f"{r['layers']} layers ({r['variant']})")
        ax.plot([r["single_bytes"] / 1e6], [r["single_psnr"]], "s", label=f"single layer ({r['variant']})")
    ax.set_xlabel("bytes received (MB)")
    ax.set_ylabel("test PSNR (dB)")
    ax.set_title(f"{scene}: progressive decoding")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def overhead_estimate(layered_bytes, psnr, lo, hi):
    """(overhead, how) of a layered file of ``layered_bytes`` reaching ``psnr``, against the
    single-layer points lo = (bytes, psnr) at 95 % and hi at 100 % of the budget.

    * layered PSNR >= single at the same budget: the layered file costs nothing extra at this
      fidelity (overhead reported as <= the size difference, "bound");
    * between the two points: single-layer bytes at that PSNR interpolated in log-bytes;
    * below the 95 % point: extrapolated (marked, less reliable);
    * flat single-layer curve (< 0.05 dB between the points): undefined (None)."""
    (b0, p0), (b1, p1) = lo, hi
    if psnr >= p1:
        return layered_bytes / b1 - 1, "bound"
    if p1 - p0 < 0.05:
        return None, "flat"
    t = (psnr - p0) / (p1 - p0)
    eq = math.exp(math.log(b0) + t * (math.log(b1) - math.log(b0)))
    return layered_bytes / eq - 1, "interpolated" if t >= 0 else "extrapolated"


def _fmt_overhead(r) -> str:
    if r["overhead"] is None:
        return "n/a (flat)"
    sign = "<= " if r["overhead_how"] == "bound" else ""
    return f"{sign}{100 * r['overhead']:+.2f} %" + (" (extrap.)" if r["overhead_how"] == "extrapolated" else "")


def time_decodes(data):
    from gsz.decoder import StreamDecoder, decode
    whole, stream = [], []
    for _ in range(3):
        t = time.perf_counter()
        decode(data)
        whole.append(time.perf_counter() - t)
        t = time.perf_counter()
        dec = StreamDecoder()
        for s in range(0, len(data), 65536):
            dec.feed(data[s:s + 65536])
        dec.finish()
        stream.append(time.perf_counter() - t)
    return min(whole), min(stream)


def fixed_configuration(a) -> int:
    """Layered vs single-layer bytes at ``--reserve 0.8 --bits B`` (no search noise)."""
    import gsz
    from gsz.encoder.pipeline import EncodeOptions, compute_train_importance, encode
    print("| scene | layers | bytes | vs 1 layer | geometry B | RAHT B | scales B | layer ends (fraction of the file) |")
    print("|---|---|---|---|---|---|---|---|")
    for scene in a.scenes.split(","):
        path = SHARED / f"{scene}.ply"
        if not path.exists():
            continue
        cloud = gsz.read_ply(path)
        imp = compute_train_importance(cloud, EncodeOptions(train_views=8, importance_width=200))
        base = None
        for layers in (1, 2, 3, 4):
            r = encode(cloud, EncodeOptions(bits=a.fixed_bits, layers=layers, first_layer=a.first_layer),
                       importance=imp)
            c = r.report.components
            base = base or len(r.data)
            rel = "—" if layers == 1 else f"{100 * (len(r.data) / base - 1):+.2f} %"
            ends = ", ".join(f"{x['decodable_fraction']:.3f}" for x in r.report.layers)
            print(f"| {scene} | {layers} | {len(r.data):,} | {rel} | {c['geometry']:,} | {c['raht_bytes']:,} | "
                  f"{c['scale_bytes']:,} | {ends} |", flush=True)
    return 0


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--scenes", default=",".join(SCENES))
    ap.add_argument("--ratio", type=float, default=12.0)
    ap.add_argument("--layers", type=int, default=3)
    ap.add_argument("--first-layer", type=float, default=0.1)
    ap.add_argument("--noise", action="store_true")
    ap.add_argument("--width", type=int, default=800)
    ap.add_argument("--out", default=str(ROOT / "bench" / "out" / "stream.json"))
    ap.add_argument("--redo", action="store_true",
                    help="re-measure the layered file of finished scene/budget rows (after a codec "
                         "change), keeping their single-layer references")
    ap.add_argument("--fixed-bits", type=int, default=None, metavar="B",
                    help="instead: bytes of 1..4-layer files at a fixed configuration (reserve 0.8, "
                         "uniform B bits) and where they go, per scene")
    a = ap.parse_args(argv)
    if not SHARED.exists():
        print(f"SKIP: {SHARED} not present")
        return 0
    if a.fixed_bits is not None:
        return fixed_configuration(a)
    import gsz
    from gsz.decoder import iter_layers
    from gsz.evaluation.cameras import load_cameras
    from gsz.evaluation.evaluate import evaluate, render_views
    from gsz.encoder.pipeline import EncodeOptions, compute_train_importance
    from gsz.encoder.search import SearchOptions, encode_to_budget

    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    rows = json.loads(out.read_text()) if out.exists() else []
    for r in rows:              # rows written before overhead_estimate existed
        if "overhead_how" not in r:
            r["overhead"], r["overhead_how"] = overhead_estimate(
                r["layered_bytes"], r["layered_psnr"], (r["single95_bytes"], r["single95_psnr"]),
                (r["single_bytes"], r["single_psnr"]))
            r.pop("equivalent_single_bytes", None)
    key_of = lambda r: (r["scene"], r["variant"], r["layers"], r["first_layer"], r["ratio"])  # noqa: E731
    wanted = {(s_, v, a.layers, a.first_layer, a.ratio) for s_ in a.scenes.split(",") for v in ("grid", "noised")}
    stale = [r for r in rows if a.redo and key_of(r) in wanted]
    rows = [r for r in rows if r not in stale]
    done = {key_of(r) for r in rows}
    for scene in a.scenes.split(","):
        path = SHARED / f"{scene}.ply"
        if not path.exists():
            continue
        ply_bytes = os.path.getsize(path)
        target = int(ply_bytes / a.ratio)
        base = gsz.read_ply(path)
        variants = [("grid", base)] + ([("noised", add_noise(base))] if a.noise else [])
        for variant, cloud in variants:
            if (scene, variant, a.layers, a.first_layer, a.ratio) in done:
                continue
            print(f"== {scene} ({variant}): {len(cloud):,} Gaussians, target {target:,} B", file=sys.stderr)
            cams = load_cameras(None, cloud, n_test=8, width=a.width).test
            refs = render_views(cloud, cams)
            imp = compute_train_importance(cloud, EncodeOptions())
            runs = {}
            prior = next((r for r in rows + stale if (r["scene"], r["variant"], r["ratio"]) == (scene, variant, a.ratio)), None)
            for key, layers, t in (("layered", a.layers, target), ("single", 1, target),
                                   ("single95", 1, int(0.95 * target))):
                if key != "layered" and prior is not None:
                    continue            # single-layer references of this scene/budget already measured
                t0 = time.perf_counter()
                r = encode_to_budget(cloud, t, importance=imp, options=SearchOptions(
                    layers=layers, first_layer=a.first_layer))
                secs = time.perf_counter() - t0
                ev = evaluate(refs, r.cloud, cams)
                runs[key] = (r, ev, secs)
                print(f"   {key}: {len(r.data):,} B, test PSNR {ev['psnr']:.2f} dB, {secs:.0f} s", file=sys.stderr)
            lay, ev_l, secs_l = runs["layered"]
            layer_psnr = []
            for u, row in zip(iter_layers(lay.data), lay.report.layers):
                e = evaluate(refs, u.cloud, cams)
                layer_psnr.append({"layer": u.layer, "gaussians": len(u.cloud), "decodable_at": row["decodable_at"],
                                   "fraction": row["decodable_at"] / len(lay.data), "psnr": e["psnr"], "ssim": e["ssim"]})
            if prior is None:
                single = {"single_bytes": len(runs["single"][0].data), "single_psnr": runs["single"][1]["psnr"],
                          "single_ssim": runs["single"][1]["ssim"], "single_reserve": runs["single"][0].report.reserve,
                          "single95_bytes": len(runs["single95"][0].data), "single95_psnr": runs["single95"][1]["psnr"]}
            else:
                single = {k: prior[k] for k in ("single_bytes", "single_psnr", "single_ssim", "single_reserve",
                                                "single95_bytes", "single95_psnr")}
            ovh, how = overhead_estimate(len(lay.data), ev_l["psnr"], (single["single95_bytes"], single["single95_psnr"]),
                                         (single["single_bytes"], single["single_psnr"]))
            t_whole, t_stream = time_decodes(lay.data)
            row = {"scene": scene, "variant": variant, "ratio": a.ratio, "layers": a.layers,
                   "first_layer": a.first_layer, "target": target, "gaussians": len(lay.cloud),
                   "layered_bytes": len(lay.data), "layered_psnr": ev_l["psnr"], "layered_ssim": ev_l["ssim"],
                   "layered_reserve": lay.report.reserve, **single, "overhead": ovh, "overhead_how": how,
                   "layer0_fraction": layer_psnr[0]["fraction"], "layer_psnr": layer_psnr,
                   "decode_s": t_whole, "stream_decode_s": t_stream,
                   "stream_vs_whole": t_stream / t_whole, "search_s": secs_l}
            print(f"   layer 0 after {100 * row['layer0_fraction']:.1f} % of the bytes; overhead "
                  f"{_fmt_overhead(row)}; PSNR per layer "
                  + " / ".join(f"{l['psnr']:.2f}" for l in layer_psnr)
                  + f"; decode {t_whole:.2f} s whole, {t_stream:.2f} s streamed", file=sys.stderr)
            rows.append(row)
            out.write_text(json.dumps(rows, indent=1))
        scene_rows = [r for r in rows if r["scene"] == scene and r["layers"] == a.layers
                      and r["first_layer"] == a.first_layer]
        if scene_rows:
            plot(scene, scene_rows, out.parent / f"stream_{scene}.png")
    print(f"{'scene':28} {'var':6} {'bytes':>10} {'L0 %':>6} {'overhead':>9} {'PSNR single':>11} "
          f"{'PSNR layered':>12}  per-layer PSNR            decode s (whole/stream)")
    for r in rows:
        print(f"{r['scene']:28} {r['variant']:6} {r['layered_bytes']:>10,} {100 * r['layer0_fraction']:6.1f} "
              f"{_fmt_overhead(r):>9} {r['single_psnr']:11.2f} {r['layered_psnr']:12.2f}  "
              + " / ".join(f"{l['psnr']:.2f}" for l in r["layer_psnr"])
              + f"   {r['decode_s']:.2f} / {r['stream_decode_s']:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
