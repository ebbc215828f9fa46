"""Object light stage: the light the object reflects onto the room (pixels and patch centres), as
irradiance / pi (DESIGN "Per-frame stages"). The object's proxy triangles are the emitters.

ObjectLight is built once per scene from the receiver map and the patch mesh; per frame
`triangle_radiance` lights the proxy's triangles from the room, `light` sums their light onto the
pixels and the patch centres, and `centre_light_parts` splits the centres' light into the room's
and the sun's parts (a room with a sun)."""
from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from app.config import ObjectConfig
from kernels.buffers import Workspace, Workspaces
from kernels.farfield import VertexInterpolation, point_emitter_sum
from kernels.room_share import room_share_launch
from kernels.vec import cross3, same_key
from kernels.visibility import (Occluder, SeenEmitters, distance_to, emitter_sum, emitter_sum_seen_bounded,
                                segments_visible, transfer_matrix)
from recon.patches import PatchMesh
from recon.proxy import bounding_sphere
from recon.response import luminance
from recon.scene import SceneObject

BLOCKS = (2,)  # patches a side of the blocks of non-emitting patches gathered as one, fine to coarse (a
# coarser level saves time but lets the proxy's light err more: docs/history.md)
BLOCK_NEAR = 4.0  # a block is split within this many block radii of the object's sphere (PatchBlocks)


class _Level:
    """One size of PatchBlocks: per block its corners (B,4,3), normal, centre, radius; per patch its
    block (-1: none) and its area share of it."""

    def __init__(self, pm, grids: list[tuple[np.ndarray, int, int]], k: int):
        members, corners = [], []
        for idx, nu, nv in grids:
            grid = idx.reshape(nu, nv)  # build_patches' order: iu major
            for u0 in range(0, nu, k):
                for v0 in range(0, nv, k):
                    g = grid[u0:u0 + k, v0:v0 + k]
                    if g.size > 1:
                        members.append(g.ravel())
                        corners.append([pm.corners[g[0, 0], 0], pm.corners[g[-1, 0], 1], pm.corners[g[-1, -1], 2],
                                        pm.corners[g[0, -1], 3]])
        self.block_of = np.full(pm.n_patches, -1)
        for b, m in enumerate(members):
            self.block_of[m] = b
        self.corners = np.array(corners, np.float64).reshape(-1, 4, 3)
        self.normal = pm.normal[[m[0] for m in members]] if members else np.zeros((0, 3))
        self.centre = self.corners.mean(1)
        self.radius = np.linalg.norm(self.corners - self.centre[:, None], axis=2).max(1) if members else np.zeros(0)
        self.rows = np.flatnonzero(self.block_of >= 0)
        area = np.bincount(self.block_of[self.rows], pm.area[self.rows], len(members))
        self.share = pm.area[self.rows] / area[self.block_of[self.rows]]

    def radiance(self, B: np.ndarray, blocks: np.ndarray) -> np.ndarray:
        """The area-weighted mean of B (P,3) over each of `blocks` (n,3)."""
        b = self.block_of[self.rows]
        w = self.share[:, None] * B[self.rows]
        out = np.stack([np.bincount(b, w[:, c], len(self.centre)) for c in range(3)], 1)
        return out[blocks]


class PatchBlocks:
    """The non-emitting quads' patches merged in blocks of k x k of each size k in BLOCKS (fewer at a
    quad's edge), per scene: a block's corners span its patches (one rectangle of the quad: form
    factors add over it), its radiance is their area-weighted mean. Seen from a point d away a
    block of radius r differs from its patches' sum by O(r/d) of the radiance's variation over it
    (the form factor's gradient across it) and by the visibility of its centre standing for its
    patches', so a block is used whole only farther than BLOCK_NEAR block radii from the object's
    bounding sphere, the coarsest such block (gather_set)."""

    def __init__(self, pm):
        grids = []
        for qi in np.unique(pm.quad):
            idx = np.flatnonzero(pm.quad == qi)
            grid = _patch_grid(pm, idx)
            if grid is not None and not pm.is_emitter[idx].any():
                grids.append((idx, *grid))
        self.levels = [_Level(pm, grids, k) for k in BLOCKS]
        self._pm = pm

    def gather_set(self, B: np.ndarray, centre: np.ndarray, radius: float
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(corners (M,4,3), normals (M,3), radiance (M,3)) of the patches and blocks to gather B (P,3)
        from at an object of bounding sphere (centre, radius): each patch in the coarsest of its
        blocks farther than BLOCK_NEAR block radii from the sphere, or alone."""
        pm = self._pm
        free = np.ones(pm.n_patches, bool)  # patches not yet in a chosen block
        corners, normals, rad = [], [], []
        for lv in self.levels[::-1]:
            far = np.linalg.norm(lv.centre - centre, axis=1) - radius > BLOCK_NEAR * lv.radius
            rows = lv.rows[free[lv.rows] & far[lv.block_of[lv.rows]]]
            used = np.unique(lv.block_of[rows])
            free[rows] = False
            corners.append(lv.corners[used])
            normals.append(lv.normal[used])
            rad.append(lv.radiance(B, used))
        fine = np.flatnonzero(free)
        return (np.concatenate([pm.corners[fine], *corners]), np.concatenate([pm.normal[fine], *normals]),
                np.concatenate([B[fine], *rad]))


def _patch_grid(pm, idx: np.ndarray) -> tuple[int, int] | None:
    """(nu, nv) of one quad's patches idx (recon.patches.build_patches: iu major, corner 0 -> 1 along
    u, 0 -> 3 along v), or None where they do not form that grid."""
    c = pm.corners[idx]
    ev, eu = c[0, 3] - c[0, 0], c[0, 1] - c[0, 0]
    size = max(np.linalg.norm(ev), np.linalg.norm(eu), 1e-12)
    d = c[:, 0] - c[0, 0]
    off_v = np.linalg.norm(d - np.outer(d @ ev / (ev @ ev), ev), axis=1) > 1e-6 * size  # left the first column
    nv = int(np.argmax(off_v)) if off_v.any() else len(idx)
    nu = len(idx) // nv
    if nu * nv != len(idx) or nu * nv < 2:
        return None
    g = c.reshape(nu, nv, 4, 3)
    expect = c[0, 0] + np.arange(nu)[:, None, None] * eu + np.arange(nv)[None, :, None] * ev
    if np.abs(g[:, :, 0] - expect).max() > 1e-6 * size * max(nu, nv):
        return None
    return nu, nv


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
    tolerance: float = 0.0  # a triangle is a point emitter at a receiver where that is within this share
    # of its unoccluded light (kernels.visibility.emitter_sum_seen_bounded); 0: exact form factors
    uploaded: SeenEmitters | None = None  # tris, rad, seen and tolerance already on the device (one upload
    # for the frame's sums), or None


def _far_emitters(tris: np.ndarray, rad: np.ndarray, seen: np.ndarray, extra: ExtraEmitters | None) -> tuple:
    """_reflected's far_emitters of triangles (T,3,3) with radiance rad (T,3) and visibility rows seen,
    then the extra emitters' far-field stand-ins (when given)."""
    tn = cross3(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    far = (tris.mean(1), tn, rad, seen)
    if extra is None:
        return far
    return tuple(np.concatenate([a, b]) for a, b in zip(far, (extra.far_c, extra.far_tn, extra.far_rad,
                                                             extra.far_seen)))


def cell_facing_key(c: np.ndarray, tn: np.ndarray, cells: int) -> np.ndarray:
    """(N,) int64 group key in [0, 6 cells^3) of emitters at c (N,3) with area normals tn (N,3): the cell of
    their box (`cells` a side) times 6 plus the axis the normal faces most (0..5: +x, -x, +y, -y, +z, -z)."""
    nrm = tn / np.maximum(np.linalg.norm(tn, axis=1, keepdims=True), 1e-12)
    ax = np.abs(nrm).argmax(1)
    facing = 2 * ax + (nrm[np.arange(len(nrm)), ax] < 0)
    lo, hi = c.min(0), c.max(0)
    cell = np.clip(((c - lo) / np.maximum(hi - lo, 1e-9) * cells).astype(np.int64), 0, cells - 1)
    return (cell @ np.array([1, cells, cells * cells])) * 6 + facing


class FarGroups:
    """The far field's point emitters of one proxy shape merged by cell (`cells` a side of their box) and facing
    axis, as _source_groups groups them (a drag frame's far field, ObjectLight.far_cells: at most 48 emitters in
    place of the proxy's triangles). Per group the summed area normal tn_g = sum tn_t, and the centroid, the
    radiance and the visibility rows averaged with weights w_t = tn_t . tn_g / |tn_g| (each member's area
    projected on the group's facing; a fractional table, which point_emitter_sum takes). For a receiver in front
    of every member this keeps sum_t B_t cos_t A_t to first order in the members' spread over the distance; at
    FAR_FIELD (3) radii and 2 cells a side the spread is under half the distance. Made once per shape (the
    grouping, the normals and the table do not change with a translation); per frame two sparse products."""

    def __init__(self, c: np.ndarray, tn: np.ndarray, seen: np.ndarray, cells: int):
        _, group = np.unique(cell_facing_key(c, tn, cells), return_inverse=True)
        m = int(group.max()) + 1 if len(group) else 0
        self.tn = np.stack([np.bincount(group, tn[:, j], m) for j in range(3)], 1)
        n_g = self.tn / np.maximum(np.linalg.norm(self.tn, axis=1, keepdims=True), 1e-12)
        w = np.maximum(np.einsum("tc,tc->t", tn, n_g[group]), 0.0)
        wsum = np.maximum(np.bincount(group, w, m), 1e-30)
        self.W = sp.csr_matrix((w / wsum[group], (group, np.arange(len(group)))), shape=(m, len(group)))
        self.seen = np.asarray(self.W @ np.asarray(seen, np.float64), np.float32)

    def emitters(self, c: np.ndarray, rad: np.ndarray) -> tuple:
        """(centres (G,3), twice the area x unit normal (G,3), radiance (G,3), visibility rows (G, 6 CUBE_RES^2))
        of the groups, for the triangles' centroids c (T,3) and radiance rad (T,3) of this frame."""
        return self.W @ c, self.tn, self.W @ np.asarray(rad, np.float64), self.seen


ROOM_EPS = 1e-3  # m: a receiver's end of its segments to the object pulled off its surface along its normal
ROOM_CELLS = 2  # cells a side of the object's box that group its light into point sources (room_share;
# 3 and 4 gave the same error against a ray per (receiver, triangle) on sun_102's receiver vertices)


def _source_groups(tris: np.ndarray, tri_rad: np.ndarray, extra: ExtraEmitters | None, cells: int = ROOM_CELLS
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(points (G,3), unit normals (G,3), power (G,)) of the object's light grouped by cell (`cells` a
    side of the emitters' box) and by the axis its emitters face (the largest component of the normal,
    with its sign): per group the power-weighted centroid and mean normal of its emitters (the proxy's
    triangles of radiance tri_rad (T,3) and the extra emitters' far-field stand-ins) and their power
    (luminance x area); groups without light are left out."""
    tn = cross3(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])  # twice the area x normal
    c, P = tris.mean(1), luminance(tri_rad) * 0.5 * np.linalg.norm(tn, axis=1)
    if extra is not None and len(extra.far_c):
        c, tn = np.concatenate([c, extra.far_c]), np.concatenate([tn, extra.far_tn])
        P = np.concatenate([P, luminance(extra.far_rad) * 0.5 * np.linalg.norm(extra.far_tn, axis=1)])
    P = np.maximum(P, 0.0)
    nrm = tn / np.maximum(np.linalg.norm(tn, axis=1, keepdims=True), 1e-12)
    group = cell_facing_key(c, tn, cells)
    m = 6 * cells ** 3
    power = np.bincount(group, P, m)
    on = np.flatnonzero(power > 0)
    pts = np.stack([np.bincount(group, P * c[:, j], m) for j in range(3)], 1)[on] / power[on, None]
    n = np.stack([np.bincount(group, P * nrm[:, j], m) for j in range(3)], 1)[on]
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    return pts, n, power[on]


def room_share(points: np.ndarray, normals: np.ndarray, tris: np.ndarray, tri_rad: np.ndarray,
               room: Occluder, extra: ExtraEmitters | None = None, workspace: Workspace | None = None,
               cells: int = ROOM_CELLS) -> np.ndarray:
    """(N,) in [0, 1]: the share of the object's light that reaches each receiver point (N,3, unit
    normals (N,3)) past the room `room` (its walls and furniture; the object itself is not in it).

    The object's own sums (emitter_sum, point_emitter_sum) test only the object as occluder: its light
    went through a sofa seat onto the sofa's back and through the sofa back onto the wall (sun_102: a
    sunlit torus 2 m in front of a sofa, +2 levels on the sofa back where the truth has +0.2). A
    receiver's view of the object is blocked as a whole or along an occluder's edge across it, so the
    object is taken as a few point sources (_source_groups: by cell of its box, 2 a side, and by the axis
    its faces face: at most 48), each weighted at the receiver by the point-source form factor (power x both
    cosines / distance^2) and tested with one segment: a few rays per receiver in place of one per
    (receiver, triangle). Groups whose faces look away from a receiver weigh nothing there, so a face
    the room hides does not borrow the visibility of the object's far side. One launch, a thread per receiver
    (kernels.room_share; room_share_numpy: the numpy it replaced, within 1e-12)."""
    if len(points) == 0:
        return np.ones(0)
    src, src_n, power = _source_groups(tris, tri_rad, extra, cells)
    return room_share_launch(points, normals, src, src_n, power, room, ROOM_EPS, workspace, 6 * cells ** 3)


def room_share_numpy(points: np.ndarray, normals: np.ndarray, tris: np.ndarray, tri_rad: np.ndarray,
                     room: Occluder, extra: ExtraEmitters | None = None, workspace: Workspace | None = None,
                     cells: int = ROOM_CELLS) -> np.ndarray:
    """room_share in numpy, with segments_visible for the segments (the weights as (N,G) arrays): the reference
    of its kernel (kernels.room_share) and the bench's "before"."""
    n = len(points)
    out = np.ones(n)
    if n == 0:
        return out
    src, src_n, power = _source_groups(tris, tri_rad, extra, cells)
    if len(src) == 0:
        return out
    d = src[None] - points[:, None]  # (N,G,3) receiver -> source
    dist2 = np.maximum(np.einsum("ngc,ngc->ng", d, d), 1e-12)
    cos_x = np.einsum("ngc,nc->ng", d, normals)
    cos_s = -np.einsum("ngc,gc->ng", d, src_n)
    w = power[None] * np.maximum(cos_x, 0.0) * np.maximum(cos_s, 0.0) / dist2 ** 2
    rows, g = np.nonzero(w > 0)
    if len(rows) == 0:
        return out
    vis = np.zeros(w.shape)
    vis[rows, g] = segments_visible(room, points[rows] + normals[rows] * ROOM_EPS, src[g], workspace)
    total = w.sum(1)
    ok = total > 0
    out[ok] = (w * vis).sum(1)[ok] / total[ok]
    return out


