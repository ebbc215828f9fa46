"""Captured light per bounce count, part by part (issue 34, branch spur34c): which of spur34b's parts moves
which room. Usage:

    bench_spur34c.py --rooms ~/.cache/photoar/rooms_full --only sun_103,sun_105 --work DIR
                     [--variants base,rho,levels,full,sun] [--json OUT] [--map]

It needs spur34b's product code, which main reverted (0c8b8a6, 47f22bd): run it on a tree with
`git diff a7963e9 5ed2bc0 -- lighting app | git apply` (lighting.radiance.bounce_levels, estimate_sun's
B_gather); on main it stops with that message. Results: docs/unseen.md, section "spur34c".

Per room: calibrate and `scene` once (the own-room flow's calibrated camera, bench/own_room_flow.py; kept in
DIR/ROOM and reused), then `composite --lighting captured` once per variant (each its own precompute cache)
and the shared scorer. Variants (lighting.radiance.bounce_levels is spur34b's rule; B the light the engine
holds per bounce count, rho the reflectivities, the sun's strength from lighting.sun._sun_strength):
  base    main: B = [L] * 5, rho = L / (G L); strength rho = L / (G L), E_ind = G L
  rho     the bounce-consistent reflectivities only; B = [L] * 5; strength as base
  levels  rho and B per bounce count; strength from the camera's level alone (B[n] / (G B[n]), G B[n])
  full    spur34b: rho and B per bounce count; strength gathers one bounce short (B[n] / (G B[n-1]), G B[n-1])
  sun     the engine as base; only the strength from the levels, one bounce short (as full)
A name sun_room / window_room / lamps_room runs the shared scene's own folder (`composite --lighting captured
--passes 64`, as tests/lighting/test_sun.py). With --map, bench/bench_spurious_map.py's table (which light term
puts the spurious pixels where) per variant instead, plus 'known' (the benchmark folder under known light).
With --reflectivity, per surface of the benchmark folder itself (the true geometry, declared albedos) under
captured light: the median of main's reflectivity (L / G L) and of the bounce-consistent one over the declared
albedo, on measured non-emitting patches split by origin (photo, probe).
Each row: the scorer's figures, the sun's estimated strength (luminance of E_perp) and the spurious bound
max(0.01, 1.2 x own_room_flow.spurious_noise_floor)."""
from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

VARIANTS = ("base", "rho", "levels", "full", "sun")
_state: dict = {"variant": "base", "levels": None, "sun": None}


def _patch() -> None:
    """Route lighting.radiance.bounce_levels and app.stages.sun.estimate_sun through the current variant."""
    import app.stages.sun as sun_stage
    import lighting.radiance as radiance

    if not hasattr(radiance, "bounce_levels"):
        raise SystemExit("bench_spur34c: lighting.radiance has no bounce_levels (spur34b's code, reverted on main); "
                         "apply it first: git diff a7963e9 5ed2bc0 -- lighting app | git apply")
    real_levels, real_sun = radiance.bounce_levels, sun_stage.estimate_sun
    _state["real_levels"] = real_levels

    def levels(G, rm, sources, bounces, *a, **k):
        B, rho = real_levels(G, rm, sources, bounces, *a, **k)
        _state["levels"] = B
        v = _state["variant"]
        flat = np.stack([rm.radiance] * (bounces + 1))
        if v in ("base", "sun"):
            return flat, rm.reflectivity
        if v == "rho":
            return flat, rho
        return B, rho

    def estimate(*a, **k):
        v = _state["variant"]
        if v == "levels":
            k.pop("B_gather", None)
        elif v == "sun":
            a = list(a)
            a[8] = _state["levels"][-1]  # B, the camera's level
            k["B_gather"] = _state["levels"][-2]
        sun, info = real_sun(*a, **k)
        _state["sun"] = info
        _state["pixels"] = dict(pix_patch=a[2], L_b=a[5], saturated=a[6], recv=a[7],
                                shape=np.array(a[0].photo.shape[:2]))
        return sun, info

    import lighting.sun as sun_mod

    real_strength = sun_mod._sun_strength

    def strength(d, holes, occluder, pm, B, G_c, info, B_gather=None):
        """Keep the strength's inputs per patch (for offline rules: bench_spur34c's --dump)."""
        from lighting.sun import SUN_DIAMETER_DEG, Sun, SunLight
        light = SunLight(Sun(d, SUN_DIAMETER_DEG, np.full(3, np.pi), np.zeros(3)), holes, occluder, where="dump")
        e = light.patch_irradiance(pm.corners, pm.normal, ~pm.is_emitter)[:, 0]
        G = np.asarray(G_c, np.float64)
        lv = _state["levels"]
        _state["dump"] = dict(d=np.asarray(d), e=e, normal=pm.normal, quad=pm.quad, corners=pm.corners,
                              is_emitter=pm.is_emitter, B=B, E_ind=G @ (B if B_gather is None else B_gather),
                              E_L=G @ B, albedo=np.asarray(getattr(pm, "albedo", np.zeros_like(B))),
                              B4=lv[-1] if lv is not None else B, B3=lv[-2] if lv is not None else B,
                              GB3=G @ lv[-2] if lv is not None else G @ B)
        return real_strength(d, holes, occluder, pm, B, G_c, info, B_gather)

    sun_mod._sun_strength = strength
    radiance.bounce_levels = levels
    sun_stage.estimate_sun = estimate


