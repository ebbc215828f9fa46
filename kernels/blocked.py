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


@wp.kernel
def _blocked_kernel(first: int, pts: wp.array(dtype=wp.vec3), eyes: wp.array(dtype=wp.vec3),
                    g: wp.array2d(dtype=wp.float32), lo: wp.vec3, hi: wp.vec3, out: wp.array(dtype=wp.float32)):
    j = first + wp.tid()
    e = eyes[j]
    c = 0.5 * (lo + hi)
    rad2 = wp.length_sq(hi - c)
    acc = float(0.0)
    for r in range(pts.shape[0]):
        w = g[j, r]
        if w > 0.0:
            p = pts[r]
            v = e - p
            t = wp.clamp(wp.dot(c - p, v) / wp.max(wp.dot(v, v), 1.0e-20), 0.0, 1.0)
            if wp.length_sq(p + t * v - c) <= rad2:  # the segment passes the box's bounding sphere
                if segment_meets_box(p, e, lo, hi):
                    acc += w
    out[j] = acc


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

        def launch(a: int, b: int) -> None:
            wp.launch(_blocked_kernel, dim=b - a, inputs=[a, self.pts, self.eyes, self.g, lo, hi],
                      outputs=[self.out], device=self.device)

        runtime.launch_split(launch, len(self.out), split)
        if not self.cpu:
            wp.copy(self.host, self.out)
            wp.synchronize_device(self.device)
        return self.host.numpy().astype(np.float64)
