"""Engine benchmark: precompute time, frame time and error against the truth, ray throughput.

usage: python bench/bench_engine.py [--shared ../shared] [--out out/bench] [--passes 4 16 64 256 0]

For each shared scene: the uncached precompute, then one frame per pass limit (0 = all sources)
scored with ../shared/tools/score.py; the visibility kernel's Mrays/s (Warp) beside Open3D's
RaycastingScene (Embree) on the same segments. Prints tables, writes results.json and a
frame-time-vs-error plot (speed_vs_error.png) into --out.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.engine import Engine, EngineParams, FrameConfig  # noqa: E402
from app.report import plot_xy, table  # noqa: E402
from bench import shared_scenes  # noqa: E402
from kernels.visibility import segments_visible  # noqa: E402
from recon.io import write_png  # noqa: E402
from recon.scene import load_scene  # noqa: E402


def score(shared: Path, scene_dir: Path, png: Path) -> dict:
    out = subprocess.run([sys.executable, str(shared / "tools" / "score.py"), str(scene_dir), str(png)],
                         capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def scored_row(shared: Path, scene_dir: Path, png: Path, frame, **first) -> dict:
    """Write the frame's picture, score it against the truth, and return a table row that starts
    with `first` and ends with frame time and the scorer's figures."""
    write_png(png, frame.pixels)
    s = score(shared, scene_dir, png)
    return {**first, "frame_s": frame.stats["frame_s"], "energy_ratio": s["energy_ratio"],
            "rmse_affected": s["rmse_affected"], "rmse_untouched": s["rmse_affected_if_untouched"],
            "spurious": s["spurious"], "rmse_object": s["rmse_object"]}


def ray_throughput(engine: Engine, n: int = 1_000_000, seed: int = 0) -> dict:
    """Mrays/s of segment occlusion tests inside the room: Warp kernel vs Open3D/Embree."""
    import open3d as o3d

    pm = engine.pre.patches
    rng = np.random.default_rng(seed)
    lo, hi = engine.scene.room_min + 0.01, engine.scene.room_max - 0.01
    a = rng.uniform(lo, hi, (n, 3)).astype(np.float32)
    b = rng.uniform(lo, hi, (n, 3)).astype(np.float32)
    occ = engine.scene_occ
    segments_visible(occ, a[:1000], b[:1000])  # compile / warm up
    t = time.perf_counter()
    vis_wp = segments_visible(occ, a, b)
    t_wp = time.perf_counter() - t
    solid = ~pm.is_emitter[pm.tri_patch]
    rs = o3d.t.geometry.RaycastingScene()
    rs.add_triangles(o3d.core.Tensor(pm.vert_pos.astype(np.float32)), o3d.core.Tensor(pm.tris[solid].astype(np.uint32)))
    d = b - a
    rays = o3d.core.Tensor(np.concatenate([a, d], 1))
    rs.test_occlusions(rays[:1000], tfar=0.9999)
    t = time.perf_counter()
    occl = rs.test_occlusions(rays, tfar=0.9999).numpy()
    t_o3d = time.perf_counter() - t
    agree = float(np.mean((vis_wp == 1) == ~occl))
    return {"rays": n, "warp_mrays_s": n / t_wp / 1e6, "open3d_embree_mrays_s": n / t_o3d / 1e6, "agreement": agree}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--shared", type=Path, default=ROOT.parent / "shared")
    ap.add_argument("--out", type=Path, default=ROOT / "out" / "bench")
    ap.add_argument("--scenes", nargs="+", default=["window_room", "lamps_room"])
    ap.add_argument("--passes", nargs="+", type=int, default=[4, 16, 64, 256, 0])
    ap.add_argument("--mode", choices=["hdr", "ldr"], default="hdr")
    a = ap.parse_args()
    a.out.mkdir(parents=True, exist_ok=True)
    results, ray_rows, curves = [], [], {}
    for name, scene_dir in shared_scenes(a.shared, a.scenes):
        scene = load_scene(scene_dir)
        with tempfile.TemporaryDirectory() as cache:
            engine = Engine(scene, EngineParams(mode=a.mode), cache_dir=cache, quiet=True)
        ray_rows.append({"scene": name, **ray_throughput(engine)})
        xs, ys = [], []
        for passes in a.passes:
            cfg = FrameConfig(passes=passes or None, mode=a.mode)  # EngineParams is frozen: a frame config each
            engine.render(scene.obj, cfg)  # warm: kernels compiled, caches filled
            frame = engine.render(scene.obj, cfg)
            row = scored_row(a.shared, scene_dir, a.out / f"{name}_p{passes}.png", frame, scene=name,
                             passes=frame.stats["passes"], precompute_s=engine.precompute_s,
                             masks_s=frame.stats["timings"]["masks"])
            results.append(row)
            xs.append(row["frame_s"])
            ys.append(row["rmse_affected"])
            print(table([row], list(row)), flush=True)
        curves[name] = (xs, ys)
    if not results:
        print("no scenes found; pass --shared")
        return
    print("\nspeed against error (HDR path, all terms on)")
    print(table(results, list(results[0])))
    print("\nvisibility rays (segment occlusion tests inside the room)")
    print(table(ray_rows, list(ray_rows[0])))
    (a.out / "results.json").write_text(json.dumps({"frames": results, "rays": ray_rows}, indent=2))
    plot_xy(curves, "frame time (s)", "rmse_affected (8-bit levels)", a.out / "speed_vs_error.png",
            title="passes 4..all, lower-left is better")
    print(f"\nwrote {a.out / 'results.json'} and {a.out / 'speed_vs_error.png'}")


if __name__ == "__main__":
    main()
