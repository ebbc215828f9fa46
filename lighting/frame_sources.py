"""Per-frame source list and representative source set under a pass budget (seed sec. 6.2.1, 6.4).

`ShadowSources` is built once per scene from the source set, the transfers and the radiance
mesh: a source KD-tree, a receiver octree over the non-emitting patches, the shaft hierarchy
between them, and a block prefix table of the transfers G * B over the KD order (the KD splits
fall on its blocks). Per frame, `select(box_min, box_max, passes)`:
1. traverses the shafts with the object's box: the sources of the leaf shafts met (each counted
   once: the frame tag of the seed is a boolean mark here) and, per leaf shaft, its receivers;
2. marks the KD-tree nodes holding those sources (the tag pushed up to the root) and picks
   `passes` nodes by repeatedly splitting the marked node with the largest key (a heap), sec. 6.4.
   The seed's key is the mean transfer to the receivers; here, given the receiver vertices, it is
   the transfer to the receiver vertices whose segment to the source meets the object's box (the
   light the object can block this frame, kernels/blocked.py), each vertex weighted by its pixel
   footprint (the light the camera sees blocked). Without a budget every marked
   source is its own pass;
3. gives each chosen node a shadow-map eye at the key-weighted centroid of its marked members
   (the seed: the centre of the most contributing member; the centroid cuts the 50-pass rmse by
   a third or more on the benchmark rooms), and weights that sum the transfers of its marked members (the cluster
   keeps their energy): a difference of two prefix rows per run of whole blocks, raw columns at
   the ends;
4. gives the (receiver patch, pass) pairs that can be shadowed: only those pixels are touched.
"""
from __future__ import annotations

import heapq
from dataclasses import dataclass

import numpy as np

from kernels.blocked import BlockedTransfer
from kernels.runtime import launch_split
from lighting.hierarchy import receiver_octree, source_kdtree
from lighting.shafts import ShaftHierarchy
from recon.response import luminance

BOX_GRID_M = 1e-3  # the object's box is grown outward to this grid before selection (select)
# near_factor's floor on a node's distance to the object's box (m): it only keeps the factor finite for
# nodes touching the box (ten steps of BOX_GRID_M). A floor of a patch's size (0.25 m) instead ranks nodes
# touching the box with those a patch away, and leaves the unseen sun_101's 64-pass drag frame at energy
# 1.15 (0.01-0.05 m: 1.05)
NEAR_FLOOR_M = 0.01
# near_factor's cap on size / distance: the factor stands for a cluster's error against its key, which
# cannot exceed the key itself; a node 10 times as large as its distance spans most of the object's
# view (half-angle atan(5) = 79 degrees), its shadow wrong throughout, and a closer one is not more wrong.
# Uncapped, the nodes touching the box (up to 1 + size / NEAR_FLOOR_M) take the passes the window's clusters
# need (window_room's 64-pass drag frame: rmse_affected 1.38 uncapped, 0.93 capped at 10, 0.88 at 3; sun_101
# energy 1.05 at 10 and uncapped, 1.10 at 3)
NEAR_MAX_RATIO = 10.0
# memory allowed to the per-scene table of single-source transfers (ShadowSources.keep_single_transfers);
# a room whose table is larger makes each list's transfers per frame instead (kept for the next one)
SINGLE_TABLE_MAX_BYTES = 1 << 30


@dataclass
class FrameSources:
    """One frame's shadow passes: eyes (n,3) m; W_v (Vr,n,3) receiver-vertex and W_c (P,n,3)
    patch-centre transfers (irradiance/pi per pass); cand (P,n) bool receiver pairs; the number
    of sources in the source list."""

    eyes: np.ndarray
    W_v: np.ndarray
    W_c: np.ndarray
    cand: np.ndarray
    n_listed: int
    n_receivers: int
    spread: np.ndarray | None = None  # (n,2,3) m: each pass's cluster's half-axes across its view (0: one source)


