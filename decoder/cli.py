"""gsz-decode and gsz-info (numpy-only command-line tools)."""
from __future__ import annotations

import argparse
import json
import sys
import time

from .cli_common import (EXIT_INTERRUPTED, STDOUT, QUIET, VERBOSE, HelpFormatter, add_overwrite,
                         add_verbosity, add_version_flag, check_output, fail, warn, write_output)
from .errors import GszError, GszUsageError

__all__ = ["decode_main", "info_main", "add_max_gaussians", "add_version_flag"]

_fail = fail


def add_max_gaussians(p: argparse.ArgumentParser) -> None:
    """The --max-gaussians option of gsz-decode, gsz-info and gsz-view."""
    from .layer import GAUSSIANS_PER_BYTE
    p.add_argument("--max-gaussians", type=int, default=None, metavar="N",
                   help="accept files of up to N Gaussians whatever their size (default: reject more "
                        f"than 2^28, or more than {GAUSSIANS_PER_BYTE} per byte of the file: a decompression bomb)")


def decode_main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="gsz-decode", description="Decode a .gsz file to a 3DGS PLY, an .spz or glTF.",
                                formatter_class=HelpFormatter,
                                epilog="Exit status: 0 ok, 1 error (bad input, cannot write), 2 bad options, "
                                       "130 interrupted.")
    add_version_flag(p)
    p.add_argument("input", help="input .gsz file, or a .glb carrying one (EXT_gaussian_splatting_compression_gsz)")
    p.add_argument("-o", "--output", required=True,
                   help="output: OUT.ply (graphdeco PLY), OUT.spz (SPZ, see --spz-version; RDF frame, as "
                        "splat-transform writes it), or OUT.glb / OUT.gltf (plain KHR_gaussian_splatting "
                        "glTF, float32; needs the gltf extra); written atomically; - writes the PLY to stdout")
    p.add_argument("--spz-version", type=int, choices=(3, 4), default=3,
                   help="SPZ version of an .spz output: 3 (gzip, read by every SPZ reader) or 4 (zstd "
                        "streams, smaller; splat-transform 3.x and the current spz library read it)")
    add_overwrite(p)
    p.add_argument("--layers", type=int, default=None, metavar="K",
                   help="decode only the first K importance layers (default: all)")
    p.add_argument("--partial", action="store_true",
                   help="decode the complete layers of a truncated file (with a warning) instead of failing")
    p.add_argument("--tiles", default=None, metavar="I,J,...",
                   help="decode only these spatial tiles (indices as gsz-info lists them)")
    p.add_argument("--region", type=float, nargs=6, default=None,
                   metavar=("XMIN", "YMIN", "ZMIN", "XMAX", "YMAX", "ZMAX"),
                   help="decode only the Gaussians inside this box (and only the tiles that meet it)")
    p.add_argument("--json", action="store_true", help="print a JSON summary on stdout")
    add_max_gaussians(p)
    add_verbosity(p, quiet_help="errors only (no summary line, no warnings)",
                  verbose_help="also the input's size and the decoder's speed")
    a = p.parse_args(argv)
    from .io_util import sigterm_as_interrupt
    try:
        with sigterm_as_interrupt():
            out = _decode_to_file(a)
    except KeyboardInterrupt:          # Ctrl-C or SIGTERM: atomic_write left no partial file
        print("gsz-decode: interrupted; no output written", file=sys.stderr)
        return EXIT_INTERRUPTED
    if isinstance(out, int):
        return out
    cloud, dt, truncated = out
    from .native import active_path
    summary = {"input": a.input, "output": a.output, "num_gaussians": len(cloud), "truncated": truncated,
               "sh_degree": cloud.sh_degree, "decode_seconds": round(dt, 4),
               "gaussians_per_second": round(len(cloud) / dt) if dt > 0 else None,
               "decoder": active_path()}
    if a.json:
        print(json.dumps(summary))
    elif a.verbosity > QUIET:
        print(f"gsz-decode: decoded {len(cloud):,} Gaussians (SH degree {cloud.sh_degree}) in {dt:.3f} s "
              f"({active_path()} decoder) -> {'stdout' if a.output == STDOUT else a.output}", file=sys.stderr)
        if a.verbosity >= VERBOSE:
            import os
            rate = summary["gaussians_per_second"]
            print(f"gsz-decode: input {a.input}: {os.path.getsize(a.input):,} bytes"
                  + (f"; {rate:,} Gaussians/s" if rate else ""), file=sys.stderr)
    return 0


