"""Current-results pages: one markdown page per topic in docs/results/, made from bench/out/*.json.

    .venv/bin/python bench/results.py            # write docs/results/*.md
    .venv/bin/python bench/results.py --check    # exit 1 when the committed pages are not what it writes

Every figure on a page is a value of a committed JSON file (formatted, counted or compared, never
typed in); every page names, per JSON, the command, commit and machine that made it, as recorded in
the JSON.  Where a JSON does not record one, the page says "not recorded" and, where the run's
notes (kept in git history) named it, quotes them from ``NOTES`` below.  Same JSON, same pages:
nothing here reads the clock, the machine or git.  Standard library only.

Decisions and the evidence behind them are short records in docs/design/; history is git's.
"""
from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
JSON_DIR = ROOT / "bench" / "out"
PAGES_DIR = ROOT / "docs" / "results"
REGEN = ".venv/bin/python bench/results.py"

#: What the run notes (bench/RESULTS.md, now in git history) said about JSON files that do not
#: record their own command, commit or machine.  Quoted as notes, never as recorded values.
VM = "2-core VM (AMD EPYC)"
NOTES = {
    "codec.json": dict(command=".venv/bin/python bench/bench_codec.py --noise --bits 8,10,12 --blocks 1,80",
                       commit="a9d09ba", machine=VM + ", idle", when="2026-12-02 06:36-06:53 UTC"),
    "done_means_codec.json": dict(command=".venv/bin/python bench/done_means_codec.py"),
    "done_means_codec_noised.json": dict(command=".venv/bin/python bench/done_means_codec.py --noised"),
    "decode.json": dict(commit="a9d09ba (the encoded files)", machine=VM + ", idle; decode.log: 2 cores",
                        when="2026-12-02 06:50 UTC"),
    "eval_views.json": dict(command=".venv/bin/python bench/bench_eval_views.py", machine=VM + ", idle",
                            when="2026-12-02"),
    "eval_views_losses.json": dict(command=".venv/bin/python bench/bench_eval_views.py --points "
                                   "showroom_lacadiere_crop_sh0:noised:12,houseplant_sh0:grid:40,"
                                   "measuring_jug_sh3:noised:12", machine=VM + ", idle", when="2026-12-02"),
    "loss_proxy.json": dict(command=".venv/bin/python bench/bench_loss_proxy.py --scenes "
                            "houseplant_sh0,measuring_jug_sh3 --count 12"),
    "loss_proxy_jug60.json": dict(command="the same on measuring_jug_sh3 with --ratio 60"),
    "search_scaling.json": dict(command=".venv/bin/python bench/bench_search.py --scenes none --scaling "
                                "--fractions 0.125,0.25,0.5,1", commit="390a095", machine=VM + ", idle",
                                when="2026-12-02 05:43 UTC"),
    "search_above_ceiling.json": dict(command=".venv/bin/python bench/bench_search.py --scenes "
                                      "measuring_jug_sh3 --ratios 4,6 --noise", commit="fb9cefb",
                                      machine=VM + ", idle", when="2026-12-02 02:54-03:04 UTC"),
    "stream.json": dict(command=".venv/bin/python bench/bench_stream.py", commit="71b11a3",
                        machine=VM + ", a test run beside it for ~3 min", when="2026-12-02 05:15-05:29 UTC"),
    "golden.json": dict(command="golden.py's usage: `bench/golden.py --write bench/out/golden.json`",
                        commit="the file's git log"),
}

NA = "not recorded"


# --- formatting -------------------------------------------------------------------------------

def n(x) -> str:
    return f"{int(x):,}"


def f1(x) -> str:
    return "–" if x is None else f"{x:.1f}"


def f2(x) -> str:
    return "–" if x is None else f"{x:.2f}"


def mb(x) -> str:
    return f"{x / 1e6:.2f}"


def pct(x, digits=1) -> str:
    return f"{100 * x:+.{digits}f} %"


def table(head: list, rows: list) -> list:
    out = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    out += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return out + [""]


def code(s) -> str:
    return f"`{s}`"


def cell(name: str, key: str, recorded) -> str:
    """A provenance cell: the recorded value, else what the notes said ('... (notes)'), else
    'not recorded'."""
    if recorded:
        # a command's --out path says nothing about the run (the JSON is named beside it)
        # ... nor does the interpreter (every command runs with the checkout's .venv/bin/python)
        return code(re.sub(r" --out \S+", "", re.sub(r"^\.venv/bin/python ", "", recorded))) \
            if key == "command" else str(recorded)
    noted = NOTES.get(name, {}).get(key)
    if not noted:
        return NA
    return (code(noted) if key == "command" and noted.startswith(".venv") else noted) + " (notes)"


def header(title: str, what: str, sources: list) -> list:
    """Title, one line on what the page shows, and the provenance table.  ``sources``: dicts with
    json (file name), label (optional), command, commit, machine, when (recorded values or None)."""
    lines = [f"# {title}", "", what, "",
             f"Generated by `bench/results.py` from:", ""]
    rows = []
    for s in sources:
        name = s["json"]
        label = code("bench/out/" + name) + (f" ({s['label']})" if s.get("label") else "")
        rows.append([label] + [cell(name, k, s.get(k)) for k in ("command", "commit", "machine", "when")])
    lines += table(["JSON", "command", "commit", "machine", "run"], rows)
    if any(c.endswith(" (notes)") for r in rows for c in r):
        lines += ["(notes): not recorded in the JSON; from bench/RESULTS.md (git history).", ""]
    return lines


def machine_of(m: dict | None) -> str | None:
    if not m:
        return None
    # (the Python version stays in the JSON: the pages have a 40 kB budget)
    parts = [f"{m['nproc']} cores" if m.get("nproc") else None, m.get("cpu_model")]
    return ", ".join(p for p in parts if p) or None


