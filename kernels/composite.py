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

The points are uploaded once (MaskedSum's constructor); a frame sums over a listed subset of
them (`select`), in any number of index ranges (app.runtime.split). Nothing is allocated after
construction.
"""
from __future__ import annotations

import numpy as np
import warp as wp

from kernels import runtime
from kernels.buffers import Buffer
from kernels.shadowmap import MapSet, ShadowMaps, may_occlude, occluded


@wp.kernel
def _list_kernel(ms: MapSet, n_maps: int, col0: int, centre: wp.array(dtype=wp.vec3),
                 radius: wp.array(dtype=wp.float32), cand: wp.array2d(dtype=wp.uint8), cull: int,
                 lists: wp.array2d(dtype=wp.int32), n_list: wp.array(dtype=wp.int32)):
    g = wp.tid()
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
def _cell_list_kernel(ms: MapSet, cell_group: wp.array(dtype=wp.int32), active: wp.array(dtype=wp.uint8),
                      centre: wp.array(dtype=wp.vec3), radius: wp.array(dtype=wp.float32), cull: int,
                      g_lists: wp.array2d(dtype=wp.int32), g_n: wp.array(dtype=wp.int32),
                      lists: wp.array2d(dtype=wp.int32), n_list: wp.array(dtype=wp.int32)):
    c = wp.tid()
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


@wp.kernel
def _masked_sum_kernel(ms: MapSet, lo: int, col0: int, idx: wp.array(dtype=wp.int32),
                       pos: wp.array(dtype=wp.vec3), rows: wp.array2d(dtype=wp.int32),
                       bary: wp.array(dtype=wp.vec3), cell: wp.array(dtype=wp.int32),
                       lists: wp.array2d(dtype=wp.int32), n_list: wp.array(dtype=wp.int32),
                       weights: wp.array2d(dtype=wp.vec3),
                       acc: wp.array(dtype=wp.vec3), count: wp.array(dtype=wp.float32)):
    i = lo + wp.tid()
    k = idx[i]
    g = cell[k]
    p = pos[k]
    b = bary[k]
    total = wp.vec3(0.0, 0.0, 0.0)
    hits = float(0.0)
    for t in range(n_list[g]):
        s = lists[g, t]
        if occluded(ms, s, p):
            j = col0 + s
            w = weights[rows[k, 0], j] * b[0] + weights[rows[k, 1], j] * b[1] + weights[rows[k, 2], j] * b[2]
            total += w
            hits += 1.0
    acc[i] = acc[i] + total
    count[i] = count[i] + hits


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
        n_alloc = max(self.size, 1)  # Warp arrays of zero length cannot be launched over
        self.pos = Buffer(n_alloc, wp.vec3, d)
        self.rows = Buffer((n_alloc, 3), wp.int32, d)
        self.bary = Buffer(n_alloc, wp.vec3, d)
        self.cell = Buffer(n_alloc, wp.int32, d)
        for buf, v in ((self.pos, pos), (self.rows, np.asarray(rows).reshape(-1, 3)),
                       (self.bary, np.asarray(bary).reshape(-1, 3)), (self.cell, self.point_cell)):
            buf.upload(v)
        # bounding spheres (centre, radius) of each group's and each cell's points: what the
        # shadow cones are tested against (a margin for float32 points)
        self.g_centre, self.g_radius = _spheres(pos, group, G, d)
        self.c_centre, self.c_radius = _spheres(pos, self.point_cell, C, d)
        self.cell_group = Buffer(C, wp.int32, d)
        self.cell_group.upload(cells // span if len(cells) else np.zeros(1))
        self.active = Buffer(C, wp.uint8, d)  # cells with selected points
        self.max_maps = max_maps
        self.g_lists = wp.zeros((G, max_maps), dtype=wp.int32, device=d)
        self.g_n = wp.zeros(G, dtype=wp.int32, device=d)
        self.lists = wp.zeros((C, max_maps), dtype=wp.int32, device=d)
        self.n_list = wp.zeros(C, dtype=wp.int32, device=d)
        self.idx = Buffer(n_alloc, wp.int32, d)
        self.acc = Buffer(n_alloc, wp.vec3, d)
        self.count = Buffer(n_alloc, wp.float32, d)
        self.n = 0
        self.select(None)

    def select(self, idx: np.ndarray | None = None) -> None:
        """Sum over the points `idx` (indices into the constructor's points; None: all of them)
        from now on, starting from zero; result() rows follow idx's order."""
        if idx is None:
            self.idx.host[:self.size] = np.arange(self.size)
            self.idx.push(self.size)
            self.n = self.size
            self.active.host[:] = 1
        else:
            self.n = self.idx.upload(idx)
            self.active.host[:] = 0
            self.active.host[self.point_cell[np.asarray(idx, np.int64)]] = 1
        self.active.push()
        self.reset()

    def reset(self) -> None:
        self.acc.dev.zero_()
        self.count.dev.zero_()

    def prepare(self, maps: ShadowMaps, n_maps: int, first: int, cand: wp.array) -> None:
        """Each cell's list of maps 0..n_maps-1 of `maps` (sources first.. of `cand`'s columns)
        that may occlude its points. Run once per batch, before accumulate."""
        if n_maps > self.max_maps:
            raise ValueError(f"{n_maps} maps exceed the {self.max_maps} this MaskedSum lists per batch")
        wp.launch(_list_kernel, dim=self.n_groups,
                  inputs=[maps.ms, n_maps, first, self.g_centre.dev, self.g_radius.dev, cand, self.cull],
                  outputs=[self.g_lists, self.g_n], device=self.device)
        wp.launch(_cell_list_kernel, dim=self.n_cells,
                  inputs=[maps.ms, self.cell_group.dev, self.active.dev, self.c_centre.dev, self.c_radius.dev,
                          self.cull, self.g_lists, self.g_n], outputs=[self.lists, self.n_list], device=self.device)

    def accumulate(self, maps: ShadowMaps, first: int, weights: wp.array, lo: int = 0, hi: int | None = None) -> None:
        """Add the prepared batch's masked sums to selected points lo..hi-1 (default all); disjoint
        ranges may run concurrently. `weights` (rows, sources) vec3, column first + map."""
        hi = self.n if hi is None else min(hi, self.n)
        if hi <= lo:
            return
        wp.launch(_masked_sum_kernel, dim=hi - lo,
                  inputs=[maps.ms, lo, first, self.idx.dev, self.pos.dev, self.rows.dev, self.bary.dev,
                          self.cell.dev, self.lists, self.n_list, weights],
                  outputs=[self.acc.dev, self.count.dev], device=self.device)

    def add(self, maps: ShadowMaps, n_maps: int, first: int, cand: wp.array, weights: wp.array) -> None:
        """Accumulate maps [0, n_maps) of `maps`, which stand for sources first .. first+n_maps-1."""
        if self.n == 0 or n_maps == 0:
            return
        self.prepare(maps, n_maps, first, cand)
        self.accumulate(maps, first, weights)

    def result(self) -> tuple[np.ndarray, np.ndarray]:
        """(n,3) float64 masked sums and (n,) number of occluded sources per selected point."""
        wp.synchronize_device(self.device)
        return (self.acc.pull(self.n).astype(np.float64), self.count.pull(self.n).astype(np.float64))


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
