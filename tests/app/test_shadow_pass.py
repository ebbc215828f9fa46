"""The shadow pass stage (app.stages.shadow_pass): its listed pixels and its fill.

The selection is checked against its definition written over the whole image (the form the
engine had before the stage listed pixels per patch), the fill against a direct 3x3 mean.
"""
import dataclasses

import numpy as np
import pytest

from app.cli import demo_scene_dir
from app.dragpath import drag_offsets, moved
from app.engine import Engine, EngineParams, FrameConfig
from app.stages.shadow_pass import window_pairs
from kernels.maskfill import WindowFill
from recon.proxy import bounding_sphere
from recon.scene import load_scene


def _window_mean(known, values, missing, surface, W, H):
    """Mean of known values in each missing pixel's 3x3 window on its own surface (0 where none)."""
    val = {int(k): v for k, v in zip(known, values)}
    out = np.zeros((len(missing), 3))
    for i, q in enumerate(missing):
        y, x = divmod(int(q), W)
        got = [val[o] for dy in (-1, 0, 1) for dx in (-1, 0, 1)
               if 0 <= y + dy < H and 0 <= x + dx < W
               for o in [(y + dy) * W + x + dx] if o in val and surface[o] == surface[q]]
        if got:
            out[i] = np.mean(got, axis=0)
    return out


