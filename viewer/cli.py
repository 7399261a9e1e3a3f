"""``gsz-view``: look at a .gsz / .ply / .glb / .gltf, or compare a decoded scene with its original.

    gsz-view FILE                                   # one scene (.gsz, .ply, .glb, .gltf, .spz, .sog, ...)
    gsz-view DECODED.gsz --compare ORIGINAL.ply     # A/B compare: split, side by side, flip
    gsz-view ORIGINAL.ply --budgets 2MB,5MB,10MB    # encode at each budget in the background,
                                                    # then compare the one picked in the panel
    gsz-view FILE [--compare ORIG] --screenshot OUT.png [--camera I] [--width W --height H]
                                                    # headless: render TEST camera I, exit

Cameras: ``--cameras`` (cameras.json or a COLMAP model) or, by default, the ORIGINAL's default
camera set -- the same views gsz-eval scores (``load_cameras(None, cloud).test``).  The
screenshot path needs no display and no GPU (EGL; Mesa llvmpipe renders on the CPU); the window
needs a display: without one (Linux: neither DISPLAY nor WAYLAND_DISPLAY set) gsz-view says so
and points to ``--screenshot`` instead of running an invisible window.
Exit status: 0 ok, 1 error (bad input, no display or usable OpenGL, an existing --screenshot
file without -w), 2 bad options, 130 interrupted.
"""
from __future__ import annotations

import argparse
import os
import sys

import numpy as np

from ..decoder.errors import GszError, GszUsageError

__all__ = ["main", "build_parser"]


def build_parser() -> argparse.ArgumentParser:
    from ..decoder.cli_common import HelpFormatter, add_overwrite, add_verbosity, add_version_flag
    p = argparse.ArgumentParser(
        prog="gsz-view", formatter_class=HelpFormatter,
        description="Interactive viewer for .gsz/.ply Gaussian-splat scenes with A/B compare "
                    "against the original (split, side by side, flip, error heat map).",
        epilog="Window keys: drag orbit, right-drag look, middle/shift-drag pan, wheel zoom, "
               "WASD/QE fly (shift x4), 1/2/3 single/split/side, F or space flip, H heat map, "
               "[ ] previous/next camera, R reset, P screenshot, Tab panel, Esc quit.  The window "
               "needs a display; --screenshot does not.  Exit status: 0 ok, 1 error (bad input, "
               "no display or OpenGL, output exists), 2 bad options, 130 interrupted.")
    add_version_flag(p)
    p.add_argument("file", help="scene to show, told by content (.gsz, .ply, .glb, .gltf, .spz, .sog or its "
                                 "meta.json, .ksplat, .splat); with --budgets, the original")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--compare", metavar="ORIGINAL", help="original scene (any format FILE can be) to compare FILE with")
    g.add_argument("--budgets", metavar="LIST",
                   help="comma-separated sizes (e.g. 2MB,5MB,10MB): encode FILE at each in the "
                        "background and compare")
    p.add_argument("--cameras", metavar="PATH", help="cameras.json or COLMAP model (default: the "
                   "original's default camera set, as gsz-eval)")
    p.add_argument("--up", default="auto", help="scene up axis for default cameras and orbit "
                   "(auto, -y, +y, +z, ...; default auto)")
    p.add_argument("--layers", type=int, default=None, metavar="K",
                   help="show only the first K importance layers of a layered .gsz FILE (what a "
                        "streaming client shows once those layers have arrived); with --compare, "
                        "every layer prefix is also offered as a B choice")
    p.add_argument("--simulate-network", metavar="RATE", default=None,
                   help="window: replay the .gsz (FILE, or the decoded side of --compare) as if it "
                        "arrived at RATE (e.g. 2MB/s): the scene builds up layer by layer; the panel "
                        "can replay at other rates")
    p.add_argument("--screenshot", metavar="OUT.png", help="render one frame headless (no display "
                   "needed) and exit")
    add_overwrite(p)
    p.add_argument("--stats", action="store_true",
                   help="print the frame time (and sort / GPU preprocess / draw times) on stderr: "
                        "once for --screenshot, about once a second in the window")
    add_verbosity(p, quiet_help="errors only", verbose_help="(no more detail than the default)")
    p.add_argument("--camera", type=int, default=0, metavar="I", help="TEST camera index for "
                   "--screenshot and the initial view (default 0)")
    p.add_argument("--width", type=int, default=None, help="image width (screenshot default 800, "
                   "window default 1280)")
    p.add_argument("--height", type=int, default=None, help="image height (default: the camera's "
                   "aspect, 3:4 of the width for default cameras)")
    p.add_argument("--mode", choices=("single", "split", "side"), default=None,
                   help="compare layout (default split when comparing)")
    p.add_argument("--split", type=float, default=0.5, help="split position, 0..1 of the width")
    p.add_argument("--flip", action="store_true", help="single mode: show the decoded scene (B)")
    p.add_argument("--heatmap", action="store_true", help="show the error heat map instead of B")
    p.add_argument("--background", default="0,0,0", metavar="R,G,B",
                   help="background colour, 3 numbers in 0..1 (default 0,0,0)")
    p.add_argument("--sh-degree", type=int, default=None, help="SH degree to render (default: all)")
    p.add_argument("--render-scale", type=float, default=None,
                   help="window: render at this fraction of the window size (default 1; 0.5 on "
                        "software GL)")
    lab = p.add_mutually_exclusive_group()
    lab.add_argument("--labels", dest="labels", action="store_true", default=None,
                     help="screenshot: draw the size / PSNR labels (default when comparing)")
    lab.add_argument("--no-labels", dest="labels", action="store_false")
    from ..decoder.cli import add_max_gaussians
    add_max_gaussians(p)
    return p


