"""The sphere drag frame: the room's change while dragging with no shadow maps (FrameConfig.drag_shadow
"spheres"; kernels.sphere_occlusion).

Per scene (made on the first such frame, SphereShadow):
- at the drag frame's coarse pixels (app.dragframe.DragStages' receivers, 1/s each way), the incident
  light as order-3 SH of the room's broad light and, kept apart, the compact sources: the emitters'
  and the sunlit patches, grouped per quad into cells of at most CELL metres (each a disk of its area);
  both from the precompute's transfers G_v at the receiver vertices, interpolated as E_x is;
Per object shape: K spheres fitted in the object's frame (fit_spheres).
Per frame: one kernel over the coarse pixels gives the ratio room / photo (the light the spheres block,
less the light they reflect, over the pixel's light); the drag frame's compose brings it back
bilinearly and mixes the full-resolution object over it; the sun's pass stays the full frame's.
No source list, no shadow maps, no object light by rays, no second order.
"""
from __future__ import annotations

import dataclasses
import functools
import time

import numpy as np
from scipy.cluster.vq import kmeans2

from app import runtime
from app.glue import FrameTimer
from kernels.sphere_occlusion import N_SH, SphereRatio, sh16_np

# Compact sources are cut into cells no larger than this (m): a cell is one disk to the kernel, so its
# shadow is the disk's; half a metre keeps a window's cells within ~15 degrees from 2 m, the angular
# resolution order-3 SH has (about 180 / 4 degrees) below which the SH part would blur them anyway.
CELL = 0.5
# Ellipsoids per object shape: enough to separate a chair's seat, back and legs (fit_parts).
N_PARTS = 8
# Sharpness of a part's ambient cube (sphere_radiance): cos^4 keeps the outermost ~40 degrees of each side
CUBE_POWER = 4
# Voxels along the object's longest side when its solid is sampled (solid_points): 1 cm for a 1 m chair, three
# across its 3 cm legs
VOXELS = 96
# A part whose ellipsoid of inertia is less than this share inside the object is cut in two (fit_parts): a
# ball's is all inside, a box's about 0.75 (the ellipsoid reaches past its faces), half a ring's or an L's
# much less (the hole, the corner's empty side)
MIN_FILL = 0.6
FILL_SAMPLES = 2000


