"""Scene model and the loader for benchmark scene folders (../shared/scenes/FORMAT.md).

The scene model is what the rest of photoar works on, whatever produced it (a benchmark folder,
vanishing-point calibration, multi-view reconstruction):
  camera      calibrated main camera (recon.camera.Camera)
  quads       planar one-sided rectangles: room surfaces, box faces, emitters (Quad)
  obj         the synthetic object to insert, in world coordinates (SceneObject)
  response    camera response (recon.response.CameraResponse)
  photo       the 8-bit photograph of the empty room, (H,W,3) uint8 RGB
Units: metres, linear radiance in the scene's units, world +Y up.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from recon.camera import Camera
from recon.io import SceneError, json_array, json_bool, json_field, open3d, read_image_rgb, read_json
from recon.response import CameraResponse

LIGHT_ROLES = ("window", "lamp", "ceiling_lamp", "point_lamp")  # quads that may emit


@dataclass
class Quad:
    name: str
    corners: np.ndarray  # (4,3) c0..c3; c0->c1 texture columns, c0->c3 texture rows
    normal: np.ndarray  # (3,) unit, the lit / emitting side
    albedo: np.ndarray  # (3,) linear diffuse reflectance (mean)
    emission: np.ndarray  # (3,) emitted radiance, zero for non-emitters
    role: str = "room"  # room | furniture | window | lamp | ceiling_lamp | point_lamp
    texture: np.ndarray | None = None  # (Ht,Wt,3) float linear albedo, or None
    declared_emitter: bool = False  # scene.json says "emitter": true (with or without emitted_radiance)
    opening: bool = False  # a window that is a hole in its wall: sky (and sun) come through it

    @property
    def is_emitter(self) -> bool:
        return bool(np.any(self.emission > 0))

    @property
    def light_shaped(self) -> bool:
        """A quad that may emit (declared emitter, or a window/lamp role): cut into finer patches
        so its soft shadows are resolved, whether or not its radiance is declared."""
        return self.is_emitter or self.declared_emitter or self.role in LIGHT_ROLES


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
    strength_estimated: bool = False  # "strength": "estimate": only the direction is given; irradiance is
    # zero here and the engine estimates it from the photo (captured light)

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
    response: CameraResponse | None  # None: not given (captured light recovers it)
    photo: np.ndarray  # (H,W,3) uint8 RGB, the empty room
    room_min: np.ndarray
    room_max: np.ndarray
    meta: dict = field(default_factory=dict)
    sun: Sun | None = None  # the sun, in scenes with an opening


def load_mesh(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Triangle mesh -> vertices (V,3), vertex normals (V,3), faces (F,3); SceneError if unusable.

    Open3D's reader prints to the C-level stderr (RPly's messages, sometimes bytes of the file);
    that is captured and its first line, cleaned, becomes part of the one error message."""
    from kernels.quiet import captured_stderr

    o3d = open3d()
    if not path.is_file():
        raise SceneError(f"{path}: file not found")
    with captured_stderr() as reader:
        mesh = o3d.io.read_triangle_mesh(str(path))
    v = np.asarray(mesh.vertices, np.float64)
    f = np.asarray(mesh.triangles, np.int32)
    if len(v) == 0 or len(f) == 0:
        said = "".join(c if c.isprintable() and c.isascii() else "?" for c in (reader.lines() or [""])[0])[:100]
        raise SceneError(f"{path}: could not load a triangle mesh (no vertices or faces"
                         f"{'; reader: ' + said.strip() if said.strip() else ''})")
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


def rot_y(a: float) -> np.ndarray:
    """(3,3) rotation by `a` radians about world +Y (takes +Z towards +X)."""
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def is_axis_aligned(yaw: float) -> bool:
    """A box turned by `yaw` radians about +Y is axis-aligned (yaw a multiple of 90 degrees)."""
    return bool(abs(np.sin(yaw)) < 1e-9 or abs(np.cos(yaw)) < 1e-9)


def aligned_size(size, yaw: float) -> np.ndarray:
    """World extents (3,) of an axis-aligned box of local `size` turned by `yaw` (x and z swap at 90 deg)."""
    return np.abs(rot_y(yaw)) @ np.asarray(size, np.float64)


