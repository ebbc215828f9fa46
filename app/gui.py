"""Open3D GUI for interactive placement: a thin view over app.placement.PlacementController.

Layout: a tab control on the left with "Photo" (the live composite in an ImageWidget; click to
place the object on the surface under the cursor, drag to slide it on its resting plane) and
"3D" (a SceneWidget with the scene model coloured by patch radiance through the camera response,
the placed object and the camera frustum); a side panel on the right with the object picker,
the pass budget (slider 10-50, or all sources), the HDR/LDR compositing path, live frame time
and pass count, undo/redo and save/load.

Keys (window focus): Q/E turn -/+15 deg about +Y, R/F lift/lower 2 cm, =/- scale x1.1 / /1.1,
arrow keys slide 5 cm along world x/z, Z undo, Y redo.

Threads: the per-scene precompute runs in a worker thread (progress bar, window stays
responsive); frames are composited in a second worker that always renders the newest pose
(edits made while a frame is running coalesce into one frame); while the pose rests the same
worker refines it a slice at a time, showing each frame at rest as it comes (a finer cluster
frame, then the all-sources frame: PlacementController.refine; the next edit interrupts it).
Widgets are touched only on the main thread (Application.post_to_main_thread).
"""
from __future__ import annotations

import ctypes
import ctypes.util
import functools
import logging
import math
import threading
import time
from pathlib import Path
from typing import Callable

import numpy as np

from app.placement import PlacementController, Pose

log = logging.getLogger("photoar")

PANEL_W = 300  # px, side panel width (at scaling 1)
ROTATE_STEP = 15.0  # deg
LIFT_STEP = 0.02  # m
MOVE_STEP = 0.05  # m
SCALE_STEP = 1.1
REFINE_SLICE_S = 0.05  # s of refinement between checks for a new edit (the drag frame stays on screen meanwhile)
# The newest pose's preview (the pose label, the 3D view's object, the last frame with the pose's outline, shown
# while that pose's frame is made) is redrawn at most once per PREVIEW_INTERVAL_S, not on each edit, and not at all
# while the mouse button is held (DRAG_PREVIEWS): each preview is a redraw of the whole window, on the CPU where
# there is no GPU (Mesa's llvmpipe under Xvfb), about 50 ms of CPU a redraw on a 2-core machine (loaded), CPU the drag
# frames need; and a preview being drawn when a frame is handed over delays that frame's own draw. During a drag
# the window is drawn once per frame: each frame shown while the pose moves carries the newest pose's outline and
# label (_show_frame). docs/benchmarks.md, "The GUI's event to screen (gui48)" (20 Hz during drags before).
PREVIEW_INTERVAL_S = 0.05
DRAG_PREVIEWS = False
# The pointer has rested once the event loop ran a tick STILL_S after the last edit with no edit since: three
# reports of a 60 Hz mouse (a drag reports each move at the screen's rate; a hand that stopped reports none).
# Timed by the loop's ticks, not the clock: a main thread held up by a redraw delivers the moves made meanwhile
# on its next tick, and a drag is not taken for a rest then. The frame under way, of a pose an edit has
# replaced since, is then abandoned between two of its stages (Engine.render's stop) so that the resting
# pose's frame starts at once instead of after it: the rested pose is on screen up to a frame sooner. While
# the edits keep coming every frame is finished: each would be overtaken before its end, and none shown.
# REST_TWO_TICKS: the tick that ends STILL_S after the last edit must be followed by another tick with no edit
# between (the rest is read at the end of the tick after the one that saw STILL_S pass). One tick was not enough: Open3D
# calls the tick callback at the end of the tick, after its draw (bench/bench_gui_tick_order.py), so a tick whose
# draw ran past STILL_S looked like a rest before the moves made meanwhile were delivered by the next tick, and
# the frame under way was abandoned mid-drag (gui36, docs/benchmarks.md).
STILL_S = 3 / 60
REST_TWO_TICKS = True
# The 3D view's object is uploaded only while the 3D tab is shown (_show_object): each upload costs the main thread
# a mesh and the renderer a new geometry, for a view that is not drawn while the Photo tab is.
SKIP_HIDDEN_3D = True
SETTLE_TICKS = 20  # redraws before a scripted screenshot is compared (settled_screenshot)
# The default window shows the frames at their own pixel size (default_window_size): where the window is drawn on the
# CPU (Mesa's llvmpipe), a draw costs CPU per window pixel, and a 640x480 photo scaled up to a 1280x720 window cost
# ~2x the draw for no detail (docs/benchmarks.md, "The window at the photo's own size (gui36)").
SCREEN_MARGIN_PX = 64  # px of the screen left free each way by the default window (title bar, task bar)
TAB_BAR_EM = 1.375  # the TabControl's tab bar height in font sizes (22 px at Open3D's 16 px font; checked at layout)


# ---------------------------------------------------------------------------- X11 screenshot
class _XImage(ctypes.Structure):
    # the leading fields of Xlib's XImage (X11/Xlib.h), stable since X11R6
    _fields_ = [("width", ctypes.c_int), ("height", ctypes.c_int), ("xoffset", ctypes.c_int),
                ("format", ctypes.c_int), ("data", ctypes.c_void_p), ("byte_order", ctypes.c_int),
                ("bitmap_unit", ctypes.c_int), ("bitmap_bit_order", ctypes.c_int), ("bitmap_pad", ctypes.c_int),
                ("depth", ctypes.c_int), ("bytes_per_line", ctypes.c_int), ("bits_per_pixel", ctypes.c_int),
                ("red_mask", ctypes.c_ulong), ("green_mask", ctypes.c_ulong), ("blue_mask", ctypes.c_ulong)]


_X_ERROR_HANDLER = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p, ctypes.c_void_p)
_x_errors: list[int] = []
_x_handler = _X_ERROR_HANDLER(lambda d, e: _x_errors.append(1) or 0)


def _xlib(what: str):
    """Xlib through ctypes with the calls used here declared; RuntimeError naming `what` when it cannot load."""
    name = ctypes.util.find_library("X11") or "libX11.so.6"
    try:
        x11 = ctypes.CDLL(name)
    except OSError as e:
        raise RuntimeError(f"{name}: cannot load Xlib for {what} ({e})") from None
    x11.XOpenDisplay.restype = ctypes.c_void_p
    x11.XOpenDisplay.argtypes = [ctypes.c_char_p]
    x11.XDefaultRootWindow.restype = ctypes.c_ulong
    x11.XDefaultRootWindow.argtypes = [ctypes.c_void_p]
    x11.XDisplayWidth.argtypes = x11.XDisplayHeight.argtypes = [ctypes.c_void_p, ctypes.c_int]
    x11.XGetImage.restype = ctypes.POINTER(_XImage)
    x11.XGetImage.argtypes = [ctypes.c_void_p, ctypes.c_ulong, ctypes.c_int, ctypes.c_int, ctypes.c_uint,
                              ctypes.c_uint, ctypes.c_ulong, ctypes.c_int]
    x11.XDestroyImage = None  # a macro, not a symbol: the image is freed with XFree on its data
    x11.XFree.argtypes = [ctypes.c_void_p]
    x11.XCloseDisplay.argtypes = [ctypes.c_void_p]
    x11.XSync.argtypes = [ctypes.c_void_p, ctypes.c_int]
    x11.XSetErrorHandler.argtypes = [_X_ERROR_HANDLER]
    x11.XSetErrorHandler.restype = ctypes.c_void_p
    return x11


