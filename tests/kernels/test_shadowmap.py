"""Tests for kernels.shadowmap.ShadowMaps and kernels.masked_sums.MaskedSum.

Scene: a square plate (two triangles) at y = 1 over the floor y = 0, point sources above it. The
reference is exact and analytic: the segment from a floor point p to an eye e crosses the plate's
plane at p + (e - p) / e_y, and is blocked when that point lies inside the square.
"""
import sys
from pathlib import Path

import numpy as np
import pytest
import warp as wp

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from kernels.masked_sums import MaskedSum  # noqa: E402
from kernels.shadowmap import ShadowMaps  # noqa: E402

HALF = 0.5  # plate half-size (m)
PLATE_Y = 1.0
PLATE_V = np.array([[-HALF, PLATE_Y, -HALF], [-HALF, PLATE_Y, HALF], [HALF, PLATE_Y, HALF], [HALF, PLATE_Y, -HALF]])
PLATE_F = np.array([[0, 1, 2], [0, 2, 3]], np.int32)
# map-mode eyes well outside the plate's bounding sphere (radius ~0.71 about (0,1,0))
EYES = np.array([[0.0, 2.5, 0.0], [0.6, 2.2, -0.3], [-0.8, 2.8, 0.5], [0.3, 3.0, 0.9], [-0.4, 2.0, -0.7]])
RAY_EYE = np.array([0.1, 1.4, -0.05])  # inside the bounding sphere: resolved by exact rays


def _floor_grid(step=0.05, ext=3.0):
    # offset so that no crossing lands exactly on the plate's edge (a tie the exact test cannot break)
    g = np.arange(-ext, ext + 1e-9, step) + 0.01234
    X, Z = np.meshgrid(g, g + 0.00567)
    return np.column_stack([X.ravel(), np.zeros(X.size), Z.ravel()])


def _exact(points, eyes):
    """(N,S) bool occlusion by the plate, and (N,S) signed margin (m) of the crossing inside the square."""
    t = (PLATE_Y - points[:, None, 1]) / (eyes[None, :, 1] - points[:, None, 1])
    q = points[:, None, :] + t[..., None] * (eyes[None, :, :] - points[:, None, :])
    margin = HALF - np.maximum(np.abs(q[..., 0]), np.abs(q[..., 2]))
    return margin > 0, margin


def _masked(device, points, rows=None, bary=None, group=None):
    n = len(points)
    rows = np.zeros((n, 3), np.int32) if rows is None else rows
    bary = np.tile([1.0, 0.0, 0.0], (n, 1)) if bary is None else bary
    group = np.zeros(n, np.int32) if group is None else group
    return MaskedSum(points, rows, bary, group, device)


def _wp2(a, dtype, device):
    return wp.array(np.ascontiguousarray(a), dtype=dtype, device=device)


def _run(device, points, eyes, weights=None, cand=None, batches=None, capacity=None, res=256, **kw):
    """MaskedSum over the eyes rendered in the given batch sizes; returns (sums, counts)."""
    S = len(eyes)
    weights = np.ones((1, S, 3), np.float32) if weights is None else weights
    cand = np.ones((1, S), np.uint8) if cand is None else cand
    batches = [S] if batches is None else batches
    maps = ShadowMaps(capacity or max(batches), res, device=device)
    maps.set_proxy(PLATE_V, PLATE_F)
    acc = _masked(device, points, **kw)
    cand_wp = _wp2(cand.astype(np.uint8), wp.uint8, device)
    w_wp = _wp2(weights.astype(np.float32), wp.vec3, device)
    first = 0
    for b in batches:
        n = maps.render(eyes[first:first + b])
        assert n == b
        acc.add(maps, n, first, cand_wp, w_wp)
        first += n
    return acc.result()


def test_depth_map_values(device):
    # the map from straight above stores the plate's depth along the view axis; pixels off the plate stay empty
    maps = ShadowMaps(2, 64, device=device)
    maps.set_proxy(PLATE_V, PLATE_F)
    assert maps.render(EYES[:1]) == 1
    d = maps.depth_numpy()
    assert d.shape == (2, 64, 64)
    np.testing.assert_allclose(d[0, 24:40, 24:40], 2.5 - PLATE_Y, rtol=1e-5)
    # the square inscribed in the fitted circle leaves the corners of the map empty
    assert np.isinf(d[0, :4, :4]).all() and np.isinf(d[0, -4:, -4:]).all()
    assert np.isinf(d[1]).all()  # the unused slot of the batch is empty
    with pytest.raises(ValueError):
        maps.render(EYES[:3])  # more maps than the batch capacity


