"""`photoar composite`: insert a scene's synthetic object into its photo (the main pipeline).

Reads like the steps it runs: load the scene model, precompute (cached), render one frame,
write composite.png / composite.exr / report.json atomically into the output folder.
"""
from __future__ import annotations

import logging
import time
from pathlib import Path

from app.engine import Engine, EngineParams
from recon.io import AtomicOutput, write_exr, write_json, write_png
from recon.scene import SceneError, check_object_inside, load_scene, make_object

log = logging.getLogger("photoar")


def default_cache_dir() -> Path:
    import os

    return Path(os.environ.get("PHOTOAR_CACHE", Path.home() / ".cache" / "photoar"))


def main(scene_dir: str | Path, out: str | Path, params: EngineParams | None = None,
         cache_dir: str | Path | None = None, object_mesh: str | Path | None = None,
         quiet: bool = False) -> dict:
    """Composite the scene's object (or `object_mesh` at the scene's object pose) into its photo.

    Returns the report (also written as out/report.json).
    """
    params = params or EngineParams()
    t0 = time.perf_counter()
    scene = load_scene(scene_dir)
    if object_mesh is not None:
        if scene.obj is None:
            raise SceneError(f"{Path(scene_dir) / 'scene.json'}: no 'synthetic_object' pose for {object_mesh}")
        scene.obj = make_object(Path(object_mesh), scene.obj.object_to_world, scene.obj.albedo)
        check_object_inside(scene.obj, scene.room_min, scene.room_max, f"{object_mesh}: placed object")
    if scene.obj is None:
        raise SceneError(f"{Path(scene_dir) / 'scene.json'}: missing field 'synthetic_object'")
    load_s = time.perf_counter() - t0
    engine = Engine(scene, params, cache_dir=cache_dir if cache_dir is not None else default_cache_dir(),
                    quiet=quiet)
    frame = engine.render(scene.obj)
    report = {
        "scene": str(scene_dir),
        "load_s": load_s,
        "precompute_s": engine.precompute_s,
        "precompute_cache_hit": engine.cache_hit,
        "precompute_uncached_s": engine.pre.seconds,
        **frame.stats,
        "lighting": params.lighting,
        "params": {k: getattr(params, k) for k in params.__dataclass_fields__},
    }
    if params.lighting == "captured":
        from lighting.radiance import RadianceMesh

        report["radiance_mesh"] = RadianceMesh(engine.pre.B[-1], engine.pre.albedo, engine.pre.origin).summary()
    if params.lighting == "photo":
        report["photo_light"] = engine.photo_light
    with AtomicOutput(out) as stage:
        write_png(stage / "composite.png", frame.pixels)
        write_exr(stage / "composite.exr", frame.radiance)
        write_json(stage / "report.json", report)
    log.info("wrote %s (precompute %.1f s, frame %.2f s, %d sources)", Path(out) / "composite.png",
             engine.precompute_s, frame.stats["frame_s"], frame.stats["n_sources"])
    return report
