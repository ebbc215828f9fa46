"""Photo light's albedo scale and the sun's strength against the truth, per fit variant (issue 34 item 4; photosun34b).

For each room kept by `bench_unseen --keep KEEP` (KEEP/<room>/room, /cache) the photo-light composite is run once
with two hooks: the interreflection fit's inputs (lighting.photolight.fit_photo_light) and the sun strength's
(lighting.sun._sun_strength: the direction, the patches' sun share e = cos x sunlit share, the radiance B and the
transfers G_c) are kept. Then the fit is run again per variant (`base`, or PhotoPriors fields `NAME=VALUE[,...]`)
and the sun's strength is recomputed from the variant's radiance with the product's formula (pi (B_lit / rho -
E_ind) / cos, median over the fully sunlit patches; `strength`) and with refl108's bounce rule (`strength_bounces`:
lighting.sun._sun_strength with bounces 4, the emitters at their fitted radiance). Printed against the truth's
scene.json: the walls' and the floor's albedo (luminance; k = truth / fit), each declared emitter's radiance over
the truth's, and the sun's irradiance over the truth's. The replica of the product's sun is printed beside the product's.
Results: docs/unseen.md, "photosun34b" and "photo109".

`python bench/bench_photo_sunscale.py KEEP ROOMS room[,room...] [--variants "base;bounce_levels=4"] [--out DIR]`
"""
from __future__ import annotations

import argparse
import copy
import dataclasses
import json
import logging
import os
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from lighting.sources import luminance  # noqa: E402


def strength(d: np.ndarray, e: np.ndarray, quad: np.ndarray, emit: np.ndarray, normal: np.ndarray, G: np.ndarray,
             B: np.ndarray) -> np.ndarray:
    """The sun's irradiance (3,) from radiance B (P,3) as lighting.sun._sun_strength computes it (its docstring),
    given the patches' sun share e (P,) for direction d."""
    cos = np.maximum(normal @ d, 0.0)
    full = (e > 0.98 * cos) & (cos > 0.2)
    E_ind = np.asarray(G, np.float64) @ B
    with np.errstate(divide="ignore", invalid="ignore"):
        rho_all = np.where(E_ind > 0, B / E_ind, 0.0)
    est = []
    for q in np.unique(quad[full]):
        unlit = (quad == q) & (e == 0) & ~emit & (luminance(E_ind) > 0)
        on = full & (quad == q)
        if unlit.sum() < 3:
            continue
        rho = np.median(rho_all[unlit], axis=0)
        if np.any(rho <= 0):
            continue
        est.append(np.pi * (B[on] / rho - E_ind[on]) / cos[on, None])
    return np.maximum(np.median(np.concatenate(est), axis=0), 0.0) if est else np.full(3, np.nan)


def strength_bounces(sd: dict, B: np.ndarray, bounces: int = 4) -> np.ndarray:
    """The sun's irradiance (3,) by lighting.sun._sun_strength with its bounce rule (`bounces`, docs "refl108"),
    the emitters' radiance taken from B (photo light's mesh marks them with emission 1)."""
    import lighting.sun as S

    pm = copy.deepcopy(sd["pm"])
    pm.emission = np.where(np.any(pm.emission > 0, axis=1)[:, None], B, 0.0)
    info: dict = {}
    S._sun_strength(sd["d"], sd["holes"], sd["occluder"], pm, B, sd["G"], info, bounces)
    return np.array(info.get("irradiance_perpendicular", [np.nan] * 3))


def truth(root: Path) -> dict:
    """The truth's walls' and floor's albedo (luminance), its sun's irradiance and its emitters' radiance."""
    s = json.loads((root / "scene.json").read_text())
    pr = {p["name"]: p for p in s["primitives"]}
    sun = [p for p in s["primitives"] if p.get("role") == "sun"]
    walls = [luminance(np.array(p["albedo"])) for n, p in pr.items()
             if p.get("role") == "room" and n.split("_")[0] in ("back", "front", "left", "right")]
    return {"wall": float(np.mean(walls)), "floor": float(luminance(np.array(pr["floor"]["albedo"]))),
            "sun": float(luminance(np.array(sun[0]["irradiance_perpendicular"]))) if sun else float("nan"),
            "emit": {p["name"]: p["emitted_radiance"] for p in s["primitives"] if p.get("emitter") and p.get("role") != "sun"}}


