"""Single-photo calibration from vanishing points (recon/vanishing.py), clicks as given against
clicks snapped to the photo's edges (recon/edgesnap.py): error against the scenes' true cameras and
time per calibration, and in how many draws the principal point was held at the image centre (where
the scenes' true one is). Rows: the scene's own annotation draw, then RMS / worst over N fresh draws of
the click noise (N(0, 0.5^2) px per coordinate, as the annotations).
`python bench/bench_calibration.py [--draws N]`."""
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
from recon.vanishing import calibrate_lines, lines_from_scene, parse_lines, rotation_error_deg  # noqa: E402

SHARED = ROOT.parent / "shared"


def _errors(calib, cam: Camera, room: float) -> tuple[float, float, float]:
    return (abs(calib.camera.K[0, 0] / cam.K[0, 0] - 1), rotation_error_deg(calib.camera.R, cam.R),
            float(np.linalg.norm(calib.camera.centre - cam.centre) / room))


def main() -> None:
    import cv2

    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--draws", type=int, default=40, help="noise draws per scene")
    a = ap.parse_args()
    rows = []
    for name in ("window_room", "lamps_room"):
        path = SHARED / "scenes" / name / "scene.json"
        if not path.is_file():
            print(f"skip {name}: {path} not available")
            continue
        d = json.loads(path.read_text())
        cam = Camera.load(path)
        room = float(np.linalg.norm(np.subtract(d["world"]["room_max"], d["world"]["room_min"])))
        photo = cv2.imread(str(path.parent / "background.png"))[:, :, ::-1].copy()
        true = lines_from_scene(d, noisy=False)
        rng = np.random.default_rng(1)
        draws = [parse_lines(lines_from_scene(d, noisy=True))]
        for _ in range(a.draws):
            L = {k: (np.asarray(true[k]) + rng.normal(0, 0.5, np.shape(true[k]))).tolist() for k in "xyz"}
            L["origin"] = (np.asarray(true["origin"]) + rng.normal(0, 0.5, 2)).tolist()
            draws.append(parse_lines(L))
        for mode, img in (("clicks", None), ("snapped", photo)):
            errs, times, snapped, held = [], [], [], 0
            for L in draws:
                t0 = time.perf_counter()
                calib = calibrate_lines(L, cam.width, cam.height, camera_height=cam.centre[1], image=img)
                times.append(time.perf_counter() - t0)
                errs.append(_errors(calib, cam, room))
                snapped.append(sum(int(v.snapped.sum()) for v in calib.vps.values()))
                held += calib.principal_point_from == "image centre"
            e = np.array(errs)
            rms, worst = np.sqrt(np.mean(e[1:] ** 2, axis=0)), e[1:].max(axis=0)
            n_segs = sum(len(v) for v in L["families"].values())
            rows.append({"scene": name, "segments": mode, "focal": f"{e[0, 0]:.2%}", "rotation deg": f"{e[0, 1]:.3f}",
                         "centre/room": f"{e[0, 2]:.2%}", "focal RMS/worst": f"{rms[0]:.2%} / {worst[0]:.2%}",
                         "rotation RMS/worst": f"{rms[1]:.3f} / {worst[1]:.3f}",
                         "centre RMS/worst": f"{rms[2]:.2%} / {worst[2]:.2%}",
                         "snapped": f"{np.mean(snapped):.1f} of {n_segs}", "c held": f"{held}/{len(draws)}",
                         "ms": f"{1e3 * np.median(times):.0f}"})
    print(f"first three error columns: the scene's annotation draw; RMS/worst: over {a.draws} fresh draws")
    print(table(rows, ["scene", "segments", "focal", "rotation deg", "centre/room", "focal RMS/worst",
                       "rotation RMS/worst", "centre RMS/worst", "snapped", "c held", "ms"]))
    print("targets (issue 6): focal < 1 %, rotation < 0.5 deg, camera centre < 2 % of the room diagonal")


if __name__ == "__main__":
    main()
