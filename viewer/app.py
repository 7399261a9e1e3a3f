"""The viewer application: scenes, view state, input handling and frame composition.

:class:`ViewerApp` owns no window.  Whoever drives it (``gsz.viewer.window`` with glfw +
imgui, the headless ``--screenshot`` path, or a test) calls, per frame::

    app.handle_event(ev)      # for each input event (MouseDown / MouseMove / Key... below)
    app.step(dt)              # fly movement, background jobs, sort requests, metrics
    app.render()              # scene(s) -> float targets -> composite into app.output
    app.draw_ui()             # optional: the imgui panel and labels (needs an imgui frame)
    app.present(fbo)          # copy app.output to the window (or read it: app.read_output())

Coordinates of events are window pixels with the origin at the top left (glfw / imgui).
Scenes: A = the original (left half), B = the decoded file (right half).  A lone file is A.
"""
from __future__ import annotations

import dataclasses
import os
import time
from dataclasses import dataclass

import numpy as np

from ..decoder.cloud import GaussianCloud
from ..decoder.errors import GszError

from .camera_control import CameraController
from .gl_renderer import FloatTarget, SplatRenderer, load_shader
from .sorter import DepthSorter, camera_key
# MODES, format_bytes, Scene and Settings are re-exported: users import them from here
from .state import HEAT_FULL_SCALE, MODES, Scene, Settings, ViewState, format_bytes

__all__ = ["Scene", "scene_from_file", "scene_from_bytes", "ViewerApp", "Settings",
           "MouseDown", "MouseUp", "MouseMove", "Scroll", "KeyDown", "KeyUp",
           "MODES", "format_bytes"]

#: grab distance (pixels) of the split line
SPLIT_GRAB_PX = 8


# ------------------------------------------------------------------------------------------------
# events
# ------------------------------------------------------------------------------------------------

@dataclass
class MouseDown:
    x: float
    y: float
    button: int = 0          # 0 left, 1 right, 2 middle


@dataclass
class MouseUp:
    x: float
    y: float
    button: int = 0


@dataclass
class MouseMove:
    x: float
    y: float


@dataclass
class Scroll:
    dy: float                # + = towards the scene


@dataclass
class KeyDown:
    key: str                 # lower-case name: "w", "1", "space", "shift", "escape", "[" ...


@dataclass
class KeyUp:
    key: str


# ------------------------------------------------------------------------------------------------
# scenes
# ------------------------------------------------------------------------------------------------

def _components_of(src) -> dict:
    from ..decoder import inspect
    info = inspect(src)
    comps = {}
    for ch in info["chunks"]:
        comps[ch["name"]] = comps.get(ch["name"], 0) + int(ch["bytes"])
    comps["header+table"] = int(info["payload"]["bytes"]) - sum(int(c["bytes"]) for c in info["chunks"])
    if info["container"] == "glb":
        comps["glTF JSON + GLB framing"] = int(info["bytes"]) - int(info["payload"]["bytes"])
    return comps


def scene_from_file(path, name: str | None = None, *, max_gaussians: int | None = None) -> Scene:
    """Load any scene :func:`gsz.load` reads (told by content; GszError naming the file on failure;
    a .gsz within ``max_gaussians``, see :func:`gsz.decoder.decode`) with its size and, for a
    .gsz or a .glb carrying one, its per-component bytes."""
    from ..decoder.formats import is_compressed
    from ..evaluation.evaluate import load_cloud
    path = os.fspath(path)
    cloud = load_cloud(path, max_gaussians=max_gaussians)
    compressed = is_compressed(path)
    comps = _components_of(path) if compressed else {}
    return Scene(name or os.path.basename(path), cloud, path, os.path.getsize(path), comps,
                 max_gaussians=max_gaussians, compressed=compressed)


