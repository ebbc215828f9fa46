"""Regenerate docs/three_lightings.png: one scene composited under the three lightings side by side.

usage: python scripts/make_three_lightings.py [--scene ../shared/scenes/window_room]
Panels, left to right: known light (declared emitters and albedos), captured light (probe bracket
and photo), photo light (the photo alone; the scene stripped of response, albedos, emitter
radiance and probe), each cropped around the object and its shadows, 288 x 216, with its label. Writes docs/three_lightings.png (< 300 KB);
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
from recon.io import write_png  # noqa: E402
from bench.bench_photolight import strip_scene  # noqa: E402
from recon.scene import load_scene, read_image_rgb  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--scene", type=Path, default=ROOT.parent / "shared" / "scenes" / "window_room")
    a = ap.parse_args()
    out, cache = ROOT / "out" / "three_lightings", ROOT / "out" / ".cache"
    panels, box = [], None
    photo = read_image_rgb(a.scene / "background.png").astype(int)
    for lighting in ("known", "captured", "photo"):
        scene = strip_scene(a.scene, out / "stripped") if lighting == "photo" else a.scene
        composite.main(scene, out / lighting, EngineParams(lighting=lighting), cache_dir=cache, quiet=True)
        img = read_image_rgb(out / lighting / "composite.png")
        if box is None:  # around the object: 2.2 x its projected height, 4:3
            sc = load_scene(a.scene)
            uv, _ = sc.camera.project(sc.obj.vertices)
            H, W = photo.shape[:2]
            h = min(int(2.2 * np.ptp(uv[:, 1])), H)
            w = min(h * 4 // 3, W)
            cx, cy = uv.mean(0)
            y0, x0 = int(np.clip(cy - h / 2, 0, H - h)), int(np.clip(cx - w / 2, 0, W - w))
            box = (y0, x0, h, w)
        y0, x0, h, w = box
        img = cv2.resize(img[y0:y0 + h, x0:x0 + w], (288, 216), interpolation=cv2.INTER_AREA)
        cv2.putText(img, f"{lighting} light", (8, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 0), 3, cv2.LINE_AA)
        cv2.putText(img, f"{lighting} light", (8, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 255), 1,
                    cv2.LINE_AA)
        panels.append(img)
        panels.append(np.full((img.shape[0], 6, 3), 255, np.uint8))
    write_png(ROOT / "docs" / "three_lightings.png", np.concatenate(panels[:-1], axis=1))
    print("docs/three_lightings.png")


if __name__ == "__main__":
    main()
