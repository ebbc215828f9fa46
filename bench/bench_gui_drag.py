"""Where the GUI's drag latency goes (`photoar gui --drag-bench`), and A/B of the window's variants in ONE process.

Run under Xvfb:
    xvfb-run -a python -m bench.bench_gui_drag /work/shared/scenes/window_room --n 60 --rounds 3 \
        --variants base,new

Opens the PlacementWindow as `photoar gui ROOM` does, then runs PlacementWindow.run_drag_bench --rounds times per
variant, the variants interleaved (base, new, base, new, ...); between two drags the object goes back to its start
(undo), the kept frames are dropped (every drag frame is computed) and the refinement at rest is let finish.
A variant is a set of the window's switches (VARIANTS below). Each drag is traced by wrappers around
PlacementController.render, PlacementWindow._show_frame / _preview / _on_image_mouse and the event loop's
run_one_tick, and each event's latency (the bench's own figure) is split into:
  wait    from the event (before its handler) to the start of the render of the frame that showed it
  frame   that render (PlacementController.render, wall)
  handoff from the render's end to the start of _show_frame on the main thread (post_to_main_thread)
  show    _show_frame itself (the image upload to the ImageWidget, labels)
  tick    from _show_frame's end to the end of the event loop's tick that ran it (what the bench measured up to
          gui48: Open3D runs posted functions after the tick's draw, so the frame is not drawn yet)
  draw    from the end of that tick to the end of the tick that drew the frame (the bench's end since gui48)
Per-thread CPU (/proc/self/task) over each drag: the render thread, the main thread, Mesa's llvmpipe threads.
Prints one JSON line per drag and a summary table per variant.
"""
from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np


def threads_cpu() -> dict[tuple[str, str], float]:
    """CPU seconds (user + system) per (thread id, thread name) of this process (/proc/self/task/*/stat)."""
    tick = os.sysconf("SC_CLK_TCK")
    out = {}
    for tid in os.listdir("/proc/self/task"):
        try:
            with open(f"/proc/self/task/{tid}/stat") as f:
                s = f.read()
        except OSError:
            continue
        fields = s[s.rindex(")") + 2:].split()
        out[(tid, s[s.index("(") + 1:s.rindex(")")])] = (int(fields[11]) + int(fields[12])) / tick
    return out


def _thread_cpu() -> dict[str, float]:
    """CPU seconds (user + system) per thread group of this process: render, main, llvmpipe, other."""
    out: dict[str, float] = {}
    main = str(os.getpid())
    for (tid, name), cpu in threads_cpu().items():
        if tid == main:
            key = "main"
        elif name.startswith("photoar-render"):
            key = "render"
        elif name.startswith("llvmpipe"):
            key = "llvmpipe"
            out["llvmpipe_threads"] = out.get("llvmpipe_threads", 0) + 1
        else:
            key = "other"
        out[key] = out.get(key, 0.0) + cpu
    return out


def _by_name() -> dict[str, float]:
    """CPU seconds per thread name of this process (threads of one name summed: Python's and the engine's workers
    are all "python", Mesa's "llvmpipe-0", "llvmpipe-1" stay apart)."""
    out: dict[str, float] = {}
    for (_, name), cpu in threads_cpu().items():
        out[name] = out.get(name, 0.0) + cpu
    return out


class _AppProxy:
    """gui.Application.instance with run_one_tick timed (the window's `app`)."""

    def __init__(self, app, ticks: list):
        self._app, self._ticks = app, ticks

    def run_one_tick(self):
        t0 = time.perf_counter()
        r = self._app.run_one_tick()
        self._ticks.append((t0, time.perf_counter()))
        return r

    def __getattr__(self, name):
        return getattr(self._app, name)


def _name_render_thread() -> None:
    """Name the render thread for /proc (Python's thread name is not the OS's)."""
    import ctypes

    libc = ctypes.CDLL(None)
    libc.prctl(15, b"photoar-render", 0, 0, 0)  # PR_SET_NAME


