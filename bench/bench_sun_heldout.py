"""Held-out sunny rooms: sun_room with other suns, their truth from photoar's own path tracer.

usage: python bench/bench_sun_heldout.py [--shared ../shared] [--spp 64] [--suns AZ,EL;AZ,EL;...] [--keep DIR]

The shared sunny room has one sun; issue 20's figures are also to hold on sunny rooms not seen. For
each sun (azimuth in the floor plane from +x towards +z, elevation above it, degrees; the first is
sun_room's own as a control) this builds a scene folder like a benchmark one: scene.json with the sun
moved (its direction, centre and normal), the "photo" background.png/.exr an empty-room render of
`photoar reference`'s path tracer (the scene's model: patches, textures, sky and the sun through the
opening, 4 bounces; `--spp` samples, seed 1), and truth.png/.exr/truth_mask.png the differential
reference on that photo (seed 2: photo + the object's change from the same samples, as
`photoar reference` writes it). Then the engine composites it with known light (all sources and
50 passes) and ../shared/tools/score.py scores it. The tracer shares the engine's scene model, so
these truths measure the engine's approximations (radiosity on patches, source clusters, the sun's
PCSS shadow, the sunlit pieces, the bounces) but not a model mismatch; the control row says how far
such a truth is from the shared one. Prints one table; takes a few minutes a sun.
"""
from __future__ import annotations

import argparse
import importlib.util
import json
import math
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.cmd_reference import render_reference  # noqa: E402
from app.engine import Engine, EngineParams  # noqa: E402
from app.report import table  # noqa: E402
from recon.io import write_exr, write_json, write_png  # noqa: E402
from recon.scene import load_scene  # noqa: E402


def sun_direction(az_deg: float, el_deg: float) -> np.ndarray:
    """Unit vector towards the sun: azimuth in the floor plane from +x towards +z, elevation above it."""
    az, el = math.radians(az_deg), math.radians(el_deg)
    return np.array([math.cos(el) * math.cos(az), math.sin(el), math.cos(el) * math.sin(az)])


def azimuth_elevation(d: np.ndarray) -> tuple[float, float]:
    d = np.asarray(d, float) / np.linalg.norm(d)
    return math.degrees(math.atan2(d[2], d[0])), math.degrees(math.asin(d[1]))


def moved_sun_folder(src: Path, dst: Path, d: np.ndarray) -> None:
    """A copy of scene folder `src` in `dst` (large files linked) with its sun towards unit d."""
    dst.mkdir(parents=True)
    for f in src.iterdir():
        if f.name in ("scene.json", "background.exr", "truth.png", "truth.exr", "truth_mask.png"):
            continue
        if f.name == "background.png":  # a stand-in until the empty room is rendered (a copy: it is replaced)
            shutil.copyfile(f, dst / f.name)
        else:
            (dst / f.name).symlink_to(f.resolve())
    js = json.loads((src / "scene.json").read_text())
    lo, hi = np.array(js["world"]["room_min"], float), np.array(js["world"]["room_max"], float)
    for p in js["primitives"]:
        if p.get("type") == "sun":
            p["direction_to_sun"] = d.tolist()
            p["normal"] = (-d).tolist()
            p["centre"] = (0.5 * (lo + hi) + float(p.get("distance_m", 200.0)) * d).tolist()
    write_json(dst / "scene.json", js)


def shared_scorer(shared: Path):
    spec = importlib.util.spec_from_file_location("score", shared / "tools" / "score.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.score


def build_truth(folder: Path, spp: int) -> dict:
    """background.* (empty-room render, seed 1) and truth.* / truth_mask.png (the reference on it,
    seed 2) in `folder`; returns the render times and the sun's share of the floor in view."""
    scene = load_scene(folder)
    t0 = time.perf_counter()
    empty = render_reference(scene, spp, seed=1, quiet=True)
    H, W = scene.camera.height, scene.camera.width
    photo = empty.I_noobj.reshape(H, W, 3)
    write_exr(folder / "background.exr", photo.astype(np.float32))
    write_png(folder / "background.png", scene.response.to_pixels(photo))
    t1 = time.perf_counter()
    scene = load_scene(folder)  # with the rendered photo
    ref = render_reference(scene, spp, seed=2, quiet=True)
    write_png(folder / "truth.png", ref.pixels.reshape(H, W, 3))
    write_exr(folder / "truth.exr", ref.composite.reshape(H, W, 3).astype(np.float32))
    write_png(folder / "truth_mask.png", np.clip(np.rint(255 * ref.coverage.reshape(H, W)), 0, 255).astype(np.uint8))
    clipped = float((scene.photo >= 254).any(-1).mean())
    return {"photo_s": t1 - t0, "truth_s": time.perf_counter() - t1, "clipped_px": clipped}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shared", type=Path, default=ROOT.parent / "shared")
    ap.add_argument("--spp", type=int, default=64, help="samples per pixel of each render (default 64)")
    ap.add_argument("--suns", default=None,
                    help="suns as 'AZ,EL;AZ,EL' in degrees (default: sun_room's own, then two others)")
    ap.add_argument("--keep", type=Path, default=None, help="keep the built folders here")
    a = ap.parse_args(argv)
    src = a.shared / "scenes" / "sun_room"
    if not (src / "scene.json").is_file():
        print(f"bench_sun_heldout: {src}: no sun_room (needs ../shared)", file=sys.stderr)
        return 2
    own = load_scene(src).sun.direction
    az0, el0 = azimuth_elevation(own)
    suns = ([(az0, el0), (az0 - 15.0, el0 + 10.0), (az0 + 12.0, el0 - 8.0)] if a.suns is None else
            [tuple(float(x) for x in s.split(",")) for s in a.suns.split(";")])
    score = shared_scorer(a.shared)
    base = Path(tempfile.mkdtemp(prefix="heldout-")) if a.keep is None else a.keep
    rows = []
    try:
        for k, (az, el) in enumerate(suns):
            folder = base / f"sun_{k}_az{az:.0f}_el{el:.0f}"
            moved_sun_folder(src, folder, sun_direction(az, el))
            info = build_truth(folder, a.spp)
            scene = load_scene(folder)
            for passes in (None, 50):
                eng = Engine(scene, EngineParams(passes=passes), quiet=True)
                fr = eng.render(scene.obj)
                out = folder / f"ours_{passes or 'all'}.png"
                write_png(out, fr.pixels)
                s = score(str(folder), str(out))
                rows.append({"sun (az, el)": f"{az:.0f}, {el:.0f}" + (" (own)" if k == 0 and a.suns is None else ""),
                             "passes": passes or "all", "sun lights room": bool(eng.sun.on),
                             "clipped px": info["clipped_px"], "energy_ratio": s["energy_ratio"],
                             "rmse_affected": s["rmse_affected"], "untouched": s["rmse_affected_if_untouched"],
                             "spurious": s["spurious"], "rmse_object": s["rmse_object"]})
                print(f"sun {az:.0f},{el:.0f} passes {passes or 'all'}: energy {s['energy_ratio']:.3f}, rmse "
                      f"{s['rmse_affected']:.2f} (untouched {s['rmse_affected_if_untouched']:.1f}), rmse_object "
                      f"{s['rmse_object']:.2f} (truth renders {info['photo_s']:.0f} + {info['truth_s']:.0f} s)",
                      file=sys.stderr, flush=True)
    finally:
        if a.keep is None:
            shutil.rmtree(base, ignore_errors=True)
    print(table(rows, ["sun (az, el)", "passes", "sun lights room", "clipped px", "energy_ratio", "rmse_affected",
                       "untouched", "spurious", "rmse_object"]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