def load(name: str, json_dir: Path):
    p = json_dir / name
    return json.loads(p.read_text(encoding="utf-8")) if p.exists() else None


def image(path: Path, alt: str) -> str:
    return f"![{alt}](../../bench/out/{path.name})"


SCENE_ORDER = ["tiny_graphdeco_iter7000_sh3", "measuring_jug_sh3", "houseplant_sh0",
               "showroom_lacadiere_crop_sh0", "plaza_taebak_crop_sh0", "flowers_daffodils_sh2"]


def scene_key(scene: str):
    return (SCENE_ORDER.index(scene) if scene in SCENE_ORDER else len(SCENE_ORDER), scene)


# --- rd.json: RD vs peers, and the size search at every point ------------------------------------

def _rd_sources(rd: dict, which: str) -> list:
    meta = rd["meta"]
    gsz = meta.get("gsz", {})
    commit = gsz.get("commit", "")[:7] or None
    if commit and gsz.get("tracked_files_modified"):
        commit += " (tracked files modified)"
    src = [dict(json="rd.json", label="gsz rows", command=meta.get("command"), commit=commit,
                machine=machine_of(meta.get("machine")),
                when=_span(meta.get("started"), meta.get("finished")))]
    src = _rd_gsz_sources(rd) or src
    if which == "peers":
        for r in rd.get("runs", []):
            if "peers_not_run" in r:
                continue
            src.append(dict(json="rd.json", label="peer rows, run " + r.get("started", "?")[:10],
                            command=r.get("command"), commit=(r.get("gsz", {}).get("commit") or "")[:7] or None,
                            machine=machine_of(r.get("machine")),
                            when=_span(r.get("started"), r.get("finished")) + "; " + (r.get("splat_transform") or "")))
    return src


def _rd_gsz_sources(rd: dict) -> list:
    """The runs whose gsz rows the file holds: each scene's rows come from the newest run that
    encoded it (runs with --skip-gsz encode none; a run without --scenes encodes every scene)."""
    scenes = {r["scene"] for r in rd.get("rows", []) if r["codec"] == "gsz"}
    out, left = [], set(scenes)
    for r in reversed(rd.get("runs", [])):
        cmd = (r.get("command") or "").split()
        if "--skip-gsz" in cmd or not left:
            continue
        ran = set(cmd[cmd.index("--scenes") + 1].split(",")) if "--scenes" in cmd else set(scenes)
        got = sorted(left & ran)
        if not got:
            continue
        left -= ran
        g = r.get("gsz", {})
        commit = (g.get("commit") or "")[:7] or None
        if commit and g.get("tracked_files_modified"):
            commit += " (tracked files modified)"
        out.append(dict(json="rd.json", label="gsz rows: " + ", ".join(got), command=r.get("command"),
                        commit=commit, machine=machine_of(r.get("machine")),
                        when=_span(r.get("started"), r.get("finished"))))
    return out


def _span(start: str | None, end: str | None) -> str:
    """'2026-12-02 04:14:12 – 04:48:02' (the end's date only when it differs)."""
    if not start:
        return NA
    if not end:
        return f"{start} – not finished"
    return f"{start} – {end[11:] if end[:10] == start[:10] else end}"


def _frac(t: dict) -> str:
    f = t.get("bytes_fraction")
    if f is None:
        return "n/a"
    return {"at_most": "≤ ", "more_than": "> "}.get(t.get("bytes_kind"), "") + f"{f:.2f}"


def _gain(t: dict | None) -> str:
    if t is None:
        return "–"
    d = t.get("delta_db")
    return f"{'n/a' if d is None else f'{d:+.1f}'} / {_frac(t)}"