def _sphere_ff(r: float, d: np.ndarray) -> np.ndarray:
    """min(1, (r/d)^2): the most form factor (projected solid angle / pi) anything inside a sphere of
    radius r sends to a point at distance d from its centre (the whole sphere above the horizon)."""
    return np.minimum(1.0, (r / np.maximum(d, 1e-9)) ** 2)


def _light_bound(points: np.ndarray, dist: np.ndarray, tri_rad: np.ndarray, radius: float,
                 extra: ExtraEmitters | None, centre: np.ndarray) -> np.ndarray:
    """An upper bound (N,3) of the object's light (irradiance/pi) at points (N,3), dist (N,) from the
    centre of its bounding sphere of `radius`: the brightest triangle over the sphere's form factor
    (_sphere_ff). The extra emitters (the sunlit pieces: small, a few times brighter) are bounded over
    their own sphere and added, where that is less than the brightest of both over the object's.
    centre: the bounding sphere's centre (3,) that `dist` is measured from; the distances to the
    pieces' sphere come from dist and one product per point,
    |p - c|^2 = dist^2 + 2 (p - centre).(centre - c) + |centre - c|^2, not from (N,3) differences.
    With the pieces the sums run per channel over (3,N) rows (numpy's (N,1) x (3,) broadcasts loop 3
    values at a time: several times slower on ~1e4-1e5 points); the result is their transpose."""
    f_obj = _sphere_ff(radius, dist)
    if extra is None or len(extra.tris) == 0:
        return tri_rad.max(0) * f_obj[:, None]
    v = extra.tris.reshape(-1, 3)
    c = 0.5 * (v.min(0) + v.max(0))
    r = float(np.linalg.norm(v - c, axis=1).max())
    w = np.asarray(centre, np.float64) - c
    d2 = dist * dist + 2.0 * (points @ w - float(np.asarray(centre, np.float64) @ w)) + float(w @ w)
    # 1e-9: this d^2's rounding (against |p - c|^2 from the differences) kept on the bound's side
    f_pc = _sphere_ff(r, np.sqrt(np.maximum(d2, 0.0)) * (1.0 - 1e-9))
    t, rad = tri_rad.max(0), extra.rad.max(0)
    out = np.minimum(np.maximum(t, rad)[:, None] * f_obj, t[:, None] * f_obj + rad[:, None] * f_pc)
    return out.T


def _headroom_at(resp, L: np.ndarray, levels: float) -> np.ndarray:
    """headroom (n,3) float32 of the radiance L (n,3) under the response resp (no cache)."""
    xs, ys = resp.breakpoints()
    y = (resp.to_levels(L) + levels) / 255.0  # the response value to exceed, (n,3)
    out = np.full(y.shape, np.inf, np.float32)
    for ch in range(3):
        k = np.searchsorted(ys[ch], y[:, ch], side="right")  # first breakpoint above it
        ok = k < ys.shape[1]
        k = k[ok]
        x0, x1, y0, y1 = xs[ch, k - 1], xs[ch, k], ys[ch, k - 1], ys[ch, k]
        x_top = x0 + (y[ok, ch] - y0) / (y1 - y0) * (x1 - x0)  # the largest X with f(X) <= y
        out[ok, ch] = np.maximum(x_top / resp.exposure_time - L[ok, ch], 0.0)
    return out