class _UsageError(GszUsageError):
    pass


def _up_vector(up_arg, cloud, cameras_path, cams):
    from ..evaluation.cameras import _up_vector, detect_up
    if up_arg != "auto":
        return _up_vector(up_arg)
    if cameras_path is not None:
        # Dataset cameras: their mean "image up" (-y row of R) is the scene's up.
        allc = list(cams.train) + list(cams.test)
        v = -np.mean([c.R[1] for c in allc], axis=0)
        if np.linalg.norm(v) > 1e-6:
            return v / np.linalg.norm(v)
    return _up_vector(detect_up(cloud.positions))


def _load_cameras(args, ref_cloud, width):
    from ..evaluation.cameras import load_cameras
    try:
        cams = load_cameras(args.cameras, ref_cloud, width=width, up=args.up)
    except ValueError as e:
        raise _UsageError(f"--up: {e}") from None
    if not cams.test:
        raise _UsageError("the camera set has no test cameras")
    return cams


def _with_height(cam, height):
    from ..evaluation.cameras import Camera
    if height is None or height == cam.height:
        return cam
    # Keep the focal length and the optical centre's place: the frame grows or shrinks evenly.
    return Camera(cam.R, cam.t, cam.fx, cam.fy, cam.cx, cam.cy + (height - cam.height) / 2.0,
                  cam.width, height, cam.name)


def _settings(args, comparing: bool, a, b):
    from .app import Settings
    from ..decoder.cli_common import parse_background
    s = Settings(background=parse_background(args.background))
    if comparing:
        s.mode = args.mode or ("single" if args.flip else "split")
    else:
        s.mode = "single"
    s.show = 1 if args.flip else 0
    s.heatmap = bool(args.heatmap)
    if not 0.0 <= args.split <= 1.0:
        raise _UsageError(f"--split must be in 0..1, got {args.split}")
    s.split = float(args.split)
    max_deg = max(a.cloud.sh_degree, b.cloud.sh_degree if b is not None else 0)
    if args.sh_degree is not None:
        if not 0 <= args.sh_degree <= 3:
            raise _UsageError(f"--sh-degree must be 0..3, got {args.sh_degree}")
        s.sh_degree = args.sh_degree
    else:
        s.sh_degree = max_deg
    if args.render_scale is not None:
        if not 0.1 <= args.render_scale <= 1.0:
            raise _UsageError(f"--render-scale must be in 0.1..1, got {args.render_scale}")
        s.render_scale = args.render_scale
    return s


