"""A/B in ONE process (gui48b, not kept): Mesa's llvmpipe threads at nice 0 against nice 10, drag by drag.

    ROUNDS=7 xvfb-run -a python -m bench.bench_gui_llvmpipe_nice

Opens the window on window_room as `photoar gui` does (bench_gui_drag's setup, no refinement at rest), then per
round one 60-move drag (bench_gui_drag.trace_drag) with the llvmpipe threads at nice 0 and one at nice 10
(setpriority on their thread ids; going back to 0 needs root or RLIMIT_NICE). Prints the bench's figures, the render
thread's frame, llvmpipe CPU and the latency breakdown per drag.
"""
import os, sys, time
from pathlib import Path
import open3d.visualization.gui as gui
from app.cli import build_parser
from app.cmd_gui import controller
from app.gui import PlacementWindow
import bench.bench_gui_drag as B
ctl = controller(build_parser().parse_args(["-q", "gui", str(Path(os.environ.get("PHOTOAR_SHARED", "/work/shared")) / "scenes/window_room")]))
choices = ctl.object_choices([Path(ctl.pose.mesh).parent] if ctl.pose.mesh else [])
app = gui.Application.instance; app.initialize()
win = PlacementWindow(ctl, choices, title="bench", width=1280, height=720)
win._refine_at_rest = lambda pose: None
B.settle(win, 0, 120)
def lp_tids():
    return [int(tid) for tid, name in B.threads_cpu() if name.startswith("llvmpipe")]
def setnice(v):
    for t in lp_tids(): os.setpriority(os.PRIO_PROCESS, t, v)
start = ctl.pose
rows = {"base": [], "nice10": []}
for rnd in range(int(os.environ.get("ROUNDS", "4"))):
    for name, v in (("base", 0), ("nice10", 10)):
        setnice(v)
        while ctl.pose != start and ctl.undo(): pass
        ctl.clear_frames(); s0 = win.frames_shown; win.request_frame(); B.settle(win, s0, 120)
        r = B.trace_drag(win, 60); c = r["cpu_s"]
        print(f"{name:7s} r{rnd}: mean/p95 {r['event_to_screen_ms_mean']:.0f}/{r['event_to_screen_ms_p95']:.0f} shown {r['frames_shown']} render {r['render_ms_mean']} "
              f"llvmpipe {c.get('llvmpipe',0):.2f} s | {r['breakdown_ms']} load {r['load']}", flush=True)
setnice(0)
win.closed = True; win.window.close(); app.run_one_tick()
