"""Which clicked line family makes calibrate's focal length off (issue 34 item 6; branch cam109).

Per room: calibrate on the scene's noisy clicks (what a user clicks) with the camera height and the photo (as
bench/own_room_flow.calibrated_from_lines), then with one family's clicks (or the origin) replaced by their
noiseless positions (scene.json `px_true`); focal error %, calibrate's sigma, centre error cm; and each family's
click offsets and segment lengths (px).

    python bench/bench_cam109_clicks.py [--rooms DIR] --only ROOMS
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main(argv=None) -> int:
    from recon.camera import Camera
    from recon.io import read_image_rgb
    from recon.vanishing import calibrate_lines, lines_from_scene, parse_lines

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rooms", type=Path, default=Path.home() / ".cache/photoar/rooms_full")
    ap.add_argument("--only", default="window_108")
    a = ap.parse_args(argv)
    for name in a.only.split(","):
        root = a.rooms / name
        sc = json.loads((root / "scene.json").read_text())
        truth = Camera.load(root / "scene.json")
        img = read_image_rgb(root / "background.png")
        noisy, true = parse_lines(lines_from_scene(sc, True)), parse_lines(lines_from_scene(sc, False))

        def run(L, tag):
            cal = calibrate_lines(L, truth.width, truth.height, camera_height=truth.centre[1], image=img)
            c = cal.camera
            print(f"{name} {tag:12s} focal {100 * (c.K[0, 0] / truth.K[0, 0] - 1):+.2f} % sigma "
                  f"{100 * cal.focal_rel_sigma:.2f} % centre {100 * np.linalg.norm(c.centre - truth.centre):.1f} cm",
                  flush=True)

        run(noisy, "noisy")
        for f in noisy["families"]:
            run({**noisy, "families": {**noisy["families"], f: true["families"][f]}}, f"true {f}")
        run({**noisy, "origin": true["origin"]}, "true origin")
        for f in noisy["families"]:
            t = np.asarray(true["families"][f], float)
            d = np.asarray(noisy["families"][f], float) - t
            print(f"   {f}: click offsets px {np.round(d, 2).tolist()} lengths px "
                  f"{np.round(np.linalg.norm(t[:, 2:] - t[:, :2], axis=1)).tolist()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
