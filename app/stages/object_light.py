"""Object light stage: the light the object reflects onto the room (pixels and patch centres), as
irradiance / pi (DESIGN "Per-frame stages"). The object's proxy triangles are the emitters."""
from __future__ import annotations

import hashlib
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from kernels.buffers import Workspace, workspace
from kernels.visibility import (Occluder, distance_to, emitter_sum, emitter_sum_seen, segments_visible,
                                transfer_matrix)
from recon.response import luminance
from recon.scene import SceneObject

if TYPE_CHECKING:
    from app.engine import Engine


def object_irradiance(eng: "Engine", pts: np.ndarray, nrm: np.ndarray, proxy_occ: Occluder, B: np.ndarray
                       ) -> np.ndarray:
    """Irradiance/pi (N,3) at object surface points from patches of radiance B (P,3), with
    self-occlusion."""
    pm = eng.pre.patches
    G = transfer_matrix(pts, nrm, pm.corners, pm.normal, [eng.scene_occ, proxy_occ], n_side=1,
                        eps=2e-3, device=eng.device, workspace=workspace(eng, "object_irradiance"))
    return G.astype(np.float64) @ B


def triangle_radiance(eng: "Engine", obj: SceneObject, pv, pf, proxy_occ, B: np.ndarray) -> np.ndarray:
    """Outgoing radiance (T,3) of each proxy triangle, lit at its centroid by patches of radiance B
    (P,3), gathered over every patch with visibility past the scene and the proxy (object_irradiance).
    (The SH9 volume x the proxy's self transfer in place of the non-emitting patches was measured and
    left out: on lamps_room it lit the proxy brighter and raised spurious from 0.0037 to 0.0050.)"""
    c = pv[pf].mean(1)
    return obj.albedo * eng._object_irradiance(c, proxy_shape(eng, pv, pf, proxy_occ).normals, proxy_occ, B)


@dataclass
class ExtraEmitters:
    """Emitters the object has besides its proxy's triangles (the sunlit pieces of its faces,
    app.stages.sun): triangles for the exact sum near the object, point emitters beyond FAR_FIELD."""

    tris: np.ndarray  # (S,3,3) CCW seen from the emitting side
    rad: np.ndarray  # (S,3) radiance
    seen: np.ndarray  # (S, 6 res^2) bool: the directions each one sees out of the object (its visibility)
    res: int  # cells per cube face side of `seen`
    capacity: int  # the most such emitters the shape can have (kernel buffers are made that large once)
    far_c: np.ndarray  # (F,3) point emitters' positions
    far_tn: np.ndarray  # (F,3) twice their area x unit normal
    far_rad: np.ndarray  # (F,3) radiance
    far_seen: np.ndarray  # (F, 6 CUBE_RES^2) bool: the directions each one sees out of the object


