"""Assemble a user's room folder (scene format 1, docs/scene-format.md) from what a photographer
has: a calibrated camera (camera.json of `photoar calibrate`), a primitive model (`photoar model`,
`photoar reconstruct` or a hand-written geometry file), a photo with its exposure time, and
optionally a mirror-ball bracket with its tape-measured pose and a sun.

Pure functions: they validate and build the scene.json dict from inputs parsed by the shared
parsers (recon.camera.Camera, recon.scene.parse_primitives); app/cmd_scene.py reads the files and
writes the folder. Every problem raises recon.io.SceneError with one line `<file>: <field/problem>`.

Conventions as in ../shared/scenes/FORMAT.md: metres, world +Y up, floor at y = 0 for a room box
standing on the floor; OpenCV cameras x_cam = R X + t; the probe camera is orthographic, looks
from the point it was shot from at the ball centre and is upright (image x horizontal, y down).
"""
from __future__ import annotations

import json
import math

import numpy as np

from recon.camera import Camera
from recon.io import SceneError
from recon.scene import PrimitiveSpec, aligned_size, box_faces, box_quads, is_axis_aligned
from recon.scene import parse_primitives as scene_primitives
from recon.scene import parse_sun, sun_entry

SCENE_FORMAT_VERSION = 1
ROLES_EMITTING = ("window", "lamp", "ceiling_lamp", "point_lamp")
ROLES = ("room", "furniture") + ROLES_EMITTING
ROOM_FACE_NAMES = {(0, 0): "left", (0, 1): "right", (1, 0): "floor", (1, 1): "ceiling", (2, 0): "back",
                   (2, 1): "front"}
SUN_ANGULAR_DIAMETER_DEG = 0.53
SUN_DISTANCE_M = 2000.0
SUN_DECLARED_BY_USER = "user"  # the sun entry's "declared_by" when the user gave it (--sun-* or a sun in
# --primitives): `--sun auto` then uses it under captured light (app.engine); benchmark suns have no such key


def _quad_entry(name: str, corners: np.ndarray, normal: np.ndarray, extra: dict) -> dict:
    return {"name": name, "type": "quad", "corners": np.asarray(corners).tolist(),
            "normal": np.asarray(normal).tolist(), **extra}


def room_quads(lo: np.ndarray, hi: np.ndarray, extra: dict | None = None) -> list[dict]:
    """The six inward quads of the room box [lo, hi] named floor/ceiling/back/front/left/right."""
    return [_quad_entry(ROOM_FACE_NAMES[(axis, side)], c, n, {"role": "room", **(extra or {}), "emitter": False})
            for axis, side, c, n in box_faces(lo, hi, inward=True)]


def _entries(spec: PrimitiveSpec, lo: np.ndarray, hi: np.ndarray) -> list[dict]:
    """scene.json entries (geometry + role [+ albedo, emitted_radiance where given]) of one
    primitive: a quad as it is, an axis-aligned box as a box, a turned box as its six faces."""
    extra: dict = {"role": spec.role}
    if "albedo" in spec.raw:
        extra["albedo"] = spec.albedo.tolist()
    extra["emitter"] = spec.role in ROLES_EMITTING
    if extra["emitter"] and "emitted_radiance" in spec.raw:
        extra["emitted_radiance"] = spec.emitted_radiance.tolist()
    if spec.opening:  # a hole in its wall: sky and sun come through (checked in parse_primitives)
        extra["opening"] = True
    if spec.kind == "quad":
        return [_quad_entry(spec.name, spec.corners, spec.quad_normal, extra)]
    yaw = math.radians(spec.yaw_deg)
    if is_axis_aligned(yaw):  # a FORMAT.md box
        return [{"name": spec.name, "type": "box", "center": spec.center.tolist(),
                 "size": aligned_size(spec.size, yaw).tolist(), **extra}]
    return [_quad_entry(q.name, q.corners, q.normal, extra)
            for q in box_quads(spec.name, spec.center, spec.size, yaw, spec.albedo, spec.role, lo, hi)]


def _check_opening(p: PrimitiveSpec, where: str, src: str) -> None:
    """`"opening"` (a window that is a hole in its wall, FORMAT.md): a JSON boolean, on a window quad."""
    v = p.raw["opening"]
    if not isinstance(v, bool):
        raise SceneError(f"{src}: field '{where}.opening' must be true or false, got {json.dumps(v)}")
    if v and not (p.kind == "quad" and p.role == "window"):
        raise SceneError(f"{src}: field '{where}.opening': only a quad with role 'window' can be an opening "
                         f"(this is a {p.kind} with role {p.role!r})")


