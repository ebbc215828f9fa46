"""The pairs of points and targets whose segment an occluder blocks, weighed by transfers (Warp kernel).

[p_i -> q_k blocked] for N fixed points p_i and per-call targets q_k, each target with a column of a
fixed transfer T (N,J) that was made without the occluder (form factor x the room's visibility,
kernels.visibility.transfer_matrix): one ray per pair with T > 0 whose segment meets the occluder's
box, its answer weighed in the launch by its row's transfer and by those of the row's members
(app.stages.sun: the blocked part of the sun's loss passed on by T, a cluster of patches' one ray per
target).
The points and the transfer are fixed per scene (uploaded once); the targets per call (kept
buffers: nothing is allocated after the first call).
"""
from __future__ import annotations

from typing import Callable

import numpy as np
import warp as wp

from kernels.buffers import Buffer
from kernels.runtime import launch_split
from kernels.visibility import Occluder, segment_blocked


@wp.func
def _segment_meets_centred_box(a: wp.vec3, b: wp.vec3, h: wp.vec3) -> bool:
    """True when the segment a-b meets the box |x_k| <= h_k (coordinates about the box's centre, along its
    axes). The separating-axis test of a segment against a box: it misses the box exactly when its
    projections and the box's are apart on one of the box's 3 axes or on one of the 3 crosses of the
    segment with them (m, e: the segment's midpoint and half vector). No divisions, unlike the slab test
    (kernels.visibility.segment_meets_box: the same yes/no except, by rounding, on a segment that grazes the
    box's surface; the callers' boxes bound the occluder with a margin, so no segment that meets the occluder
    grazes them)."""
    m = 0.5 * (a + b)
    e = 0.5 * (b - a)
    ex = wp.abs(e[0])
    ey = wp.abs(e[1])
    ez = wp.abs(e[2])
    if wp.abs(m[0]) > h[0] + ex or wp.abs(m[1]) > h[1] + ey or wp.abs(m[2]) > h[2] + ez:
        return False
    if wp.abs(m[1] * e[2] - m[2] * e[1]) > h[1] * ez + h[2] * ey:
        return False
    if wp.abs(m[2] * e[0] - m[0] * e[2]) > h[0] * ez + h[2] * ex:
        return False
    return wp.abs(m[0] * e[1] - m[1] * e[0]) <= h[0] * ey + h[1] * ex


@wp.kernel
def _blocked_sums_kernel(mesh: wp.uint64, start: int, points: wp.array(dtype=wp.vec3),
                         T: wp.array2d(dtype=wp.float32), is_short: wp.array(dtype=wp.uint8),
                         column: wp.array(dtype=wp.int32), weight: wp.array(dtype=wp.vec3), m: int, m_short: int,
                         targets: wp.array(dtype=wp.vec3), box_c: wp.vec3, box_h: wp.vec3,
                         member_start: wp.array(dtype=wp.int32), U: wp.array2d(dtype=wp.float32),
                         has_obb: int, obb_c: wp.vec3, obb_axes: wp.mat33, obb_half: wp.vec3,
                         targets_obb: wp.array(dtype=wp.vec3),
                         near: wp.array(dtype=wp.vec3), far: wp.array(dtype=wp.vec3),
                         member_sum: wp.array(dtype=wp.vec3)):
    # per launch row i, over its blocked pairs (T[i, column[k]] > 0, the segment points[i] -> targets[k]
    # meets the occluder): near[i] = sum_{k < m_short} T[i, column[k]] weight[k], far[i] the same over
    # k >= m_short (the short points take only the first m_short targets); its members j (member_start[i] ..
    # member_start[i+1]) get member_sum[j] = sum_{k < m_short} U[j, column[k]] weight[k] (one thread a row:
    # a member's sum is written by its row's thread only). A segment's ray is cast only where it meets the
    # box about the occluder: with has_obb the oriented one (centre obb_c, axes the rows of obb_axes, half
    # sides obb_half; targets_obb: the targets in its frame), else the upright one (centre box_c, half sides box_h).
    i = start + wp.tid()
    p = points[i]
    p_box = p - box_c
    p_obb = obb_axes * (p - obb_c)
    mi = m
    if is_short[i] != wp.uint8(0):
        mi = m_short
    j0 = member_start[i]
    j1 = member_start[i + 1]
    for j in range(j0, j1):
        member_sum[j] = wp.vec3(0.0, 0.0, 0.0)
    a = wp.vec3(0.0, 0.0, 0.0)
    b = wp.vec3(0.0, 0.0, 0.0)
    for k in range(mi):
        c = column[k]
        t = T[i, c]
        if t > 0.0:
            q = targets[k]
            meets = bool(False)
            if has_obb != 0:
                meets = _segment_meets_centred_box(p_obb, targets_obb[k], obb_half)
            else:
                meets = _segment_meets_centred_box(p_box, q - box_c, box_h)
            if meets:
                if segment_blocked(mesh, p, q):
                    w = weight[k]
                    if k < m_short:
                        a += t * w
                        for j in range(j0, j1):
                            member_sum[j] = member_sum[j] + U[j, c] * w
                    else:
                        b += t * w
    near[i] = a
    far[i] = b


