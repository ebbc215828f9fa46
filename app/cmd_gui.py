"""`photoar gui`: the interactive placement window (app/gui.py over app/placement.py).

  photoar gui SCENE_DIR [--object MESH] [--place X,Y,Z --screenshot PNG --frames N]
  photoar gui ROOM --model [--photo PHOTO --camera camera.json] [--clicks clicks.json] [--out DIR]

SCENE_DIR is a benchmark scene folder (../shared/scenes/FORMAT.md) or a placement JSON saved
from the window. With --screenshot (or --frames) the window opens, applies the placement,
composites N frames, saves a screenshot of itself and exits: the headless-testable mode (run it
under Xvfb: `xvfb-run -a photoar gui ...`).

With --model the window models the room instead (app/gui.py ModelWindow over
app/clickmodeller.py): click walls, the ceiling, furniture, windows and lamps on the photo, and Save
writes DIR/clicks.json and DIR/primitives.json exactly as `photoar model --clicks --image` does (DIR
defaults to ROOM/model). The photo and camera are ROOM's scene.json and background.png, or
--photo/--camera (a calibrated photo before any room folder exists). --script EVENTS.json plays
mouse events through the window and exits (the headless mode; ModelWindow.run_script).
"""
from __future__ import annotations

import argparse
import logging
import os
from pathlib import Path

import numpy as np

from app.cli import add_object_args
from app.config import DRAG_PASSES, DRAG_PASSES_NO_SUN, DRAG_SCALE
from kernels.quiet import native_output_held

log = logging.getLogger("photoar")


def _positive_int(s: str) -> int:
    v = int(s)
    if v < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {v}")
    return v