def run(root: Path, work: Path, shared: Path, variants: list[str]) -> dict:
    """Calibrate + scene once (reused when DIR/ROOM/room/scene.json exists), then each variant's composite."""
    import own_room_flow as f

    work.mkdir(parents=True, exist_ok=True)
    shared_scene = root.parent.name == "scenes"  # a shared scene: its own folder under captured light
    inp = f.write_inputs(root, work / "in")
    if not shared_scene:
        f.declared_openings(inp["room"], inp["scene"])
    room = root if shared_scene else work / "room"
    if not (room / "scene.json").is_file():
        rc, err, _ = f._photoar(["calibrate", str(inp["photo"]), "--lines", str(inp["lines"]), "--height",
                                 str(inp["height"]), "--out", str(work / "cal")])
        if rc:
            raise RuntimeError(f"{root.name}: calibrate: {err}")
        rc, err, _ = f._photoar(f.scene_argv(inp, room, work / "cal" / "camera.json"))
        if rc:
            raise RuntimeError(f"{root.name}: scene: {err}")
    floor = f.spurious_noise_floor(root)
    truth_sun = next((p for p in inp["scene"]["primitives"] if p["type"] == "sun"), None)
    w = np.array([0.2126, 0.7152, 0.0722])
    out = {"spurious_floor": floor, "bound": max(0.01, 1.2 * floor), "variants": {}}
    if truth_sun is not None:
        out["truth_sun_lum"] = float(np.asarray(truth_sun["irradiance_perpendicular"], float) @ w)
    for v in variants:
        _state.update(variant=v, levels=None, sun=None)
        t0 = time.process_time()
        dest = work / f"out_{v}"
        shutil.rmtree(work / f"cache_{v}", ignore_errors=True)  # the precompute runs (the variants live there)
        argv = (["composite", str(room), "--out", str(dest), "--lighting", "captured", "--passes", "64",
                 "--cache", str(work / f"cache_{v}")] if shared_scene
                else f._composite_argv(room, dest, inp, "captured", work / f"cache_{v}"))
        rc, err, _ = f._photoar(argv)
        row: dict = {"cpu_s": round(time.process_time() - t0, 1)}
        if rc:
            row["error"] = err
        else:
            row.update(f.score(root, dest / "composite.png", shared))
            info = _state["sun"] or {}
            if "irradiance_perpendicular" in info:
                row["sun_lum"] = float(np.asarray(info["irradiance_perpendicular"]) @ w)
                if "truth_sun_lum" in out:
                    row["sun_rel"] = row["sun_lum"] / out["truth_sun_lum"]
        out["variants"][v] = row
        if _state.get("dump") is not None:
            np.savez_compressed(work / f"strength_{v}.npz", **_state.pop("dump"), **_state.pop("pixels", {}))
        print(f"{root.name} {v}: " + " ".join(f"{k}={row[k]:.4g}" for k in
              ("energy_ratio", "rmse_affected", "spurious", "rmse_object", "bias_object", "sun_rel") if k in row)
              + f" (bound {out['bound']:.3f})" + (f" error {row['error']}" if "error" in row else ""), flush=True)
    return out


def spurious_maps(root: Path, work: Path, variants: list[str]) -> None:
    """bench_spurious_map's table per variant on the calibrated scene `run` kept (and 'known': the benchmark
    folder under known light); each table also goes to WORK/map_<variant>.json."""
    import bench_spurious_map as m

    for v in variants:
        _state.update(variant="base" if v == "known" else v, levels=None, sun=None)
        cache = work / f"mapcache_{v}"
        shutil.rmtree(cache, ignore_errors=True)
        cache.mkdir(parents=True)
        room = root if v == "known" or root.parent.name == "scenes" else work / "room"
        argv = sys.argv
        sys.argv = ["bench_spurious_map", str(room), str(root), "--cache", str(cache), "--json",
                    str(work / f"map_{v}.json")] + (["--lighting", "known"] if v == "known" else [])
        try:
            m.main()
        finally:
            sys.argv = argv
            shutil.rmtree(cache, ignore_errors=True)


