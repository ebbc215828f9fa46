"""Captured light in the sun rooms: how much of the object's captured-vs-known gap is the camera, the sun's
estimate, and the rest of the captured light (issue 34; branch sun108).

usage: python bench/bench_sun108.py --rooms ~/.cache/photoar/rooms_full --only sun_104,sun_107 [--out DIR]

Per room (bench/own_room_flow.py's own-room flow, object's colour, captured light), four composites that each
swap one input for the truth's, scored by ../shared/tools/score.py:
  captured       calibrate's camera (scene refines it), the sun composite estimates   (the user's flow)
  true cam       the room's true camera, not refined (--no-refine-camera), the sun estimated
                 (captured - true cam: the camera)
  true cam+sun   the true camera, not refined, the truth's sun typed in (--sun-direction, --sun-irradiance)
                 (true cam - true cam+sun: the sun's direction/strength estimate)
  known          the benchmark folder under known light
                 (true cam+sun - known: the rest of captured light: the radiance mesh and its reflectivities,
                 the object's near-field light through them)
The sun estimate (composite's report.json "sun") is printed against the truth's: angle (deg), strength ratio.
Writes one JSON per room under --out (default <rooms>/results_sun108) as it goes, then the table.
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

FIGS = ("energy_ratio", "rmse_object", "bias_object")


def estimated_sun(out: Path) -> dict | None:
    """The sun composite used (OUT/report.json "sun": the estimate under captured light with no sun typed
    in; app.stages.sun.SunSetup.report), as {"direction_to_sun", "irradiance_perpendicular"}; None without."""
    rj = out / "report.json"
    s = json.loads(rj.read_text()).get("sun") if rj.is_file() else None
    if not s or "direction" not in s:
        return None
    return {"direction_to_sun": s["direction"], "irradiance_perpendicular": s["irradiance_perpendicular"]}


def sun_error(est: dict | None, true: dict) -> dict:
    """Angle (deg) between the estimated and true direction to the sun, and the strength ratio est/true
    (irradiance_perpendicular, mean over RGB)."""
    if est is None:
        return {"angle_deg": None, "strength_ratio": None}
    a, b = np.asarray(est["direction_to_sun"], float), np.asarray(true["direction_to_sun"], float)
    ang = float(np.degrees(np.arccos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1, 1))))
    r = float(np.mean(est["irradiance_perpendicular"]) / np.mean(true["irradiance_perpendicular"]))
    return {"angle_deg": ang, "strength_ratio": r}


def run_room(root: Path, work: Path, shared: Path) -> dict:
    from bench.own_room_flow import (_composite_argv, _photoar, benchmark_camera_json, declared_openings, fmt,
                                     scene_argv, score, write_inputs)

    work.mkdir(parents=True, exist_ok=True)
    cache = work / "cache"
    inp = write_inputs(root, work / "in")
    declared_openings(inp["room"], inp["scene"])
    sun = next(p for p in inp["scene"]["primitives"] if p["type"] == "sun")
    res: dict = {"rows": {}, "seconds": {}, "sun": {}}

    def step(name, argv):
        t0 = time.time()
        rc, err, _ = _photoar(argv)
        res["seconds"][name] = round(time.time() - t0, 1)
        if rc != 0:
            raise RuntimeError(f"{name}: {err}")

    true_cam = work / "in" / "camera_true.json"
    true_cam.write_text(json.dumps(benchmark_camera_json(inp["scene"])))
    step("calibrate", ["calibrate", str(inp["photo"]), "--lines", str(inp["lines"]), "--height", str(inp["height"]),
                       "--out", str(work / "cal")])
    declared = [f"--sun-direction={fmt(sun['direction_to_sun'])}", "--sun-irradiance",
                fmt(sun["irradiance_perpendicular"])]
    for name, cam, extra in (("captured", work / "cal" / "camera.json", []), ("true cam", true_cam, []),
                             ("true cam+sun", true_cam, declared)):
        room = work / ("room_" + name.replace(" ", "_").replace("+", "_"))
        # the true camera as it is: scene's refinement (with a declared sun also against the sunlit outline,
        # recon/camrefine.py) would move it (sun_107: 2.2 cm, -0.63 % in focal with the sun declared)
        keep = ["--no-refine-camera"] if cam == true_cam else []
        step(f"scene {name}", scene_argv(inp, room, cam) + keep + extra)
        out = work / ("out_" + room.name[5:])
        step(f"composite {name}", _composite_argv(room, out, inp, "captured", cache))
        res["sun"][name] = sun_error(estimated_sun(out), sun)
        res["rows"][name] = score(root, out / "composite.png", shared)
    out = work / "out_known"
    step("composite known", ["composite", str(root), "--out", str(out), "--lighting", "known", "--cache", str(cache)])
    res["rows"]["known"] = score(root, out / "composite.png", shared)
    return res


def print_table(results: dict[str, dict]) -> None:
    names = ("captured", "true cam", "true cam+sun", "known")
    print("\n| room | sun est.: angle / strength | " + " | ".join(f"{n}: rmse_obj (bias) / energy" for n in names)
          + " | camera | sun est. | rest of captured light |")
    print("| --- | --- | " + " | ".join("---" for _ in names) + " | --- | --- | --- |")
    for room, r in results.items():
        if "error" in r:
            print(f"| {room} | ERROR {r['error']} |")
            continue
        rows, s = r["rows"], r["sun"].get("true cam", {})
        cells = [f"{rows[n]['rmse_object']:.2f} ({rows[n]['bias_object']:+.1f}) / {rows[n]['energy_ratio']:.3f}"
                 for n in names]
        o = [rows[n]["rmse_object"] for n in names]
        sa = "-" if s.get("angle_deg") is None else f"{s['angle_deg']:.2f} deg / {s['strength_ratio']:.3f}x"
        print(f"| {room} | {sa} | " + " | ".join(cells)
              + f" | {o[0] - o[1]:+.2f} | {o[1] - o[2]:+.2f} | {o[2] - o[3]:+.2f} |")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rooms", required=True)
    ap.add_argument("--only", required=True, help="comma-separated sun_N rooms")
    ap.add_argument("--shared", default=str(ROOT.parent / "shared"))
    ap.add_argument("--out", help="result folder (default <rooms>/results_sun108)")
    ap.add_argument("--work", help="keep the work folders here (default a folder under --out)")
    ap.add_argument("--report", action="store_true", help="only print the table of the results there are")
    a = ap.parse_args(argv)
    import os

    rooms = Path(a.rooms).expanduser()
    out = Path(a.out).expanduser() if a.out else rooms / "results_sun108"
    out.mkdir(parents=True, exist_ok=True)
    shared = Path(os.environ.get("PHOTOAR_SHARED", a.shared))
    results = {}
    for name in a.only.split(","):
        f = out / f"{name}.json"
        if a.report:
            if f.is_file():
                results[name] = json.loads(f.read_text())
                if "error" not in results[name]:  # the sun from the kept work folders (composite's report)
                    true = next(p for p in json.loads((rooms / name / "scene.json").read_text())["primitives"]
                                if p["type"] == "sun")
                    for n, d in (("captured", "captured"), ("true cam", "true_cam")):
                        results[name]["sun"][n] = sun_error(estimated_sun(Path(a.work or out / "work") / name
                                                                          / f"out_{d}"), true)
            continue
        work = Path(a.work or out / "work") / name
        try:
            results[name] = run_room(rooms / name, work, shared)
        except Exception as e:  # a failing room is a row with its error
            results[name] = {"error": f"{type(e).__name__}: {e}"}
        f.write_text(json.dumps(results[name], indent=1))
        print(name, json.dumps(results[name]), flush=True)
    print_table(results)
    return 0


if __name__ == "__main__":
    sys.exit(main())
