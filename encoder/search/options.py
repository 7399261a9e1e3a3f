"""What the size search can be asked for: its options and the error for a budget it cannot meet."""
from __future__ import annotations

from dataclasses import dataclass

from ...decoder.errors import GszError
from ...evaluation.cameras import DEFAULT_VIEW_WIDTH

from ..pipeline import MANY_BLOCKS, SceneOptions

#: bit-width of the SH codebook and the kept exact SH vectors (the paper's setting), except where
#: a budget above the 8-bit quality ceiling lets the kept vectors' groups join the allocation
#: (and the codebook's: SearchOptions.codebook_bits)
SH_BITS = 8

#: Widths a component the search may code the SH codebook at: at low rates a coarser codebook
#: buys more words (trained tiny at 27x: 262 words at 5 bits against 65 at 8, +1.5 dB;
#: docs/design/codebook-bits.md)
CODEBOOK_BITS = (SH_BITS, 6, 5)


class BudgetError(GszError, ValueError):
    """The requested budget cannot be met (names the smallest reachable size)."""

    def __init__(self, target: int, minimum: int, path=None):
        self.target = int(target)
        self.minimum = int(minimum)
        super().__init__(f"size budget {self.target:,} bytes is below the smallest reachable file "
                         f"for this scene, {self.minimum:,} bytes", path)


@dataclass(kw_only=True)
class SearchOptions(SceneOptions):
    """Knobs of the search (defaults are what the benchmarks use); the fields shared with a
    fixed configuration (layers, tiles, executor, importance pass, seed) are
    :class:`~gsz.encoder.pipeline.SceneOptions`'.

    reserves        tau grid, descending
    max_candidates  taus spread over the feasible range, encoded and compared by train PSNR
                    (a smaller tau must win by TAU_PREFERENCE_DB a unit of tau)
    refine_steps    rounds of also trying the grid neighbours of the best tau so far
    depth_steps     octree levels away from the position-error default the search may go
                    (either way); after the tau search at the default depth it walks the depth
                    from the best candidate while train PSNR improves, then refines tau there
    max_extra_depth cap on levels deeper than the default (the budget-saturated case)
    weight_channels weight Omega per channel by measured rendering sensitivity (channel_weights)
    tolerance       accepted shortfall below the target (fraction)
    max_rounds      calibration rounds per tau
    solver          "fast" (convex hull + repair) or "cbc" (PuLP, the paper's ILP)
    blocks          blocks per quantised channel of every channel set
    codebook        SH codebook size (None: the search tries a few)
    eval_views      train views rendered to compare candidates: generated ones, or as many of
                    the caller's cameras spread evenly over them; eval_width their width at
                    most.  The default is gsz-eval's view width: below it candidates that
                    prune more win on train views and lose on test views
                    (docs/design/view-width.md)
    sh_scalar       weigh the scalar SH path (every vector quantised group-wise, its widths
                    in the allocation) against the codebook at high rates
    sh_drop         where the best file keeps no SH vector exact, also try the file without
                    the SH rest (degree 0) at its tau and depth; the train views decide
    sh_classes      also encode the codebook path with its kept vectors in importance
                    classes (SHCL, format 1.3), their widths in the allocation; the train
                    views decide (docs/design/sh-classes.md)
    sh_refine       also encode every SH vector as its codeword plus a correction (SHRF,
                    format 1.9), the corrections' widths in the allocation; the train views
                    decide (docs/design/sh-refine.md)
    layer0_share    wanted fraction of the file bytes before layer 0 is decodable: when the
                    chosen file's layer 0 ends after more than 1.5x this, the layers are
                    re-split with a proportionally smaller layer 0 and that candidate re-encoded
    screen          before encoding a tau below the best so far, render its exact-attribute
                    (pruned + voxelised) cloud and skip the tau when that bound is no better
                    than the best candidate's train PSNR
    overlap         train the SH codebooks on a worker thread during the set-up
    codebook_bits   coarser widths a component the SH codebook may be coded at: the estimate
                    that picks the codebook size and keep-count weighs them beside SH_BITS
                    (always weighed) and takes one only where it gains CODEBOOK_BITS_MARGIN
    """

    reserves: tuple = (1.0, 0.9, 0.8, 0.7, 0.6, 0.5, 0.4, 0.3, 0.2)
    max_candidates: int = 3
    depth_steps: int = 3
    max_extra_depth: int = 3
    refine_steps: int = 3
    weight_channels: bool = True
    tolerance: float = 0.005
    max_rounds: int = 8
    solver: str = "fast"
    blocks: int = MANY_BLOCKS
    codebook: int | None = None
    eval_views: int = 6
    eval_width: int = DEFAULT_VIEW_WIDTH
    sh_scalar: bool = True
    sh_drop: bool = True
    sh_classes: bool = True
    sh_refine: bool = True
    layer0_share: float = 0.1
    screen: bool = True
    overlap: bool = True
    codebook_bits: tuple = CODEBOOK_BITS
