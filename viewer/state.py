"""The viewer's settings and the view state its panel reads, apart from any GL code.

:class:`ViewState` is the GL-free half of :class:`gsz.viewer.app.ViewerApp` (its base class):
the scenes on screen, the compare mode, frame times, the PSNR/SSIM cache and the GL-free
commands the panel (:mod:`gsz.viewer.ui`) issues (streaming and screenshots are the app's).  The
panel imports this module, never the app, so the app can import the panel.
"""
from __future__ import annotations

import threading
import time

import numpy as np
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from ..decoder.cloud import GaussianCloud
from ..decoder.errors import GszError

if TYPE_CHECKING:      # annotations only: importing them would load the GL stack
    from .gl_renderer import SplatRenderer
    from .sorter import DepthSorter

MODES = ("single", "split", "side")
#: full scale of the heat map (same as gsz-eval's error PNG)
HEAT_FULL_SCALE = 0.1
#: the panel's strip at the window's right edge (window coordinates): a share of the window's
#: width within these bounds; the scenes are drawn left of it, so it covers neither half
PANEL_MIN, PANEL_MAX, PANEL_SHARE = 200, 320, 0.3


def panel_width(display_width: float) -> float:
    """Width of the panel strip in a window ``display_width`` wide (window coordinates)."""
    return float(min(PANEL_MAX, max(PANEL_MIN, PANEL_SHARE * float(display_width))))


def view_key(camera) -> tuple:
    """Identity of what a camera sees: pose, intrinsics and size."""
    return (np.concatenate([camera.R.reshape(-1), camera.t,
                            [camera.fx, camera.fy, camera.cx, camera.cy]]).astype(np.float64).tobytes(),
            int(camera.width), int(camera.height))


def format_bytes(n) -> str:
    if n is None:
        return "?"
    try:
        from ..decoder.sizes import format_size
        return format_size(int(n))
    except Exception:
        return f"{n / 1e6:.2f} MB" if n >= 1e5 else f"{n / 1e3:.1f} kB"


@dataclass
class Scene:
    """One cloud on screen.

    name        label shown in the UI ("original", "decoded", "2MB" ...)
    cloud       GaussianCloud
    file_bytes  size of the file it came from (None if unknown)
    components  per-component bytes of a .gsz (chunk name -> bytes, from ``inspect()``)
    max_gaussians  the decoder limit it was loaded with (a stream replay uses it too)
    compressed  the file is a .gsz or a .glb carrying one (told by content): it has layers and
                can be replayed through the streaming decoder
    """

    name: str
    cloud: GaussianCloud
    path: str | None = None
    file_bytes: int | None = None
    components: dict = field(default_factory=dict)
    renderer: SplatRenderer | None = None
    sorter: DepthSorter | None = None
    whole: GaussianCloud | None = None      # for a layer prefix / a stream: the whole file's cloud
    note: str = ""                          # shown after the label (e.g. streaming progress)
    max_gaussians: int | None = None
    compressed: bool = False

    @property
    def frame_cloud(self) -> GaussianCloud:
        """The cloud that defines default cameras and the up axis (the whole scene, also when
        only some layers are shown, so views stay comparable)."""
        return self.whole if self.whole is not None else self.cloud

    @property
    def label(self) -> str:
        return f"{self.name}  {format_bytes(self.file_bytes)}" + (f"  {self.note}" if self.note else "")


@dataclass
class Settings:
    mode: str = "single"               # one of MODES
    show: int = 0                      # single mode: 0 = A, 1 = B (flip toggles)
    heatmap: bool = False              # error heat map instead of B
    split: float = 0.5                 # split position, fraction of the width
    background: tuple = (0.0, 0.0, 0.0)
    sh_degree: int = 3                 # capped per scene at its own degree
    scale_modifier: float = 1.0
    render_scale: float = 1.0          # render at this fraction of the window size
    fly_speed: float = 1.0             # scene radii per second
    auto_metrics: bool = True          # PSNR/SSIM of the resting view, computed automatically
    labels: bool = True
    show_panel: bool = True            # Tab hides / shows the control panel


