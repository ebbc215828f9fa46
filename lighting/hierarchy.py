"""Patch hierarchies for the shaft structure: receiver octree and source KD-tree (seed sec. 6.2).

Both trees store their patches in depth-first order, so every node owns a contiguous range
[lo, hi) of `order` (the patch ids in that order) and, for the octree, a contiguous range of
leaves. Boxes are axis-aligned bounds of the node's patch corners, metres.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Tree:
    """A patch hierarchy in flat arrays (N nodes); node 0 is the root."""

    order: np.ndarray  # (M,) patch ids in depth-first order
    lo: np.ndarray  # (N,) first position in `order`
    hi: np.ndarray  # (N,) one past the last position
    box_min: np.ndarray  # (N,3)
    box_max: np.ndarray  # (N,3)
    children: list[list[int]]  # child node ids (empty for leaves)
    leaf_lo: np.ndarray  # (N,) first leaf (leaves numbered in depth-first order)
    leaf_hi: np.ndarray  # (N,)

    @property
    def n_nodes(self) -> int:
        return len(self.lo)

    @property
    def is_leaf(self) -> np.ndarray:
        return np.array([not c for c in self.children])

    @property
    def size(self) -> np.ndarray:
        """Box diagonal (N,) m."""
        return np.linalg.norm(self.box_max - self.box_min, axis=1)

    def leaf_of_position(self) -> np.ndarray:
        """Leaf index (M,) of each position of `order`."""
        out = np.empty(len(self.order), np.int64)
        leaves = np.flatnonzero(self.is_leaf)
        for k, n in enumerate(leaves[np.argsort(self.leaf_lo[leaves])]):
            out[self.lo[n]:self.hi[n]] = k
        return out


def _build(ids: np.ndarray, centres: np.ndarray, pmin: np.ndarray, pmax: np.ndarray, split) -> Tree:
    order: list[int] = []
    lo, hi, bmin, bmax, children, leaf_lo, leaf_hi = [], [], [], [], [], [], []
    n_leaves = [0]

    def node(members: np.ndarray) -> int:
        k = len(lo)
        lo.append(len(order))
        hi.append(0)
        bmin.append(pmin[members].min(0))
        bmax.append(pmax[members].max(0))
        children.append([])
        leaf_lo.append(n_leaves[0])
        leaf_hi.append(0)
        parts = split(members)
        if parts is None:
            order.extend(members.tolist())
            n_leaves[0] += 1
        else:
            for part in parts:
                children[k].append(node(part))
        hi[k] = len(order)
        leaf_hi[k] = n_leaves[0]
        return k

    node(np.asarray(ids))
    return Tree(np.array(order, np.int64), np.array(lo), np.array(hi), np.array(bmin), np.array(bmax), children,
                np.array(leaf_lo), np.array(leaf_hi))


def receiver_octree(ids: np.ndarray, centres: np.ndarray, corners: np.ndarray, leaf_size: int = 8) -> Tree:
    """Top-down octree over patches `ids` (split at the box centre until <= leaf_size patches).

    centres (P,3), corners (P,4,3) of all patches; ids selects the receivers."""
    pmin, pmax = corners.min(1), corners.max(1)

    def split(m: np.ndarray):
        if len(m) <= leaf_size:
            return None
        c = centres[m]
        mid = 0.5 * (c.min(0) + c.max(0))
        code = ((c > mid) * [1, 2, 4]).sum(1)
        parts = [m[code == k] for k in range(8) if np.any(code == k)]
        return parts if len(parts) > 1 else None  # coincident centres: stop

    return _build(ids, centres, pmin, pmax, split)


def source_kdtree(ids: np.ndarray, centres: np.ndarray, corners: np.ndarray, align: int = 1) -> Tree:
    """Binary KD-tree over source patches `ids`, split at the median of the longest axis down to
    single patches (the deep hierarchy sec. 6.4 needs for fine control of the pass count).

    align: a node of at least 2 * align patches splits at the multiple of `align` nearest its
    median, so every such node starts (and, unless it ends the order, ends) at a multiple of
    `align` in `order`: the blocks of a prefix table over that order (ShadowSources.weights)."""
    pmin, pmax = corners.min(1), corners.max(1)

    def split(m: np.ndarray):
        if len(m) <= 1:
            return None
        c = centres[m]
        ax = int(np.argmax(c.max(0) - c.min(0)))
        o = np.argsort(c[:, ax], kind="stable")
        h = len(m) // 2
        if align > 1 and len(m) >= 2 * align:
            h = min(max(int(round(h / align)) * align, align), len(m) // align * align)
        return [m[o[:h]], m[o[h:]]]

    return _build(ids, centres, pmin, pmax, split)
