"""`photoar composite`: insert a scene's synthetic object into its photo (the main pipeline).

Reads like the steps it runs: load the scene model, precompute (cached), render one frame,
write composite.png / composite.exr / report.json atomically into the output folder.
"""
from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Callable

from app.engine import Engine, EngineParams
from app.report import stages_ms
from app.workres import DEFAULT_WORK_RES, full_resolution, working_scene
from recon.io import AtomicOutput, write_exr, write_json, write_png
from recon.overlap import furniture_overlaps, push_words
from recon.scene import SceneError, SceneObject, check_object_inside, load_scene, make_object

log = logging.getLogger("photoar")

# An object may sink this far (m) into furniture without a warning: the room model's boxes are
# fitted to a photo, and an object resting on one may touch it within that.
FURNITURE_TOLERANCE_M = 0.01


def default_cache_dir() -> Path:
    import os

    return Path(os.environ.get("PHOTOAR_CACHE", Path.home() / ".cache" / "photoar"))


def place_object(scene, object_mesh=None, place=None, yaw: float = 0.0, object_size: float | None = None,
                 placement=None, albedo=None) -> SceneObject:
    """The object to composite, posed (see `main`); SceneError naming the file when there is none
    or it lies outside the room, one warning line for each piece of furniture its triangles cut into
    by more than FURNITURE_TOLERANCE_M (naming it and the depth)."""
    from app.placement import PlacementController, Pose

    json_path = Path(scene.root) / "scene.json"
    if placement is not None:
        if object_mesh is not None or place is not None:
            raise SceneError(f"{placement}: --placement brings its own mesh and pose; drop --object/--place")
        ctl = PlacementController(scene)
        ctl.load(placement)
        obj = ctl.scene_object()
        if obj is None:
            raise SceneError(f"{placement}: field 'object' is null (the placement holds no object)")
        where = f"{placement}: placed object"
    elif place is not None:
        mesh = object_mesh if object_mesh is not None else (scene.obj.source if scene.obj is not None else None)
        if mesh is None:
            raise SceneError(f"{json_path}: no 'synthetic_object' mesh for --place; give --object MESH")
        ctl = PlacementController(scene)
        om = ctl.load_mesh(mesh, object_size, albedo, max_faces=1 << 30)  # the composite keeps every face
        obj = ctl.scene_object(Pose(om.path, tuple(float(x) for x in place), float(yaw)))
        where = f"{mesh}: object at --place {list(place)} --yaw {yaw:g}"
    elif object_mesh is not None:
        if scene.obj is None:
            raise SceneError(f"{json_path}: no 'synthetic_object' pose for {object_mesh}; give --place X,Y,Z "
                             f"[--yaw DEG]")
        obj = make_object(Path(object_mesh), scene.obj.object_to_world,
                          scene.obj.albedo if albedo is None else albedo)
        where = f"{object_mesh}: placed object"
    elif scene.obj is None:
        raise SceneError(f"{json_path}: missing field 'synthetic_object'; give --object MESH --place X,Y,Z "
                         f"[--yaw DEG] or --placement FILE")
    else:
        return scene.obj
    check_object_inside(obj, scene.room_min, scene.room_max, where)
    for o in furniture_overlaps(obj.vertices, obj.faces, scene.quads, min_depth=FURNITURE_TOLERANCE_M):
        log.warning("%s: the object cuts %.1f cm into furniture '%s' (moving it %.1f cm %s clears it)", where,
                    100 * o.depth, o.name, 100 * o.depth, push_words(o.push))
    return obj


def main(scene_dir: str | Path, out: str | Path, params: EngineParams | None = None,
         cache_dir: str | Path | None = None, object_mesh: str | Path | None = None,
         quiet: bool = False, device: str | None = None, place=None, yaw: float = 0.0,
         object_size: float | None = None, placement: str | Path | None = None,
         work_res: int | None = None, object_albedo=None, make_engine: Callable[..., Engine] = Engine) -> dict:
    """Composite the scene's object (or `object_mesh`) into its photo.

    The object stands at, in order of preference: the saved GUI placement `placement`; `place`
    (the bottom centre of the mesh's bounding box, world metres) turned by `yaw` degrees about +Y,
    exactly as `photoar gui --place --yaw` (app.placement, mesh units as the GUI reads them,
    `object_size` its largest extent in metres); the scene's synthetic_object pose.
    `object_albedo` (3,) overrides the mesh's albedo. `work_res`: the long side (pixels) the engine
    works at, the composite is written at the photo's resolution (app.workres; default 1024, 0:
    the photo's own). `make_engine` builds the engine from (working scene, params, cache_dir=,
    device=, quiet=) as Engine does (`photoar batch` passes one that keeps engines in memory).
    Returns the report (also written as out/report.json).
    """
    params = params or EngineParams()
    t0 = time.perf_counter()
    scene = load_scene(scene_dir)
    scene.obj = place_object(scene, object_mesh, place, yaw, object_size, placement, object_albedo)
    load_s = time.perf_counter() - t0
    work = working_scene(scene, DEFAULT_WORK_RES if work_res is None else work_res)
    engine = make_engine(work, params, cache_dir=cache_dir if cache_dir is not None else default_cache_dir(),
                         device=device, quiet=quiet)
    frame = engine.render(scene.obj)
    pixels, radiance = frame.pixels, frame.radiance
    full_s = 0.0
    if work is not scene:
        t1 = time.perf_counter()
        pixels, radiance = full_resolution(engine, frame, scene)
        full_s = time.perf_counter() - t1
    report = {
        "scene": str(scene_dir),
        "load_s": load_s,
        "precompute_s": engine.precompute_s,
        "precompute_cache_hit": engine.cache_hit,
        "precompute_uncached_s": engine.pre.seconds,
        **frame.stats,
        "stages_ms": stages_ms(frame.stats),
        "resolution": [scene.camera.width, scene.camera.height],
        "working_resolution": [work.camera.width, work.camera.height],
        "full_resolution_s": full_s,
        "lighting": params.lighting,
        "params": {k: getattr(params, k) for k in params.__dataclass_fields__},
    }
    if params.lighting == "captured":
        from lighting.radiance import RadianceMesh

        report["radiance_mesh"] = RadianceMesh(engine.pre.B[-1], engine.pre.albedo, engine.pre.origin,
                                             engine.pre.emitter).summary()
    if params.lighting == "photo":
        report["photo_light"] = {**engine.photo_light,
                                 "emitter_scale_at_object": round(engine.object_shading.emitter_scale, 4)}
    with AtomicOutput(out) as stage:
        write_png(stage / "composite.png", pixels)
        write_exr(stage / "composite.exr", radiance)
        write_json(stage / "report.json", report)
    log.info("wrote %s (precompute %.1f s, frame %.2f s, %d sources)", Path(out) / "composite.png",
             engine.precompute_s, frame.stats["frame_s"], frame.stats["n_sources"])
    return report
