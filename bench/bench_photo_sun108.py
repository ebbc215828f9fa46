"""What sets the object's sun under photo light, per sun room, against the truth (issue 34 item 4; photo108).

For each room kept by `bench_unseen --keep KEEP --lights photo` (KEEP/<room>/out_photo/report.json and
composite.png) prints, against the benchmark folder's truth (ROOMS/<room>/scene.json, truth.png):
- the sun: photo light's estimate over the truth's irradiance_perpendicular (luminance, and R/B);
- the walls' and the floor's albedo the interreflection fit lands on over the truth's (luminance);
- the sunlit floor: the fitted clipped region's radiance, its lower bound (the clip level) and the truth's
  (stats.sun_patch_floor_mean_radiance), luminance;
- the object, composite over truth in linear luminance (the scene's response inverted), on its sun side
  (true mesh normal . true sun > 0.2) and its shade (< -0.1), seen by the true camera (the calibrated camera
  moves the object by a pixel or two; the object's inner pixels only, eroded by 2 px).

`--truth-sun DIR`: each kept room's photo composite again (into DIR) with the estimated sun's irradiance replaced
by the truth's (the direction kept): the sun strength's share of the object's error.

`python bench/bench_photo_sun108.py KEEP ROOMS room[,room...] [--light photo] [--json OUT] [--truth-sun DIR]`
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

LUM = np.array([0.2126, 0.7152, 0.0722])


def lum(v) -> float:
    return float(np.asarray(v, float) @ LUM)


def truth(root: Path) -> dict:
    """The truth's sun, walls', floor's albedo, sunlit floor radiance and clip level (luminance)."""
    s = json.loads((root / "scene.json").read_text())
    pr = {p["name"]: p for p in s["primitives"]}
    sun = [p for p in s["primitives"] if p.get("role") == "sun"][0]
    walls = [lum(p["albedo"]) for n, p in pr.items()
             if p.get("role") == "room" and n.split("_")[0] in ("back", "front", "left", "right")]
    irr = np.array(sun["irradiance_perpendicular"])
    return {"sun": lum(irr), "sun_rb": float(irr[0] / irr[2]), "wall": float(np.mean(walls)),
            "floor": lum(pr["floor"]["albedo"]), "lit_floor": s["stats"].get("sun_patch_floor_mean_radiance"),
            "unlit_floor": s["stats"].get("unlit_floor_near_patch_mean_radiance"),
            "clip": 1.0 / s["main_camera"]["exposure_time"], "object_albedo": s["synthetic_object"]["albedo"]}


