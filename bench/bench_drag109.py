"""Drag path A/B of the launch split's hand-off (issue 36, drag109): per room, one Engine and evaluate's drag path
(app.dragpath.drag_offsets, the first pose excluded), each pose rendered as a drag frame by every variant in turn (the
order reversed every other pose), in rounds, in one process: wall and process CPU per frame (mean / p95), and
whether every variant's frame at a pose has the same pixels (SHA-256). The all-sources frame at the scene's pose is
rendered by each variant too: its wall, and its pixels' hash (must be the same).

usage: python bench/bench_drag109.py [--scenes window_room,sun_room,DIR,...] [--variants pool,inline] [--path 30]
                                     [--rounds 2] [--out FILE.json]

Variants: `pool`, kernels.runtime.run_parallel as it is (every part on the pool while the caller waits); `inline`,
its last part on the calling thread (_run_inline; measured and not kept).
"""
from __future__ import annotations

import argparse
import contextlib
import hashlib
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.composite import default_cache_dir  # noqa: E402
from app.config import DRAG_PASSES, DRAG_SCALE  # noqa: E402
from app.dragpath import drag_offsets, moved  # noqa: E402
from app.engine import Engine, EngineParams, FrameConfig  # noqa: E402
from recon.scene import load_scene  # noqa: E402


def _run_inline(jobs):
    """kernels.runtime.run_parallel with its last job run on the calling thread, the others on the pool (the
    variant `inline`; not kept: docs/benchmarks.md "drag109")."""
    from concurrent.futures import wait

    from kernels import runtime

    if len(jobs) <= 1:
        return [j() for j in jobs]
    if runtime._pool is None:
        runtime.run_parallel([lambda: None, lambda: None])  # makes the pool
    futures = [runtime._pool.submit(j) for j in jobs[:-1]]
    try:
        last = jobs[-1]()
    finally:
        wait(futures)
    return [f.result() for f in futures] + [last]


@contextlib.contextmanager
def _inline(on: bool):
    """kernels.runtime.run_parallel replaced by _run_inline while the block runs (on), or left as it is."""
    from kernels import runtime

    old = runtime.run_parallel
    if on:
        runtime.run_parallel = _run_inline
    try:
        yield
    finally:
        runtime.run_parallel = old


VARIANTS = {"pool": lambda: _inline(False), "inline": lambda: _inline(True)}


def scene_dir(name: str) -> Path:
    p = Path(name).expanduser()
    return p if p.is_dir() else Path(os.environ.get("PHOTOAR_SHARED", ROOT.parent / "shared")) / "scenes" / name


def _sha(pixels: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(pixels).tobytes()).hexdigest()[:12]


def bench_scene(d: Path, names: list[str], n_path: int, rounds: int) -> dict:
    scene = load_scene(d)
    eng = Engine(scene, EngineParams(), cache_dir=default_cache_dir(), quiet=True)
    cfg = FrameConfig(passes=DRAG_PASSES, drag=DRAG_SCALE)
    offsets = drag_offsets(scene, scene.obj, n_path)
    out = {"scene": d.name, "all": {}}
    for n in names:  # the all-sources frame: each variant's bytes and wall (one each, after a first warm one)
        with VARIANTS[n]():
            eng.render(scene.obj, FrameConfig())
            w0 = time.perf_counter()
            fr = eng.render(scene.obj, FrameConfig())
            out["all"][n] = {"sha": _sha(fr.pixels), "wall_s": time.perf_counter() - w0}
    for n in names:  # warm: every variant's first drag frames
        with VARIANTS[n]():
            eng.render(moved(scene.obj, offsets[0]), cfg)
    wall = {n: [] for n in names}
    cpu = {n: [] for n in names}
    same = differ = 0
    for r in range(rounds):
        for i, o in enumerate(offsets[1:]):
            shas = set()
            for n in (names if (r + i) % 2 == 0 else names[::-1]):
                with VARIANTS[n]():
                    c0, w0 = time.process_time(), time.perf_counter()
                    fr = eng.render(moved(scene.obj, o), cfg)
                    wall[n].append(time.perf_counter() - w0)
                    cpu[n].append(time.process_time() - c0)
                    shas.add(_sha(fr.pixels))
            same, differ = same + (len(shas) == 1), differ + (len(shas) > 1)
    out["poses_same"], out["poses_differ"] = same, differ
    out["rows"] = [{"variant": n, "wall_ms": 1e3 * float(np.mean(wall[n])),
                    "wall_p95": 1e3 * float(np.percentile(wall[n], 95)), "cpu_ms": 1e3 * float(np.mean(cpu[n])),
                    "frames": len(wall[n])} for n in names]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", default="window_room,lamps_room,sun_room")
    ap.add_argument("--variants", default="pool,inline")
    ap.add_argument("--path", type=int, default=30)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args()
    names = a.variants.split(",")
    for n in names:
        if n not in VARIANTS:
            raise SystemExit(f"unknown variant {n!r}; known: {', '.join(VARIANTS)}")
    results = []
    for s in a.scenes.split(","):
        d = scene_dir(s)
        if not (d / "scene.json").is_file() and not d.is_dir():
            raise SystemExit(f"no scene at {d}")
        res = bench_scene(d, names, a.path, a.rounds)
        results.append(res)
        al = ", ".join(f"{n} {v['sha']} {v['wall_s']:.3f} s" for n, v in res["all"].items())
        print(f"\n{res['scene']} (load {os.getloadavg()[0]:.1f}): all sources {al}; drag poses with the same pixels "
              f"{res['poses_same']} / {res['poses_same'] + res['poses_differ']}")
        for row in res["rows"]:
            print(f"  {row['variant']:>8} wall {row['wall_ms']:6.1f} / p95 {row['wall_p95']:6.1f} ms, "
                  f"cpu {row['cpu_ms']:6.1f} ms ({row['frames']} frames)")
        sys.stdout.flush()
    if a.out:
        a.out.write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