def _decode_to_file(a):
    """Decode ``a.input`` and write ``a.output``: (cloud, seconds, truncation message or None),
    or the exit code of a one-line error already printed."""
    tiles = region = None
    if a.tiles is not None:
        try:
            tiles = [int(v) for v in a.tiles.split(",") if v.strip()]
        except ValueError:
            return _fail("gsz-decode", GszUsageError(f"--tiles must be comma-separated tile indices, got {a.tiles!r}"))
    if a.region is not None:
        region = (a.region[:3], a.region[3:])
    import warnings

    from .decode import decode
    from .errors import GszTruncatedError, GszTruncatedWarning
    from .ply import cloud_to_ply_bytes
    if a.layers is not None and a.layers < 1:
        return _fail("gsz-decode", GszUsageError(f"--layers must be >= 1, got {a.layers}"))
    if a.max_gaussians is not None and a.max_gaussians < 1:
        return _fail("gsz-decode", GszUsageError(f"--max-gaussians must be a positive integer, got {a.max_gaussians}"))
    if a.output == STDOUT and a.json:
        return _fail("gsz-decode", GszUsageError("-o - writes the PLY to stdout: --json cannot share it"))
    truncated = None
    gltf_out = a.output.lower().endswith((".glb", ".gltf"))
    try:
        # before the decode, not after it
        check_output(a.output, inputs=[a.input], overwrite=a.overwrite, stdout=True)
        if gltf_out:
            from .gltf import pygltflib
            pygltflib()                                     # the missing extra, said before the decode
        t0 = time.perf_counter()
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", GszTruncatedWarning)
            cloud = decode(a.input, layers=a.layers, partial=a.partial, tiles=tiles, region=region,
                           max_gaussians=a.max_gaussians)
        dt = time.perf_counter() - t0
        for w in caught:
            if issubclass(w.category, GszTruncatedWarning):
                truncated = str(w.message)
                warn("gsz-decode", truncated, a.verbosity)
        if gltf_out:
            from .decode import payload_frame
            from .gltf import write_gltf
            write_gltf(cloud, a.output, frame=payload_frame(a.input))
        elif a.output.lower().endswith(".spz"):
            from .container import FRAME_RUB
            from .decode import payload_frame
            from .frames import to_rdf
            from .spz import write_spz
            if payload_frame(a.input) == FRAME_RUB:      # gsz writes SPZ in RDF, as splat-transform does
                cloud = to_rdf(cloud, "RUB")
            write_spz(cloud, a.output, version=a.spz_version)
        else:
            write_output(a.output, cloud_to_ply_bytes(cloud))
    except GszError as e:
        if isinstance(e, GszTruncatedError) and not a.partial:
            return _fail("gsz-decode", f"{e} (--partial decodes the complete layers of a truncated file)", 1)
        return _fail("gsz-decode", e)
    except OSError as e:
        return _fail("gsz-decode", GszError(f"cannot write: {e.strerror or e}", a.output))
    return cloud, dt, truncated