class ViewState:
    """What the panel reads and the commands it issues; :class:`ViewerApp` adds the GL side.

    settings    Settings (the panel writes into it)
    scenes      [A] or [A, B]; variants: the B candidates, b_index the one shown (-1: none)
    camera_list [(kind, index, camera)] snap targets, camera_index the current one; control
                the CameraController
    frame_times perf_counter times of the last rendered frames; stats, status: for the panel
    width       composed frame width (window pixels)
    _drawn, _drawn_key  the renders of the last frame and what they showed (set by render)
    """

    def __init__(self, settings: Settings | None = None):
        self.settings = settings or Settings()
        self._metrics = None                # (key, {"psnr", "ssim", ...}) of the last finished
        self._metrics_pending = None        # key the worker computes now
        self._metrics_want = None           # the newest request not started yet
        self._metrics_lock = threading.Lock()
        self._metrics_cond = threading.Condition(self._metrics_lock)
        self._metrics_thread = None
        self._drawn = {}

    @staticmethod
    def pivot_distance(cloud, cam) -> float:
        """Distance from ``cam`` to the scene centre (the orbit pivot)."""
        from ..evaluation.cameras import robust_bounds
        if len(cloud) == 0:
            return 1.0
        lo, hi, _ = robust_bounds(cloud.positions)
        d = float(np.linalg.norm((lo + hi) / 2 - cam.center))
        return d if d > 0 else 1.0

    @property
    def a(self) -> Scene:
        return self.scenes[0]

    @property
    def b(self) -> Scene | None:
        return self.variants[self.b_index] if 0 <= self.b_index < len(self.variants) else None

    @property
    def comparing(self) -> bool:
        return self.b is not None

    def stream_candidate(self) -> Scene | None:
        """The scene a stream replay applies to: the decoded .gsz (B, else a lone .gsz A)."""
        for s in ([self.b] if self.b is not None else []) + [self.a]:
            if bool(s.path) and s.compressed and (s.whole is None or s is self.stream_scene):   # not a layer prefix
                return s
        return None

    def set_mode(self, mode: str):
        if mode not in MODES:
            raise GszError(f"mode must be one of {', '.join(MODES)}, got {mode!r}")
        self.settings.mode = mode

    def set_b(self, index: int):
        if 0 <= index < len(self.variants):
            self.b_index = index

    def snap(self, index: int):
        """Snap the view to camera ``index`` of :attr:`camera_list` (test views first)."""
        n = len(self.camera_list)
        self.camera_index = index % n
        cam = self.camera_list[self.camera_index][2]
        self.control.snap_to(cam, self.pivot_distance(self.a.cloud, cam))

    def split_px(self) -> float:
        return round(self.settings.split * self.width)

    @property
    def fps(self) -> float:
        """Rendered frames per second over the last 2 s (0 when idle: unchanged views are
        not re-rendered)."""
        now = time.perf_counter()
        f = [t for t in self.frame_times if now - t < 2.0]
        return (len(f) - 1) / (f[-1] - f[0]) if len(f) > 1 and f[-1] > f[0] else 0.0

    # -- metrics -----------------------------------------------------------------------------------
    def metrics_camera(self):
        """The camera "this view" is scored at: the current pose at the snapped camera's own
        size and intrinsics (so a test view scores exactly as gsz-eval scores it), or, away
        from any snapped camera, at gsz-eval's default width with the shown aspect."""
        from ..evaluation.cameras import DEFAULT_VIEW_WIDTH
        snapped = getattr(self.control, "_snapped", None)
        if snapped is not None:
            return self.control.camera(snapped.width, snapped.height)
        w, h = self._render_size()
        return self.control.camera(DEFAULT_VIEW_WIDTH, max(1, round(DEFAULT_VIEW_WIDTH * h / max(w, 1))))

    def _metrics_key(self, cam=None):
        s = self.settings
        cam = cam or self.metrics_camera()
        return (view_key(cam), id(self.b), id(self.a.cloud), id(self.b.cloud) if self.b else None,
                tuple(float(v) for v in s.background), int(s.sh_degree), float(s.scale_modifier))

    def request_metrics(self, wait: bool = False):
        """PSNR/SSIM of B against A for the current view with gsz-eval's protocol: both clouds
        rendered by the CPU reference renderer (:mod:`gsz.evaluation.render`) at
        :meth:`metrics_camera` on the background shown, compared by
        :func:`gsz.evaluation.evaluate.evaluate` (8-bit rounding, 100 dB cap, reference SSIM).
        Runs on one worker thread (the newest request wins); ``wait`` blocks until this view's
        numbers are in :meth:`current_metrics` (or the worker failed: see :attr:`status`)."""
        if not self.comparing:
            return
        cam = self.metrics_camera()
        key = self._metrics_key(cam)
        s = self.settings
        job = (key, self.a.cloud, self.b.cloud, cam, tuple(float(v) for v in s.background),
               int(s.sh_degree), float(s.scale_modifier))
        with self._metrics_lock:
            done = self._metrics is not None and self._metrics[0] == key
            if not done and self._metrics_pending != key:
                self._metrics_want = job
                if self._metrics_thread is None:          # the worker clears it as it ends
                    self._metrics_thread = threading.Thread(target=self._metrics_worker,
                                                            name="gsz-view-metrics", daemon=True)
                    self._metrics_thread.start()
            if wait:
                self._metrics_cond.wait_for(lambda: (self._metrics is not None and self._metrics[0] == key)
                                            or (self._metrics_want is None and self._metrics_pending is None))

    def _metrics_worker(self) -> None:
        from ..evaluation.evaluate import evaluate
        from ..evaluation.render import render
        while True:
            with self._metrics_lock:
                job, self._metrics_want = self._metrics_want, None
                if job is None:
                    self._metrics_thread = None
                    self._metrics_cond.notify_all()
                    return
                self._metrics_pending = job[0]
            key, a, b, cam, bg, deg, scale = job
            result = None
            try:
                def render_fn(cloud, camera, background):
                    return render(cloud, camera, background=background,
                                  sh_degree=min(deg, cloud.sh_degree), scale_modifier=scale)
                ev = evaluate(a, b, [cam], background=bg, render_fn=render_fn)
                result = {"psnr": ev["psnr"], "ssim": ev["ssim"], "width": cam.width, "height": cam.height}
            except Exception as e:   # e.g. torch missing: say so in the panel, never hang
                self.status = f"PSNR/SSIM failed: {type(e).__name__}: {e}"
            with self._metrics_lock:
                if result is not None:
                    self._metrics = (key, result)
                self._metrics_pending = None
                self._metrics_cond.notify_all()

    def current_metrics(self):
        """{"psnr", "ssim", "width", "height"} for the current view, or None (not computed yet,
        or the view changed since)."""
        if not self.comparing:
            return None
        with self._metrics_lock:
            m = self._metrics
        if m is not None and m[0] == self._metrics_key():
            return m[1]
        return None

    def labels(self):
        """[(x, y, text)] overlay labels for the current layout (window pixels, top left)."""
        if not self.comparing:
            return [(8, 8, self.a.label)]
        s = self.settings
        m = self.current_metrics()
        mtxt = f"\nPSNR {m['psnr']:.2f} dB  SSIM {m['ssim']:.4f}" if m else ""
        b_txt = self.b.label + mtxt
        if s.heatmap:
            b_txt = f"|{self.a.name} - {self.b.name}|  white = {HEAT_FULL_SCALE:g}" + mtxt
        if s.mode == "single":
            return [(8, 8, self.a.label if (s.show == 0 and not s.heatmap) else b_txt)]
        x_b = (self.width // 2 if s.mode == "side" else self.split_px()) + 8
        return [(8, 8, self.a.label), (x_b, 8, b_txt)]
