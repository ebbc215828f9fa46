"""Masked transfer sums: sum_j W_xj M_xj over a batch of shadow maps (seed eq. 3 / eq. 4).

Each point x (a pixel's surface point, or a patch centre) carries up to three weight rows
(vertex indices) and barycentric weights; W for source j is interpolated from those rows:
W_xj = sum_k b_k W[row_k, j]. Rows hold radiance transfers L_ij (HDR path) or intensity
transfers S_ij (LDR path); the kernel does not care which. `cand[group_x, j]` (uint8) lets a
point skip sources whose shaft cannot meet the object (group = the point's receiver patch).

Per batch, each group first lists the maps its points may be occluded in: its candidates whose
shadow cone meets the group's bounding sphere (kernels.shadowmap.may_occlude, conservative, so
the sums are those of testing every map); then each cell (the points of a group that share a
`tile`, e.g. an 8x8 block of pixels) keeps those of its group's maps whose cone meets the cell's
own, smaller sphere, and a point loops over its cell's list only.

The sums go cell by cell: `select` orders the selected points by cell, and one thread takes a
run (a cell's selected points) map by map of the cell's list, reading the map's frame once for
the run and looking up nearby texels point after point. The work of a point is the length of its
cell's list, so concurrent ranges are cut by work (`balanced`), not by point count: the cells near
the object list most maps.

A cluster map (a spread) is looked up with a PCSS penumbra (`penumbra`). Its cost is held down
by the map's depth range pyramid (kernels.shadowmap.depth_range): a run whose points' widest
boxes are all lit, or all in umbra, is settled with no tap (exact), as is a point's blocker
search or filter box; a run within one tap spacing of its mean shares one blocker search there
(`_run_blockers`), each point still filtering its own box.

The points are uploaded once (MaskedSum's constructor); a frame sums over a listed subset of
them (`select`), in any number of index ranges (app.runtime.split, or `balanced`). No Warp array
is allocated after construction.
"""
from __future__ import annotations

import numpy as np
import warp as wp

from kernels import runtime
from kernels.buffers import Buffer
from kernels.shadowmap import MapSet, ShadowMaps, depth_range, may_occlude, texel_depth
from kernels.visibility import segment_blocked


@wp.kernel
def _list_kernel(ms: MapSet, g0: int, n_maps: int, col0: int, centre: wp.array(dtype=wp.vec3),
                 radius: wp.array(dtype=wp.float32), cand: wp.array2d(dtype=wp.uint8), cull: int,
                 lists: wp.array2d(dtype=wp.int32), n_list: wp.array(dtype=wp.int32)):
    g = g0 + wp.tid()
    m = int(0)
    for s in range(n_maps):
        if cand[g, col0 + s] == wp.uint8(0):
            continue
        if cull == 1:
            if not may_occlude(ms, s, centre[g], radius[g]):
                continue
        lists[g, m] = s
        m += 1
    n_list[g] = m


@wp.kernel
def _cell_list_kernel(ms: MapSet, c0: int, cell_group: wp.array(dtype=wp.int32), active: wp.array(dtype=wp.uint8),
                      centre: wp.array(dtype=wp.vec3), radius: wp.array(dtype=wp.float32), cull: int,
                      g_lists: wp.array2d(dtype=wp.int32), g_n: wp.array(dtype=wp.int32),
                      lists: wp.array2d(dtype=wp.int32), n_list: wp.array(dtype=wp.int32)):
    c = c0 + wp.tid()
    m = int(0)
    if active[c] != wp.uint8(0):
        g = cell_group[c]
        for t in range(g_n[g]):
            s = g_lists[g, t]
            if cull == 1:
                if not may_occlude(ms, s, centre[c], radius[c]):
                    continue
            lists[c, m] = s
            m += 1
    n_list[c] = m


PCSS_TAPS = 5  # samples per axis of the blocker search and of the filter (the default of ShadowMaps.taps,
# which a map set's lookups read: MapSet.taps)


@wp.func
def _hard(ms: MapSet, s: int, x: float, y: float, z: float) -> float:
    """kernels.shadowmap.occluded's lookup at pixel position (x, y) and view depth z: 1 or 0."""
    if z > texel_depth(ms, s, x, y) + ms.bias:
        return 1.0
    return 0.0


