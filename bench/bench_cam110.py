"""Where sun_109's refined camera stops, and why (issue 34 item 6; branch cam110).

Per room: calibrate's camera as the own-room flow makes it (bench_camrefine.calibrated_room), refined as `scene`
refines it (no sun stage); errors against the truth's camera (focal %, centre cm and its x/y/z parts, rotation deg,
object px); calibrate's focal sigma and whether cam108's focal recheck was due; the completed objective
(camrefine._fit_cost) on common samples of: calibrate's camera, the accepted camera, the truth, and the fit started
from the truth's camera; each room edge's signed sub-pixel offset at the truth and at the accepted camera.

    python bench/bench_cam110.py [--rooms DIR] --only ROOMS [--json OUT]
    python bench/bench_cam110.py --compare [--rooms DIR] --only ROOMS [--json OUT]
        one line per room: calibrate's camera and the camera `scene` would use with recheck_samples="all" (the
        rule before, cam108: the focal recheck ranks its fits on every common sample) and "measurable" (the
        default: on the samples neither camera projects by a clipped pixel), focal % / centre cm / object px
        against the truth. Where cam108's focal recheck is not due the two runs take the same code path, so only
        "measurable" is run there (the camera is the rule before's by construction)
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


def _errs(room, cam) -> dict:
    e = room.errors(cam)
    d = cam.centre - room.truth.centre
    e["dc_cm"] = [round(100 * float(v), 2) for v in d]
    return e


def diagnose(root: Path) -> dict:
    from bench.bench_cam108 import edge_offsets
    from bench.bench_camrefine import calibrated_room
    from bench.bench_guard106 import edge_labels
    from recon import camrefine as cr

    room = calibrated_room(root)
    cam = room.cam
    t0 = time.process_time()
    r = cr.refine_camera(cam, room.prims, room.img, room.cal.to_json())
    cpu = time.process_time() - t0
    lines = cr.clicked_lines(room.cal.to_json())
    photo = cr.PhotoEdges(room.img)
    model = cr._Model(room.truth)
    ft = cr._fit(model, np.zeros(model.n), (4.0, 2.0), room.edges, room.occ, photo, lines)
    from_truth = model.camera(ft.x)
    cams = {"calibrated": cam, "accepted": r.camera, "truth": room.truth, "fit_from_truth": from_truth}
    common = cr._union(*[cr._sample_edges(c, room.edges, room.occ) for c in cams.values()])
    labels = edge_labels(room.prims, room.edges)
    out = {"room": root.name, "sigma_f_pct": 100 * float(cam.focal_rel_sigma or np.nan),
           "recheck_due": cr._focal_recheck_due(cam, r.camera, "moved"), "summary": r.summary(),
           "accepted": r.accepted, "reason": r.reason, "cpu_s": cpu}
    for k, c in cams.items():
        out[k] = {**_errs(room, c), "fit_cost": cr._fit_cost(c, common, photo, lines),
                  "lines_chi2": cr._lines_chi2(c, lines)[0]}
    out["edges_truth"] = edge_offsets(room.truth, room.S_truth, photo, labels)
    S_acc = cr._sample_edges(r.camera, room.edges, room.occ)
    out["edges_accepted"] = edge_offsets(r.camera, S_acc, photo, labels)
    return out


def compare_room(root: Path) -> dict:
    from bench.bench_camrefine import calibrated_room
    from recon import camrefine as cr

    room = calibrated_room(root)
    cam = room.cam
    out = {"room": root.name, "sigma_f_pct": 100 * float(cam.focal_rel_sigma or np.nan),
           "calibrated": room.errors(cam)}
    for mode in ("measurable", "all"):
        t0 = time.process_time()
        r = cr.refine_camera(cam, room.prims, room.img, room.cal.to_json(), recheck_samples=mode)
        out[mode] = {**room.errors(r.camera), "accepted": r.accepted, "start": r.start, "reason": r.reason,
                     "cpu_s": time.process_time() - t0, "summary": r.summary(),
                     "due": bool(r.accepted and cr._focal_recheck_due(cam, r.camera, "moved")),
                     "K": r.camera.K.tolist(), "R": r.camera.R.tolist(), "t": r.camera.t.tolist()}
        if mode == "measurable" and not out[mode]["due"] and "focal search" not in r.start:
            break
    if "all" in out:
        a, b = out["all"], out["measurable"]
        b["same_as_all"] = bool(a["K"] == b["K"] and a["R"] == b["R"] and a["t"] == b["t"])
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rooms", type=Path, default=Path.home() / ".cache/photoar/rooms_full")
    ap.add_argument("--only", default="sun_109")
    ap.add_argument("--json", type=Path)
    ap.add_argument("--compare", action="store_true")
    a = ap.parse_args(argv)
    res = []
    if a.compare:
        for name in a.only.split(","):
            o = compare_room(a.rooms / name)
            res.append(o)
            c, m = o["calibrated"], o["measurable"]
            f = lambda e: f"{e['focal_pct']:+.2f}% {e['centre_cm']:.1f}cm {e['object_px']:.2f}px"
            old = o.get("all")
            print(f"{name:11s} sf {o['sigma_f_pct']:.2f}% cal {f(c)} | " +
                  (f"all {f(old)} | measurable {f(m)} " + ("=" if m["same_as_all"] else "CHANGED") if old else
                   f"not due: {f(m)}") + f" ({m['start']}; {m['cpu_s']:.0f}s)", flush=True)
            if a.json:
                a.json.write_text(json.dumps(res, indent=1))
        return 0
    for name in a.only.split(","):
        o = diagnose(a.rooms / name)
        res.append(o)
        print(f"{name}: sigma_f {o['sigma_f_pct']:.2f} % recheck due {o['recheck_due']} ({o['cpu_s']:.1f} s cpu)\n  "
              f"{o['summary']}")
        for k in ("calibrated", "accepted", "truth", "fit_from_truth"):
            e = o[k]
            print(f"  {k:15s} focal {e['focal_pct']:+.2f} % centre {e['centre_cm']:.1f} cm {e['dc_cm']} rot "
                  f"{e['rot_deg']:.2f} deg obj {e['object_px']:.2f} px | cost {e['fit_cost']:.1f} lines "
                  f"{e['lines_chi2']:.1f}")
        for k in ("edges_truth", "edges_accepted"):
            print("  " + k + ": " + "; ".join(f"{d['edge']} {d['group']} {d['found']}/{d['samples']} "
                                             f"{d['offset_px']:+.2f}" for d in o[k]))
        if a.json:
            a.json.write_text(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
