"""gsz-encode: compress a 3DGS PLY into a .gsz file."""
from __future__ import annotations

import argparse
import contextlib
import json
import os
import sys

from ..decoder.errors import GszError, GszUsageError
from .encode_report import EncodeReport, WrittenFile


def build_parser() -> argparse.ArgumentParser:
    from ..decoder.cli_common import (HelpFormatter, add_overwrite, add_verbosity, add_version_flag)
    from .pipeline import MANY_BLOCKS, ONE_BLOCK_MIN_BITS, STREAMING_LAYERS, EncodeOptions
    from .search import SearchOptions
    from .sh_colour import SH_COLOUR_CHOICES
    d = EncodeOptions()
    p = argparse.ArgumentParser(
        prog="gsz-encode", description="Compress a trained 3DGS point_cloud.ply into a .gsz file.",
        formatter_class=HelpFormatter,
        epilog="Give a size target (--size, --ratio or --profile) and the encoder searches the "
               "configuration; without one it encodes the fixed configuration below.  Exit status: "
               "0 ok, 1 error (bad input, unreachable size, output exists or cannot be written), "
               "2 bad options, 130 interrupted.")
    add_version_flag(p)
    p.add_argument("input", help="input scene, told by content: a graphdeco 3DGS PLY (SH degree 0-3; also "
                                 "its nerfstudio rgb and 2DGS variants and PlayCanvas's compressed PLY), a "
                                 "KHR_gaussian_splatting .glb/.gltf, an .spz, .splat, .ksplat or PlayCanvas "
                                 "SOG (.sog or meta.json)")
    out = p.add_argument_group("output")
    out.add_argument("-o", "--output", required=True,
                     help="output .gsz file, or OUT.glb: the .gsz inside a glTF binary "
                          "(EXT_gaussian_splatting_compression_gsz, format_spec/GLTF.md); written "
                          "atomically; - writes the .gsz to stdout (nothing else goes there)")
    add_overwrite(out)
    out.add_argument("--report", default=None, metavar="DIR",
                     help="also write DIR/bits.png (the bit-width of every channel and block; needs "
                          "matplotlib, gsz[plots]) and DIR/report.json; with a size target or a fixed "
                          "configuration")
    out.add_argument("--json", action="store_true", help="print a JSON report on stdout")
    add_verbosity(out, quiet_help="errors only",
                  verbose_help="every stage with its time and memory, and the search's detail")
    budget = p.add_argument_group("size target (the encoder searches the configuration; give one)")
    budget.add_argument("--size", default=None, help="byte budget, e.g. 5MB, 4.5MiB, 800kB, 1200000")
    budget.add_argument("--ratio", default=None, help="compression ratio vs the input PLY, e.g. 30 or 30x "
                                                      "(for any other input: vs the graphdeco PLY of its scene)")
    budget.add_argument("--profile", default=None, help="large (8x), medium (12x), small (18x), very-small (27x), tiny (40x)")
    budget.add_argument("--solver", default="fast", choices=["fast", "cbc"],
                        help="bit-allocation solver of the size search")
    fixed = p.add_argument_group("fixed configuration (without a size target)")
    fixed.add_argument("--reserve", type=float, default=None, help=f"fraction of Gaussians kept by importance pruning (tau; default {d.reserve})")
    fixed.add_argument("--bits", type=int, default=None, help=f"uniform bit-width of every quantisation group (1-16; default {d.bits})")
    fixed.add_argument("--keep", type=int, default=None, help="number of most important Gaussians whose exact SH is kept (default: 1%% of voxels)")
    fixed.add_argument("--depth", type=int, default=None, help="octree depth 1-21 (default: chosen from the position-error budget)")
    fixed.add_argument("--rel-error", type=float, default=None, help="auto-depth position-error budget, relative to the robust scene diagonal")
    fixed.add_argument("--sh-bits", type=int, default=None, help="bit-width of SH codebook and kept vectors (default: --bits)")
    fixed.add_argument("--sh-classes", type=int, default=None, help="importance classes of the kept SH vectors, 2-16 (format 1.3; default: none)")
    fixed.add_argument("--sh-refine", action="store_true", default=None,
                       help="code the kept SH vectors as corrections of their nearest codeword (format 1.9)")
    both = p.add_argument_group("both modes")
    both.add_argument("--codebook", type=int, default=None,
                      help=f"SH vector-quantisation codebook size K (fixed configuration default {d.codebook}; "
                           "the size search picks K itself unless given)")
    both.add_argument("--blocks", type=int, default=None,
                      help=f"blocks per quantised channel (default for a fixed configuration: 1 at >= "
                           f"{ONE_BLOCK_MIN_BITS} bits, one quantisation step per channel, {MANY_BLOCKS} below; "
                           f"{SearchOptions.blocks} for the size search, which picks a bit-width per block)")
    both.add_argument("--beta", type=float, default=d.beta, help="volume-term exponent of the importance")
    both.add_argument("--cameras", default=None, help="cameras.json or COLMAP model for the importance pass (default: generated views)")
    both.add_argument("--train-views", type=int, default=d.train_views, help="number of generated train views (without --cameras)")
    both.add_argument("--importance-width", type=int, default=d.importance_width, help="render width of the importance pass")
    both.add_argument("--raht-classes", type=int, default=d.raht_classes,
                      help="importance classes of the RAHT leaves, 2-16 (an RWGT chunk, format 1.5: "
                           "important Gaussians get finer opacity, rotation and colour for the same "
                           f"bytes); 1: plain RAHT (default {d.raht_classes})")
    both.add_argument("--sh-colour", choices=SH_COLOUR_CHOICES, default=d.sh_colour,
                      help="colour space of the DC colour and SH rest: luma-chroma (format 1.7: "
                           "correlated channels code in fewer bits), klt (format 1.8: the SH rest "
                           "in its own principal axes, correlated coefficients too), rgb, or auto: "
                           "the DC as luma-chroma, the SH rest in the KLT where it gains, else "
                           "luma-chroma unless it sits on a delivery format's coarse grid "
                           "(default auto)")
    both.add_argument("--seed", type=int, default=d.seed, help="RNG seed (VQ)")
    lay = p.add_argument_group("layers, tiles and workers")
    lay.add_argument("--layers", type=int, nargs="?", default=d.layers, const=STREAMING_LAYERS, metavar="L",
                     help="importance-ordered layers for progressive streaming; layer 0 = the most "
                          "important Gaussians, decodable on its own. --layers alone = "
                          f"{STREAMING_LAYERS} (docs/design/layers.md); default 1 (single layer, "
                          "best fidelity per byte)")
    lay.add_argument("--first-layer", type=float, default=d.first_layer,
                     help="fraction of the Gaussians in layer 0 (with --layers > 1)")
    lay.add_argument("--tile-gaussians", type=int, default=d.tile_gaussians, metavar="N",
                     help="split a scene of more than N Gaussians (after pruning) into spatial tiles "
                          "of at most N, each decodable alone; 0: never split")
    lay.add_argument("--executor", default=d.executor, metavar="WHERE",
                     help="where per-tile work runs: local (worker processes), inline, ray (a local "
                          "Ray, needs gsz[cluster]) or ray://HOST:PORT (an existing cluster); the "
                          "file is the same whichever")
    lay.add_argument("--workers", type=int, default=None, help="worker processes (default: the machine's cores less one; 1 runs the work in the encoder's own process)")
    return p