@wp.func
def _range_says(ms: MapSet, s: int, xl: float, xh: float, yl: float, yh: float, zl: float, zh: float, g: float,
                a1: wp.vec2, a2: wp.vec2) -> int:
    """What the depth range pyramid says of every tap of the widest boxes (scale g) about the texel
    box xl..xh, yl..yh at view depths zl..zh: 0 none is blocked, 1 all are, -1 unknown."""
    e = g * (1.0 - 1.0 / float(ms.taps))
    hx = e * (wp.abs(a1[0]) + wp.abs(a2[0])) + 1.0e-3
    hy = e * (wp.abs(a1[1]) + wp.abs(a2[1])) + 1.0e-3
    x0 = int(wp.floor(xl - hx + 0.5))
    x1 = int(wp.floor(xh + hx + 0.5))
    y0 = int(wp.floor(yl - hy + 0.5))
    y1 = int(wp.floor(yh + hy + 0.5))
    if x1 < 0 or y1 < 0 or x0 >= ms.res or y0 >= ms.res:
        return 0
    inside = x0 >= 0 and y0 >= 0 and x1 < ms.res and y1 < ms.res
    r = depth_range(ms, s, wp.max(x0, 0), wp.min(x1, ms.res - 1), wp.max(y0, 0), wp.min(y1, ms.res - 1))
    if zh <= r[0] + ms.bias:
        return 0
    if inside and zl > r[1] + ms.bias:
        return 1
    return -1


@wp.func
def _box_taps(ms: MapSet, s: int, x: float, y: float, z: float, a1: wp.vec2, a2: wp.vec2, g: float) -> int:
    """What the n x n taps x + u a1 + v a2 (|u|, |v| <= g (1 - 1/n)) of map s can say at view
    depth z, from the depth range pyramid over the texels they round to: 0 none is blocked, 1 all
    are, -1 unknown (look them up). Exact: texel depths lie within the range, and a tap off the
    map reads no blocker."""
    return _range_says(ms, s, x, x, y, y, z, z, g, a1, a2)


@wp.func
def _blockers(ms: MapSet, s: int, x: float, y: float, z: float, a1: wp.vec2, a2: wp.vec2, gs: float) -> wp.vec2:
    """PCSS blocker search of penumbra's widest box (scale gs) about (x, y) at view depth z:
    (0, 0) none blocked, (1, 0) all blocked, else (-1, the blockers' mean depth, at least the
    proxy's nearest)."""
    known = _box_taps(ms, s, x, y, z, a1, a2, gs)
    if known >= 0:
        return wp.vec2(float(known), 0.0)
    zsum = float(0.0)
    nb = float(0.0)
    n = ms.taps
    for a in range(n):
        for b in range(n):
            u = (2.0 * (float(a) + 0.5) / float(n) - 1.0) * gs
            v = (2.0 * (float(b) + 0.5) / float(n) - 1.0) * gs
            t = texel_depth(ms, s, x + u * a1[0] + v * a2[0], y + u * a1[1] + v * a2[1])
            if z > t + ms.bias:
                zsum += t
                nb += 1.0
    if nb == 0.0:
        return wp.vec2(0.0, 0.0)
    if nb == float(n * n):
        return wp.vec2(1.0, 0.0)
    return wp.vec2(-1.0, wp.max(zsum / nb, wp.max(ms.near[s], 1.0e-3)))


