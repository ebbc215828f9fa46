"""The depth range pyramid of cluster maps (kernels.shadowmap.depth_range) and the penumbra's early
outs that read it (kernels.masked_sums._box_taps): the pyramid bounds every texel of a range, and
sums with the early outs equal those that look every tap up."""
import numpy as np
import warp as wp

from kernels.masked_sums import MaskedSum
from kernels.shadowmap import MapSet, ShadowMaps, depth_range
from tests.kernels.test_shadowmap import CUBE_HI, CUBE_LO, _cube, _floor_grid, _wp2


@wp.kernel
def _ranges_kernel(ms: MapSet, box: wp.array2d(dtype=wp.int32), out: wp.array(dtype=wp.vec2)):
    i = wp.tid()
    out[i] = depth_range(ms, box[i, 0], box[i, 1], box[i, 2], box[i, 3], box[i, 4])


def _cube_maps(device, res, eyes, spread, axes=None):
    v, t = _cube()
    maps = ShadowMaps(len(eyes), res, device=device)
    maps.set_proxy(v, t)
    n = maps.prepare(eyes, spread, axes)
    maps.raster(0, n)
    return maps, n


EYES = np.array([[0.0, 3.0, 0.2], [1.5, 2.6, -0.8], [-2.0, 2.2, 1.0], [0.4, 4.0, -1.1]])


