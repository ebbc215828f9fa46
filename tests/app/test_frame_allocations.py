"""An allocation-free frame (issue 17, item 2): over frames 2..N of a drag (app.dragpath) of the
bundled demo scene's object, the engine allocates no Warp array (wp.zeros/empty/full/clone,
wp.array copies of host data: every array that owns new memory) and builds no Warp BVH
(wp.Mesh, wp.Bvh); the first frame of a shape may allocate everything at capacity, and the first frame
with a map per source (the all-sources frame) its own masked sums (ShadowPass.sums_source).

Every allocation is charged to the stage whose block was running: the stage of the next
`tick("<stage>", ...)` after the allocating line in Engine._frame_steps, the names of
stats['timings']. A failure lists the counts per stage and the places that allocated.
"""
from __future__ import annotations

import collections
import contextlib
import dataclasses
import inspect
import os
import re
import sys
import threading

import numpy as np
import pytest
import warp as wp

from app.cli import demo_scene_dir
from app.config import DRAG_PASSES, DRAG_SCALE, DRAG_SHADOW
from app.dragpath import drag_offsets, moved
from app.engine import Engine, EngineParams, FrameConfig
from recon.scene import load_scene

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
_TICK = re.compile(r"""tick\(\s*["'](\w+)["']""")
_TICK_LINES: dict = {}  # code object -> [(line, stage)] of its tick calls
# the allocation helpers (Buffer, Workspace): an allocation is placed at the line that called them
HELPERS = (os.path.join("kernels", "buffers.py"),)


def _stage_ticks(code) -> list[tuple[int, str]]:
    if code not in _TICK_LINES:
        try:
            lines, start = inspect.getsourcelines(code)
        except (OSError, TypeError):
            lines, start = [], 0
        _TICK_LINES[code] = [(start + i, m.group(1)) for i, ln in enumerate(lines) for m in [_TICK.search(ln)] if m]
    return _TICK_LINES[code]


def _stage_of(f) -> str | None:
    """The stage running in the stack ending at frame f: the next tick after _frame_steps's line."""
    while f is not None:
        ticks = _stage_ticks(f.f_code) if f.f_code.co_name == "_frame_steps" else []
        if ticks:
            after = [name for line, name in ticks if line >= f.f_lineno]
            return after[0] if after else "after the last stage"
        f = f.f_back
    return None


def _where(render_thread: int) -> tuple[str, str]:
    """(stage, place) of the allocation being made: the stage from the frame function's next
    tick (for a launch in a worker thread, app.runtime's, the stage the rendering thread waits
    in), the place the innermost project line outside the tests and the HELPERS (file:line function),
    with the helper's line it went through."""
    place, via = None, None
    f = inspect.currentframe().f_back.f_back
    here = f
    while f is not None:
        fn = f.f_code.co_filename
        # the project's own files: a venv inside the checkout (.venv, as `make deps` makes it) holds warp's
        if fn.startswith(ROOT) and "/tests/" not in fn and "site-packages" not in fn:
            line = f"{os.path.relpath(fn, ROOT)}:{f.f_lineno} {f.f_code.co_name}"
            if os.path.relpath(fn, ROOT) not in HELPERS:
                place = line if via is None else f"{line} (through {via})"
                break
            via = via or line
        f = f.f_back
    place = place or via or "?"
    stage = _stage_of(here)
    if stage is None and threading.get_ident() != render_thread:
        stage = _stage_of(sys._current_frames().get(render_thread))
    return stage or "outside the frame's stages", place


@contextlib.contextmanager
def counting_allocations():
    """Record (kind, stage, place) of every Warp array that allocates memory and every BVH built."""
    events: list[tuple[str, str, str]] = []
    me = threading.get_ident()
    init = wp.array.__init__
    mesh_init, bvh_init = wp.Mesh.__init__, wp.Bvh.__init__

    def array_init(self, *a, **k):
        init(self, *a, **k)
        if getattr(self, "deleter", None) is not None and getattr(self, "ptr", None):  # owns new memory
            events.append(("array", *_where(me)))

    def mesh(self, *a, **k):
        events.append(("Mesh", *_where(me)))
        mesh_init(self, *a, **k)

    def bvh(self, *a, **k):
        events.append(("Bvh", *_where(me)))
        bvh_init(self, *a, **k)

    wp.array.__init__, wp.Mesh.__init__, wp.Bvh.__init__ = array_init, mesh, bvh
    try:
        yield events
    finally:
        wp.array.__init__, wp.Mesh.__init__, wp.Bvh.__init__ = init, mesh_init, bvh_init


def _report(events) -> str:
    per_stage = collections.Counter(stage for _, stage, _ in events)
    places = collections.Counter(f"{kind} in {stage}: {place}" for kind, stage, place in events)
    return (f"allocations per stage over frames 2..N: {dict(per_stage)}\n"
            + "\n".join(f"  {n:4d} x {p}" for p, n in places.most_common(40)))


@pytest.fixture(scope="module")
def drag_allocations(tmp_path_factory):
    """Events of frames 2..N of a 6-position drag at 10 passes and, at the last pose, the all-sources
    frame (batches of maps of the same capacity); frame 1 and an all-sources frame at its pose made first."""
    scene = load_scene(demo_scene_dir())
    eng = Engine(scene, EngineParams(patch_size=0.35), cache_dir=tmp_path_factory.mktemp("cache"), quiet=True)
    offs = drag_offsets(scene, scene.obj, 6)
    first = eng.render(moved(scene.obj, offs[0]), FrameConfig(passes=10))
    eng.render(moved(scene.obj, offs[0]), FrameConfig(passes=None))
    with counting_allocations() as events:
        frames = [eng.render(moved(scene.obj, o), FrameConfig(passes=10)) for o in offs[1:]]
        frames.append(eng.render(moved(scene.obj, offs[-1]), FrameConfig(passes=None)))
    return first, frames, events


