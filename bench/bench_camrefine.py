"""The camera refinement (recon/camrefine.py) against the truth's camera, room by room.

Per room: calibrate's camera (the room's clicked lines, snapped to the photo, plus the camera height:
recon.vanishing.calibrate_lines, as `photoar calibrate` runs it; turned 180 deg about +Y when only the
turn lies in the taped room, as `scene` does), then `refine_camera` with each variant given, and, with
--true, the refinement started from the truth's camera (no clicked lines: how far the photo's edges
drag a camera that is right). calibrate's camera carries its focal sigma, as `scene` reads it from camera.json
(refine_camera's second search over the focal length runs where the first fails the clicked lines). Errors against the truth's camera: focal (%), principal point (px),
rotation (deg), centre (cm), the image error: rms px between the two cameras' images of the
room's edge samples the truth's camera sees, and the object's image error: the same over the vertices of the
scene's synthetic object where it stands (what rmse_object scores: bench/bench_object_shift.py gives how
rmse_object grows with it). Beside each refined camera's object error, its uncertainty there: the fit's own
1 sigma (its parameter covariance, recon.camrefine.camera_covariance: samples taken as independent) and the
jackknife over the room's edges (recon.camrefine.edge_jackknife: the edges as the independent units), with the
one edge whose removal moves the object most. With --json each refined camera (K, R, t) is written too.

`python bench/bench_camrefine.py [--rooms DIR] [--only window_101,...,sun_room] [--variant profiles]
[--variant lines] [--true] [--locator centroid|step] [--json OUT]`; a variant is refine_camera's keyword arguments as
`key=value,key=value` (e.g. `fine_stage=lines`, `fine_stage=lines,principal_point=free`). Shared rooms (window_room, lamps_room, sun_room) are
read from $PHOTOAR_SHARED/scenes.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

UNSEEN = [f"{k}_{s}" for k in ("window", "lamps", "sun") for s in (101, 102, 103)]
SHARED_ROOMS = ["window_room", "lamps_room", "sun_room"]


def _room_dir(name: str, rooms: Path) -> Path:
    if name in SHARED_ROOMS:
        return Path(os.environ.get("PHOTOAR_SHARED", ROOT.parent / "shared")) / "scenes" / name
    return rooms / name


def object_points(root: Path) -> np.ndarray:
    """(V,3) world points of the scene's synthetic object (its mesh's vertices through object_to_world), m:
    where the composite's object lands, which is what rmse_object scores."""
    from recon.scene import load_mesh

    so = json.loads((root / "scene.json").read_text())["synthetic_object"]
    v, _, _ = load_mesh(root / so["mesh"])
    M = np.asarray(so["object_to_world"], float)
    return v @ M[:3, :3].T + M[:3, 3]


def camera_errors(cam, truth, S, P=None) -> dict:
    """Errors of `cam` against `truth`: focal %, principal point px, rotation deg, centre cm, the
    image error px (rms over the samples S, the truth's visible room-edge samples) and, with P (the
    object's world points), the object's image error px (rms over P)."""
    from recon.camrefine import _project
    from recon.vanishing import rotation_error_deg

    ua, _ = _project(cam, S)
    ub, _ = _project(truth, S)
    obj = float("nan")
    if P is not None and len(P):
        pa, _ = cam.project(P)
        pb, _ = truth.project(P)
        obj = float(np.sqrt(np.mean(np.sum((pa - pb) ** 2, axis=1))))
    return {"object_px": obj, "focal_pct": 100 * (cam.K[0, 0] / truth.K[0, 0] - 1),
            "pp_px": float(np.linalg.norm(cam.K[:2, 2] - truth.K[:2, 2])),
            "rot_deg": rotation_error_deg(cam.R, truth.R),
            "centre_cm": 100 * float(np.linalg.norm(cam.centre - truth.centre)),
            "image_px": float(np.sqrt(np.mean(np.sum((ua - ub) ** 2, axis=1)))) if len(S.X) else float("nan")}


@dataclasses.dataclass
class CalibratedRoom:
    """A benchmark room as the own-room flow hands it to the camera refinement: the truth's camera, calibrate's on
    the clicked lines (its focal sigma kept, turned to stand inside the taped room), the photo, the calibration and
    the primitives, the room's edges and their occluder, with the truth's visible room-edge samples and the object's
    points that camera_errors scores."""
    truth: object
    cam: object
    img: np.ndarray
    cal: object
    prims: list
    edges: list
    occ: object
    S_truth: object
    P: np.ndarray

    def errors(self, camera) -> dict:
        """camera_errors of `camera` against the truth over this room's edge samples and object points."""
        return camera_errors(camera, self.truth, self.S_truth, self.P)


def calibrated_room(root: Path) -> CalibratedRoom:
    """bench.own_room_flow.calibrated_from_lines(root) made ready for refine_camera (CalibratedRoom)."""
    from bench.own_room_flow import calibrated_from_lines
    from recon import assemble as asm
    from recon import camrefine as cr

    truth, img, cal, prims, lo, hi = calibrated_from_lines(root)
    cam = asm.inside_turn(dataclasses.replace(cal.camera, focal_rel_sigma=cal.focal_rel_sigma), lo, hi)[0]
    faces = cr.room_faces(prims)
    edges, occ = cr.room_edges(faces), cr._Occluder(faces)
    return CalibratedRoom(truth, cam, img, cal, prims, edges, occ, cr._sample_edges(truth, edges, occ),
                          object_points(root))