def screen_size() -> tuple[int, int] | None:
    """(width, height) px of the X display's default screen, or None when there is no X display (Xlib)."""
    try:
        x11 = _xlib("the screen size")
    except RuntimeError:
        return None
    d = x11.XOpenDisplay(None)
    if not d:
        return None
    try:
        return int(x11.XDisplayWidth(d, 0)), int(x11.XDisplayHeight(d, 0))
    finally:
        x11.XCloseDisplay(d)


def grab_screen(x: int, y: int, w: int, h: int) -> np.ndarray:
    """RGB (h,w,3) uint8 of the X display's root window in the rectangle (x, y, w, h), clipped
    to the screen (Xlib XGetImage through ctypes; needs a 24/32-bit TrueColor X server such as
    Xvfb). RuntimeError when there is no X display or the grab fails."""
    x11 = _xlib("the screenshot")
    d = x11.XOpenDisplay(None)
    if not d:
        raise RuntimeError("no X display to take the screenshot from (is DISPLAY set?)")
    old = x11.XSetErrorHandler(_x_handler)  # Xlib's default handler would exit the process
    try:
        sw, sh = x11.XDisplayWidth(d, 0), x11.XDisplayHeight(d, 0)
        x0, y0 = max(0, int(x)), max(0, int(y))
        x1, y1 = min(sw, int(x) + int(w)), min(sh, int(y) + int(h))
        if x1 <= x0 or y1 <= y0:
            raise RuntimeError(f"window rectangle {x},{y} {w}x{h} lies off the {sw}x{sh} screen")
        _x_errors.clear()
        ZPIXMAP = 2
        img = x11.XGetImage(d, x11.XDefaultRootWindow(d), x0, y0, x1 - x0, y1 - y0, 0xFFFFFFFF, ZPIXMAP)
        x11.XSync(d, 0)
        if not img or _x_errors:
            raise RuntimeError("XGetImage failed")
        im = img.contents
        if im.bits_per_pixel != 32 or im.red_mask != 0xFF0000 or im.blue_mask != 0xFF:
            raise RuntimeError(f"unsupported X visual ({im.bits_per_pixel} bpp, red mask {im.red_mask:#x})")
        raw = np.frombuffer(ctypes.string_at(im.data, im.bytes_per_line * im.height), np.uint8)
        px = raw.reshape(im.height, im.bytes_per_line)[:, :4 * im.width].reshape(im.height, im.width, 4)
        rgb = px[..., [2, 1, 0]].copy() if im.byte_order == 0 else px[..., [1, 2, 3]].copy()
        x11.XFree(ctypes.c_void_p(im.data))
        x11.XFree(img)
        return rgb
    finally:
        x11.XSetErrorHandler(ctypes.cast(old, _X_ERROR_HANDLER) if old else _X_ERROR_HANDLER())
        x11.XCloseDisplay(d)


# ---------------------------------------------------------------------------- drawing helpers
def default_window_size(img_w: int, img_h: int, panel_w: int, tab_h: int,
                        screen: tuple[int, int] | None) -> tuple[int, int]:
    """The default window's (width, height) px for frames of img_w x img_h px: the image at its own pixel size
    (1:1) under a tab bar of tab_h px, with the panel_w px side panel beside it; an image that does not fit the
    screen (width, height px; None: unknown, no limit) less SCREEN_MARGIN_PX each way is scaled down to fit,
    aspect kept. At least 320x240 (`--window`'s minimum)."""
    s = 1.0
    if screen is not None:
        s = min(1.0, (screen[0] - SCREEN_MARGIN_PX - panel_w) / img_w, (screen[1] - SCREEN_MARGIN_PX - tab_h) / img_h)
    w, h = int(math.floor(s * img_w + 1e-6)), int(math.floor(s * img_h + 1e-6))
    return max(320, w + panel_w), max(240, h + tab_h)


def image_fit(frame_w: float, frame_h: float, img_w: int, img_h: int) -> tuple[float, float, float]:
    """(scale, x offset, y offset) of an image drawn aspect-fit and centred in a frame, as
    Open3D's ImageWidget draws it."""
    s = min(frame_w / img_w, frame_h / img_h)
    return s, (frame_w - s * img_w) / 2, (frame_h - s * img_h) / 2


def outline_preview(pixels: np.ndarray, ctl: PlacementController, pose: Pose) -> np.ndarray:
    """The last composite with the outline (convex hull) of the object at `pose` drawn on it:
    instant feedback while the frame for that pose is being composited."""
    import cv2

    obj = ctl.scene_object(pose)
    out = np.array(pixels, copy=True)
    if obj is None:
        return out
    uv, z = ctl.scene.camera.project(obj.vertices)
    uv = uv[z > 1e-3]
    if len(uv) < 3:
        return out
    hull = cv2.convexHull(np.round(uv * 4).astype(np.int32))
    cv2.polylines(out, [hull], True, (255, 220, 0), 1, cv2.LINE_AA, shift=2)
    return out


def room_mesh(ctl: PlacementController):
    """Open3D TriangleMesh of the scene model, one colour per patch: patch radiance through the
    camera response once the engine is ready, the quads' albedo (emitters: their radiance)
    before."""
    from recon.io import open3d

    o3d = open3d()

    sc = ctl.scene
    eng = ctl.engine
    if eng is not None:
        pm = eng.pre.patches
        v = pm.vert_pos[pm.tris].reshape(-1, 3)
        col = eng.scene.response.to_levels(eng.pre.B[-1][pm.tri_patch]) / 255.0  # the engine's response
    else:
        corners = np.array([q.corners for q in sc.quads])
        v = corners[:, [0, 1, 2, 0, 2, 3]].reshape(-1, 3)
        quad_col = np.array([sc.response.to_levels(q.emission)[None][0] / 255.0
                             if q.is_emitter and sc.response is not None else q.albedo
                             for q in sc.quads])
        col = np.repeat(quad_col, 2, axis=0)
    m = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(v),
                                  o3d.utility.Vector3iVector(np.arange(len(v)).reshape(-1, 3)))
    # the renderer encodes its linear output for display; the levels already are display values
    m.vertex_colors = o3d.utility.Vector3dVector(np.repeat(np.clip(col, 0, 1) ** 2.2, 3, axis=0))
    return m


def frustum_lines(ctl: PlacementController, depth: float = 0.5):
    from recon.io import open3d

    o3d = open3d()

    cam = ctl.scene.camera
    W, H = cam.width, cam.height
    corners = [(-0.5, -0.5), (W - 0.5, -0.5), (W - 0.5, H - 0.5), (-0.5, H - 0.5)]
    c = cam.centre
    pts = [c] + [c + depth * ctl.pixel_ray(u, v) / (ctl.pixel_ray(u, v) @ (cam.R[2])) for u, v in corners]
    lines = [[0, 1], [0, 2], [0, 3], [0, 4], [1, 2], [2, 3], [3, 4], [4, 1]]
    ls = o3d.geometry.LineSet(o3d.utility.Vector3dVector(np.array(pts)), o3d.utility.Vector2iVector(lines))
    ls.paint_uniform_color([1.0, 0.8, 0.0])
    return ls


