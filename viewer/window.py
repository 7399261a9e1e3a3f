"""A glfw window with a moderngl context and imgui-bundle's native glfw/OpenGL3 backends.

``imgui_bundle`` is imported BEFORE ``glfw``: it points pyGLFW at its own GLFW 3.5 library, so
imgui's backend and pyGLFW share one GLFW (and 3.5's null platform + EGL lets the window open
with no display at all, which the UI tests use).  Input reaches the app through imgui's IO
state, translated each frame by :meth:`Window.input_events` into the app's event objects, and
only when imgui does not want the mouse / keyboard itself (clicks on the panel stay there).
"""
from __future__ import annotations

import ctypes
import os
import time

from .app import KeyDown, KeyUp, MouseDown, MouseMove, MouseUp, Scroll
from .gl_renderer import GLUnavailable

__all__ = ["Window", "OffscreenWindow", "open_window", "frame", "run", "has_display", "scene_width",
           "stats_line"]

# app key name -> imgui.Key attribute
_KEYS = {**{c: c for c in "wasdqefhrpnb"}, "1": "_1", "2": "_2", "3": "_3", "space": "space",
         "escape": "escape", "tab": "tab", "[": "left_bracket", "]": "right_bracket"}


def has_display() -> bool:
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


class _ImguiInput:
    """Translates imgui's input state (fed by the glfw backend, or by ``io.add_*_event``) into
    the app's events; shared by :class:`Window` and :class:`OffscreenWindow`."""

    _prev_mouse = None
    _shift = False

    def input_events(self) -> list:
        """App events for this frame from imgui's input state (framebuffer pixels)."""
        imgui = self.imgui
        io = imgui.get_io()
        sc = self.pixel_scale()
        out = []
        if io.key_shift != self._shift:
            self._shift = io.key_shift
            out.append(KeyDown("shift") if io.key_shift else KeyUp("shift"))
        pos = io.mouse_pos
        if abs(pos.x) < 1e30 and abs(pos.y) < 1e30:   # -FLT_MAX when the mouse is outside
            p = (pos.x * sc, pos.y * sc)
            if p != self._prev_mouse:
                out.append(MouseMove(*p))
                self._prev_mouse = p
        else:
            p = self._prev_mouse or (0.0, 0.0)
        for b in range(3):
            if imgui.is_mouse_released(b):
                out.append(MouseUp(p[0], p[1], b))   # always: ends drags begun on the scene
            elif imgui.is_mouse_clicked(b) and not io.want_capture_mouse:
                out.append(MouseDown(p[0], p[1], b))
        if io.mouse_wheel and not io.want_capture_mouse:
            out.append(Scroll(float(io.mouse_wheel)))
        if not io.want_capture_keyboard:
            for name, attr in _KEYS.items():
                key = getattr(imgui.Key, attr)
                if imgui.is_key_pressed(key, False):
                    out.append(KeyDown(name))
                elif imgui.is_key_released(key):
                    out.append(KeyUp(name))
        return out


