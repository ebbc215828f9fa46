"""Sphere drag frame against the map drag frame (issue 36): error at the scene's pose, path time, A/B.

usage: python bench/bench_dragshadow.py [--scenes window_room,lamps_room,sun_room | DIR,...] [--path 12]
                                        [--modes maps,spheres,spheres4] [--no-all] [--out FILE.json]

Per scene one Engine (the default precompute cache): the all-sources frame (unless --no-all: its score
is then not printed), then per mode one drag frame at the scene's own pose scored against the truth
(lighting.metrics), and a drag of --path poses (app.dragpath; the first frame excluded) rendered in
rounds interleaved over the modes (the same machine load for all). Modes: `maps` (FrameConfig.drag
DRAG_SCALE, DRAG_PASSES clustered shadow maps: the drag frame before), `spheres` (drag_shadow "spheres"
at DRAG_SCALE), `spheresS` (spheres at 1/S). Prints per mode energy_ratio / rmse_affected, path mean /
p95 ms and the per-stage means, next to issue 36's bound (rmse_affected <= 1.5 x the all-sources frame's
+ 0.5, energy 0.93-1.07). Timings depend on the machine's load: compare the rows of one run.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.composite import default_cache_dir  # noqa: E402
from app.config import DRAG_PASSES, DRAG_SCALE  # noqa: E402
from app.dragpath import drag_offsets, moved  # noqa: E402
from app.engine import Engine, EngineParams  # noqa: E402
from app.evaluate import path_stages_ms  # noqa: E402
from bench.bench_drag import scene_dir  # noqa: E402
from lighting import metrics  # noqa: E402
from recon.io import read_image_rgb  # noqa: E402
from recon.scene import load_scene  # noqa: E402


def mode_config(engine: Engine, mode: str):
    """The FrameConfig of a mode name (module docstring)."""
    base = dataclasses.replace(engine.frame_config(), passes=DRAG_PASSES, drag=DRAG_SCALE)
    if mode == "maps":
        return base
    if mode.startswith("spheres"):
        s = int(mode[len("spheres"):] or DRAG_SCALE)
        return dataclasses.replace(base, drag=s, drag_shadow="spheres")
    raise SystemExit(f"unknown mode {mode!r}: maps, spheres or spheresS")


def run_scene(name: str, modes: list[str], n_path: int, with_all: bool) -> dict:
    import cv2

    d = scene_dir(name)
    scene = load_scene(d)
    eng = Engine(scene, EngineParams(), cache_dir=default_cache_dir(), quiet=True)
    truth = read_image_rgb(d / "truth.png")
    mask = cv2.imread(str(d / "truth_mask.png"), cv2.IMREAD_GRAYSCALE)

    def score(px):
        s = metrics.score_regions(px, scene.photo, truth, mask)
        return round(float(s["energy_ratio"]), 3), round(float(s["rmse_affected"]), 2)

    out = {"scene": name, "modes": {}}
    if with_all:
        t = time.perf_counter()
        fr = eng.render(scene.obj, dataclasses.replace(eng.frame_config(), passes=None))
        out["all"] = {"frame_s": time.perf_counter() - t, "score": score(fr.pixels)}
    cfgs = {m: mode_config(eng, m) for m in modes}
    for m, c in cfgs.items():
        t = time.perf_counter()
        eng.render(scene.obj, c)  # the stages made, kernels compiled
        first = time.perf_counter() - t
        fr = eng.render(scene.obj, c)
        out["modes"][m] = {"first_s": first, "score": score(fr.pixels), "pose_frame_s": fr.stats["frame_s"]}
    offsets = drag_offsets(scene, scene.obj, n_path)
    stats = {m: [] for m in modes}
    for o in offsets:  # interleaved: each pose in every mode
        ob = moved(scene.obj, o)
        for m, c in cfgs.items():
            stats[m].append(eng.render(ob, c).stats)
    for m in modes:
        t = np.array([s["frame_s"] for s in stats[m][1:]]) * 1e3
        out["modes"][m].update(mean_ms=float(t.mean()), p95_ms=float(np.percentile(t, 95)),
                               stages_ms={k: round(v, 1) for k, v in path_stages_ms(stats[m][1:]).items()})
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", default="window_room,lamps_room,sun_room")
    ap.add_argument("--modes", default="maps,spheres")
    ap.add_argument("--path", type=int, default=12)
    ap.add_argument("--no-all", action="store_true")
    ap.add_argument("--out", default=None)
    a = ap.parse_args()
    res = []
    for name in a.scenes.split(","):
        r = run_scene(name, a.modes.split(","), a.path, not a.no_all)
        res.append(r)
        al = r.get("all")
        bound = f"bound rmse <= {1.5 * al['score'][1] + 0.5:.2f}" if al else ""
        print(f"{name}: all {al['score'] if al else '-'} ({al['frame_s']:.2f} s) {bound}" if al else name, flush=True)
        for m, v in r["modes"].items():
            print(f"  {m:10s} energy/rmse {v['score']}  path mean/p95 {v['mean_ms']:.0f}/{v['p95_ms']:.0f} ms  "
                  f"{v['stages_ms']}", flush=True)
    if a.out:
        Path(a.out).write_text(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
