"""The shadow pass stage (app.stages.shadow_pass): its listed pixels and its fill.

The selection is checked against its definition written over the whole image (the form the
engine had before the stage listed pixels per patch), the fill against a direct 3x3 mean.
"""
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
    lattice = ((yy % 2 == 0) & (xx % 2 == 0)).reshape(-1) & eng.recv_pix
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
        want = eng.recv_pix & (cov.reshape(-1) < 1.0) & cand.any(1)[np.maximum(eng.pix_patch, 0)]
        near = np.linalg.norm(eng.pix_pos - centre, axis=1) < sp.near_factor * radius
        exact = want & (near | lattice | ~cover)
        pix_pt, fill_pt, cen = sp._select(centre, radius, cov, cand)
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
    pv, pf, occ, _, _ = eng._object_shape(obj)
    fs = eng.shadow_sources.select(pv.min(0), pv.max(0), None)
    centre, radius = bounding_sphere(pv)
    cov = np.zeros((scene.camera.height, scene.camera.width))
    pix_pt, _, cen = sp._select(centre, radius, cov, fs.cand)
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
            sp._upload_batch(fs.cand, fs.W_v, fs.W_c, first, n, cen)
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