def object_light(eng: "Engine", pv, pf, tri_rad, proxy_occ, centre, radius, covered: np.ndarray | None = None,
                 extra: ExtraEmitters | None = None):
    """Light reflected by the object onto pixels (H*W,3) and patch centres (P,3), as irradiance/pi.

    Far from the object the reflected light varies slowly: it is evaluated at receiver vertices
    and interpolated like the transfers, on the pixels of the patches it reaches (PixelTable).
    Within `near_factor` bounding radii of the object's centre, where it changes fast (contact,
    under a seat), it is evaluated per pixel where the upper bound of its gain exceeds a quarter
    level: exactly on an adaptive screen grid, blended between the grid's nodes where the light
    varies slowly (_near_pixels). covered: optional (H*W,) bool, pixels the object hides entirely
    (their room is not seen: left at the interpolated value). extra: emitters besides the proxy's
    triangles (ExtraEmitters), or None.
    """
    pre, pm = eng.pre, eng.pre.patches
    resp = eng.scene.response
    table = pixel_table(eng)
    tris = pv[pf]
    tvis = proxy_shape(eng, pv, pf, proxy_occ).visibility
    far = None
    if extra is not None:
        tn = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
        far = (np.concatenate([tris.mean(1), extra.far_c]), np.concatenate([tn, extra.far_tn]),
               np.concatenate([tri_rad, extra.far_rad]), np.concatenate([tvis.seen, extra.far_seen]))
    max_rad = tri_rad.max(0) if extra is None else np.maximum(tri_rad.max(0), extra.rad.max(0))
    rv = pre.recv_vert
    R_v = _reflected(pm.vert_inset[rv], pm.vert_normal[rv], tris, tri_rad, proxy_occ, centre, radius, eng.device,
                     tvis, workspace(eng, "object_light.vertices"), far, extra)
    R_pix = np.zeros((len(eng.L_b), 3))
    # the pixels of the patches with a vertex that gets a visible share of the object's light
    reach_v = luminance(R_v) * float(eng.rho_x.max()) > 5e-4 * float(luminance(eng.B_src).mean())
    touched = np.zeros(len(pm.vert_pos), bool)
    touched[rv[reach_v]] = True
    rp = table.pixels_of(np.unique(pm.tri_patch[touched[pm.tris].any(1)]))
    R_pix[rp] = np.einsum("nk,nkc->nc", pre.pix_bary[rp], R_v[eng.pix_rows[rp]])
    dist = np.linalg.norm(eng.pix_pos[rp] - centre, axis=1)
    near = dist < eng.near_factor * radius
    rp, dist = rp[near], dist[near]
    f_bound = np.minimum(1.0, (radius / np.maximum(dist, 1e-6)) ** 2)
    bound = eng.rho_x[rp] * max_rad * f_bound[:, None]
    gain = (resp.to_levels(eng.L_b[rp] + bound) - resp.to_levels(eng.L_b[rp])).max(1)
    sel = rp[gain > 0.25]
    if covered is not None:
        sel = sel[~covered[sel]]
    if len(sel):
        R_pix[sel] = _near_pixels(eng, sel, tris, tri_rad, proxy_occ, extra)
    # patch centres, for the second-order term
    dist_c = np.linalg.norm(pm.centre - centre, axis=1)
    reach = np.minimum(1.0, (radius / np.maximum(dist_c, 1e-6)) ** 2) * luminance(max_rad)
    near_c = np.flatnonzero((reach > 1e-4 * luminance(eng.B_src).mean()) & ~pm.is_emitter)
    R_cen = np.zeros((pm.n_patches, 3))
    R_cen[near_c] = _reflected(pm.centre[near_c], pm.normal[near_c], tris, tri_rad, proxy_occ, centre, radius,
                               eng.device, tvis, workspace(eng, "object_light.centres"), far, extra)
    eng._n_object_light_pixels = len(sel)
    return R_pix, R_cen


FAR_FIELD = 3.0  # bounding radii from the object's centre beyond which its triangles act as point sources


CUBE_RES = 8  # cells per cube face side of the proxy triangles' visibility table (TriangleVisibility)


def _cube_bin(d: np.ndarray, r: int) -> np.ndarray:
    """Cube-map cell (...,) int of directions d (...,3) (any length): face 2 axis + (negative), then
    r x r cells over the other two coordinates in axis order."""
    ad = np.abs(d)
    a = ad.argmax(-1)
    m = np.take_along_axis(ad, a[..., None], -1)[..., 0]
    neg = np.take_along_axis(d, a[..., None], -1)[..., 0] < 0
    u = np.take_along_axis(d, ((a + 1) % 3)[..., None], -1)[..., 0] / np.maximum(m, 1e-30)
    v = np.take_along_axis(d, ((a + 2) % 3)[..., None], -1)[..., 0] / np.maximum(m, 1e-30)
    iu = np.clip(((u + 1) * 0.5 * r).astype(int), 0, r - 1)
    iv = np.clip(((v + 1) * 0.5 * r).astype(int), 0, r - 1)
    return ((2 * a + neg) * r + iu) * r + iv


def _cube_dirs(r: int) -> np.ndarray:
    """Unit directions (6 r r, 3) at the centres of _cube_bin's cells."""
    c = (np.arange(r) + 0.5) / r * 2 - 1
    out = np.zeros((6, r, r, 3))
    for face in range(6):
        a, neg = divmod(face, 2)
        out[face, :, :, a] = -1.0 if neg else 1.0
        out[face, :, :, (a + 1) % 3] = c[:, None]
        out[face, :, :, (a + 2) % 3] = c[None, :]
    out = out.reshape(-1, 3)
    return out / np.linalg.norm(out, axis=1, keepdims=True)


