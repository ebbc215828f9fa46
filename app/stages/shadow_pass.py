"""The shadow pass: shadow maps of the object proxy and the occlusion masks they give, summed on
listed pixels and patch centres (seed sec. 6.3.3; DESIGN "Per-frame masks on Warp CPU").

Per frame, of the receiver pixels on patches that some pass's shaft can shadow (cand):
- exact: every pixel within `near_factor` bounding radii of the object, and farther out a lattice
  of every second pixel in x and y (plus the pixels no lattice pixel of their own quad
  neighbours), where shadows are soft and vary slowly: sum_j W_xj M_xj over the passes;
- filled: the other ones, the mean of the exact values in their 3x3 window on the same quad
  (ShadowPass.fill, kernels.maskfill, given the values compose derives from the sums).
Pixels the object covers completely are skipped. The patch centres of those patches get their
sums too (second order).

Everything per scene is set up once (ShadowPass's constructor): the points (receiver pixels and
patch centres) are uploaded once and a frame uploads the indices of its listed ones, the proxy
is the object's own per-shape BVH, and the per-batch transfers and candidate flags go into
buffers of the batch's capacity. Launches are split over the cores by app.runtime.
"""
from __future__ import annotations

import sys
from dataclasses import dataclass

import numpy as np
import warp as wp
from tqdm import tqdm

from app import runtime
from kernels.buffers import Buffer
from kernels.composite import MaskedSum
from kernels.maskfill import WindowFill
from kernels.shadowmap import ShadowMaps
from kernels.visibility import Occluder
from recon.patches import PatchMesh


@dataclass
class Masks:
    """One frame's masked sums: pixels pix_sel (exact) and their sums O_pix (n,3); fill_sel
    the pixels compose fills from them (ShadowPass.fill); patch centres cen_sel and O_cen (m,3).
    Sums are irradiance/pi (HDR transfers) or levels (LDR intensity transfers)."""

    pix_sel: np.ndarray
    fill_sel: np.ndarray
    cen_sel: np.ndarray
    O_pix: np.ndarray
    O_cen: np.ndarray


# Map size of frames whose maps stand for clusters of sources (a pass budget): 128 scores as
# well as 256 there; a map per source (the all-sources frame at rest) keeps EngineParams.map_res,
# whose hard lamp shadows lose at 128 (bench/bench_shadow_pass.py measures both).
CLUSTER_MAP_RES = 128
TILE = 8  # pixels: side of the image blocks whose points share a list of maps that may shadow them


