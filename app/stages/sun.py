"""The sun stage: the directional source's per-frame work (DESIGN "Per-frame stages").

Per frame, on listed points only (the sunlit pixels and sample points of sunlit patches, fixed per
scene; the object's proxy and its silhouette):
- `SunStage.frame`: one orthographic PCSS shadow map of the object toward the sun (the sun's one
  pass of the budget), the irradiance/pi it takes from the sunlit pixels and from every patch;
- `SunStage.later_bounces`: a first-bounce change of patch radiance passed on for the later bounces,
  straight to the receiver vertices on clusters of patches (LaterBounces);
- `SunStage.object_emitters`: the object's sunlit parts for the object-light stage: its sun-facing
  faces split once per shape in object space (lighting.sun.SunlitPieces, with the object's own shadow
  and each piece's visibility table), per frame only the room's shadow on them tested; wholly lit
  faces emit whole, partly lit faces their lit pieces;
- `SunStage.refine_clipped_edges`: the object's outline where a sunlit face or sunlit floor clips,
  re-sampled finely (a clipping neighbour is tens of times brighter: 2x2 samples a pixel put the
  coverage, hence the pixel, tens of levels off).
Units: irradiance/pi (the radiance a white Lambertian surface reflects), as in app.engine.
"""
from __future__ import annotations

import copy
import functools
import logging
from dataclasses import dataclass

import cv2
import numpy as np

from app import runtime
from kernels.blocked_transfer import BlockedPairs
from kernels.sunshadow import OutlineShade, SunShadowMap
from kernels.vec import cross3
from kernels.visibility import Occluder, SeenEmitters
from app.stages.object_light import CUBE_RES, ExtraEmitters, TriangleVisibility, shape_key
from app.stages.receiver_map import reflectance
from app.stages.shadow_pass import window_pairs
from lighting.radiance import PHOTO
from lighting.sun import SunLight, SunlitPieces, estimate_sun, no_sun_reason, openings, surface_albedo
from recon.assemble import SUN_DECLARED_BY_USER
from recon.patches import PatchMesh
from recon.response import luminance
from recon.scene import Scene

log = logging.getLogger("photoar")
CLIP_LEVEL = 254  # an 8-bit level at or above which a photo channel counts as clipped (the sun's pixels)


PIECE_TABLE_RES = 16  # cells per cube side of the sunlit pieces' visibility table (~6 degrees): at floor
# points beside sun_room's chair their light was within 1.1 % of a Monte Carlo reference on average, as with
# a ray per piece (8 cells: 1.5 %); bench/bench_sun.py prints the pieces against Monte Carlo per pixel


EDGE_MIN_RAYS = 256  # rays per concurrent part of refine_clipped_edges's launch at least (a thread's
# hand-off costs about what a few hundred ray casts do)


EDGE_FIRST_RAYS = 4  # rays cast first on every outline pixel (kernels.sunshadow.first_samples: the s x s grid's
# corners); the other s*s - 4 only on pixels where those disagree (some reach the object, some do not)


PIECE_SIZE = 0.25  # the sunlit pieces' size (SunlitPieces), in bounding radii of the object


PIECE_POINT_TOLERANCE = 0.05  # a lit piece is a point emitter at a receiver where the bound of that error is
# at most this share of its unoccluded light there (kernels.visibility.emitter_sum_seen_bounded)


def _piece_rows(pieces: np.ndarray, parent: np.ndarray, tris: np.ndarray) -> tuple[np.ndarray, ...]:
    """Where each piece (S,3,3) of a regular m^2 split of its face tris[parent] (lighting.sun: corners
    at barycentric (b1, b2) multiples of 1/m, 'up' pieces (i,j),(i+1,j),(i,j+1) and 'down' ones
    (i+1,j),(i+1,j+1),(i,j+1)) lies: (m (S,), row i (S,), place in its row (S,): 2j up, 2j + 1 down),
    from its centroid (b1 = (i + 1/3 or 2/3) / m, b2 = (j + 1/3 or 2/3) / m)."""
    m = np.rint(np.sqrt(np.bincount(parent)[parent])).astype(np.int64)
    v = tris[parent]
    e1, e2, d = v[:, 1] - v[:, 0], v[:, 2] - v[:, 0], pieces.mean(1) - v[:, 0]
    a11, a12, a22 = (e1 * e1).sum(1), (e1 * e2).sum(1), (e2 * e2).sum(1)
    r1, r2 = (d * e1).sum(1), (d * e2).sum(1)
    det = a11 * a22 - a12 * a12
    b1, b2 = (a22 * r1 - a12 * r2) / det * m, (a11 * r2 - a12 * r1) / det * m
    return m, np.floor(b1).astype(np.int64), np.rint(2.0 * b2 - 2.0 / 3.0).astype(np.int64)


def piece_runs(part: np.ndarray, share: np.ndarray, parent: np.ndarray, rows: tuple[np.ndarray, ...],
               tris: np.ndarray) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """The lit pieces `part` (indices into a shape's pieces: their faces `parent` (S,), their places
    `rows` (_piece_rows), lit shares `share` (S,)) ordered run by run, and the runs as SeenEmitters
    groups (start, count, polygons (G,4,3) with the faces `tris` (T,3,3) where they are this frame,
    vertices): a run is a row of one face's regular split (lighting.sun's m^2 pieces lie in m rows
    between lines parallel to an edge) whose consecutive pieces have the same lit share (hence
    radiance); its polygon is the trapezoid (or triangle) they tile."""
    m, row, elem = rows
    order = part[np.lexsort((elem[part], row[part], parent[part]))]
    pa, ro, el, sh = parent[order], row[order], elem[order], share[order]
    brk = np.ones(len(order), bool)
    brk[1:] = (pa[1:] != pa[:-1]) | (ro[1:] != ro[:-1]) | (el[1:] != el[:-1] + 1) | (sh[1:] != sh[:-1])
    start = np.flatnonzero(brk)
    count = np.diff(np.append(start, len(order)))
    last = start + count - 1
    i, mm, f = ro[start].astype(np.float64), m[order[start]].astype(np.float64), pa[start]
    ea, eb = el[start], el[last]
    lo_min, lo_max = (ea + 1) // 2, eb // 2 + 1  # the run's ends on its row's lower line, in 1/m steps
    up_min, up_max = ea // 2, (eb + 1) // 2  # on its upper line
    # CCW as the face: (i, lo_max), (i, lo_min), (i+1, up_min), (i+1, up_max), a repeated corner dropped
    b1 = np.stack([i, i, i + 1, i + 1], 1)
    b2 = np.stack([lo_max, lo_min, up_min, up_max], 1).astype(np.float64)
    tri_top = lo_min == lo_max  # the lower line is one point: a triangle
    b1[tri_top, 1:3], b2[tri_top, 1:3] = b1[tri_top, 2:4], b2[tri_top, 2:4]
    verts = 4 - tri_top - (up_min == up_max)
    v = tris[f]
    polys = v[:, None, 0] + (b1 / mm[:, None])[..., None] * (v[:, None, 1] - v[:, None, 0]) \
        + (b2 / mm[:, None])[..., None] * (v[:, None, 2] - v[:, None, 0])
    return order, (start, count, polys, verts)