def parse_primitives(d, src: str) -> tuple[list[dict], np.ndarray, np.ndarray]:
    """A primitives file (`photoar model` / `reconstruct` output or {"primitives": [...]}, parsed
    by recon.scene.parse_primitives) -> (scene.json primitives, room_min, room_max). A box with role
    "room" is the room shell (six inward quads); quads with role "room" are room surfaces as they are."""
    specs = scene_primitives(d, src)
    where = {id(raw): f"primitives[{i}]" for i, raw in enumerate(d["primitives"])}  # indices as in the file
    names: set[str] = set()
    for p in specs:
        if p.role not in ROLES:
            raise SceneError(f"{src}: field '{where[id(p.raw)]}.role' must be one of {', '.join(ROLES)}, got "
                             f"{p.role!r}")
        if p.name in names:
            raise SceneError(f"{src}: field '{where[id(p.raw)]}.name': duplicate name {p.name!r}")
        names.add(p.name)
        if "opening" in p.raw:
            _check_opening(p, where[id(p.raw)], src)
    shells = [p for p in specs if p.role == "room" and p.kind == "box"]
    if len(shells) > 1:
        raise SceneError(f"{src}: field '{where[id(shells[1].raw)]}': a second box with role 'room' (one room "
                         "shell only)")
    room_pts = [p.corners for p in specs if p.role == "room" and p.kind == "quad"]
    shell = None
    if shells:
        p = shells[0]
        if not is_axis_aligned(math.radians(p.yaw_deg)):
            raise SceneError(f"{src}: field '{where[id(p.raw)]}.yaw_deg': the room box must be axis-aligned (it "
                             "defines the world axes)")
        half = aligned_size(p.size, math.radians(p.yaw_deg)) / 2
        shell = (p.center - half, p.center + half)
        room_pts.append(np.stack(shell))
    if not room_pts:
        raise SceneError(f"{src}: no room: give a box with \"role\": \"room\" (the room shell, inside "
                         "dimensions) or the room's surfaces as quads with role 'room'")
    pts = np.concatenate(room_pts)
    lo, hi = pts.min(0), pts.max(0)
    if np.any(hi - lo <= 1e-6):
        raise SceneError(f"{src}: the room is flat (extent {np.round(hi - lo, 3).tolist()} m)")
    out: list[dict] = []
    for p in specs:
        if p.role == "room" and p.kind == "box":
            out += room_quads(*shell, {"albedo": p.albedo.tolist()} if "albedo" in p.raw else None)
        else:
            out += _entries(p, lo, hi)
    return out, lo, hi


def camera_in_room(cam: Camera, lo: np.ndarray, hi: np.ndarray, tol: float = 1e-3) -> bool:
    """The camera centre lies in the room box [lo, hi] (metres, world), within `tol`."""
    c = cam.centre
    return bool(np.all(c >= lo - tol) and np.all(c <= hi + tol))


TURN_Y = np.diag([-1.0, 1.0, -1.0])  # 180 deg about the world +Y axis through the origin


def turned_about_y(cam: Camera) -> Camera:
    """The same photo with the world turned 180 deg about +Y through the origin: the other sign of
    the floor axes that vanishing lines leave open (calibrate's --flip-xz). x_cam = R x + t with
    x = TURN_Y x', so R' = R TURN_Y, t' = t; the centre becomes TURN_Y C."""
    import dataclasses

    return dataclasses.replace(cam, R=cam.R @ TURN_Y, t=cam.t.copy())


def inside_turn(cam: Camera, lo: np.ndarray, hi: np.ndarray) -> tuple[Camera, bool]:
    """(camera, turned): `cam`, or its 180 deg turn about +Y (turned_about_y) when only the turned one lies
    in the room box [lo, hi]; `cam` unchanged when neither or both do (check_camera_in_room says which)."""
    if camera_in_room(cam, lo, hi):
        return cam, False
    turned = turned_about_y(cam)
    return (turned, True) if camera_in_room(turned, lo, hi) else (cam, False)


def check_camera_in_room(cam: Camera, lo: np.ndarray, hi: np.ndarray, camera_src: str, prims_src: str,
                         tol: float = 1e-3) -> None:
    """The photo was taken inside the room: its camera centre lies in the room box."""
    c = cam.centre
    if not camera_in_room(cam, lo, hi, tol):
        raise SceneError(f"{camera_src}: the camera centre {np.round(c, 3).tolist()} m lies outside the room "
                         f"{np.round(lo, 3).tolist()} .. {np.round(hi, 3).tolist()} of {prims_src}: check the "
                         "calibration's scale (camera height / known length) and the room's measurements")


# ----------------------------------------------------------------------------------------------
# Light probe

def probe_camera(centre, radius: float, shot_from, width: int, height: int, src: str = "--probe-shot-from") -> dict:
    """Upright orthographic probe camera (FORMAT.md light_probe.camera) looking from `shot_from` at
    the ball `centre` (m); the ball of `radius` m fills the square image (inscribed circle)."""
    c, s = np.asarray(centre, float), np.asarray(shot_from, float)
    d = c - s
    dist = float(np.linalg.norm(d))
    if not dist > radius:
        raise SceneError(f"{src}: the shot-from point {s.tolist()} is inside the ball (distance {dist:.3f} m "
                            f"<= radius {radius} m)")
    z = d / dist
    x = np.cross(z, [0.0, 1.0, 0.0])
    if np.linalg.norm(x) < 1e-3:
        raise SceneError(f"{src}: the probe was shot straight from above or below: an upright camera's roll "
                            "is undetermined; shoot it from the side")
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    return {"model": "orthographic", "width": int(width), "height": int(height),
            "pixel_size_m": 2.0 * float(radius) / int(width), "cx": (width - 1) / 2.0, "cy": (height - 1) / 2.0,
            "R": R.tolist(), "t": (-R @ s).tolist(), "centre": s.tolist(), "view_direction": z.tolist(),
            "distance_to_ball_centre_m": dist}


