"""A/B of the drag frame's object-side glue (glue48): the sun per camera hit and the far changed patches' SH in numpy
(before) against one launch each (kernels.hit_average.SunAtHits, kernels.disk_sh: after), in one process, the
variants interleaved in rounds.

usage: python bench/bench_glue48.py [--scenes window_room,sun_room] [--path 8] [--rounds 3]

Per scene one Engine; each round runs evaluate's drag path (DRAG_PASSES, DRAG_SCALE, DRAG_SHADOW; --path poses
after two warm-up frames) once per variant. "before" routes DragObject.shade's SunAtHits through
app.stages.object_drag.sun_per_hit_numpy (the numpy block the launch replaced) and hands hit_average its result,
and its disk_sh_launch to the numpy disk_sh; "hits" does the former only; "after" is the code as it is. Prints
per variant the frame's wall mean, the rendering thread's glue CPU per stage (bench_glue_cpu.ThreadCpu: its CPU
outside the kernels it launches), and the largest difference of the composites between "before" and "after"
(levels: 8-bit pixel values; the largest, and the worst frame's rms) and how many are byte-identical; then each
lever's own call alone (its arguments captured at the last pose), before and after, interleaved, its CPU per call.
Timings depend on the load: compare the variants of one run only.
"""
from __future__ import annotations

import argparse
import collections
import hashlib
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import app.stages.object_drag as object_drag  # noqa: E402
from app.dragpath import moved  # noqa: E402
from app.evaluate import path_stages_ms  # noqa: E402
from bench.bench_glue_cpu import ThreadCpu, warm_drag  # noqa: E402

_kernel_hit_average = object_drag.hit_average
_disk_launch = object_drag.disk_sh_launch


def _numpy_disk(probes, centres, normals, areas, radiance, *rest):
    """disk_sh_launch as DragObject.shade called it before glue48: the numpy disk_sh."""
    return object_drag.disk_sh(probes, centres, normals, areas, radiance)


def _numpy_sun(drag) -> callable:
    """hit_average as DragObject.shade called it before glue48: a SunAtHits turned into a numpy `add` first."""
    def hit_average(hits, faces, L_vert, add, *rest):
        if isinstance(add, object_drag.SunAtHits):
            ds = drag._shape[1]
            add = object_drag.sun_per_hit_numpy(ds, drag.shading.sun, add.v, add.n, faces, add.room, hits, add.mean,
                                                add.R)[0]
        return _kernel_hit_average(hits, faces, L_vert, add, *rest)
    return hit_average


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", default="window_room,sun_room")
    ap.add_argument("--path", type=int, default=8)
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args()
    cpu = None
    for name in args.scenes.split(","):
        scene, eng, cfg, offsets = warm_drag(name, args.path)
        cpu = cpu or ThreadCpu()
        variants = {"before": ("hits", "disk"), "hits": ("disk",), "after": ()}  # the levers left in numpy
        glue = {v: collections.defaultdict(float) for v in variants}
        wall = {v: [] for v in variants}
        python = {v: [] for v in variants}
        frames: dict[str, list[np.ndarray]] = {}
        for _ in range(args.rounds):
            for v, numpy_levers in variants.items():
                if "hits" in numpy_levers:
                    object_drag.hit_average = _numpy_sun(eng.object_drag)
                if "disk" in numpy_levers:
                    object_drag.disk_sh_launch = _numpy_disk
                cpu.stage.clear()
                stats, pix = [], []
                for o in offsets:
                    t = time.perf_counter()
                    cpu.start_frame()
                    fr = eng.render(moved(scene.obj, o), cfg)
                    wall[v].append(time.perf_counter() - t)
                    stats.append(fr.stats)
                    pix.append(np.asarray(fr.pixels))
                object_drag.hit_average, object_drag.disk_sh_launch = _kernel_hit_average, _disk_launch
                for k, s in cpu.stage.items():
                    glue[v][k] += s / (len(offsets) * args.rounds)
                python[v].append(path_stages_ms(stats)["python"])
                frames.setdefault(v, pix)
        diff = [np.abs(a.astype(np.float64) - b) for a, b in zip(frames["before"], frames["after"])]
        same = sum(hashlib.sha1(a.tobytes()).digest() == hashlib.sha1(b.tobytes()).digest()
                   for a, b in zip(frames["before"], frames["after"]))
        print(f"{name}: {len(offsets)} poses x {args.rounds} rounds; composites before/after byte-identical "
              f"{same}/{len(offsets)}, largest difference {max(d.max() for d in diff):.3g} levels, "
              f"rmse {max(np.sqrt(np.mean(d ** 2)) for d in diff):.3g} levels (worst frame)")
        for v in variants:
            g = glue[v]
            print(f"  {v}: wall {1e3 * np.mean(wall[v]):.1f} ms, python (wall) {np.mean(python[v]):.1f} ms, "
                  f"glue cpu {1e3 * sum(g.values()):.1f} ms:", {k: round(1e3 * x, 1) for k, x in g.items()})
        _per_call(eng, scene, cfg, offsets[-1], cpu, args.rounds)


def _per_call(eng, scene, cfg, offset, cpu: ThreadCpu, rounds: int, reps: int = 20) -> None:
    """Each lever's own call at the path's last pose, before (numpy) and after (its launch), interleaved: the
    rendering thread's CPU per call, all of it and outside kernels (ms). The call's arguments are captured
    from one frame."""
    got = {}

    def hits_spy(*a):
        got["hits"] = a
        return _kernel_hit_average(*a)

    def disk_spy(*a):
        got["disk"] = a
        return _disk_launch(*a)
    object_drag.hit_average, object_drag.disk_sh_launch = hits_spy, disk_spy
    try:
        eng.render(moved(scene.obj, offset), cfg)
    finally:
        object_drag.hit_average, object_drag.disk_sh_launch = _kernel_hit_average, _disk_launch
    calls = {}
    if "hits" in got and isinstance(got["hits"][3], object_drag.SunAtHits):
        h, numpy_hits = got["hits"], _numpy_sun(eng.object_drag)
        n = int(np.count_nonzero(h[0].hit))
        calls[f"sun per hit ({n} hits)"] = (lambda: numpy_hits(*h), lambda: _kernel_hit_average(*h))
    if "disk" in got:
        d = got["disk"]
        calls[f"disk_sh ({len(d[0])} probes x {len(d[1])} patches)"] = (lambda: _numpy_disk(*d),
                                                                         lambda: _disk_launch(*d))
    for name, (before, after) in calls.items():
        cost = {"before": [0.0, 0.0], "after": [0.0, 0.0]}
        for fn in (before, after):
            fn()
        for _ in range(rounds):
            for v, fn in (("before", before), ("after", after)):
                c, k = time.thread_time(), cpu.kernel
                for _ in range(reps):
                    fn()
                cost[v][0] += time.thread_time() - c
                cost[v][1] += cpu.kernel - k
        per = 1e3 / (rounds * reps)
        print(f"  {name}: cpu per call before {per * cost['before'][0]:.2f} ms (glue "
              f"{per * (cost['before'][0] - cost['before'][1]):.2f}) -> after {per * cost['after'][0]:.2f} ms (glue "
              f"{per * (cost['after'][0] - cost['after'][1]):.2f})")


if __name__ == "__main__":
    main()