def trace_drag(win, n: int) -> dict:
    """One run_drag_bench of n moves with the trace; returns its JSON figures, the breakdown and CPU."""
    ctl = win.ctl
    renders, shows, events, ticks, previews = [], [], [], [], []
    named = [False]
    orig_render, orig_show, orig_mouse, orig_preview = ctl.render, win._show_frame, win._on_image_mouse, win._preview

    def render(pose=None, stop=None):
        if not named[0]:
            _name_render_thread()
            named[0] = True
        t0 = time.perf_counter()
        fr = orig_render(pose, stop=stop)
        renders.append((t0, time.perf_counter(), pose, fr is None))
        return fr

    def show(fr, pose):
        t0 = time.perf_counter()
        orig_show(fr, pose)
        shows.append((t0, time.perf_counter(), pose))

    def mouse(e):
        t0 = time.perf_counter()
        r = orig_mouse(e)
        events.append((t0, time.perf_counter(), ctl.pose))
        return r

    def preview():
        t0 = time.perf_counter()
        r = orig_preview()
        if r:
            previews.append((t0, time.perf_counter()))
        return r

    app = win.app
    ctl.render, win._show_frame, win._on_image_mouse, win._preview = render, show, mouse, preview
    win.app = _AppProxy(app, ticks)
    named0, cpu0, w0 = _by_name(), _thread_cpu(), time.perf_counter()
    try:
        res = win.run_drag_bench(n)
    finally:
        ctl.render, win._show_frame = orig_render, orig_show
        win._on_image_mouse, win._preview = orig_mouse, orig_preview
        win.app = app
    wall = time.perf_counter() - w0
    cpu1 = _thread_cpu()
    cpu = {k: round(cpu1.get(k, 0.0) - cpu0.get(k, 0.0), 3) for k in cpu1 if k != "llvmpipe_threads"}
    cpu["llvmpipe_threads"] = cpu1.get("llvmpipe_threads", 0)
    named1 = _by_name()
    cpu["by_name"] = {k: round(v - named0.get(k, 0.0), 3) for k, v in named1.items() if v - named0.get(k, 0.0) >= 0.005}

    # the drag's moves only (the press is events[0], the release the last)
    moves = events[1:-1]
    t_first = moves[0][0]
    index = {}
    for i, (_, _, p) in enumerate(moves):
        index[p] = i
    _, drawn = win.bench_timeline
    parts = {k: [] for k in ("wait", "frame", "handoff", "show", "tick", "draw", "total")}
    for i, (te, _, _) in enumerate(moves):
        cand = [s for s in shows if s[0] >= te and index.get(s[2], -1) >= i]
        if not cand:
            continue
        s0, s1, sp = min(cand, key=lambda s: s[0])
        r = [r for r in renders if r[2] == sp and not r[3] and r[1] <= s0]
        if not r:
            continue
        r0, r1, _, _ = max(r, key=lambda r: r[1])
        tk = [t for t in ticks if t[0] <= s0 <= t[1]]
        tend = tk[0][1] if tk else s1
        parts["wait"].append(r0 - te)
        parts["frame"].append(r1 - r0)
        parts["handoff"].append(s0 - r1)
        parts["show"].append(s1 - s0)
        dr = [t for t, p in drawn if p == sp and t >= s1]
        dend = min(dr) if dr else tend
        parts["tick"].append(tend - s1)
        parts["draw"].append(dend - tend)
        parts["total"].append(dend - te)
    drag_renders = [r for r in renders if r[0] >= t_first]
    tick_d = [t1 - t0 for t0, t1 in ticks if t0 >= t_first]
    return {**res, "wall_s": round(wall, 2), "load": round(os.getloadavg()[0], 2),
            "breakdown_ms": {k: round(1e3 * float(np.mean(v)), 1) if v else None for k, v in parts.items()},
            "frames_rendered": sum(1 for r in drag_renders if not r[3]),
            "frames_abandoned": sum(1 for r in drag_renders if r[3]),
            # of those, abandoned before the last move (the pointer taken for at rest mid-drag: a frame lost)
            "abandoned_mid_drag": sum(1 for r in drag_renders if r[3] and r[1] < moves[-1][0]),
            "render_ms_mean": round(1e3 * float(np.mean([r[1] - r[0] for r in drag_renders if not r[3]])), 1)
            if drag_renders else None,
            "previews": len(previews),
            "preview_ms_mean": round(1e3 * float(np.mean([b - a for a, b in previews])), 2) if previews else None,
            "tick_ms_mean": round(1e3 * float(np.mean(tick_d)), 2) if tick_d else None,
            "tick_ms_max": round(1e3 * float(np.max(tick_d)), 1) if tick_d else None,
            "cpu_s": cpu}


