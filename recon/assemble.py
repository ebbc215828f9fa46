"""Assemble a user's room folder (scene format 1, docs/scene-format.md) from what a photographer
has: a calibrated camera (camera.json of `photoar calibrate`), a primitive model (`photoar model`,
`photoar reconstruct` or a hand-written geometry file), a photo with its exposure time, and
optionally a mirror-ball bracket with its tape-measured pose and a sun.

Pure functions: they parse, validate and build the scene.json dict; app/cmd_scene.py reads the
files and writes the folder. Every problem raises AssembleError with one line
`<file>: <field/problem>`.

Conventions as in ../shared/scenes/FORMAT.md: metres, world +Y up, floor at y = 0 for a room box
standing on the floor; OpenCV cameras x_cam = R X + t; the probe camera is orthographic, looks
from the point it was shot from at the ball centre and is upright (image x horizontal, y down).
"""
from __future__ import annotations

import math

import numpy as np

SCENE_FORMAT_VERSION = 1
ROLES_EMITTING = ("window", "lamp", "ceiling_lamp", "point_lamp")
ROLES = ("room", "furniture") + ROLES_EMITTING
ROOM_FACE_NAMES = {(0, 0): "left", (0, 1): "right", (1, 0): "floor", (1, 1): "ceiling", (2, 0): "back",
                   (2, 1): "front"}
SUN_ANGULAR_DIAMETER_DEG = 0.53
SUN_DISTANCE_M = 2000.0


class AssembleError(ValueError):
    """Bad input to `photoar scene`; the message is `<file>: <field/problem>`."""


def _vec(value, shape: tuple, where: str, src: str) -> np.ndarray:
    try:
        a = np.asarray(value, np.float64)
    except (TypeError, ValueError):
        raise AssembleError(f"{src}: field '{where}' is not numeric") from None
    if a.shape != shape or not np.all(np.isfinite(a)):
        raise AssembleError(f"{src}: field '{where}' must be {list(shape)} finite numbers, got shape {list(a.shape)}")
    return a


# ----------------------------------------------------------------------------------------------
# Camera

def parse_camera(d, src: str) -> dict:
    """camera.json of `photoar calibrate` (K as a block or flat fx..height, R, t) -> {K, R, t,
    width, height, focal_rel_sigma, ill_conditioned}; the world->camera rotation must be proper."""
    if not isinstance(d, dict):
        raise AssembleError(f"{src}: top level must be an object")
    if "main_camera" in d and isinstance(d["main_camera"], dict):  # a scene.json as camera source
        d = d["main_camera"]
    k = d.get("K") if isinstance(d.get("K"), dict) else d
    keys = ("fx", "fy", "cx", "cy", "width", "height")
    missing = [x for x in keys if x not in k]
    if missing:
        raise AssembleError(f"{src}: missing field 'K' (needs {', '.join(keys)}; missing {', '.join(missing)})")
    K = {x: float(_vec(k[x], (), f"K.{x}", src)) for x in keys}
    if not (K["fx"] > 0 and K["fy"] > 0 and K["width"] >= 1 and K["height"] >= 1):
        raise AssembleError(f"{src}: field 'K' must have positive fx, fy, width, height")
    if K["width"] != int(K["width"]) or K["height"] != int(K["height"]):
        raise AssembleError(f"{src}: field 'K.width'/'K.height' must be whole pixels")
    K["width"], K["height"] = int(K["width"]), int(K["height"])
    for x in ("R", "t"):
        if x not in d:
            raise AssembleError(f"{src}: missing field '{x}'")
    R = _vec(d["R"], (3, 3), "R", src)
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-5) or np.linalg.det(R) < 0:
        raise AssembleError(f"{src}: field 'R' is not a rotation matrix (R R^T = I and det R = +1 required)")
    t = _vec(d["t"], (3,), "t", src)
    return {"K": K, "R": R, "t": t, "width": K["width"], "height": K["height"],
            "focal_rel_sigma": d.get("focal_rel_sigma"), "ill_conditioned": bool(d.get("ill_conditioned", False))}


def camera_centre(cam: dict) -> np.ndarray:
    return -cam["R"].T @ cam["t"]


# ----------------------------------------------------------------------------------------------
# Primitives

