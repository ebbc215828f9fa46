"""`photoar evaluate`: speed against error over pass budgets (seed sec. 6.4 and 7, fig. 18).

    photoar evaluate SCENE_DIR --passes 10,20,50,all --out DIR

Renders the scene's object once per pass budget from one precompute and writes
`evaluation.json` (a row per setting: passes, frame_s, traversal_s, energy_ratio,
rmse_affected, spurious, rmse_object, ssim_affected; the scorer's definitions, see
lighting/metrics.py) and `speed_vs_error.png` (frame time against rmse_affected). The error is
measured against the scene's `truth.png` when there is one, else against the path-traced
reference of `photoar reference` (`--reference-spp N`), else against the all-sources composite
(then that row itself scores zero).

`--path N` adds a drag: N poses of the object along a straight line over the floor through its
pose (app.dragpath), rendered as drag frames (FrameConfig.drag = DRAG_SCALE: the room at 1/3
resolution, app.dragframe; the room's change as DRAG_SHADOW says: maps, DRAG_PASSES of them, or the
sphere frame of app.dragshadow) from the same precompute (the release at rest refines
from the smallest pass budget given, as the GUI's slider sets it), and a row
with "passes": "drag": that drag frame at the scene's own pose, scored like the others. The path's
"stages_ms" has "python": the frame's time outside Warp kernels on the rendering thread, measured by
timers around every launch (app.glue.KernelClock): the Python and numpy glue within and between the stages.
evaluation.json gets "path": positions (N), passes (asked), n_passes (the distinct pass counts the path's frames took:
a drag frame in a room no sun lights takes at most DRAG_PASSES_NO_SUN), frame_s_mean and frame_s_p95 over frames
2..N (the first frame pays one-off work: kernels, the object's shape), and the per-phase mean
"stages_ms"; then the release at rest (drag_path): converge_s (to all-source quality against the
truth), exact_s (to the all-sources frame) and the frames shown ("shown": each one's t_s since the
move, passes, exact, frame_s, "stages_ms" and rmse_affected). Every row has the frame's per-phase
"stages_ms" too.
"""
from __future__ import annotations

import argparse
import logging
from pathlib import Path

import numpy as np

from app.config import DRAG_PASSES, DRAG_SCALE, DRAG_SHADOW  # the drag frame's settings

log = logging.getLogger("photoar")

CONVERGE_RMSE = 0.05  # levels: "all-source quality" (issue 17): rmse_affected within this of the all-sources frame's


def parse_passes(text: str) -> list[int | None]:
    """'10,20,50,all' -> [10, 20, 50, None]."""
    out: list[int | None] = []
    for part in text.split(","):
        part = part.strip().lower()
        if part == "all":
            out.append(None)
            continue
        try:
            v = int(part)
        except ValueError:
            raise argparse.ArgumentTypeError(f"pass counts are integers or 'all', got {part!r}") from None
        if v < 1:
            raise argparse.ArgumentTypeError(f"pass counts must be at least 1, got {v}")
        out.append(v)
    if not out:
        raise argparse.ArgumentTypeError("no pass counts given")
    return out


