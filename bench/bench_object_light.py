"""Object-light stage benchmark (app/stages/object_light.py): its coarse evaluation against the exact one.

usage: python bench/bench_object_light.py [--shared ../shared] [--scenes window_room lamps_room sun_room]
                                          [--n 6] [--repeat 3]

Per scene: a drag at 50 passes (app.dragpath) is rendered once and each frame's object-light inputs
are kept; then, interleaved so both see the same machine load, the stage (the proxy triangles' light,
triangle_radiance, and the light they reflect, object_light) is timed as it runs and in its exact
form (every patch gathered alone: BLOCK_NEAR = inf; every near pixel evaluated: GRID_STRIDES = ()).
Prints warm per-frame medians (ms) and the coarse form's error against the exact one: the proxy
triangles' total light, the room pixels' levels (max and rms over the lit pixels) and the patch
centres' light. With the sun (sun_room) the sunlit pieces are made from each form's own proxy light.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.dragpath import drag_offsets, moved  # noqa: E402
from app.engine import Engine, EngineParams, FrameConfig  # noqa: E402
from app.stages import object_light as OL  # noqa: E402
from recon.proxy import bounding_sphere  # noqa: E402
from recon.response import luminance  # noqa: E402
from recon.scene import load_scene  # noqa: E402


def _capture(eng: Engine, scene, n: int) -> list[dict]:
    """The object-light inputs of each frame of an n-position drag (frames 2..n)."""
    frames = []
    tri_fn = eng.object_light.triangle_radiance

    def keep(obj, pv, pf, occ, B):
        frames.append(dict(obj=obj, pv=pv, pf=pf, occ=occ, B=B.copy(), cov=None))
        return tri_fn(obj, pv, pf, occ, B)

    eng.object_light.triangle_radiance = keep
    try:
        for o in drag_offsets(scene, scene.obj, n):
            f = eng.render(moved(scene.obj, o), FrameConfig(passes=50))
            frames[-1]["cov"] = f.coverage.reshape(-1) >= 1.0
    finally:
        del eng.object_light.triangle_radiance
    return frames[1:]


def _place(occ, pv: np.ndarray) -> None:
    """The proxy's BVH moved to this frame's vertices: the engine translates and refits one BVH per
    shape in place, so a captured frame's occluder is where the last frame left it."""
    occ.move(pv)


def _stage(eng: Engine, c: dict):
    """triangle_radiance + (the sun's pieces) + object_light of one captured frame: (seconds, outputs)."""
    pv, pf, occ = c["pv"], c["pf"], c["occ"]
    centre, radius = bounding_sphere(pv)
    _place(occ, pv)
    t = time.perf_counter()
    tri_rad = eng.object_light.triangle_radiance(c["obj"], pv, pf, occ, c["B"])
    extra = None
    if eng.sun_pixels.pix is not None:
        tri_rad, extra = eng.sun_pixels.stage.object_emitters(pv, pf, tri_rad, c["obj"].albedo, occ, radius)
    R_pix, R_cen = eng.object_light.light(pv, pf, tri_rad, occ, centre, radius, c["cov"], extra)
    return time.perf_counter() - t, (tri_rad, R_pix, R_cen)


def bench(scene_dir: Path, n: int, repeat: int) -> None:
    scene = load_scene(scene_dir)
    eng = Engine(scene, EngineParams(), quiet=True)
    frames = _capture(eng, scene, n)
    exact_form = {"BLOCK_NEAR": np.inf, "GRID_STRIDES": ()}
    kept = {k: getattr(OL, k) for k in exact_form}
    times = {"coarse": [], "exact": []}
    out = {}
    for r in range(repeat):
        for i, c in enumerate(frames):
            for form in (("coarse", "exact") if r % 2 == 0 else ("exact", "coarse")):
                for k, v in (exact_form if form == "exact" else kept).items():
                    setattr(OL, k, v)
                dt, res = _stage(eng, c)
                times[form].append(dt)
                out[form, i] = res
    for k, v in kept.items():
        setattr(OL, k, v)
    resp = scene.response
    rows = []
    for i in range(len(frames)):
        (tc, pc, cc), (te, pe, ce) = out["coarse", i], out["exact", i]
        lit = np.abs(pe).sum(1) > 0
        d = resp.to_levels(eng.receivers.L_b + eng.receivers.rho_x * pc) - resp.to_levels(eng.receivers.L_b + eng.receivers.rho_x * pe)
        area = eng.pre.patches.area
        rows.append((luminance(tc).sum() / luminance(te).sum() - 1, np.abs(d).max(), np.sqrt((d[lit] ** 2).mean()),
                     (luminance(cc) * area).sum() / max((luminance(ce) * area).sum(), 1e-30) - 1))
    rows = np.array(rows)
    print(f"{scene_dir.name}: object-light stage, warm median over {len(frames)} drag frames x {repeat}: "
          f"coarse {1e3 * np.median(times['coarse']):.0f} ms, exact {1e3 * np.median(times['exact']):.0f} ms; "
          f"coarse vs exact: proxy light total {100 * np.abs(rows[:, 0]).max():.2f} %, pixel levels max "
          f"{rows[:, 1].max():.2f} rms {rows[:, 2].max():.3f}, patch centres total "
          f"{100 * np.abs(rows[:, 3]).max():.2f} %")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shared", default=str(ROOT.parent / "shared"))
    ap.add_argument("--scenes", nargs="+", default=["window_room", "lamps_room", "sun_room"])
    ap.add_argument("--n", type=int, default=6, help="drag positions (the first is not timed)")
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args()
    for name in a.scenes:
        d = Path(a.shared) / "scenes" / name
        if not (d / "scene.json").is_file():
            print(f"{name}: skipped ({d} not found)")
            continue
        bench(d, a.n, a.repeat)


if __name__ == "__main__":
    main()