def test_mask_matches_exact_rays(device):
    # occluded-map counts from shadow maps agree with exact segment/plate tests on >= 99% of floor points
    pts = _floor_grid()
    occ, margin = _exact(pts, EYES)
    _, count = _run(device, pts, EYES)
    ref = occ.sum(1)
    assert 0.05 < (ref > 0).mean() < 0.6  # a real shadow, and a real lit area
    assert (count == ref).mean() >= 0.99
    clear_miss = (margin < -0.02).all(1)
    assert clear_miss.sum() > 1000 and np.all(count[clear_miss] == 0)
    clear = (np.abs(margin) > 0.02).all(1)  # every crossing at least 2 cm from the plate's edge
    np.testing.assert_array_equal(count[clear], ref[clear])
    assert (ref[clear] == len(EYES)).sum() > 50  # the umbra is among the clear points


def test_eye_inside_bounding_sphere_uses_exact_rays(device):
    # an eye inside the proxy's bounding sphere is resolved by ray casting: same answer as the exact test
    pts = _floor_grid(step=0.04, ext=4.0)
    occ, margin = _exact(pts, RAY_EYE[None])
    _, count = _run(device, pts, RAY_EYE[None])
    assert 0.02 < occ.mean() < 0.5
    near_edge = np.abs(margin[:, 0]) < 1e-5
    np.testing.assert_array_equal(count[~near_edge], occ[~near_edge, 0].astype(float))
    # mixed batch: ray-mode and map-mode eyes side by side each keep their own mode
    eyes = np.vstack([EYES[:2], RAY_EYE, EYES[2:]])
    occ, margin = _exact(pts, eyes)
    _, count = _run(device, pts, eyes)
    clear = (np.abs(margin) > 0.02).all(1)
    np.testing.assert_array_equal(count[clear], occ[clear].sum(1))
    assert (count == occ.sum(1)).mean() >= 0.99


def test_batches_reuse_buffers(device):
    # 3 maps then 2 maps through one ShadowMaps object accumulate exactly what 5 maps at once do
    pts = _floor_grid(step=0.06)
    S = len(EYES)
    W = (np.arange(S, dtype=np.float32)[None, :, None] + 1.0) * np.array([1.0, 10.0, 100.0], np.float32)
    one_acc, one_cnt = _run(device, pts, EYES, weights=W)
    for capacity in (3, 5):
        acc, cnt = _run(device, pts, EYES, weights=W, batches=[3, 2], capacity=capacity)
        np.testing.assert_array_equal(cnt, one_cnt)
        np.testing.assert_allclose(acc, one_acc, rtol=1e-6)
    # reversing the order of the eyes (so batch 2 reuses slots last filled by other eyes) changes nothing
    acc, cnt = _run(device, pts, EYES[::-1], weights=W[:, ::-1], batches=[3, 2], capacity=3)
    np.testing.assert_array_equal(cnt, one_cnt)
    np.testing.assert_allclose(acc, one_acc, rtol=1e-6)
    # and both agree with the exact answer
    occ, margin = _exact(pts, EYES)
    clear = (np.abs(margin) > 0.02).all(1)
    np.testing.assert_array_equal(one_cnt[clear], occ[clear].sum(1))


