"""The drag frame's CPU before and after glue111 (issue 36), variants interleaved in one process.

usage: python bench/bench_glue111.py [--scenes sun_room,window_room,lamps_room] [--path 12] [--rounds 2]
                                    [--variants base,new,split] [--rest]

glue111 changed four pieces of per-frame glue, each for the same bytes:
- ShadowSources._pairs (lighting/frame_sources.py) takes its row and column cuts from flags over the leaves and
  passes (_cuts) instead of np.unique and np.searchsorted;
- the triangle normals and other 3-vector cross products of the per-frame stages take kernels.vec.cross3 (numpy's
  formula per component) instead of np.cross;
- DragObject.shape (app.stages.object_drag) and ObjectShading.object_shape compare the quantised shape with the
  last one's instead of hashing it (SHA-1) every frame; object_light.shape_key (the proxy's key, ~8 calls a frame)
  keeps the last arrays' key.
And it can cut the second order's launch (ComposeStage.second_order) over the cores by its work, (receiver vertex,
changed patch) pairs (app.stages.compose.SO_MIN_PAIRS; off by default: slower on the loaded machine), not by the
vertex count, which leaves the drag frame's ~1200 vertices one launch on the rendering thread.
Variant `base` puts the old code back (the np.unique _pairs below, np.cross in every module that imported cross3, the
hashed shape keys, kept apart so that both variants share the kept shapes); `new` is the code as it is; `split` is `new` with SO_MIN_PAIRS = 1 << 17. Besides the CPU times,
the wall time of the frame's stages (stats["timings"]) are printed. Per scene one Engine, evaluate's drag path (DRAG_PASSES, DRAG_SCALE, DRAG_SHADOW; --path
poses after two warm-up frames), each pose rendered by every variant in turn (the order reversed every other
pose and round, so both see the same load). Per variant: the process's CPU (time.process_time, all threads), the
rendering thread's CPU (time.thread_time) and its glue CPU per FrameTimer stage (bench_glue_cpu.ThreadCpu), ms a
frame; and the SHA-256 of the drag path's composites (pixels and radiance, all poses chained, first 12 hex digits):
the same in both variants when the change is byte-identical (--rest: also the all-sources frame's pixels at the
scene's own pose, per variant). In a room no sun lights the drag frame's source list is kept while the grown box
holds (app.dragframe.DRAG_SOURCE_GRID): the variant that renders a pose first makes it, so the sources stage is
compared between variants in sun rooms only. Timings depend on the load: compare rows of one run.
"""
from __future__ import annotations

import argparse
import collections
import hashlib
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.dragpath import moved  # noqa: E402
from app.stages import compose, object_drag, object_light, object_shading, sun  # noqa: E402
from bench.bench_glue_cpu import ThreadCpu, warm_drag  # noqa: E402
from kernels import vec  # noqa: E402
from lighting import frame_sources  # noqa: E402


def _cuts_base(size, lo, hi):
    """frame_sources._cuts as ShadowSources._pairs did it before glue111: np.unique of the bounds, and each value's
    index by np.searchsorted (here over all of [0, size], where the old code searched the bounds themselves)."""
    cuts = np.unique(np.concatenate([[0, size], lo, hi]))
    return cuts, np.searchsorted(cuts, np.arange(size + 1))


NEW_CUTS = frame_sources._cuts
NEW_SHAPE = object_drag.DragObject.shape


def _shape_base(self, v, n, f, R):
    """DragObject.shape before glue111: the key a SHA-1 of the quantised shape (kept apart, in _base_key, so that the
    variants share the kept shape and neither makes it again while the shape stays)."""
    mean = v.mean(0)
    local, nl = (v - mean) @ R, n @ R
    cfg = self.shading.config
    key = hashlib.sha1(np.floor(local * 1e5 + object_drag.KEY_OFFSET).tobytes()
                       + np.floor(nl * 1e5 + object_drag.KEY_OFFSET).tobytes() + np.ascontiguousarray(f).tobytes()
                       + f"{cfg.prt_dirs} {cfg.vis_stride}".encode()).hexdigest()
    if self._shape is None or getattr(self, "_base_key", None) != key:
        self._base_key = key
        return NEW_SHAPE(self, v, n, f, R)
    return self._shape[1], mean


def _cross_users() -> list:
    """The modules that took cross3 by name (not kernels.vec itself, nor this bench)."""
    return [m for m in list(sys.modules.values())
            if m is not None and getattr(m, "cross3", None) in (vec.cross3, np.cross)
            and m.__name__ not in ("kernels.vec", "__main__", "bench.bench_glue111")]


NEW_SHAPE_KEY = object_light.shape_key
NEW_OBJECT_SHAPE = object_shading.ObjectShading.object_shape


def _shape_key_base(pv, pf):
    """object_light.shape_key before glue111: hashed every call."""
    return hashlib.sha1(np.round(pv - pv.mean(0), 6).tobytes() + np.ascontiguousarray(pf).tobytes()).hexdigest()