# A variant: attributes of app.gui (module constants) set before its drags, and "size": the window's size (WxH px;
# "fit": PlacementWindow's default, the frames 1:1 beside the panel), set before its drags.
VARIANTS: dict[str, dict] = {
    "base": {"DRAG_PREVIEWS": True, "SKIP_HIDDEN_3D": False},  # main's window (gui37): previews at 20 Hz in drags
    "new": {"DRAG_PREVIEWS": False, "SKIP_HIDDEN_3D": True},  # gui48's: drawn once per frame while dragging
    "w1280": {"size": (1280, 720)},  # main's default window (gui48's), the 640x480 photo scaled up 1.45x
    "fit": {"size": "fit"},  # gui36's default window: the photo 1:1 beside the panel (940x502 for 640x480)
    "rest1": {"size": "fit", "REST_TWO_TICKS": False},  # main's rest rule: one tick STILL_S after the last edit
}


def apply_variant(win, name: str, base_state: dict) -> None:
    import app.gui as g

    for k, v in base_state.items():
        setattr(g, k, v)
    for k, v in VARIANTS[name].items():
        if k == "size":
            laid_out = win.image.frame.height > 0  # before the first layout: the size the window opened with
            size = (win._fit_size(tab_h=win.image.frame.y - win.tabs.frame.y) if laid_out else win._fit_set) \
                if v == "fit" else v
            if (win.window.size.width, win.window.size.height) != tuple(size):
                win.window.size = win.gui.Size(*size)
        else:
            setattr(g, k, v)


def settle(win, shown0: int, timeout_s: float = 120.0) -> None:
    """Run the event loop until a frame after the shown0-th is on screen and the render thread has nothing to do
    (its refinement at rest finished or not run: --refine), or timeout_s; then one more second of ticks."""
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < timeout_s:
        win.app.run_one_tick()
        time.sleep(0.01)
        lf = win.last_frame
        if win.frames_shown > shown0 and not win._dirty and (lf.stats.get("converged") or not REFINE[0]):
            break
    t1 = time.perf_counter()
    while time.perf_counter() - t1 < 1.0:
        win.app.run_one_tick()
        time.sleep(0.01)


REFINE = [False]