def main(scene_dir: str | Path, out: str | Path, passes: list[int | None], params=None, cache_dir=None,
         quiet: bool = False, reference_spp: int | None = None, device: str | None = None,
         path: int | None = None) -> list[dict]:
    """Rows of the evaluation (also written to out/evaluation.json and the plot); path: poses of
    the drag (None: no drag)."""
    import dataclasses

    from app.composite import default_cache_dir
    from app.engine import Engine, EngineParams
    from app.report import plot_xy, stages_ms, table
    from lighting import metrics
    from recon.io import AtomicOutput, read_image_rgb, write_json, write_png
    from recon.scene import SceneError, load_scene

    scene = load_scene(scene_dir)
    if scene.obj is None:
        raise SceneError(f"{Path(scene_dir) / 'scene.json'}: missing field 'synthetic_object'")
    params = params or EngineParams()
    engine = Engine(scene, params, cache_dir=cache_dir if cache_dir is not None else default_cache_dir(),
                    device=device, quiet=quiet)
    frames = {}
    order = sorted(set(passes), key=lambda p: (p is None, p or 0))
    if None not in order and not (Path(scene_dir) / "truth.png").is_file() and reference_spp is None:
        order.append(None)  # the all-sources frame is the reference
    for n in order:
        frames[n] = engine.render(scene.obj, dataclasses.replace(engine.frame_config(), passes=n))
    finite = [n for n in passes if n is not None]
    drag_cfg = dataclasses.replace(engine.frame_config(), passes=DRAG_PASSES, drag=DRAG_SCALE,
                                   drag_shadow=DRAG_SHADOW)
    if path is not None:
        engine.render(scene.obj, drag_cfg)  # the drag stages made, kernels compiled: the row's time is a frame's
        frames["drag"] = engine.render(scene.obj, drag_cfg)
    truth_png = Path(scene_dir) / "truth.png"
    if truth_png.is_file() and (Path(scene_dir) / "truth_mask.png").is_file():
        truth = read_image_rgb(truth_png)
        import cv2

        mask = cv2.imread(str(Path(scene_dir) / "truth_mask.png"), cv2.IMREAD_GRAYSCALE)
        against = "truth.png"
    elif reference_spp is not None:
        from app.cmd_reference import build_tracer, render_reference

        kw = {"device": device}
        if params.lighting != "known":  # the model lit as the engine lights it (its radiance mesh)
            kw = {"tracer": build_tracer(engine.scene, textures=False, patches=engine.pre.patches, device=device)}
        ref = render_reference(engine.scene, reference_spp, quiet=quiet, photo_radiance=engine.receivers.L_b,
                               response=engine.scene.response, **kw)
        truth = ref.pixels
        mask = np.rint(ref.coverage * 255).astype(np.uint8)
        against = f"path-traced reference ({ref.spp} spp)"
    else:
        truth = frames[None].pixels
        cov = engine.object_shading.object_hits(scene.obj.vertices, scene.obj.faces).coverage()
        mask = np.rint(cov * 255).astype(np.uint8)
        against = "all-sources composite"
    rows = []
    reg = metrics.regions(scene.photo, truth, mask)["affected"]  # the same for every row
    for n in passes + (["drag"] if "drag" in frames else []):
        fr = frames[n]
        s = metrics.score_regions(fr.pixels, scene.photo, truth, mask)
        rows.append({"passes": "all" if n is None else n, "n_passes": fr.stats["passes"],
                     "frame_s": fr.stats["frame_s"], "traversal_s": fr.stats["timings"]["sources"],
                     "masks_s": fr.stats["timings"]["masks"],
                     "energy_ratio": s["energy_ratio"], "rmse_affected": s["rmse_affected"],
                     "spurious": s["spurious"], "rmse_object": s["rmse_object"],
                     "ssim_affected": metrics.ssim(fr.pixels, truth, reg) if reg.any() else 1.0,
                     "n_sources": fr.stats["n_sources"], "against": against, "stages_ms": stages_ms(fr.stats),
                     **({"drag_scale": DRAG_SCALE} if n == "drag" else {})})
    log.info("\n%s", table(rows, ["passes", "frame_s", "traversal_s", "energy_ratio", "rmse_affected", "spurious",
                                  "ssim_affected"]))
    extra = {}
    if path is not None:
        rmse = None
        if against == "truth.png":  # converge_s: to the first frame within CONVERGE_RMSE of the all-sources one
            def rmse(pixels):
                return metrics.score_regions(pixels, scene.photo, truth, mask)["rmse_affected"]
        extra["path"], converged = drag_path(engine, scene, drag_cfg.passes, path, rmse, drag=DRAG_SCALE,
                                             refine_passes=min(finite) if finite else None)
        extra["converge_s"] = extra["path"]["converge_s"]
        extra["exact_s"] = extra["path"]["exact_s"]
        if None in frames:  # the refined frame against the all-sources row (levels)
            extra["path"]["converge_rmse_vs_all"] = float(np.sqrt(np.mean(
                (converged.pixels.astype(np.float64) - frames[None].pixels) ** 2)))
    with AtomicOutput(out) as stage:
        write_json(stage / "evaluation.json", {"scene": str(scene_dir), "against": against,
                                               "precompute_s": engine.precompute_s, "rows": rows,
                                               **engine.shadow_sources.stats(), **extra})
        plot_xy({"photoar": ([r["frame_s"] for r in rows], [r["rmse_affected"] for r in rows])},
                "frame time (s)", f"RMSE over affected pixels (levels) vs {against}", stage / "speed_vs_error.png",
                title=f"{scene.name}: passes {', '.join(str(r['passes']) for r in rows)}")
        for n in passes + (["drag"] if "drag" in frames else []):
            write_png(stage / f"composite_{'all' if n is None else n}.png", frames[n].pixels)
    return rows