def page_rd(rd: dict, json_dir: Path) -> str:
    meta = rd["meta"]
    rows = rd["rows"]
    lines = header("Rate–distortion: gsz vs SOG, SPZ and compressed.ply",
                   "Every shared scene and its noised variant: gsz's size search at PLY bytes / "
                   + ", ".join(f"{r:g}" for r in sorted(meta["ratios"], reverse=True))
                   + " and at the SOG file's bytes, against the PlayCanvas peers (splat-transform, SOG with "
                   + code(" ".join(meta.get("sog_flags", []))) + ").", _rd_sources(rd, "peers"))
    lines += [f"Scoring for every codec: gsz-eval's protocol ({meta['views']} default test views at "
              f"{meta['width']} px, 8-bit renders, PSNR against the original's).  "
              "Every row (bytes, SSIM, timings): `bench/out/rd.csv`.", ""]
    by = {}
    for t in rd.get("targets", []):
        by.setdefault((t["scene"], t["variant"]), {})[t["peer"]] = t
    keys = sorted(by, key=lambda k: (scene_key(k[0]), k[1]))
    met_db = sum(1 for k in keys if by[k].get("sog", {}).get("target_db_met"))
    met_fr = sum(1 for k in keys if by[k].get("sog", {}).get("target_fraction_met"))
    lines += ["## Against SOG (goals: ≥ +3 dB at SOG's bytes, ≤ 0.5× SOG's bytes at its PSNR)", "",
              f"+3 dB met on {met_db} of {len(keys)} scene variants; 0.5× met on {met_fr} of {len(keys)}.  "
              "Gain = gsz PSNR at the peer's bytes minus the peer's; ratio = bytes gsz needs for the peer's "
              "PSNR / the peer's bytes (interpolated in log-bytes; ≤ / > where outside gsz's points; n/a: "
              "the peer's bytes lie outside gsz's range).", ""]
    trows = []
    for k in keys:
        s = by[k].get("sog")
        if s is None:
            trows.append([k[0], k[1]] + ["–"] * 4 + [_gain(by[k].get("spz")), _gain(by[k].get("compressed.ply"))])
            continue
        g = s.get("gsz_psnr_at_peer_bytes")
        trows.append([k[0], k[1], n(s["peer_bytes"]), f2(s["peer_psnr"]),
                      f"{f2(g)} ({s.get('psnr_kind', '?')})",
                      f"{s['delta_db']:+.2f} {'met' if s.get('target_db_met') else 'NOT met'}"
                      if s.get("delta_db") is not None else "n/a",
                      f"{_frac(s)} {'met' if s.get('target_fraction_met') else 'NOT met'}",
                      _gain(by[k].get("spz")), _gain(by[k].get("compressed.ply"))])
    lines += table(["scene", "variant", "SOG B", "SOG dB", "gsz dB at SOG B", "gain dB", "bytes ratio",
                    "SPZ gain / ratio", "compressed.ply gain / ratio"], trows)

    budgets = [f"{r:g}x" for r in sorted(meta["ratios"], reverse=True)] + ["sog", "spz"]
    peers = ["sog", "spz", "compressed.ply"]
    grid = {}
    for r in rows:
        grid.setdefault((r["scene"], r["variant"]), {})[r["budget"] if r["codec"] == "gsz" else ("peer", r["codec"])] = r
    lines += ["## RD points (test PSNR, dB)", "",
              "gsz columns: the budget PLY bytes / ratio (\"sog\", \"spz\": the SOG / SPZ file's bytes); the file is at most "
              "the budget.  Peer cells: MB / dB.", ""]
    prow, notes = [], []
    for k in sorted(grid, key=lambda k: (scene_key(k[0]), k[1])):
        g = grid[k]
        any_row = next(iter(g.values()))
        cells = [k[0], k[1], mb(any_row["ply_bytes"])]
        for b in budgets:
            r = g.get(b)
            cells.append(f2(r["psnr"]) if r else "–")
            if r and r.get("note"):
                notes.append(f"* {k[0]} {k[1]} {b}: {n(r['bytes'])} B for a {n(r['target'])} B budget; "
                             f"the report: {r['note']}")
        for p in peers:
            r = g.get(("peer", p))
            cells.append(f"{mb(r['bytes'])} / {f2(r['psnr'])}" if r else "–")
        prow.append(cells)
    lines += table(["scene", "variant", "PLY MB"] + [f"gsz {b.replace('x', '×')}" for b in budgets]
                   + ["SOG", "SPZ", "compressed.ply"], prow)
    lines += notes + ([""] if notes else [])
    pngs = [json_dir / f"rdpeers_{s}.png" for s in sorted({k[0] for k in grid}, key=scene_key)]
    pngs = [p for p in pngs if p.exists()]
    if pngs:
        lines += ["## Plots (bytes, log scale → PSNR; `bench/rd.py` writes them)", ""]
        lines += [image(p, "RD " + p.stem[len("rdpeers_"):]) for p in pngs] + [""]
    lines += ["Reproduce: `bench/rd.py` (peers are installed into bench/.peers on first use; "
              "~2 h on 2 cores), `--skip-peers` for gsz's rows alone.", ""]
    return "\n".join(lines)


def _monotone(rs: list) -> bool:
    rs = sorted(rs, key=lambda r: r["bytes"])
    return all(b["psnr"] >= a["psnr"] for a, b in zip(rs, rs[1:]))


