"""A cluster frame's shadow-pass weights in one launch (lighting.frame_sources.ShadowSources.weights).

A pass that stands for a cluster of sources (a KD node's marked members) weighs each receiver by the
transfers G * B summed over those members: whole blocks of `block` KD positions as a difference of two
rows of the per-scene prefix table, the few positions at either end of a run as raw columns (G * B in
float64). numpy did this as an (n, rows, 3) table, a float64 (columns, rows, 3) temporary of the raw
columns and two transposed copies into the frame's (rows, n, 3) layout: 25-30 ms of glue per drag frame
on window_room (1177 receiver vertices + 3273 patch centres, 64 passes). Here one thread per (run of
receiver rows, pass) writes its weights in place.

The sums are exactly numpy's (lighting.frame_sources.weights_reference, the specification; the frames
at rest that take clustered passes stay byte-identical): a node of one whole-block run takes the
float32 difference of its two prefix rows, otherwise the float64 sum of the runs' differences in run
order; the raw columns' float64 products are summed in numpy's column order and added to the float32
weight in float64 before rounding; negatives (rounded prefixes where the exact sum is 0) are clamped to
0. Floating-point contraction is off in this module (fuse_fp): a fused multiply-add would round
differently from numpy's product then sum.
"""
from __future__ import annotations

import numpy as np
import warp as wp

from kernels.buffers import Buffer

wp.set_module_options({"fuse_fp": False})

_INDEX = ("tab_lo", "tab_hi", "row_a", "row_b", "raw_lo", "raw_hi", "raw_pos")  # ClusterWeights' plan arrays


# receiver rows per thread: a thread sums one node over a run of rows, reading its two prefix rows and its
# raw columns' G rows as contiguous runs (a thread per row over every node reads 2n rows of the prefix table at
# once, more streams than the CPU prefetches: 9 ms against numpy's 15 on window_room; per (row, node) the
# thread's setup cost more than its sums)
ROWS_PER_THREAD = 128


@wp.kernel
def _weights_kernel(prefix: wp.array2d(dtype=wp.vec3), gt: wp.array2d(dtype=wp.float32),
                    b: wp.array(dtype=wp.vec3d), tab_lo: wp.array(dtype=wp.int32), tab_hi: wp.array(dtype=wp.int32),
                    row_a: wp.array(dtype=wp.int32), row_b: wp.array(dtype=wp.int32),
                    raw_lo: wp.array(dtype=wp.int32), raw_hi: wp.array(dtype=wp.int32),
                    raw_pos: wp.array(dtype=wp.int32), one_run: int, n: int, first: int, vr: int, rows: int,
                    out_v: wp.array2d(dtype=wp.vec3), out_c: wp.array2d(dtype=wp.vec3)):
    tid = first + wp.tid()
    chunk = tid // n
    k = tid - chunk * n
    r0 = chunk * ROWS_PER_THREAD
    r1 = wp.min(r0 + ROWS_PER_THREAD, rows)
    t0 = tab_lo[k]
    t1 = tab_hi[k]
    c0 = raw_lo[k]
    c1 = raw_hi[k]
    for r in range(r0, r1):
        w = wp.vec3(0.0)
        if t1 > t0:
            if one_run != 0:
                w = prefix[row_b[t0], r] - prefix[row_a[t0], r]
            else:
                acc = wp.vec3d(wp.float64(0.0), wp.float64(0.0), wp.float64(0.0))
                for t in range(t0, t1):
                    pb = prefix[row_b[t], r]
                    pa = prefix[row_a[t], r]
                    acc = acc + (wp.vec3d(wp.float64(pb[0]), wp.float64(pb[1]), wp.float64(pb[2]))
                                 - wp.vec3d(wp.float64(pa[0]), wp.float64(pa[1]), wp.float64(pa[2])))
                w = wp.vec3(wp.float32(acc[0]), wp.float32(acc[1]), wp.float32(acc[2]))
        if c1 > c0:
            acc = wp.vec3d(wp.float64(0.0), wp.float64(0.0), wp.float64(0.0))
            for c in range(c0, c1):
                p = raw_pos[c]
                acc = acc + b[p] * wp.float64(gt[p, r])
            w = wp.vec3(wp.float32(wp.float64(w[0]) + acc[0]), wp.float32(wp.float64(w[1]) + acc[1]),
                        wp.float32(wp.float64(w[2]) + acc[2]))
        w = wp.vec3(wp.max(w[0], 0.0), wp.max(w[1], 0.0), wp.max(w[2], 0.0))
        if r < vr:
            out_v[r, k] = w
        else:
            out_c[r - vr, k] = w


