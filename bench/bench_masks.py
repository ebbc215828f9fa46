"""The drag frame's "masks" stage (issue 36): variants of the shadow pass A/B in one process.

usage: python bench/bench_masks.py [--scenes window_room,lamps_room,sun_room | DIR,...] [--path 8]
                                   [--variants base,points] [--rounds 2]

Per scene one Engine (the default precompute cache) and the drag frame of app.config (1/DRAG_SCALE,
DRAG_PASSES); for each variant a drag of --path poses (app.dragpath), in rounds interleaved over the
variants (the same machine load for all), and the drag frame at the scene's own pose scored against its
truth (lighting.metrics), with the largest level difference from the first variant's frame. Variants:
- base: the shadow pass as it is;
- points: each graded spacing's sums cut over the cores by point count (2048 a range), not by (point, map)
  pairs (ShadowPass._sum before MIN_PART_PAIRS);
- soft: every cluster map looked up with its PCSS penumbra (ShadowPass.weak_clusters None: the weak passes too);
- levels: the depth pyramids built level by level (ShadowMaps.merge_mips False; the same pyramids);
- blockloop: may_occlude loops over a box's coarse blocks (MapSet.sat 0; the same lists); soft+levels+blockloop is
  main's shadow pass before masks37;
- tolN: the graded lattice's refine tolerance N % (ShadowPass.refine_tol);
- copycentres: the patch centres' transfers copied into the batch's weights by upload_batch (before masks48b),
  not read by the sums in place from W_c (ShadowPass._centre_table None);
- numpyrefine: the graded lattice's refine tests in numpy (ShadowPass.refine_on_device False; before drag36);
- pixelwise: the drag compose's kernel pixel by pixel (DragCompose.rowwise False, for every engine; before drag36);
- A+B: variants A and B together.
Prints per variant the means over the path of the masks and upsample stages (wall), the frame's wall and
CPU time (the process's, all threads), and "crit": the frame's critical path in CPU time, the rendering
thread's own CPU time plus, for each set of concurrent launches (app.runtime.run), the CPU time of its
longest one: about the frame's wall time on an idle machine of as many cores as launches (two here),
which the wall time of a loaded machine does not show; "masks crit" the same for the shadow pass alone.
"objects" is the stages sun .. second_order (wall);
"same path": every path frame equal, byte for byte, to the first variant's.
Timings depend on the machine's load: compare the rows of one run.
"""
from __future__ import annotations

import argparse
import sys
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app import runtime  # noqa: E402
from app.composite import default_cache_dir  # noqa: E402
from app.config import DRAG_PASSES, DRAG_SCALE  # noqa: E402
from app.dragpath import drag_offsets, moved  # noqa: E402
from app.engine import Engine, EngineParams, FrameConfig  # noqa: E402
from app.stages import shadow_pass as sp  # noqa: E402
from bench.bench_drag import scene_dir  # noqa: E402
from kernels import runtime as krt  # noqa: E402
from lighting import metrics  # noqa: E402
from recon.io import read_image_rgb  # noqa: E402
from recon.scene import load_scene  # noqa: E402

CRIT = {"masks": 0.0}
# per calling thread: the summed CPU time of the longest job of each set of concurrent launches ("crit") and of
# all their jobs ("cpu")
LAUNCHES: dict[int, dict[str, float]] = {}
# the stages between the masks and compose
OBJECT_STAGES = ("sun", "object_light", "object_shading", "second_order")


def _launches() -> dict[str, float]:
    """The calling thread's launch accumulators."""
    return LAUNCHES.setdefault(threading.get_ident(), {"crit": 0.0, "cpu": 0.0})


def _timed_run_parallel(run_parallel):
    """kernels.runtime.run_parallel that adds, for its calling thread, the CPU time of each call's longest job
    (crit) and of all its jobs (cpu)."""
    def run(jobs):
        if len(jobs) <= 1:
            return [j() for j in jobs]
        cpu = [0.0] * len(jobs)

        def timed(i, job):
            def go():
                t0 = time.thread_time()
                try:
                    return job()
                finally:
                    cpu[i] = time.thread_time() - t0
            return go
        acc = _launches()
        out = run_parallel([timed(i, j) for i, j in enumerate(jobs)])
        acc["crit"] += max(cpu)
        acc["cpu"] += sum(cpu)
        return out
    return run


