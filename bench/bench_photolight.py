"""Photo-light benchmark (issue 19): light from the photo alone, and its sensitivity to the priors.

usage: python bench/bench_photolight.py [--shared ../shared] [--scenes window_room lamps_room] [--quick]
                                        [--keep-bracket]

Per shared scene, stripped of everything photo light must not use (camera_response, albedos and
textures, emitted_radiance, light_probe; with --keep-bracket the probe's bracket stays, as in a
user's own room folder, and photo light reads the photo through the response recovered from it
instead of the assumed sRGB, lighting.photolight.photo_response, and the response exponent variant
changes nothing): the scorer's figures (energy_ratio, rmse_affected and its
untouched value, spurious, rmse_object) for `composite --lighting photo`, the emitter radiance the
inverse radiosity estimates next to the declared one, and the same figures with each prior (wall
albedo, unseen reflectivity, response exponent) varied by -20 % and +20 %. The transfers are
computed once per scene; each variant re-fits the radiance mesh and renders one frame.
Timings: precompute cold (no cache; includes one fit), the fit alone (warm) and one frame (all
sources), on this machine.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.engine import Engine, EngineParams  # noqa: E402
from recon.io import write_png  # noqa: E402
from app.report import table  # noqa: E402
from lighting.photolight import PhotoPriors, srgb_response  # noqa: E402
from lighting.sources import luminance  # noqa: E402
from recon.scene import load_scene  # noqa: E402


def strip_scene(src: Path, dst: Path, keep_bracket: bool = False) -> Path:
    """A copy of a benchmark scene folder with only what photo light may use: geometry, roles,
    camera, photo and the object (no camera_response, albedos, textures, emitted_radiance, probe);
    keep_bracket: the probe's bracket (light_probe and its images) stays, for its response."""
    dst.mkdir(parents=True, exist_ok=True)
    d = json.loads((src / "scene.json").read_text())
    for k in ("camera_response", "emitters_summary") + (() if keep_bracket else ("light_probe",)):
        d.pop(k, None)
    for f in d.get("light_probe", {}).get("ldr_files", []):
        (dst / f).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(src / f, dst / f)
    for p in d["primitives"]:
        for k in ("albedo", "albedo_texture", "texture_shape", "emitted_radiance"):
            p.pop(k, None)
    (dst / "scene.json").write_text(json.dumps(d))
    files = d["main_camera"].get("files", {})
    for f in (files.get("background_png", "background.png"), d["synthetic_object"]["mesh"]):
        shutil.copy(src / f, dst / f)
    return dst


def score_png(scene_dir: Path, pixels, shared: Path) -> dict:
    sys.path.insert(0, str(shared / "tools"))
    import score  # the shared scorer

    with tempfile.TemporaryDirectory() as t:
        write_png(Path(t) / "c.png", pixels)
        return score.score(str(scene_dir), str(Path(t) / "c.png"))


def relight(eng: Engine, priors: PhotoPriors):
    """An engine of the same scene with other priors (the transfers from the cache) and one frame of it.
    Returns the frame, the seconds the new engine took (the fit, the stages; the transfers read) and its
    fit's report."""
    new = Engine(eng.scene, eng.params, cache_dir=eng.cache_dir, quiet=True, photo_priors=priors)
    return new.render(new.scene.obj), new.precompute_s, new.photo_light


def row(scene: str, prior: str, s: dict, fit: dict) -> dict:
    em = "; ".join(f"{e['name']} {[round(v, 2) for v in e['radiance']]} +-{100 * (e['rel_std'] or 0):.0f}%"
                   for e in fit["emitters"])
    return {"scene": scene, "prior": prior, "energy_ratio": round(s["energy_ratio"], 3),
            "rmse_aff": round(s["rmse_affected"], 2), "untouched": round(s["rmse_affected_if_untouched"], 2),
            "spurious": round(s["spurious"], 5), "rmse_object": round(s["rmse_object"], 2),
            "bias_object": round(s["bias_object"], 2), "implied_albedo": fit["implied_wall_albedo"],
            "emitter_lum": round(sum(float(luminance(e["radiance"])) for e in fit["emitters"]), 2), "emitters": em}


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--shared", type=Path, default=ROOT.parent / "shared")
    ap.add_argument("--scenes", nargs="+", default=["window_room", "lamps_room"])
    ap.add_argument("--quick", action="store_true", help="nominal priors only (no sensitivity)")
    ap.add_argument("--keep-bracket", action="store_true",
                    help="keep the probe bracket: photo light reads the photo through its recovered response")
    a = ap.parse_args()
    base = PhotoPriors()
    variants = [("nominal", base)]
    if not a.quick:
        for f in ("wall_albedo", "unseen_reflectivity", "gamma_scale"):
            for k in (0.8, 1.2):
                variants.append((f"{f} x{k}", dataclasses.replace(base, **{f: getattr(base, f) * k})))
    rows, emit_rows, times = [], [], []
    with tempfile.TemporaryDirectory() as tmp:
        for name in a.scenes:
            src = a.shared / "scenes" / name
            d = strip_scene(src, Path(tmp) / name, a.keep_bracket)
            t0 = time.perf_counter()
            eng = Engine(load_scene(d), EngineParams(lighting="photo"), quiet=True)
            pre_s = time.perf_counter() - t0
            declared = load_scene(src).quads
            nominal_lum = 0.0
            for label, pr in variants:
                frame, fit_s, fit = relight(eng, pr)
                s = score_png(src, frame.pixels, a.shared)
                rows.append(row(name, label, s, fit))
                # summed emitter luminance against the nominal priors' (response variants: other units)
                rows[-1]["emitter_change"] = f"{100 * (rows[-1]['emitter_lum'] / nominal_lum - 1):+.0f}%" \
                    if label != "nominal" and nominal_lum > 0 else ""
                if label == "nominal":
                    nominal_lum = rows[-1]["emitter_lum"]
                if label == "nominal":
                    times.append({"scene": name, "precompute_cold_s": round(pre_s, 1),
                                  "photo_light_fit_s": round(fit_s, 2),
                                  "frame_s": round(frame.stats["frame_s"], 1)})
                    decl = {q.name: [round(float(v), 2) for v in q.emission] for q in declared if q.is_emitter}
                    for e in fit["emitters"]:
                        emit_rows.append({"scene": name, "emitter": e["name"], "estimated": e["radiance"],
                                          "rel_std": e["rel_std"], "declared (scene units)": decl.get(e["name"], "-")})
    print("photo light: scores of `composite --lighting photo` on stripped scenes, priors varied one at a time")
    print(table(rows, list(rows[0])))
    print(f"\nestimated emitter radiance (units of the response photo light read: {fit['response']}) next to the "
          f"declared one (true response; unused)")
    print(table(emit_rows, list(emit_rows[0])))
    print("\ntimings (this machine, shared CPU: expect 2-4x an idle one)")
    print(table(times, list(times[0])))
    return 0


if __name__ == "__main__":
    sys.exit(main())
