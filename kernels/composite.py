"""Masked transfer sums: sum_j W_xj M_xj over a batch of shadow maps (seed eq. 3 / eq. 4).

Each point x (a pixel's surface point, or a patch centre) carries up to three weight rows
(vertex indices) and barycentric weights; W for source j is interpolated from those rows:
W_xj = sum_k b_k W[row_k, j]. Rows hold radiance transfers L_ij (HDR path) or intensity
transfers S_ij (LDR path); the kernel does not care which. `cand[group_x, j]` (uint8) lets a
point skip sources whose shaft cannot meet the object (group = the point's receiver patch).
"""
from __future__ import annotations

import numpy as np
import warp as wp

from kernels import runtime
from kernels.shadowmap import MapSet, ShadowMaps, occluded


@wp.kernel
def _masked_sum_kernel(ms: MapSet, n_maps: int, first: int,
                       pos: wp.array(dtype=wp.vec3), rows: wp.array2d(dtype=wp.int32),
                       bary: wp.array(dtype=wp.vec3), group: wp.array(dtype=wp.int32),
                       cand: wp.array2d(dtype=wp.uint8), weights: wp.array2d(dtype=wp.vec3),
                       acc: wp.array(dtype=wp.vec3), count: wp.array(dtype=wp.float32)):
    i = wp.tid()
    g = group[i]
    p = pos[i]
    b = bary[i]
    total = wp.vec3(0.0, 0.0, 0.0)
    hits = float(0.0)
    for s in range(n_maps):
        j = first + s
        if cand[g, j] == wp.uint8(0):
            continue
        if occluded(ms, s, p):
            w = weights[rows[i, 0], j] * b[0] + weights[rows[i, 1], j] * b[1] + weights[rows[i, 2], j] * b[2]
            total += w
            hits += 1.0
    acc[i] = acc[i] + total
    count[i] = count[i] + hits


class MaskedSum:
    """Accumulator over batches of maps for a fixed set of points; allocates once."""

    def __init__(self, pos: np.ndarray, rows: np.ndarray, bary: np.ndarray, group: np.ndarray,
                 device: str | None = None):
        self.device = runtime.device(device)
        d = self.device
        self.n = len(pos)
        self.pos = wp.array(np.asarray(pos, np.float32), dtype=wp.vec3, device=d)
        self.rows = wp.array(np.asarray(rows, np.int32), dtype=wp.int32, device=d)
        self.bary = wp.array(np.asarray(bary, np.float32), dtype=wp.vec3, device=d)
        self.group = wp.array(np.asarray(group, np.int32), dtype=wp.int32, device=d)
        self.acc = wp.zeros(self.n, dtype=wp.vec3, device=d)
        self.count = wp.zeros(self.n, dtype=wp.float32, device=d)

    def reset(self) -> None:
        self.acc.zero_()
        self.count.zero_()

    def add(self, maps: ShadowMaps, n_maps: int, first: int, cand: wp.array, weights: wp.array) -> None:
        """Accumulate maps [0, n_maps) of `maps`, which stand for sources first .. first+n_maps-1."""
        if self.n == 0 or n_maps == 0:
            return
        wp.launch(_masked_sum_kernel, dim=self.n,
                  inputs=[maps.ms, n_maps, first, self.pos, self.rows, self.bary, self.group, cand, weights],
                  outputs=[self.acc, self.count], device=self.device)

    def result(self) -> tuple[np.ndarray, np.ndarray]:
        """(N,3) float64 masked sums and (N,) number of occluded sources per point."""
        return self.acc.numpy().astype(np.float64), self.count.numpy().astype(np.float64)