# ---------------------------------------------------------------------------- the window
class PlacementWindow:
    """The window; `ctl` holds every bit of state, this class only shows it and forwards input."""

    def __init__(self, ctl: PlacementController, mesh_choices: list[str], title: str = "photoar",
                 width: int | None = None, height: int | None = None, object_size: float | None = None):
        """width x height: the window's size in px; None: default_window_size (the frames 1:1)."""
        import open3d.visualization.gui as gui
        import open3d.visualization.rendering as rendering

        from recon.io import open3d

        o3d = open3d()

        self.o3d, self.gui, self.rendering = o3d, gui, rendering
        self.ctl = ctl
        self.app = gui.Application.instance
        self.object_size = object_size
        self.choices = list(dict.fromkeys(mesh_choices))
        self.frames_shown = 0
        self.refined_frames = 0  # frames at rest shown by _refine_at_rest (intermediate and all-sources)
        self.last_frame = None  # FrameResult on display
        # run_drag_bench: the poses whose frames _show_frame handed to the image widget and the window has not drawn
        # yet (None: no bench), and those it drew in the tick under way (_on_layout: each hand-over asks for a layout,
        # which Open3D runs in the window's next draw)
        self._bench_handed: list | None = None
        self._bench_drawn: list = []
        self._object_stale = False  # the 3D view's object lags the pose (the 3D tab is hidden; shown on selecting it)
        self.frame_times: list[float] = []  # seconds per engine frame (not kept ones)
        self.error: str | None = None
        self.engine_ready = threading.Event()
        self.closed = False
        self._dirty = False
        self._render_cv = threading.Condition()
        self._script: Callable[[], bool] | None = None  # headless mode: decides whether to render more
        self._pre_t0 = time.perf_counter()
        self._pre_fraction: float | None = None  # share of the precompute done (Engine's progress callback)
        self._preview_due = False  # the newest pose's outline is not on screen yet (main thread only)
        self._preview_t = -math.inf  # when the last outline preview was drawn (perf_counter s)
        self._dragging = False  # the mouse button is down on the photo: a gesture is under way (no refinement)
        self._edit_t = -math.inf  # when the last edit changed the pose (perf_counter s; main thread writes it)
        self._tick_t = -math.inf  # when the event loop's last tick ran _on_tick (perf_counter s; at the tick's end)
        self._tick_prev = -math.inf  # when the tick before it did (_overtaken's rest)

        # default size: the frames 1:1 (default_window_size); the tab bar's height is checked once laid out (_on_tick)
        self._fit_pending = width is None or height is None
        self._fit_set = self._fit_size() if self._fit_pending else (width, height)  # the size asked at creation
        w = self.window = self.app.create_window(title, *self._fit_set)
        em = w.theme.font_size
        self.tabs = gui.TabControl()
        self.image = gui.ImageWidget(o3d.geometry.Image(np.ascontiguousarray(ctl.scene.photo)))
        self.image.set_on_mouse(self._on_image_mouse)
        self.tabs.add_tab("Photo", self.image)
        self.scene3d = gui.SceneWidget()
        self.scene3d.scene = rendering.Open3DScene(w.renderer)
        self.scene3d.scene.set_background([0.1, 0.1, 0.12, 1.0])
        self.tabs.add_tab("3D", self.scene3d)
        self.tabs.set_on_selected_tab_changed(self._on_tab)
        w.add_child(self.tabs)

        # scrolls where the window is lower than the panel (the default window is as high as the photo)
        p = self.panel = gui.ScrollableVert(0.4 * em, gui.Margins(0.6 * em, 0.6 * em, 0.6 * em, 0.6 * em))
        self.status = gui.Label("precomputing the scene ...")
        self.progress = gui.ProgressBar()
        p.add_child(self.status)
        p.add_child(self.progress)
        p.add_fixed(0.5 * em)
        p.add_child(gui.Label("Object"))
        self.picker = gui.Combobox()
        for c in self.choices:
            self.picker.add_item(Path(c).name)
        self.picker.set_on_selection_changed(self._on_pick_object)
        p.add_child(self.picker)
        b_open = gui.Button("Open mesh...")
        b_open.set_on_clicked(self._on_open_mesh)
        p.add_child(b_open)
        p.add_fixed(0.5 * em)
        p.add_child(gui.Label("Shadow passes per frame"))
        self.slider = gui.Slider(gui.Slider.INT)
        self.slider.set_limits(10, max(50, int(ctl.passes or 0)))
        self.slider.int_value = int(ctl.passes) if ctl.passes else 50
        self.slider.set_on_value_changed(self._on_passes)
        p.add_child(self.slider)
        self.all_sources = gui.Checkbox("all sources")
        self.all_sources.checked = ctl.passes is None
        self.all_sources.set_on_checked(self._on_all_sources)
        p.add_child(self.all_sources)
        # label and control on one row each: the panel fits beside a 640x480 photo's default window down to its
        # Undo/Save row (the help below it scrolls)
        self.mode = gui.RadioButton(gui.RadioButton.HORIZ)
        self.mode.set_items(["HDR", "LDR"])
        self.mode.selected_index = 1 if ctl.config.mode == "ldr" else 0
        self.mode.set_on_selection_changed(self._on_mode)
        from app.engine import LIGHTING

        self.lighting = gui.Combobox()
        for name in LIGHTING:
            self.lighting.add_item(name)
        self.lighting.selected_text = ctl.lighting
        self.lighting.set_on_selection_changed(self._on_lighting)
        for text, widget in (("Compositing", self.mode), ("Lighting", self.lighting)):
            line = gui.Horiz(0.4 * em)
            line.add_child(gui.Label(text))
            line.add_stretch()
            line.add_child(widget)
            p.add_child(line)
        p.add_fixed(0.5 * em)
        self.frame_label = gui.Label("frame: -")
        self.pass_label = gui.Label("passes: -")
        self.pose_label = gui.Label("pose: -")
        for lab in (self.frame_label, self.pass_label, self.pose_label):
            p.add_child(lab)
        row = gui.Horiz(0.4 * em)
        for text, fn in (("Undo", self._on_undo), ("Redo", self._on_redo), ("Save", self._on_save),
                         ("Load", self._on_load)):
            b = gui.Button(text)
            b.set_on_clicked(fn)
            row.add_child(b)
        p.add_child(row)
        p.add_fixed(0.5 * em)
        p.add_child(gui.Label("click: place  drag: move\nQ/E turn  R/F lift  =/- scale\n"
                              "arrows: slide  Z undo  Y redo"))
        w.add_child(p)
        w.set_on_layout(self._on_layout)
        w.set_on_key(self._on_key)
        w.set_on_tick_event(self._on_tick)
        w.set_on_close(self._on_close)

        self._mat_room = rendering.MaterialRecord()
        self._mat_room.shader = "defaultUnlit"
        self._mat_obj = rendering.MaterialRecord()
        self._mat_obj.shader = "defaultLit"
        self._mat_line = rendering.MaterialRecord()
        self._mat_line.shader = "unlitLine"
        self._mat_line.line_width = 2.0
        self._show_room()
        sc, cam = ctl.scene, ctl.scene.camera
        ext = np.eye(4)
        ext[:3, :3], ext[:3, 3] = cam.R, cam.t
        bbox = o3d.geometry.AxisAlignedBoundingBox(sc.room_min, sc.room_max)
        self.scene3d.setup_camera(cam.K, ext, cam.width, cam.height, bbox)
        self.scene3d.scene.add_geometry("camera", frustum_lines(ctl), self._mat_line)

        ctl.on_change = self._on_pose_change
        if ctl.pose.mesh is not None:
            self._select_choice(ctl.pose.mesh)
            self._show_pose(ctl.pose)
            self._show_object()
        self._start_precompute()
        threading.Thread(target=self._render_loop, name="photoar-render", daemon=True).start()

    # ------------------------------------------------------------------ layout
    def _fit_size(self, tab_h: int | None = None) -> tuple[int, int]:
        """default_window_size for this window's frames (the working camera's size) on this screen; tab_h: the tab
        bar's height as laid out (None: TAB_BAR_EM of Open3D's theme font, before the window exists)."""
        cam = self.ctl.scene.camera
        win = getattr(self, "window", None)
        scaling = win.scaling if win is not None else 1.0
        if tab_h is None:
            em = win.theme.font_size if win is not None else 16
            tab_h = int(round(TAB_BAR_EM * em))
        return default_window_size(cam.width, cam.height, int(PANEL_W * scaling), tab_h, screen_size())

    def _check_fit(self) -> None:
        """Once the Photo tab is laid out, resize a default-sized window whose tab bar is not the one assumed, so
        that the frames show 1:1 (one resize at most; none if the window was resized meanwhile)."""
        img, tabs = self.image.frame, self.tabs.frame
        if img.height <= 0:
            return
        self._fit_pending = False
        size = self._fit_size(tab_h=img.y - tabs.y)
        now = (self.window.size.width, self.window.size.height)
        if now == tuple(self._fit_set) and now != size:
            self.window.size = self.gui.Size(*size)

    def _on_layout(self, ctx) -> None:
        if self._bench_handed:  # Open3D lays the window out inside its draw: the frames handed over are drawn now
            self._bench_drawn.extend(self._bench_handed)
            self._bench_handed.clear()
        r = self.window.content_rect
        pw = int(PANEL_W * self.window.scaling)
        self.tabs.frame = self.gui.Rect(r.x, r.y, r.width - pw, r.height)
        self.panel.frame = self.gui.Rect(r.get_right() - pw, r.y, pw, r.height)

    def pixel_to_window(self, u: float, v: float) -> tuple[float, float]:
        """Photo pixel (u, v) -> window coordinates (image_to_pixel's inverse)."""
        f = self.image.frame
        cam = self.ctl.scene.camera
        s, ox, oy = image_fit(f.width, f.height, cam.width, cam.height)
        return f.x + ox + (u + 0.5) * s, f.y + oy + (v + 0.5) * s

    def image_to_pixel(self, x: float, y: float) -> tuple[float, float] | None:
        """Window coordinates -> photo pixel (u, v) (None outside the photo)."""
        f = self.image.frame
        cam = self.ctl.scene.camera
        s, ox, oy = image_fit(f.width, f.height, cam.width, cam.height)
        u = (x - f.x - ox) / s - 0.5
        v = (y - f.y - oy) / s - 0.5
        if not (-0.5 <= u <= cam.width - 0.5 and -0.5 <= v <= cam.height - 0.5):
            return None
        return u, v

    # ------------------------------------------------------------------ workers
    def _precompute(self) -> None:
        try:
            eng = self.ctl.start_engine(progress=self._on_precompute_progress)
            if eng is not self.ctl.engine:  # the lighting changed meanwhile: its own precompute follows
                return
            self.ctl.prepare_drag()  # the drag frame's stages now, not on the first drag
            msg = (f"precompute {eng.precompute_s:.1f} s" + (" (cached)" if eng.cache_hit else "")
                   + f", {eng.pre.patches.n_patches} patches")
        except Exception as e:  # noqa: BLE001 - shown in the window, and ends a headless run
            log.exception("precompute failed")
            self.error = f"precompute failed: {e}"
            self.app.post_to_main_thread(self.window, lambda: setattr(self.status, "text", self.error))
            return

        def done():
            self.status.text = msg
            self.progress.value = 1.0
            self._show_room()
            self.window.set_needs_layout()

        self.app.post_to_main_thread(self.window, done)
        self.engine_ready.set()
        self.request_frame()

    def _on_precompute_progress(self, done: int, total: int) -> None:
        self._pre_fraction = done / max(total, 1)  # read by _on_tick on the main thread

    def _start_precompute(self) -> None:
        self.engine_ready.clear()
        self._pre_t0, self._pre_fraction = time.perf_counter(), None
        threading.Thread(target=self._precompute, name="photoar-precompute", daemon=True).start()

    def request_frame(self) -> None:
        with self._render_cv:
            self._dirty = True
            self._render_cv.notify()

    def _overtaken(self, pose: Pose) -> bool:
        """Abandon the frame of `pose` under way? The window closed, or an edit replaced the pose and the
        pointer has rested: a tick of the event loop ended STILL_S after the last edit and another ended after it
        with no edit since (REST_TWO_TICKS; else the first of them is enough)."""
        tick = self._tick_prev if REST_TWO_TICKS else self._tick_t
        return self.closed or (pose != self.ctl.pose and tick - self._edit_t >= STILL_S)

    def _render_loop(self) -> None:
        abandoned = False  # the last frame was abandoned: this one is finished (every other frame at least shows)
        while not self.closed:
            with self._render_cv:
                while not self._dirty and not self.closed:
                    self._render_cv.wait(0.5)
                self._dirty = False
            if self.closed or not self.engine_ready.is_set():
                continue
            if self._script is not None and not self._script():
                continue
            pose = self.ctl.pose
            stop = None if abandoned or self._script is not None else functools.partial(self._overtaken, pose)
            try:
                fr = self.ctl.render(pose, stop=stop)
            except Exception as e:  # noqa: BLE001 - an engine error must not kill the window
                if self.closed:  # the window closed mid-frame: the engine's worker pool is gone, nothing to report
                    return
                log.exception("frame failed")
                self.error = f"frame failed: {e}"
                self.app.post_to_main_thread(self.window, lambda: setattr(self.status, "text", self.error))
                continue
            abandoned = fr is None
            if abandoned:  # overtaken: the edit that replaced its pose asked for the next frame (request_frame)
                continue
            if not fr.stats["cached"]:
                self.frame_times.append(fr.stats["frame_s"])
            self.app.post_to_main_thread(self.window, lambda fr=fr, pose=pose: self._show_frame(fr, pose))
            if not fr.stats.get("converged") and self._script is None:
                self._refine_at_rest(pose)

    def _refine_at_rest(self, pose: Pose) -> None:
        """While `pose` is the current one and no edit is waiting, add sources a slice at a time;
        show each frame at rest as it is complete (Engine.refine's intermediate frames, then the
        all-sources frame)."""
        def edited() -> bool:  # the next edit or a press ends it between any two of its steps; none starts while
            # the button is held (the pose is not at rest: the next move comes; the release asks for the refinement)
            return self.closed or self._dirty or self._dragging or pose != self.ctl.pose

        while not edited():
            try:
                fr = self.ctl.refine(pose, budget_s=REFINE_SLICE_S, intermediate=True, stop=edited)
            except Exception as e:  # noqa: BLE001 - an engine error must not kill the window
                if self.closed:  # the window closed mid-slice: the engine's worker pool is gone, nothing to report
                    return
                log.exception("refinement failed")
                self.error = f"refinement failed: {e}"
                return
            if fr is not None:
                self.refined_frames += 1
                self.app.post_to_main_thread(self.window, lambda fr=fr, pose=pose: self._show_frame(fr, pose))
                if fr.stats["converged"]:
                    return

    # ------------------------------------------------------------------ showing
    def _show_frame(self, fr, pose: Pose) -> None:
        self.last_frame = fr
        if pose == self.ctl.pose:
            self._set_image(fr.pixels)
        else:  # an edit arrived meanwhile: show this frame with the newer outline until its own
            self._set_image(outline_preview(fr.pixels, self.ctl, self.ctl.pose))
        if self._preview_due:  # the newest pose's label and 3D object go with this redraw: no preview due
            self._preview_due, self._preview_t = False, time.perf_counter()
            self._show_pose(self.ctl.pose)
            self._show_object()
        st = fr.stats
        kept = " (kept)" if st["cached"] else ""
        self.frame_label.text = (f"frame: {st['frame_s'] * 1000:.0f} ms{kept}"
                                 + (f", engine {st['engine_s']:.2f} s" if st.get("engine_s") else ""))
        budget = "all" if st.get("budget") is None else st["budget"]
        self.pass_label.text = f"passes: {st['passes']} (budget {budget}), {st['mode'].upper()}"
        self.frames_shown += 1
        if self._bench_handed is not None:  # --drag-bench: the next draw shows it (_on_layout marks it drawn)
            self._bench_handed.append(pose)
            self.window.set_needs_layout()
        self.window.post_redraw()

    def _set_image(self, pixels: np.ndarray) -> None:
        self.image.update_image(self.o3d.geometry.Image(np.ascontiguousarray(pixels)))
        self.window.post_redraw()

    def _show_room(self) -> None:
        s = self.scene3d.scene
        if s.has_geometry("room"):
            s.remove_geometry("room")
        s.add_geometry("room", room_mesh(self.ctl), self._mat_room)

    def _on_tab(self, index: int) -> None:
        if index == 1 and self._object_stale:
            self._show_object()

    def _show_object(self) -> None:
        """The placed object in the 3D view; only while the 3D tab is shown (a hidden view is not drawn, and each
        upload costs the main thread and the renderer: the next selection of the tab shows the pose then)."""
        self._object_stale = SKIP_HIDDEN_3D and self.tabs.selected_tab_index != 1
        if self._object_stale:
            return
        o3d = self.o3d
        s = self.scene3d.scene
        if s.has_geometry("object"):
            s.remove_geometry("object")
        obj = self.ctl.scene_object()
        if obj is None:
            return
        m = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(obj.vertices), o3d.utility.Vector3iVector(obj.faces))
        m.vertex_normals = o3d.utility.Vector3dVector(obj.normals)
        m.paint_uniform_color(np.clip(obj.albedo, 0, 1))
        s.add_geometry("object", m, self._mat_obj)

    def _show_pose(self, p: Pose) -> None:
        self.pose_label.text = (f"pose: ({p.position[0]:.2f}, {p.position[1]:.2f}, {p.position[2]:.2f}) m\n"
                                f"yaw {p.yaw_deg:.0f} deg, lift {p.lift * 100:.0f} cm, scale {p.scale:.2f}"
                                + ("\nWARNING: inside furniture" if self.ctl.collides(p) else ""))

    def _on_pose_change(self, pose: Pose) -> None:
        """Controller callback (main thread: edits come from widget events)."""
        self._edit_t = time.perf_counter()
        self.request_frame()
        self._preview_due = True
        self._preview()

    def _preview(self) -> bool:
        """Show the newest pose (the pose label, the 3D view's object, its outline over the last frame) when
        it is due, the last preview is at least PREVIEW_INTERVAL_S old and the button is not held (DRAG_PREVIEWS;
        else _on_tick or the next frame shows it); returns whether it did. The three go with one redraw."""
        now = time.perf_counter()
        if not self._preview_due or now - self._preview_t < PREVIEW_INTERVAL_S:
            return False
        if self._dragging and not DRAG_PREVIEWS:
            return False
        self._preview_due, self._preview_t = False, now
        pose = self.ctl.pose
        self._show_pose(pose)
        self._show_object()
        if self.last_frame is not None:
            self._set_image(outline_preview(self.last_frame.pixels, self.ctl, pose))
        return True

    def _on_tick(self) -> bool:
        self._tick_prev, self._tick_t = self._tick_t, time.perf_counter()
        if self._fit_pending:
            self._check_fit()
        if self._preview():
            return True
        if not self.engine_ready.is_set() and self.error is None:
            t = time.perf_counter() - self._pre_t0
            f = self._pre_fraction
            self.progress.value = f if f is not None else 1.0 - math.exp(-t / 30.0)  # cached: no steps reported
            self.status.text = f"precomputing the scene ({self.ctl.lighting} light) ... {t:.0f} s"
            return True
        return False

    def _on_close(self) -> bool:
        self.closed = True
        with self._render_cv:
            self._render_cv.notify()
        return True

    # ------------------------------------------------------------------ input
    def _guard(self, fn, *args) -> None:
        try:
            fn(*args)
        except ValueError as e:
            self.status.text = str(e)

    def _on_image_mouse(self, e):
        gui = self.gui
        if self.ctl.pose.mesh is None and self.choices:
            self._guard(self.ctl.set_object, self.choices[0], self.object_size)
        t = e.type
        if t == gui.MouseEvent.Type.BUTTON_DOWN and e.is_button_down(gui.MouseButton.LEFT):
            uv = self.image_to_pixel(e.x, e.y)
            if uv is not None:
                self.ctl.begin_gesture()
                self._guard(self.ctl.place_at_pixel, *uv)
                self._dragging = True
            return gui.Widget.EventCallbackResult.CONSUMED
        if t == gui.MouseEvent.Type.DRAG and self._dragging:
            uv = self.image_to_pixel(e.x, e.y)
            if uv is not None:
                self._guard(self.ctl.move_to_pixel, *uv)
            return gui.Widget.EventCallbackResult.CONSUMED
        if t == gui.MouseEvent.Type.BUTTON_UP and self._dragging:
            self._dragging = False
            self.ctl.end_gesture()
            self.request_frame()  # at rest now: the render loop shows the pose's kept frame and refines it
            return gui.Widget.EventCallbackResult.CONSUMED
        return gui.Widget.EventCallbackResult.IGNORED

    def _on_key(self, e) -> bool:
        gui, ctl = self.gui, self.ctl
        if e.type != gui.KeyEvent.Type.DOWN or ctl.pose.mesh is None:
            return False
        K = gui.KeyName
        actions = {K.Q: (ctl.rotate, -ROTATE_STEP), K.E: (ctl.rotate, ROTATE_STEP),
                   K.R: (ctl.lift_by, LIFT_STEP), K.F: (ctl.lift_by, -LIFT_STEP),
                   K.EQUALS: (ctl.scale_by, SCALE_STEP), K.PLUS: (ctl.scale_by, SCALE_STEP),
                   K.MINUS: (ctl.scale_by, 1 / SCALE_STEP),
                   K.LEFT: (ctl.move_by, -MOVE_STEP, 0.0), K.RIGHT: (ctl.move_by, MOVE_STEP, 0.0),
                   K.UP: (ctl.move_by, 0.0, -MOVE_STEP), K.DOWN: (ctl.move_by, 0.0, MOVE_STEP)}
        if e.key == K.Z:
            ctl.undo()
            return True
        if e.key == K.Y:
            ctl.redo()
            return True
        if e.key in actions:
            fn, *args = actions[e.key]
            self._guard(fn, *args)
            return True
        return False

    def _select_choice(self, path: str) -> None:
        if path not in self.choices:
            self.choices.append(path)
            self.picker.add_item(Path(path).name)
        self.picker.selected_index = self.choices.index(path)

    def _on_pick_object(self, text: str, index: int) -> None:
        self._guard(self.ctl.set_object, self.choices[index], self.object_size)

    def _on_open_mesh(self) -> None:
        gui = self.gui
        dlg = gui.FileDialog(gui.FileDialog.OPEN, "Open an object mesh", self.window.theme)
        dlg.add_filter(".ply .obj .glb .gltf .off .stl", "meshes")
        dlg.set_on_cancel(self.window.close_dialog)

        def done(path: str) -> None:
            self.window.close_dialog()
            self._guard(self._set_mesh, path)

        dlg.set_on_done(done)
        self.window.show_dialog(dlg)

    def _set_mesh(self, path: str) -> None:
        self.ctl.set_object(path, self.object_size)
        self._select_choice(self.ctl.pose.mesh)

    def _on_passes(self, value: float) -> None:
        if not self.all_sources.checked:
            self.ctl.set_budget(int(value))
            self.request_frame()

    def _on_all_sources(self, checked: bool) -> None:
        self.ctl.set_budget(None if checked else int(self.slider.int_value))
        self.request_frame()

    def _on_mode(self, index: int) -> None:
        self.ctl.set_budget(mode="ldr" if index == 1 else "hdr")
        self.request_frame()

    def _on_lighting(self, text: str, index: int) -> None:
        if text == self.ctl.lighting:
            return
        self.engine_ready.clear()  # frames wait for the new engine
        self.ctl.set_lighting(text)  # another precompute (cached per lighting)
        self._start_precompute()

    def _on_undo(self) -> None:
        self.ctl.undo()

    def _on_redo(self) -> None:
        self.ctl.redo()

    def _file_dialog(self, mode, title: str, then: Callable[[str], None]) -> None:
        gui = self.gui
        dlg = gui.FileDialog(mode, title, self.window.theme)
        dlg.add_filter(".json", "placements")
        dlg.set_on_cancel(self.window.close_dialog)

        def done(path: str) -> None:
            self.window.close_dialog()
            try:
                then(path)
            except (ValueError, OSError) as e:
                self.status.text = str(e)

        dlg.set_on_done(done)
        self.window.show_dialog(dlg)

    def _on_save(self) -> None:
        self._file_dialog(self.gui.FileDialog.SAVE, "Save placement",
                          lambda p: setattr(self.status, "text", f"saved {self.ctl.save(p)}"))

    def _on_load(self) -> None:
        def load(p: str) -> None:
            self.ctl.load(p)
            if self.ctl.pose.mesh is not None:
                self._select_choice(self.ctl.pose.mesh)

        self._file_dialog(self.gui.FileDialog.OPEN, "Load placement", load)

    # ------------------------------------------------------------------ scripted runs
    def screenshot(self) -> np.ndarray:
        """RGB (H,W,3) uint8 of the window as it is on the X display."""
        f = self.window.os_frame
        return grab_screen(f.x, f.y, f.width, f.height)

    def settled_screenshot(self, timeout_s: float = 20.0) -> np.ndarray:
        """screenshot() once the display has caught up with the window: redraws until three grabs
        in a row agree, after at least SETTLE_TICKS redraws (the renderer presents through a
        swapchain of several images, so the display can lag the last drawn frame by a few draws;
        a fixed number of redraws made the headless screenshot miss the last frame now and then)."""
        t0, prev, same, ticks = time.perf_counter(), None, 0, 0
        while time.perf_counter() - t0 < timeout_s:
            self.window.post_redraw()
            self.app.run_one_tick()
            time.sleep(0.02)
            ticks += 1
            if ticks < SETTLE_TICKS:
                continue
            shot = self.screenshot()
            same = same + 1 if prev is not None and np.array_equal(shot, prev) else 0
            if same >= 2:
                return shot
            prev = shot
        return self.screenshot()

    def run_frames(self, n: int, timeout_s: float = 600.0) -> None:
        """Headless mode: wait for the precompute, composite the current pose `n` times (each by
        the engine, no kept frames), show the last one and let the window draw it."""
        remaining = [n]

        def script() -> bool:
            if remaining[0] <= 0:
                return False
            remaining[0] -= 1
            self.ctl.clear_frames()
            if remaining[0] > 0:
                self.request_frame()
            return True

        self._script = script
        t0 = time.perf_counter()
        target = self.frames_shown + n
        self.request_frame()
        while self.app.run_one_tick():
            if self.error is not None:
                raise RuntimeError(f"{self.ctl.scene.root}: {self.error}")
            if self.frames_shown >= target:
                break
            if time.perf_counter() - t0 > timeout_s:
                raise RuntimeError(f"{self.ctl.scene.root}: no frame after {timeout_s:.0f} s")
            time.sleep(0.005)
        self._script = None
        for _ in range(10):  # let the window draw the last image
            self.window.post_redraw()
            self.app.run_one_tick()
            time.sleep(0.02)


    def run_drag_bench(self, n: int, interval_s: float = 1 / 60, timeout_s: float = 600.0) -> dict:
        """Headless drag benchmark (`photoar gui --drag-bench N`): once the engine is ready and the
        object's first frame is on screen, press the mouse on the object's footprint, play n DRAG events
        through the window's own handler (_on_image_mouse), one every interval_s (a 60 Hz mouse) with the
        event loop running between them, along the straight drag of app.dragpath projected to the photo;
        wait for the last pose's frame, release. Each event's latency runs from the moment the event is
        handed to the window (before its handler: the handler's own work is part of the latency) to the end
        of the event loop's tick that drew the first frame of its pose or a later one (the render loop drops the
        poses it had no time for: it renders the newest). Open3D runs the functions posted to the main thread
        (_show_frame: the image updated, a redraw posted) after the tick's draw, so that frame is drawn in a later
        tick, the one whose draw lays the window out (_on_layout). Returns drag_latencies' figures."""
        from app.dragpath import drag_offsets

        T = self.gui.MouseEvent.Type
        t0 = time.perf_counter()

        shown: list[tuple[float, Pose]] = []

        def tick() -> None:  # the frames drawn in this tick are on screen once it returns
            self.app.run_one_tick()
            if self._bench_drawn:
                now = time.perf_counter()
                shown.extend((now, p) for p in self._bench_drawn)
                self._bench_drawn.clear()

        def spin_until(cond, what: str) -> None:
            while not cond():
                if self.error is not None:
                    raise RuntimeError(f"{self.ctl.scene.root}: {self.error}")
                if time.perf_counter() - t0 > timeout_s:
                    raise RuntimeError(f"{self.ctl.scene.root}: --drag-bench: no {what} after {timeout_s:.0f} s")
                tick()
                time.sleep(0.002)

        spin_until(lambda: self.engine_ready.is_set() and self.frames_shown > 0, "first frame")
        obj = self.ctl.scene_object()
        if obj is None:
            raise ValueError(f"{self.ctl.scene.root}: --drag-bench needs an object (scene.json's or --object)")
        lo, hi = obj.vertices.min(0), obj.vertices.max(0)
        pivot = np.array([(lo[0] + hi[0]) / 2, lo[1], (lo[2] + hi[2]) / 2])
        uv, _ = self.ctl.scene.camera.project(pivot + drag_offsets(self.ctl.scene, obj, n + 1))
        self._on_image_mouse(_ScriptMouse(T.BUTTON_DOWN, *self.pixel_to_window(*uv[0])))
        self._bench_handed, self._bench_drawn = [], []
        events: list[tuple[float, Pose]] = []
        for k in range(1, n + 1):
            t_ev = time.perf_counter()
            next_t = t_ev + interval_s
            self._on_image_mouse(_ScriptMouse(T.DRAG, *self.pixel_to_window(*uv[k])))
            events.append((t_ev, self.ctl.pose))
            while time.perf_counter() < next_t:
                tick()
                time.sleep(0.001)
        last = events[-1][1]
        spin_until(lambda: any(p == last for _, p in shown), "frame of the last pose")
        self._bench_handed = None
        self._on_image_mouse(_ScriptMouse(T.BUTTON_UP, *self.pixel_to_window(*uv[n])))
        self.bench_timeline = (events, shown)  # for bench/bench_gui_drag.py's breakdown
        return drag_latencies(events, shown)


