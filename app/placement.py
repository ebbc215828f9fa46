"""Placement controller: put an object mesh into a scene's photo and recomposite on every change.

The interactive scenario of the seed (a user drops a furniture model into a photo of their room
and moves it while its shadows follow) with no GUI code, so the logic is tested headless;
app/gui.py is a thin view over it. DESIGN.md: "a thin view over a placement controller".

Pose model (world: metres, +Y up, floor at y = 0):
  the object's pivot is the bottom centre of its mesh's bounding box (object coordinates);
  object_to_world = T(position + lift * Y) @ R_y(yaw) @ S(unit_scale * scale) @ T(-pivot)
  position (3,) is the point on the supporting surface the object rests on; lift (m) raises it
  off that surface; yaw (degrees) turns it counter-clockwise about +Y seen from above.

Picking casts the pixel's camera ray (recon.camera conventions: (u, v) with (0, 0) the centre of
the top-left pixel) against the scene model's quads (kernels.raycast). A hit on an upward
surface (floor, desk top) is the resting point; a hit on a wall or an emitter drops the object
straight down from just in front of that surface onto whatever is below.

Every edit is one undoable step; a drag is one step (begin_gesture / end_gesture). Frames come
from app.engine.Engine within the frame settings `config` (an app.engine.FrameConfig: pass budget,
None = all sources, and compositing mode), which set_budget replaces whole and never edits, so a
frame and the key it is kept under always agree; frames of recent states are kept, so undo/redo
shows the earlier composite at once and bit for bit. At rest, `refine` adds the remaining
sources a slice of time per call until the all-sources frame of the pose (Engine.refine).
"""
from __future__ import annotations

import logging
import threading
import time
from collections import OrderedDict
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable

import numpy as np

from app.config import DRAG_PASSES as DRAG_FRAME_PASSES, DRAG_SCALE, DRAG_SHADOW

from recon.scene import Scene, SceneError, SceneObject, furniture_boxes, load_mesh, load_scene
from recon.io import read_json

log = logging.getLogger("photoar")

FORMAT = "photoar-placement"
VERSION = 1
MESH_SUFFIXES = (".ply", ".obj", ".glb", ".gltf", ".off", ".stl")
UP_COS = 0.7  # a surface whose normal has n_y above this is one an object can rest on
ROOM_MARGIN = 2e-3  # m kept between the object's bounding box and the room's walls
DRAG_PASSES = 50  # default pass budget of a frame while the object moves (refine() completes it at rest)


# ---------------------------------------------------------------------------- object meshes
@dataclass
class ObjectMesh:
    """An object mesh in its own coordinates, ready to pose.

    vertices (V,3), normals (V,3) unit, faces (F,3) int32, in model units; pivot (3,) bottom
    centre of the bounding box; unit_scale metres per model unit.
    """

    path: str
    vertices: np.ndarray
    normals: np.ndarray
    faces: np.ndarray
    pivot: np.ndarray
    unit_scale: float
    albedo: np.ndarray
    size_m: float | None = None  # requested largest extent (None: automatic)

    @property
    def extent_m(self) -> np.ndarray:
        """(3,) bounding-box size in metres at scale 1."""
        return (self.vertices.max(0) - self.vertices.min(0)) * self.unit_scale


