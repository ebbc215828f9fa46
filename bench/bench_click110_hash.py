"""sha256 over the click models of the three shared rooms: {default, seen_only, stacked} clicks x 10
noise seeds (bench/clicks_truth.py, 1 px) x {clicks only, refined against the photo}; the models'
primitives, refined/ill_determined report and sizes to tape (ClickModel.to_json), json with sorted keys.
A change that must leave every existing clicks file's model alone prints the same hash before and after.

usage: PYTHONPATH=. python bench/bench_click110_hash.py [--draws 10]
"""
from __future__ import annotations

import argparse
import hashlib
import json
import logging
import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("PHOTOAR_SHARED", ROOT.parent / "shared"))
sys.path.insert(0, str(ROOT))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--draws", type=int, default=10)
    a = ap.parse_args()
    from recon.camera import Camera
    from recon.clickmodel import model_from_clicks
    from recon.edgesnap import EdgeImage
    from recon.io import read_image_rgb
    from bench.clicks_truth import true_clicks

    logging.disable(logging.WARNING)
    total = hashlib.sha256()
    for name in ("window_room", "lamps_room", "sun_room"):
        root = SHARED / "scenes" / name
        sc = json.loads((root / "scene.json").read_text())
        cam = Camera.from_json(sc["main_camera"], str(root), "main_camera.")
        edges = EdgeImage(read_image_rgb(root / "background.png"))
        h = hashlib.sha256()
        for mode in ({}, {"seen_only": True}, {"stacked": True}):
            for seed in range(a.draws):
                clicks, done = true_clicks(sc, sigma_px=1.0, seed=seed, **mode)
                ch = None if done["ceiling"] else sc["world"]["room_max"][1]
                for photo in (None, edges):
                    m = model_from_clicks(clicks, cam, name, ch, photo=photo).to_json()
                    h.update(json.dumps(m, sort_keys=True, default=float).encode())
        total.update(h.digest())
        print(f"{name:<12} {h.hexdigest()[:16]}")
    print(f"all          {total.hexdigest()[:16]}")


if __name__ == "__main__":
    main()