FAR_FIELD = 3.0  # bounding radii from the object's centre beyond which its triangles act as point sources
# The drag frame's far field merges them 2 cells a side (ObjectLight.far_cells, FarGroups): at most 48
# point emitters, each spanning at most half the object's box, seen from FAR_FIELD radii or farther; the same
# grouping as room_share's (ROOM_CELLS: 3 and 4 a side gave 2's error there)
DRAG_FAR_CELLS = 2


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
        tn = cross3(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
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


FREE_RES = 8  # cells per cube face side of the proxy triangles' ray-free directions (free_cells)
# bounces among the object's own faces of the light it sends to the room (ObjectLight.self_light): the truth's 4
# bounces less the room pixel's and the first light's (sun -> face -> face -> face -> room pixel)
SELF_BOUNCES = 2
EXACT_EPS = 1e-3  # m: the exact sum's ray ends pulled off the surfaces (kernels.visibility.emitter_sum's eps)
GATHER_EPS = 2e-3  # m: triangle_radiance's (transfer_matrix's eps)


def _cell_cones(res: int) -> tuple[np.ndarray, np.ndarray]:
    """Per cube-map cell (kernels.visibility.cube_cell's layout, 6 res^2): the unit direction of its
    centre (C,3) and the largest angle (C,) from it to the cell's directions (at a corner: the
    directions within an angle of the centre cut the face plane in a convex region)."""
    centre = _cube_dirs(res)
    g = np.arange(res + 1) / res * 2 - 1
    half = np.zeros(len(centre))
    for face in range(6):
        a, neg = divmod(face, 2)
        for du in (0, 1):
            for dv in (0, 1):
                c = np.zeros((res, res, 3))
                c[:, :, a] = -1.0 if neg else 1.0
                c[:, :, (a + 1) % 3] = g[du:du + res, None]
                c[:, :, (a + 2) % 3] = g[None, dv:dv + res]
                c = c.reshape(-1, 3) / np.linalg.norm(c.reshape(-1, 3), axis=1, keepdims=True)
                sl = slice(face * res * res, (face + 1) * res * res)
                half[sl] = np.maximum(half[sl], np.arccos(np.clip((c * centre[sl]).sum(1), -1.0, 1.0)))
    return centre, half


def free_cells(tris: np.ndarray, eps: tuple[float, float] = (EXACT_EPS, EXACT_EPS), res: int = FREE_RES
               ) -> np.ndarray:
    """(T, 6 res^2) bool: per triangle the cube cells of directions from its centroid + e x its unit
    normal (the apex, any e in the range eps) in which no ray meets another triangle of the shape, a
    conservative test: a
    triangle wholly behind the apex's plane parallel to the triangle is never met by a ray that leaves
    in front of it (emitter_sum only uses the table for those); any other is met only in the
    directions of the cone over its three vertices, so a cell whose cone (_cell_cones) lies outside
    it (its axis outside, farther than its half-angle from each edge's arc) is free of it. The margins
    (1e-3 rad, and 1e-4 of the shape's size + the apex's range at the nearest vertex) cover the
    float32 rays, the cell assignment and where the apex lies; an apex in or near a triangle's plane
    frees nothing."""
    T = len(tris)
    n = cross3(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    lo, hi = min(eps), max(eps)
    apex = tris.mean(1) + n * (0.5 * (lo + hi))  # (T,3) the rays' starting points (+- (hi - lo) / 2)
    size = float(np.ptp(tris.reshape(-1, 3), axis=0).max())
    axis, half = _cell_cones(res)
    free = np.ones((T, len(axis)), bool)
    for t in range(T):
        rel = tris - apex[t]  # (U,3,3) the other triangles' vertices from the apex
        cand = (rel @ n[t]).max(1) > -1e-4 * size - 0.5 * (hi - lo)  # in front of the lowest apex
        cand[t] = False
        rel = rel[cand]
        if len(rel) == 0:
            continue
        dist = np.linalg.norm(rel, axis=2)  # (U,3)
        margin = 1e-3 + (1e-4 * size + hi) / np.maximum(dist.min(1), 1e-12)  # (U,) rad
        v = rel / np.maximum(dist, 1e-300)[..., None]  # unit directions of the vertices
        det = np.einsum("uc,uc->u", v[:, 0], cross3(v[:, 1], v[:, 2]))
        if (np.abs(det) < 1e-9).any() or (margin > 0.5).any():  # the apex near a triangle's plane
            free[t] = False
            continue
        sgn = np.sign(det)[:, None]
        # within half + margin of the cone, as cosines and sines (no angle per cell and triangle):
        # phi = half + margin < pi/2 (cells are narrower than 60 deg, margin <= 0.5)
        cos_phi = np.outer(np.cos(half), np.cos(margin)) - np.outer(np.sin(half), np.sin(margin))  # (C,U)
        sin_phi = np.outer(np.sin(half), np.cos(margin)) + np.outer(np.cos(half), np.sin(margin))
        inside = np.ones((len(axis), len(v)), bool)
        near = np.zeros((len(axis), len(v)), bool)
        for e in range(3):
            a, b = v[:, e], v[:, (e + 1) % 3]
            m = cross3(a, b)
            m /= np.maximum(np.linalg.norm(m, axis=1, keepdims=True), 1e-300)  # (U,3) the edge's circle
            h = axis @ m.T  # (C,U) sine of the axis' angle to the edge's great circle
            inside &= h * sgn.T > 0  # on the triangle's side of it
            # the angle from the axis to the arc: to its great circle where the foot lies between the
            # ends, else to the nearer end
            # (the foot, axis - h m, has the axis' products with m x a and b x m: both lie in the circle's plane)
            between = (axis @ cross3(m, a).T >= 0) & (axis @ cross3(b, m).T >= 0)
            near |= np.where(between, np.abs(h) <= sin_phi, np.maximum(axis @ a.T, axis @ b.T) >= cos_phi)
        free[t] = ~(inside | near).any(1)
    return free


class ProxyShape:
    """Per proxy shape (a translation changes none of it): the triangles' visibility table
    (TriangleVisibility), unit normals (T,3) and ray-free directions for the exact sum (free_cells)."""

    def __init__(self, tris: np.ndarray, proxy_occ: Occluder):
        self.visibility = TriangleVisibility(tris, proxy_occ)
        n = cross3(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
        self.normals = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
        self.free = free_cells(tris, (EXACT_EPS, GATHER_EPS))


_shape_key_last: tuple | None = None  # shape_key's last (pv copy, pf copy, key): one tuple, rebound whole


def shape_key(pv: np.ndarray, pf: np.ndarray) -> str:
    """The key of a proxy's shape: the centred proxy to 1 um (a translation keeps it). A frame asks it ~8 times of
    the same proxy (~40 us of hashing each): the last arrays' key is kept and returned for equal arrays (the same
    shape, dtype and values; docs/benchmarks.md, "glue111")."""
    global _shape_key_last
    last = _shape_key_last
    if last is not None and same_key(last[:2], (pv, pf)):
        return last[2]
    key = hashlib.sha1(np.round(pv - pv.mean(0), 6).tobytes() + np.ascontiguousarray(pf).tobytes()).hexdigest()
    _shape_key_last = (np.array(pv, copy=True), np.array(pf, copy=True), key)
    return key


def _reflected(points: np.ndarray, normals: np.ndarray, tris: np.ndarray, tri_rad: np.ndarray, proxy_occ: Occluder,
               centre: np.ndarray, radius: float, device, tvis: TriangleVisibility | None = None,
               ws: Workspace | None = None, far_emitters: tuple | None = None,
               extra: ExtraEmitters | None = None, free: np.ndarray | None = None,
               room: Occluder | None = None, room_cells: int = ROOM_CELLS, far_groups: FarGroups | None = None,
               tables: LightTables | None = None, share_above: float | None = None,
               far_field: float = FAR_FIELD) -> np.ndarray:
    """sum_t B_t F(x -> t) V(x, t) (N,3) at points (N,3) [normals (N,3)]: exact (emitter_sum) within
    FAR_FIELD bounding radii of the object; beyond, where each triangle subtends a small solid angle,
    the point-source form factor A_t cos_x cos_t / (pi r^2) times the triangle's own visibility
    towards x from the per-shape table `tvis` (the object is the only occluder, as in emitter_sum).
    ws: the call site's kernel buffers (kernels.buffers.Workspace), or None. far_emitters: the point
    emitters used beyond FAR_FIELD instead of the triangles' centroids, (positions (F,3), twice area x
    unit normal (F,3), radiance (F,3), visibility table rows (F, 6 CUBE_RES^2) bool), or None. extra:
    more emitters summed exactly within FAR_FIELD (_exact_sum), or None. free: the shape's free_cells
    (fewer rays in the exact sum), or None. room: the room's occluder, whose walls and furniture between
    a point and the object take their share of its light (room_share, its light grouped in room_cells a side), or
    None (the object alone). far_groups: the triangles' far field merged (FarGroups of this shape; used when no
    far_emitters are given), None: each triangle its own. tables: the near sum's triangles seen through the
    shape's table, no rays (LightTables: a drag frame), or None. share_above: the room's share only at points whose
    light's luminance exceeds this (the others keep all of it), None: at every lit point. far_field: the bounding
    radii beyond which the triangles are point emitters (FAR_FIELD; a drag frame's vertices: ObjectLight.far_field)."""
    out = np.zeros((len(points), 3))
    far = np.linalg.norm(points - centre, axis=1) > far_field * radius
    near = np.flatnonzero(~far)
    if len(near):
        out[near] = _exact_sum(points[near], normals[near], tris, tri_rad, proxy_occ, device, ws, extra, free, tables)
    far = np.flatnonzero(far)
    if len(far):
        if far_emitters is None and far_groups is not None:
            c, tn, rad, seen = far_groups.emitters(tris.mean(1), tri_rad)
        elif far_emitters is None:
            c = tris.mean(1)
            tn = cross3(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])  # (T,3) twice the area x normal
            rad = tri_rad
            seen = tvis.seen if tvis is not None else np.ones((len(tris), 6 * CUBE_RES ** 2), bool)
        else:
            c, tn, rad, seen = far_emitters
        out[far] = point_emitter_sum(points[far], normals[far], c, tn, rad, seen, CUBE_RES, device=device,
                                     split=256, workspace=_sub_workspace(ws, "far"), capacity=2 * len(tris))
    if room is not None:
        lit = np.flatnonzero(out.any(1) if share_above is None else luminance(out) > share_above)
        out[lit] *= room_share(points[lit], normals[lit], tris, tri_rad, room, extra,
                               _sub_workspace(ws, "room"), room_cells)[:, None]
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


GRID_STRIDES = (16, 8, 4, 2)  # px between the adaptive grid's exact samples, coarse to fine (_near_pixels)
GRID_TOLERANCE = 0.5  # levels: a cell of the coarsest stride whose nodes differ by more is refined
# (x (coarsest / stride)^2 at a finer stride: the blend's error falls with the cell's area)
GRID_CLEARANCE = 2.0  # a cell is blended only this many cell diagonals away from the object or farther


def _exact_sum(points: np.ndarray, normals: np.ndarray, tris: np.ndarray, tri_rad: np.ndarray, proxy_occ: Occluder,
               device, ws: Workspace | None, extra: ExtraEmitters | None = None,
               free: np.ndarray | None = None, tables: LightTables | None = None) -> np.ndarray:
    """sum_t B_t F(x -> t) V(x, t) (N,3): the proxy's triangles with a ray each (emitter_sum; none where
    `free`, the shape's free_cells, shows no ray can be blocked), plus the extra emitters with their
    visibility from their per-shape table (emitter_sum_seen_bounded, within extra.tolerance); with the
    extra emitters uploaded (extra.uploaded), both sums in one launch (SeenEmitters.sum_with_rays).
    tables: the proxy's triangles too with their visibility from the shape's table and point form factors
    within its tolerance (LightTables: a drag frame; no ray), None: a ray each."""
    if tables is not None:
        rays = tables.rays_at(points)
        if rays.any():  # within the bounding sphere: a ray each, as without tables
            out = np.empty((len(points), 3))
            out[rays] = _exact_sum(points[rays], normals[rays], tris, tri_rad, proxy_occ, device,
                                   _sub_workspace(ws, "rays"), extra, free)
            far = ~rays
            if far.any():
                out[far] = _exact_sum(points[far], normals[far], tris, tri_rad, proxy_occ, device, ws, extra, free,
                                      tables)
            return out
        out = tables.emitters(tris, tri_rad, device, ws).sum(points, normals, split=256, workspace=ws)
        if extra is not None and len(extra.tris):
            out += _extra_sum(points, normals, extra, device, ws)
        return out
    if extra is not None and len(extra.tris) and extra.uploaded is not None:  # both in one launch
        return extra.uploaded.sum_with_rays(points, normals, tris, tri_rad, proxy_occ, eps=EXACT_EPS, split=256,
                                            workspace=ws, free=free, free_res=FREE_RES)
    out = emitter_sum(points, normals, tris, tri_rad, proxy_occ, eps=EXACT_EPS, device=device, split=256,
                      workspace=ws, free=free, free_res=FREE_RES)
    if extra is not None and len(extra.tris):
        out += _extra_sum(points, normals, extra, device, ws)
    return out


def _extra_sum(points: np.ndarray, normals: np.ndarray, extra: ExtraEmitters, device, ws: Workspace | None
               ) -> np.ndarray:
    """The extra emitters' light (N,3) at points (N,3) [normals (N,3)], from their tables (their upload when
    they have one)."""
    if extra.uploaded is not None:
        return extra.uploaded.sum(points, normals, split=256, workspace=_sub_workspace(ws, "extra"))
    return emitter_sum_seen_bounded(points, normals, extra.tris, extra.rad, extra.seen, extra.res, extra.tolerance,
                                    device=device, split=256, workspace=_sub_workspace(ws, "extra"),
                                    capacity=extra.capacity)


class LightTables:
    """A drag frame's proxy emitters (ObjectLight.tables): each triangle's visibility from the shape's
    TriangleVisibility table (the directions its centroid sees out of the object, CUBE_RES a face side), not a
    ray per (receiver, triangle), and a triangle far enough from a receiver as a point emitter or its quarters'
    mid-point rule where the bound of that error is within `tolerance` of its unoccluded light
    (kernels.visibility.emitter_sum_seen_bounded); the sum at a receiver then costs a table lookup and mostly
    one division per triangle in place of three arc tangents and a ray. The table errs where another part of
    the object lies between a triangle and a receiver off its cell's centre ray (a cell spans about 14 deg): on
    the bundled scene 26 near pixels lost up to 28 levels at 0.91-1 bounding radii from the centre, where a
    receiver may touch the object and a cell is wider than the gap; so the receivers within the bounding sphere
    (`sphere`, set per frame) keep a ray per triangle."""

    def __init__(self, seen: np.ndarray, tolerance: float, capacity: int):
        """seen: the triangles' rows of the table (T, 6 CUBE_RES^2) bool; capacity: the shape's triangles (the
        buffers' size: a frame summing some of its faces allocates nothing)."""
        self.seen, self.tolerance, self.capacity = seen, tolerance, capacity
        self._last: tuple | None = None  # (tris, tri_rad, SeenEmitters) of the last upload
        self.sphere: tuple[np.ndarray, float] | None = None  # the object's bounding sphere (centre, radius) this frame

    def rays_at(self, points: np.ndarray) -> np.ndarray:
        """(N,) bool: the points (N,3) within the bounding sphere (none without one), which keep their rays."""
        if self.sphere is None:
            return np.zeros(len(points), bool)
        c, r = self.sphere
        d = points - c
        return np.einsum("nc,nc->n", d, d) <= r * r

    def emitters(self, tris: np.ndarray, tri_rad: np.ndarray, device, ws: Workspace | None) -> SeenEmitters:
        """The triangles tris (T,3,3) of radiance tri_rad (T,3) uploaded with their table rows, in ws's
        sub-workspace "tables" (kept: nothing allocated after a shape's first frame); the last upload again
        where it holds the same triangles and radiance (a frame's vertices, pixels and centres share one)."""
        last = self._last
        if last is not None and np.array_equal(last[0], tris) and np.array_equal(last[1], tri_rad):
            return last[2]
        em = SeenEmitters(device, _sub_workspace(ws, "tables"))
        em.set(tris, tri_rad, self.seen, CUBE_RES, self.tolerance, capacity=self.capacity)
        self._last = (np.array(tris, copy=True), np.array(tri_rad, copy=True), em)
        return em


def _sub_workspace(ws: Workspace | None, name: str) -> Workspace | None:
    """ws.sub(name), None without a workspace (fresh buffers)."""
    return None if ws is None else ws.sub(name)


class _ScreenValues:
    """Exact object light at screen pixels, kept in dense (H*W,) maps for one frame's _near_pixels
    (made once per engine; `clear` resets the pixels written, so no pass over the frame)."""

    def __init__(self, n_pixels: int):
        self.known = np.zeros(n_pixels, bool)
        self.value = np.zeros((n_pixels, 3))
        self._written: list[np.ndarray] = []
        self.count = 0

    def add(self, idx: np.ndarray, values_of) -> None:
        """Evaluate values_of(pixels) at the distinct pixels `idx` not yet known."""
        new = idx[~self.known[idx]]
        if len(new):
            self.value[new] = values_of(new)
            self.known[new] = True
            self._written.append(new)
            self.count += len(new)

    def clear(self) -> None:
        for w in self._written:
            self.known[w] = False
        self._written, self.count = [], 0


def _distinct(idx: np.ndarray, size: int) -> np.ndarray:
    """The sorted distinct values of idx (ints in [0, size)) through a mark array (no sort)."""
    mark = np.zeros(size, bool)
    mark[idx] = True
    return np.flatnonzero(mark)


def _bilinear(corner: np.ndarray, fp: np.ndarray, W: int, s: int) -> np.ndarray:
    """(m,3): the bilinear blend of the cells' node values corner (m,4,3) (corners y0,x0 / y0,x0+s /
    y0+s,x0 / y0+s,x0+s) at pixels fp (m,) of a W-wide screen, cells of stride s; the four weights (4,m)
    as one product (numpy's (m,1) x (m,3) broadcasts loop 3 values at a time)."""
    y, x = np.divmod(fp, W)
    fy, fx = (y % s) / s, (x % s) / s
    w = np.empty((4, len(fp)))
    np.multiply(1 - fy, 1 - fx, out=w[0])
    np.multiply(1 - fy, fx, out=w[1])
    np.multiply(fy, 1 - fx, out=w[2])
    np.multiply(fy, fx, out=w[3])
    return np.einsum("km,mkc->mc", w, corner)


class StrideTable:
    """One stride s of _near_pixels' screen grid, per scene: cell ids of the pixels ((y//s) x cells a
    row + x//s), and whether a pixel's cell has its four nodes (corners y0, y0+s x x0, x0+s) on the
    screen and on receivers of one quad, the pixel's own (where a blend of the nodes is one plane's)."""

    def __init__(self, s: int, H: int, W: int, recv_pix: np.ndarray, pix_quad: np.ndarray):
        self.s, self.W, self.H = s, W, H
        self.wc = (W - 1) // s + 1
        self.n_cells = ((H - 1) // s + 1) * self.wc
        y, x = np.divmod(np.arange(H * W), W)
        self.cell = ((y // s) * self.wc + x // s).astype(np.int64)
        cells = np.arange(self.n_cells)
        ny, nx = self._corners(cells)
        inside = (ny < H) & (nx < W)
        nodes = np.where(inside, ny * W + nx, 0)
        q = pix_quad[nodes]
        cell_ok = (inside & recv_pix[nodes]).all(1) & (q == q[:, :1]).all(1)
        self.pixel_ok = cell_ok[self.cell] & (q[self.cell, 0] == pix_quad)

    def _corners(self, cells: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        y0, x0 = (cells // self.wc) * self.s, (cells % self.wc) * self.s
        return (np.stack([y0, y0, y0 + self.s, y0 + self.s], 1), np.stack([x0, x0 + self.s, x0, x0 + self.s], 1))

    def nodes(self, cells: np.ndarray) -> np.ndarray:
        """(C,4) pixel index of the cells' corners (cells with pixel_ok pixels: all on the screen)."""
        ny, nx = self._corners(cells)
        return ny * self.W + nx


def object_self_light(pv: np.ndarray, pf: np.ndarray, proxy_occ: Occluder, radiance: list[np.ndarray],
                      albedo: np.ndarray, bounces: int = SELF_BOUNCES, device: str | None = None,
                      workspace: Workspace | None = None) -> list[np.ndarray]:
    """The light the object's faces reflect onto each other (its interreflection), per part of their radiance.

    For each (T,3) array of `radiance` (the proxy (pv, pf)'s faces' outgoing radiance, irradiance/pi units: the
    room's light, the sun's face averages), the radiance (T,3) it adds to the faces after `bounces` bounces among
    them: L_k+1 = albedo x sum_t L_k,t F(centroid -> t) V (kernels.visibility.emitter_sum: exact polygon form
    factors, a centroid-to-centroid ray past the proxy), summed over k = 1..bounces. Linear in the radiance (the
    parts add). triangle_radiance's gather leaves the proxy's own faces dark (the proxy occludes, emits nothing);
    the truth's object is lit by itself too: on sun_101's chair 20 % of a face's hemisphere is the chair, 8 % of
    the light it sends to the room (bench/bench_sunglow110.py, docs/unseen.md "sunglow110"). A convex proxy gets 0."""
    tris = np.asarray(pv, np.float64)[pf]
    c = tris.mean(1)
    nrm = cross3(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    nrm = nrm / np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-30)
    out = []
    for L in radiance:
        total, step = np.zeros((len(tris), 3)), np.asarray(L, np.float64)
        for _ in range(bounces):
            if not step.any():
                break
            step = albedo * emitter_sum(c, nrm, tris, step, proxy_occ, eps=EXACT_EPS, device=device, split=256,
                                        workspace=workspace)
            total += step
        out.append(total)
    return out


class ObjectLight:
    """The light the object reflects onto the room, for one scene: built once from the receiver map
    (pixels, their patches, positions, reflectance, the photo's radiance and response), the patch
    mesh, the radiance receivers gather and the room's occluder; owns its per-scene tables
    (PatchBlocks, PixelTable, VertexInterpolation, StrideTables, headroom) and the per-shape
    ProxyShape, and its kernels' buffers. Irradiance/pi throughout."""

    def __init__(self, config: ObjectConfig, patches: PatchMesh, recv_vert: np.ndarray, pix_bary: np.ndarray,
                 pix_pos: np.ndarray, pix_patch: np.ndarray, pix_rows: np.ndarray, recv_pix: np.ndarray,
                 rho_x: np.ndarray, L_b: np.ndarray, B_src: np.ndarray, scene_occ: Occluder, response,
                 camera, device: str, sun_dir: np.ndarray | None = None):
        """config: near_factor (the per-pixel region); recv_vert (Vr,), pix_bary (H*W,3): the precompute's
        receiver vertices and pixel barycentrics; pix_pos, pix_patch, pix_rows, recv_pix, rho_x, L_b: the
        receiver map (app.stages.receiver_map, after the sun's changes); B_src (P,3): the radiance receivers
        gather; response: the camera's (headroom); sun_dir: unit direction towards the sun, or None."""
        self.config = config
        self.patches, self.recv_vert, self.pix_bary = patches, recv_vert, pix_bary
        self.pix_pos, self.pix_patch, self.pix_rows, self.recv_pix = pix_pos, pix_patch, pix_rows, recv_pix
        self.rho_x, self.L_b, self.B_src = rho_x, L_b, B_src
        self.scene_occ, self.response, self.camera, self.device = scene_occ, response, camera, device
        self.sun_dir = sun_dir
        # cells a side of the object's box that group its light for the room's share (room_share): ROOM_CELLS;
        # a drag frame sets app.dragframe.DRAG_ROOM_CELLS
        self.room_cells = ROOM_CELLS
        # the far field's emitters merged this many cells a side (FarGroups), None: every triangle its own (at
        # rest); a drag frame sets DRAG_FAR_CELLS (app.dragframe.DragStages)
        self.far_cells: int | None = None
        self._far_groups: tuple | None = None  # (shape key, cells, FarGroups) of the last proxy shape
        # the near sums' proxy triangles seen through the shape's visibility table within this tolerance
        # (LightTables), None: a ray per (receiver, triangle) (at rest); a drag frame sets
        # app.dragframe.DRAG_LIGHT_TABLES
        self.table_tolerance: float | None = None
        # the patch centres' light within this many bounding radii summed as near the pixels, beyond it the proxy's
        # far groups bounded by _light_bound, no room share (_coarse_centres); None: _reflected's (at rest); a drag
        # frame sets app.dragframe.DRAG_CENTRE_NEAR
        self.centre_near: float | None = None
        # the near pixels on _near_pixels's adaptive screen grid (True, at rest), or each summed (False: a drag
        # frame, app.dragframe.DRAG_LIGHT_GRID)
        self.near_grid = True
        # the room's share at the receiver vertices only where their light is drawn (passes the level at which
        # their patches take it; True: a drag frame, app.dragframe.DRAG_SHARE_DRAWN), False: at every lit vertex
        self.share_drawn = False
        # bounding radii beyond which the receiver vertices see the proxy as point emitters (FAR_FIELD at rest; a
        # drag frame sets app.dragframe.DRAG_FAR_FIELD; FAR_FIELD still with the sun's emitters: each sunlit face a
        # point from 2 radii moved sun_room's drag row by +0.007 energy, rmse_affected 1.208 -> 1.223)
        self.far_field = FAR_FIELD
        self._light_tables: tuple | None = None  # (ProxyShape, LightTables) of the last proxy shape
        # a drag frame's vertices and centres summed together (_drag_sums; False: apart, the same values)
        self.merge_sums = True
        self.n_pixels = 0  # pixels the last frame evaluated per pixel (the near region)
        self.n_exact = 0  # of those, the ones summed exactly (the rest blended on the screen grid)
        self._workspaces = Workspaces()
        self._patch_blocks: PatchBlocks | None = None
        self._pixel_table: PixelTable | None = None
        self._interpolation: VertexInterpolation | None = None
        self._strides: dict[int, StrideTable] = {}
        self._screen: _ScreenValues | None = None
        self._headroom: tuple | None = None
        self._proxy_shape: tuple | None = None  # (shape_key, ProxyShape) of the last proxy shape
        self._sun_centre_shape: str | None = None  # the proxy shape sun_centre_light last saw

    def triangle_radiance(self, obj: SceneObject, pv, pf, proxy_occ, B: np.ndarray) -> np.ndarray:
        """Outgoing radiance (T,3) of each proxy triangle, lit at its centroid by patches of radiance B
        (P,3), gathered with visibility past the scene and the proxy (self-occlusion) over a coarse
        set of patches (PatchBlocks.gather_set): the emitters and the patches near the object as they
        are, the other patches merged in blocks of a quad's patches, coarser farther away."""
        c = pv[pf].mean(1)
        corners, normals, B_set = self.patch_blocks().gather_set(B, *bounding_sphere(pv))
        shape = self.proxy_shape(pv, pf, proxy_occ)
        G = transfer_matrix(c, shape.normals, corners, normals,
                            [self.scene_occ, proxy_occ], n_side=1, eps=GATHER_EPS, device=self.device,
                            chunk=max(16, -(-len(c) // 2)),  # two launches side by side: both cores
                            workspace=self._workspaces.get("object_irradiance"), free=shape.free, free_res=FREE_RES)
        return obj.albedo * (G.astype(np.float64) @ B_set)

    def self_light(self, pv, pf, proxy_occ, radiance: list[np.ndarray], albedo: np.ndarray,
                   bounces: int = SELF_BOUNCES) -> list[np.ndarray]:
        """object_self_light with this stage's device and buffers."""
        return object_self_light(pv, pf, proxy_occ, radiance, albedo, bounces, self.device,
                                 self._workspaces.get("object_light.self"))

    def patch_blocks(self) -> PatchBlocks:
        """The engine's PatchBlocks (made on first use: it depends on the scene only)."""
        if self._patch_blocks is None:
            self._patch_blocks = PatchBlocks(self.patches)
        return self._patch_blocks

    def light(self, pv, pf, tri_rad, proxy_occ, centre, radius, covered: np.ndarray | None = None,
                     extra: ExtraEmitters | None = None, centres: bool = True):
        """Light reflected by the object onto pixels (H*W,3) and patch centres (P,3), as irradiance/pi.

        Far from the object the reflected light varies slowly: it is evaluated at receiver vertices
        and interpolated like the transfers, on the pixels of the patches it reaches (one kernel over
        the frame, kernels.farfield.VertexInterpolation); beyond FAR_FIELD radii the proxy's triangles
        are point emitters (kernels.farfield.point_emitter_sum).
        Within `near_factor` bounding radii of the object's centre, where it changes fast (contact,
        under a seat), it is evaluated per pixel where the upper bound of its gain exceeds a quarter
        level: exactly on an adaptive screen grid, blended between the grid's nodes where the light
        varies slowly (_near_pixels). covered: optional (H*W,) bool, pixels the object hides entirely
        (their room is not seen: left at the interpolated value). extra: emitters besides the proxy's
        triangles (ExtraEmitters), or None. centres=False: R_cen is None (the caller sums it in parts, as
        the sun's branch does: sun_centre_light).
        """
        pm = self.patches
        table = self.pixel_table()
        tris = pv[pf]
        shape = self.proxy_shape(pv, pf, proxy_occ)
        tvis = shape.visibility
        far = _far_emitters(tris, tri_rad, tvis.seen, extra) if extra is not None else None
        rv = self.recv_vert
        # the light a receiver vertex must pass to be drawn (below it its patches keep the photo's light)
        drawn = 5e-4 * float(luminance(self.B_src).mean()) / float(self.rho_x.max())
        R_cen = None
        if centres and extra is None and self.centre_near is not None and self.merge_sums:
            R_v, R_cen = self._drag_sums(pv, pf, tris, tri_rad, proxy_occ, centre, radius, shape, drawn)
        else:
            R_v = _reflected(pm.vert_inset[rv], pm.vert_normal[rv], tris, tri_rad, proxy_occ, centre, radius,
                             self.device, tvis, self._workspaces.get("object_light.vertices"), far, extra, shape.free,
                             room=self.scene_occ, room_cells=self.room_cells,
                             far_groups=self.far_groups(pv, pf, shape),
                             tables=self.light_tables(shape, centre, radius, extra),
                             share_above=drawn if self.share_drawn else None,
                             far_field=self.far_field if extra is None else FAR_FIELD)
        # the pixels of the patches with a vertex that gets a visible share of the object's light take
        # the vertices' light, interpolated
        reach_v = luminance(R_v) * float(self.rho_x.max()) > 5e-4 * float(luminance(self.B_src).mean())
        touched = np.zeros(len(pm.vert_pos), bool)
        touched[rv[reach_v]] = True
        patch_on = np.zeros(pm.n_patches, bool)
        patch_on[pm.tri_patch[touched[pm.tris].any(1)]] = True
        R_pix = self.vertex_interpolation().run(patch_on, R_v)
        # near the object the pixels whose gain may pass a quarter level are evaluated per pixel
        # (_near_pixels): the pixels of the touched patches that reach within near_factor radii
        near_p = np.flatnonzero(patch_on & (np.linalg.norm(pm.centre - centre, axis=1)
                                            < self.config.near_factor * radius + pm.radius))
        rp = table.pixels_of(near_p)
        dist = np.linalg.norm(self.pix_pos[rp] - centre, axis=1)
        rp, dist = rp[dist < self.config.near_factor * radius], dist[dist < self.config.near_factor * radius]
        bound = self.rho_x[rp] * _light_bound(self.pix_pos[rp], dist, tri_rad, radius, extra, centre)
        above = bound > self.headroom(0.25, rp)  # T(L_b + bound) - T(L_b) > 0.25 level
        sel = rp[above[:, 0] | above[:, 1] | above[:, 2]]
        if covered is not None:
            sel = sel[~covered[sel]]
        if len(sel) and not self.near_grid:  # every near pixel summed (a drag frame's few hundred)
            R_pix[sel] = _exact_sum(self.pix_pos[sel], pm.normal[self.pix_patch[sel]], tris, tri_rad, proxy_occ,
                                    self.device, self._workspaces.get("near_pixels.exact"), extra, shape.free,
                                    self.light_tables(shape, centre, radius, extra))
            self.n_exact = len(sel)
        elif len(sel):
            R_pix[sel] = self._near_pixels(sel, tris, tri_rad, proxy_occ, extra, shape.free,
                                           self.light_tables(shape, centre, radius, extra))
        if centres and R_cen is None:
            R_cen = self.centre_light(pv, pf, tri_rad, proxy_occ, centre, radius, extra, far)
        self.n_pixels = len(sel)
        return R_pix, R_cen

    def centre_light(self, pv, pf, tri_rad, proxy_occ, centre, radius, extra: ExtraEmitters | None = None,
                     far: tuple | None = None, site: str = "object_light.centres",
                     faces: np.ndarray | None = None) -> np.ndarray:
        """The light (P,3) the object reflects onto the patch centres, as irradiance/pi (object_light's
        R_cen; far: its far-field emitters when there are extra ones; site: the call site's kernel buffers).
        faces: only these faces emit (their rows of the shape's tables; tri_rad (T,3) zero elsewhere), with
        the extra emitters."""
        pm = self.patches
        tris, rad = pv[pf], tri_rad
        shape = self.proxy_shape(pv, pf, proxy_occ)
        free = shape.free
        if faces is not None:
            tris, rad = tris[faces], tri_rad[faces]
            free = free[faces] if free is not None else None
            far = _far_emitters(tris, rad, shape.visibility.seen[faces], extra)
        dist_c = np.linalg.norm(pm.centre - centre, axis=1)
        reach = luminance(_light_bound(pm.centre, dist_c, tri_rad, radius, extra, centre))
        near_c = np.flatnonzero((reach > 1e-4 * luminance(self.B_src).mean()) & ~pm.is_emitter)
        R_cen = np.zeros((pm.n_patches, 3))
        if self.centre_near is not None and faces is None:  # a drag frame: the proxy's groups (DragCentres)
            R_cen[near_c] = self._coarse_centres(near_c, dist_c[near_c], pv, pf, tris, rad, proxy_occ, centre, radius,
                                                 extra, self._workspaces.get(site))
            return R_cen
        R_cen[near_c] = _reflected(pm.centre[near_c], pm.normal[near_c], tris, rad, proxy_occ, centre, radius,
                                   self.device, shape.visibility, self._workspaces.get(site), far, extra, free,
                                   room=self.scene_occ, room_cells=self.room_cells,
                                   far_groups=self.far_groups(pv, pf, shape) if faces is None else None,
                                   tables=self.light_tables(shape, centre, radius, extra, faces))
        return R_cen

    def sun_centre_light(self, pv, pf, sun_rad, proxy_occ, centre, radius, extra: ExtraEmitters | None,
                         site: str = "object_light.centres.sun") -> np.ndarray:
        """centre_light (P,3) of the object's light from the sun alone: the faces with sun radiance
        sun_rad (T,3) (the wholly sunlit ones; the others zero) and the lit pieces `extra`. Only those
        faces are summed (their rows of the shape's tables), so with centre_light of the room's light it
        makes the whole light at the patch centres for about the cost of one call (the sum is linear in
        the radiance; each part skips the centres its own bound puts below centre_light's threshold)."""
        key = shape_key(pv, pf)
        if self._sun_centre_shape != key:  # a shape's first frame: every face that faces the
            # sun (zero radiance where unlit), so that its kernel buffers are made at their capacity once
            self._sun_centre_shape = key
            T = pv[pf]
            faces = np.flatnonzero((cross3(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0]) @ self.sun_dir > 0)
                                   | sun_rad.any(1))
        else:
            faces = np.flatnonzero(sun_rad.any(1))
        if len(faces) == 0 and (extra is None or len(extra.tris) == 0):
            return np.zeros((self.patches.n_patches, 3))
        return self.centre_light(pv, pf, sun_rad, proxy_occ, centre, radius, extra, site=site, faces=faces)

    def centre_light_parts(self, pv, pf, room_rad, sun_rad, proxy_occ, centre, radius,
                           extra: ExtraEmitters | None, site: str = "object_light.centres.parts"
                           ) -> tuple[np.ndarray, np.ndarray]:
        """centre_light (P,3) of the room's light room_rad (T,3) and, apart, of the sun's: sun_rad (T,3) (the
        wholly sunlit faces; zero elsewhere) with the lit pieces `extra`, as centre_light(room_rad) and
        sun_centre_light give them (their sum: the whole light at the patch centres). One pass: near the
        object one launch sums both with one ray per face and centre (SeenEmitters.sum_with_rays2), at the
        centres the whole light's bound reaches (those of either part); beyond FAR_FIELD each part's point
        emitters (the sun's: its lit faces and the pieces' stand-ins)."""
        pm = self.patches
        tris = pv[pf]
        shape = self.proxy_shape(pv, pf, proxy_occ)
        if extra is None or extra.uploaded is None or len(extra.tris) == 0:  # no pieces: two plain calls
            return (self.centre_light(pv, pf, room_rad, proxy_occ, centre, radius, site=site + ".room"),
                    self.sun_centre_light(pv, pf, sun_rad, proxy_occ, centre, radius, extra, site=site + ".sun"))
        dist_c = np.linalg.norm(pm.centre - centre, axis=1)
        reach = luminance(_light_bound(pm.centre, dist_c, room_rad + sun_rad, radius, extra, centre))
        near_c = np.flatnonzero((reach > 1e-4 * luminance(self.B_src).mean()) & ~pm.is_emitter)
        room, sun = np.zeros((pm.n_patches, 3)), np.zeros((pm.n_patches, 3))
        ws = self._workspaces.get(site)
        if self.centre_near is not None:  # a drag frame: the proxy's groups (_coarse_centres), each part
            d = dist_c[near_c]
            room[near_c] = self._coarse_centres(near_c, d, pv, pf, tris, room_rad, proxy_occ, centre, radius, None,
                                                ws.sub("room"))
            sun[near_c] = self._coarse_centres(near_c, d, pv, pf, tris, sun_rad, proxy_occ, centre, radius, extra,
                                               ws.sub("sun"))
            return room, sun
        far = dist_c[near_c] > FAR_FIELD * radius
        c_near, c_far = near_c[~far], near_c[far]
        if len(c_near):
            room[c_near], sun[c_near] = extra.uploaded.sum_with_rays2(
                pm.centre[c_near], pm.normal[c_near], tris, room_rad, sun_rad, proxy_occ, eps=EXACT_EPS, split=256,
                workspace=ws, free=shape.free, free_res=FREE_RES)
        if len(c_far):
            faces = np.flatnonzero(sun_rad.any(1))
            for out, far_em, name in ((room, _far_emitters(tris, room_rad, shape.visibility.seen, None), "far.room"),
                                      (sun, _far_emitters(tris[faces], sun_rad[faces], shape.visibility.seen[faces],
                                                          extra), "far.sun")):
                out[c_far] = point_emitter_sum(pm.centre[c_far], pm.normal[c_far], *far_em, CUBE_RES,
                                               device=self.device,
                                               split=256, workspace=_sub_workspace(ws, name),
                                               capacity=2 * len(tris) + extra.capacity)
        # the room's walls and furniture between a centre and the object (room_share, of the whole light)
        lit = near_c[(room[near_c] + sun[near_c]).any(1)]
        share = room_share(pm.centre[lit], pm.normal[lit], tris, room_rad + sun_rad, self.scene_occ, extra,
                           ws.sub("room"), self.room_cells)
        room[lit] *= share[:, None]
        sun[lit] *= share[:, None]
        return room, sun

    def headroom(self, levels: float, idx: np.ndarray) -> np.ndarray:
        """(len(idx),3) float32: at pixels idx and per channel the most radiance s >= 0 (L_b's units) that
        added to the photo's L_b raises it by at most `levels` (8-bit levels: T(L_b + s) - T(L_b) <= levels;
        inf where T cannot rise that much), from the response's breakpoints (exact: T is piecewise linear
        and non-decreasing). A test s > headroom in place of T(L_b + s) - T(L_b) > levels, with no response
        evaluation per frame. It depends on the scene only, so a level's first call works it out at every
        receiver pixel at once and keeps it (per L_b array and level): a drag frame, whose near region moves
        onto new pixels, only looks it up. Per channel it is a function of the pixel's L_b alone, so it is
        evaluated once per distinct L_b value (a photo's pixels share few: its 8-bit levels) and gathered;
        a pixel outside the receivers is worked out when first asked for and kept."""
        cached = self._headroom
        if cached is None:
            rp = np.flatnonzero(self.recv_pix)
            vals = [np.unique(self.L_b[rp, c], return_inverse=True) for c in range(3)]  # (distinct values, rows)
            n = max(len(u) for u, _ in vals)
            table = np.stack([np.pad(u, (0, n - len(u)), mode="edge") for u, _ in vals], 1)  # (n,3) L_b values
            inv = np.stack([i.reshape(-1) for _, i in vals], 1)  # (len(rp),3) each receiver's row of table
            cached = self._headroom = (rp, table, inv, {})
        rp, table, inv, per_level = cached
        if levels not in per_level:
            h, known = np.zeros(self.L_b.shape, np.float32), np.zeros(len(self.L_b), bool)
            hv = _headroom_at(self.response, table, levels)
            h[rp] = np.take_along_axis(hv, inv, 0)
            known[rp] = True
            per_level[levels] = (h, known)
        h, known = per_level[levels]
        new = idx[~known[idx]]
        if len(new):
            h[new] = _headroom_at(self.response, self.L_b[new], levels)
            known[new] = True
        return h[idx]

    def far_groups(self, pv: np.ndarray, pf: np.ndarray, shape: ProxyShape) -> FarGroups | None:
        """The proxy's FarGroups (far_cells a side), kept for the last shape; None without far_cells."""
        if self.far_cells is None:
            return None
        key = shape_key(pv, pf)
        cached = self._far_groups
        if cached is None or cached[0] != key or cached[1] != self.far_cells:
            tris = pv[pf]
            tn = cross3(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
            cached = self._far_groups = (key, self.far_cells, FarGroups(tris.mean(1), tn, shape.visibility.seen,
                                                                        self.far_cells))
        return cached[2]

    def _drag_sums(self, pv, pf, tris: np.ndarray, tri_rad: np.ndarray, proxy_occ: Occluder, centre: np.ndarray,
                   radius: float, shape: ProxyShape, drawn: float) -> tuple[np.ndarray, np.ndarray]:
        """(R_v (Vr,3), R_cen (P,3)): a drag frame's light at the receiver vertices (as _reflected gives it with
        far_field, the tables and the room's share where luminance passes `drawn` when share_drawn) and at the
        patch centres (as centre_light gives it with centre_near: _coarse_centres), both sets' near receivers in
        one exact sum and their far ones in one far-group sum (the same emitters: each receiver's value is the
        same, in two launches' hand-offs to the cores, not four). No extra emitters (the sun's path sums its
        centres in parts)."""
        pm, rv = self.patches, self.recv_vert
        p_v, n_v = pm.vert_inset[rv], pm.vert_normal[rv]
        dist_c = np.linalg.norm(pm.centre - centre, axis=1)
        reach = luminance(_light_bound(pm.centre, dist_c, tri_rad, radius, None, centre))
        near_c = np.flatnonzero((reach > 1e-4 * luminance(self.B_src).mean()) & ~pm.is_emitter)
        pts, nrm = np.concatenate([p_v, pm.centre[near_c]]), np.concatenate([n_v, pm.normal[near_c]])
        nv = len(rv)
        dist = np.concatenate([np.linalg.norm(p_v - centre, axis=1), dist_c[near_c]])
        near = dist <= np.concatenate([np.full(nv, self.far_field), np.full(len(near_c), self.centre_near)]) * radius
        ws = self._workspaces.get("object_light.drag")
        out = np.zeros((len(pts), 3))
        if near.any():
            out[near] = _exact_sum(pts[near], nrm[near], tris, tri_rad, proxy_occ, self.device, ws, None, shape.free,
                                   self.light_tables(shape, centre, radius, None))
        far = np.flatnonzero(~near)
        if len(far):
            groups = self.far_groups(pv, pf, shape)
            em = groups.emitters(tris.mean(1), tri_rad) if groups is not None else _far_emitters(
                tris, tri_rad, shape.visibility.seen, None)
            out[far] = point_emitter_sum(pts[far], nrm[far], *em, CUBE_RES, device=self.device, split=256,
                                         workspace=ws.sub("far"), capacity=2 * len(tris))
            fc = far[far >= nv]  # the far centres: at most the sphere bound (_coarse_centres)
            out[fc] = np.minimum(out[fc], _light_bound(pts[fc], dist[fc], tri_rad, radius, None, centre))
        R_v = out[:nv]
        lit = np.flatnonzero(luminance(R_v) > drawn if self.share_drawn else R_v.any(1))
        R_v[lit] *= room_share(p_v[lit], n_v[lit], tris, tri_rad, self.scene_occ, None, ws.sub("room"),
                               self.room_cells)[:, None]
        R_cen = np.zeros((pm.n_patches, 3))
        R_cen[near_c] = out[nv:]
        return R_v, R_cen

    def _coarse_centres(self, idx: np.ndarray, dist: np.ndarray, pv, pf, tris: np.ndarray, rad: np.ndarray,
                        proxy_occ: Occluder, centre: np.ndarray, radius: float, extra: ExtraEmitters | None,
                        ws: Workspace) -> np.ndarray:
        """A drag frame's light (len(idx),3) of the triangles tris (T,3,3) of radiance rad (T,3) (and the extra
        emitters) at the patch centres idx, dist (len(idx),) from the bounding sphere's (centre, radius): within
        centre_near radii summed as the near pixels are (_exact_sum, through the shape's tables when table_tolerance
        is set), beyond as the far field's groups (FarGroups: at most 6 DRAG_FAR_CELLS^3 point emitters with the extra
        emitters' stand-ins), each centre's value at most _light_bound's (a point emitter nearer than its spread
        is not). No room share: in a drag frame the centres' light only feeds the second order (the object is
        shaded from its tables before it: app.stages.object_drag), which the room's light passes on once more."""
        pm = self.patches
        shape = self.proxy_shape(pv, pf, proxy_occ)
        out = np.zeros((len(idx), 3))
        near = dist <= self.centre_near * radius
        n_i, f_i = idx[near], idx[~near]
        if len(n_i):
            out[near] = _exact_sum(pm.centre[n_i], pm.normal[n_i], tris, rad, proxy_occ, self.device, ws, extra,
                                   shape.free, self.light_tables(shape, centre, radius, extra))
        if len(f_i):
            groups = self.far_groups(pv, pf, shape)
            em = groups.emitters(tris.mean(1), rad) if groups is not None else _far_emitters(
                tris, rad, shape.visibility.seen, None)
            if extra is not None and len(extra.far_c):
                em = tuple(np.concatenate([a, b]) for a, b in zip(em, (extra.far_c, extra.far_tn, extra.far_rad,
                                                                       extra.far_seen)))
            cap = len(tris) + (extra.capacity if extra is not None else 0)
            far = point_emitter_sum(pm.centre[f_i], pm.normal[f_i], *em, CUBE_RES, device=self.device, split=256,
                                    workspace=ws.sub("far"), capacity=cap)
            out[~near] = np.minimum(far, _light_bound(pm.centre[f_i], dist[~near], rad, radius, extra, centre))
        return out

    def light_tables(self, shape: ProxyShape, centre: np.ndarray, radius: float, extra: ExtraEmitters | None,
                     faces: np.ndarray | None = None) -> LightTables | None:
        """The near sums' LightTables of the proxy shape `shape` (of its `faces`, None: all; the whole shape's
        kept for its frames) at the bounding sphere (centre, radius), None without table_tolerance (rays) or with
        extra emitters (the sun's: sun_room's drag row with tables 24 levels off at a few pixels beside the chair,
        rmse_affected 1.208 -> 1.224; as far off with only the faces turned from the sun through the tables, which
        the sunlit floor lights as brightly: docs/benchmarks.md "The sun rooms' drag object light (sunobj37)")."""
        if self.table_tolerance is None or extra is not None:
            return None
        seen = shape.visibility.seen
        if faces is not None:
            tables = LightTables(seen[faces], self.table_tolerance, len(seen))
        else:
            kept = self._light_tables
            if kept is None or kept[0] is not shape or kept[1].tolerance != self.table_tolerance:
                kept = self._light_tables = (shape, LightTables(seen, self.table_tolerance, len(seen)))
            tables = kept[1]
        tables.sphere = (np.asarray(centre, np.float64), float(radius))
        return tables

    def proxy_shape(self, pv: np.ndarray, pf: np.ndarray, proxy_occ: Occluder) -> ProxyShape:
        """The proxy's ProxyShape, kept for the last shape (shape_key)."""
        key = shape_key(pv, pf)
        cached = self._proxy_shape
        if cached is None or cached[0] != key:
            cached = self._proxy_shape = (key, ProxyShape(pv[pf], proxy_occ))
        return cached[1]

    def vertex_interpolation(self) -> VertexInterpolation:
        """The engine's VertexInterpolation of the receiver vertices' light onto the receiver pixels (made
        on first use: it depends on the scene only)."""
        if self._interpolation is None:
            self._interpolation = VertexInterpolation(np.where(self.recv_pix, self.pix_patch, -1), self.pix_rows,
                                                      self.pix_bary, self.patches.n_patches, len(self.recv_vert),
                                                      self.device)
        return self._interpolation

    def pixel_table(self) -> PixelTable:
        """The engine's PixelTable (made on first use: it depends on the scene only)."""
        if self._pixel_table is None:
            self._pixel_table = PixelTable(self.recv_pix, self.pix_patch, self.patches.n_patches)
        return self._pixel_table

    def _near_pixels(self, sel: np.ndarray, tris: np.ndarray, tri_rad: np.ndarray, proxy_occ: Occluder,
                     extra: ExtraEmitters | None = None, free: np.ndarray | None = None,
                     tables: LightTables | None = None) -> np.ndarray:
        """The object's light (len(sel),3), irradiance/pi, at the listed pixels `sel` near the object.

        An adaptive screen grid: at each stride of GRID_STRIDES a pixel whose cell (its four nodes)
        lies on its own quad (one plane), at least GRID_CLEARANCE cell diagonals from the object's
        proxy (the light varies on the scale of that distance) and whose nodes differ by at most
        GRID_TOLERANCE levels (x (coarsest / stride)^2 at a finer stride: a blend's error falls with
        the cell's area) takes the bilinear blend of the nodes, evaluated exactly
        (kernels.visibility.emitter_sum); the rest go on to the next, finer stride, and what is left
        after the finest is evaluated per pixel (contact, quad edges, the object's silhouette).
        The cells' quad test is made once per scene (StrideTable), the clearance once per cell and frame,
        the blend's test against the response through `headroom` (no response evaluation per pixel).
        """
        pm = self.patches
        W = self.camera.width
        if self._screen is None:
            self._screen = _ScreenValues(len(self.pix_pos))
        sv = self._screen
        sv.clear()
        ws = self._workspaces.get("near_pixels.exact")

        def values_of(idx: np.ndarray) -> np.ndarray:
            return _exact_sum(self.pix_pos[idx], pm.normal[self.pix_patch[idx]], tris, tri_rad, proxy_occ, self.device,
                              ws, extra, free, tables)

        out = np.zeros((len(sel), 3))
        todo = np.arange(len(sel))
        for s in GRID_STRIDES:
            if len(todo) == 0:
                break
            st = self.stride_table(s)
            p = sel[todo]
            ok = st.pixel_ok[p]  # the pixel's cell lies on its own quad, on receivers
            if not ok.any():
                continue
            cid = st.cell[p]
            cells = _distinct(cid[ok], st.n_cells)  # the cells holding pixels to do
            nodes = st.nodes(cells)  # (C,4)
            # clearance: the cell's nodes' distance to the proxy, against its diagonal
            cn = np.unique(nodes)
            d = distance_to(proxy_occ, self.pix_pos[cn], workspace=self._workspaces.get("near_pixels.clearance"))
            d_node = d[np.searchsorted(cn, nodes)].min(1)
            diag = np.linalg.norm(self.pix_pos[nodes[:, 0]] - self.pix_pos[nodes[:, 3]], axis=1)
            clear = d_node > GRID_CLEARANCE * diag
            if not clear.any():
                continue
            cells, nodes = cells[clear], nodes[clear]
            slot = np.full(st.n_cells, -1, np.int64)
            slot[cells] = np.arange(len(cells))
            h = slot[cid]
            ok &= h >= 0
            sv.add(np.unique(nodes), values_of)
            cc = sv.value[nodes]  # (cells, 4, 3) the cells' node values
            k = np.flatnonzero(ok)
            fp, h = p[k], h[k]
            spread = self.rho_x[fp] * (cc.max(1) - cc.min(1))[h]
            below = spread <= self.headroom(GRID_TOLERANCE * (GRID_STRIDES[0] / s) ** 2, fp)
            smooth = below[:, 0] & below[:, 1] & below[:, 2]  # (.all(1) loops 3 values at a time: slower)
            k, fp, h = k[smooth], fp[smooth], h[smooth]
            out[todo[k]] = _bilinear(cc[h], fp, W, s)
            keep = np.ones(len(todo), bool)
            keep[k] = False
            todo = todo[keep]
        if len(todo):
            sv.add(sel[todo], values_of)
            out[todo] = sv.value[sel[todo]]
        self.n_exact = sv.count
        return out

    def stride_table(self, s: int) -> StrideTable:
        """The engine's StrideTable of stride s (made on first use: it depends on the scene only)."""
        if s not in self._strides:
            cam = self.camera
            pix_quad = np.where(self.pix_patch >= 0, self.patches.quad[np.maximum(self.pix_patch, 0)], -1)
            self._strides[s] = StrideTable(s, cam.height, cam.width, self.recv_pix, pix_quad)
        return self._strides[s]
