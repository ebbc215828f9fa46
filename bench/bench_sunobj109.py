"""The object's sun through the openings: the disk's centre (the rule before) against the share of the sun's
disk each opening passes (issue 34, branch sunobj109), under known light at rest.

For each room one Engine (`--lighting known`: the benchmark folder's own camera and declared light), then the
frame at rest (`evaluate --passes all`) rendered with SunLight.tan_a forced to 0 ("centre": the ray toward the
disk's centre, main's rule, byte for byte) and as it is ("disk"), in turns; scored by lighting.metrics against
truth.png (energy / rmse_affected / spurious / rmse_object (bias)), sha256 of the pixels. --cost N: the object's
per-frame sun terms (ObjectShading._vertex_radiance and shade, which hold every call of the change) timed N rounds
per variant, interleaved, CPU ms (process_time), median.

    python bench/bench_sunobj109.py ROOM [ROOM ...] [--drag] [--cost 5] [--save DIR]
"""
from __future__ import annotations

import argparse
import dataclasses
import gc
import hashlib
import time
from pathlib import Path

import numpy as np


def _report(a, room: Path, name: str, frame: str, fr, scene, truth: np.ndarray, mask: np.ndarray) -> None:
    """Print one frame's scores (energy / rmse_affected / spurious / rmse_object (bias)) and hash; save it (--save)."""
    import cv2

    from lighting import metrics

    sc = metrics.score_regions(fr.pixels, scene.photo, truth, mask)
    h = hashlib.sha256(np.ascontiguousarray(fr.pixels).tobytes()).hexdigest()[:8]
    # the bias of rmse_object: ours - truth over score.py's object region, blurred luminance
    lum = lambda x: cv2.GaussianBlur(x.astype(np.float64) @ np.array([0.2126, 0.7152, 0.0722]), (0, 0), 2)
    reg = metrics.object_region(np.where(mask > 127, 255, 0).astype(np.uint8))
    bias = float((lum(fr.pixels) - lum(truth))[reg].mean())
    if a.save is not None:
        from recon.io import write_png

        a.save.mkdir(parents=True, exist_ok=True)
        write_png(a.save / f"{room.name}_{name}_{frame}.png", fr.pixels)
    print(f"{room.name} {name} {frame}: {sc['energy_ratio']:.3f} / {sc['rmse_affected']:.2f} / {sc['spurious']:.4f} / "
          f"{sc['rmse_object']:.2f} ({bias:+.2f})  sha {h}", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("rooms", nargs="+", type=Path)
    ap.add_argument("--cost", type=int, default=0, help="rounds of the per-frame object shading timing")
    ap.add_argument("--save", type=Path, default=None, help="write each composite here")
    ap.add_argument("--drag", action="store_true", help="also the drag frame at the scene's pose (evaluate --path's "
                    "drag row: rendered twice, the second scored)")
    a = ap.parse_args()

    import cv2

    from app.composite import default_cache_dir
    from app.config import DRAG_PASSES, DRAG_SCALE, DRAG_SHADOW
    from app.engine import Engine, EngineParams
    from app.stages import object_shading as os_mod
    from lighting import metrics
    from lighting.sun import SunLight
    from recon.io import read_image_rgb
    from recon.scene import load_scene

    disk_tan = SunLight.tan_a
    variants = {"centre": property(lambda self: 0.0), "disk": disk_tan}
    orig_vr, orig_shade = os_mod.ObjectShading._vertex_radiance, os_mod.ObjectShading.shade
    last: dict = {}

    def rec_vr(self, *args):
        last["vr"] = args
        return orig_vr(self, *args)

    def rec_shade(self, *args, **kw):
        last["shade"] = (args, kw)
        return orig_shade(self, *args, **kw)

    os_mod.ObjectShading._vertex_radiance, os_mod.ObjectShading.shade = rec_vr, rec_shade
    for room in a.rooms:
        scene = load_scene(room)
        engine = Engine(scene, EngineParams(lighting="known"), cache_dir=default_cache_dir(), quiet=True)
        truth = read_image_rgb(room / "truth.png")
        mask = cv2.imread(str(room / "truth_mask.png"), cv2.IMREAD_GRAYSCALE)
        cfg = dataclasses.replace(engine.frame_config(), passes=None)
        drag_cfg = dataclasses.replace(engine.frame_config(), passes=DRAG_PASSES, drag=DRAG_SCALE,
                                       drag_shadow=DRAG_SHADOW)
        calls = {}
        for name, prop in variants.items():
            SunLight.tan_a = prop
            fr = engine.render(scene.obj, cfg)
            calls[name] = (last["vr"], last["shade"])
            frames = {"rest": fr}
            if a.drag:
                engine.render(scene.obj, drag_cfg)
                frames["drag"] = engine.render(scene.obj, drag_cfg)
            for frame, fr in frames.items():
                _report(a, room, name, frame, fr, scene, truth, mask)
        if a.cost and engine.object_shading.sun is not None:
            ms: dict[str, list[float]] = {n: [] for n in variants}
            for _ in range(a.cost):
                for name, prop in variants.items():
                    SunLight.tan_a = prop
                    vr, (sargs, skw) = calls[name]
                    t = time.process_time()
                    orig_vr(engine.object_shading, *vr)
                    orig_shade(engine.object_shading, *sargs, **skw)
                    ms[name].append(1e3 * (time.process_time() - t))
            print(f"{room.name} object shading (vertex radiance + shade) CPU ms, median of {a.cost}: "
                  + ", ".join(f"{n} {np.median(v):.1f}" for n, v in ms.items()), flush=True)
        SunLight.tan_a = disk_tan
        del engine
        gc.collect()


if __name__ == "__main__":
    main()