def object_regions(root: Path, composite: Path) -> dict:
    """Composite over truth (linear luminance, mean) on the object's sun side and shade (module docstring)."""
    import cv2
    import open3d as o3d

    from bench.bench_sun_decompose import object_mesh
    from recon.scene import load_scene

    s = json.loads((root / "scene.json").read_text())
    inv = np.asarray(s["camera_response"]["inverse_table"], float)  # (3,256)
    sun = [p for p in s["primitives"] if p.get("role") == "sun"][0]
    d = np.asarray(sun["direction_to_sun"], float)
    cam = load_scene(root).camera
    V, F = object_mesh(root)
    rc = o3d.t.geometry.RaycastingScene()
    rc.add_triangles(V.astype(np.float32), F)
    rays = cam.pixel_rays(1)
    o = np.broadcast_to(cam.centre, rays.shape)
    ans = rc.cast_rays(o3d.core.Tensor(np.concatenate([o, rays], -1).reshape(-1, 6).astype(np.float32)))
    tri = ans["primitive_ids"].numpy().reshape(cam.height, cam.width).astype(np.int64)
    hit = np.isfinite(ans["t_hit"].numpy().reshape(cam.height, cam.width))
    inner = cv2.erode(hit.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    fv = V[F]
    nf = np.cross(fv[:, 1] - fv[:, 0], fv[:, 2] - fv[:, 0])
    nf /= np.linalg.norm(nf, axis=1, keepdims=True)
    ns = np.where(hit, (nf @ d)[np.where(hit, tri, 0)], 0.0)

    def lin(path: Path) -> np.ndarray:
        z = cv2.imread(str(path))[..., ::-1].astype(np.int64)
        return np.stack([inv[c][z[..., c]] for c in range(3)], -1) @ LUM

    co, tr = lin(composite), lin(root / "truth.png")
    out = {}
    for name, sel in (("sun_side", inner & (ns > 0.2)), ("shade", inner & (ns < -0.1)), ("all", inner)):
        if sel.sum() >= 20:
            out[name] = round(float(co[sel].mean() / max(tr[sel].mean(), 1e-12)), 3)
            out[name + "_px"] = int(sel.sum())
    return out


def room_row(keep: Path, rooms: Path, room: str, light: str) -> dict:
    t = truth(rooms / room)
    rep = json.loads((keep / room / f"out_{light}" / "report.json").read_text())
    pl = rep.get("photo_light", {})
    sun = rep.get("sun", {}).get("irradiance_perpendicular")
    row = {"room": room, "truth": t}
    if sun:
        row["sun_x"] = lum(sun) / t["sun"]
        row["sun_rb"] = sun[0] / max(sun[2], 1e-12)
    if pl.get("wall_albedo"):
        row["wall_x"] = lum(pl["wall_albedo"]) / t["wall"]
    surf = (pl.get("albedo_fit") or {}).get("surfaces", {})
    if "floor" in surf:
        row["floor_x"] = lum(surf["floor"]) / t["floor"]
    for em in pl.get("emitters", []):
        if em["name"].startswith("floor") and "clipped" in em["name"]:
            row["lit_floor_x"] = lum(em["radiance"]) / t["lit_floor"] if t["lit_floor"] else float("nan")
            row["clip_over_truth_lit"] = t["clip"] / t["lit_floor"] if t["lit_floor"] else float("nan")
    for name, rad in pl.get("pinned_regions", {}).items():  # a level measured by its penumbra (photosun110)
        if name.startswith("floor"):
            row["lit_floor_x"] = lum(rad) / t["lit_floor"] if t["lit_floor"] else float("nan")
    row["object"] = object_regions(rooms / room, keep / room / f"out_{light}" / "composite.png")
    return row


def recompose(keep: Path, rooms: Path, room: str, out: Path, shared: Path, sun_scale=None) -> dict:
    """The kept room's photo composite again, with the estimated sun's irradiance replaced: sun_scale(E_perp
    (3,), room) -> (3,) (e.g. the truth's). Returns the score."""
    import lighting.sun as S
    from bench.own_room_flow import _composite_argv, _photoar, score, write_inputs

    orig = S._sun_strength

    def ss(d, holes, occluder, pm, B, G_c, info):
        sun, inf = orig(d, holes, occluder, pm, B, G_c, info)
        if sun is not None and sun_scale is not None:
            import dataclasses

            sun = dataclasses.replace(sun, irradiance=np.asarray(sun_scale(sun.irradiance, room), float))
        return sun, inf

    S._sun_strength = ss
    try:
        inp = write_inputs(rooms / room, out / "in")
        o = out / "out_photo"
        rc, err, _ = _photoar(_composite_argv(keep / room / "room", o, inp, "photo", keep / room / "cache"))
        return score(rooms / room, o / "composite.png", shared) if rc == 0 else {"error": err}
    finally:
        S._sun_strength = orig


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("keep", type=Path)
    ap.add_argument("rooms", type=Path)
    ap.add_argument("room")
    ap.add_argument("--light", default="photo")
    ap.add_argument("--json", type=Path)
    ap.add_argument("--truth-sun", type=Path, help="recompose each room with the truth's sun irradiance into this folder")
    a = ap.parse_args()
    if a.truth_sun:
        import os

        shared = Path(os.environ.get("PHOTOAR_SHARED", ROOT.parent / "shared"))
        for room in a.room.split(","):
            s = json.loads((a.rooms / room / "scene.json").read_text())
            irr = [p for p in s["primitives"] if p.get("role") == "sun"][0]["irradiance_perpendicular"]
            sc = recompose(a.keep, a.rooms, room, a.truth_sun / room, shared, lambda e, r, irr=irr: irr)
            print(room, "truth sun:", {k: sc.get(k) for k in ("energy_ratio", "rmse_affected", "rmse_object", "bias_object")},
                  flush=True)
        return
    rows = []
    print("room      sun/truth  R/B (truth)   walls/truth floor/truth litfloor/truth clip/truth-lit  "
          "object: sun side / shade / all (composite over truth)")
    for room in a.room.split(","):
        r = room_row(a.keep, a.rooms, room, a.light)
        rows.append(r)
        ob = r["object"]
        print(f"{room:9s} {r.get('sun_x', float('nan')):6.2f}   {r.get('sun_rb', float('nan')):5.2f} ({r['truth']['sun_rb']:.2f})"
              f"   {r.get('wall_x', float('nan')):6.2f}     {r.get('floor_x', float('nan')):6.2f}      "
              f"{r.get('lit_floor_x', float('nan')):6.2f}        {r.get('clip_over_truth_lit', float('nan')):5.2f}       "
              f"{ob.get('sun_side', float('nan')):.3f} ({ob.get('sun_side_px', 0)}) / {ob.get('shade', float('nan')):.3f} "
              f"({ob.get('shade_px', 0)}) / {ob.get('all', float('nan')):.3f}", flush=True)
    if a.json:
        a.json.write_text(json.dumps(rows, indent=1, default=float))


if __name__ == "__main__":
    main()
