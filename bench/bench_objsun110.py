"""The sun's loss beside the object's foot gathered per sample point's cell (issue 34, branch objsun110): the
frame at rest under known light with ObjectConfig.sun_cells off ("patch": each sun-lost patch whole, main's rule)
and on ("cells": the patches near the object as the cells of their sun sample points), in turns, one Engine per room.

Scores (lighting.metrics against truth.png): energy / rmse_affected / spurious / rmse_object (bias: ours - truth
over score.py's object region, blurred luminance), sha256 of the pixels. --drag: the drag frame too (evaluate
--path's: rendered twice, the second scored). --cost N: ObjectShading._vertex_radiance on the frame at rest's own
arguments, N rounds per variant interleaved, CPU ms (process_time), median. --foot: mean luminance of the object's
pixels per height above the floor (camera hits; 0-2, 2-4, 4-7, 7-10, 10-20 cm), truth and ours.

    python bench/bench_objsun110.py ROOM [ROOM ...] [--drag] [--cost 3] [--foot] [--lighting captured] [--save DIR]
"""
from __future__ import annotations

import argparse
import dataclasses
import gc
import hashlib
import time
from pathlib import Path

import numpy as np

BANDS = (0.0, 0.02, 0.04, 0.07, 0.10, 0.20)


def _scores(fr, scene, truth: np.ndarray, mask: np.ndarray) -> str:
    """energy / rmse_affected / spurious / rmse_object (bias) of one frame and its hash."""
    import cv2

    from lighting import metrics

    sc = metrics.score_regions(fr.pixels, scene.photo, truth, mask)
    h = hashlib.sha256(np.ascontiguousarray(fr.pixels).tobytes()).hexdigest()[:8]
    lum = lambda x: cv2.GaussianBlur(x.astype(np.float64) @ np.array([0.2126, 0.7152, 0.0722]), (0, 0), 2)
    reg = metrics.object_region(np.where(mask > 127, 255, 0).astype(np.uint8))
    bias = float((lum(fr.pixels) - lum(truth))[reg].mean())
    return (f"{sc['energy_ratio']:.3f} / {sc['rmse_affected']:.2f} / {sc['spurious']:.4f} / "
            f"{sc['rmse_object']:.2f} ({bias:+.2f})  sha {h}")


def _foot(engine, fr, truth: np.ndarray, mask: np.ndarray) -> str:
    """Mean luminance (truth / ours) of the object's unblurred pixels (mask, fully covered) per height band of the
    camera hit above the floor (y = 0), faces that are not horizontal only."""
    os_ = engine.object_shading
    mesh = engine.last_shading[0]
    v, n, f = mesh
    hits = os_.object_hits(v, f, supersample=1)
    u0, v0, u1, v1 = hits.rect
    h = hits.hit
    tri = hits.tri
    pos = np.einsum("nk,nkc->nc", hits.bary, v[f[np.maximum(tri, 0)]])
    nrm_y = np.abs(n[f[np.maximum(tri, 0)]].mean(1)[:, 1])
    ww = u1 - u0 + 1
    idx = np.arange(len(h))
    py, px = v0 + idx // ww, u0 + idx % ww
    lumw = np.array([0.2126, 0.7152, 0.0722])
    ok = h & (nrm_y < 0.5) & (mask[py, px] > 127)
    out = []
    for a, b in zip(BANDS[:-1], BANDS[1:]):
        s = ok & (pos[:, 1] >= a) & (pos[:, 1] < b)
        if s.any():
            t = float((truth[py[s], px[s]] @ lumw).mean())
            o = float((fr.pixels[py[s], px[s]] @ lumw).mean())
            out.append(f"{100 * a:.0f}-{100 * b:.0f} cm {t:.0f}/{o:.0f} ({s.sum()} px)")
    return "; ".join(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("rooms", nargs="+", type=Path)
    ap.add_argument("--cost", type=int, default=0, help="rounds of the per-frame vertex radiance timing")
    ap.add_argument("--drag", action="store_true", help="also the drag frame at the scene's pose")
    ap.add_argument("--foot", action="store_true", help="luminance per height above the floor")
    ap.add_argument("--variants", default="patch,cells", help="patch (main's rule), cells (the sun's loss per "
                    "sample point's cell near the object)")
    ap.add_argument("--lighting", default="known", help="known (the folder's declared light) or captured (the "
                    "probes; the folder's own camera: bench_unseen's true-camera row)")
    ap.add_argument("--save", type=Path, default=None, help="write each composite here")
    a = ap.parse_args()

    import cv2

    from app.composite import default_cache_dir
    from app.config import DRAG_PASSES, DRAG_SCALE, DRAG_SHADOW
    from app.engine import Engine, EngineParams
    from app.stages import object_shading as os_mod
    from recon.io import read_image_rgb
    from recon.scene import load_scene

    orig_vr = os_mod.ObjectShading._vertex_radiance
    last: dict = {}

    def rec_vr(self, *args):
        last["vr"] = args
        return orig_vr(self, *args)

    os_mod.ObjectShading._vertex_radiance = rec_vr
    for room in a.rooms:
        scene = load_scene(room)
        engine = Engine(scene, EngineParams(lighting=a.lighting), cache_dir=default_cache_dir(), quiet=True)
        truth = read_image_rgb(room / "truth.png")
        mask = cv2.imread(str(room / "truth_mask.png"), cv2.IMREAD_GRAYSCALE)
        cfg = dataclasses.replace(engine.frame_config(), passes=None)
        drag_cfg = dataclasses.replace(engine.frame_config(), passes=DRAG_PASSES, drag=DRAG_SCALE,
                                       drag_shadow=DRAG_SHADOW)
        oc = engine.object_shading.config
        allv = {"patch": dataclasses.replace(oc, sun_cells=False), "cells": dataclasses.replace(oc, sun_cells=True)}
        variants = {k: allv[k] for k in a.variants.split(",")}
        args = {}
        for name, c in variants.items():
            engine.object_shading.config = c
            fr = engine.render(scene.obj, cfg)
            args[name] = last.get("vr")
            print(f"{room.name} {name} rest: {_scores(fr, scene, truth, mask)}", flush=True)
            if a.foot and engine.last_shading is not None:
                print(f"{room.name} {name} foot (truth/ours): {_foot(engine, fr, truth, mask)}", flush=True)
            if a.save is not None:
                from recon.io import write_png

                a.save.mkdir(parents=True, exist_ok=True)
                write_png(a.save / f"{room.name}_{name}_rest.png", fr.pixels)
            if a.drag:
                engine.render(scene.obj, drag_cfg)
                fd = engine.render(scene.obj, drag_cfg)
                print(f"{room.name} {name} drag: {_scores(fd, scene, truth, mask)}", flush=True)
        if a.cost and all(v is not None for v in args.values()):
            ms: dict[str, list[float]] = {n: [] for n in variants}
            for _ in range(a.cost):
                for name, c in variants.items():
                    engine.object_shading.config = c
                    t = time.process_time()
                    orig_vr(engine.object_shading, *args[name])
                    ms[name].append(1e3 * (time.process_time() - t))
            print(f"{room.name} vertex radiance CPU ms, median of {a.cost}: "
                  + ", ".join(f"{n} {np.median(v):.1f}" for n, v in ms.items()), flush=True)
        engine.object_shading.config = oc
        del engine
        gc.collect()


if __name__ == "__main__":
    main()
