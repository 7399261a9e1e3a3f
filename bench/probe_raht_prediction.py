"""Would RAHT prediction across octree levels pay (G-PCC's inter-depth prediction; issue 18,
docs/design/high-rate-gap.md)?  Outside the format: the RAHT channels of a voxelised scene
(opacity, Euler angles, DC colour) coded as today (every AC coefficient quantised) against the
AC coefficients minus their prediction from the parent level.

    .venv/bin/python bench/probe_raht_prediction.py SCENE.ply [--depth 11] [--noise]

The prediction of a node at octree level k+1: the weighted mean of its parent's value and the
values of the parent's neighbours (level k) that touch the node (3 faces, 3 edges, 1 corner),
weights ``--weights`` (parent, face, edge, corner; G-PCC's spirit: nearer counts more).  The
node values the decoder would have are the level-k means of a reconstruction at the same step
(the plain path's: an approximation of the closed loop, whose coarser coefficients carry errors
of the same size).  The leaf signal "every leaf = its level-(k+1) node's prediction" goes
through the same forward RAHT; its AC coefficients of the three binary levels that merge level
k+1 into k are the predicted ones.  Per channel and step (a share of the channel's AC RMS): the
zeroth-order entropy of the symbols in 80 blocks of the level-ordered stream (the codec's
layout) and the SSE, plain against predicted, per octree level where ``--levels``.
"""
from __future__ import annotations

import argparse
import itertools

import numpy as np

CHANNELS = ("opacity", "roll", "pitch", "yaw", "dc_r", "dc_g", "dc_b")


def voxelise(cloud, depth: int):
    """(sorted unique Morton codes, mean attributes [N, 7]) on a cubic grid of 2^depth a side."""
    from gsz.decoder.morton import morton_encode
    from gsz.decoder.rotation import quaternion_to_euler
    p = cloud.positions.astype(np.float64)
    lo = p.min(0)
    side = float((p.max(0) - lo).max()) or 1.0
    ijk = np.minimum((((p - lo) / side) * 2 ** depth).astype(np.int64), 2 ** depth - 1)
    codes, inv = np.unique(morton_encode(ijk), return_inverse=True)
    attrs = np.concatenate([cloud.opacities[:, None], quaternion_to_euler(cloud.rotations),
                            cloud.sh_dc], 1).astype(np.float64)
    sums = np.zeros((codes.size, attrs.shape[1]))
    np.add.at(sums, inv.ravel(), attrs)
    return codes.astype(np.uint64), sums / np.bincount(inv.ravel())[:, None]


def level_of_ac(tree) -> np.ndarray:
    """Binary level of every AC coefficient in stream order (0 = the finest merge)."""
    return np.concatenate([np.full(n, lv, np.int64) for lv, n in tree.level_sizes()])


def node_means(codes: np.ndarray, values: np.ndarray, shift: int):
    """(node codes at ``shift`` bits up, mean of each node's leaves [n, C], node of each leaf)."""
    up = codes >> np.uint64(shift)
    nodes, inv = np.unique(up, return_inverse=True)
    inv = inv.ravel()
    cnt = np.bincount(inv, minlength=nodes.size).astype(np.float64)
    means = np.stack([np.bincount(inv, weights=values[:, c], minlength=nodes.size)
                      for c in range(values.shape[1])], 1) / cnt[:, None]
    return nodes, means, inv


def predicted_leaf_signal(codes: np.ndarray, rec: np.ndarray, depth: int, k: int,
                          weights: tuple) -> np.ndarray:
    """Every leaf's prediction of its level-(k+1) node from level-k values of ``rec`` [N, C]."""
    from gsz.decoder.morton import morton_decode, morton_encode
    parents, pmeans, _ = node_means(codes, rec, 3 * (depth - k))
    children, _, leaf_child = node_means(codes, rec, 3 * (depth - k - 1))
    cijk = morton_decode(children).astype(np.int64)
    pijk = cijk >> 1
    direction = 2 * (cijk & 1) - 1                  # the side of the parent the child sits on
    side = 1 << k
    num = np.zeros((children.size, rec.shape[1]))
    den = np.zeros(children.size)
    for o in itertools.product((0, 1), repeat=3):
        w = weights[sum(o)]
        if w == 0:
            continue
        q = pijk + direction * np.array(o)
        inside = ((q >= 0) & (q < side)).all(1)
        code = morton_encode(np.where(inside[:, None], q, 0)).astype(np.uint64)
        at = np.minimum(np.searchsorted(parents, code), parents.size - 1)
        found = inside & (parents[at] == code)
        num[found] += w * pmeans[at[found]]
        den[found] += w
    return (num / den[:, None])[leaf_child]