def scene_from_bytes(name: str, data: bytes, cloud: GaussianCloud | None = None) -> Scene:
    """A scene for an in-memory .gsz (a budget encode); decodes ``data`` when no cloud given."""
    if cloud is None:
        from ..decoder import decode
        cloud = decode(data)
    try:
        comps = _components_of(data)
    except Exception:
        comps = {}
    return Scene(name, cloud, None, len(data), comps)


def layer_prefix_scenes(scene: Scene) -> list:
    """For a scene decoded from a layered .gsz: one scene per proper prefix of its layers (what a
    streaming client shows after layer 0, after layers 0-1, ...), each labelled with the bytes
    received by then.  [] for single-layer files and PLYs."""
    if not scene.path or not scene.compressed:
        return []
    from ..decoder import inspect
    rows = inspect(scene.path)["layers"]
    out = []
    for r in rows[:-1]:
        n = r["cumulative_gaussians"]
        name = f"{scene.name} (layer 0)" if r["layer"] == 0 else f"{scene.name} (layers 0-{r['layer']})"
        out.append(Scene(name, scene.cloud.subset(np.arange(n)), scene.path, r["decodable_at"], {},
                         whole=scene.cloud, compressed=True))
    return out


def _gl_renderer_name(ctx) -> str:
    try:
        return str(ctx.info.get("GL_RENDERER", ""))
    except Exception:
        return ""


