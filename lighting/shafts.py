"""Shaft hierarchy linking the source KD-tree with the receiver octree (seed sec. 6.2, 6.2.1).

A shaft bounds every segment between a source node's box and a receiver node's box: the union
box of the two, cut by the planes of Haines & Wallace ("Shaft culling for efficient ray-traced
radiosity", 1994; Haines, "A shaft culling tool", JGT 2000): for each pair of axes and each of
the four corner directions in their plane, where one box juts out further on one axis and the
other box on the other axis, the plane through the two boxes' corner edges. An object box that
lies outside the union box or wholly outside one plane cannot block any segment of the shaft.

Construction starts from (source root, receiver root) and splits the larger node (box diagonal)
until both are leaves, or until the shaft's transfer to every receiver in it is below
`threshold` of that receiver's total (the seed's 2 % rule). Unlike the seed, a shaft stopped by
that rule is KEPT as a coarse leaf rather than dropped: its sources stay in the source list
whenever the object meets it. Dropping it loses the shadow of many individually weak sources
that together matter (measured in bench/bench_interactive.py), while keeping it costs only some
extra candidates. Receivers are patch centres (their transfers are G_c rows).

Traversal (per frame) tests the object's box level by level and returns the leaf shafts it
meets; their source ranges give the source list, their receiver ranges the receiver list.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lighting.hierarchy import Tree

_PAIRS = [(0, 1), (0, 2), (1, 2)]


def shaft_planes(amin: np.ndarray, amax: np.ndarray, bmin: np.ndarray, bmax: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Bounding planes of the shafts between boxes a and b, vectorised over N shafts.

    Boxes (N,3). Returns normals (N,12,3) and offsets (N,12): a point x is outside plane k when
    n_k . x > d_k. Unused planes have n = 0, d = 0 (nothing is outside them).
    """
    N = len(amin)
    normals = np.zeros((N, 12, 3))
    offsets = np.zeros((N, 12))
    k = 0
    for i, j in _PAIRS:
        for si in (0, 1):
            for sj in (0, 1):
                sgn_i, sgn_j = (1.0 if si else -1.0), (1.0 if sj else -1.0)
                ai = amax[:, i] if si else amin[:, i]
                aj = amax[:, j] if sj else amin[:, j]
                bi = bmax[:, i] if si else bmin[:, i]
                bj = bmax[:, j] if sj else bmin[:, j]
                da_i = sgn_i * (ai - bi)  # > 0: a juts out further on axis i in this direction
                da_j = sgn_j * (aj - bj)
                need = ((da_i > 0) & (da_j < 0)) | ((da_i < 0) & (da_j > 0))
                # line through (ai, aj) and (bi, bj); normal (dj, -di), oriented outwards
                ni, nj = (bj - aj), -(bi - ai)
                flip = ni * sgn_i + nj * sgn_j < 0
                ni, nj = np.where(flip, -ni, ni), np.where(flip, -nj, nj)
                normals[need, k, i] = ni[need]
                normals[need, k, j] = nj[need]
                offsets[need, k] = (ni * ai + nj * aj)[need]
                k += 1
    return normals, offsets


def box_outside(normals: np.ndarray, offsets: np.ndarray, umin: np.ndarray, umax: np.ndarray,
                box_min: np.ndarray, box_max: np.ndarray) -> np.ndarray:
    """(N,) True where the box (3,) lies wholly outside shaft n (union box (N,3) and planes)."""
    out = np.any((box_max < umin) | (box_min > umax), axis=1)
    c, h = 0.5 * (box_min + box_max), 0.5 * (box_max - box_min)
    lowest = normals @ c - np.abs(normals) @ h  # min of n.x over the box
    return out | np.any(lowest > offsets + 1e-9, axis=1)


@dataclass
class ShaftLevel:
    src: np.ndarray  # (n,) source node ids
    recv: np.ndarray  # (n,) receiver node ids
    umin: np.ndarray  # (n,3) union box
    umax: np.ndarray
    normals: np.ndarray  # (n,12,3)
    offsets: np.ndarray  # (n,12)
    leaf: np.ndarray  # (n,) bool: no children
    weak: np.ndarray  # (n,) bool: a leaf only because it carries < threshold of every receiver's light
    child_lo: np.ndarray  # (n,) children's range in the next level
    child_hi: np.ndarray