class TriangleVisibility:
    """Which directions each proxy triangle's centroid sees out of the object (T, 6 CUBE_RES^2) bool,
    one ray per cube-map cell against the proxy itself. Per shape: a translation changes nothing."""

    def __init__(self, tris: np.ndarray, proxy_occ: Occluder, eps: float = 1e-3, res: int = CUBE_RES):
        self.res = res
        dirs = _cube_dirs(res)
        c = tris.mean(1)
        tn = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
        tn /= np.maximum(np.linalg.norm(tn, axis=1, keepdims=True), 1e-12)
        a = np.repeat(c + tn * eps, len(dirs), 0)
        b = a + np.tile(dirs, (len(tris), 1)) * 1e3
        self.seen = segments_visible(proxy_occ, a, b).reshape(len(tris), len(dirs)).astype(bool)

    def lookup(self, tri_to_point: np.ndarray) -> np.ndarray:
        """(N,T) float: 1 where the direction (N,T,3) from triangle t leaves the object unblocked."""
        return _seen_lookup(self.seen, tri_to_point, self.res)


def _seen_lookup(seen: np.ndarray, tri_to_point: np.ndarray, res: int = CUBE_RES) -> np.ndarray:
    """(N,T) float: seen[t, cell of the direction (N,T,3) from emitter t] (a visibility table's rows)."""
    t = np.broadcast_to(np.arange(seen.shape[0]), tri_to_point.shape[:2])
    return seen[t, _cube_bin(tri_to_point, res)].astype(np.float64)


class ProxyShape:
    """Per proxy shape (a translation changes none of it): the triangles' visibility table
    (TriangleVisibility) and unit normals (T,3)."""

    def __init__(self, tris: np.ndarray, proxy_occ: Occluder):
        self.visibility = TriangleVisibility(tris, proxy_occ)
        n = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
        self.normals = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)


def shape_key(pv: np.ndarray, pf: np.ndarray) -> str:
    """The key of a proxy's shape: the centred proxy to 1 um (a translation keeps it)."""
    return hashlib.sha1(np.round(pv - pv.mean(0), 6).tobytes() + np.ascontiguousarray(pf).tobytes()).hexdigest()


def proxy_shape(eng: "Engine", pv: np.ndarray, pf: np.ndarray, proxy_occ: Occluder) -> ProxyShape:
    """The proxy's ProxyShape, kept for the last shape (shape_key)."""
    key = shape_key(pv, pf)
    cached = getattr(eng, "_proxy_shape", None)
    if cached is None or cached[0] != key:
        cached = eng._proxy_shape = (key, ProxyShape(pv[pf], proxy_occ))
    return cached[1]


def _reflected(points: np.ndarray, normals: np.ndarray, tris: np.ndarray, tri_rad: np.ndarray, proxy_occ: Occluder,
               centre: np.ndarray, radius: float, device, tvis: TriangleVisibility | None = None,
               ws: Workspace | None = None, far_emitters: tuple | None = None,
               extra: ExtraEmitters | None = None) -> np.ndarray:
    """sum_t B_t F(x -> t) V(x, t) (N,3) at points (N,3) [normals (N,3)]: exact (emitter_sum) within
    FAR_FIELD bounding radii of the object; beyond, where each triangle subtends a small solid angle,
    the point-source form factor A_t cos_x cos_t / (pi r^2) times the triangle's own visibility
    towards x from the per-shape table `tvis` (the object is the only occluder, as in emitter_sum).
    ws: the call site's kernel buffers (kernels.buffers.Workspace), or None. far_emitters: the point
    emitters used beyond FAR_FIELD instead of the triangles' centroids, (positions (F,3), twice area x
    unit normal (F,3), radiance (F,3), visibility table rows (F, 6 CUBE_RES^2) bool), or None. extra:
    more emitters summed exactly within FAR_FIELD (_exact_sum), or None."""
    out = np.zeros((len(points), 3))
    far = np.linalg.norm(points - centre, axis=1) > FAR_FIELD * radius
    near = np.flatnonzero(~far)
    if len(near):
        out[near] = _exact_sum(points[near], normals[near], tris, tri_rad, proxy_occ, device, ws, extra)
    far = np.flatnonzero(far)
    if len(far):
        if far_emitters is None:
            c = tris.mean(1)
            tn = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])  # (T,3) twice the area x normal
            rad, seen = tri_rad, (tvis.seen if tvis is not None else None)
        else:
            c, tn, rad, seen = far_emitters
        d = c[None] - points[far][:, None]  # (N,T,3) point -> triangle
        r2 = np.einsum("ntc,ntc->nt", d, d)
        cos_x = np.maximum(np.einsum("ntc,nc->nt", d, normals[far]), 0.0)
        cos_t = np.maximum(-np.einsum("ntc,tc->nt", d, tn), 0.0)  # |tn| = 2 area; both cosines carry 1/r
        g = cos_x * cos_t * 0.5 / (np.pi * r2 * r2)
        if seen is not None:
            g *= _seen_lookup(seen, -d)
        out[far] = g @ rad
    return out