@wp.func
def _run_blockers(ms: MapSet, s: int, a1: wp.vec2, a2: wp.vec2, xl: float, xh: float, yl: float, yh: float,
                  zl: float, zh: float, xm: float, ym: float, zm: float) -> wp.vec2:
    """What a run of points (texel box xl..xh, yl..yh, view depths zl..zh, mean (xm, ym, zm))
    shares in map s: (0, 0) every point lit and (1, 0) every point in umbra (exact: every tap
    of every point's widest box, from the depth range pyramid); (2, zb) one blocker search at the
    run's mean gives its points' blocker depth zb, where the run lies within one tap spacing of
    that search's widest axis (its points' own searches would differ by less than a tap's
    offset); (3, 0) each point searches."""
    zn = wp.max(ms.near[s], 1.0e-3)
    l1 = wp.max(wp.length(a1), wp.length(a2))
    lim = float(ms.res) / wp.max(l1, 1.0e-9)
    gh = wp.min(wp.max(zh - zn, 0.0) / (zh * zn), lim)  # the scale grows with the depth
    known = _range_says(ms, s, xl, xh, yl, yh, zl, zh, gh, a1, a2)  # every point's widest box lies in this one
    if known >= 0:
        return wp.vec2(float(known), 0.0)
    gm = wp.min(wp.max(zm - zn, 0.0) / (zm * zn), lim)
    gl = wp.min(wp.max(zl - zn, 0.0) / (zl * zn), lim)
    step = 2.0 * gm * l1 / float(ms.taps)
    if gl * l1 < 0.5 or wp.max(xh - xl, yh - yl) > step or (gh - gl) * l1 > step:
        return wp.vec2(3.0, 0.0)
    sb = _blockers(ms, s, xm, ym, zm, a1, a2, gm)
    if sb[0] >= 0.0:
        return sb
    return wp.vec2(2.0, sb[1])


@wp.func
def penumbra(ms: MapSet, s: int, x: float, y: float, z: float, a1: wp.vec2, a2: wp.vec2, zb_run: float) -> float:
    """Occluded share (0..1) of map s's cluster of sources at the point seen at texel (x, y)
    and view depth z (PCSS): a1, a2 = the cluster's half-axes (m, MapSet.axis1/2) x texels per
    unit tangent, in the map's (right, up). A blocker at depth zb shifts by a (z - zb) / (z zb)
    texels as the source moves by a across the cluster, so the lookup is filtered over the
    parallelogram u a1 + v a2 (|u|, |v| <= 1) so scaled, zb the mean depth of the blockers found
    in the widest such one (zb = the proxy's nearest depth). Below half a texel it is the hard
    lookup of kernels.shadowmap.occluded. Where the depth range pyramid shows that no tap of a
    box, or every one, is blocked, its taps are not looked up (_box_taps: the same result).
    zb_run > 0: the blocker depth of the point's run (_run_blockers), no search of its own."""
    zn = wp.max(ms.near[s], 1.0e-3)
    l1 = wp.max(wp.length(a1), wp.length(a2))
    gs = wp.max(z - zn, 0.0) / (z * zn)
    gs = wp.min(gs, float(ms.res) / wp.max(l1, 1.0e-9))
    if gs * l1 < 0.5:
        return _hard(ms, s, x, y, z)
    zb = zb_run
    if zb <= 0.0:
        sb = _blockers(ms, s, x, y, z, a1, a2, gs)
        if sb[0] >= 0.0:  # no blocker found (lit), or every tap of the widest box blocked: the narrower too (umbra)
            return sb[0]
        zb = sb[1]
    n = ms.taps
    g = wp.min((z - zb) / (z * zb), gs)
    if g * l1 < 0.5:
        return _hard(ms, s, x, y, z)
    known = _box_taps(ms, s, x, y, z, a1, a2, g)
    if known >= 0:
        return float(known)
    hit = float(0.0)
    for a in range(n):
        for b in range(n):
            u = (2.0 * (float(a) + 0.5) / float(n) - 1.0) * g
            v = (2.0 * (float(b) + 0.5) / float(n) - 1.0) * g
            if z > texel_depth(ms, s, x + u * a1[0] + v * a2[0], y + u * a1[1] + v * a2[1]) + ms.bias:
                hit += 1.0
    return hit / float(n * n)


@wp.func
def _weight(weights: wp.array2d(dtype=wp.vec3), rows: wp.array2d(dtype=wp.int32), bary: wp.array(dtype=wp.vec3),
            k: int, j: int, centres: wp.array2d(dtype=wp.vec3), n_rows: int) -> wp.vec3:
    """Point k's transfer for column j: its three weight rows blended by its barycentrics. Rows n_rows and up
    are read from `centres` (its row r - n_rows, the same column) where that table is given (not of 0 rows):
    the patch centres' transfers read in place instead of copied into `weights` (MaskedSum.accumulate)."""
    bk = bary[k]
    r0 = rows[k, 0]
    if r0 >= n_rows and centres.shape[0] > 0:  # a centre: its three rows are one (bary 1, 0, 0), same formula
        c = r0 - n_rows
        return centres[c, j] * bk[0] + centres[rows[k, 1] - n_rows, j] * bk[1] + centres[rows[k, 2] - n_rows, j] * bk[2]
    return weights[r0, j] * bk[0] + weights[rows[k, 1], j] * bk[1] + weights[rows[k, 2], j] * bk[2]