def drag_latencies(events: list[tuple[float, object]], shown: list[tuple[float, object]]) -> dict:
    """The --drag-bench figures from events (time s, pose made) in order and frames shown (time s, pose):
    an event's latency is the time to the first frame shown after it of its pose or a later event's
    (a pose is matched to the last event that made it); events with no such frame are left out of the
    mean and p95 (run_drag_bench waits for the last pose's frame: there are none). {"events",
    "event_to_screen_ms_mean", "event_to_screen_ms_p95", "frames_shown": frames shown from the first
    event on}."""
    index = {p: i for i, (_, p) in enumerate(events)}
    lat = []
    for i, (t, _) in enumerate(events):
        after = [ts - t for ts, p in shown if ts >= t and index.get(p, -1) >= i]
        if after:
            lat.append(1e3 * min(after))
    lat_a = np.array(lat) if lat else np.full(1, np.nan)
    return {"events": len(events), "event_to_screen_ms_mean": float(lat_a.mean()),
            "event_to_screen_ms_p95": float(np.percentile(lat_a, 95)),
            "frames_shown": sum(1 for ts, _ in shown if ts >= events[0][0]) if events else 0}


# ---------------------------------------------------------------------------- model mode
class _ScriptMouse:
    """A mouse event of a script (`photoar gui --model --script`), shaped like gui.MouseEvent for
    ModelWindow._on_image_mouse: type, x, y (window coordinates), is_button_down."""

    def __init__(self, type_, x: float, y: float):
        self.type, self.x, self.y = type_, x, y

    def is_button_down(self, button) -> bool:
        import open3d.visualization.gui as gui

        return button == gui.MouseButton.LEFT