def page_search(rd: dict, scaling, above) -> str:
    meta = rd["meta"]
    g = [r for r in rd["rows"] if r["codec"] == "gsz" and "depth" in r]
    runs = _rd_gsz_sources(rd)         # listed in full on rd.md (the pages share 40 kB)
    src = [dict(json="rd.json", label="gsz rows", command=f"the {len(runs)} gsz runs rd.md lists",
                commit=", ".join(r["commit"].split()[0] for r in runs if r.get("commit")),
                machine=runs[0]["machine"] if runs else None, when="see rd.md")]
    if scaling is not None:
        src.append(dict(json="search_scaling.json"))
    if above is not None:
        src.append(dict(json="search_above_ceiling.json"))
    lines = header("Size search", "`encode_to_budget` (what `gsz-encode --size/--ratio` runs) at every budget of "
                   "the RD benchmark: how close to the budget, what it chose, how long it took.", src)
    so = meta.get("search_options", {})
    lines += ["Options: the run's `SearchOptions` (`meta.search_options` of `bench/out/rd.json`).", ""]
    tol = so.get("tolerance", 0.005)
    over = sum(1 for r in g if r["bytes"] > r["target"])
    within = sum(1 for r in g if r["bytes"] >= r["target"] * (1 - tol))
    groups = {}
    for r in g:
        groups.setdefault((r["scene"], r["variant"]), []).append(r)
    mono = sum(1 for rs in groups.values() if _monotone(rs))
    lines += [f"Over the budget: {over} of {len(g)} points; within {100 * tol:g} % below it: {within} of {len(g)}; "
              f"test PSNR monotone in bytes: {mono} of {len(groups)} scene variants.  Test PSNR on the "
              f"{meta['views']} default test views at {meta['width']} px (never seen by the search).", ""]
    lines += ["Per point: the file's bytes (against the budget), the chosen τ / octree depth, SH codebook size "
              "K / kept exact SH vectors, candidates encoded / screened out, wall seconds of the search (+ the "
              "importance pass).  Test PSNR: [rd.md](rd.md); calibration rounds, CPU seconds: "
              "`bench/out/rd.json`.", ""]
    variants = sorted({k[1] for k in groups})
    order = {b: i for i, b in enumerate([f"{r:g}x" for r in sorted(meta["ratios"], reverse=True)] + ["sog", "spz"])}

    def point(r):
        if r is None:
            return ["–"] * 5
        return [f"{n(r['bytes'])} ({pct((r['bytes'] - r['target']) / r['target'], 2)})", f"{r['reserve']} / {r['depth']}",
                f"{r['codebook_size']} / {n(r['sh_keep'])}", f"{r['candidates']} / {r['screened']}",
                f"{r['search_s']:.0f} (+{r['importance_s']:.0f})"]
    head = ["budget"] + [f"{h}{' (' + v + ')' if i == 0 else ''}" for v in variants
                         for i, h in enumerate(["bytes", "τ / depth", "K / kept", "enc. / scr.", "s (+imp.)"])]
    rows = []
    for scene in sorted({k[0] for k in groups}, key=scene_key):
        by = {v: {r["budget"]: r for r in groups.get((scene, v), [])} for v in variants}
        budgets = sorted({b for v in variants for b in by[v]}, key=lambda b: (order.get(b, len(order)), b))
        rows.append([f"**{scene}**"] + [""] * (len(head) - 1))
        rows += [[b.replace("x", "×")] + [c for v in variants for c in point(by[v].get(b))] for b in budgets]
    lines += table(head, rows)
    if scaling is not None:
        stages = ["importance", "vq", "tables", "sh-model", "calibrate", "eval", "screen", "geometry"]
        lines += ["## Scaling with N (flowers subsampled, budget = PLY bytes × fraction / 20)", ""]
        lines += table(["fraction", "N", "bytes / target", "search s", "CPU s", "encoded / screened", "τ"]
                       + [f"{s} s" for s in stages],
                       [[f"{r['scaling']:g}", n(r["n"]), f"{n(r['bytes'])} / {n(r['target'])}", f1(r["seconds"]),
                         f1(r["cpu_seconds"]), f"{r['candidates']} / {r['screened']}", r["reserve"]]
                        + [f1(r["stage_seconds"].get(s)) for s in stages] for r in scaling])
    if above is not None:
        lines += ["## Budgets above the 8-bit SH ceiling (measuring_jug_sh3)", "",
                  "A budget above the best file the scene allows gives that file, smaller than the budget "
                  "(the report's note says so).", ""]
        rows = [[r["variant"], f"{r['ratio_target']:g}×", n(r["target"]), f"{n(r['bytes'])} ({pct(r['deviation'])})",
                 f2(r["psnr"]), r["depth"], n(r["sh_keep"]), f1(r["search_seconds"])] for r in above]
        lines += table(["variant", "budget", "target B", "bytes", "test dB", "depth", "kept SH", "search s"], rows)
        lines += ["Before the SH spend (2c45cc2): [docs/design/sh-spend.md](../design/sh-spend.md).", ""]
    lines += ["Reproduce: `bench/rd.py --skip-peers` (every point; `--report` prints the "
              "tables), `bench/bench_search.py --scaling` and "
              "`--scenes measuring_jug_sh3 --ratios 4,6 --noise`.", ""]
    return "\n".join(lines)


# --- other topics ----------------------------------------------------------------------------------

def page_eval_views(sets: list) -> str:
    lines = header("Which train views judge the size search's candidates",
                   "The search runs once per point; every candidate it encoded is rendered afterwards from the "
                   "8 test views at 800 px and from several train-view sets (count @ width).  Regret = test PSNR "
                   "lost by taking that train set's best candidate instead of the test-best one (dB; 0 = the "
                   "train set ranks like the test views).", [dict(json=name) for name, _ in sets])
    cols = []
    for _, rows in sets:
        for r in rows:
            cols += [c for c in r["picks"] if c not in cols]
    out = []
    for name, rows in sets:
        for r in rows:
            out.append([f"{r['eval_width']} / {r['importance_width']}",
                        f"{r['scene']} {r['variant']} {r['ratio']:g}×", len(r["candidates"])]
                       + [f2(r["picks"][c]["regret"]) if c in r["picks"] else "–" for c in cols]
                       + [f2(max(c["test 8@800"] for c in r["candidates"]))])
    lines += ["Regret (dB) of each train set (count @ width); \"compare / importance px\": the widths the search "
              "itself used to compare candidates and for the importance pass.", ""]
    lines += table(["compare / importance px", "point", "candidates"] + [c.replace("train ", "") for c in cols]
                   + ["best test dB"], out)
    lines += ["Reproduce: `bench/bench_eval_views.py [--search-width W] [--importance-width W] "
              "[--points scene:variant:ratio,...]`.", ""]
    return "\n".join(lines)


def page_loss_proxy(sets: list) -> str:
    lines = header("Does the bit allocation's loss predict rendered fidelity?",
                   "Per scene, 14 allocations of one solver budget (the optima of the unweighted and of the "
                   "sensitivity-weighted Ω, and optima of Ω under random per-channel factors) encoded for real "
                   "and rendered from 6 train views at 640 px; Spearman rank correlation of −ΣΩ with PSNR.",
                   [dict(json=name) for name, _ in sets])
    rows = []
    for name, rs in sets:
        for r in rs:
            lo, hi = r["attr_bytes_range"]
            rows.append([r["scene"], f"{r['ratio']:g}×", r["reserve"], r["allocations"], f"{n(lo)} – {n(hi)}",
                         f2(r["spearman_unweighted"]), f2(r["spearman_weighted"]), f2(r["psnr_weighted_optimum"]),
                         f2(r["psnr_unweighted_optimum"]), f"{f2(r['psnr_random_best'])} / {f2(r['psnr_random_median'])}"])
    lines += table(["scene", "budget", "τ", "allocations", "attribute B", "Spearman unweighted", "weighted",
                    "dB weighted opt.", "dB unweighted opt.", "dB random best / median"], rows)
    lines += ["Reproduce: `bench/bench_loss_proxy.py --scenes houseplant_sh0,measuring_jug_sh3 "
              "--count 12` (`--ratio 60` for the 60× row).", ""]
    return "\n".join(lines)


