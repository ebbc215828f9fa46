"""Progressive refinement at rest (Engine.refine) and the frozen per-frame config (FrameConfig),
on the bundled demo scene."""
import dataclasses

import numpy as np
import pytest

from app.cli import demo_scene_dir
from app.dragpath import moved
from app.engine import Engine, EngineParams, FrameConfig
from recon.scene import load_scene


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    scene = load_scene(demo_scene_dir())
    eng = Engine(scene, EngineParams(patch_size=0.35, passes=10), cache_dir=tmp_path_factory.mktemp("cache"),
                 quiet=True)
    return scene, eng


def _rmse(a, b):
    return float(np.sqrt(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2)))


def test_refine_converges_to_the_all_sources_frame(demo):
    scene, eng = demo
    exact = eng.render(scene.obj, FrameConfig(passes=None))
    drag = eng.render(scene.obj, FrameConfig(passes=10))  # the frame shown while dragging
    assert _rmse(drag.pixels, exact.pixels) > 0.5  # 10 passes are visibly not the all-sources frame
    schedule = eng.refine_schedule(scene.obj, FrameConfig(passes=10))
    # before the all-sources frame, a frame twice as fine as the drag frame on full-size maps
    assert [c.passes for c in schedule] == [20, None] and schedule[0].full_maps and not schedule[1].full_maps
    calls, shown = 0, []
    while True:
        calls += 1
        fr = eng.refine(scene.obj, FrameConfig(passes=10), budget_s=0.0)  # one batch per call
        if fr is not None:
            shown.append((calls, fr))
            if fr.stats["exact"]:
                break
        assert calls < 1000
    # the all-sources frame draws its full-size maps, then its weak sources' half-size ones, in batches
    # of their own (app.rest_maps)
    pv = eng.object_shading.object_shape(scene.obj)[0]
    order = eng.rest_maps.order(eng.shadow_sources.select(pv.min(0), pv.max(0), None))
    S, b = exact.stats["passes"], eng.params.batch
    hard = S if order is None else order[1]
    n_batches = [-(-20 // b), -(-hard // b) + -(-(S - hard) // b)]
    # spread over calls: one batch of shadow maps each, and each frame pauses between its stages (after the
    # source list, the object's light, its shading and the second order: a caller's stop() is asked there too),
    # then its compositing
    stage_pauses = 4
    assert n_batches[1] > 1 and calls == sum(n_batches) + 2 * (stage_pauses + 1)
    (c_mid, mid), (c_end, fr) = shown
    assert c_mid == n_batches[0] + stage_pauses + 1 and not mid.stats["exact"] and mid.stats["passes"] == 20
    assert mid.stats["refine_frames"] == 0 and fr.stats["refine_frames"] == 1
    # the intermediate frame is shown before the exact one and is closer to it than the drag frame
    assert _rmse(mid.pixels, exact.pixels) < _rmse(drag.pixels, exact.pixels)
    assert _rmse(fr.pixels, exact.pixels) <= 0.05
    assert fr.stats["passes"] == exact.stats["passes"] and fr.stats["refine_calls"] == calls
    assert eng.refine(scene.obj) is fr  # converged: later calls at rest return it at once


def test_refine_schedule_is_set_by_the_drag_budget_and_the_source_count(demo):
    scene, eng = demo
    listed = int(eng.shadow_sources.traverse(scene.obj.vertices.min(0), scene.obj.vertices.max(0))[0].sum())
    for passes in (1, 10, listed // 16, listed // 16 + 1, listed):
        sched = eng.refine_schedule(scene.obj, FrameConfig(passes=passes))
        assert sched[-1] == FrameConfig(None)
        # an intermediate frame only where it holds at most 1/8 of the all-sources frame's maps
        assert len(sched) == (2 if 2 * passes <= listed / 8 else 1), (passes, listed)
    assert eng.refine_schedule(scene.obj, FrameConfig(passes=None)) == [FrameConfig(None)]
    # once timed: no finer frame when it took as long as the all-sources frame (it would show nothing sooner)
    saved = dict(eng.refiner.rest_s)
    assert set(saved) == {"finer", "exact"} and 0 < saved["finer"] < saved["exact"]  # refine timed both
    try:
        eng.refiner.rest_s.update(finer=1.0, exact=1.0)
        assert eng.refine_schedule(scene.obj, FrameConfig(passes=10)) == [FrameConfig(None)]
        eng.refiner.rest_s.update(finer=0.9)
        assert len(eng.refine_schedule(scene.obj, FrameConfig(passes=10))) == 2
    finally:
        eng.refiner.rest_s.update(saved)
    assert eng.refine_schedule(scene.obj, FrameConfig(passes=10, mode="ldr"))[0].mode == "ldr"
    # without a budget the call runs to the all-sources frame (no intermediate one is made), also when one
    # was under way
    starts = eng.frames_started
    fr = eng.refine(moved(scene.obj, np.array([-0.3, 0.0, 0.0])), FrameConfig(passes=10))
    assert fr.stats["exact"] and fr.stats["refine_calls"] == 1 and fr.stats["refine_frames"] == 0
    assert eng.frames_started == starts + 1
    other = moved(scene.obj, np.array([-0.6, 0.0, 0.0]))
    assert eng.refine(other, FrameConfig(passes=10), budget_s=0.0) is None  # the finer frame begun
    fr = eng.refine(other, FrameConfig(passes=10))
    assert fr.stats["exact"] and fr.stats["refine_frames"] == 0
    assert _rmse(fr.pixels, eng.render(other, FrameConfig(passes=None)).pixels) <= 0.05


def test_refine_starts_over_when_the_pose_changes(demo):
    scene, eng = demo
    other = moved(scene.obj, np.array([-0.3, 0.0, 0.0]))
    eng.refine(moved(scene.obj, np.array([-0.6, 0.0, 0.0])), budget_s=0.0)  # a pose left mid-way
    assert eng.refine(other, budget_s=0.0) is None
    # a frame of another pose in between moves the shared shadow-map proxy and the object's BVHs:
    # the refinement of `other` must not finish with them
    eng.render(moved(scene.obj, np.array([-0.9, 0.0, 0.0])), FrameConfig(passes=10))
    fr = eng.refine(other)  # to the end
    exact = eng.render(other, FrameConfig(passes=None))
    assert _rmse(fr.pixels, exact.pixels) <= 0.05
    # ... and LDR refinement is its own frame
    ldr = eng.refine(other, FrameConfig(passes=10, mode="ldr"))
    assert ldr.stats["mode"] == "ldr"
    assert _rmse(ldr.pixels, eng.render(other, FrameConfig(None, "ldr")).pixels) <= 0.05


def test_frame_config_is_frozen_validated_and_never_written(demo):
    scene, eng = demo
    cfg = FrameConfig(passes=7, mode="hdr")
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.passes = 8
    before = dataclasses.asdict(eng.params)
    fr = eng.render(scene.obj, cfg)
    assert fr.stats["passes"] == 7 and dataclasses.asdict(eng.params) == before and cfg.passes == 7
    for bad in ({"passes": 0}, {"passes": 2.5}, {"mode": "sdr"}, {"fps": 0.0}):
        with pytest.raises(ValueError):
            FrameConfig(**bad)


def test_object_shape_is_built_once_per_shape_and_refit_when_dragged(demo):
    # the proxy, the shading mesh and their BVHs are kept per shape: a drag translates and refits
    # them; the frames equal those made afresh (shape_cache off); a turn is a new shape
    from app.dragpath import drag_offsets

    scene, eng = demo
    cfg = FrameConfig(passes=10)
    eng.render(scene.obj, cfg)
    builds = eng.object_shading.n_shape_builds
    for o in drag_offsets(scene, scene.obj, 3):
        obj = moved(scene.obj, o)
        kept = eng.render(obj, cfg)
        kept_cfg = eng.object_shading.config
        eng.object_shading.config = dataclasses.replace(kept_cfg, shape_cache=False)
        try:
            fresh = eng.render(obj, cfg)
        finally:
            eng.object_shading.config = kept_cfg
        assert _rmse(kept.pixels, fresh.pixels) <= 0.05, o
    assert eng.object_shading.n_shape_builds == builds + 3  # only the three fresh ones
    c, s = np.cos(0.5), np.sin(0.5)
    R = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    centre = scene.obj.vertices.mean(0)
    turned = dataclasses.replace(scene.obj, vertices=(scene.obj.vertices - centre) @ R.T + centre,
                                 normals=scene.obj.normals @ R.T)
    eng.render(turned, cfg)
    assert eng.object_shading.n_shape_builds == builds + 4


def test_placement_refine_shows_intermediate_frames_at_rest(tmp_path):
    # the GUI's path (PlacementController.refine(intermediate=True)): the frame at rest before the
    # all-sources one comes back unconverged and is not kept; the old contract (None until the
    # all-sources frame) holds without intermediate
    from app.placement import PlacementController

    ctl = PlacementController.open(demo_scene_dir(), params=EngineParams(passes=10, patch_size=0.35),
                                   cache_dir=tmp_path / "cache", quiet=True)
    ctl.start_engine()
    ctl.set_object(ctl.scene.obj.source)
    drag = ctl.render()
    assert drag.stats["budget"] == 10 and not drag.stats["converged"]
    got = []
    while not (got and got[-1].stats["converged"]):
        fr = ctl.refine(budget_s=0.0, intermediate=True)
        if fr is not None:
            got.append(fr)
        assert len(got) < 5
    mid, end = got
    assert not mid.stats["converged"] and mid.stats["passes"] == 20 and end.stats["passes"] > 20
    kept = ctl.refine()  # at rest: the all-sources frame is kept, not the intermediate one
    assert kept.stats["cached"] and kept.stats["converged"] and np.array_equal(kept.pixels, end.pixels)
    ctl.move_by(0.2, 0.0)
    ctl.render()
    calls = 0
    while (fr := ctl.refine(budget_s=0.0)) is None:  # intermediate frames are not returned
        calls += 1
        assert calls < 1000
    assert fr.stats["converged"] and fr.stats["passes"] > 20
    # the window's refinement at rest (app/gui.py, without a display: what the method touches) shows
    # the intermediate frame, then the all-sources frame, and stops there
    import types

    from app.gui import PlacementWindow

    class Win:
        closed, _dirty, _dragging, refined_frames, error, window = False, False, False, 0, None, None

        def __init__(self):
            self.ctl, self.shown = ctl, []
            self.app = types.SimpleNamespace(post_to_main_thread=lambda window, f: f())

        def _show_frame(self, fr, pose):
            self.shown.append((fr, pose))

    ctl.move_by(0.2, 0.0)
    ctl.render()
    win = Win()
    PlacementWindow._refine_at_rest(win, ctl.pose)
    assert [f.stats["converged"] for f, _ in win.shown] == [False, True] and win.refined_frames == 2
    assert win.shown[0][0].stats["passes"] == 20 and all(p == ctl.pose for _, p in win.shown)


def test_refine_stops_where_stop_says_and_goes_on_from_there(demo):
    # stop() is asked before each step (a batch of maps or a stage of the frame): True ends the call there
    # with no frame, and the next call goes on from that step; the frame is the uninterrupted one, bit for bit
    scene, eng = demo
    pose = moved(scene.obj, np.array([-0.45, 0.0, 0.0]))
    asked = []
    assert eng.refine(pose, FrameConfig(passes=10), stop=lambda: asked.append(1) or True) is None
    assert len(asked) == 1  # asked once, before a first step it did not take (no budget: it would run to the end)
    steps = [0]

    def two_steps():  # allows two steps per call
        steps[0] += 1
        return steps[0] % 3 == 0

    calls = 0
    while (fr := eng.refine(pose, FrameConfig(passes=10), stop=two_steps)) is None:
        calls += 1
        assert calls < 1000
    pv = eng.object_shading.object_shape(pose)[0]
    order = eng.rest_maps.order(eng.shadow_sources.select(pv.min(0), pv.max(0), None))
    S, b = fr.stats["passes"], eng.params.batch
    hard = S if order is None else order[1]
    # no budget: straight to the all-sources frame, its batches, four stage pauses and the compositing step
    n_steps = -(-hard // b) + -(-(S - hard) // b) + 4 + 1
    assert fr.stats["exact"] and calls + 1 == -(-n_steps // 2) and fr.stats["refine_calls"] == calls + 2
    eng.refiner.forget()
    whole = eng.refine(pose, FrameConfig(passes=10))
    assert whole is not fr and whole.stats["refine_calls"] == 1
    assert np.array_equal(whole.pixels, fr.pixels) and np.array_equal(whole.radiance, fr.radiance)


def test_render_abandons_the_frame_where_stop_says(demo):
    # Engine.render asks stop() after each step (a stage or a batch of maps): True abandons the frame, None;
    # a stop that never says True gives the uninterrupted frame bit for bit, and so does a frame after an
    # abandoned one (the abandoned frame leaves nothing behind)
    scene, eng = demo
    pose = moved(scene.obj, np.array([0.3, 0.0, 0.0]))
    cfg = FrameConfig(passes=10)
    asked = []
    assert eng.render(pose, cfg, stop=lambda: asked.append(1) or len(asked) == 2) is None
    assert len(asked) == 2  # it stopped at the second pause, asked nothing more
    seen = []
    fr = eng.render(pose, cfg, stop=lambda: seen.append(1) or False)
    assert len(seen) >= 4  # at least the frame's four stage pauses (and one per batch of maps)
    whole = eng.render(pose, cfg)
    assert not np.shares_memory(fr.pixels, whole.pixels)  # two frames, not one buffer compared with itself
    assert np.array_equal(fr.pixels, whole.pixels) and np.array_equal(fr.radiance, whole.radiance)


def test_finer_frame_in_a_sun_room_splits_near_the_object_and_reaches_all_source_quality(shared_scenes_cache,
                                                                                          tmp_path):
    # sun_room: refine's finer frame (REFINE_STEP x 50 passes, full-size maps) splits its clusters near the object
    # first (app.progressive.finer_near_split), which brings its rmse_affected against the truth within
    # CONVERGE_RMSE of the all-sources frame's (measured, bench in docs/benchmarks.md "rest48": 0.9815 against
    # 0.9738); with the plain key it misses (1.0256). Scored by the shared scorer; the margins hold 0.02 levels.
    from app.evaluate import CONVERGE_RMSE
    from recon.io import write_png
    from tests.conftest import score, shared_scene

    scene_dir = shared_scene("sun_room")
    eng = Engine(load_scene(scene_dir), EngineParams(), cache_dir=shared_scenes_cache, quiet=True)
    obj, mode = eng.scene.obj, eng.frame_config().mode
    finer = eng.refine_schedule(obj, FrameConfig(50, mode))[0]
    assert finer.passes == 100 and finer.full_maps
    rmse = {}
    for name, cfg, near in (("near", finer, True), ("plain", finer, False), ("all", FrameConfig(None, mode), True)):
        eng.rest_near_split = near
        fr = eng.render(obj, cfg)
        write_png(tmp_path / f"{name}.png", fr.pixels)
        rmse[name] = score(scene_dir, tmp_path / f"{name}.png")["rmse_affected"]
    assert rmse["near"] <= rmse["all"] + CONVERGE_RMSE - 0.02, rmse
    assert rmse["plain"] > rmse["all"] + CONVERGE_RMSE - 0.02, rmse  # what the near split fixes
