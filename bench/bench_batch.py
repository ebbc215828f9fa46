"""`photoar batch` throughput: composites per minute with 1 and 2 Dask workers, and the share of
worker time spent in the rooms' precompute against the frames.

usage: python bench/bench_batch.py [--shared ../shared] [--scenes window_room lamps_room]
                                   [--products 3] [--workers 1 2] [--passes N]

Per worker count: a fresh precompute cache (every room's precompute is computed once, as in a
first batch over new rooms), a jobs file of --products poses of each scene's own object (its
scene.json pose moved by up to 0.3 m and turned), `photoar batch` on a local cluster of that many
workers. Prints the wall seconds (cluster start to report), composites per minute, the worker
seconds of the rooms' warm tasks (precompute) and of the jobs (a frame each, with loading the
scene and writing the outputs), and the precompute's share of their sum. The machine's load
average is printed too: the figures are only as quiet as the machine.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.cmd_batch import run_batch  # noqa: E402
from app.report import table  # noqa: E402
from bench import shared_scenes  # noqa: E402

OFFSETS = [(0.0, 0.0, 0.0), (0.3, 0.0, 30.0), (-0.3, 0.2, 60.0), (0.2, -0.3, 90.0), (-0.2, -0.2, 120.0)]


def write_jobs(path: Path, scenes: list[tuple[str, Path]], products: int, passes: int | None) -> int:
    """`products` jobs per scene: its own object at its scene.json position moved by OFFSETS (dx,
    dz metres, yaw degrees). Returns the number of jobs."""
    lines = []
    for name, scene_dir in scenes:
        obj = json.loads((scene_dir / "scene.json").read_text())["synthetic_object"]
        lo, hi = obj["world_bbox_min"], obj["world_bbox_max"]
        cx, cz = (lo[0] + hi[0]) / 2, (lo[2] + hi[2]) / 2
        for k in range(products):
            dx, dz, yaw = OFFSETS[k % len(OFFSETS)]
            opts = {"place": [round(cx + dx, 3), lo[1], round(cz + dz, 3)], "yaw": yaw}
            if passes is not None:
                opts["passes"] = passes
            lines.append(json.dumps({"id": f"{name}-{k}", "scene": str(scene_dir), "options": opts}))
    path.write_text("\n".join(lines) + "\n")
    return len(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shared", type=Path, default=ROOT.parent / "shared")
    ap.add_argument("--scenes", nargs="+", default=["window_room", "lamps_room"])
    ap.add_argument("--products", type=int, default=3, help="jobs per scene (default %(default)s)")
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--passes", type=int, default=None, help="shadow passes per frame (default: all sources)")
    a = ap.parse_args()
    scenes = list(shared_scenes(a.shared, a.scenes))
    rows = []
    for n in a.workers:
        with tempfile.TemporaryDirectory() as tmp:
            tmp = Path(tmp)
            n_jobs = write_jobs(tmp / "jobs.jsonl", scenes, a.products, a.passes)
            t0 = time.perf_counter()
            rep = run_batch(tmp / "jobs.jsonl", tmp / "out", workers=n, cache=tmp / "cache", quiet=True)
            wall = time.perf_counter() - t0
            warm_s = sum(r.get("seconds", 0.0) for r in rep["rooms"])
            job_s = sum(j.get("seconds", 0.0) for j in rep["jobs"])
            frame_s = sum(j.get("frame_s") or 0.0 for j in rep["jobs"])
            rows.append({"workers": n, "jobs": n_jobs, "done": rep["done"], "failed": rep["failed"],
                         "wall_s": wall, "per_min": 60 * rep["done"] / wall, "warm_s": warm_s, "jobs_s": job_s,
                         "frames_s": frame_s, "precompute_share": warm_s / max(warm_s + job_s, 1e-9),
                         "load_avg": os.getloadavg()[0]})
            print(table(rows[-1:], list(rows[-1])), flush=True)
            for j in rep["jobs"]:
                if j["status"] == "failed":
                    print(f"  {j['id']}: {j['error']}")
    print(table(rows, list(rows[0])) if rows else "no scenes")
    return 0


if __name__ == "__main__":
    sys.exit(main())
