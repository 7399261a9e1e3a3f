"""Rate-distortion curve of one scene: encode it at a few budgets, score each decoded file with
gsz-eval's protocol, draw the curve (``gsz-eval --rd SCENE --sizes 1MB,2MB,4MB -o DIR``).

The importance pass runs once for every budget and the original's test views are rendered once;
each budget is then a size search (:func:`gsz.encoder.search.encode_to_budget`) whose decoded
scene is compared with the original by :func:`gsz.evaluation.evaluate.evaluate` -- the numbers are
those ``gsz-eval SCENE FILE`` prints for the written files.
"""
from __future__ import annotations

import re
import time

import numpy as np


def budget_file_name(stem: str, label: str) -> str:
    """``<stem>-<label>.gsz`` with the label's characters safe in a file name."""
    return f"{stem}-{re.sub(r'[^A-Za-z0-9._-]+', '_', label)}.gsz"


def rd_points(cloud, targets: list, cameras, *, background=(0.0, 0.0, 0.0), options=None,
              source: str | None = None, report=None, progress=None) -> tuple[list, list]:
    """(points, unreachable) for ``targets`` [(label, bytes)] ascending: each point
    ``{"target", "target_bytes", "bytes", "data", "psnr", "ssim", "views", "reserve", "voxels",
    "encode_seconds"}`` (``data``: the file), each unreachable budget ``{"target",
    "target_bytes", "error"}``.  ``report(text)`` is told each budget's outcome."""
    from ..evaluation.evaluate import evaluate, render_views
    from .pipeline import compute_train_importance
    from .sanitize import sanitize_cloud
    from .search import BudgetError, SearchOptions, encode_to_budget
    sopts = options or SearchOptions()
    cloud, _, _ = sanitize_cloud(cloud, source)      # once: every budget encodes the same scene
    importance = None
    refs = None
    points, unreachable = [], []
    for label, target in targets:
        t0 = time.perf_counter()
        try:
            if importance is None:
                from .search.bound import check_reachable
                check_reachable(cloud, target, sopts)      # an unreachable first budget: no pass
                importance = compute_train_importance(cloud, sopts, progress=progress)
            res = encode_to_budget(cloud, target, options=sopts, importance=importance, progress=progress)
        except BudgetError as e:
            unreachable.append({"target": label, "target_bytes": int(target), "error": str(e)})
            if report:
                report(f"{label}: unreachable: {e}")
            continue
        secs = time.perf_counter() - t0
        if refs is None:
            refs = render_views(cloud, cameras, background=background)
        ev = evaluate(refs, res.cloud, cameras, background=background)
        points.append({"target": label, "target_bytes": int(target), "bytes": len(res.data),
                       "data": res.data, "psnr": ev["psnr"], "ssim": ev["ssim"], "views": ev["views"],
                       "reserve": res.report.reserve, "voxels": res.report.voxels,
                       "encode_seconds": round(secs, 2)})
        if report:
            report(f"{label}: {len(res.data):,} bytes, PSNR {ev['psnr']:.2f} dB, SSIM {ev['ssim']:.4f} "
                   f"(encoded in {secs:.1f} s)")
    return points, unreachable


def rd_figure(rd: dict):
    """PSNR (top) and SSIM (bottom) against the file size, one labelled marker per budget."""
    import os

    from matplotlib.figure import Figure
    pts = rd["points"]
    size = np.array([p["bytes"] for p in pts], float)
    scale, unit = (1e6, "MB") if size.max() >= 1e6 else (1e3, "kB")
    x = size / scale
    fig = Figure(figsize=(7.0, 6.0), dpi=100)
    top, bottom = fig.subplots(2, 1, sharex=True)
    for ax, key, style, colour, label in ((top, "psnr", "o-", "tab:blue", "PSNR (dB)"),
                                          (bottom, "ssim", "s-", "tab:red", "SSIM")):
        y = [p[key] for p in pts]
        ax.plot(x, y, style, color=colour)
        for p, xv, yv in zip(pts, x, y):
            ax.annotate(p["target"], (xv, yv), textcoords="offset points", xytext=(5, -11), fontsize=8)
        ax.set_ylabel(label)
        ax.grid(True, alpha=0.3)
    if len(x) > 1 and x.max() / max(x.min(), 1e-12) > 4:
        bottom.set_xscale("log")
    bottom.set_xlabel(f"file size ({unit}, 10^{3 if unit == 'kB' else 6} bytes)")
    top.set_title(f"{os.path.basename(rd['scene'])} ({rd['input_bytes']:,} bytes): {len(rd['cameras'])} "
                  f"test views at {rd['width']}x{rd['height']}, gsz-eval protocol", fontsize=9)
    fig.tight_layout()
    return fig


def png_bytes(fig) -> bytes:
    import io
    buf = io.BytesIO()
    fig.savefig(buf, format="png", metadata={"Software": None})     # no version stamp: same bytes
    return buf.getvalue()
