"""A/B of the drag frame's object-light glue cuts of objglue36, in one process, the variants interleaved in rounds.

usage: python bench/bench_objglue36.py [--scenes window_room,sun_room] [--path 8] [--rounds 3]

Per scene one Engine (bench_glue_cpu.warm_drag); each round runs evaluate's drag path once per variant: "before"
(the levers switched back to main's code: lift_off_contacts loaded from commit 69048c8, building a cKDTree
of the points and asking it about every listed patch; room_share_numpy, main's room_share; hit_average handed
an `add` of zeros where there is none, as main made and uploaded it) and "after"
(the code as it is). Prints per variant the frame's wall mean, `stages_ms["python"]` and the rendering thread's
glue CPU per stage (bench_glue_cpu.ThreadCpu; the object_light stage's per frame as a median and quartiles too: a
frame the load stalls moves a mean), how many composites are byte-identical between the two; then each
lever's own call alone (arguments captured at the path's last pose), before and after interleaved, the rendering
thread's CPU per call. Timings depend on the load: compare the variants of one run only.
"""
from __future__ import annotations

import argparse
import collections
import contextlib
import hashlib
import subprocess
import sys
import time
import types
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import app.stages.object_drag as object_drag  # noqa: E402
import app.stages.object_light as object_light  # noqa: E402
import app.stages.object_shading as object_shading  # noqa: E402
from app.dragpath import moved  # noqa: E402
from app.evaluate import path_stages_ms  # noqa: E402
from bench.bench_glue_cpu import ThreadCpu, warm_drag  # noqa: E402

_lift = object_shading.lift_off_contacts
_room_share = object_light.room_share
_hit_average = object_drag.hit_average


def _hit_average_zeros(hits, faces, L_vert, add, colour, *rest):
    """hit_average as main called it in a room without a sun: its `add` made as zeros and uploaded."""
    if add is None:
        add, colour = np.zeros(len(hits.hit)), np.zeros(3)
    return _hit_average(hits, faces, L_vert, add, colour, *rest)


def _main_module(path: str, commit: str = "69048c8"):
    """The module at `path` as main had it (commit), loaded apart (its functions: the "before" variants)."""
    src = subprocess.run(["git", "-C", str(ROOT), "show", f"{commit}:{path}"], capture_output=True, text=True,
                         check=True).stdout
    mod = types.ModuleType("main_" + Path(path).stem)
    mod.__file__ = str(ROOT / path)
    sys.modules[mod.__name__] = mod  # (dataclasses look their module up)
    exec(compile(src, f"main:{path}", "exec"), mod.__dict__)
    return mod


_main_shading = _main_module("app/stages/object_shading.py")


@contextlib.contextmanager
def before():
    """The levers switched back to main's code (object_drag imports lift_off_contacts at each call)."""
    object_shading.lift_off_contacts = _main_shading.lift_off_contacts
    object_light.room_share = object_light.room_share_numpy  # main's room_share, kept as the kernel's reference
    object_drag.hit_average = _hit_average_zeros
    try:
        yield
    finally:
        object_shading.lift_off_contacts = _lift
        object_light.room_share = _room_share
        object_drag.hit_average = _hit_average


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
        variants = {"before": before, "after": contextlib.nullcontext}
        glue = {v: collections.defaultdict(float) for v in variants}
        wall = {v: [] for v in variants}
        python = {v: [] for v in variants}
        per_frame = {v: [] for v in variants}  # the object_light stage's glue CPU per frame
        frames: dict[str, list[bytes]] = {}
        for _ in range(args.rounds):
            for v, ctx in variants.items():
                cpu.stage.clear()
                stats, pix = [], []
                with ctx():
                    for o in offsets:
                        t, ol = time.perf_counter(), cpu.stage.get("object_light", 0.0)
                        cpu.start_frame()
                        fr = eng.render(moved(scene.obj, o), cfg)
                        wall[v].append(time.perf_counter() - t)
                        per_frame[v].append(cpu.stage["object_light"] - ol)
                        stats.append(fr.stats)
                        pix.append(hashlib.sha1(np.ascontiguousarray(fr.pixels).tobytes()).digest())
                for k, s in cpu.stage.items():
                    glue[v][k] += s / (len(offsets) * args.rounds)
                python[v].append(path_stages_ms(stats)["python"])
                frames.setdefault(v, pix)
        same = sum(a == b for a, b in zip(frames["before"], frames["after"]))
        print(f"{name}: {len(offsets)} poses x {args.rounds} rounds; composites before/after byte-identical "
              f"{same}/{len(offsets)}")
        for v in variants:
            g = glue[v]
            print(f"  {v}: wall {1e3 * np.mean(wall[v]):.1f} ms, python (wall) {np.mean(python[v]):.1f} ms, "
                  f"glue cpu {1e3 * sum(g.values()):.1f} ms:", {k: round(1e3 * x, 1) for k, x in g.items()})
            print(f"    object_light glue per frame: median {1e3 * np.median(per_frame[v]):.1f} ms, quartiles "
                  f"{1e3 * np.percentile(per_frame[v], 25):.1f}-{1e3 * np.percentile(per_frame[v], 75):.1f} ms")
        _per_call(eng, scene, cfg, offsets[-1], args.rounds)


def _per_call(eng, scene, cfg, offset, rounds: int, reps: int = 20) -> None:
    """Each lever's own call at the pose, before and after interleaved: the rendering thread's CPU per call (ms),
    and the largest difference of their results."""
    got: dict[str, list] = collections.defaultdict(list)

    def spy(name, fn):
        def wrapper(*a, **k):
            got[name].append((a, k))
            return fn(*a, **k)
        return wrapper
    object_shading.lift_off_contacts = spy("lift_off_contacts", _lift)
    object_light.room_share = spy("room_share", _room_share)
    object_drag.hit_average = spy("hit_average", _hit_average)
    try:
        eng.render(moved(scene.obj, offset), cfg)
    finally:
        object_shading.lift_off_contacts, object_light.room_share = _lift, _room_share
        object_drag.hit_average = _hit_average
    levers = {"lift_off_contacts": (_main_shading.lift_off_contacts, _lift),
              "room_share": (object_light.room_share_numpy, _room_share),
              "hit_average": (_hit_average_zeros, _hit_average)}
    for name, (fb, fa) in levers.items():
        for a, k in got[name]:
            if name == "hit_average" and a[3] is not None:  # a sun room: the lever (no add) does not run
                continue
            r0 = np.array(fb(*a, **k), copy=True)  # (hit_average's result is a kept image)
            r1 = fa(*a, **k)
            cost = {"before": 0.0, "after": 0.0}
            for _ in range(rounds):
                for v, fn in (("before", fb), ("after", fa)):
                    c = time.thread_time()
                    for _ in range(reps):
                        fn(*a, **k)
                    cost[v] += time.thread_time() - c
            per = 1e3 / (rounds * reps)
            what = (f"{len(a[0].hit)} sub-samples" if name == "hit_average" else
                    f"{len(a[0])} points, {len(a[2])} {'patches' if name == 'lift_off_contacts' else 'triangles'}")
            print(f"  {name} ({what}): cpu per call before {per * cost['before']:.2f} ms -> after "
                  f"{per * cost['after']:.2f} ms; largest difference {np.abs(r0 - r1).max():.3g}")


if __name__ == "__main__":
    main()
