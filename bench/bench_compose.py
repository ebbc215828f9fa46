"""Compose stage benchmark (issue 17, app.stages.compose): the second order and the compositing of a
50-pass drag, against the engine's numpy form they replaced, on the same inputs.

usage: python bench/bench_compose.py [--scenes window_room lamps_room] [--n 6] [--repeat 5] [--cache DIR]

Per shared scene: a drag of --n positions at 50 passes (app.dragpath); the compose stage's inputs of
every frame after the first are kept and replayed --repeat times (warm), so that the table shows the
stage alone: second order (ComposeStage.second_order; numpy: G_v[:, nz] @ dB), compose (ComposeStage.
frame, which includes the shadow pass's fill of the skipped pixels, timed apart as `fill`; numpy:
app.stages.compose.compose_reference), both modes, median ms per frame; and the largest difference of
the 8-bit frames (levels) and of the radiance between the two forms.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.dragpath import drag_offsets, moved  # noqa: E402
from app.engine import Engine, EngineParams, FrameConfig  # noqa: E402
from app.stages.compose import compose_reference  # noqa: E402
from recon.scene import load_scene  # noqa: E402


def _median_ms(fn, repeat: int) -> float:
    ts = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t)
    return 1e3 * float(np.median(ts))


def _dense(stage, R) -> np.ndarray:
    """The object light in the dense (N,3) form the numpy reference takes."""
    if isinstance(R, np.ndarray):
        return R
    out = np.zeros_like(stage.L_b)
    if len(R) == 3:
        rp = stage.recv_pix
        out[rp] = np.einsum("nk,nkc->nc", stage.pix_bary[rp], R[0][stage.pix_rows[rp]])
    out[R[-2]] = R[-1]
    return out


def bench_scene(name: str, scene_dir: Path, n: int, repeat: int, cache: str) -> list[dict]:
    scene = load_scene(scene_dir)
    eng = Engine(scene, EngineParams(), cache_dir=cache, quiet=True)
    stage = eng.compose
    rows = []
    for mode in ("hdr", "ldr"):
        captured = []
        frame, second = stage.frame, stage.second_order
        so_args = {}

        def keep_so(dB, more=None, dE_more=None):
            so_args["dB"], so_args["more"] = dB.copy(), None if more is None else more.copy()
            so_args["dE_more"] = None if dE_more is None else dE_more.copy()  # the sun's later bounces
            return second(dB, more, dE_more)

        def keep_frame(*a):
            captured.append((dict(so_args), [x.copy() if isinstance(x, np.ndarray) else x for x in a]))
            return frame(*a)

        stage.frame, stage.second_order = keep_frame, keep_so
        try:
            for o in drag_offsets(scene, scene.obj, n):
                eng.render(moved(scene.obj, o), FrameConfig(passes=50, mode=mode))
        finally:
            del stage.frame, stage.second_order
        captured = captured[1:]  # the first frame of a drag is excluded (as evaluate --path)
        t_so = t_so_ref = t_c = t_fill = t_ref = 0.0
        d_lev = d_rad = 0.0
        for so, a in captured:
            mode_, pix_sel, O_pix, fill_sel, fill, R, dE_v, cov, obj_rad, sun_pix, sun_loss = a
            dB = so["dB"] if so["more"] is None else so["dB"] + so["more"]
            t_so += _median_ms(lambda: stage.second_order(so["dB"], so["more"], so["dE_more"]), repeat)
            nz = np.flatnonzero(np.abs(dB).sum(1) > 0)
            t_so_ref += _median_ms(lambda: eng.pre.G_v[:, nz].astype(np.float64) @ dB[nz], repeat)
            dE = stage.second_order(so["dB"], so["more"], so["dE_more"]).copy()
            t_c += _median_ms(lambda: stage.frame(*a[:6], dE, *a[7:]), repeat)
            vals = O_pix if mode == "ldr" else np.full_like(O_pix, 0.5)
            t_fill += _median_ms(lambda: fill(pix_sel, vals, fill_sel), repeat)
            Rd = _dense(stage, R)
            ref_args = (mode, stage.L_b, eng.receivers.L_b_levels, stage.E_x, stage.rho_x, stage.recv_pix, stage.pix_rows,
                        stage.pix_bary, scene.photo, scene.response, pix_sel, O_pix, fill_sel, fill, Rd, dE, cov,
                        obj_rad, sun_pix, sun_loss)
            t_ref += _median_ms(lambda: compose_reference(*ref_args), repeat)
            rad, pix, _ = stage.frame(*a[:6], dE, *a[7:])
            rad_r, pix_r, _ = compose_reference(*ref_args)
            d_lev = max(d_lev, float(np.abs(pix.reshape(-1, 3).astype(int) - pix_r).max()))
            d_rad = max(d_rad, float(np.abs(rad.reshape(-1, 3) - rad_r).max() / max(rad_r.max(), 1e-12)))
        k = len(captured)
        rows.append(dict(scene=name, mode=mode, frames=k, so_ms=t_so / k, so_numpy_ms=t_so_ref / k,
                         compose_ms=t_c / k, fill_ms=t_fill / k, compose_numpy_ms=t_ref / k, max_level_diff=d_lev,
                         max_rel_radiance_diff=d_rad))
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shared", default=str(ROOT.parent / "shared"))
    ap.add_argument("--scenes", nargs="+", default=["window_room", "lamps_room"])
    ap.add_argument("--n", type=int, default=6)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--cache", default=None, help="precompute cache folder (default: a temporary one)")
    a = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name in a.scenes:
            rows += bench_scene(name, Path(a.shared) / "scenes" / name, a.n, a.repeat, a.cache or tmp)
    print("compose stage, warm, median ms per frame over a 50-pass drag (frames 2..n); numpy = the form it replaced")
    print(f"{'scene':12s} {'mode':4s} {'second order':>12s} {'(numpy)':>8s} {'compose':>8s} {'of it fill':>10s} "
          f"{'(numpy)':>8s} {'max dlevel':>10s} {'max drad':>9s}")
    for r in rows:
        print(f"{r['scene']:12s} {r['mode']:4s} {r['so_ms']:12.1f} {r['so_numpy_ms']:8.1f} {r['compose_ms']:8.1f} "
              f"{r['fill_ms']:10.1f} {r['compose_numpy_ms']:8.1f} {r['max_level_diff']:10.0f} "
              f"{r['max_rel_radiance_diff']:9.1e}")


if __name__ == "__main__":
    main()
