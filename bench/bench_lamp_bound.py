"""Why a lamp goes dark under photo light (issue 34 item 4; docs/unseen.md "lamp110b").

`python bench/bench_lamp_bound.py DIR [--room R,...]` on bench_lamp_pool.py's dumps (DIR/ROOM.pkl): the walls' fit
again; per emitter its fitted radiance over the truth's (luminance), whether it sits at its lower bound and where the
bound comes from, the walls' cosine with each other emitter (columns of the weighted transfer, green channel), and
the walls' residual when that emitter is held at the truth (the others refitted) over the product's: near 1 means
the walls cannot tell the truth from the fit; and what the others become then. With `--rooms ROOMS` (the rooms'
folder), the photo's radiance scale: the response's radiance of the photo's unclipped seen pixels over the room's
background.exr (median per channel): a lamp's fit / truth is only a fit error once divided by its luminance.
Loaded machine: no timings.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from scipy.optimize import lsq_linear

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main() -> None:
    from bench.bench_lamp_pool import load_dumps
    from lighting import photolight
    from lighting.sources import luminance

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dir", type=Path)
    ap.add_argument("--room")
    ap.add_argument("--rooms", type=Path, help="the rooms' folder (ROOM/background.exr): the photo's radiance scale")
    a = ap.parse_args()
    seen: dict = {}
    orig = photolight.fit_albedo_scale

    def hook(*args, **kw):
        res = orig(*args, **kw)
        seen.update(w=args[7], L_S=args[8], fit_on=args[6], a0=res.a0, A1=res.A1, rho=res.wall)
        return res

    photolight.fit_albedo_scale = hook
    for room, d in load_dumps(a.dir, a.room):
        args, kw = d["calls"][-1]
        seen.clear()
        rep = photolight.fit_photo_light(*args, **kw).report
        ems = rep["emitters"]
        e = np.array([x["radiance"] for x in ems])
        w = np.where(seen["fit_on"], seen["w"], 0.0)
        c = 1
        rho = float(np.asarray(seen["rho"]).reshape(-1)[c]) if np.size(seen["rho"]) > 1 else float(seen["rho"])
        A1 = seen["A1"][:, :, c] if seen["A1"].ndim == 3 else seen["A1"]
        J = rho * w[:, None] * A1
        b = w * (seen["L_S"][:, c] - rho * seen["a0"][:, c])
        nrm = np.linalg.norm(J, axis=0)
        cos = (J.T @ J) / np.maximum(np.outer(nrm, nrm), 1e-300)
        lower = np.array([x["lower_bound"] for x in ems])[:, c]
        r0 = np.linalg.norm(J @ e[:, c] - b)
        scale = ""
        if a.rooms is not None and (a.rooms / room / "background.exr").exists():
            from lighting.hdr import load_radiance
            px = np.asarray(args[3]).reshape(-1, 3)
            ex = load_radiance(a.rooms / room / "background.exr").reshape(-1, 3)
            ok = (np.asarray(args[2]) >= 0) & (px.max(axis=1) < 250) & (px.min(axis=1) > 10)
            ratio_px = args[4].to_radiance(px[ok]) / np.maximum(ex[ok], 1e-12)
            scale = f" photo radiance / exr {np.round(np.median(ratio_px, axis=0), 3).tolist()}"
        print(f"{room}:{scale} walls {rep['wall_albedo']} resid {rep['fit_rms_relative_residual']} "
              f"surface_albedos_for {rep['surface_albedos_for']}")
        for g, em in enumerate(ems):
            t = d["truth"].get(em["name"].replace(" (clipped region)", ""))
            ratio, rt, refit = float("nan"), float("nan"), ""
            if t is not None:
                ratio = float(luminance(e[g])) / float(luminance(np.asarray(t)))
                others = [h for h in range(len(ems)) if h != g]
                sol = lsq_linear(J[:, others], b - J[:, g] * t[c], bounds=(lower[others], np.inf), method="bvls")
                rt = np.linalg.norm(J[:, others] @ sol.x + J[:, g] * t[c] - b) / max(r0, 1e-300)
                refit = " ".join(f"{ems[h]['name'][:12]}={sol.x[j] / d['truth'][ems[h]['name']][c]:.2f}"
                                 for j, h in enumerate(others) if ems[h]["name"] in d["truth"])
            cs = " ".join(f"{ems[h]['name'][:12]}={cos[g, h]:.3f}" for h in range(len(ems)) if h != g)
            print(f"  {em['name'][:28]:28s} fit/truth {ratio:6.3f} at_bound {em['at_lower_bound']!s:5s} "
                  f"lower {em['lower_bound_from']:22s} ({lower[g]:.4g}) resid@truth/resid {rt:6.3f} "
                  f"reach {nrm[g] * (t[c] if t is not None else e[g, c]) / max(np.linalg.norm(b), 1e-300):.3f} cos {cs} | others@truth: {refit}")


if __name__ == "__main__":
    main()
