"""Pictures of an encode: the bit-width chart of ``gsz-encode --report`` (matplotlib).

``write_report`` writes ``bits.png`` -- one row per quantised channel (the 7 RAHT channels, the
3 log-scales and, where the file keeps exact SH vectors, one row per SH component), one column
per block, coloured by the bit-width the encoder gave that (channel, block) group, with a colour
bar, and the file, its size and its budget in the title -- and ``report.json``.  The widths are
read back from the file itself, so a fixed configuration and a size search draw the same way.

matplotlib is an optional dependency (the ``plots`` extra): :func:`require_matplotlib` says so
in one line before an encode that would need it.
"""
from __future__ import annotations

import io
import json
import os

import numpy as np

from ..decoder.errors import GszError
from .encode_report import EncodeReport

#: colour map of the chart: perceptually ordered, readable in grey
CMAP = "viridis"


def require_matplotlib(what: str = "--report") -> None:
    """GszError naming the extra to install when matplotlib is missing (checked before the
    work that would need it, not after an encode)."""
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        raise GszError(f'{what} draws its chart with matplotlib, which is not installed: '
                       'pip install "gsz[plots]"') from None


def file_bits(data: bytes) -> dict:
    """The group bit-widths stored in a .gsz file, in the form of the size search's report
    (``EncodeReport.bits``): ``raht`` [7, sum B] and ``scales`` [3, sum B] with every part's blocks
    side by side, ``sh_kept`` per part [D, B] (None where a part keeps no exact vector), ``sh``
    the codebook's width (None without SH), plus ``parts`` (layer, tile, blocks) per part."""
    from ..decoder.bytesio import Reader
    from ..decoder.container import read_container
    from ..decoder.glb import gsz_payload, is_glb
    from ..decoder.layout import CHUNK_ATTR, CHUNK_SHVQ, DIRECT_CHANNELS, RAHT_CHANNELS
    if is_glb(data):
        data = gsz_payload(data)[0]
    container = read_container(data)
    raht, scales, kept, parts, cb_bits = [], [], [], [], None

    def channel_set(r: Reader) -> np.ndarray:
        c, _length, b, _mode = r.u8(), r.u32(), r.u16(), r.u8()
        bits = r.array(np.uint8, c * b).reshape(c, b).astype(np.int64)
        r.bytes(8 * c * b)          # mins, maxs
        r.blob()
        return bits

    for ch in container.chunks:
        if ch.type == CHUNK_ATTR:
            r = Reader(ch.data, "ATTR")
            r.u8()
            r.bytes(8 * r.u8())     # the RAHT DC values
            raht.append(channel_set(r))
            scales.append(channel_set(r))
            parts.append({"layer": ch.layer, "tile": ch.tile,
                          "blocks": int(raht[-1].shape[1])})
            kept.append(None)
        elif ch.type == CHUNK_SHVQ:
            r = Reader(ch.data, "SHVQ")
            k_cb, p, _d = r.u32(), r.u32(), r.u16()
            if k_cb:
                cb = channel_set(r)
                cb_bits = int(np.bincount(cb.ravel()).argmax())
            if p:
                kept[-1] = channel_set(r)
    return {"raht": np.concatenate(raht, axis=1).tolist(), "scales": np.concatenate(scales, axis=1).tolist(),
            "raht_channels": list(RAHT_CHANNELS), "scale_channels": list(DIRECT_CHANNELS),
            "sh": cb_bits, "sh_kept": [None if k is None else k.tolist() for k in kept], "parts": parts}


def bit_matrix(bits: dict) -> tuple[np.ndarray, list[str]]:
    """(widths [rows, blocks] float with NaN where a row has no group, row labels) of an
    ``EncodeReport.bits`` dict: the attribute channels, then one row per kept SH component."""
    rows = [np.asarray(b, float) for b in bits["raht"]] + [np.asarray(b, float) for b in bits["scales"]]
    labels = list(bits["raht_channels"]) + [f"scale_{i}" if not str(n).startswith("scale") else str(n)
                                            for i, n in enumerate(bits["scale_channels"])]
    kept = [np.asarray(k, float) for k in (bits.get("sh_kept") or []) if k is not None]
    if kept:
        d = kept[0].shape[0]
        sh = np.concatenate(kept, axis=1)       # the parts' kept sets side by side
        rows += list(sh)
        labels += [f"f_rest_{(j % 3) * (d // 3) + j // 3}" for j in range(d)]
    width = max(len(r) for r in rows)
    out = np.full((len(rows), width), np.nan)
    for i, r in enumerate(rows):
        out[i, :len(r)] = r
    return out, labels


