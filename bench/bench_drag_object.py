"""The drag frame's object from per-shape tables against the object as at rest (issue 36 item 2): A/B in one process.

usage: python bench/bench_drag_object.py [--scenes window_room,lamps_room,sun_room | DIR,...] [--path 6]
                                         [--passes 64] [--out FILE.json]

Per scene (a shared scene's name or a benchmark folder, e.g. ~/.cache/photoar/rooms/sun_101) one Engine; the
drag frame (FrameConfig(passes, drag=DRAG_SCALE)) with Engine.drag_object_tables True ("tables":
app.stages.object_drag), the same with the object light's far field per triangle ("far_each": ObjectLight.far_cells
None, the drag frame before DRAG_FAR_CELLS) and with drag_object_tables False ("rest": the object shaded and its
light sent as at rest) rendered alternately along a drag of --path poses (app.dragpath; the first pose excluded).
Prints per configuration the path's mean object_shading / object_light / frame ms, the process's CPU time per
frame ("cpu": all its threads; steadier than the wall time under load) and the frame's time outside Warp kernels
("python", app.glue), and at the scene's own pose the drag frame's error: rmse of the object's pixels (8-bit
levels, pixels the all-sources frame covers fully) against the all-sources frame's, and the truth's rmse_object /
rmse_affected / energy_ratio (lighting.metrics, tools/score.py's measures). Timings depend on the machine's load:
compare the rows of one run.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.composite import default_cache_dir  # noqa: E402
from app.config import DRAG_SCALE  # noqa: E402
from app.stages.object_light import DRAG_FAR_CELLS  # noqa: E402
from app.dragpath import drag_offsets, moved  # noqa: E402
from app.engine import Engine, EngineParams, FrameConfig  # noqa: E402
from bench.bench_drag import scene_dir  # noqa: E402
from lighting import metrics  # noqa: E402
from recon.io import read_image_rgb  # noqa: E402
from recon.scene import load_scene  # noqa: E402


def object_rmse(a: np.ndarray, b: np.ndarray, cov: np.ndarray) -> float:
    """rmse (8-bit levels) of two frames' pixels over the pixels the object covers fully (cov (H,W) >= 1)."""
    m = cov >= 1.0
    return float(np.sqrt(np.mean((a[m].astype(np.float64) - b[m].astype(np.float64)) ** 2)))


def bench_scene(d: Path, n_path: int, passes: int, rounds: int = 2) -> dict:
    import cv2

    scene = load_scene(d)
    eng = Engine(scene, EngineParams(), cache_dir=default_cache_dir(), quiet=True)
    truth = read_image_rgb(d / "truth.png")
    mask = cv2.imread(str(d / "truth_mask.png"), cv2.IMREAD_GRAYSCALE)
    full = eng.render(scene.obj, FrameConfig())
    cfg = FrameConfig(passes=passes, drag=DRAG_SCALE)
    offsets = drag_offsets(scene, scene.obj, n_path)
    out = {"scene": str(d), "all_sources": metrics.score_regions(full.pixels, scene.photo, truth, mask), "rows": {}}
    times = {k: [] for k in ("tables", "far_each", "rest")}
    ol = eng.pixel_stages(DRAG_SCALE).object_light
    for r in range(rounds):
        for name in times:
            eng.drag_object_tables = name != "rest"
            ol.far_cells = None if name == "far_each" else DRAG_FAR_CELLS
            fr = eng.render(scene.obj, cfg)
            if r == 0:
                s = metrics.score_regions(fr.pixels, scene.photo, truth, mask)
                out["rows"][name] = {"object_vs_all_sources": object_rmse(fr.pixels, full.pixels, full.coverage),
                                     **{k: float(s[k]) for k in ("rmse_object", "rmse_affected", "energy_ratio")}}
            for o in offsets[1:]:
                c0 = time.process_time()
                st = eng.render(moved(scene.obj, o), cfg).stats
                times[name].append({**st, "cpu_s": time.process_time() - c0})
    for name, st in times.items():
        row = out["rows"][name]
        for k in ("object_shading", "object_light"):
            row[k + "_ms"] = 1e3 * float(np.mean([s["timings"][k] for s in st]))
        row["frame_ms"] = 1e3 * float(np.mean([s["frame_s"] for s in st]))
        row["cpu_ms"] = 1e3 * float(np.mean([s["cpu_s"] for s in st]))  # the process's CPU time, all its threads
        row["python_ms"] = 1e3 * float(np.mean([s["frame_s"] - s["kernel_s"] for s in st]))  # app.glue
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default="window_room,lamps_room,sun_room")
    ap.add_argument("--path", type=int, default=6)
    ap.add_argument("--passes", type=int, default=64)
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args()
    results = []
    for name in a.scenes.split(","):
        res = bench_scene(scene_dir(name), a.path, a.passes)
        al = res["all_sources"]
        print(f"\n{res['scene']}: all sources rmse_object {al['rmse_object']:.2f}, rmse_affected "
              f"{al['rmse_affected']:.2f}, energy {al['energy_ratio']:.3f}")
        print(f"{'object':>8} {'shading ms':>10} {'light ms':>9} {'frame ms':>9} {'cpu ms':>7} {'python ms':>9}  "
              f"{'obj vs all':>10} "
              f"{'rmse_obj':>8} {'rmse_aff':>8} {'energy':>7}")
        for name, r in res["rows"].items():
            print(f"{name:>8} {r['object_shading_ms']:10.1f} {r['object_light_ms']:9.1f} {r['frame_ms']:9.1f} "
                  f"{r['cpu_ms']:7.1f} "
                  f"{r['python_ms']:9.1f}  "
                  f"{r['object_vs_all_sources']:10.2f} {r['rmse_object']:8.2f} {r['rmse_affected']:8.2f} "
                  f"{r['energy_ratio']:7.3f}")
        sys.stdout.flush()
        results.append(res)
    if a.out is not None:
        from recon.io import write_json

        write_json(a.out, results)


if __name__ == "__main__":
    main()
