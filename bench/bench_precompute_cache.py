"""Engine construction cold and warm: what the per-scene artefact cache saves (app.stages.precompute).

usage: python bench/bench_precompute_cache.py [--shared ../shared] [--scenes window_room lamps_room] [--warm 2]

Per scene: one Engine on an empty cache folder (cold: the transfers, the shaft hierarchy and the SH
volume are built and written), then --warm more on the same folder (warm: all three read back).
Prints the seconds of each construction, the artefacts built (n_precompute) and read
(n_cache_loads), and the shaft hierarchy's build-or-read seconds. Warp kernels are compiled before
the cold engine (a throw-away engine on the bundled demo scene), so cold is the precompute only.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.cli import demo_scene_dir  # noqa: E402
from app.engine import Engine, EngineParams  # noqa: E402
from app.report import table  # noqa: E402
from bench import shared_scenes  # noqa: E402
from recon.scene import load_scene  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shared", type=Path, default=ROOT.parent / "shared")
    ap.add_argument("--scenes", nargs="+", default=["window_room", "lamps_room"])
    ap.add_argument("--warm", type=int, default=2, help="warm constructions after the cold one (default %(default)s)")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:  # compile the kernels outside the timings
        Engine(load_scene(demo_scene_dir()), EngineParams(patch_size=0.5), cache_dir=tmp, quiet=True)
    rows = []
    for name, scene_dir in shared_scenes(a.shared, a.scenes):
        scene = load_scene(scene_dir)
        with tempfile.TemporaryDirectory() as cache:
            for k in range(1 + a.warm):
                t0 = time.perf_counter()
                eng = Engine(scene, EngineParams(), cache_dir=cache, quiet=True)
                rows.append({"scene": name, "run": "cold" if k == 0 else f"warm {k}",
                             "engine_s": time.perf_counter() - t0, "built": eng.n_precompute,
                             "read": eng.n_cache_loads, "shafts_s": eng.seconds["shafts"]})
                print(table(rows[-1:], list(rows[-1])), flush=True)
    print(table(rows, list(rows[0])) if rows else "no scenes")
    return 0


if __name__ == "__main__":
    sys.exit(main())