class ViewerApp(ViewState):
    """Everything but the window.  ``ctx`` = a moderngl context current on this thread.

    a, b        Scene (b None for a lone file); b may also arrive later (budget encodes)
    cameras     CameraSet of the scene (snap targets: test views, then train views)
    camera_index  initial view (and the one "reset" returns to), index into test views first
    up          world up vector of the scene, for orbit and fly
    threaded_sort  sort on a worker thread (True in the window; the screenshot path and
                tests may use False for fully deterministic frames)
    """

    def __init__(self, ctx, a: Scene, b: Scene | None = None, *, cameras, up,
                 width: int = 1280, height: int = 720, settings: Settings | None = None,
                 threaded_sort: bool = True, budget_jobs=None, screenshot_dir: str = ".",
                 camera_index: int = 0, more_b=(), stream_rate: float | None = None):
        import moderngl
        super().__init__(settings)
        self.ctx = ctx
        self._mgl = moderngl
        self.threaded_sort = threaded_sort
        self.width, self.height = int(width), int(height)
        self.cameras = cameras
        self.camera_list = [("test", i, c) for i, c in enumerate(cameras.test)] + \
                           [("train", i, c) for i, c in enumerate(cameras.train)]
        self.camera_index = int(camera_index) % len(self.camera_list)
        first = self.camera_list[self.camera_index][2]
        centre = self.pivot_distance(a.cloud, first)
        self.control = CameraController(first, centre, up)
        self.scene_radius = max(self._scene_radius(a.cloud), 1e-6)
        self.scenes = [a] + ([b] if b is not None else [])
        self.variants = []                  # extra B candidates (budget encodes), Scene list
        self.b_index = 0 if b is not None else -1
        if b is not None:
            self.variants.append(b)
            self.variants += list(more_b)      # e.g. the layer prefixes of a layered B
        for s in self.scenes + self.variants[1:]:
            self._upload(s)
        self.budget_jobs = budget_jobs
        self._seen_budget_results = 0
        self.held = set()
        self.drag = None                    # "split" | "orbit" | "pan" | "look" | None
        self.mouse = (0.0, 0.0)
        self.quit = False
        self.frame_times = []
        self.stats = {"frame_s": 0.0, "sort_s": 0.0, "preprocess_s": 0.0, "draw_s": 0.0,
                      "sort_current": True}
        self.status = ""
        self.screenshot_dir = screenshot_dir
        self.screenshots_taken = 0
        self.is_llvmpipe = "llvmpipe" in _gl_renderer_name(ctx).lower()
        self._targets = {}
        self.output = None
        self._out_size = None
        self._last_move = time.monotonic()
        self._last_version = self.control.version
        self._frame_key = None              # what the last drawn frame showed
        self.stream = None                  # StreamPlayback of a .gsz scene, or None
        self.stream_scene = None
        self.stream_status = None           # last snapshot (without the cloud), for the panel
        self._stream_version = 0
        self.stream_rate = 2e6 if stream_rate is None else float(stream_rate)
        if stream_rate is not None:
            self.start_stream(self.b if self.b is not None else self.a, stream_rate)
        self.comp = ctx.program(vertex_shader=load_shader("fullscreen.vert.glsl"),
                                fragment_shader=load_shader("composite.frag.glsl"))
        self.comp_vao = ctx.vertex_array(self.comp, [])
        self._dummy = FloatTarget(ctx, 1, 1)

    # -- helpers -------------------------------------------------------------------------------
    @staticmethod
    def _scene_radius(cloud) -> float:
        from ..evaluation.cameras import robust_bounds
        if len(cloud) == 0:
            return 1.0
        lo, hi, _ = robust_bounds(cloud.positions)
        return 0.5 * float(np.linalg.norm(hi - lo))

    def _upload(self, scene: Scene):
        if len(scene.cloud) == 0:           # nothing arrived yet (streaming): drawn as background
            return
        if scene.renderer is None:
            scene.renderer = SplatRenderer(self.ctx, scene.cloud)
        if scene.sorter is None:
            scene.sorter = DepthSorter(scene.cloud.positions, threaded=self.threaded_sort)

    # -- simulated streaming ---------------------------------------------------------------------
    def start_stream(self, scene: Scene | None = None, rate: float | None = None) -> None:
        """Replay ``scene``'s .gsz through the streaming decoder at ``rate`` bytes/s (None: as
        fast as it decodes): the scene empties, then grows layer by layer as bytes 'arrive'."""
        from .streaming import StreamPlayback
        scene = scene or self.stream_candidate()
        if scene is None or not scene.path or not scene.compressed:
            raise GszError("streaming replay needs a .gsz scene (or a .glb carrying one)")
        self.stop_stream()
        with open(scene.path, "rb") as f:
            data = f.read()
        if scene.whole is None:
            scene.whole = scene.cloud
        self._set_cloud(scene, scene.whole.subset(np.arange(0)))
        self.stream_scene = scene
        self.stream_rate = self.stream_rate if rate is None else float(rate)
        self._stream_version = 0
        self.stream = StreamPlayback(data, rate, max_gaussians=scene.max_gaussians)
        self._poll_stream()

    def stop_stream(self) -> None:
        if self.stream is not None:
            self.stream.stop()
            self.stream = None

    def _set_cloud(self, scene: Scene, cloud: GaussianCloud) -> None:
        if scene.sorter is not None:
            scene.sorter.close()
            scene.sorter = None
        if scene.renderer is not None:
            scene.renderer.release()
            scene.renderer = None
        scene.cloud = cloud
        self._upload(scene)
        self._frame_key = None
        self._metrics = None

    def _poll_stream(self) -> None:
        if self.stream is None:
            return
        snap = self.stream.snapshot()
        scene = self.stream_scene
        if snap["version"] != self._stream_version and snap["cloud"] is not None:
            self._stream_version = snap["version"]
            self._set_cloud(scene, snap["cloud"])
        layers = f"{snap['layers']}/{snap['layers_total'] or '?'}"
        if (snap.get("tiles_total") or 1) > 1:
            layers += f" ({snap['tiles']} tile parts of {snap['tiles_total']} tiles)"
        if snap["error"]:
            scene.note = f"stream error: {snap['error']}"
        elif snap["done"]:
            scene.note = ""
        else:
            scene.note = (f"streaming {format_bytes(snap['bytes'])} of {format_bytes(snap['total'])}, "
                          f"layer {layers}")
        self.stream_status = dict(snap, cloud=None)

    def close(self):
        self.stop_stream()
        for s in [self.scenes[0]] + self.variants:
            if s.sorter is not None:
                s.sorter.close()
            if s.renderer is not None:
                s.renderer.release()
                s.renderer = None
        for t in self._targets.values():
            t.release()
        self._targets.clear()
        if self.output is not None:
            self.output[0].release()
            self.output[1].release()
            self.output = None

    # -- state changes ---------------------------------------------------------------------------
    def resize(self, width: int, height: int):
        self.width, self.height = max(1, int(width)), max(1, int(height))

    # -- input -------------------------------------------------------------------------------------
    def handle_event(self, ev) -> None:
        s = self.settings
        if isinstance(ev, MouseDown):
            self.mouse = (ev.x, ev.y)
            if (ev.button == 0 and self.comparing and s.mode == "split"
                    and abs(ev.x - self.split_px()) <= SPLIT_GRAB_PX):
                self.drag = "split"
            elif ev.button == 2 or (ev.button == 0 and "shift" in self.held):
                self.drag = "pan"
            elif ev.button == 1:
                self.drag = "look"
            else:
                self.drag = "orbit"
        elif isinstance(ev, MouseUp):
            self.drag = None
        elif isinstance(ev, MouseMove):
            dx, dy = ev.x - self.mouse[0], ev.y - self.mouse[1]
            self.mouse = (ev.x, ev.y)
            if self.drag == "split":
                s.split = float(np.clip(ev.x / max(self.width, 1), 0.0, 1.0))
            elif self.drag == "orbit":
                self.control.orbit(dx, dy)
            elif self.drag == "look":
                self.control.look(dx, dy)
            elif self.drag == "pan":
                self.control.pan(dx, dy, self.height)
        elif isinstance(ev, Scroll):
            self.control.zoom(ev.dy)
        elif isinstance(ev, KeyDown):
            k = ev.key.lower()
            self.held.add(k)
            self._key_action(k)
        elif isinstance(ev, KeyUp):
            self.held.discard(ev.key.lower())

    def _key_action(self, k: str):
        s = self.settings
        if k == "1":
            self.set_mode("single")
        elif k == "2" and self.comparing:
            self.set_mode("split")
        elif k == "3" and self.comparing:
            self.set_mode("side")
        elif k in ("f", "space") and self.comparing:
            # Flip: full-frame A <-> B at the same camera (enters single mode).
            if s.mode != "single":
                s.mode, s.show = "single", 1
            else:
                s.show = 1 - s.show if s.show in (0, 1) else 0
        elif k == "h" and self.comparing:
            s.heatmap = not s.heatmap
        elif k == "r":
            self.control.reset()
        elif k in ("]", "n"):
            self.snap(self.camera_index + 1)
        elif k in ("[", "b"):
            self.snap(self.camera_index - 1)
        elif k == "p":
            self.request_screenshot()
        elif k == "tab":
            s.show_panel = not s.show_panel
        elif k == "escape":
            self.quit = True

    # -- per-frame logic ---------------------------------------------------------------------------
    def step(self, dt: float) -> None:
        """Advance ``dt`` seconds: fly with held keys, pick up finished background work."""
        h = self.held
        right = ("d" in h) - ("a" in h)
        fwd = ("w" in h) - ("s" in h)
        up = ("e" in h) - ("q" in h)
        if right or fwd or up:
            speed = self.settings.fly_speed * self.scene_radius * (4.0 if "shift" in h else 1.0)
            self.control.fly(right, up, fwd, speed * dt)
        if self.control.version != self._last_version:
            self._last_version = self.control.version
            self._last_move = time.monotonic()
        self._poll_budgets()
        self._poll_stream()

    def _poll_budgets(self):
        if self.budget_jobs is None:
            return
        snap = self.budget_jobs.snapshot()
        self.status = snap["status"]
        res = snap["results"]
        while self._seen_budget_results < len(res):
            r = res[self._seen_budget_results]
            self._seen_budget_results += 1
            scene = scene_from_bytes(r.label, r.data, r.cloud)
            self._upload(scene)
            self.variants.append(scene)
            if self.b_index < 0:
                self.b_index = len(self.variants) - 1
                if self.settings.mode == "single":
                    self.settings.mode = "split"

    def _render_size(self):
        sc = float(np.clip(self.settings.render_scale, 0.1, 1.0))
        w = max(1, int(round(self.width * sc)))
        h = max(1, int(round(self.height * sc)))
        if self.settings.mode == "side" and self.comparing:
            w = max(1, int(self.width // 2 * sc))
        return w, h

    def _target(self, slot: str, w: int, h: int) -> FloatTarget:
        t = self._targets.get(slot)
        if t is None or t.size != (w, h):
            if t is not None:
                t.release()
            t = FloatTarget(self.ctx, w, h)
            t.texture.repeat_x = t.texture.repeat_y = False
            self._targets[slot] = t
        return t

    def _scenes_needed(self):
        s = self.settings
        if not self.comparing:
            return [("a", self.a)]
        if s.mode == "single" and not s.heatmap:
            return [("a", self.a)] if s.show == 0 else [("b", self.b)]
        return [("a", self.a), ("b", self.b)]

    def view_camera(self):
        w, h = self._render_size()
        return self.control.camera(w, h)

    def render(self, *, wait_for_sort: bool = False) -> None:
        """Draw the current view into :attr:`output` (an RGBA8 framebuffer of window size).

        wait_for_sort  block until every drawn scene's order is sorted for this exact camera
                       (screenshots); otherwise the newest finished order is used and
                       :attr:`needs_redraw` stays True until the sort catches up.
        """
        t0 = time.perf_counter()
        cam = self.view_camera()
        needed = self._scenes_needed()
        for _, scene in needed:
            if scene.sorter is None:        # empty (a stream before its first layer)
                continue
            scene.sorter.request(cam)
            if wait_for_sort or scene.sorter.order() is None:
                scene.sorter.wait_current(timeout=600.0)
        # Nothing that shows has changed (idle window, a background encode ticking): keep
        # the last frame instead of re-rendering every splat.
        key = (camera_key(cam), cam.width, cam.height, self.width, self.height,
               dataclasses.astuple(self.settings), id(self.b),
               tuple((id(scene.cloud), scene.sorter.sorts_done if scene.sorter else -1)
                     for _, scene in needed))
        if key != self._frame_key or self.output is None:
            self._draw(cam, needed)
            self._frame_key = key
            self.stats["frame_s"] = time.perf_counter() - t0
            self.frame_times = (self.frame_times + [time.perf_counter()])[-30:]
        if self.stats["sort_current"] and self.settings.auto_metrics and self.comparing \
                and time.monotonic() - self._last_move > 0.3:
            self.request_metrics()

    def _draw(self, cam, needed) -> None:
        mgl = self._mgl
        s = self.settings
        drawn = {}
        sort_s = 0.0
        pre_s = draw_s = 0.0
        current = True
        for slot, scene in needed:
            target = self._target(slot, cam.width, cam.height)
            drawn[slot] = target
            if scene.renderer is None:      # nothing arrived yet: background only
                target.fbo.use()
                self.ctx.viewport = (0, 0, target.width, target.height)
                self.ctx.clear(*[float(v) for v in s.background], 0.0)
                continue
            order = scene.sorter.order()
            current &= scene.sorter.is_current
            sort_s = max(sort_s, scene.sorter.last_sort_s)
            deg = min(int(s.sh_degree), scene.cloud.sh_degree)
            scene.renderer.render(cam, target, order=order, background=s.background,
                                  sh_degree=deg, scale_modifier=s.scale_modifier)
            pre_s += scene.renderer.last_times["preprocess_s"]
            draw_s += scene.renderer.last_times["draw_s"]
        # Composite into the output framebuffer.
        if self._out_size != (self.width, self.height):
            if self.output is not None:
                self.output[0].release()
                self.output[1].release()
            tex = self.ctx.texture((self.width, self.height), 4)
            self.output = (tex, self.ctx.framebuffer(color_attachments=[tex]))
            self._out_size = (self.width, self.height)
        fbo = self.output[1]
        fbo.use()
        self.ctx.viewport = (0, 0, self.width, self.height)
        self.ctx.disable(mgl.BLEND)
        ta = drawn.get("a", self._dummy)
        tb = drawn.get("b", self._dummy)
        smooth = float(s.render_scale) < 1.0
        for t in (ta, tb):
            t.texture.filter = (mgl.LINEAR, mgl.LINEAR) if smooth else (mgl.NEAREST, mgl.NEAREST)
        ta.texture.use(0)
        tb.texture.use(1)
        p = self.comp
        p["u_a"].value = 0
        p["u_b"].value = 1
        p["u_size"].value = (float(self.width), float(self.height))
        p["u_full_scale"].value = HEAT_FULL_SCALE
        p["u_line_color"].value = (1.0, 0.85, 0.1)
        p["u_split"].value = float(self.split_px())
        if not self.comparing:
            mode, show, heat = 0, 0, False
        elif s.mode == "single":
            mode, show, heat = 0, (2 if s.heatmap else s.show), False
        else:
            mode, show, heat = MODES.index(s.mode), 0, bool(s.heatmap)
        p["u_mode"].value = mode
        p["u_show"].value = show
        p["u_heat"].value = heat
        self.comp_vao.render(mode=mgl.TRIANGLES, vertices=3)
        # Keep the two renders of this view for PSNR/SSIM (read back lazily).
        self._drawn = drawn
        self._drawn_key = (camera_key(cam), cam.width, cam.height, id(self.b), s.background,
                           s.sh_degree, s.scale_modifier)
        self.stats.update(sort_s=sort_s, preprocess_s=pre_s, draw_s=draw_s, sort_current=current)

    @property
    def needs_redraw(self) -> bool:
        """True while the view changes without new input: a sort for the current camera is
        still running, or fly keys are held.  (Background encodes and PSNR/SSIM results only
        change the panel; the window picks them up at its idle polling rate.)"""
        return not self.stats.get("sort_current", True) or bool(self.held & set("wasdqe"))

    # -- output ------------------------------------------------------------------------------------
    def read_output(self) -> np.ndarray:
        """[H, W, 3] uint8 of the last composed frame (row 0 = top)."""
        raw = self.output[1].read(components=3, alignment=1)
        return np.frombuffer(raw, np.uint8).reshape(self.height, self.width, 3)[::-1].copy()

    def present(self, fbo) -> None:
        """Copy the composed frame into ``fbo`` (e.g. ``ctx.screen``)."""
        self.ctx.copy_framebuffer(fbo, self.output[1])

    def request_screenshot(self, path: str | None = None) -> str:
        """Write the current view (exactly sorted, without the panel) to a PNG; returns the
        path.  Default name: gsz-view-NNN.png in :attr:`screenshot_dir`."""
        for _, scene in self._scenes_needed():
            scene.sorter.request(self.view_camera())
        self.render(wait_for_sort=True)
        if path is None:
            while True:
                self.screenshots_taken += 1
                path = os.path.join(self.screenshot_dir, f"gsz-view-{self.screenshots_taken:03d}.png")
                if not os.path.exists(path):
                    break
        write_png(path, self.read_output())
        self.status = f"saved {path}"
        return path

    # -- UI ------------------------------------------------------------------------------------------
    def draw_ui(self) -> None:
        """The imgui panel + labels; call between ``imgui.new_frame()`` and ``imgui.render()``."""
        from .ui import draw_panel
        draw_panel(self)


def write_png(path: str, rgb: np.ndarray) -> None:
    """Write an [H, W, 3] uint8 image atomically (temp file + rename)."""
    import io
    from PIL import Image
    from ..decoder.io_util import atomic_write
    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(rgb, np.uint8), "RGB").save(buf, format="PNG", optimize=True)
    atomic_write(path, buf.getvalue())
