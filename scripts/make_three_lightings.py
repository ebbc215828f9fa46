"""Regenerate docs/three_lightings.png: one scene composited under the three lightings side by side.

usage: python scripts/make_three_lightings.py [--scene ../shared/scenes/window_room]
Panels, left to right: known light (declared emitters and albedos), captured light (probe bracket
and photo), photo light (the photo alone; the scene stripped of response, albedos, emitter
radiance and probe), each at half size with its label. Writes docs/three_lightings.png (< 300 KB);
out/three_lightings holds the runs.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app import composite  # noqa: E402
from app.engine import EngineParams  # noqa: E402
from app.io import write_png  # noqa: E402
from bench.bench_photolight import strip_scene  # noqa: E402
from recon.scene import read_image_rgb  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--scene", type=Path, default=ROOT.parent / "shared" / "scenes" / "window_room")
    a = ap.parse_args()
    out, cache = ROOT / "out" / "three_lightings", ROOT / "out" / ".cache"
    panels = []
    for lighting in ("known", "captured", "photo"):
        scene = strip_scene(a.scene, out / "stripped") if lighting == "photo" else a.scene
        composite.main(scene, out / lighting, EngineParams(lighting=lighting), cache_dir=cache, quiet=True)
        img = read_image_rgb(out / lighting / "composite.png")
        img = cv2.resize(img, (img.shape[1] // 2, img.shape[0] // 2), interpolation=cv2.INTER_AREA)
        cv2.putText(img, f"{lighting} light", (8, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 0), 3, cv2.LINE_AA)
        cv2.putText(img, f"{lighting} light", (8, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 255), 1,
                    cv2.LINE_AA)
        panels.append(img)
        panels.append(np.full((img.shape[0], 6, 3), 255, np.uint8))
    write_png(ROOT / "docs" / "three_lightings.png", np.concatenate(panels[:-1], axis=1))
    print("docs/three_lightings.png")


if __name__ == "__main__":
    main()
