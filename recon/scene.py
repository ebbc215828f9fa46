"""Scene model and the loader for benchmark scene folders (../shared/scenes/FORMAT.md).

The scene model is what the rest of photoar works on, whatever produced it (a benchmark folder,
vanishing-point calibration, multi-view reconstruction):
  camera      calibrated main camera (recon.camera.Camera)
  quads       planar one-sided rectangles: room surfaces, box faces, emitters (Quad)
  obj         the synthetic object to insert, in world coordinates (SceneObject)
  response    camera response (lighting.tonemap.CameraResponse)
  photo       the 8-bit photograph of the empty room, (H,W,3) uint8 RGB
Units: metres, linear radiance in the scene's units, world +Y up.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from lighting.tonemap import CameraResponse
from recon.camera import Camera


class SceneError(ValueError):
    """Bad scene input; the message names the file and the field or problem."""


@dataclass
class Quad:
    name: str
    corners: np.ndarray  # (4,3) c0..c3; c0->c1 texture columns, c0->c3 texture rows
    normal: np.ndarray  # (3,) unit, the lit / emitting side
    albedo: np.ndarray  # (3,) linear diffuse reflectance (mean)
    emission: np.ndarray  # (3,) emitted radiance, zero for non-emitters
    role: str = "room"  # room | furniture | window | ceiling_lamp | point_lamp
    texture: np.ndarray | None = None  # (Ht,Wt,3) float linear albedo, or None
    opening: bool = False  # a window that is a hole in its wall: sky (and sun) come through it

    @property
    def is_emitter(self) -> bool:
        return bool(np.any(self.emission > 0))


@dataclass
class SceneObject:
    vertices: np.ndarray  # (V,3) world coordinates, metres
    normals: np.ndarray  # (V,3) unit outward vertex normals, world
    faces: np.ndarray  # (F,3) int32
    albedo: np.ndarray  # (3,) linear diffuse reflectance
    object_to_world: np.ndarray  # (4,4)
    source: str = ""

    @property
    def centre(self) -> np.ndarray:
        return 0.5 * (self.vertices.min(0) + self.vertices.max(0))

    @property
    def radius(self) -> float:
        """Radius of the bounding sphere about `centre`, metres."""
        return float(np.linalg.norm(self.vertices - self.centre, axis=1).max())


@dataclass
class Sun:
    """A far directional disk emitter (FORMAT.md "Openings, sky and sun"); lights the room only
    through opening quads. Units: irradiance in the scene's radiance units x sr."""

    direction: np.ndarray  # (3,) unit vector from the room towards the sun
    angular_diameter_deg: float  # full apparent diameter of the disk
    irradiance: np.ndarray  # (3,) irradiance on a surface facing the sun (irradiance_perpendicular)
    radiance: np.ndarray  # (3,) radiance of the disk (emitted_radiance); 0 if not given
    distance_m: float = float("inf")  # distance of the disk from the room centre (inf: parallel rays)

    @property
    def half_angle(self) -> float:
        """Angular radius of the disk, radians."""
        return float(np.radians(0.5 * self.angular_diameter_deg))


@dataclass
class Scene:
    name: str
    root: Path
    camera: Camera
    quads: list[Quad]
    obj: SceneObject | None
    response: CameraResponse
    photo: np.ndarray  # (H,W,3) uint8 RGB, the empty room
    room_min: np.ndarray
    room_max: np.ndarray
    meta: dict = field(default_factory=dict)
    sun: Sun | None = None  # the sun, in scenes with an opening


def _field(d: dict, key: str, where: str, path: Path):
    if not isinstance(d, dict) or key not in d:
        raise SceneError(f"{path}: missing field '{where}{key}'")
    return d[key]


def _vec(value, n: int, where: str, path: Path, shape: tuple | None = None) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise SceneError(f"{path}: field '{where}' is not numeric") from None
    want = shape if shape is not None else (n,)
    if arr.shape != want or not np.all(np.isfinite(arr)):
        raise SceneError(f"{path}: field '{where}' must be {want} finite numbers, got shape {arr.shape}")
    return arr


def read_image_rgb(path: Path) -> np.ndarray:
    """8-bit RGB image (H,W,3) uint8; SceneError naming the file if unreadable."""
    import cv2

    if not path.is_file():
        raise SceneError(f"{path}: file not found")
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise SceneError(f"{path}: not a readable image")
    return img[..., ::-1].copy()


