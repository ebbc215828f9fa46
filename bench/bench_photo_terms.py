"""Photo light against captured light on one room: which estimated term costs the object (issue 34 item 4).

Photo light (lighting.photolight) and captured light (lighting.radiance) build the same thing, a radiance per
patch of the room model, from different measurements: photo light reads the seen patches off the photo and fits
the emitters (windows, lamps, clipped regions) to the walls; captured light reads the probe. This bench takes a
room `scene` made by the own-room flow (bench_unseen --keep DIR: DIR/<room>/room or room_true_cam) and
composites it under captured light, then under photo light with one of photo light's terms replaced by captured
light's, each scored by the shared scorer against the room's truth:

- `photo`: as the product runs it;
- `cap_emit`: the emitter patches (the model's windows / lamps and the fitted clipped regions) take captured
  light's radiance;
- `cap_rest`: every other patch (the far field: the photo-read walls and the gathered unseen patches) takes
  captured light's radiance;
- `cap_all`: every patch takes captured light's radiance;
- `noscale`: photo light without the emitter scale at the object (lighting.photolocal: scale 1);
- `cap_emit_noscale`: both;
- `bounce_limited`: photo light's mesh per bounce level as the truth's renderer (4 bounces after the camera
  hit) limits it: the object gathers one bounce less than the camera sees, as under known light;
- `prior:NAME=VALUE[;NAME=VALUE]`: photo light with lighting.photolight.PhotoPriors(NAME=VALUE, ...).

Printed per variant: energy / rmse_affected / rmse_object (bias_object) and the emitter scale at the object
(lighting.photolocal); with captured light also photo light's radiance over captured's (luminance, area-weighted)
per emitter quad, over the photo-read patches, over the gathered (unseen) ones and per surface of those, saved
with both meshes to OUT/radiance.npz. The captured-light swaps are not self-consistent (a swapped emitter does not
re-light the gathered patches): they say where the object's light comes from, not what a fix would give. Results:
docs/unseen.md, "photosun34".

`python bench/bench_photo_terms.py KEEP_DIR ROOMS_DIR ROOM [--camera cal|true] [--variants photo,cap_emit,...]
[--no-captured] [--known] [--out DIR]`
"""
from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

VARIANTS = ("photo", "cap_emit", "cap_rest", "cap_all", "noscale", "cap_emit_noscale")


class Hooks:
    """Monkeypatches of use_lighting (stash captured light's mesh; swap photo light's terms) and of the
    photolocal scale, active for one composite at a time."""

    def __init__(self):
        from app.stages import precompute
        from lighting import photolocal

        self.variant = "photo"
        self.captured: dict | None = None
        self.info: dict = {}
        orig_use, orig_scale = precompute.use_lighting, photolocal.LocalLight.scale
        hooks = self

        def use_lighting(pre, lighting, fit_photo):
            orig_use(pre, lighting, fit_photo)
            pm = pre.patches
            if lighting == "known":
                hooks.known = {"B": np.array(pre.B[-1]), "patches": pm}
            elif lighting == "captured":
                hooks.captured = {"B": np.array(pre.B), "emitter": np.array(pre.emitter, bool)}
            elif lighting == "photo":
                hooks.photo = {"B": np.array(pre.B[-1]), "origin": np.array(pre.origin), "patches": pm}
                if hooks.variant.startswith("cap_"):
                    hooks.swap(pre)
                elif hooks.variant == "bounce_limited":
                    hooks.bounce_limited(pre)

        def scale(self_, centre, radius):
            s = orig_scale(self_, centre, radius)
            hooks.info["scale_product"] = s
            return 1.0 if "noscale" in hooks.variant else s

        orig_fit = precompute.fit_photo_light

        def fit_photo_light(pre, scene, bounces, priors, *rest):
            hooks.quad_names = [q.name for q in scene.quads]
            if priors is None and hooks.variant.startswith("prior:"):  # prior:NAME=VALUE[;NAME=VALUE]
                from lighting.photolight import PhotoPriors

                kw = dict(x.split("=") for x in hooks.variant[6:].split(";"))
                priors = PhotoPriors(**{k: eval(v) for k, v in kw.items()})  # noqa: S307 (bench option)
            return orig_fit(pre, scene, bounces, priors, *rest)

        precompute.use_lighting = use_lighting
        precompute.fit_photo_light = fit_photo_light
        photolocal.LocalLight.scale = scale

    def bounce_limited(self, pre) -> None:
        """Each bounce level of photo light's mesh as the truth's renderer limits it: the fitted model (emitters
        and fitted reflectivity) gathered bounce by bounce (lighting.radiosity.gather), and each non-emitter patch's
        measured radiance scaled by its model's level k over its last level (pre.B[k] = B * Bm[k] / Bm[-1])."""
        from lighting.radiosity import gather

        pm = pre.patches
        emit = (np.asarray(pre.origin) == 3) | pm.is_emitter
        B = np.array(pre.B[-1])
        Bm = gather(pre.G_c, np.where(emit[:, None], 0.0, pre.albedo), np.where(emit[:, None], B, 0.0),
                    len(pre.B) - 1)
        with np.errstate(divide="ignore", invalid="ignore"):
            f = [np.where(Bm[-1] > 0, b / Bm[-1], 1.0) for b in Bm]
        pre.B = np.stack([np.where(emit[:, None], B, B * np.clip(fk, 0.0, 1.0)) for fk in f])
        self.info["bounce_levels"] = [round(float(np.sum(pm.area[~emit] @ b[~emit]) /
                                                  max(np.sum(pm.area[~emit] @ B[~emit]), 1e-30)), 3) for b in pre.B]

    def swap(self, pre) -> None:
        """Replace photo light's terms by captured light's, per self.variant."""
        if self.captured is None:
            raise RuntimeError("run captured light first")
        pm = pre.patches
        emit = (np.asarray(pre.origin) == 3) | pm.is_emitter
        cap = self.captured["B"]
        if cap.shape[1] != pre.B.shape[1]:
            raise RuntimeError(f"patch meshes differ: {cap.shape} vs {pre.B.shape}")
        v = self.variant
        take = np.zeros(len(emit), bool)
        if v.startswith("cap_emit"):
            take = emit
        elif v.startswith("cap_rest"):
            take = ~emit
        elif v.startswith("cap_all"):
            take[:] = True
        B = np.array(pre.B)
        B[:, take] = cap[-1][take]
        pre.B = B
        pm.emission = np.where(pm.is_emitter[:, None], np.maximum(pre.B[-1], 1e-12), 0.0)


