"""Patch size against error and cost: the measurement behind EngineParams.patch_size.

usage: python bench/bench_patch_size.py [--shared ../shared] [--sizes 0.5 0.35 0.25 0.18 0.125]

For each shared scene and patch size: uncached precompute time, frame time (all sources, HDR
path) and the scorer's figures. Prints a table, writes out/bench/patch_size.json and a plot.
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.engine import Engine, EngineParams  # noqa: E402
from app.report import plot_xy, table  # noqa: E402
from bench import shared_scenes  # noqa: E402
from bench.bench_engine import scored_row  # noqa: E402
from recon.scene import load_scene  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--shared", type=Path, default=ROOT.parent / "shared")
    ap.add_argument("--out", type=Path, default=ROOT / "out" / "bench")
    ap.add_argument("--scenes", nargs="+", default=["window_room", "lamps_room"])
    ap.add_argument("--sizes", nargs="+", type=float, default=[0.5, 0.35, 0.25, 0.18, 0.125])
    a = ap.parse_args()
    a.out.mkdir(parents=True, exist_ok=True)
    rows, curves = [], {}
    for name, scene_dir in shared_scenes(a.shared, a.scenes):
        scene = load_scene(scene_dir)
        xs, ys = [], []
        for size in a.sizes:
            with tempfile.TemporaryDirectory() as cache:
                engine = Engine(scene, EngineParams(patch_size=size), cache_dir=cache, quiet=True)
            engine.render(scene.obj)
            frame = engine.render(scene.obj)
            row = scored_row(a.shared, scene_dir, a.out / f"{name}_patch{size}.png", frame, scene=name,
                             patch_m=size, patches=frame.stats["n_patches"], precompute_s=engine.pre.seconds)
            rows.append(row)
            xs.append(row["frame_s"])
            ys.append(row["rmse_affected"])
            print(table([row], list(row)), flush=True)
        curves[name] = (xs, ys)
    if rows:
        print("\npatch size against error and cost (HDR path, all sources)")
        print(table(rows, list(rows[0])))
        (a.out / "patch_size.json").write_text(json.dumps(rows, indent=2))
        plot_xy(curves, "frame time (s)", "rmse_affected (8-bit levels)", a.out / "patch_size.png",
                title="patch sizes 0.5 .. 0.125 m")


if __name__ == "__main__":
    main()