def page_codec(codec, dm, dm_noised) -> str:
    src = [dict(json=nm) for nm, d in (("codec.json", codec), ("done_means_codec.json", dm),
                                      ("done_means_codec_noised.json", dm_noised)) if d is not None]
    lines = header("Codec at fixed configurations",
                   "`gsz-encode --bits B` without the size search: uniform bit-widths, one block per channel "
                   "or 80, on every shared scene and its noised variant (values moved off the delivery grid).  "
                   "PSNR: gsz-eval's protocol (8 test views, 800 px).", src)
    if codec:
        configs = sorted({(r["bits"], r["blocks"]) for r in codec})
        by = {}
        for r in codec:
            by.setdefault((r["scene"], r["variant"]), {})[(r["bits"], r["blocks"])] = r
        lines += [f"## Ratio to the PLY / test PSNR (`--reserve {codec[0]['reserve']}`)", ""]
        lines += table(["scene", "variant"] + [f"{b} bit, {k} blk" for b, k in configs],
                       [[s, v] + [f"{c['ratio_vs_ply']:.1f}× / {c['psnr']:.2f}" if (c := cfg.get(x)) else "–"
                                  for x in configs]
                        for (s, v), cfg in sorted(by.items(), key=lambda kv: (scene_key(kv[0][0]), kv[0][1]))])
        at = [r for r in codec if r["bits"] == max(b for b, _ in configs) and r["blocks"] == min(k for _, k in configs)
              and r["variant"] == "grid"]
        if at:
            r0 = at[0]
            lines += [f"## Where the bytes go at {r0['bits']} bits, {r0['blocks']} block (grid variants)", ""]
            lines += table(["scene", "Gaussians → voxels (depth)", "bytes", "B/Gaussian", "geometry",
                            "attributes", "SH", "encode s", "decode s"],
                           [[r["scene"], f"{n(r['gaussians'])} → {n(r['voxels'])} ({r['depth']})",
                             n(r["bytes"]), f2(r["bytes_per_gaussian"]), n(r["components"]["geometry"]),
                             n(r["components"]["attributes"]), n(r["components"].get("sh", 0)),
                             f1(sum(r["encode_seconds"].values())), f2(r["decode_seconds"])]
                            for r in sorted(at, key=lambda r: (scene_key(r["scene"]), r["variant"]))])
    if dm or dm_noised:
        noised = {r["scene"]: r for r in dm_noised or []}
        base = dm or dm_noised
        lines += ["## Acceptance through the command-line tools: ≥ 10× and ≥ 35 dB at uniform 12 bits", "",
                  "`gsz-encode IN -o OUT <flags>`, `gsz-decode`, the PLY read back, `gsz-eval`.  Met: "
                  + "; ".join(f"{sum(1 for r in d if r['meets'])} of {len(d)} scenes ({nm})"
                              for nm, d in (("grid", dm), ("noised", dm_noised)) if d) + ".", ""]

        def res(r):
            return (f"{n(r['bytes'])} B, {r['ratio']:.2f}×, {r['psnr']:.2f} dB, "
                    + ("meets" if r["meets"] else "**misses**")) if r else "–"
        lines += table(["scene", "gsz-encode flags", "Gaussians (depth), grid", "grid", "noised"],
                       [[r["scene"], code(" ".join(r["flags"])), f"{n(r['gaussians'])} ({r['depth']})",
                         res(r if dm else None), res(noised.get(r["scene"]))] for r in base])
    lines += ["Reproduce: `bench/bench_codec.py --noise --bits 8,10,12 --blocks 1,80`, "
              "`bench/done_means_codec.py [--noised]`.  Why one block from 10 bits up: "
              "[docs/design/default-blocks.md](../design/default-blocks.md).", ""]
    return "\n".join(lines)


def _uptimes(d: dict) -> str | None:
    """'06:50:18, load 1.19 -> 1.09' from recorded ``uptime`` lines (time of day, 1-minute load)."""
    ups = [d[k] for k in ("uptime_before", "uptime_after") if d.get(k)]
    if not ups:
        return None
    loads = [u.split("load average:")[1].split(",")[0].strip() for u in ups if "load average:" in u]
    return f"{ups[0].split()[0]}, load {' → '.join(loads)}"


def page_decode(d: dict) -> str:
    lines = header("Decode speed", "`gsz.decoder.decode(path)`: NumPy reference (`GSZ_NATIVE=0`) and native "
                   "(identical output).  Wall: best of the repeats; CPU: that run's process CPU time; stages: "
                   "one after the other (thread CPU).", [dict(json="decode.json", command=d.get("command"), commit=d.get("commit"),
                                                   machine=d.get("machine"), when=_uptimes(d))])
    stages = ["geometry", "attributes", "sh", "finish"]     # (the container parse: ~0 s)
    rows = []
    # bench_decode's cached files: SCENE_reserve_08_bits_12_..._SIZE_MTIME.gsz -> SCENE
    name = (lambda r: Path(r["file"]).name.split("_reserve_")[0].removesuffix(".gsz"))
    for r in sorted(d["results"], key=lambda r: scene_key(name(r))):
        for path in ("numpy", "native"):
            p = r["paths"].get(path)
            if p:
                rows.append([name(r), n(p["gaussians"]),
                             mb(r["bytes"]), path,
                             f"{p['seconds']:.3f}", f"{p['cpu_seconds']:.3f}", f2(p["gaussians_per_second"] / 1e6)]
                            + [f"{p['stages'].get(s, 0):.3f}" for s in stages])
    lines += table(["scene", "Gaussians", "MB", "path", "wall s", "CPU s", "M Gaussians/s"]
                   + [f"{s} s" for s in stages], rows)
    lines += ["Files: the shared scenes at `gsz-encode --reserve 0.8 --bits 12 --blocks 1` (cached in "
              "bench/.cache/decode); `big_*`: [scale.md](scale.md)'s 1.2 M files (2 tiles decode in "
              "parallel; stages summed over parts).", ""]
    return "\n".join(lines)