@wp.kernel
def _masked_sum_kernel(ms: MapSet, lo: int, hi: int, col0: int, run0: int,
                       run_start: wp.array(dtype=wp.int32), run_cell: wp.array(dtype=wp.int32),
                       idx: wp.array(dtype=wp.int32),
                       pos: wp.array(dtype=wp.vec3), rows: wp.array2d(dtype=wp.int32),
                       bary: wp.array(dtype=wp.vec3), lists: wp.array2d(dtype=wp.int32),
                       n_list: wp.array(dtype=wp.int32), weights: wp.array2d(dtype=wp.vec3),
                       centres: wp.array2d(dtype=wp.vec3), n_rows: int, hard0: int,
                       acc: wp.array(dtype=wp.vec3), count: wp.array(dtype=wp.float32)):
    # one thread per run (the selected points of one cell, consecutive), clipped to points lo..hi-1:
    # map by map of the cell's list, the map's frame is read once for all the run's points; points k >= hard0
    # take the hard lookup of a cluster map's eye too (no penumbra: MaskedSum.accumulate's hard_from)
    r = run0 + wp.tid()
    a = wp.max(run_start[r], lo)
    b = wp.min(run_start[r + 1], hi)
    c = run_cell[r]
    half = float(ms.res) * 0.5
    for t in range(n_list[c]):
        s = lists[c, t]
        j = col0 + s
        o = ms.origin[s]
        if ms.ray[s] == 1:  # summed by _ray_sum_kernel
            continue
        f = ms.fwd[s]
        rt = ms.right[s]
        up = ms.up[s]
        it = ms.inv_tan[s]
        sp = ms.spread[s]
        if sp <= 0.0:  # one source: the hard lookup of kernels.shadowmap.occluded, the map's frame scaled to
            # texels once (x + 0.5 = right.d / z * inv_tan * res/2 + res/2) and one reciprocal per point
            rx = rt * (it * half)
            uy = up * (it * half)
            for i in range(a, b):
                k = idx[i]
                d = pos[k] - o
                z = wp.dot(d, f)
                if z > 1.0e-6:
                    iz = 1.0 / z
                    ix = int(wp.floor(wp.dot(d, rx) * iz + half))
                    iy = int(wp.floor(wp.dot(d, uy) * iz + half))
                    if ix >= 0 and iy >= 0 and ix < ms.res and iy < ms.res:
                        if z > ms.depth[s, iy, ix] + ms.bias:
                            acc[i] = acc[i] + _weight(weights, rows, bary, k, j, centres, n_rows)
                            count[i] = count[i] + 1.0
            continue
        a1 = wp.vec2(wp.dot(ms.axis1[s], rt), wp.dot(ms.axis1[s], up)) * (it * half)
        a2 = wp.vec2(wp.dot(ms.axis2[s], rt), wp.dot(ms.axis2[s], up)) * (it * half)
        run = wp.vec2(3.0, 0.0)
        # a cluster map: what the whole run shares (all its points, for any cut lo..hi); a run of one point
        # (a patch centre, a sparse lattice's corner) shares nothing: its own lookup alone gives the same value
        if sp > 0.0 and run_start[r + 1] - run_start[r] > 1:
            xl = float(1.0e30)
            xh = float(-1.0e30)
            yl = float(1.0e30)
            yh = float(-1.0e30)
            zl = float(1.0e30)
            zh = float(-1.0e30)
            xs = float(0.0)
            ys = float(0.0)
            zs = float(0.0)
            m = float(0.0)
            for i in range(run_start[r], run_start[r + 1]):
                d = pos[idx[i]] - o
                z = wp.dot(d, f)
                if z > 1.0e-6:
                    x = wp.dot(d, rt) / z * it * half + half - 0.5
                    y = wp.dot(d, up) / z * it * half + half - 0.5
                    xl = wp.min(xl, x)
                    xh = wp.max(xh, x)
                    yl = wp.min(yl, y)
                    yh = wp.max(yh, y)
                    zl = wp.min(zl, z)
                    zh = wp.max(zh, z)
                    xs += x
                    ys += y
                    zs += z
                    m += 1.0
            if m == 0.0:
                continue
            run = _run_blockers(ms, s, a1, a2, xl, xh, yl, yh, zl, zh, xs / m, ys / m, zs / m)
            if run[0] == 0.0:
                continue
        for i in range(a, b):
            k = idx[i]
            d = pos[k] - o
            z = wp.dot(d, f)
            if z > 1.0e-6:  # kernels.shadowmap._to_map with the map's frame at hand
                x = wp.dot(d, rt) / z * it * half + half - 0.5
                y = wp.dot(d, up) / z * it * half + half - 0.5
                fr = float(0.0)
                if sp > 0.0 and k < hard0:  # a cluster map: its penumbra
                    if run[0] == 1.0:
                        fr = 1.0
                    elif run[0] == 2.0:
                        fr = penumbra(ms, s, x, y, z, a1, a2, run[1])
                    else:
                        fr = penumbra(ms, s, x, y, z, a1, a2, 0.0)
                else:  # one source: the hard lookup of kernels.shadowmap.occluded
                    fr = _hard(ms, s, x, y, z)
                if fr > 0.0:
                    acc[i] = acc[i] + fr * _weight(weights, rows, bary, k, j, centres, n_rows)
                    count[i] = count[i] + fr