class ShadowSources:
    def __init__(self, src: np.ndarray, centres: np.ndarray, normals: np.ndarray, corners: np.ndarray,
                 receivers: np.ndarray, G_c: np.ndarray, G_v: np.ndarray, B: np.ndarray,
                 leaf_size: int = 8, threshold: float = 0.02, keep_weak: bool = True, block: int = 4,
                 recv_points: np.ndarray | None = None, device: str | None = None,
                 recv_weights: np.ndarray | None = None):
        """src (S,) source patch ids; receivers (R,) receiver patch ids; G_c (P,P), G_v (Vr,P)
        transfers; B (P,3) source radiance; centres/normals (P,3), corners (P,4,3) m. block: source
        positions per column of the cluster-weight prefix table (its memory is 1/block of one
        float32 (Vr+P, S, 3) table; a cluster's weight costs up to 2 (block-1) raw columns more).
        recv_points (Vr,3) m: the receiver vertices of the G_v rows; with them the representatives
        split, and place their eyes, by the light the object's box can block (blocked_key); without
        them by each source's mean transfer (strength). recv_weights (Vr,): each receiver vertex's
        weight in that key (the engine: its pixel footprint, so the key counts the blocked light the
        camera sees; default 1). device: where that kernel runs."""
        self.P = len(centres)
        self.keep_weak = keep_weak
        self.G_v, self.G_c, self.B = G_v, G_c, B
        self.empty = len(src) == 0 or len(receivers) == 0  # nothing lights anything: no passes ever
        if self.empty:
            return
        self.block = max(int(block), 1)
        self.src_tree = source_kdtree(np.asarray(src), centres, corners, self.block)
        self.recv_tree = receiver_octree(np.asarray(receivers), centres, corners, leaf_size)
        self.src_ids = self.src_tree.order  # source patch id at each KD position
        self.eye_pos = centres + normals * 1e-3
        ro, so = self.recv_tree.order, self.src_ids
        lum_B = luminance(B[so])
        T = np.asarray(G_c[np.ix_(ro, so)], np.float64) * lum_B[None, :]
        prefix = np.zeros((len(ro), len(so) + 1), np.float32)
        prefix[:, 1:] = np.cumsum(T, axis=1)
        self.shafts = ShaftHierarchy(self.src_tree, self.recv_tree, prefix, prefix[:, -1].astype(np.float64),
                                     threshold)
        # a source's average transfer to the receiver vertices (the heap's key, summed per node)
        self.strength = (np.asarray(G_v[:, so], np.float64) * lum_B[None, :]).mean(0) if len(so) else np.zeros(0)
        self.leaf_of_recv = np.full(self.P, -1, np.int64)
        self.leaf_of_recv[ro] = self.recv_tree.leaf_of_position()
        self.n_recv_leaves = int(self.recv_tree.leaf_hi[0]) if len(ro) else 0
        self.prefix = self._weight_prefix()
        self.blocked = None
        if recv_points is not None:
            self.use_receivers(recv_points, device, recv_weights)

    def use_receivers(self, recv_points: np.ndarray, device: str | None = None,
                      recv_weights: np.ndarray | None = None) -> None:
        """Split and place the representatives by the light the object's box can block (see
        __init__'s recv_points/recv_weights). Kept apart from the construction because it holds
        device buffers: the rest is a per-scene artefact cached on disk (app.stages.precompute)."""
        if self.empty:
            return
        lum_B = luminance(self.B[self.src_ids])
        self.blocked = self._blocked_transfer(np.asarray(recv_points, np.float64), lum_B, device, recv_weights)
        self._cluster_device, self._cluster_made = device, False  # the cluster weights' kernel: see `cluster`
        self._block_shares = None  # blocked_key's per-scene shares, made on its first call
        self.shafts.use_device(device if device is not None else "cpu")

    @property
    def cluster(self):
        """The cluster weights' kernel and its tables (_cluster_weights), or None (weights then runs
        weights_reference; None too before use_receivers). Made on first use, by `weights` on the first frame
        whose passes are clusters (a drag frame, a frame of a pass budget, Engine.refine's finer frame before
        the exact one), not by use_receivers: its G table is a copy of G (57 MB, 0.3 s on window_room) that an
        engine whose frames are all one pass per source (the all-sources frame) never reads."""
        if not self.__dict__.get("_cluster_made", True):
            self._cluster, self._cluster_made = self._cluster_weights(self._cluster_device), True
        return self.__dict__.get("_cluster")

    @cluster.setter
    def cluster(self, cw) -> None:
        self._cluster, self._cluster_made = cw, True

    def _cluster_weights(self, device: str | None, max_bytes: int = SINGLE_TABLE_MAX_BYTES):
        """The cluster weights' kernel and its tables (kernels.cluster_weights: the prefix table, G per KD
        position as rows (S, Vr + P) float32, B per KD position), or None (weights then runs
        weights_reference) where that G table would take more than max_bytes. Made after the device buffers
        (`cluster`: on first use), not in the per-scene artefact."""
        from kernels.cluster_weights import ClusterWeights
        from kernels.runtime import device as resolve

        so = self.src_ids
        if len(so) * (self.G_v.shape[0] + self.P) * 4 > max_bytes:
            return None
        gt = np.empty((len(so), self.G_v.shape[0] + self.P), np.float32)
        gt[:, :self.G_v.shape[0]] = np.asarray(self.G_v[:, so], np.float32).T
        gt[:, self.G_v.shape[0]:] = np.asarray(self.G_c[:, so], np.float32).T
        return ClusterWeights(self.prefix, gt, np.asarray(self.B[so], np.float64), self.G_v.shape[0],
                              resolve(device))

    def _blocked_transfer(self, points: np.ndarray, lum_B: np.ndarray, device: str | None,
                          recv_weights: np.ndarray | None = None) -> BlockedTransfer:
        """The kernel's inputs per block of `block` KD positions (a block is one source to it: its
        eye the strength-weighted centroid of its members', its transfer theirs summed), transfers
        to each receiver vertex scaled by recv_weights."""
        so, k = self.src_ids, self.block
        starts = np.arange(0, len(so), k)
        w = self.strength
        wsum = np.add.reduceat(w, starts)
        e = self.eye_pos[so]
        eye = np.where((wsum > 0)[:, None], np.add.reduceat(w[:, None] * e, starts) / np.where(wsum > 0, wsum, 1)[:, None],
                       np.add.reduceat(e, starts) / np.diff(np.append(starts, len(so)))[:, None])
        g = np.add.reduceat(np.asarray(self.G_v[:, so], np.float64) * lum_B[None, :], starts, axis=1)
        if recv_weights is not None:
            g *= np.asarray(recv_weights, np.float64)[:, None]
        return BlockedTransfer(points, eye, g.T, device)

    def blocked_key(self, box_min: np.ndarray, box_max: np.ndarray, split=None) -> np.ndarray:
        """(S,) per KD position: the luminance transfer to the receiver vertices whose segment to the
        source's block meets the box (BlockedTransfer; split: its launches cut into ranges), shared
        among the block's members by strength (evenly where their strength is 0)."""
        b = self.blocked(box_min, box_max, split)
        shares = getattr(self, "_block_shares", None)
        if shares is None:  # per scene: each KD position's block and its share of it
            so, k = self.src_ids, self.block
            starts = np.arange(0, len(so), k)
            size = np.diff(np.append(starts, len(so)))
            wsum = np.add.reduceat(self.strength, starts)
            share = np.where(np.repeat(wsum, size) > 0, self.strength / np.repeat(np.where(wsum > 0, wsum, 1), size),
                             1.0 / np.repeat(size, size))
            shares = self._block_shares = (np.repeat(np.arange(len(starts)), size), share)
        return b[shares[0]] * shares[1]

    def _weight_prefix(self) -> np.ndarray:
        """(S // block + 1 (+1), Vr + P, 3) float32: row b holds, for every receiver vertex (G_v
        rows) then every patch centre (G_c rows), the transfer G * B summed over the sources at KD
        positions [0, b * block); a last row holds the sum over all S when S is not a multiple of
        block. Summed in float64: a difference of two rows is within 1.2e-7 of the receiver's
        total transfer of the exact sum."""
        k, so = self.block, self.src_ids
        S = len(so)
        bounds = np.append(np.arange(0, S + 1, k), [S] if S % k else []).astype(np.int64)
        rows = self.G_v.shape[0] + self.P
        out = np.zeros((len(bounds), rows, 3), np.float32)
        run = np.zeros((rows, 3))
        step = 128  # blocks per chunk (bounds the float64 temporaries)
        for b0 in range(0, len(bounds) - 1, step):
            b1 = min(len(bounds) - 1, b0 + step)
            cols = so[bounds[b0]:bounds[b1]]
            seg = bounds[b0:b1] - bounds[b0]  # block starts within the chunk
            Bc = np.asarray(self.B[cols], np.float64)
            for G, r0, r1 in ((self.G_v, 0, self.G_v.shape[0]), (self.G_c, self.G_v.shape[0], rows)):
                gb = np.asarray(G[:, cols], np.float64)[:, :, None] * Bc[None]
                cum = np.cumsum(np.add.reduceat(gb, seg, axis=1), axis=1) + run[r0:r1, None, :]
                out[b0 + 1:b1 + 1, r0:r1] = cum.transpose(1, 0, 2)
                run[r0:r1] = cum[:, -1]
        return out

    def keep_single_transfers(self, split=None, max_bytes: int = SINGLE_TABLE_MAX_BYTES) -> bool:
        """Make the per-scene table of single-source transfers: (Vr + P, S, 3) float32, column j
        G[:, src_ids[j]] * B[src_ids[j]] (receiver-vertex rows, then patch-centre rows), in KD order,
        read-only. An all-sources frame then reads its transfers from it: the table itself when its
        list holds every source, else a ColumnView of the listed columns (no per-frame copy). Not
        made (False) when it would take more than max_bytes: then each list's transfers are made
        per frame (_single_transfers, the last list's kept). split: as _column_transfers's."""
        self.single = None
        if self.empty:
            return False
        S, rows = len(self.src_ids), self.G_v.shape[0] + self.P
        if rows * S * 3 * 4 > max_bytes:
            return False
        B = self.B[self.src_ids].astype(np.float32)
        table = np.empty((rows, S, 3), np.float32)
        Vr = self.G_v.shape[0]
        _column_transfers(self.G_v, self.src_ids, B, split=split, out=table[:Vr])
        _column_transfers(self.G_c, self.src_ids, B, split=split, out=table[Vr:])
        table.flags.writeable = False
        self.single = table
        self._single = None
        return True

    def _single_transfers(self, ids: np.ndarray, split=None, pos: np.ndarray | None = None):
        """(W_v (Vr,n,3), W_c (P,n,3)) float32 of one pass per source `ids` (at KD positions `pos`),
        read-only: from the per-scene table when there is one (keep_single_transfers: the table's
        rows when every source is listed, else ColumnViews of its listed columns). Without the
        table they are made here and the last list's are kept: the all-sources frames of poses
        whose box meets the same sources (every frame of Engine.refine, a room whose shafts all meet
        the object) reuse them."""
        table = getattr(self, "single", None)
        if table is not None:
            Vr = self.G_v.shape[0]
            if pos is None:  # the KD positions of the ids
                order = np.argsort(self.src_ids)
                pos = order[np.searchsorted(self.src_ids, ids, sorter=order)]
            if len(pos) == table.shape[1]:
                return table[:Vr], table[Vr:]
            return ColumnView(table, 0, Vr, pos), ColumnView(table, Vr, table.shape[0], pos)
        last = getattr(self, "_single", None)
        if last is not None and np.array_equal(last[0], ids):
            return last[1], last[2]
        self._single = None  # the old arrays go before the new ones are made
        B = self.B[ids].astype(np.float32)
        W_v = _column_transfers(self.G_v, ids, B, split=split)
        W_c = _column_transfers(self.G_c, ids, B, split=split)
        W_v.flags.writeable = W_c.flags.writeable = False
        self._single = (ids.copy(), W_v, W_c)
        return W_v, W_c

    def stats(self) -> dict:
        if self.empty:
            return {"shafts": 0, "leaf_shafts": 0, "shaft_mb": 0.0, "source_nodes": 0, "receiver_nodes": 0,
                    "weight_table_mb": 0.0, "single_table_mb": 0.0}
        single = getattr(self, "single", None)
        return {"shafts": self.shafts.n_shafts, "leaf_shafts": self.shafts.n_leaf_shafts,
                "shaft_mb": self.shafts.nbytes / 2 ** 20, "source_nodes": self.src_tree.n_nodes,
                "receiver_nodes": self.recv_tree.n_nodes, "weight_table_mb": self.prefix.nbytes / 2 ** 20,
                "single_table_mb": 0.0 if single is None else single.nbytes / 2 ** 20}

    def weights(self, lo: np.ndarray, hi: np.ndarray, marked: np.ndarray, split=None) -> tuple[np.ndarray, np.ndarray]:
        """weights_reference's (W_v (Vr,n,3), W_c (P,n,3)), the same bytes: its plan (which prefix rows and
        raw columns each node sums, _weight_plan) made here, the sums written in the frame's layout by one
        launch (kernels.cluster_weights: `cluster`, made on the first call; without it weights_reference). split:
        the launch cut over the cores (app.runtime.split)."""
        cw = self.cluster
        if cw is None:
            return self.weights_reference(lo, hi, marked)
        return cw(*self._weight_plan(lo, hi, marked), split=split)

    def _segments(self, lo: np.ndarray, hi: np.ndarray, marked: np.ndarray) -> tuple:
        """(node, a, b, A, Bk, row) of the nodes [lo, hi): each marked run's segment [a, b) within its node
        (sorted by node), the segment's whole-block bounds [A, Bk) (multiples of the block; the last source
        S has its own prefix row) and row(x), the prefix row of a block bound x."""
        k = self.block
        edge = np.diff(np.concatenate([[0], marked.astype(np.int8), [0]]))
        rs, re = np.flatnonzero(edge == 1), np.flatnonzero(edge == -1)  # marked runs [rs, re)
        i0 = np.searchsorted(re, lo, side="right")
        count = np.searchsorted(rs, hi, side="left") - i0
        node = np.repeat(np.arange(len(lo)), count)
        first = np.cumsum(count) - count
        run = np.arange(len(node)) - first[node] + i0[node]
        a, b = np.maximum(rs[run], lo[node]), np.minimum(re[run], hi[node])  # segments, sorted by node
        S, last = len(self.src_ids), len(self.prefix) - 1
        A, Bk = -(-a // k) * k, np.where(b == S, S, b // k * k)  # S has its own prefix row

        def row(x):
            return np.where(x == S, last, x // k)
        return node, a, b, A, Bk, row

    def _weight_plan(self, lo: np.ndarray, hi: np.ndarray, marked: np.ndarray) -> tuple:
        """(tab_lo, tab_hi, row_a, row_b, raw_lo, raw_hi, raw_pos, one_run) of weights_reference's sums:
        node k's whole-block runs are the prefix-row pairs (row_a, row_b)[tab_lo[k]:tab_hi[k]] (one_run: no
        node has two, so each is one float32 difference), its raw columns the KD positions
        raw_pos[raw_lo[k]:raw_hi[k]] in weights_reference's order (every segment's left end, then every
        segment's right end)."""
        n = len(lo)
        node, a, b, A, Bk, row = self._segments(lo, hi, marked)
        tab = np.flatnonzero(A < Bk)  # segments holding whole blocks (sorted by node)
        t_node = node[tab]
        one_run = bool(np.all(np.diff(t_node) > 0))
        nodes = np.arange(n)
        tab_lo, tab_hi = np.searchsorted(t_node, nodes), np.searchsorted(t_node, nodes, side="right")
        col_node, pos = _raw_columns(node, a, b, A, Bk)
        raw_lo, raw_hi = np.searchsorted(col_node, nodes), np.searchsorted(col_node, nodes, side="right")
        return tab_lo, tab_hi, row(A[tab]), row(Bk[tab]), raw_lo, raw_hi, pos, one_run

    def weights_reference(self, lo: np.ndarray, hi: np.ndarray, marked: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(W_v (Vr,n,3), W_c (P,n,3)) float32: per node [lo, hi) of KD positions (sorted, disjoint,
        each holding a marked source), the transfers G * B summed over its marked sources. Each
        node's marked runs are split into whole blocks (a difference of two prefix rows) and at most
        block-1 raw columns at either end. numpy; `weights` gives the same bytes (tests)."""
        Vr = self.G_v.shape[0]
        n = len(lo)
        node, a, b, A, Bk, row = self._segments(lo, hi, marked)
        W = np.zeros((n, Vr + self.P, 3), np.float32)
        tab = np.flatnonzero(A < Bk)  # segments holding whole blocks (sorted by node)
        if len(tab):
            t_node = node[tab]
            if len(np.unique(t_node)) == len(t_node):  # one block run per node (a whole marked node)
                W[t_node] = self.prefix[row(Bk[tab])] - self.prefix[row(A[tab])]
            else:  # many runs: float64 sums
                starts = np.flatnonzero(np.diff(np.concatenate([[-1], t_node])))
                W[t_node[starts]] = np.add.reduceat(self.prefix[row(Bk[tab])].astype(np.float64)
                                                    - self.prefix[row(A[tab])], starts, axis=0)
        col_node, pos = _raw_columns(node, a, b, A, Bk)
        if len(pos):
            ids = self.src_ids[pos]
            Bc = np.asarray(self.B[ids], np.float64)
            starts = np.flatnonzero(np.diff(np.concatenate([[-1], col_node])))
            owners = col_node[starts]
            for G, rows in ((self.G_v, slice(0, Vr)), (self.G_c, slice(Vr, None))):  # float64 sums
                W[owners, rows] += np.add.reduceat(np.asarray(G[:, ids], np.float64).T[:, :, None] * Bc[:, None],
                                                   starts, axis=0)
        np.maximum(W, 0.0, out=W)  # a difference of rounded prefixes where the exact sum is 0
        return np.ascontiguousarray(W[:, :Vr].transpose(1, 0, 2)), np.ascontiguousarray(W[:, Vr:].transpose(1, 0, 2))

    def _pairs(self, l_lo: np.ndarray, l_hi: np.ndarray, k_lo: np.ndarray, k_hi: np.ndarray, n: int) -> np.ndarray:
        """cand (P, n) bool: patch p x pass k is True when some rectangle [l_lo, l_hi) x [k_lo, k_hi)
        of (receiver leaves, passes) holds (p's leaf, k). The rectangles' edges cut both axes into
        cells that are wholly in or out: their corners are counted (+1 / -1) on that coarse grid
        and summed up both axes (2-D prefix sums, int32), then each cell is spread back over its
        leaves and passes (a column gather, then one row gather per patch)."""
        L = self.n_recv_leaves
        rb, r_at = _cuts(L, l_lo, l_hi)  # row cuts (leaves)
        cb, c_at = _cuts(n, k_lo, k_hi)  # column cuts (passes)
        a0, a1 = r_at[l_lo], r_at[l_hi]
        b0, b1 = c_at[k_lo], c_at[k_hi]
        m = len(cb)
        size = len(rb) * m
        D = (np.bincount(np.concatenate([a0 * m + b0, a1 * m + b1]), minlength=size)
             - np.bincount(np.concatenate([a0 * m + b1, a1 * m + b0]), minlength=size)).astype(np.int32)
        D = D.reshape(len(rb), m)
        np.cumsum(D, axis=0, dtype=np.int32, out=D)
        np.cumsum(D, axis=1, dtype=np.int32, out=D)
        cells = D[:-1, :-1] > 0  # (row cells, column cells)
        per_pass = cells[:, np.searchsorted(cb, np.arange(n), side="right") - 1]  # (row cells, n)
        per_pass = np.concatenate([per_pass, np.zeros((1, n), bool)])  # last: patches in no leaf
        cell_of_leaf = np.searchsorted(rb, np.arange(L), side="right") - 1
        row = np.where(self.leaf_of_recv >= 0, cell_of_leaf[np.maximum(self.leaf_of_recv, 0)] if L else 0,
                       len(per_pass) - 1)
        return per_pass[row]

    # ------------------------------------------------------------------ per frame
    def traverse(self, box_min: np.ndarray, box_max: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(marked (S,) bool over KD positions, hit source nodes, hit receiver nodes)."""
        S = len(self.src_ids)
        s_nodes, r_nodes = self.shafts.traverse(box_min, box_max, self.keep_weak)
        t = self.src_tree
        diff = np.bincount(t.lo[s_nodes], minlength=S + 1) - np.bincount(t.hi[s_nodes], minlength=S + 1)
        marked = np.cumsum(diff[:-1]) > 0
        return marked, s_nodes, r_nodes

    def near_factor(self, box_min: np.ndarray, box_max: np.ndarray) -> np.ndarray:
        """(N,) per source-tree node: 1 + its box's diagonal over its distance to the object's box
        [box_min, box_max] (m), the distance at least NEAR_FLOOR_M, the ratio at most NEAR_MAX_RATIO.

        Why: a cluster's one map puts all of its members' light at its eye. A member at offset s from
        the eye casts the object's shadow shifted by about s x (receiver distance) / (distance to the
        object), so the cluster's error grows with its extent as seen from the object (size over
        distance); a cluster beside the object (the sunlit floor next to a chair) blocks, from its
        eye, light its far members send past the object (sun_room: energy 1.2-1.3 at 16-64 passes
        with the plain key). Scaling the key by this factor splits those clusters first."""
        t = self.src_tree
        if getattr(self, "_node_size", None) is None:  # per tree (not in the cached artefact of older runs)
            self._node_size = np.linalg.norm(t.box_max - t.box_min, axis=1)
        gap = np.maximum(0.0, np.maximum(t.box_min - box_max, box_min - t.box_max))
        return 1.0 + np.minimum(self._node_size / np.maximum(np.linalg.norm(gap, axis=1), NEAR_FLOOR_M),
                                NEAR_MAX_RATIO)

    def representatives(self, marked: np.ndarray, passes: int | None, key: np.ndarray | None = None,
                        node_factor: np.ndarray | None = None) -> list[int]:
        """KD nodes (sorted by position) covering every marked source, at most `passes` of them
        when the marked sources allow (sec. 6.4: split the node with the largest key summed over
        its marked members; key (S,) per KD position, default the mean transfer `strength`;
        node_factor (N,) per node: that sum scaled by it, e.g. near_factor)."""
        t = self.src_tree
        cm = np.concatenate([[0], np.cumsum(marked)])
        cs = np.concatenate([[0.0], np.cumsum(np.where(marked, self.strength if key is None else key, 0.0))])
        n_marked = int(cm[-1])
        if n_marked == 0:
            return []
        if passes is None or passes >= n_marked:
            leaf_node = np.empty(len(marked), np.int64)
            leaves = np.flatnonzero(t.is_leaf)
            leaf_node[t.lo[leaves]] = leaves  # the source tree's leaves hold one source each
            return leaf_node[np.flatnonzero(marked)].tolist()
        if passes < 1:
            raise ValueError("passes must be at least 1")

        def count(n):
            return cm[t.hi[n]] - cm[t.lo[n]]

        def prio(n):
            p = -(cs[t.hi[n]] - cs[t.lo[n]])
            return p if node_factor is None else p * node_factor[n]

        heap = [(prio(0), 0)]
        done: list[int] = []
        while heap and len(heap) + len(done) < passes:
            _, n = heapq.heappop(heap)
            kids = [c for c in t.children[n] if count(c) > 0]
            if not kids:
                done.append(n)
                continue
            for c in kids:
                heapq.heappush(heap, (prio(c), c))
        nodes = done + [n for _, n in heap]
        return sorted(nodes, key=lambda n: t.lo[n])

    def eyes(self, starts: np.ndarray, pos: np.ndarray, key: np.ndarray) -> np.ndarray:
        """(n,3) shadow-map eyes of the nodes whose marked members are pos[starts[k]:starts[k+1]]:
        the centroid of their eyes weighted by key (per KD position; the members' plain centroid
        where their keys sum to 0); a node of one member keeps that member's eye."""
        e = self.eye_pos[self.src_ids[pos]]
        w = key[pos]
        wsum = np.add.reduceat(w, starts)
        eyes = np.add.reduceat(w[:, None] * e, starts) / np.where(wsum > 0, wsum, 1.0)[:, None]
        flat = wsum <= 0
        if flat.any() and key is not self.strength:  # the mean transfer, then the plain centroid
            eyes[flat] = self.eyes(starts, pos, self.strength)[flat]
        elif flat.any():
            eyes[flat] = (np.add.reduceat(e, starts) / np.diff(np.append(starts, len(pos)))[:, None])[flat]
        one = np.diff(np.append(starts, len(pos))) == 1
        eyes[one] = e[starts[one]]
        return eyes

    def spread(self, starts: np.ndarray, pos: np.ndarray, key: np.ndarray, eyes: np.ndarray,
               target: np.ndarray) -> np.ndarray:
        """(n,2,3) m: each node's extent across its eye's view, the PCSS light size of its map
        (kernels.masked_sums.penumbra): the principal half-axes, each of the RMS distance along it,
        of the offsets perpendicular to the direction from the eye to `target` (the object) of its marked
        members (pos[starts[k]:starts[k+1]]) from the eye, weighted by key as the eye is (uniformly
        where the keys sum to 0). A node of one member has 0 (a point source)."""
        e = self.eye_pos[self.src_ids[pos]]
        cnt = np.diff(np.append(starts, len(pos)))
        node = np.repeat(np.arange(len(starts)), cnt)
        w = key[pos].astype(np.float64)
        flat = np.add.reduceat(w, starts) <= 0
        w = np.where(flat[node], 1.0, w)
        wsum = np.add.reduceat(w, starts)
        fwd = target - eyes
        fwd /= np.maximum(np.linalg.norm(fwd, axis=1, keepdims=True), 1e-12)
        d = e - eyes[node]
        d -= (d * fwd[node]).sum(1, keepdims=True) * fwd[node]
        C = np.add.reduceat(w[:, None, None] * d[:, :, None] * d[:, None, :], starts) / wsum[:, None, None]
        lam, vec = np.linalg.eigh(C)  # ascending; the smallest is ~0, along the view
        axes = np.sqrt(np.maximum(lam[:, None, [2, 1]], 0.0)) * vec[:, :, [2, 1]]  # (n,3,2) columns
        axes = axes.transpose(0, 2, 1)  # (n,2,3): the RMS half-axes, largest first
        axes[cnt == 1] = 0.0
        return axes

    def select(self, box_min: np.ndarray, box_max: np.ndarray, passes: int | None, split=None,
               near_split: bool = False) -> FrameSources:
        """The frame's shadow passes for an object inside the box (module docstring). split(launch(lo,
        hi), n): how kernel launches are cut over the cores (app.runtime.split; default one launch).
        near_split: split the clusters that are large as seen from the object first (near_factor; the
        drag frame's few passes); False keeps the plain key (the frames at rest)."""
        if passes is not None and passes < 1:
            raise ValueError("passes must be at least 1")
        Vr = self.G_v.shape[0]
        nodes = []
        # the box grown outward to a 1 mm grid: a pose that moves by less (float noise, the same pose
        # reached another way) selects the same passes; the shafts and the blocked-light key test
        # segments against the box, so a micro-metre change could otherwise flip a cluster split
        box_min = np.floor(np.asarray(box_min, np.float64) / BOX_GRID_M) * BOX_GRID_M
        box_max = np.ceil(np.asarray(box_max, np.float64) / BOX_GRID_M) * BOX_GRID_M
        if not self.empty:
            t = self.src_tree
            marked, s_nodes, r_nodes = self.traverse(box_min, box_max)
            key = self.strength
            if self.blocked is not None and passes is not None and passes < marked.sum():
                key = self.blocked_key(box_min, box_max, split)
            clustered = passes is not None and passes < marked.sum()
            nodes = self.representatives(marked, passes, key,
                                         self.near_factor(box_min, box_max) if near_split and clustered else None)
        n = len(nodes)
        if n == 0:
            return FrameSources(np.zeros((0, 3)), np.zeros((Vr, 0, 3)), np.zeros((self.P, 0, 3)),
                                np.zeros((self.P, 0), bool), 0, 0)
        lo, hi = t.lo[nodes], t.hi[nodes]
        pos = np.flatnonzero(marked)  # marked KD positions, in order: each node holds a run of them
        starts = np.searchsorted(pos, lo)
        ids = self.src_ids[pos]
        if n == len(pos):  # one source per pass (the all-sources frame): its own transfers
            W_v, W_c = self._single_transfers(ids, split, pos)
        else:
            W_v, W_c = self.weights(lo, hi, marked, split)
        eyes = self.eye_pos[ids] if n == len(pos) else self.eyes(starts, pos, key)
        spread = (np.zeros((n, 2, 3)) if n == len(pos) else
                  self.spread(starts, pos, key, eyes, 0.5 * (box_min + box_max)))
        # receiver pairs: leaf shafts (source node, receiver node) -> (receiver leaves, passes)
        k_lo = np.searchsorted(hi, t.lo[s_nodes], side="right")
        k_hi = np.searchsorted(lo, t.hi[s_nodes], side="left")
        r = self.recv_tree
        l_lo, l_hi = r.leaf_lo[r_nodes], r.leaf_hi[r_nodes]
        ok = k_hi > k_lo
        cand = self._pairs(l_lo[ok], l_hi[ok], k_lo[ok], k_hi[ok], n)
        return FrameSources(eyes, W_v, W_c, cand, int(marked.sum()), int(cand.any(1).sum()), spread)


class ColumnView:
    """Read-only (rows, n, 3) view of the rows [r0, r1) and the columns `pos` of a (R, S, 3)
    table, without copying it: indexing it as an array (rows, then a slice or index of its columns)
    gathers only what is asked for; any other use (np.asarray, arithmetic) makes the full array."""

    def __init__(self, table: np.ndarray, r0: int, r1: int, pos: np.ndarray):
        self.table, self.r0, self.r1, self.pos = table, int(r0), int(r1), np.asarray(pos, np.int64)
        self.shape = (self.r1 - self.r0, len(self.pos)) + table.shape[2:]
        self.dtype = table.dtype
        self.ndim = len(self.shape)

    def __len__(self) -> int:
        return self.shape[0]

    def __array__(self, dtype=None, copy=None):
        a = self.table[self.r0:self.r1, self.pos]
        return a if dtype is None else a.astype(dtype, copy=False)

    def __getitem__(self, key):
        key = key if isinstance(key, tuple) else (key,)
        if len(key) > 2 or any(k is Ellipsis or k is None for k in key):
            return np.asarray(self)[key]
        rows, cols = key + (slice(None),) * (2 - len(key))
        outer = isinstance(rows, slice) or isinstance(cols, slice)  # numpy: the index arrays are not paired
        cols = self.pos[cols]
        if isinstance(rows, slice):
            a, b, step = rows.indices(self.shape[0])
            if step > 0:
                return self.table[self.r0 + a:self.r0 + max(a, b):step, cols]
            rows = np.arange(self.r0, self.r1)[rows]
        else:
            rows = np.asarray(rows)
            if rows.dtype == bool:
                rows = np.flatnonzero(rows)
            if rows.ndim > 1:
                return np.asarray(self)[key]
            rows = self.r0 + np.where(rows < 0, rows + self.shape[0], rows)
        if outer and np.ndim(rows) == 1 and np.ndim(cols) == 1:
            return self.table[rows[:, None], cols[None, :]]
        return self.table[rows, cols]


def _column_transfers(G: np.ndarray, ids: np.ndarray, B: np.ndarray, rows: int = 256, split=None,
                      out: np.ndarray | None = None) -> np.ndarray:
    """(R, n, 3) float32 G[:, ids] * B (B (n,3) float32): the transfers of single sources, in slabs
    of `rows` rows (a slab's gathered columns stay in cache; the same products as one broadcast),
    into `out` when given. split(work(lo, hi), R): runs row ranges concurrently (app.runtime.split:
    one range per core; numpy's gather and product release the GIL); default one range."""
    if out is None:
        out = np.empty((G.shape[0], len(ids), 3), np.float32)

    def work(lo: int, hi: int) -> None:
        for r0 in range(lo, hi, rows):
            r1 = min(r0 + rows, hi)
            g = np.asarray(G[r0:r1].take(ids, axis=1), np.float32)
            np.multiply(g[:, :, None], B[None], out=out[r0:r1])

    launch_split(work, G.shape[0], split)
    return out


def _cuts(size: int, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(cuts, at): the distinct values of 0, size, lo and hi (integers in [0, size]), ascending (np.unique's), and
    at (size + 1,) each value's index in cuts (np.searchsorted's for the values present): by flags over [0, size]
    (ShadowSources._pairs; np.unique of sun_room's ~15k bounds took ~1.3 ms a frame, this ~0.1)."""
    mark = np.zeros(size + 1, bool)
    mark[0] = mark[size] = True
    mark[lo] = True
    mark[hi] = True
    return np.flatnonzero(mark), np.cumsum(mark) - 1


def _raw_columns(node: np.ndarray, a: np.ndarray, b: np.ndarray, A: np.ndarray, Bk: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """(col_node, pos): the raw columns of the segments [a, b) of `node` (FrameSources._segments) as KD positions
    pos, each with its node, sorted by node: [a, A) and [Bk, b) of a segment holding whole blocks (A <= Bk),
    [a, b) of the others; every segment's left end, then every segment's right end."""
    whole = A <= Bk
    r_lo = np.concatenate([a, np.where(whole, Bk, b)])
    r_hi = np.concatenate([np.where(whole, A, b), b])
    r_node = np.concatenate([node, node])
    o = np.argsort(r_node, kind="stable")
    r_lo, r_hi, r_node = r_lo[o], r_hi[o], r_node[o]
    length = r_hi - r_lo
    keep = length > 0
    r_lo, length, r_node = r_lo[keep], length[keep], r_node[keep]
    col_node = np.repeat(r_node, length)
    pos = np.arange(len(col_node)) - np.repeat(np.cumsum(length) - length, length) + np.repeat(r_lo, length)
    return col_node, pos
