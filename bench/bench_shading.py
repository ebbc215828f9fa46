"""Object-shading benchmark: SH volume build time and shading throughput (seed sec. 5).

usage: python bench/bench_shading.py [--shared ../shared]

Prints one table per shared scene (or the bundled demo scene without ../shared): build time of a
20x10x20 SH9 volume (the seed: 30 s on a 2.5 GHz Pentium 4), vertices/s of volume shading
(trilinear SH lookup + irradiance + camera response; the seed: 350 k vertices/s), vertices/s of
the self-occlusion transfer (PRT) and of the exact emitter gather, the volume's error
against brute-force gathering at 50 random points, and the per-frame specular cube map's build
time and error against a 3x finer one (Phong exponent 32).

--drag N (alone with --drag-only): per shared scene, the object_shading stage of an N-pose 50-pass drag
with the shortcuts of app/stages/object_shading.py (the shadowed room's far field as SH9 through the
self-occlusion transfer, no room rays for the emitters where shaft_clear) against the exact gathers,
interleaved pose by pose in one engine (medians of warm frames), and the vertex radiance's change.
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.cli import demo_scene_dir  # noqa: E402
from app.engine import Engine, EngineParams  # noqa: E402
from app.report import table  # noqa: E402
from kernels.irradiance_volume import build_volume  # noqa: E402
from kernels.shade import self_transfer  # noqa: E402
from kernels.visibility import Occluder, transfer_matrix  # noqa: E402
from lighting import sh  # noqa: E402
from recon.proxy import subdivide  # noqa: E402
from recon.response import luminance  # noqa: E402
from recon.scene import inside_furniture, load_scene  # noqa: E402


def bench_scene(name: str, scene_dir: Path) -> dict:
    scene = load_scene(scene_dir)
    with tempfile.TemporaryDirectory() as cache:
        eng = Engine(scene, EngineParams(), cache_dir=cache, quiet=True)
    pm = eng.pre.patches
    t = time.perf_counter()
    build_volume(scene.room_min, scene.room_max, 1.0, pm.corners, pm.normal, eng.B_src, eng.scene_occ, pm.tri_patch,
                 shape=(20, 10, 20))
    t_vol = time.perf_counter() - t
    light = eng.room_light
    v, n, f = subdivide(scene.obj.vertices, scene.obj.normals, scene.obj.faces, max_edge=0.08, max_faces=3000)
    reps = max(1, 200_000 // len(v))
    vv, nn = np.tile(v, (reps, 1)), np.tile(n, (reps, 1))
    t = time.perf_counter()
    E = sh.irradiance(light.indirect_sh(vv), nn) / np.pi
    scene.response.to_levels(scene.obj.albedo * E)
    t_sh = time.perf_counter() - t
    occ = Occluder(v, f)
    self_transfer(v[:10], n[:10], occ)
    t = time.perf_counter()
    self_transfer(v, n, occ, 128)
    t_prt = time.perf_counter() - t
    t = time.perf_counter()
    light.direct(v, n, n_side=1)
    t_dir = time.perf_counter() - t
    rng = np.random.default_rng(0)
    pts = rng.uniform(scene.room_min + 0.3, scene.room_max - 0.3, (400, 3))
    pts = pts[~inside_furniture(scene, pts, 0.01)][:50]
    nr = rng.normal(size=(50, 3))
    nr /= np.linalg.norm(nr, axis=1, keepdims=True)
    ref = luminance(transfer_matrix(pts, nr, pm.corners, pm.normal, [eng.scene_occ], n_side=4).astype(float)
                    @ eng.B_src)
    hyb = np.abs(luminance(light.irradiance(pts, nr)) - ref) / ref
    # specular: the per-frame pre-filtered cube map (default 16^2 faces) against a fine one
    c = scene.obj.centre
    t = time.perf_counter()
    cm = eng.object_shading.specular_map(c)
    t_spec = time.perf_counter() - t
    shading = eng.object_shading
    shading.config = dataclasses.replace(shading.config, envmap_res=48)  # a fine one
    dirs = rng.normal(size=(2000, 3))
    ref_s = luminance(shading.specular_map(c).lookup(dirs))
    spec_err = np.abs(luminance(cm.lookup(dirs)) - ref_s) / ref_s
    return {"scene": name, "patches": pm.n_patches, "volume_20x10x20_s": t_vol,
            "specular_map_s": t_spec, "specular_err_mean": float(np.mean(spec_err)),
            "sh_shading_vert_s": len(vv) / t_sh, "prt_128dir_vert_s": len(v) / t_prt,
            "emitter_gather_vert_s": len(v) / t_dir, "volume_err_mean": float(np.mean(hyb)),
            "volume_err_max": float(np.max(hyb))}


def bench_drag(name: str, scene_dir: Path, n: int) -> dict:
    """object_shading ms of the drag with the shortcuts on (new) and off (exact), interleaved, and the
    largest / mean change of the vertex radiance (luminance, relative to its mean)."""
    from app.dragpath import drag_offsets, moved
    from app.engine import FrameConfig

    scene = load_scene(scene_dir)
    eng = Engine(scene, EngineParams(), quiet=True)
    offs = drag_offsets(scene, scene.obj, n)
    cfg = FrameConfig(passes=50)
    eng.render(moved(scene.obj, offs[0]), cfg)
    ms: dict[bool, list[float]] = {True: [], False: []}
    diff = []
    for i, o in enumerate(offs[1:]):
        L = {}
        for on in ((True, False) if i % 2 else (False, True)):
            eng.object_shading.config = dataclasses.replace(eng.object_shading.config, dB_far_field=on,
                                                            shaft_cull=on)
            fr = eng.render(moved(scene.obj, o), cfg)
            ms[on].append(1e3 * fr.stats["timings"]["object_shading"])
            L[on] = luminance(eng.last_shading[1])
        diff.append(np.abs(L[True] - L[False]) / L[False].mean())
    d = np.concatenate(diff)
    return {"scene": name, "frames": len(ms[True]), "exact_ms": float(np.median(ms[False])),
            "new_ms": float(np.median(ms[True])), "ratio": float(np.median(ms[False]) / np.median(ms[True])),
            "dL_mean": float(d.mean()), "dL_p99": float(np.percentile(d, 99)), "dL_max": float(d.max())}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--shared", type=Path, default=ROOT.parent / "shared")
    ap.add_argument("--drag", type=int, default=0, help="poses of the object_shading A/B drag (0: none)")
    ap.add_argument("--drag-only", action="store_true", help="only the drag A/B")
    a = ap.parse_args()
    if a.drag:
        drag = [bench_drag(n, a.shared / "scenes" / n, a.drag) for n in ("window_room", "lamps_room", "sun_room")
                if (a.shared / "scenes" / n / "scene.json").is_file()]
        if drag:
            print(table(drag, list(drag[0])))
            print("(object_shading ms, warm, medians; exact: DB far field and shaft culling off)")
        if a.drag_only:
            return
    scenes = [(n, a.shared / "scenes" / n) for n in ("window_room", "lamps_room")
              if (a.shared / "scenes" / n / "scene.json").is_file()] or [("demo", demo_scene_dir())]
    rows = [bench_scene(n, d) for n, d in scenes]
    print(table(rows, list(rows[0])))
    print("(seed, 2.5 GHz Pentium 4: 30 s per 20x10x20 volume, 350 k vertices/s shading)")


if __name__ == "__main__":
    main()
