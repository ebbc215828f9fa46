"""Why a room's edges accept a camera ~1 % off in focal length (issue 34 item 6; branch cam108).

Per room: the own-room flow's camera (bench/own_room_flow.calibrated_from_lines, turned as `scene` turns it),
refined by recon.camrefine.refine_camera as `scene` calls it (no sun stage); errors against the truth's camera
(bench/bench_camrefine.camera_errors). With --profile: the refinement's own cost (the profile stage's robust
edge cost and the clicked lines' chi-square) along the focal length, every other parameter re-fitted
(coarse radii 4, 2 px, then the profile stage), from the truth's camera; and each room edge's mean signed
sub-pixel offset at the truth's camera (a biased edge class shows there).

    python bench/bench_cam108.py [--rooms DIR] --only window_107[,...] [--profile] [--json OUT]
    python bench/bench_cam108.py --compare [--always] [--rooms DIR] --only ROOMS [--json OUT]
        one line per room: calibrate's camera, the camera scene would use before (focal_search="off") and
        after (the default, "moved"; with --always also "always"), focal % / centre cm / object px against the
        truth's camera, whether the focal recheck ran, and the cameras bitwise equal or not
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


class FixedFocal:
    """A recon.camrefine._Model with the focal length held at exp(lf) x the base camera's (5 parameters)."""

    def __init__(self, base, lf: float):
        self.base, self.lf, self.n, self.cam0, self.C0 = base, lf, 5, base.cam0, base.C0
        self.free_pp, self.pp_prior = False, False

    def camera(self, x):
        return self.base.camera(np.r_[np.asarray(x, float)[:5], self.lf])


def split_cost(fit) -> tuple[float, float, int]:
    """(robust edge cost f^2 sum log1p((r/f)^2) over the found samples (the capped edge weights are inside r),
    the clicked lines' chi-square, found samples) of a fit's last solve."""
    from recon.camrefine import ROBUST_SIGMAS
    res = fit.res
    ne = int(fit.used.sum())
    r = np.asarray(res.fun, float)
    z = (r[:ne] / ROBUST_SIGMAS) ** 2
    return float(ROBUST_SIGMAS ** 2 * np.sum(np.log1p(z))), float(r[ne:] @ r[ne:]), ne


def edge_offsets(cam, S, photo, labels):
    from recon.camrefine import _fine_edges, _project
    uv, n = _project(cam, S)
    q, ok, _ = _fine_edges(photo, uv, n, S.edge)
    off = np.sum(n * (q - uv), axis=1)
    out = []
    for e in np.unique(S.edge):
        m = (S.edge == e) & ok
        out.append({"edge": int(e), "group": labels[e], "samples": int((S.edge == e).sum()), "found": int(m.sum()),
                    "offset_px": float(np.mean(off[m])) if m.any() else float("nan"),
                    "spread_px": float(np.std(off[m])) if m.any() else float("nan")})
    return out


def run_room(root: Path, profile: bool, focals=(-2.0, -1.5, -1.0, -0.5, 0.0, 0.5, 1.0)) -> dict:
    from bench.bench_camrefine import camera_errors, object_points
    from bench.bench_guard106 import edge_labels
    from bench.own_room_flow import calibrated_from_lines
    from recon import assemble as asm
    from recon import camrefine as cr

    truth, img, cal, prims, lo, hi = calibrated_from_lines(root)
    cam = dataclasses.replace(cal.camera, focal_rel_sigma=cal.focal_rel_sigma)
    cam = asm.inside_turn(cam, lo, hi)[0]
    faces = cr.room_faces(prims)
    edges = cr.room_edges(faces)
    occ = cr._Occluder(faces)
    P = object_points(root)
    S_truth = cr._sample_edges(truth, edges, occ)
    cj = cal.to_json()
    r = cr.refine_camera(cam, prims, img, cj)
    out = {"room": root.name, "calibrated": camera_errors(cam, truth, S_truth, P),
           "refined": {**camera_errors(r.camera, truth, S_truth, P), "accepted": r.accepted, "reason": r.reason,
                       "summary": r.summary()}}
    if not profile:
        return out
    labels = edge_labels(prims, edges)
    photo = cr.PhotoEdges(img)
    lines = cr.clicked_lines(cj)
    out["truth_edges"] = edge_offsets(truth, S_truth, photo, labels)
    base = cr._Model(truth)
    prof = []
    for fp in focals:
        m = FixedFocal(base, float(np.log1p(fp / 100)))
        f = cr._fit(m, np.zeros(5), (4.0, 2.0), edges, occ, photo, lines)
        if f.res is None:
            prof.append({"focal_pct": fp, "cost": None})
            continue
        ce, cl, ne = split_cost(f)
        c = m.camera(f.x)
        prof.append({"focal_pct": fp, "edge_cost": ce, "lines_chi2": cl, "n": ne,
                     "edges": len(np.unique(f.S.edge[f.used])),
                     **{k: v for k, v in camera_errors(c, truth, S_truth, P).items() if k != "focal_pct"},
                     "chamfer_edge_mean": float(np.mean([np.mean(d) for d in
                                                         [cr._edge_distances(c, S_truth, photo)[S_truth.edge == e]
                                                          for e in np.unique(S_truth.edge)]]))})
    out["profile"] = prof
    return out


