"""Wall time per stage of the multi-image reconstruction, and its accuracy, on the shared sets.

  python bench/bench_multiview.py [--sets temple,sceaux,window_room,lamps_room]

Prints one row per set: seconds for SIFT extraction, exhaustive matching, incremental mapping,
room fitting (scene sets) and view.png rendering, with registered images, mean reprojection
error, and the accuracy figures of issue 7 (temple: worst centre error in % of the ring diameter
after a similarity to the published calibration; Sceaux: focal length against openMVG's K; scenes:
worst rotation / centre error after a similarity to the true cameras and worst plane error of the
fitted floor and walls, in the calibrated main photo's frame or, without a camera, after a
similarity on the camera centres; the fitted room's size and how many cameras it contains).
Renders go to out/bench/multiview_<set>.png. `--composite` also composites each scene with
captured light in its fitted room (the own-room acceptance: energy 0.8-1.25, rmse_affected at
most 0.6 x untouched). Timings on a shared 2-core machine are inflated by
contention.
"""
from __future__ import annotations

import argparse
import json
import logging
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.report import table  # noqa: E402
from recon import multiview as mv  # noqa: E402
from recon.view import render_png  # noqa: E402

SHARED = ROOT.parent / "shared"
MULTI = SHARED / "data" / "multiview"


def _render(name, res, prims, row):
    (ROOT / "out" / "bench").mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    row["renderer"] = render_png(ROOT / "out" / "bench" / f"multiview_{name}.png", res.points, res.colors,
                                 res.cameras, prims)
    row["render_s"] = time.perf_counter() - t0


def bench_temple() -> dict:
    base = MULTI / "middlebury_templeSparseRing"
    known = mv.read_middlebury_par(base / "templeSR_par.txt")
    res = mv.reconstruct(base / "images", mv.SfmOptions(single_camera=True, max_features=2000), progress=False)
    C = np.array([c.centre for c in known.values()])
    diam = 2 * np.mean(np.linalg.norm(C - C.mean(0), axis=1))
    al = res.transformed(mv.similarity_from_centres(res, known))
    err = mv.pose_errors(al.cameras, known)
    row = {"set": "temple 640x480", **res.timings, "registered": f"{len(res.cameras)}/{res.n_images}",
           "reproj_px": res.mean_reproj_px,
           "accuracy": f"centre max {100 * max(e[1] for e in err.values()) / diam:.2f} % of diameter, "
                       f"f {next(iter(res.cameras.values())).K[0, 0]:.0f} px (1520)"}
    _render("temple", al, [], row)
    return row


def bench_sceaux() -> dict:
    base = MULTI / "sceaux_castle"
    f_true = json.loads((base / "K.json").read_text())["K_stored_corner_convention"][0][0]
    res = mv.reconstruct(base / "images", mv.SfmOptions(max_features=4000), progress=False)
    f = float(np.mean([c.K[0, 0] for c in res.cameras.values()]))
    row = {"set": "sceaux 1416x1064", **res.timings, "registered": f"{len(res.cameras)}/{res.n_images}",
           "reproj_px": res.mean_reproj_px, "accuracy": f"f {f:.0f} px ({f_true:.0f}, {100 * (f / f_true - 1):+.1f} %)"}
    _render("sceaux", res, [], row)
    return row


def _plane_err(fit, truth: dict, sim: "mv.Similarity") -> tuple[list[str], float, float]:
    """Observed surfaces, worst angle (deg) and worst distance (m) to the truth after `sim` (fit -> truth)."""
    worst_a = worst_d = 0.0
    seen = []
    for n, s in fit.surfaces.items():
        if s.observed:
            nn, dd = fit.surface_plane(n)
            nn, dd = sim.R @ nn, sim.s * dd - (sim.R @ nn) @ sim.t
            worst_a = max(worst_a, float(np.degrees(np.arccos(np.clip(nn @ truth[n]["normal"], -1, 1)))))
            worst_d = max(worst_d, float(abs(nn @ np.mean(truth[n]["corners"], 0) + dd)))
            seen.append(n)
    return seen, worst_a, worst_d