@wp.kernel
def _ray_sum_kernel(ms: MapSet, lo: int, hi: int, col0: int, run0: int,
                    run_start: wp.array(dtype=wp.int32), run_cell: wp.array(dtype=wp.int32),
                    idx: wp.array(dtype=wp.int32),
                    pos: wp.array(dtype=wp.vec3), rows: wp.array2d(dtype=wp.int32),
                    bary: wp.array(dtype=wp.vec3), lists: wp.array2d(dtype=wp.int32),
                    n_list: wp.array(dtype=wp.int32), weights: wp.array2d(dtype=wp.vec3),
                    centres: wp.array2d(dtype=wp.vec3), n_rows: int, hard0: int,
                    acc: wp.array(dtype=wp.vec3), count: wp.array(dtype=wp.float32)):
    # _masked_sum_kernel's runs, the ray-mode maps of their lists only (a source inside the proxy's
    # bounding sphere: the exact segment against the proxy, ~8x a map lookup on the CPU, so cast only
    # where the point's transfer is nonzero: `count` counts those). Launched only for batches with such maps.
    r = run0 + wp.tid()
    a = wp.max(run_start[r], lo)
    b = wp.min(run_start[r + 1], hi)
    c = run_cell[r]
    for t in range(n_list[c]):
        s = lists[c, t]
        if ms.ray[s] == 1:
            j = col0 + s
            o = ms.origin[s]
            for i in range(a, b):
                k = idx[i]
                w = _weight(weights, rows, bary, k, j, centres, n_rows)
                if w[0] != 0.0 or w[1] != 0.0 or w[2] != 0.0:  # no ray where it adds nothing (the source's back side)
                    if segment_blocked(ms.proxy, pos[k], o):
                        acc[i] = acc[i] + w
                        count[i] = count[i] + 1.0