def _geometry(raw: dict, prim) -> list[dict]:
    """scene.json entries (FORMAT.md schema, geometry + role [+ albedo, emitter]) of one parsed primitive."""
    role = prim.role
    extra: dict = {"role": role}
    if "albedo" in raw:
        extra["albedo"] = [float(x) for x in prim.albedo]
    emitting = role in ROLES_EMITTING
    extra["emitter"] = emitting
    if emitting and "emitted_radiance" in raw:
        extra["emitted_radiance"] = [float(x) for x in prim.emitted_radiance]
    if prim.kind == "quad":
        v = prim.vertices()
        return [{"name": prim.name, "type": "quad", "corners": v.tolist(),
                 "normal": prim.rotation()[:, 2].tolist(), **extra}]
    q = prim.yaw / (math.pi / 2)
    if abs(q - round(q)) < 1e-9:  # axis-aligned: a FORMAT.md box
        size = np.abs(np.round(np.cos(prim.yaw))) * prim.size + np.abs(np.round(np.sin(prim.yaw))) * prim.size[[2, 1, 0]]
        return [{"name": prim.name, "type": "box", "center": prim.center.tolist(), "size": size.tolist(), **extra}]
    # a turned box: its six outward faces as quads
    r, h = prim.rotation(), prim.size / 2
    out = []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            u_ax, v_ax = [a for a in range(3) if a != axis]
            local = np.zeros((4, 3))
            local[:, axis] = sign * h[axis]
            for k, (a, b) in enumerate([(-1, -1), (1, -1), (1, 1), (-1, 1)]):
                local[k, u_ax], local[k, v_ax] = a * h[u_ax], b * h[v_ax]
            c = prim.center + local @ r.T
            n = sign * r[:, axis]
            if np.dot(np.cross(c[1] - c[0], c[3] - c[0]), n) < 0:
                c = c[[0, 3, 2, 1]]
            out.append({"name": f"{prim.name}.{'xyz'[axis]}{'-+'[sign > 0]}", "type": "quad", "corners": c.tolist(),
                        "normal": n.tolist(), **extra})
    return out


def room_quads(lo: np.ndarray, hi: np.ndarray, extra: dict | None = None) -> list[dict]:
    """The six inward quads of the room box [lo, hi] named floor/ceiling/back/front/left/right."""
    from recon.scene import box_faces

    out = []
    for axis, side, c, n in box_faces(lo, hi, inward=True):
        out.append({"name": ROOM_FACE_NAMES[(axis, side)], "type": "quad", "role": "room", "corners": c.tolist(),
                    "normal": n.tolist(), **(extra or {}), "emitter": False})
    return out


def parse_primitives(d, src: str) -> tuple[list[dict], np.ndarray, np.ndarray]:
    """A primitives file (`photoar model` / `reconstruct` output or {"primitives": [...]}) ->
    (scene.json primitives, room_min, room_max). A box with role "room" is the room shell (six
    inward quads); quads with role "room" are room surfaces as they are."""
    from recon.primitives import primitive_from_json

    if not isinstance(d, dict) or not isinstance(d.get("primitives"), list) or not d["primitives"]:
        raise AssembleError(f"{src}: field 'primitives' must be a non-empty list")
    out: list[dict] = []
    room_pts: list[np.ndarray] = []
    names: set[str] = set()
    n_room_boxes = 0
    for i, raw in enumerate(d["primitives"]):
        where = f"primitives[{i}]"
        if isinstance(raw, dict) and raw.get("type") == "sun":
            continue  # a benchmark scene.json given as model: its sun is not geometry
        try:
            prim = primitive_from_json(raw, where, src)
        except ValueError as e:
            raise AssembleError(str(e)) from None
        if prim.role not in ROLES:
            raise AssembleError(f"{src}: field '{where}.role' must be one of {', '.join(ROLES)}, got {prim.role!r}")
        if prim.name in names:
            raise AssembleError(f"{src}: field '{where}.name': duplicate name {prim.name!r}")
        names.add(prim.name)
        if prim.role == "room" and prim.kind == "box":
            n_room_boxes += 1
            if n_room_boxes > 1:
                raise AssembleError(f"{src}: field '{where}': a second box with role 'room' (one room shell only)")
            q = prim.yaw / (math.pi / 2)
            if abs(q - round(q)) > 1e-9:
                raise AssembleError(f"{src}: field '{where}.yaw_deg': the room box must be axis-aligned (it "
                                    "defines the world axes)")
            v = prim.vertices()
            lo, hi = v.min(0), v.max(0)
            extra = {"albedo": [float(x) for x in prim.albedo]} if "albedo" in raw else None
            out += room_quads(lo, hi, extra)
            room_pts.append(v)
            continue
        if prim.role == "room":
            room_pts.append(prim.vertices())
        out += _geometry(raw, prim)
    if not room_pts:
        raise AssembleError(f"{src}: no room: give a box with \"role\": \"room\" (the room shell, inside "
                            "dimensions) or the room's surfaces as quads with role 'room'")
    pts = np.concatenate(room_pts)
    lo, hi = pts.min(0), pts.max(0)
    if np.any(hi - lo <= 1e-6):
        raise AssembleError(f"{src}: the room is flat (extent {np.round(hi - lo, 3).tolist()} m)")
    return out, lo, hi