def load_object_mesh(path: str | Path, size_m: float | None = None, albedo=None,
                     max_faces: int = 4000) -> ObjectMesh:
    """Load a PLY/OBJ/GLB mesh (Open3D) for placement.

    size_m: largest bounding-box extent in metres. None keeps the file's units when its largest
    extent lies in [0.05, 1.5] (scene objects are in metres; the bunny's scan units are metres)
    and otherwise scales it to 0.6 m (the teapot is 6.4 units wide). Meshes above `max_faces`
    triangles are decimated (quadric error, Open3D): the engine shades every vertex per frame.
    """
    from recon.io import open3d

    o3d = open3d()

    path = Path(path)
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise SceneError(f"{path}: not a mesh file (expected one of {', '.join(MESH_SUFFIXES)})")
    v, n, f = load_mesh(path)
    if len(f) > max_faces:
        m = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(v), o3d.utility.Vector3iVector(f))
        m = m.simplify_quadric_decimation(max_faces)
        m.remove_unreferenced_vertices()
        m.compute_vertex_normals()
        v, f = np.asarray(m.vertices, np.float64), np.asarray(m.triangles, np.int32)
        n = np.asarray(m.vertex_normals, np.float64)
        log.info("%s: decimated to %d triangles", path, len(f))
    lo, hi = v.min(0), v.max(0)
    extent = float((hi - lo).max())
    if not extent > 0:
        raise SceneError(f"{path}: mesh is degenerate (zero extent)")
    if size_m is not None:
        if not size_m > 0:
            raise ValueError(f"{path}: object size must be positive, got {size_m}")
        unit = size_m / extent
    else:
        unit = 1.0 if 0.05 <= extent <= 1.5 else 0.6 / extent
    pivot = np.array([(lo[0] + hi[0]) / 2, lo[1], (lo[2] + hi[2]) / 2])
    alb = np.full(3, 0.6) if albedo is None else np.asarray(albedo, np.float64).reshape(3)
    if np.any(alb < 0) or np.any(alb > 1):
        raise ValueError(f"{path}: albedo must lie in [0, 1], got {alb.tolist()}")
    return ObjectMesh(str(path.resolve()), v, n, f, pivot, unit, alb, size_m)


def _rot_y(deg: float) -> np.ndarray:
    a = np.radians(deg)
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


# ---------------------------------------------------------------------------- pose state
@dataclass(frozen=True)
class Pose:
    """What one undo step restores (hashable: it keys the frame cache)."""

    mesh: str | None = None  # resolved mesh path, None = no object
    position: tuple[float, float, float] = (0.0, 0.0, 0.0)  # m, resting point of the pivot
    yaw_deg: float = 0.0
    lift: float = 0.0  # m above the resting point
    scale: float = 1.0  # on top of the mesh's unit scale

    def matrix(self, om: ObjectMesh) -> np.ndarray:
        """object_to_world (4,4) for mesh `om`."""
        M = np.eye(4)
        M[:3, :3] = _rot_y(self.yaw_deg) * (om.unit_scale * self.scale)
        M[:3, 3] = np.asarray(self.position) + np.array([0.0, self.lift, 0.0]) - M[:3, :3] @ om.pivot
        return M


@dataclass
class Hit:
    """A pixel ray's first hit on the scene model."""

    point: np.ndarray  # (3,) m
    normal: np.ndarray  # (3,) unit, the surface's lit side
    surface: str  # quad name (floor, back, desk_top.y+, window...)
    distance: float  # m along the ray


@dataclass
class FrameResult:
    pixels: np.ndarray  # (H,W,3) uint8 composite
    radiance: np.ndarray  # (H,W,3) float32 composite radiance
    stats: dict = field(default_factory=dict)


