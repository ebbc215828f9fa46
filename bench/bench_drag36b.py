"""Drag-frame levers A/B (issue 36, drag36b): per room, the drag path's CPU and wall time per frame and the drag
row's score for several drag-frame variants, interleaved in rounds in one process (the loaded 2-core machine).

usage: python bench/bench_drag36b.py [--scenes window_room,sun_room,DIR,...] [--variants base,s4,...] [--path 8]
                                     [--rounds 2] [--out FILE.json] [--object-replay REPS]

A variant is a name from VARIANTS: a FrameConfig for the drag frame and, optionally, a change to the engine made
before its frames and undone after (so every variant runs on the same Engine, caches and load). Per variant it
prints the path's mean process CPU per frame (all threads: the measure on a loaded machine), its mean / p95 wall,
the per-stage wall means, and the drag frame at the scene's own pose scored against the truth (energy_ratio /
rmse_affected; bound 1.5 x the all-sources frame's rmse_affected + 0.5, energy 0.93-1.07), with its SHA-256.
"""
from __future__ import annotations

import argparse
import contextlib
import dataclasses
import hashlib
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
from app.evaluate import path_stages_ms  # noqa: E402
from lighting import metrics  # noqa: E402
from recon.io import read_image_rgb  # noqa: E402
from recon.scene import load_scene  # noqa: E402


@contextlib.contextmanager
def _object_params(eng: Engine, **kw):
    """The engine's EngineParams with `kw` changed while the block runs (read per frame: params.object)."""
    old = eng.params
    eng.params = dataclasses.replace(old, **kw)
    try:
        yield
    finally:
        eng.params = old


@contextlib.contextmanager
def _nothing(eng: Engine):
    yield


@contextlib.contextmanager
def _drag_supersample(eng: Engine, s: int, scale: int = DRAG_SCALE):
    """The drag stages' (at 1/scale) object rays per pixel side set to s while the block runs
    (DragStages.supersample)."""
    st = eng.pixel_stages(scale)
    old = (st.supersample, st._scene_depth)
    st.supersample, st._scene_depth = s, _DEPTHS.get((id(st), s))
    try:
        yield
    finally:
        _DEPTHS[(id(st), s)] = st._scene_depth  # kept for the next frames of the variant (made once)
        st.supersample, st._scene_depth = old


_DEPTHS: dict = {}


@contextlib.contextmanager
def _drag_stages(eng: Engine, scale: int, supersample: int | None = None, **kw):
    """The engine's drag stages at 1/scale replaced, while the block runs, by a DragStages(eng, scale, **kw) made
    once per variant (e.g. map_res: its cluster map size), with `supersample` rays per pixel side if given."""
    from app.dragframe import DragStages

    from app import dragframe

    div = kw.pop("map_div", None)
    key = (id(eng), scale, supersample, div, tuple(sorted(kw.items())))
    if key not in _STAGES:
        made = dragframe.drag_map_res
        if div is not None:  # every map (clusters and single sources) at map_res / div, whatever the scale
            dragframe.drag_map_res = lambda s, map_res: made(div, map_res)
        try:
            _STAGES[key] = DragStages(eng, scale, **kw)
        finally:
            dragframe.drag_map_res = made
        if supersample is not None:
            _STAGES[key].supersample = supersample
    old = eng._drag.get(scale)
    eng._drag[scale] = _STAGES[key]
    try:
        yield
    finally:
        if old is None:
            del eng._drag[scale]
        else:
            eng._drag[scale] = old


_STAGES: dict = {}


@contextlib.contextmanager
def _hard_centres(eng: Engine, on: bool, scale: int = DRAG_SCALE):
    """The drag stages' patch centres with the cluster maps' hard lookup (ShadowPass.hard_centres) on or off while
    the block runs (drag107)."""
    sp = eng.pixel_stages(scale).shadow_pass
    old = sp.hard_centres
    sp.hard_centres = on
    try:
        yield
    finally:
        sp.hard_centres = old


@contextlib.contextmanager
def _main107(eng: Engine, scale: int = DRAG_SCALE):
    """main's drag frame before drag107: 64 passes whatever the sun, the centres' penumbrae."""
    with _passes_no_sun(eng, None, scale), _hard_centres(eng, False, scale):
        yield