def _variant(text: str) -> dict:
    out = {}
    for kv in filter(None, text.split(",")):
        k, v = kv.split("=", 1)
        out[k] = {"true": True, "false": False}.get(v.lower(), v)
    return out


def run_room(name: str, rooms: Path, variants: list[str], true_start: bool) -> dict:
    from bench.own_room_flow import calibrated_from_lines
    from recon import assemble as asm
    from recon.camrefine import _Occluder, _sample_edges, edge_jackknife, refine_camera, room_edges, room_faces

    truth, img, cal, prims, lo, hi = calibrated_from_lines(_room_dir(name, rooms))
    cam = dataclasses.replace(cal.camera, focal_rel_sigma=cal.focal_rel_sigma)  # as `scene` reads camera.json:
    # the focal length's sigma lets refine_camera search again when its first search fails the clicked lines
    cam = asm.inside_turn(cam, lo, hi)[0]
    faces = room_faces(prims)
    S = _sample_edges(truth, room_edges(faces), _Occluder(faces))
    P = object_points(_room_dir(name, rooms))
    cj = cal.to_json()
    out = {"room": name, "pp_from": cj.get("principal_point_from"), "calibrated": camera_errors(cam, truth, S, P)}
    for v in variants:
        t0 = time.time()
        kw = _variant(v)
        r = refine_camera(cam, prims, img, cj, **kw)
        out[v or "default"] = {**camera_errors(r.camera, truth, S, P), "accepted": r.accepted, "reason": r.reason,
                               "object_std_px": _object_std(r, P), "jackknife": edge_jackknife(r, P),
                               "seconds": time.time() - t0, "refinement": r.to_json(),
                               "camera": {"K": r.camera.K.tolist(), "R": r.camera.R.tolist(), "t": r.camera.t.tolist()}}
        if true_start:
            r = refine_camera(truth, prims, img, None, **kw)
            moved = camera_errors(r.camera, truth, S, P) if r.accepted else None
            out[(v or "default") + " from truth"] = {"moved_px": r.moved_px, "accepted": r.accepted,
                                                     "reason": r.reason, "errors": moved}
    return out


def _object_std(r, P: np.ndarray) -> float:
    """The refined fit's own 1-sigma uncertainty of the object's image (px, rms over its vertices), from the
    fit's parameter covariance (recon.camrefine.camera_covariance); nan without a fit."""
    from recon.camrefine import point_std_px

    if r.covariance is None or r.x is None or r.camera_at is None or not len(P):
        return float("nan")
    return point_std_px(r.camera_at, np.asarray(r.x, float), np.asarray(r.covariance, float), P)


def _fmt(e: dict) -> str:
    return (f"{e['focal_pct']:+.2f} % / {e['pp_px']:.1f} px / {e['rot_deg']:.2f} deg / {e['centre_cm']:.1f} cm / "
            f"{e['image_px']:.2f} px / object {e['object_px']:.2f} px")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rooms", type=Path, default=Path(os.environ.get("PHOTOAR_ROOMS",
                                                                      Path.home() / ".cache/photoar/rooms")))
    ap.add_argument("--only", default=",".join(UNSEEN + SHARED_ROOMS))
    ap.add_argument("--variant", action="append", default=None,
                    help="refine_camera keyword arguments key=value,... (repeatable; default: the default)")
    ap.add_argument("--true", action="store_true", help="also refine from the truth's camera (no clicked lines)")
    ap.add_argument("--json", type=Path, help="write the results here")
    ap.add_argument("--locator", choices=("centroid", "step", "kink"), help="recon.edgesnap.LOCATOR for this run (the "
                    "sub-pixel rule of calibrate's snap and of the profile stage)")
    ap.add_argument("--profile-locator", choices=("centroid", "step", "kink"),
                    help="recon.photoedges.PROFILE_LOCATOR: the profile stage's rule only "
                    "(calibrate keeps --locator's)")
    a = ap.parse_args()
    if a.profile_locator:
        from recon import photoedges

        photoedges.PROFILE_LOCATOR = a.profile_locator
    if a.locator:
        from recon import edgesnap

        edgesnap.LOCATOR = a.locator
    variants = a.variant or [""]
    results = []
    for name in a.only.split(","):
        r = run_room(name, a.rooms, variants, a.true)
        results.append(r)
        print(f"{name} (principal point from: {r['pp_from']}): calibrated {_fmt(r['calibrated'])}", flush=True)
        for v in variants:
            e = r[v or "default"]
            jk = e["jackknife"]
            print(f"  {v or 'default'}: {_fmt(e)} (fit's own 1 sigma {e['object_std_px']:.2f} px"
                  + (f"; edge jackknife 1 sigma {jk[0]:.2f} px, edge {jk[2]} alone moves it {jk[1]:.2f} px"
                     if np.isfinite(jk[0]) else "") + ")"
                  f"{'' if e['accepted'] else ' (kept: ' + e['reason'] + ')'}"
                  f" [{e['seconds']:.1f} s]", flush=True)
            if a.true:
                t = r[(v or "default") + " from truth"]
                print(f"    from truth: moves {t['moved_px']:.2f} px, "
                      f"{'taken: ' + _fmt(t['errors']) if t['accepted'] else 'kept (' + t['reason'] + ')'}",
                      flush=True)
        if a.json:
            a.json.write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
