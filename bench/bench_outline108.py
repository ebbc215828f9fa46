"""The truth's camera refined with the truth's sun typed in (issue 34 item 6; branch outline108).

usage: python bench/bench_outline108.py --rooms ~/.cache/photoar/rooms_full --only sun_101,...,sun_107

Per room: the own-room flow's inputs (bench/own_room_flow.tape_room with the truth's windows marked as openings,
the truth's sun as `scene --sun-direction/--sun-irradiance` declares it, the probe bracket's response) and the
truth's camera, refined by recon.camrefine.refine_camera with the sun; printed: accepted, the guard's move of the
room's edges (moved_px), the refined camera's focal error (%), centre error (cm) and rms image error over the
object's vertices (px), and each measured outline edge's offset at the refined camera (resid_px). A correct camera
should come back unchanged (accepted False, "already fits") or move by a fraction of a px at the object.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def room(root: Path) -> dict:
    """The truth's camera of room folder `root` refined with its sun typed in: figures (see the module doc)."""
    from bench.bench_camrefine import object_points
    from bench.bench_camsun import errors
    from bench.own_room_flow import benchmark_camera_json, sunlit_room
    from recon.camera import Camera
    from recon.camrefine import refine_camera
    from recon.io import read_image_rgb

    sc, prims, _, _, sun, g = sunlit_room(root)
    truth = Camera.load(root / "scene.json")
    img = read_image_rgb(root / "background.png")
    r = refine_camera(truth, prims, img, benchmark_camera_json(sc), sun=sun, response=g)
    return {**errors(r.camera, truth, object_points(root)), "accepted": r.accepted, "moved_px": r.moved_px,
            "start": r.start, "reason": r.reason, "sun_edges": r.sun_edges}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rooms", required=True)
    ap.add_argument("--only", required=True, help="comma-separated sun_N rooms")
    ap.add_argument("--json", help="write the figures here")
    a = ap.parse_args(argv)
    out = {}
    for name in a.only.split(","):
        out[name] = e = room(Path(a.rooms).expanduser() / name)
        res = [round(s["resid_px"], 2) for s in e["sun_edges"] or [] if "resid_px" in s]
        print(f"{name}: accepted {e['accepted']} moved {e['moved_px']:.2f} px; focal {100 * e['focal_rel']:+.2f} %, "
              f"centre {100 * e['centre_m']:.1f} cm, object {e['object_px']:.2f} px ({e['start']}); outline "
              f"residuals {res}", flush=True)
    if a.json:
        Path(a.json).write_text(json.dumps(out, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
