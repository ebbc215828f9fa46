"""The sun's strength from the photo's own pixels, per candidate, against the truth (issue 34 item 4; photosun110).

Photo light fits the sun's strength through the walls' albedo (lighting.sun._sun_strength on the photo fit's
radiance), which measures rho_wall x rho_floor x sun and so carries the albedo scale to about its power 2.6
(docs/unseen.md "photosun34b", "photo109"). This bench measures, on each room kept by `bench_unseen --keep KEEP`,
what the photo's unclipped pixels say about the sunlit floor's level, without the fit:

- (a) `ramp`: the penumbra of the opening's edges on the floor. A floor pixel's radiance is L_sh + s A, with s its
  share of the sun's 0.53 deg disk through the opening (lighting.sun.SunLight.disk_through, averaged over 3 x 3
  sub-pixel rays on the floor's plane: the renderer's box pixel), L_sh the local shadow level (the mean of the
  unclipped s = 0 floor pixels within 7 px) and A = rho_floor E_sun cos / pi the sunlit step. A is fitted with the
  direction moved by up to a few tenths of a degree (the calibrated camera and the hard-edged direction misplace the
  penumbra by a pixel or two, and the ramp is 2-4 px wide): least squares on the unclipped ramp pixels, and a
  one-sided residual on the clipped ones (the model must reach their level). Pixels near a furniture shadow are left
  out (the meshes' shadows are the centre's ray only).
- (b) `unclipped lit`: the sunlit receiver pixels (the centre's ray, the occluders counted) that do not clip, per
  surface, with the same surface's unlit pixels: E_sun cos / pi = E_ind (L_lit / L_unlit - 1), E_ind gathered from
  the fit's radiance (G_c B).
- (c) `shadow / indirect`: the floor's reflectivity B_unlit / G_c B (what the product divides by).

Printed per room against the truth's scene.json (floor albedo, sun irradiance, direction) and its background.exr
stats (sun_patch_floor_mean_radiance: the sunlit floor's true mean level). Results: docs/unseen.md "photosun110".

`python bench/bench_photo_penumbra110.py KEEP ROOMS room[,room...] [--out DIR] [--truth-direction]`
"""
from __future__ import annotations

import argparse
import json
import logging
import os
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from lighting.sources import luminance  # noqa: E402


def capture(keep: Path, rooms: Path, room: str, out: Path, shared: Path) -> dict:
    """Run the photo composite of a kept room with a hook on the sun stage's estimate_sun (its last call's inputs
    and answer kept); returns {"sun": ..., "score": ...}."""
    import app.stages.sun as SS
    from bench.own_room_flow import _composite_argv, _photoar, score, write_inputs

    state: dict = {}
    orig = SS.estimate_sun

    def hook(scene, pm, pix_patch, pix_pos, dirs, L_b, saturated, recv, B, G_c, occluder, min_overlap=0.5,
             direction=None, bounces=None):
        sun, info = orig(scene, pm, pix_patch, pix_pos, dirs, L_b, saturated, recv, B, G_c, occluder, min_overlap,
                         direction, bounces)
        state["sun"] = {"scene": scene, "pm": pm, "pix_patch": np.array(pix_patch), "pix_pos": np.array(pix_pos),
                        "L_b": np.array(L_b), "recv": np.array(recv), "B": np.array(B), "G_c": G_c,
                        "occluder": occluder, "sun": sun, "info": dict(info)}
        return sun, info

    SS.estimate_sun = hook
    try:
        inp = write_inputs(rooms / room, out / "in")
        o = out / "out_photo"
        rc, err, _ = _photoar(_composite_argv(keep / room / "room", o, inp, "photo", keep / room / "cache"))
        state["score"] = score(rooms / room, o / "composite.png", shared) if rc == 0 else {"error": err}
    finally:
        SS.estimate_sun = orig
    return state


def truth(root: Path) -> dict:
    """The truth's floor albedo (3,), sun irradiance (3,) and direction, and background.exr's sunlit-floor stats."""
    s = json.loads((root / "scene.json").read_text())
    pr = {p["name"]: p for p in s["primitives"]}
    sun = [p for p in s["primitives"] if p.get("role") == "sun"][0]
    return {"floor": np.array(pr["floor"]["albedo"]), "E": np.array(sun["irradiance_perpendicular"]),
            "d": np.array(sun["direction_to_sun"]), "lit_mean": s["stats"].get("sun_patch_floor_mean_radiance"),
            "unlit_mean": s["stats"].get("unlit_floor_near_patch_mean_radiance")}


