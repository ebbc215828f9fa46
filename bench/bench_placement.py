"""Placement benchmark: frame time while dragging an object across the floor.

usage: python bench/bench_placement.py [--scenes demo window_room] [--passes 10 20 50 0] [--steps 6]
                                       [--cache out/.cache] [--out out/bench_placement]

Drives app.placement.PlacementController as the window does during a drag (one move_to_pixel
per mouse step along a line of floor pixels, then one composite of the newest pose), for each
pass budget (0 = all sources). Kept frames are bypassed: every step runs the engine. Prints a
table (mean / max seconds per step, engine phases) and writes results.json into --out. The GUI
adds the image upload to this (a few ms; the window's frame label shows the same figure).
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.cli import demo_scene_dir  # noqa: E402
from app.engine import EngineParams  # noqa: E402
from app.placement import PlacementController  # noqa: E402
from app.report import table  # noqa: E402


def drag(ctl: PlacementController, steps: int) -> list[dict]:
    """Drag the object along a line of pixels across the lower image; one frame per step."""
    cam = ctl.scene.camera
    W, H = cam.width, cam.height
    us = np.linspace(0.35 * W, 0.6 * W, steps)
    vs = np.linspace(0.80 * H, 0.75 * H, steps)
    ctl.place_at_pixel(us[0], vs[0])
    ctl.begin_gesture()
    out = []
    for u, v in zip(us, vs):
        t0 = time.perf_counter()
        ctl.move_to_pixel(u, v)
        ctl.clear_frames()
        fr = ctl.render()
        out.append({"step_s": time.perf_counter() - t0, "engine_s": fr.stats["engine_s"],
                    "passes": fr.stats["passes"], **{k: v for k, v in fr.stats.get("timings", {}).items()}})
    ctl.end_gesture()
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="+", default=["demo", "window_room"])
    ap.add_argument("--shared", type=Path, default=ROOT.parent / "shared")
    ap.add_argument("--passes", type=int, nargs="+", default=[10, 20, 50, 0])
    ap.add_argument("--steps", type=int, default=6)
    ap.add_argument("--cache", type=Path, default=ROOT / "out" / ".cache")
    ap.add_argument("--out", type=Path, default=ROOT / "out" / "bench_placement")
    a = ap.parse_args()
    rows = []
    for name in a.scenes:
        path = demo_scene_dir() if name == "demo" else a.shared / "scenes" / name
        if not (path / "scene.json").is_file():
            print(f"skip {name}: {path} not found")
            continue
        ctl = PlacementController.open(path, params=EngineParams(passes=a.passes[0]), cache_dir=a.cache)
        t0 = time.perf_counter()
        eng = ctl.start_engine()
        pre_s = time.perf_counter() - t0
        ctl.set_object(ctl.scene.obj.source)
        for p in a.passes:
            ctl.set_budget(p or None)
            ctl.render()  # warm-up: kernels compiled, per-budget structures built
            steps = drag(ctl, a.steps)
            s = np.array([r["step_s"] for r in steps])
            phases = {k: float(np.mean([r.get(k, 0.0) for r in steps])) for k in steps[0]
                      if k not in ("step_s", "engine_s", "passes")}
            top = sorted(phases.items(), key=lambda kv: -kv[1])[:3]
            rows.append({"scene": name, "size": f"{ctl.scene.camera.width}x{ctl.scene.camera.height}",
                         "budget": p or "all", "passes": steps[-1]["passes"], "mean_s": float(s.mean()),
                         "max_s": float(s.max()), "fps": float(1 / s.mean()), "precompute_s": pre_s,
                         "cache_hit": eng.cache_hit, "slowest": ", ".join(f"{k} {v:.2f}" for k, v in top)})
            print(table(rows[-1:], list(rows[-1])), flush=True)
    print(table(rows, ["scene", "size", "budget", "passes", "mean_s", "max_s", "fps", "precompute_s", "slowest"]))
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "results.json").write_text(json.dumps(rows, indent=2, default=str) + "\n")


if __name__ == "__main__":
    main()