@contextlib.contextmanager
def _passes_no_sun(eng: Engine, n: int | None, scale: int = DRAG_SCALE):
    """The drag stages' pass ceiling in a room no sun lights (DragStages.passes_no_sun) set to n while the block
    runs (None: the passes asked; drag107)."""
    st = eng.pixel_stages(scale)
    old = st.passes_no_sun
    st.passes_no_sun = n
    try:
        yield
    finally:
        st.passes_no_sun = old


@contextlib.contextmanager
def _source_grid(eng: Engine, grid: float | None, scale: int = DRAG_SCALE):
    """The drag stages' source-list grid (DragStages.source_grid, bounding radii; None: a selection every frame)
    set to `grid` while the block runs, with the kept selection of this grid's last frame (drag108: each variant keeps
    its own, as if it ran alone)."""
    st = eng.pixel_stages(scale)
    old = (st.source_grid, st._sources)
    st.source_grid, st._sources = grid, _KEPT.get((id(st), grid))
    try:
        yield
    finally:
        _KEPT[(id(st), grid)] = st._sources
        st.source_grid, st._sources = old


_KEPT: dict = {}


@contextlib.contextmanager
def _near_grid(eng: Engine, on: bool, scale: int = DRAG_SCALE):
    """The drag stages' near pixels of the object light on the adaptive screen grid (ObjectLight.near_grid, as at
    rest) or each summed (DRAG_LIGHT_GRID False) while the block runs (drag108)."""
    ol = eng.pixel_stages(scale).object_light
    old = ol.near_grid
    ol.near_grid = on
    try:
        yield
    finally:
        ol.near_grid = old


def _cfg(scale: int = DRAG_SCALE, passes: int = DRAG_PASSES) -> FrameConfig:
    return FrameConfig(passes=passes, drag=scale)


# name -> (FrameConfig, context manager factory taking the engine)
@contextlib.contextmanager
def _tilted(eng: Engine, on: bool):
    """The drag frame's tables for a tilted object (DragObject.tilted, drag109) on or off while the block runs (off:
    main's before drag109, the tilted object shaded as at rest)."""
    od = eng.object_drag
    old = od.tilted
    od.tilted = on
    try:
        yield
    finally:
        od.tilted = old


VARIANTS = {
    "base": (_cfg(), _nothing),
    "main107": (_cfg(), _main107),  # main's drag frame before drag107 (64 passes, the centres' penumbrae)
    "softcen": (_cfg(), lambda e: _hard_centres(e, False)),  # drag107 without the centres' hard lookup
    "ns64": (_cfg(), lambda e: _passes_no_sun(e, None)),  # main's drag frame before drag107: 64 passes, sun or not
    "s4": (_cfg(4), _nothing),
    "s5": (_cfg(5), _nothing),
    "s6": (_cfg(6), _nothing),
    "s4p56": (_cfg(4, 56), _nothing),
    "s5p48": (_cfg(5, 48), _nothing),
    "p48": (_cfg(passes=48), _nothing),
    "s4p48": (_cfg(4, 48), _nothing),
    "noOL": (_cfg(), lambda e: _object_params(e, object_light=False)),
    "no2nd": (_cfg(), lambda e: _object_params(e, second_order=False)),
    "ss1": (_cfg(), lambda e: _drag_supersample(e, 1)),
    "ss2": (_cfg(), lambda e: _drag_supersample(e, 2)),
    "s3ss2": (_cfg(3), lambda e: _drag_supersample(e, 2, 3)),  # main's drag frame whatever the defaults
    "s4ss1": (_cfg(4), lambda e: _drag_supersample(e, 1, 4)),
    "s4ss2": (_cfg(4), lambda e: _drag_supersample(e, 2, 4)),
    "s4m85ss1": (_cfg(4), lambda e: _drag_stages(e, 4, 1, map_res=85)),
    "s4m85ss2": (_cfg(4), lambda e: _drag_stages(e, 4, 2, map_res=85)),
    "s4m128ss1": (_cfg(4), lambda e: _drag_stages(e, 4, 1, map_res=128)),
    "s4d3ss1": (_cfg(4), lambda e: _drag_stages(e, 4, 1, map_div=3)),
    "s4d3p48": (_cfg(4, 48), lambda e: _drag_stages(e, 4, 1, map_div=3)),  # drag107
    "srcnone": (_cfg(), lambda e: _source_grid(e, None)),  # drag108: a source list every drag frame (main's)
    "src25": (_cfg(), lambda e: _source_grid(e, 0.25)),  # drag108: the source list kept on a 0.25-radius grid
    "src50": (_cfg(), lambda e: _source_grid(e, 0.5)),
    "src100": (_cfg(), lambda e: _source_grid(e, 1.0)),
    "src200": (_cfg(), lambda e: _source_grid(e, 2.0)),
    "neargrid": (_cfg(), lambda e: _near_grid(e, True)),  # drag108: the near pixels on the adaptive grid
    "tilt0": (_cfg(), lambda e: _tilted(e, False)),  # drag109: a tilted object shaded as at rest (main's before)
}