def test_fill_is_the_mean_of_known_neighbours_on_the_same_surface(device):
    rng = np.random.default_rng(3)
    W, H = 37, 23
    surface = (np.arange(W)[None, :] // 9 + 5 * (np.arange(H)[:, None] // 7)).reshape(-1).astype(np.int32)
    surface[rng.uniform(size=W * H) < 0.05] = -1  # pixels that see nothing
    order = rng.permutation(W * H)
    known, missing = order[:300], order[300:700]  # distinct; some missing pixels have no known neighbour
    values = rng.normal(size=(300, 3))
    f = WindowFill(W, H, surface, device)
    ref = _window_mean(known, values, missing, surface, W, H)
    for split in (None, lambda launch, n: [launch(a, b) for a, b in ((0, n // 3), (n // 3, n))]):
        got = f.fill(known, values, missing, split=split).copy()
        np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-12)
    assert (np.abs(ref).sum(1) == 0).sum() > 10 and (np.abs(ref).sum(1) > 0).sum() > 200
    # the index map is clean again: another call with other known pixels sees only those
    np.testing.assert_allclose(f.fill(known[:50], values[:50], missing), _window_mean(
        known[:50], values[:50], missing, surface, W, H), rtol=1e-12, atol=1e-12)


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    scene = load_scene(demo_scene_dir())
    eng = Engine(scene, EngineParams(patch_size=0.35), cache_dir=tmp_path_factory.mktemp("cache"), quiet=True)
    return scene, eng


def test_listed_pixels_follow_their_definition(demo):
    # exact: wanted receiver pixels near the object, on the lattice, or with no lattice pixel of their
    # quad in their window; filled: the other wanted ones; wanted: receivers on a candidate patch that the
    # object does not cover completely
    scene, eng = demo
    sp = eng.shadow_pass
    cam = scene.camera
    H, W = cam.height, cam.width
    yy, xx = np.mgrid[0:H, 0:W]
    lattice = ((yy % 2 == 0) & (xx % 2 == 0)).reshape(-1) & eng.receivers.recv_pix
    quad = sp.pix_quad
    cover = np.zeros(H * W, bool)
    for _, _, src, dst in window_pairs(H, W):
        cover[dst] |= lattice[src] & (quad[src] == quad[dst])
    rng = np.random.default_rng(0)
    for o in drag_offsets(scene, scene.obj, 3):
        obj = moved(scene.obj, o)
        pv = obj.vertices
        centre, radius = bounding_sphere(pv)
        fs = eng.shadow_sources.select(pv.min(0), pv.max(0), 10)
        cand = fs.cand & (rng.uniform(size=fs.cand.shape) < 0.9)  # some patches without candidates
        cov = np.zeros((H, W))
        u, v = cam.project(centre[None])[0][0].astype(int)
        cov[max(v - 20, 0):v + 20, max(u - 20, 0):u + 20] = 1.0  # a block the object covers
        cov[max(v - 25, 0):v + 25, max(u - 25, 0):max(u - 20, 0)] = 0.5  # partly covered: still wanted
        want = eng.receivers.recv_pix & (cov.reshape(-1) < 1.0) & cand.any(1)[np.maximum(eng.receivers.pix_patch, 0)]
        near = np.linalg.norm(eng.receivers.pix_pos - centre, axis=1) < sp.near_factor * radius
        exact = want & (near | lattice | ~cover)
        pix_pt, fill_pt, cen = sp.select(centre, radius, cov, cand)
        np.testing.assert_array_equal(np.sort(sp.recv[pix_pt]), np.flatnonzero(exact))
        np.testing.assert_array_equal(np.sort(sp.recv[fill_pt]), np.flatnonzero(want & ~exact))
        np.testing.assert_array_equal(cen, np.flatnonzero(cand.any(1) & ~eng.pre.patches.is_emitter))
        assert (want & near).sum() > 100 and (want & ~exact).sum() > 1000 and (cov.reshape(-1) >= 1)[want].sum() == 0


def test_frames_use_the_map_size_of_their_kind(demo):
    # a frame whose maps stand for clusters of sources uses the cluster maps, one map per source the full ones
    scene, eng = demo
    sp = eng.shadow_pass
    assert sp.maps_cluster.res == 128 and sp.maps_full.res == eng.params.map_res == 256
    fr = eng.render(scene.obj, FrameConfig(passes=3))
    assert fr.stats["passes"] == 3 and fr.stats["n_sources"] > 3 and sp.maps is sp.maps_cluster
    fr = eng.render(scene.obj, FrameConfig(passes=None))
    assert fr.stats["passes"] == fr.stats["n_sources"] and sp.maps is sp.maps_full


def test_masked_sums_are_cut_by_work_and_equal_whatever_the_cut(demo):
    # the all-sources frame's masks: the points are summed cell by cell, in ranges of near-equal
    # (point, map) pairs; every cut gives the same sums as one range, in the caller's point order
    scene, eng = demo
    sp, sums = eng.shadow_pass, eng.shadow_pass.sums
    obj = scene.obj
    pv, pf, occ, _, _ = eng.object_shading.object_shape(obj)
    fs = eng.shadow_sources.select(pv.min(0), pv.max(0), None)
    centre, radius = bounding_sphere(pv)
    cov = np.zeros((scene.camera.height, scene.camera.width))
    pix_pt, _, cen = sp.select(centre, radius, cov, fs.cand)
    pts = np.concatenate([pix_pt, sp.n_pix_points + cen])
    out = []
    for k in (1, 2, 3):
        sums.select(pts)
        order = sums.idx.host[:sums.n].copy()
        assert np.array_equal(order[sums.order], pts)  # result rows follow the caller's order
        assert np.all(np.diff(sums.point_cell[order]) >= 0)  # summed cell by cell
        maps = sp.maps_full
        maps.set_proxy(pv, pf, occ)
        for first in range(0, min(len(fs.eyes), 3 * sp.batch), sp.batch):  # the first three batches
            n = maps.prepare(fs.eyes[first:first + sp.batch])
            maps.raster(0, n)
            sp.upload_batch(fs.cand, fs.W_v, fs.W_c, first, n, cen)
            sums.prepare(maps, n, 0, sp.cand.dev, split=lambda launch, m: [launch(a, b) for a, b in
                                                                            ((0, m // 2), (m // 2, m))])
            parts = sums.balanced(k)
            # contiguous, covering every point, cut between runs (a cell's points in one part)
            assert parts[0][0] == 0 and parts[-1][1] == sums.n and len(parts) <= k
            assert all(a[1] == b[0] for a, b in zip(parts[:-1], parts[1:]))
            assert set(p[0] for p in parts) <= set(sums._run_start.tolist())
            if first == 0 and k == 2:  # the parts' work (pairs, and a unit per point): within one run's
                work = np.diff(sums._run_start) * (sums.n_list.numpy()[sums._run_cell] + 1)
                per = [work[(sums._run_start[:-1] >= a) & (sums._run_start[:-1] < b)].sum() for a, b in parts]
                assert len(parts) == 2 and abs(per[0] - per[1]) <= work.max()
            for a, b in parts:
                sums.accumulate(maps, 0, sp.weights.dev, a, b)
        out.append(sums.result())
    for acc, count in out[1:]:
        np.testing.assert_array_equal(acc, out[0][0])
        np.testing.assert_array_equal(count, out[0][1])
    assert out[0][1].sum() > 0


def test_centre_transfers_read_in_place_give_the_same_sums(demo):
    # the graded drag frame's sums read the patch centres' transfers straight from W_c (_centre_table) instead
    # of upload_batch copying their rows into the batch's weights: the same sums, bit for bit, with the copied
    # rows poisoned (NaN) to show they are not read
    scene, eng = demo
    sp, sums = eng.shadow_pass, eng.shadow_pass.sums
    pv, pf, occ, _, _ = eng.object_shading.object_shape(scene.obj)
    fs = eng.shadow_sources.select(pv.min(0), pv.max(0), None)
    centre, radius = bounding_sphere(pv)
    pix_pt, _, cen = sp.select(centre, radius, np.zeros((scene.camera.height, scene.camera.width)), fs.cand)
    table = sp._centre_table(fs.W_c)
    assert table is not None and table.ptr == fs.W_c.ctypes.data  # a view, no copy (the CPU)
    maps = sp.maps_full
    maps.set_proxy(pv, pf, occ)
    n = maps.prepare(fs.eyes[:sp.batch])  # the batch from source 0: W_c's columns are the weights' columns
    maps.raster(0, n)
    out = []
    for in_place in (False, True):
        sp.weights.host[sp.n_recv_vert:] = np.nan
        sp.upload_batch(fs.cand, fs.W_v, fs.W_c, 0, n, cen, centres=not in_place)
        sums.select(np.concatenate([pix_pt, sp.n_pix_points + cen]))
        sums.prepare(maps, n, 0, sp.cand.dev)
        for a, b in sums.balanced(2):
            if in_place:
                sums.accumulate(maps, 0, sp.weights.dev, a, b, table, sp.n_recv_vert)
            else:
                sums.accumulate(maps, 0, sp.weights.dev, a, b)
        out.append(sums.result()[0].copy())
    assert np.isfinite(out[0]).all() and np.abs(out[0][len(pix_pt):]).sum() > 0  # the centres are summed
    np.testing.assert_array_equal(out[1], out[0])


def _bilinear_reference(known, values, missing, surface, W, H, s):
    """Bilinear of each missing pixel's s x s lattice square's known corners on its own surface
    (weights renormalised), else the 3x3 mean (_window_mean)."""
    val = {int(k): v for k, v in zip(known, values)}
    out = _window_mean(known, values, missing, surface, W, H)
    for i, q in enumerate(missing):
        y, x = divmod(int(q), W)
        x0, y0 = x // s * s, y // s * s
        fx, fy = (x - x0) / s, (y - y0) / s
        acc, wsum = np.zeros(3), 0.0
        for cx, cy in ((0, 0), (1, 0), (0, 1), (1, 1)):
            w = (fx if cx else 1 - fx) * (fy if cy else 1 - fy)
            sx, sy = x0 + cx * s, y0 + cy * s
            o = sy * W + sx
            if w > 0 and sx < W and sy < H and o in val and surface[o] == surface[q]:
                acc += w * val[o]
                wsum += w
        if wsum > 0:
            out[i] = acc / wsum
    return out


def test_fill_on_a_coarser_lattice_is_bilinear_on_the_same_surface(device):
    # spacing 4 and 8: the bilinear of the known corners on the pixel's surface; a linear function
    # sampled on the lattice comes back exactly inside a surface; spacing 2 stays the 3x3 mean
    rng = np.random.default_rng(5)
    W, H = 41, 29
    surface = (np.arange(W)[None, :] // 13 + 5 * (np.arange(H)[:, None] // 11)).reshape(-1).astype(np.int32)
    yy, xx = np.divmod(np.arange(W * H), W)
    f = WindowFill(W, H, surface, device)
    for s in (4, 8):
        known = np.flatnonzero((yy % s == 0) & (xx % s == 0) & (rng.uniform(size=W * H) < 0.9))
        missing = np.setdiff1d(np.arange(W * H), known)
        values = np.stack([0.3 * xx[known] - 0.2 * yy[known] + 1.0, xx[known] * 0.0 + 2.0, 0.1 * yy[known]], 1)
        f.set_spacing(missing, s)
        got = f.fill(known, values, missing).copy()
        np.testing.assert_allclose(got, _bilinear_reference(known, values, missing, surface, W, H, s),
                                   rtol=1e-12, atol=1e-12)
        # inside a surface, with all four corners known: the linear function itself
        x0, y0 = xx[missing] // s * s, yy[missing] // s * s
        inner = np.ones(len(missing), bool)
        for cx, cy in ((0, 0), (1, 0), (0, 1), (1, 1)):
            o = np.minimum(y0 + cy * s, H - 1) * W + np.minimum(x0 + cx * s, W - 1)
            inner &= np.isin(o, known) & (surface[o] == surface[missing]) & (x0 + cx * s < W) & (y0 + cy * s < H)
        assert inner.sum() > 100
        np.testing.assert_allclose(got[inner, 0], 0.3 * xx[missing[inner]] - 0.2 * yy[missing[inner]] + 1.0,
                                   rtol=1e-9, atol=1e-9)
    f.set_spacing(np.zeros(0, np.int64), 2)  # back to the 3x3 mean everywhere
    known = np.flatnonzero((yy % 2 == 0) & (xx % 2 == 0))
    missing = np.setdiff1d(np.arange(W * H), known)
    values = rng.normal(size=(len(known), 3))
    np.testing.assert_allclose(f.fill(known, values, missing), _window_mean(known, values, missing, surface, W, H),
                               rtol=1e-12, atol=1e-12)


def test_graded_lattice_matches_the_exact_sums_on_a_real_room(shared_scenes_cache):
    # window_room at 50 passes, the object at its own pose: the graded frame's shadow fractions
    # (exact pixels, and the ones filled from them) against every wanted pixel summed exactly
    from tests.conftest import shared_scene

    scene = load_scene(shared_scene("window_room"))
    eng = Engine(scene, EngineParams(), cache_dir=shared_scenes_cache, quiet=True)
    sp = eng.shadow_pass
    obj = scene.obj
    pv, pf, occ, shade_mesh, shade_occ = eng.object_shading.object_shape(obj)
    centre, radius = bounding_sphere(pv)
    cov = eng.object_shading.object_hits(shade_mesh[0], shade_mesh[2], occluder=shade_occ).coverage()
    fs = eng.shadow_sources.select(pv.min(0), pv.max(0), 50)

    def masks(scale):
        steps = sp.run((pv, pf, occ), centre, radius, cov, fs.cand, fs.eyes, fs.W_v, fs.W_c, False,
                       spread=fs.spread, scale=scale)
        while True:
            try:
                next(steps)
            except StopIteration as stop:
                return stop.value

    E = eng.receivers.E_x
    g = masks(E)
    counts = dict(sp.last_graded)
    # a pixel is summed or filled, never both (compose would overwrite the exact sum with the fill)
    assert len(np.intersect1d(g.pix_sel, g.fill_sel)) == 0
    frac_g = np.zeros(E.shape)
    frac_g[g.pix_sel] = g.O_pix / np.maximum(E[g.pix_sel], 1e-12)
    frac_g[g.fill_sel] = sp.fill(g.pix_sel, frac_g[g.pix_sel], g.fill_sel)
    near, sp.near_factor = sp.near_factor, 1e9  # every wanted pixel exact
    try:
        x = masks(None)
    finally:
        sp.near_factor = near
    assert len(x.fill_sel) == 0 and set(x.pix_sel.tolist()) == set(g.pix_sel.tolist()) | set(g.fill_sel.tolist())
    frac_x = np.zeros(E.shape)
    frac_x[x.pix_sel] = x.O_pix / np.maximum(E[x.pix_sel], 1e-12)
    err = np.abs(frac_g - frac_x).max(1)[g.fill_sel]
    print("graded:", counts, "fill error mean", err.mean(), "p99", np.percentile(err, 99), "max", err.max())
    # most wanted pixels are filled on the coarse lattices: a frame sums far fewer points
    assert counts[8] + counts[4] > 0.5 * len(g.fill_sel) and counts["exact"] < 0.15 * len(x.pix_sel)
    assert err.mean() < 0.1 * sp.refine_tol and np.percentile(err, 99) < sp.refine_tol
    np.testing.assert_allclose(g.O_cen, x.O_cen, rtol=1e-5, atol=1e-7)  # patch centres are all summed


def _demo_object(scene, eng):
    """(pv, pf, occ, centre, radius, cov) of the demo's object: its proxy shape, bounding sphere and an
    all-zero coverage image (the masks' tests see the room without the object's own pixels)."""
    pv, pf, occ, _, _ = eng.object_shading.object_shape(scene.obj)
    centre, radius = bounding_sphere(pv)
    return pv, pf, occ, centre, radius, np.zeros((scene.camera.height, scene.camera.width))


def test_pipelined_batches_give_the_same_masks(demo):
    # the all-sources frame draws batch k+1's maps (into the twin set) while batch k is summed: the
    # masks are bitwise those of drawing, then summing, each batch in turn; likewise a cluster frame
    # of several batches (the non-graded path)
    scene, eng = demo
    sp = eng.shadow_pass
    pv, pf, occ, centre, radius, cov = _demo_object(scene, eng)
    for passes in (None, 2 * sp.batch + 5):
        fs = eng.shadow_sources.select(pv.min(0), pv.max(0), passes)
        assert len(fs.eyes) > sp.batch  # several batches: the twin maps are used
        out = []
        for pipelined in (False, True, False):
            sp.pipelined = pipelined
            steps = sp.run((pv, pf, occ), centre, radius, cov, fs.cand, fs.eyes, fs.W_v, fs.W_c, passes is None,
                           spread=fs.spread)
            done = []
            try:
                while True:
                    done.append(next(steps))
            except StopIteration as stop:
                out.append(stop.value)
            assert done[-1] == len(fs.eyes)
        sp.pipelined = True
        assert np.abs(out[0].O_pix).sum() > 0
        for m in out[1:]:
            np.testing.assert_array_equal(m.O_pix, out[0].O_pix)
            np.testing.assert_array_equal(m.O_cen, out[0].O_cen)
            np.testing.assert_array_equal(m.pix_sel, out[0].pix_sel)


def test_the_sun_takes_a_pass_of_the_budget_and_leaves_the_masks_alone(shared_scenes_cache, monkeypatch):
    # sun_room: the sun takes one pass of a frame's budget and adds no cluster map, and nothing of the
    # masks depends on it: switched off as bench/bench_sun.py's A/B switches it (sun_pix None, sun_on
    # False), the frame of one pass less lists the same maps and gives the same masks, bit for bit
    # (so the A/B's masks differ only by its one cluster map more without the sun)
    from tests.conftest import shared_scene

    scene = load_scene(shared_scene("sun_room"))
    eng = Engine(scene, EngineParams(passes=50), cache_dir=shared_scenes_cache, quiet=True)
    assert eng.sun_pixels.pix is not None and eng.sun.on
    got = {}
    run = eng.shadow_pass.run

    def spy(*args, **kwargs):
        got["eyes"], got["cand"] = args[5].copy(), args[4].copy()
        got["masks"] = yield from run(*args, **kwargs)
        return got["masks"]

    monkeypatch.setattr(eng.shadow_pass, "run", spy)
    obj = moved(scene.obj, drag_offsets(scene, scene.obj, 2)[1])
    frames = {}
    for on, passes in ((True, 50), (False, 49), (False, 50)):
        if not on:
            monkeypatch.setattr(eng, "sun_pixels", dataclasses.replace(eng.sun_pixels, pix=None, stage=None))
        st = eng.render(obj, FrameConfig(passes, eng.params.mode)).stats
        frames[on, passes] = dict(got, passes=st["passes"])
    sun, off, off50 = frames[True, 50], frames[False, 49], frames[False, 50]
    assert sun["passes"] == 50 and len(sun["eyes"]) == 49  # 49 cluster maps and the sun's pass
    assert off["passes"] == len(off["eyes"]) == 49 and off50["passes"] == len(off50["eyes"]) == 50
    np.testing.assert_array_equal(sun["eyes"], off["eyes"])
    np.testing.assert_array_equal(sun["cand"], off["cand"])
    for f in ("pix_sel", "fill_sel", "cen_sel", "O_pix", "O_cen"):
        np.testing.assert_array_equal(getattr(sun["masks"], f), getattr(off["masks"], f), err_msg=f)


def _masks(sp, proxy, centre, radius, cov, fs, W_v=None, order=None):
    """ShadowPass.run's Masks of an all-sources frame (its generator run to the end)."""
    steps = sp.run(proxy, centre, radius, cov, fs.cand, fs.eyes, fs.W_v if W_v is None else W_v, fs.W_c, True,
                   order=order)
    try:
        while True:
            next(steps)
    except StopIteration as stop:
        return stop.value


def test_all_sources_order_and_half_size_maps(demo):
    # run(order=(perm, hard)): the passes drawn in the order perm, the first `hard` on map_res maps, the
    # others on cluster_map_res maps with the same hard lookup. Every pass hard in a shuffled order: the
    # masks of the listed order (sums in another order: float rounding); none hard: bitwise the frame whose
    # every map is half-size; a mix: the sum of the two parts drawn apart (each with the other's transfers
    # zero, so the same pixels are listed); the weak passes sum every listed pixel here (weak_lattice off:
    # test_weak_passes_fill_the_near_ring)
    scene, eng = demo
    sp = eng.shadow_pass
    sp.weak_lattice = False
    try:
        _order_and_half_size_maps(scene, eng, sp)
    finally:
        sp.weak_lattice = True


def _order_and_half_size_maps(scene, eng, sp):
    pv, pf, occ, centre, radius, cov = _demo_object(scene, eng)
    proxy = (pv, pf, occ)
    fs = eng.shadow_sources.select(pv.min(0), pv.max(0), None)
    S = len(fs.eyes)
    assert S > 2 * sp.batch
    perm = np.random.default_rng(5).permutation(S)
    ref = _masks(sp, proxy, centre, radius, cov, fs)
    assert np.abs(ref.O_pix).sum() > 0
    got = _masks(sp, proxy, centre, radius, cov, fs, order=(perm, S))
    np.testing.assert_array_equal(got.pix_sel, ref.pix_sel)
    np.testing.assert_allclose(got.O_pix, ref.O_pix, rtol=1e-5, atol=1e-6 * np.abs(ref.O_pix).max())
    np.testing.assert_allclose(got.O_cen, ref.O_cen, rtol=1e-5, atol=1e-6 * np.abs(ref.O_cen).max())
    full = sp.maps_full
    try:  # every map half-size
        sp.maps_full = sp.maps_cluster
        half = _masks(sp, proxy, centre, radius, cov, fs)
    finally:
        sp.maps_full = full
    got = _masks(sp, proxy, centre, radius, cov, fs, order=(np.arange(S), 0))
    np.testing.assert_array_equal(got.O_pix, half.O_pix)
    assert np.abs(half.O_pix - ref.O_pix).max() > 0  # the map size shows
    h = S // 3 + 1  # a mix: the first h of perm full-size
    got = _masks(sp, proxy, centre, radius, cov, fs, order=(perm, h))
    W = np.asarray(fs.W_v)
    Wa, Wb = W.copy(), W.copy()
    Wa[:, perm[h:]] = 0.0
    Wb[:, perm[:h]] = 0.0
    a = _masks(sp, proxy, centre, radius, cov, fs, W_v=Wa)
    try:
        sp.maps_full = sp.maps_cluster
        b = _masks(sp, proxy, centre, radius, cov, fs, W_v=Wb)
    finally:
        sp.maps_full = full
    np.testing.assert_allclose(got.O_pix, a.O_pix + b.O_pix, rtol=1e-5, atol=1e-6 * np.abs(ref.O_pix).max())


def test_pipelined_batches_and_column_gather_give_the_same_masks(demo):
    # the all-sources frame's batches take scattered columns (order): gathered by kernels.gather, with the next
    # batch's maps drawn on the side thread (pipelined) or not, the masks are bitwise those of numpy's gather,
    # each batch drawn and summed in turn
    scene, eng = demo
    sp = eng.shadow_pass
    pv, pf, occ, centre, radius, cov = _demo_object(scene, eng)
    fs = eng.shadow_sources.select(pv.min(0), pv.max(0), None)
    S = len(fs.eyes)
    assert S > 2 * sp.batch
    order = (np.random.default_rng(7).permutation(S), S // 2)
    gather, defaults = sp._gather, (sp._gather, sp.pipelined)
    assert gather is not None  # the CPU device
    out = []
    try:
        for g, pipelined in ((None, False), (gather, True), (None, True), (gather, False)):
            sp._gather, sp.pipelined = g, pipelined
            out.append(_masks(sp, (pv, pf, occ), centre, radius, cov, fs, order=order))
    finally:
        sp._gather, sp.pipelined = defaults
    assert np.abs(out[0].O_pix).sum() > 0 and np.abs(out[0].O_cen).sum() > 0
    for m in out[1:]:
        np.testing.assert_array_equal(m.pix_sel, out[0].pix_sel)
        np.testing.assert_array_equal(m.O_pix, out[0].O_pix)
        np.testing.assert_array_equal(m.O_cen, out[0].O_cen)


def test_weak_passes_fill_the_near_ring(demo):
    # run(order=(perm, hard)) with weak_lattice: the weak passes are not summed at the ring's pixels (listed for
    # being within near_factor radii, off the lattice, at graded_near radii or more) but filled there from their
    # sums at the other listed pixels (the 3x3 same-quad mean); the strong passes are summed at every pixel.
    # Against the strong and the weak passes drawn apart (each with the other's transfers zero), every pixel
    # summed so
    # (the far lattice off: test_weak_passes_sum_the_far_lattice_at_spacing_4)
    scene, eng = demo
    sp = eng.shadow_pass
    far = sp.weak_far
    sp.weak_far = 0.0
    try:
        _weak_ring(scene, eng, sp)
    finally:
        sp.weak_far = far


def _demo_passes(scene, eng, seed: int, strong_share: int):
    """(proxy, centre, radius, cov, fs, perm, h): the demo object's proxy and bounds, the source list over its
    box, a seeded order of its passes and the count h = S // strong_share + 1 of them drawn first (strong)."""
    pv, pf, occ, centre, radius, cov = _demo_object(scene, eng)
    fs = eng.shadow_sources.select(pv.min(0), pv.max(0), None)
    S = len(fs.eyes)
    return (pv, pf, occ), centre, radius, cov, fs, np.random.default_rng(seed).permutation(S), S // strong_share + 1


def _strong_and_weak_apart(sp, proxy, centre, radius, cov, fs, perm, h):
    """(strong, weak) masks of the passes drawn apart: the strong passes perm[:h] on their full maps with the
    weak passes' transfers zero, and the weak passes perm[h:] on the cluster maps with the strong ones' zero."""
    W = np.asarray(fs.W_v)
    Wa, Wb = W.copy(), W.copy()
    Wa[:, perm[h:]] = 0.0
    Wb[:, perm[:h]] = 0.0
    a = _masks(sp, proxy, centre, radius, cov, fs, W_v=Wa)
    full = sp.maps_full
    try:
        sp.maps_full = sp.maps_cluster
        b = _masks(sp, proxy, centre, radius, cov, fs, W_v=Wb)
    finally:
        sp.maps_full = full
    return a, b


def _weak_ring(scene, eng, sp):
    proxy, centre, radius, cov, fs, perm, h = _demo_passes(scene, eng, seed=11, strong_share=3)
    got = _masks(sp, proxy, centre, radius, cov, fs, order=(perm, h))
    pix_pt = sp.recv_index[got.pix_sel]
    ring = sp.weak_ring(pix_pt, centre, radius)
    d = np.linalg.norm(sp.pt_pos[pix_pt] - centre, axis=1)
    assert ring.sum() > 100  # the demo's object has a ring
    assert np.all(d[ring] >= sp.graded_near * radius) and np.all(d[ring] < sp.near_factor * radius)
    assert not np.any(sp.lattice[got.pix_sel[ring]])
    a, b = _strong_and_weak_apart(sp, proxy, centre, radius, cov, fs, perm, h)
    np.testing.assert_array_equal(a.pix_sel, got.pix_sel)
    tol = 1e-6 * np.abs(a.O_pix + b.O_pix).max()
    keep = ~ring
    np.testing.assert_allclose(got.O_pix[keep], a.O_pix[keep] + b.O_pix[keep], rtol=1e-5, atol=tol)
    filled = sp.fill(got.pix_sel[keep], b.O_pix[keep], got.pix_sel[ring]).copy()
    np.testing.assert_allclose(got.O_pix[ring], a.O_pix[ring] + filled, rtol=1e-5, atol=tol)
    assert np.abs(b.O_pix[ring]).sum() > 0 and np.abs(filled - b.O_pix[ring]).max() > 0  # the fill shows


def test_weak_passes_sum_the_far_lattice_at_spacing_4(demo):
    # run(order=(perm, hard)) with weak_far: beyond weak_far bounding radii the weak passes are summed on the
    # spacing-4 lattice only; at the other pixels of the spacing-2 lattice there (whose square's four corners
    # they sum) their sums are the bilinear interpolation of the corners' (kernels.maskfill, spacing 4), and
    # at the near ring's pixels the 3x3 mean as before (of the lattice's values, filled or summed). The strong
    # passes are summed at every pixel. Against the strong and the weak passes drawn apart (each with the
    # other's transfers zero), every pixel summed so
    scene, eng = demo
    sp = eng.shadow_pass
    proxy, centre, radius, cov, fs, perm, h = _demo_passes(scene, eng, seed=13, strong_share=4)
    far = sp.weak_far
    assert far > sp.graded_near
    sp.weak_far = sp.graded_near  # the demo's image: enough of the spacing-4 lattice within a few radii
    try:
        got = _masks(sp, proxy, centre, radius, cov, fs, order=(perm, h))
        pix_pt = sp.recv_index[got.pix_sel]
        ring = sp.weak_ring(pix_pt, centre, radius)
        coarse = sp.weak_coarse(pix_pt, centre, radius, ring)
    finally:
        sp.weak_far = far
    assert coarse.sum() > 100 and not np.any(coarse & ring)
    y, x = np.divmod(got.pix_sel[coarse], sp.width)
    assert np.all((x % 2 == 0) & (y % 2 == 0)) and not np.any((x % 4 == 0) & (y % 4 == 0))
    d = np.linalg.norm(sp.pt_pos[pix_pt] - centre, axis=1)
    assert np.all(d[coarse] >= sp.graded_near * radius)
    # their squares' corners: summed pixels of the frame, on the same quad
    corners = sp.sq_corners[4][sp.pt_sq[4][pix_pt[coarse]]]
    assert np.all(np.isin(corners, pix_pt[~coarse & ~ring]))
    a, b = _strong_and_weak_apart(sp, proxy, centre, radius, cov, fs, perm, h)
    np.testing.assert_array_equal(a.pix_sel, got.pix_sel)
    tol = 1e-6 * np.abs(a.O_pix + b.O_pix).max()
    keep = ~ring & ~coarse
    np.testing.assert_allclose(got.O_pix[keep], a.O_pix[keep] + b.O_pix[keep], rtol=1e-5, atol=tol)
    # bilinear at spacing 4, by hand: the corners' weights (1 - fx, fx) x (1 - fy, fy), fx = (x mod 4) / 4
    at = {int(p): i for i, p in enumerate(got.pix_sel)}
    want = np.zeros((int(coarse.sum()), 3))
    for n, (px, py) in enumerate(zip(x, y)):
        x0, y0 = px // 4 * 4, py // 4 * 4
        fx, fy = (px - x0) / 4, (py - y0) / 4
        for cx, cy, w in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)), (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):
            if w > 0:
                want[n] += w * b.O_pix[at[(y0 + 4 * cy) * sp.width + x0 + 4 * cx]]
    np.testing.assert_allclose(got.O_pix[coarse], a.O_pix[coarse] + want, rtol=1e-5, atol=tol)
    assert np.abs(want - b.O_pix[coarse]).max() > 0  # the interpolation shows
    lat = b.O_pix.copy()
    lat[coarse] = want
    filled = sp.fill(got.pix_sel[~ring], lat[~ring], got.pix_sel[ring]).copy()
    np.testing.assert_allclose(got.O_pix[ring], a.O_pix[ring] + filled, rtol=1e-5, atol=tol)


def test_source_cells_give_the_same_masks(demo):
    # the frames with a map per source sum in culling cells of TILE_SOURCE px (source_cells): the cells' lists are
    # conservative (kernels.masked_sums), so a point adds the same maps in the same order as in TILE's cells: the
    # masks bitwise those of TILE's cells, with fewer (cell, map) entries
    from app.stages.shadow_pass import TILE, TILE_SOURCE

    scene, eng = demo
    sp = eng.shadow_pass
    assert TILE_SOURCE > TILE and sp.sums_source.n_cells < sp.sums.n_cells
    pv, pf, occ, centre, radius, cov = _demo_object(scene, eng)
    fs = eng.shadow_sources.select(pv.min(0), pv.max(0), None)
    S = len(fs.eyes)
    order = (np.random.default_rng(17).permutation(S), S // 3)
    out = []
    try:
        for cells in (False, True):
            sp.source_cells = cells
            out.append(_masks(sp, (pv, pf, occ), centre, radius, cov, fs, order=order))
    finally:
        sp.source_cells = True
    assert np.abs(out[0].O_pix).sum() > 0 and np.abs(out[0].O_cen).sum() > 0
    np.testing.assert_array_equal(out[1].pix_sel, out[0].pix_sel)
    np.testing.assert_array_equal(out[1].O_pix, out[0].O_pix)
    np.testing.assert_array_equal(out[1].O_cen, out[0].O_cen)


def test_set_taps_refuses_fewer_than_two(demo):
    # a PCSS lookup needs at least 2 taps per axis: 1 is refused with one line, and the taps stay as they were
    _, eng = demo
    sp = eng.shadow_pass
    before = sp.taps
    with pytest.raises(ValueError, match="at least 2 taps per axis, got 1"):
        sp.set_taps(1)
    assert sp.taps == before and sp.maps_full.taps == before


def _refine_reference(sp, pend, test, mark, tol, extra=None):
    """The numpy of _graded_finer's refine tests and next corners, per point (GradedRefine.step's contract)."""
    known, allowed, frac = sp._known, sp._allowed, sp._frac
    state = np.full(len(pend), 2, np.uint8)
    if test:
        c = sp.sq_corners[test][sp.pt_sq[test][pend]] if test in (4, 8) else sp.corners[pend].astype(np.int64)
        c = np.where(c == -2, c[:, :1], c)  # a corner of zero weight: the first one
        ok = np.all((c >= 0) & known[np.maximum(c, 0)], axis=1)
        f = frac[np.maximum(c, 0)]
        with np.errstate(invalid="ignore"):
            ok &= (f.max(1) - f.min(1)).max(1) <= tol  # NaN: not agreed
        state[ok] = 1
        state[known[pend]] = 0
    rest = pend[state == 2]
    new = [np.zeros(0, np.int64) if extra is None else extra]
    if mark in (4, 8):
        c = sp.sq_corners[mark][sp.pt_sq[mark][rest]].reshape(-1)
        c = c[c >= 0]
        new.append(c[allowed[c] & ~known[c]])
    elif mark == 2:
        c2 = sp.corners[rest]
        ok2 = (c2 >= 0) & allowed[np.maximum(c2, 0)]
        n2 = np.concatenate([c2[ok2], rest[~ok2.any(1)]])
        new.append(n2[~known[n2]])
    return state, np.unique(np.concatenate(new))


def test_refine_kernel_gives_the_numpy_refine_tests(demo):
    # kernels.graded_refine (each spacing's refine test and the next corners in one launch) against the numpy it
    # replaced, on the demo's lattices with random flags and fractions: the fractions on a grid of tol / 2 (so that
    # many squares differ by exactly tol: the <= is tested at its edge), some NaN, and every test and mark mode.
    # The outputs are flags and point lists: equal, no tolerance
    _, eng = demo
    sp = eng.shadow_pass
    R = sp.n_pix_points
    rng = np.random.default_rng(7)
    tol = 0.1
    saved = sp._known.copy(), sp._allowed.copy(), sp._frac.copy()
    try:
        for trial in range(3):
            sp._known[:] = rng.random(R) < (0.2, 0.6, 0.95)[trial]
            sp._allowed[:] = rng.random(R) < 0.9
            sp._frac[:] = rng.integers(0, 3, (R, 3)) * (tol / 2) + 0.25
            sp._frac[rng.random(R) < 0.01, rng.integers(0, 3)] = np.nan
            pend = np.flatnonzero(sp._allowed & (rng.random(R) < 0.7))
            extra = np.sort(rng.choice(R, 5, replace=False))
            for test, mark in ((0, 8), (8, 4), (4, 2), (2, 0), (8, 0), (4, 8), (0, 2)):
                st, new = sp._refine.step(pend, test, mark, tol, extra if test == 0 else None)
                ref_st, ref_new = _refine_reference(sp, pend, test, mark, tol, extra if test == 0 else None)
                assert (st == 1).sum() > 0 or test == 0
                np.testing.assert_array_equal(st, ref_st)
                np.testing.assert_array_equal(new, ref_new)
                assert not sp._refine._need_np.any()  # the flags are left cleared
    finally:
        sp._known[:], sp._allowed[:], sp._frac[:] = saved


def test_graded_frame_refined_by_the_kernel_is_the_numpy_frame(demo):
    # the graded (drag) frame's masks with the refine tests launched (refine_on_device) are bitwise those of the
    # numpy refine (_graded_finer), at two tolerances, and the frame fills and sums as many points as it did
    scene, eng = demo
    sp = eng.shadow_pass
    pv, pf, occ, centre, radius, cov = _demo_object(scene, eng)
    fs = eng.shadow_sources.select(pv.min(0), pv.max(0), 16)
    tol0 = sp.refine_tol
    try:
        for tol in (tol0, tol0 / 4):
            sp.refine_tol = tol
            out = []
            for on_device in (False, True):
                sp.refine_on_device = on_device
                steps = sp.run((pv, pf, occ), centre, radius, cov, fs.cand, fs.eyes, fs.W_v, fs.W_c, False,
                               spread=fs.spread, scale=eng.receivers.E_x)
                while True:
                    try:
                        next(steps)
                    except StopIteration as stop:
                        out.append((stop.value, dict(sp.last_graded)))
                        break
            (a, ga), (b, gb) = out
            assert ga == gb and ga[8] + ga[4] + ga[2] > 0
            for f in ("pix_sel", "fill_sel", "cen_sel", "O_pix", "O_cen"):
                np.testing.assert_array_equal(getattr(b, f), getattr(a, f))
            assert not sp._known.any()
    finally:
        sp.refine_tol, sp.refine_on_device = tol0, True


def test_hard_centres_take_each_cluster_eye_s_hard_lookup(demo):
    # ShadowPass.hard_centres (the drag frame's patch centres): with MaskedSum.accumulate's hard_from at the first
    # centre point, the pixels' sums are the penumbra's, bit for bit, and each centre's sum is the one its cluster
    # maps give as point sources at their eyes (the same maps prepared with no spread: the hard lookup's branch);
    # the two hard branches project with float32 formulas that differ in rounding, so a centre on a texel's edge
    # may flip one map: at most 0.5 % of the centres
    scene, eng = demo
    sp, sums = eng.shadow_pass, eng.shadow_pass.sums
    pv, pf, occ, _, _ = eng.object_shading.object_shape(scene.obj)
    fs = eng.shadow_sources.select(pv.min(0), pv.max(0), 16, near_split=True)
    centre, radius = bounding_sphere(pv)
    pix_pt, _, cen = sp.select(centre, radius, np.zeros((scene.camera.height, scene.camera.width)), fs.cand)
    maps = sp.maps_cluster
    maps.set_proxy(pv, pf, occ)
    n = len(fs.eyes)
    assert 1 < n <= sp.batch and np.linalg.norm(fs.spread, axis=2).max() > 0  # clusters with a spread
    sp.upload_batch(fs.cand, fs.W_v, fs.W_c, 0, n, cen)
    out = {}
    for name, spread, hard in (("penumbra", True, None), ("hard centres", True, sp.n_pix_points),
                               ("point eyes", False, None)):
        if spread:
            maps.prepare(fs.eyes, np.linalg.norm(fs.spread, axis=2).max(1), fs.spread)
        else:
            maps.prepare(fs.eyes)
        maps.raster(0, n)
        sums.select(np.concatenate([pix_pt, sp.n_pix_points + cen]))
        sums.prepare(maps, n, 0, sp.cand.dev)
        for a, b in sums.balanced(2):
            sums.accumulate(maps, 0, sp.weights.dev, a, b, hard_from=hard)
        out[name] = sums.result()[0].copy()
    k = len(pix_pt)
    np.testing.assert_array_equal(out["hard centres"][:k], out["penumbra"][:k])
    c_hard, c_eye, c_pen = out["hard centres"][k:], out["point eyes"][k:], out["penumbra"][k:]
    assert np.abs(c_pen - c_hard).max() > 1e-3 * np.abs(c_pen).max()  # the centres' penumbrae did count
    off = np.abs(c_hard - c_eye).max(1) > 1e-6 * np.abs(c_eye).max()
    assert off.sum() <= max(1, 0.005 * len(cen)), f"{off.sum()} of {len(cen)} centres differ"