def drag_path(engine, scene, passes: int | None, n: int, rmse=None, drag: int | None = None,
              refine_passes: int | None = None):
    """Frame times of n poses along a drag over the floor (app.dragpath) at `passes` (drag frames at
    1/drag resolution, FrameConfig.drag; None: full-resolution frames); the first frame is excluded.
    Engine.refine's budget at rest is refine_passes (None: `passes`).
    Then the release: the object back at its own pose, one frame at `passes`
    (the last move) and Engine.refine (steps of 1/30 s), which shows intermediate frames
    (Engine.refine_schedule) and ends in the all-sources frame. exact_s: the time from that move
    to the all-sources frame; converge_s: to the first frame shown at rest (the release frame
    included) whose rmse(pixels) is within CONVERGE_RMSE of the all-sources frame's (rmse:
    callable(pixels) -> rmse_affected against the scene's truth; None: converge_s = exact_s).
    Frames are scored after the timing. Returns (the "path" entry, the all-sources Frame).
    Raises RuntimeError if a frame ran per-scene precompute."""
    import time

    import dataclasses

    from app.dragpath import drag_offsets, moved
    from app.report import stages_ms

    offsets = drag_offsets(scene, scene.obj, n)
    cfg = dataclasses.replace(engine.frame_config(), passes=passes, drag=drag, drag_shadow=DRAG_SHADOW)
    before = engine.n_precompute
    stats = [engine.render(moved(scene.obj, o), cfg).stats for o in offsets]
    t0 = time.perf_counter()
    release = engine.render(scene.obj, cfg)
    shown = [(time.perf_counter() - t0, 1, release)]  # (seconds since the move, frame slices, frame)
    steps = 1
    rest = cfg if refine_passes is None else dataclasses.replace(cfg, passes=refine_passes, drag=None)
    while True:
        fr = engine.refine(scene.obj, rest, budget_s=1 / 30)
        steps += 1
        if fr is not None:
            shown.append((time.perf_counter() - t0, steps, fr))
            if fr.stats["exact"]:
                break
    exact_s, done = shown[-1][0], shown[-1][2]
    if engine.n_precompute != before:
        raise RuntimeError(f"per-scene precompute ran {engine.n_precompute - before} time(s) inside the drag path")
    times = np.array([s["frame_s"] for s in stats[1:]])
    scores = [float(rmse(f.pixels)) for _, _, f in shown] if rmse is not None else None
    first = (next(i for i, r in enumerate(scores) if r <= scores[-1] + CONVERGE_RMSE) if scores is not None
             else len(shown) - 1)
    converge_s, converge_frames = shown[first][0], shown[first][1]
    if scores is not None:
        measures = (f"seconds from the last move (the frame at `passes` of the object's own pose) until the first "
                    f"frame shown at rest (that frame, Engine.refine's intermediate frames, the all-sources frame) "
                    f"whose rmse_affected against the truth is within {CONVERGE_RMSE} of the all-sources frame's; "
                    f"exact_s: until Engine.refine returns the all-sources frame itself")
    else:
        measures = ("seconds from the last move (the frame at `passes` of the object's own pose) until Engine.refine "
                    "returns the all-sources frame of that pose (no truth to score the intermediate frames): "
                    "equal to exact_s")
    used = sorted({int(s["passes"]) for s in stats[1:] if "passes" in s})  # what the frames took (a ceiling may cut)
    entry = {"positions": int(n), "passes": "all" if passes is None else passes, "n_passes": used,
             "frame_s_mean": float(times.mean()), "frame_s_p95": float(np.percentile(times, 95)),
             "frame_s": [float(s["frame_s"]) for s in stats], "offsets_m": offsets.tolist(),
             "length_m": float(np.linalg.norm(offsets[-1] - offsets[0])), "precompute_runs": engine.n_precompute - before,
             "drag_scale": drag, "stages_ms": path_stages_ms(stats[1:]), "converge_s": converge_s,
             "converge_frames": converge_frames,
             "exact_s": exact_s, "exact_frames": steps, "converge_measures": measures,
             "release_frame_s": float(release.stats["frame_s"]), "refine_s": done.stats["refine_s"],
             "shown": [{"t_s": t, "passes": int(f.stats["passes"]), "exact": bool(f.stats.get("exact", False)),
                        "frame_s": float(f.stats["frame_s"]), "stages_ms": stages_ms(f.stats),
                        **({"rmse_affected": scores[i]} if scores is not None else {})}
                       for i, (t, _, f) in enumerate(shown)]}
    return entry, done


