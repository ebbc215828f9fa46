"""Which piece of sun_109's refined camera costs the object its error (issue 34 item 6; branch cam110).

The own-room flow's `scene` and `composite` (captured light) run with a given camera and `scene --no-refine-camera`,
for: the camera cam108's ranking gave (`refine_camera(..., recheck_samples="all")`: main's), this branch's, and the
truth's camera with one piece of main's camera swapped in at a time (its centre; its focal length; its rotation).
Per run: score.py's figures and the sun `composite` estimated (angle to the truth's sun, deg; irradiance over the
truth's).

    python bench/bench_cam110_swap.py [--rooms DIR] [--only sun_109] --work DIR [--json OUT]
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import shutil
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def camera_json(cam) -> dict:
    """calibrate's camera.json format (K block, R, t, centre) of a recon.camera.Camera."""
    K = {"fx": float(cam.K[0, 0]), "fy": float(cam.K[1, 1]), "cx": float(cam.K[0, 2]), "cy": float(cam.K[1, 2]),
         "width": int(cam.width), "height": int(cam.height)}
    return {"K": K, **K, "R": np.asarray(cam.R).tolist(), "t": np.asarray(cam.t).tolist(),
            "centre": np.asarray(cam.centre).tolist()}


def swapped(truth, wrong, piece: str):
    """The truth's camera with `piece` ("centre", "focal" or "rotation") of `wrong`."""
    K, R, C = truth.K.copy(), truth.R.copy(), truth.centre.copy()
    if piece == "centre":
        C = wrong.centre.copy()
    elif piece == "focal":
        K[0, 0], K[1, 1] = wrong.K[0, 0], wrong.K[1, 1]
    elif piece == "rotation":
        R = wrong.R.copy()
    return dataclasses.replace(truth, K=K, R=R, t=-R @ C)


def run(root: Path, work: Path, shared: Path) -> list[dict]:
    from bench import own_room_flow as fl
    from bench.bench_camrefine import calibrated_room
    from recon import camrefine as cr

    room = calibrated_room(root)
    wrong = cr.refine_camera(room.cam, room.prims, room.img, room.cal.to_json(), recheck_samples="all").camera
    new = cr.refine_camera(room.cam, room.prims, room.img, room.cal.to_json()).camera
    cams = {"main's refined": wrong, "cam110's refined": new,
            **{f"truth, main's {p}": swapped(room.truth, wrong, p) for p in ("centre", "focal", "rotation")}}
    inp = fl.write_inputs(root, work / "in")
    fl.declared_openings(inp["room"], inp["scene"])
    sun = next(p for p in inp["scene"]["primitives"] if p["type"] == "sun")
    s_true = np.asarray(sun["direction_to_sun"], float)
    out = []
    for i, (tag, cam) in enumerate(cams.items()):
        cj = work / f"camera_{i}.json"
        cj.write_text(json.dumps(camera_json(cam)))
        rdir, odir = work / f"room_{i}", work / f"out_{i}"
        rc, err, _ = fl._photoar(fl.scene_argv(inp, rdir, cj) + ["--no-refine-camera"])
        row = {"camera": tag, **room.errors(cam)}
        if rc == 0:
            rc, err, _ = fl._photoar(fl._composite_argv(rdir, odir, inp, "captured", work / f"cache_{i}"))
        if rc != 0:
            row["error"] = err
        else:
            row.update(fl.score(root, odir / "composite.png", shared))
            rep = json.loads((odir / "report.json").read_text()).get("sun") or {}
            if "direction" in rep:
                d = np.asarray(rep["direction"], float)
                row["sun_angle_deg"] = float(np.degrees(np.arccos(np.clip(d @ s_true / np.linalg.norm(d), -1, 1))))
                row["sun_irradiance_ratio"] = float(np.mean(rep["irradiance_perpendicular"]) /
                                                    np.mean(sun["irradiance_perpendicular"]))
        shutil.rmtree(work / f"cache_{i}", ignore_errors=True)
        out.append(row)
        g = {k: row.get(k, float("nan")) for k in ("energy_ratio", "rmse_affected", "rmse_object", "sun_angle_deg",
                                                    "sun_irradiance_ratio")}
        print(f"{tag:24s} focal {row['focal_pct']:+.2f} % centre {row['centre_cm']:.1f} cm rot {row['rot_deg']:.2f} "
              f"obj {row['object_px']:.2f} px | " + (row.get("error") or
              f"energy {g['energy_ratio']:.3f} rmse_aff {g['rmse_affected']:.2f} rmse_obj {g['rmse_object']:.2f} "
              f"sun {g['sun_angle_deg']:.2f} deg x{g['sun_irradiance_ratio']:.2f}"), flush=True)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rooms", type=Path, default=Path.home() / ".cache/photoar/rooms_full")
    ap.add_argument("--only", default="sun_109")
    ap.add_argument("--work", type=Path, required=True)
    ap.add_argument("--shared", type=Path, default=Path(__import__("os").environ.get("PHOTOAR_SHARED",
                                                                                     ROOT.parent / "shared")))
    ap.add_argument("--json", type=Path)
    a = ap.parse_args(argv)
    res = {}
    for name in a.only.split(","):
        res[name] = run(a.rooms / name, a.work / name, a.shared)
        if a.json:
            a.json.write_text(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
