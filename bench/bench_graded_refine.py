"""The graded lattice's refine glue alone, numpy against kernels.graded_refine, A/B in one process (issue 36, drag36).

usage: python bench/bench_graded_refine.py [--scenes window_room,sun_room | DIR,...] [--path 6] [--reps 20]

Per scene one Engine and evaluate's drag path (DRAG_PASSES, DRAG_SCALE, DRAG_SHADOW). At each pose the drag frame
is rendered once while the refine's inputs are captured: the pending points and the near points of the spacing-8
step, the state at the entry of ShadowPass._graded_finer_device (known, allowed, values, fractions) and every
masked sum it asks for. Then both variants are replayed from that state, interleaved, --reps times each, the masked
sums replaced by the captured results (the kernels' sums are not timed; the same points are selected and summed
in both variants, so the results fit either):
- numpy: ShadowPass._square_corners(pend, 8) + np.unique (the spacing-8 corners), then ShadowPass._graded_finer;
- kernel: GradedRefine.step(pend, 0, 8, extra=near), then ShadowPass._graded_finer_device.
Prints per scene the rendering thread's CPU (time.thread_time) per frame for each variant, mean and median over
the poses, and whether the two variants' Masks are equal at every pose. CPU of one thread: little moved by the
load, unlike wall times.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.dragpath import moved  # noqa: E402
from app.stages import shadow_pass as sp_mod  # noqa: E402
from bench.bench_glue_cpu import warm_drag  # noqa: E402


def capture(eng, scene, cfg, offset, sp) -> dict:
    """The refine's inputs of the drag frame at `offset` (module doc), the frame rendered once."""
    got: dict = {"sums": []}
    step, finer, sum_ = sp._refine.step, sp._graded_finer_device, sp._sum

    def cap_step(pend, test, mark, tol, extra=None):
        if test == 0:
            got["first"] = (pend.copy(), extra.copy(), sp._allowed.copy())
        return step(pend, test, mark, tol, extra)

    def cap_finer(pend, first_pts, cen, O_cen, scale):
        got["finer"] = (pend.copy(), first_pts.copy(), cen.copy(), O_cen.copy(), scale.copy())
        got["state"] = tuple(a.copy() for a in (sp._known, sp._allowed, sp._vals, sp._frac))
        got["in_finer"] = True
        try:
            return finer(pend, first_pts, cen, O_cen, scale)
        finally:
            got["in_finer"] = False

    def cap_sum():
        v = sum_()
        if got.get("in_finer"):
            got["sums"].append(v.copy())
        return v

    sp._refine.step, sp._graded_finer_device, sp._sum = cap_step, cap_finer, cap_sum
    try:
        eng.render(moved(scene.obj, offset), cfg)
    finally:
        del sp._refine.step, sp._graded_finer_device, sp._sum
    return got


def replay(sp, got: dict, variant: str):
    """(thread CPU seconds, Masks) of one variant's refine from the captured state (module doc)."""
    sums = iter(got["sums"])
    pend0, near, allowed0 = got["first"]
    pend, first_pts, cen, O_cen, scale = got["finer"]
    sp._known[:] = False
    sp._allowed[:] = allowed0
    sp._sum = lambda: next(sums)
    try:
        t = time.thread_time()
        if variant == "numpy":
            sq8, c8 = sp._square_corners(pend0, 8)
            first = np.unique(np.concatenate([near, c8]))
        else:
            sq8, (_, first) = None, sp._refine.step(pend0, 0, 8, sp.refine_tol, extra=near)
        dt = time.thread_time() - t
        assert np.array_equal(first, first_pts)
        for a, b in zip((sp._known, sp._allowed, sp._vals, sp._frac), got["state"]):
            a[...] = b
        t = time.thread_time()
        if variant == "numpy":
            masks = sp._graded_finer(pend, sq8, first_pts, cen, O_cen, scale)
        else:
            masks = sp._graded_finer_device(pend, first_pts, cen, O_cen, scale)
        dt += time.thread_time() - t
    finally:
        del sp._sum
        sp._known[:] = False
    return dt, masks


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", default="window_room,sun_room")
    ap.add_argument("--path", type=int, default=6)
    ap.add_argument("--reps", type=int, default=20)
    a = ap.parse_args()
    for name in a.scenes.split(","):
        scene, eng, cfg, offsets = warm_drag(name, a.path + 2)
        sp = eng._drag[cfg.drag].shadow_pass
        assert isinstance(sp, sp_mod.ShadowPass) and sp.refine_on_device
        ms = {"numpy": [], "kernel": []}
        same = True
        for o in offsets[2:]:
            got = capture(eng, scene, cfg, o, sp)
            per = {"numpy": [], "kernel": []}
            out = {}
            for _ in range(a.reps):
                for v in ("numpy", "kernel"):
                    dt, out[v] = replay(sp, got, v)
                    per[v].append(dt)
            same &= all(np.array_equal(getattr(out["numpy"], f), getattr(out["kernel"], f))
                        for f in ("pix_sel", "fill_sel", "cen_sel", "O_pix", "O_cen"))
            for v in per:
                ms[v].append(1e3 * np.median(per[v]))
        print(f"{Path(name).name}: refine glue CPU per frame (ms, median of {a.reps} reps per pose; mean / median "
              f"over {len(ms['numpy'])} poses): numpy {np.mean(ms['numpy']):.2f} / {np.median(ms['numpy']):.2f}, "
              f"kernel {np.mean(ms['kernel']):.2f} / {np.median(ms['kernel']):.2f}; "
              f"{'same Masks' if same else 'MASKS DIFFER'}", flush=True)


if __name__ == "__main__":
    main()