class Window(_ImguiInput):
    """One window + GL 4.3 core context (+ imgui).  ``headless=None``: the GLFW null platform
    with an EGL context when there is no display (nothing is shown; frames can be read)."""

    def __init__(self, width: int = 1280, height: int = 720, title: str = "gsz-view", *,
                 headless: bool | None = None):
        try:
            from imgui_bundle import imgui  # noqa: F401  (must precede glfw, see module doc)
            import glfw
            import moderngl
        except ImportError as e:
            raise GLUnavailable(f"the viewer needs imgui-bundle, glfw and moderngl ({e}); "
                                "pip install 'gsz[viewer]'") from None
        self.imgui, self.glfw = imgui, glfw
        self.headless = (not has_display()) if headless is None else bool(headless)
        if self.headless:
            if not hasattr(glfw, "PLATFORM_NULL"):
                raise GLUnavailable("this glfw has no null platform (needs GLFW >= 3.4)")
            glfw.init_hint(glfw.PLATFORM, glfw.PLATFORM_NULL)
        glfw.ERROR_REPORTING = "ignore"     # failures become one GLUnavailable line, not warnings
        if not glfw.init():
            why = (glfw.get_error()[1] or b"").decode(errors="replace")
            raise GLUnavailable(f"cannot open a window: glfw could not start ({why or 'no display'}); "
                                "render a view without one with --screenshot OUT.png [--camera I]")
        glfw.window_hint(glfw.CONTEXT_VERSION_MAJOR, 4)
        glfw.window_hint(glfw.CONTEXT_VERSION_MINOR, 3)
        glfw.window_hint(glfw.OPENGL_PROFILE, glfw.OPENGL_CORE_PROFILE)
        glfw.window_hint(glfw.OPENGL_FORWARD_COMPAT, True)
        if self.headless:
            glfw.window_hint(glfw.CONTEXT_CREATION_API, glfw.EGL_CONTEXT_API)
        self.win = glfw.create_window(int(width), int(height), title, None, None)
        if not self.win:
            why = (glfw.get_error()[1] or b"").decode(errors="replace")
            glfw.terminate()
            raise GLUnavailable(f"cannot open an OpenGL 4.3 window ({why or 'no reason given'}); "
                                "--screenshot OUT.png renders without a window")
        glfw.make_context_current(self.win)
        glfw.swap_interval(0)   # uncapped: the FPS readout should mean something
        try:
            self.ctx = moderngl.create_context(require=430)
        except Exception as e:
            glfw.destroy_window(self.win)
            glfw.terminate()
            raise GLUnavailable(f"cannot use the window's GL context: {e}") from None
        imgui.create_context()
        imgui.get_io().set_ini_filename("")   # no imgui.ini in the user's folder
        imgui.backends.glfw_init_for_opengl(ctypes.cast(self.win, ctypes.c_void_p).value, True)
        imgui.backends.opengl3_init("#version 430")
        self._closed = False
        self._prev_mouse = None
        self._shift = False

    # -- geometry -------------------------------------------------------------------------------
    def framebuffer_size(self):
        return self.glfw.get_framebuffer_size(self.win)

    def pixel_scale(self) -> float:
        """Framebuffer pixels per window coordinate (2 on a HiDPI screen)."""
        w, _ = self.glfw.get_window_size(self.win)
        fw, _ = self.framebuffer_size()
        return fw / w if w else 1.0

    @property
    def should_close(self) -> bool:
        return bool(self.glfw.window_should_close(self.win))

    # -- frame ----------------------------------------------------------------------------------
    def begin_frame(self, wait: float = 0.0):
        """Poll (or wait up to ``wait`` seconds for) events and start an imgui frame."""
        if wait > 0:
            self.glfw.wait_events_timeout(wait)
        else:
            self.glfw.poll_events()
        imgui = self.imgui
        imgui.backends.opengl3_new_frame()
        imgui.backends.glfw_new_frame()
        imgui.new_frame()

    def end_frame(self, app=None):
        """Show the app's frame (the scene area at the left), draw imgui on top, swap."""
        imgui = self.imgui
        imgui.render()
        self.ctx.screen.use()
        fw, fh = self.framebuffer_size()
        self.ctx.viewport = (0, 0, fw, fh)
        self.ctx.clear(0.06, 0.06, 0.06, 1.0)        # the panel strip's background
        if app is not None and app.output is not None:
            app.present(self.ctx.screen)
        imgui.backends.opengl3_render_draw_data(imgui.get_draw_data())

    def read_screen(self):
        """[H, W, 3] uint8 of the back buffer (call after :meth:`end_frame`, before swap)."""
        import numpy as np
        fw, fh = self.framebuffer_size()
        raw = self.ctx.screen.read(viewport=(0, 0, fw, fh), components=3, alignment=1)
        return np.frombuffer(raw, np.uint8).reshape(fh, fw, 3)[::-1].copy()

    def swap(self):
        self.glfw.swap_buffers(self.win)

    def close(self):
        if self._closed:
            return
        self._closed = True
        imgui = self.imgui
        imgui.backends.opengl3_shutdown()
        imgui.backends.glfw_shutdown()
        imgui.destroy_context()
        self.glfw.destroy_window(self.win)
        self.glfw.terminate()