class ClusterWeights:
    """The per-scene tables of the cluster weights on `device`, uploaded once: prefix (blocks, rows, 3)
    float32 (ShadowSources.prefix: receiver-vertex rows, then patch-centre rows), gt (S, rows) float32 the
    transfers G of each KD position's source (its column of G_v, then of G_c), b (S, 3) float64 its
    radiance B. On the CPU the prefix table is read where it lies (no copy)."""

    def __init__(self, prefix: np.ndarray, gt: np.ndarray, b: np.ndarray, n_recv_vert: int, device: str):
        self.device = device
        self.cpu = wp.get_device(device).is_cpu
        self.rows = prefix.shape[1]
        self.vr = int(n_recv_vert)
        self.prefix = wp.array(np.ascontiguousarray(prefix, np.float32), dtype=wp.vec3, device=device,
                               copy=not self.cpu)
        self.gt = wp.array(np.ascontiguousarray(gt, np.float32), dtype=wp.float32, device=device)
        self.b = wp.array(np.ascontiguousarray(b, np.float64), dtype=wp.vec3d, device=device)
        # the plan's index arrays, at capacity (a frame allocates nothing): a node, a run and a raw column each
        # hold a KD position of their own, so none outnumbers the sources
        cap = max(gt.shape[0], 1) + 1
        self.index = {nm: Buffer(cap, wp.int32, device) for nm in _INDEX}
        self._out: dict[int, tuple[wp.array, wp.array]] = {}  # CUDA: the outputs per pass count

    def __call__(self, tab_lo: np.ndarray, tab_hi: np.ndarray, row_a: np.ndarray, row_b: np.ndarray,
                 raw_lo: np.ndarray, raw_hi: np.ndarray, raw_pos: np.ndarray, one_run: bool, split=None
                 ) -> tuple[np.ndarray, np.ndarray]:
        """(W_v (Vr,n,3), W_c (P,n,3)) float32, new arrays, of n = len(tab_lo) nodes: node k's whole-block
        runs are the prefix-row pairs (row_a, row_b)[tab_lo[k]:tab_hi[k]] (one_run: each node has at most
        one), its raw columns the KD positions raw_pos[raw_lo[k]:raw_hi[k]], in summation order. split(launch(lo,
        hi), m): cuts the (run of rows, node) threads into ranges (app.runtime.split); default one launch."""
        from kernels.runtime import launch_split

        n, dev = len(tab_lo), self.device
        vr, P = self.vr, self.rows - self.vr
        W_v = np.empty((vr, n, 3), np.float32)
        W_c = np.empty((P, n, 3), np.float32)
        if n == 0:
            return W_v, W_c
        ins = [self.index[nm].dev for nm in _INDEX]
        for nm, a in zip(_INDEX, (tab_lo, tab_hi, row_a, row_b, raw_lo, raw_hi, raw_pos)):
            self.index[nm].upload(np.asarray(a, np.int32))
        if self.cpu:
            out_v = wp.array(W_v, dtype=wp.vec3, device=dev, copy=False)
            out_c = wp.array(W_c, dtype=wp.vec3, device=dev, copy=False)
        else:  # device outputs of exactly (rows, n), kept per n
            if n not in self._out:
                self._out[n] = (wp.zeros((vr, n), dtype=wp.vec3, device=dev), wp.zeros((P, n), dtype=wp.vec3, device=dev))
            out_v, out_c = self._out[n]

        def launch(a: int, b: int) -> None:
            wp.launch(_weights_kernel, dim=b - a, inputs=[self.prefix, self.gt, self.b, *ins, int(one_run), n, a, vr,
                                                           self.rows],
                      outputs=[out_v, out_c], device=dev)

        launch_split(launch, -(-self.rows // ROWS_PER_THREAD) * n, split)
        if not self.cpu:
            W_v[...] = out_v.numpy()
            W_c[...] = out_c.numpy()
        return W_v, W_c
