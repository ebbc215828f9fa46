"""The sun stage: the directional source's per-frame work (DESIGN "Per-frame stages", issue 20).

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

import functools

import cv2
import numpy as np

from app import runtime
from kernels.sunshadow import OutlineHits, SunShadowMap
from kernels.visibility import Occluder, SeenEmitters
from app.stages.object_light import CUBE_RES, ExtraEmitters, TriangleVisibility, shape_key
from lighting.sun import SunLight, SunlitPieces


PIECE_TABLE_RES = 16  # cells per cube side of the sunlit pieces' visibility table (~6 degrees): at floor
# points beside sun_room's chair their light was within 1.1 % of a Monte Carlo reference on average, as with
# a ray per piece (8 cells: 1.5 %); bench/bench_sun.py prints the pieces against Monte Carlo per pixel


EDGE_MIN_RAYS = 256  # rays per concurrent part of refine_clipped_edges's launch at least (a thread's
# hand-off costs about what a few hundred ray casts do)


PIECE_SIZE = 0.25  # the sunlit pieces' size (SunlitPieces), in bounding radii of the object


PIECE_POINT_TOLERANCE = 0.05  # a lit piece is a point emitter at a receiver where the bound of that error is
# at most this share of its unoccluded light there (kernels.visibility.emitter_sum_seen_bounded)


class SunStage:
    """The sun's per-frame work for one scene (built by Engine._sun_setup_pixels)."""

    def __init__(self, light: SunLight, pts: np.ndarray, footprint: np.ndarray, E_pix: np.ndarray,
                 c_patch: np.ndarray, c_pts: np.ndarray, c_vis: np.ndarray, n_patches: int, device: str,
                 patches=None):
        """light: the sun through the openings; pts (N,3), footprint (N,) m, E_pix (N,3): the sunlit
        pixels' lookup points, pixel footprints and direct sun; c_patch (Pc,), c_pts (Pc*K,3),
        c_vis (Pc,K): sunlit patches, their K sample points and the sun's visibility there; patches:
        the scene's PatchMesh (the clusters of later_bounces)."""
        self.light = light
        self.pts, self.footprint, self.E_pix = pts, footprint.astype(np.float32), E_pix
        self.c_patch, self.c_pts, self.c_vis = c_patch, c_pts, c_vis
        self.n_patches = n_patches
        self.E_perp = light.sun.irradiance / np.pi
        self.map = SunShadowMap(light.sun.direction, light.sun.half_angle, device=device)
        self._pix = self.map.points(pts, footprint)  # kept on the device: no buffers per frame
        self._cen = self.map.points(c_pts)
        self.device = device
        self.edge_samples = 4  # rays per side of an outline pixel (refine_clipped_edges)
        self.patches = patches
        self._later: LaterBounces | None = None  # the scene's later-bounce operators (later_bounces)
        self._pieces: tuple | None = None  # the last proxy shape's (object_emitters)
        self._outline = OutlineHits(device)  # refine_clipped_edges's rays (buffers kept)
        self._emitters = SeenEmitters(device)  # object_emitters's lit pieces on the device (buffers kept)

    def frame(self, vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The sun's pass for an object: (irradiance/pi lost at the sunlit pixels (N,3), at every
        patch (P,3), mean over its sample points)."""
        self.map.render(vertices, faces)
        occ_pix = self.map.occlusion_at(self._pix)
        occ_c = self.map.occlusion_at(self._cen).reshape(self.c_vis.shape)
        loss_c = np.zeros((self.n_patches, 3))
        loss_c[self.c_patch] = (self.c_vis * occ_c).mean(1)[:, None] * self.E_perp
        return occ_pix[:, None] * self.E_pix, loss_c

    def later_bounces(self, dB1: np.ndarray, albedo: np.ndarray, G: np.ndarray, G_v: np.ndarray,
                      bounces: int) -> np.ndarray | None:
        """G_v sum_{k=1}^{bounces-2} (rho G)^k dB1 (Vr,3): a first-bounce change of patch radiance dB1
        (P,3) (sun a patch no longer reflects, light of the sunlit object) through the patch transfers
        G (P,P) for the later bounces the camera sees, passed on to the receiver vertices (G_v (Vr,P));
        None when there are none. One pass through G_v is the engine's second order (exact, on the
        changed patches); what has gone through G once is spread over the room and is carried on
        clusters of neighbouring patches (LaterBounces), a few thousandth of the dense work."""
        if bounces <= 2:
            return None
        lb = self._later
        if lb is None or lb.key != (id(G), id(G_v), id(albedo)):
            if self.patches is None:
                raise ValueError("SunStage: later bounces need the patch mesh (patches=)")
            lb = self._later = LaterBounces(G, G_v, albedo, self.patches, exact=self.c_patch)
        return lb(dB1, bounces - 2)

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
        if len(pieces) == 0:
            return tri_rad, None
        origin = tris.reshape(-1, 3).mean(0)
        share = pieces.lit_share(origin)
        T = len(pf)
        lit = share > 0
        whole = np.bincount(pieces.parent, (share >= 1.0).astype(float), T) == np.bincount(pieces.parent, minlength=T)
        whole &= np.bincount(pieces.parent, minlength=T) > 0
        E_face = np.zeros(T)  # cos of the wholly sunlit faces
        E_face[pieces.parent] = pieces.cos
        tri_rad = tri_rad + albedo * (np.where(whole, E_face, 0.0)[:, None] * self.E_perp)
        part = np.flatnonzero(lit & ~whole[pieces.parent])
        if len(part) == 0:
            return tri_rad, None
        rad = albedo * ((share[part] * pieces.cos[part])[:, None] * self.E_perp)
        sub = pieces.tris(origin)[part]
        # far field: one point emitter per partly lit face at its lit pieces' power centroid
        par, inv = np.unique(pieces.parent[part], return_inverse=True)
        a = pieces.area[part]
        w = a * share[part]
        A = np.bincount(inv, a, len(par))
        c = np.stack([np.bincount(inv, w * sub[:, :, k].mean(1), len(par)) for k in range(3)], 1)
        c /= np.bincount(inv, w, len(par))[:, None]
        power = np.stack([np.bincount(inv, a * rad[:, k], len(par)) for k in range(3)], 1)
        nrm = pieces.normal[part][np.unique(inv, return_index=True)[1]]
        order = np.argsort(inv, kind="stable")  # the pieces face by face: one sum per face (np.add.at: 5x slower)
        far_seen = np.add.reduceat(w[order, None] * coarse[part[order]], np.searchsorted(inv[order], np.arange(len(par))))
        far_seen /= np.bincount(inv, w, len(par))[:, None]
        seen = table.seen[part]
        uploaded = self._emitters.set(sub, rad, seen, table.res, PIECE_POINT_TOLERANCE, capacity=len(pieces))
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
            self._pieces = (key, pieces, table, coarse)
        return self._pieces[1:]

    def refine_clipped_edges(self, camera, cam_occ: Occluder, mesh, own: Occluder, L_vert: np.ndarray,
                             sun_vert: np.ndarray, albedo: np.ndarray, cov: np.ndarray, obj_rad: np.ndarray,
                             clipped: np.ndarray, s: int | None = None) -> np.ndarray:
        """Coverage and object radiance re-sampled with s x s rays (default edge_samples) on the object's outline pixels
        that touch clipping light (in place on cov (H,W) and obj_rad (H,W,3)); returns those pixels.

        Outline: pixels partly covered, or uncovered/covered ones beside a pixel that is not;
        clipping: the photo clips there or next to it (`clipped` (H*W,) bool, a sunlit floor) or
        the object's radiance there or next to it is 1 or more (a sunlit face; radiance 1 is the
        white level). Object radiance per ray: L_vert interpolated, with the sun per hit (its
        self-shadow edge: rays on the faces it crosses, SunLight.irradiance_on_mesh) as
        Engine._shade_object does."""
        H, W = cov.shape
        s = s or self.edge_samples
        v, n, f = mesh
        rows, cols = np.flatnonzero(cov.any(1)), np.flatnonzero(cov.any(0))
        if len(rows) == 0:
            return np.zeros(0, np.int64)
        # the object's box and 2 pixels around it: every outline pixel and its 3x3 window lie inside
        y0, y1 = max(rows[0] - 2, 0), min(rows[-1] + 3, H)
        x0, x1 = max(cols[0] - 2, 0), min(cols[-1] + 3, W)
        lum = obj_rad[y0:y1, x0:x1] @ np.array([0.2126, 0.7152, 0.0722])
        bright = (lum >= 1.0) | clipped.reshape(H, W)[y0:y1, x0:x1]
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
        # s x s rays a pixel against the object, each that reaches it depth-tested against the room (one launch)
        tri, bary, hit = self._outline(own, cam_occ, camera.centre, camera.R.T @ np.linalg.inv(camera.K), px, py, s,
                                       functools.partial(runtime.split, device=self.device, min_items=EDGE_MIN_RAYS))
        rad = np.zeros((len(tri), 3))
        h = np.flatnonzero(hit)
        corners = f[tri[h]]
        b = bary[h].astype(np.float64)
        rad[h] = np.einsum("nk,nkc->nc", b, L_vert[corners])
        lit_v = sun_vert.any(1) if sun_vert is not None and len(h) else None
        k = np.flatnonzero(lit_v[f].any(1)[tri[h]]) if lit_v is not None else []  # on faces with a sunlit corner
        if len(k):  # (on the others both the per-hit sun and the vertex blend it replaces are 0)
            hk, bk, ck = h[k], b[k], corners[k]
            pos = np.einsum("nk,nkc->nc", bk, v[ck])
            nrm = np.einsum("nk,nkc->nc", bk, n[ck])
            nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-12)
            E_hit = self.light.irradiance_on_mesh(pos, nrm, lit_v[ck], [own])
            rad[hk] = np.maximum(rad[hk] + albedo * (E_hit - np.einsum("nk,nkc->nc", bk, sun_vert[ck])), 0.0)
        k = s * s
        hits = hit.reshape(-1, k)
        c = hits.mean(1)
        mean = rad.reshape(-1, k, 3).sum(1) / np.maximum(hits.sum(1), 1)[:, None]
        cov[py, px] = c
        obj_rad[py, px] = np.where(c[:, None] > 0, mean, obj_rad[py, px])
        return py * W + px


def patch_clusters(patches) -> tuple[np.ndarray, int]:
    """(cluster (P,) int, count): the patches of one quad whose centres fall in one cube of twice
    the median patch side (about 2 x 2 patches)."""
    side = 2.0 * float(np.median(np.sqrt(patches.area)))
    key = np.column_stack([patches.quad, np.floor(patches.centre / side).astype(np.int64)])
    _, cl = np.unique(key, axis=0, return_inverse=True)
    cl = cl.ravel()
    return cl, int(cl.max()) + 1


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
      W_c = S diag(rho_c) G[:, exact] (C,E): their first pass on the clusters, for the later passes.
    Per frame: y_1 = Q S dB1' + W dB1[exact] (dB1': dB1 off the exact patches), y_{k+1} = Q y_k;
    result H dB1[exact] + V (Q S dB1' + y_2 + ... + y_n). Work per frame ~ C^2, not P^2."""

    def __init__(self, G: np.ndarray, G_v: np.ndarray, albedo: np.ndarray, patches, exact: np.ndarray | None = None):
        import scipy.sparse as sp

        self.key = (id(G), id(G_v), id(albedo))
        cl, n = patch_clusters(patches)
        P = len(cl)
        area = np.asarray(patches.area, np.float64)
        self.cluster, self.n = cl, n
        self.w = area / np.bincount(cl, area, n)[cl]  # area-weighted mean over each cluster
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
        self.V = np.ascontiguousarray((sum_rows @ G_v32.T).T, np.float32)  # (Vr,C)

    def __call__(self, dB1: np.ndarray, n: int) -> np.ndarray:
        """G_v sum_{k=1}^{n} (rho G)^k dB1 (Vr,3) for dB1 (P,3). The products are einsums over a
        contiguous last axis, not BLAS calls: a threaded BLAS on a loaded machine took 40-60 ms for what
        takes 1-2 ms here."""
        if n <= 0 or not np.any(dB1):
            return np.zeros((len(self.V), 3))
        rest = np.where(self.is_exact[:, None], 0.0, dB1) * self.w[:, None]
        xm = np.stack([np.bincount(self.cluster, rest[:, c], self.n) for c in range(3)]).astype(np.float32)  # (3,C)
        y = np.einsum("cij,cj->ci", self.Q, xm)  # first pass of the rest, on the clusters
        total = y.copy()
        xe = np.ascontiguousarray(dB1[self.exact].T, np.float32)  # (3,E)
        out = np.einsum("cve,ce->vc", self.H, xe)  # first pass of the exact patches, at the receivers
        y += np.einsum("ce,cek->ck", xe, self.W)
        for _ in range(n - 1):
            y = np.einsum("cij,cj->ci", self.Q, y)
            total += y
        return out + np.einsum("vk,ck->vc", self.V, total)