def term_ratios(B_photo: np.ndarray, B_cap: np.ndarray, patches, origin, names=None) -> dict:
    """Photo light's radiance over captured light's (luminance, area-weighted) per class of patch: each
    emitter quad (the model's, 'quad N') and fitted clipped region ('clipped N'), the photo-read patches,
    the gathered ones; and the photo-read patches' per-patch ratio's median."""
    from lighting.radiance import GATHERED, PHOTO
    from lighting.sources import luminance

    origin = np.asarray(origin)
    lp, lc, a = luminance(B_photo), luminance(B_cap), patches.area
    out = {}
    emit = (origin == 3) | patches.is_emitter
    for q in np.unique(patches.quad[emit]):
        m = emit & (patches.quad == q)
        tag = "quad" if patches.is_emitter[m].any() else "clipped"
        out[f"{tag} {names[q] if names else q}"] = round(float((a[m] @ lp[m]) / max(a[m] @ lc[m], 1e-30)), 3)
    for name, m in (("photo-read", (origin == PHOTO) & ~emit), ("gathered", (origin == GATHERED) & ~emit)):
        if m.any():
            out[name] = round(float((a[m] @ lp[m]) / max(a[m] @ lc[m], 1e-30)), 3)
        for q in np.unique(patches.quad[m]) if names and name == "gathered" else []:
            mq = m & (patches.quad == q)
            out[f"gathered {names[q]}"] = round(float((a[mq] @ lp[mq]) / max(a[mq] @ lc[mq], 1e-30)), 3)
    m = (origin == PHOTO) & ~emit & (lc > 0)
    if m.any():
        out["photo-read median"] = round(float(np.median(lp[m] / lc[m])), 3)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("keep", type=Path)
    ap.add_argument("rooms", type=Path)
    ap.add_argument("room")
    ap.add_argument("--camera", choices=("cal", "true"), default="cal")
    ap.add_argument("--variants", default=",".join(VARIANTS))
    ap.add_argument("--no-captured", action="store_true", help="skip captured light (no cap_* variants then)")
    ap.add_argument("--known", action="store_true",
                    help="also each surface's mean radiance against known light's on the benchmark folder")
    ap.add_argument("--out", type=Path, default=None, help="work folder (default KEEP/ROOM/terms_CAMERA)")
    ap.add_argument("--shared", type=Path, default=Path(os.environ.get("PHOTOAR_SHARED", ROOT.parent / "shared")))
    a = ap.parse_args()
    from bench.own_room_flow import _composite_argv, _photoar, score, write_inputs

    root = a.rooms / a.room
    work = a.keep / a.room
    room = work / ("room" if a.camera == "cal" else "room_true_cam")
    out = a.out or work / f"terms_{a.camera}"
    out.mkdir(parents=True, exist_ok=True)
    inp = write_inputs(root, out / "in")
    cache = work / "cache"
    hooks = Hooks()
    rows = {}
    for v in ([] if a.no_captured else ["captured"]) + a.variants.split(","):
        hooks.variant, hooks.info = v, {}
        light = "captured" if v == "captured" else "photo"
        o = out / f"out_{v}"
        rc, err, _ = _photoar(_composite_argv(room, o, inp, light, cache))
        if rc != 0:
            rows[v] = {"error": err}
            print(v, "error", err, flush=True)
            continue
        s = score(root, o / "composite.png", a.shared)
        rep = json.loads((o / "report.json").read_text())
        pl = rep.get("photo_light", {})
        row = {k: s[k] for k in ("energy_ratio", "rmse_affected", "rmse_object", "bias_object")}
        row["emitter_scale"] = pl.get("emitter_scale_at_object")
        row["scale_product"] = hooks.info.get("scale_product")
        if "bounce_levels" in hooks.info:
            row["bounce_levels"] = hooks.info["bounce_levels"]
            print("  bounce levels / measured:", row["bounce_levels"], flush=True)
        if v == "photo":
            row["emitters"] = [(e["name"], e["radiance"], e["at_lower_bound"]) for e in pl.get("emitters", [])]
            row["wall_albedo"] = pl.get("wall_albedo")
        if v == "photo" and hooks.captured is not None:
            row["photo_over_captured"] = term_ratios(hooks.photo["B"], hooks.captured["B"][-1],
                                                     hooks.photo["patches"], hooks.photo["origin"],
                                                     getattr(hooks, "quad_names", None))
            print("  photo / captured radiance:", row["photo_over_captured"], flush=True)
            print("  emitters:", row["emitters"], "walls", row["wall_albedo"], flush=True)
            pm = hooks.photo["patches"]
            np.savez(out / "radiance.npz", photo=hooks.photo["B"], captured=hooks.captured["B"][-1],
                     origin=hooks.photo["origin"], quad=pm.quad, centre=pm.centre, normal=pm.normal, area=pm.area,
                     names=np.array(getattr(hooks, "quad_names", [])))
        rows[v] = row
        print(f"{a.room} {a.camera} {v:18s} energy {row['energy_ratio']:.3f} aff {row['rmse_affected']:.2f} "
              f"obj {row['rmse_object']:.2f} ({row['bias_object']:+.2f}) scale {row['emitter_scale']} "
              f"(product {row['scale_product']})", flush=True)
    if a.known and hooks.captured is not None:
        rows["surfaces_over_truth"] = surfaces_over_truth(hooks, root, out, a.shared)
    (out / "terms.json").write_text(json.dumps(rows, indent=1))