def reflectivities(root: Path, work: Path) -> list[dict]:
    """Per surface and origin (photo, probe): patches, declared albedo, main's and the bounce-consistent
    reflectivity over it (medians of luminance) on the benchmark folder `root` under captured light."""
    import app.stages.precompute as pc
    import lighting.radiance as radiance
    from app.cli import main as cli

    w = np.array([0.2126, 0.7152, 0.0722])
    real, got = pc.captured_radiance_mesh, {}

    def mesh(patches, G, occ, probe, scene, pix_patch, bounces=None):
        rm = real(patches, G, occ, probe, scene, pix_patch, None)
        _, rho = _state["real_levels"](G, rm, np.array([q.light_shaped for q in scene.quads], bool)[patches.quad],
                                        max(bounces or 4, 2))
        got.update(main=rm.reflectivity @ w, new=rho @ w, origin=rm.origin, quad=np.asarray(patches.quad),
                   emit=np.zeros(len(rm.origin), bool) if rm.emitter is None else np.asarray(rm.emitter, bool),
                   albedo=np.asarray(patches.albedo) @ w, names=[q.name for q in scene.quads],
                   shaped=np.array([q.light_shaped for q in scene.quads], bool), L=rm.radiance @ w)
        return rm  # the engine as main

    pc.captured_radiance_mesh = mesh
    shutil.rmtree(work / "refl", ignore_errors=True)
    try:
        if cli(["-q", "composite", str(root), "--out", str(work / "refl" / "o"), "--cache", str(work / "refl" / "c"),
                "--passes", "8", "--lighting", "captured"]):
            raise RuntimeError(f"{root}: composite --lighting captured failed")
    finally:
        pc.captured_radiance_mesh = real
        shutil.rmtree(work / "refl", ignore_errors=True)
    rows = []
    for q in np.flatnonzero(got["shaped"]):  # windows and lamps: their captured radiance (roomgen's room_config.json
        m = got["quad"] == q  # holds the declared one)
        if m.any():
            rows.append({"surface": got["names"][q], "origin": "light", "patches": int(m.sum()),
                         "radiance_lum_median": float(np.median(got["L"][m]))})
            print(f"{root.name} {got['names'][q]:16s} light: {m.sum():4d} patches, captured radiance (luminance, "
                  f"median) {rows[-1]['radiance_lum_median']:.3f}", flush=True)
    for q in np.unique(got["quad"]):
        for origin, tag in ((radiance.PHOTO, "photo"), (radiance.PROBE, "probe")):
            m = (got["quad"] == q) & (got["origin"] == origin) & ~got["emit"] & (got["albedo"] > 0)
            if m.sum() < 20:
                continue
            rows.append({"surface": got["names"][q], "origin": tag, "patches": int(m.sum()),
                         "declared": float(np.median(got["albedo"][m])),
                         "main": float(np.median(got["main"][m] / got["albedo"][m])),
                         "bounce_consistent": float(np.median(got["new"][m] / got["albedo"][m]))})
            r = rows[-1]
            print(f"{root.name} {r['surface']:16s} {tag}: {r['patches']:4d} patches, declared {r['declared']:.3f}, "
                  f"main / declared {r['main']:.3f}, bounce-consistent / declared {r['bounce_consistent']:.3f}",
                  flush=True)
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rooms", default=os.path.expanduser("~/.cache/photoar/rooms_full"))
    ap.add_argument("--only", required=True, help="comma-separated room folder names")
    ap.add_argument("--work", required=True, help="work folder (scene folders kept and reused)")
    ap.add_argument("--variants", default=",".join(VARIANTS))
    ap.add_argument("--shared", default=os.environ.get("PHOTOAR_SHARED", "../shared"))
    ap.add_argument("--json", help="append the results here")
    ap.add_argument("--map", action="store_true", help="bench_spurious_map's table per variant (and 'known')")
    ap.add_argument("--reflectivity", action="store_true",
                    help="per surface: main's and the bounce-consistent reflectivity over the declared albedo")
    a = ap.parse_args(argv)
    variants = a.variants.split(",")
    bad = [v for v in variants if v not in VARIANTS + (("known",) if a.map else ())]
    if bad:
        ap.error(f"unknown variant(s) {bad}; choose from {VARIANTS}")
    if any(n.endswith("_106") for n in a.only.split(",")):
        ap.error("the *_106 rooms are the held-out check")
    _patch()
    res = {}
    for name in a.only.split(","):
        root = Path(a.shared) / "scenes" / name if name in ("sun_room", "window_room", "lamps_room") \
            else Path(a.rooms).expanduser() / name
        if a.reflectivity:
            res[name] = reflectivities(root, Path(a.work) / name)
        elif a.map:
            if (root.parent.name != "scenes" and not (Path(a.work) / name / "room" / "scene.json").is_file()
                    and any(v != "known" for v in variants)):
                run(root, Path(a.work) / name, Path(a.shared), [])  # calibrate and scene only
            spurious_maps(root, Path(a.work) / name, variants)
            continue
        else:
            res[name] = run(root, Path(a.work) / name, Path(a.shared), variants)
        if a.json:
            p = Path(a.json)
            old = json.loads(p.read_text()) if p.is_file() else {}
            old[name] = res[name]
            p.write_text(json.dumps(old, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