def _read_inputs(a, prog):
    """The input cloud and, when --cameras is given, its train cameras."""
    import numpy as np

    from ..decoder.errors import PlyFormatError
    from ..decoder.formats import load
    with prog.stage("read", a.input):
        cloud = load(a.input)                 # any scene format, told by content
    if getattr(a, "ratio_bytes", 0) is None:
        from ..decoder.ply import graphdeco_ply_bytes
        a.ratio_bytes = graphdeco_ply_bytes(len(cloud), cloud.sh_degree)
    if len(cloud) == 0:
        raise PlyFormatError("has 0 vertices (Gaussians): nothing to encode", a.input)
    zero = ~(np.abs(cloud.rotations).sum(axis=1) > 0)    # the importance renderer needs a rotation
    if zero.any():
        raise PlyFormatError(f"{int(zero.sum())} vertices have an all-zero rotation quaternion "
                             f"(rot_0..rot_3), first at vertex {int(np.argmax(zero))}", a.input)
    cameras = None
    if a.cameras:
        from ..evaluation.cameras import load_cameras
        cameras = load_cameras(a.cameras, cloud).train
    return cloud, cameras


def _run_fixed(a, prog) -> EncodeReport:
    from .pipeline import EncodeOptions, encode
    opts = EncodeOptions(reserve=EncodeOptions.reserve if a.reserve is None else a.reserve,
                         bits=EncodeOptions.bits if a.bits is None else a.bits,
                         codebook=EncodeOptions.codebook if a.codebook is None else a.codebook,
                         keep=a.keep, blocks=a.blocks, depth=a.depth, rel_error=a.rel_error, beta=a.beta,
                         sh_bits=a.sh_bits, sh_classes=a.sh_classes or EncodeOptions.sh_classes,
                         sh_refine=bool(a.sh_refine),
                         train_views=a.train_views, importance_width=a.importance_width,
                         layers=a.layers, first_layer=a.first_layer, seed=a.seed,
                         tile_gaussians=a.tile_gaussians or None, executor=a.executor,
                         workers=a.workers, raht_classes=a.raht_classes, sh_colour=a.sh_colour).validate()
    _check_paths(a)                           # after the options: their errors come first
    cloud, cameras = _read_inputs(a, prog)
    result = encode(cloud, opts, cameras=cameras, progress=prog, source=a.input, reuse_input=True)
    r = _finish(a, result)
    _write_report(a, r, result.data)
    return r