def info_main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="gsz-info", description="Show the header and chunk table of a .gsz file.",
                                formatter_class=HelpFormatter,
                                epilog="Exit status: 0 ok, 1 error (bad input), 2 bad options, 130 interrupted.")
    add_version_flag(p)
    p.add_argument("input", help="input .gsz file, or a .glb carrying one")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    add_max_gaussians(p)
    add_verbosity(p, quiet_help="no warnings on stderr", verbose_help="(the table is always complete)")
    a = p.parse_args(argv)
    try:
        if a.max_gaussians is not None and a.max_gaussians < 1:
            raise GszUsageError(f"--max-gaussians must be a positive integer, got {a.max_gaussians}")
        from .decode import inspect
        info = inspect(a.input, max_gaussians=a.max_gaussians)
    except GszError as e:
        return _fail("gsz-info", e)
    except KeyboardInterrupt:
        print("gsz-info: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    try:
        return _print_info(a, info)
    except BrokenPipeError:
        # the reader (head, less) stopped reading: nothing is wrong with the file; stdout goes
        # to /dev/null so that the interpreter's final flush does not fail again
        import os
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0


def _print_info(a, info: dict) -> int:
    from .native import active_path, unavailable_reason
    decoder = {"path": active_path(), "native_unavailable": unavailable_reason() or None}
    if a.json:
        print(json.dumps({**info, "decoder": decoder}, indent=1))
        return 0
    frames = {0: "unspecified", 1: "RDF (x right, y down, z forward)", 2: "RUB (x right, y up, z back)"}
    print(f"file        {info['file']}")
    print(f"size        {info['bytes']:,} bytes ({info['bytes'] / max(1, info['num_gaussians']):.2f} B/Gaussian)")
    if info["container"] == "glb":
        print(f"container   .glb (EXT_gaussian_splatting_compression_gsz): the .gsz is bytes "
              f"{info['payload']['offset']:,}..{info['payload']['offset'] + info['payload']['bytes']:,}, "
              f"offsets below are the .glb's")
    print(f"version     {info['version']}")
    print(f"gaussians   {info['num_gaussians']:,}")
    print(f"SH degree   {info['sh_degree']}")
    print(f"frame       {frames.get(info['frame'], info['frame'])}")
    print("bbox        " + " .. ".join("(" + ", ".join(f"{v:.4g}" for v in b) + ")"
                                     for b in (info["bbox_min"], info["bbox_max"])))
    tiled = len(info["tiles"]) > 1
    print(f"{'chunk':6} {'offset':>10} {'bytes':>12} {'share':>7}  layer" + ("  tile" if tiled else "")
          + "  description")
    for c in info["chunks"]:
        print(f"{c['type']:6} {c['offset']:>10,} {c['bytes']:>12,} {100 * c['bytes'] / info['bytes']:6.2f}%"
              f"  {c['layer']:>5}" + (f"  {c['tile']:>4}" if tiled else "")
              + f"  {c['name']}{'' if c['required'] else ' (optional)'}")
    if tiled:
        print(f"{'tile':6} {'gaussians':>12} {'bytes':>12}  {'layers':>6}  bounding box")
        for r in info["tiles"]:
            box = " .. ".join("(" + ", ".join(f"{v:.4g}" for v in b) + ")" for b in (r["bbox_min"], r["bbox_max"]))
            print(f"{r['tile']:<6} {r['gaussians']:>12,} {r['bytes']:>12,}  {len(r['parts']):>6}  {box}")
    if len(info["layers"]) > 1:
        print(f"{'layer':6} {'gaussians':>12} {'cumulative':>12} {'offset':>10} {'bytes':>12} {'decodable at':>14}")
        for r in info["layers"]:
            print(f"{r['layer']:<6} {r['gaussians']:>12,} {r['cumulative_gaussians']:>12,} {r['offset']:>10,} "
                  f"{r['bytes']:>12,} {r['decodable_at']:>10,} B {100 * r['decodable_at'] / info['bytes']:5.1f}%")
    print(f"decoder     {decoder['path']}" + (f" ({decoder['native_unavailable']})"
                                                  if decoder["native_unavailable"] else ""))
    opts = info.get("meta", {}).get("options")
    if opts:
        print("encoder     " + " ".join(f"{k}={v}" for k, v in sorted(opts.items())))
    lim = info["limit"]
    print(f"limit       {lim['max_gaussians']:,} Gaussians"
          + (f" (default: {lim['per_byte']} per byte, at most 2^28)" if lim["per_byte"] else " (--max-gaussians)"))
    if lim["exceeded"]:
        warn("gsz-info", f"{info['file']}: gsz-decode would reject this file: {lim['exceeded']}", a.verbosity)
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(decode_main())