def test_a_new_selection_sums_from_zero(device):
    # MaskedSum.select zeroes only the rows the selection uses (its first n): sums over all points, then a few
    # of them in a scrambled order, then all again give each point its own count, the exact occluded-eye count
    # away from the plate's edge, every time (no row keeps a sum of the selection before)
    pts = _floor_grid(step=0.06)
    S = len(EYES)
    maps = ShadowMaps(S, 256, device=device)
    maps.set_proxy(PLATE_V, PLATE_F)
    assert maps.render(EYES) == S
    cand = _wp2(np.ones((1, S), np.uint8), wp.uint8, device)
    w = _wp2(np.ones((1, S, 3), np.float32), wp.vec3, device)
    acc = _masked(device, pts)
    acc.add(maps, S, 0, cand, w)
    full_sum, full_cnt = (a.copy() for a in acc.result())
    occ, margin = _exact(pts, EYES)
    clear = (np.abs(margin) > 0.02).all(1)
    np.testing.assert_array_equal(full_cnt[clear], occ[clear].sum(1))
    idx = np.random.default_rng(3).permutation(len(pts))[:len(pts) // 5]
    acc.select(idx)
    acc.add(maps, S, 0, cand, w)
    sub_sum, sub_cnt = acc.result()
    np.testing.assert_array_equal(sub_cnt, full_cnt[idx])
    np.testing.assert_array_equal(sub_sum, full_sum[idx])
    acc.select(None)
    acc.add(maps, S, 0, cand, w)
    again_sum, again_cnt = acc.result()
    np.testing.assert_array_equal(again_cnt, full_cnt)
    np.testing.assert_array_equal(again_sum, full_sum)


def test_weights_accumulate_barycentric(device):
    # sums equal, per point, sum over occluded candidate sources of the barycentric interpolation of W
    rng = np.random.default_rng(11)
    pts = _floor_grid(step=0.07)
    n, S, R, G = len(pts), len(EYES), 40, 4
    W = rng.uniform(0.5, 2.0, (R, S, 3)).astype(np.float32)  # distinct values per row, source and channel
    rows = rng.integers(0, R, (n, 3)).astype(np.int32)
    bary = rng.dirichlet([1.0, 1.0, 1.0], n).astype(np.float32)
    group = rng.integers(0, G, n).astype(np.int32)
    cand = (rng.uniform(size=(G, S)) < 0.7).astype(np.uint8)
    cand[0] = 1  # group 0 sees all sources
    acc, cnt = _run(device, pts, EYES, weights=W, cand=cand, batches=[2, 2, 1], capacity=2, rows=rows,
                    bary=bary, group=group)
    occ, margin = _exact(pts, EYES)
    m = occ & cand[group].astype(bool)  # (n,S) the sources that count
    w_pt = np.einsum("nk,nksc->nsc", bary.astype(np.float64), W[rows].astype(np.float64))  # (n,S,3)
    ref = np.einsum("ns,nsc->nc", m.astype(np.float64), w_pt)
    clear = (np.abs(margin) > 0.02).all(1)
    assert m[clear].sum() > 500
    np.testing.assert_allclose(acc[clear], ref[clear], rtol=1e-5, atol=1e-6)
    np.testing.assert_array_equal(cnt[clear], m[clear].sum(1))
    close = np.isclose(acc, ref, rtol=1e-5, atol=1e-6).all(1)
    assert close.mean() >= 0.99
    # reset() clears the accumulators
    ms = _masked(device, pts[:10])
    ms.reset()
    a, c = ms.result()
    assert np.all(a == 0) and np.all(c == 0)


# ----------------------------------------------------------------------------------------------------------
# closed proxies (back faces culled when rasterising)
# ----------------------------------------------------------------------------------------------------------

CUBE_LO, CUBE_HI = np.array([-0.3, 0.7, -0.3]), np.array([0.3, 1.3, 0.3])


def _cube(flip=()):
    """Closed cube, 12 triangles wound outward; faces listed in `flip` (0..5) wound inward instead."""
    lo, hi = CUBE_LO, CUBE_HI
    v = np.array([[(lo, hi)[i][0], (lo, hi)[j][1], (lo, hi)[k][2]] for i in (0, 1) for j in (0, 1) for k in (0, 1)])
    # quads with outward (counter-clockwise seen from outside) winding: -x, +x, -y, +y, -z, +z
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    tris = []
    for qi, (a, b, c, d) in enumerate(quads):
        pair = [(a, b, c), (a, c, d)]
        if qi in flip:
            pair = [(x, z, y) for x, y, z in pair]
        tris += pair
    v_out, t_out = v, np.array(tris, np.int32)
    centre = 0.5 * (lo + hi)
    fn = np.cross(v_out[t_out[:, 1]] - v_out[t_out[:, 0]], v_out[t_out[:, 2]] - v_out[t_out[:, 0]])
    outward = ((v_out[t_out].mean(1) - centre) * fn).sum(1) > 0
    assert outward.sum() == 12 - 2 * len(flip)
    return v_out, t_out


def _exact_box(points, eyes, lo, hi):
    """(N,S) bool: does the segment point -> eye cross the box [lo, hi]? (slab test)"""
    d = eyes[None, :, :] - points[:, None, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        t0 = (lo - points[:, None, :]) / d
        t1 = (hi - points[:, None, :]) / d
    tmin = np.nanmax(np.minimum(t0, t1), axis=-1)
    tmax = np.nanmin(np.maximum(t0, t1), axis=-1)
    return (tmax >= np.maximum(tmin, 0.0)) & (tmin <= 1.0)


def _run_mesh(device, points, eyes, verts, tris, res=256):
    maps = ShadowMaps(len(eyes), res, device=device)
    maps.set_proxy(verts, tris)
    ms = _masked(device, points)
    n = maps.render(eyes)
    ms.add(maps, n, 0, _wp2(np.ones((1, n), np.uint8), wp.uint8, device),
           _wp2(np.ones((1, n, 3), np.float32), wp.vec3, device))
    return ms.result()[1]


def _check_cube(device, flip):
    pts = _floor_grid(step=0.05)
    eyes = np.vstack([EYES, [0.1, 1.45, -0.05]])  # the last one sits inside the bounding sphere (ray mode)
    v, t = _cube(flip)
    count = _run_mesh(device, pts, eyes, v, t)
    ref = _exact_box(pts, eyes, CUBE_LO, CUBE_HI).sum(1)
    grow = _exact_box(pts, eyes, CUBE_LO - 0.02, CUBE_HI + 0.02).sum(1)
    shrink = _exact_box(pts, eyes, CUBE_LO + 0.02, CUBE_HI - 0.02).sum(1)
    clear = grow == shrink  # no crossing within 2 cm of the cube's silhouette
    assert (ref[clear] >= 3).sum() > 100 and (ref[clear] == 0).sum() > 1000
    np.testing.assert_array_equal(count[clear], ref[clear])
    assert (count == ref).mean() >= 0.99


def test_closed_cube_outward(device):
    # a closed, outward-wound cube (back faces culled) shadows exactly like the solid box
    _check_cube(device, flip=())


def test_closed_cube_inward(device):
    # the same cube wound inward throughout still shadows like the solid box
    _check_cube(device, flip=tuple(range(6)))


def test_closed_cube_inconsistent_winding(device):
    # a closed cube whose top face is wound inward (a common mesh defect) still shadows like the solid box
    _check_cube(device, flip=(3,))


# ----------------------------------------------------------------------------------------------------------
# culling: the lists of maps that may shadow a cell of points change no sum
# ----------------------------------------------------------------------------------------------------------

def test_culling_changes_no_sum(device):
    # points around and under a closed cube and a plate (many near a shadow's edge), eyes on every side
    # incl. one in ray mode, cells of a few points each: culled and unculled sums agree exactly, and the
    # culling drops most (point, map) pairs that the shadows miss
    rng = np.random.default_rng(5)
    v, t = _cube()
    eyes = np.vstack([EYES, [[2.5, 1.0, 0.3], [-2.0, 0.4, -1.5], [0.1, 1.45, -0.05], [0.0, 4.0, 2.5]]])
    pts = np.vstack([_floor_grid(step=0.04), rng.uniform([-3, 0, -3], [3, 2.5, 3], (4000, 3))])
    pts = pts[np.all((pts < CUBE_LO - 0.01) | (pts > CUBE_HI + 0.01), axis=1)]  # none inside the cube
    n, S = len(pts), len(eyes)
    W = rng.uniform(0.5, 2.0, (n, S, 3)).astype(np.float32)
    rows = np.repeat(np.arange(n, dtype=np.int32)[:, None], 3, 1)
    bary = np.tile([1.0, 0.0, 0.0], (n, 1))
    group = (np.floor(pts[:, 0]) + 4).astype(np.int32)  # strips of points 1 m wide
    tile = (np.floor(pts[:, 2] / 0.1) * 100 + np.floor(pts[:, 1] / 0.1)).astype(np.int64)  # 10 cm cells
    cand = np.ones((group.max() + 1, S), np.uint8)
    maps = ShadowMaps(S, 128, device=device)
    maps.set_proxy(v, t)
    assert maps.render(eyes) == S
    out, lists = [], []
    for cull, sat in ((True, 1), (False, 1), (True, 0)):  # sat 0: may_occlude loops over the blocks, no table
        maps.ms.sat = sat
        ms = MaskedSum(pts, rows, bary, group, device, cull=cull, tile=tile, max_maps=S)
        ms.add(maps, S, 0, _wp2(cand, wp.uint8, device), _wp2(W, wp.vec3, device))
        out.append(ms.result() + (ms.n_list.numpy()[ms.point_cell].sum(),))
        lists.append((ms.n_list.numpy().copy(), ms.lists.numpy().copy()))
    maps.ms.sat = 1
    (a1, c1, pairs1), (a0, c0, pairs0), _ = out
    # the blocks' summed-area table lists the maps the loop over the blocks lists
    assert all(np.array_equal(x, y) for x, y in zip(lists[0], lists[2]))
    np.testing.assert_array_equal(c1, c0)
    np.testing.assert_array_equal(a1, a0)
    assert 0.02 < (c0 > 0).mean() < 0.9 and c0.sum() > 500
    assert pairs0 == n * S and pairs1 < 0.5 * pairs0
    # the counts are the exact ones away from the silhouette
    ref = _exact_box(pts, eyes, CUBE_LO, CUBE_HI).sum(1)
    clear = _exact_box(pts, eyes, CUBE_LO - 0.02, CUBE_HI + 0.02).sum(1) == \
        _exact_box(pts, eyes, CUBE_LO + 0.02, CUBE_HI - 0.02).sum(1)
    np.testing.assert_array_equal(c1[clear], ref[clear])



def test_coarse_blocks_summed_area_table(device):
    # may_occlude asks whether any coarse block of a box was drawn in from the blocks' summed-area table (one box
    # sum, not a loop over the blocks): the table is the blocks' 2-d running sum, and a random box's sum is
    # positive exactly where one of its blocks is set; a batch drawn again from other eyes leaves no stale count
    v, t = _cube()
    maps = ShadowMaps(len(EYES), 100, device=device)  # 13 blocks a side, the last partly off the map
    maps.set_proxy(v, t)
    rng = np.random.default_rng(11)
    for eyes in (EYES, EYES[::-1] * np.array([1.0, 1.4, 1.0])):
        n = maps.render(eyes)
        coarse = maps.ms.coarse.numpy()[:n]
        sat = maps.ms.coarse_sat.numpy()[:n]
        assert 0.05 < coarse.mean() < 0.95
        ref = np.zeros_like(sat)
        ref[:, 1:, 1:] = coarse.cumsum(1).cumsum(2)
        np.testing.assert_array_equal(sat, ref)
        nc = coarse.shape[1]
        for _ in range(500):
            k = rng.integers(n)
            y0, y1 = np.sort(rng.integers(0, nc, 2))
            x0, x1 = np.sort(rng.integers(0, nc, 2))
            box = sat[k, y1 + 1, x1 + 1] - sat[k, y0, x1 + 1] - sat[k, y1 + 1, x0] + sat[k, y0, x0]
            assert (box > 0) == coarse[k, y0:y1 + 1, x0:x1 + 1].any()


def test_ray_mode_culling_by_the_proxy_box(device):
    # an eye inside the cube's bounding sphere (ray mode): cells whose segments to the eye miss the
    # cube's box are not listed, and the sums are those of testing every point
    rng = np.random.default_rng(7)
    v, t = _cube()
    eye = np.array([[0.45, 0.75, 0.0]])  # beside the cube, as a floor or wall source beside an object
    pts = np.vstack([_floor_grid(step=0.04), rng.uniform([-3, 0, -3], [3, 2.5, 3], (4000, 3))])
    pts = pts[np.all((pts < CUBE_LO - 0.01) | (pts > CUBE_HI + 0.01), axis=1)]
    n = len(pts)
    rows = np.repeat(np.arange(n, dtype=np.int32)[:, None], 3, 1)
    bary = np.tile([1.0, 0.0, 0.0], (n, 1))
    W = rng.uniform(0.5, 2.0, (n, 1, 3)).astype(np.float32)
    group = (np.floor(pts[:, 0]) + 4).astype(np.int32)
    tile = (np.floor(pts / 0.1) @ [10000, 1, 100]).astype(np.int64)  # 10 cm cells
    maps = ShadowMaps(1, 128, device=device)
    maps.set_proxy(v, t)
    assert maps.render(eye) == 1 and maps.n_ray == 1
    out = []
    for cull in (True, False):
        ms = MaskedSum(pts, rows, bary, group, device, cull=cull, tile=tile, max_maps=1)
        ms.add(maps, 1, 0, _wp2(np.ones((group.max() + 1, 1), np.uint8), wp.uint8, device), _wp2(W, wp.vec3, device))
        out.append(ms.result() + (ms.n_list.numpy()[ms.point_cell].sum(),))
    (a1, c1, pairs1), (a0, c0, pairs0) = out
    np.testing.assert_array_equal(c1, c0)
    np.testing.assert_array_equal(a1, a0)
    print("ray-mode pairs listed", pairs1, "of", n, "occluded", (c0 > 0).sum())
    assert pairs0 == n and pairs1 < 0.7 * n and c0.sum() > 200

# ----------------------------------------------------------------------------------------------------------
# cluster maps: the penumbra of a map that stands for a spread of sources (kernels.masked_sums.penumbra)
# ----------------------------------------------------------------------------------------------------------

def _cluster_sums(device, pts, eyes, spread, cull=True, res=256, axes=None, tile=None, taps=None):
    S = len(eyes)
    maps = ShadowMaps(S, res, device=device) if taps is None else ShadowMaps(S, res, device=device, taps=taps)
    maps.set_proxy(PLATE_V, PLATE_F)
    n = maps.prepare(eyes, spread, axes)
    maps.raster(0, n)
    ms = MaskedSum(pts, np.zeros((len(pts), 3), np.int32), np.tile([1.0, 0.0, 0.0], (len(pts), 1)),
                   np.zeros(len(pts), np.int32), device, cull=cull, max_maps=S, tile=tile)
    ms.add(maps, n, 0, _wp2(np.ones((1, S), np.uint8), wp.uint8, device),
           _wp2(np.ones((1, S, 3), np.float32), wp.vec3, device))
    return ms.result()


def test_zero_spread_is_the_hard_lookup(device):
    # clusters of zero extent (point sources) give exactly today's lookup
    pts = _floor_grid(step=0.05)
    hard = _run(device, pts, EYES)
    zero = _cluster_sums(device, pts, EYES, np.zeros(len(EYES)))
    np.testing.assert_array_equal(zero[0], hard[0])
    np.testing.assert_array_equal(zero[1], hard[1])


def test_spread_gives_the_square_light_penumbra(device):
    # a map of spread h from (0, 2.5, 0) looking down: the occluded share is close to the mean hard mask
    # of a square of point sources of half-width h about the eye; culling changes nothing
    h = 0.2
    pts = _floor_grid(step=0.02, ext=1.5)
    eye = np.array([[0.0, 2.5, 0.0]])
    _, frac = _cluster_sums(device, pts, eye, np.array([h]))
    _, frac0 = _cluster_sums(device, pts, eye, np.array([h]), cull=False)
    np.testing.assert_array_equal(frac, frac0)
    g = np.linspace(-h, h, 21)
    grid = np.array([[x, 2.5, z] for x in g for z in g])
    ref = _exact(pts, grid)[0].mean(1)
    pen = (ref > 0) & (ref < 1)
    assert pen.sum() > 500 and np.all((frac >= 0) & (frac <= 1))
    assert np.abs(frac - ref).mean() < 0.02 and np.abs(frac - ref)[pen].mean() < 0.08
    assert np.abs(frac[pen] - 0.5).mean() < 0.45  # soft: not the hard 0/1 of one point source


def test_fewer_taps_keep_the_square_light_penumbra(device):
    # the drag frame's lookups (ShadowMaps.taps = app.dragframe.DRAG_PCSS_TAPS, 3 per axis, against 5 at
    # rest): the square light's penumbra of the test above, each point within a coarser step of the mean of
    # 21 x 21 point sources (1/9 of the light per tap), and no bias: the occluded light sums to the
    # reference's within 2 %
    h = 0.2
    pts = _floor_grid(step=0.02, ext=1.5)
    eye = np.array([[0.0, 2.5, 0.0]])
    _, frac = _cluster_sums(device, pts, eye, np.array([h]), taps=3)
    g = np.linspace(-h, h, 21)
    ref = _exact(pts, np.array([[x, 2.5, z] for x in g for z in g]))[0].mean(1)
    pen = (ref > 0) & (ref < 1)
    assert pen.sum() > 500 and np.all((frac >= 0) & (frac <= 1))
    assert np.abs(frac - ref).mean() < 0.025 and np.abs(frac - ref)[pen].mean() < 0.12
    assert abs(frac.sum() / ref.sum() - 1.0) < 0.02
    assert np.abs(frac[pen] - 0.5).mean() < 0.45  # still soft


def _oblique_square(h: float):
    """(eye, e1, e2, axes (1,2,3)): a square light of half-side h (m) at (0.9, 2.3, 0.4) facing the plate's
    centre, seen obliquely from the floor (the plate's depth varies across its map)."""
    eye = np.array([0.9, 2.3, 0.4])
    fwd = (np.array([0.0, PLATE_Y, 0.0]) - eye) / np.linalg.norm(np.array([0.0, PLATE_Y, 0.0]) - eye)
    e1 = np.cross(fwd, [0.0, 0.0, 1.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(fwd, e1)
    return eye, e1, e2, np.array([[h * e1, h * e2]])


def test_small_cells_share_a_blocker_search(device):
    # a square light seen obliquely (the plate's depth varies across the map), cells of 3 x 3 cm (9
    # points each): a run within one tap spacing of its mean searches the blockers once
    # (kernels.masked_sums._run_blockers); the penumbra stays that of the square light, within a
    # small difference of every point searching on its own (one cell of all points)
    h = 0.2
    pts = _floor_grid(step=0.01, ext=1.2)
    eye, e1, e2, axes = _oblique_square(h)
    tile = (np.floor(pts[:, 0] / 0.03) * 1000 + np.floor(pts[:, 2] / 0.03)).astype(np.int64)
    _, own = _cluster_sums(device, pts, eye[None], np.array([h]), axes=axes)
    _, shared = _cluster_sums(device, pts, eye[None], np.array([h]), axes=axes, tile=tile)
    g = np.linspace(-1, 1, 21)
    ref = _exact(pts, np.array([eye + u * h * e1 + v * h * e2 for u in g for v in g]))[0].mean(1)
    pen = (ref > 0) & (ref < 1)
    assert pen.sum() > 2000
    for frac in (own, shared):
        assert np.abs(frac - ref).mean() < 0.015 and np.abs(frac - ref)[pen].mean() < 0.06
    assert (shared != own).sum() > 50  # the runs did share
    assert np.abs(shared - own)[pen].mean() < 0.005


def test_a_run_of_one_point_gives_its_own_lookup(device):
    # every point a cell of its own (a patch centre, a sparse lattice's corner): its run shares no search,
    # and the sums are bitwise those of each point searching on its own (one cell of all points, whose run
    # is too wide to share one), on the oblique square light of the test above
    h = 0.2
    pts = _floor_grid(step=0.02, ext=1.2)
    eye, e1, e2, axes = _oblique_square(h)
    _, own = _cluster_sums(device, pts, eye[None], np.array([h]), axes=axes)
    _, single = _cluster_sums(device, pts, eye[None], np.array([h]), axes=axes, tile=np.arange(len(pts)))
    assert ((own > 0) & (own < 1)).sum() > 500
    np.testing.assert_array_equal(single, own)


def test_spread_along_one_axis_gives_the_line_light_penumbra(device):
    # half-axes (h along x, 0): a line of sources along x; the penumbra is soft across x-edges only
    h = 0.2
    pts = _floor_grid(step=0.02, ext=1.5)
    eye = np.array([[0.0, 2.5, 0.0]])
    _, frac = _cluster_sums(device, pts, eye, np.array([h]), axes=np.array([[[h, 0.0, 0.0], [0.0, 0.0, 0.0]]]))
    line = np.array([[x, 2.5, 0.0] for x in np.linspace(-h, h, 41)])
    ref = _exact(pts, line)[0].mean(1)
    assert np.abs(frac - ref).mean() < 0.02
    z_edge = (np.abs(np.abs(pts[:, 2]) - HALF * 2.5 / 1.5) < 0.03) & (np.abs(pts[:, 0]) < 0.5)
    assert z_edge.sum() > 20 and np.all((frac[z_edge] == 0) | (frac[z_edge] == 1))  # hard along z
