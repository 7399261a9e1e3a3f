"""The report of an encode: one typed shape for the fixed configuration and the size search.

    res = gsz.encoder.api.encode_result(cloud, size="5MB")
    res.report.bytes, res.report.reserve, res.report.search.train_psnr
    json.dumps(res.report.to_json(), default=float)      # what gsz-encode --json prints

:class:`EncodeReport` holds what both modes know (sizes, counts, the chosen reserve / depth /
codebook, timings); :class:`FixedDetails` and :class:`SearchDetails` what only one of them knows;
:class:`WrittenFile` what gsz-encode adds once the file is on disk.  ``to_json()`` gives each
mode's JSON with exactly the keys, values and key order it had as a plain dict (the fixed mode's
JSON keeps its older, smaller key set), so --json and report.json read as before.

Lists of rows (layers, candidates, calibration rounds, ...) stay JSON rows: they are printed far
more than read, and their keys are documented where they are made.  Standard library only: every
encoder module may import this one.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

#: the two ways to encode, as the search's JSON names them in "mode"
MODE_FIXED = "fixed"
MODE_SEARCH = "size-search"


@dataclass
class FixedDetails:
    """What only a fixed configuration (:func:`gsz.encoder.pipeline.encode`) reports."""

    kept_after_prune: int       # Gaussians left by the importance prune, before voxel merging
    merged_fraction: float      # fraction of the pruned Gaussians merged into a shared voxel
    options: dict               # the EncodeOptions as META records them (depth, blocks resolved)


@dataclass
class SearchDetails:
    """What only the size search (:func:`gsz.encoder.search.encode_to_budget`) reports."""

    deviation: float            # (.gsz bytes - target) / target: <= 0, within the tolerance unless ``note``
    sh_path: str | None         # the SH rest's coding: "vq", "classes", "scalar" or "refine"; None without it
    layer_blocks: list          # [L] blocks per channel of each layer's ATTR chunk
    calibration: list           # the chosen file's rounds {round, solver_budget_bytes, predicted_bytes, actual_bytes}
    calibration_all: list       # every calibrated candidate {reserve, bytes, rounds, sh_path}
    first_layer: float          # fraction of the Gaussians in layer 0 of the chosen file
    candidates: list            # encoded candidates by descending reserve {reserve, depth, first_layer,
    #                             bytes, train_psnr, train_view_psnr, layer0_too_late}
    screened: list              # taus judged by their exact-attribute bound {reserve, depth, bound_psnr,
    #                             inferred, views, best_psnr, needed_psnr, skipped}
    dropped: list               # candidates given up after their hardest views {reserve, depth, bytes,
    #                             views, partial_psnr}
    train_psnr: float           # the chosen file's mean PSNR over the eval views (dB)
    channel_weights: dict       # rendering sensitivity per channel {raht: [7], scales: [3], sh}
    beta: float                 # volume-term exponent of the importance pass
    eval_views: list            # names of the train views candidates were compared on
    eval_size: list | None      # [width, height] of those views; None without views
    note: str | None = None     # why the file ends well below the target, when it does


@dataclass
class WrittenFile:
    """What gsz-encode adds once the file is written."""

    input: str                  # the input path as given
    output: str                 # the output path as given ("-": stdout)
    input_bytes: int            # size of the input file
    ratio: float                # the scene's graphdeco PLY bytes (the input's own for a plain PLY) / bytes
    gsz_bytes: int              # size of the .gsz payload (== bytes unless written inside a .glb)
    container: str | None = None          # "glb" when the .gsz went into a .glb; None: a plain .gsz
    target: str | None = None             # the size target in the user's units, e.g. "150 kB" (size search)
    gsz_target_bytes: int | None = None   # the .gsz's budget where the .glb's JSON takes part of target_bytes
    report_files: list | None = None      # the files --report DIR wrote (chart, report.json)

    def to_json(self) -> dict:
        """The keys gsz-encode has always added, in their order (report_files excepted: last)."""
        out = {"gsz_bytes": self.gsz_bytes}
        if self.container is not None:
            out["container"] = self.container
        out.update(input=self.input, output=self.output, input_bytes=self.input_bytes, ratio=self.ratio)
        if self.target is not None:
            out["target"] = self.target
        if self.gsz_target_bytes is not None:
            out["gsz_target_bytes"] = self.gsz_target_bytes
        return out


@dataclass
class EncodeReport:
    """What an encode made and what it cost; ``fixed`` or ``search`` holds the mode's own part."""

    mode: Literal["fixed", "size-search"]  # MODE_FIXED or MODE_SEARCH
    bytes: int                  # file size: the .gsz's, or the written .glb's once gsz-encode wrapped it
    input_gaussians: int        # Gaussians of the input scene
    voxels: int                 # Gaussians in the file (after the prune and voxel merging)
    bytes_per_gaussian: float   # .gsz bytes per Gaussian in the file
    depth: int                  # octree depth
    sh_degree: int              # SH degree the file keeps (0: none, also where the search dropped them)
    reserve: float              # tau: fraction of the Gaussians kept by the importance prune
    codebook_size: int          # SH codebook entries over all parts (0 without SH or codebook)
    sh_keep: int                # SH vectors kept exact (0 without SH)
    components: dict            # bytes per part of the file {geometry, attributes, ..., metadata}
    layers: list                # per layer {layer, gaussians, cumulative_gaussians, offset, bytes,
    #                             decodable_at, decodable_fraction}
    seconds: dict               # wall seconds per stage {stage: s}
    total_seconds: float        # wall seconds of the whole encode
    memory: dict                # peak RSS {peak_rss_mb, stages: {stage: {peak_mb, rise_mb}}}
    cpu_seconds: float          # CPU seconds of the process over the encode (all its threads)
    target_bytes: int | None = None   # the size budget (None: a fixed configuration)
    sh_colour: str | None = None      # the colour space of the file's SH rest and DC (SHXF chunk):
    #                                   "rgb", "luma-chroma", "luma-chroma DC" or "luma-chroma SH rest"
    bits: dict | None = None    # group widths {raht: [7][B], scales: [3][B], raht_channels, scale_channels,
    #                             sh, sh_kept: per part [D][B] or None}; a fixed encode's once charted
    input_fixes: list | None = None   # the input values sanitising bounded or dropped; None: none
    fixed: FixedDetails | None = None     # set when mode is MODE_FIXED
    search: SearchDetails | None = None   # set when mode is MODE_SEARCH
    written: WrittenFile | None = None    # set by gsz-encode after writing the file

    def __post_init__(self):
        # a report always carries its mode's own part: to_json() relies on it
        if (self.mode == MODE_FIXED) != (self.fixed is not None) or \
                (self.mode == MODE_SEARCH) != (self.search is not None):
            raise ValueError(f"EncodeReport: mode {self.mode!r} needs exactly its own details")

    def to_json(self) -> dict:
        """The JSON object of gsz-encode --json and report.json (values as held, not copied)."""
        out = self._search_json() if self.mode == MODE_SEARCH else self._fixed_json()
        if self.input_fixes is not None:
            out["input_fixes"] = self.input_fixes
        if self.written is not None:
            out.update(self.written.to_json())
        if self.mode == MODE_FIXED and self.bits is not None:   # charted after the encode: after the rest
            out["bits"] = self.bits
        if self.written is not None and self.written.report_files is not None:
            out["report_files"] = self.written.report_files
        return out

    def _fixed_json(self) -> dict:
        f = self.fixed
        # the fixed JSON's "sh": the SH coder's counts, {} without SH
        sh = {"kept": self.sh_keep, "codebook_size": self.codebook_size} if self.sh_degree > 0 else {}
        if sh and self.sh_colour is not None:
            sh["colour"] = self.sh_colour
        return {"bytes": self.bytes, "input_gaussians": self.input_gaussians,
                "kept_after_prune": f.kept_after_prune, "voxels": self.voxels,
                "bytes_per_gaussian": self.bytes_per_gaussian, "depth": self.depth,
                "merged_fraction": f.merged_fraction, "sh_degree": self.sh_degree,
                # an SH-0 file's DC colour has a colour space too (SHXF bit 1)
                "sh_colour": self.sh_colour,
                "components": self.components, "sh": sh, "seconds": self.seconds,
                "total_seconds": self.total_seconds, "memory": self.memory, "options": f.options,
                "layers": self.layers}

    def _search_json(self) -> dict:
        s = self.search
        out = {"mode": self.mode, "target_bytes": self.target_bytes, "bytes": self.bytes,
               "deviation": s.deviation, "reserve": self.reserve, "depth": self.depth,
               "input_gaussians": self.input_gaussians, "voxels": self.voxels,
               "bytes_per_gaussian": self.bytes_per_gaussian, "sh_degree": self.sh_degree,
               "codebook_size": self.codebook_size, "sh_keep": self.sh_keep, "sh_path": s.sh_path,
               "sh_colour": self.sh_colour,
               "layers": self.layers, "layer_blocks": s.layer_blocks, "bits": self.bits,
               "calibration": s.calibration, "calibration_all": s.calibration_all,
               "first_layer": s.first_layer, "candidates": s.candidates, "screened": s.screened,
               "dropped": s.dropped, "train_psnr": s.train_psnr, "channel_weights": s.channel_weights,
               "beta": s.beta, "eval_views": s.eval_views, "eval_size": s.eval_size,
               "components": self.components, "seconds": self.seconds,
               "total_seconds": self.total_seconds, "memory": self.memory,
               "cpu_seconds": self.cpu_seconds}
        if s.note is not None:
            out["note"] = s.note
        return out
