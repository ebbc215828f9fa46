"""Masked transfer sums: sum_j W_xj M_xj over a batch of shadow maps (seed eq. 3 / eq. 4).

Each point x (a pixel's surface point, or a patch centre) carries up to three weight rows
(vertex indices) and barycentric weights; W for source j is interpolated from those rows:
W_xj = sum_k b_k W[row_k, j]. Rows hold radiance transfers L_ij (HDR path) or intensity
transfers S_ij (LDR path); the kernel does not care which. `cand[group_x, j]` (uint8) lets a
point skip sources whose shaft cannot meet the object (group = the point's receiver patch).

Per batch, each group first lists the maps its points may be occluded in: its candidates whose
shadow cone meets the group's bounding sphere (kernels.shadowmap.may_occlude, conservative, so
the sums are those of testing every map); a point then loops over its group's list only.

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
def _masked_sum_kernel(ms: MapSet, lo: int, col0: int, idx: wp.array(dtype=wp.int32),
                       pos: wp.array(dtype=wp.vec3), rows: wp.array2d(dtype=wp.int32),
                       bary: wp.array(dtype=wp.vec3), group: wp.array(dtype=wp.int32),
                       lists: wp.array2d(dtype=wp.int32), n_list: wp.array(dtype=wp.int32),
                       weights: wp.array2d(dtype=wp.vec3),
                       acc: wp.array(dtype=wp.vec3), count: wp.array(dtype=wp.float32)):
    i = lo + wp.tid()
    k = idx[i]
    g = group[k]
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
    n_groups: rows of `cand` (default max(group)+1); max_maps: the most maps of one batch;
    cull: skip maps whose shadow cone misses a group's points (False: test every candidate).
    """

    def __init__(self, pos: np.ndarray, rows: np.ndarray, bary: np.ndarray, group: np.ndarray,
                 device: str | None = None, n_groups: int | None = None, max_maps: int = 64, cull: bool = True):
        self.device = d = runtime.device(device)
        pos = np.asarray(pos, np.float64).reshape(-1, 3)
        group = np.asarray(group, np.int64).reshape(-1)
        self.size = len(pos)
        self.n_groups = int(n_groups if n_groups is not None else (group.max() + 1 if len(group) else 1))
        self.cull = int(cull)
        n_alloc = max(self.size, 1)  # Warp arrays of zero length cannot be launched over
        self.pos = Buffer(n_alloc, wp.vec3, d)
        self.rows = Buffer((n_alloc, 3), wp.int32, d)
        self.bary = Buffer(n_alloc, wp.vec3, d)
        self.group = Buffer(n_alloc, wp.int32, d)
        for buf, v in ((self.pos, pos), (self.rows, np.asarray(rows).reshape(-1, 3)),
                       (self.bary, np.asarray(bary).reshape(-1, 3)), (self.group, group)):
            buf.upload(v)
        # each group's bounding sphere (centre, radius): what the shadow cones are tested against
        cnt = np.maximum(np.bincount(group, minlength=self.n_groups), 1)
        centre = np.stack([np.bincount(group, pos[:, c], self.n_groups) for c in range(3)], 1) / cnt[:, None]
        rad = np.zeros(self.n_groups)
        np.maximum.at(rad, group, np.linalg.norm(pos - centre[group], axis=1))
        self.g_centre = Buffer(self.n_groups, wp.vec3, d)
        self.g_radius = Buffer(self.n_groups, wp.float32, d)
        self.g_centre.upload(centre)
        self.g_radius.upload(rad * (1 + 1e-4) + 1e-4)  # float32 points round off: a margin
        self.max_maps = max_maps
        self.lists = wp.zeros((self.n_groups, max_maps), dtype=wp.int32, device=d)
        self.n_list = wp.zeros(self.n_groups, dtype=wp.int32, device=d)
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
        else:
            self.n = self.idx.upload(idx)
        self.reset()

    def reset(self) -> None:
        self.acc.dev.zero_()
        self.count.dev.zero_()

    def prepare(self, maps: ShadowMaps, n_maps: int, first: int, cand: wp.array) -> None:
        """Each group's list of maps 0..n_maps-1 of `maps` (sources first.. of `cand`'s columns)
        that may occlude its points. Run once per batch, before accumulate."""
        if n_maps > self.max_maps:
            raise ValueError(f"{n_maps} maps exceed the {self.max_maps} this MaskedSum lists per batch")
        wp.launch(_list_kernel, dim=self.n_groups,
                  inputs=[maps.ms, n_maps, first, self.g_centre.dev, self.g_radius.dev, cand, self.cull],
                  outputs=[self.lists, self.n_list], device=self.device)

    def accumulate(self, maps: ShadowMaps, first: int, weights: wp.array, lo: int = 0, hi: int | None = None) -> None:
        """Add the prepared batch's masked sums to selected points lo..hi-1 (default all); disjoint
        ranges may run concurrently. `weights` (rows, sources) vec3, column first + map."""
        hi = self.n if hi is None else min(hi, self.n)
        if hi <= lo:
            return
        wp.launch(_masked_sum_kernel, dim=hi - lo,
                  inputs=[maps.ms, lo, first, self.idx.dev, self.pos.dev, self.rows.dev, self.bary.dev,
                          self.group.dev, self.lists, self.n_list, weights],
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