class SunStage:
    """The sun's per-frame work for one scene (built by SunSetup.apply)."""

    def __init__(self, light: SunLight, pts: np.ndarray, footprint: np.ndarray, E_pix: np.ndarray,
                 c_patch: np.ndarray, c_pts: np.ndarray, c_vis: np.ndarray, n_patches: int, device: str,
                 patches=None, white: np.ndarray | None = None):
        """light: the sun through the openings; pts (N,3), footprint (N,) m, E_pix (N,3): the sunlit
        pixels' lookup points, pixel footprints and direct sun; c_patch (Pc,), c_pts (Pc*K,3),
        c_vis (Pc,K): sunlit patches, their K sample points and the sun's visibility there; patches:
        the scene's PatchMesh (the clusters of later_bounces); white (3,): the photo's white level in
        radiance, the response's radiance at level 255 per channel (default 1: a response whose top
        is 1 at exposure 1 s)."""
        self.light = light
        self.white = np.ones(3) if white is None else np.asarray(white, np.float64).reshape(3)
        self.pts, self.footprint, self.E_pix = pts, footprint.astype(np.float32), E_pix
        self.c_patch, self.c_pts, self.c_vis = c_patch, c_pts, c_vis
        self.n_patches = n_patches
        self.E_perp = light.sun.irradiance / np.pi
        self.map = SunShadowMap(light.sun.direction, light.sun.half_angle, device=device)
        # the sunlit pixels' and the patches' sample points (footprint 0) in one set, kept on the device (no
        # buffers per frame): frame() looks both up in one launch
        self._n_pix = len(pts)
        self._lookups = self.map.points(np.concatenate([np.asarray(pts, np.float64).reshape(-1, 3),
                                                        np.asarray(c_pts, np.float64).reshape(-1, 3)]),
                                        np.concatenate([np.asarray(footprint, np.float32).reshape(-1),
                                                        np.zeros(len(np.asarray(c_pts).reshape(-1, 3)), np.float32)]))
        self.device = device
        self.edge_samples = 4  # rays per side of an outline pixel (refine_clipped_edges)
        self.edge_first = EDGE_FIRST_RAYS  # of those, the rays cast on every outline pixel (the rest only where
        # they disagree; None: all on every pixel)
        self.patches = patches
        self._later: LaterBounces | None = None  # the scene's later-bounce operators (later_bounces)
        self._blocked: tuple | None = None  # (key, BlockedPairs of the receiver vertices and clusters, clusters, Vr)
        self.lost: np.ndarray | None = None  # (Pc,K) the last frame's lost share of the sun per sample point
        # of the sunlit patches (frame())
        self._pieces: tuple | None = None  # the last proxy shape's (object_emitters)
        self._outline = OutlineShade(device, light.entries, light.d)  # refine_clipped_edges's
        # rays and their shading (buffers kept)
        # the last object_emitters's sun radiance (T,3) of each proxy face averaged over the face (wholly and
        # partly lit; zero unlit): the object's own interreflection takes it (ObjectLight.self_light)
        self.face_sun: np.ndarray | None = None
        self._emitters = SeenEmitters(device)  # object_emitters's lit pieces on the device (buffers kept)

    @property
    def edge_rays(self) -> int:
        """Rays refine_clipped_edges cast in its last call."""
        return self._outline.rays

    def source_eyes(self, B: np.ndarray, albedo: np.ndarray, eyes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(patch ids (n,), eyes (n,3) m): where the shadow pass should see the sunlit patches' light from.
        A sunlit patch's radiance B (P,3) is its sun, rho E_sun/pi x the sunlit share of its sample points,
        plus the rest (its indirect light, spread over it); the sun lies on the sunlit sample points only,
        which the object's shadow or the sunlit patch's edge leaves to one side. The eye: the luminance-
        weighted mean of the sunlit points' centroid (the sun's share of B, at most 1) and the patch's own
        eye (eyes (P,3): its centre lifted 1 mm). sun_106 (known light): the object hides 53 % of the
        loss's first pass; with the centre the shadow pass hides 9.2 of the sunlit light that a ray per
        sample point finds hidden (9.6), and the sun-loss balance came out 3 % short (docs/unseen.md,
        energy107)."""
        J, K = self.c_vis.shape
        n_vis = self.c_vis.sum(1)
        ids = self.c_patch[n_vis > 0]
        pts = self.c_pts.reshape(J, K, 3)[n_vis > 0]
        vis = self.c_vis[n_vis > 0]
        lit = (vis[..., None] * pts).sum(1) / vis.sum(1)[:, None]  # the sunlit points' centroid (lifted 1 mm)
        sun = luminance(albedo[ids] * (vis.mean(1)[:, None] * self.E_perp))
        share = np.clip(sun / np.maximum(luminance(B[ids]), 1e-12), 0.0, 1.0)[:, None]
        return ids, eyes[ids] + share * (lit - eyes[ids])

    def frame(self, vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The sun's pass for an object: (irradiance/pi lost at the sunlit pixels (N,3), at every
        patch (P,3), mean over its sample points)."""
        self.map.render(vertices, faces)
        occ = self.map.occlusion_at(self._lookups)
        occ_pix, occ_c = occ[:self._n_pix], occ[self._n_pix:].reshape(self.c_vis.shape)
        self.lost = self.c_vis * occ_c  # share of the sun lost at each sample point (first_pass_blocked)
        loss_c = np.zeros((self.n_patches, 3))
        loss_c[self.c_patch] = self.lost.mean(1)[:, None] * self.E_perp
        return occ_pix[:, None] * self.E_pix, loss_c

    def later_bounces(self, dB1: np.ndarray, albedo: np.ndarray, G: np.ndarray, G_v: np.ndarray,
                      bounces: int, dB2: np.ndarray | None = None, occluder: Occluder | None = None,
                      recv_points: np.ndarray | None = None, box: tuple | None = None, split=None,
                      first: np.ndarray | None = None, onto: np.ndarray | None = None,
                      obb: tuple | None = None) -> np.ndarray | None:
        """What the engine's one pass through G_v (its second order) leaves out of the sun's changes, at
        the receiver vertices (Vr,3); None when nothing.

        A change of patch radiance reaches the camera through as many more bounces as the truth's
        `bounces` leave it (paths of at most `bounces` reflections, the camera's hit included):
        - dB1 (P,3), the sun a patch no longer reflects (the object's sun shadow): one reflection
          made, so G_v (rho G)^k dB1 for k = 1 .. bounces-2;
        - dB2 (P,3), the sunlit object's light reflected by the patches (rho R, R from the object's
          sunlit parts only): two made (sun -> object -> patch), so k = 1 .. bounces-3. (The object's
          light from the room, gathered from B^(bounces-2), has none left: not passed on here.)
        The later passes run through G on clusters of patches (LaterBounces).

        With `occluder` (the object's proxy, bounded by `box` (lo, hi)) and `recv_points` (Vr,3), the sun's loss is not counted
        twice where the object also hides the shadowed floor: the shadow pass already takes from a
        receiver the light of every source (the sunlit patches among them, at their full radiance) that
        the object hides from it, so the loss's first pass through G_v and G must skip the pairs the
        object blocks. They are found with one ray per (receiver, sunlit patch that lost sun) to the
        loss-weighted centre of the patch's lost sample points (first_pass_blocked); the first pass
        at the patches that this gives back is a change of two reflections, passed on like dB2; its own
        first pass through G_v is added to `first` (P,3) when given (the caller's one pass over the
        changed patches: the engine's second order), else made here. With `onto` (P,3) (the same one
        pass, e.g. the array given as `first`) the later bounces are added to it at the patches instead of
        returned at the receiver vertices (LaterBounces: G_v's pass is linear, the same sums). `obb`: an
        oriented box about the occluder, tested instead of `box` (upright_box; first_pass_blocked casts fewer
        rays, the same answer)."""
        extra_v = None
        if occluder is not None and self.lost is not None and self.c_patch.size and np.any(dB1[self.c_patch]):
            if recv_points is None or box is None:
                raise ValueError("SunStage.later_bounces: the occluder needs recv_points and its box")
            later = bounces > 2  # the loss's pass through G (at the patches) is a later bounce
            blk = self.first_pass_blocked(occluder, box, dB1, G, G_v, recv_points, split,
                                          albedo if later else None, at_patches=later, obb=obb)
            extra_v = -blk[0]
            if later:
                back = -albedo * blk[1]  # light the patches keep: their first pass of dB1 counted it lost
                if first is not None:
                    first += back
                else:  # its own first pass
                    nz = np.flatnonzero(back.any(1))
                    extra_v = extra_v + np.asarray(G_v)[:, nz] @ back[nz].astype(np.float32)
                # the sun the sunlit patches still reflect that the object hides from other patches (the
                # shadow pass's loss there, passed on once by the engine) has two reflections made too:
                # its later passes (with the loss's, whose blocked pairs the given-back light cancels)
                dB2 = -albedo * blk[2] if dB2 is None else dB2 - albedo * blk[2]
        if bounces <= 2:
            return extra_v
        lb = self._later_operators(G, G_v, albedo)
        out = lb(dB1, bounces - 2, later=dB2, onto=onto)  # dB2 with one pass fewer (bounces - 3)
        if out is None:
            return extra_v
        return out if extra_v is None else out + extra_v

    def _later_operators(self, G: np.ndarray, G_v: np.ndarray, albedo: np.ndarray) -> "LaterBounces":
        """The scene's LaterBounces over G, G_v and the albedo, made once and kept."""
        lb = self._later
        if lb is None or lb.key != (id(G), id(G_v), id(albedo)):
            if self.patches is None:
                raise ValueError("SunStage: later bounces need the patch mesh (patches=)")
            lb = self._later = LaterBounces(G, G_v, albedo, self.patches, exact=self.c_patch)
        return lb

    def later_at_patches(self, dB1: np.ndarray, albedo: np.ndarray, G: np.ndarray, G_v: np.ndarray,
                         bounces: int) -> np.ndarray | None:
        """sum_{k=1}^{bounces-2} (rho G)^k dB1 (P,3): the later bounces of the sun a patch no longer reflects
        (dB1 (P,3), the object's sun shadow; one reflection made), as a change of every patch's radiance,
        i.e. what the object sees of its own sun shadow on the walls and ceiling that the shadowed floor
        lit. The object, the camera's hit, gathers the room's patches with `bounces` - 1 reflections left,
        the shadowed floor's own change (k = 0) exactly (ObjectShading's sun_dB): these are the rest.
        sun_101 (known light): the chair's back, facing a wall and the ceiling lit by the sunlit floor its
        own shadow darkens, gathered 7 % of its light too much without them (k = 1, measured against a
        point-sampled gather). None when there is nothing to pass on (bounces <= 2, no loss)."""
        if bounces <= 2 or not np.any(dB1):
            return None
        out = np.zeros((len(dB1), 3))
        self._later_operators(G, G_v, albedo)(dB1, bounces - 2, onto=out)
        return out

    def first_pass_blocked(self, occluder: Occluder, box: tuple, dB1: np.ndarray, G: np.ndarray, G_v: np.ndarray,
                           recv_points: np.ndarray, split=None, albedo: np.ndarray | None = None,
                           at_patches: bool = True, obb: tuple | None = None) -> tuple[np.ndarray, ...]:
        """(G_v's, G's) first pass of the sun's loss dB1 (P,3) over the (receiver, sunlit patch) pairs that
        `occluder` (within `box`, (lo, hi)) blocks: (Vr,3) at the receiver vertices, (P,3) at the patch centres. A patch's loss
        is placed at the loss-weighted centre of its lost sample points (this frame's, from frame()).
        With `albedo` (P,3), also G's pass over the blocked pairs of the sun the sunlit patches still reflect,
        rho E_sun x the share not lost (P,3), received on the clusters of patches (patch_clusters: centre and
        mean transfer; each patch gets its cluster's: it is a later pass's change, which LaterBounces carries
        on the clusters), each patch's at the centre of its still sunlit sample points.
        The patches' pairs are tested from their cluster's centre (one ray per cluster and target, each
        member patch weighing it by its own transfer): G's pass at the patches is a later bounce's change
        (passed on once more, through G_v), as LaterBounces carries on the clusters; the receiver vertices'
        are tested each (their first pass is seen directly).
        at_patches=False: the receiver vertices' only. Patches of zero albedo (emitters) get nothing at
        the centres (what they would get is reflected by nothing). obb: (centre, axes rows, half sides) an
        oriented box about the occluder (upright_box) that a segment must meet for its ray to be cast
        (instead of `box`)."""
        key = (id(G), id(G_v), len(recv_points))
        if self._blocked is None or self._blocked[0] != key:
            pm = self.patches
            if pm is None:
                raise ValueError("SunStage: first_pass_blocked needs the patch mesh (patches=)")
            cols = self.c_patch
            import scipy.sparse as sp

            G_s = np.ascontiguousarray(np.asarray(G, np.float32)[:, cols] * pm.albedo.any(1)[:, None])  # (P,J)
            cl, n, w = cluster_weights(pm)
            mean_rows = sp.csr_matrix((w, (cl, np.arange(len(cl)))), shape=(n, len(cl)))  # (C,P) area-weighted
            member = np.zeros(n, np.int64)  # one patch of each cluster (its quad's normal)
            member[cl] = np.arange(len(cl))
            cl_pts = mean_rows @ pm.centre + pm.normal[member] * 1e-3
            T_cl = np.asarray(mean_rows @ G_s, np.float32)  # (C,J) > 0 where some member's transfer is
            T_v = np.ascontiguousarray(np.asarray(G_v, np.float32)[:, cols])  # (Vr,J)
            # the receiver vertices and the clusters' centres in one launch (the vertices: the lost sun's targets),
            # each cluster's member patches weighing its rays by their own transfers (G_s)
            pairs = BlockedPairs(np.concatenate([recv_points, cl_pts]), np.concatenate([T_v, T_cl]), self.device,
                                 capacity=2 * len(cols), short=np.arange(len(T_v) + n) < len(T_v),
                                 members=(len(T_v) + cl, G_s))
            self._blocked = (key, pairs, cl, len(T_v))  # the transfers live in the pairs (uploaded once)
        _, pairs, cl, Vr = self._blocked
        J, K = self.c_vis.shape
        w = self.lost
        pts = self.c_pts.reshape(J, K, 3)
        change = dB1[self.c_patch]
        lost = np.flatnonzero(change.any(1))
        targets, columns, weights = [_weighted_centres(w[lost], pts[lost])], [lost], [change[lost]]
        if at_patches and albedo is not None:
            kept = np.maximum(self.c_vis - w, 0.0)  # the sun each sample point still gets
            sun = albedo[self.c_patch] * ((kept.sum(1) / K)[:, None] * self.E_perp)  # rho E_sun/pi still reflected
            lit = np.flatnonzero(sun.any(1))
            targets.append(_weighted_centres(kept[lit], pts[lit]))  # each patch's still sunlit sample points
            columns.append(lit)
            weights.append(sun[lit])
        # the pairs' sums in the launch (BlockedPairs.sums): the receivers' over the lost centres (G_v's pass),
        # the clusters' member patches' over them (G's), the clusters' over the still sunlit centres
        near, far, blk_c = pairs.sums(occluder, np.concatenate(targets), np.concatenate(columns),
                                      np.concatenate(weights), box, split, m_short=len(lost), obb=obb)
        blk_v = near[:Vr]
        if not at_patches:  # the vertices' rows only
            return (blk_v,)
        if albedo is None:
            return blk_v, blk_c
        # a later pass's change: on the clusters of patches that carry it (LaterBounces), each patch its cluster's
        return blk_v, blk_c, far[Vr:][cl]

    def object_emitters(self, pv: np.ndarray, pf: np.ndarray, tri_rad: np.ndarray, albedo: np.ndarray,
                        proxy_occ: Occluder, radius: float) -> tuple[np.ndarray, ExtraEmitters | None]:
        """The proxy's sunlit parts as emitters for the object-light stage: (tri_rad (T,3) of the
        proxy (pv, pf) with the sun of its wholly sunlit faces added, the lit pieces of its partly
        sunlit faces (ExtraEmitters) or None).

        The pieces (lighting.sun.SunlitPieces, radius/4 m) and the object's own shadow on them are
        made once per shape; per frame only the room's shadow on them is tested. A face whole in
        the sun emits as one triangle (the same light at the same place); a partly lit face's lit
        pieces keep where its light leaves and what each receiver sees of it. Beyond FAR_FIELD
        radii a partly lit face's lit pieces are one point emitter at their power centroid that sees
        a direction as much as they do (power-weighted, their table at CUBE_RES cells a side)."""
        tris = pv[pf]
        pieces, table, coarse = self._pieces_of(pv, pf, tris, proxy_occ, radius)
        self.face_sun = np.zeros_like(tri_rad)
        if len(pieces) == 0:
            return tri_rad, None
        origin = tris.reshape(-1, 3).mean(0)
        share = pieces.lit_share(origin)
        T = len(pf)
        lit = share > 0
        count, E_face = self._pieces[5]  # pieces per face, each face's cos (of the shape)
        whole = (np.bincount(pieces.parent, (share >= 1.0).astype(float), T) == count) & (count > 0)
        self.face_sun = albedo * (np.where(whole, E_face, 0.0)[:, None] * self.E_perp)
        tri_rad = tri_rad + self.face_sun
        part = np.flatnonzero(lit & ~whole[pieces.parent])
        if len(part) == 0:
            return tri_rad, None
        rad = albedo * ((share[part] * pieces.cos[part])[:, None] * self.E_perp)
        # the partly lit faces' sun averaged over the face (their pieces' power / the face's area: face_sun)
        t = tris
        area = 0.5 * np.linalg.norm(cross3(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1)
        pw = pieces.area[part][:, None] * rad
        self.face_sun += np.stack([np.bincount(pieces.parent[part], pw[:, k], T) for k in range(3)], 1) \
            / np.maximum(area, 1e-30)[:, None]
        sub = pieces.tris(origin)[part]
        # far field: one point emitter per partly lit face at its lit pieces' power centroid (the sums over
        # each face's pieces as products with a (faces x pieces) weight matrix: a few small products in
        # place of per-column bincounts and a reduceat over the table's columns)
        par, first, inv = np.unique(pieces.parent[part], return_index=True, return_inverse=True)
        a = pieces.area[part]
        w = a * share[part]
        to_face = np.zeros((len(par), len(part)))
        to_face[inv, np.arange(len(part))] = w
        w_face = to_face.sum(1)
        A = np.bincount(inv, a, len(par))
        c = (to_face @ sub.mean(1)) / w_face[:, None]
        to_face[inv, np.arange(len(part))] = a
        power = to_face @ rad
        nrm = pieces.normal[part[first]]
        to_face[inv, np.arange(len(part))] = w / w_face[inv]
        far_seen = to_face @ coarse[part]
        # the pieces run by run (rows of a face alike lit: one polygon where every piece is seen, SeenEmitters)
        order, groups = piece_runs(part, share, pieces.parent, self._pieces[4], tris)
        at = np.empty(len(pieces), np.int64)
        at[part] = np.arange(len(part))
        sub, rad, seen = sub[at[order]], rad[at[order]], table.seen[order]
        uploaded = self._emitters.set(sub, rad, seen, table.res, PIECE_POINT_TOLERANCE, capacity=len(pieces),
                                      groups=groups)
        extra = ExtraEmitters(sub, rad, seen, table.res, len(pieces), c, 2.0 * A[:, None] * nrm,
                              power / A[:, None], far_seen, PIECE_POINT_TOLERANCE, uploaded)
        return tri_rad, extra

    def _pieces_of(self, pv: np.ndarray, pf: np.ndarray, tris: np.ndarray, proxy_occ: Occluder,
                   radius: float) -> tuple[SunlitPieces, TriangleVisibility, np.ndarray]:
        """The SunlitPieces of this proxy shape, their visibility table (the directions each piece
        sees out of the object, PIECE_TABLE_RES cells per cube side) and that table as the share of
        each of CUBE_RES^2 cells per cube face it sees (S, 6 CUBE_RES^2) float, kept for the last shape
        (object_light.shape_key)."""
        key = shape_key(pv, pf)
        if self._pieces is None or self._pieces[0] != key:
            pieces = SunlitPieces(self.light, tris, proxy_occ, size=radius * PIECE_SIZE)
            table = TriangleVisibility(pieces.tris(tris.reshape(-1, 3).mean(0)), proxy_occ, res=PIECE_TABLE_RES) \
                if len(pieces) else None
            k = PIECE_TABLE_RES // CUBE_RES
            coarse = table.seen.reshape(-1, 6, CUBE_RES, k, CUBE_RES, k).mean((3, 5)).reshape(len(pieces), -1) \
                if table is not None else None
            count = np.bincount(pieces.parent, minlength=len(tris))  # pieces per face (object_emitters)
            E_face = np.zeros(len(tris))  # the faces' cos toward the sun (object_emitters: of the wholly lit ones)
            E_face[pieces.parent] = pieces.cos
            self._pieces = (key, pieces, table, coarse, _piece_rows(pieces.tris0, pieces.parent, tris - pieces.origin),
                            (count, E_face))
        return self._pieces[1:4]

    def refine_clipped_edges(self, camera, cam_occ: Occluder, mesh, own: Occluder, L_vert: np.ndarray,
                             sun_vis: np.ndarray | None, albedo: np.ndarray, cov: np.ndarray, obj_rad: np.ndarray,
                             clipped: np.ndarray, s: int | None = None, groups: np.ndarray | None = None
                             ) -> np.ndarray:
        """Coverage and object radiance re-sampled with s x s rays (default edge_samples) on the object's outline pixels
        that touch clipping light (in place on cov (H,W) and obj_rad (H,W,3)); returns those pixels.

        Outline: pixels partly covered, or uncovered/covered ones beside a pixel that is not;
        clipping: the photo clips there or next to it (`clipped` (H*W,) bool, a sunlit floor) or
        the object's radiance there or next to it reaches the photo's white level in some channel (a
        sunlit face; self.white, the response's radiance at level 255: it scales as 1 / exposure).
        Object radiance per ray: L_vert interpolated, with the sun per hit (its
        self-shadow edge: rays on the faces it crosses, SunLight.hit_correction; sun_vis (V,) the
        vertices' sun share; groups: the mesh's faces before own_cuts' cut, SunLight.hit_codes) as
        ObjectShading.shade does.

        Adaptive: `edge_first` rays (the s x s grid's corners, first_samples) are cast on every outline
        pixel and the other s*s - edge_first only where some of those reach the object and some do not; of
        the ~3 px wide outline band the edge crosses ~1 px, so most pixels are wholly on or off the object
        and keep their corner rays' coverage (0 or 1) and mean radiance. The corners span the hull of all
        s x s sub-samples, so a pixel crossed by one straight edge is never missed; what is: a corner of
        the outline or a part thinner than a pixel that passes between all 4, and radiance averaged over 4
        points instead of s*s on wholly covered pixels."""
        H, W = cov.shape
        s = s or self.edge_samples
        v, n, f = mesh
        bx, by, bw, bh = cv2.boundingRect((cov != 0).view(np.uint8))  # the covered pixels' box (one pass)
        if bw == 0:
            return np.zeros(0, np.int64)
        # the object's box and 2 pixels around it: every outline pixel and its 3x3 window lie inside
        y0, y1 = max(by - 2, 0), min(by + bh + 2, H)
        x0, x1 = max(bx - 2, 0), min(bx + bw + 2, W)
        bright = (obj_rad[y0:y1, x0:x1] >= self.white).any(-1) | clipped.reshape(H, W)[y0:y1, x0:x1]
        on = (cov[y0:y1, x0:x1] > 0).astype(np.uint8)
        box = np.ones((3, 3), np.uint8)
        near_on = cv2.dilate(on, box) > 0
        inner = cv2.erode(on, box, borderType=cv2.BORDER_REPLICATE) > 0
        near_bright = cv2.dilate(bright.astype(np.uint8), box) > 0
        outline = near_on & ~inner & near_bright  # partly covered pixels are never inner
        py, px = np.nonzero(outline)
        if len(py) == 0:
            return np.zeros(0, np.int64)
        order = np.r_[0:len(py):2, 1:len(py):2]  # every other pixel first: the two halves of the launch
        py, px = py[order] + y0, px[order] + x0  # both spread over the outline (as much work each)
        # s x s rays a pixel against the object, each that reaches it depth-tested against the room (one launch):
        # edge_first of them on every pixel, the rest only where those disagree (the outline crosses the pixel)
        n_sub = s * s
        first = n_sub if self.edge_first is None else min(self.edge_first, n_sub)
        # each hit shaded in the same launch (the vertex blend of L_vert; the sun per hit on the faces with a
        # sunlit corner, as SunLight.hit_correction: on the others both it and the blend it replaces are 0)
        sun = None
        if sun_vis is not None:
            sun = (sun_vis, self.light.hit_codes(n, f, sun_vis, groups), albedo, self.E_perp,
                   self.light.mesh_ids([own]), 1e-3, self.light.tan_a)
        c, mean, _ = self._outline(
            own, cam_occ, camera.centre, camera.R.T @ np.linalg.inv(camera.K), px, py, s, mesh, L_vert, sun,
            functools.partial(runtime.split, device=self.device, min_items=max(1, EDGE_MIN_RAYS // first)), first)
        cov[py, px] = c
        obj_rad[py, px] = np.where(c[:, None] > 0, mean, obj_rad[py, px])
        return py * W + px


def upright_box(points: np.ndarray, pad: float = 1e-3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The smallest box about `points` (N,3) m with one axis along world +Y (up) and its other two turned
    about it (the least-area rectangle of the points seen from above, cv2.minAreaRect), grown `pad` m:
    (centre (3,), axes (3,3) orthonormal rows, half sides (3,)). An object standing on a floor turned
    against the world's axes fills its axis-aligned box's corners poorly (a square turned 30 degrees: 1.9x
    the area seen from above); this box bounds it as tightly whatever its turn."""
    pts = np.asarray(points, np.float64)
    xz = pts[:, [0, 2]]
    o = xz.mean(0)
    corners = cv2.boxPoints(cv2.minAreaRect((xz - o).astype(np.float32))).astype(np.float64) + o
    e1, e2 = corners[1] - corners[0], corners[2] - corners[1]
    n1, n2 = np.linalg.norm(e1), np.linalg.norm(e2)
    if n1 < 1e-9 or n2 < 1e-9:  # points on a vertical line or plane: the axis-aligned box
        lo, hi = pts.min(0) - pad, pts.max(0) + pad
        return 0.5 * (lo + hi), np.eye(3), 0.5 * (hi - lo)
    u = np.array([e1[0], 0.0, e1[1]]) / n1
    w = np.array([-u[2], 0.0, u[0]])
    axes = np.stack([u, [0.0, 1.0, 0.0], w])
    loc = pts @ axes.T
    lo, hi = loc.min(0) - pad, loc.max(0) + pad
    return axes.T @ (0.5 * (lo + hi)), axes, 0.5 * (hi - lo)


def patch_clusters(patches) -> tuple[np.ndarray, int]:
    """(cluster (P,) int, count): the patches of one quad whose centres fall in one cube of twice
    the median patch side (about 2 x 2 patches)."""
    side = 2.0 * float(np.median(np.sqrt(patches.area)))
    key = np.column_stack([patches.quad, np.floor(patches.centre / side).astype(np.int64)])
    _, cl = np.unique(key, axis=0, return_inverse=True)
    cl = cl.ravel()
    return cl, int(cl.max()) + 1


def cluster_weights(patches) -> tuple[np.ndarray, int, np.ndarray]:
    """(cluster (P,), count, w (P,)): patch_clusters and each patch's weight in its cluster's
    area-weighted mean (its area over the cluster's)."""
    cl, n = patch_clusters(patches)
    area = np.asarray(patches.area, np.float64)
    return cl, n, area / np.bincount(cl, area, n)[cl]


def _weighted_centres(w: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """(J,3) each patch's centre of its sample points pts (J,K,3) weighted by w (J,K); the plain
    mean where the weights are all 0."""
    tot = w.sum(1)
    return np.where(tot[:, None] > 0, np.einsum("pk,pkc->pc", w, pts) / np.maximum(tot, 1e-30)[:, None],
                    pts.mean(1))


def _pass(Q: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Q_c x_c per channel (3,C) for Q (3,C,C), x (3,C) float32: each row's dot product with its channel's x
    (np.vecdot: a BLAS dot per row, not threaded at these lengths), not a matrix-vector BLAS call (threaded)."""
    return np.vecdot(Q, x[:, None, :])


class LaterBounces:
    """The later bounces of a first-bounce change of patch radiance dB1, at the receiver vertices:
    G_v sum_{k=1}^{n} (rho G)^k dB1, on clusters of neighbouring patches (patch_clusters).

    A change is carried as its area-weighted mean over each cluster (S, C x P) and sent through the
    clusters' summed transfers (exact where it is constant on a cluster). The first pass from the
    `exact` patches (the sunlit ones, where the object's sun shadow falls: a large, sharp loss whose
    first bounce lights the walls beside it unevenly) is kept exact at the receivers. Per scene, per
    channel c (float32):
      Q_c = S diag(rho_c) G_cl (C,C), G_cl (P,C) G's columns summed per cluster: one pass;
      V = G_v's columns summed per cluster (Vr,C): to the receiver vertices;
      H_c = G_v diag(rho_c) G[:, exact] (Vr,E): the exact patches' first pass at the receivers;
      W_c = S diag(rho_c) G[:, exact] (C,E): their first pass on the clusters, for the later passes;
      QW_c = Q_c W_c (C,E): and the pass after it.
    Per frame: y_1 = Q S dB1' + W dB1[exact] (dB1': dB1 off the exact patches), y_{k+1} = Q y_k;
    result H dB1[exact] + V (Q S dB1' + y_2 + ... + y_n). Work per frame ~ C^2, not P^2, and none for
    a part that is zero (the sun's loss lies on the exact patches only: its y_2 is QW dB1[exact]).
    With `onto` (__call__) the two passes to the receivers are left to the caller's one pass through
    G_v at the patches: V t = G_v t[cluster] and H e = G_v (rho G[:, exact] e), the same sums."""

    def __init__(self, G: np.ndarray, G_v: np.ndarray, albedo: np.ndarray, patches, exact: np.ndarray | None = None):
        import scipy.sparse as sp

        self.key = (id(G), id(G_v), id(albedo))
        cl, n, self.w = cluster_weights(patches)  # w: area-weighted mean over each cluster
        P = len(cl)
        self.cluster, self.n = cl, n
        sum_cols = sp.csr_matrix((np.ones(P, np.float32), (np.arange(P), cl)), shape=(P, n))  # (P,C)
        sum_rows = sum_cols.T.tocsr()  # (C,P)
        G32, G_v32 = np.asarray(G, np.float32), np.asarray(G_v, np.float32)
        G_cl = np.ascontiguousarray((sum_rows @ G32.T).T, np.float32)  # (P,C): G's columns summed per cluster
        self.exact = np.zeros(0, np.int64) if exact is None else np.unique(np.asarray(exact, np.int64))
        self.is_exact = np.zeros(P, bool)
        self.is_exact[self.exact] = True
        G_ex = G32[:, self.exact]  # (P,E)
        Q, W, H = [], [], []
        for c in range(3):
            rho = albedo[:, c].astype(np.float32)
            S_c = sp.csr_matrix(((self.w * rho).astype(np.float32), (cl, np.arange(P))), shape=(n, P))
            Q.append(S_c @ G_cl)  # (C,C)
            W.append((S_c @ G_ex).T)  # (E,C)
            H.append(G_v32 @ (rho[:, None] * G_ex))  # (Vr,E)
        self.Q = np.ascontiguousarray(np.stack(Q), np.float32)  # (3,C,C)
        self.W = np.ascontiguousarray(np.stack(W), np.float32)  # (3,E,C)
        self.H = np.ascontiguousarray(np.stack(H), np.float32)  # (3,Vr,E)
        self.QW = np.ascontiguousarray(np.matmul(self.W, self.Q.transpose(0, 2, 1)), np.float32)  # (3,E,C): W then Q
        self.V = np.ascontiguousarray((sum_rows @ G_v32.T).T, np.float32)  # (Vr,C)
        rest = np.flatnonzero(~self.is_exact)
        # (C,P) float64: a change's area-weighted mean over each cluster off the exact patches (theirs: 0), one
        # sparse product (each cluster's terms summed in patch order, as np.bincount would)
        self.mean_rest = sp.csr_matrix((self.w[rest], (cl[rest], rest)), shape=(n, P))
        self.G_ex = np.ascontiguousarray(G_ex.T)  # (E,P): the exact patches' rows of G's pass (onto)
        self.rho = np.asarray(albedo, np.float64)

    def __call__(self, dB1: np.ndarray, n: int, later: np.ndarray | None = None,
                 onto: np.ndarray | None = None) -> np.ndarray | None:
        """G_v sum_{k=1}^{n} (rho G)^k dB1 (Vr,3) for dB1 (P,3), plus the same of `later` (P,3) with one
        pass fewer (k = 1 .. n-1: a change with one more reflection made), both in one run: their
        first passes side by side, then one chain of passes in which `later` joins a pass late (the
        passes through Q are linear). With `onto` (P,3): sum_{k=1}^{n} (rho G)^k dB1 (and later's) added
        to it at the patches instead (the caller passes it through G_v once); returns None. The
        products are not threaded BLAS calls (a threaded BLAS on a loaded machine took 40-60 ms for what
        takes 1-2 ms here): the passes through Q are row-by-vector dot products (np.vecdot: one BLAS dot of
        C terms per row, as fast with OpenBLAS on one thread as on two; for sun_room's C = 953, 0.2 ms against
        the einsum's 0.52 with Q in cache, 0.39 against 0.55 with Q read from memory), the rest einsums."""
        if later is not None and (n <= 1 or not np.any(later)):
            later = None
        if n <= 0 or (not np.any(dB1) and later is None):
            return None if onto is not None else np.zeros((len(self.V), 3))
        parts = []  # per change: (its first pass on the clusters of the rest (3,C) or None, exact part (E,3))
        for x in ((dB1, later) if later is not None else (dB1,)):
            xm = self.mean_rest @ x  # (C,3): S x' on the clusters
            a = None
            if xm.any():
                a = _pass(self.Q, np.ascontiguousarray(xm.T, np.float32))
            parts.append((a, x[self.exact]))
        total = np.zeros((3, self.n), np.float32)  # the passes on the clusters, summed
        for a, _ in parts:
            if a is not None:
                total += a
        xe = sum(e for _, e in parts)  # (E,3): the exact patches' first pass at the receivers
        z = None
        for k in range(n - 1):
            if k == 0:  # the second pass of dB1: Q y_1 = Q (Q S dB1') + QW dB1[exact]
                a, e = parts[0]
                nz = np.flatnonzero(e.any(1))
                z = np.einsum("cek,ec->ck", self.QW[:, nz], e[nz].astype(np.float32))
                if a is not None:
                    z += _pass(self.Q, a)
            else:
                if k == 1 and len(parts) > 1:  # later's chain joins: its y_1 = Q S later' + W later[exact]
                    a, e = parts[1]
                    nz = np.flatnonzero(e.any(1))
                    z = z + np.einsum("cek,ec->ck", self.W[:, nz], e[nz].astype(np.float32))
                    if a is not None:
                        z = z + a
                z = _pass(self.Q, z)
            total += z
        nz = np.flatnonzero(xe.any(1))
        if onto is not None:
            # G_v's: H e; the exact patches' rows gathered only where few are non-zero (a zero row adds nothing)
            xz, Gz = (xe.T.astype(np.float32), self.G_ex) if 2 * len(nz) >= len(xe) else \
                (xe[nz].T.astype(np.float32), self.G_ex[nz])
            onto += self.rho * np.einsum("ce,ep->cp", xz, Gz).T
            onto += total.T[self.cluster]  # G_v's pass of each patch its cluster's is V total
            return None
        out = np.einsum("cve,ec->vc", self.H[:, :, nz], xe[nz].astype(np.float32))
        return out + np.einsum("vk,ck->vc", self.V, total)


@dataclass
class SunPixels:
    """What the sun changes of the scene's per-scene arrays (SunSetup.apply): new arrays, the
    receiver map's own are left as they were."""

    patches: PatchMesh  # the patch mesh with the emission and reflectivity the sun leaves (captured/photo)
    recv_pix: np.ndarray  # (H*W,) bool receivers, sunlit patches' pixels added (captured/photo)
    E_x: np.ndarray  # (H*W,3) irradiance/pi, the direct sun added on sunlit pixels
    L_b: np.ndarray  # (H*W,3) photo radiance, at least the model's rho E_x in a sunlit pixel's clipped channels
    rho_pix: np.ndarray | None = None  # (N,) pixels whose reflectance is the surface's albedo (clipped, edge)
    rho: np.ndarray | None = None  # (N,3) that albedo
    pix: np.ndarray | None = None  # (S,) the sunlit receiver pixels (None: the sun lights no surface)
    stage: SunStage | None = None  # the sun's per-frame work
    photo_clip: np.ndarray | None = None  # (H*W,) bool: the photo clips (some channel at 254 or more)

    def reflectance(self, rho_x: np.ndarray) -> np.ndarray:
        """rho_x (H*W,3) with the sun's albedo on the clipped and edge pixels (in place; returned)."""
        if self.pix is not None:
            rho_x[self.rho_pix] = self.rho
        return rho_x


class SunSetup:
    """Which sun lights the room (EngineParams.sun under its lighting) and what it changes once per
    scene: the direct sun joins E_x, clipped sunlit pixels take the model's radiance, and under
    captured or photo light the sun estimated from the photo turns the sunlit patches the radiance
    flagged as emitters back into reflectors (apply, on its own copy of the patch mesh).

    The sunlit patch clips in the photo: there L_b is a floor, not the radiance, and a shadow term
    that is a share of L_b would be far too small. In the clipped channels of sunlit pixels L_b is
    raised to the model's radiance rho x (E_x + E_sun), rho the surface's albedo (declared texture, or
    the patch reflectivity the captured light recovered), so the sun's shadow there is the absolute
    rho x E_sun x occluded share; a channel below the clip level is a measurement and stays.

    Under photo light the engine then fits the photo again with each patch's share in the estimated sun
    (sun_share), so that the sunlit patches out of view join the fit's clipped region, and applies a new
    SunSetup to that fit (app.engine.Engine._refit_sunlit)."""

    def __init__(self, scene: Scene, lighting: str, choice: str, scene_occ: Occluder, patches: PatchMesh,
                 bounces: int | None = None):
        """Known light lights the precompute with the declared sun; captured and photo light take the
        declared one or the estimate in apply(), after the precompute. ValueError when --sun declared
        has no sun entry. bounces: the estimate's strength gathers one bounce less than the radiance
        (lighting.sun._sun_strength's `bounces`; photo light once its fit has the bounce levels, app.engine
        Engine._sun_bounces); None: as measured."""
        self.scene, self.lighting, self.scene_occ = scene, lighting, scene_occ
        self.bounces = bounces
        self.where = str(scene.meta.get("json_path", scene.name))
        self.source = self._source(choice)  # "declared", "estimate" or None (no sun)
        self.patches = patches  # apply() works on a copy of the precompute's (its emission and reflectivity)
        self.light: SunLight | None = None
        self.estimate: dict | None = None  # the photo's sun estimate (lighting.sun.estimate_sun's info)
        self._patch_light: np.ndarray | None = None
        if self.source == "declared" and lighting == "known":
            self.light = SunLight(scene.sun, openings(scene), scene_occ, where=f"{self.where}: sun")

    def _source(self, choice: str) -> str | None:
        sun, lighting = self.scene.sun, self.lighting
        if choice == "declared" and sun is None:
            raise ValueError(f"{self.where}: --sun declared: the scene has no sun entry (`photoar scene "
                             "--sun-direction/--sun-irradiance` writes one)")
        if lighting == "known":
            if sun is not None and sun.strength_estimated:
                raise ValueError(f"{self.where}: sun: its strength is to be estimated from the photo "
                                 "(\"strength\": \"estimate\"): use --lighting captured, or give `photoar scene "
                                 "--sun-irradiance`")
            return "declared" if sun is not None else None
        if lighting == "captured":
            if choice == "auto":
                user = sun is not None and self.scene.meta.get("sun_declared_by") == SUN_DECLARED_BY_USER
                return "declared" if user else "estimate"
            return choice
        return "estimate"  # photo: from the photo alone (as captured light's estimate)

    def patch_light(self) -> np.ndarray:
        """Direct sun irradiance/pi (P,3) averaged over each patch (computed once per sun)."""
        if self._patch_light is None:
            pm = self.patches
            self._patch_light = np.zeros((pm.n_patches, 3))
            if self.light is not None and self.light.active:
                self._patch_light = self.light.patch_irradiance(pm.corners, pm.normal, ~pm.is_emitter)
        return self._patch_light

    @property
    def on(self) -> bool:
        """True when the sun lights some surface: it then takes one pass of every frame."""
        return self.light is not None and self.light.active and self.patch_light().any()

    def report(self) -> dict:
        """The sun used (report.json "sun"): from "declared" or "estimate", its unit direction towards
        the sun (world, +Y up), irradiance_perpendicular (RGB, scene radiance units x sr), and whether
        it lights some surface (lights_room; else no_direct_sun says why)."""
        sun = self.light.sun
        d = {"from": self.source, "direction": (sun.direction / np.linalg.norm(sun.direction)).tolist(),
             "irradiance_perpendicular": np.asarray(sun.irradiance, float).tolist(), "lights_room": bool(self.on)}
        if self.source == "declared" and self.scene.sun.strength_estimated:
            d["strength_from"] = "estimate"  # the declared direction, the strength estimated from the photo
        if self.light.reason:
            d["no_direct_sun"] = self.light.reason
        return d

    def apply(self, pre, rm, device: str) -> SunPixels:
        """The sun's changes to the receiver map `rm` (app.stages.receiver_map) of the precompute `pre`."""
        E_x, L_b, recv_pix = rm.E_x.copy(), rm.L_b.copy(), rm.recv_pix.copy()
        self.patches = copy.copy(pre.patches)
        self.patches.emission, self.patches.albedo = pre.patches.emission.copy(), pre.patches.albedo.copy()
        if self.lighting in ("captured", "photo"):  # the sun estimated from the photo (no probe: photo)
            self._estimate(pre, rm, E_x, recv_pix)
        out = SunPixels(self.patches, recv_pix, E_x, L_b)
        if not self.on:
            return out
        scene, pm, cam = self.scene, self.patches, self.scene.camera
        pix_patch, pix_pos = rm.pix_patch, rm.pix_pos
        rp = np.flatnonzero(recv_pix)
        nrm = pm.normal[pix_patch[rp]]
        vis = self._ring_share(rp, nrm, self.light.visibility(pix_pos[rp], nrm), rm, E_x, L_b)
        lit = vis > 0
        out.pix = rp[lit]
        E_sun = vis[lit, None] * (self.light.sun.irradiance / np.pi)  # the estimate with captured light
        E_x[out.pix] += E_sun
        # pixel footprint on the surface (m): filter radius of the shadow lookup (box ~ disk)
        depth = pre.pix_depth[out.pix].astype(np.float64)
        cos_v = np.abs(np.einsum("nc,nc->n", rm.dirs[out.pix], nrm[lit]))
        footprint = 0.5 * depth / cam.K[0, 0] / np.sqrt(np.maximum(cos_v, 0.05))
        pts = pix_pos[out.pix] + nrm[lit] * 1e-3
        # pixels next to the sunlit ones (partly sunlit, centre in shade) and the clipped ones: the
        # photo's L_b / E_x is no reflectance there; take the surface's albedo
        H, W = cam.height, cam.width
        lit_img = np.zeros(H * W, bool)
        lit_img[out.pix] = True
        near = np.zeros(H * W, bool)
        for dy, dx, src, dst in window_pairs(H, W):
            near[dst] |= lit_img[src]
        edge = np.flatnonzero(near & ~lit_img & recv_pix)
        # clipped sunlit pixels: model radiance instead of the photo's floor, channel by channel (a channel
        # below the clip level is a measurement: a dark plank in the sun clips in red only, and its green
        # and blue taken from the model would brighten it where nothing changes)
        clip_c = scene.photo.reshape(-1, 3)[out.pix] >= CLIP_LEVEL
        sat = clip_c.any(1)
        idx, clip_c = out.pix[sat], clip_c[sat]
        rho = self._albedo(pm, pix_patch, pix_pos, idx)
        L_b[idx] = np.where(clip_c, np.maximum(L_b[idx], rho * E_x[idx]), L_b[idx])
        rho = np.where(clip_c, rho, reflectance(L_b[idx], E_x[idx]))  # the measured channels' own
        out.rho_pix = np.concatenate([idx, edge])
        out.rho = np.concatenate([rho, self._albedo(pm, pix_patch, pix_pos, edge)])
        # sample points of sunlit patches (second order: the patches' lost sun)
        lit_c = np.flatnonzero(self.patch_light().any(1))
        n_side = 4
        f = (np.arange(n_side) + 0.5) / n_side
        fu, fv = [a.ravel() for a in np.meshgrid(f, f)]
        c0 = pm.corners[lit_c, 0]
        c_pts = (c0[:, None] + fu[None, :, None] * (pm.corners[lit_c, 1] - c0)[:, None]
                 + fv[None, :, None] * (pm.corners[lit_c, 3] - c0)[:, None]).reshape(-1, 3)
        nrm_c = np.repeat(pm.normal[lit_c], len(fu), axis=0)
        c_vis = self.light.visibility(c_pts, nrm_c).reshape(len(lit_c), len(fu))
        out.photo_clip = (scene.photo.reshape(-1, 3) >= CLIP_LEVEL).any(1)
        out.stage = SunStage(self.light, pts, footprint, E_sun, lit_c, c_pts + nrm_c * 1e-3, c_vis, pm.n_patches,
                             device, patches=pm, white=scene.response.to_radiance(np.full((1, 3), 255, np.uint8))[0])
        return out

    def sun_share(self) -> np.ndarray:
        """(P,) in [0, 1]: each reflector's sunlit share (its mean direct sun over that of a wholly sunlit patch
        at its cos; patches with cos <= 0.2, as lighting.sun._sun_strength leaves them, and emitters 0); all 0
        without a sun on some surface."""
        pm = self.patches
        if not self.on:
            return np.zeros(pm.n_patches)
        cos = np.maximum(pm.normal @ self.light.d, 0.0)
        full = luminance(self.light.sun.irradiance / np.pi)
        share = luminance(self.patch_light()) / max(full, 1e-300)
        return np.where((cos > 0.2) & ~pm.is_emitter, np.clip(share / np.maximum(cos, 1e-9), 0.0, 1.0), 0.0)

    def sunlit_patches(self) -> np.ndarray:
        """(P,) bool: the reflectors the sun lights (none without a sun on some surface; under known
        light at the radiosity's radiance, which holds the sun).
        The object gathers them exactly (lighting.irradiance.RoomLight.gather_exactly), not through
        the SH volume: a sunlit patch is several times brighter than the rest of the room and often a
        few cm from the object (it stands in it), where the 0.25 m SH9 grid's broad lobe spreads it."""
        if not self.on:
            return np.zeros(self.patches.n_patches, bool)
        return self.patch_light().any(1) & ~self.patches.is_emitter

    def object_radiance(self, pre, B_src: np.ndarray) -> np.ndarray:
        """The patch radiance (P,3) the object gathers the room's light from (its SH volume and exact
        gather), after apply(): B_src, with the model's rho x (E_ind + E_sun) on the sunlit patches
        the photo does not measure (captured and photo light, a sun that lights the room).

        Under captured light B_src is measured: a patch with origin PHOTO (lighting.radiance)
        by its unclipped photo pixels, which stays. A sunlit patch whose photo pixels clip has only
        the probe's view of it (coarse: the sun patch's edge is smeared over its neighbours, a few
        probe pixels at grazing angles); a sphere standing in the patch then gathers far too little
        from the floor under it. Under photo light (lighting.photolight) such a patch is fitted as a
        clipped emitter group whose radiance is whatever the walls ask of it, held at least at the
        white level: a floor as bright as the photo's white, not as the sun makes it. The sun
        estimated from this photo already implies that radiance: rho (the surface's reflectivity, set
        by _estimate) times the gathered light E_ind = G_c B_src plus the sun's share on the patch
        (patch_light: the patch's sunlit fraction x cos x E_sun). A patch with no reflectivity (rho 0:
        an emitter kept, or a sunlit surface with no unlit patch to lend it one) keeps its
        measurement. B_src itself when nothing changes (known light: the sun is in the radiosity; no
        sun; no such patch)."""
        if self.lighting not in ("captured", "photo") or not self.on:
            return B_src
        pm, sun = self.patches, self.patch_light()
        lit = (sun.any(1) & ~pm.is_emitter & (np.asarray(pre.origin) != PHOTO)
               & (luminance(pm.albedo) > 0))
        if not lit.any():
            return B_src
        out = np.array(B_src, np.float64, copy=True)
        E_ind = pre.G_c[lit].astype(np.float64) @ np.asarray(B_src, np.float64)
        out[lit] = pm.albedo[lit] * (E_ind + sun[lit])
        # photo light's one info line says what it did to its fit (captured light's measurement: debug)
        (log.info if self.lighting == "photo" else log.debug)(
            "%s light: the sun lights %d patches the photo shows clipped; the object sees them as lit by the "
            "estimated sun (mean luminance %.3g, the photo's clipped value %.3g)", self.lighting, int(lit.sum()),
            float(luminance(out[lit]).mean()), float(luminance(np.asarray(B_src)[lit]).mean()))
        return out

    def _ring_share(self, rp: np.ndarray, nrm: np.ndarray, vis: np.ndarray, rm, E_x: np.ndarray,
                    L_b: np.ndarray) -> np.ndarray:
        """The sun's visibility vis (R,) (cos x sunlit, at pixel centres) of the receiver pixels rp,
        with the sun's share the photo measures on the two pixel rings along the sunlit region's
        outline: its outer lit pixels and the unlit ones beside them. A pixel the outline crosses is
        partly sunlit in the photo, while its centre is wholly lit or wholly not: taken at its centre,
        the sun's shadow leaves a dark line on the lit side (the photo's partial light over the full
        sun) and a bright one on the other (light the object's shadow never removes).
        Share s = (L_b / rho - E_ind) / E_sun (luminance, clipped to [0, 1]; rho the surface's albedo,
        E_ind the light without the sun, E_sun its full direct light there); on a lit pixel that clips
        the photo is a floor and the share stays 1."""
        cam, pm, pix_patch = self.scene.camera, self.patches, rm.pix_patch
        H, W = cam.height, cam.width
        lit_img = np.zeros(H * W, bool)
        lit_img[rp[vis > 0]] = True
        lit_nb, unlit_nb = np.zeros(H * W, bool), np.zeros(H * W, bool)
        for _, _, src, dst in window_pairs(H, W):
            lit_nb[dst] |= lit_img[src]
            unlit_nb[dst] |= ~lit_img[src]
        cos = np.maximum(nrm @ self.light.d, 0.0)
        ring = np.flatnonzero(np.where(vis > 0, unlit_nb[rp], lit_nb[rp] & (cos > 0)))
        if len(ring) == 0:
            return vis
        px = rp[ring]
        rho = self._albedo(pm, pix_patch, rm.pix_pos, px)
        E_sun = cos[ring, None] * (self.light.sun.irradiance / np.pi)
        with np.errstate(divide="ignore", invalid="ignore"):
            share = (luminance(L_b[px] / np.maximum(rho, 1e-6) - E_x[px])
                     / np.maximum(luminance(E_sun), 1e-30))
        share = np.clip(np.nan_to_num(share), 0.0, 1.0)
        clipped = (self.scene.photo.reshape(-1, 3)[px] >= CLIP_LEVEL).any(1)
        share = np.where(clipped & (vis[ring] > 0), 1.0, share)
        out = vis.copy()
        out[ring] = share * cos[ring]
        return out

    def _albedo(self, pm: PatchMesh, pix_patch: np.ndarray, pix_pos: np.ndarray, idx: np.ndarray) -> np.ndarray:
        """The surface's albedo (N,3) at pixels idx: the declared texture's under known light, else the
        patch reflectivity the light recovered."""
        if self.lighting == "known":
            return surface_albedo(self.scene, pm.quad[pix_patch[idx]], pix_pos[idx].astype(np.float64),
                                  pm.albedo[pix_patch[idx]])
        return pm.albedo[pix_patch[idx]]

    def _emitting(self, pm: PatchMesh, B: np.ndarray) -> PatchMesh:
        """pm for the strength's bounce model (self.bounces): photo light marks its emitters with emission 1 (app.
        stages.precompute.fit_photo_light); the model needs their radiance B (P,3), as captured light's mesh holds
        it. pm itself without bounces or under captured light."""
        if not self.bounces or self.lighting != "photo":
            return pm
        out = copy.copy(pm)
        out.emission = np.where(np.any(pm.emission > 0, axis=1)[:, None], B, 0.0)
        return out

    # captured light: the sun's strength by the bounce rule (lighting.sun._sun_strength's `bounces`) with each patch
    # at the bounce level it was measured at (the probe's one fewer than the photo's: lighting.radiance.
    # measured_levels), and the sunlit patches take the reflectivity that rule found. Opt-in (docs/unseen.md
    # "spur111"): the strength comes within 1.02x / 0.95x / 0.96x of the truth's in sun_110 / 108 / 104 (1.15x /
    # 1.04x / 1.08x before) and sun_110's and sun_108's spurious and energy come right, but sun_104's captured energy
    # jumps over its bound (the too strong sun hid another error there) and sun_room's floor, darker where the sun
    # falls than its unlit median, reads the sun 0.88x. False: the measured radiance gathered as it is, the sunlit
    # patches their surface's unlit median (the rule before)
    captured_bounces = False
    # with captured_bounces, which reflectivity the sunlit patches take and the strength reads (docs/unseen.md
    # "capb112"): "rule" the bounce rule's own (the unlit patches' at their level, spur111); "measured" the strength
    # by the rule, the sunlit patches their surface's unlit median as measured (the rule before); "penumbra" the
    # sunlit surface's own, from its penumbra (lighting.sunramp: the shadow level beside the ramp over the gathered
    # irradiance there), the strength then pi x step / (cos rho); "shadow" that rho, the strength the rule's rho x sun
    # over it
    captured_sunlit = "rule"

    def _estimate_bounces(self, pre) -> int | None:
        """The bounces the sun estimate's strength rule takes (lighting.sun._sun_strength's `bounces`): self.bounces;
        under captured light with captured_bounces the camera's bounces (len(pre.B) - 1: the precompute's levels);
        None: the measured radiance gathered as it is."""
        if self.bounces or self.lighting != "captured" or not self.captured_bounces:
            return self.bounces
        return len(pre.B) - 1

    def _levels(self, pre) -> np.ndarray | None:
        """(P,) the bounce level of each patch's measured radiance (lighting.radiance.measured_levels) for the
        strength's bounce rule under captured light with captured_bounces; None: all at the camera's (photo)."""
        n = self._estimate_bounces(pre)
        if not n or self.lighting != "captured" or not self.captured_bounces:
            return None
        from lighting.radiance import measured_levels

        return measured_levels(pre.origin, n)

    def _penumbra_strength(self, sun, info: dict, rm, pre, recv_any: np.ndarray):
        """captured_sunlit "penumbra": the estimated sun's strength from the sunlit surface's own penumbra
        (lighting.sunramp.sunlit_step): the step A = rho E_sun cos / pi, and rho = the shadow level beside the ramp
        over the model's gathered irradiance/pi on those pixels (no unlit floor's reflectivity borrowed), so
        E_sun = pi A / (cos rho). Of the surfaces the strength used (info["reflectivity_by_quad"]), the one with
        the most unclipped ramp pixels; that surface's sunlit patches take rho, the others their rule's rho scaled
        so that rho x sun is unchanged. The sun as given where no surface's ramp reads (too few unclipped pixels)."""
        import dataclasses as dc

        from lighting.sunramp import sunlit_step

        by_quad = info.get("reflectivity_by_quad") or {}
        if not by_quad:
            return sun
        scene, pm = self.scene, self.patches
        holes = openings(scene)
        ok = recv_any & (rm.pix_rows.min(1) >= 0)
        E = np.zeros((len(ok), 3))
        E[ok] = np.einsum("nk,nkc->nc", pre.pix_bary[ok], rm.E_v[rm.pix_rows[ok]])
        pix_quad = np.where(rm.pix_patch >= 0, pm.quad[np.maximum(rm.pix_patch, 0)], -1)
        best = None
        for q in sorted(int(k) for k in by_quad):
            quad = scene.quads[q]
            st = sunlit_step(lambda d: SunLight(dc.replace(sun, direction=d), holes, self.scene_occ,
                                                where="sun penumbra"),
                             scene.camera, scene.photo, rm.L_b, pix_quad, rm.pix_pos, ok, q,
                             (quad.corners[0], quad.normal), sun.direction, E=E)
            if st is None or st.shadow_irradiance is None or np.any(st.shadow_irradiance <= 0):
                continue
            if best is None or st.n_ramp > best.n_ramp:
                best = st
        if best is None:
            info["penumbra"] = "no surface's penumbra reads"
            return sun
        q = best.quad
        cos = float(scene.quads[q].normal @ (sun.direction / np.linalg.norm(sun.direction)))
        rho = best.shadow / best.shadow_irradiance
        if cos <= 0.2 or np.any(rho <= 0):
            info["penumbra"] = "the penumbra's surface faces away from the sun"
            return sun
        if self.captured_sunlit == "shadow":  # rho x sun as the rule measured it, rho the surface's own
            E_new = np.asarray(sun.irradiance, np.float64) * np.asarray(by_quad[str(q)]) / rho
        else:
            E_new = np.pi * best.step / (cos * rho)
        scale = np.asarray(sun.irradiance, np.float64) / np.maximum(E_new, 1e-12)
        info["reflectivity_by_quad"] = {k: (rho if int(k) == q else np.asarray(r) * scale).tolist()
                                        for k, r in by_quad.items()}
        info["penumbra_rho"] = [round(float(v), 4) for v in rho]
        info["penumbra"] = {**best.report(), "irradiance_rule": [float(v) for v in sun.irradiance],
                            "rho_rule": [float(v) for v in by_quad[str(q)]]}
        info["irradiance_perpendicular"] = E_new.tolist()
        return dc.replace(sun, irradiance=E_new)

    def _estimate(self, pre, rm, E_x: np.ndarray, recv_pix: np.ndarray) -> None:
        """Captured or photo light: the sun estimated from the photo and the radiance mesh
        (lighting.sun.estimate_sun) replaces the declared one (or the declared one as given, --sun
        declared); the sunlit patches take the reflectivity of their surface's unlit patches and
        become receivers (recv_pix, E_x edited here: apply's copies). The declared sun, if any, is
        only reported against."""
        pm, scene = self.patches, self.scene
        if not openings(scene):
            self.light = None
            if scene.sun is not None:  # a sun with no way in (lighting.sun.no_sun_reason)
                log.warning("%s", no_sun_reason(scene.sun.direction, scene.sun.irradiance, [], f"{self.where}: sun"))
            return
        sat = np.any(scene.photo.reshape(-1, 3) >= 255, axis=1)
        pix_patch, pix_rows = rm.pix_patch, rm.pix_rows
        # the captured radiance flags the sunlit patch as an emitter (brighter than the mesh, which
        # holds no sun, can light it); the sun is looked for on every surface but windows and lamps
        shaped = np.array([q.light_shaped for q in scene.quads], bool)[pm.quad]
        recv_any = (pre.pix_tri >= 0) & (pix_rows.min(1) >= 0) & ~shaped[np.maximum(pix_patch, 0)]
        flagged = pm.is_emitter & ~shaped  # plain surfaces the radiance test flagged: tried as sunlit
        kept = pm.emission[flagged].copy()
        pm.emission[flagged] = 0.0
        if self.source == "declared" and scene.sun.strength_estimated:  # its direction; strength from the photo
            sun, info = estimate_sun(scene, pm, pix_patch, rm.pix_pos.astype(np.float64), rm.dirs, rm.L_b,
                                     sat, recv_any, pre.B[-1], pre.G_c, self.scene_occ, direction=scene.sun.direction)
            where = f"{self.where}: sun (strength estimated)"
        elif self.source == "declared":  # the user's sun as given (--sun); no estimate
            sun, info, where = scene.sun, None, f"{self.where}: sun"
        else:
            levels = self._levels(pre)
            sun, info = estimate_sun(scene, self._emitting(pm, pre.B[-1]), pix_patch, rm.pix_pos.astype(np.float64),
                                     rm.dirs, rm.L_b, sat, recv_any, pre.B[-1], pre.G_c, self.scene_occ,
                                     bounces=self._estimate_bounces(pre), levels=levels)
            where = f"{self.where}: sun estimate"
            if sun is not None and levels is not None and self.captured_sunlit in ("penumbra", "shadow"):
                sun = self._penumbra_strength(sun, info, rm, pre, recv_any)
        self._patch_light = None
        # an estimated direction was fitted with the disk's centre alone (a hard edge) to the photo's sunlit
        # outline, whose split lies inside the penumbra: the object keeps that model (docs/unseen.md "sunobj109")
        self.light = SunLight(sun, openings(scene), self.scene_occ, where=where,
                              disk=self.source == "declared") if sun else None
        if sun is None and self.source == "declared":
            log.warning("%s: its strength could not be estimated from the photo (%s): no direct sun; give "
                        "`photoar scene --sun-irradiance`", where, info.get("reason"))
        if info is not None and sun is not None and scene.sun is not None and not scene.sun.strength_estimated:
            d0 = scene.sun.direction / np.linalg.norm(scene.sun.direction)
            info["declared_direction"] = d0.tolist()
            info["direction_error_deg"] = float(np.degrees(np.arccos(np.clip(sun.direction @ d0, -1, 1))))
            info["declared_irradiance_perpendicular"] = scene.sun.irradiance.tolist()
            info["strength_ratio"] = float(luminance(sun.irradiance) / max(luminance(scene.sun.irradiance), 1e-12))
        if info is not None:
            self.estimate = info
            if sun is None and self.source == "estimate" and (sat & recv_any).any():
                # a room with an opening whose photo clips on its surfaces, and no sun: its shadow and
                # its light on the object are left out; the user must hear it (under -q too)
                log.warning("%s: %s: the photo clips on %d surface pixels but no sun was found; the "
                            "composite has no sun shadow (give `photoar scene --sun-direction` if the sun "
                            "shines in)", self.where, estimate_line(info), int((sat & recv_any).sum()))
            else:
                log.info("%s", estimate_line(info))
            log.debug("sun estimate: %s", info)
        if self.light is not None and self.light.active:
            # patches the sun lights are reflectors, not emitters: receivers of the object's shadows;
            # the other flagged ones emit again
            lit = self.patch_light().any(1)
            pm.emission[flagged & ~lit] = kept[~lit[flagged]]
            new = recv_any & ~recv_pix & lit[np.maximum(pix_patch, 0)]
            recv_pix |= new
            E_x[new] = np.einsum("nk,nkc->nc", pre.pix_bary[new], rm.E_v[pix_rows[new]])
            # sunlit patches: the photo clips there and the probe sees them coarsely; take the
            # reflectivity of the unlit patches of the same surface (as the strength estimate does: under captured
            # light with the bounce rule its own, so that rho x sun is the radiance the photo and probe measure)
            by_quad = (info or {}).get("reflectivity_by_quad", {}) \
                if self.lighting == "captured" and self._estimate_bounces(pre) and self.captured_sunlit != "measured" \
                else {}
            for q in np.unique(pm.quad[lit]):
                same = (pm.quad == q) & ~pm.is_emitter
                if str(q) in by_quad:  # the strength's own reflectivity (bounce rule): rho x sun as the photo has it
                    pm.albedo[same & lit] = np.asarray(by_quad[str(q)], np.float64)
                elif (same & ~lit).sum() >= 3:
                    pm.albedo[same & lit] = np.median(pm.albedo[same & ~lit], axis=0)
        else:
            pm.emission[flagged] = kept  # no sun: what the radiance flagged emits

    def photo_report(self, photo_light: dict) -> dict:
        """Photo light with openings: photo_light (the fit's report) with "sun": whether the sun estimated
        from the photo lights the room and how many patches it lights (the fit's clipped-region emitters
        among them marked sunlit reflectors); a declared sun that the photo does not show is warned about
        (it is never used). Without openings photo_light as it is."""
        if not openings(self.scene):
            return photo_light
        lit = self.patch_light().any(1)
        out = {**photo_light, "sun": {"modelled": bool(self.on), "sunlit_patches": int(lit.sum()),
                                      "estimate": "sun_estimate"}}
        lit_quads = {self.scene.quads[q].name for q in np.unique(self.patches.quad[lit])}
        emitters = []
        for em in photo_light.get("emitters", []):  # clipped regions the sun explains
            name, clip = em["name"].removesuffix(" (clipped region)"), em["name"].endswith(" (clipped region)")
            emitters.append({**em, "sunlit_reflector": True} if clip and name in lit_quads else em)
        if "emitters" in photo_light:
            out["emitters"] = emitters
        if not self.on and self.scene.sun is not None:
            reason = (self.estimate or {}).get("reason", "its estimate lights no surface")
            log.warning("%s: sun: --lighting photo found no sun in the photo (%s); the "
                        "declared sun is not used", self.where, reason)
        return out


def estimate_line(info: dict) -> str:
    """One short line of a sun estimate (lighting.sun.estimate_sun's info; report.json holds it whole)."""
    if "irradiance_perpendicular" not in info:
        return f"sun estimate: no sun ({info.get('reason', 'none found')})"
    line = "sun estimate: direction ({:.3f}, {:.3f}, {:.3f}), irradiance ({:.3g}, {:.3g}, {:.3g})".format(
        *info["direction"], *info["irradiance_perpendicular"])
    if "direction_error_deg" in info:
        line += f"; {info['direction_error_deg']:.2f} deg and {info['strength_ratio']:.2f}x against the declared sun"
    return line