class OffscreenWindow(_ImguiInput):
    """The :class:`Window` interface without glfw: an EGL context and an RGBA8 framebuffer
    standing in for the screen, imgui rendering into it (``io.display_size`` set by hand).
    Input comes only from ``io.add_*_event`` calls or injected app events.  For tests and scripted
    captures on machines where even the GLFW null platform is unavailable."""

    headless = True

    def __init__(self, width: int = 1280, height: int = 720, title: str = "gsz-view", **_):
        from .gl_renderer import create_headless_context
        from imgui_bundle import imgui
        self.imgui = imgui
        self.ctx = create_headless_context()
        self.size = (int(width), int(height))
        self._tex = self.ctx.texture(self.size, 4)
        self.screen = self.ctx.framebuffer(color_attachments=[self._tex])
        imgui.create_context()
        imgui.get_io().set_ini_filename("")
        imgui.backends.opengl3_init("#version 430")
        self._closed = False
        self._t = time.perf_counter()

    def framebuffer_size(self):
        return self.size

    def pixel_scale(self) -> float:
        return 1.0

    should_close = False

    def begin_frame(self, wait: float = 0.0):
        imgui = self.imgui
        io = imgui.get_io()
        io.display_size = imgui.ImVec2(float(self.size[0]), float(self.size[1]))
        now = time.perf_counter()
        io.delta_time = max(now - self._t, 1e-4)
        self._t = now
        imgui.backends.opengl3_new_frame()
        imgui.new_frame()

    def end_frame(self, app=None):
        imgui = self.imgui
        imgui.render()
        self.screen.use()
        self.ctx.viewport = (0, 0, *self.size)
        self.ctx.clear(0.06, 0.06, 0.06, 1.0)
        if app is not None and app.output is not None:
            app.present(self.screen)
        imgui.backends.opengl3_render_draw_data(imgui.get_draw_data())

    def read_screen(self):
        import numpy as np
        raw = self.screen.read(components=3, alignment=1)
        return np.frombuffer(raw, np.uint8).reshape(self.size[1], self.size[0], 3)[::-1].copy()

    def swap(self):
        pass

    def close(self):
        if self._closed:
            return
        self._closed = True
        self.imgui.backends.opengl3_shutdown()
        self.imgui.destroy_context()
        self.screen.release()
        self._tex.release()
        self.ctx.release()


def open_window(width: int = 1280, height: int = 720, title: str = "gsz-view", *,
                allow_offscreen: bool = False):
    """A :class:`Window` (real display, or the GLFW null platform + EGL without one); with
    ``allow_offscreen``, an :class:`OffscreenWindow` when no glfw window can be opened."""
    try:
        return Window(width, height, title)
    except GLUnavailable:
        if not allow_offscreen:
            raise
        return OffscreenWindow(width, height, title)


def scene_width(window, app) -> int:
    """Framebuffer pixels left of the panel strip (the whole width with the panel hidden)."""
    fw, _ = window.framebuffer_size()
    if not app.settings.show_panel:
        return fw
    from .state import panel_width
    sc = window.pixel_scale()
    return max(1, fw - int(round(panel_width(fw / sc) * sc)))


def frame(window: Window, app, dt: float, *, events=(), wait: float = 0.0) -> None:
    """One full frame: input (window + injected ``events``), step, panel, render, show.  The
    scenes take the window left of the panel's strip."""
    window.begin_frame(wait)
    fw, fh = window.framebuffer_size()
    sw = scene_width(window, app)
    if (sw, fh) != (app.width, app.height) and fw > 0 and fh > 0:
        app.resize(sw, fh)
    for ev in list(window.input_events()) + list(events):
        app.handle_event(ev)
    app.step(dt)
    app.draw_ui()
    app.render()
    window.end_frame(app)


def stats_line(app) -> str:
    """One line of the last rendered frame's times (``--stats``)."""
    st = app.stats
    n = sum(len(s.cloud) for _, s in app._scenes_needed())
    fps = app.fps
    return (f"frame {1e3 * st['frame_s']:.1f} ms" + (f" ({fps:.1f} FPS)" if fps else "")
            + f": sort {1e3 * st['sort_s']:.1f} ms, gpu preprocess {1e3 * st['preprocess_s']:.1f} ms, "
            f"draw {1e3 * st.get('draw_s', 0.0):.1f} ms; {app.width}x{app.height}, {n:,} splats")


def run(window: Window, app, *, stats=None) -> None:
    """The interactive loop until the window closes or the app quits (Esc).  Sleeps in
    ``wait_events_timeout`` when nothing changes, so an idle viewer uses no CPU.  ``stats``:
    a callback given :func:`stats_line` about once a second while frames are rendered."""
    last = time.perf_counter()
    idle_frames = 0
    told = last
    while not window.should_close and not app.quit:
        now = time.perf_counter()
        dt, last = min(now - last, 0.25), now
        # imgui needs a couple of frames to settle after input; then idle politely.
        wait = 0.05 if (idle_frames > 3 and not app.needs_redraw) else 0.0
        frame(window, app, dt, wait=wait)
        window.swap()
        idle_frames = idle_frames + 1 if not app.needs_redraw else 0
        if stats is not None and now - told >= 1.0 and app.frame_times and app.frame_times[-1] > told:
            stats(stats_line(app))
            told = now
