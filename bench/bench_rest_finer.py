"""Refine's finer frame at rest (issue 36, item 5; rest48): its clusters split near the object first or by the
plain key, scored against the truth next to the all-sources frame, in one process.

usage: python bench/bench_rest_finer.py ROOM [--variants all,near,plain] [--passes 100] [--repeat 0]

ROOM: a shared scene's name or a benchmark folder with truth.png and truth_mask.png. Variants: all (the all-sources
frame), near (FrameConfig(passes, full_maps=True) with Engine.rest_near_split: the near split in rooms a sun lights,
app.progressive.finer_near_split), plain (rest_near_split False: the plain key). Prints per variant energy_ratio /
rmse_affected (and its difference from the all-sources frame's: within CONVERGE_RMSE = 0.05 is "all-source
quality") / spurious / rmse_object, and with --repeat N the medians of N rounds (variants interleaved) of the
frame's process CPU seconds (both cores: steadier under load than its wall time), wall seconds and masks stage.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main(argv=None) -> int:
    import cv2

    from app.composite import default_cache_dir
    from app.config import FrameConfig
    from app.engine import Engine, EngineParams
    from bench.bench_rest import scene_dir
    from lighting import metrics
    from recon.io import read_image_rgb
    from recon.scene import load_scene

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("room")
    ap.add_argument("--variants", default="all,near,plain")
    ap.add_argument("--passes", type=int, default=100)
    ap.add_argument("--repeat", type=int, default=0)
    a = ap.parse_args(argv)
    variants = a.variants.split(",")
    path = scene_dir(a.room)
    scene = load_scene(path)
    eng = Engine(scene, EngineParams(), cache_dir=default_cache_dir(), quiet=True)
    truth = read_image_rgb(path / "truth.png")
    mask = cv2.imread(str(path / "truth_mask.png"), cv2.IMREAD_GRAYSCALE)
    mode = eng.frame_config().mode

    def config(v: str) -> FrameConfig:
        if v == "all":
            return FrameConfig(None, mode)
        eng.rest_near_split = v == "near"
        return FrameConfig(a.passes, mode, full_maps=True)

    times: dict[str, list] = {v: [] for v in variants}
    scores: dict[str, dict] = {}
    for rnd in range(a.repeat + 1):
        for v in (variants if rnd % 2 == 0 else variants[::-1]):
            cfg = config(v)
            c0 = time.process_time()
            fr = eng.render(scene.obj, cfg)
            cpu = time.process_time() - c0
            if rnd == 0:  # warm; the frames are deterministic: scored once
                scores[v] = metrics.score_regions(fr.pixels, scene.photo, truth, mask)
            else:
                times[v].append((cpu, fr.stats["frame_s"], fr.stats["timings"]["masks"]))
    ref = scores["all"]["rmse_affected"] if "all" in scores else float("nan")
    for v in variants:
        s = scores[v]
        m = np.median(np.array(times[v]), 0) if times[v] else [float("nan")] * 3
        print(f"{path.name:12s} {v:6s} energy {s['energy_ratio']:.4f} rmse_affected {s['rmse_affected']:.4f} "
              f"(vs all {s['rmse_affected'] - ref:+.4f}) spurious {s['spurious']:.4f} rmse_object "
              f"{s['rmse_object']:.3f}  CPU {m[0]:.2f} s wall {m[1]:.2f} s masks {m[2]:.2f} s", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
