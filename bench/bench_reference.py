"""Reference benchmark: the path-traced reference at the truth's noise vs photoar's frame.

usage: python bench/bench_reference.py [--shared ../shared] [--out out/bench_reference]
                                       [--pilot-spp 16] [--max-spp 256] [--scenes ...]

Per shared scene:
  1. a pilot reference (kernels.pathtrace via app.cmd_reference) at --pilot-spp; its standard
     error of luminance(I_noobj - I_obj) over the truth's shadow region (outside the dilated
     mask, truth < 0.85 background: the definition of scene.json's
     stats.shadow_difference_noise_final) gives the spp whose noise matches the truth's,
     spp = pilot * (noise_pilot / noise_truth)^2 (capped at --max-spp);
  2. the reference at that spp: render time, its own noise estimate, score.py's figures;
  3. photoar's engine frame (precompute cached) with EngineParams(passes=50) and with all
     sources: frame time and score.py's figures;
and one table: speed ratio (reference time / frame time) beside both sets of errors. Writes
results.json, the reference PNGs and error heat-maps (against truth.png) into --out.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.cmd_reference import LUM, build_tracer, render_reference  # noqa: E402
from app.engine import Engine, EngineParams  # noqa: E402
from app.report import table  # noqa: E402
from lighting import metrics  # noqa: E402
from recon.io import read_exr, read_image_rgb, write_png  # noqa: E402
from recon.scene import load_scene  # noqa: E402


def truth_shadow_region(scene_dir: Path) -> np.ndarray:
    """(H*W,) bool: the benchmark's shadow region (outside the dilated mask, truth < 0.85 bg)."""
    import cv2

    bg = read_exr(scene_dir / "background.exr") @ LUM
    tr = read_exr(scene_dir / "truth.exr") @ LUM
    mask = metrics.object_region(cv2.imread(str(scene_dir / "truth_mask.png"), cv2.IMREAD_GRAYSCALE))
    return (~mask & (tr < 0.85 * bg)).reshape(-1)


def shadow_noise(ref, region: np.ndarray) -> float:
    se = ref.noise_diff.reshape(-1, 3) @ LUM
    return float(np.sqrt(np.mean(se[region] ** 2)))


def scores(scene_dir: Path, pixels: np.ndarray) -> dict:
    bg, tr = read_image_rgb(scene_dir / "background.png"), read_image_rgb(scene_dir / "truth.png")
    import cv2

    mk = cv2.imread(str(scene_dir / "truth_mask.png"), cv2.IMREAD_GRAYSCALE)
    s = metrics.score_regions(pixels, bg, tr, mk)
    s["ssim_affected"] = metrics.ssim(pixels, tr, metrics.regions(bg, tr, mk)["affected"])
    return s


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--shared", type=Path, default=ROOT.parent / "shared")
    ap.add_argument("--out", type=Path, default=ROOT / "out" / "bench_reference")
    ap.add_argument("--scenes", nargs="+", default=["window_room", "lamps_room"])
    ap.add_argument("--pilot-spp", type=int, default=16)
    ap.add_argument("--max-spp", type=int, default=256)
    ap.add_argument("--cache", type=Path, default=ROOT / "out" / ".cache")
    a = ap.parse_args()
    a.out.mkdir(parents=True, exist_ok=True)
    rows, results = [], []
    for name in a.scenes:
        scene_dir = a.shared / "scenes" / name
        scene = load_scene(scene_dir)
        stats = json.loads((scene_dir / "scene.json").read_text())["stats"]
        truth_noise = float(stats["shadow_difference_noise_final"])
        region = truth_shadow_region(scene_dir)
        tracer = build_tracer(scene)
        tracer.render(np.arange(16), 1)  # compile outside the timings
        pilot = render_reference(scene, a.pilot_spp, seed=11, tracer=tracer, quiet=True)
        pilot_noise = shadow_noise(pilot, region)
        spp = int(min(a.max_spp, math.ceil(a.pilot_spp * (pilot_noise / truth_noise) ** 2)))
        print(f"{name}: pilot {a.pilot_spp} spp noise {pilot_noise:.4f} (truth {truth_noise:.4f}) -> {spp} spp",
              flush=True)
        ref = render_reference(scene, spp, seed=1, tracer=tracer, quiet=True)
        png = a.out / f"{name}_reference.png"
        write_png(png, ref.pixels)
        tr = read_image_rgb(scene_dir / "truth.png")
        write_png(a.out / f"{name}_reference_error.png", metrics.error_heatmap(ref.pixels, tr, sigma=2.0))
        s_ref = scores(scene_dir, ref.pixels)
        res = {"scene": name, "truth_noise": truth_noise, "pilot_spp": a.pilot_spp, "pilot_noise": pilot_noise,
               "spp": ref.spp, "ref_noise": shadow_noise(ref, region), "ref_render_s": ref.stats["render_s"],
               "ref_stats": ref.stats, "ref_scores": s_ref, "engine": []}
        rows.append({"scene": name, "method": f"reference {ref.spp} spp", "time_s": ref.stats["render_s"],
                     "speed_ratio": 1.0, "noise": res["ref_noise"], **{k: s_ref[k] for k in
                     ("energy_ratio", "rmse_affected", "spurious", "rmse_object", "ssim_affected")}})
        for passes in (50, None):
            eng = Engine(scene, EngineParams(passes=passes), cache_dir=a.cache, quiet=True)
            eng.render(scene.obj)  # warm-up (kernel compiles, SH volume)
            t = time.perf_counter()
            frame = eng.render(scene.obj)
            frame_s = time.perf_counter() - t
            s = scores(scene_dir, frame.pixels)
            write_png(a.out / f"{name}_engine_{passes or 'all'}.png", frame.pixels)
            res["engine"].append({"passes": passes, "frame_s": frame_s, "scores": s,
                                  "vs_reference": metrics.compare(frame.pixels, ref.pixels)})
            rows.append({"scene": name, "method": f"photoar passes={passes or 'all'}", "time_s": frame_s,
                         "speed_ratio": ref.stats["render_s"] / frame_s, "noise": "",
                         **{k: s[k] for k in ("energy_ratio", "rmse_affected", "spurious", "rmse_object",
                                              "ssim_affected")}})
        results.append(res)
        print(table(rows, ["scene", "method", "time_s", "speed_ratio", "noise", "energy_ratio", "rmse_affected",
                           "spurious", "rmse_object", "ssim_affected"]), flush=True)
    (a.out / "results.json").write_text(json.dumps(results, indent=2, default=float) + "\n")
    print("\nspeed_ratio = reference render time / photoar frame time (2-core CPU, Warp single-threaded per launch);"
          "\nnoise = RMS standard error of luminance(I_noobj - I_obj) over the truth's shadow region "
          "(radiance units, the truth's own: see truth_noise in results.json).")


if __name__ == "__main__":
    main()