def bench_scene(name: str, mode: str) -> dict:
    """mode "calibrated": the main photo's camera from its clicked vanishing lines + camera height
    (`photoar calibrate`), its K held in SfM, `reconstruct --camera`'s alignment; "free": no camera
    (shared self-calibrated K), planes compared after a similarity on the camera centres."""
    import cv2

    from app.cmd_reconstruct import align_and_fit
    from recon.vanishing import calibrate_lines, lines_from_scene, parse_lines

    scene = SHARED / "scenes" / name
    d = json.loads((scene / "scene.json").read_text())
    known = {"background.png": mv.Camera.load(scene / "scene.json")}
    calib = None
    if mode == "calibrated":
        photo = cv2.imread(str(scene / "background.png"))[:, :, ::-1].copy()
        t = known["background.png"]
        calib = calibrate_lines(parse_lines(lines_from_scene(d, noisy=True)), t.width, t.height,
                                camera_height=t.centre[1], image=photo).camera
    with tempfile.TemporaryDirectory() as tmp:
        (Path(tmp) / "background.png").symlink_to(scene / "background.png")
        for v in d["views"]:
            (Path(tmp) / Path(v["file"]).name).symlink_to(scene / v["file"])
            known[Path(v["file"]).name] = mv.Camera.from_json(v, scene / "scene.json", "views.")
        res = mv.reconstruct(Path(tmp), mv.SfmOptions(camera=calib, max_features=8000, peak_threshold=0.002,
                                                      two_view_tracks=True), progress=False)
    err = mv.pose_errors(res.transformed(mv.similarity_from_poses(res, known), "m").cameras, known)
    t0 = time.perf_counter()
    al, fit, scale = align_and_fit(res, (calib, "background.png") if calib is not None else None)
    fit_s = time.perf_counter() - t0
    sim = mv.Similarity() if calib is not None else mv.similarity_from_centres(al, known)
    truth = {p["name"]: p for p in d["primitives"]}
    seen, worst_a, worst_d = _plane_err(fit, truth, sim)
    room = float(max(np.subtract(d["world"]["room_max"], d["world"]["room_min"])))
    inside = int(fit.contains(np.array([c.centre for c in al.cameras.values()])).sum())
    row = {"set": f"{name} {mode}", **res.timings, "fit_s": fit_s,
           "registered": f"{len(res.cameras)}/{res.n_images}", "reproj_px": res.mean_reproj_px,
           "accuracy": f"rot max {max(e[0] for e in err.values()):.2f} deg, centre max "
                       f"{100 * max(e[1] for e in err.values()) / room:.2f} % room; planes {'+'.join(seen)}: "
                       f"max {worst_a:.2f} deg, {100 * worst_d:.1f} cm; room "
                       f"{'x'.join(f'{v * sim.s:.2f}' for v in fit.hi - fit.lo)} m; {inside}/{len(al.cameras)} "
                       f"cameras inside; scale {scale['source']}; {len(fit.boxes)} boxes"}
    _render(f"{name}_{mode}", al, fit.primitives(), row)
    row["primitives"] = fit.primitives()
    return row


def bench_composite(name: str, prims: list[dict]) -> dict:
    """Composite with captured light in the scene whose six room quads are replaced by the fitted room
    box's walls (observed and guessed; furniture, window and lamps as in scene.json: a user models
    them with `photoar model`), scored by ../shared/tools/score.py (the own-room acceptance)."""
    import subprocess

    from app.cli import main as cli
    from recon.view import room_walls

    src = SHARED / "scenes" / name
    room = next(p for p in prims if p.get("role") == "room")
    walls = {n: q for n, q, _ in room_walls(room)}
    d = json.loads((src / "scene.json").read_text())
    for p in d["primitives"]:
        if p.get("role") == "room" and p["type"] == "quad":
            q = walls[p["name"]]
            n = np.cross(q[1] - q[0], q[3] - q[0])
            for k in ("albedo_texture", "texture_shape"):
                p.pop(k, None)
            p.update(corners=q.tolist(), normal=(n / np.linalg.norm(n)).tolist(),
                     size_m=[float(np.linalg.norm(q[1] - q[0])), float(np.linalg.norm(q[3] - q[0]))])
    c, size = np.array(room["center"]), np.array(room["size"])
    d["world"]["room_min"], d["world"]["room_max"] = (c - size / 2).tolist(), (c + size / 2).tolist()
    with tempfile.TemporaryDirectory() as tmp:
        dst = Path(tmp) / name
        dst.mkdir()
        for f in src.iterdir():
            if f.name != "scene.json":
                (dst / f.name).symlink_to(f)
        (dst / "scene.json").write_text(json.dumps(d))
        t0 = time.perf_counter()
        if cli(["-q", "composite", str(dst), "--out", str(Path(tmp) / "out"), "--lighting", "captured",
                "--cache", str(Path(tmp) / "cache")]) != 0:
            raise RuntimeError(f"{name}: composite failed")
        dt = time.perf_counter() - t0
        out = subprocess.run([sys.executable, str(SHARED / "tools" / "score.py"), str(src),
                              str(Path(tmp) / "out" / "composite.png")], capture_output=True, text=True, check=True)
        sc = json.loads(out.stdout.strip().splitlines()[-1])
    return {"set": f"{name} fitted room, captured light", "composite_s": dt, "energy": sc["energy_ratio"],
            "rmse_affected": sc["rmse_affected"], "untouched": sc["rmse_affected_if_untouched"],
            "spurious": sc["spurious"], "rmse_object": sc["rmse_object"]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sets", default="temple,sceaux,window_room,lamps_room",
                    help="comma list; a scene runs twice: calibrated main photo, and no camera")
    ap.add_argument("--composite", action="store_true",
                    help="also composite each scene with captured light in its fitted room (calibrated) and score it")
    a = ap.parse_args()
    logging.basicConfig(level=logging.WARNING, format="%(message)s")
    rows, comp = [], []
    for s in a.sets.split(","):
        if s in ("temple", "sceaux"):
            rows.append(bench_temple() if s == "temple" else bench_sceaux())
        else:
            rows += [bench_scene(s, "calibrated"), bench_scene(s, "free")]
            if a.composite:
                comp.append(bench_composite(s, rows[-2]["primitives"]))
        print(f"done {s}", file=sys.stderr)
    print(table(rows, ["set", "features_s", "matching_s", "mapping_s", "fit_s", "render_s", "registered",
                       "reproj_px", "accuracy"], floatfmt=".2f"))
    if comp:
        print(table(comp, ["set", "composite_s", "energy", "rmse_affected", "untouched", "spurious", "rmse_object"],
                    floatfmt=".3f"))


if __name__ == "__main__":
    main()
