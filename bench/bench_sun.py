"""Sun benchmark: the cost of the sun's pass in a frame, and PCSS against jittered sun maps.

usage: python bench/bench_sun.py [--shared ../shared] [--passes 50] [--repeat 8] [--ab-only | --outline-only]
                                 [--scene-ab] [--runs K] [--summary-json PATH]

On sun_room, one engine: the drag frame with --passes shadow passes, the sun being one of them (the
sun's map, its PCSS lookups, its pieces of object light, the outline where it clips, what it adds to
the second order and the object), against the same frame with the sun switched off (all --passes for
the room's patches), interleaved pose by pose; prints the ratio (the median of the pose pairs with its
bootstrap interval), and what the sun adds in CPU time (each kernel's by its launching thread's clock,
those that move by 0.5 ms or more either way, and the process's), steadier than wall time when other jobs load the machine. Then the sunlit object's light at
pixels around it from whole faces and from the lit pieces against a dense Monte Carlo reference, and
rmse_object with the clipped outline re-sampled 1 x 1 to 8 x 8, every ray on every pixel or
adaptively (SunStage.edge_first), with the rays cast and _outline_shade_kernel's thread-CPU ms. Then the sun shadow alone: one
PCSS map against N jittered binary maps (directions spread over the 0.53 deg disk), time and the
mean absolute difference of the occluded share on the sunlit pixels from a 64-map reference.
Last, the scorer's figures for the --passes frame with known and with captured light, and the
captured sun estimate against the declared sun. Prints tables; timings are warm (second and later
frames). --runs K repeats the A/B in K fresh processes and prints each one's overheads and their median,
lowest and highest over the processes (one process's figure moves by a few per cent from process to
process, more than its own interval says).
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.dragpath import drag_offsets, moved  # noqa: E402
from app.engine import Engine, EngineParams  # noqa: E402
from recon.io import write_json, write_png  # noqa: E402
from app.report import table  # noqa: E402
from kernels.raycast import cast_rays  # noqa: E402
from kernels.sunshadow import SunShadowMap, vogel_disk  # noqa: E402
from recon.scene import load_scene  # noqa: E402


def jittered(engine: Engine, obj, n: int) -> np.ndarray:
    """Mean binary occlusion over n maps toward points spread over the sun's disk."""
    sun = engine.scene.sun
    d = sun.direction / np.linalg.norm(sun.direction)
    helper = np.array([0.0, 1.0, 0.0]) if abs(d[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    a = np.cross(helper, d)
    a /= np.linalg.norm(a)
    b = np.cross(d, a)
    acc = np.zeros(len(engine.sun_pixels.stage.pts))
    for u, v in vogel_disk(n) * np.tan(sun.half_angle):
        m = SunShadowMap(d + u * a + v * b, 0.0, device=engine.device)
        m.render(obj.vertices, obj.faces)
        acc += m.occlusion(engine.sun_pixels.stage.pts, engine.sun_pixels.stage.footprint)
    return acc / n


def pieces_against_monte_carlo(engine: Engine, obj, n_mc: int = 400000, seed: int = 0) -> list[dict]:
    """The sunlit object's light (irradiance/pi, luminance) at floor and wall pixels around it: whole
    faces (mean sun, one visibility test each), every lit piece with a ray each, the engine's emitters
    (app.stages.sun.SunStage.object_emitters: wholly lit faces whole, partly lit faces' lit pieces with
    their per-shape visibility table, far ones as points within their bound), and a dense Monte Carlo reference (n_mc area samples on the
    object, sun and receiver visibility per sample)."""
    from kernels.visibility import Occluder, emitter_sum, emitter_sum_seen_bounded
    from lighting.sources import luminance

    V, F = obj.vertices, obj.faces
    occ = Occluder(V, F, engine.device)
    T = V[F]
    nt = np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0])
    A = 0.5 * np.linalg.norm(nt, axis=1)
    nt /= 2 * A[:, None]
    rng = np.random.default_rng(seed)
    ti = rng.choice(len(F), n_mc, p=A / A.sum())
    r1, r2 = np.sqrt(rng.random(n_mc)), rng.random(n_mc)
    P = (1 - r1)[:, None] * T[ti, 0] + (r1 * (1 - r2))[:, None] * T[ti, 1] + (r1 * r2)[:, None] * T[ti, 2]
    Nn = nt[ti]
    L = obj.albedo * engine.sun.light.irradiance(P, Nn, [occ])  # radiance of each sample
    faces = obj.albedo * engine.sun.light.triangle_irradiance(T, [occ])
    radius = float(np.linalg.norm(V - 0.5 * (V.min(0) + V.max(0)), axis=1).max())
    sub, E, _ = engine.sun.light.sunlit_elements(T, [occ], size=radius / 4.0)
    sun_rad, extra = engine.sun_pixels.stage.object_emitters(V, F, np.zeros((len(F), 3)), obj.albedo, occ, radius)
    uv, _ = engine.scene.camera.project(0.5 * (V.min(0) + V.max(0))[None])
    cu, cv = uv[0]
    W = engine.scene.camera.width
    rows = []
    for du, dv in ((-150, 130), (-60, 60), (-20, 35), (-180, -120), (80, -40)):
        i = int(round(cv + dv)) * W + int(round(cu + du))
        if not engine.receivers.recv_pix[i]:
            continue
        p = engine.receivers.pix_pos[i].astype(np.float64)
        pn = engine.pre.patches.normal[engine.receivers.pix_patch[i]]
        d = P - p
        r = np.linalg.norm(d, axis=1)
        d /= r[:, None]
        ce, cr = np.maximum(-(d * Nn).sum(1), 0), np.maximum(d @ pn, 0)
        act = np.flatnonzero((ce > 0) & (cr > 0) & (L.sum(1) > 0))
        o = p + pn * 1e-3
        dd = P[act] - o
        rr = np.linalg.norm(dd, axis=1)
        dd /= rr[:, None]
        _, _, d_obj = cast_rays(occ, o, dd)
        _, _, d_room = cast_rays(engine.scene_occ, o, dd)
        a = act[(d_obj > rr - 2e-3) & (d_room > rr - 2e-3)]
        mc = luminance((L[a] * (ce[a] * cr[a] / (np.pi * r[a] ** 2))[:, None]).sum(0) * A.sum() / n_mc)
        f = luminance(emitter_sum(p[None], pn[None], T, faces, occ, device=engine.device)[0])
        pc = luminance(emitter_sum(p[None], pn[None], sub, obj.albedo * E, occ, device=engine.device)[0])
        en = emitter_sum(p[None], pn[None], T, sun_rad, occ, device=engine.device)[0]
        if extra is not None:  # as the engine sums them: far pieces as points within extra.tolerance
            en = en + emitter_sum_seen_bounded(p[None], pn[None], extra.tris, extra.rad, extra.seen, extra.res,
                                               extra.tolerance, device=engine.device)[0]
        en = luminance(en)
        rows.append({"pixel (du, dv)": f"({du}, {dv})", "monte_carlo": mc, "faces": f, "pieces": pc, "engine": en,
                     "faces/mc": f / max(mc, 1e-12), "pieces/mc": pc / max(mc, 1e-12),
                     "engine/mc": en / max(mc, 1e-12)})
    return rows


