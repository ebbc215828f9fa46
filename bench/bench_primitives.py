"""Interactive drag update of the primitive model (seed sec. 3): median time of one warm-started
image-constraint update (one vertex's target moved a few pixels, then `PrimitiveModel.drag`),
per scene and dragged primitive. Prints a table; `python bench/bench_primitives.py [--n N]`.
Issue 6 asks for < 10 ms median."""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.report import table  # noqa: E402
from recon.camera import Camera  # noqa: E402
from recon.primitives import model_from_dict  # noqa: E402

SHARED = ROOT.parent / "shared"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--n", type=int, default=40, help="drag steps per primitive")
    a = ap.parse_args()
    rows = []
    for name, prims in (("window_room", ["desk_top", "desk_leg0", "shelf", "back"]),
                        ("lamps_room", ["sofa_seat", "cabinet", "window"])):
        path = SHARED / "scenes" / name / "scene.json"
        if not path.is_file():
            print(f"skip {name}: {path} not available")
            continue
        d = json.loads(path.read_text())
        cam = Camera.load(path)
        model = model_from_dict(d)
        for p in model.prims:  # every vertex in front of the camera pinned where it projects
            uv, z = cam.project(p.vertices())
            for k in np.flatnonzero(z > 0.1):
                model.set_constraint(p.name, int(k), uv[k])
        for pname in prims:
            p = model[pname]
            cons = [c for c in model.constraints if c.primitive == pname]
            k, start = cons[-1].vertex, cons[-1].px.copy()
            for up in (False, True):
                times, nfev, rms = [], [], []
                for i in range(a.n):  # the mouse moves along a small circle, 1 px per step
                    target = start + 6 * np.array([np.cos(i / 6), np.sin(i / 6)]) - [6, 0]
                    t0 = time.perf_counter()
                    info = model.drag(cam, pname, k, target, up=up)
                    times.append(time.perf_counter() - t0)
                    nfev.append(info["nfev"])
                    rms.append(info["rms_px"])
                rows.append({"scene": name, "primitive": pname, "solved": "+parent" if up else "self+children",
                             "params": info["n_params"], "median_ms": 1e3 * float(np.median(times)),
                             "p90_ms": 1e3 * float(np.percentile(times, 90)), "median_nfev": float(np.median(nfev)),
                             "rms_px": float(np.median(rms))})
    print(table(rows, ["scene", "primitive", "solved", "params", "median_ms", "p90_ms", "median_nfev", "rms_px"]))
    if rows:
        for solved in ("self+children", "+parent"):
            ms = [r["median_ms"] for r in rows if r["solved"] == solved]
            print(f"median drag update ({solved}): {np.median(ms):.2f} ms")


if __name__ == "__main__":
    main()
