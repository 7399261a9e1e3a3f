"""Pictures of an encode: the bit-width heatmap of the size search (PNG, Pillow only)."""
from __future__ import annotations

import json
import os

import numpy as np

# A perceptually ordered colour ramp (dark blue -> teal -> yellow), 1 .. 16 bits.
_RAMP = np.array([[68, 1, 84], [59, 82, 139], [33, 145, 140], [94, 201, 98], [253, 231, 37]], float)


def _colour(v: np.ndarray) -> np.ndarray:
    t = np.clip(v, 0, 1) * (len(_RAMP) - 1)
    i = np.minimum(t.astype(int), len(_RAMP) - 2)
    f = (t - i)[..., None]
    return (_RAMP[i] * (1 - f) + _RAMP[i + 1] * f).astype(np.uint8)


def bits_heatmap(rows: list[tuple[str, np.ndarray]], cell: int = 10):
    """Image of group bit-widths: one row per channel (label, [B] bits), one column per block."""
    from PIL import Image, ImageDraw
    width = max(len(b) for _, b in rows)
    label_w, top, legend_h = 70, 22, 34
    img = Image.new("RGB", (label_w + width * cell + 10, top + len(rows) * cell + legend_h), "white")
    d = ImageDraw.Draw(img)
    d.text((4, 4), "bit-width per (channel, block)", fill="black")
    for r, (name, bits) in enumerate(rows):
        y = top + r * cell
        d.text((4, y - 1), name, fill="black")
        cols = _colour((np.asarray(bits, float) - 1) / 15)
        for b, c in enumerate(cols):
            x = label_w + b * cell
            d.rectangle([x, y, x + cell - 1, y + cell - 2], fill=tuple(int(v) for v in c))
    y = top + len(rows) * cell + 8
    for q in range(1, 17):
        x = label_w + (q - 1) * 2 * cell
        d.rectangle([x, y, x + 2 * cell - 1, y + cell], fill=tuple(int(v) for v in _colour(np.array((q - 1) / 15))))
        if q in (1, 4, 8, 12, 16):
            d.text((x, y + cell + 1), str(q), fill="black")
    return img


def write_search_report(report: dict, folder) -> list[str]:
    """Write ``bits.png`` (heatmap of the chosen bit-widths) and ``report.json`` into ``folder``."""
    from ..decoder.io_util import atomic_write
    import io
    os.makedirs(folder, exist_ok=True)
    bits = report["bits"]
    rows = [(n, np.asarray(b)) for n, b in zip(bits["raht_channels"], bits["raht"])]
    rows += [(n, np.asarray(b)) for n, b in zip(bits["scale_channels"], bits["scales"])]
    # the kept exact SH vectors' groups, where the search allocated them (saturated budgets)
    for li, kept in enumerate(bits.get("sh_kept") or []):
        if kept is not None:
            rows += [(f"sh{j} L{li}", np.asarray(b)) for j, b in enumerate(kept)]
    buf = io.BytesIO()
    bits_heatmap(rows).save(buf, format="PNG")
    png = os.path.join(folder, "bits.png")
    atomic_write(png, buf.getvalue())
    js = os.path.join(folder, "report.json")
    atomic_write(js, json.dumps(report, indent=1, default=float).encode())
    return [png, js]