_LAUNCH = None


def bootstrap_median(x: np.ndarray, n: int = 2000, level: float = 0.9, seed: int = 0) -> np.ndarray:
    """(low, high): the `level` interval of the median of x by resampling x with replacement n times
    (how far the median of a dozen noisy frame pairs can be trusted)."""
    rng = np.random.default_rng(seed)
    med = np.median(rng.choice(np.asarray(x, np.float64), (n, len(x))), axis=1)
    return np.quantile(med, [(1 - level) / 2, (1 + level) / 2])


def kernel_clock(stop: bool = False) -> dict:
    """Time every Warp launch from now on by the launching thread's CPU clock (a CPU launch runs in
    that thread): {kernel name: seconds}, cleared by the caller; stop=True puts warp.launch back."""
    import threading

    import warp as wp

    global _LAUNCH
    if stop:
        if _LAUNCH is not None:
            wp.launch = _LAUNCH
            _LAUNCH = None
        return {}
    acc: dict[str, float] = {}
    lock = threading.Lock()
    _LAUNCH = orig = wp.launch

    def launch(kernel, *args, **kwargs):
        t = time.thread_time()
        out = orig(kernel, *args, **kwargs)
        dt = time.thread_time() - t
        with lock:
            key = getattr(kernel, "key", str(kernel))
            acc[key] = acc.get(key, 0.0) + dt
        return out

    wp.launch = launch
    return acc