def compare_room(root: Path, always: bool) -> dict:
    from bench.bench_camrefine import calibrated_room
    from recon import camrefine as cr

    room = calibrated_room(root)
    cam = room.cam
    out = {"room": root.name, "sigma_f_pct": 100 * float(cam.focal_rel_sigma or np.nan),
           "calibrated": room.errors(cam)}
    for mode in ("off", "moved") + (("always",) if always else ()):
        t0 = time.process_time()
        r = cr.refine_camera(cam, room.prims, room.img, room.cal.to_json(), focal_search=mode)
        out[mode] = {**room.errors(r.camera), "accepted": r.accepted, "start": r.start,
                     "reason": r.reason, "cpu_s": time.process_time() - t0,
                     "K": r.camera.K.tolist(), "R": r.camera.R.tolist(), "t": r.camera.t.tolist()}
    a = out["off"]
    for mode in ("moved", "always"):
        if mode in out:
            b = out[mode]
            out[mode]["same_as_off"] = bool(a["K"] == b["K"] and a["R"] == b["R"] and a["t"] == b["t"])
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rooms", type=Path, default=Path.home() / ".cache/photoar/rooms_full")
    ap.add_argument("--only", default="window_107")
    ap.add_argument("--profile", action="store_true")
    ap.add_argument("--json", type=Path)
    ap.add_argument("--compare", action="store_true")
    ap.add_argument("--always", action="store_true")
    a = ap.parse_args(argv)
    if a.compare:
        res = []
        for name in a.only.split(","):
            o = compare_room(a.rooms / name, a.always)
            res.append(o)
            c = o["calibrated"]
            line = (f"{name:11s} sf {o['sigma_f_pct']:.2f}% cal {c['focal_pct']:+.2f}% {c['centre_cm']:.1f}cm "
                    f"{c['object_px']:.2f}px")
            for mode in ("off", "moved", "always"):
                if mode in o:
                    b = o[mode]
                    line += (f" | {mode} {'A' if b['accepted'] else 'k'} {b['focal_pct']:+.2f}% {b['centre_cm']:.1f}cm "
                             f"{b['object_px']:.2f}px {b['cpu_s']:.0f}s" + ("" if mode == "off" else
                                                                         (" =" if b["same_as_off"] else " CHANGED")))
            print(line, flush=True)
            if a.json:
                a.json.write_text(json.dumps(res, indent=1))
        return 0
    res = []
    for name in a.only.split(","):
        o = run_room(a.rooms / name, a.profile)
        res.append(o)
        c, r = o["calibrated"], o["refined"]
        print(f"{name}: calibrated focal {c['focal_pct']:+.2f} % centre {c['centre_cm']:.1f} cm "
              f"obj {c['object_px']:.2f} px"
              f" -> refined ({'acc' if r['accepted'] else 'kept: ' + r['reason'][:40]}) focal {r['focal_pct']:+.2f} % "
              f"centre {r['centre_cm']:.1f} cm obj {r['object_px']:.2f} px", flush=True)
        for e in o.get("truth_edges", []):
            print(f"   edge {e['edge']:3d} {e['group']:14s} n {e['samples']:4d} found {e['found']:4d} "
                  f"offset {e['offset_px']:+.2f} spread {e['spread_px']:.2f}")
        for p in o.get("profile", []):
            if p.get("cost", 1) is None:
                print(f"   focal {p['focal_pct']:+.1f}: no fit")
                continue
            print(f"   focal {p['focal_pct']:+.1f} %: edge cost {p['edge_cost']:8.2f} lines {p['lines_chi2']:6.2f} "
                  f"total {p['edge_cost'] + p['lines_chi2']:8.2f} n {p['n']} E {p['edges']} "
                  f"centre {p['centre_cm']:.1f} cm "
                  f"obj {p['object_px']:.2f} chamfer/edge {p['chamfer_edge_mean']:.3f}", flush=True)
    if a.json:
        a.json.write_text(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
