"""Layered (progressive) files: layer 0 should arrive after about ``layer0_share`` of the bytes.

Kept exact SH vectors make the most important Gaussians several times dearer than the rest, so
on SH scenes a Gaussian share of ``first_layer`` can cost far more bytes; the chosen configuration
is re-split with a proportionally smaller layer 0 (at most twice).  A layer 0 that holds codeword
indices also carries the whole SH codebook (GSZ.md §4.1), which on small scenes outweighs
everything else in it (tiny_graphdeco at 12x: a 47 kB codebook for 87 Gaussians); keeping layer
0's vectors exact instead moves the codebook to layer 1, so that variant is tried too.  Among the
candidates, those whose layer 0 arrives in time win over those that do not.
"""
from __future__ import annotations

from ..pipeline import layer_report
from .candidate import Candidate, best_of


def layer0_share(c: Candidate) -> float:
    """Fraction of the file's bytes after which layer 0 is decodable."""
    return layer_report(c.data)[0]["decodable_fraction"]


def layer0_late(c: Candidate, sopts) -> bool:
    return layer0_share(c) > 1.5 * sopts.layer0_share


def resplit_layer0(search) -> None:
    """Re-encode the best candidate of ``search`` (a BudgetSearch) with a smaller layer 0, and
    with layer 0's SH vectors kept exact, while its layer 0 arrives late (twice at most); a
    candidate whose variants were tried is marked ``layer0_too_late``."""
    sopts = search.sopts
    for _ in range(2 if sopts.layers > 1 else 0):
        pool = [c for c in search.candidates if not c.layer0_too_late]
        if not pool:
            break
        best = best_of(pool)
        share = layer0_share(best)
        if share <= 1.5 * sopts.layer0_share:
            break
        fl = best.first_layer * sopts.layer0_share / share
        search.progress.log(f"layer 0 arrives after {100 * share:.1f} % of the file: re-splitting the "
                            f"layers with {100 * fl:.2f} % of the Gaussians in layer 0")
        n_before = len(search.candidates)
        search.try_tau(best.reserve, best.depth, fl)
        n0 = best.encoded.layer0_points
        keep = best.encoded.sh_keep
        if keep is not None and keep < n0:
            search.progress.log(f"... and keeping layer 0's {n0:,} SH vectors exact (the codebook "
                                f"then travels with layer 1)")
            search.try_tau(best.reserve, best.depth, best.first_layer, min_keep=n0)
        if len(search.candidates) > n_before:
            best.layer0_too_late = True


def finalists(candidates: list, sopts) -> list:
    """The candidates the file is chosen from: not superseded by a re-split, and of those, the
    ones whose layer 0 arrives in time when any does."""
    chosen = [c for c in candidates if not c.layer0_too_late]
    if sopts.layers > 1 and any(not layer0_late(c, sopts) for c in chosen):
        chosen = [c for c in chosen if not layer0_late(c, sopts)]
    return chosen