def box_quads(name: str, center: np.ndarray, size: np.ndarray, yaw: float, albedo: np.ndarray, role: str,
              room_min: np.ndarray, room_max: np.ndarray) -> list[Quad]:
    """The outward faces of a box (centre and full extents in m, turned by `yaw` radians about +Y),
    named '<name>.x-' ... '<name>.z+'. An axis-aligned box (yaw a multiple of 90 degrees) loses the
    faces flush against a room wall or the floor (never lit, never seen); a turned box keeps all six."""
    center, size = np.asarray(center, np.float64), np.asarray(size, np.float64)
    if is_axis_aligned(yaw):
        size = aligned_size(size, yaw)
        quads = []
        for axis, side, c, normal in box_faces(center - size / 2, center + size / 2):
            wall = (room_min, room_max)[side][axis]
            if abs(c[0, axis] - wall) < 1e-6:
                continue  # face pressed against the wall/floor
            quads.append(Quad(f"{name}.{'xyz'[axis]}{'-+'[side]}", c, normal, albedo, np.zeros(3), role))
        return quads
    r, h = rot_y(yaw), size / 2
    quads = []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            u_ax, v_ax = [a for a in range(3) if a != axis]
            local = np.zeros((4, 3))
            local[:, axis] = sign * h[axis]
            for k, (a, b) in enumerate([(-1, -1), (1, -1), (1, 1), (-1, 1)]):
                local[k, u_ax], local[k, v_ax] = a * h[u_ax], b * h[v_ax]
            c = center + local @ r.T
            n = sign * r[:, axis]
            if np.dot(np.cross(c[1] - c[0], c[3] - c[0]), n) < 0:
                c = c[[0, 3, 2, 1]]
            quads.append(Quad(f"{name}.{'xyz'[axis]}{'-+'[sign > 0]}", c, n, albedo, np.zeros(3), role))
    return quads


def quad_primitive(name: str, corners: np.ndarray, normal: np.ndarray, albedo: np.ndarray, emission: np.ndarray,
                   role: str, texture: np.ndarray | None = None, declared_emitter: bool = False,
                   opening: bool = False) -> Quad:
    """A quad primitive as the engine's one-sided Quad: corners reordered (and the texture
    transposed with them) so that (c1-c0)x(c3-c0) points to the lit side `normal`."""
    corners = np.asarray(corners, np.float64)
    normal = np.asarray(normal, np.float64)
    normal = normal / max(np.linalg.norm(normal), 1e-12)
    if np.dot(np.cross(corners[1] - corners[0], corners[3] - corners[0]), normal) < 0:
        corners = corners[[0, 3, 2, 1]]
        texture = None if texture is None else texture.transpose(1, 0, 2)
    return Quad(name, corners, normal, albedo, emission, role, texture, declared_emitter, opening)


@dataclass
class PrimitiveSpec:
    """One entry of a "primitives" list (scene.json, a model file, `photoar reconstruct`'s
    primitives.json), validated; the schema is in recon/primitives.py's docstring. Units: metres."""
    name: str
    kind: str  # "box" | "quad"
    role: str  # default "furniture" for a box, "room" for a quad
    albedo: np.ndarray  # (3,) linear diffuse reflectance, default 0.5
    emitter: bool
    emitted_radiance: np.ndarray  # (3,), zero unless given
    center: np.ndarray | None = None  # box: (3,)
    size: np.ndarray | None = None  # box: (3,) positive full extents along its own axes
    yaw_deg: float = 0.0  # box: turn about +Y, degrees
    corners: np.ndarray | None = None  # quad: (4,3) c0..c3
    normal: np.ndarray | None = None  # quad: (3,) unit lit side; None = as (c1-c0)x(c3-c0)
    texture: str | None = None  # quad: 'albedo_texture', relative to the file's folder
    opening: bool = False  # quad: "opening": true, a hole in its wall (sky and sun come through)
    raw: dict = field(default_factory=dict)  # the JSON object it was parsed from (which keys were given)

    @property
    def quad_normal(self) -> np.ndarray:
        """Quad: the lit side, given or (c1-c0)x(c3-c0), unit."""
        c = self.corners
        n = self.normal if self.normal is not None else np.cross(c[1] - c[0], c[3] - c[0])
        return n / max(np.linalg.norm(n), 1e-12)