def _run_search(a, prog) -> EncodeReport:
    from .search import SearchOptions, encode_to_budget
    from ..decoder.sizes import budget_from_args, format_size, size_style

    fixed_only = [flag for flag, v in (("--reserve", a.reserve), ("--bits", a.bits), ("--keep", a.keep),
                                       ("--depth", a.depth), ("--rel-error", a.rel_error),
                                       ("--sh-bits", a.sh_bits), ("--sh-classes", a.sh_classes),
                                       ("--sh-refine", a.sh_refine))
                  if v is not None]
    if fixed_only:
        raise GszUsageError("--size/--ratio/--profile choose the reserve, depth, bit-widths and kept SH "
                            f"themselves; drop {'/'.join(fixed_only)}")
    _check_paths(a)
    cloud = cameras = None
    if a.size is None and a.ratio_bytes is None:   # a ratio of a non-PLY input: of its scene's PLY
        cloud, cameras = _read_inputs(a, prog)
    target = budget_from_args(size=a.size, ratio=a.ratio, profile=a.profile, ply_bytes=a.ratio_bytes)
    style = size_style(a.size) if a.size is not None else "auto"
    prog.log(f"target size {format_size(target, style)} ({target:,} bytes)")
    if cloud is None:
        cloud, cameras = _read_inputs(a, prog)
    payload_target = target
    if _glb_output(a):                        # the budget is the .glb's: leave room for its JSON
        from ..decoder.gltf import glb_overhead
        payload_target = target - glb_overhead(len(cloud), cloud.sh_degree)
        if payload_target <= 0:
            raise GszError(f"--size: {target:,} bytes do not even hold the .glb's JSON", a.output)
    sopts = SearchOptions(solver=a.solver,
                          blocks=SearchOptions.blocks if a.blocks is None else a.blocks,
                          train_views=a.train_views, beta=a.beta,
                          importance_width=a.importance_width, seed=a.seed,
                          layers=a.layers, first_layer=a.first_layer, tile_gaussians=a.tile_gaussians or None,
                          executor=a.executor, workers=a.workers, raht_classes=a.raht_classes,
                          codebook=a.codebook, sh_colour=a.sh_colour)
    # the cloud is the CLI's own and not read again: the encoder may overwrite it (1 GB less at 6 M)
    result = encode_to_budget(cloud, payload_target, options=sopts, cameras=cameras, progress=prog,
                              source=a.input, reuse_input=True)
    r = _finish(a, result, target=format_size(target, style))
    if payload_target != target:              # the budget the user gave is the .glb's
        r.target_bytes, r.written.gsz_target_bytes = target, payload_target
    _write_report(a, r, result.data)
    prog.log(f"{100 * r.bytes / target:.2f} % of the {r.written.target} target; reserve {r.reserve}, "
             f"codebook {r.codebook_size}{_codebook_width(r)}, keep {r.sh_keep}, "
             f"train PSNR {r.search.train_psnr:.2f} dB")
    return r


