"""The drag frame (FrameConfig.drag, app.dragframe, kernels.drag_compose): the room's change at a coarser
working resolution, upsampled as the ratio to the photo, the object at full resolution."""
import dataclasses

import numpy as np
import pytest

from app.cli import demo_scene_dir


def test_coarse_camera_maps_pixel_blocks():
    # a world point seen at full-resolution pixel (u, v) is seen at ((u + 0.5) / s - 0.5, ...) by the
    # camera of 1/s the size: coarse pixel i covers full pixels s i .. s i + s - 1 (pixel centres at integers)
    from app.dragframe import coarse_camera
    from recon.scene import load_scene

    cam = load_scene(demo_scene_dir()).camera
    rng = np.random.default_rng(0)
    pts = cam.centre + cam.pixel_rays()[rng.integers(0, cam.height, 20), rng.integers(0, cam.width, 20)] * 3.0
    uv, _ = cam.project(pts)
    for s in (2, 4):
        c = coarse_camera(cam, s)
        assert (c.width, c.height) == (-(-cam.width // s), -(-cam.height // s))
        uv_c, _ = c.project(pts)
        np.testing.assert_allclose(uv_c, (uv + 0.5) / s - 0.5, atol=1e-9)


@pytest.fixture(scope="module")
def demo_engine(tmp_path_factory):
    from app.engine import Engine, EngineParams
    from recon.scene import load_scene

    scene = load_scene(demo_scene_dir())
    return scene, Engine(scene, EngineParams(patch_size=0.35), cache_dir=tmp_path_factory.mktemp("cache"), quiet=True)


def test_drag_frame_leaves_the_frames_at_rest_unchanged(demo_engine):
    # the drag frame is a separate path: a 50-pass frame and the all-sources frame are byte-identical
    # before and after drag frames of two scales
    from app.engine import FrameConfig

    scene, eng = demo_engine
    before = [eng.render(scene.obj, FrameConfig(passes=p)).pixels.copy() for p in (50, None)]
    for s in (2, 4):
        eng.render(scene.obj, FrameConfig(passes=50, drag=s))
    after = [eng.render(scene.obj, FrameConfig(passes=p)).pixels for p in (50, None)]
    for a, b in zip(before, after):
        assert np.array_equal(a, b)


def test_drag_frames_make_no_per_source_sums(demo_engine):
    # the per-source frames' masked sums (ShadowPass.sums_source: culling cells of TILE_SOURCE px) are made on
    # the first frame with a map per source: the drag frames' shadow pass, whose maps stand for clusters, never
    # makes them; the all-sources frame at rest does, and its masks read the same points in fewer cells
    from app.engine import FrameConfig

    scene, eng = demo_engine
    eng.render(scene.obj, FrameConfig(passes=10, drag=2))
    drag_sp = eng._drag[2].shadow_pass
    assert drag_sp._sums_source is None
    eng.render(scene.obj, FrameConfig(passes=None))
    assert drag_sp._sums_source is None
    made = eng.shadow_pass._sums_source
    assert made is not None and made.size == eng.shadow_pass.sums.size
    assert made.n_cells < eng.shadow_pass.sums.n_cells

def test_emitter_group_of_each_patch_is_made_once(demo_engine):
    # app.stages.object_drag.DragObject.emitter_group_of, which a sunny drag frame reads for the sun's loss on
    # emitter patches: made once per engine, the same array on every later frame; each emitter patch's group is a
    # group of its own radiance whose rectangle holds its centre (kernels.shade.patch_groups: one surface and
    # radiance that tiles a rectangle), every other patch -1
    from app.engine import FrameConfig

    scene, eng = demo_engine
    drag = eng.object_drag
    group = drag.emitter_group_of()
    eng.render(scene.obj, FrameConfig(passes=10, drag=2))
    assert drag.emitter_group_of() is group
    rl, pm = eng.object_shading.room_light, eng.object_shading.patches
    em, (start, polys) = eng.object_shading.emitter_groups()
    assert len(em) > 0 and len(polys) == len(start) - 1
    assert np.all(group[np.setdiff1d(np.arange(pm.n_patches), em)] == -1)
    g = group[em]
    assert np.all((g >= 0) & (g < len(polys)))
    np.testing.assert_array_equal(rl.radiance[em], rl.radiance[em[start[g]]])
    lo, hi = polys.min(1)[g], polys.max(1)[g]
    assert np.all((pm.centre[em] >= lo - 1e-9) & (pm.centre[em] <= hi + 1e-9))


def test_weak_cluster_maps_take_the_hard_lookup_within_their_share(demo_engine):
    # the drag frame's weak passes (app.dragframe.DRAG_HARD_WEAK: share_j <= drag_weak_budget(scale), WEBER x scale,
    # app.rest_maps) are looked up hard, the others with their PCSS penumbra: exactly the weak passes' maps lose their
    # spread, and at every patch centre and every summed pixel (the same points in either frame) the sums move by at
    # most the weak passes' own transfers there (each an occluded share in 0..1, hard or soft); with no pass weak (a
    # budget of 0) the masks are the all-PCSS ones bit for bit
    from app.dragframe import DRAG_HARD_WEAK, drag_weak_budget
    from app.engine import FrameConfig
    from app.rest_maps import WEBER, RestMaps
    from recon.proxy import bounding_sphere

    scene, eng = demo_engine
    eng.render(scene.obj, FrameConfig(passes=50, drag=3))
    px = eng.pixel_stages(3)
    sp = px.shadow_pass
    budget = drag_weak_budget(3)
    assert budget == pytest.approx(3 * WEBER)
    assert DRAG_HARD_WEAK and sp.weak_clusters is not None and sp.weak_clusters.budget == pytest.approx(budget)
    pv, pf, occ, _, _ = eng.object_shading.object_shape(scene.obj)
    centre, radius = bounding_sphere(pv)
    fs = eng.shadow_sources.select(pv.min(0), pv.max(0), 50, near_split=True)
    n = len(fs.eyes)
    shares = sp.weak_clusters.shares(fs.W_v)
    weak = shares <= budget
    assert 0 < weak.sum() < n  # the demo's 50 passes hold both kinds
    assert weak.sum() >= (shares <= WEBER).sum()  # the drag budget makes no pass strong that WEBER made weak

    def masks():
        steps = sp.run((pv, pf, occ), centre, radius, px.zero_cov, fs.cand, fs.eyes, fs.W_v, fs.W_c, False,
                       spread=fs.spread, scale=px.receivers.E_x)
        while True:
            try:
                next(steps)
            except StopIteration as stop:
                return stop.value

    kept, kept_centres = sp.weak_clusters, sp.hard_centres
    sp.hard_centres = False  # the centres with their penumbrae (DRAG_HARD_CENTRES looks every map up hard there)
    try:
        hard = masks()
        assert sp.last_hard == weak.sum()
        own = np.linalg.norm(fs.spread[:n], axis=2).max(1).astype(np.float32)  # each cluster's half-width (m)
        assert np.any(own[weak] > 0.0)
        spread = sp.maps.ms.spread.numpy()[:n]
        assert np.all(spread[weak] == 0.0) and np.array_equal(spread[~weak], own[~weak])
        sp.weak_clusters = None
        soft = masks()
        assert sp.last_hard == 0 and np.array_equal(sp.maps.ms.spread.numpy()[:n], own)
        sp.weak_clusters = RestMaps(px.receivers.E_v, budget=0.0)
        none_weak = masks()
    finally:
        sp.weak_clusters, sp.hard_centres = kept, kept_centres
    assert np.array_equal(hard.cen_sel, soft.cen_sel) and len(hard.cen_sel) > 0
    bound = np.asarray(fs.W_c, np.float64)[hard.cen_sel][:, weak].sum(1)
    diff = np.abs(hard.O_cen - soft.O_cen)
    assert np.all(diff <= bound * (1 + 1e-5) + 1e-7)
    assert diff.max() > 0.0  # the weak passes' hard shadows do differ from their penumbrae somewhere
    # the pixels summed in both frames (the graded lattice refines where the fractions differ, so the sets may
    # differ): each within the weak passes' transfers at the pixel (its rows' W_v, barycentric)
    both, ih, isf = np.intersect1d(hard.pix_sel, soft.pix_sel, return_indices=True)
    assert len(both) > 0.5 * len(soft.pix_sel)
    rows, bary = px.receivers.pix_rows[both], px.shadow_pass._points[2][both]
    W_weak = np.asarray(fs.W_v, np.float64)[:, weak].sum(1)  # (Vr,3)
    pix_bound = np.einsum("nk,nkc->nc", bary, W_weak[np.maximum(rows, 0)])
    pix_diff = np.abs(hard.O_pix[ih] - soft.O_pix[isf])
    assert np.all(pix_diff <= pix_bound * (1 + 1e-4) + 1e-6)
    for field in ("pix_sel", "fill_sel", "cen_sel", "O_pix", "O_cen"):
        assert np.array_equal(getattr(none_weak, field), getattr(soft, field)), field


def test_a_coarse_step_reaches_full_resolution_as_a_ramp_of_scale_pixels(demo_engine):
    # drag_weak_budget's premise (WEBER x scale): the drag frame's ratio room / photo is upsampled bilinearly
    # (DragStages.ratio, the form drag_compose_kernel computes), so a step of height h between two coarse pixels
    # changes neighbouring full pixels by at most h / scale (to float32 rounding), and the whole step is kept
    from app.dragframe import drag_weak_budget
    from app.engine import FrameConfig

    scene, eng = demo_engine
    for s in (2, 3, 4):
        eng.render(scene.obj, FrameConfig(passes=10, drag=s))
        px = eng.pixel_stages(s)
        h, w = px.shape
        L_b = px.receivers.L_b.reshape(h, w, 3).astype(np.float32)
        step = 0.06
        room = L_b.copy()
        room[:, w // 2:] *= 1.0 - step  # a coarse step of 6 % of the light between columns w/2 - 1 and w/2
        ratio = px.ratio(room)
        ok = (px._inv_Lb > 0).all(2)  # coarse pixels with a photo to take a ratio of
        H, W = px.full_shape
        rows = [y for y in range(H) if ok[min(y // s, h - 1), w // 2 - 3:w // 2 + 3].all()
                and ok[min(max(y // s - 1, 0), h - 1), w // 2 - 3:w // 2 + 3].all()
                and ok[min(y // s + 1, h - 1), w // 2 - 3:w // 2 + 3].all()
                and not px._no_ratio[y, s * (w // 2 - 2):s * (w // 2 + 2)].any()]
        assert len(rows) > 10
        seg = ratio[rows, s * (w // 2 - 2):s * (w // 2 + 2)]  # full columns across the step
        assert np.abs(np.diff(seg, axis=1)).max() <= step / s * (1 + 1e-4) + 1e-6
        np.testing.assert_allclose(seg[:, 0], 1.0, atol=1e-6)
        np.testing.assert_allclose(seg[:, -1], 1.0 - step, atol=1e-6)
        # a weak pass's step of the drag budget reaches neighbouring full pixels as one of WEBER at most
        assert drag_weak_budget(s) / s == pytest.approx(drag_weak_budget(1))


def test_drag_compose_kernel_matches_its_reference(demo_engine):
    # kernels.drag_compose against DragStages.finish_reference (numpy, float32 ratio): the 8-bit frame
    # within 1 level (the two round a ratio computed in float64 and float32), radiance within 1e-4 relative
    from app.engine import FrameConfig

    scene, eng = demo_engine
    fr = eng.render(scene.obj, FrameConfig(passes=50, drag=2))
    px = eng.pixel_stages(2)
    cov = fr.coverage
    # one coarse room (the photo darkened or brightened per coarse pixel) through both finishes
    rng = np.random.default_rng(1)
    h, w = px.shape
    room_c = px.receivers.L_b.reshape(h, w, 3) * rng.uniform(0.6, 1.1, (h, w, 1))
    obj_rad = fr.radiance * (cov[..., None] > 0)
    rad_k, pix_k, room_k = px.finish(room_c.astype(np.float32), cov, obj_rad)
    rad_r, pix_r, room_r = px.finish_reference(eng, room_c.astype(np.float32), cov, obj_rad)
    assert np.abs(pix_k.astype(int) - pix_r).max() <= 1
    assert np.mean(pix_k != pix_r) < 1e-3
    np.testing.assert_allclose(room_k, room_r, rtol=1e-4, atol=1e-7)
    np.testing.assert_allclose(rad_k, rad_r, rtol=1e-4, atol=1e-7)
    # with the sun's share at full resolution (pixels, share of their light taken): room = L_b (ratio - u)
    sun_pix = np.flatnonzero(eng.receivers.recv_pix)[::7]
    share = rng.uniform(0.0, 1.0, (len(sun_pix), 3))
    rad_k, pix_k, room_k = px.finish(room_c.astype(np.float32), cov, obj_rad, (sun_pix, share))
    rad_r, pix_r, room_r = px.finish_reference(eng, room_c.astype(np.float32), cov, obj_rad, (sun_pix, share))
    assert np.abs(pix_k.astype(int) - pix_r).max() <= 1 and np.mean(pix_k != pix_r) < 1e-3
    np.testing.assert_allclose(room_k, room_r, rtol=1e-4, atol=1e-6)
    # the kernel clears the share as it reads it: the next frame without a sun has none
    rad_1, pix_1, _ = px.finish(room_c.astype(np.float32), cov, obj_rad)
    rad_0, pix_0, _ = px.finish_reference(eng, room_c.astype(np.float32), cov, obj_rad)
    assert np.abs(pix_1.astype(int) - pix_0).max() <= 1
    # a coarse room equal to the photo leaves every uncovered pixel at the photo's level
    rad1, pix1, _ = px.finish(px.receivers.L_b.reshape(h, w, 3).astype(np.float32), np.zeros_like(cov),
                              np.zeros_like(obj_rad))
    assert np.array_equal(pix1, scene.photo)


def test_rowwise_drag_compose_is_the_pixelwise_kernel_bit_for_bit(demo_engine):
    # drag_compose_kernel (each thread's run: row terms once, the four coarse ratios read again only where the left
    # coarse column changes) against drag_compose_pixelwise_kernel (every pixel its own, the kernel it replaced):
    # the same bytes, at scales 2 and 3 (3: the coarse image's last column and row clamped), with the sun's share
    # and the object, the frame cut into ranges that start mid-row (runs that cross into the next row)
    from app.engine import FrameConfig
    from kernels import runtime

    scene, eng = demo_engine
    fr = eng.render(scene.obj, FrameConfig(passes=50, drag=2))
    rng = np.random.default_rng(4)
    cov = fr.coverage
    obj_rad = fr.radiance * (cov[..., None] > 0)
    for s in (2, 3):
        px = eng.pixel_stages(s)
        h, w = px.shape
        room_c = (px.receivers.L_b.reshape(h, w, 3) * rng.uniform(0.6, 1.1, (h, w, 1))).astype(np.float32)
        sun_pix = np.flatnonzero(eng.receivers.recv_pix)[::5]
        share = rng.uniform(0.0, 0.5, (len(sun_pix), 3))
        dc = px._compose
        n = dc.H * dc.W
        cuts = [0, 1000, 20011, n // 2 + 7, n]  # ranges that start mid-row

        def split(launch, m):
            assert m == n
            for a, b in zip(cuts, cuts[1:]):
                launch(a, b)
        outs = []
        try:
            for rowwise in (False, True):
                dc.rowwise = rowwise
                outs.append([x.copy() for x in dc.run(room_c, cov.reshape(-1).astype(np.float32),
                                                      obj_rad.reshape(-1, 3).astype(np.float32), split,
                                                      (sun_pix, share))])
                outs.append([x.copy() for x in dc.run(room_c, cov.reshape(-1).astype(np.float32),
                                                      obj_rad.reshape(-1, 3).astype(np.float32),
                                                      lambda launch, m: runtime.launch_split(launch, m))])
        finally:
            dc.rowwise = True
        for a, b in zip(outs[:2], outs[2:]):
            for x, y in zip(a, b):
                assert np.array_equal(x, y)
        assert not np.array_equal(outs[0][2], outs[1][2])  # the sun's share moved pixels


def test_drag_finish_copies_only_the_objects_rectangle_bit_for_bit(demo_engine):
    # DragStages.finish given the object's rectangle (ObjectHits.rect: cov and obj_rad are 0 outside it) copies
    # only that rectangle into the kernel's buffers, the last one's zeroed first: along a drag (the rectangle
    # moving; once after a whole-frame copy of another pose) every frame is the whole-frame copy's, bit for bit
    from app.dragpath import drag_offsets, moved

    scene, eng = demo_engine
    px = eng.pixel_stages(2)
    h, w = px.shape
    room_c = px.receivers.L_b.reshape(h, w, 3).astype(np.float32) * np.float32(0.8)
    poses = []
    for k, o in enumerate(drag_offsets(scene, scene.obj, 4)):
        obj = moved(scene.obj, o)
        hits = eng.object_shading.object_hits(obj.vertices, obj.faces)
        cov = hits.coverage()
        assert (cov > 0).sum() > 100
        poses.append((hits.rect, cov, hits.average(np.ones((len(hits.hit), 3)) * (0.3 + 0.1 * k))))
    assert len({p[0] for p in poses}) == len(poses)  # the rectangle moves every time
    part = []
    for k, (rect, cov, obj_rad) in enumerate(poses):
        if k == 2:
            px.finish(room_c, np.roll(cov, 40, 1), np.roll(obj_rad, 40, 1))
        part.append([a.copy() for a in px.finish(room_c, cov, obj_rad, rect=rect)])
    for (rect, cov, obj_rad), got in zip(poses, part):
        for a, b in zip(px.finish(room_c, cov, obj_rad), got):
            assert np.array_equal(a, b)


@pytest.mark.parametrize("room", ["window_room", "lamps_room", "sun_room"])
def test_drag_frame_scores_near_the_all_sources_frame(shared_room, room):
    # each shared room against its truth (tools/score.py's measures, lighting.metrics): evaluate's drag frame
    # (1/DRAG_SCALE resolution, DRAG_PASSES passes, clusters split near the object first) within issue 36's bound, rmse_affected <= 1.5 x the all-sources frame's
    # + 0.5 and energy_ratio in 0.93-1.07 (sun_room: the sun's pass at full resolution); its change lies where
    # the full-resolution frame of as many passes changes the photo
    from app.engine import FrameConfig
    from app.evaluate import DRAG_PASSES, DRAG_SCALE

    from app.config import DRAG_PASSES_NO_SUN

    sr = shared_room(room)
    scene, eng = sr.scene, sr.engine
    # the full-resolution frame of the drag frame's passes (at most DRAG_PASSES_NO_SUN where no sun lights the
    # room): the same clusters (split near the object first)
    passes = DRAG_PASSES if eng.sun_pixels.stage is not None else min(DRAG_PASSES, DRAG_PASSES_NO_SUN)
    select = eng.shadow_sources.select
    eng.shadow_sources.select = lambda *a, near_split=False, **k: select(*a, near_split=True, **k)
    try:
        same = eng.render(scene.obj, FrameConfig(passes=passes))
    finally:
        del eng.shadow_sources.select
    drag = eng.render(scene.obj, FrameConfig(passes=DRAG_PASSES, drag=DRAG_SCALE))
    s_all, s_drag = sr.s_all, sr.score(drag.pixels)
    assert s_drag["rmse_affected"] <= 1.5 * s_all["rmse_affected"] + 0.5
    assert 0.93 <= s_drag["energy_ratio"] <= 1.07
    # the object's pixels below are compared with the full frame's at its sampling, 2 x 2 rays a pixel (the drag
    # frame casts DRAG_SUPERSAMPLE: one ray a pixel differs from a 2 x 2 mean where a pixel holds an inner edge)
    st = eng.pixel_stages(DRAG_SCALE)
    ss = st.supersample
    st.supersample, st._scene_depth = eng.params.object.supersample, None
    try:
        _object_pixels_as_at_rest(eng, scene, same)
    finally:
        st.supersample, st._scene_depth = ss, None


def _object_pixels_as_at_rest(eng, scene, same) -> None:
    """test_drag_frame_scores_near_the_all_sources_frame's checks of the drag frame's object pixels against `same`,
    the full-resolution frame of the drag frame's passes and clusters."""
    import cv2

    from app.engine import FrameConfig
    from app.evaluate import DRAG_PASSES, DRAG_SCALE

    drag = eng.render(scene.obj, FrameConfig(passes=DRAG_PASSES, drag=DRAG_SCALE))
    inside = same.coverage >= 1
    # the object from per-shape tables (app.stages.object_drag: SH9 at 27 probes, the self-visibility by
    # 30-degree cells, no rays per vertex) within 3 levels rmse of the full frame's object pixels, i.e. a few
    # per cent of the object's level, with no bias beyond 1 level (the room's light in SH9 errs by 1-3 %); in a
    # sun room within 5 levels: the sun's self-shadow edge per camera hit from a 256-texel depth map (not a ray)
    # moves the edge across a pixel of a face 20-50 times brighter than its shaded side
    diff = drag.pixels[inside].astype(float) - same.pixels[inside]
    assert np.sqrt(np.mean(diff ** 2)) <= (3.0 if eng.sun_pixels.stage is None else 5.0)
    assert abs(diff.mean()) <= 1.0
    eng.drag_object_tables = False  # the object shaded as at rest: the frames below and their bound
    drag = eng.render(scene.obj, FrameConfig(passes=DRAG_PASSES, drag=DRAG_SCALE))
    eng.drag_object_tables = True
    # shaded as at rest, the object's own pixels are the full frame's within rounding, but for the room's shadow at
    # the patch centres that lights them, read from the drag frame's maps (85 px at 1/3, app.dragframe.drag_map_res;
    # the full frame's 128): on lamps_room 7 of 8452 pixels 2 levels off, none more
    d_obj = np.abs(drag.pixels[inside].astype(int) - same.pixels[inside]).max(1)
    assert d_obj.max() <= 2 and np.mean(d_obj > 1) <= 1e-3
    # where the drag frame moves a pixel by more than 2 levels, the full-resolution frame moves it or a pixel
    # within 2 working pixels (the bilinear footprint) by more than half a level
    moved = (np.abs(same.pixels.astype(int) - scene.photo).max(2) > 0.5).astype(np.uint8)
    near = cv2.dilate(moved, np.ones((4 * DRAG_SCALE + 1,) * 2, np.uint8)) > 0
    moved_drag = np.abs(drag.pixels.astype(int) - scene.photo).max(2) > 2
    assert np.mean(moved_drag & ~near) < 1e-4


def _drag_tables_match_exact(sr, obj) -> None:
    """sun_room's drag frame of `obj` shaded from the per-shape tables against the same drag frame with the object
    shaded as at rest: the criteria of test_sun_room_drag_tables_match_the_exact_object."""
    from app.engine import FrameConfig
    from app.evaluate import DRAG_PASSES, DRAG_SCALE

    eng = sr.engine
    cfg = FrameConfig(passes=DRAG_PASSES, drag=DRAG_SCALE)
    assert eng.drag_object_tables and eng.drag_object_sun
    try:
        eng.drag_object_tables = False
        exact = eng.render(obj, cfg)
        _, L_x, _, vis_x = eng.last_shading
        eng.drag_object_tables = True
        drag = eng.render(obj, cfg)
        _, L_t, _, vis_t = eng.last_shading
        sun_t = eng.object_drag.last.L_sun
    finally:
        eng.drag_object_tables = True
    assert eng.object_drag.last is not None and eng.object_drag.last.shaded.L_vert is L_t  # the tables ran
    same = np.abs(vis_t - vis_x) <= 0.05
    assert same.mean() >= 0.98
    lum = np.array([0.2126, 0.7152, 0.0722])
    lit, dark = same & (vis_x > 0), same & (vis_x == 0)
    assert lit.sum() > 100 and dark.sum() > 100
    assert abs((L_t[lit] @ lum).mean() / (L_x[lit] @ lum).mean() - 1.0) <= 0.03
    # the shaded side without the direct sun: the drag frame's vertex radiance holds its buried vertices'
    # neighbours' sun (it subtracts it, L_sun, before its per-hit sun), the frame at rest their own (0 there)
    assert abs(((L_t - sun_t)[dark] @ lum).mean() / (L_x[dark] @ lum).mean() - 1.0) <= 0.20
    e_x, e_t = sr.score(exact.pixels)["energy_ratio"], sr.score(drag.pixels)["energy_ratio"]
    assert abs(e_t - e_x) <= 0.02


def test_sun_room_drag_tables_match_the_exact_object(shared_room):
    # sun_room's drag frame shades the chair from the per-shape tables (the sun: cos x the self-shadow cast once per
    # shape and direction x the opening per vertex; the sunlit floor patches: form factors x the visibility table)
    # against the same drag frame with the object shaded as at rest (rays per vertex and per camera hit), at the
    # scene's own pose: the vertices' sun share (cos x visibility) agrees on all but 2 % of the vertices (those on
    # the floor: a ray from the floor's plane grazes it at rest), the sunlit side's mean radiance within 3 % (the
    # sun's direct light, the same cos and shadow, is most of it), the shaded side's within 20 % (it sees the sunlit
    # floor less the object's shadow on it, the difference of two gathers each a few per cent off by the 30-degree
    # visibility cells: 3 % measured without the direct sun), the object's light on the room (the drag row's energy)
    # within 0.02
    sr = shared_room("sun_room")
    _drag_tables_match_exact(sr, sr.scene.obj)


def _tilted(obj, deg: float):
    """obj turned by `deg` about the world x axis through its lowest point's centre, then lifted to stand on the
    floor again (its lowest vertex at the old one's height): a pose not turned about +Y only."""
    import dataclasses

    a = np.radians(deg)
    Rx = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(a), -np.sin(a)], [0.0, np.sin(a), np.cos(a)]])
    c = obj.centre.copy()
    c[1] = obj.vertices[:, 1].min()
    v = (obj.vertices - c) @ Rx.T + c
    lift = np.array([0.0, c[1] - v[:, 1].min(), 0.0])
    M = obj.object_to_world.copy()
    M[:3, :3] = Rx @ M[:3, :3]
    M[:3, 3] = Rx @ (M[:3, 3] - c) + c + lift
    return dataclasses.replace(obj, vertices=v + lift, normals=obj.normals @ Rx.T, object_to_world=M)


def test_tilted_object_drag_tables_match_the_exact_object(shared_room):
    # a tilted chair (20 deg about x) in sun_room: the drag frame shades it from per-shape tables made in the world's
    # orientation (object_drag.frame_yaw: before drag109 it was shaded as at rest on every drag frame), against the
    # same drag frame with the object shaded as at rest, at its pose: the criteria of the upright chair's test above
    # (sun share on 98 % of the vertices, sunlit side within 3 %, shaded side within 20 %, energy within 0.02). A
    # translated pose keeps the shape's tables; a turn about +Y makes new ones (the tilt is in the shape's frame)
    from app.dragpath import moved
    from app.engine import FrameConfig
    from app.evaluate import DRAG_PASSES, DRAG_SCALE
    from app.stages.object_drag import frame_yaw, yaw_of

    sr = shared_room("sun_room")
    scene, eng = sr.scene, sr.engine
    obj = _tilted(scene.obj, 20.0)
    assert yaw_of(obj.object_to_world) is None and frame_yaw(obj.object_to_world) == 0.0
    np.testing.assert_allclose((obj.object_to_world[:3, :3] @ np.linalg.solve(
        scene.obj.object_to_world[:3, :3], (scene.obj.vertices - scene.obj.object_to_world[:3, 3]).T)).T
        + obj.object_to_world[:3, 3], obj.vertices, atol=1e-9)
    _drag_tables_match_exact(sr, obj)
    cfg = FrameConfig(passes=DRAG_PASSES, drag=DRAG_SCALE)
    shape = eng.object_drag._shape[1]
    eng.render(moved(obj, np.array([0.05, 0.0, -0.03])), cfg)
    assert eng.object_drag._shape[1] is shape  # a translation: the same tables
    c, s = np.cos(0.3), np.sin(0.3)
    Ry = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    m = obj.vertices.mean(0)
    M = obj.object_to_world.copy()
    M[:3, :3] = Ry @ M[:3, :3]
    M[:3, 3] = Ry @ (M[:3, 3] - m) + m
    import dataclasses

    turned = dataclasses.replace(obj, vertices=(obj.vertices - m) @ Ry.T + m, normals=obj.normals @ Ry.T,
                                 object_to_world=M)
    eng.render(turned, cfg)
    assert eng.object_drag._shape[1] is not shape


@pytest.mark.parametrize("name", ["lamps_102", "lamps_101"])
def test_unseen_lamp_rooms_drag_frame_within_the_bound(shared_scenes_cache, name):
    # unseen rooms (bench/bench_unseen.py's, rendered by ../shared/tools/roomgen.py into $PHOTOAR_ROOMS or
    # ~/.cache/photoar/rooms; skipped where not rendered), objects on the floor under lamps, issue 36's bound.
    # lamps_102, a torus whose shadow is mostly the contact band along its outline: the drag frame's cluster maps
    # at 64 px (128 / 3) leaked light into that band, rmse_affected 5.37 against the bound 5.03 (all sources 3.02);
    # at the per-source map's size at 1/3 (app.dragframe.drag_map_res: 85 px) 4.01. lamps_101, a small box: its
    # lamp's hard shadow beyond the bounding sphere fell between the graded lattice's corners at 1/3, 4.71 against
    # 1.74; exact within 2 radii (app.dragframe.DRAG_GRADED_NEAR) 1.32
    import os
    from pathlib import Path

    import cv2

    from app.dragframe import DRAG_GRADED_NEAR, drag_map_res
    from app.engine import Engine, EngineParams, FrameConfig
    from app.evaluate import DRAG_PASSES, DRAG_SCALE
    from lighting import metrics
    from recon.io import read_image_rgb
    from recon.scene import load_scene

    d = Path(os.environ.get("PHOTOAR_ROOMS", Path.home() / ".cache" / "photoar" / "rooms")) / name
    if not (d / "scene.json").is_file():
        pytest.skip(f"unseen room {d} not rendered (bench/bench_unseen.py --render)")
    scene = load_scene(d)
    eng = Engine(scene, EngineParams(), cache_dir=shared_scenes_cache, quiet=True)
    truth = read_image_rgb(d / "truth.png")
    mask = cv2.imread(str(d / "truth_mask.png"), cv2.IMREAD_GRAYSCALE)
    s_all = metrics.score_regions(eng.render(scene.obj, FrameConfig(passes=None)).pixels, scene.photo, truth, mask)
    drag = eng.render(scene.obj, FrameConfig(passes=DRAG_PASSES, drag=DRAG_SCALE))
    sp = eng.pixel_stages(DRAG_SCALE).shadow_pass
    assert sp.maps_cluster.res == drag_map_res(DRAG_SCALE, eng.params.shadow.map_res)
    assert sp.graded_near == DRAG_GRADED_NEAR
    s_drag = metrics.score_regions(drag.pixels, scene.photo, truth, mask)
    assert s_drag["rmse_affected"] <= 1.5 * s_all["rmse_affected"] + 0.5, (s_drag, s_all)
    assert 0.93 <= s_drag["energy_ratio"] <= 1.07, s_drag


def test_drag_object_hits_with_the_scene_depth_kept_are_the_frames_at_rest(demo_engine):
    # the drag frame's camera hits read the scene's distance per sub-sample from a table cast by tiles of 16 x 16 px
    # as the object first reaches them (kernels.scene_depth.SceneDepth), not a scene ray per hit (CameraHits):
    # the same rays, the same closest scene hit, so the same triangles, barycentrics and hits bit for bit, along a
    # drag and with the object half sunk into the floor (the floor in front of its lower half: the test matters)
    from app.dragpath import drag_offsets, moved

    scene, eng = demo_engine
    osh = eng.object_shading
    st = eng.pixel_stages(2)
    caster, ss = st.scene_depth(), st.supersample  # the drag frame's rays per pixel side (dragframe.DRAG_SUPERSAMPLE)
    height = np.ptp(scene.obj.vertices[:, 1])
    offsets = list(drag_offsets(scene, scene.obj, 5)) + [np.array([0.0, -0.5 * height, 0.0])]
    hidden = 0
    for o in offsets:
        pv, pf, proxy_occ, (v, n, f), shade_occ = osh.object_shape(moved(scene.obj, o))
        a = osh.object_hits(v, f, supersample=ss, occluder=shade_occ)
        b = osh.object_hits(v, f, supersample=ss, occluder=shade_occ, caster=caster)
        assert a.rect == b.rect and a.hit.sum() > 100
        assert np.array_equal(a.tri, b.tri) and np.array_equal(a.bary, b.bary) and np.array_equal(a.hit, b.hit)
        hidden = ((a.tri >= 0) & ~a.hit).sum()
    assert hidden > 50  # the sunk pose: sub-samples on the object behind the floor
    assert caster._done.any() and not caster._done.all()  # only the tiles the object reached were cast