def _load_scenes(args):
    """(A = original, B = decoded or None, budget jobs or None)."""
    from .app import scene_from_file
    if args.layers is not None and (args.layers < 1 or args.budgets):
        raise _UsageError("--layers must be >= 1 and applies to a .gsz FILE (not with --budgets)")
    if args.compare:
        b = _first_layers(scene_from_file(args.file, "decoded", max_gaussians=args.max_gaussians), args.layers)
        a = scene_from_file(args.compare, "original", max_gaussians=args.max_gaussians)
        return a, b, None
    a = _first_layers(scene_from_file(args.file, "original" if args.budgets else None,
                                      max_gaussians=args.max_gaussians), args.layers)
    jobs = None
    if args.budgets:
        from .budgets import BudgetJobs, parse_budgets
        jobs = BudgetJobs(a.cloud, parse_budgets(args.budgets), start=False)
    return a, None, jobs


def _first_layers(scene, k):
    """The scene cut to its first ``k`` layers (None: unchanged)."""
    if k is None:
        return scene
    from .app import layer_prefix_scenes
    prefixes = layer_prefix_scenes(scene)
    if not scene.path or not scene.compressed:
        raise _UsageError(f"--layers {k}: {scene.path} is not a .gsz file (or a .glb carrying one)")
    if k > len(prefixes) + 1:
        raise _UsageError(f"--layers {k}: {scene.path} has {len(prefixes) + 1} layer(s)")
    return prefixes[k - 1] if k <= len(prefixes) else scene


def _screenshot(args, a, b, jobs) -> str:
    from .app import ViewerApp
    if args.simulate_network is not None:
        raise _UsageError("--simulate-network is for the window; --layers K renders a layer prefix headless")
    from ..evaluation.cameras import DEFAULT_VIEW_WIDTH
    from .gl_renderer import create_headless_context
    width = DEFAULT_VIEW_WIDTH if args.width is None else args.width
    if width < 1 or (args.height is not None and args.height < 1) or width > 16384 \
            or (args.height or 0) > 16384:
        raise _UsageError("--width/--height must be 1..16384")
    cams = _load_cameras(args, a.frame_cloud, width)
    if not 0 <= args.camera < len(cams.test):
        raise _UsageError(f"--camera {args.camera}: the camera set has {len(cams.test)} test "
                          f"cameras (0..{len(cams.test) - 1})")
    cam = _with_height(cams.test[args.camera], args.height)
    if jobs is not None:
        jobs.start()
        jobs.wait(count=1)
        snap = jobs.snapshot()
        if not snap["results"]:
            label, msg = snap["errors"][0]
            raise GszError(f"--budgets {label}: encoding failed: {msg}")
    comparing = b is not None or jobs is not None
    settings = _settings(args, comparing, a, b)
    ctx = create_headless_context()
    app = ViewerApp(ctx, a, b, cameras=cams, up=_up_vector(args.up, a.frame_cloud, args.cameras, cams),
                    width=cam.width, height=cam.height, settings=settings, threaded_sort=False,
                    budget_jobs=jobs)
    try:
        app.step(0.0)   # picks up a finished budget encode
        app.control.snap_to(cam)
        app.render(wait_for_sort=True)
        if args.stats:
            from .window import stats_line
            print(f"gsz-view: {stats_line(app)}", file=sys.stderr, flush=True)
        labels = args.labels if args.labels is not None else app.comparing
        if labels and app.comparing:
            app.request_metrics(wait=True)
        if labels:
            _draw_labels_offscreen(app)
        from .app import write_png
        write_png(args.screenshot, app.read_output())
    finally:
        app.close()
        ctx.release()
    return args.screenshot


def _draw_labels_offscreen(app) -> None:
    """Draw the imgui labels into app.output without a window (EGL + FBO)."""
    try:
        from imgui_bundle import imgui
    except ImportError:
        return
    from .ui import draw_labels
    imgui.create_context()
    try:
        io = imgui.get_io()
        io.set_ini_filename("")
        io.display_size = imgui.ImVec2(float(app.width), float(app.height))
        imgui.backends.opengl3_init("#version 430")
        for _ in range(2):   # the first frame builds the font atlas
            imgui.backends.opengl3_new_frame()
            imgui.new_frame()
            draw_labels(app)
            imgui.render()
        app.output[1].use()
        app.ctx.viewport = (0, 0, app.width, app.height)
        imgui.backends.opengl3_render_draw_data(imgui.get_draw_data())
        imgui.backends.opengl3_shutdown()
    finally:
        imgui.destroy_context()