def solid_points(vertices: np.ndarray, faces: np.ndarray, lo: np.ndarray, side: float) -> np.ndarray:
    """(n,3) centres of the voxels (side m, a grid from lo (3,)) inside the closed triangle mesh (vertices,
    faces) (m): Open3D's ray-parity occupancy; empty when none is inside (an open or paper-thin mesh)."""
    import open3d as o3d

    v = np.asarray(vertices, np.float64)[np.unique(faces)]
    if side <= 0:
        return np.zeros((0, 3))
    v0, v1 = v.min(0), v.max(0)
    i0 = np.floor((v0 - lo) / side).astype(int)
    i1 = np.ceil((v1 - lo) / side).astype(int)
    axes = [lo[i] + side * (np.arange(i0[i], max(i1[i], i0[i] + 1)) + 0.5) for i in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    rs = o3d.t.geometry.RaycastingScene()
    rs.add_triangles(o3d.core.Tensor(np.asarray(vertices, np.float32)), o3d.core.Tensor(np.asarray(faces, np.uint32)))
    occ = rs.compute_occupancy(o3d.core.Tensor(grid.astype(np.float32))).numpy() > 0
    return grid[occ]


def components(vertices: np.ndarray, faces: np.ndarray) -> list[np.ndarray]:
    """The faces of each connected piece of a mesh (vertices merged by position to 1 um), largest first."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    _, vid = np.unique(np.round(np.asarray(vertices, np.float64), 6), axis=0, return_inverse=True)
    f = vid.ravel()[np.asarray(faces)]
    n = int(f.max()) + 1
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]]])
    _, lab = connected_components(coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n)), directed=False)
    flab = lab[f[:, 0]]
    out = [np.flatnonzero(flab == c) for c in np.unique(flab)]
    return sorted(out, key=len, reverse=True)


def _ellipsoid(pts: np.ndarray, half: float, inside) -> tuple[np.ndarray, np.ndarray, float]:
    """(centre, axes (3,3), fill) of points (voxel centres, voxel side 2 half): the ellipsoid of inertia,
    semi-axes sqrt(5) sigma_i, at least half; fill: the share of FILL_SAMPLES points spread evenly in it
    (a fixed seed) that inside(points) (n,) bool finds in the object (a ring's half: its hole is empty)."""
    c = pts.mean(0)
    q = pts - c
    ev, vec = np.linalg.eigh(q.T @ q / len(pts))
    semi = np.maximum(np.sqrt(5.0 * np.maximum(ev, 0.0)), max(half, 1e-4))
    A = vec * semi
    u = np.random.default_rng(0).normal(size=(FILL_SAMPLES, 3))
    u *= (np.random.default_rng(1).uniform(size=(FILL_SAMPLES, 1)) ** (1 / 3)) / np.linalg.norm(u, axis=1, keepdims=True)
    fill = float(np.mean(inside(c + u @ A.T)))
    return c, A, fill


def fit_parts(vertices: np.ndarray, faces: np.ndarray, k: int = N_PARTS, seed: int = 0
              ) -> tuple[np.ndarray, np.ndarray]:
    """(centres (k',3), axes (k',3,3): columns the semi-axes) of ellipsoids standing for a triangle mesh
    (m, its own frame) as an occluder. Each connected piece's solid (solid_points) is one part, its
    ellipsoid of inertia (Legendre's: the solid ellipsoid of the same centroid and second moments; a ball
    is its own, a slab a flat one, a leg a needle); a part whose ellipsoid is less than MIN_FILL inside the object
    (an L, two legs joined by a rail) is cut in two by k-means, the worst first, while there are fewer than
    k parts (the largest pieces are kept whole when there are more pieces than k: the smallest are
    merged into their nearest part's points). A piece with no inside (open, paper-thin) stands for its
    vertices. k' <= k."""
    import open3d as o3d

    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces)
    half = float((v.max(0) - v.min(0)).max()) / VOXELS / 2
    rs = o3d.t.geometry.RaycastingScene()
    rs.add_triangles(o3d.core.Tensor(v.astype(np.float32)), o3d.core.Tensor(f.astype(np.uint32)))

    def inside(p: np.ndarray) -> np.ndarray:
        return rs.compute_occupancy(o3d.core.Tensor(p.astype(np.float32))).numpy() > 0

    parts = []
    for comp in components(v, f):
        pts = solid_points(v, f[comp], lo=v.min(0), side=2 * half)
        if len(pts) < 4:
            pts = v[np.unique(f[comp])]
        parts.append(pts)
    while len(parts) > k:  # the smallest piece joins the part whose centroid is nearest
        small = parts.pop()
        c = small.mean(0)
        j = int(np.argmin([np.linalg.norm(p.mean(0) - c) for p in parts]))
        parts[j] = np.concatenate([parts[j], small])
    fits = [_ellipsoid(p, half, inside) for p in parts]
    while len(parts) < k:
        j = int(np.argmin([ft[2] for ft in fits]))
        if fits[j][2] >= MIN_FILL or len(parts[j]) < 8:
            break
        pts = parts.pop(j)
        fits.pop(j)
        _, lab = kmeans2(pts, 2, minit="++", iter=20, seed=seed)
        for m in (lab == 0, lab == 1):
            if m.sum() >= 2:
                parts.append(pts[m])
                fits.append(_ellipsoid(pts[m], half, inside))
    return np.array([ft[0] for ft in fits]), np.array([ft[1] for ft in fits])


def compact_cells(patches, mask: np.ndarray, cell: float = CELL) -> np.ndarray:
    """(P,) int: the compact source cell of each patch in `mask` (-1 others): per quad, a grid of
    `cell` metres over the quad's two longest extents of its masked patch centres."""
    out = np.full(patches.n_patches, -1, np.int64)
    nxt = 0
    for q in np.unique(patches.quad[mask]):
        ids = np.flatnonzero(mask & (patches.quad == q))
        c = patches.centre[ids]
        c0 = c - c.mean(0)
        _, _, vt = np.linalg.svd(c0, full_matrices=False) if len(ids) > 1 else (None, None, np.eye(3))
        uv = c0 @ vt[:2].T
        ij = np.floor((uv - uv.min(0)) / cell).astype(np.int64)
        _, lab = np.unique(ij, axis=0, return_inverse=True)
        out[ids] = nxt + lab.ravel()
        nxt += lab.max() + 1
    return out


def vertex_light(G_v: np.ndarray, B: np.ndarray, vpos: np.ndarray, centres: np.ndarray, cells: np.ndarray,
                 cell_area: np.ndarray, chunk: int = 128):
    """At the receiver vertices (Vr): (sh (Vr,16,3): the SH of the light of every patch that is not in a
    compact cell; cw (Vr,C,3): each cell's light; cc (Vr,C,3): its luminance-weighted centroid);
    G_v (Vr,P), B (P,3), vpos (Vr,3), centres (P,3), cells (P,) (-1: broad light)."""
    Vr, C = len(vpos), int(cell_area.shape[0])
    broad = cells < 0
    Bb = B[broad].astype(np.float64)
    sh = np.zeros((Vr, N_SH, 3))
    for a in range(0, Vr, chunk):
        g = G_v[a:a + chunk][:, broad].astype(np.float64)
        d = centres[broad][None] - vpos[a:a + chunk, None]
        d /= np.maximum(np.linalg.norm(d, axis=2, keepdims=True), 1e-9)
        Y = sh16_np(d)  # (v,p,16)
        sh[a:a + chunk] = np.einsum("vpk,vp,pc->vkc", Y, g, Bb, optimize=True)
    cw = np.zeros((Vr, C, 3))
    cc = np.zeros((Vr, C, 3))
    lum = B.mean(1)
    for c in range(C):
        ids = np.flatnonzero(cells == c)
        g = G_v[:, ids].astype(np.float64)
        cw[:, c] = g @ B[ids]
        wl = g * lum[ids]
        s = wl.sum(1, keepdims=True)
        cc[:, c] = np.where(s > 0, (wl @ centres[ids]) / np.maximum(s, 1e-30), centres[ids].mean(0))
    return sh, cw, cc


class SphereShadow:
    """The sphere drag frame of one engine at 1/scale resolution (module docstring)."""

    def __init__(self, engine, scale: int):
        t0 = time.perf_counter()
        self.engine = engine
        self.px = px = engine.pixel_stages(scale)  # the coarse receivers and the drag compose
        pre, r = px.pre, px.receivers
        pm = pre.patches
        B = engine.B_src
        compact = pm.is_emitter | engine.sun.sunlit_patches()
        cells = compact_cells(pm, compact)
        C = int(cells.max() + 1) if (cells >= 0).any() else 0
        area = np.bincount(cells[cells >= 0], pm.area[cells >= 0], C) if C else np.zeros(0)
        sh_v, cw_v, cc_v = vertex_light(pre.G_v, B, pm.vert_pos[pre.recv_vert], pm.centre, cells, area)
        self.pix = pix = np.flatnonzero(r.recv_pix)
        rows, bary = r.pix_rows[pix], pre.pix_bary[pix].astype(np.float64)
        self._rows, self._bary = rows, bary

        def interp(a):
            return np.einsum("nk,nk...->n...", bary, a[rows])

        sh, cw = interp(sh_v), interp(cw_v)
        # centroids: weighted by the cells' light at the three vertices
        wl = bary[:, :, None] * cw_v[rows].mean(3)  # (n,3,C)
        cc = np.einsum("nkc,nkcd->ncd", wl, cc_v[rows]) / np.maximum(wl.sum(1), 1e-30)[..., None]
        nrm = pm.normal[r.pix_patch[pix]]
        # the patch centres too (second order: the patches the object darkens pass less light on)
        sh_c, cw_c, cc_c = vertex_light(pre.G_c, B, pm.centre, pm.centre, cells, area)
        self.E_c = pre.G_c.astype(np.float64) @ B
        pos = np.concatenate([r.pix_pos[pix], pm.centre + 1e-3 * pm.normal])
        self.kernel = SphereRatio(pos, np.concatenate([nrm, pm.normal]), np.concatenate([r.E_x[pix], self.E_c]),
                                  np.concatenate([sh, sh_c]), np.concatenate([cw, cw_c]), np.concatenate([cc, cc_c]),
                                  np.sqrt(area / np.pi), engine.device)
        self._albedo = pm.albedo
        self._E_x = r.E_x[pix]
        self.n_cells = C
        self.shape = px.shape
        self._room = np.zeros((px.shape[0] * px.shape[1], 3), np.float32)
        self._Lb = r.L_b.astype(np.float32)
        self._spheres: dict = {}  # shape key -> (centres, radii) in the object's frame
        self._split = functools.partial(runtime.split, device=engine.device, min_items=256)
        self.build_s = time.perf_counter() - t0

    def spheres(self, obj) -> tuple[np.ndarray, np.ndarray]:
        """The object's parts at its pose (world: centres (K,3), axes (K,3,3)): fitted once per shape in
        its own frame (object_to_world's inverse), moved by object_to_world."""
        M = np.asarray(obj.object_to_world, np.float64)
        key = (obj.faces.shape, hash(np.ascontiguousarray(obj.faces).tobytes()), len(obj.vertices))
        if key not in self._spheres:
            Minv = np.linalg.inv(M)
            v_obj = obj.vertices @ Minv[:3, :3].T + Minv[:3, 3]
            self._spheres = {key: fit_parts(np.round(v_obj, 6), obj.faces)}
        c, ax = self._spheres[key]
        return c @ M[:3, :3].T + M[:3, 3], M[:3, :3] @ ax

    def ratio(self, centres: np.ndarray, axes: np.ndarray, radiance: np.ndarray, dB_more: np.ndarray | None = None
              ) -> np.ndarray:
        """(h*w,3) the coarse room radiance: the photo's times the parts' ratio at the receivers, plus the
        second order: the patches' change (their ratio's, rho E_c (r_c - 1), and dB_more (P,3), the sun's)
        passed on once through G_v (the coarse compose's second_order) and interpolated to the pixels."""
        n = len(self.pix)
        rat = self.kernel.run(centres, axes, radiance, self._split)
        dB = self._albedo * self.E_c * (rat[n:].astype(np.float64) - 1.0)
        if dB_more is not None:
            dB = dB + dB_more
        dE_v = self.px.compose.second_order(dB)
        dE = np.einsum("nk,nkc->nc", self._bary, dE_v[self._rows])
        room = self._room
        room[:] = self._Lb
        room[self.pix] = self._Lb[self.pix] * np.maximum(rat[:n] + dE / np.maximum(self._E_x, 1e-12), 0.0)
        return room

    def frame_steps(self, obj, config, frame_type):
        """Engine._frame_steps for a sphere drag frame (a generator with no yields, returns a frame_type:
        app.engine.Frame, passed in: the engine imports this module)."""
        eng, px = self.engine, self.px
        sun, oc = eng.sun_pixels.stage, eng.params.object
        ft = FrameTimer()
        tick, timings = ft.tick, ft.timings
        pv, pf, proxy_occ, shade_mesh, shade_occ, centre, radius, hits, cov = eng.frame_object(obj, ft)
        t = ft.last
        timings["sources"] = 0.0  # no source list
        pm = eng.pre.patches
        dB_shadow = np.zeros((pm.n_patches, 3))
        sun_loss = sun_dB = None
        if sun is not None:
            sun_loss, sun_loss_c = sun.frame(obj.vertices, obj.faces)
            sun_dB = -pm.albedo * sun_loss_c
            t = tick("sun", t)
        shade = functools.partial(eng.object_shading.shade, obj, shade_mesh, hits, proxy_occ, dB_shadow, sun_dB)
        if sun is None and hits.hit.any():  # the vertex radiance of a near pose (as the map drag frame)
            fresh = []
            vertex = px.near_pose("object radiance", lambda: (fresh.append(shade()) or (fresh[0].L_vert, None)),
                                  shade_mesh[0], shade_mesh[2], centre, oc.volume_spacing)
            shaded = fresh[0] if fresh else shade(vertex=vertex)
        else:
            shaded = shade()
        obj_rad = shaded.radiance
        if sun is not None and shaded.L_vert is not None:
            sun.refine_clipped_edges(eng.scene.camera, eng.cam_occ, shade_mesh, shade_occ, shaded.L_vert,
                                     shaded.sun_vis, obj.albedo, cov, obj_rad, eng.sun_pixels.photo_clip,
                                     groups=eng.object_shading.face_groups)
        t = tick("object_shading", t)
        sc, sa = self.spheres(obj)
        lo = self.sphere_radiance(shade_mesh[0], shade_mesh[1], shaded.L_vert, sc)
        room_c = self.ratio(sc, sa, lo, sun_dB)
        t = tick("masks", t)  # the room's shadow: the spheres' kernel (in place of the shadow maps)
        radiance, pixels, room = px.finish(room_c, cov, obj_rad, eng._sun_share(sun_loss))
        tick("upsample", t)
        frame_s = ft.close()
        eng.last_shading = (shade_mesh, shaded.L_vert, obj.albedo, shaded.sun_vis) if hits.hit.any() else None
        stats = {"frame_s": frame_s, "timings": timings, "n_sources": int(self.n_cells) + int(sun is not None),
                 "passes": int(sun is not None), "spheres": int(len(sc)), "mode": "hdr", "drag_shadow": "spheres",
                 "n_patches": int(pm.n_patches), "glue": ft.glue, "kernel_s": ft.clock.seconds}
        return frame_type(radiance, pixels, stats, room, cov.astype(np.float32))
        yield  # a generator (Engine.render drives it)

    @staticmethod
    def sphere_radiance(verts: np.ndarray, normals: np.ndarray, L_vert: np.ndarray | None, centres: np.ndarray
                        ) -> np.ndarray:
        """(K,6,3) each part's radiance as an ambient cube (+x, -x, +y, -y, +z, -z; the kernel's lo): per face
        direction a, the mean radiance of the shading vertices nearest the part's centre that face it
        (n.a > 0), weighted by max(0, u.a)^CUBE_POWER, u the unit direction from the centre to the vertex:
        the part's surface farthest out that way, what a receiver on that side sees nearest (the bottom of a
        ball at its contact, not its lit equator); a direction none faces takes the part's mean. Zeros when
        the object is unseen (L_vert None)."""
        K = len(centres)
        out = np.zeros((K, 6, 3))
        if L_vert is None:
            return out
        near = np.argmin(((verts[:, None] - centres[None]) ** 2).sum(2), axis=1)
        dirs = np.concatenate([np.eye(3)[:, None], -np.eye(3)[:, None]], 1).reshape(6, 3)  # +x,-x,+y,-y,+z,-z
        facing = (normals @ dirs.T) > 0.0  # (V,6)
        for k in range(K):
            m = near == k
            if not m.any():
                out[k] = L_vert.mean(0)
                continue
            u = verts[m] - centres[k]
            u /= np.maximum(np.linalg.norm(u, axis=1, keepdims=True), 1e-12)
            wk = np.maximum(u @ dirs.T, 0.0) ** CUBE_POWER * facing[m]
            s = wk.sum(0)
            out[k] = np.where(s[:, None] > 0, (wk.T @ L_vert[m]) / np.maximum(s, 1e-12)[:, None], L_vert[m].mean(0))
        return out