def _object_shape_base(self, obj):
    """ObjectShading.object_shape before glue111: its key a SHA-1 every frame (kept apart, in _base_key; a new key
    goes through the new method, which keeps or makes the shape, so both variants share the shape and its BVHs),
    then the kept shape translated as before."""
    p, v = self.config, obj.vertices
    offset = v.mean(0)
    key = hashlib.sha1(np.round(v - offset, 6).tobytes() + np.round(obj.normals, 6).tobytes()
                       + np.ascontiguousarray(obj.faces).tobytes() + str(p.proxy_faces).encode()).hexdigest()
    sh = self._shape if self.config.shape_cache else None
    if sh is None or getattr(self, "_base_key", None) != key:
        self._base_key = key
        return NEW_OBJECT_SHAPE(self, obj)
    pv, sv = sh["pv"] + offset, sh["sv"] + offset
    if not np.array_equal(offset, sh["offset"]):
        sh["proxy_occ"].move(pv)
        sh["shade_occ"].move(sv)
        sh["offset"] = offset
    self._shade_occ = (sv, sh["shade_occ"])
    self.face_groups = sh["groups"]
    return pv, sh["pf"], sh["proxy_occ"], (sv, sh["sn"], sh["sf"]), sh["shade_occ"]


def use(variant: str) -> None:
    """base: the code before glue111; new: glue111's; split: glue111's with the second order cut by work."""
    frame_sources._cuts = _cuts_base if variant == "base" else NEW_CUTS
    for m in _cross_users():
        m.cross3 = np.cross if variant == "base" else vec.cross3
    compose.SO_MIN_PAIRS = 1 << 17 if variant == "split" else None
    object_drag.DragObject.shape = _shape_base if variant == "base" else NEW_SHAPE
    object_light.shape_key = sun.shape_key = _shape_key_base if variant == "base" else NEW_SHAPE_KEY
    object_shading.ObjectShading.object_shape = _object_shape_base if variant == "base" else NEW_OBJECT_SHAPE


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", default="sun_room,window_room,lamps_room")
    ap.add_argument("--path", type=int, default=12)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--variants", default="base,new")
    ap.add_argument("--rest", action="store_true", help="also hash the all-sources frame at the scene's own pose")
    args = ap.parse_args()
    variants = args.variants.split(",")
    cpu = None
    for name in args.scenes.split(","):
        scene, eng, cfg, offsets = warm_drag(name, args.path)
        cpu = cpu or ThreadCpu()
        print(f"{name}: modules using cross3: {sorted(m.__name__ for m in _cross_users())}")
        rows = {v: [] for v in variants}
        stage = {v: collections.defaultdict(float) for v in variants}
        wall = {v: collections.defaultdict(float) for v in variants}
        sha = {v: [hashlib.sha256(), hashlib.sha256()] for v in variants}
        for r in range(args.rounds):
            for i, o in enumerate(offsets):
                order = variants if (i + r) % 2 == 0 else variants[::-1]
                for v in order:
                    use(v)
                    before = dict(cpu.stage)
                    k0 = cpu.kernel
                    c, p = time.thread_time(), time.process_time()
                    cpu.start_frame()
                    fr = eng.render(moved(scene.obj, o), cfg)
                    rows[v].append((time.process_time() - p, time.thread_time() - c, cpu.kernel - k0))
                    for k, x in fr.stats.get("timings", {}).items():
                        if isinstance(x, (int, float)):
                            wall[v][k] += x
                    for k, x in cpu.stage.items():
                        stage[v][k] += x - before.get(k, 0.0)
                    if r == 0:
                        sha[v][0].update(np.ascontiguousarray(fr.pixels).tobytes())
                        sha[v][1].update(np.ascontiguousarray(fr.radiance).tobytes())
        if args.rest:  # the frame at rest, every source, at the scene's own pose, once per variant
            for v in variants:
                use(v)
                fr = eng.render(scene.obj, eng.frame_config())
                print(f"  {v:5s} all-sources frame at the scene's pose: pixels "
                      f"{hashlib.sha256(np.ascontiguousarray(fr.pixels).tobytes()).hexdigest()[:12]}")
        use("new")
        for v in variants:
            n = len(rows[v])
            proc, thread, kern = 1e3 * np.mean(rows[v], 0)
            st = {k: round(1e3 * x / n, 2) for k, x in stage[v].items()}
            print(f"  {v:5s} frames {n}: process cpu {proc:.1f}, thread cpu {thread:.1f}, glue {thread - kern:.1f} ms; "
                  f"pixels {sha[v][0].hexdigest()[:12]} radiance {sha[v][1].hexdigest()[:12]}")
            print(f"        glue per stage (ms): {st}")
            print(f"        wall per stage (ms): { {k: round(1e3 * x / n, 2) for k, x in wall[v].items()} }")


if __name__ == "__main__":
    main()