def test_depth_range_bounds_every_texel(device):
    rng = np.random.default_rng(3)
    for res in (128, 100):  # a power of two and not
        maps, n = _cube_maps(device, res, EYES, np.full(len(EYES), 0.3))
        depth = maps.depth_numpy()
        drawn = np.isfinite(depth)
        assert 0.05 < drawn.mean() < 0.95
        k = 3000
        s = rng.integers(0, n, k)
        a, b = rng.integers(0, res, (2, k, 2))
        a[: k // 3] = b[: k // 3]  # single texels too
        x0, x1 = np.minimum(a[:, 0], b[:, 0]), np.maximum(a[:, 0], b[:, 0])
        y0, y1 = np.minimum(a[:, 1], b[:, 1]), np.maximum(a[:, 1], b[:, 1])
        box = np.column_stack([s, x0, x1, y0, y1]).astype(np.int32)
        out = wp.zeros(k, dtype=wp.vec2, device=device)
        wp.launch(_ranges_kernel, dim=k, inputs=[maps.ms, _wp2(box, wp.int32, device), out], device=device)
        got = out.numpy()
        for i in range(k):
            block = depth[s[i], y0[i]:y1[i] + 1, x0[i]:x1[i] + 1]
            assert got[i, 0] <= block.min() and got[i, 1] >= block.max(), (res, box[i], got[i])
            if x0[i] == x1[i] and y0[i] == y1[i]:
                assert got[i, 0] == got[i, 1] == block[0, 0]
        # a range of the whole map: its exact min and max
        wp.launch(_ranges_kernel, dim=1, inputs=[maps.ms, _wp2(np.array([[0, 0, res - 1, 0, res - 1]], np.int32),
                                                                 wp.int32, device), out], device=device)
        assert tuple(out.numpy()[0]) == (depth[0].min(), depth[0].max())


def test_merged_levels_are_the_level_by_level_pyramid(device):
    # build_mips' first launch writes levels 1 and 2 at once, its second every coarser level a thread per map
    # (merge_mips): every level of the pyramid equals the one
    # built level by level, bit for bit, and each block holds the exact min and max of its texels; map sides that
    # halve evenly and ones that do not (85 -> 43 -> 22: a level-2 block with one level-1 block, edge texels alone),
    # and a map with one level (2 texels a side: no level 2). An empty texel (inf) counts as 1e30 in both
    for res in (128, 85, 100, 2):
        maps, n = _cube_maps(device, res, EYES, np.full(len(EYES), 0.3))
        pyr = {}
        for merged in (True, False):
            maps.merge_mips = merged
            maps.ms.mip_min.fill_(-7.0)
            maps.ms.mip_max.fill_(-7.0)
            maps.build_mips(0, n)
            pyr[merged] = (maps.ms.mip_min.numpy().copy(), maps.ms.mip_max.numpy().copy())
        assert np.array_equal(pyr[True][0], pyr[False][0]) and np.array_equal(pyr[True][1], pyr[False][1])
        depth = maps.depth_numpy()
        side, off = maps._mip_side, maps.ms.mip_off.numpy()
        for lv in range(1, maps.ms.mip_levels + 1):
            b = 2 ** lv
            for k in range(n):
                for by in range(side[lv]):
                    for bx in range(side[lv]):
                        block = depth[k, by * b:(by + 1) * b, bx * b:(bx + 1) * b]
                        i = off[lv] + by * side[lv] + bx
                        # an empty texel (inf) reads as 1e30, the kernels' start value
                        assert pyr[True][0][k, i] == min(block.min(), np.float32(1e30))
                        assert pyr[True][1][k, i] == max(block.max(), np.float32(-1e30))


def test_early_outs_change_no_sum(device):
    # square and line clusters over a cube: the sums with the pyramid equal those with a pyramid
    # that knows nothing (every range (-inf, inf): every tap looked up), bit for bit
    rng = np.random.default_rng(7)
    pts = np.vstack([_floor_grid(step=0.03, ext=2.5), rng.uniform([-1.5, 0.0, -1.5], [1.5, 1.6, 1.5], (6000, 3))])
    # and a shell 5-50 mm outside the cube's faces: points whose blockers lie just in front of them
    c, h = 0.5 * (CUBE_LO + CUBE_HI), 0.5 * (CUBE_HI - CUBE_LO)
    d = rng.normal(size=(6000, 3))
    d /= np.abs(d / h).max(1, keepdims=True)  # on the cube's surface
    shell = c + d + np.sign(d) * (np.abs(d / h) > 0.999) * rng.uniform(0.005, 0.05, (6000, 1))
    pts = np.vstack([pts, shell])
    pts = pts[~np.all((pts > CUBE_LO - 0.004) & (pts < CUBE_HI + 0.004), axis=1)]  # none inside
    spread = np.array([0.4, 0.25, 0.6, 0.1])
    axes = np.zeros((len(EYES), 2, 3))
    axes[:, 0, 0] = spread
    axes[:, 1, 2] = spread * np.array([1.0, 0.5, 0.0, 1.0])  # the third a line of sources
    n_pts, S = len(pts), len(EYES)
    W = rng.uniform(0.5, 2.0, (n_pts, S, 3)).astype(np.float32)
    rows = np.repeat(np.arange(n_pts, dtype=np.int32)[:, None], 3, 1)
    bary = np.tile([1.0, 0.0, 0.0], (n_pts, 1))
    tile = (np.floor(pts[:, 0] / 0.1) * 1000 + np.floor(pts[:, 2] / 0.1)).astype(np.int64)
    out = []
    for know in (True, False):
        maps, n = _cube_maps(device, 128, EYES, spread, axes)
        if not know:
            maps.ms.mip_min.fill_(-np.inf)
            maps.ms.mip_max.fill_(np.inf)
        ms = MaskedSum(pts, rows, bary, np.zeros(n_pts, np.int32), device, tile=tile, max_maps=S)
        ms.add(maps, n, 0, _wp2(np.ones((1, S), np.uint8), wp.uint8, device), _wp2(W, wp.vec3, device))
        out.append(ms.result())
    (a1, c1), (a0, c0) = out
    frac = c0 / S
    assert ((frac > 0) & (frac < 1) & (np.abs(frac * 4 - np.round(frac * 4)) > 1e-6)).sum() > 200  # soft somewhere
    np.testing.assert_array_equal(c1, c0)
    np.testing.assert_array_equal(a1, a0)


def test_maps_that_read_no_pyramid_are_skipped(device):
    # build_mips writes the pyramids of the cluster maps only: a map of spread 0 (the hard lookup) keeps what its
    # pyramid held, the others get the exact min and max of their texels at every level
    spread = np.array([0.3, 0.0, 0.3, 0.0])
    maps, n = _cube_maps(device, 85, EYES, spread)
    for merged in (True, False):
        maps.merge_mips = merged
        maps.ms.mip_min.fill_(-7.0)
        maps.build_mips(0, n)
        lo, depth = maps.ms.mip_min.numpy(), maps.depth_numpy()
        assert np.all(lo[1] == -7.0) and np.all(lo[3] == -7.0)
        top = maps.ms.mip_off.numpy()[maps.ms.mip_levels]
        assert lo[0, top] == depth[0].min() and lo[2, top] == depth[2].min()
