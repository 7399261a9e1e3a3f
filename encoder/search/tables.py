"""A stage's loss and rate tables per (channel, block) group and the byte accounting around them:
what the bit allocation works on, and how its pick maps back to per-layer bit-widths."""
from __future__ import annotations

import numpy as np

from ...decoder.groups import blocks_for

from ..pipeline import Stage, encoder_name


def attribute_sets(stage: Stage, blocks: int):
    """(x [C, L], blocks) of every attribute channel set of the stage, in the solver's group
    order (layer 0 RAHT, layer 0 scales, layer 1 RAHT, ...)."""
    return [(x, blocks_for(x.shape[1], lb)) for layer, lb in zip(stage.layers, stage.layer_blocks(blocks))
            for x in (layer.raht_ac, layer.scales)]


def raw_tables(stage: Stage, blocks: int):
    """Loss [C, B, 16] (importance-weighted in parts with RAHT weights) and rate [C, B, 16] of
    every channel set, computed once per stage (the size bounds, every calibration round and
    every re-run of a tau share them)."""
    from ...kernels.quantize import quantize_all_bits

    from ..rate import rate_matrix
    key = ("tables", blocks)
    if key not in stage.cache:
        out = []
        for i, (x, b) in enumerate(attribute_sets(stage, blocks)):
            wt = _loss_weights(stage, stage.layers[i // 2], b)[i % 2]
            if x.shape[1]:
                _, _, _, loss = quantize_all_bits(x, b)
                if wt is not None:
                    loss = loss * wt
                rate = rate_matrix(x, b)
            else:
                loss = np.zeros((x.shape[0], b, 16))
                rate = np.zeros((x.shape[0], b, 16))
            out.append((loss, rate))
        stage.cache[key] = out
    return stage.cache[key]


def _loss_weights(stage: Stage, layer, scale_blocks: int):
    """(RAHT, scales) loss multipliers of a part with RAHT weights (None, None without): its
    weighted RAHT's coefficient errors are sum(w * error^2), w proportional to the classes'
    mean importance, so over the mean leaf weight, times the part's mean importance over the
    stage's, they weigh like the SH classes' errors (importance over the stage mean); its
    class-ordered scale blocks by their voxels' mean importance over the stage's."""
    w = layer.leaf_weights
    if w is None:
        return None, None
    from ...decoder.quant import split_lengths

    from ..pipeline import capped_importance
    capped = stage.cache.get("capped_importance")
    if capped is None:
        capped = stage.cache["capped_importance"] = capped_importance(stage.importance)
    mean = float(capped.mean()) or 1.0
    imp = capped[layer.index]
    raht = float(w.shape[0]) / float(w.sum()) * float(imp.mean()) / mean
    stored = imp[layer.scale_order] / mean
    lens = split_lengths(stored.shape[0], scale_blocks)
    ends = np.cumsum(lens)
    per_block = np.add.reduceat(stored, ends - lens) / lens if stored.size else np.zeros(0)
    return raht, per_block[None, :, None]


def attribute_tables(stage: Stage, blocks: int, weights: dict | None = None):
    """(loss [G, 16] weighted per channel by ``weights`` -- channel_weights --, rate [G, 16],
    shapes ((C, B) per channel set)) of every attribute group of the stage."""
    losses, rates, shapes = [], [], []
    w_sets = (None, None) if weights is None else (weights["raht"], weights["scales"])
    for i, (loss, rate) in enumerate(raw_tables(stage, blocks)):
        w = w_sets[i % 2]
        if w is not None:
            loss = loss * np.asarray(w, np.float64)[:, None, None]
        losses.append(loss.reshape(-1, 16))
        rates.append(rate.reshape(-1, 16))
        shapes.append(loss.shape[:2])
    return np.concatenate(losses), np.concatenate(rates), tuple(shapes)


def group_meta_bytes(shapes) -> int:
    """Bytes of the channel sets' headers and per-group parameters (GSZ.md §5)."""
    # per channel set: C u8, L u32, B u16, model_mode u8, blob length u64; per group: u8 + 2 f32
    return sum(16 + 9 * c * b for c, b in shapes)


def split_bits(pick: np.ndarray, shapes) -> list:
    """Per layer, (raht_bits [7, B_l], scale_bits [3, B_l]) from the solver's pick over every
    layer's groups (order: layer 0 RAHT, layer 0 scales, layer 1 RAHT, ...)."""
    bits = pick.astype(np.int64) + 1
    out, pos = [], 0
    for c, b in shapes:
        out.append(bits[pos:pos + c * b].reshape(c, b))
        pos += c * b
    return [(out[i], out[i + 1]) for i in range(0, len(out), 2)]


def split_kept_bits(pick: np.ndarray, shapes, kept_layers: list, num_layers: int) -> list:
    """Per layer, the kept SH vectors' group bit-widths [D, B_l] from the solver's pick over
    their groups (layers in ``kept_layers`` order); None for a layer whose kept vectors are not
    in the allocation (none kept, or all at SH_BITS)."""
    out, pos = [None] * num_layers, 0
    for li, (c, b) in zip(kept_layers, shapes):
        w = pick[pos:pos + c * b].astype(np.int64).reshape(c, b) + 1
        w[w == 1] = 0           # kept_tables' column 0 is the constant group (width 0)
        out[li] = w
        pos += c * b
    return out


def concat_bits(bits: list) -> tuple[np.ndarray, np.ndarray]:
    """Every layer's blocks side by side: ([7, sum B_l], [3, sum B_l]) for reports/heatmaps."""
    return (np.concatenate([r for r, _ in bits], axis=1), np.concatenate([s for _, s in bits], axis=1))


def size_bounds(stage: Stage, blocks: int) -> tuple[float, float]:
    """Rough (min, max) file bytes at this tau: all groups at 1 bit / at 16 bits."""
    lo = hi = stage.geometry_bytes + 400.0
    for (x, b), (_, r) in zip(attribute_sets(stage, blocks), raw_tables(stage, blocks)):
        if x.shape[1]:
            lo += r[:, :, 0].sum() / 8 + 9 * r.shape[0] * b
            hi += r[:, :, 15].sum() / 8 + 9 * r.shape[0] * b
    if stage.sh.shape[1]:
        m, d = stage.sh.shape
        lo += m * 12 / 8 + 64
        hi += m * d * 16 / 8
    return lo, hi


def container_overhead(num_chunks: int) -> int:
    """Header, chunk table and trailing CRC of a container with ``num_chunks`` chunks."""
    return 64 + 24 * num_chunks + 4


def num_chunks(stage: Stage) -> int:
    """Chunks of the stage's file: per layer GEOM, ATTR (and SHVQ with SH, and SHXF with a
    colour transform), plus META."""
    per_part = (3 if stage.sh.shape[1] else 2) + (1 if stage.sh_colour else 0)
    return len(stage.layers) * per_part + 1


def search_meta(stage: Stage, target: int, extra: dict) -> dict:
    """The META chunk's JSON of a size-search file."""
    return {"encoder": encoder_name(), "codec": "mesongs++", "mode": "size-search",
            "target_bytes": int(target), "reserve": stage.reserve, "depth": stage.depth,
            "input_gaussians": stage.input_gaussians, "voxels": stage.num_points, **extra}
