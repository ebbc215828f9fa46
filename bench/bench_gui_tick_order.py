"""Where Open3D's Application.run_one_tick calls a window's tick callback relative to its draw (app/gui.py's
REST_TWO_TICKS). Run under Xvfb:  xvfb-run -a python -m bench.bench_gui_tick_order
A bare 320x240 window whose layout callback (run inside the draw) sleeps 80 ms; four ticks that each draw; prints,
per tick, ms from the tick's start to the draw's start and to the tick callback, and the tick's end. Open3D 0.20:
the callback comes after the draw, at the tick's end (81-116 ms into a tick whose draw took 80 ms).
"""
import time, numpy as np
import open3d as o3d
import open3d.visualization.gui as gui
app = gui.Application.instance
app.initialize()
w = app.create_window("order", 320, 240)
iw = gui.ImageWidget(o3d.geometry.Image(np.zeros((48, 64, 3), np.uint8)))
w.add_child(iw)
log = []
def layout(ctx):
    log.append(("draw-start", time.perf_counter()))
    time.sleep(0.08)  # a draw held up 80 ms
    iw.frame = w.content_rect
def on_tick():
    log.append(("tick-callback", time.perf_counter()))
    return False
w.set_on_layout(layout)
w.set_on_tick_event(on_tick)
for _ in range(20):
    app.run_one_tick()
for k in range(4):
    log.clear()
    w.set_needs_layout(); w.post_redraw()
    t0 = time.perf_counter()
    app.run_one_tick()
    t1 = time.perf_counter()
    print([(n, round(1e3 * (t - t0), 1)) for n, t in log], "tick ends", round(1e3 * (t1 - t0), 1), flush=True)
    time.sleep(0.03)
w.close(); app.run_one_tick()
import os  # noqa: E402

os._exit(0)  # Open3D's exit can hang with its threads running
