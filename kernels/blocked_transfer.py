"""The pairs of points and targets whose segment an occluder blocks (Warp kernel).

[p_i -> q_k blocked] for N fixed points p_i and per-call targets q_k, each target with a column of a
fixed transfer T (N,J) that was made without the occluder (form factor x the room's visibility,
kernels.visibility.transfer_matrix): one ray per pair with T > 0 whose segment meets the occluder's
box. Callers weigh one ray's answer by several transfers (app.stages.sun: the blocked part of the
sun's loss passed on by T, a cluster of patches' one ray per target).
The points and the transfer are fixed per scene (uploaded once); the targets per call (kept
buffers: nothing is allocated after the first call).
"""
from __future__ import annotations

from typing import Callable

import numpy as np
import warp as wp

from kernels.buffers import Buffer
from kernels.runtime import launch_split
from kernels.visibility import Occluder, segment_blocked, segment_meets_box


@wp.kernel
def _blocked_pairs_kernel(mesh: wp.uint64, start: int, points: wp.array(dtype=wp.vec3),
                          T: wp.array2d(dtype=wp.float32), is_short: wp.array(dtype=wp.uint8), column: wp.array(dtype=wp.int32),
                          m: int, m_short: int, targets: wp.array(dtype=wp.vec3), lo: wp.vec3, hi: wp.vec3,
                          out: wp.array2d(dtype=wp.uint8)):
    # 1 where T[i, column[k]] > 0 and the segment points[i] -> targets[k] meets the occluder; the
    # short points only with the first m_short targets
    i = start + wp.tid()
    p = points[i]
    mi = m
    if is_short[i] != wp.uint8(0):
        mi = m_short
    for k in range(mi):
        b = wp.uint8(0)
        if T[i, column[k]] > 0.0:
            if segment_meets_box(p, targets[k], lo, hi):
                if segment_blocked(mesh, p, targets[k]):
                    b = wp.uint8(1)
        out[i, k] = b


class BlockedPairs:
    """[p_i -> q_k blocked] (N,m) for N fixed points and per-call targets q_k, each with a column of
    a fixed transfer T (N,J) that must be > 0 for its ray to be cast (else 0): the pairs themselves,
    for callers that weigh one ray's answer by several transfers (e.g. every patch of a cluster).
    Points flagged `short` take only a call's first targets (two sets of points in one launch); the
    points are kept interleaved so that the ranges of a split launch get as many of each."""

    def __init__(self, points: np.ndarray, T: np.ndarray, device: str, capacity: int,
                 short: np.ndarray | None = None):
        """points (N,3) m; T (N,J); capacity: the most targets of a call; short (N,) bool."""
        self.n, self.j = T.shape
        if len(points) != self.n:
            raise ValueError(f"BlockedPairs: {len(points)} points for a transfer of {self.n} rows")
        short = np.zeros(self.n, bool) if short is None else np.asarray(short, bool)
        # each set's rows spread evenly over [0, N): rank within its set / the set's size
        rank = np.empty(self.n)
        for flag in (False, True):
            idx = np.flatnonzero(short == flag)
            rank[idx] = (np.arange(len(idx)) + 0.5) / max(len(idx), 1)
        self.order = np.argsort(rank, kind="stable")  # launch row r holds point order[r]
        self.device = device
        self.points = wp.array(np.asarray(points, np.float32)[self.order], dtype=wp.vec3, device=device)
        self.T = wp.array(np.ascontiguousarray(np.asarray(T, np.float32)[self.order]), dtype=wp.float32, device=device)
        self.short = wp.array(short[self.order].astype(np.uint8), dtype=wp.uint8, device=device)
        cap = max(int(capacity), 1)
        self._targets = Buffer(cap, wp.vec3, device)
        self._column = Buffer(cap, wp.int32, device)
        self._out = Buffer((max(self.n, 1), cap), wp.uint8, device)
        self._row_of = np.argsort(self.order)  # point i's launch row
        self._short = short

    def __call__(self, occluder: Occluder, targets: np.ndarray, columns: np.ndarray,
                 box: tuple[np.ndarray, np.ndarray],
                 split: Callable[[Callable[[int, int], None], int], None] | None = None,
                 m_short: int | None = None) -> np.ndarray:
        """(N,m) bool for targets (m,3) m and their columns (m,) of T, in the points' order. box: (lo (3,),
        hi (3,)) about the occluder (a segment that misses it casts no ray); split: optional
        callable(launch(lo, hi), n) that runs the launch over index ranges (e.g. app.runtime.split),
        None: one launch; m_short: how many of the first targets the short points take (default all;
        the rest of their rows False)."""
        m = len(columns)
        m_short = m if m_short is None else min(int(m_short), m)
        if self.n == 0 or m == 0:
            return np.zeros((self.n, m), bool)
        self._column.upload(np.asarray(columns, np.int32))
        self._targets.upload(np.asarray(targets, np.float32))
        mesh = wp.uint64(occluder.id)

        def launch(a: int, b: int) -> None:
            wp.launch(_blocked_pairs_kernel, dim=b - a, inputs=[mesh, a, self.points, self.T, self.short,
                                                              self._column.dev, m, m_short, self._targets.dev,
                                                              wp.vec3(*map(float, box[0])),
                                                              wp.vec3(*map(float, box[1]))], outputs=[self._out.dev],
                      device=self.device)

        launch_split(launch, self.n, split)
        out = self._out.pull(self.n)[:, :m].take(self._row_of, axis=0) > 0
        out[self._short, m_short:] = False
        return out
