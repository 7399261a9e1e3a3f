"""The imgui-bundle control panel and the per-half labels of a :class:`gsz.viewer.state.ViewState`
(the :class:`gsz.viewer.app.ViewerApp`).

Call :func:`draw_panel` between ``imgui.new_frame()`` and ``imgui.render()``.  Every widget
writes straight into ``app.settings`` / calls an app method, so whatever the panel can do a
test can do through the same methods.
"""
from __future__ import annotations

from imgui_bundle import imgui

from .state import MODES, format_bytes, panel_width

_MODE_LABELS = {"single": "single / flip (F)", "split": "split (2)", "side": "side by side (3)"}


def _label(x, y, text):
    dl = imgui.get_foreground_draw_list()
    # app coordinates are framebuffer pixels; imgui draws in window coordinates (HiDPI)
    k = imgui.get_io().display_framebuffer_scale.x or 1.0
    pos = imgui.ImVec2(float(x) / k, float(y) / k)
    # dark box behind the text so it reads on any background
    size = imgui.calc_text_size(text)
    dl.add_rect_filled(imgui.ImVec2(pos.x - 4, pos.y - 2),
                       imgui.ImVec2(pos.x + size.x + 4, pos.y + size.y + 2),
                       imgui.color_convert_float4_to_u32(imgui.ImVec4(0, 0, 0, 0.6)))
    dl.add_text(pos, imgui.color_convert_float4_to_u32(imgui.ImVec4(1, 1, 1, 1)), text)


def draw_labels(app) -> None:
    if app.settings.labels:
        for x, y, text in app.labels():
            _label(x, y + 0.0, text)


def _components(scene):
    if not scene.components:
        return
    if imgui.begin_table(f"comp_{id(scene)}", 2, imgui.TableFlags_.borders_inner_v):
        for name, n in sorted(scene.components.items(), key=lambda kv: -kv[1]):
            imgui.table_next_row()
            imgui.table_next_column()
            imgui.text(name)
            imgui.table_next_column()
            imgui.text(f"{n:,} B")
        imgui.end_table()


def draw_panel(app) -> None:
    s = app.settings
    draw_labels(app)
    if not s.show_panel:
        return
    # The panel fills its own strip at the right edge; the scenes are drawn left of it
    # (gsz.viewer.window.frame), so it covers neither the original nor the decoded half.
    io = imgui.get_io()
    disp_w, disp_h = io.display_size.x, io.display_size.y
    panel_w = panel_width(disp_w)
    imgui.set_next_window_pos(imgui.ImVec2(disp_w - panel_w, 0.0), imgui.Cond_.always)
    imgui.set_next_window_size(imgui.ImVec2(panel_w, disp_h), imgui.Cond_.always)
    imgui.begin("gsz-view", None, imgui.WindowFlags_.no_move | imgui.WindowFlags_.no_resize
                | imgui.WindowFlags_.no_collapse)
    st = app.stats
    fps = app.fps
    imgui.text((f"{fps:5.1f} FPS" if fps else "idle (view unchanged)")
               + f"   last frame {1e3 * st['frame_s']:.1f} ms")
    imgui.text(f"sort {1e3 * st['sort_s']:.1f} ms{'' if st['sort_current'] else ' (sorting...)'}"
               f"   gpu prep {1e3 * st['preprocess_s']:.1f} ms")
    if app.is_llvmpipe:
        imgui.text_colored(imgui.ImVec4(1, 0.7, 0.2, 1), "software GL (llvmpipe): lower render scale")

    imgui.separator_text("scene")
    for scene in [app.a] + ([app.b] if app.comparing else []):
        if imgui.tree_node(f"{scene.name}##{id(scene)}"):
            imgui.text(f"{len(scene.cloud):,} splats, SH degree {scene.cloud.sh_degree}")
            imgui.text(f"file {format_bytes(scene.file_bytes)}"
                       + (f" ({scene.file_bytes:,} B)" if scene.file_bytes else ""))
            _components(scene)
            imgui.tree_pop()

    if len(app.variants) > 1 or app.budget_jobs is not None:
        imgui.separator_text("compare against")
        names = [v.label for v in app.variants]
        if names:
            changed, idx = imgui.combo("decoded", max(app.b_index, 0), names)
            if changed:
                app.set_b(idx)
        if app.budget_jobs is not None:
            snap = app.budget_jobs.snapshot()
            total = len(app.budget_jobs.budgets)
            done = len(snap["results"]) + len(snap["errors"])
            imgui.progress_bar(done / max(total, 1), imgui.ImVec2(-1, 0), f"{done}/{total} budgets")
            imgui.text_wrapped(snap["status"])
            for label, msg in snap["errors"]:
                imgui.text_colored(imgui.ImVec4(1, 0.4, 0.4, 1), f"{label}: {msg}")

    _streaming(app)

    if app.comparing:
        imgui.separator_text("compare")
        for m in MODES:
            if imgui.radio_button(_MODE_LABELS[m], s.mode == m):
                app.set_mode(m)
        if s.mode == "single":
            if imgui.button(f"flip (F): showing {'A ' + app.a.name if s.show == 0 else 'B ' + app.b.name}"):
                s.show = 1 - s.show
        if s.mode == "split":
            _, s.split = imgui.slider_float("split", s.split, 0.0, 1.0)
        _, s.heatmap = imgui.checkbox("error heat map (H)", s.heatmap)
        m = app.current_metrics()
        if m:
            imgui.text(f"this view: PSNR {m['psnr']:.2f} dB   SSIM {m['ssim']:.4f}")
            imgui.text_disabled(f"(gsz-eval protocol: CPU renders at {m['width']}x{m['height']})")
        else:
            imgui.text("this view: PSNR/SSIM pending")
        _, s.auto_metrics = imgui.checkbox("auto PSNR/SSIM when the view rests", s.auto_metrics)
        imgui.same_line()
        if imgui.button("now"):
            app.request_metrics()

    imgui.separator_text("render")
    max_deg = max(x.cloud.sh_degree for x in [app.a] + ([app.b] if app.comparing else []))
    s.sh_degree = min(s.sh_degree, max_deg)
    _, s.sh_degree = imgui.slider_int("SH degree", s.sh_degree, 0, max_deg)
    _, s.scale_modifier = imgui.slider_float("splat scale", s.scale_modifier, 0.05, 2.0)
    _, s.render_scale = imgui.slider_float("render scale", s.render_scale, 0.1, 1.0)
    changed, col = imgui.color_edit3("background", list(s.background))
    if changed:
        s.background = tuple(float(c) for c in col)
    _, s.labels = imgui.checkbox("labels", s.labels)

    _camera(app, s)
    if app.status:
        imgui.text_wrapped(app.status)
    imgui.end()