def parse_primitive(p, where: str, path: str | os.PathLike) -> PrimitiveSpec:
    """Validate one primitive's JSON (`where` e.g. "primitives[3]"); SceneError naming the file and field."""
    if not isinstance(p, dict):
        raise SceneError(f"{path}: field '{where}' must be an object")
    kind = json_field(p, "type", where + ".", path)
    if kind not in ("box", "quad"):
        raise SceneError(f"{path}: field '{where}.type' must be 'box' or 'quad', got {kind!r}")
    spec = PrimitiveSpec(str(p.get("name", where)), kind, str(p.get("role", "furniture" if kind == "box" else "room")),
                         json_array(p.get("albedo", [0.5] * 3), (3,), f"{where}.albedo", path),
                         json_bool(p, "emitter", where + ".", path),
                         json_array(p.get("emitted_radiance", [0.0] * 3), (3,), f"{where}.emitted_radiance", path),
                         raw=p)
    if kind == "box":
        spec.center = json_array(json_field(p, "center", where + ".", path), (3,), f"{where}.center", path)
        spec.size = json_array(json_field(p, "size", where + ".", path), (3,), f"{where}.size", path)
        if np.any(spec.size <= 0):
            raise SceneError(f"{path}: field '{where}.size' must be positive")
        spec.yaw_deg = float(json_array(p.get("yaw_deg", 0.0), (), f"{where}.yaw_deg", path))
    else:
        spec.corners = json_array(json_field(p, "corners", where + ".", path), (4, 3), f"{where}.corners", path)
        if np.linalg.norm(np.cross(spec.corners[1] - spec.corners[0], spec.corners[3] - spec.corners[0])) < 1e-12:
            raise SceneError(f"{path}: field '{where}.corners' is degenerate (zero-length side or collinear)")
        if p.get("normal") is not None:
            n = json_array(p["normal"], (3,), f"{where}.normal", path)
            if not np.linalg.norm(n) > 1e-12:
                raise SceneError(f"{path}: field '{where}.normal' must not be zero")
            spec.normal = n / np.linalg.norm(n)
        if p.get("albedo_texture"):
            spec.texture = str(p["albedo_texture"])
        spec.opening = json_bool(p, "opening", where + ".", path)
    return spec


def parse_primitives(d, path: str | os.PathLike) -> list[PrimitiveSpec]:
    """The validated "primitives" list of a JSON object (non-empty)."""
    prims = json_field(d, "primitives", "", path)
    if not isinstance(prims, list) or not prims:
        raise SceneError(f"{path}: field 'primitives' must be a non-empty list")
    # the sun is a far disk outside the room (FORMAT.md), not a room primitive
    return [parse_primitive(p, f"primitives[{i}]", path) for i, p in enumerate(prims)
            if not (isinstance(p, dict) and p.get("type") == "sun")]


def load_scene(scene_dir: str | os.PathLike, load_textures: bool = True) -> Scene:
    """Read a benchmark scene folder (scene.json + photo + object mesh) into the scene model."""
    root = Path(scene_dir)
    path = root / "scene.json"
    if not root.is_dir():
        raise SceneError(f"{root}: scene folder not found")
    d = read_json(path, SceneError)
    if not isinstance(d, dict):
        raise SceneError(f"{path}: top level must be an object")

    world = json_field(d, "world", "", path)
    room_min = json_array(json_field(world, "room_min", "world.", path), (3,), "world.room_min", path)
    room_max = json_array(json_field(world, "room_max", "world.", path), (3,), "world.room_max", path)
    if np.any(room_max <= room_min):
        raise SceneError(f"{path}: field 'world.room_max' must exceed 'world.room_min'")

    cam = json_field(d, "main_camera", "", path)
    json_field(cam, "exposure_time", "main_camera.", path)  # never defaulted: a wrong exposure scales the object
    camera = Camera.from_json(cam, path, "main_camera.")
    width, height, exposure = camera.width, camera.height, camera.exposure_time

    response = None  # optional: captured light recovers it from the probe bracket
    if "camera_response" in d:
        resp = d["camera_response"]
        try:
            response = CameraResponse(json_field(resp, "forward_table", "camera_response.", path),
                                      json_field(resp, "inverse_table", "camera_response.", path), exposure)
        except ValueError as e:
            raise SceneError(f"{path}: field 'camera_response': {e}") from None

    quads: list[Quad] = []
    sun: Sun | None = None  # the sun entry (parse_primitives leaves it out: it is no room primitive)
    sun_declared_by = None
    found = sun_entry(d, path)
    if found is not None:
        i, p = found
        name = p.get("name")
        sun = parse_sun(p, f"primitives[{i}]" + (f" ({name!r})" if isinstance(name, str) and name else ""), path)
        sun_declared_by = p.get("declared_by")  # "user": from `photoar scene` (app.engine --sun auto)
    unknown_emitters: list[str] = []  # windows or lamps of unknown strength (photo light finds them)
    for p in parse_primitives(d, path):
        if p.emitter and "emitted_radiance" not in p.raw:
            unknown_emitters.append(p.name)
        if p.kind == "box":
            quads += box_quads(p.name, p.center, p.size, np.radians(p.yaw_deg), p.albedo, p.role, room_min, room_max)
        else:
            texture = None
            if load_textures and p.texture:
                texture = read_image_rgb(root / p.texture).astype(np.float32) / 255.0
            emission = p.emitted_radiance if p.emitter else np.zeros(3)
            quads.append(quad_primitive(p.name, p.corners, p.quad_normal, p.albedo, emission, p.role, texture,
                                        p.emitter, p.opening))

    obj = None
    if "synthetic_object" in d:
        so = d["synthetic_object"]
        M = json_array(json_field(so, "object_to_world", "synthetic_object.", path), (4, 4),
                       "synthetic_object.object_to_world", path)
        mesh_path = root / str(json_field(so, "mesh", "synthetic_object.", path))
        obj = make_object(mesh_path, M, json_array(so.get("albedo", [0.5] * 3), (3,), "synthetic_object.albedo", path))
        check_object_inside(obj, room_min, room_max, f"{path}: field 'synthetic_object.object_to_world'")

    files = cam.get("files", {}) if isinstance(cam.get("files", {}), dict) else {}
    photo = read_image_rgb(root / files.get("background_png", "background.png"))
    if photo.shape[:2] != (height, width):
        raise SceneError(f"{root / files.get('background_png', 'background.png')}: image is "
                         f"{photo.shape[1]}x{photo.shape[0]}, camera says {width}x{height}")
    return Scene(str(d.get("name", root.name)), root, camera, quads, obj, response, photo, room_min, room_max,
                 meta={"json_path": str(path), "emitters_without_radiance": unknown_emitters,
                       "sun_declared_by": sun_declared_by}, sun=sun)


