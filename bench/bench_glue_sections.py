"""The drag frame's glue CPU per section: the rendering thread's CPU time inside each of the named functions
(SECTIONS, inclusive: a section holds the sections it calls), less its CPU time in the kernels it launches
(bench_glue_cpu.ThreadCpu), ms per frame, and the glue per FrameTimer stage.

usage: python bench/bench_glue_sections.py SCENE [POSES]

evaluate's drag path (DRAG_PASSES, DRAG_SCALE, DRAG_SHADOW; POSES (default 8) after two warm-up frames). Each
function is wrapped once, on the rendering thread only (a call from a pool thread is not counted). Timings
depend on the load: compare sections of one run.
"""
from __future__ import annotations

import collections
import importlib
import sys
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from app.dragpath import moved  # noqa: E402
from bench.bench_glue_cpu import ThreadCpu, warm_drag  # noqa: E402


SECTIONS = [  # (module, function or Class.method)
    ("app.engine", "Engine.frame_object"), ("app.stages.object_shading", "ObjectShading.object_hits"),
    ("lighting.frame_sources", "ShadowSources.select"), ("lighting.frame_sources", "ShadowSources.traverse"),
    ("app.engine", "Engine._object_light"), ("app.stages.object_drag", "DragObject.shade"),
    ("app.stages.object_drag", "DragObject.proxy_radiance"), ("app.stages.object_shading", "lift_off_contacts"),
    ("kernels.disk_sh", "disk_sh_launch"), ("kernels.hit_average", "hit_average"),
    ("kernels.drag_gather", "gather_seen"), ("app.stages.object_light", "ObjectLight.light"),
    ("app.stages.object_light", "ObjectLight.centre_light_parts"),
    ("app.stages.object_light", "ObjectLight._coarse_centres"),
    ("app.stages.object_light", "ObjectLight._drag_sums"), ("app.stages.object_light", "_reflected"),
    ("app.stages.object_light", "room_share"), ("app.stages.object_light", "_light_bound"),
    ("app.stages.object_light", "_exact_sum"), ("app.stages.sun", "SunStage.object_emitters"),
    ("app.stages.sun", "SunStage.later_at_patches"), ("app.stages.sun", "SunStage.later_bounces"),
    ("app.stages.sun", "SunStage.refine_clipped_edges"), ("app.engine", "Engine._sun_later_bounces"),
    ("app.stages.compose", "ComposeStage.second_order")]


def _install(cpu: ThreadCpu, acc: dict) -> None:
    """Wrap each SECTIONS function (in its module and in every module that imported it by name)."""
    depth = collections.Counter()

    def wrap(label, fn):
        def wrapper(*a, **k):
            if threading.get_ident() != cpu.main or depth[label]:
                return fn(*a, **k)
            depth[label] += 1
            c, k0 = time.thread_time(), cpu.kernel
            try:
                return fn(*a, **k)
            finally:
                acc[label] += (time.thread_time() - c) - (cpu.kernel - k0)
                depth[label] -= 1
        return wrapper

    for mod, qual in SECTIONS:
        *path, attr = qual.split(".")
        owner = importlib.import_module(mod)
        for p in path:
            owner = getattr(owner, p)
        fn = getattr(owner, attr)
        setattr(owner, attr, wrap(qual, fn))
        if not path:  # a module's function: its importers' names too
            for m in list(sys.modules.values()):
                if m is not None and getattr(m, attr, None) is fn:
                    setattr(m, attr, getattr(owner, attr))


def main() -> None:
    name = sys.argv[1]
    n_path = int(sys.argv[2]) if len(sys.argv) > 2 else 8
    scene, eng, cfg, offsets = warm_drag(name, n_path)
    cpu = ThreadCpu()
    acc: dict[str, float] = collections.defaultdict(float)
    _install(cpu, acc)
    cpu.stage.clear()
    for o in offsets:
        cpu.start_frame()
        eng.render(moved(scene.obj, o), cfg)
    n = len(offsets)
    print(name, "glue cpu per stage (ms):", {k: round(1e3 * v / n, 1) for k, v in cpu.stage.items()})
    for k, v in sorted(acc.items(), key=lambda x: -x[1]):
        print(f"  {1e3 * v / n:6.2f}  {k}")


if __name__ == "__main__":
    main()
