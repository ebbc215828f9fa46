"""The drag frame's glue as CPU time of the rendering thread (issue 36's `stages_ms["python"]`, measured apart from
the waits a loaded machine adds to it).

usage: python bench/bench_glue_cpu.py [--scenes window_room,sun_room] [--path 12]

`stages_ms["python"]` (app.glue.FrameTimer) is wall time outside Warp kernels: on a busy machine it holds the time
the rendering thread waits for a core or for the GIL as well as its own work. This bench runs evaluate's drag path
(DRAG_PASSES, DRAG_SCALE, DRAG_SHADOW; --path poses after two warm-up frames) in one Engine per scene and reads the
rendering thread's CPU time (time.thread_time) at every FrameTimer.tick, less its CPU time inside the outermost
`warp.launch` / `kernels.runtime.run_parallel` calls it makes (the kernels it runs itself; those the pool runs use
other threads). Prints per scene the frame's wall and process CPU, the rendering thread's CPU, the part of it in
kernels, and the rest (the glue's CPU) per stage, ms per frame. Timings depend on the load: compare rows of one
run; CPU times vary less with it than wall times.
"""
from __future__ import annotations

import argparse
import collections
import dataclasses
import sys
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.composite import default_cache_dir  # noqa: E402
from app.dragpath import drag_offsets, moved  # noqa: E402
from app.engine import Engine, EngineParams  # noqa: E402
from app.evaluate import DRAG_PASSES, DRAG_SCALE, DRAG_SHADOW, path_stages_ms  # noqa: E402
from app.glue import FrameTimer, KernelClock  # noqa: E402
from recon.scene import load_scene  # noqa: E402
from bench.bench_drag import scene_dir  # noqa: E402


class ThreadCpu:
    """The main thread's CPU seconds inside the outermost kernel calls (`kernel`), and its CPU seconds outside
    them per FrameTimer stage (`stage`), installed over warp.launch, kernels.runtime.run_parallel and
    FrameTimer.tick (after app.glue's own wrappers: the glue clock is unchanged)."""

    def __init__(self) -> None:
        import warp as wp

        from kernels import runtime

        self.main = threading.get_ident()
        self.kernel, self._depth = 0.0, 0
        self.stage: dict[str, float] = collections.defaultdict(float)
        self._last: tuple[float, float] | None = None
        KernelClock()  # app.glue installs its wrappers on the first clock: these go over them
        wp.launch = self._wrap(wp.launch)
        runtime.run_parallel = self._wrap(runtime.run_parallel)
        tick = FrameTimer.tick

        def timed_tick(timer, name, *a, **k):
            if threading.get_ident() == self.main and self._last is not None:
                c = time.thread_time()
                self.stage[name] += (c - self._last[0]) - (self.kernel - self._last[1])
                self._last = (c, self.kernel)
            return tick(timer, name, *a, **k)
        FrameTimer.tick = timed_tick

    def _wrap(self, fn):
        def wrapper(*args, **kwargs):
            if threading.get_ident() != self.main or self._depth:
                return fn(*args, **kwargs)
            self._depth += 1
            c = time.thread_time()
            try:
                return fn(*args, **kwargs)
            finally:
                self.kernel += time.thread_time() - c
                self._depth -= 1
        wrapper.__wrapped_by_glue__ = True
        return wrapper

    def start_frame(self) -> None:
        self._last = (time.thread_time(), self.kernel)


def warm_drag(name: str, n_path: int):
    """(scene, engine, drag FrameConfig, offsets) of a scene (bench_drag.scene_dir's names) on evaluate's drag path
    of n_path poses (DRAG_PASSES, DRAG_SCALE, DRAG_SHADOW), its first two poses rendered once (kernels compiled,
    buffers made): what the glue benches time."""
    scene = load_scene(scene_dir(name))
    eng = Engine(scene, EngineParams(), cache_dir=default_cache_dir(), quiet=True)
    cfg = dataclasses.replace(eng.frame_config(), passes=DRAG_PASSES, drag=DRAG_SCALE, drag_shadow=DRAG_SHADOW)
    offsets = drag_offsets(scene, scene.obj, n_path)
    for o in offsets[:2]:
        eng.render(moved(scene.obj, o), cfg)
    return scene, eng, cfg, offsets


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", default="window_room,sun_room")
    ap.add_argument("--path", type=int, default=12)
    args = ap.parse_args()
    cpu = None
    for name in args.scenes.split(","):
        scene, eng, cfg, offsets = warm_drag(name, args.path)
        cpu = cpu or ThreadCpu()
        cpu.stage.clear()
        rows, stats = [], []
        for o in offsets:
            k0 = cpu.kernel
            t, c, p = time.perf_counter(), time.thread_time(), time.process_time()
            cpu.start_frame()
            fr = eng.render(moved(scene.obj, o), cfg)
            rows.append((time.perf_counter() - t, time.process_time() - p, time.thread_time() - c, cpu.kernel - k0))
            stats.append(fr.stats)
        wall, proc, thread, kern = 1e3 * np.mean(rows, 0)
        n = len(offsets)
        print(f"{name}: wall {wall:.1f}, process cpu {proc:.1f}, rendering thread cpu {thread:.1f} "
              f"(in kernels {kern:.1f}, glue {thread - kern:.1f}); stages_ms python (wall) "
              f"{path_stages_ms(stats)['python']:.1f} ms per frame")
        print("  glue cpu per stage (ms):", {k: round(1e3 * v / n, 1) for k, v in cpu.stage.items()})


if __name__ == "__main__":
    main()
