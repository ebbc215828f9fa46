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
    calls = 0
    while True:
        calls += 1
        fr = eng.refine(scene.obj, FrameConfig(passes=10), budget_s=0.0)  # one batch per call
        if fr is not None:
            break
        # a render in between (e.g. the GUI's kept frame) does not disturb the refinement
        if calls == 2:
            eng.render(scene.obj, FrameConfig(passes=10))
        assert calls < 1000
    n_batches = -(-exact.stats["passes"] // eng.params.batch)
    # spread over calls: one batch of shadow maps each, then the shading and compositing
    assert n_batches > 1 and calls == n_batches + 1
    assert _rmse(fr.pixels, exact.pixels) <= 0.05
    assert fr.stats["passes"] == exact.stats["passes"] and fr.stats["refine_calls"] == calls
    assert eng.refine(scene.obj) is fr  # converged: later calls at rest return it at once


def test_refine_starts_over_when_the_pose_changes(demo):
    scene, eng = demo
    other = moved(scene.obj, np.array([-0.3, 0.0, 0.0]))
    eng.refine(moved(scene.obj, np.array([-0.6, 0.0, 0.0])), budget_s=0.0)  # a pose left mid-way
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