def _codebook_width(r) -> str:
    """The log's "at N bits" where the search coded the SH codebook below SH_BITS."""
    from .search import SH_BITS
    bits = (r.bits or {}).get("sh_codebook")
    return f" at {bits} bits" if bits and bits != SH_BITS else ""


def _write_report(a, r: EncodeReport, data: bytes) -> None:
    if a.report:
        from .report import write_report
        files = write_report(r, a.report, data)
        r.written.report_files = files       # in the printed JSON; report.json holds the rest


def _glb_output(a) -> bool:
    return a.output.lower().endswith(".glb")


def _finish(a, result, target: str | None = None) -> EncodeReport:
    """Write the file atomically, or to stdout for ``-o -`` (a .glb around the .gsz for OUT.glb),
    and complete the report (``target``: the size target as the user's units show it);
    ``bytes`` becomes the written file's size, ``written.gsz_bytes`` is the .gsz payload's."""
    from ..decoder.cli_common import write_output
    data = result.data
    r = result.report
    gsz_bytes, container = len(data), None
    if _glb_output(a):
        from ..decoder.gltf import gsz_glb_bytes
        data = gsz_glb_bytes(data)
        container = "glb"
    r.bytes = len(data)
    write_output(a.output, data)              # a GszError naming a.output when it fails
    in_bytes = a.input_bytes
    base = getattr(a, "ratio_bytes", None) or in_bytes
    r.written = WrittenFile(input=a.input, output=a.output, input_bytes=in_bytes, ratio=base / r.bytes,
                            gsz_bytes=gsz_bytes, container=container, target=target)
    return r


def _check_paths(a) -> None:
    """Input and output checks after the options' and before the long encode: a readable regular
    input file, an output that is not an input, is new (or -w) and whose folder is writable, a
    report folder whose files may be written, and the optional packages the outputs need."""
    from ..decoder.cli_common import STDOUT, check_output
    from ..decoder.errors import PlyFormatError
    from ..decoder.io_util import check_input_file
    if a.output == STDOUT and a.json:
        raise GszUsageError("-o - writes the .gsz to stdout: --json cannot share it (use --report DIR)")
    a.input_bytes = check_input_file(a.input, PlyFormatError)
    # what --ratio divides and the report's ratio measures: a graphdeco PLY's own size; for any
    # other input (already compressed, or laid out otherwise) the size of its scene's PLY, known
    # once the scene is read (None until then)
    a.ratio_bytes = a.input_bytes if _plain_ply(a.input) else None
    check_output(a.output, inputs=[a.input, a.cameras], overwrite=a.overwrite, stdout=True)
    if a.output.lower().endswith(".gltf"):
        raise GszUsageError("gsz-encode writes .gsz or .glb (the .gsz needs a glTF binary's BIN chunk); "
                            "plain glTF comes from gsz-decode IN.gsz -o OUT.gltf", a.output)
    if _glb_output(a):
        from ..decoder.gltf import pygltflib
        pygltflib()                           # the missing extra is said before the encode
    if a.report:
        if os.path.exists(a.report) and not os.path.isdir(a.report):
            raise GszError("--report: is a file, expected a folder", a.report)
        from .report import require_matplotlib
        require_matplotlib()
        for name in ("report.json", "bits.png"):
            check_output(os.path.join(a.report, name), inputs=[a.input, a.cameras], overwrite=a.overwrite)