def block_entropy_bits(sym: np.ndarray, blocks: int = 80) -> float:
    """Zeroth-order entropy of integer symbols [L] in ``blocks`` contiguous blocks, in bits."""
    from gsz.decoder.quant import split_lengths
    total, s = 0.0, 0
    for n in split_lengths(sym.size, blocks).tolist():
        seg = sym[s:s + n]
        s += n
        if seg.size:
            _, cnt = np.unique(seg, return_counts=True)
            total -= float((cnt * np.log2(cnt / seg.size)).sum())
    return total


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("scene")
    p.add_argument("--depth", type=int, default=11)
    p.add_argument("--noise", action="store_true", help="the bench's small noise on the scene first")
    p.add_argument("--steps", default="1,0.5,0.25,0.1,0.05", help="steps as shares of each channel's AC RMS")
    p.add_argument("--weights", default="4,2,1,0", help="parent, face, edge, corner neighbour weights")
    p.add_argument("--levels", action="store_true", help="also the bits by octree level")
    a = p.parse_args(argv)
    from gsz.decoder import read_ply
    from gsz.decoder.raht import build_raht_tree, raht_inverse
    from gsz.encoder.raht import raht_forward

    cloud = read_ply(a.scene)
    if a.noise:
        from bench_codec import add_noise  # noqa: E402  (the bench's noised variant)
        cloud = add_noise(cloud)
    weights = tuple(float(v) for v in a.weights.split(","))
    codes, attrs = voxelise(cloud, a.depth)
    n = codes.size
    tree = build_raht_tree(codes, a.depth)
    dc, ac = raht_forward(attrs, tree)
    lev = level_of_ac(tree)
    rms = np.sqrt((ac ** 2).mean(0))
    print(f"{a.scene}: {len(cloud):,} Gaussians, {n:,} voxels at depth {a.depth}; weights {weights}")
    print("| step (x AC RMS) | channel | plain bits/coef | predicted bits/coef | change | plain SSE | predicted SSE |")
    print("|---|---|---|---|---|---|---|")
    for share in (float(v) for v in a.steps.split(",")):
        step = share * rms
        q_plain = np.rint(ac / step)
        rec = raht_inverse(dc, q_plain * step, tree)
        pred_ac = np.zeros_like(ac)
        for k in range(a.depth):
            sig = predicted_leaf_signal(codes, rec, a.depth, k, weights)
            _, pac = raht_forward(sig, tree)
            sel = (lev >= 3 * (a.depth - k - 1)) & (lev < 3 * (a.depth - k))
            pred_ac[sel] = pac[sel]
        res = ac - pred_ac
        q_res = np.rint(res / step)
        tot_p = tot_r = 0.0
        for c, name in enumerate(CHANNELS):
            bp = block_entropy_bits(q_plain[:, c].astype(np.int64))
            br = block_entropy_bits(q_res[:, c].astype(np.int64))
            sp = float(((ac[:, c] - q_plain[:, c] * step[c]) ** 2).sum())
            sr = float(((res[:, c] - q_res[:, c] * step[c]) ** 2).sum())
            tot_p, tot_r = tot_p + bp, tot_r + br
            print(f"| {share:g} | {name} | {bp / n:.3f} | {br / n:.3f} | {100 * (br / bp - 1):+.1f} % "
                  f"| {sp:.4g} | {sr:.4g} |")
        print(f"| {share:g} | **all** | {tot_p / n:.3f} | {tot_r / n:.3f} | **{100 * (tot_r / tot_p - 1):+.1f} %** | | |",
              flush=True)
        if a.levels:
            for k in range(a.depth):
                sel = (lev >= 3 * (a.depth - k - 1)) & (lev < 3 * (a.depth - k))
                if sel.sum() < 100:
                    continue
                bp = sum(block_entropy_bits(q_plain[sel, c].astype(np.int64), 1) for c in range(7))
                br = sum(block_entropy_bits(q_res[sel, c].astype(np.int64), 1) for c in range(7))
                print(f"|   level {k}->{k + 1} | {int(sel.sum()):,} coefs | {bp / n:.3f} | {br / n:.3f} "
                      f"| {100 * (br / max(bp, 1e-9) - 1):+.1f} % | | |")
    return 0


if __name__ == "__main__":
    import sys
    from pathlib import Path
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    raise SystemExit(main())
