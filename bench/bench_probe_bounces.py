"""How many bounces the benchmark's mirror-ball probe sees, against the photo and the known radiosity.

usage: python bench/bench_probe_bounces.py SCENE_DIR [--cache DIR]

SCENE_DIR is a benchmark folder (background.exr, probe_truth.exr, scene.json with its light_probe). The probe's
true HDR image is projected onto the patch mesh as captured light does (lighting.radiance.project_probe), and
the photo's true radiance (background.exr) is averaged per patch (lighting.radiance.photo_radiance). On the
patches both see (probe solid angle > 1e-4 sr, >= 30 photo pixels, not emitters), per surface, the median
luminance ratio probe / photo and probe / the known radiosity after k bounces, B[k] (lighting.radiosity.gather:
the camera sees B[4], the truth's 4 bounces). A probe that sees what the photo sees reads ~1 against the photo
and against B[4]; one rendered with a bounce less reads ~1 against B[3]. Results: docs/unseen.md, "sun_103's
spurious under captured light" (spur34).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

LUM_RGB = np.array([0.2126, 0.7152, 0.0722])


def probe_against_photo(scene_dir: Path, cache: Path | None = None) -> dict[str, dict[str, float]]:
    """{surface: {"patches", "probe/photo", "probe/B[k]" for each level k}}: medians over the patches both see."""
    from app.engine import Engine, EngineParams
    from lighting.radiance import photo_radiance, project_probe
    from recon.io import read_exr
    from recon.scene import load_scene

    s = load_scene(scene_dir)
    e = Engine(s, EngineParams(lighting="known"), cache_dir=cache, quiet=True)
    pm = e.pre.patches
    lp = json.loads((scene_dir / "scene.json").read_text())["light_probe"]
    probe, omega = project_probe(pm, e.cam_occ, lp, read_exr(scene_dir / "probe_truth.exr"))
    pix_patch = e.receivers.pix_patch
    photo, count = photo_radiance(pix_patch, read_exr(scene_dir / "background.exr").reshape(-1, 3),
                                  np.zeros(len(pix_patch), bool), pm.n_patches)
    both = (omega > 1e-4) & (count >= 30) & ~pm.is_emitter
    names = [q.name for q in s.quads]
    lum_probe, lum_photo = probe @ LUM_RGB, photo @ LUM_RGB
    out = {}
    for q in np.unique(pm.quad[both]):
        m = both & (pm.quad == q)
        if m.sum() < 3:
            continue
        row = {"patches": int(m.sum()), "probe/photo": float(np.median(lum_probe[m] / lum_photo[m]))}
        for k, B in enumerate(e.pre.B):
            lum_B = B[m] @ LUM_RGB
            ok = lum_B > 0
            row[f"probe/B[{k}]"] = float(np.median(lum_probe[m][ok] / lum_B[ok])) if ok.any() else float("nan")
        out[names[q]] = row
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene", type=Path)
    ap.add_argument("--cache", type=Path, default=None)
    a = ap.parse_args()
    rows = probe_against_photo(a.scene, a.cache)
    keys = list(next(iter(rows.values())).keys())[1:]
    print(f"{a.scene}: per surface, medians over the patches the probe and the photo both see")
    print("| surface | patches | " + " | ".join(keys) + " |")
    print("| --- | --- | " + " | ".join("---" for _ in keys) + " |")
    for name, r in rows.items():
        print(f"| {name} | {r['patches']} | " + " | ".join(f"{r[k]:.3f}" for k in keys) + " |")


if __name__ == "__main__":
    main()
