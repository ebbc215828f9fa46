"""The shaft hierarchy's traversal with an object's box in one launch (lighting.shafts.ShaftHierarchy.traverse).

numpy tested the box level by level (17 levels on the shared rooms, ~9000 shafts tested per frame of the
~105 000): a gather of each level's active planes, two small matrix products and the children's index
arithmetic, 5-9 ms of glue per frame on window_room. Here one thread walks the levels in the same
breadth-first order (each level's shafts in the order numpy keeps them, their children appended in
order), so the leaf shafts come out in numpy's order. The test is numpy's (lighting.shafts.box_outside):
the box is outside a shaft when it lies outside the union box, or outside one of its planes by more than
1e-9 (n.c - |n|.h > d + 1e-9, c and h the box's centre and half size). numpy's matrix products may round
those dot products differently (they differ by ~1e-15 on window_room's shafts), so a box whose distance to
a plane lies within ~1e-15 of the 1e-9 tolerance could be judged otherwise: the tolerance itself is
arbitrary at that scale, and the byte-identity tests of the frames at rest hold.

One thread: the traversal is a chain of dependent levels, and a level holds at most a few thousand active
shafts; on CUDA a launch per level with a compaction would suit better (this kernel is valid there, slow).
"""
from __future__ import annotations

import numpy as np
import warp as wp

wp.set_module_options({"fuse_fp": False})

LEAF, WEAK = 1, 2  # flags: a leaf shaft; one stopped by the transfer threshold (lighting.shafts)


@wp.kernel
def _traverse_kernel(normals: wp.array2d(dtype=wp.vec3d), offsets: wp.array2d(dtype=wp.float64),
                     umin: wp.array(dtype=wp.vec3d), umax: wp.array(dtype=wp.vec3d), flags: wp.array(dtype=wp.int32),
                     child_lo: wp.array(dtype=wp.int32), child_hi: wp.array(dtype=wp.int32),
                     bmin: wp.vec3d, bmax: wp.vec3d, c: wp.vec3d, h: wp.vec3d, keep_weak: int,
                     cur: wp.array(dtype=wp.int32), nxt: wp.array(dtype=wp.int32), out: wp.array(dtype=wp.int32),
                     count: wp.array(dtype=wp.int32)):
    tol = wp.float64(1.0e-9)
    n_cur = int(1)
    cur[0] = 0
    n_out = int(0)
    parity = int(0)  # 0: the level's shafts are in cur, 1: in nxt
    while n_cur > 0:
        n_nxt = int(0)
        for i in range(n_cur):
            s = int(0)
            if parity == 0:
                s = cur[i]
            else:
                s = nxt[i]
            lo = umin[s]
            hi = umax[s]
            outside = int(0)
            for a in range(3):
                if bmax[a] < lo[a] or bmin[a] > hi[a]:
                    outside = 1
            if outside == 0:
                for k in range(12):
                    nv = normals[s, k]
                    nc = nv[0] * c[0] + nv[1] * c[1] + nv[2] * c[2]
                    nh = wp.abs(nv[0]) * h[0] + wp.abs(nv[1]) * h[1] + wp.abs(nv[2]) * h[2]
                    if nc - nh > offsets[s, k] + tol:
                        outside = 1
            if outside == 0:
                f = flags[s]
                if (f & 1) != 0:
                    if keep_weak != 0 or (f & 2) == 0:
                        out[n_out] = s
                        n_out += 1
                else:
                    for ch in range(child_lo[s], child_hi[s]):
                        if parity == 0:
                            nxt[n_nxt] = ch
                        else:
                            cur[n_nxt] = ch
                        n_nxt += 1
        n_cur = n_nxt
        parity = 1 - parity
    count[0] = n_out


class ShaftTraversal:
    """A ShaftHierarchy's levels flattened (global shaft ids: level by level) on `device`, uploaded once, and
    the traversal's scratch buffers (capacity: every shaft)."""

    def __init__(self, levels, device: str):
        self.device = device
        self.cpu = wp.get_device(device).is_cpu
        start = np.cumsum([0] + [len(lv.src) for lv in levels])
        N = int(start[-1])
        self.src = np.concatenate([lv.src for lv in levels]).astype(np.int64)
        self.recv = np.concatenate([lv.recv for lv in levels]).astype(np.int64)
        flags = np.concatenate([lv.leaf.astype(np.int32) * LEAF + lv.weak.astype(np.int32) * WEAK for lv in levels])
        nxt = np.append(start[1:], start[-1])  # each level's children lie in the next level
        lo = np.concatenate([lv.child_lo + nxt[i] for i, lv in enumerate(levels)])
        hi = np.concatenate([lv.child_hi + nxt[i] for i, lv in enumerate(levels)])
        d = device
        self.normals = wp.array(np.concatenate([lv.normals for lv in levels]).astype(np.float64), dtype=wp.vec3d, device=d)
        self.offsets = wp.array(np.concatenate([lv.offsets for lv in levels]).astype(np.float64), dtype=wp.float64,
                                device=d)
        self.umin = wp.array(np.concatenate([lv.umin for lv in levels]).astype(np.float64), dtype=wp.vec3d, device=d)
        self.umax = wp.array(np.concatenate([lv.umax for lv in levels]).astype(np.float64), dtype=wp.vec3d, device=d)
        self.flags = wp.array(flags, dtype=wp.int32, device=d)
        self.child_lo = wp.array(lo.astype(np.int32), dtype=wp.int32, device=d)
        self.child_hi = wp.array(hi.astype(np.int32), dtype=wp.int32, device=d)
        self.cur = wp.zeros(max(N, 1), dtype=wp.int32, device=d)
        self.nxt = wp.zeros(max(N, 1), dtype=wp.int32, device=d)
        self.out = wp.zeros(max(N, 1), dtype=wp.int32, device=d)
        self.count = wp.zeros(1, dtype=wp.int32, device=d)
        self.n = N

    def __call__(self, box_min: np.ndarray, box_max: np.ndarray, keep_weak: bool = True
                 ) -> tuple[np.ndarray, np.ndarray]:
        """(source node ids, receiver node ids) of the leaf shafts the box meets, numpy's order (new arrays)."""
        if self.n == 0:
            return np.zeros(0, np.int64), np.zeros(0, np.int64)
        box_min, box_max = np.asarray(box_min, np.float64), np.asarray(box_max, np.float64)
        c, h = 0.5 * (box_min + box_max), 0.5 * (box_max - box_min)  # as lighting.shafts.box_outside
        v = [wp.vec3d(*map(float, x)) for x in (box_min, box_max, c, h)]
        wp.launch(_traverse_kernel, dim=1, inputs=[self.normals, self.offsets, self.umin, self.umax, self.flags,
                                                    self.child_lo, self.child_hi, *v, int(keep_weak), self.cur,
                                                    self.nxt, self.out, self.count], device=self.device)
        n = int(self.count.numpy()[0])
        hit = self.out.numpy()[:n] if self.cpu else self.out[:n].numpy()
        return self.src[hit], self.recv[hit]
