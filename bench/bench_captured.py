"""Captured-lighting benchmark (seed sec. 4.2): the radiance mesh from the probe bracket and the photo.

usage: python bench/bench_captured.py [--shared ../shared]

Per shared scene: each emitter's captured radiance (area-weighted over its patches) against the
declared one; the largest per-patch emitter error with and without the EM split of pixel flux
(from probe_truth.exr, so only the projection is measured); the median relative error of the
recovered reflectivity per source of a patch's radiance (photo, probe, gathered); the share of
the declared emitters' power on the patches found to emit from the captured radiance alone
(emitter_power_found) and the power of patches wrongly found to emit (emitter_extra, same unit);
and the scorer's figures for `composite --lighting captured`.
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app import composite  # noqa: E402
from app.engine import Engine, EngineParams  # noqa: E402
from app.report import table  # noqa: E402
from lighting import metrics  # noqa: E402
from lighting import radiance as R  # noqa: E402
from recon.io import read_exr, read_image_rgb  # noqa: E402
from recon.patches import build_patches  # noqa: E402
from recon.response import luminance  # noqa: E402
from recon.scene import load_scene  # noqa: E402


def bench_scene(name: str, d: Path, cache: Path) -> dict:
    import cv2

    params = EngineParams(lighting="captured")
    with tempfile.TemporaryDirectory() as out:
        composite.main(d, Path(out) / "o", params, cache_dir=cache, quiet=True)
        pixels = read_image_rgb(Path(out) / "o" / "composite.png")
    scene = load_scene(d)
    eng = Engine(scene, params, cache_dir=cache, quiet=True)
    pm = eng.pre.patches
    truth = build_patches(eng.scene, params.patch_size, params.emitter_patch_size)
    em = truth.is_emitter
    for q in np.unique(pm.quad[em]):
        sel = em & (pm.quad == q)
        w = pm.area[sel]
        est = (eng.pre.B[-1][sel] * w[:, None]).sum(0) / w.sum()
        print(f"{name}: emitter {scene.quads[q].name}: captured {np.round(est, 2).tolist()} declared "
              f"{scene.quads[q].emission.tolist()}")
    lp = json.loads((d / "scene.json").read_text())["light_probe"]
    img = read_exr(d / "probe_truth.exr")
    em_err = {}
    for it in (0, 8):
        rad, _ = R.project_probe(pm, eng.cam_occ, lp, img, iterations=it)
        em_err[it] = float(np.abs(luminance(rad[em]) / luminance(truth.emission[em]) - 1).max())
    row = {"scene": name, "emitter_err_plain": em_err[0], "emitter_err_em": em_err[8]}
    for label, code in (("photo", R.PHOTO), ("probe", R.PROBE), ("gathered", R.GATHERED)):
        sel = (eng.pre.origin == code) & ~em & (luminance(truth.albedo) > 0)
        rel = np.abs(luminance(pm.albedo[sel]) / luminance(truth.albedo[sel]) - 1)
        row[f"refl_err_{label}"] = float(np.median(rel)) if sel.any() else float("nan")
        row[f"n_{label}"] = int(sel.sum())
    # emitters found from the radiance alone (nothing declared is read) against the declared ones
    power = luminance(truth.emission) * truth.area
    found = eng.pre.emitter
    row["emitter_power_found"] = float(power[found].sum() / power.sum())
    row["emitter_extra"] = float((luminance(eng.pre.B[-1]) * pm.area)[found & ~em].sum() / power.sum())
    mask = cv2.imread(str(d / "truth_mask.png"), cv2.IMREAD_GRAYSCALE)
    s = metrics.score_regions(pixels, scene.photo, read_image_rgb(d / "truth.png"), mask)
    row.update(energy=s["energy_ratio"], rmse=s["rmse_affected"], untouched=s["rmse_affected_if_untouched"],
               spurious=s["spurious"], rmse_object=s["rmse_object"])
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--shared", type=Path, default=ROOT.parent / "shared")
    a = ap.parse_args()
    scenes = [(n, a.shared / "scenes" / n) for n in ("window_room", "lamps_room")
              if (a.shared / "scenes" / n / "scene.json").is_file()]
    if not scenes:
        sys.exit(f"no shared scenes under {a.shared}: this bench needs their probe brackets and truth")
    with tempfile.TemporaryDirectory() as cache:
        rows = [bench_scene(n, d, Path(cache)) for n, d in scenes]
    print(table(rows, list(rows[0])))


if __name__ == "__main__":
    main()