_STAGE_CPU: dict[str, float] = {}  # process CPU seconds per stage of the frames since the last reset


def _count_stage_cpu() -> None:
    """Wrap app.glue.FrameTimer so that every tick also adds the process CPU since the last tick (all threads: the
    stage's kernels on both cores) to _STAGE_CPU[name]."""
    from app import glue

    init, tick = glue.FrameTimer.__init__, glue.FrameTimer.tick

    def init2(self):
        init(self)
        self._cpu_last = time.process_time()

    def tick2(self, name, t):
        now = time.process_time()
        _STAGE_CPU[name] = _STAGE_CPU.get(name, 0.0) + now - self._cpu_last
        self._cpu_last = now
        return tick(self, name, t)

    glue.FrameTimer.__init__, glue.FrameTimer.tick = init2, tick2


def scene_dir(name: str) -> Path:
    p = Path(name).expanduser()
    return p if p.is_dir() else Path(os.environ.get("PHOTOAR_SHARED", ROOT.parent / "shared")) / "scenes" / name


def bench_scene(d: Path, names: list[str], n_path: int, rounds: int) -> dict:
    import cv2

    scene = load_scene(d)
    eng = Engine(scene, EngineParams(), cache_dir=default_cache_dir(), quiet=True)
    truth = read_image_rgb(d / "truth.png")
    mask = cv2.imread(str(d / "truth_mask.png"), cv2.IMREAD_GRAYSCALE)

    def score(fr) -> dict:
        s = metrics.score_regions(fr.pixels, scene.photo, truth, mask)
        return {"energy": float(s["energy_ratio"]), "rmse": float(s["rmse_affected"]),
                "rmse_object": float(s["rmse_object"]),
                "sha": hashlib.sha256(np.ascontiguousarray(fr.pixels).tobytes()).hexdigest()[:12]}

    full = eng.render(scene.obj, FrameConfig())
    out = {"scene": d.name, "all": score(full)}
    out["bound"] = 1.5 * out["all"]["rmse"] + 0.5
    offsets = drag_offsets(scene, scene.obj, n_path)
    stats = {n: [] for n in names}
    stage_cpu = {n: {} for n in names}
    scores = {}
    for n in names:  # the drag frame at the scene's own pose, scored (and every variant's one-off work done)
        cfg, ctx = VARIANTS[n]
        with ctx(eng):
            for st in eng._drag.values():  # no pose reuse (DragStages.near_pose) across variants (drag107)
                getattr(st, "_near", {}).clear()
            eng.render(scene.obj, cfg)  # as evaluate's drag row: the second frame at the pose
            scores[n] = score(eng.render(scene.obj, cfg))
            eng.render(moved(scene.obj, offsets[0]), cfg)
    for r in range(rounds):  # each pose rendered by every variant in turn: the same load for all
        for i, o in enumerate(offsets[1:]):
            # the order reversed every other pose: the first render of a pose also fills the caches the others
            # read at that pose (the object's shape, DragStages.near_pose), which biased the first variant's
            # object stages (drag107)
            for n in (names if (r + i) % 2 == 0 else names[::-1]):
                cfg, ctx = VARIANTS[n]
                with ctx(eng):
                    _STAGE_CPU.clear()
                    c0, w0 = time.process_time(), time.perf_counter()
                    ds = eng.pixel_stages(cfg.drag)
                    r0 = ds.sources_reused
                    st = eng.render(moved(scene.obj, o), cfg).stats
                    stats[n].append({**st, "cpu_s": time.process_time() - c0, "wall_s": time.perf_counter() - w0,
                                     "sources_reused": ds.sources_reused - r0})
                    for k, v in _STAGE_CPU.items():
                        stage_cpu[n][k] = stage_cpu[n].get(k, 0.0) + v
    out["rows"] = []
    for n in names:
        cpu = np.array([s["cpu_s"] for s in stats[n]]) * 1e3
        wall = np.array([s["wall_s"] for s in stats[n]]) * 1e3
        sc = scores[n]
        out["rows"].append({"variant": n, "cpu_ms": float(cpu.mean()), "cpu_med": float(np.median(cpu)),
                            "wall_ms": float(wall.mean()), "wall_p95": float(np.percentile(wall, 95)), **sc,
                            "ok": bool(sc["rmse"] <= out["bound"] and 0.93 <= sc["energy"] <= 1.07),
                            "stages_ms": path_stages_ms(stats[n]),
                            "sources_reused": sum(s["sources_reused"] for s in stats[n]) / len(stats[n]),
                            "stages_cpu_ms": {k: 1e3 * v / len(stats[n]) for k, v in stage_cpu[n].items()}})
    return out


