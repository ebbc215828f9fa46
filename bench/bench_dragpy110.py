"""Drag-frame glue A/B of dragpy110 (issue 36 item 3, "little orchestration"): bench_drag36b's per-room interleaved
run (process CPU per frame and per stage, the rendering thread's glue `stages_ms["python"]`, the drag row at the
scene's own pose and its SHA-256) with this branch's glue levers switched off one at a time.

usage: python bench/bench_dragpy110.py --scenes window_room,lamps_room,sun_room --variants base,noview [--path 10]
                                       [--rounds 2] [--cpu-glue]
       python bench/bench_dragpy110.py --upload-micro
       python bench/bench_dragpy110.py --profile SCENE   (cProfile of warm drag frames on the thread's CPU time)

--cpu-glue: app.glue's FrameTimer on the rendering thread's CPU time (time.thread_time), not wall: stats["python"]
and the per-stage glue are then the thread's CPU outside Warp kernels (the loaded machine's waits left out).

Variants:
  noview   kernels.buffers.VIEW_CACHE 0: every Workspace.upload makes a new Warp view of its buffer's leading
           block (wp.array.__getitem__), as before dragpy110
"""
from __future__ import annotations

import contextlib
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_drag36b as b36  # noqa: E402


@contextlib.contextmanager
def _module_attr(module, name: str, value):
    """module.name = value while the block runs."""
    old = getattr(module, name)
    setattr(module, name, value)
    try:
        yield
    finally:
        setattr(module, name, old)


def _noview(eng):
    from kernels import buffers

    return _module_attr(buffers, "VIEW_CACHE", 0)


b36.VARIANTS.update({
    "noview": (b36._cfg(), _noview),
})

_THREAD: dict[str, list[float]] = {}  # variant -> the rendering thread's CPU seconds per drag frame
_GLUE: dict[str, list[dict]] = {}  # variant -> each drag frame's stats["glue"] (s per stage)
_current: list[str] = [""]


class _ThreadClock:
    """app.glue's `time` with perf_counter = thread_time: FrameTimer's stages, its glue and stats["python"] in the
    rendering thread's CPU seconds (kernels launched from it count as kernel time, the pool's are not its CPU)."""

    def __getattr__(self, name):
        import time

        return time.thread_time if name == "perf_counter" else getattr(time, name)


def _named(name: str, factory):
    @contextlib.contextmanager
    def ctx(eng):
        _current[0] = name
        with factory(eng):
            yield
        _current[0] = ""
    return ctx


def _thread_cpu() -> None:
    """Engine.render also records, per variant, the rendering thread's CPU time (time.thread_time: its glue and the
    kernel launches it runs itself, not the pool's) of every drag frame."""
    import time

    from app.engine import Engine

    render = Engine.render

    def timed(self, obj, config=None, *a, **kw):
        t = time.thread_time()
        fr = render(self, obj, config, *a, **kw)
        if _current[0] and config is not None and config.drag is not None:
            _THREAD.setdefault(_current[0], []).append(time.thread_time() - t)
            _GLUE.setdefault(_current[0], []).append(fr.stats.get("glue", {}))
        return fr

    Engine.render = timed


_print = b36.print_scene


def print_scene(res: dict) -> None:
    """bench_drag36b's table, then per variant the rendering thread's glue (stages_ms["python"], wall ms a frame)."""
    _print(res)
    label = "CPU" if _CPU_GLUE[0] else "wall"
    for r in res["rows"]:
        th = _THREAD.pop(r["variant"], [])[3:]  # not the three untimed frames at the pose (scored)
        gl = _GLUE.pop(r["variant"], [])[3:]
        per = {k: 1e3 * sum(g.get(k, 0.0) for g in gl) / max(len(gl), 1) for k in sorted({k for g in gl for k in g})}
        print(f"{r['variant']:>10} python (glue {label} ms a frame) {r['stages_ms'].get('python', float('nan')):6.1f}"
              f"  rendering thread CPU ms a frame {1e3 * sum(th) / max(len(th), 1):6.1f}  glue by stage: " +
              " ".join(f"{k} {v:.1f}" for k, v in per.items()))


b36.print_scene = print_scene
_CPU_GLUE = [False]

def upload_micro(k: int = 5000, rounds: int = 3) -> None:
    """Workspace.upload's own cost (rendering thread CPU us a call) with VIEW_CACHE 64 and 0, interleaved: a (500,3)
    vec3d and a (500,) float64 upload of the same shapes each call (the drag frame's calls repeat their shapes)."""
    import time

    import numpy as np
    import warp as wp

    from kernels import buffers, runtime

    runtime.init()
    ws = buffers.Workspace()
    x, y = np.random.rand(500, 3), np.random.rand(500)
    for _ in range(rounds):
        for vc in (64, 0):
            buffers.VIEW_CACHE = vc
            t = time.thread_time()
            for _ in range(k):
                ws.upload("a", x, wp.vec3d, "cpu")
                ws.upload("b", y, wp.float64, "cpu")
            print(f"VIEW_CACHE {vc:2d}: {1e6 * (time.thread_time() - t) / (2 * k):.1f} us per upload")


def profile(scene: str, n_path: int = 12, top: int = 40) -> None:
    """cProfile of warm drag frames of `scene` along its drag path (the first two not profiled), timed by the
    rendering thread's CPU (time.thread_time: waits for a core and the pool's kernels left out): the top functions by
    own time, then by cumulative time (the profiler inflates small calls ~1.5x)."""
    import cProfile
    import io
    import pstats
    import time

    from app.composite import default_cache_dir
    from app.dragpath import drag_offsets, moved
    from app.engine import Engine, EngineParams
    from recon.scene import load_scene

    sc = load_scene(b36.scene_dir(scene))
    eng = Engine(sc, EngineParams(), cache_dir=default_cache_dir(), quiet=True)
    cfg, offs = b36._cfg(), drag_offsets(sc, sc.obj, n_path)
    for o in offs[:2]:
        eng.render(moved(sc.obj, o), cfg)
    pr = cProfile.Profile(time.thread_time)
    pr.enable()
    for o in offs[2:]:
        eng.render(moved(sc.obj, o), cfg)
    pr.disable()
    st = pstats.Stats(pr, stream=(out := io.StringIO()))
    print(f"{scene}: rendering thread CPU {1e3 * st.total_tt / len(offs[2:]):.1f} ms a frame (profiled)")
    for key in ("tottime", "cumtime"):
        st.sort_stats(key).print_stats(top)
    print(out.getvalue())


if __name__ == "__main__":
    if "--profile" in sys.argv:  # --profile SCENE
        profile(sys.argv[sys.argv.index("--profile") + 1])
        sys.exit()
    if "--upload-micro" in sys.argv:
        upload_micro()
        sys.exit()
    for _n, (_c, _f) in list(b36.VARIANTS.items()):
        b36.VARIANTS[_n] = (_c, _named(_n, _f))
    _thread_cpu()
    if "--cpu-glue" in sys.argv:  # app.glue's clock on the rendering thread's CPU time (not wall)
        sys.argv.remove("--cpu-glue")
        from app import glue

        glue.time = _ThreadClock()
        _CPU_GLUE[0] = True
    b36.main()