def check_camera_in_room(cam: dict, lo: np.ndarray, hi: np.ndarray, camera_src: str, prims_src: str,
                         tol: float = 1e-3) -> None:
    """The photo was taken inside the room: its camera centre lies in the room box."""
    c = camera_centre(cam)
    if np.any(c < lo - tol) or np.any(c > hi + tol):
        raise AssembleError(f"{camera_src}: the camera centre {np.round(c, 3).tolist()} m lies outside the room "
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
        raise AssembleError(f"{src}: the shot-from point {s.tolist()} is inside the ball (distance {dist:.3f} m "
                            f"<= radius {radius} m)")
    z = d / dist
    x = np.cross(z, [0.0, 1.0, 0.0])
    if np.linalg.norm(x) < 1e-3:
        raise AssembleError(f"{src}: the probe was shot straight from above or below: an upright camera's roll "
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
        raise AssembleError(f"--probe-radius: must be positive, got {radius}")
    cam = probe_camera(centre, radius, shot_from, size, size, src)
    return {"centre": [float(x) for x in centre], "radius": float(radius), "camera": cam,
            "ball_in_image": {"centre_px": [(size - 1) / 2.0, (size - 1) / 2.0], "radius_px": size / 2.0},
            "ldr_files": list(files), "exposure_times": [float(t) for t in times]}


def check_probe_inside(centre, radius: float, shot_from, lo, hi) -> None:
    """The ball lies in the room (the shot-from point may not: only its direction is used)."""
    c = np.asarray(centre, float)
    if np.any(c - radius < lo - 1e-3) or np.any(c + radius > hi + 1e-3):
        raise AssembleError(f"--probe-centre: the ball {c.tolist()} (radius {radius} m) is not inside the room "
                            f"{np.round(lo, 3).tolist()} .. {np.round(hi, 3).tolist()}")


# ----------------------------------------------------------------------------------------------
# Sun

def sun_primitive(direction, irradiance, lo, hi) -> dict:
    """FORMAT.md "sun" entry: a 0.53 deg disk at 2000 m in `direction` (towards the sun, from the
    room centre) whose irradiance on a surface facing it is `irradiance` (RGB, scene units)."""
    d = np.asarray(direction, float)
    if not np.linalg.norm(d) > 0:
        raise AssembleError("--sun-direction: must be a non-zero vector")
    d = d / np.linalg.norm(d)
    E = np.asarray(irradiance, float)
    if np.any(E < 0) or not np.any(E > 0):
        raise AssembleError(f"--sun-irradiance: must be non-negative and not all zero, got {E.tolist()}")
    half = math.radians(SUN_ANGULAR_DIAMETER_DEG / 2)
    projected_solid_angle = math.pi * math.sin(half) ** 2  # of the disk, = its solid angle to 1e-5
    centre = 0.5 * (np.asarray(lo) + np.asarray(hi)) + SUN_DISTANCE_M * d
    return {"name": "sun", "type": "sun", "role": "sun", "emitter": True, "direction_to_sun": d.tolist(),
            "angular_diameter_deg": SUN_ANGULAR_DIAMETER_DEG, "emitted_radiance": (E / projected_solid_angle).tolist(),
            "irradiance_perpendicular": E.tolist(), "distance_m": SUN_DISTANCE_M, "centre": centre.tolist(),
            "radius_m": SUN_DISTANCE_M * math.tan(half), "normal": (-d).tolist(), "albedo": [0.0, 0.0, 0.0]}


# ----------------------------------------------------------------------------------------------
# The scene

def scene_dict(name: str, cam: dict, exposure_time: float, prims: list[dict], lo, hi,
               light_probe: dict | None = None, sun: dict | None = None, camera_response: dict | None = None
               ) -> dict:
    """The scene.json of a user's room (docs/scene-format.md): only what the engine reads."""
    d = {
        "name": name, "format_version": SCENE_FORMAT_VERSION,
        "world": {"room_min": [float(x) for x in lo], "room_max": [float(x) for x in hi], "up": [0.0, 1.0, 0.0],
                  "floor_y": float(lo[1])},
        "main_camera": {"K": dict(cam["K"]), "R": cam["R"].tolist(), "t": cam["t"].tolist(),
                        "exposure_time": float(exposure_time), "files": {"background_png": "background.png"}},
        "primitives": prims + ([sun] if sun else []),
    }
    if light_probe is not None:
        d["light_probe"] = light_probe
    if camera_response is not None:
        d["camera_response"] = camera_response
    return d