class PixelTable:
    """Receiver pixels grouped by patch (per scene): the pixels of a set of patches without a pass
    over the frame."""

    def __init__(self, recv_pix: np.ndarray, pix_patch: np.ndarray, n_patches: int):
        rp = np.flatnonzero(recv_pix)
        order = np.argsort(pix_patch[rp], kind="stable")
        self.pixels = rp[order]
        self.start = np.searchsorted(pix_patch[self.pixels], np.arange(n_patches + 1))

    def pixels_of(self, patches: np.ndarray) -> np.ndarray:
        """Sorted receiver pixels (N,) of the patch ids `patches`."""
        if len(patches) == 0:
            return np.zeros(0, np.int64)
        a, b = self.start[patches], self.start[patches + 1]
        n = b - a
        idx = np.repeat(a - np.concatenate([[0], np.cumsum(n)[:-1]]), n) + np.arange(n.sum())
        return np.sort(self.pixels[idx])


def pixel_table(eng: "Engine") -> PixelTable:
    """The engine's PixelTable (made on first use: it depends on the scene only)."""
    t = getattr(eng, "_pixel_table", None)
    if t is None:
        t = eng._pixel_table = PixelTable(eng.recv_pix, eng.pix_patch, eng.pre.patches.n_patches)
    return t


GRID_STRIDES = (16, 8, 4, 2)  # px between the adaptive grid's exact samples, coarse to fine (_near_pixels)
GRID_TOLERANCE = 0.5  # levels: a cell of the coarsest stride whose nodes differ by more is refined
# (x (coarsest / stride)^2 at a finer stride: the blend's error falls with the cell's area)
GRID_CLEARANCE = 2.0  # a cell is blended only this many cell diagonals away from the object or farther


def _exact_sum(points: np.ndarray, normals: np.ndarray, tris: np.ndarray, tri_rad: np.ndarray, proxy_occ: Occluder,
               device, ws: Workspace | None, extra: ExtraEmitters | None = None) -> np.ndarray:
    """sum_t B_t F(x -> t) V(x, t) (N,3): the proxy's triangles with a ray each (emitter_sum), plus the
    extra emitters with their visibility from their per-shape table (emitter_sum_seen)."""
    out = emitter_sum(points, normals, tris, tri_rad, proxy_occ, device=device, split=256, workspace=ws)
    if extra is not None and len(extra.tris):
        out += emitter_sum_seen(points, normals, extra.tris, extra.rad, extra.seen, extra.res, device=device,
                                split=256, workspace=_extra_workspace(ws), capacity=extra.capacity)
    return out


def _extra_workspace(ws: Workspace | None) -> Workspace | None:
    """The buffers of the extra emitters' sum at a call site (kept beside the site's own)."""
    if ws is None:
        return None
    extra = getattr(ws, "_extra", None)
    if extra is None:
        extra = ws._extra = Workspace(ws.rows, ws.sources)
    return extra