def object_replay(d: Path, n_path: int, reps: int) -> dict:
    """The drag frame's first steps alone (Engine.frame_object: the object's shape, its camera hits against the kept
    scene depth, its coverage) at each pose of the path, with 2 x 2 and with 1 ray a pixel, interleaved `reps` times:
    process CPU per call (ms), median over the calls of each pose, then mean over the poses."""
    from app.glue import FrameTimer

    scene = load_scene(d)
    eng = Engine(scene, EngineParams(), cache_dir=default_cache_dir(), quiet=True)
    st = eng.pixel_stages(DRAG_SCALE)
    depth = {s: None for s in (2, 1)}
    offsets = drag_offsets(scene, scene.obj, n_path)[1:]
    cpu = {s: [[] for _ in offsets] for s in depth}
    for r in range(reps + 1):
        for i, o in enumerate(offsets):
            obj = moved(scene.obj, o)
            for s in depth:
                st.supersample, st._scene_depth = s, depth[s]
                c0 = time.process_time()
                ft = FrameTimer()
                eng.frame_object(obj, ft, st.scene_depth(), s)
                ft.close()
                if r:  # the first round casts the scene depth's tiles
                    cpu[s][i].append(time.process_time() - c0)
                depth[s] = st._scene_depth
    return {f"ss{s}": float(np.mean([np.median(c) for c in cpu[s]]) * 1e3) for s in depth}


def print_scene(res: dict) -> None:
    a = res["all"]
    print(f"\n{res['scene']}: all sources {a['energy']:.3f} / {a['rmse']:.2f} / {a.get('rmse_object', 0):.2f} "
          f"(bound {res['bound']:.2f}) {a['sha']}")
    keys = ["proxy", "object", "sources", "masks", "sun", "object_light", "object_shading", "second_order", "compose",
            "upsample"]
    print("(stage columns: process CPU ms per frame, all threads)")
    print(f"{'variant':>10} {'cpu':>6} {'cpumed':>6} {'wall':>6} {'p95':>6} {'energy':>6} {'rmse':>5} {'r_obj':>5} " +
          " ".join(f"{k[:7]:>7}" for k in keys) + "  sha")
    for r in res["rows"]:
        st = r["stages_cpu_ms"]
        print(f"{r['variant']:>10} {r['cpu_ms']:6.1f} {r['cpu_med']:6.1f} {r['wall_ms']:6.1f} {r['wall_p95']:6.1f} "
              f"{r['energy']:6.3f} {r['rmse']:5.2f} {r.get('rmse_object', 0):5.2f} " + " ".join(f"{st.get(k, 0.0):7.1f}" for k in keys) +
              f"  {r['sha']}" + f" reused {r.get('sources_reused', 0):.2f}" + ("" if r["ok"] else "  OUT"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default="window_room,sun_room")
    ap.add_argument("--variants", default="base,s4,noOL,no2nd")
    ap.add_argument("--path", type=int, default=8)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--object-replay", type=int, default=0, metavar="REPS",
                    help="instead: the object's first steps alone, 2 x 2 against 1 ray a pixel, REPS rounds")
    a = ap.parse_args()
    if a.object_replay:
        for s in a.scenes.split(","):
            res = object_replay(scene_dir(s), a.path, a.object_replay)
            print(scene_dir(s).name, "object stage CPU ms a frame:", res, flush=True)
        return
    names = a.variants.split(",")
    _count_stage_cpu()
    for n in names:
        if n not in VARIANTS:
            raise SystemExit(f"unknown variant {n!r}; known: {', '.join(VARIANTS)}")
    results = []
    for s in a.scenes.split(","):
        res = bench_scene(scene_dir(s), names, a.path, a.rounds)
        print_scene(res)
        sys.stdout.flush()
        results.append(res)
    if a.out is not None:
        from recon.io import write_json

        write_json(a.out, results)


if __name__ == "__main__":
    main()