def bits_figure(bits: dict, title: str):
    """A matplotlib Figure (no pyplot: no global state, no display) of the bit-width chart."""
    from matplotlib.figure import Figure
    mat, labels = bit_matrix(bits)
    n_rows, n_blocks = mat.shape
    fig = Figure(figsize=(min(16.0, 4.0 + 0.09 * n_blocks), 1.8 + 0.16 * n_rows), dpi=100)
    ax = fig.add_subplot()
    im = ax.imshow(np.ma.masked_invalid(mat), aspect="auto", cmap=CMAP, vmin=1, vmax=16,
                   interpolation="nearest")
    ax.set_yticks(range(n_rows), labels, fontsize=7 if n_rows > 20 else 8)
    ax.set_xlabel("block (consecutive coefficients of a channel; parts side by side)")
    ax.set_ylabel("channel")
    n_attr = len(bits["raht"]) + len(bits["scales"])
    if n_rows > n_attr:                 # the kept SH rows below a line
        ax.axhline(n_attr - 0.5, color="white", linewidth=1.5)
    ends = np.cumsum([p["blocks"] for p in bits.get("parts", [])])[:-1]
    for x in ends:                      # part (layer / tile) boundaries
        ax.axvline(x - 0.5, color="white", linewidth=1.0, linestyle="--")
    cbar = fig.colorbar(im, ax=ax, ticks=[1, 4, 8, 12, 16], fraction=0.04, pad=0.02)
    cbar.set_label("bits per group")
    ax.set_title(title, fontsize=9)
    fig.tight_layout()
    return fig


def _title(report: EncodeReport) -> str:
    written = report.written
    name = os.path.basename(written.output if written else "") or "file"
    size = report.bytes
    line = f"{name}: {size:,} bytes"
    if report.target_bytes:
        label = (written.target if written else None) or f"{report.target_bytes:,} bytes"
        line += f" (budget {label}, {100 * size / report.target_bytes:.2f} %)"
    else:
        line += " (fixed configuration)"
    extra = [f"reserve {report.reserve}"]
    if report.voxels:
        extra.append(f"{report.voxels:,} Gaussians")
    sh = (report.bits or {}).get("sh")
    if sh:
        extra.append(f"SH codebook at {sh} bits")
    return line + "\n" + ", ".join(extra)


def write_report(report: EncodeReport, folder, data: bytes | None = None) -> list[str]:
    """Write ``bits.png`` (the bit-width chart) and ``report.json`` (``report.to_json()``) into
    ``folder``; the widths come from ``report.bits`` (a size search's) or else from the file
    ``data`` (then kept in ``report.bits``).  Returns the two paths."""
    from ..decoder.io_util import atomic_write
    require_matplotlib()
    if report.bits is None:
        if data is None:
            raise GszError("write_report: the report has no bit-widths and no file was given")
        report.bits = file_bits(data)
    os.makedirs(folder, exist_ok=True)
    buf = io.BytesIO()
    # no Software/date metadata: the same encode draws the same bytes
    bits_figure(report.bits, _title(report)).savefig(buf, format="png", metadata={"Software": None})
    png = os.path.join(folder, "bits.png")
    atomic_write(png, buf.getvalue())
    js = os.path.join(folder, "report.json")
    atomic_write(js, json.dumps(report.to_json(), indent=1, default=float).encode())
    return [png, js]


def write_search_report(report: EncodeReport, folder) -> list[str]:
    """:func:`write_report` of a size search's report (its ``bits``)."""
    return write_report(report, folder)