def _near_pixels(eng: "Engine", sel: np.ndarray, tris: np.ndarray, tri_rad: np.ndarray, proxy_occ: Occluder,
                 extra: ExtraEmitters | None = None) -> np.ndarray:
    """The object's light (len(sel),3), irradiance/pi, at the listed pixels `sel` near the object.

    An adaptive screen grid: at each stride of GRID_STRIDES a pixel whose cell (its four nodes)
    lies on its own quad (one plane), at least GRID_CLEARANCE cell diagonals from the object's
    proxy (the light varies on the scale of that distance) and whose nodes differ by at most
    GRID_TOLERANCE levels (x (coarsest / stride)^2 at a finer stride: a blend's error falls with
    the cell's area) takes the bilinear blend of the nodes, evaluated exactly
    (kernels.visibility.emitter_sum); the rest go on to the next, finer stride, and what is left
    after the finest is evaluated per pixel (contact, quad edges, the object's silhouette).
    """
    pm = eng.pre.patches
    H, W = eng.scene.camera.height, eng.scene.camera.width
    resp = eng.scene.response

    known_idx = np.zeros(0, np.int64)
    known_val = np.zeros((0, 3))

    def exact(idx: np.ndarray) -> None:
        nonlocal known_idx, known_val
        new = np.setdiff1d(idx, known_idx)
        if len(new):
            val = _exact_sum(eng.pix_pos[new], pm.normal[eng.pix_patch[new]], tris, tri_rad, proxy_occ, eng.device,
                             workspace(eng, "near_pixels.exact"), extra)
            known_idx = np.concatenate([known_idx, new])
            known_val = np.concatenate([known_val, val])
            order = np.argsort(known_idx)
            known_idx, known_val = known_idx[order], known_val[order]

    out = np.zeros((len(sel), 3))
    todo = np.arange(len(sel))
    quad_sel = pm.quad[eng.pix_patch[sel]]
    for s in GRID_STRIDES:
        if len(todo) == 0:
            break
        p = sel[todo]
        y, x = np.divmod(p, W)
        y0, x0 = y - y % s, x - x % s
        ny = np.stack([y0, y0, y0 + s, y0 + s], 1)
        nx = np.stack([x0, x0 + s, x0, x0 + s], 1)
        inside = (ny < H) & (nx < W)
        nodes = np.where(inside, ny * W + nx, 0)
        ok = (inside & eng.recv_pix[nodes]
              & (pm.quad[np.maximum(eng.pix_patch[nodes], 0)] == quad_sel[todo][:, None])).all(1)
        if ok.any():
            # clearance: the cell's nodes' distance to the proxy
            cn = np.unique(nodes[ok])
            d = distance_to(proxy_occ, eng.pix_pos[cn], workspace=workspace(eng, "near_pixels.clearance"))
            d_node = d[np.searchsorted(cn, nodes[ok])].min(1)
            diag = np.linalg.norm(eng.pix_pos[nodes[ok, 0]] - eng.pix_pos[nodes[ok, 3]], axis=1)
            clear = np.zeros(len(todo), bool)
            clear[np.flatnonzero(ok)] = d_node > GRID_CLEARANCE * diag
            ok &= clear
        if ok.any():
            exact(np.unique(nodes[ok]))
            corner = known_val[np.searchsorted(known_idx, nodes[ok])]  # (m,4,3)
            fp = p[ok]
            spread = eng.rho_x[fp] * (corner.max(1) - corner.min(1))
            gain = (resp.to_levels(eng.L_b[fp] + spread) - resp.to_levels(eng.L_b[fp])).max(1)
            smooth = gain <= GRID_TOLERANCE * (GRID_STRIDES[0] / s) ** 2
            fy = ((y - y0)[ok] / s)[:, None]
            fx = ((x - x0)[ok] / s)[:, None]
            blend = ((1 - fy) * ((1 - fx) * corner[:, 0] + fx * corner[:, 1]) +
                     fy * ((1 - fx) * corner[:, 2] + fx * corner[:, 3]))
            done = np.flatnonzero(ok)[smooth]
            out[todo[done]] = blend[smooth]
            keep = np.ones(len(todo), bool)
            keep[done] = False
            todo = todo[keep]
    if len(todo):
        exact(sel[todo])
        out[todo] = known_val[np.searchsorted(known_idx, sel[todo])]
    eng._n_object_light_exact = len(known_idx)
    return out
