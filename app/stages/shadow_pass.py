"""The shadow pass: shadow maps of the object proxy and the occlusion masks they give, summed on
listed pixels and patch centres (seed sec. 6.3.3; DESIGN "Per-frame masks on Warp CPU").

Per frame, of the receiver pixels on patches that some pass's shaft can shadow (cand):
- exact: every pixel within `near_factor` bounding radii of the object, and farther out a lattice
  of every second pixel in x and y (plus the pixels no lattice pixel of their own quad
  neighbours), where shadows are soft and vary slowly: sum_j W_xj M_xj over the passes (the
  all-sources frame's weak passes, app.rest_maps, fill the off-lattice pixels beyond graded_near
  radii instead, ShadowPass.weak_ring, and beyond weak_far radii sum the spacing-4 lattice only and fill
  the spacing-2 one bilinearly, ShadowPass.weak_coarse);
- filled: the other ones, the mean of the exact values in their 3x3 window on the same quad
  (ShadowPass.fill, kernels.maskfill, given the values compose derives from the sums).
A cluster frame whose maps fit one batch (the drag's) instead sums on a graded lattice
(ShadowPass._run_graded): exact within the object's bounding sphere, and farther out the corners
of 8x8 lattice squares, refined to 4x4, 2x2 and single pixels only where the corners' shadow
fractions differ by more than REFINE_TOL; the rest is filled bilinearly from the corners.
Pixels the object covers completely are skipped. The patch centres of those patches get their
sums too (second order).

Everything per scene is set up once (ShadowPass's constructor): the points (receiver pixels and
patch centres) are uploaded once and a frame uploads the indices of its listed ones, the proxy
is the object's own per-shape BVH, and the per-batch transfers and candidate flags go into
buffers of the batch's capacity. A frame of several batches (run) draws the next batch's maps on a
side thread while the batch before is summed (two sets of maps; the transfers are uploaded on the
rendering thread, into one set of buffers); the all-sources frame's scattered columns are gathered by a kernel
(kernels.gather).
Launches are split over the cores by app.runtime.
"""
from __future__ import annotations

import functools
import sys
from dataclasses import dataclass

import numpy as np
import warp as wp
from tqdm import tqdm

