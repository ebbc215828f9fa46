"""The sphere drag frame (FrameConfig.drag_shadow "spheres", app.dragshadow): no shadow maps; scored against
the shared rooms' truth next to the all-sources frame."""
import dataclasses

import numpy as np
import pytest


@pytest.mark.parametrize("room", ["window_room", "lamps_room"])
def test_sphere_drag_frame_scores_within_issue_36s_bound(shared_room, room):
    # the drag frame at the scene's pose (1/2 resolution, the object as ellipsoids against the room's SH light
    # and compact sources) against the truth (tools/score.py's measures, lighting.metrics): rmse_affected <=
    # 1.5 x the all-sources frame's + 0.5, energy_ratio 0.93-1.07 (issue 36). sun_room does not hold it
    # (docs/benchmarks.md "The sphere drag frame"). It draws no shadow map: no source list, no passes
    from app.engine import FrameConfig

    sr = shared_room(room)
    scene, eng = sr.scene, sr.engine
    cfg = FrameConfig(passes=64, drag=2, drag_shadow="spheres")  # the scale it was measured at
    drag = eng.render(scene.obj, cfg)
    s_all, s_drag = sr.s_all, sr.score(drag.pixels)
    assert s_drag["rmse_affected"] <= 1.5 * s_all["rmse_affected"] + 0.5
    assert 0.93 <= s_drag["energy_ratio"] <= 1.07
    assert drag.stats["passes"] == 0 and drag.stats["timings"]["sources"] == 0.0
    # the object's own pixels are the map drag frame's when that frame shades the object as at rest (the same
    # object stages at full resolution; the sphere frame does not use object_drag's per-shape tables)
    eng.drag_object_tables = False
    st = eng.pixel_stages(cfg.drag)  # at the sphere frame's object rays, 2 x 2 (the map frame's: DRAG_SUPERSAMPLE)
    ss = st.supersample
    st.supersample, st._scene_depth = eng.params.object.supersample, None
    try:
        maps = eng.render(scene.obj, dataclasses.replace(cfg, drag_shadow="maps"))
    finally:
        st.supersample, st._scene_depth = ss, None
    eng.drag_object_tables = True
    inside = maps.coverage >= 1
    assert np.abs(drag.pixels[inside].astype(int) - maps.pixels[inside]).max() <= 1
    # a moved pose moves the shadow: the frame differs from the photo near the new pose and not at the old one's
    # contact alone (the parts move with object_to_world)
    from app.dragpath import drag_offsets, moved

    off = drag_offsets(scene, scene.obj, 3)[0]
    fr2 = eng.render(moved(scene.obj, off), cfg)
    assert not np.array_equal(fr2.pixels, drag.pixels)


def test_frames_at_rest_unchanged_by_sphere_drag_frames(shared_room):
    # the sphere drag frame is a separate path: the all-sources frame is byte-identical before and after one
    from app.engine import FrameConfig

    sr = shared_room("lamps_room")
    scene, eng = sr.scene, sr.engine
    before = eng.render(scene.obj, FrameConfig(passes=50)).pixels.copy()
    eng.render(scene.obj, FrameConfig(passes=64, drag=2, drag_shadow="spheres"))
    assert np.array_equal(before, eng.render(scene.obj, FrameConfig(passes=50)).pixels)