def _size(s: str) -> tuple[int, int]:
    try:
        w, h = (int(x) for x in s.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT, got {s!r}") from None
    if w < 320 or h < 240:
        raise argparse.ArgumentTypeError(f"window must be at least 320x240, got {s!r}")
    return w, h


def register(sub) -> None:
    g = sub.add_parser("gui", help="interactive placement window (Open3D): click to place, drag to move",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    g.add_argument("scene", type=Path, help="scene folder, or a placement JSON saved from the window")
    add_object_args(g)
    g.add_argument("--passes", type=_positive_int, default=DRAG_PASSES,
                   help="shadow passes per frame while the object moves (default %(default)s, the drag frame's; at most "
                        f"{DRAG_PASSES_NO_SUN} in a room no sun lights; the window's slider changes it); at rest the "
                        "window shows a finer frame, then the all-sources frame (Engine.refine)")
    g.add_argument("--drag-scale", type=_positive_int, default=DRAG_SCALE, metavar="S",
                   help="frames while the object moves compute the room's change at 1/S resolution each way and "
                        "the object at full (app.dragframe; default %(default)s); 1: the whole frame at full "
                        "resolution")
    g.add_argument("--all-sources", action="store_true", help="one shadow pass per source (slow)")
    g.add_argument("--mode", choices=["hdr", "ldr"], default="hdr", help="compositing path (default %(default)s)")
    g.add_argument("--screenshot", type=Path, default=None,
                   help="after the frames, save a PNG of the window and exit")
    g.add_argument("--frames", type=_positive_int, default=None,
                   help="composite this many frames of the placement, then exit (default 1 with --screenshot)")
    g.add_argument("--drag-bench", type=_positive_int, default=None, metavar="N",
                   help="script a drag of N mouse moves through the window's event loop (one each 1/60 s), then "
                        "print one JSON line: events, event_to_screen_ms_mean, event_to_screen_ms_p95, "
                        "frames_shown; and exit (run it under xvfb-run)")
    g.add_argument("--window", type=_size, default=None, metavar="WxH",
                   help="window size (default: the photo at its own pixel size beside the panel, scaled down to fit "
                        "the screen; the window stays resizable)")
    g.add_argument("--cache", type=Path, default=None,
                   help="folder for per-scene precompute (default $PHOTOAR_CACHE or ~/.cache/photoar)")
    from app.cli import add_lighting_arg, add_sun_arg

    add_lighting_arg(g)
    add_sun_arg(g)
    g.add_argument("--device", default=None, help="Warp device, e.g. cpu or cuda:0 (default cpu)")
    g.add_argument("--work-res", type=int, default=1024, metavar="PX",
                   help="preview and drag at most PX pixels on the photo's long side (default %(default)s; 0: the "
                        "photo's own); `photoar composite --placement` writes the full resolution")
    m = g.add_argument_group("model mode (--model)")
    m.add_argument("--model", action="store_true", help="model the room by clicking on the photo")
    m.add_argument("--photo", type=Path, default=None, help="the photo (default ROOM/background.png)")
    m.add_argument("--camera", type=Path, default=None,
                   help="camera.json from `photoar calibrate` (default ROOM/scene.json's main_camera)")
    m.add_argument("--clicks", type=Path, default=None, help="start from these clicks (a saved clicks.json)")
    m.add_argument("--ceiling-height", type=float, default=None,
                   help="the ceiling's height (m) when no click gives it (as `photoar model`)")
    m.add_argument("--out", type=Path, default=None, help="where Save writes clicks.json and primitives.json "
                   "(default ROOM/model)")
    m.add_argument("--script", type=Path, default=None,
                   help="EVENTS.json: play these mouse events through the window, then exit (headless tests)")
    g.set_defaults(run=run)


def run_model(a: argparse.Namespace) -> int:
    """`photoar gui ROOM --model`: the model window (app/gui.py ModelWindow)."""
    from app.clickmodeller import ModelController
    from recon.camera import Camera
    from recon.clickmodel import load_clicks
    from recon.io import read_image_rgb, read_json

    room = Path(a.scene)
    photo_path = a.photo or room / "background.png"
    camera = Camera.load(a.camera or room / "scene.json")
    photo = read_image_rgb(photo_path)
    if photo.shape[:2] != (camera.height, camera.width):
        raise ValueError(f"{photo_path}: image is {photo.shape[1]}x{photo.shape[0]}, the camera says "
                         f"{camera.width}x{camera.height}")
    clicks = load_clicks(a.clicks) if a.clicks is not None else None
    events = None
    if a.script is not None:
        d = read_json(a.script)
        events = d.get("events") if isinstance(d, dict) else None
        if not isinstance(events, list):
            raise ValueError(f"{a.script}: expected {{\"events\": [...]}}")
    out = a.out or room / "model"
    ctl = ModelController(camera, photo, clicks, str(out / "clicks.json"), a.ceiling_height)

    import open3d.visualization.gui as gui

    from app.gui import ModelWindow

    app = gui.Application.instance
    app.initialize()
    width, height = a.window or (1280, 720)  # the model window keeps 1280x720 by default
    win = ModelWindow(ctl, out, title=f"photoar - model {room.name}", width=width, height=height)
    if events is None:
        app.run()
        return 0
    win.run_script(events)
    if a.screenshot is not None:
        from recon.io import write_png

        write_png(a.screenshot, win.screenshot())
    win.closed = True
    win.window.close()
    app.run_one_tick()
    if any(ev.get("save") for ev in events) and win.saved is None:
        raise ValueError(f"{a.script}: the model was not saved: {ctl.message or win.status.text}")
    return 0


def run(a: argparse.Namespace) -> int:
    if not os.environ.get("DISPLAY"):
        raise RuntimeError("photoar gui: no X display (DISPLAY is not set); run it under Xvfb, "
                           "e.g. `xvfb-run -a photoar gui SCENE_DIR --screenshot shot.png`")
    if a.model:
        return run_model(a)
    for opt in ("photo", "camera", "clicks", "ceiling_height", "out", "script"):
        if getattr(a, opt) is not None:
            raise ValueError(f"--{opt.replace('_', '-')}: only with --model")
    if a.object_size is not None and not a.object_size > 0:
        raise ValueError(f"{a.object}: --object-size must be positive, got {a.object_size}")
    ctl = controller(a)
    choices = ctl.object_choices([Path(ctl.pose.mesh).parent] if ctl.pose.mesh else [])

    # Filament and Vulkan print their start-up lines from C++ (8 on a Mesa machine): held back,
    # shown after a failure or with -v.
    with native_output_held(show=bool(getattr(a, "verbose", False))):
        return _show(a, ctl, choices)


def controller(a: argparse.Namespace):
    """The window's PlacementController of the parsed `gui` arguments `a` (no window, no engine yet): frames
    while the object moves are drag frames at 1/--drag-scale (--all-sources, --drag-scale 1: full size), the
    frames of --frames / --screenshot (a pose at rest) full size; the object at its pose."""
    from app.composite import default_cache_dir
    from app.engine import EngineParams
    from app.placement import PlacementController

    params = EngineParams(passes=None if a.all_sources else a.passes, mode=a.mode, lighting=a.lighting,
                          sun=a.sun)
    # frames while the object moves are drag frames; --frames / --screenshot composite a pose at rest (full size)
    still = a.frames is not None or a.screenshot is not None
    ctl = PlacementController.open(a.scene, params=params, cache_dir=a.cache or default_cache_dir(),
                                   quiet=a.quiet, work_res=a.work_res,
                                   drag=a.drag_scale if a.drag_scale > 1 and not still else None)
    ctl.device = a.device
    mesh = a.object
    if mesh is None and ctl.pose.mesh is None:
        if ctl.scene.obj is None:
            raise ValueError(f"{ctl.scene.root / 'scene.json'}: no synthetic_object; give --object MESH")
        mesh = Path(ctl.scene.obj.source)
    if mesh is not None:
        ctl.set_object(mesh, a.object_size, a.object_albedo)
    if a.place is not None:
        ctl.place_at(a.place)
        if a.yaw:
            ctl.rotate(a.yaw)
    return ctl


def _show(a: argparse.Namespace, ctl, choices) -> int:
    """Open the window; run it (interactive) or render --frames and take the --screenshot."""
    import open3d.visualization.gui as gui

    from app.gui import PlacementWindow
    from recon.io import write_png

    app = gui.Application.instance
    app.initialize()
    width, height = a.window or (None, None)
    win = PlacementWindow(ctl, choices, title=f"photoar - {ctl.scene.name}", width=width, height=height,
                          object_size=a.object_size)
    if a.drag_bench is not None:
        import json

        res = win.run_drag_bench(a.drag_bench)
        print(json.dumps(res))
        win.closed = True
        win.window.close()
        app.run_one_tick()
        return 0
    n = a.frames or (1 if a.screenshot is not None else None)
    if n is None:
        app.run()
        return 0
    win.run_frames(n)
    times = win.frame_times
    log.info("%d frames, %.2f s mean per frame (passes %s, %s)", len(times), float(np.mean(times)) if times else 0.0,
             win.last_frame.stats.get("passes") if win.last_frame else "-", ctl.config.mode)
    if a.screenshot is not None:
        shot = win.settled_screenshot()
        write_png(a.screenshot, shot)  # atomic
        print(a.screenshot)
    win.closed = True
    win.window.close()
    app.run_one_tick()
    return 0
