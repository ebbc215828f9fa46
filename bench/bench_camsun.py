"""The camera refinement with and without the sunlit patch's outline (issue 34 item 6, camsun34).

On the work folders `bench_unseen.py --keep DIR` leaves (the declared-sun flow's room_sun: its primitives
with the openings marked, its sun, its probe bracket; calibrate's camera.json), refine_camera is run on
calibrate's camera without the sun (the flow before) and with it (the sun the flow has: room_sun's
scene.json sun, with the response merged from its probe bracket), and each camera is compared with the
room's truth: focal length, centre, and the image error at the object (rms over its vertices, px).

usage: python bench/bench_camsun.py --keep DIR [--rooms ~/.cache/photoar/rooms] [--only sun_101,...]
       [--estimated]   (the captured composite's sun estimate in place of the declared sun)
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def errors(cam, truth, P: np.ndarray) -> dict:
    """Focal (relative), centre (m) and object image (px, rms over P) errors of cam against truth."""
    d = cam.project(P)[0] - truth.project(P)[0]
    return {"focal_rel": float(cam.K[0, 0] / truth.K[0, 0] - 1), "centre_m": float(np.linalg.norm(cam.centre - truth.centre)),
            "object_px": float(np.sqrt(np.mean(np.sum(d ** 2, axis=1)))),
            "object_mean_px": float(np.linalg.norm(d.mean(axis=0)))}


def room(name: str, rooms: Path, keep: Path, estimated: bool = False) -> dict:
    from bench.bench_camrefine import object_points
    from lighting import hdr
    from recon import assemble as asm
    from recon.camera import Camera
    from recon.camrefine import refine_camera
    from recon.io import read_image_rgb

    root, work = rooms / name, keep / name
    truth = Camera.load(root / "scene.json")
    sj = json.loads((work / "room_sun" / "scene.json").read_text())
    prims, lo, hi = asm.parse_primitives({"primitives": [p for p in sj["primitives"] if p.get("type") != "sun"]},
                                         "room_sun")
    sun = next(p for p in sj["primitives"] if p.get("type") == "sun")
    if estimated:  # the captured composite's sun estimate (made on the flow's refined camera) in place of it
        est = json.loads((work / "out_captured" / "report.json").read_text())["sun_estimate"]["direction"]
        sun = {**sun, "direction_to_sun": est}
    cj = json.loads((work / "cal" / "camera.json").read_text())
    cam = Camera.load(work / "cal" / "camera.json")
    cam = asm.inside_turn(cam, lo, hi)[0]
    img = read_image_rgb(work / "room_sun" / "background.png")
    lp = sj["light_probe"]
    shots = [read_image_rgb(work / "room_sun" / f) for f in lp["ldr_files"]]
    _, g = hdr.merge_bracket(shots, lp["exposure_times"])
    P = object_points(root)
    out = {"room": name, "calibrated": errors(cam, truth, P)}
    t0 = time.process_time()
    r0 = refine_camera(cam, prims, img, cj)
    t1 = time.process_time()
    out["refined"] = {**errors(r0.camera, truth, P), "accepted": r0.accepted, "cpu_s": t1 - t0}
    r1 = refine_camera(cam, prims, img, cj, sun=sun, response=g)
    out["with sun"] = {**errors(r1.camera, truth, P), "accepted": r1.accepted, "start": r1.start,
                       "reason": r1.reason, "cpu_s": time.process_time() - t1, "edges": r1.sun_edges}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--keep", required=True)
    ap.add_argument("--rooms", default=os.environ.get("PHOTOAR_ROOMS", str(Path.home() / ".cache/photoar/rooms")))
    ap.add_argument("--only", default="sun_101,sun_102,sun_103")
    ap.add_argument("--json")
    ap.add_argument("--estimated", action="store_true", help="the sun's direction the captured composite estimated "
                    "(out_captured/report.json) in place of the declared one")
    a = ap.parse_args()
    res = []
    for n in a.only.split(","):
        r = room(n, Path(a.rooms), Path(a.keep), a.estimated)
        res.append(r)
        for k in ("calibrated", "refined", "with sun"):
            e = r[k]
            print(f"{n:8s} {k:11s} focal {100 * e['focal_rel']:+.2f} % centre {100 * e['centre_m']:.1f} cm "
                  f"object {e['object_px']:.2f} px (mean {e['object_mean_px']:.2f})"
                  + (f" accepted {e['accepted']} {e.get('start', '')} {e.get('reason', '')}" if "accepted" in e else ""))
        for e in r["with sun"]["edges"] or []:
            print("   ", e)
    if a.json:
        Path(a.json).write_text(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