class ShadowPass:
    """The shadow-pass stage of one scene (see the module docstring)."""

    def __init__(self, pix_pos: np.ndarray, pix_rows: np.ndarray, pix_bary: np.ndarray, pix_patch: np.ndarray,
                 recv_pix: np.ndarray, patches: PatchMesh, n_recv_vert: int, width: int, height: int,
                 batch: int, map_res: int, device: str, quiet: bool = True, near_factor: float = 1.5,
                 cluster_map_res: int | None = None):
        """pix_*: per pixel (H*W) surface point (m), receiver-vertex rows and barycentrics, patch
        (-1 none); recv_pix (H*W,) bool the receiver pixels; n_recv_vert: rows of the pixel
        transfers W_v; batch: maps per batch; map_res: map size of a frame with one map per
        source (the all-sources frame), cluster_map_res (at most map_res; default
        CLUSTER_MAP_RES) that of a frame whose maps stand for clusters of sources; near_factor: exact pixels within this many bounding
        radii of the object."""
        self.device, self.quiet, self.batch = device, quiet, batch
        self.near_factor = near_factor
        self.width, self.height = W, H = width, height
        P = patches.n_patches
        self.n_recv_vert = n_recv_vert
        self.pix_quad = np.where(pix_patch >= 0, patches.quad[np.maximum(pix_patch, 0)], -1).astype(np.int32)
        yy, xx = np.mgrid[0:H, 0:W]
        self.lattice = ((yy % 2 == 0) & (xx % 2 == 0)).reshape(-1) & recv_pix
        cover = np.zeros(H * W, bool)
        for dy, dx, ok_src, ok_dst in window_pairs(H, W):
            cover[ok_dst] |= self.lattice[ok_src] & (self.pix_quad[ok_src] == self.pix_quad[ok_dst])
        self.lattice_cover = cover  # pixels with a lattice pixel of their own quad in their 3x3 window
        # points of the masked sums: the receiver pixels, then every patch centre (lifted 1 mm)
        self.recv = np.flatnonzero(recv_pix).astype(np.int64)
        R = len(self.recv)
        self.n_pix_points = R
        rows = np.concatenate([np.maximum(pix_rows[self.recv], 0), n_recv_vert + np.repeat(np.arange(P)[:, None], 3, 1)])
        bary = np.concatenate([pix_bary[self.recv], np.tile([1.0, 0.0, 0.0], (P, 1))])
        pos = np.concatenate([pix_pos[self.recv], patches.centre + patches.normal * 1e-3])
        group = np.concatenate([pix_patch[self.recv], np.arange(P)])
        # culling cells: the pixels of a patch in one TILE x TILE block (a centre is a cell of its own)
        ty, tx = np.divmod(self.recv, W)
        tile = np.concatenate([(ty // TILE) * (W // TILE + 1) + tx // TILE, np.full(P, -1)])
        self.sums = MaskedSum(pos, rows, bary, group, device, n_groups=P, max_maps=batch, tile=tile)
        # exact on every frame they are wanted (lattice, or no lattice neighbour): in scan order (the
        # masked sums take them cell by cell);
        # the rest (filled unless near the object): sorted by patch, with each patch's range
        static = (self.lattice | ~self.lattice_cover)[self.recv]
        self.lat_pt = np.flatnonzero(static)
        self.lat_patch = pix_patch[self.recv[self.lat_pt]]
        rest = np.flatnonzero(~static)
        rest = rest[np.argsort(pix_patch[self.recv[rest]], kind="stable")]
        self.rest_pt = rest
        self.rest_patch = pix_patch[self.recv[rest]]
        self.rest_pos = pix_pos[self.recv[rest]].astype(np.float64)
        self.rest_start = np.searchsorted(self.rest_patch, np.arange(P + 1))
        self.patch_centre, self.patch_radius = patches.centre, patches.radius
        self.emitter = patches.is_emitter
        self.maps_full = ShadowMaps(batch, map_res, device=device)
        res = min(cluster_map_res or CLUSTER_MAP_RES, map_res)
        self.maps_cluster = self.maps_full if res == map_res else ShadowMaps(batch, res, device=device)
        self.maps = self.maps_full  # the last frame's
        self.weights = Buffer((n_recv_vert + P, batch), wp.vec3, device)  # pixel rows, then centre rows
        self.cand = Buffer((P, batch), wp.uint8, device)
        self._fill = WindowFill(W, H, self.pix_quad, device)
        self._covered = np.zeros(H * W, bool)  # scratch: pixels the object covers, this frame

    # ------------------------------------------------------------------ per frame
    def run(self, proxy: tuple[np.ndarray, np.ndarray, Occluder | None], centre: np.ndarray, radius: float,
            coverage: np.ndarray, cand: np.ndarray, eyes: np.ndarray, W_pix: np.ndarray, W_c: np.ndarray,
            per_source: bool = True, spread: np.ndarray | None = None, full_maps: bool = False):
        """The frame's masks, as a generator: yields the sources done after each batch of maps
        (Engine.refine may pause there) and returns the Masks.

        proxy: (vertices (V,3) m, triangles (F,3), its BVH or None); centre/radius: the object's
        bounding sphere (m); coverage (H,W) share of each pixel the object covers; cand (P,S)
        bool receiver patch x pass; eyes (S,3) m; W_pix (Vr,S,3) pixel-row transfers (radiance,
        or LDR intensity), W_c (P,S,3) patch-centre transfers; per_source: one map per source
        (maps of map_res), else maps of clusters (cluster_map_res); spread (S,2,3) m: each
        cluster's half-axes across its view (FrameSources.spread), whose penumbra a cluster map's lookup filters by
        (kernels.composite.penumbra; ignored with per_source, whose maps keep the hard lookup);
        full_maps: cluster maps of map_res too (Engine.refine's frames at rest)."""
        pix_pt, fill_pt, cen = self._select(centre, radius, coverage, cand)
        R = self.n_pix_points
        self.sums.select(np.concatenate([pix_pt, R + cen]))
        self.maps = self.maps_full if per_source or full_maps else self.maps_cluster
        self.maps.set_proxy(proxy[0], proxy[1], proxy[2])
        n_src, dev = len(eyes), self.device
        for first in tqdm(range(0, n_src, self.batch), desc="shadow passes", unit="batch", leave=False,
                          disable=self.quiet or n_src <= 4 * self.batch or not sys.stderr.isatty()):
            ax = None if per_source or spread is None else spread[first:first + self.batch]
            n = self.maps.prepare(eyes[first:first + self.batch],
                                  None if ax is None else np.linalg.norm(ax, axis=2).max(1), ax)
            runtime.split(self.maps.raster, n, dev, min_items=1)
            self._upload_batch(cand, W_pix, W_c, first, n, cen)
            self.sums.prepare(self.maps, n, 0, self.cand.dev,
                              split=lambda launch, m: runtime.split(launch, m, dev, min_items=1024))
            # both cores, cut where the (point, map) pairs are halved: the cells near the object list most maps
            runtime.run([lambda a=a, b=b: self.sums.accumulate(self.maps, 0, self.weights.dev, a, b)
                         for a, b in self.sums.balanced(runtime.parts(dev, self.sums.n, min_items=2048))])
            yield first + n  # sources done: refine() may stop here and resume on its next call
        acc, _ = self.sums.result()
        n_pix = len(pix_pt)
        return Masks(self.recv[pix_pt], self.recv[fill_pt], cen, acc[:n_pix], acc[n_pix:])

    def fill(self, known: np.ndarray, values: np.ndarray, missing: np.ndarray) -> np.ndarray:
        """Values (len(missing),3) at pixels `missing`: mean of the `known` pixels' values in
        their 3x3 window that lie on the same quad (every pixel a frame fills has one, see
        lattice_cover). A view of a reused buffer, valid until the next call."""
        return self._fill.fill(known, values, missing,
                               split=lambda launch, n: runtime.split(launch, n, self.device, min_items=8192))

    def _select(self, centre: np.ndarray, radius: float, coverage: np.ndarray, cand: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(exact pixel points, filled pixel points, patch centres) of the frame; points index
        the receiver pixels (self.recv)."""
        ok = cand.any(1) if cand.shape[1] else np.zeros(len(cand), bool)
        lat = self.lat_pt[ok[self.lat_patch]]
        rest = ok[self.rest_patch]
        # near the object: the rest pixels of patches within reach, tested one by one
        reach = self.near_factor * radius
        near_patch = np.flatnonzero(ok & (np.linalg.norm(self.patch_centre - centre, axis=1)
                                          < reach + self.patch_radius + 1e-3))
        lo, hi = self.rest_start[near_patch], self.rest_start[near_patch + 1]
        span = np.repeat(lo - np.concatenate([[0], np.cumsum(hi - lo)[:-1]]), hi - lo) + np.arange((hi - lo).sum())
        close = span[np.linalg.norm(self.rest_pos[span] - centre, axis=1) < reach]
        rest[close] = False
        pix_pt = np.concatenate([lat, self.rest_pt[close]])
        fill_pt = self.rest_pt[rest]
        covered = np.flatnonzero(coverage.reshape(-1) >= 1.0)
        if len(covered):  # pixels the object hides completely: no shadow to show
            self._covered[covered] = True
            pix_pt = pix_pt[~self._covered[self.recv[pix_pt]]]
            fill_pt = fill_pt[~self._covered[self.recv[fill_pt]]]
            self._covered[covered] = False
        cen = np.flatnonzero(ok & ~self.emitter)
        return pix_pt, fill_pt, cen

    def _upload_batch(self, cand: np.ndarray, W_pix: np.ndarray, W_c: np.ndarray, first: int, n: int,
                      cen: np.ndarray) -> None:
        """Sources first..first+n-1's transfers and candidate flags into the batch buffers. Of the
        patch-centre rows only those of the frame's centres `cen` that are candidates of some source
        of the batch: the masked sums read no other (a centre's list holds its candidates only)."""
        Vr = self.n_recv_vert
        w = self.weights.host
        w[:Vr, :n] = W_pix[:, first:first + n]
        c = cen[cand[cen, first:first + n].any(1)]
        w[Vr + c, :n] = W_c[c, first:first + n]
        self.weights.push()
        self.cand.host[:, :n] = cand[:, first:first + n]
        self.cand.push()


def window_pairs(H: int, W: int):
    """(dy, dx, src, dst) flat pixel index pairs for every offset of a 3x3 window (cached)."""
    key = (H, W)
    if key not in _WINDOW_CACHE:
        yy, xx = np.mgrid[0:H, 0:W]
        pairs = []
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                sy, sx = yy + dy, xx + dx
                ok = (sy >= 0) & (sy < H) & (sx >= 0) & (sx < W)
                pairs.append((dy, dx, (sy * W + sx)[ok], (yy * W + xx)[ok]))
        _WINDOW_CACHE[key] = pairs
    return _WINDOW_CACHE[key]


_WINDOW_CACHE: dict = {}