from app import runtime
from kernels.buffers import Buffer
from kernels.gather import ColumnGather
from kernels.graded_refine import GradedRefine
from kernels.masked_sums import PCSS_TAPS, MaskedSum
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
# whose hard lamp shadows lose at 128 (bench/bench_shadow_pass.py measures both), except for the
# weak sources, which take this size too (app.rest_maps; run's order).
CLUSTER_MAP_RES = 128
# Graded lattice (ShadowPass._run_graded): a lattice square is filled from its corners where their
# shadow fractions (occluded share of the pixel's light: sum / scale) differ by at most this much;
# about the smallest luminance contrast the eye sees (Weber's fraction, 1-2 %).
REFINE_TOL = 0.02
# The fewest (point, map) pairs a concurrent range of a graded frame's sums gets (ShadowPass._sum): a pair costs
# 0.2-0.4 us on the 2-core CPU (a cluster map's PCSS lookup), so this is about a millisecond of work per range,
# ten times a thread's hand-off (~0.1 ms). A cut by point count (2048 points, 20-90 maps listed each near the
# object) left each spacing's launch of a drag frame on one core.
MIN_PART_PAIRS = 4096
TILE = 8  # pixels: side of the image blocks whose points share a list of maps that may shadow them
# the same for the frames with one map per source (the all-sources frame): their lookups are hard (one texel, no
# PCSS taps), so a point's test costs little beside a cell's per map (listing it, reading the map's frame and its
# first texels), and cells of 4 times the area list 1.6-1.9 times fewer (cell, map) entries for 1.13-1.16 times
# the (point, map) tests (bench_rest's runs / pairs, five rooms); 32 px lists longer than it saves
# (lamps_room: the sums' kernel time above 16 px's). The cluster frames keep TILE: their PCSS tests cost taps each
TILE_SOURCE = 16


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
        self._points = (pix_pos, pix_rows, pix_bary, pix_patch, patches)  # the masked sums' (_masked_sum)
        self.sums = self._masked_sum(TILE)
        self._sums_source: MaskedSum | None = None  # the same points in cells of TILE_SOURCE px (sums_source)
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
        # graded lattice (cluster frames, _run_graded): per receiver point, the corners of its lattice
        # square of spacing 2 (receiver points of its quad; -1 none, -2 weight zero), and
        # the receiver points sorted by patch (the near ones are found patch by patch)
        self.pt_patch = pix_patch[self.recv]
        self.recv_index = np.full(H * W, -1, np.int64)  # pixel -> receiver point (-1 none)
        self.recv_index[self.recv] = np.arange(R)
        self.corners = _lattice_corners(self.recv, self.pix_quad, W, H)
        # lattice squares of spacing 4 and 8 (one per quad they hold pixels of): each point's, and
        # their corners (receiver points of the square's quad; -1 none)
        self.pt_sq, self.sq_corners, self._sq_mark = {}, {}, {}
        for s in (4, 8):
            self.pt_sq[s], self.sq_corners[s] = _lattice_squares(self.recv, self.pix_quad, W, H, s)
            self._sq_mark[s] = np.zeros(len(self.sq_corners[s]), bool)
        self.pt_by_patch = np.argsort(self.pt_patch, kind="stable")
        self.pt_start = np.searchsorted(self.pt_patch[self.pt_by_patch], np.arange(P + 1))
        self.pt_pos = pix_pos[self.recv].astype(np.float64)
        self._allowed = np.zeros(R, bool)  # scratch: wanted points of the frame
        self._centres: wp.array | None = None  # _run_graded's W_c read in place by the sums (_centre_table)
        self._known = np.zeros(R, bool)  # scratch: points summed so far in the frame
        self._vals = np.zeros((R, 3))  # their sums
        self._frac = np.zeros((R, 3))  # and their shadow fractions (sum / scale: _run_graded's refine test)
        self.refine_tol = REFINE_TOL
        # graded frames: each spacing's refine test in one launch (kernels.graded_refine; False: the numpy of
        # _graded_finer, its reference, for A/B)
        self.refine_on_device = True
        self.graded = True  # False: every frame on the spacing-2 lattice (run's other branch), for A/B
        # exact within this many bounding radii (graded frames): inside the bounding sphere a receiver
        # may touch the object (contact shadows, no penumbra to interpolate); beyond it the lattice
        self.graded_near = 1.0
        # graded frames: the cluster maps whose passes are weak (app.rest_maps.RestMaps: share_j <= its budget, each
        # pass's largest share of a receiver's light) take the hard lookup of their cluster's eye, no PCSS penumbra
        # (the drag frame's: app.dragframe.DRAG_HARD_WEAK); None: every cluster map its penumbra
        self.weak_clusters = None
        # graded frames: the patch centres look every cluster map up with its eye's hard lookup, no PCSS penumbra
        # (MaskedSum.accumulate's hard_from; the drag frame's: app.dragframe.DRAG_HARD_CENTRES)
        self.hard_centres = False
        self.last_hard = 0  # the last graded frame's cluster maps so looked up
        self.maps_full = ShadowMaps(batch, map_res, device=device)
        res = min(cluster_map_res or CLUSTER_MAP_RES, map_res)
        self.maps_cluster = self.maps_full if res == map_res else ShadowMaps(batch, res, device=device)
        # a second set of each map size: a batch's maps are drawn into one while the masked sums of the
        # batch before read the other (run: the raster overlaps the sums; the same maps, the same sums)
        self._twin = {id(self.maps_full): ShadowMaps(batch, map_res, device=device)}
        if self.maps_cluster is not self.maps_full:
            self._twin[id(self.maps_cluster)] = ShadowMaps(batch, self.maps_cluster.res, device=device)
        self.set_taps(PCSS_TAPS)
        self.pipelined = wp.get_device(device).is_cpu  # False: each batch drawn, then summed (A/B; CUDA: async anyway)
        self.maps = self.maps_full  # the last frame's
        self.weights = Buffer((n_recv_vert + P, batch), wp.vec3, device)  # pixel rows, then centre rows
        self.cand = Buffer((P, batch), wp.uint8, device)
        self.weak_lattice = True  # run(order=): the weak passes fill the near ring's pixels (weak_ring; False: A/B)
        # run(order=) with weak_lattice: beyond this many bounding radii the weak passes are summed on the spacing-4
        # lattice only and filled bilinearly on the spacing-2 one (weak_coarse; 0: off, for A/B)
        self.weak_far = 2.0
        self.source_cells = True  # run(per_source): the masked sums in cells of TILE_SOURCE px (False: TILE, for A/B)
        # run's `order` (the all-sources frame): a batch's scattered columns gathered by a kernel on the CPU
        self._gather = ColumnGather(max(n_recv_vert, P), batch, device) if wp.get_device(device).is_cpu else None
        self._fill = WindowFill(W, H, self.pix_quad, device)
        self._covered = np.zeros(H * W, bool)  # scratch: pixels the object covers, this frame

    @functools.cached_property
    def _refine(self) -> GradedRefine:
        """The graded frames' refine launches (kernels.graded_refine), made on the first graded frame: its lattice
        tables on the device, a few MB at full resolution that the frames at rest never read."""
        return GradedRefine(self.pt_sq, self.sq_corners, self.corners, self._known, self._allowed, self._frac,
                            self.device)

    def set_taps(self, taps: int) -> None:
        """The PCSS taps per axis of every map set's cluster lookups from now on (ShadowMaps.taps; the
        frames at rest keep kernels.masked_sums.PCSS_TAPS, the drag frame app.dragframe.DRAG_PCSS_TAPS)."""
        if taps < 2:
            raise ValueError(f"a PCSS lookup takes at least 2 taps per axis, got {taps}")
        self.taps = int(taps)
        for m in {id(m): m for m in (self.maps_full, self.maps_cluster, *self._twin.values())}.values():
            m.taps = m.ms.taps = self.taps

    def _masked_sum(self, tile_px: int) -> MaskedSum:
        """The masked sums of the receiver pixels, then every patch centre (lifted 1 mm), in culling cells of the
        pixels of a patch in one tile_px x tile_px block (a centre is a cell of its own)."""
        pix_pos, pix_rows, pix_bary, pix_patch, patches = self._points
        P, W = patches.n_patches, self.width
        rows = np.concatenate([np.maximum(pix_rows[self.recv], 0),
                               self.n_recv_vert + np.repeat(np.arange(P)[:, None], 3, 1)])
        bary = np.concatenate([pix_bary[self.recv], np.tile([1.0, 0.0, 0.0], (P, 1))])
        pos = np.concatenate([pix_pos[self.recv], patches.centre + patches.normal * 1e-3])
        group = np.concatenate([pix_patch[self.recv], np.arange(P)])
        ty, tx = np.divmod(self.recv, W)
        tile = np.concatenate([(ty // tile_px) * (W // tile_px + 1) + tx // tile_px, np.full(P, -1)])
        return MaskedSum(pos, rows, bary, group, self.device, n_groups=P, max_maps=self.batch, tile=tile)

    @property
    def sums_source(self) -> MaskedSum:
        """`sums`'s points in culling cells of TILE_SOURCE px: the frames with a map per source (run's per_source
        with source_cells). Made on first use: the drag frame's shadow pass, whose frames have maps of clusters,
        never makes it (a second set of points and cells, a few MB)."""
        if self._sums_source is None:
            self._sums_source = self._masked_sum(TILE_SOURCE)
        return self._sums_source

    # ------------------------------------------------------------------ per frame
    def run(self, proxy: tuple[np.ndarray, np.ndarray, Occluder | None], centre: np.ndarray, radius: float,
            coverage: np.ndarray, cand: np.ndarray, eyes: np.ndarray, W_pix: np.ndarray, W_c: np.ndarray,
            per_source: bool = True, spread: np.ndarray | None = None, full_maps: bool = False,
            scale: np.ndarray | None = None, order: tuple[np.ndarray, int] | None = None):
        """The frame's masks, as a generator: yields the sources done after each batch of maps
        (Engine.refine may pause there) and returns the Masks.

        proxy: (vertices (V,3) m, triangles (F,3), its BVH or None); centre/radius: the object's
        bounding sphere (m); coverage (H,W) share of each pixel the object covers; cand (P,S)
        bool receiver patch x pass; eyes (S,3) m; W_pix (Vr,S,3) pixel-row transfers (radiance,
        or LDR intensity), W_c (P,S,3) patch-centre transfers; per_source: one map per source
        (maps of map_res), else maps of clusters (cluster_map_res); spread (S,2,3) m: each
        cluster's half-axes across its view (FrameSources.spread), whose penumbra a cluster map's lookup filters by
        (kernels.masked_sums.penumbra; ignored with per_source, whose maps keep the hard lookup);
        full_maps: cluster maps of map_res too (Engine.refine's frames at rest); scale (H*W,3):
        the sums of the pixels' unshadowed light (E_x, or levels in LDR), given: a cluster frame of
        one batch fills on the graded lattice (_run_graded); order: with per_source, (perm (S,), hard): the
        passes drawn in the order perm, its first `hard` on maps of map_res, the others on maps of
        cluster_map_res (the same hard lookup; in batches of their own; app.rest_maps); None: every pass
        in its order, map_res."""
        if self.graded and scale is not None and not per_source and 0 < len(eyes) <= self.batch:
            return (yield from self._run_graded(proxy, centre, radius, coverage, cand, eyes, W_pix, W_c,
                                                spread, full_maps, scale))
        self._fill.set_spacing(np.zeros(0, np.int64), 2)
        pix_pt, fill_pt, cen = self.select(centre, radius, coverage, cand)
        R = self.n_pix_points
        sums = self.sums_source if per_source and self.source_cells else self.sums  # TILE_SOURCE cells, or TILE
        primary = self.maps_full if per_source or full_maps else self.maps_cluster
        n_src, dev = len(eyes), self.device
        perm, hard = (None, n_src) if order is None or not per_source else (order[0], min(max(int(order[1]), 0), n_src))
        # the weak passes (order's last n_src - hard) skip the ring's own pixels (weak_ring); their sums start apart
        ring = self.weak_ring(pix_pt, centre, radius) if self.weak_lattice and hard < n_src else None
        # and, at weak_far radii and beyond, the spacing-2 lattice's pixels off the spacing-4 lattice (weak_coarse)
        coarse = self.weak_coarse(pix_pt, centre, radius, ring) if ring is not None and self.weak_far else None
        skip = ring if coarse is None else ring | coarse
        sel_all = np.concatenate([pix_pt, R + cen])
        sel_weak = sel_all if ring is None else np.concatenate([pix_pt[~skip], R + cen])
        sums.select(sel_all if hard > 0 else sel_weak)
        strong = None  # the sums of the passes before the weak ones, when these have their own selection
        if perm is not None:
            eyes = eyes[perm]
        # batches [first, end): the hard sources' on `primary`, then the others' on the cluster-size maps
        firsts = list(range(0, hard, self.batch)) + list(range(hard, n_src, self.batch))
        ends = [min(f + self.batch, hard if f < hard else n_src) for f in firsts]
        kinds = [primary if f < hard else self.maps_cluster for f in firsts]
        for base in dict.fromkeys(map(id, kinds)):
            m0 = primary if base == id(primary) else self.maps_cluster
            for m in (m0, self._twin[id(m0)])[:1 + (self.pipelined and len(firsts) > 1)]:
                m.set_proxy(proxy[0], proxy[1], proxy[2])

        def aim(k: int) -> tuple[ShadowMaps, int]:
            """Batch k's maps (set k % 2 of its size when pipelined), aimed; (maps, n)."""
            maps = (kinds[k], self._twin[id(kinds[k])])[k % 2] if self.pipelined else kinds[k]
            first, end = firsts[k], ends[k]
            ax = None if per_source or spread is None else spread[first:end]
            return maps, maps.prepare(eyes[first:end], None if ax is None else np.linalg.norm(ax, axis=2).max(1), ax)

        def draw(k: int, split: bool) -> tuple[ShadowMaps, int]:
            """aim(k), then its maps drawn (split over the cores, or in one launch: the side thread's work)."""
            maps, n = aim(k)
            if split:
                runtime.split(maps.raster, n, dev, min_items=1)
            else:
                maps.raster(0, n)
            return maps, n

        def upload(k: int) -> None:
            """Batch k's transfers and candidate flags into the batch buffers (weights, cand)."""
            first, end = firsts[k], ends[k]
            cols = None if perm is None else perm[first:end]
            self.upload_batch(cand, W_pix, W_c, first, end - first, cen, cols)

        nxt = draw(0, True) if firsts else None
        for k in tqdm(range(len(firsts)), desc="shadow passes", unit="batch", leave=False,
                      disable=self.quiet or n_src <= 4 * self.batch or not sys.stderr.isatty()):
            self.maps, n = nxt
            first = firsts[k]
            drawing = None
            if k + 1 < len(firsts) and self.pipelined:  # the next batch: its maps aimed and drawn on the side thread
                drawing = runtime.background(functools.partial(draw, k + 1, False))
            try:
                if ring is not None and first == hard and hard > 0:  # the first weak batch
                    strong = sums.result()[0]
                    sums.select(sel_weak)
                upload(k)
                sums.prepare(self.maps, n, 0, self.cand.dev,
                             split=lambda launch, m: runtime.split(launch, m, dev, min_items=1024))
                # both cores, cut where the (point, map) pairs are halved: the cells near the object list most maps
                runtime.run([lambda a=a, b=b: sums.accumulate(self.maps, 0, self.weights.dev, a, b)
                             for a, b in sums.balanced(runtime.parts(dev, sums.n, min_items=2048))])
            finally:  # joined before the pause: nothing runs while refine() holds the frame
                if drawing is not None:
                    nxt = drawing.result()
            if k + 1 < len(firsts) and not self.pipelined:
                nxt = draw(k + 1, True)
            yield first + n  # sources done: refine() may stop here and resume on its next call
        self.maps = primary
        acc, _ = sums.result()
        n_pix = len(pix_pt)
        if ring is None:
            return Masks(self.recv[pix_pt], self.recv[fill_pt], cen, acc[:n_pix], acc[n_pix:])
        # the weak passes' sums at the ring's pixels: the mean of their sums at the known pixels of the 3x3
        # window on the same quad (the fill of the lattice's other pixels), added to the strong passes' own
        out = np.zeros((len(sel_all), 3)) if strong is None else strong
        keep = np.flatnonzero(~skip)
        out[n_pix:] += acc[len(keep):]
        weak = np.zeros((n_pix, 3))
        weak[keep] = acc[:len(keep)]
        if coarse is not None and coarse.any():  # bilinear from the corners of their spacing-4 squares, all summed
            self._fill.set_spacing(self.recv[pix_pt[coarse]], 4)
            try:
                weak[coarse] = self.fill(self.recv[pix_pt[keep]], acc[:len(keep)], self.recv[pix_pt[coarse]])
            finally:
                self._fill.set_spacing(np.zeros(0, np.int64), 2)
        have = np.flatnonzero(~ring)
        weak[ring] = self.fill(self.recv[pix_pt[have]], weak[have], self.recv[pix_pt[ring]])
        out[:n_pix] += weak
        return Masks(self.recv[pix_pt], self.recv[fill_pt], cen, out[:n_pix], out[n_pix:])

    def weak_ring(self, pix_pt: np.ndarray, centre: np.ndarray, radius: float) -> np.ndarray:
        """(len(pix_pt),) bool: the exact pixels of an all-sources frame that its weak passes (app.rest_maps)
        fill instead of summing. They are the pixels summed only because they lie within near_factor bounding
        radii (not on the lattice, and every one with a lattice pixel of its own quad in its 3x3 window), at
        graded_near radii or more: beyond the bounding sphere no receiver touches the object. A weak pass
        changes a pixel by at most WEBER (2 %) of its light, so its own hard edge is no visible step; the strong
        passes (the lamps' contact shadows) are still summed at every such pixel. A pixel none of whose window's
        known pixels is summed by the weak passes (the object covers them) stays exact."""
        pts = pix_pt
        static = (self.lattice | ~self.lattice_cover)[self.recv[pts]]
        ring = ~static & (np.linalg.norm(self.pt_pos[pts] - centre, axis=1) >= self.graded_near * radius)
        if ring.any():
            at = np.flatnonzero(ring)
            known = self.recv[pts[~ring]]
            seen = self.fill(known, np.ones((len(known), 3)), self.recv[pts[at]])
            ring[at[seen[:, 0] <= 0.0]] = False
        return ring

    def weak_coarse(self, pix_pt: np.ndarray, centre: np.ndarray, radius: float, ring: np.ndarray) -> np.ndarray:
        """(len(pix_pt),) bool: the exact pixels of an all-sources frame that its weak passes fill bilinearly from
        the corners of their spacing-4 lattice square instead of summing: pixels of the spacing-2 lattice at
        weak_far bounding radii or more, off the spacing-4 lattice, whose square's four corners (on its quad) are
        all exact pixels the weak passes sum (not in `ring`, weak_ring's). Each weak pass changes a pixel by at
        most WEBER (2 %) of its light (app.rest_maps), so no edge of one is a visible step; what the interpolation
        could show is the weak passes' edges coinciding, which they do where the receiver nears the object (the
        contact: the sphere and the ring). weak_far = 2 radii, one object width beyond the bounding sphere:
        there the weak sources' shadows, cast from every direction, fan apart by at least the object's own size,
        and their sum varies smoothly. The strong passes are still summed at every such pixel."""
        pts = pix_pt
        rx, ry = np.divmod(self.recv[pts], self.width)[::-1]
        lat2 = (rx % 2 == 0) & (ry % 2 == 0)
        cand = lat2 & ((rx % 4 != 0) | (ry % 4 != 0)) & ~ring
        cand &= np.linalg.norm(self.pt_pos[pts] - centre, axis=1) >= self.weak_far * radius
        if not cand.any():
            return cand
        summed = self._allowed  # scratch (R,): the pixels the weak passes sum unless coarse
        summed[pts[~cand & ~ring]] = True
        at = np.flatnonzero(cand)
        c = self.sq_corners[4][self.pt_sq[4][pts[at]]]
        good = np.all((c >= 0) & summed[np.maximum(c, 0)], axis=1)
        summed[pts[~cand & ~ring]] = False
        out = np.zeros(len(pts), bool)
        out[at[good]] = True
        return out

    def _run_graded(self, proxy, centre: np.ndarray, radius: float, coverage: np.ndarray, cand: np.ndarray,
                    eyes: np.ndarray, W_pix: np.ndarray, W_c: np.ndarray, spread: np.ndarray | None,
                    full_maps: bool, scale: np.ndarray):
        """run() of a cluster frame whose maps fit one batch, on a graded lattice refined where the
        shadow varies: exact are the pixels near the object (as in run) and the corners of lattice
        squares of spacing 8 over the others; a pixel whose square's corners (all on its quad and
        wanted) differ in shadow fraction by at most refine_tol is filled from them (bilinear), the
        others go to the square of half the spacing, whose corners are summed next; at spacing 2
        a pixel is filled as in run (the 3x3 mean) where its own corners agree so, else summed itself.
        The maps are rendered and listed once; each spacing is one launch of the masked sums."""
        dev, n = self.device, len(eyes)
        R = self.n_pix_points
        ok = cand.any(1) if cand.shape[1] else np.zeros(len(cand), bool)
        allowed = self._allowed
        allowed[:] = ok[self.pt_patch]
        covered = np.flatnonzero(coverage.reshape(-1) >= 1.0)
        if len(covered):  # pixels the object hides completely: no shadow to show
            hidden = self.recv_index[covered]
            allowed[hidden[hidden >= 0]] = False
        reach = self.graded_near * radius
        near_patch = np.flatnonzero(ok & (np.linalg.norm(self.patch_centre - centre, axis=1)
                                          < reach + self.patch_radius + 1e-3))
        lo, hi = self.pt_start[near_patch], self.pt_start[near_patch + 1]
        span = self.pt_by_patch[np.repeat(lo - np.concatenate([[0], np.cumsum(hi - lo)[:-1]]), hi - lo)
                                + np.arange((hi - lo).sum())]
        near = span[np.linalg.norm(self.pt_pos[span] - centre, axis=1) < reach]
        near = near[allowed[near]]
        cen = np.flatnonzero(ok & ~self.emitter)
        allowed[near] = False  # from here: the wanted points farther out
        pend = np.flatnonzero(allowed)
        allowed[near] = True

        # the batch's maps, their transfers and each cell's list, once for every spacing
        self.maps = self.maps_full if full_maps else self.maps_cluster
        self.maps.set_proxy(proxy[0], proxy[1], proxy[2])
        ax = None if spread is None else spread[:n]
        self.last_hard = 0
        if ax is not None and self.weak_clusters is not None:  # weak passes: a spread of 0, the hard lookup
            weak = self.weak_clusters.shares(W_pix)[:n] <= self.weak_clusters.budget
            self.last_hard = int(weak.sum())
            if self.last_hard:
                ax = np.where(weak[:, None, None], 0.0, ax)
        n = self.maps.prepare(eyes, None if ax is None else np.linalg.norm(ax, axis=2).max(1), ax)
        runtime.split(self.maps.raster, n, dev, min_items=1)
        self._centres = self._centre_table(W_c)  # the centres' transfers read in place where it can (the CPU)
        self.upload_batch(cand, W_pix, W_c, 0, n, cen, centres=self._centres is None)

        if self.refine_on_device:  # the spacing-8 corners flagged by a kernel (_graded_finer_device)
            sq8, (_, first_pts) = None, self._refine.step(pend, 0, 8, self.refine_tol, extra=near)
        else:
            sq8, c8 = self._square_corners(pend, 8)
            first_pts = np.unique(np.concatenate([near, c8]))
        self.sums.select(np.concatenate([first_pts, R + cen]))
        self.sums.activate_groups(ok)
        self.sums.prepare(self.maps, n, 0, self.cand.dev,
                          split=lambda launch, m: runtime.split(launch, m, dev, min_items=1024))
        acc = self._sum()
        O_cen = acc[len(first_pts):]
        self._summed(first_pts, acc[:len(first_pts)], scale)
        if self.refine_on_device:
            masks = self._graded_finer_device(pend, first_pts, cen, O_cen, scale)
        else:
            masks = self._graded_finer(pend, sq8, first_pts, cen, O_cen, scale)
        yield n
        return masks

    def _graded_finer(self, pend: np.ndarray, sq: np.ndarray, first_pts: np.ndarray, cen: np.ndarray,
                      O_cen: np.ndarray, scale: np.ndarray) -> Masks:
        """_run_graded after its first launch (the near points, the spacing-8 corners and the patch centres,
        summed): the squares of spacing 8 and 4 tested and refined, the spacing-2 pixels, each spacing one
        launch of the masked sums on the batch's maps; the frame's Masks. pend: the wanted points farther out,
        sq: the spacing-8 squares holding them; scale: run's."""
        allowed, known, vals, fracs = self._allowed, self._known, self._vals, self._frac
        exact = [first_pts]
        fill_pt, fill_s = [], []
        for s in (8, 4):
            # a square is filled from its corners where all four are wanted, summed, and differ in
            # shadow fraction by at most refine_tol
            c = self.sq_corners[s][sq]
            cc = np.maximum(c, 0)
            good = np.all((c >= 0) & known[cc], axis=1)
            frac = fracs[cc]  # (squares, 4, 3)
            good &= (frac.max(1) - frac.min(1)).max(1) <= self.refine_tol
            sq_good = self._sq_mark[s]
            sq_good[sq[good]] = True
            pend = pend[~known[pend]]
            done = sq_good[self.pt_sq[s][pend]]
            sq_good[sq[good]] = False
            fill_pt.append(pend[done])
            fill_s.append(np.full(int(done.sum()), s))
            pend = pend[~done]
            if s == 8:
                sq, new = self._square_corners(pend, 4)
            else:  # the last spacing, 2: each pixel's own corners; one with none wanted is summed itself
                c2 = self.corners[pend]
                ok2 = (c2 >= 0) & allowed[np.maximum(c2, 0)]
                new = np.unique(np.concatenate([c2[ok2], pend[~ok2.any(1)]]))
                new = new[~known[new]]
            if len(new):
                self.sums.select(new)
                self._summed(new, self._sum(), scale)
                exact.append(new)
        # spacing 2: a pixel is filled (the 3x3 mean) where its own corners are wanted, summed, and agree
        # as above; the others are summed themselves
        pend = pend[~known[pend]]
        c = self.corners[pend]
        need = c != -2
        good = np.all(~need | ((c >= 0) & known[np.maximum(c, 0)]), axis=1)
        # a corner of zero weight is replaced by the first one (never of zero weight): the same
        # max and min; only the squares whose corners are all summed are tested
        at = np.flatnonzero(good)
        c = c[at]
        frac = fracs[np.where(need[at], c, c[:, :1])]
        good[at] = (frac.max(1) - frac.min(1)).max(1) <= self.refine_tol
        fill_pt.append(pend[good])
        fill_s.append(np.full(int(good.sum()), 2))
        new = pend[~good]
        if len(new):
            self.sums.select(new)
            vals[new] = self._sum()
            known[new] = True
            exact.append(new)
        return self._graded_masks(exact, fill_pt, fill_s, cen, O_cen)

    def _graded_finer_device(self, pend: np.ndarray, first_pts: np.ndarray, cen: np.ndarray, O_cen: np.ndarray,
                             scale: np.ndarray) -> Masks:
        """_graded_finer with each spacing's refine test and the next spacing's corners in one launch
        (kernels.graded_refine: the same tests, points and order, so the same Masks; no squares list)."""
        exact, fill_pt, fill_s = [first_pts], [], []
        for s, mark in ((8, 4), (4, 2)):
            state, new = self._refine.step(pend, s, mark, self.refine_tol)
            done = pend[state == 1]
            fill_pt.append(done)
            fill_s.append(np.full(len(done), s))
            pend = pend[state == 2]
            if len(new):
                self.sums.select(new)
                self._summed(new, self._sum(), scale)
                exact.append(new)
        state, _ = self._refine.step(pend, 2, 0, self.refine_tol)
        done = pend[state == 1]
        fill_pt.append(done)
        fill_s.append(np.full(len(done), 2))
        new = pend[state == 2]
        if len(new):
            self.sums.select(new)
            self._vals[new] = self._sum()
            self._known[new] = True
            exact.append(new)
        return self._graded_masks(exact, fill_pt, fill_s, cen, O_cen)

    def _graded_masks(self, exact: list[np.ndarray], fill_pt: list[np.ndarray], fill_s: list[np.ndarray],
                      cen: np.ndarray, O_cen: np.ndarray) -> Masks:
        """The graded frame's Masks from its summed points (exact, in summing order), its filled points and their
        spacings; the frame's known flags cleared and the fill's spacings set."""
        known, vals = self._known, self._vals
        pix_pt = np.concatenate(exact)
        fill_pt, fill_s = np.concatenate(fill_pt), np.concatenate(fill_s)
        # a pixel filled at spacing 8 or 4 may be a corner of a finer square, summed after it was filled:
        # it keeps its exact sum (compose writes the filled values after the summed ones)
        unsummed = ~known[fill_pt]
        fill_pt, fill_s = fill_pt[unsummed], fill_s[unsummed]
        O_pix = vals[pix_pt].copy()
        known[pix_pt] = False
        coarse = fill_s > 2
        self._fill.set_spacing(self.recv[fill_pt[coarse]], fill_s[coarse])
        self.last_graded = {8: int(np.sum(fill_s == 8)), 4: int(np.sum(fill_s == 4)), 2: int(np.sum(fill_s == 2)),
                            "exact": len(pix_pt)}
        return Masks(self.recv[pix_pt], self.recv[fill_pt], cen, O_pix, O_cen)

    def _summed(self, pts: np.ndarray, v: np.ndarray, scale: np.ndarray) -> None:
        """_run_graded's points pts summed to v: known, their values and shadow fractions (v / scale) kept."""
        self._known[pts] = True
        self._vals[pts] = v
        self._frac[pts] = v / np.maximum(scale[self.recv[pts]], 1e-12)

    def _square_corners(self, pts: np.ndarray, s: int) -> tuple[np.ndarray, np.ndarray]:
        """_run_graded's (the squares of spacing s holding points pts, the wanted corners of those not summed
        yet), from the frame's scratch flags (_allowed, _known)."""
        mark = self._sq_mark[s]
        mark[self.pt_sq[s][pts]] = True
        sq = np.flatnonzero(mark)
        mark[sq] = False
        c = self.sq_corners[s][sq].reshape(-1)
        c = c[c >= 0]
        return sq, np.unique(c[self._allowed[c] & ~self._known[c]])

    def _sum(self) -> np.ndarray:
        """The prepared batch's masked sums over the selected points, both cores cut by work: the number of
        ranges from the (point, map) pairs (MaskedSum.work), at least MIN_PART_PAIRS each."""
        dev = self.device
        work = self.sums.run_work()  # read once for the number of ranges and their cuts
        k = runtime.parts(dev, int(work[-1]) if len(work) else 0, min_items=MIN_PART_PAIRS)
        wc, vr = self._centres, self.n_recv_vert
        hard = self.n_pix_points if self.hard_centres else None  # the centres' points follow the pixels'
        runtime.run([lambda a=a, b=b: self.sums.accumulate(self.maps, 0, self.weights.dev, a, b, wc, vr, hard)
                     for a, b in self.sums.balanced(k, work)])
        return self.sums.result(counts=False)[0]  # the counts are not read

    def fill(self, known: np.ndarray, values: np.ndarray, missing: np.ndarray, out=None) -> np.ndarray | None:
        """Values (len(missing),3) at pixels `missing`: mean of the `known` pixels' values in
        their 3x3 window that lie on the same quad (every pixel a frame fills has one, see
        lattice_cover). A view of a reused buffer, valid until the next call; or, given `out` (an
        image-sized wp.array of vec3d), written there at their pixels (WindowFill.fill)."""
        return self._fill.fill(known, values, missing,
                               split=lambda launch, n: runtime.split(launch, n, self.device, min_items=8192), out=out)

    def select(self, centre: np.ndarray, radius: float, coverage: np.ndarray, cand: np.ndarray
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

    def upload_batch(self, cand: np.ndarray, W_pix: np.ndarray, W_c: np.ndarray, first: int, n: int,
                      cen: np.ndarray, cols: np.ndarray | None = None, centres: bool = True) -> None:
        """Sources first..first+n-1's transfers and candidate flags into the batch buffers (weights, cand); cols:
        the passes' columns instead, n of them, e.g. run's perm). Of the
        patch-centre rows only those of the frame's centres `cen` that are candidates of some source
        of the batch: the masked sums read no other (a centre's list holds its candidates only); none where
        not `centres` (the sums read W_c in place: _centre_table)."""
        Vr = self.n_recv_vert
        wb, cb = self.weights, self.cand
        w = wb.host
        if cols is None:
            w[:Vr, :n] = W_pix[:, first:first + n]
            if centres:
                c = cen[cand[cen, first:first + n].any(1)]
                w[Vr + c, :n] = W_c[c, first:first + n]
            cb.host[:, :n] = cand[:, first:first + n]
        elif self._gather is None or not self._gather_cols(cand, W_pix, W_c, cen, cols, wb, cb):
            w[:Vr, :n] = W_pix[:, cols]
            cc = cand[:, cols]
            c = cen[cc[cen].any(1)]
            w[Vr + c, :n] = _take(W_c, c, cols)
            cb.host[:, :n] = cc
        wb.push()
        cb.push()

    def _centre_table(self, W_c) -> wp.array | None:
        """W_c (P,S,3) as a Warp table the masked sums read in place (no copy; columns as the batch's weights,
        so the batch must start at source 0), or None where it cannot be one: not the CPU (W_c lives on the
        host), or not a C-contiguous float32 array."""
        if not wp.get_device(self.device).is_cpu or not isinstance(W_c, np.ndarray) or W_c.dtype != np.float32 \
                or W_c.ndim != 3 or W_c.shape[2] != 3 or not W_c.flags.c_contiguous or not len(W_c):
            return None
        return wp.array(W_c, dtype=wp.vec3, device=self.device, copy=False)

    def _gather_cols(self, cand: np.ndarray, W_pix, W_c, cen: np.ndarray, cols: np.ndarray, wb: Buffer, cb: Buffer
                     ) -> bool:
        """upload_batch's columns `cols` by kernels.gather: the same values as its numpy gather (15-27 ms a
        batch on the loaded 2-core machine, the kernels 5-6 ms); False where the tables are not host float32
        tables (upload_batch's numpy gather then writes every buffer)."""
        g, Vr, n = self._gather, self.n_recv_vert, len(cols)
        # one launch each (a few ms): split over the pool's threads they wait for a core longer than they run
        if not g.flags(cand, cols, cb.dev):
            return False
        c = cen[cb.host[cen, :n].any(1)]
        rows = np.arange(Vr)
        return g.vec3(W_pix, rows, rows, cols, wb.dev) and g.vec3(W_c, c, Vr + c, cols, wb.dev)


def _take(W, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """W[rows][:, cols] of an (R,S,3) array or a ColumnView (lighting.frame_sources), gathering only those."""
    if hasattr(W, "table"):  # a ColumnView: its table's rows and columns
        return W.table[W.r0 + rows[:, None], W.pos[cols][None, :]]
    return W[np.ix_(rows, cols)]


def _square_corners(index: np.ndarray, quad: np.ndarray, x0: np.ndarray, y0: np.ndarray, q: np.ndarray, s: int,
                    W: int, H: int) -> np.ndarray:
    """(n, 4) int64: the receiver-point index (`index`: per image pixel, -1 none) of the corners
    (x0, y0), (x0 + s, y0), (x0, y0 + s), (x0 + s, y0 + s) of n lattice squares of spacing s on
    quads q; -1 where a corner is off the image, not a receiver pixel or on another quad."""
    c = np.empty((len(x0), 4), np.int64)
    for k, (cx, cy) in enumerate(((0, 0), (1, 0), (0, 1), (1, 1))):
        sx, sy = x0 + cx * s, y0 + cy * s
        inside = (sx < W) & (sy < H)
        o = np.where(inside, sy * W + sx, 0)
        i = np.where(inside, index[o], -1)
        c[:, k] = np.where((i >= 0) & (quad[o] == q), i, -1)
    return c


def _lattice_corners(recv: np.ndarray, quad: np.ndarray, W: int, H: int, s: int = 2) -> np.ndarray:
    """Per receiver pixel recv[i]: (len(recv), 4) int32 indices into recv of the corners of its
    lattice square of spacing s (x0 = s floor(x / s), ...; order of _square_corners); -2 where the
    corner's bilinear weight is zero, -1 where it is off the image, not a receiver pixel or on
    another quad."""
    index = np.full(H * W, -1, np.int64)
    index[recv] = np.arange(len(recv))
    y, x = np.divmod(recv, W)
    x0, y0 = x // s * s, y // s * s
    c = _square_corners(index, quad, x0, y0, quad[recv], s, W, H)
    for k, (cx, cy) in enumerate(((0, 0), (1, 0), (0, 1), (1, 1))):
        c[((cx == 1) & (x == x0)) | ((cy == 1) & (y == y0)), k] = -2
    return c.astype(np.int32)


def _lattice_squares(recv: np.ndarray, quad: np.ndarray, W: int, H: int, s: int) -> tuple[np.ndarray, np.ndarray]:
    """The lattice squares of spacing s of receiver pixels recv, one per (square, quad): each
    pixel's square (len(recv),) and the squares' corners (n, 4) as indices into recv
    (_square_corners)."""
    index = np.full(H * W, -1, np.int64)
    index[recv] = np.arange(len(recv))
    y, x = np.divmod(recv, W)
    q = quad[recv].astype(np.int64)
    key = (q * (H // s + 1) + y // s) * (W // s + 1) + x // s
    keys, pt_sq = np.unique(key, return_inverse=True)
    first = np.zeros(len(keys), np.int64)
    first[pt_sq[::-1]] = np.arange(len(recv))[::-1]  # one pixel of each square
    c = _square_corners(index, quad, x[first] // s * s, y[first] // s * s, q[first], s, W, H)
    return pt_sq.astype(np.int64).reshape(-1), c


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
