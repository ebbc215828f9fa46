"""What a photographer would have of a benchmark room, and nothing more (issue 16): the photo, its
clicked vanishing lines, the room measured with a tape (geometry only: no albedo, no emitted
radiance), a mirror-ball bracket with its exposure times and the ball's tape-measured pose, the
object mesh. Helpers shared by test_scene_cmd, test_own_room and test_readme_walkthrough."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np

from recon.vanishing import lines_from_scene


def tape_room(scene: dict) -> dict:
    """{"primitives": [...]}: the room as one box of role "room", furniture boxes, window/lamp quads."""
    lo, hi = np.array(scene["world"]["room_min"]), np.array(scene["world"]["room_max"])
    prims = [{"name": "room", "type": "box", "role": "room", "center": ((lo + hi) / 2).tolist(),
              "size": (hi - lo).tolist()}]
    for p in scene["primitives"]:
        if p.get("role") in ("room", "sun") or p.get("type") == "sun":
            continue
        role = {"ceiling_lamp": "lamp", "point_lamp": "lamp"}.get(p["role"], p["role"])
        q = {"name": p["name"], "type": p["type"], "role": role}
        q.update({k: p[k] for k in ("center", "size", "corners", "normal") if k in p})
        prims.append(q)
    return {"primitives": prims}


def probe_args(scene: dict) -> dict:
    """The probe's tape pose and bracket: centre, radius, shot-from (the probe camera's centre), times."""
    lp = scene["light_probe"]
    return {"centre": lp["centre"], "radius": lp["radius"], "shot_from": lp["camera"]["centre"],
            "times": lp["exposure_times"], "files": lp["ldr_files"]}


def object_pose(scene: dict, mesh: Path) -> tuple[list[float], float]:
    """--place (world point of the bottom centre of the mesh's own bounding box) and --yaw (deg,
    right-handed about +Y) of the scene's synthetic object (object_to_world = T R_y(yaw))."""
    from recon.scene import load_mesh

    M = np.array(scene["synthetic_object"]["object_to_world"], float)
    v, _, _ = load_mesh(mesh)
    lo, hi = v.min(0), v.max(0)
    pivot = np.array([(lo[0] + hi[0]) / 2, lo[1], (lo[2] + hi[2]) / 2])
    place = M[:3, :3] @ pivot + M[:3, 3]
    yaw = float(np.degrees(np.arctan2(M[0, 2], M[0, 0])))
    return place.tolist(), yaw


def write_inputs(scene_dir: Path, out: Path) -> dict:
    """Write the user's files for benchmark `scene_dir` into `out`: photo.png, lines.json, room.json,
    clicks.json (the room clicked on the photo, as `photoar gui --model` saves it: tests/clicks_truth.py,
    1 px noise), ball_N.png, the object's mesh as object.ply. Returns the numbers a user would type (the
    object's albedo is the product's colour, which the user knows)."""
    scene = json.loads((scene_dir / "scene.json").read_text())
    out.mkdir(parents=True, exist_ok=True)
    shutil.copy(scene_dir / "background.png", out / "photo.png")
    (out / "lines.json").write_text(json.dumps(lines_from_scene(scene)))
    (out / "room.json").write_text(json.dumps(tape_room(scene), indent=1))
    from tests.clicks_truth import true_clicks

    (out / "clicks.json").write_text(json.dumps(true_clicks(scene, sigma_px=1.0, seed=0)[0], indent=1))
    pa = probe_args(scene)
    probes = []
    for i, f in enumerate(pa["files"]):
        shutil.copy(scene_dir / f, out / f"ball_{i}.png")
        probes.append(out / f"ball_{i}.png")
    mesh = scene_dir / scene["synthetic_object"]["mesh"]
    shutil.copy(mesh, out / "object.ply")
    place, yaw = object_pose(scene, mesh)
    return {"scene": scene, "photo": out / "photo.png", "lines": out / "lines.json", "room": out / "room.json",
            "clicks": out / "clicks.json",
            "probes": probes, "mesh": out / "object.ply", "exposure": scene["main_camera"]["exposure_time"],
            "height": scene["main_camera"]["centre"][1], "place": place, "yaw": yaw,
            "albedo": scene["synthetic_object"]["albedo"], **pa}


def fmt(v) -> str:
    return ",".join(repr(float(x)) for x in v)


def scene_argv(inp: dict, room: Path, camera: Path, shot_from=None) -> list[str]:
    """`photoar scene` arguments for the inputs of write_inputs."""
    return ["scene", str(room), "--photo", str(inp["photo"]), "--exposure-time", str(inp["exposure"]),
            "--camera", str(camera), "--primitives", str(inp["room"]),
            "--probe", *map(str, inp["probes"]), "--probe-times", *map(str, inp["times"]),
            "--probe-centre", fmt(inp["centre"]), "--probe-radius", str(inp["radius"]),
            "--probe-shot-from", fmt(inp["shot_from"] if shot_from is None else shot_from)]


def benchmark_camera_json(scene: dict) -> dict:
    """camera.json of the scene's true main camera (calibrate's format: K block, R, t)."""
    c = scene["main_camera"]
    return {"K": c["K"], **{k: c["K"][k] for k in ("fx", "fy", "cx", "cy", "width", "height")}, "R": c["R"],
            "t": c["t"], "centre": c["centre"]}