def ramp(sd: dict, d0: np.ndarray, shift: bool = True) -> dict:
    """Candidate (a): lighting.sunramp.sunlit_step on the quad with the most clipped receiver pixels (the sunlit
    floor), from the direction d0, moved with the step (`shift`) or not."""
    from lighting.sun import SUN_DIAMETER_DEG, SunLight, openings
    from lighting.sunramp import CLIP, sunlit_step
    from recon.scene import Sun

    scene, pm = sd["scene"], sd["pm"]
    pp = sd["pix_patch"]
    pix_quad = np.where(pp >= 0, pm.quad[np.maximum(pp, 0)], -1)
    clip = np.any(scene.photo.reshape(-1, 3) >= CLIP, axis=1) & sd["recv"] & (pix_quad >= 0)
    if not clip.any():
        return {"error": "no clipped receiver pixel"}
    qs, cnt = np.unique(pix_quad[clip], return_counts=True)
    q = int(qs[np.argmax(cnt)])
    quad = scene.quads[q]
    holes = openings(scene)

    def light_of(d):
        return SunLight(Sun(d, SUN_DIAMETER_DEG, np.ones(3), np.zeros(3)), holes, sd["occluder"], where="bench")

    n = np.asarray(quad.normal, np.float64)
    r = sunlit_step(light_of, scene.camera, scene.photo, sd["L_b"], pix_quad, sd["pix_pos"], sd["recv"], q,
                    (quad.corners[0], n), np.asarray(d0, np.float64), move=shift)
    if r is None:
        return {"error": "no step (too few ramp pixels, a move over the limit or no positive step)"}
    return {"A": float(luminance(r.step)), "A_c": r.step, "L_sh": float(luminance(r.shadow)),
            "moved_deg": r.moved_deg, "n_ramp": r.n_ramp, "n_clipped": r.n_clipped, "cos": float(n @ r.direction),
            "quad": quad.name, "d": r.direction}


def unclipped_lit(sd: dict, d: np.ndarray) -> dict:
    """Candidate (b): per surface, E_sun cos / pi = E_ind (L_lit / L_unlit - 1) on its sunlit pixels that do not clip
    (the centre's ray with the occluders, 3 px in from the outline), E_ind the fit's gathered light at each pixel's
    patch, L_unlit the median of the same surface's unlit unclipped pixels. Returns {surface: (E_sun est (lum), n)}."""
    from scipy.ndimage import binary_erosion

    from lighting.sun import SUN_DIAMETER_DEG, SunLight, openings
    from recon.scene import Sun

    scene, pm, cam = sd["scene"], sd["pm"], sd["scene"].camera
    H, W = cam.height, cam.width
    pp = sd["pix_patch"]
    recv = sd["recv"] & (pp >= 0)
    pix_quad = np.where(pp >= 0, pm.quad[np.maximum(pp, 0)], -1)
    clip = np.any(scene.photo.reshape(-1, 3) >= 250, axis=1)
    light = SunLight(Sun(d, SUN_DIAMETER_DEG, np.ones(3), np.zeros(3)), openings(scene), sd["occluder"], where="bench")
    idx = np.flatnonzero(recv)
    nrm = pm.normal[pp[idx]]
    v = light.visibility(sd["pix_pos"][idx].astype(np.float64), nrm)
    lit = np.zeros(H * W, bool)
    lit[idx[v > 0.2]] = True
    unlit = np.zeros(H * W, bool)
    unlit[idx[v <= 0]] = True
    lit = binary_erosion(lit.reshape(H, W), iterations=3).reshape(-1)
    unlit = binary_erosion(unlit.reshape(H, W), iterations=3).reshape(-1)
    vis = np.zeros(H * W)
    vis[idx] = v
    E_ind = luminance(np.asarray(sd["G_c"], np.float64) @ np.asarray(sd["B"], np.float64))
    lum = luminance(sd["L_b"])
    out = {}
    for q in np.unique(pix_quad[lit & ~clip]):
        a = lit & ~clip & (pix_quad == q)
        b = unlit & ~clip & (pix_quad == q)
        if a.sum() < 20 or b.sum() < 20:
            continue
        E = E_ind[pp[a]]
        ratio = lum[a] / np.median(lum[b])
        est = np.pi * E * (ratio - 1.0) / vis[a]
        out[scene.quads[int(q)].name] = (float(np.median(est)), int(a.sum()), float(np.median(ratio)),
                                         int((lit & clip & (pix_quad == q)).sum()))
    return out