def _mark() -> tuple[float, float, float]:
    """The calling thread's (CPU time, launches' crit, launches' cpu) so far."""
    acc = _launches()
    return time.thread_time(), acc["crit"], acc["cpu"]


def _timed_shadow_pass(run):
    """ShadowPass.run that adds its critical path (rendering thread + longest concurrent launches) to CRIT."""
    def timed(self, *a, **k):
        t0, c0, _ = _mark()
        out = yield from run(self, *a, **k)
        t1, c1, _ = _mark()
        CRIT["masks"] += t1 - t0 + c1 - c0
        return out
    return timed


def _sum_by_points(self) -> np.ndarray:
    """ShadowPass._sum cut by point count (variant `points`)."""
    dev = self.device
    runtime.run([lambda a=a, b=b: self.sums.accumulate(self.maps, 0, self.weights.dev, a, b)
                 for a, b in self.sums.balanced(runtime.parts(dev, self.sums.n, min_items=2048))])
    return self.sums.result()[0]


def apply(variant: str, shadow_pass) -> callable:
    """Set `variant` on the drag frame's shadow pass (several joined by "+": each in turn); returns the undo."""
    if "+" in variant:
        undos = [apply(v, shadow_pass) for v in variant.split("+")]
        return lambda: [u() for u in reversed(undos)] and None
    if variant == "base":
        return lambda: None
    if variant == "points":
        shadow_pass._sum = _sum_by_points.__get__(shadow_pass)
        return lambda: delattr(shadow_pass, "_sum")
    if variant == "soft":  # every cluster map its PCSS penumbra (ShadowPass.weak_clusters None)
        was = shadow_pass.weak_clusters
        shadow_pass.weak_clusters = None
        return lambda: setattr(shadow_pass, "weak_clusters", was)
    if variant == "levels":  # the depth pyramids built level by level (ShadowMaps.merge_mips False)
        maps = [m for m in {id(m): m for m in (shadow_pass.maps_cluster, *shadow_pass._twin.values())}.values()]
        for m in maps:
            m.merge_mips = False
        return lambda: [setattr(m, "merge_mips", True) for m in maps] and None
    if variant == "blockloop":  # may_occlude loops over a box's coarse blocks, no summed-area table (MapSet.sat 0)
        maps = [m for m in {id(m): m for m in (shadow_pass.maps_cluster, *shadow_pass._twin.values())}.values()]
        for m in maps:
            m.ms.sat = 0
        return lambda: [setattr(m.ms, "sat", 1) for m in maps] and None
    if variant == "copycentres":  # the patch centres' transfers copied into the batch's weights (before masks48b)
        shadow_pass._centre_table = lambda W_c: None
        return lambda: delattr(shadow_pass, "_centre_table")
    if variant == "numpyrefine":  # the graded lattice's refine tests in numpy (before drag36: refine_on_device False)
        shadow_pass.refine_on_device = False
        return lambda: setattr(shadow_pass, "refine_on_device", True)
    if variant == "pixelwise":  # the drag compose's kernel pixel by pixel (before drag36: DragCompose.rowwise False)
        from kernels.drag_compose import DragCompose
        DragCompose.rowwise = False
        return lambda: setattr(DragCompose, "rowwise", True)
    if variant.startswith("tol"):  # the graded lattice's refine tolerance tolN, N in percent (ShadowPass.refine_tol)
        was = shadow_pass.refine_tol
        shadow_pass.refine_tol = int(variant[3:]) / 100
        return lambda: setattr(shadow_pass, "refine_tol", was)
    raise SystemExit(f"unknown variant {variant!r} (base, points, tolN, soft, levels, "
                     "blockloop, copycentres, numpyrefine, pixelwise)")


