"""The drag frame's source list (issue 36, `stages_ms["sources"]`): ShadowSources.select's steps timed along a drag.

usage: python bench/bench_sources.py [--scenes window_room,sun_room,~/.cache/photoar/rooms/window_101] [--path 12]
                                     [--repeat 3]

Per scene one Engine (the default precompute cache); the object's box at --path poses along app.dragpath's drag;
each pose's select at the drag frame's pass budget (app.config.DRAG_PASSES, near split) run with the kernels
(kernels.cluster_weights, kernels.shaft_traverse: "kernels") and with their numpy forms (weights_reference,
traverse_reference: "numpy"), interleaved in one process, --repeat rounds. Prints per variant the median of the
calling thread's CPU ms of each step (time.thread_time: the Python and numpy glue, and the kernels launched on
that thread) and the process's CPU ms of the whole select (both cores: the pooled launches too), and whether the
two variants' frame sources are the same bytes. Timings depend on the machine's load: compare the rows of one run.
"""
from __future__ import annotations

import argparse
import functools
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.composite import default_cache_dir  # noqa: E402
from app.config import DRAG_PASSES  # noqa: E402
from app.dragpath import drag_offsets, moved  # noqa: E402
from app.engine import Engine, EngineParams  # noqa: E402
from app.runtime import split as split_launches  # noqa: E402
from bench.bench_drag import scene_dir  # noqa: E402
from lighting import frame_sources  # noqa: E402
from recon.scene import load_scene  # noqa: E402

STEPS = ("traverse", "blocked_key", "near_factor", "representatives", "weights", "eyes", "spread", "_pairs")


def bench_scene(d: Path, n_path: int, repeat: int) -> dict:
    scene = load_scene(d)
    eng = Engine(scene, EngineParams(), cache_dir=default_cache_dir(), quiet=True)
    ss = eng.shadow_sources
    split = functools.partial(split_launches, device=eng.device, min_items=64)
    passes = DRAG_PASSES - int(eng.sun_pixels.stage is not None)
    boxes = []
    for o in drag_offsets(scene, scene.obj, n_path):
        pv = eng.object_shading.object_shape(moved(scene.obj, o))[0]
        boxes.append((pv.min(0), pv.max(0)))
    kernels = (ss.cluster, ss.shafts._kernel)
    variants = {"kernels": kernels, "numpy": (None, None)}
    times: dict[str, dict[str, list[float]]] = {v: {k: [] for k in STEPS + ("select", "select_cpu")} for v in variants}
    timed = {}

    def wrap(name, fn):
        def f(*a, **kw):
            t = time.thread_time()
            try:
                return fn(*a, **kw)
            finally:
                timed.setdefault(name, 0.0)
                timed[name] += time.thread_time() - t
        return f

    cls = frame_sources.ShadowSources
    originals = {k: getattr(cls, k) for k in STEPS}
    out = {}
    try:
        for k in STEPS:
            setattr(cls, k, wrap(k, originals[k]))
        for r in range(repeat):
            for v, (cw, tk) in variants.items():
                ss.cluster, ss.shafts._kernel = cw, tk
                for i, (lo, hi) in enumerate(boxes):
                    timed.clear()
                    t0, c0 = time.thread_time(), time.process_time()
                    fs = ss.select(lo, hi, passes, split, near_split=True)
                    times[v]["select"].append(time.thread_time() - t0)
                    times[v]["select_cpu"].append(time.process_time() - c0)
                    for k in STEPS:
                        times[v][k].append(timed.get(k, 0.0))
                    if r == 0:
                        out.setdefault(i, {})[v] = fs
    finally:
        for k in STEPS:
            setattr(cls, k, originals[k])
        ss.cluster, ss.shafts._kernel = kernels
    same = all(np.array_equal(getattr(o["kernels"], f), getattr(o["numpy"], f))
               for o in out.values() for f in ("eyes", "W_v", "W_c", "cand", "spread"))
    return {"scene": str(d), "passes": passes, "same_bytes": bool(same),
            "ms": {v: {k: 1e3 * float(np.median(x)) for k, x in t.items()} for v, t in times.items()}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default="window_room,sun_room")
    ap.add_argument("--path", type=int, default=12)
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args()
    for name in a.scenes.split(","):
        res = bench_scene(scene_dir(name), a.path, a.repeat)
        print(f"\n{res['scene']} ({res['passes']} passes; kernels and numpy give the same bytes: {res['same_bytes']})")
        print(f"{'variant':>8} " + " ".join(f"{k[:11]:>11}" for k in STEPS + ("select", "select_cpu")))
        for v, ms in res["ms"].items():
            print(f"{v:>8} " + " ".join(f"{ms[k]:11.2f}" for k in STEPS + ("select", "select_cpu")))
        sys.stdout.flush()


if __name__ == "__main__":
    main()