def redraw_costs(win, k: int) -> None:
    """CPU and wall of one window redraw at rest, per kind of update (k of each, interleaved): `none` (two ticks, no
    redraw posted), `redraw` (post_redraw only), `image` (the last frame re-uploaded to the ImageWidget), `outline`
    (outline_preview over the last frame, uploaded), `object` (the 3D view's object re-uploaded), `label` (the pose
    label), `preview` (PlacementWindow._preview: label, object and outline). Each step: the update, post_redraw, two
    ticks (a redraw posted in one tick is drawn in the next). Prints ms per step."""
    import app.gui as g

    pose = win.ctl.pose
    px = win.last_frame.pixels
    acts = {
        "none": lambda: None,
        "redraw": lambda: win.window.post_redraw(),
        "image": lambda: win._set_image(px),
        "outline": lambda: win._set_image(g.outline_preview(px, win.ctl, pose)),
        "object": lambda: (win._show_object(), win.window.post_redraw()),
        "label": lambda: (win._show_pose(pose), win.window.post_redraw()),
        "preview": lambda: (setattr(win, "_preview_due", True), setattr(win, "_preview_t", -1e9), win._preview()),
    }
    acc = {n: {"wall": 0.0, "main": 0.0, "llvmpipe": 0.0, "other": 0.0, "render": 0.0} for n in acts}
    for _ in range(k):
        for n, f in acts.items():
            c0, t0 = _thread_cpu(), time.perf_counter()
            f()
            win.app.run_one_tick()
            win.app.run_one_tick()
            t1, c1 = time.perf_counter(), _thread_cpu()
            acc[n]["wall"] += t1 - t0
            for key in ("main", "llvmpipe", "other", "render"):
                acc[n][key] += c1.get(key, 0.0) - c0.get(key, 0.0)
            time.sleep(0.02)
    print(f"redraw costs, ms per step (mean of {k}; load {os.getloadavg()[0]:.1f}): wall / CPU main / llvmpipe / other")
    for n, a in acc.items():
        print(f"{n:8s} {1e3 * a['wall'] / k:7.1f} / {1e3 * a['main'] / k:6.1f} / {1e3 * a['llvmpipe'] / k:6.1f} / "
              f"{1e3 * a['other'] / k:6.1f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scene", type=Path)
    ap.add_argument("--n", type=int, default=60)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--variants", default="base")
    ap.add_argument("--redraw", type=int, default=0, metavar="K",
                    help="instead of drags: redraw_costs with K steps of each kind (at rest, after the refinement)")
    ap.add_argument("--refine", action="store_true",
                    help="let the window refine each rest (full-size frames, tens of seconds loaded) before the next "
                         "drag; default: no refinement at rest in this process (each drag starts with an idle render "
                         "thread either way)")
    ap.add_argument("--settle-s", type=float, default=60.0, help="at most this long for the refinement between drags")
    a = ap.parse_args()

    import open3d.visualization.gui as gui

    from app.cli import build_parser
    from app.cmd_gui import controller
    from app.gui import PlacementWindow
    import app.gui as g

    args = build_parser().parse_args(["-q", "gui", str(a.scene)])
    ctl = controller(args)
    choices = ctl.object_choices([Path(ctl.pose.mesh).parent] if ctl.pose.mesh else [])
    app = gui.Application.instance
    app.initialize()
    win = PlacementWindow(ctl, choices, title="bench")  # photoar gui's default size (a variant's "size" sets it)
    REFINE[0] = a.refine
    if not a.refine:
        win._refine_at_rest = lambda pose: None
    names = a.variants.split(",")
    base_state = {k: getattr(g, k) for nm in names for k in VARIANTS[nm] if k != "size"}
    rows: dict[str, list] = {nm: [] for nm in names}
    if a.redraw:
        settle(win, 0, a.settle_s)
        redraw_costs(win, a.redraw)
        a.rounds = 0
    start_pose = None
    for rnd in range(a.rounds):
        for nm in names:
            apply_variant(win, nm, base_state)
            if start_pose is not None:
                while ctl.pose != start_pose and ctl.undo():
                    pass
            ctl.clear_frames()
            shown0 = win.frames_shown
            win.request_frame()
            settle(win, shown0, a.settle_s)
            if start_pose is None:
                start_pose = ctl.pose
            r = trace_drag(win, a.n)
            r["variant"], r["round"] = nm, rnd
            r["window"] = f"{win.window.size.width}x{win.window.size.height}"
            rows[nm].append(r)
            print(json.dumps(r), flush=True)
    apply_variant(win, names[0], base_state)
    print("variant | mean / p95 ms | frames shown | wait / frame / handoff / show / tick / draw ms | render ms | "
          "cpu render / main / llvmpipe / other s")
    for nm in names:
        for r in rows[nm]:
            b, c = r["breakdown_ms"], r["cpu_s"]
            print(f"{nm} | {r['event_to_screen_ms_mean']:.0f} / {r['event_to_screen_ms_p95']:.0f} | "
                  f"{r['frames_shown']} | "
                  f"{b['wait']} / {b['frame']} / {b['handoff']} / {b['show']} / {b['tick']} / {b['draw']} | "
                  f"{r['render_ms_mean']} | "
                  f"{c.get('render', 0):.2f} / {c.get('main', 0):.2f} / {c.get('llvmpipe', 0):.2f} / "
                  f"{c.get('other', 0):.2f} (load {r['load']}, {r['window']})")
    win.closed = True
    win.window.close()
    app.run_one_tick()


if __name__ == "__main__":
    main()
