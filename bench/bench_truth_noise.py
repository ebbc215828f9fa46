"""How noisy each shared scene's truth is where the scorer draws its 2-level line (issue 20's spurious).

usage: python bench/bench_truth_noise.py [--shared ../shared] [--scenes window_room lamps_room sun_room]

Per scene, from its files alone (luminance as ../shared/tools/score.py computes it, the object
dilated 7 px left out): the robust std (1.4826 x MAD) of truth - background per pixel (after a
5 px median is taken off) and of the scorer's sigma-2 blur of it less a sigma-8 blur (what the
scorer still sees of the noise), and the share of pixels whose smooth (sigma-8) change lies
within 1.5-2.5 levels, where that noise decides 'rest' against 'affected'.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.report import table  # noqa: E402
from bench import shared_scenes  # noqa: E402
from recon.io import read_image_rgb  # noqa: E402
from recon.response import luminance  # noqa: E402


def robust_std(x: np.ndarray) -> float:
    return float(1.4826 * np.median(np.abs(x - np.median(x))))


def truth_noise(scene_dir: Path) -> dict:
    bg = luminance(read_image_rgb(scene_dir / "background.png").astype(np.float64))
    tr = luminance(read_image_rgb(scene_dir / "truth.png").astype(np.float64))
    obj = cv2.imread(str(scene_dir / "truth_mask.png"), cv2.IMREAD_GRAYSCALE) > 127
    keep = ~(cv2.dilate(obj.astype(np.uint8), np.ones((15, 15), np.uint8)) > 0)
    d = (tr - bg).astype(np.float32)
    smooth = cv2.GaussianBlur(d, (0, 0), 8.0)
    return {"raw_noise": robust_std((d - cv2.medianBlur(d, 5))[keep]),
            "noise_after_blur": robust_std((cv2.GaussianBlur(d, (0, 0), 2.0) - smooth)[keep]),
            "near_threshold": float(((np.abs(smooth) > 1.5) & (np.abs(smooth) < 2.5))[keep].mean())}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shared", type=Path, default=ROOT.parent / "shared")
    ap.add_argument("--scenes", nargs="+", default=["window_room", "lamps_room", "sun_room"])
    a = ap.parse_args()
    rows = [{"scene": name, **truth_noise(d)} for name, d in shared_scenes(a.shared, a.scenes)]
    print(table(rows, ["scene", "raw_noise", "noise_after_blur", "near_threshold"]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