class BlockedPairs:
    """[p_i -> q_k blocked] for N fixed points and per-call targets q_k, each with a column of a fixed
    transfer T (N,J) that must be > 0 for its ray to be cast (else 0), weighed by the transfers (sums:
    one ray's answer weighed by its row's transfer and by those of the row's members, e.g. every patch
    of a cluster).
    Points flagged `short` take only a call's first targets (two sets of points in one launch); the
    points are kept interleaved so that the ranges of a split launch get as many of each, and spread
    (a golden-ratio sequence over each set) so that they get as many from every part of the room (the
    rays near the occluder, most of a launch's work, fall on every range alike)."""

    def __init__(self, points: np.ndarray, T: np.ndarray, device: str, capacity: int,
                 short: np.ndarray | None = None, members: tuple[np.ndarray, np.ndarray] | None = None):
        """points (N,3) m; T (N,J); capacity: the most targets of a call; short (N,) bool; members:
        (owner (M,) int: the point each member belongs to, U (M,J): its transfer) for sums."""
        self.n, self.j = T.shape
        if len(points) != self.n:
            raise ValueError(f"BlockedPairs: {len(points)} points for a transfer of {self.n} rows")
        short = np.zeros(self.n, bool) if short is None else np.asarray(short, bool)
        # each set's rows spread evenly over [0, 1): its k-th row at frac((k + 1/2) phi), a low-discrepancy
        # sequence (any range of the launch rows takes about the same share of every part of each set)
        rank = np.empty(self.n)
        for flag in (False, True):
            idx = np.flatnonzero(short == flag)
            rank[idx] = np.modf((np.arange(len(idx)) + 0.5) * 0.6180339887498949)[0]
        self.order = np.argsort(rank, kind="stable")  # launch row r holds point order[r]
        self.device = device
        self.points = wp.array(np.asarray(points, np.float32)[self.order], dtype=wp.vec3, device=device)
        self.T = wp.array(np.ascontiguousarray(np.asarray(T, np.float32)[self.order]), dtype=wp.float32, device=device)
        self.short = wp.array(short[self.order].astype(np.uint8), dtype=wp.uint8, device=device)
        cap = max(int(capacity), 1)
        self._targets = Buffer(cap, wp.vec3, device)
        self._column = Buffer(cap, wp.int32, device)
        self._weight = Buffer(cap, wp.vec3, device)
        self._targets_obb = Buffer(cap, wp.vec3, device)  # the targets in the oriented box's frame (sums)
        self._row_of = np.argsort(self.order)  # point i's launch row
        # the members grouped by their point's launch row (CSR): member_start (N+1,), U in that order
        owner = np.zeros(0, np.int64) if members is None else np.asarray(members[0], np.int64)
        U = np.zeros((0, self.j), np.float32) if members is None else np.asarray(members[1], np.float32)
        if len(owner) != len(U) or (len(owner) and (owner.min() < 0 or owner.max() >= self.n)):
            raise ValueError("BlockedPairs: members need one owner in [0, N) per row of their transfer")
        rows = self._row_of[owner]
        self._member_order = np.argsort(rows, kind="stable")  # CSR slot s holds member _member_order[s]
        start = np.zeros(self.n + 1, np.int32)
        start[1:] = np.cumsum(np.bincount(rows, minlength=self.n))
        self.member_start = wp.array(start, dtype=wp.int32, device=device)
        self.U = wp.array(np.ascontiguousarray(U[self._member_order]) if len(U) else np.zeros((1, max(self.j, 1)), np.float32),
                          dtype=wp.float32, device=device)
        self._near = Buffer(max(self.n, 1), wp.vec3, device)
        self._far = Buffer(max(self.n, 1), wp.vec3, device)
        self._member_sum = Buffer(max(len(owner), 1), wp.vec3, device)
        self._members = len(owner)

    def sums(self, occluder: Occluder, targets: np.ndarray, columns: np.ndarray, weights: np.ndarray,
             box: tuple[np.ndarray, np.ndarray],
             split: Callable[[Callable[[int, int], None], int], None] | None = None,
             m_short: int | None = None, obb: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The blocked pairs of targets (m,3) m with their columns (m,) of T, weighed: (near (N,3), far (N,3),
        members (M,3)) float64, in the points' and members' order, with b_ik the pair's answer:
          near_i = sum_{k < m_short} T[i, columns_k] b_ik weights_k, far_i the same over k >= m_short (0 for
          the short points), members_j = sum_{k < m_short} U[j, columns_k] b_{owner_j k} weights_k
        (weights (m,3): each target's, e.g. the change it carries). One launch writes them (float32 sums),
        the weighing only on the blocked pairs. box: (lo (3,), hi (3,)) about the occluder (without `obb`, a
        segment that misses it casts no ray); split: optional callable(launch(lo, hi), n) that runs the launch over
        index ranges (e.g. app.runtime.split), None: one launch; m_short: how many of the first targets
        the short points take (default all). obb: (centre (3,), axes
        (3,3) orthonormal rows, half sides (3,)) m, an oriented box about the occluder, tested instead of `box`
        (the same answer, fewer rays where the object is turned against the world's axes; on sun_room's drag
        every segment that met it met `box` too, so testing both only cost a test per pair)."""
        m = len(columns)
        m_short = m if m_short is None else min(int(m_short), m)
        if self.n == 0 or m == 0:
            return np.zeros((self.n, 3)), np.zeros((self.n, 3)), np.zeros((self._members, 3))
        self._column.upload(np.asarray(columns, np.int32))
        self._targets.upload(np.asarray(targets, np.float32))
        self._weight.upload(np.asarray(weights, np.float32))
        mesh = wp.uint64(occluder.id)
        lo, hi = np.asarray(box[0], np.float64), np.asarray(box[1], np.float64)
        box_c, box_h = wp.vec3(*map(float, 0.5 * (lo + hi))), wp.vec3(*map(float, 0.5 * (hi - lo)))
        if obb is None:
            ob = (0, wp.vec3(0.0, 0.0, 0.0), wp.mat33(*np.eye(3).ravel()), wp.vec3(0.0, 0.0, 0.0))
        else:
            axes = np.asarray(obb[1], np.float64)
            ob = (1, wp.vec3(*map(float, obb[0])), wp.mat33(*map(float, axes.ravel())), wp.vec3(*map(float, obb[2])))
            self._targets_obb.upload((np.asarray(targets, np.float64) - np.asarray(obb[0], np.float64)) @ axes.T)

        def launch(a: int, b: int) -> None:
            wp.launch(_blocked_sums_kernel, dim=b - a,
                      inputs=[mesh, a, self.points, self.T, self.short, self._column.dev, self._weight.dev, m,
                              m_short, self._targets.dev, box_c, box_h, self.member_start, self.U, *ob,
                              self._targets_obb.dev],
                      outputs=[self._near.dev, self._far.dev, self._member_sum.dev], device=self.device)

        launch_split(launch, self.n, split)
        near = self._near.pull(self.n).take(self._row_of, axis=0).astype(np.float64)
        far = self._far.pull(self.n).take(self._row_of, axis=0).astype(np.float64)
        members = np.empty((self._members, 3))
        members[self._member_order] = self._member_sum.pull(self._members)
        return near, far, members