def load_mesh(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Triangle mesh -> vertices (V,3), vertex normals (V,3), faces (F,3); SceneError if unusable."""
    import open3d as o3d

    if not path.is_file():
        raise SceneError(f"{path}: file not found")
    mesh = o3d.io.read_triangle_mesh(str(path))
    v = np.asarray(mesh.vertices, np.float64)
    f = np.asarray(mesh.triangles, np.int32)
    if len(v) == 0 or len(f) == 0:
        raise SceneError(f"{path}: could not load a triangle mesh (no vertices or faces)")
    if not np.all(np.isfinite(v)) or f.max() >= len(v) or f.min() < 0:
        raise SceneError(f"{path}: mesh has non-finite vertices or out-of-range face indices")
    if not mesh.has_vertex_normals():
        mesh.compute_vertex_normals()
    n = np.asarray(mesh.vertex_normals, np.float64)
    return v, n, f


def box_faces(lo, hi, inward: bool = False) -> list[tuple[int, int, np.ndarray, np.ndarray]]:
    """The six faces of the box [lo, hi] (m): (axis, side, corners (4,3), unit normal (3,)), side 0
    at lo[axis] and 1 at hi[axis]. Normals point out of the box, or into it with `inward` (a
    room's walls); corners run counter-clockwise seen from the side the normal points to."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    faces = []
    for axis in range(3):
        for side in (0, 1):
            normal = np.zeros(3)
            normal[axis] = (1.0 if side else -1.0) * (-1.0 if inward else 1.0)
            u_ax, v_ax = [a for a in range(3) if a != axis]
            c = np.empty((4, 3))
            for k, (a, b) in enumerate([(0, 0), (1, 0), (1, 1), (0, 1)]):
                c[k, axis] = (lo, hi)[side][axis]
                c[k, u_ax] = (lo, hi)[a][u_ax]
                c[k, v_ax] = (lo, hi)[b][v_ax]
            if np.dot(np.cross(c[1] - c[0], c[3] - c[0]), normal) < 0:
                c = c[[0, 3, 2, 1]]
            faces.append((axis, side, c, normal))
    return faces


def _box_quads(name: str, center: np.ndarray, size: np.ndarray, albedo: np.ndarray,
               room_min: np.ndarray, room_max: np.ndarray) -> list[Quad]:
    """The six outward faces of an axis-aligned box, minus faces flush against a room wall."""
    quads = []
    for axis, side, c, normal in box_faces(center - size / 2, center + size / 2):
        wall = (room_min, room_max)[side][axis]
        if abs(c[0, axis] - wall) < 1e-6:
            continue  # face pressed against the wall/floor: never lit, never seen
        quads.append(Quad(f"{name}.{'xyz'[axis]}{'-+'[side]}", c, normal, albedo, np.zeros(3), "furniture"))
    return quads


def read_json(path: str | os.PathLike, error: type[Exception] | None = None):
    """Parsed JSON of `path`. A missing file raises FileNotFoundError and malformed JSON ValueError,
    both naming the file; with `error` (e.g. SceneError) both raise that instead."""
    path = Path(path)
    if not path.is_file():
        raise (error or FileNotFoundError)(f"{path}: file not found")
    try:
        return json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise (error or ValueError)(f"{path}: malformed JSON ({e})") from None


def load_scene(scene_dir: str | os.PathLike, load_textures: bool = True) -> Scene:
    """Read a benchmark scene folder (scene.json + photo + object mesh) into the scene model."""
    root = Path(scene_dir)
    path = root / "scene.json"
    if not root.is_dir():
        raise SceneError(f"{root}: scene folder not found")
    d = read_json(path, SceneError)
    if not isinstance(d, dict):
        raise SceneError(f"{path}: top level must be an object")

    world = _field(d, "world", "", path)
    room_min = _vec(_field(world, "room_min", "world.", path), 3, "world.room_min", path)
    room_max = _vec(_field(world, "room_max", "world.", path), 3, "world.room_max", path)
    if np.any(room_max <= room_min):
        raise SceneError(f"{path}: field 'world.room_max' must exceed 'world.room_min'")

    cam = _field(d, "main_camera", "", path)
    k = _field(cam, "K", "main_camera.", path)
    fx, fy, cx, cy = (float(_vec(_field(k, key, "main_camera.K.", path), 1, f"main_camera.K.{key}", path,
                                 shape=()))
                      for key in ("fx", "fy", "cx", "cy"))
    width, height = int(_field(k, "width", "main_camera.K.", path)), int(_field(k, "height", "main_camera.K.", path))
    if fx <= 0 or fy <= 0 or width <= 0 or height <= 0:
        raise SceneError(f"{path}: field 'main_camera.K' must have positive focal lengths and size")
    R = _vec(_field(cam, "R", "main_camera.", path), 3, "main_camera.R", path, shape=(3, 3))
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-5):
        raise SceneError(f"{path}: field 'main_camera.R' is not a rotation matrix")
    t = _vec(_field(cam, "t", "main_camera.", path), 3, "main_camera.t", path)
    exposure = float(cam.get("exposure_time", 1.0))
    if not exposure > 0:
        raise SceneError(f"{path}: field 'main_camera.exposure_time' must be positive")
    camera = Camera(np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]]), R, t, width, height, exposure)

    resp = _field(d, "camera_response", "", path)
    try:
        response = CameraResponse(_field(resp, "forward_table", "camera_response.", path),
                                  _field(resp, "inverse_table", "camera_response.", path), exposure)
    except ValueError as e:
        raise SceneError(f"{path}: field 'camera_response': {e}") from None

    quads: list[Quad] = []
    sun: Sun | None = None
    prims = _field(d, "primitives", "", path)
    if not isinstance(prims, list) or not prims:
        raise SceneError(f"{path}: field 'primitives' must be a non-empty list")
    for i, p in enumerate(prims):
        where = f"primitives[{i}]"
        name = str(p.get("name", where)) if isinstance(p, dict) else where
        kind = _field(p, "type", where + ".", path)
        albedo = _vec(p.get("albedo", [0, 0, 0]), 3, f"{where}.albedo", path)
        if kind == "box":
            center = _vec(_field(p, "center", where + ".", path), 3, f"{where}.center", path)
            size = _vec(_field(p, "size", where + ".", path), 3, f"{where}.size", path)
            quads += _box_quads(name, center, size, albedo, room_min, room_max)
        elif kind == "quad":
            corners = _vec(_field(p, "corners", where + ".", path), 3, f"{where}.corners", path, shape=(4, 3))
            normal = _vec(_field(p, "normal", where + ".", path), 3, f"{where}.normal", path)
            normal = normal / max(np.linalg.norm(normal), 1e-12)
            if np.dot(np.cross(corners[1] - corners[0], corners[3] - corners[0]), normal) < 0:
                corners = corners[[0, 3, 2, 1]]  # keep (c1-c0)x(c3-c0) on the lit side
                flipped = True
            else:
                flipped = False
            emission = _vec(p.get("emitted_radiance", [0, 0, 0]), 3, f"{where}.emitted_radiance", path) \
                if p.get("emitter") else np.zeros(3)
            texture = None
            if load_textures and p.get("albedo_texture"):
                img = read_image_rgb(root / p["albedo_texture"]).astype(np.float32) / 255.0
                texture = img.transpose(1, 0, 2) if flipped else img
            quads.append(Quad(name, corners, normal, albedo, emission, str(p.get("role", "room")), texture,
                              bool(p.get("opening", False))))
        elif kind == "sun":
            if sun is not None:
                raise SceneError(f"{path}: field '{where}': a second sun (only one 'sun' primitive is allowed)")
            sun = parse_sun(p, where, path)
        else:
            raise SceneError(f"{path}: field '{where}.type' must be 'quad', 'box' or 'sun', got {kind!r}")

    obj = None
    if "synthetic_object" in d:
        so = d["synthetic_object"]
        M = _vec(_field(so, "object_to_world", "synthetic_object.", path), 4, "synthetic_object.object_to_world",
                 path, shape=(4, 4))
        mesh_path = root / str(_field(so, "mesh", "synthetic_object.", path))
        obj = make_object(mesh_path, M, _vec(so.get("albedo", [0.5] * 3), 3, "synthetic_object.albedo", path))
        check_object_inside(obj, room_min, room_max, f"{path}: field 'synthetic_object.object_to_world'")

    files = cam.get("files", {}) if isinstance(cam.get("files", {}), dict) else {}
    photo = read_image_rgb(root / files.get("background_png", "background.png"))
    if photo.shape[:2] != (height, width):
        raise SceneError(f"{root / files.get('background_png', 'background.png')}: image is "
                         f"{photo.shape[1]}x{photo.shape[0]}, camera says {width}x{height}")
    return Scene(str(d.get("name", root.name)), root, camera, quads, obj, response, photo, room_min, room_max,
                 meta={"json_path": str(path)}, sun=sun)


