"""Where Mesa's llvmpipe CPU goes in `photoar gui` (gui48b): idle ticks, window redraws and drags, per thread.

Run under Xvfb:
    xvfb-run -a python -m bench.bench_gui_redraw /work/shared/scenes/window_room --rounds 2 --drags 3

Opens the PlacementWindow as `photoar gui` does (bench.bench_gui_drag's setup, no refinement at rest), then, in ONE
process, variants interleaved per round:
  1. 3 s of the event loop with nothing posted (`idle`), and with a redraw posted 5 times a second (`redraw`), each
     with the 3D view as it is, with SceneWidget.enable_scene_caching(True), and with the SceneWidget hidden:
     CPU ms per second by thread name (/proc/self/task/*/stat);
  2. llvmpipe CPU per redraw of: the placement window, a bare 1280x720 window with only an ImageWidget of the
     photo, the same with a TabControl holding the ImageWidget and an empty SceneWidget, and a bare 640x360 window;
  3. drags (bench_gui_drag.trace_drag, 60 moves): the bench's figures, the number of window draws (each tick asks
     for a layout, which Open3D runs only inside a draw: a count of draws; part 1's idle row checks that asking for
     a layout does not draw by itself) and llvmpipe CPU per drag and per draw.
"""
from __future__ import annotations

import argparse
import collections
import os
import time
from pathlib import Path

import numpy as np

from bench.bench_gui_drag import threads_cpu


def _by_name(c0: dict, c1: dict) -> collections.Counter:
    agg: collections.Counter = collections.Counter()
    for k, v in c1.items():
        agg[k[1]] += v - c0.get(k, 0.0)
    return agg


def run_loop(app, secs: float, post=None, every: float = 0.2) -> tuple[collections.Counter, float, int]:
    """Tick the event loop for secs (1 ms sleeps, as run_drag_bench's loop); post() every `every` s when given.
    Returns (CPU s by thread name, wall s, posts)."""
    c0, t0, last, k = threads_cpu(), time.perf_counter(), -1e9, 0
    while time.perf_counter() - t0 < secs:
        if post is not None and time.perf_counter() - last >= every:
            last = time.perf_counter()
            post()
            k += 1
        app.run_one_tick()
        time.sleep(0.001)
    return _by_name(c0, threads_cpu()), time.perf_counter() - t0, k


