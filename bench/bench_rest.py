"""The all-sources frame at rest (issue 36, item 5): before/after in one process, scored against the truth.

usage: python bench/bench_rest.py [--scenes window_room,lamps_room,sun_room,~/.cache/photoar/rooms/lamps_102]
                                  [--repeat 3] [--variants before,kernel,prev,upload,ring,cells8,after,all128,far1.5] [--json OUT]

Per scene (a shared scene's name or a benchmark folder with truth.png and truth_mask.png) one engine,
warm (one frame of each variant first), then `--repeat` rounds in which every variant renders the
all-sources frame at the object's own pose, interleaved (the machine's load falls on every variant
alike). Variants:
  before: the second order's blocked pairs by the numpy pair search (app.stages.second_order.blocked_pass),
          every map at map_res (the code before this bench);
  kernel: the blocked pairs in one Warp launch (BlockedSecondOrder), every map at map_res;
  prev:   the kernel and the weak sources on half-size maps (app.rest_maps), each batch's scattered transfer columns
          gathered by numpy on the rendering thread (the engine of the round before);
  upload: prev, the columns gathered by a Warp kernel (kernels.gather);
  ring:   upload, and the weak sources' sums filled at the near ring's pixels (ShadowPass.weak_ring): the
          engine of the round before;
  cells8: ring, and the weak sources summed on the spacing-4 lattice beyond weak_far bounding radii and
          filled bilinearly on the spacing-2 one there (ShadowPass.weak_coarse);
  after:  cells8, the masked sums in culling cells of TILE_SOURCE px (ShadowPass.source_cells): the engine's
          default;
  farX:   after with weak_far X (bounding radii);
  all128: the kernel, every source on a half-size map (what the rule is measured against).
Prints per variant the median frame seconds (wall, and the process's CPU seconds: both cores, steadier
under load) and stage milliseconds, the sources on full-size maps, the masked sums' (point, map) tests and
(run, map) entries of the frame (deterministic: the work the load cannot blur), and
energy_ratio / rmse_affected / spurious / rmse_object against the truth (the frames are deterministic:
scored once).
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def scene_dir(name: str) -> Path:
    """A benchmark folder: the path itself, or a shared scene's name (under $PHOTOAR_SHARED/scenes)."""
    p = Path(os.path.expanduser(name))
    return p if p.is_dir() else Path(os.environ.get("PHOTOAR_SHARED", ROOT.parent / "shared")) / "scenes" / name


def variant(engine, name: str, kernel, numpy_blocked, rest_maps: dict, gather, default_far: float = 2.0) -> None:
    """Set the engine to one variant (module docstring); rest_maps: {"after": ..., "all128": ...}; gather: the
    shadow pass's ColumnGather."""
    engine._blocked = numpy_blocked if name == "before" else kernel
    engine.rest_maps = rest_maps.get(name)
    sp = engine.shadow_pass
    sp._gather = None if name in ("before", "kernel", "prev") else gather
    sp.weak_lattice = name in ("ring", "cells8", "after", "all128") or name.startswith("far")
    # ring: the weak sources summed on the spacing-2 lattice at every distance (the round before's default);
    # farX: on the spacing-4 lattice from X bounding radii (ShadowPass.weak_coarse); after: the engine's weak_far
    sp.source_cells = name not in ("before", "kernel", "prev", "upload", "ring", "cells8")
    sp.weak_far = float(name[3:]) if name.startswith("far") else (0.0 if name in ("ring", "all128") else default_far)