class ModelWindow:
    """`photoar gui ROOM --model`: click the room's model on the photo. A thin view over
    app.clickmodeller.ModelController: the photo with the model drawn over it (left), the tools,
    the wall a window/lamp lies on, the opening toggle, undo/redo and save (right).

    Mouse on the photo: a press adds the tool's next point, or, near a clicked point, grabs it
    (drag to move it, release to drop). A corner out of the photo is skipped (button, or N) with
    the sizes typed or the wall the piece stands against chosen. Keys: Z undo, Y redo, S save."""

    def __init__(self, ctl, out: Path, title: str = "photoar - model", width: int = 1280, height: int = 720):
        import open3d.visualization.gui as gui

        from app.clickmodeller import TOOLS
        from recon.io import open3d

        self.o3d, self.gui, self.ctl, self.out = open3d(), gui, ctl, Path(out)
        self.app = gui.Application.instance
        self.closed = False
        self.saved: Path | None = None
        w = self.window = self.app.create_window(title, width, height)
        em = w.theme.font_size
        self.image = gui.ImageWidget(self.o3d.geometry.Image(np.ascontiguousarray(ctl.photo)))
        self.image.set_on_mouse(self._on_image_mouse)
        w.add_child(self.image)
        p = self.panel = gui.Vert(0.4 * em, gui.Margins(0.6 * em, 0.6 * em, 0.6 * em, 0.6 * em))
        p.add_child(gui.Label("Tool"))
        self.tools = gui.RadioButton(gui.RadioButton.VERT)
        self.tools.set_items(list(TOOLS))
        self.tools.set_on_selection_changed(self._on_tool)
        p.add_child(self.tools)
        p.add_fixed(1.5 * em)  # the vertical radio list is taller than its layout height
        p.add_child(gui.Label("Window / lamp on"))
        self.on = gui.Combobox()
        self.on.set_on_selection_changed(self._on_quad_on)
        p.add_child(self.on)
        self.opening = gui.Checkbox("opening (a hole in the wall)")
        self.opening.set_on_checked(self._on_opening)
        p.add_child(self.opening)
        p.add_child(gui.Label("Furniture stands on"))
        self.stands_on = gui.Combobox()
        self.stands_on.set_on_selection_changed(self._on_stands_on)
        p.add_child(self.stands_on)
        p.add_child(gui.Label("Corners out of the photo: sizes (m), against"))
        row = gui.Horiz(0.4 * em)
        self.size = gui.TextEdit()
        self.size.placeholder_text = "a, b"
        self.size.set_on_value_changed(self._on_size)
        row.add_child(self.size)
        self.against = gui.Combobox()
        self.against.set_on_selection_changed(self._on_against)
        row.add_child(self.against)
        p.add_child(row)
        p.add_child(gui.Label("Taped size the status asks for: piece, k, metres"))
        self.tape = gui.TextEdit()
        self.tape.placeholder_text = "sofa_seat 0 0.9"
        self.tape.set_on_value_changed(self._on_tape)
        p.add_child(self.tape)
        b_skip = gui.Button("Corner out of photo (N)")
        b_skip.set_on_clicked(self._on_skip)
        p.add_child(b_skip)
        row = gui.Horiz(0.4 * em)
        for text, fn in (("Undo", self._on_undo), ("Redo", self._on_redo), ("Save", self._on_save)):
            b = gui.Button(text)
            b.set_on_clicked(fn)
            row.add_child(b)
        p.add_child(row)
        self.status = gui.Label("")
        p.add_child(self.status)
        p.add_child(gui.Label("press: next point / grab one\ndrag: move it  N corner out of photo\n"
                              "H corner hidden behind a piece\n"
                              "Z undo  Y redo  S save"))
        w.add_child(p)
        w.set_on_layout(self._on_layout)
        w.set_on_key(self._on_key)
        w.set_on_close(self._on_close)
        self.refresh()

    # ------------------------------------------------------------------ view
    def _on_layout(self, ctx) -> None:
        r = self.window.content_rect
        pw = int(PANEL_W * self.window.scaling)
        self.image.frame = self.gui.Rect(r.x, r.y, r.width - pw, r.height)
        self.panel.frame = self.gui.Rect(r.get_right() - pw, r.y, pw, r.height)

    def image_to_pixel(self, x: float, y: float) -> tuple[float, float] | None:
        """Window coordinates -> photo pixel (u, v) (None outside the photo)."""
        f, cam = self.image.frame, self.ctl.camera
        s, ox, oy = image_fit(f.width, f.height, cam.width, cam.height)
        u, v = (x - f.x - ox) / s - 0.5, (y - f.y - oy) / s - 0.5
        return (u, v) if self.ctl.inside(u, v) else None

    def pixel_to_window(self, u: float, v: float) -> tuple[float, float]:
        """Photo pixel (u, v) -> window coordinates (the inverse of image_to_pixel)."""
        f, cam = self.image.frame, self.ctl.camera
        s, ox, oy = image_fit(f.width, f.height, cam.width, cam.height)
        return f.x + ox + (u + 0.5) * s, f.y + oy + (v + 0.5) * s

    def refresh(self) -> None:
        """Redraw the photo with the model and update the panel from the controller."""
        self.image.update_image(self.o3d.geometry.Image(np.ascontiguousarray(self.ctl.overlay())))
        names = ["last wall"] + self.ctl.walls() + ["ceiling"]
        self.on.clear_items()
        for n in names:
            self.on.add_item(n)
        self.on.selected_text = self.ctl.quad_on or "last wall"
        self.against.clear_items()
        for n in ["no wall"] + self.ctl.walls():
            self.against.add_item(n)
        self.against.selected_text = self.ctl.against or "no wall"
        self.stands_on.clear_items()
        for n in ["floor"] + self.ctl.pieces():
            self.stands_on.add_item(n)
        self.stands_on.selected_text = self.ctl.stands_on or "floor"
        from app.clickmodeller import NEEDS, TOOLS

        self.tools.selected_index = TOOLS.index(self.ctl.tool)
        self.status.text = (f"{self.ctl.tool}: point {len(self.ctl.pending) + 1} of {NEEDS[self.ctl.tool]}\n"
                            f"{len(self.ctl.clicks)} clicked\n{self.ctl.message}")
        self.window.post_redraw()

    # ------------------------------------------------------------------ input
    def _guard(self, fn, *args):
        try:
            return fn(*args)
        except ValueError as e:
            self.status.text = str(e)
            return None

    def _on_image_mouse(self, e):
        gui = self.gui
        t = e.type
        if t == gui.MouseEvent.Type.BUTTON_DOWN and e.is_button_down(gui.MouseButton.LEFT):
            uv = self.image_to_pixel(e.x, e.y)
            if uv is not None and not self.ctl.grab(*uv):
                self._guard(self.ctl.click, *uv)
            self.refresh()
            return gui.Widget.EventCallbackResult.CONSUMED
        if t == gui.MouseEvent.Type.DRAG and self.ctl.dragging:
            uv = self.image_to_pixel(e.x, e.y)
            if uv is not None:
                self.ctl.drag_to(*uv)
                self.refresh()
            return gui.Widget.EventCallbackResult.CONSUMED
        if t == gui.MouseEvent.Type.BUTTON_UP and self.ctl.dragging:
            self.ctl.release()
            self.refresh()
            return gui.Widget.EventCallbackResult.CONSUMED
        return gui.Widget.EventCallbackResult.IGNORED

    def _on_key(self, e) -> bool:
        gui = self.gui
        if e.type != gui.KeyEvent.Type.DOWN:
            return False
        actions = {gui.KeyName.Z: self._on_undo, gui.KeyName.Y: self._on_redo, gui.KeyName.S: self._on_save,
                   gui.KeyName.N: self._on_skip, gui.KeyName.H: self._on_skip_hidden}
        if e.key in actions:
            actions[e.key]()
            return True
        return False

    def _on_tool(self, index: int) -> None:
        from app.clickmodeller import TOOLS

        self.ctl.set_tool(TOOLS[index])
        self.refresh()

    def _on_quad_on(self, text: str, index: int) -> None:
        self.ctl.quad_on = None if text == "last wall" else text

    def _on_opening(self, checked: bool) -> None:
        self.ctl.opening = bool(checked)

    def _on_size(self, text: str) -> None:
        try:
            v = [float(x) for x in text.replace("x", ",").split(",") if x.strip()]
        except ValueError:
            v = []
        ok = len(v) == 2 and all(math.isfinite(x) and x > 0 for x in v)
        self.ctl.size_m = v if ok else None
        if text.strip() and not ok:
            self.status.text = f"sizes: expected two positive numbers in metres, got {text!r}"

    def _on_tape(self, text: str) -> None:
        """"PIECE K METRES": the piece's size_m[K], taped (ModelController.set_size)."""
        parts = text.replace(",", " ").split()
        try:
            name, k, metres = parts[0], int(parts[1]), float(parts[2])
            if len(parts) != 3:
                raise ValueError
        except (IndexError, ValueError):
            if text.strip():
                self.status.text = f"taped size: expected 'piece k metres' (e.g. sofa_seat 0 0.9), got {text!r}"
            return
        try:
            self.ctl.set_size(name, k, metres)
        except ValueError as e:
            self.status.text = str(e)
            return
        self.refresh()

    def _on_against(self, text: str, index: int) -> None:
        self.ctl.against = None if text == "no wall" else text

    def _on_stands_on(self, text: str, index: int) -> None:
        self.ctl.stands_on = None if text == "floor" else text

    def _on_skip(self) -> None:
        self._guard(self.ctl.skip_corner)
        self.refresh()

    def _on_skip_hidden(self) -> None:
        """A furniture floor corner in the photo but behind a piece: null, listed in "hidden"."""
        self._guard(self.ctl.skip_corner, True)
        self.refresh()

    def _on_undo(self) -> None:
        self.ctl.undo()
        self.refresh()

    def _on_redo(self) -> None:
        self.ctl.redo()
        self.refresh()

    def _on_save(self) -> None:
        from recon.io import SceneError

        try:
            self.ctl.save(self.out)
        except SceneError as e:
            self.status.text = f"not saved: {e}"
            return
        self.saved = self.out
        self.status.text = f"saved {self.out / 'primitives.json'}"
        log.info("saved %s and %s", self.out / "clicks.json", self.out / "primitives.json")

    def _on_close(self) -> bool:
        self.closed = True
        return True

    # ------------------------------------------------------------------ scripted runs
    def screenshot(self) -> np.ndarray:
        """RGB (H,W,3) uint8 of the window as it is on the X display, after SETTLE_TICKS redraws (the
        display lags the last drawn frame by a few)."""
        for _ in range(SETTLE_TICKS):
            self.window.post_redraw()
            self.app.run_one_tick()
            time.sleep(0.02)
        f = self.window.os_frame
        return grab_screen(f.x, f.y, f.width, f.height)

    def run_script(self, events: list[dict], ticks: int = 3) -> None:
        """Headless mode: play `events` through the window's own handlers, each after a few turns of
        the event loop (so layout and redraws happen as they would for a user). Events:
        {"tool": name}, {"on": wall name | "ceiling" | "last wall"}, {"opening": bool},
        {"size_m": "a, b"}, {"against": wall name | "no wall"}, {"stands_on": piece name | "floor"},
        {"skip": true} (a corner out of the photo), {"hidden": true} (a floor corner behind a piece), {"tape": "piece k metres"} (a taped size_m[k]), {"click": [u, v]} (photo pixels: press and release there), {"drag": [[u0, v0], [u1, v1]]}
        (press on a clicked point, move, release), {"undo": n}, {"redo": n}, {"save": true}."""
        gui = self.gui
        from app.clickmodeller import TOOLS

        def spin() -> None:
            for _ in range(ticks):
                self.window.post_redraw()
                self.app.run_one_tick()
                time.sleep(0.01)

        def mouse(kind, u, v) -> None:
            x, y = self.pixel_to_window(u, v)
            self._on_image_mouse(_ScriptMouse(kind, x, y))
            spin()

        spin()
        T = gui.MouseEvent.Type
        for ev in events:
            if "tool" in ev:
                self.tools.selected_index = TOOLS.index(ev["tool"])
                self._on_tool(TOOLS.index(ev["tool"]))
            elif "on" in ev:
                self.on.selected_text = ev["on"]
                self._on_quad_on(ev["on"], 0)
            elif "opening" in ev:
                self.opening.checked = bool(ev["opening"])
                self._on_opening(bool(ev["opening"]))
            elif "size_m" in ev:
                self.size.text_value = str(ev["size_m"])
                self._on_size(str(ev["size_m"]))
            elif "against" in ev:
                self.against.selected_text = ev["against"]
                self._on_against(ev["against"], 0)
            elif "stands_on" in ev:
                self.stands_on.selected_text = ev["stands_on"]
                self._on_stands_on(ev["stands_on"], 0)
            elif ev.get("skip"):
                self._on_skip()
            elif ev.get("hidden"):
                self._on_skip_hidden()
            elif "tape" in ev:
                self.tape.text_value = str(ev["tape"])
                self._on_tape(str(ev["tape"]))
            elif "click" in ev:
                mouse(T.BUTTON_DOWN, *ev["click"])
                mouse(T.BUTTON_UP, *ev["click"])
            elif "drag" in ev:
                (u0, v0), (u1, v1) = ev["drag"]
                mouse(T.BUTTON_DOWN, u0, v0)
                for s in (0.5, 1.0):
                    mouse(T.DRAG, u0 + s * (u1 - u0), v0 + s * (v1 - v0))
                mouse(T.BUTTON_UP, u1, v1)
            elif "undo" in ev:
                for _ in range(int(ev["undo"])):
                    self._on_undo()
            elif "redo" in ev:
                for _ in range(int(ev["redo"])):
                    self._on_redo()
            elif ev.get("save"):
                self._on_save()
            else:
                raise ValueError(f"script event {ev!r}: expected tool, on, opening, size_m, against, stands_on, skip, "
                                 "click, drag, undo, redo or save")
            spin()
