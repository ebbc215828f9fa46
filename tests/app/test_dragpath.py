"""`photoar evaluate --path N` (app.dragpath, app.evaluate.drag_path) on the bundled demo scene."""
import json

import numpy as np
import pytest

from app.cli import demo_scene_dir, main


def test_drag_stays_in_room_off_furniture_through_pose():
    from app.dragpath import drag_offsets, moved
    from recon.scene import furniture_boxes, load_scene

    scene = load_scene(demo_scene_dir())
    off = drag_offsets(scene, scene.obj, 9)
    assert off.shape == (9, 3) and np.all(off[:, 1] == 0)
    # a straight line through the object's own pose (offset 0 lies on the segment)
    d = off[-1] - off[0]
    assert np.linalg.norm(d) > 0.3
    t = -off[0] @ d / (d @ d)
    assert -1e-9 <= t <= 1 + 1e-9 and np.linalg.norm(off[0] + t * d) < 1e-9
    for o in off:
        v = moved(scene.obj, o).vertices
        lo, hi = v.min(0), v.max(0)
        assert np.all(lo >= scene.room_min) and np.all(hi <= scene.room_max)
        for b_lo, b_hi in furniture_boxes(scene):
            assert not np.all((lo < b_hi - 1e-3) & (hi > b_lo + 1e-3))
    with pytest.raises(ValueError, match="at least 2"):
        drag_offsets(scene, scene.obj, 1)


def test_evaluate_path_and_stage_table(tmp_path):
    out = tmp_path / "eval"
    assert main(["-q", "evaluate", str(demo_scene_dir()), "--passes", "20,all", "--path", "4", "--out", str(out),
                 "--patch-size", "0.35", "--cache", str(tmp_path / "cache")]) == 0
    ev = json.loads((out / "evaluation.json").read_text())
    p = ev["path"]
    from app.config import DRAG_PASSES, DRAG_SCALE

    assert p["positions"] == 4 and p["passes"] == DRAG_PASSES == 64 and p["precompute_runs"] == 0  # the drag frame's
    assert len(p["frame_s"]) == 4 and len(p["offsets_m"]) == 4
    rest = np.array(p["frame_s"][1:])  # the first frame is excluded
    assert p["frame_s_mean"] == pytest.approx(rest.mean())
    assert rest.min() <= p["frame_s_p95"] <= rest.max()
    # the per-stage table: the engine's phases, which add up to (at most) the frame time
    for r in ev["rows"]:
        st = r["stages_ms"]
        assert {"proxy", "object", "sources", "masks", "object_shading", "object_light", "compose"} <= set(st)
        assert 0 < sum(st.values()) <= 1e3 * r["frame_s"] + 1e-6
    assert set(p["stages_ms"]) >= {"masks", "compose"}
    # the drag frame (issue 36): a row at the scene's pose, and the path made of drag frames, whose stage
    # table has the coarse room's upsampling and the glue ("python": the frame's time outside Warp kernels,
    # app.glue): the timed stages make up the frame, the glue is part of it
    (drag,) = [r for r in ev["rows"] if r["passes"] == "drag"]
    assert drag["drag_scale"] == p["drag_scale"] == DRAG_SCALE == 3 and (out / "composite_drag.png").is_file()
    assert {"upsample", "python"} <= set(p["stages_ms"])
    stages = dict(p["stages_ms"])
    glue = stages.pop("python")
    assert sum(stages.values()) == pytest.approx(1e3 * rest.mean(), rel=1e-9)  # the ticks enclose the frame exactly
    assert 0 < glue < 1e3 * rest.mean()
    # at rest after the drag: refined to the all-sources frame (the "all" row) at the object's pose
    assert ev["converge_s"] == p["converge_s"] > 0 and p["converge_frames"] > 1
    assert 0 < p["release_frame_s"] < p["converge_s"] and "all-sources frame" in p["converge_measures"]
    assert p["converge_rmse_vs_all"] <= 0.05
    # no truth.png: converge_s is the time to the exact all-sources frame, after the frames shown at rest
    assert ev["exact_s"] == p["exact_s"] == p["converge_s"] == p["shown"][-1]["t_s"]
    assert [s["exact"] for s in p["shown"]] == [False] * (len(p["shown"]) - 1) + [True]
    assert "rmse_affected" not in p["shown"][0] and "no truth" in p["converge_measures"]
    # each frame shown at rest has its own time and stage table (the release frame's is release_frame_s):
    # its timed stages make up the frame, which took no longer than the time since the move
    assert p["shown"][0]["frame_s"] == p["release_frame_s"]
    for s in p["shown"]:
        assert {"masks", "compose"} <= set(s["stages_ms"]) and 0 < s["frame_s"] <= s["t_s"]
        assert 0 < sum(s["stages_ms"].values()) <= 1e3 * s["frame_s"] + 1e-6