def _streaming(app) -> None:
    """The simulated-network replay of a layered or tiled file."""
    cand = app.stream_candidate()
    if cand is not None:
        imgui.separator_text("streaming (simulated network)")
        st_ = app.stream_status
        if st_ is not None:
            frac = st_["bytes"] / max(1, st_["total"])
            imgui.progress_bar(frac, imgui.ImVec2(-1, 0),
                               f"{format_bytes(st_['bytes'])} / {format_bytes(st_['total'])}")
            tiles = f"   tiles {st_['tiles']} parts / {st_['tiles_total']}" if (st_.get("tiles_total") or 1) > 1 else ""
            imgui.text(f"layers {st_['layers']}/{st_['layers_total'] or '?'}{tiles}   "
                       f"{len(app.stream_scene.cloud):,} splats" + ("   done" if st_["done"] else ""))
        mbps = app.stream_rate / 1e6
        _, mbps = imgui.slider_float("MB/s", mbps, 0.05, 100.0, "%.2f", imgui.SliderFlags_.logarithmic)
        app.stream_rate = mbps * 1e6
        if imgui.button(f"replay {cand.name} at {mbps:.2f} MB/s"):
            app.start_stream(cand, app.stream_rate)


def _camera(app, s) -> None:
    """Snap to a camera, step through them, fly speed, screenshot."""
    imgui.separator_text("camera")
    kind, i, cam = app.camera_list[app.camera_index]
    names = [f"{k} {j}  {c.name}" for k, j, c in app.camera_list]
    changed, idx = imgui.combo("snap to", app.camera_index, names)
    if changed:
        app.snap(idx)
    if imgui.button("< prev ([)"):
        app.snap(app.camera_index - 1)
    imgui.same_line()
    if imgui.button("next (]) >"):
        app.snap(app.camera_index + 1)
    imgui.same_line()
    if imgui.button("reset (R)"):
        app.control.reset()
    _, s.fly_speed = imgui.slider_float("fly speed", s.fly_speed, 0.01, 10.0, "%.2f",
                                        imgui.SliderFlags_.logarithmic)
    imgui.text_wrapped("Tab: hide panel  drag: orbit  right-drag: look  middle/shift-drag: pan  wheel: zoom  "
                       "WASD/QE: fly (shift x4)")
    if imgui.button("screenshot (P)"):
        app.request_screenshot()