def _plain_ply(path) -> bool:
    """True for a PLY input that is not PlayCanvas's compressed PLY (its header, read alone)."""
    from ..decoder.errors import GszError as _E
    from ..decoder.formats import PLY, sniff_file
    try:
        if sniff_file(path) != PLY:
            return False
        with open(path, "rb") as f:
            head = f.read(1 << 16)
    except (_E, OSError):
        return True                           # the reader gives the real error
    end = head.find(b"end_header")
    return b"element chunk" not in (head[:end] if end >= 0 else head)


def _run(a):
    """(report, progress) of the encode ``a`` asks for, its output written."""
    import torch  # noqa: F401  (the encoder's first need: a core-only install is told here, before any work)

    from .progress import Progress
    prog = Progress(verbosity=a.verbosity)
    searching = any(v is not None for v in (a.size, a.ratio, a.profile))
    return (_run_search(a, prog) if searching else _run_fixed(a, prog)), prog


@contextlib.contextmanager
def _input_warnings_as_lines(verbosity: int):
    """GszInputWarnings (a fixed input value, ignored PLY vertices) printed as they come, one
    'gsz-encode: warning: FILE: ...' line each (none with -q); other warnings as Python prints
    them."""
    import warnings

    from ..decoder.cli_common import warn
    from ..decoder.errors import GszInputWarning
    with warnings.catch_warnings():
        shown = warnings.showwarning

        def show(message, category, filename, lineno, file=None, line=None):
            if issubclass(category, GszInputWarning):
                warn("gsz-encode", message, verbosity)
            elif verbosity > 0:
                shown(message, category, filename, lineno, file, line)
        warnings.showwarning = show
        warnings.simplefilter("always", GszInputWarning)
        yield


def main(argv=None) -> int:
    from ..decoder.cli_common import STDOUT, run_guarded
    from ..decoder.io_util import sigterm_as_interrupt
    args = {}

    def work():                               # parsing too: Ctrl-C may land in the start-up
        a = args["a"] = build_parser().parse_args(argv)
        with sigterm_as_interrupt(), _input_warnings_as_lines(a.verbosity):
            return _run(a)                    # imports torch: Ctrl-C may land there too
    code, out = run_guarded("gsz-encode", work, "interrupted; no output written")
    if code is not None:
        return code
    a, (r, prog) = args["a"], out
    if a.json:
        print(json.dumps(r.to_json(), indent=1, default=float))
    else:
        where = "stdout" if a.output == STDOUT else a.output
        prog.log(f"wrote {where}: {r.bytes:,} bytes ({r.written.ratio:.1f}x smaller than the PLY, "
                 f"{r.bytes_per_gaussian:.2f} B/Gaussian, {r.voxels:,} Gaussians)")
        prog.log("  " + ", ".join(f"{k} {v:,}" for k, v in r.components.items()))
        if len(r.layers) > 1:
            prog.log("  layers: " + ", ".join(
                f"{x['layer']}: {x['cumulative_gaussians']:,} Gaussians after {100 * x['decodable_fraction']:.1f} %"
                for x in r.layers))
        if r.written.report_files:
            prog.log(f"  report: {', '.join(r.written.report_files)}")
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