def floor_reflectivity(sd: dict, q_name: str, d: np.ndarray) -> float:
    """Candidate (c) / the product's divisor: the median B / (G_c B) over the floor's unlit patches (luminance)."""
    from lighting.sun import SUN_DIAMETER_DEG, SunLight, openings
    from recon.scene import Sun

    pm, scene = sd["pm"], sd["scene"]
    q = [i for i, x in enumerate(scene.quads) if x.name == q_name][0]
    light = SunLight(Sun(d, SUN_DIAMETER_DEG, np.full(3, np.pi), np.zeros(3)), openings(scene), sd["occluder"],
                     where="bench")
    e = light.patch_irradiance(pm.corners, pm.normal, ~pm.is_emitter)[:, 0]
    B = np.asarray(sd["B"], np.float64)
    E = np.asarray(sd["G_c"], np.float64) @ B
    unl = (pm.quad == q) & (e == 0) & ~pm.is_emitter & (luminance(E) > 0)
    return float(np.median(luminance(B[unl]) / luminance(E[unl])))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("keep", type=Path)
    ap.add_argument("rooms", type=Path)
    ap.add_argument("room")
    ap.add_argument("--out", type=Path, default=Path("/tmp/bench_photo_penumbra110"))
    ap.add_argument("--shared", type=Path, default=Path(os.environ.get("PHOTOAR_SHARED", ROOT.parent / "shared")))
    a = ap.parse_args()
    rows = {}
    for room in a.room.split(","):
        state = capture(a.keep, a.rooms, room, a.out / room, a.shared)
        logging.disable(logging.WARNING)
        t, sd = truth(a.rooms / room), state.get("sun")
        if sd is None or sd["sun"] is None:
            print(f"{room}: no sun estimated", flush=True)
            continue
        d0 = np.asarray(sd["sun"].direction, np.float64)
        E_t = float(luminance(t["E"]))
        E_p = float(luminance(np.asarray(sd["sun"].irradiance)))
        rho_t = float(luminance(t["floor"]))
        row = {"E_truth": E_t, "E_product": E_p, "score": state["score"]}
        for name, d_start, shift in (("est", d0, False), ("est+move", d0, True), ("truth dir", t["d"], False)):
            r = ramp(sd, d_start, shift)
            if "error" in r:
                print(f"  {room} {name}: {r['error']}")
                continue
            A_t = rho_t * E_t * r["cos"] / np.pi
            rho_p = floor_reflectivity(sd, r["quad"], r["d"])
            E_a = np.pi * r["A"] / (rho_p * r["cos"])
            row[name] = {"A_over_truth": r["A"] / A_t, "E_over_truth_rho_fit": E_a / E_t, "rho_fit_over_truth":
                         rho_p / rho_t, "lit_over_truth": (r["L_sh"] + r["A"]) / t["lit_mean"], **{
                             k: r[k] for k in ("moved_deg", "n_ramp", "n_clipped", "L_sh")}}
            print(f"{room} {name:9s}: A/truth {r['A'] / A_t:.2f}  lit {(r['L_sh'] + r['A']):.3f} / truth "
                  f"{t['lit_mean']:.3f} ({(r['L_sh'] + r['A']) / t['lit_mean']:.2f})  shadow {r['L_sh']:.3f} "
                  f"(truth ring {t['unlit_mean']:.3f})  moved {r['moved_deg']:.2f} deg  "
                  f"ramp px {r['n_ramp']} clipped {r['n_clipped']}  rho_fit/truth {rho_p / rho_t:.2f}  "
                  f"sun {E_a / E_t:.2f}x (product {E_p / E_t:.2f}x)", flush=True)
        b = unclipped_lit(sd, d0)
        row["unclipped_lit"] = {k: {"E_over_truth": v[0] / E_t, "n": v[1], "ratio": v[2], "n_clipped": v[3]}
                                for k, v in b.items()}
        print(f"{room} (b) unclipped lit: " + "; ".join(f"{k} {v[0] / E_t:.2f}x (n {v[1]}, lit/unlit {v[2]:.1f}, "
                                                        f"clipped {v[3]})" for k, v in b.items()), flush=True)
        rows[room] = row
        logging.disable(logging.NOTSET)
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "penumbra.json").write_text(json.dumps(rows, indent=1, default=float))


if __name__ == "__main__":
    main()