# ---------------------------------------------------------------------------- controller
class PlacementController:
    """Scene + engine + one placed object, with undo/redo and JSON save/load.

    The engine (per-scene precompute, seconds to minutes uncached) is built by `start_engine`,
    which a GUI runs in a worker thread; picking and pose edits work before it is ready.
    """

    def __init__(self, scene: Scene, params=None, cache_dir: str | Path | None = None, quiet: bool = True,
                 frame_cache: int = 16, drag: int | None = None):
        """drag: frames while the object moves are drag frames, the room at 1/drag resolution each way
        (FrameConfig.drag, app.dragframe), when params gives a pass budget; None: at full resolution.
        With no params they always are (at app.config.DRAG_SCALE)."""
        from kernels.visibility import Occluder

        self.scene = scene
        self.params = params
        self.drag = DRAG_SCALE if params is None and drag is None else drag
        self.device: str | None = None  # Warp device of the engine (None: kernels.runtime's default)
        self.cache_dir = cache_dir
        self.quiet = quiet
        self.engine = None
        self._config = None  # FrameConfig of the next frames (None: from params; see `config`)
        self.meshes: dict[str, ObjectMesh] = {}
        self.pose = Pose()
        self.undo_stack: list[Pose] = []
        self.redo_stack: list[Pose] = []
        self._gesture: Pose | None = None
        self._frames: OrderedDict = OrderedDict()
        self._frame_cache = frame_cache
        self._lock = threading.RLock()
        self.on_change: Callable[[Pose], None] | None = None
        # the scene model as two triangles per quad, for picking
        corners = np.array([q.corners for q in scene.quads], np.float64)
        tris = np.concatenate([[4 * i, 4 * i + 1, 4 * i + 2, 4 * i, 4 * i + 2, 4 * i + 3]
                               for i in range(len(corners))]).reshape(-1, 3).astype(np.int32)
        self._quad_occ = Occluder(corners.reshape(-1, 3), tris)
        self._quad_normals = np.array([q.normal for q in scene.quads], np.float64)

    # ------------------------------------------------------------------ construction
    @classmethod
    def open(cls, path: str | Path, params=None, cache_dir: str | Path | None = None,
             quiet: bool = True, work_res: int | None = None, drag: int | None = None) -> "PlacementController":
        """A benchmark scene folder, or a saved placement JSON (which names its scene folder);
        work_res: preview at most this many pixels on the photo's long side (app.workres); drag: as
        the constructor's."""
        from app.workres import working_scene

        path = Path(path)
        if path.is_file() and path.suffix.lower() == ".json" and path.name != "scene.json":
            data = _read_placement(path)
            ctl = cls(working_scene(load_scene(data["scene"]), work_res), params, cache_dir, quiet, drag=drag)
            ctl._apply_saved(data, path)
            return ctl
        if path.is_file() and path.name == "scene.json":
            path = path.parent
        return cls(working_scene(load_scene(path), work_res), params, cache_dir, quiet, drag=drag)

    def start_engine(self, params=None, progress=None):
        """Build the engine (precompute, cached under cache_dir); returns it. progress: callable(done,
        total) during the precompute (app.engine.Engine)."""
        from app.engine import Engine, EngineParams

        started = self.params
        own = params is None  # built from the controller's params, which set_lighting may replace meanwhile
        params = params or self.params or EngineParams(passes=DRAG_PASSES)
        eng = Engine(self.scene, params, cache_dir=self.cache_dir, device=self.device, quiet=self.quiet,
                     progress=progress)
        with self._lock:
            if own and self.params is not started:
                return eng  # set_lighting ran meanwhile: this engine is not the controller's
            self.engine = eng
            self.params = eng.params
            if self._config is None:
                self._config = self._frame_config(eng.params)
        return eng

    def prepare_drag(self) -> None:
        """Build the drag frame's per-scene stages of the engine now (app.dragframe.DragStages, or the sphere
        frame's data), not on the first drag frame: the GUI calls it once the engine is ready."""
        from app.dragframe import sphere_stages, uses_spheres

        with self._lock:
            eng, cfg = self.engine, self.config
        if eng is None or cfg.drag is None:
            return
        if uses_spheres(eng, cfg):
            sphere_stages(eng, cfg.drag)
        else:
            eng.pixel_stages(cfg.drag)

    def set_lighting(self, lighting: str) -> bool:
        """Light the room another way (a key of app.engine.LIGHTING). The engine is per lighting: when
        it changes, the engine and the kept frames are dropped and start_engine must run again
        (the precompute, cached per lighting). Returns whether it changed."""
        from app.engine import LIGHTING, EngineParams

        if lighting not in LIGHTING:
            raise ValueError(f"lighting must be one of {sorted(LIGHTING)}, got {lighting!r}")
        with self._lock:
            old = self.params.lighting if self.params is not None else EngineParams().lighting
            if lighting == old:
                return False
            p = self.params or EngineParams(passes=self.config.passes)
            # --sun estimate / declared choose between captured light's two suns; other lightings take auto
            self.params = replace(p, lighting=lighting, sun=p.sun if lighting == "captured" else "auto")
            self.engine = None
            self._frames.clear()
        return True

    @property
    def lighting(self) -> str:
        from app.engine import EngineParams

        return (self.params or EngineParams()).lighting

    # ------------------------------------------------------------------ object choice
    def object_choices(self, extra_dirs: list[str | Path] = ()) -> list[str]:
        """Mesh files offered to the user: the scene's own object, meshes in its folder, then
        meshes in `extra_dirs` (resolved paths, no duplicates)."""
        out: list[str] = []
        if self.scene.obj is not None and self.scene.obj.source:
            out.append(str(Path(self.scene.obj.source).resolve()))
        for d in [self.scene.root, *extra_dirs]:
            d = Path(d)
            if d.is_dir():
                for p in sorted(d.iterdir()):
                    if p.suffix.lower() in MESH_SUFFIXES and str(p.resolve()) not in out:
                        out.append(str(p.resolve()))
        return out

    def load_mesh(self, path: str | Path, size_m: float | None = None, albedo=None,
                  max_faces: int = 4000) -> ObjectMesh:
        """Load (once) the mesh at `path`; the scene's own object keeps its albedo. Meshes above
        `max_faces` are decimated (load_object_mesh; `photoar composite` keeps them whole)."""
        key = str(Path(path).resolve())
        if key not in self.meshes or (size_m is not None and self.meshes[key].size_m != size_m):
            if albedo is None and self.scene.obj is not None and \
                    Path(self.scene.obj.source).resolve() == Path(key):
                albedo = self.scene.obj.albedo
            self.meshes[key] = load_object_mesh(key, size_m, albedo, max_faces)
        return self.meshes[key]

    def set_object(self, path: str | Path, size_m: float | None = None, albedo=None) -> Pose:
        """Swap the placed mesh (keeping the pose; a fresh scene puts it where the scene's object
        stands, or in the middle of the floor in view)."""
        om = self.load_mesh(path, size_m, albedo)
        pose = self.pose
        if pose.mesh is None:
            pose = replace(pose, position=tuple(self._default_position()))
        return self._commit(self._fit(replace(pose, mesh=om.path), om))

    def _default_position(self) -> np.ndarray:
        if self.scene.obj is not None:
            M = self.scene.obj.object_to_world
            v = self.scene.obj.vertices
            return np.array([M[0, 3], v[:, 1].min(), M[2, 3]])
        cam = self.scene.camera
        hit = self.pick(cam.width / 2 - 0.5, cam.height * 0.75)
        return self._support_point(hit, 0.5) if hit is not None else (self.scene.room_min + self.scene.room_max) / 2

    # ------------------------------------------------------------------ picking
    def pixel_ray(self, u: float, v: float) -> np.ndarray:
        """Unit world direction (3,) of the camera ray through pixel (u, v)."""
        cam = self.scene.camera
        d = cam.R.T @ np.linalg.solve(cam.K, np.array([u, v, 1.0]))
        return d / np.linalg.norm(d)

    def cast(self, origin: np.ndarray, direction: np.ndarray) -> Hit | None:
        """First scene-model quad hit from `origin` along unit `direction` (None: no hit)."""
        from kernels.raycast import cast_rays

        tri, _, depth = cast_rays(self._quad_occ, np.asarray(origin, np.float64),
                                  np.asarray(direction, np.float64).reshape(1, 3))
        if tri[0] < 0:
            return None
        q = int(tri[0]) // 2
        # intersect the quad's plane in float64 (the kernel works in float32)
        nrm = self._quad_normals[q]
        c0 = self.scene.quads[q].corners[0]
        denom = float(np.dot(nrm, direction))
        t = float(np.dot(nrm, c0 - origin) / denom) if abs(denom) > 1e-12 else float(depth[0])
        return Hit(np.asarray(origin) + t * np.asarray(direction), nrm.copy(), self.scene.quads[q].name, t)

    def pick(self, u: float, v: float) -> Hit | None:
        """The scene surface seen at pixel (u, v), or None (outside the model)."""
        return self.cast(self.scene.camera.centre, self.pixel_ray(u, v))

    def _support_point(self, hit: Hit, reach: float) -> np.ndarray:
        """Where an object clicked at `hit` rests (its pivot): the hit itself on an upward
        surface; otherwise the surface below the point `reach` + 1 cm in front of the hit surface
        (reach: how far the object extends from its pivot towards that surface, m)."""
        if hit.normal[1] > UP_COS:
            return hit.point
        n_h = np.array([hit.normal[0], 0.0, hit.normal[2]])
        n_h = n_h / np.linalg.norm(n_h) if np.linalg.norm(n_h) > 1e-9 else np.zeros(3)  # ceiling: straight down
        start = hit.point + n_h * (reach + 0.01)
        start[1] = min(hit.point[1], self.scene.room_max[1] - 1e-3)
        below = self.cast(start, np.array([0.0, -1.0, 0.0]))
        if below is None or below.normal[1] <= UP_COS:
            return np.array([start[0], self.scene.room_min[1], start[2]])
        return below.point

    # ------------------------------------------------------------------ edits
    def place_at_pixel(self, u: float, v: float) -> Pose:
        """Rest the object on the surface seen at pixel (u, v)."""
        om = self._current_mesh()
        hit = self.pick(u, v)
        if hit is None:
            raise ValueError(f"pixel ({u:.1f}, {v:.1f}) sees no surface of the scene model")
        pose = replace(self.pose, position=(0.0, 0.0, 0.0), lift=0.0)
        reach = float(np.max(-self._world_vertices(pose, om) @ hit.normal * np.array(1.0)))
        pos = self._support_point(hit, max(reach, 0.0))
        return self._commit(self._fit(replace(self.pose, position=tuple(pos), lift=0.0), om))

    def place_at(self, point) -> Pose:
        """Put the object's pivot (bottom centre) at world `point` (3,), metres, as given."""
        p = np.asarray(point, np.float64).reshape(3)
        if not np.all(np.isfinite(p)):
            raise ValueError(f"placement point must be finite, got {p.tolist()}")
        om = self._current_mesh()
        return self._commit(self._fit(replace(self.pose, position=tuple(p), lift=0.0), om))

    def move_to_pixel(self, u: float, v: float) -> Pose:
        """Slide the object on its resting plane (y of its resting point) to under pixel (u, v)."""
        om = self._current_mesh()
        c = self.scene.camera.centre
        d = self.pixel_ray(u, v)
        y = self.pose.position[1]
        if abs(d[1]) < 1e-9 or (y - c[1]) / d[1] <= 0:
            return self.pose  # the ray never meets the resting plane in front of the camera
        p = c + d * (y - c[1]) / d[1]
        return self._commit(self._fit(replace(self.pose, position=(p[0], y, p[2])), om))

    def move_by(self, dx: float, dz: float) -> Pose:
        """Slide the object by (dx, dz) metres on its resting plane."""
        x, y, z = self.pose.position
        return self._commit(self._fit(replace(self.pose, position=(x + dx, y, z + dz)), self._current_mesh()))

    def rotate(self, deg: float) -> Pose:
        """Turn about +Y by `deg` degrees (counter-clockwise seen from above)."""
        yaw = (self.pose.yaw_deg + deg + 180.0) % 360.0 - 180.0
        return self._commit(self._fit(replace(self.pose, yaw_deg=yaw), self._current_mesh()))

    def lift_by(self, dy: float) -> Pose:
        """Raise (dy > 0) or lower the object above its resting point; never below it."""
        return self._commit(self._fit(replace(self.pose, lift=max(0.0, self.pose.lift + dy)), self._current_mesh()))

    def scale_by(self, factor: float) -> Pose:
        if not factor > 0:
            raise ValueError(f"scale factor must be positive, got {factor}")
        return self._commit(self._fit(replace(self.pose, scale=self.pose.scale * factor), self._current_mesh()))

    def begin_gesture(self) -> None:
        """Start a drag: the edits until end_gesture form one undo step."""
        self._gesture = self.pose

    def end_gesture(self) -> None:
        start, self._gesture = self._gesture, None
        if start is not None and start != self.pose:
            self.undo_stack.append(start)
            self.redo_stack.clear()

    def undo(self) -> bool:
        if not self.undo_stack:
            return False
        self.redo_stack.append(self.pose)
        self._set(self.undo_stack.pop())
        return True

    def redo(self) -> bool:
        if not self.redo_stack:
            return False
        self.undo_stack.append(self.pose)
        self._set(self.redo_stack.pop())
        return True

    def _current_mesh(self) -> ObjectMesh:
        if self.pose.mesh is None:
            raise ValueError("no object chosen: call set_object(mesh) first")
        return self.meshes[self.pose.mesh]

    def _fit(self, pose: Pose, om: ObjectMesh) -> Pose:
        """Keep the object inside the room: slide it off walls and below the ceiling."""
        rm, rM = self.scene.room_min + ROOM_MARGIN, self.scene.room_max - ROOM_MARGIN
        v = self._world_vertices(pose, om)
        lo, hi = v.min(0), v.max(0)
        if np.any(hi - lo > rM - rm):
            raise ValueError(f"{om.path}: object ({np.round(hi - lo, 2).tolist()} m) is larger than the room")
        shift = np.maximum(rm - lo, 0.0) + np.minimum(rM - hi, 0.0)
        x, y, z = pose.position
        return replace(pose, position=(float(x + shift[0]), float(y), float(z + shift[2])),
                       lift=float(pose.lift + min(shift[1], 0.0)), yaw_deg=float(pose.yaw_deg), scale=float(pose.scale))

    def _commit(self, pose: Pose) -> Pose:
        if pose != self.pose:
            if self._gesture is None:
                self.undo_stack.append(self.pose)
                self.redo_stack.clear()
            self._set(pose)
        return self.pose

    def _set(self, pose: Pose) -> None:
        with self._lock:
            self.pose = pose
        if self.on_change is not None:
            self.on_change(pose)

    # ------------------------------------------------------------------ the placed object
    @staticmethod
    def _world_vertices(pose: Pose, om: ObjectMesh) -> np.ndarray:
        M = pose.matrix(om)
        return om.vertices @ M[:3, :3].T + M[:3, 3]

    def scene_object(self, pose: Pose | None = None) -> SceneObject | None:
        """The posed object in world coordinates (None when no object is chosen)."""
        pose = self.pose if pose is None else pose
        if pose.mesh is None:
            return None
        om = self.meshes[pose.mesh]
        M = pose.matrix(om)
        v = om.vertices @ M[:3, :3].T + M[:3, 3]
        n = om.normals @ _rot_y(pose.yaw_deg).T  # uniform scale: normals only turn
        return SceneObject(v, n, om.faces, om.albedo, M, om.path)

    def collides(self, pose: Pose | None = None) -> bool:
        """Does the object's bounding box overlap a furniture box by more than 1 mm?
        (Conservative: a chair tucked under a desk counts.)"""
        obj = self.scene_object(pose)
        if obj is None:
            return False
        lo, hi = obj.vertices.min(0), obj.vertices.max(0)
        return any(bool(np.all((lo < b_hi - 1e-3) & (hi > b_lo + 1e-3))) for b_lo, b_hi in furniture_boxes(self.scene))

    # ------------------------------------------------------------------ frames
    @property
    def config(self):
        """The FrameConfig of the next frames (frozen; set_budget replaces it)."""
        with self._lock:
            if self._config is None:
                self._config = self._frame_config(self.params)
            return self._config

    def _frame_config(self, p):
        """The FrameConfig of params `p` (None: no settings given): frames while the object moves are drag
        frames (app.dragframe) at 1/self.drag when there is a pass budget and self.drag is set."""
        from app.engine import FrameConfig

        if p is None:
            return FrameConfig(DRAG_FRAME_PASSES, "hdr", drag=self.drag, drag_shadow=DRAG_SHADOW)
        drag = self.drag if p.passes is not None else None
        return FrameConfig(p.passes, p.mode, p.fps, drag=drag, drag_shadow=DRAG_SHADOW)

    @property
    def passes(self) -> int | None:
        return self.config.passes

    def set_budget(self, passes: int | None | str = "keep", mode: str | None = None) -> None:
        """Shadow passes per frame (None: one per source; "keep": unchanged) and compositing mode
        ('hdr' | 'ldr'; None: unchanged)."""
        if passes != "keep" and passes is not None and (not isinstance(passes, int) or passes < 1):
            raise ValueError(f"passes must be at least 1, got {passes}")
        if mode is not None and mode not in ("hdr", "ldr"):
            raise ValueError(f"mode must be 'hdr' or 'ldr', got {mode!r}")
        with self._lock:  # a new FrameConfig: a frame already running keeps the one it was given
            cfg = self.config
            passes = cfg.passes if passes == "keep" else passes
            # all sources: at full resolution; a pass budget: the drag frame's scale, if any
            drag = None if passes is None else (cfg.drag or self.drag)
            self._config = replace(cfg, passes=passes, mode=mode or cfg.mode, drag=drag)

    def render(self, pose: Pose | None = None, stop: Callable[[], bool] | None = None) -> FrameResult | None:
        """Composite `pose` (default: the current one) through the engine.

        stats: frame_s (this call), engine_s (the engine's own figure, 0 for a kept frame),
        passes, mode, cached. stop: Engine.render's (asked between the frame's steps: True abandons
        it, returns None, keeps nothing). Raises RuntimeError before start_engine has finished.
        """
        t0 = time.perf_counter()
        with self._lock:
            eng = self.engine
            pose = self.pose if pose is None else pose
            if eng is None:
                raise RuntimeError(f"{self.scene.root}: the engine is not ready (precompute still running)")
            cfg = self.config
            key = (pose, cfg)
            kept = self._kept_frame(key, t0)
            if kept is not None:
                return kept
        obj = self.scene_object(pose)
        if obj is None:
            H, W = self.scene.camera.height, self.scene.camera.width
            rad = eng.receivers.L_b.reshape(H, W, 3).astype(np.float32)
            fr = FrameResult(self.scene.photo.copy(), rad, {"passes": 0, "engine_s": 0.0})
        else:
            f = eng.render(obj, cfg, stop)
            if f is None:
                return None
            fr = FrameResult(f.pixels, f.radiance, {"passes": f.stats["passes"], "engine_s": f.stats["frame_s"],
                                                    "timings": f.stats.get("timings", {})})
        fr.pixels.setflags(write=False)
        fr.radiance.setflags(write=False)
        fr.stats.update(mode=cfg.mode, budget=cfg.passes, converged=obj is None or (cfg.passes is None and cfg.fps is None))
        with self._lock:
            self._frames[key] = fr
            while len(self._frames) > self._frame_cache:
                self._frames.popitem(last=False)
        return FrameResult(fr.pixels, fr.radiance, {**fr.stats, "cached": False, "frame_s": time.perf_counter() - t0})

    def _kept_frame(self, key, t0: float) -> FrameResult | None:
        """The frame kept under `key` (pose, config), marked cached and timed from t0; None if not
        kept. Call with the lock held."""
        fr = self._frames.get(key)
        if fr is None:
            return None
        self._frames.move_to_end(key)
        return FrameResult(fr.pixels, fr.radiance, {**fr.stats, "cached": True, "frame_s": time.perf_counter() - t0})

    def refine(self, pose: Pose | None = None, budget_s: float | None = None,
               intermediate: bool = False, stop: Callable[[], bool] | None = None) -> FrameResult | None:
        """At rest: advance the all-sources frame of `pose` (default: the current one) for about
        `budget_s` seconds (None: to the end) and return it once every source is in, else None.
        intermediate: also return Engine.refine's intermediate frames as they come (converged
        False; the drag budget sets them, Engine.refine_schedule). The finished frame is kept like
        any other (budget None), so later calls return it at once. stop: Engine.refine's (checked
        between steps: True returns None at once). stats as render's, with
        converged True and engine_s the refinement's compute time."""
        t0 = time.perf_counter()
        with self._lock:
            eng = self.engine
            pose = self.pose if pose is None else pose
            if eng is None:
                raise RuntimeError(f"{self.scene.root}: the engine is not ready (precompute still running)")
            cfg = replace(self.config, passes=None, fps=None, drag=None)
            key = (pose, cfg)
            kept = self._kept_frame(key, t0)
            if kept is not None:
                return kept
        obj = self.scene_object(pose)
        if obj is None:  # the photo itself: nothing to refine
            return self.render(pose)
        at_rest = replace(self.config, fps=None, drag=None,  # full resolution; the drag budget sets the frames
                          passes=DRAG_PASSES if self.config.drag else self.config.passes)
        f = eng.refine(obj, at_rest, budget_s, stop)
        if f is None or not (f.stats["exact"] or intermediate):
            return None
        fr = FrameResult(f.pixels, f.radiance, {"passes": f.stats["passes"], "engine_s": f.stats["refine_s"],
                                                "timings": f.stats.get("timings", {}), "mode": cfg.mode,
                                                "budget": None, "converged": bool(f.stats["exact"])})
        fr.pixels.setflags(write=False)
        fr.radiance.setflags(write=False)
        if not f.stats["exact"]:  # an intermediate frame: shown, not kept
            return FrameResult(fr.pixels, fr.radiance, {**fr.stats, "cached": False,
                                                        "frame_s": time.perf_counter() - t0})
        with self._lock:
            self._frames[key] = fr
            while len(self._frames) > self._frame_cache:
                self._frames.popitem(last=False)
        return FrameResult(fr.pixels, fr.radiance, {**fr.stats, "cached": False, "frame_s": time.perf_counter() - t0})

    def clear_frames(self) -> None:
        """Forget kept frames (the next render of every pose runs the engine)."""
        with self._lock:
            self._frames.clear()

    # ------------------------------------------------------------------ save / load
    def to_dict(self) -> dict:
        pose = self.pose
        d: dict = {"format": FORMAT, "version": VERSION, "scene": str(Path(self.scene.root).resolve()),
                   "object": None}
        if pose.mesh is not None:
            om = self.meshes[pose.mesh]
            d["object"] = {"mesh": om.path, "size_m": om.size_m, "albedo": om.albedo.tolist(),
                           "position": list(pose.position), "yaw_deg": pose.yaw_deg, "lift": pose.lift,
                           "scale": pose.scale, "object_to_world": pose.matrix(om).tolist()}
        if self.params is not None or self._config is not None:
            d["engine"] = {"passes": self.config.passes, "mode": self.config.mode}
        return d

    def save(self, path: str | Path) -> Path:
        """Write the placement as JSON atomically (a temporary file renamed over `path`)."""
        from recon.io import write_json

        path = Path(path)
        write_json(path, self.to_dict())
        return path

    def load(self, path: str | Path) -> Pose:
        """Apply a saved placement of this scene (one undo step)."""
        path = Path(path)
        data = _read_placement(path)
        if Path(data["scene"]).resolve() != Path(self.scene.root).resolve():
            log.warning("%s: placement was saved for %s, applying it to %s", path, data["scene"], self.scene.root)
        return self._apply_saved(data, path)

    def _apply_saved(self, data: dict, path: Path) -> Pose:
        o = data.get("object")
        if o is None:
            return self._commit(Pose())
        mesh = Path(o["mesh"])
        if not mesh.is_absolute():
            mesh = path.parent / mesh
        om = self.load_mesh(mesh, o.get("size_m"), o.get("albedo"))
        pose = Pose(om.path, tuple(float(x) for x in o["position"]), float(o.get("yaw_deg", 0.0)),
                    float(o.get("lift", 0.0)), float(o.get("scale", 1.0)))
        if "engine" in data:
            e = data["engine"]
            self.set_budget(e.get("passes", "keep"), e.get("mode"))
        return self._commit(self._fit(pose, om))