class ShaftHierarchy:
    """Shafts between a source tree and a receiver tree, built once per scene."""

    def __init__(self, sources: Tree, receivers: Tree, transfer_prefix: np.ndarray, total: np.ndarray,
                 threshold: float = 0.02):
        """transfer_prefix (R, S+1): per receiver (rows in receiver-tree order), cumulative
        luminance transfer over sources in source-tree order; total (R,) each receiver's total."""
        self.src_tree, self.recv_tree = sources, receivers
        self.threshold = threshold
        self.levels: list[ShaftLevel] = []
        s_leaf, r_leaf = sources.is_leaf, receivers.is_leaf
        s_size, r_size = sources.size, receivers.size
        tot = np.maximum(total, 1e-30)
        src = np.array([0])
        recv = np.array([0])
        while len(src):
            # the largest share of a receiver's light carried by each shaft
            r_lo, r_hi = receivers.lo[recv], receivers.hi[recv]
            counts = r_hi - r_lo
            rows = np.repeat(r_lo - np.cumsum(counts) + counts, counts) + np.arange(counts.sum())
            sh = np.repeat(np.arange(len(src)), counts)
            share = (transfer_prefix[rows, sources.hi[src][sh]] - transfer_prefix[rows, sources.lo[src][sh]]) / tot[rows]
            big = np.zeros(len(src))
            np.maximum.at(big, sh, share)
            both_leaves = s_leaf[src] & r_leaf[recv]
            leaf = both_leaves | (big < threshold)
            split_src = ~leaf & ~s_leaf[src] & (r_leaf[recv] | (s_size[src] >= r_size[recv]))
            n_child = np.where(leaf, 0, np.where(split_src, [len(sources.children[s]) for s in src],
                                                 [len(receivers.children[r]) for r in recv]))
            child_hi = np.cumsum(n_child)
            nm, nx = self._planes(src, recv)
            self.levels.append(ShaftLevel(src, recv, *nx, *nm, leaf, leaf & ~both_leaves, child_hi - n_child, child_hi))
            new_s, new_r = [], []
            for k in np.flatnonzero(~leaf):
                if split_src[k]:
                    for c in sources.children[src[k]]:
                        new_s.append(c)
                        new_r.append(recv[k])
                else:
                    for c in receivers.children[recv[k]]:
                        new_s.append(src[k])
                        new_r.append(c)
            src, recv = np.array(new_s, np.int64), np.array(new_r, np.int64)

    def _planes(self, src, recv):
        s, r = self.src_tree, self.recv_tree
        amin, amax, bmin, bmax = s.box_min[src], s.box_max[src], r.box_min[recv], r.box_max[recv]
        return shaft_planes(amin, amax, bmin, bmax), (np.minimum(amin, bmin), np.maximum(amax, bmax))

    @property
    def n_shafts(self) -> int:
        return sum(len(lv.src) for lv in self.levels)

    @property
    def n_leaf_shafts(self) -> int:
        return int(sum(lv.leaf.sum() for lv in self.levels))

    @property
    def nbytes(self) -> int:
        return sum(sum(a.nbytes for a in vars(lv).values()) for lv in self.levels)

    def use_device(self, device: str) -> None:
        """Traverse with one Warp launch on `device` from now on (kernels.shaft_traverse: the levels
        flattened and uploaded here; not part of the cached artefact)."""
        from kernels.shaft_traverse import ShaftTraversal

        self._kernel = ShaftTraversal(self.levels, device)

    def traverse(self, box_min: np.ndarray, box_max: np.ndarray, keep_weak: bool = True
                 ) -> tuple[np.ndarray, np.ndarray]:
        """Leaf shafts met by the object's box: (source node ids, receiver node ids), each (n,).
        keep_weak=False drops the shafts stopped by the threshold (the seed's rule). With use_device's
        kernel: the same shafts in the same order (traverse_reference, numpy)."""
        kernel = getattr(self, "_kernel", None)
        if kernel is not None:
            return kernel(box_min, box_max, keep_weak)
        return self.traverse_reference(box_min, box_max, keep_weak)

    def traverse_reference(self, box_min: np.ndarray, box_max: np.ndarray, keep_weak: bool = True
                           ) -> tuple[np.ndarray, np.ndarray]:
        """traverse in numpy, level by level (the specification of kernels.shaft_traverse)."""
        box_min, box_max = np.asarray(box_min, np.float64), np.asarray(box_max, np.float64)
        active = np.array([0])
        out_s, out_r = [], []
        for lv, nxt in zip(self.levels, self.levels[1:] + [None]):
            if len(active) == 0:
                break
            hit = active[~box_outside(lv.normals[active], lv.offsets[active], lv.umin[active], lv.umax[active],
                                      box_min, box_max)]
            lf = lv.leaf[hit]
            inner = hit[~lf]
            if not keep_weak:
                hit = hit[~lv.weak[hit]]
                lf = lv.leaf[hit]
            out_s.append(lv.src[hit[lf]])
            out_r.append(lv.recv[hit[lf]])
            counts = lv.child_hi[inner] - lv.child_lo[inner]
            active = (np.repeat(lv.child_lo[inner] - np.cumsum(counts) + counts, counts)
                      + np.arange(counts.sum())) if len(inner) else np.zeros(0, np.int64)
        return np.concatenate(out_s), np.concatenate(out_r)
