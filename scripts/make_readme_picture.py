"""Regenerate docs/demo.png: the bundled demo photo beside `photoar demo`'s composite.

usage: python scripts/make_readme_picture.py  (writes docs/demo.png; out/readme holds the run)
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app import composite  # noqa: E402
from app.cli import demo_scene_dir  # noqa: E402
from recon.io import read_image_rgb, write_png  # noqa: E402


def main() -> None:
    out = ROOT / "out" / "readme"
    report = composite.main(demo_scene_dir(), out, cache_dir=ROOT / "out" / ".cache", quiet=True)
    photo = read_image_rgb(demo_scene_dir() / "background.png")
    comp = read_image_rgb(out / "composite.png")
    gap = np.full((photo.shape[0], 8, 3), 255, np.uint8)
    write_png(ROOT / "docs" / "demo.png", np.concatenate([photo, gap, comp], axis=1))
    print(f"docs/demo.png (frame {report['frame_s']:.2f} s, {report['n_sources']} sources)")


if __name__ == "__main__":
    main()