def page_stream(rows: list, json_dir: Path) -> str:
    lines = header("Progressive streaming", "Per scene at PLY / ratio: a layered file from the size search and "
                   "single-layer files at the budget and at 95 % of it, scored on the 8 test views at 800 px.  "
                   "Overhead = the layered file's bytes over the single-layer bytes with the same PSNR "
                   "(interpolated in log-bytes; extrapolated where marked; ≤: the layered file is at least as "
                   "good at its size).  Decode: whole-file `decode()` vs "
                   "`StreamDecoder` fed 64 KiB pieces, best of 3.", [dict(json="stream.json")])
    out = []
    for r in sorted(rows, key=lambda r: (scene_key(r["scene"]), r["variant"])):
        lp = sorted(r["layer_psnr"], key=lambda x: x["layer"])
        out.append([r["scene"], r["variant"], f"{r['ratio']:g}×", r["layers"], n(r["layered_bytes"]),
                    f"{100 * r['layer0_fraction']:.1f} %",
                    " → ".join(f"{x['psnr']:.2f} ({100 * x['fraction']:.0f} %)" for x in lp),
                    f"{f2(r['single_psnr'])} / {f2(r['single95_psnr'])}",
                    ("≤ " if r.get("overhead_how") == "bound" else "") + pct(r["overhead"], 2)
                    + (" (extrapolated)" if r.get("overhead_how") == "extrapolated" else ""),
                    f"{r['decode_s']:.2f} / {r['stream_decode_s']:.2f}"])
    lines += table(["scene", "variant", "budget", "layers", "file B", "layer 0 at", "dB after each layer (share "
                    "of the file)", "single-layer dB at budget / 95 %", "overhead", "decode s whole / streamed"], out)
    pngs = [json_dir / f"stream_{s}.png" for s in sorted({r["scene"] for r in rows}, key=scene_key)]
    pngs = [p for p in pngs if p.exists()]
    if pngs:
        lines += ["## Bytes received → test PSNR", ""] + [image(p, p.stem) for p in pngs] + [""]
    lines += ["Reproduce: `bench/bench_stream.py` (defaults `--ratio 12 --layers 3 --first-layer "
              "0.1`).  Why one layer by default and 3 for `--layers`: [docs/design/layers.md](../design/layers.md).", ""]
    return "\n".join(lines)


def page_scale(sets: list) -> str:
    lines = header("Real-size scenes (1-6 M Gaussians): single tile vs tiles",
                   "Size-search encodes of `bench/big_scene.py` scenes, each a `gsz-encode --ratio` process "
                   "under `/usr/bin/time -v` (`single`: one tile; `tiled`: tiles of at most tile_gaussians, on "
                   "local worker processes).",
                   [dict(json=name, command=s.get("command"), commit=s.get("commit"),
                         machine=f"{s['cores']} cores" if s.get("cores") else None, when=_uptimes(s))
                    for name, s in sets])
    ratio = (lambda s, r: r.get("ratio", s["ratio"]))
    # a run at several ratios is there for its RD points: its rows go to the cost-of-tiling
    # table (_tiling_cost), its stages are not tabled below
    multi = [s for _, s in sets if len({ratio(s, r) for r in s["rows"]}) > 1]
    single_ratio = [s for _, s in sets if not any(s is m for m in multi)]
    # stages per column: the grid scenes' local runs (a Ray run's and a noised scene's stages
    # are like their local / grid twin's; their peaks are in the table above)
    cols = []
    for s in single_ratio:
        for r in s["rows"]:
            label = f"{Path(s['scene']).stem} {r['variant']}"
            # one column per scene and variant: the Ray run's local twin is the first run's file
            if r["variant"] != "ray" and "noised" not in label and label not in dict(cols):
                cols.append((label, r))
    test_db = (lambda r: "–" if r.get("test_psnr") is None else f"{r['test_psnr']:.2f} / {r['test_ssim']:.4f}")
    # a local row of the Ray run repeats the first run's file (same sha256): its row once
    shown, rows = set(), []
    for s in single_ratio:
        for r in s["rows"]:
            key = (Path(s["scene"]).stem, r["variant"], r["sha256"])
            if key not in shown:
                shown.add(key)
                rows.append([f"`{key[0]}`, {r['variant']}", f"{ratio(s, r):g}×", r.get("tiles", "–"),
                             f"{n(r['bytes'])} ({r['of_target_pct']:.2f} %)", f"{r['reserve']} / {r['depth']}",
                             f2(r["train_psnr"]), test_db(r), f1(r["wall_s"]), f1(r["cpu_s"]),
                             n(r["peak_rss_mb"]), code(r["sha256"][:8])])
    lines += table(["scene, variant", "ratio", "tiles", "bytes (of target)", "τ / depth", "train dB",
                    "test dB / SSIM", "wall s", "CPU s", "peak RSS MB", "sha256"], rows)
    lines += _tiling_cost(sets)
    stages = []
    for _, r in cols:
        stages += [k for k in r["stage_seconds"] if k not in stages]
    lines += ["## Seconds per stage (each stage's peak RSS: the JSONs' `stage_peak_mb`)", ""]
    lines += table(["stage"] + [c for c, _ in cols],
                   [[st] + [("–" if st not in r["stage_seconds"] else f1(r['stage_seconds'][st])) for _, r in cols]
                    for st in stages])
    lines += ["Scenes: `bench/big_scene.py --gaussians 1.2M --sh 3 -o bench/.cache/big_1.2M_sh3.ply` "
              "(3M likewise).  Why and where tiles: [docs/design/tiles.md](../design/tiles.md).", ""]
    return "\n".join(lines)