def _top(agg: collections.Counter, div: float) -> str:
    return ", ".join(f"{n} {1e3 * v / div:.0f}" for n, v in agg.most_common(5) if v > 0.0005)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scene", type=Path)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--drags", type=int, default=3)
    ap.add_argument("--n", type=int, default=60)
    a = ap.parse_args()

    import open3d.visualization.gui as gui
    import open3d.visualization.rendering as rendering

    import bench.bench_gui_drag as B
    from app.cli import build_parser
    from app.cmd_gui import controller
    from app.gui import PlacementWindow
    from recon.io import open3d

    o3d = open3d()
    ctl = controller(build_parser().parse_args(["-q", "gui", str(a.scene)]))
    choices = ctl.object_choices([Path(ctl.pose.mesh).parent] if ctl.pose.mesh else [])
    app = gui.Application.instance
    app.initialize()
    win = PlacementWindow(ctl, choices, title="bench", width=1280, height=720)
    win._refine_at_rest = lambda pose: None
    B.settle(win, 0, 120.0)
    draws = [0]
    layout = win._on_layout

    def counted_layout(ctx) -> None:
        draws[0] += 1
        layout(ctx)

    win.window.set_on_layout(counted_layout)
    img = o3d.geometry.Image(np.ascontiguousarray(ctl.scene.photo))
    bare = app.create_window("bare", 1280, 720)
    bare.add_child(gui.ImageWidget(img))
    tabbed = app.create_window("tabs", 1280, 720)
    tabs = gui.TabControl()
    tabs.add_tab("Photo", gui.ImageWidget(img))
    sw = gui.SceneWidget()
    sw.scene = rendering.Open3DScene(tabbed.renderer)
    tabs.add_tab("3D", sw)
    tabbed.add_child(tabs)
    small = app.create_window("small", 640, 360)
    small.add_child(gui.ImageWidget(img))
    run_loop(app, 1.0)

    def redraw_placement() -> None:
        win.window.set_needs_layout()
        win.window.post_redraw()

    sc = win.scene3d
    states = {"as is": lambda: (sc.enable_scene_caching(False), setattr(sc, "visible", True)),
              "scene caching": lambda: (sc.enable_scene_caching(True), setattr(sc, "visible", True)),
              "SceneWidget hidden": lambda: (sc.enable_scene_caching(False), setattr(sc, "visible", False))}
    print(f"1. CPU ms per second by thread, 3 s each (llvmpipe threads: Mesa's, {os.cpu_count()} cores)")
    for rnd in range(a.rounds):
        for name, setup in states.items():
            setup()
            for kind, post in (("idle", None), ("redraw 5/s", redraw_placement)):
                d0 = draws[0]
                agg, wall, _ = run_loop(app, 3.0, post)
                print(f"  {kind:10s} {name:18s} draws {draws[0] - d0:2d} | {_top(agg, wall)} "
                      f"(load {os.getloadavg()[0]:.1f})", flush=True)
    states["as is"]()
    print("2. CPU ms per redraw by thread (a redraw posted 5 times a second for 3 s)")
    targets = {"placement window 1280x720": redraw_placement, "bare ImageWidget 1280x720": bare.post_redraw,
               "tabs + SceneWidget 1280x720": tabbed.post_redraw, "bare ImageWidget 640x360": small.post_redraw}
    for rnd in range(a.rounds):
        for name, post in targets.items():
            agg, _, k = run_loop(app, 3.0, post)
            print(f"  {name:28s} | {_top(agg, k)} (load {os.getloadavg()[0]:.1f})", flush=True)
    for w in (bare, tabbed, small):
        w.close()
    run_loop(app, 0.5)

    class _CountingApp:  # each tick asks for a layout: Open3D runs it only inside a draw, so _on_layout counts draws
        def __init__(self, app):
            self._app = app

        def run_one_tick(self):
            win.window.set_needs_layout()
            return self._app.run_one_tick()

        def __getattr__(self, name):
            return getattr(self._app, name)

    print(f"3. drags of {a.n} moves (the first warms up)")
    start = ctl.pose
    win.app = _CountingApp(app)
    d0 = draws[0]
    agg, wall, _ = run_loop(win.app, 2.0)
    print(f"  idle, a layout asked each tick: draws {draws[0] - d0}, llvmpipe {1e3 * sum(v for n, v in agg.items() if n.startswith('llvmpipe')):.0f} ms")
    for i in range(a.drags):
        while ctl.pose != start and ctl.undo():
            pass
        ctl.clear_frames()
        s0 = win.frames_shown
        win.request_frame()
        B.settle(win, s0, 120.0)
        d0 = draws[0]
        r = B.trace_drag(win, a.n)
        c, nd = r["cpu_s"], draws[0] - d0
        print(f"  drag {i}: mean / p95 {r['event_to_screen_ms_mean']:.0f} / {r['event_to_screen_ms_p95']:.0f} ms, "
              f"{r['frames_shown']} frames shown, {nd} draws, render {r['render_ms_mean']} ms, wall {r['wall_s']} s | "
              f"CPU s render {c.get('render', 0):.2f} main {c.get('main', 0):.2f} llvmpipe {c.get('llvmpipe', 0):.2f} "
              f"({1e3 * c.get('llvmpipe', 0) / max(nd, 1):.0f} ms a draw) other {c.get('other', 0):.2f} | "
              f"{r['breakdown_ms']} (load {r['load']})", flush=True)
    win.app = app
    win.closed = True
    win.window.close()
    app.run_one_tick()


if __name__ == "__main__":
    main()