def shared_score(shared: Path, pixels: np.ndarray) -> dict:
    """The shared scorer's figures (../shared/tools/score.py, run as the judges run it) for an 8-bit
    composite of sun_room."""
    with tempfile.TemporaryDirectory() as tmp:
        png = Path(tmp) / "c.png"
        write_png(png, pixels)
        out = subprocess.run([sys.executable, str(shared / "tools" / "score.py"), str(shared / "scenes" / "sun_room"),
                              str(png)], capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def outline_table(engine: Engine, obj, shared: Path, repeat: int = 5) -> str:
    """rmse_object/bias_object of the drag frame with the outline where sunlight clips re-sampled s x s,
    every ray on every pixel or adaptively (SunStage.edge_first first rays, all s x s where they
    disagree; the frame's own: 4 x 4 adaptively), with the rays cast and _outline_shade_kernel's
    thread-CPU ms (the median of `repeat` frames)."""
    rows = []
    stage = engine.sun_pixels.stage
    first0 = stage.edge_first
    # the outline where sunlight clips, re-sampled s x s: every ray on every pixel, or adaptively (the
    # frame's own: edge_first rays a pixel, all s x s where they disagree)
    for s, first in ((1, None), (2, None), (3, None), (4, None), (4, first0), (8, None), (8, first0)):
        stage.edge_samples, stage.edge_first = s, first
        ms = []
        for _ in range(repeat):
            launched = kernel_clock()
            frame = engine.render(obj)
            kernel_clock(stop=True)
            ms.append(1e3 * launched.get("_outline_shade_kernel", 0.0))
        sc = shared_score(shared, frame.pixels)
        rows.append({"outline rays": f"{s} x {s}" + ("" if first is None or first >= s * s else f", {first} first"),
                     "rays": stage._outline.rays, "kernel_ms": float(np.median(ms)),
                     "rmse_object": sc["rmse_object"], "bias_object": sc["bias_object"]})
    stage.edge_samples, stage.edge_first = 4, first0
    return table(rows, ["outline rays", "rays", "kernel_ms", "rmse_object", "bias_object"])


def scene_ab(scene, engine: Engine, obj, offsets: list, cache: Path | None) -> tuple[str, dict]:
    """The sun frame against the same frame in the scene without its sun entry: a second engine on
    `scene` with `sun=None` (its own precompute: the room lit by the sky through the opening alone),
    the same poses, interleaved ABBA. The on/off A/B above keeps the sunlit room's precompute and only
    drops the sun's pass; this one is the room a user would have on a sunless day (its source list and
    light differ, and so does the cost of its masks). Returns the printed tables and their overheads
    ({"overhead", "low", "high", "cpu"}: fractions)."""
    import dataclasses

    sunless = Engine(dataclasses.replace(scene, sun=None), engine.params, cache_dir=cache, quiet=True)
    sunless.render(moved(obj, offsets[0]))
    t: dict[bool, list[float]] = {True: [], False: []}
    cpu: dict[bool, list[float]] = {True: [], False: []}
    stages: dict[bool, list[dict]] = {True: [], False: []}
    for i, o in enumerate(offsets):
        for on in ((True, False) if i % 2 == 0 else (False, True)):
            c0 = time.process_time()
            st = (engine if on else sunless).render(moved(obj, o)).stats
            cpu[on].append(time.process_time() - c0)
            t[on].append(st["frame_s"])
            stages[on].append(st["timings"])
    pairs = np.array(t[True]) / np.array(t[False])
    lo, hi = bootstrap_median(pairs) - 1.0
    summary = {"overhead": float(np.median(pairs) - 1.0), "low": float(lo), "high": float(hi),
               "cpu": float(np.median(np.array(cpu[True]) / np.array(cpu[False])) - 1.0)}
    names = list(stages[True][-1])
    out = table([{"stage": k, "sun_ms": 1e3 * float(np.median([s.get(k, 0.0) for s in stages[True]])),
                  "sunless_scene_ms": 1e3 * float(np.median([s.get(k, 0.0) for s in stages[False]]))}
                 for k in names], ["stage", "sun_ms", "sunless_scene_ms"])
    out += "\n" + table([
        {"frame": f"{engine.params.passes} passes, sun one of them", "frame_s": float(np.median(t[True]))},
        {"frame": f"{engine.params.passes} passes, the scene without its sun", "frame_s": float(np.median(t[False]))},
        {"frame": "overhead, median of pairs (fraction)", "frame_s": summary["overhead"]},
        {"frame": "  its 90 % interval, low (bootstrap)", "frame_s": summary["low"]},
        {"frame": "  its 90 % interval, high (bootstrap)", "frame_s": summary["high"]},
        {"frame": "process CPU overhead, median of pairs", "frame_s": summary["cpu"]}], ["frame", "frame_s"])
    return out, summary


def many_runs(a: argparse.Namespace) -> int:
    """The sun's A/B in a.runs fresh processes one after another (each: a new engine, warm caches, its own
    interleaved --repeat poses). One process's median of pairs moves by a few per cent from process to
    process on this machine, more than its own bootstrap interval says (the processes differ in where
    their threads and buffers land), so a claim about the overhead rests on the spread over processes.
    Prints a row per run and the median over runs; a failed run stops with its output."""
    rows, kinds = [], ["on_off"] + (["scene"] if a.scene_ab else [])
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(a.runs):
            out = Path(tmp) / f"run{i}.json"
            cmd = [sys.executable, __file__, "--shared", str(a.shared), "--passes", str(a.passes), "--repeat",
                   str(a.repeat), "--ab-only", "--summary-json", str(out)] + (["--scene-ab"] if a.scene_ab else [])
            if a.cache is not None:
                cmd += ["--cache", str(a.cache)]
            done = subprocess.run(cmd, capture_output=True, text=True)
            if done.returncode != 0:
                sys.stderr.write(done.stdout + done.stderr)
                return done.returncode
            res = json.loads(out.read_text())
            row = {"run": i + 1}
            for k in kinds:
                row.update({f"{k}": res[k]["overhead"], f"{k}_low": res[k]["low"], f"{k}_high": res[k]["high"],
                            f"{k}_cpu": res[k]["cpu"]})
            rows.append(row)
            print(f"run {i + 1}/{a.runs}: " + ", ".join(f"{k} {100 * row[k]:+.1f} %" for k in kinds), flush=True)
    cols = ["run"] + [c for k in kinds for c in (k, f"{k}_low", f"{k}_high", f"{k}_cpu")]
    print(table(rows, cols))
    summary = []
    for k in kinds:
        for c in (k, f"{k}_cpu"):
            v = np.array([r[c] for r in rows])
            summary.append({"overhead": c, "median over runs": float(np.median(v)), "lowest": float(v.min()),
                            "highest": float(v.max()), "runs at most 0.10": f"{int((v <= 0.10).sum())} of {len(v)}"})
    print(table(summary, ["overhead", "median over runs", "lowest", "highest", "runs at most 0.10"]))
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shared", type=Path, default=ROOT.parent / "shared")
    ap.add_argument("--passes", type=int, default=50)
    ap.add_argument("--repeat", type=int, default=8, help="drag poses of the A/B")
    ap.add_argument("--cache", type=Path, default=None)
    ap.add_argument("--ab-only", action="store_true", help="only the sun on/off A/B (and --scene-ab's)")
    ap.add_argument("--outline-only", action="store_true", help="only the clipped outline's table")
    ap.add_argument("--scene-ab", action="store_true",
                    help="also the frame against the same frame in the scene without its sun entry (a second engine)")
    ap.add_argument("--runs", type=int, default=1,
                    help="the A/B (--ab-only, with --scene-ab's if given) in this many fresh processes, one after "
                         "another: the overheads' spread from process to process")
    ap.add_argument("--summary-json", type=Path, default=None, help="write the A/B's overheads (fractions) here")
    a = ap.parse_args(argv)
    if a.runs > 1:
        return many_runs(a)
    scene = load_scene(a.shared / "scenes" / "sun_room")
    engine = Engine(scene, EngineParams(passes=a.passes), cache_dir=a.cache, quiet=True)
    obj = scene.obj
    # A/B on one engine: the same drag frame with the sun and with the sun switched off (all --passes
    # for the room's patches), interleaved pose by pose in ABBA order so that a shared machine's load
    # and the engine's per-shape caches fall on both alike
    with_sun = engine.sun_pixels
    without = dataclasses.replace(with_sun, pix=None, stage=None)

    def sun(on: bool) -> None:
        engine.sun_pixels = with_sun if on else without

    if a.outline_only:
        engine.render(obj)
        print(outline_table(engine, obj, a.shared))
        return 0
    offs = drag_offsets(scene, obj, a.repeat + 1)
    engine.render(moved(obj, offs[0]))
    t_sun, t_no, ms_sun, rays = [], [], [], []  # rays: the clipped outline's camera rays a sun frame
    stages: dict[bool, list[dict]] = {True: [], False: []}
    cpu: dict[bool, list[float]] = {True: [], False: []}  # the process's CPU seconds a frame (all threads)
    kern: dict[bool, dict[str, float]] = {True: {}, False: {}}  # kernel thread-CPU seconds, summed over frames
    launched = kernel_clock()
    for i, o in enumerate(offs[1:]):
        for on in ((True, False) if i % 2 == 0 else (False, True)):
            sun(on)
            launched.clear()
            c0 = time.process_time()
            st = engine.render(moved(obj, o)).stats
            cpu[on].append(time.process_time() - c0)
            for k, v in launched.items():
                kern[on][k] = kern[on].get(k, 0.0) + v
            (t_sun if on else t_no).append(st["frame_s"])
            stages[on].append(st["timings"])
            if on:
                ms_sun.append(st["timings"]["sun"])
                rays.append(engine.sun_pixels.stage.edge_rays)
    kernel_clock(stop=True)
    sun(True)
    # CPU time is far steadier than wall time on a shared machine (other jobs' load stretches wall time)
    n_frames = len(t_sun)
    diff = sorted(((kern[True].get(k, 0.0) - kern[False].get(k, 0.0)) / n_frames, k) for k in set(kern[True]) | set(kern[False]))
    rows = [{"kernel": k, "sun_ms": 1e3 * kern[True].get(k, 0.0) / n_frames,
             "no_sun_ms": 1e3 * kern[False].get(k, 0.0) / n_frames, "added_ms": 1e3 * d} for d, k in diff[::-1] if abs(d) >= 5e-4]  # both signs: what the sun adds and what it replaces
    rows.append({"kernel": "all kernels", "sun_ms": 1e3 * sum(kern[True].values()) / n_frames,
                 "no_sun_ms": 1e3 * sum(kern[False].values()) / n_frames,
                 "added_ms": 1e3 * (sum(kern[True].values()) - sum(kern[False].values())) / n_frames})
    rows.append({"kernel": "process CPU a frame (median)", "sun_ms": 1e3 * float(np.median(cpu[True])),
                 "no_sun_ms": 1e3 * float(np.median(cpu[False])),
                 "added_ms": 1e3 * float(np.median(cpu[True]) - np.median(cpu[False]))})
    rows.append({"kernel": "outline rays a frame (mean, count)", "sun_ms": float(np.mean(rays)), "no_sun_ms": 0.0,
                 "added_ms": float(np.mean(rays))})
    print(table(rows, ["kernel", "sun_ms", "no_sun_ms", "added_ms"]))
    print(table([{"stage": k, "sun_ms": 1e3 * float(np.median([t.get(k, 0.0) for t in stages[True]])),
                  "no_sun_ms": 1e3 * float(np.median([t.get(k, 0.0) for t in stages[False]]))}
                 for k in stages[True][-1]], ["stage", "sun_ms", "no_sun_ms"]))
    with_sun, without = float(np.median(t_sun)), float(np.median(t_no))
    best = float(min(t_sun) / min(t_no) - 1.0)  # least disturbed frames of each
    pairs = np.array(t_sun) / np.array(t_no)  # neighbouring frames (the same pose, ABBA)
    paired = float(np.median(pairs) - 1.0)
    lo, hi = bootstrap_median(pairs) - 1.0
    cpu_paired = float(np.median(np.array(cpu[True]) / np.array(cpu[False])) - 1.0)
    print(table([{"frame": f"{a.passes} passes, sun one of them", "frame_s": with_sun},
                 {"frame": f"{a.passes} passes, no sun", "frame_s": without},
                 {"frame": "sun's own pass (timings['sun'])", "frame_s": float(np.median(ms_sun))},
                 {"frame": "ratio sun / no sun (medians)", "frame_s": with_sun / without},
                 {"frame": "overhead of the medians (fraction)", "frame_s": with_sun / without - 1.0},
                 {"frame": "overhead of the fastest (fraction)", "frame_s": best},
                 {"frame": "overhead, median of pairs (fraction)", "frame_s": paired},
                 {"frame": "  its 90 % interval, low (bootstrap)", "frame_s": float(lo)},
                 {"frame": "  its 90 % interval, high (bootstrap)", "frame_s": float(hi)},
                 {"frame": "process CPU overhead, median of pairs", "frame_s": cpu_paired}], ["frame", "frame_s"]))

    summary = {"on_off": {"overhead": paired, "low": float(lo), "high": float(hi), "cpu": cpu_paired,
                          "kernel_ms": 1e3 * (sum(kern[True].values()) - sum(kern[False].values())) / n_frames}}
    if a.scene_ab:
        text, summary["scene"] = scene_ab(scene, engine, obj, offs[1:], a.cache)
        print(text)
    if a.summary_json is not None:
        write_json(a.summary_json, summary)
    if a.ab_only:
        return 0
    print(table(pieces_against_monte_carlo(engine, obj), ["pixel (du, dv)", "monte_carlo", "faces", "pieces",
                                                          "engine", "faces/mc", "pieces/mc", "engine/mc"]))
    print(outline_table(engine, obj, a.shared))
    ref = jittered(engine, obj, 64)
    rows = []
    t0 = time.perf_counter()
    engine.sun_pixels.stage.map._key = None  # drawn anew: the time of a first frame of a shape
    engine.sun_pixels.stage.map.render(obj.vertices, obj.faces)
    pcss = engine.sun_pixels.stage.map.occlusion(engine.sun_pixels.stage.pts, engine.sun_pixels.stage.footprint)
    rows.append({"method": "PCSS, 1 map, 48 taps", "s": time.perf_counter() - t0,
                 "mean_abs_err": float(np.abs(pcss - ref).mean()), "max_abs_err": float(np.abs(pcss - ref).max())})
    for n in (4, 8, 16):
        t0 = time.perf_counter()
        j = jittered(engine, obj, n)
        rows.append({"method": f"jittered, {n} maps", "s": time.perf_counter() - t0,
                     "mean_abs_err": float(np.abs(j - ref).mean()), "max_abs_err": float(np.abs(j - ref).max())})
    print(table(rows, ["method", "s", "mean_abs_err", "max_abs_err"]))

    rows = []
    cap = Engine(scene, EngineParams(passes=a.passes, lighting="captured"), cache_dir=a.cache, quiet=True)
    for name, eng in (("known", engine), ("captured", cap)):
        rows.append({"lighting": name, **shared_score(a.shared, eng.render(obj).pixels)})
    print(table(rows, ["lighting", "energy_ratio", "rmse_affected", "rmse_affected_if_untouched", "spurious",
                       "rmse_object", "bias_object"]))
    est = cap.sun.estimate or {}
    print(table([{k: (f"{v:.4g}" if isinstance(v, float) else str(np.round(v, 4).tolist()))
                  for k, v in est.items()}], list(est)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