def parse_sun(p: dict, where: str, path: Path) -> Sun:
    """The `sun` primitive (FORMAT.md), validated: SceneError naming the file and field."""
    d = _vec(_field(p, "direction_to_sun", where + ".", path), 3, f"{where}.direction_to_sun", path)
    norm = float(np.linalg.norm(d))
    if norm < 1e-9 or abs(norm - 1.0) > 1e-3:
        raise SceneError(f"{path}: field '{where}.direction_to_sun' must be a unit vector, has length {norm:.6g}")
    diam = float(_vec(p.get("angular_diameter_deg", 0.53), 1, f"{where}.angular_diameter_deg", path, shape=()))
    if not 0.0 <= diam < 90.0:
        raise SceneError(f"{path}: field '{where}.angular_diameter_deg' must be in [0, 90) degrees, got {diam}")
    E = _vec(_field(p, "irradiance_perpendicular", where + ".", path), 3, f"{where}.irradiance_perpendicular",
             path)
    L = _vec(p.get("emitted_radiance", [0.0, 0.0, 0.0]), 3, f"{where}.emitted_radiance", path)
    for key, v in (("irradiance_perpendicular", E), ("emitted_radiance", L)):
        if np.any(v < 0):
            raise SceneError(f"{path}: field '{where}.{key}' must be non-negative, got {v.tolist()}")
    dist = float(_vec(p.get("distance_m", float("inf")), 1, f"{where}.distance_m", path, shape=())) \
        if p.get("distance_m") is not None else float("inf")
    if not dist > 0:
        raise SceneError(f"{path}: field '{where}.distance_m' must be positive, got {dist}")
    return Sun(d / norm, diam, E, L, dist)