def test_evaluate_reaches_all_source_quality_before_the_exact_frame(shared_scenes_cache, tmp_path, capsys):
    # window_room has a truth: converge_s is the time to the first frame at rest within 0.05 rmse_affected
    # of the all-sources frame's, exact_s the time to the all-sources frame itself (Engine.refine's last)
    from tests.conftest import shared_scene

    out = tmp_path / "eval"
    assert main(["-q", "evaluate", str(shared_scene("window_room")), "--passes", "50,all", "--path", "2",
                 "--out", str(out), "--cache", str(shared_scenes_cache)]) == 0
    line = next(ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("path of"))
    ev = json.loads((out / "evaluation.json").read_text())
    p, shown = ev["path"], ev["path"]["shown"]
    assert f"all-source quality after {p['converge_s']:.2f} s" in line and f"after {p['exact_s']:.2f} s" in line
    assert [s["exact"] for s in shown] == [False, False, True]  # the release frame, refine's finer frame, all sources
    # the release is the drag frame (DRAG_PASSES at 1/DRAG_SCALE resolution, at most DRAG_PASSES_NO_SUN in a room
    # no sun lights, as window_room), refine's finer frame has twice the smallest budget of --passes on full-size
    # maps at full resolution
    from app.config import DRAG_PASSES, DRAG_PASSES_NO_SUN

    assert [s["passes"] for s in shown[:2]] == [min(DRAG_PASSES, DRAG_PASSES_NO_SUN), 100] and shown[2]["passes"] == ev["rows"][1]["n_passes"]
    assert p["passes"] == DRAG_PASSES and p["n_passes"] == [min(DRAG_PASSES, DRAG_PASSES_NO_SUN)]  # asked, and what it took
    t = [s["t_s"] for s in shown]
    assert 0 < p["release_frame_s"] <= t[0] < t[1] < t[2]
    # refine ends in the all-sources frame: its score is the "all" row's
    assert p["converge_rmse_vs_all"] <= 0.05
    assert shown[2]["rmse_affected"] == pytest.approx(ev["rows"][1]["rmse_affected"], abs=0.01)
    # all-source quality (within 0.05 of the all-sources frame's rmse_affected) is reached at the first frame
    # shown at rest that has it, before the exact frame: the finer frame, or already the release (the drag
    # frame of 64 passes scores 0.94 here, the all-sources frame 0.77: the finer frame)
    first = next(i for i, s in enumerate(shown) if s["rmse_affected"] <= shown[2]["rmse_affected"] + 0.05)
    assert first < 2 and shown[1]["rmse_affected"] <= shown[2]["rmse_affected"] + 0.05
    assert ev["converge_s"] == p["converge_s"] == t[first] < p["exact_s"] == ev["exact_s"] == t[2]
    assert p["converge_frames"] < p["exact_frames"] and "within 0.05" in p["converge_measures"]


def test_path_counts_precompute_inside_the_drag(tmp_path):
    # the counter fires when per-scene work runs during a frame: drop the SH volume, which the
    # object's shading rebuilds on first use, and invalidate its cache file (a cache hit is not work)
    from app.engine import Engine, EngineParams
    from app.evaluate import drag_path
    from recon.scene import load_scene

    scene = load_scene(demo_scene_dir())
    params = EngineParams(patch_size=0.35)
    cache = tmp_path / "cache"
    eng = Engine(scene, params, cache_dir=cache, quiet=True)
    assert (eng.n_precompute, eng.n_cache_loads) == (3, 0)  # the transfers, the shafts and the SH volume
    path, converged = drag_path(eng, scene, 10, 2)
    assert path["precompute_runs"] == 0 and converged.stats["passes"] > 10
    assert (eng.n_precompute, eng.n_cache_loads) == (3, 0)  # nothing per-scene ran or was read in the drag
    _read_sh_volume_in_next_frame(eng)  # read back from its cache file: not work
    drag_path(eng, scene, 10, 2)
    assert (eng.n_precompute, eng.n_cache_loads) == (3, 1)
    _read_sh_volume_in_next_frame(eng)
    (sh_file,) = cache.glob("*-sh-*.npz")
    sh_file.write_bytes(b"not an npz")  # a deliberately invalidated cache: rebuilt inside the drag
    with pytest.raises(RuntimeError, match="precompute ran 1 time"):
        drag_path(eng, scene, 10, 2)
    assert eng.n_precompute == 4


def test_path_needs_two_positions(tmp_path, capsys):
    with pytest.raises(SystemExit) as e:
        main(["evaluate", str(demo_scene_dir()), "--passes", "50,all", "--path", "1", "--out", str(tmp_path / "o")])
    assert e.value.code == 2 and "at least 2 positions" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def _read_sh_volume_in_next_frame(eng) -> None:
    """Make the engine's next frame read the SH volume (or rebuild it) as per-scene work inside the drag.
    Private reach: Engine._room_light is the one place that loads the volume and counts it (the engine
    builds it once, before any frame; a frame never does)."""
    real = eng.render

    def render(*args, **kwargs):
        del eng.render  # this frame only
        eng._room_light(eng.B_src, eng.params.volume_spacing)
        return real(*args, **kwargs)

    eng.render = render