def capture(keep: Path, rooms: Path, room: str, out: Path, shared: Path) -> dict:
    """Run the photo composite of a kept room with the hooks; returns {"fit": inputs, "sun": inputs, "score"}."""
    import lighting.photolight as PL
    import lighting.sun as S
    from bench.own_room_flow import _composite_argv, _photoar, score, write_inputs

    state: dict = {}
    orig_ss, orig_fit = S._sun_strength, PL.fit_photo_light

    def ss(d, holes, occluder, pm, B, G_c, info, bounces=None):
        light = S.SunLight(S.Sun(d, S.SUN_DIAMETER_DEG, np.full(3, np.pi), np.zeros(3)), holes, occluder, where="bench")
        e = light.patch_irradiance(pm.corners, pm.normal, ~pm.is_emitter)[:, 0]
        state["sun"] = {"d": d, "e": e, "quad": pm.quad.copy(), "emit": pm.is_emitter.copy(), "normal": pm.normal.copy(),
                        "G": np.array(G_c), "holes": holes, "occluder": occluder, "pm": copy.deepcopy(pm)}
        r = orig_ss(d, holes, occluder, pm, B, G_c, info, bounces)
        state["sun"]["product"] = np.array(info.get("irradiance_perpendicular", [np.nan] * 3))
        return r

    def fit(patches, G, pix_patch, photo, response, priors=None, quad_names=None, where="photo", quad_roles=None,
            sunlit=None, pinned=None):
        state["fit"] = {"patches": copy.deepcopy(patches), "G": G, "pix_patch": pix_patch, "photo": np.array(photo),
                        "response": response, "priors": priors, "quad_names": quad_names, "quad_roles": quad_roles,
                        "sunlit": None if sunlit is None else np.array(sunlit), "pinned": pinned}
        return orig_fit(patches, G, pix_patch, photo, response, priors, quad_names, where, quad_roles, sunlit=sunlit,
                        pinned=pinned)

    S._sun_strength, PL.fit_photo_light = ss, fit
    try:
        inp = write_inputs(rooms / room, out / "in")
        o = out / "out_photo"
        rc, err, _ = _photoar(_composite_argv(keep / room / "room", o, inp, "photo", keep / room / "cache"))
        state["score"] = score(rooms / room, o / "composite.png", shared) if rc == 0 else {"error": err}
    finally:
        S._sun_strength, PL.fit_photo_light = orig_ss, orig_fit
    return state


def refit(state: dict, variant: str):
    """The photo fit again with the variant's priors (`base`: as captured)."""
    import lighting.photolight as PL

    f = state["fit"]
    pr = f["priors"] or PL.PhotoPriors()
    if variant != "base":
        pr = dataclasses.replace(pr, **{k: eval(v) for k, v in (x.split("=") for x in variant.split(","))})  # noqa: S307
    return PL.fit_photo_light(f["patches"], f["G"], f["pix_patch"], f["photo"], f["response"], pr, f["quad_names"],
                              "bench", f["quad_roles"], sunlit=f.get("sunlit"), pinned=f.get("pinned"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("keep", type=Path)
    ap.add_argument("rooms", type=Path)
    ap.add_argument("room")
    ap.add_argument("--variants", default="base;bounce_levels=4")
    ap.add_argument("--out", type=Path, default=Path("/tmp/bench_photo_sunscale"))
    ap.add_argument("--shared", type=Path, default=Path(os.environ.get("PHOTOAR_SHARED", ROOT.parent / "shared")))
    a = ap.parse_args()
    rows = {}
    for room in a.room.split(","):
        state = capture(a.keep, a.rooms, room, a.out / room, a.shared)
        logging.disable(logging.WARNING)
        t, sd = truth(a.rooms / room), state.get("sun")
        prod = float(luminance(sd["product"])) if sd else float("nan")
        print(f"{room}: score {state['score']}; product sun {prod:.1f}, truth {t['sun']:.1f}; walls {t['wall']:.3f}, "
              f"floor {t['floor']:.3f} (truth)", flush=True)
        rows[room] = {"truth": t, "score": state["score"], "product_sun": prod, "variants": {}}
        for v in a.variants.split(";"):
            fit = refit(state, v)
            rep = fit.report
            surf = rep["albedo_fit"]["surfaces"] if rep.get("albedo_fit") else {}
            wall = float(luminance(np.array(rep["wall_albedo"])))
            floor = float(luminance(np.array(surf["floor"]))) if "floor" in surf else float("nan")
            sun = float(luminance(strength(sd["d"], sd["e"], sd["quad"], sd["emit"], sd["normal"], sd["G"],
                                           fit.radiance))) if sd else float("nan")
            ems = {x["name"]: float(luminance(np.array(x["radiance"])) / luminance(np.array(t["emit"][x["name"]])))
                   for x in rep["emitters"] if x["name"] in t["emit"]}
            sun_b = float(luminance(strength_bounces(sd, fit.radiance))) if sd else float("nan")
            rows[room]["variants"][v] = {"wall": wall, "floor": floor, "sun": sun, "sun_bounces": sun_b,
                                         "emitters_over_truth": ems}
            print(f"  {v:24s} walls {wall:.3f} (k {t['wall'] / wall:.2f})  floor {floor:.3f} (k {t['floor'] / floor:.2f})  "
                  f"sun {sun:.1f} ({sun / t['sun']:.2f}x, bounce rule {sun_b / t['sun']:.2f}x)  "
                  + " ".join(f"{n} {r:.2f}x" for n, r in ems.items()), flush=True)
        logging.disable(logging.NOTSET)
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "sunscale.json").write_text(json.dumps(rows, indent=1, default=float))


if __name__ == "__main__":
    main()
