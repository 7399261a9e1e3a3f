"""Forward RAHT (encoder side) on the tree of ``gsz.decoder.raht``.

The tree, butterfly weights and AC stream layout are the decoder's (the shared truth); this
module only runs the merges bottom-up.  numpy, float64, fully vectorised per level.
"""
from __future__ import annotations

import numpy as np

from ..decoder.raht import RahtTree, build_raht_tree, raht_inverse  # noqa: F401  (re-export)


def raht_forward(attrs: np.ndarray, tree: RahtTree) -> tuple[np.ndarray, np.ndarray]:
    """RAHT coefficients of per-leaf attributes.

    attrs: float [N, C] in ascending Morton order of the tree's voxels.
    Returns (dc float64 [C], ac float64 [N-1, C] in stream order: coarse level first).
    Orthonormal: sum(attrs^2) == dc^2 + sum(ac^2) per channel up to rounding; on a weighted
    tree sum(w * attrs^2) == dc^2 + sum(ac^2) (so coefficient errors are weighted errors).
    """
    a = np.asarray(attrs, dtype=np.float64)
    if a.ndim != 2 or a.shape[0] != tree.num_points:
        raise ValueError(f"raht_forward: attrs must be [{tree.num_points}, C], got {a.shape}")
    scale = tree.leaf_scale()
    v = a.copy() if scale is None else a * scale[:, None]
    for lv in tree.levels:  # finest first
        g1, g2, _ = lv.butterfly()
        c1 = v[lv.left]
        c2 = v[lv.right]
        v[lv.left] = g1 * c1 + g2 * c2
        v[lv.right] = g1 * c2 - g2 * c1
    return v[0].copy(), v[tree.ac_slots]


def leaf_interleaved_order(tree: RahtTree) -> np.ndarray:
    """Permutation taking stream-order AC to the reference code's Morton-leaf interleave.

    Returns int64 [N-1] idx such that ac_stream[idx] lists the AC coefficients by slot 1..N-1
    (the MesonGS++ in-place layout).  Used only to compare the two layouts (docs/design/raht-layout.md).
    """
    return np.argsort(tree.ac_slots, kind="stable")
