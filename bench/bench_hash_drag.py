"""SHA-256 of the drag path's frames (issue 36's byte-identical check for glue changes).

usage: python bench/bench_hash_drag.py [--scenes window_room,sun_room | DIR,...] [--path 4]

Per scene one Engine (the default precompute cache), evaluate's drag configuration (DRAG_PASSES, DRAG_SCALE,
DRAG_SHADOW) and the frames of app.dragpath's --path poses, each frame's composite pixels (uint8) hashed.
Prints one line per frame: scene, pose index, the first 16 hex digits. Compare the lines of two runs
(before / after a change); the scene-pose drag and all-sources composites come from `photoar evaluate`.
"""
from __future__ import annotations

import argparse
import dataclasses
import hashlib
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.composite import default_cache_dir  # noqa: E402
from app.dragpath import drag_offsets, moved  # noqa: E402
from app.engine import Engine, EngineParams  # noqa: E402
from app.evaluate import DRAG_PASSES, DRAG_SCALE, DRAG_SHADOW  # noqa: E402
from bench.bench_drag import scene_dir  # noqa: E402
from recon.scene import load_scene  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", default="window_room,sun_room")
    ap.add_argument("--path", type=int, default=4)
    args = ap.parse_args()
    for name in args.scenes.split(","):
        scene = load_scene(scene_dir(name))
        eng = Engine(scene, EngineParams(), cache_dir=default_cache_dir(), quiet=True)
        cfg = dataclasses.replace(eng.frame_config(), passes=DRAG_PASSES, drag=DRAG_SCALE, drag_shadow=DRAG_SHADOW)
        for i, o in enumerate(drag_offsets(scene, scene.obj, args.path)):
            fr = eng.render(moved(scene.obj, o), cfg)
            print(f"{Path(name).name} {i} {hashlib.sha256(fr.pixels.tobytes()).hexdigest()[:16]}", flush=True)


if __name__ == "__main__":
    main()