def _read_placement(path: Path) -> dict:
    """Parse and check a placement JSON; SceneError 'file: field: problem' on bad input."""
    data = read_json(path, SceneError)
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise SceneError(f"{path}: field 'format' must be {FORMAT!r}")
    if data.get("version") != VERSION:
        raise SceneError(f"{path}: field 'version': unsupported {data.get('version')!r} (expected {VERSION})")
    if not isinstance(data.get("scene"), str):
        raise SceneError(f"{path}: missing field 'scene'")
    o = data.get("object")
    if o is not None:
        if not isinstance(o, dict) or not isinstance(o.get("mesh"), str):
            raise SceneError(f"{path}: field 'object.mesh' must be a path")
        try:
            pos = np.asarray(o.get("position"), np.float64)
            ok = pos.shape == (3,) and np.all(np.isfinite(pos))
            for k in ("yaw_deg", "lift", "scale"):
                ok = ok and np.isfinite(float(o.get(k, 0.0)))
            ok = ok and float(o.get("scale", 1.0)) > 0
        except (TypeError, ValueError):
            ok = False
        if not ok:
            raise SceneError(f"{path}: field 'object': position must be 3 finite numbers, yaw_deg/lift finite, "
                             f"scale positive")
    e = data.get("engine")
    if e is not None and (not isinstance(e, dict) or e.get("mode", "hdr") not in ("hdr", "ldr")
                          or not (e.get("passes") is None or (isinstance(e["passes"], int) and e["passes"] >= 1))):
        raise SceneError(f"{path}: field 'engine': passes must be null or a positive integer, mode 'hdr' or 'ldr'")
    return data


__all__ = ["PlacementController", "Pose", "Hit", "ObjectMesh", "FrameResult", "load_object_mesh"]