def bench_scene(d: Path, variants: list[str], n_path: int, rounds: int) -> None:
    import cv2

    scene = load_scene(d)
    eng = Engine(scene, EngineParams(), cache_dir=default_cache_dir(), quiet=True)
    truth = read_image_rgb(d / "truth.png")
    mask = cv2.imread(str(d / "truth_mask.png"), cv2.IMREAD_GRAYSCALE)
    full = metrics.score_regions(eng.render(scene.obj, FrameConfig()).pixels, scene.photo, truth, mask)
    bound = 1.5 * full["rmse_affected"] + 0.5
    print(f"\n{d.name}: all sources rmse {full['rmse_affected']:.3f} energy {full['energy_ratio']:.3f}; "
          f"drag row bound rmse <= {bound:.2f}, energy 0.93-1.07", flush=True)
    cfg = FrameConfig(passes=DRAG_PASSES, drag=DRAG_SCALE)
    eng.render(scene.obj, cfg)  # the drag stages made
    shadow_pass = eng._drag[DRAG_SCALE].shadow_pass
    offsets = drag_offsets(scene, scene.obj, n_path)
    rows = {v: {"masks": [], "upsample": [], "wall": [], "cpu": [], "crit": [], "masks_crit": [], "objects": [],
                "compose": []} for v in variants}
    for r in range(rounds):
        for v in variants:
            undo = apply(v, shadow_pass)
            try:
                fr = eng.render(scene.obj, cfg)  # warm, and scored
                if r == 0:
                    s = metrics.score_regions(fr.pixels, scene.photo, truth, mask)
                    rows[v].update(score=(s["energy_ratio"], s["rmse_affected"]), pixels=fr.pixels)
                for o in offsets[1:]:
                    t0, (th0, c0, _), snap = time.process_time(), _mark(), dict(CRIT)
                    fr = eng.render(moved(scene.obj, o), cfg)
                    st = fr.stats
                    q = rows[v]
                    q.setdefault("hashes", []).append(hash(fr.pixels.tobytes()))
                    q["cpu"].append(time.process_time() - t0)
                    th1, c1, _ = _mark()
                    q["crit"].append(th1 - th0 + c1 - c0)
                    q["masks_crit"].append(CRIT["masks"] - snap["masks"])
                    q["wall"].append(st["frame_s"])
                    q["masks"].append(st["timings"]["masks"])
                    q["upsample"].append(st["timings"].get("upsample", 0.0))
                    q["objects"].append(sum(st["timings"].get(k, 0.0) for k in OBJECT_STAGES))
                    q["compose"].append(st["timings"].get("compose", 0.0))
            finally:
                undo()
    first = rows[variants[0]]["pixels"].astype(np.int16)
    print(f"{'variant':>8} {'masks':>7} {'objects':>7} {'compose':>7} {'upsample':>8} {'wall':>7} {'cpu':>7} "
          f"{'crit':>7} {'masks crit':>10} "
          f"{'energy':>7} {'rmse':>6} {'max diff':>8}")
    for v in variants:
        q = rows[v]
        ms = {k: 1e3 * float(np.mean(q[k])) for k in ("masks", "objects", "compose", "upsample", "wall", "cpu", "crit",
                                                      "masks_crit")}
        e, rm = q["score"]
        ok = rm <= bound and 0.93 <= e <= 1.07
        print(f"{v:>8} {ms['masks']:7.1f} {ms['objects']:7.1f} {ms['compose']:7.1f} {ms['upsample']:8.1f} "
              f"{ms['wall']:7.1f} {ms['cpu']:7.1f} {ms['crit']:7.1f} "
              f"{ms['masks_crit']:10.1f} {e:7.3f} {rm:6.3f} {int(np.abs(q['pixels'] - first).max()):8d} "
              f"{'same path' if q['hashes'] == rows[variants[0]]['hashes'] else 'PATH DIFFERS'}"
              f"{'' if ok else '  (out of bound)'}", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default="window_room,lamps_room,sun_room")
    ap.add_argument("--variants", default="base,points")
    ap.add_argument("--path", type=int, default=8)
    ap.add_argument("--rounds", type=int, default=2)
    a = ap.parse_args()
    krt.run_parallel = _timed_run_parallel(krt.run_parallel)
    sp.ShadowPass.run = _timed_shadow_pass(sp.ShadowPass.run)
    for name in a.scenes.split(","):
        bench_scene(scene_dir(name), a.variants.split(","), a.path, a.rounds)


if __name__ == "__main__":
    main()
