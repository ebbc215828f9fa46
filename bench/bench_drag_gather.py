"""The drag frame's per-vertex gather (kernels.drag_gather) against the numpy gather it replaced: A/B in one process.

usage: python bench/bench_drag_gather.py [--scenes window_room,lamps_room] [--rounds 4]

Per scene one Engine renders three drag frames (app.dragpath) and records the inputs of every gather_seen call
of app.stages.object_drag (the emitters' and the near changed patches' form factors x the object's own
visibility by direction); then times, alternately, the numpy form (kernels.formfactor.point_to_polygon's
(vertices x polygons) array, the octahedral cells in numpy, a product), the kernel in one launch and the kernel
split over the cores as the frame runs it (app.runtime.split). Checks they agree (1e-9 relative) and prints ms
per frame. Timings depend on the machine's load: compare the columns of one run.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import app.stages.object_drag as OD  # noqa: E402
from app.composite import default_cache_dir  # noqa: E402
from app.config import DRAG_PASSES, DRAG_SCALE  # noqa: E402
from app.dragpath import drag_offsets, moved  # noqa: E402
from app.engine import Engine, EngineParams, FrameConfig  # noqa: E402
from bench.bench_drag import scene_dir  # noqa: E402
from kernels.buffers import Workspace  # noqa: E402
from kernels.formfactor import point_to_polygon  # noqa: E402
from recon.scene import load_scene  # noqa: E402


def bench_scene(d: Path, rounds: int, frames: int = 3) -> dict:
    scene = load_scene(d)
    eng = Engine(scene, EngineParams(), cache_dir=default_cache_dir(), quiet=True)
    cfg = FrameConfig(passes=DRAG_PASSES, drag=DRAG_SCALE)
    calls, gather = [], OD.gather_seen

    def record(points, normals, rows, vis, polygons, radiance, R, res, device, workspace, split=None, capacity=0,
               weights=None):
        calls.append((points.copy(), normals.copy(), np.asarray(rows).copy(), polygons.copy(), radiance.copy(),
                      R.copy(), None if weights is None else weights.copy(), capacity))
        return gather(points, normals, rows, vis, polygons, radiance, R, res, device, workspace, split, capacity,
                      weights)

    OD.gather_seen = record
    try:
        for o in drag_offsets(scene, scene.obj, frames + 1)[:frames]:
            eng.render(moved(scene.obj, o), cfg)
    finally:
        OD.gather_seen = gather
    if not calls:
        return {"scene": str(d), "calls": 0}
    ds = eng.object_drag._shape[1]
    vis_dev, dev = ds.vis_on(eng.device), eng.device
    ws: dict = {}

    def kernel(c, i, split=None):
        p, n, rows, polys, rad, R, w, cap = c
        return gather(p, n, rows, vis_dev, polys, rad, R, OD.VIS_RES, dev, ws.setdefault((i, split is None),
                                                                                           Workspace()),
                      split, cap, w)

    def numpy(c, i):
        p, n, rows, polys, rad, R, w, cap = c
        F = point_to_polygon(p, n, polys, device=dev, workspace=ws.setdefault(("np", i), Workspace()), capacity=cap)
        own = np.take_along_axis(ds.vis[rows], OD._octa_cell((polys.mean(1)[None] - p[:, None]) @ R, OD.VIS_RES),
                                 axis=1)
        return ((F * own * w) if w is not None else (F * own)) @ rad

    forms = {"numpy": numpy, "kernel": kernel, "kernel_split": lambda c, i: kernel(c, i, eng.object_drag._split)}
    for i, c in enumerate(calls):
        np.testing.assert_allclose(kernel(c, i), numpy(c, i), rtol=1e-9, atol=1e-14)
    T = dict.fromkeys(forms, 0.0)
    for _ in range(rounds):
        for name, f in forms.items():
            t = time.perf_counter()
            for i, c in enumerate(calls):
                f(c, i)
            T[name] += time.perf_counter() - t
    per = len(calls) // frames
    return {"scene": str(d), "calls": per, "sizes": [(len(c[0]), len(c[3])) for c in calls[:per]],
            **{k + "_ms": 1e3 * v / (rounds * frames) for k, v in T.items()}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default="window_room,lamps_room")
    ap.add_argument("--rounds", type=int, default=4)
    a = ap.parse_args()
    for name in a.scenes.split(","):
        r = bench_scene(scene_dir(name), a.rounds)
        if not r["calls"]:
            print(f"{r['scene']}: no gather (the drag frame does not shade from the tables here)")
            continue
        print(f"{r['scene']}: {r['calls']} calls a frame, (vertices, polygons) {r['sizes']}: numpy "
              f"{r['numpy_ms']:.1f} ms, kernel {r['kernel_ms']:.1f} ms, kernel split {r['kernel_split_ms']:.1f} ms "
              f"per frame")
        sys.stdout.flush()


if __name__ == "__main__":
    main()