def _tiling_cost(sets: list) -> list:
    """The cost of tiling read off the RD curves of sets that ran single and tiled at several
    ratios with test PSNR: each ratio's two points, and the bytes the tiled curve needs for the
    single-tile point's test PSNR (the rest of each row: the JSON)."""
    from rd import bytes_at_psnr
    rows = []
    for _, s in sets:
        pts = {v: {r.get("ratio", s["ratio"]): r for r in s["rows"] if r["variant"] == v
                   and r.get("test_psnr") is not None} for v in ("single", "tiled")}
        curve = sorted((r["bytes"], r["test_psnr"]) for r in pts["tiled"].values())
        if len(curve) < 2:
            continue
        for ratio, r in sorted(pts["single"].items(), reverse=True):
            b, psnr = r["bytes"], r["test_psnr"]
            t = pts["tiled"].get(ratio)
            need, kind = bytes_at_psnr(curve, psnr)
            mark = {"interpolated": "", "at_most": "≤ ", "more_than": "> "}[kind]
            rows.append([f"`{Path(s['scene']).stem}`", f"{ratio:g}×", f"{n(b)} / {f2(psnr)}",
                         "–" if t is None else f"{n(t['bytes'])} / {f2(t['test_psnr'])} ({t.get('tiles', '–')})",
                         f"{mark}{n(need)}", f"{mark}{need / b:.3f}"])
    if not rows:
        return []
    return (["## Cost of tiling (test PSNR, 8 views at 800 px; issue 17: ≤ 1.02)", ""]
            + table(["scene", "ratio", "single tile: bytes / dB", "tiled: bytes / dB (tiles)",
                     "tiled bytes for single's dB", "ratio"], rows))


def page_golden(gold: dict) -> str:
    lines = header("Golden files (byte identity)", "Fixed and size-search encodes of the committed samples and "
                   "shared scenes; a change that claims \"no behaviour change\" must reproduce every line "
                   "(`bench/golden.py --check`).  Hashes are of the file and of the search report's decisions "
                   "(timings excluded); they depend on the CPU's float sums (renderer), so compare on one machine.",
                   [dict(json="golden.json")])
    lines += table(["configuration", "bytes", "file sha256", "report hash"],
                   [[k, n(v["bytes"]), code(v["sha256"][:8]), code(v["report"][:8])] for k, v in gold.items()])
    lines += ["Check: `bench/golden.py --check bench/out/golden.json` (`--quick`: committed "
              "samples only).", ""]
    return "\n".join(lines)


def page_sh_paths(entries: list) -> str:
    lines = header("SH paths: codebook vs scalar", "The size search with the scalar SH path off and allowed, at the "
                   "same budgets.  Why the path exists: [docs/design/sh-scalar.md](../design/sh-scalar.md).",
                   [dict(json="sh_paths.json", label=f"{e.get('scene')}{' noised' if e.get('noised') else ''}",
                         command=e.get("command"), commit=e.get("commit")) for e in entries])
    for e in entries:
        lines += [f"## {e.get('scene')}{', noised' if e.get('noised') else ''} (test PSNR on {e.get('views')} "
                  f"views at {e.get('width')} px)", ""]
        lines += table(["target B", "scalar path allowed", "bytes", "SH path", "kept SH", "K", "train dB", "test dB",
                        "s"],
                       [[n(r["target"]), "yes" if r.get("sh_scalar") else "no", n(r["bytes"]), r.get("sh_path") or "–",
                         "–" if r.get("sh_keep") is None else n(r["sh_keep"]), r.get("codebook_size") or "–",
                         f2(r.get("train_psnr")), f2(r.get("test_psnr")), f1(r.get("seconds"))]
                        for r in e.get("rows", [])])
    return "\n".join(lines)


def page_attribution(entries: list) -> str:
    lines = header("Which attribute group costs the fidelity",
                   "PSNR (dB) of the original with one attribute group replaced by the file's decoded values "
                   "(Gaussians matched by position; gsz-eval's protocol): the weakest group is the one to work on "
                   "next (`bench/bench_attribution.py`).",
                   [dict(json=x, command=d.get("command"), commit=d.get("commit"),
                         machine=machine_of(d.get("machine")), when=d.get("when")) for x, d in entries])
    def short(x: str) -> str:
        """'attribution_measuring_jug_sh3_noised_spz_bytes.json' -> 'measuring noised, SPZ B'."""
        stem = x[len("attribution_"):-len(".json")]
        at = next((f", {p.upper()} B" for p in ("sog", "spz") if stem.endswith(f"_{p}_bytes")), "")
        return stem.split("_")[0] + (" noised" if "_noised" in stem else "") + at
    names = [short(x) for x, _ in entries]
    groups = list(dict.fromkeys(r["group"] for _, d in entries for r in d.get("rows", [])))
    rows = []
    for g in groups:
        cells = []
        for _, d in entries:
            r = next((r for r in d.get("rows", []) if r["group"] == g), None)
            cells.append("–" if r is None else f2(r["psnr"]) + (" **weakest**" if g == d.get("weakest") else ""))
        rows.append([g] + cells)
    rows.append(["whole file"] + [f2(d.get("whole_file_psnr")) for _, d in entries])
    rows.append(["Gaussians matched"] + [f"{n(d.get('matched'))} / {n(d.get('original_gaussians'))}"
                                         for _, d in entries])
    lines += table(["group replaced"] + names, rows)
    return "\n".join(lines)