def run_scene(path: Path, variants: list[str], repeat: int) -> dict:
    import cv2

    from app.composite import default_cache_dir
    from app.engine import Engine, EngineParams
    from app.stages.second_order import blocked_pass
    from lighting import metrics
    from recon.io import read_image_rgb
    from recon.proxy import bounding_sphere
    from recon.scene import load_scene

    scene = load_scene(path)
    engine = Engine(scene, EngineParams(), cache_dir=default_cache_dir(), quiet=True)
    pre, pm = engine.pre, engine.pre.patches
    rv = pre.recv_vert

    def numpy_blocked(dB, occ, box, obb=None, split=None):
        pv = occ.triangles().reshape(-1, 3)
        return blocked_pass(dB, pre.G_v, pm.vert_inset[rv], pm.vert_normal[rv], pm.centre, pm.normal, pm.area,
                            occ, bounding_sphere(pv))

    from app.rest_maps import RestMaps

    r = engine.receivers
    kernel = engine._blocked
    rest_maps = {v: engine.rest_maps for v in ("prev", "upload", "ring", "after") + tuple(variants)
                 if v not in ("before", "kernel", "all128")}
    rest_maps["all128"] = RestMaps(r.E_v, budget=np.inf)
    gather = engine.shadow_pass._gather
    default_far = engine.shadow_pass.weak_far
    truth = read_image_rgb(path / "truth.png")
    mask = cv2.imread(str(path / "truth_mask.png"), cv2.IMREAD_GRAYSCALE)
    cfg = dataclasses.replace(engine.frame_config(), passes=None)
    times: dict[str, list] = {v: [] for v in variants}
    out: dict[str, dict] = {}
    for rnd in range(repeat + 1):
        for v in (variants if rnd % 2 == 0 else variants[::-1]):
            variant(engine, v, kernel, numpy_blocked, rest_maps, gather, default_far)
            sums = engine.shadow_pass.sums_source if engine.shadow_pass.source_cells else engine.shadow_pass.sums
            counts = _count_pairs(sums) if rnd == 0 else None
            c0 = time.process_time()
            fr = engine.render(scene.obj, cfg)
            cpu = time.process_time() - c0
            if rnd == 0:  # warm: kernels compiled, buffers sized; scored once
                s = metrics.score_regions(fr.pixels, scene.photo, truth, mask)
                hard = None if engine.rest_maps is None else int((~engine.rest_maps.weak(
                    engine.shadow_sources.select(*_box(engine, scene.obj), None))).sum())
                out[v] = {k: float(s[k]) for k in ("energy_ratio", "rmse_affected", "spurious", "rmse_object")}
                del sums.accumulate  # the class's again
                out[v].update(n_sources=fr.stats["n_sources"], full_size_maps=hard, pixels=fr.pixels, **counts)
                continue
            times[v].append((fr.stats["frame_s"], fr.stats["timings"], cpu))
    for v in variants:
        fs = [t[0] for t in times[v]]
        out[v]["frame_s"] = float(np.median(fs))
        out[v]["cpu_s"] = float(np.median([t[2] for t in times[v]]))
        out[v]["stages_ms"] = {k: round(1e3 * float(np.median([t[1][k] for t in times[v]])), 1)
                               for k in times[v][0][1]}
    base = out[variants[0]]["pixels"].astype(np.float64)
    for v in variants:
        out[v]["rmse_vs_" + variants[0]] = float(np.sqrt(np.mean((out[v].pop("pixels") - base) ** 2)))
    return out


def _count_pairs(sums) -> dict:
    """Count the masked sums' work of the next frame into the returned dict: "pairs" (point, map) tests and
    "runs" (run, map) entries (a run: the selected points of one culling cell; kernels.masked_sums), by wrapping
    `sums`' accumulate (the caller deletes the wrapper)."""
    counts = {"pairs": 0, "runs": 0}
    accumulate = sums.accumulate

    def counted(maps, first, weights, lo=0, hi=None):
        accumulate(maps, first, weights, lo, hi)
        n = np.diff(np.clip(sums._run_start, lo, sums.n if hi is None else min(hi, sums.n)))
        listed = sums.n_list.numpy()[sums._run_cell]
        counts["pairs"] += int((n * listed).sum())
        counts["runs"] += int(((n > 0) * listed).sum())

    sums.accumulate = counted
    return counts


def _box(engine, obj):
    pv = engine.object_shading.object_shape(obj)[0]
    return pv.min(0), pv.max(0)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", default="window_room,lamps_room,sun_room")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--variants", default="ring,after")
    ap.add_argument("--json", help="write the results here")
    a = ap.parse_args(argv)
    variants = a.variants.split(",")
    res = {}
    for name in a.scenes.split(","):
        path = scene_dir(name)
        r = run_scene(path, variants, a.repeat)
        res[name] = r
        for v in variants:
            x = r[v]
            print(f"{path.name:12s} {v:7s} frame {x['frame_s']:.2f} s (CPU {x['cpu_s']:.2f} s)  "
                  f"energy {x['energy_ratio']:.4f} rmse_aff {x['rmse_affected']:.4f} spurious {x['spurious']:.4f} rmse_obj {x['rmse_object']:.3f}  "
                  f"full-size maps {x['full_size_maps']} of {x['n_sources']}  pairs {x['pairs'] / 1e6:.2f} M runs "
                  f"{x['runs'] / 1e6:.2f} M  vs {variants[0]} "
                  f"{x['rmse_vs_' + variants[0]]:.3f}  {x['stages_ms']}", flush=True)
    if a.json:
        Path(a.json).write_text(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
