"""The size search's report: what was chosen, why, and what every stage cost."""
from __future__ import annotations

import time

import numpy as np

from ...decoder.layout import DIRECT_CHANNELS, RAHT_CHANNELS

from ..encode_report import MODE_SEARCH, EncodeReport, SearchDetails
from ..sh_colour import sh_colour_name
from ..pipeline import layer_report
from .candidate import Candidate
from .options import SH_BITS


def search_report(search, chosen: Candidate) -> EncodeReport:
    """The report of ``search`` (a finished BudgetSearch) that chose ``chosen``."""
    enc, target, tau = chosen.encoded, search.target, chosen.reserve
    sh, data = enc.sh_keep is not None, chosen.data
    eval_cams = search.judge.cameras
    details = SearchDetails(
        deviation=(len(data) - target) / target, sh_path=enc.sh_path,
        layer_blocks=[int(b.shape[1]) for b, _ in enc.layer_bits],
        calibration=enc.rounds, calibration_all=search.log, first_layer=chosen.first_layer,
        candidates=[{"reserve": c.reserve, "depth": c.depth, "first_layer": c.first_layer,
                     "bytes": c.size, "train_psnr": c.train_psnr, "train_view_psnr": c.view_psnr,
                     "layer0_too_late": c.layer0_too_late}
                    for c in sorted(search.candidates, key=lambda c: -c.reserve)],
        screened=search.screened, dropped=search.dropped, train_psnr=chosen.train_psnr,
        channel_weights=search.judge.weights, beta=float(search.sopts.beta),
        eval_views=[c.name for c in eval_cams],
        eval_size=[int(eval_cams[0].width), int(eval_cams[0].height)] if eval_cams else None,
        note=_shortfall_note(search, chosen))
    return EncodeReport(
        mode=MODE_SEARCH, target_bytes=target, bytes=len(data), reserve=tau, depth=enc.depth,
        input_gaussians=len(search.cloud), voxels=enc.num_points,
        bytes_per_gaussian=len(data) / enc.num_points, sh_degree=search.cloud.sh_degree if sh else 0,
        codebook_size=enc.codebook_size, sh_keep=enc.sh_keep if sh else 0,
        sh_colour=sh_colour_name(search.sh_colour),
        layers=layer_report(data),
        bits={"raht": enc.raht_bits.tolist(), "scales": enc.scale_bits.tolist(),
              "raht_channels": list(RAHT_CHANNELS), "scale_channels": list(DIRECT_CHANNELS),
              "sh": SH_BITS if sh else None,
              # the SH codebook's width a component (SearchOptions.codebook_bits), None without a codebook
              "sh_codebook": enc.codebook_bits if sh else None,
              # per part: the kept SH vectors' group widths [D][B_l] where they were allocated
              # (sh_path "scalar", "classes" or "refine": one block per importance class, 0 = a constant
              # group; or above the SH_BITS ceiling), else None (SH_BITS)
              "sh_kept": [None if b is None else b.tolist() for b in enc.kept_bits]},
        components={"geometry": enc.geometry_bytes, "attributes": enc.attr_bytes,
                    **enc.attr_stats, "sh": enc.sh_bytes, "metadata": enc.meta_bytes},
        seconds=dict(search.progress.seconds), total_seconds=time.perf_counter() - search.t0,
        memory=search.progress.memory_report(),
        # CPU seconds of this process (all its threads): on a shared machine the wall clock
        # depends on the other jobs, this mostly does not
        cpu_seconds=time.process_time() - search.c0,
        search=details)


def _shortfall_note(search, chosen: Candidate) -> str | None:
    """Why the file ends more than the tolerance below the target; None when it does not."""
    enc, target, tau, data = chosen.encoded, search.target, chosen.reserve, chosen.data
    if len(data) >= target * (1.0 - search.sopts.tolerance):
        return None
    bits_all = np.concatenate([enc.raht_bits.ravel(), enc.scale_bits.ravel()]
                              + [b.ravel() for b in enc.kept_bits if b is not None])
    return (f"file is {100 * (1 - len(data) / target):.2f} % below the target: "
            + ("the budget exceeds the maximum-quality size of this scene at the chosen reserve "
               "ratio (every group at its best bit-width)" if bits_all.min() >= 12 or tau == 1.0
               else "calibration did not reach the tolerance within the round limit"))
