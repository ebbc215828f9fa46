"""The shadow pass at two map sizes (issue 17: "masks only on listed pixels, at the map size the error allows").

usage: python bench/bench_shadow_pass.py [--scenes window_room,lamps_room] [--res 128,256] [--n 10] [--shared ../shared]
       python bench/bench_shadow_pass.py --ab [--scenes window_room,lamps_room,sun_room] [--repeat 4]
       python bench/bench_shadow_pass.py --texel [--scenes window_room,lamps_room,sun_room]

Per shared scene and map size (every map of the frame at that size: clusters of sources and one map
per source alike): the masks stage of a drag of N positions at 50 passes (app.dragpath; the first
frame excluded; wall ms, mean and p95, and the process's CPU ms, both cores together), the
all-sources frame's masks (in the frame, and alone: wall and CPU ms, median of 3), the (point, map) pairs the masked sums test after culling against
those the candidate lists allow, and the scores against the truth at the object's own pose
(50 passes and all sources). Warm (kernels compiled, buffers sized). The machine's load enters
the wall times; the CPU times are steadier.

--ab: the all-sources frame at map_res, its batches pipelined (ShadowPass.pipelined: batch k+1's maps
drawn while batch k is summed) against drawn-then-summed, alternating on one engine (ABBA, `--repeat`
rounds after a warm one): the masks alone and the whole frame (Engine.render), wall and process CPU ms,
medians; and whether the two give bitwise the same masks and frame.

--texel: whether a source's map of the all-sources frame could be drawn at half map_res with its
shadow's edge moved by at most half a camera pixel: per source, a half-size texel's width
(ShadowMaps' field of view: 2 tan(half angle) / res per metre of distance from the eye) at the
farthest point of each receiver patch it may shadow (cand; |centre - eye| + radius) over the
narrowest camera pixel's footprint on that patch (the distance between neighbouring pixels' surface
points on one quad); the worst patch per source: min / p10 / median over the sources and how many
are at most 1.
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.dragpath import drag_offsets, moved  # noqa: E402
from app.engine import Engine, EngineParams, FrameConfig  # noqa: E402
from app.report import table  # noqa: E402
from app.stages import shadow_pass  # noqa: E402
from lighting import metrics  # noqa: E402
from recon.io import read_image_rgb  # noqa: E402
from recon.proxy import bounding_sphere  # noqa: E402
from recon.scene import load_scene  # noqa: E402


def bench(scene_dir: Path, res: int, n: int, cache: str) -> dict:
    import cv2

    scene = load_scene(scene_dir)
    shadow_pass.CLUSTER_MAP_RES = res  # every map of every frame at this size
    eng = Engine(scene, EngineParams(map_res=res), cache_dir=cache, quiet=True)
    sp = eng.shadow_pass
    offs = drag_offsets(scene, scene.obj, n)
    cfg = FrameConfig(passes=50)
    eng.render(moved(scene.obj, offs[0]), cfg)
    wall, cpu = [], []
    for o in offs[1:]:
        obj = moved(scene.obj, o)
        # the masks stage alone, CPU time of both cores (the frame's other stages excluded)
        pv, pf, occ, _, _ = eng.object_shading.object_shape(obj)
        fs = eng.shadow_sources.select(pv.min(0), pv.max(0), 50)
        centre, radius = bounding_sphere(pv)
        cov = np.zeros((scene.camera.height, scene.camera.width))
        c0, t0 = time.process_time(), time.perf_counter()
        steps = sp.run((pv, pf, occ), centre, radius, cov, fs.cand, fs.eyes, fs.W_v, fs.W_c, False, spread=fs.spread,
                       scale=eng.receivers.E_x)  # as the engine runs it (graded lattice)
        for _ in steps:
            pass
        cpu.append(time.process_time() - c0)
        wall.append(time.perf_counter() - t0)
    row = {"scene": scene.name, "map": res, "masks_ms": 1e3 * np.mean(wall), "masks_p95_ms": 1e3 * np.percentile(wall, 95),
           "masks_cpu_ms": 1e3 * np.mean(cpu), "pairs_50": _pairs(sp)}
    # the all-sources frame's masks alone (one map per source, the object at its own pose, no pixel taken as
    # hidden by it): median of 3
    pv, pf, occ, _, _ = eng.object_shading.object_shape(scene.obj)
    fs = eng.shadow_sources.select(pv.min(0), pv.max(0), None)
    centre, radius = bounding_sphere(pv)
    cov = np.zeros((scene.camera.height, scene.camera.width))
    wall_all, cpu_all = [], []
    for _ in range(3):
        c0, t0 = time.process_time(), time.perf_counter()
        for _ in sp.run((pv, pf, occ), centre, radius, cov, fs.cand, fs.eyes, fs.W_v, fs.W_c, True, scale=eng.receivers.E_x):
            pass
        cpu_all.append(time.process_time() - c0)
        wall_all.append(time.perf_counter() - t0)
    row.update(all_masks_wall_ms=1e3 * np.median(wall_all), all_masks_cpu_ms=1e3 * np.median(cpu_all))
    truth = mask = None
    if (scene_dir / "truth.png").is_file():
        truth = read_image_rgb(scene_dir / "truth.png")
        mask = cv2.imread(str(scene_dir / "truth_mask.png"), cv2.IMREAD_GRAYSCALE)
    for label, passes in (("50", 50), ("all", None)):
        c0 = time.process_time()
        fr = eng.render(scene.obj, FrameConfig(passes=passes))
        if passes is None:
            row["all_masks_ms"] = 1e3 * fr.stats["timings"]["masks"]
            row["all_maps"] = fr.stats["passes"]
            row["all_frame_cpu_s"] = time.process_time() - c0
        if truth is not None:
            s = metrics.score_regions(fr.pixels, scene.photo, truth, mask)
            row[f"energy_{label}"] = s["energy_ratio"]
            row[f"rmse_{label}"] = s["rmse_affected"]
            row[f"rmse_object_{label}"] = s["rmse_object"]
    return row


def bench_ab(scene_dir: Path, repeat: int, cache: str) -> list[dict]:
    """The all-sources frame, pipelined against not (see --ab): one row per mode."""
    scene = load_scene(scene_dir)
    eng = Engine(scene, EngineParams(), cache_dir=cache, quiet=True)
    sp = eng.shadow_pass
    pv, pf, occ, _, _ = eng.object_shading.object_shape(scene.obj)
    fs = eng.shadow_sources.select(pv.min(0), pv.max(0), None)
    centre, radius = bounding_sphere(pv)
    cov = np.zeros((scene.camera.height, scene.camera.width))
    got = {False: [], True: []}
    last = {}
    for r in range(repeat + 1):
        for mode in ((False, True) if r % 2 == 0 else (True, False)):
            sp.pipelined = mode
            c0, t0 = time.process_time(), time.perf_counter()
            steps = sp.run((pv, pf, occ), centre, radius, cov, fs.cand, fs.eyes, fs.W_v, fs.W_c, True, scale=eng.receivers.E_x)
            try:
                while True:
                    next(steps)
            except StopIteration as stop:
                masks = stop.value
            mw, mc = time.perf_counter() - t0, time.process_time() - c0
            c0, t0 = time.process_time(), time.perf_counter()
            fr = eng.render(scene.obj, FrameConfig(passes=None))
            fw, fc = time.perf_counter() - t0, time.process_time() - c0
            if r:  # the first round warms both
                got[mode].append((mw, mc, fw, fc, fr.stats["timings"]["masks"]))
            last[mode] = (masks.O_pix, masks.O_cen, fr.pixels)
    sp.pipelined = True
    same = all(np.array_equal(a, b) for a, b in zip(last[False], last[True]))
    rows = []
    for mode in (False, True):
        a = 1e3 * np.median(np.array(got[mode]), axis=0)
        rows.append({"scene": scene.name, "pipelined": mode, "maps": len(fs.eyes), "masks_wall_ms": a[0],
                     "masks_cpu_ms": a[1], "frame_wall_ms": a[2], "frame_cpu_ms": a[3], "frame_masks_ms": a[4],
                     "bitwise_equal": same})
    return rows


def texel_ratio(scene_dir: Path, cache: str) -> dict:
    """--texel (module docstring) for one scene, the object at its own pose."""
    scene = load_scene(scene_dir)
    eng = Engine(scene, EngineParams(), cache_dir=cache, quiet=True)
    sp = eng.shadow_pass
    W, H = scene.camera.width, scene.camera.height
    pv, pf, occ, _, _ = eng.object_shading.object_shape(scene.obj)
    fs = eng.shadow_sources.select(pv.min(0), pv.max(0), None)
    # the narrowest camera-pixel footprint per patch
    pos = np.asarray(eng.receivers.pix_pos, np.float64).reshape(H, W, 3)
    ok = (eng.receivers.recv_pix & (eng.receivers.pix_patch >= 0)).reshape(H, W)
    q = sp.pix_quad.reshape(H, W)
    fp = np.full((H, W), np.inf)
    for a, b in (((slice(None), slice(0, -1)), (slice(None), slice(1, None))),
                 ((slice(0, -1), slice(None)), (slice(1, None), slice(None)))):
        good = ok[a] & ok[b] & (q[a] == q[b])
        with np.errstate(invalid="ignore"):
            d = np.where(good, np.linalg.norm(pos[a] - pos[b], axis=-1), np.inf)
        fp[a], fp[b] = np.minimum(fp[a], d), np.minimum(fp[b], d)
    foot = np.full(len(sp.patch_centre), np.inf)
    m = ok & np.isfinite(fp) & (fp > 0)
    np.minimum.at(foot, eng.receivers.pix_patch.reshape(H, W)[m], fp[m])
    maps = sp.maps_full
    maps.set_proxy(pv, pf, occ)
    c, r = maps._centre, maps._radius * 1.02 + 1e-3  # ShadowMaps.prepare's field of view
    sin_h = np.clip(r / np.linalg.norm(fs.eyes - c, axis=1), 0.0, 0.999)
    tex = 2.0 * sin_h / np.sqrt(1 - sin_h ** 2) / (maps.res // 2)
    seen = np.isfinite(foot)  # patches with pixels in view
    worst = np.zeros(len(fs.eyes))
    for a in range(0, len(fs.eyes), 256):
        e = fs.eyes[a:a + 256]
        d = np.linalg.norm(sp.patch_centre[seen, None, :] - e[None], axis=2) + sp.patch_radius[seen, None]
        worst[a:a + 256] = np.where(fs.cand[seen, a:a + 256], d / foot[seen, None], 0.0).max(0) * tex[a:a + 256]
    worst = worst[worst > 0]
    return {"scene": scene.name, "maps": len(fs.eyes), "half_texel_per_pixel_min": worst.min(),
            "p10": np.percentile(worst, 10), "median": np.median(worst), "maps_at_most_1": int((worst <= 1).sum())}


def _pairs(sp) -> str:
    """Maps per point the last batch's masked sums tested (of its 50 maps), after the candidate
    lists and the culling (a graded frame: of its last selection, the pixels summed one by one)."""
    ms = sp.sums
    idx = ms.idx.pull(ms.n).astype(np.int64)
    listed = int(ms.n_list.numpy()[ms.point_cell[idx]].sum())
    return f"{listed / max(ms.n, 1):.1f}/pt"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shared", default=os.environ.get("PHOTOAR_SHARED", str(ROOT.parent / "shared")))
    ap.add_argument("--scenes", default="window_room,lamps_room")
    ap.add_argument("--res", default="128,256")
    ap.add_argument("--n", type=int, default=10)
    ap.add_argument("--ab", action="store_true", help="the all-sources frame pipelined against not (module docstring)")
    ap.add_argument("--repeat", type=int, default=4, help="--ab: rounds of the two modes after a warm one")
    ap.add_argument("--texel", action="store_true", help="half-size texels against camera pixels (module docstring)")
    a = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as cache:
        for name in a.scenes.split(","):
            d = Path(a.shared) / "scenes" / name
            if not (d / "scene.json").is_file():
                print(f"skipping {name}: {d} not found")
                continue
            if a.texel:
                rows.append(texel_ratio(d, cache))
                print(rows[-1], flush=True)
                continue
            if a.ab:
                rows += bench_ab(d, a.repeat, cache)
                print(rows[-2], rows[-1], sep="\n", flush=True)
                continue
            for r in (int(x) for x in a.res.split(",")):
                rows.append(bench(d, r, a.n, cache))
                print(rows[-1], flush=True)
    if rows:
        cols = list(dict.fromkeys(k for r in rows for k in r))
        print(table(rows, cols))


if __name__ == "__main__":
    main()
