"""The drag frame's "masks" stage as CPU time, variants A/B in one process (issue 36; loaded machines).

usage: python bench/bench_masks_cpu.py [--scenes window_room,sun_room | DIR,...] [--path 8] [--rounds 3]
                                       [--variants base,numpyrefine]

Per scene one Engine (the default precompute cache) and evaluate's drag path (DRAG_PASSES, DRAG_SCALE,
DRAG_SHADOW; --path poses after a warm-up frame), each variant (bench.bench_masks.apply) rendering the whole
path in turn, in --rounds rounds interleaved over the variants. Per variant, ms per frame:
- refine: the rendering thread's CPU in ShadowPass._graded_finer or _graded_finer_device less their _sum calls
  (the graded lattice's refine tests, numpy or kernels.graded_refine's launches; the spacing-8 corners' step in
  _run_graded not included);
- upload: its CPU in ShadowPass.upload_batch;
- glue: the masks stage's glue CPU (the rendering thread's CPU outside its kernel calls between the FrameTimer
  ticks that close the stage: bench.bench_glue_cpu.ThreadCpu);
- masks: the stage's process CPU (time.process_time over ShadowPass.run: every thread);
- frame, wall: the frame's process CPU and its wall time (the load's waits included);
each as the mean over rounds and the per-round means; "same path": every path frame byte-equal to the first
variant's. CPU times vary less with the load than wall times, but still do: compare rows of one run.
"""
from __future__ import annotations

import argparse
import dataclasses
import hashlib
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.composite import default_cache_dir  # noqa: E402
from app.dragpath import drag_offsets, moved  # noqa: E402
from app.engine import Engine, EngineParams  # noqa: E402
from app.evaluate import DRAG_PASSES, DRAG_SCALE, DRAG_SHADOW  # noqa: E402
from app.stages import shadow_pass as sp  # noqa: E402
from bench.bench_drag import scene_dir  # noqa: E402
from bench.bench_glue_cpu import ThreadCpu  # noqa: E402
from bench.bench_masks import apply  # noqa: E402
from recon.scene import load_scene  # noqa: E402

MASKS_CPU = [0.0]  # process CPU seconds inside ShadowPass.run
UPLOAD_CPU = [0.0]  # the calling thread's CPU seconds inside ShadowPass.upload_batch
FINER_CPU = [0.0, 0.0]  # the calling thread's CPU seconds inside ShadowPass._graded_finer, and in its _sum calls


def _timed_run(run):
    """ShadowPass.run that adds the process's CPU time while it runs to MASKS_CPU."""
    def timed(self, *a, **k):
        t0 = time.process_time()
        try:
            return (yield from run(self, *a, **k))
        finally:
            MASKS_CPU[0] += time.process_time() - t0
    return timed


def _timed_upload(upload):
    """ShadowPass.upload_batch that adds its thread's CPU time to UPLOAD_CPU."""
    def timed(self, *a, **k):
        t0 = time.thread_time()
        try:
            return upload(self, *a, **k)
        finally:
            UPLOAD_CPU[0] += time.thread_time() - t0
    return timed


def _timed_finer(finers, sum_):
    """ShadowPass._graded_finer and _graded_finer_device (finers), and _sum, that add their thread's CPU time to
    FINER_CPU (_sum's inside either only)."""
    inside = [False]

    def timed(finer):
        def timed_finer(self, *a, **k):
            t0, inside[0] = time.thread_time(), True
            try:
                return finer(self, *a, **k)
            finally:
                FINER_CPU[0] += time.thread_time() - t0
                inside[0] = False
        return timed_finer

    def timed_sum(self, *a, **k):
        t0 = time.thread_time()
        try:
            return sum_(self, *a, **k)
        finally:
            if inside[0]:
                FINER_CPU[1] += time.thread_time() - t0
    return [timed(f) for f in finers], timed_sum


def bench_scene(d: Path, variants: list[str], n_path: int, rounds: int, cpu: list) -> None:
    scene = load_scene(d)
    eng = Engine(scene, EngineParams(), cache_dir=default_cache_dir(), quiet=True)
    cfg = dataclasses.replace(eng.frame_config(), passes=DRAG_PASSES, drag=DRAG_SCALE, drag_shadow=DRAG_SHADOW)
    offsets = drag_offsets(scene, scene.obj, n_path + 1)
    eng.render(moved(scene.obj, offsets[0]), cfg)  # the drag stages made
    shadow_pass = eng._drag[DRAG_SCALE].shadow_pass
    if not cpu:
        cpu.append(ThreadCpu())
    tc = cpu[0]
    rows = {v: {"refine": [], "upload": [], "glue": [], "masks": [], "frame": [], "wall": [], "hashes": []}
            for v in variants}
    for _ in range(rounds):
        for v in variants:
            undo = apply(v, shadow_pass)
            try:
                eng.render(moved(scene.obj, offsets[0]), cfg)  # warm
                tc.stage.clear()
                m0, u0, p0, f0 = MASKS_CPU[0], UPLOAD_CPU[0], time.process_time(), FINER_CPU[0] - FINER_CPU[1]
                w0 = time.perf_counter()
                hashes = []
                for o in offsets[1:]:
                    tc.start_frame()
                    fr = eng.render(moved(scene.obj, o), cfg)
                    hashes.append(hashlib.sha256(fr.pixels.tobytes()).hexdigest())
                n = len(offsets) - 1
                q = rows[v]
                q["frame"].append(1e3 * (time.process_time() - p0) / n)
                q["wall"].append(1e3 * (time.perf_counter() - w0) / n)
                q["masks"].append(1e3 * (MASKS_CPU[0] - m0) / n)
                q["upload"].append(1e3 * (UPLOAD_CPU[0] - u0) / n)
                q["refine"].append(1e3 * (FINER_CPU[0] - FINER_CPU[1] - f0) / n)
                q["glue"].append(1e3 * tc.stage.get("masks", 0.0) / n)
                q["hashes"].append(hashes)
            finally:
                undo()
    print(f"\n{d.name} ({len(offsets) - 1} poses x {rounds} rounds), ms per frame, mean (per round)")
    ref = rows[variants[0]]["hashes"]
    for v in variants:
        q = rows[v]
        cols = "  ".join(f"{k} {np.mean(q[k]):6.1f} ({' / '.join(f'{x:.1f}' for x in q[k])})"
                         for k in ("refine", "upload", "glue", "masks", "frame", "wall"))
        same = all(h == ref[0] for h in q["hashes"]) and all(h == ref[0] for h in ref)
        print(f"  {v:>12}: {cols}  {'same path' if same else 'PATH DIFFERS'}", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default="window_room,sun_room")
    ap.add_argument("--variants", default="base,numpyrefine")
    ap.add_argument("--path", type=int, default=8)
    ap.add_argument("--rounds", type=int, default=3)
    a = ap.parse_args()
    sp.ShadowPass.run = _timed_run(sp.ShadowPass.run)
    sp.ShadowPass.upload_batch = _timed_upload(sp.ShadowPass.upload_batch)
    (sp.ShadowPass._graded_finer, sp.ShadowPass._graded_finer_device), sp.ShadowPass._sum = _timed_finer(
        (sp.ShadowPass._graded_finer, sp.ShadowPass._graded_finer_device), sp.ShadowPass._sum)
    cpu: list = []
    for name in a.scenes.split(","):
        bench_scene(scene_dir(name), a.variants.split(","), a.path, a.rounds, cpu)


if __name__ == "__main__":
    main()