def make_object(mesh_path: Path, object_to_world: np.ndarray, albedo: np.ndarray) -> SceneObject:
    """Load an object mesh and place it with a 4x4 object-to-world matrix."""
    v, n, f = load_mesh(Path(mesh_path))
    M = np.asarray(object_to_world, np.float64)
    vw = v @ M[:3, :3].T + M[:3, 3]
    nw = n @ np.linalg.inv(M[:3, :3])  # inverse-transpose, row-vector form
    nw /= np.maximum(np.linalg.norm(nw, axis=1, keepdims=True), 1e-12)
    return SceneObject(vw, nw, f, np.asarray(albedo, np.float64), M, str(mesh_path))


def check_object_inside(obj: SceneObject, room_min: np.ndarray, room_max: np.ndarray, where: str,
                        tol: float = 1e-3) -> None:
    """Raise SceneError when the placed object pokes out of the room box."""
    lo, hi = obj.vertices.min(0), obj.vertices.max(0)
    if np.any(lo < room_min - tol) or np.any(hi > room_max + tol):
        raise SceneError(f"{where}: object (bbox {np.round(lo, 3).tolist()} .. {np.round(hi, 3).tolist()}) "
                         f"lies outside the room {room_min.tolist()} .. {room_max.tolist()}")


def furniture_boxes(scene: Scene) -> list[tuple[np.ndarray, np.ndarray]]:
    """(lo, hi) corners of each furniture box, rebuilt from its faces (names 'box.x-' etc.)."""
    groups: dict[str, list[np.ndarray]] = {}
    for q in scene.quads:
        if q.role == "furniture":
            groups.setdefault(q.name.rsplit(".", 1)[0], []).append(q.corners)
    return [(np.min(np.concatenate(c), 0), np.max(np.concatenate(c), 0)) for c in groups.values()]


def inside_furniture(scene: Scene, points: np.ndarray, margin: float = 0.0) -> np.ndarray:
    """(N,) bool: points inside (or within `margin` m of) a furniture box."""
    p = np.asarray(points, np.float64)
    out = np.zeros(len(p), bool)
    for lo, hi in furniture_boxes(scene):
        out |= np.all((p > lo - margin) & (p < hi + margin), axis=1)
    return out
