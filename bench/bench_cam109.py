"""The refinement's focal length when the room's edges say less about it than the clicked lines (issue 34 item 6;
branch cam109).

Per room: the own-room flow's camera (bench/own_room_flow.calibrated_from_lines, turned as `scene` turns it,
calibrate's focal sigma), refined as `scene` refines it (no sun stage) with `focal_from_lines="off"` (the rule
before; bitwise the old code) and `"retry"` (the default); errors against the truth's camera
(bench_camrefine.camera_errors: focal %, centre cm, object px = rms image error over the object's vertices); the
first fit's own focal sigma (camera_covariance, clicked lines included) over calibrate's sigma (above 1/sqrt(2):
the edges add less information on the focal length than the lines: the retry runs); cameras compared bitwise.

    python bench/bench_cam109.py [--rooms DIR] --only ROOMS [--json OUT]
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def compare_room(root: Path) -> dict:
    from bench.bench_camrefine import calibrated_room
    from recon import camrefine as cr

    room = calibrated_room(root)
    cam = room.cam
    out = {"room": root.name, "sigma_f_pct": 100 * float(cam.focal_rel_sigma or np.nan),
           "calibrated": room.errors(cam)}
    for mode in ("off", "retry"):
        t0 = time.process_time()
        r = cr.refine_camera(cam, room.prims, room.img, room.cal.to_json(), focal_from_lines=mode)
        cov = r.covariance
        out[mode] = {**room.errors(r.camera), "accepted": r.accepted, "start": r.start,
                     "reason": r.reason, "cpu_s": time.process_time() - t0, "summary": r.summary(),
                     "fit_sigma_f_pct": 100 * float(np.sqrt(cov[5, 5])) if cov is not None else float("nan"),
                     "K": r.camera.K.tolist(), "R": r.camera.R.tolist(), "t": r.camera.t.tolist()}
    a, b = out["off"], out["retry"]
    b["same_as_off"] = bool(a["K"] == b["K"] and a["R"] == b["R"] and a["t"] == b["t"])
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rooms", type=Path, default=Path.home() / ".cache/photoar/rooms_full")
    ap.add_argument("--only", default="window_108")
    ap.add_argument("--json", type=Path)
    a = ap.parse_args(argv)
    res = []
    for name in a.only.split(","):
        o = compare_room(a.rooms / name)
        res.append(o)
        c, f, g = o["calibrated"], o["off"], o["retry"]
        ratio = f["fit_sigma_f_pct"] / o["sigma_f_pct"]
        print(f"{name:11s} sf {o['sigma_f_pct']:.2f}% cal {c['focal_pct']:+.2f}% {c['centre_cm']:.1f}cm "
              f"{c['object_px']:.2f}px | off {'A' if f['accepted'] else 'k'} {f['focal_pct']:+.2f}% "
              f"{f['centre_cm']:.1f}cm {f['object_px']:.2f}px fit sf/sf {ratio:.2f} | retry "
              f"{'A' if g['accepted'] else 'k'} {g['focal_pct']:+.2f}% {g['centre_cm']:.1f}cm {g['object_px']:.2f}px "
              f"{g['cpu_s'] - f['cpu_s']:+.1f}s" + (" =" if g["same_as_off"] else " CHANGED"), flush=True)
        if a.json:
            a.json.write_text(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