def light_probe_block(centre, radius: float, shot_from, size: int, files: list[str], times: list[float],
                      src: str = "--probe-shot-from") -> dict:
    """scene.json light_probe block for a square, ball-inscribed bracket of `size` px."""
    if not radius > 0:
        raise SceneError(f"--probe-radius: must be positive, got {radius}")
    cam = probe_camera(centre, radius, shot_from, size, size, src)
    return {"centre": [float(x) for x in centre], "radius": float(radius), "camera": cam,
            "ball_in_image": {"centre_px": [(size - 1) / 2.0, (size - 1) / 2.0], "radius_px": size / 2.0},
            "ldr_files": list(files), "exposure_times": [float(t) for t in times]}


def check_probe_inside(centre, radius: float, shot_from, lo, hi) -> None:
    """The ball lies in the room (the shot-from point may not: only its direction is used)."""
    c = np.asarray(centre, float)
    if np.any(c - radius < lo - 1e-3) or np.any(c + radius > hi + 1e-3):
        raise SceneError(f"--probe-centre: the ball {c.tolist()} (radius {radius} m) is not inside the room "
                            f"{np.round(lo, 3).tolist()} .. {np.round(hi, 3).tolist()}")


# ----------------------------------------------------------------------------------------------
# Sun

def sun_primitive(direction, irradiance, lo, hi) -> dict:
    """FORMAT.md "sun" entry: a 0.53 deg disk at 2000 m in `direction` (towards the sun, from the
    room centre) whose irradiance on a surface facing it is `irradiance` (RGB, scene units)."""
    d = np.asarray(direction, float)
    if not np.linalg.norm(d) > 0:
        raise SceneError("--sun-direction: must be a non-zero vector")
    d = d / np.linalg.norm(d)
    E = np.asarray(irradiance, float)
    if np.any(E < 0) or not np.any(E > 0):
        raise SceneError(f"--sun-irradiance: must be non-negative and not all zero, got {E.tolist()}")
    half = math.radians(SUN_ANGULAR_DIAMETER_DEG / 2)
    projected_solid_angle = math.pi * math.sin(half) ** 2  # of the disk, = its solid angle to 1e-5
    centre = 0.5 * (np.asarray(lo) + np.asarray(hi)) + SUN_DISTANCE_M * d
    return {"name": "sun", "type": "sun", "role": "sun", "emitter": True, "direction_to_sun": d.tolist(),
            "angular_diameter_deg": SUN_ANGULAR_DIAMETER_DEG, "emitted_radiance": (E / projected_solid_angle).tolist(),
            "irradiance_perpendicular": E.tolist(), "distance_m": SUN_DISTANCE_M, "centre": centre.tolist(),
            "radius_m": SUN_DISTANCE_M * math.tan(half), "normal": (-d).tolist(), "albedo": [0.0, 0.0, 0.0],
            "declared_by": SUN_DECLARED_BY_USER}


def input_sun(d, src: str) -> dict | None:
    """The `sun` entry of a primitives input (e.g. a benchmark scene.json), validated by recon.scene
    .parse_sun and returned as given (its direction normalised) with `"declared_by": "user"` (None: the
    input has none)."""
    found = sun_entry(d, src)
    if found is None:
        return None
    i, p = found
    sun = parse_sun(p, f"primitives[{i}]", src)
    return {**p, "direction_to_sun": sun.direction.tolist(), "declared_by": SUN_DECLARED_BY_USER}


# ----------------------------------------------------------------------------------------------
# The scene

def scene_dict(name: str, cam: Camera, exposure_time: float, prims: list[dict], lo, hi,
               light_probe: dict | None = None, sun: dict | None = None, camera_response: dict | None = None
               ) -> dict:
    """The scene.json of a user's room (docs/scene-format.md): only what the engine reads."""
    d = {
        "name": name, "format_version": SCENE_FORMAT_VERSION,
        "world": {"room_min": [float(x) for x in lo], "room_max": [float(x) for x in hi], "up": [0.0, 1.0, 0.0],
                  "floor_y": float(lo[1])},
        "main_camera": {"K": cam.intrinsics_json(), "R": cam.R.tolist(), "t": cam.t.tolist(),
                        "exposure_time": float(exposure_time), "files": {"background_png": "background.png"}},
        "primitives": prims + ([sun] if sun else []),
    }
    if light_probe is not None:
        d["light_probe"] = light_probe
    if camera_response is not None:
        d["camera_response"] = camera_response
    return d
