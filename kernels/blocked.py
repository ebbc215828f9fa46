"""Blocked transfer per source: the light an object's box can block from each source (seed sec. 6.4).

For source j (eye e_j) and receiver points p_r with luminance transfers g_rj, the kernel sums
g_rj over the receivers whose segment p_r -> e_j meets the box: the share of the source's light
that the object can take away this frame. The representative source set splits, and places its
shadow-map eyes, by this sum (lighting.frame_sources). Buffers are allocated once (BlockedTransfer).
"""
from __future__ import annotations

import numpy as np
import warp as wp

from kernels import runtime
from kernels.visibility import segment_meets_box


# The cone prefilter's margin on the box's bounding radius (m, and relative): the points and eyes are float32
# (rounding ~1e-6 m over a room), so a segment the exact test passes lies well inside the widened cone.
CONE_MARGIN_M, CONE_MARGIN_REL = 1.0e-4, 1.0e-4


@wp.kernel
def _cone_kernel(pts: wp.array(dtype=wp.vec3), lo: wp.vec3, hi: wp.vec3, axis: wp.array(dtype=wp.vec3),
                 reach: wp.array(dtype=wp.float32), cos2: wp.array(dtype=wp.float32)):
    # per receiver point p: the cone from p that holds the box's bounding sphere (widened by the margin): its
    # axis u toward the centre, the distance a segment must reach along u (d - radius), the squared cosine of
    # its half-angle; reach < 0 where p lies inside the sphere (every segment may pass it)
    r = wp.tid()
    c = 0.5 * (lo + hi)
    rad = wp.length(hi - c) * (1.0 + CONE_MARGIN_REL) + CONE_MARGIN_M
    q = c - pts[r]
    d = wp.length(q)
    if d <= rad:
        axis[r] = wp.vec3(0.0)
        reach[r] = -1.0
        cos2[r] = 0.0
    else:
        axis[r] = q / d
        reach[r] = d - rad
        cos2[r] = 1.0 - (rad / d) * (rad / d)


# Receiver points per group of the group test (a kd-tree's leaves over the points): a group's bounding sphere is
# tested against each eye's segment first; on window_room 16 points per group keep ~a third of the pairs
GROUP_POINTS = 16


@wp.kernel
def _blocked_kernel(first: int, pts: wp.array(dtype=wp.vec3), eyes: wp.array(dtype=wp.vec3),
                    g: wp.array2d(dtype=wp.float32), lo: wp.vec3, hi: wp.vec3, axis: wp.array(dtype=wp.vec3),
                    reach: wp.array(dtype=wp.float32), cos2: wp.array(dtype=wp.float32),
                    grp_centre: wp.array(dtype=wp.vec3), grp_rad: wp.array(dtype=wp.float32),
                    grp_start: wp.array(dtype=wp.int32), grp_member: wp.array(dtype=wp.int32),
                    mask: wp.array2d(dtype=wp.int32), out: wp.array(dtype=wp.float32)):
    j = first + wp.tid()
    e = eyes[j]
    c = 0.5 * (lo + hi)
    rad2 = wp.length_sq(hi - c)
    rad = wp.sqrt(rad2) * (1.0 + CONE_MARGIN_REL) + CONE_MARGIN_M
    # the groups whose points' segments to e can pass the sphere: a point within r_g of the group's centre has
    # its segment within r_g of the centre's (at each parameter t), so the centre's segment passes within
    # rad + r_g; their members marked in this eye's row of the mask
    words = mask.shape[1]
    for wd in range(words):
        mask[j, wd] = 0
    for gi in range(grp_rad.shape[0]):
        pc = grp_centre[gi]
        v = e - pc
        t = wp.clamp(wp.dot(c - pc, v) / wp.max(wp.dot(v, v), 1.0e-20), 0.0, 1.0)
        reach_g = rad + grp_rad[gi]
        if wp.length_sq(pc + t * v - c) <= reach_g * reach_g:
            for m in range(grp_start[gi], grp_start[gi + 1]):
                r = grp_member[m]
                mask[j, r >> 5] = mask[j, r >> 5] | (1 << (r & 31))
    # the marked points in their own order (the sum's order is the points')
    acc = float(0.0)
    for wd in range(words):
        bits = mask[j, wd]
        if bits != 0:
            for b in range(32):
                if (bits & (1 << b)) != 0:
                    r = wd * 32 + b
                    w = g[j, r]
                    if w > 0.0:
                        p = pts[r]
                        v = e - p
                        # the cone first (no division): a segment that passes within the radius of the centre
                        # points into p's cone and reaches the sphere along its axis
                        near = reach[r] < 0.0
                        if not near:
                            s = wp.dot(v, axis[r])
                            if s >= reach[r]:
                                near = s * s >= wp.length_sq(v) * cos2[r]
                        if near:
                            t = wp.clamp(wp.dot(c - p, v) / wp.max(wp.dot(v, v), 1.0e-20), 0.0, 1.0)
                            if wp.length_sq(p + t * v - c) <= rad2:  # the segment passes the box's bounding sphere
                                if segment_meets_box(p, e, lo, hi):
                                    acc += w
    out[j] = acc