def sun_entry(d: dict, path) -> tuple[int, dict] | None:
    """(index, entry) of the one `"type": "sun"` entry of d["primitives"] (a scene.json or primitives
    input), None without one; SceneError naming the file at a second one."""
    found = [(i, p) for i, p in enumerate(d.get("primitives") or []) if isinstance(p, dict) and p.get("type") == "sun"]
    if len(found) > 1:
        raise SceneError(f"{path}: field 'primitives[{found[1][0]}]': a second sun (only one 'sun' primitive is "
                         "allowed)")
    return found[0] if found else None


def parse_sun(p: dict, where: str, path: Path) -> Sun:
    """The `sun` primitive (FORMAT.md), validated: SceneError naming the file and field (`where`,
    e.g. "primitives[16] ('sun')"). `direction_to_sun` may be any finite non-zero vector: it is
    normalised (a hand-typed direction need not have length 1). With `"strength": "estimate"` (no
    irradiance_perpendicular) only the direction is given: Sun.strength_estimated, irradiance zero."""
    d = json_array(json_field(p, "direction_to_sun", where + ".", path), (3,), f"{where}.direction_to_sun", path)
    norm = float(np.linalg.norm(d))
    if not norm > 1e-9:
        raise SceneError(f"{path}: field '{where}.direction_to_sun' must not be the zero vector, got {d.tolist()}")
    diam = float(json_array(p.get("angular_diameter_deg", 0.53), (), f"{where}.angular_diameter_deg", path))
    if not 0.0 <= diam < 90.0:
        raise SceneError(f"{path}: field '{where}.angular_diameter_deg' must be in [0, 90) degrees, got {diam}")
    dist = float(json_array(p["distance_m"], (), f"{where}.distance_m", path)) \
        if p.get("distance_m") is not None else float("inf")
    if not dist > 0:
        raise SceneError(f"{path}: field '{where}.distance_m' must be positive, got {dist}")
    strength = p.get("strength", "declared")
    if strength not in ("declared", "estimate"):
        raise SceneError(f"{path}: field '{where}.strength' must be \"declared\" or \"estimate\", got {strength!r}")
    if strength == "estimate":  # the direction alone (e.g. from date, time and place): E from the photo
        if "irradiance_perpendicular" in p:
            raise SceneError(f"{path}: field '{where}.irradiance_perpendicular' is given but 'strength' is "
                             "\"estimate\": drop one")
        return Sun(d / norm, diam, np.zeros(3), np.zeros(3), dist, strength_estimated=True)
    E = json_array(json_field(p, "irradiance_perpendicular", where + ".", path), (3,),
                   f"{where}.irradiance_perpendicular", path)
    L = json_array(p.get("emitted_radiance", [0.0, 0.0, 0.0]), (3,), f"{where}.emitted_radiance", path)
    for key, v in (("irradiance_perpendicular", E), ("emitted_radiance", L)):
        if np.any(v < 0):
            raise SceneError(f"{path}: field '{where}.{key}' must be non-negative, got {v.tolist()}")
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