def surfaces_over_truth(hooks: Hooks, root: Path, out: Path, shared: Path) -> dict:
    """Known light on the benchmark folder (the truth's albedos and emitters on the truth's geometry): its score,
    and each room surface's mean radiance (area-weighted luminance) under photo and captured light over known
    light's, matched by quad name (the patch meshes differ)."""
    from bench.own_room_flow import _photoar, score
    from lighting.sources import luminance
    from recon.scene import load_scene

    o = out / "out_known"
    rc, err, _ = _photoar(["composite", str(root), "--out", str(o), "--lighting", "known", "--cache", str(o / "cache")])
    if rc != 0:
        return {"error": err}
    s = score(root, o / "composite.png", shared)
    res = {"known": {k: s[k] for k in ("energy_ratio", "rmse_affected", "rmse_object", "bias_object")}}
    print(f"{root.name} known energy {s['energy_ratio']:.3f} aff {s['rmse_affected']:.2f} obj {s['rmse_object']:.2f} "
          f"({s['bias_object']:+.2f})", flush=True)

    def means(B, pm, names):
        lum = luminance(B)
        return {names[q]: float(pm.area[pm.quad == q] @ lum[pm.quad == q] / pm.area[pm.quad == q].sum())
                for q in np.unique(pm.quad)}

    kn = means(hooks.known["B"], hooks.known["patches"], [q.name for q in load_scene(root).quads])
    pm = hooks.photo["patches"]
    ph = means(hooks.photo["B"], pm, hooks.quad_names)
    ca = means(hooks.captured["B"][-1], pm, hooks.quad_names)
    for nm in ("ceiling", "floor", "left", "right", "back", "front"):
        if nm in kn and nm in ph and kn[nm] > 0:
            seen = float(np.mean(hooks.photo["origin"][pm.quad == hooks.quad_names.index(nm)] == 2))
            res[nm] = {"photo": round(ph[nm] / kn[nm], 3), "captured": round(ca[nm] / kn[nm], 3),
                       "seen": round(seen, 2)}
            print(f"  {nm:8s} photo / truth {ph[nm] / kn[nm]:.3f}  captured / truth {ca[nm] / kn[nm]:.3f}  "
                  f"seen {seen:.2f}", flush=True)
    return res


if __name__ == "__main__":
    main()
