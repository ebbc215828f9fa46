"""A/B of the drag frame's object-side glue (glue48): the sun per camera hit in numpy (before) against one launch
(kernels.hit_average.SunAtHits, after), in one process, the variants interleaved in rounds.

usage: python bench/bench_glue48.py [--scenes window_room,sun_room] [--path 8] [--rounds 3]

Per scene one Engine; each round runs evaluate's drag path (DRAG_PASSES, DRAG_SCALE, DRAG_SHADOW; --path poses
after two warm-up frames) once per variant. "before" routes DragObject.shade's SunAtHits through
app.stages.object_drag.sun_per_hit_numpy (the numpy block the launch replaced) and hands hit_average its result;
"after" is the code as it is. Prints per variant the frame's wall mean, the rendering thread's glue CPU per stage
(bench_glue_cpu.ThreadCpu: its CPU outside the kernels it launches), and per frame the largest difference of the
composites between the variants (levels: 8-bit pixel values) and whether they are byte-identical. Timings depend
on the load: compare the variants of one run only.
"""
from __future__ import annotations

import argparse
import collections
import dataclasses
import hashlib
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import app.stages.object_drag as object_drag  # noqa: E402
from app.composite import default_cache_dir  # noqa: E402
from app.dragpath import drag_offsets, moved  # noqa: E402
from app.engine import Engine, EngineParams  # noqa: E402
from app.evaluate import DRAG_PASSES, DRAG_SCALE, DRAG_SHADOW, path_stages_ms  # noqa: E402
from bench.bench_drag import scene_dir  # noqa: E402
from bench.bench_glue_cpu import ThreadCpu  # noqa: E402
from recon.scene import load_scene  # noqa: E402

_kernel_hit_average = object_drag.hit_average


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
        scene = load_scene(scene_dir(name))
        eng = Engine(scene, EngineParams(), cache_dir=default_cache_dir(), quiet=True)
        cfg = dataclasses.replace(eng.frame_config(), passes=DRAG_PASSES, drag=DRAG_SCALE, drag_shadow=DRAG_SHADOW)
        offsets = drag_offsets(scene, scene.obj, args.path)
        for o in offsets[:2]:
            eng.render(moved(scene.obj, o), cfg)
        cpu = cpu or ThreadCpu()
        variants = {"before": None, "after": _kernel_hit_average}
        glue = {v: collections.defaultdict(float) for v in variants}
        wall = {v: [] for v in variants}
        python = {v: [] for v in variants}
        frames: dict[str, list[np.ndarray]] = {}
        for _ in range(args.rounds):
            for v, fn in variants.items():
                object_drag.hit_average = fn if fn is not None else _numpy_sun(eng.object_drag)
                cpu.stage.clear()
                stats, pix = [], []
                for o in offsets:
                    t = time.perf_counter()
                    cpu.start_frame()
                    fr = eng.render(moved(scene.obj, o), cfg)
                    wall[v].append(time.perf_counter() - t)
                    stats.append(fr.stats)
                    pix.append(np.asarray(fr.pixels))
                object_drag.hit_average = _kernel_hit_average
                for k, s in cpu.stage.items():
                    glue[v][k] += s / (len(offsets) * args.rounds)
                python[v].append(path_stages_ms(stats)["python"])
                frames.setdefault(v, pix)
        diff = [float(np.abs(a.astype(np.float64) - b).max()) for a, b in zip(frames["before"], frames["after"])]
        same = sum(hashlib.sha1(a.tobytes()).digest() == hashlib.sha1(b.tobytes()).digest()
                   for a, b in zip(frames["before"], frames["after"]))
        print(f"{name}: {len(offsets)} poses x {args.rounds} rounds; composites byte-identical {same}/{len(offsets)}, "
              f"largest difference {max(diff):.3g} levels")
        for v in variants:
            g = glue[v]
            print(f"  {v}: wall {1e3 * np.mean(wall[v]):.1f} ms, python (wall) {np.mean(python[v]):.1f} ms, "
                  f"glue cpu {1e3 * sum(g.values()):.1f} ms:", {k: round(1e3 * x, 1) for k, x in g.items()})


if __name__ == "__main__":
    main()
