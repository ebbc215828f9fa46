"""The drag frame's full-resolution compose (kernels.drag_compose) alone, row-wise against pixel-wise, A/B in one
process (issue 36, drag36).

usage: python bench/bench_drag_compose.py [--scenes window_room,sun_room | DIR,...] [--path 4] [--reps 10]

Per scene one Engine and evaluate's drag path (DRAG_PASSES, DRAG_SCALE, DRAG_SHADOW). At each pose the drag frame
is rendered once and DragCompose.run's inputs captured (the coarse room, the object's coverage and radiance, the
sun's share); then DragCompose.run is replayed on one thread (no split), drag_compose_kernel (rowwise: each run's
row terms once, its four coarse ratios read again only where the left coarse column changes) and
drag_compose_pixelwise_kernel (every pixel its own, as before drag36) interleaved, --reps times each. Prints per
scene the thread's CPU (time.thread_time) per call of each, mean over the poses of the per-pose medians, and
whether the three outputs (radiance, room, pixels) are byte-equal at every pose.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.dragpath import moved  # noqa: E402
from bench.bench_glue_cpu import warm_drag  # noqa: E402
from kernels import drag_compose  # noqa: E402


def capture(eng, scene, cfg, offset) -> tuple:
    """(the DragCompose, its run's inputs) of the drag frame at `offset`, rendered once."""
    got = []
    run = drag_compose.DragCompose.run

    def cap(self, room_c, cov, obj_rad, split, sun=None, rect=None):
        got.append((self, (room_c.copy(), cov.copy(), obj_rad.copy(),
                           None if sun is None else (sun[0].copy(), sun[1].copy()), rect)))
        return run(self, room_c, cov, obj_rad, split, sun, rect)

    drag_compose.DragCompose.run = cap
    try:
        eng.render(moved(scene.obj, offset), cfg)
    finally:
        drag_compose.DragCompose.run = run
    return got[-1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", default="window_room,sun_room")
    ap.add_argument("--path", type=int, default=4)
    ap.add_argument("--reps", type=int, default=10)
    a = ap.parse_args()
    one = lambda launch, n: launch(0, n)  # noqa: E731 (one thread: the kernel's own CPU)
    for name in a.scenes.split(","):
        scene, eng, cfg, offsets = warm_drag(name, a.path + 2)
        ms = {True: [], False: []}
        same = True
        for o in offsets[2:]:
            dc, (room_c, cov, obj, sun, rect) = capture(eng, scene, cfg, o)
            per, outs = {True: [], False: []}, {}
            try:
                for _ in range(a.reps):
                    for rowwise in (False, True):
                        dc.rowwise = rowwise
                        t = time.thread_time()
                        res = dc.run(room_c, cov, obj, one, sun, rect)
                        per[rowwise].append(time.thread_time() - t)
                        outs[rowwise] = [x.copy() for x in res]
            finally:
                dc.rowwise = True
            same &= all(np.array_equal(x, y) for x, y in zip(outs[True], outs[False]))
            for k in per:
                ms[k].append(1e3 * np.median(per[k]))
        print(f"{Path(name).name}: DragCompose.run CPU per call, one thread (ms, mean of the per-pose medians over "
              f"{len(ms[True])} poses, {a.reps} reps): pixelwise {np.mean(ms[False]):.2f}, rowwise "
              f"{np.mean(ms[True]):.2f}; {'same bytes' if same else 'OUTPUTS DIFFER'}", flush=True)


if __name__ == "__main__":
    main()
