"""Is the refinement's focal move significant? (issue 34 item 6; branch cam109, a rule tried and not kept)

Per room: the own-room flow's camera (bench/own_room_flow.calibrated_from_lines, turned as `scene` turns it),
refined as `scene` refines it (no sun stage). For an accepted camera, the last profile stage is re-run from it and
its data solved twice, focal length free and held at calibrate's (the rest free), with the fit's own capped weights
and with the room model's per-edge error (`weighting="model"`): the chi-square drop of freeing the focal length
(2 x the cost difference), the free fit's own focal sigma (camera_covariance) and both cameras' errors against the
truth (focal %, centre cm, object px; bench_camrefine.camera_errors).

    python bench/bench_cam109_hold.py [--rooms DIR] --only ROOMS [--json OUT]
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


class Held:
    """A recon.camrefine._Model with the focal length (x[5]) held at `lf`: the other parameters free."""

    def __init__(self, base, lf: float):
        self.base, self.lf, self.n = base, lf, base.n - 1
        self.cam0, self.C0, self.free_pp, self.pp_prior = base.cam0, base.C0, base.free_pp, base.pp_prior

    def camera(self, x):
        x = np.asarray(x, float)
        return self.base.camera(np.r_[x[:5], self.lf, x[5:]])


def room(root: Path) -> dict:
    from bench.bench_camrefine import calibrated_room
    from recon import camrefine as cr

    rm = calibrated_room(root)
    cam, edges, occ, cj = rm.cam, rm.edges, rm.occ, rm.cal.to_json()
    r = cr.refine_camera(cam, rm.prims, rm.img, cj, focal_from_lines="off")
    out = {"room": root.name, "sigma_f": cam.focal_rel_sigma, "calibrated": rm.errors(cam),
           "refined": rm.errors(r.camera), "accepted": r.accepted}
    if not r.accepted or r.camera_at is None:
        return out
    model = r.camera_at.__self__
    lines = cr.clicked_lines(cj)
    fit = cr._profile_stage(model, r.x, edges, occ, cr.PhotoEdges(rm.img), lines)
    if fit is None:
        return out
    sub, q, sig, _ = fit.data
    held = Held(model, float(np.log(cam.K[0, 0] / model.cam0.K[0, 0])))
    for w in ("capped", "model"):
        rf = cr._solve(model, fit.x, sub, q, sig, lines, f_scale=cr.ROBUST_SIGMAS, weighting=w)
        rh = cr._solve(held, np.r_[fit.x[:5], fit.x[6:]], sub, q, sig, lines, f_scale=cr.ROBUST_SIGMAS, weighting=w)
        cov = cr.camera_covariance(rf)
        out[w] = {"chi2_drop": float(2 * (rh.cost - rf.cost)),
                  "fit_sigma_f": float(np.sqrt(cov[5, 5])) if cov is not None else float("nan"),
                  "free": rm.errors(model.camera(rf.x)), "held": rm.errors(held.camera(rh.x))}
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rooms", type=Path, default=Path.home() / ".cache/photoar/rooms_full")
    ap.add_argument("--only", default="window_108")
    ap.add_argument("--json", type=Path)
    a = ap.parse_args(argv)
    fmt = lambda e: f"{e['focal_pct']:+.2f}/{e['centre_cm']:.1f}/{e['object_px']:.2f}"  # noqa: E731
    res = []
    for name in a.only.split(","):
        o = room(a.rooms / name)
        res.append(o)
        line = f"{name:11s} sf {100 * o['sigma_f']:.2f}% cal {fmt(o['calibrated'])} ref {fmt(o['refined'])}"
        for w in ("capped", "model"):
            if w in o:
                t = o[w]
                line += (f" | {w}: drop {t['chi2_drop']:.2f} fit sf {100 * t['fit_sigma_f']:.2f}% free {fmt(t['free'])}"
                         f" held {fmt(t['held'])}")
        print(line, flush=True)
        if a.json:
            a.json.write_text(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