class MaskedSum:
    """Accumulator over batches of maps for a fixed set of points; allocates at construction only.

    pos (N,3) m; rows (N,3) weight rows; bary (N,3); group (N,) cand row of each point;
    tile (N,) optional: points of a group with the same tile form a culling cell (default: the
    group); n_groups: rows of `cand` (default max(group)+1); max_maps: the most maps of one batch;
    cull: skip maps whose shadow cone misses a cell's points (False: test every candidate).
    """

    def __init__(self, pos: np.ndarray, rows: np.ndarray, bary: np.ndarray, group: np.ndarray,
                 device: str | None = None, n_groups: int | None = None, max_maps: int = 64, cull: bool = True,
                 tile: np.ndarray | None = None):
        self.device = d = runtime.device(device)
        self._cpu = wp.get_device(d).is_cpu
        self._no_centres = wp.zeros((0, 1), dtype=wp.vec3, device=d)  # accumulate without a centres table
        pos = np.asarray(pos, np.float64).reshape(-1, 3)
        group = np.asarray(group, np.int64).reshape(-1)
        self.size = len(pos)
        self.n_groups = G = int(n_groups if n_groups is not None else (group.max() + 1 if len(group) else 1))
        self.cull = int(cull)
        tile = np.zeros(self.size, np.int64) if tile is None else np.asarray(tile, np.int64).reshape(-1)
        span = int(tile.max() - tile.min() + 1) if self.size else 1
        cells, point_cell = np.unique(group * span + (tile - (tile.min() if self.size else 0)), return_inverse=True)
        self.n_cells = C = max(len(cells), 1)
        self.point_cell = point_cell.reshape(-1)
        self._by_cell = np.argsort(self.point_cell, kind="stable")  # the points cell by cell
        self._mark = np.zeros(self.size, bool)  # scratch of select()
        self._slot = np.zeros(self.size, np.int64)
        n_alloc = max(self.size, 1)  # Warp arrays of zero length cannot be launched over
        self.pos = Buffer(n_alloc, wp.vec3, d)
        self.rows = Buffer((n_alloc, 3), wp.int32, d)
        self.bary = Buffer(n_alloc, wp.vec3, d)
        for buf, v in ((self.pos, pos), (self.rows, np.asarray(rows).reshape(-1, 3)),
                       (self.bary, np.asarray(bary).reshape(-1, 3))):
            buf.upload(v)
        # bounding spheres (centre, radius) of each group's and each cell's points: what the
        # shadow cones are tested against (a margin for float32 points)
        self.g_centre, self.g_radius = _spheres(pos, group, G, d)
        self.c_centre, self.c_radius = _spheres(pos, self.point_cell, C, d)
        self.cell_group = Buffer(C, wp.int32, d)
        self._cell_group_host = (cells // span).astype(np.int64) if len(cells) else np.zeros(1, np.int64)
        self.cell_group.upload(self._cell_group_host)
        self.active = Buffer(C, wp.uint8, d)  # cells with selected points
        self.max_maps = max_maps
        self.g_lists = wp.zeros((G, max_maps), dtype=wp.int32, device=d)
        self.g_n = wp.zeros(G, dtype=wp.int32, device=d)
        self.lists = wp.zeros((C, max_maps), dtype=wp.int32, device=d)
        self.n_list = wp.zeros(C, dtype=wp.int32, device=d)
        self.idx = Buffer(n_alloc, wp.int32, d)  # the selected points, cell by cell
        self.run_start = Buffer(n_alloc + 1, wp.int32, d)  # runs: the selected points of one cell
        self.run_cell = Buffer(n_alloc, wp.int32, d)
        self.order = np.arange(0)  # selected point i (select's order) is summed in row order[i]
        self.n_runs = 0
        self.acc = Buffer(n_alloc, wp.vec3, d)
        self.count = Buffer(n_alloc, wp.float32, d)
        self.n = 0
        self.select(None)

    def select(self, idx: np.ndarray | None = None) -> None:
        """Sum over the points `idx` (indices into the constructor's points; None: all of them)
        from now on, starting from zero; result() rows follow idx's order."""
        idx = np.arange(self.size) if idx is None else np.asarray(idx, np.int64).reshape(-1)
        # cell by cell (runs of one cell's points): the points in the constructor's cell order, kept
        # where selected (linear in the points; distinct indices, else a sort)
        mark = self._mark
        mark[idx] = True
        if 8 * len(idx) < self.size:  # few points: sorting them is cheaper than a pass over all
            mark[idx] = False
            rank = np.argsort(self.point_cell[idx], kind="stable")
            ordered = idx[rank]
            self.order = np.empty(len(idx), np.int64)
            self.order[rank] = np.arange(len(idx))
        elif int(mark.sum()) == len(idx):
            ordered = self._by_cell[mark[self._by_cell]]
            mark[idx] = False
            self._slot[ordered] = np.arange(len(ordered))
            self.order = self._slot[idx]
        else:
            mark[idx] = False
            rank = np.argsort(self.point_cell[idx], kind="stable")
            ordered = idx[rank]
            self.order = np.empty(len(idx), np.int64)
            self.order[rank] = np.arange(len(idx))
        self.n = self.idx.upload(ordered)
        c = self.point_cell[ordered]
        starts = np.flatnonzero(np.r_[True, c[1:] != c[:-1]]) if len(c) else np.zeros(0, np.int64)
        self._run_cell = c[starts]
        self.n_runs = self.run_cell.upload(self._run_cell)
        self.run_start.upload(np.r_[starts, len(c)])
        self._run_start = np.r_[starts, len(c)]
        self.active.host[:] = 0
        self.active.host[c[starts]] = 1
        self.active.push()
        self.reset()

    def activate(self, idx: np.ndarray) -> None:
        """List maps (prepare) for the cells of points `idx` too, not only the selected points'
        cells: a later select() of any of them may then be summed with the same lists (the
        selection itself is unchanged)."""
        h = self.active.host
        h[self.point_cell[np.asarray(idx, np.int64).reshape(-1)]] = 1
        self.active.push()

    def activate_groups(self, groups: np.ndarray) -> None:
        """activate() for every cell of the groups flagged in `groups` (n_groups,) bool."""
        h = self.active.host
        h[:self.n_cells] |= np.asarray(groups, bool)[self._cell_group_host].astype(np.uint8)
        self.active.push()

    def reset(self) -> None:
        """Zero the sums of the selected points: the first n rows, the only ones accumulate writes and
        result reads (the buffers hold every point; a drag frame selects a few)."""
        if self.n:
            if self._cpu:  # the host mirror is the device array (kernels.buffers): zeroed in place, no array views
                self.acc.host[:self.n] = 0.0
                self.count.host[:self.n] = 0.0
            else:
                self.acc.dev[:self.n].zero_()
                self.count.dev[:self.n].zero_()

    def prepare(self, maps: ShadowMaps, n_maps: int, first: int, cand: wp.array, split=None) -> None:
        """Each cell's list of maps 0..n_maps-1 of `maps` (sources first.. of `cand`'s columns)
        that may occlude its points. Run once per batch, before accumulate. split: optional
        callable(launch(lo, hi), n) that runs a launch over index ranges (app.runtime.split);
        default one launch."""
        if n_maps > self.max_maps:
            raise ValueError(f"{n_maps} maps exceed the {self.max_maps} this MaskedSum lists per batch")
        split = split or (lambda launch, n: launch(0, n))

        def groups(lo: int, hi: int) -> None:
            wp.launch(_list_kernel, dim=hi - lo,
                      inputs=[maps.ms, lo, n_maps, first, self.g_centre.dev, self.g_radius.dev, cand, self.cull],
                      outputs=[self.g_lists, self.g_n], device=self.device)

        def cells(lo: int, hi: int) -> None:
            wp.launch(_cell_list_kernel, dim=hi - lo,
                      inputs=[maps.ms, lo, self.cell_group.dev, self.active.dev, self.c_centre.dev,
                              self.c_radius.dev, self.cull, self.g_lists, self.g_n],
                      outputs=[self.lists, self.n_list], device=self.device)

        split(groups, self.n_groups)
        split(cells, self.n_cells)

    def work(self) -> int:
        """The prepared batch's work over the selected points: sum over them of (maps listed + 1), the
        (point, map) pairs plus a point's own cost (balanced's measure)."""
        if self.n == 0:
            return 0
        n_list = self.n_list.numpy()[:self.n_cells]
        return int(np.dot(np.diff(self._run_start), n_list[self._run_cell] + 1))

    def run_work(self) -> np.ndarray:
        """(n_runs,) int64 the cumulative work (work()'s measure) of the prepared batch's runs, in their order:
        its last entry is work(); balanced(k, it) cuts by it without reading the lists again."""
        if self.n == 0:
            return np.zeros(0, np.int64)
        n_list = self.n_list.numpy()  # the CPU array itself (on CUDA a copy)
        return np.cumsum(np.diff(self._run_start) * (n_list[self._run_cell].astype(np.int64) + 1))

    def balanced(self, k: int, work: np.ndarray | None = None) -> list[tuple[int, int]]:
        """[0, n) cut at runs into at most k ranges of the prepared batch's selected points with
        near-equal work (points x maps listed: the masked sums' (point, map) pairs), for k
        concurrent accumulate calls (a cut by point count leaves the heavy cells near the
        object to one of them). work: run_work(), if the caller has it."""
        if k <= 1 or self.n_runs <= 1:
            return [(0, self.n)] if self.n else []
        work = self.run_work() if work is None else work
        cut = np.searchsorted(work, work[-1] * np.arange(1, k) / k)
        bounds = np.unique(np.r_[0, self._run_start[np.minimum(cut + 1, self.n_runs)], self.n])
        return [(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:]) if b > a]

    def accumulate(self, maps: ShadowMaps, first: int, weights: wp.array, lo: int = 0, hi: int | None = None,
                   centres: wp.array | None = None, n_rows: int = 0, hard_from: int | None = None) -> None:
        """Add the prepared batch's masked sums to selected points lo..hi-1 (in the cell-by-cell
        order the sums keep; default all); disjoint ranges may run concurrently. `weights` (rows,
        sources) vec3, column first + map. centres: optional (rows, sources) vec3 table, same columns, of the
        weight rows n_rows and up (row r read from its row r - n_rows instead of from `weights`). hard_from:
        the points (indices into the sums' positions) from this one up look every cluster map up with its eye's
        hard lookup, no PCSS penumbra (None: none do)."""
        hi = self.n if hi is None else min(hi, self.n)
        if hi <= lo:
            return
        r0 = int(np.searchsorted(self._run_start, lo, side="right")) - 1
        r1 = int(np.searchsorted(self._run_start, hi, side="left"))
        args = [maps.ms, lo, hi, first, r0, self.run_start.dev, self.run_cell.dev, self.idx.dev,
                self.pos.dev, self.rows.dev, self.bary.dev, self.lists, self.n_list, weights,
                self._no_centres if centres is None else centres, n_rows,
                np.iinfo(np.int32).max if hard_from is None else int(hard_from)]
        wp.launch(_masked_sum_kernel, dim=r1 - r0, inputs=args, outputs=[self.acc.dev, self.count.dev],
                  device=self.device)
        if maps.n_ray:  # the batch's maps of sources inside the proxy's bounding sphere (rare)
            wp.launch(_ray_sum_kernel, dim=r1 - r0, inputs=args, outputs=[self.acc.dev, self.count.dev],
                      device=self.device)

    def add(self, maps: ShadowMaps, n_maps: int, first: int, cand: wp.array, weights: wp.array) -> None:
        """Accumulate maps [0, n_maps) of `maps`, which stand for sources first .. first+n_maps-1."""
        if self.n == 0 or n_maps == 0:
            return
        self.prepare(maps, n_maps, first, cand)
        self.accumulate(maps, first, weights)

    def result(self, counts: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
        """(n,3) float64 masked sums and (n,) number of occluded sources per selected point (of a
        ray-mode map, those of nonzero transfer only: _ray_sum_kernel; None when not `counts`)."""
        wp.synchronize_device(self.device)
        acc = self.acc.pull(self.n)[self.order].astype(np.float64)
        return acc, (self.count.pull(self.n)[self.order].astype(np.float64) if counts else None)


def _spheres(pos: np.ndarray, label: np.ndarray, n: int, device: str) -> tuple[Buffer, Buffer]:
    """Bounding spheres of the points of each label 0..n-1: (centre (n,) vec3, radius (n,)) buffers."""
    cnt = np.maximum(np.bincount(label, minlength=n), 1)[:n]
    centre = np.stack([np.bincount(label, pos[:, c], n)[:n] for c in range(3)], 1) / cnt[:, None]
    rad = np.zeros(n)
    np.maximum.at(rad, label, np.linalg.norm(pos - centre[label], axis=1))
    c_buf, r_buf = Buffer(n, wp.vec3, device), Buffer(n, wp.float32, device)
    c_buf.upload(centre)
    r_buf.upload(rad * (1 + 1e-4) + 1e-4)
    return c_buf, r_buf