def _interactive(args, a, b, jobs) -> None:
    from .app import ViewerApp, layer_prefix_scenes
    from .streaming import parse_rate
    from .window import Window, run
    rate = None
    if args.simulate_network is not None:
        target = b if b is not None else a
        if not (target.path and target.compressed) or args.layers is not None:
            raise _UsageError("--simulate-network replays a .gsz FILE (not with --layers or --budgets)")
        rate = parse_rate(args.simulate_network)
    width = 1280 if args.width is None else args.width
    height = 720 if args.height is None else args.height
    cams = _load_cameras(args, a.frame_cloud, None)
    if not 0 <= args.camera < len(cams.test):
        raise _UsageError(f"--camera {args.camera}: the camera set has {len(cams.test)} test cameras")
    comparing = b is not None or jobs is not None
    settings = _settings(args, comparing, a, b)
    win = Window(width, height, f"gsz-view - {os.path.basename(args.file)}", headless=False)
    try:
        fw, fh = win.framebuffer_size()
        app = ViewerApp(win.ctx, a, b, cameras=cams,
                        up=_up_vector(args.up, a.frame_cloud, args.cameras, cams),
                        width=fw, height=fh, settings=settings, budget_jobs=jobs,
                        camera_index=args.camera,
                        more_b=layer_prefix_scenes(b) if b is not None and args.layers is None else (),
                        stream_rate=rate)
        if args.render_scale is None and app.is_llvmpipe:
            app.settings.render_scale = 0.5
        if jobs is not None:
            jobs.start()
        try:
            run(win, app, stats=(lambda line: print(f"gsz-view: {line}", file=sys.stderr, flush=True))
                if args.stats else None)
        finally:
            app.close()
    finally:
        win.close()


def no_display_reason() -> str | None:
    """Why the window cannot open here, when the environment already says so: on Linux (and
    the BSDs) a window needs an X11 or Wayland display; elsewhere glfw decides."""
    if not sys.platform.startswith(("linux", "freebsd", "openbsd", "netbsd")):
        return None
    if os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"):
        return None
    return ("no display (neither DISPLAY nor WAYLAND_DISPLAY is set), so the viewer window cannot "
            "open; render a view without one: gsz-view FILE [--compare ORIG] --screenshot OUT.png "
            "[--camera I]")


def _check_screenshot_path(args) -> None:
    from ..decoder.cli_common import check_output
    check_output(args.screenshot, inputs=[args.file, args.compare, args.cameras], overwrite=args.overwrite)


def main(argv=None) -> int:
    from ..decoder.cli_common import EXIT_INTERRUPTED, fail, missing_extra
    args = build_parser().parse_args(argv)
    try:
        if args.screenshot:
            _check_screenshot_path(args)       # before loading: an existing file stays, fast
        else:
            reason = no_display_reason()
            if reason:
                raise GszError(reason)          # before loading anything: say it at once
        a, b, jobs = _load_scenes(args)
        if args.screenshot:
            out = _screenshot(args, a, b, jobs)
            if args.verbosity > 0:
                print(f"gsz-view: wrote {out}", file=sys.stderr)
        else:
            _interactive(args, a, b, jobs)
        return 0
    except ImportError as e:                   # a core-only install: name the extra
        err = missing_extra(e, "gsz-view")
        if err is None:
            raise
        return fail("gsz-view", err)
    except GszError as e:                      # GLUnavailable is one: exit 1
        return fail("gsz-view", e)
    except OSError as e:
        return fail("gsz-view", f"{e.strerror or e}: {e.filename or ''}".rstrip(": "), 1)
    except KeyboardInterrupt:
        print("gsz-view: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED


if __name__ == "__main__":
    sys.exit(main())