def point_groups(points: np.ndarray, size: int = GROUP_POINTS) -> list[np.ndarray]:
    """The points' indices in groups of at most `size` near each other: the leaves of a kd-tree split at the
    median of the widest axis."""
    out: list[np.ndarray] = []
    stack = [np.arange(len(points))]
    while stack:
        idx = stack.pop()
        if len(idx) <= size:
            if len(idx):
                out.append(idx)
            continue
        ax = int(np.argmax(np.ptp(points[idx], axis=0)))
        o = idx[np.argsort(points[idx, ax], kind="stable")]
        stack += [o[len(o) // 2:], o[:len(o) // 2]]
    return out


class BlockedTransfer:
    """Per-source blocked transfer for a box; receiver points (R,3) m, source eyes (S,3) m and the
    transfers g (S,R) (luminance, any unit) are uploaded once."""

    def __init__(self, points: np.ndarray, eyes: np.ndarray, g: np.ndarray, device: str | None = None):
        self.device = runtime.device(device)
        d = self.device
        self.pts = wp.array(np.asarray(points, np.float32), dtype=wp.vec3, device=d)
        self.eyes = wp.array(np.asarray(eyes, np.float32), dtype=wp.vec3, device=d)
        self.g = wp.array(np.ascontiguousarray(g, np.float32), dtype=wp.float32, device=d)
        self.out = wp.zeros(len(eyes), dtype=wp.float32, device=d)
        n = max(len(self.pts), 1)  # the cone prefilter's per-point values, written each call
        self.axis = wp.zeros(n, dtype=wp.vec3, device=d)
        self.reach = wp.zeros(n, dtype=wp.float32, device=d)
        self.cos2 = wp.zeros(n, dtype=wp.float32, device=d)
        # the points' groups (point_groups): centres, radii (widened by the margin), members; each eye's mask
        pts64 = np.asarray(points, np.float64).reshape(-1, 3)
        groups = point_groups(pts64)
        centre = np.array([pts64[i].mean(0) for i in groups]).reshape(-1, 3)
        rad = np.array([np.linalg.norm(pts64[i] - centre[k], axis=1).max() for k, i in enumerate(groups)])
        self.grp_centre = wp.array(centre.astype(np.float32), dtype=wp.vec3, device=d)
        self.grp_rad = wp.array((rad * (1 + CONE_MARGIN_REL) + CONE_MARGIN_M).astype(np.float32), dtype=wp.float32,
                                device=d)
        self.grp_start = wp.array(np.cumsum([0] + [len(i) for i in groups]).astype(np.int32), dtype=wp.int32, device=d)
        self.grp_member = wp.array(np.concatenate(groups + [np.zeros(0, np.int64)]).astype(np.int32), dtype=wp.int32,
                                   device=d)
        self.mask = wp.zeros((max(len(eyes), 1), max(-(-len(pts64) // 32), 1)), dtype=wp.int32, device=d)
        self.cpu = wp.get_device(d).is_cpu
        # the result's host copy, allocated once (a GPU array's .numpy() would allocate every call)
        self.host = self.out if self.cpu else wp.zeros(len(eyes), dtype=wp.float32, device="cpu", pinned=True)

    def __call__(self, box_min: np.ndarray, box_max: np.ndarray, split=None) -> np.ndarray:
        """(S,) float64 transfer from each source to the receivers whose segment meets the box.
        split(launch(lo, hi), n): cuts the sources into ranges, one launch each (the caller's
        two-core split, app.runtime.split); default one launch."""
        if len(self.out) == 0:
            return np.zeros(0)
        lo, hi = wp.vec3(*map(float, box_min)), wp.vec3(*map(float, box_max))

        if len(self.pts):
            wp.launch(_cone_kernel, dim=len(self.pts), inputs=[self.pts, lo, hi],
                      outputs=[self.axis, self.reach, self.cos2], device=self.device)

        def launch(a: int, b: int) -> None:
            wp.launch(_blocked_kernel, dim=b - a, inputs=[a, self.pts, self.eyes, self.g, lo, hi, self.axis,
                                                          self.reach, self.cos2, self.grp_centre, self.grp_rad,
                                                          self.grp_start, self.grp_member, self.mask],
                      outputs=[self.out], device=self.device)

        runtime.launch_split(launch, len(self.out), split)
        if not self.cpu:
            wp.copy(self.host, self.out)
            wp.synchronize_device(self.device)
        return self.host.numpy().astype(np.float64)