def path_stages_ms(all_stats: list[dict]) -> dict[str, float]:
    """Per-stage mean milliseconds over frames (app.report.mean_stages_ms) and "python": the mean of the
    frame's time outside Warp kernels on the rendering thread (app.glue.KernelClock: the Python and numpy glue,
    within the stages and between them; stats["kernel_s"]), or, for frames without that measure, the frame
    time less the sum of its timed stages."""
    from app.report import mean_stages_ms

    out = mean_stages_ms(all_stats)
    out["python"] = 1e3 * float(np.mean([s["frame_s"] - s["kernel_s"] if "kernel_s" in s else
                                         s["frame_s"] - sum(s.get("timings", {}).values()) for s in all_stats]))
    return out


def register(sub) -> None:
    from app.cli import _add_engine_args

    e = sub.add_parser("evaluate", help="speed against error over pass budgets (evaluation.json, speed_vs_error.png)")
    e.add_argument("scene", type=Path, help="scene folder")
    e.add_argument("--passes", type=parse_passes, default=parse_passes("10,20,50,all"),
                   help="comma-separated pass budgets, 'all' for one pass per source (default 10,20,50,all)")
    e.add_argument("--out", type=Path, required=True, help="output folder")
    e.add_argument("--reference-spp", type=int, default=None,
                   help="without truth.png: measure against a path-traced reference at this many samples per "
                        "pixel (default: against the all-sources composite)")
    e.add_argument("--path", type=_path_positions, default=None, metavar="N",
                   help="also time a drag: N object poses along a straight line over the floor through the "
                        "object's pose, at the smallest budget of --passes (first frame excluded)")
    _add_engine_args(e, passes=False)
    e.set_defaults(run=_run)


def _path_positions(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"path positions must be an integer, got {text!r}") from None
    if v < 2:
        raise argparse.ArgumentTypeError(f"a path needs at least 2 positions (the first frame is excluded), got {v}")
    return v


def _run(a) -> int:
    from app.cli import _params

    import dataclasses

    params = dataclasses.replace(_params(a), passes=None)
    rows = main(a.scene, a.out, a.passes, params, cache_dir=a.cache, quiet=a.quiet, reference_spp=a.reference_spp,
                device=a.device, path=a.path)
    if a.quiet:  # the rows' table is a log line; -q keeps one line a row
        for r in rows:
            print(f"passes {r['passes']}: frame {r['frame_s']:.2f} s, energy {r['energy_ratio']:.3f}, "
                  f"rmse {r['rmse_affected']:.2f}, spurious {r['spurious']:.4f}")
    if a.path is not None:
        import json

        pth = json.loads((a.out / "evaluation.json").read_text())["path"]
        print(f"path of {pth['positions']} positions at {pth['passes']} passes: frame mean "
              f"{pth['frame_s_mean']:.3f} s, p95 {pth['frame_s_p95']:.3f} s (first frame excluded); at rest "
              f"all-source quality after {pth['converge_s']:.2f} s, exact all sources after {pth['exact_s']:.2f} s")
    print(a.out / "evaluation.json")
    return 0