def test_the_counter_sees_allocations():
    # the patch counts what allocates (zeros, copies of host data, clones, BVHs) and not views or aliases
    with counting_allocations() as ev:
        a = wp.zeros(8, dtype=wp.float32, device="cpu")
        wp.array(np.ones(4, np.float32), dtype=wp.float32, device="cpu")
        wp.clone(a)
        a[2:4]  # a view: no memory
        wp.array(np.ones(4, np.float32), dtype=wp.float32, device="cpu", copy=False)  # an alias: no memory
        pts = wp.array(np.eye(3, dtype=np.float32), dtype=wp.vec3, device="cpu")
        wp.Mesh(points=pts, indices=wp.array(np.arange(3, dtype=np.int32), dtype=wp.int32, device="cpu"))
    kinds = collections.Counter(k for k, _, _ in ev)
    assert kinds == {"array": 5, "Mesh": 1}


def test_the_report_names_the_caller_of_a_buffer():
    # an allocation made through kernels.buffers (Buffer, Workspace) is placed at the project line that asked for
    # it, here kernels.drag_gather.gather_seen's uploads into a fresh workspace, with the helper's line after it
    from kernels.buffers import Workspace
    from kernels.drag_gather import gather_seen

    vis = wp.array(np.ones((2, 4), np.float32), dtype=wp.float32, device="cpu")
    poly = np.array([[[-1.0, 0.0, -1.0], [-1.0, 0.0, 1.0], [1.0, 0.0, 1.0], [1.0, 0.0, -1.0]]])
    with counting_allocations() as ev:
        gather_seen(np.array([[0.0, 1.0, 0.0], [0.2, 1.0, 0.0]]), np.array([[0.0, -1.0, 0.0]] * 2), np.arange(2),
                    vis, poly, np.ones((1, 3)), np.eye(3), 2, "cpu", Workspace())
    places = [p for _, _, p in ev]
    assert len(places) >= 4  # its inputs, each a buffer of the workspace
    assert all(re.fullmatch(r"kernels/drag_gather\.py:\d+ gather_seen \(through kernels/buffers\.py:\d+ \w+\)", p)
               for p in places), places


def test_drag_renders_real_frames(drag_allocations):
    # the frames counted are real work: shadows and the object change along the drag
    first, frames, _ = drag_allocations
    assert all(f.stats["passes"] >= 2 and f.stats["n_mask_pixels"] > 1000 for f in frames)
    assert np.abs(frames[0].radiance - frames[-2].radiance).max() > 0.01
    assert frames[-1].stats["passes"] > frames[0].stats["passes"]  # the all-sources frame has more maps


def test_shadow_pass_allocates_nothing_after_the_first_frame(drag_allocations):
    _, _, events = drag_allocations
    mine = [e for e in events if e[1] == "masks"]
    assert not mine, _report(events)


def test_frame_allocates_nothing_after_the_first_frame(drag_allocations):
    # every stage: no Warp array allocated, no BVH built after the first frame of a shape
    _, _, events = drag_allocations
    assert not events, _report(events)


def test_drag_frame_allocates_nothing_after_its_first_frame(tmp_path_factory):
    # the drag frame (FrameConfig.drag, app.dragframe): its coarse stages and full-resolution compose are
    # made on the first drag frame; frames 2..N of a drag allocate no Warp array and build no BVH
    scene = load_scene(demo_scene_dir())
    eng = Engine(scene, EngineParams(patch_size=0.35), cache_dir=tmp_path_factory.mktemp("cache"), quiet=True)
    offs = drag_offsets(scene, scene.obj, 5)
    cfg = FrameConfig(passes=10, drag=2)
    eng.render(moved(scene.obj, offs[0]), cfg)
    with counting_allocations() as events:
        frames = [eng.render(moved(scene.obj, o), cfg) for o in offs[1:]]
    assert all(f.stats["passes"] >= 2 for f in frames)
    assert not events, _report(events)


def test_sun_room_drag_frame_allocates_nothing_after_its_first_frame(shared_scenes_cache):
    # a sun room's drag frame: the sun's pass, its later bounces and the object's gather of the sun's loss
    # (app.stages.object_drag: the weights of the sunlit patches seen past the room, as many as the frame's
    # sunlit patches near the object) hold buffers of a fixed capacity: frames 2..N allocate nothing
    from tests.conftest import shared_scene

    scene = load_scene(shared_scene("sun_room"))
    eng = Engine(scene, EngineParams(), cache_dir=shared_scenes_cache, quiet=True)
    assert eng.sun.light is not None and eng.drag_object_sun
    offs = drag_offsets(scene, scene.obj, 6)
    cfg = dataclasses.replace(eng.frame_config(), passes=DRAG_PASSES, drag=DRAG_SCALE, drag_shadow=DRAG_SHADOW)
    eng.render(moved(scene.obj, offs[0]), cfg)
    with counting_allocations() as events:
        frames = [eng.render(moved(scene.obj, o), cfg) for o in offs[1:]]
    assert all(f.stats["passes"] >= 2 for f in frames)
    assert not events, _report(events)