def build(json_dir: Path = JSON_DIR) -> dict:
    """{file name: markdown} for every page the JSON in ``json_dir`` supports, and README.md."""
    pages, used, index = {}, set(), []

    def add(name, title, jsons, text):
        pages[name] = text
        used.update(jsons)
        index.append((name, title, jsons))

    rd = load("rd.json", json_dir)
    if rd:
        add("rd.md", "rate–distortion vs SOG, SPZ, compressed.ply", ["rd.json"], page_rd(rd, json_dir))
        sc, ab = (load(x, json_dir) for x in ("search_scaling.json", "search_above_ceiling.json"))
        add("search.md", "the size search at every RD point, scaling with N, budgets above the ceiling",
            ["rd.json"] + [x for x, d in (("search_scaling.json", sc), ("search_above_ceiling.json", ab),
                                          ) if d is not None],
            page_search(rd, sc, ab))
    ev = [(x, d) for x in ("eval_views.json", "eval_views_losses.json")
          if (d := load(x, json_dir)) is not None]
    if ev:
        add("eval_views.md", "which train views judge the search's candidates", [x for x, _ in ev], page_eval_views(ev))
    lp = [(x, d) for x in ("loss_proxy.json", "loss_proxy_jug60.json") if (d := load(x, json_dir)) is not None]
    if lp:
        add("loss_proxy.md", "does the allocation's loss predict rendered PSNR", [x for x, _ in lp], page_loss_proxy(lp))
    codec, dm, dmn = (load(x, json_dir) for x in ("codec.json", "done_means_codec.json", "done_means_codec_noised.json"))
    if codec or dm or dmn:
        add("codec.md", "fixed configurations, acceptance at 12 bits",
            [x for x, d in (("codec.json", codec), ("done_means_codec.json", dm),
                            ("done_means_codec_noised.json", dmn)) if d], page_codec(codec, dm, dmn))
    for name, title, jsn, fn in (("decode.md", "decode speed, NumPy vs native", "decode.json", page_decode),
                                 ("golden.md", "byte-identity record", "golden.json", page_golden),
                                 ("sh_paths.md", "codebook vs scalar SH path", "sh_paths.json", page_sh_paths)):
        d = load(jsn, json_dir)
        if d:
            add(name, title, [jsn], fn(d))
    at = [(p.name, load(p.name, json_dir)) for p in sorted(json_dir.glob("attribution_*.json"))]
    if at:
        add("attribution.md", "which attribute group costs the fidelity", [x for x, _ in at], page_attribution(at))
    sc = [(p.name, load(p.name, json_dir))
          for p in sorted(json_dir.glob("scale*.json"), key=lambda p: (len(p.name), p.name))]
    if sc:
        add("scale.md", "1-6 M Gaussians, single tile vs tiles", [x for x, _ in sc], page_scale(sc))
    st = load("stream.json", json_dir)
    if st:
        add("stream.md", "progressive streaming: layer 0, overhead, PSNR per layer", ["stream.json"],
            page_stream(st, json_dir))

    left = sorted(p.name for p in json_dir.glob("*.json") if p.name not in used)
    lines = ["# Current results", "",
             "One page per topic, generated from the benchmark JSON in `bench/out/` (each page names the "
             "command, run with `.venv/bin/python`, commit and machine of its JSON).  Regenerate all of "
             "them with", "",
             f"    {REGEN}", "",
             f"and check that the committed pages are current with `{REGEN} --check` (a test does).  "
             "A re-run benchmark rewrites its JSON; then regenerate.  Decisions, evidence: "
             "[docs/design/](../design/README.md).  Older results: git history.", ""]
    lines += table(["page", "topic", "from"], [[f"[{nm}]({nm})", t, ", ".join(code(j) for j in js)]
                                              for nm, t, js in sorted(index)])
    if left:
        # several files of one probe (its name's first word) as one glob
        heads: dict = {}
        for x in left:
            heads.setdefault(x.split("_")[0], []).append(x)
        names = [code(f"{h}_*.json") + f" ({len(xs)})" if len(xs) > 1 else code(xs[0])
                 for h, xs in heads.items()]
        lines += ["JSON with no page: " + ", ".join(names) + ".", ""]
    pages["README.md"] = "\n".join(lines)
    return {k: v.rstrip("\n") + "\n" for k, v in pages.items()}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--check", action="store_true", help="exit 1 when docs/results differs from what would be written")
    ap.add_argument("--json-dir", type=Path, default=JSON_DIR)
    ap.add_argument("--pages-dir", type=Path, default=PAGES_DIR)
    a = ap.parse_args(argv)
    pages = build(a.json_dir)
    have = {p.name for p in a.pages_dir.glob("*.md")} if a.pages_dir.exists() else set()
    if a.check:
        stale = sorted(nm for nm, text in pages.items()
                       if not (a.pages_dir / nm).exists() or (a.pages_dir / nm).read_text(encoding="utf-8") != text)
        extra = sorted(have - set(pages))
        for nm in stale:
            print(f"out of date: {a.pages_dir / nm}")
        for nm in extra:
            print(f"not generated (remove it): {a.pages_dir / nm}")
        if stale or extra:
            print(f"regenerate with: {REGEN}")
            return 1
        print(f"{len(pages)} pages current ({sum(len(t.encode()) for t in pages.values()):,} bytes)")
        return 0
    a.pages_dir.mkdir(parents=True, exist_ok=True)
    for nm in sorted(have - set(pages)):
        (a.pages_dir / nm).unlink()
    for nm, text in sorted(pages.items()):
        (a.pages_dir / nm).write_text(text, encoding="utf-8")
    print(f"wrote {len(pages)} pages to {a.pages_dir} ({sum(len(t.encode()) for t in pages.values()):,} bytes)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
