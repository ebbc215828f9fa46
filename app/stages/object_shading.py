"""Object shading stage: the object's shape (proxy, shading mesh, BVHs kept per shape), its pixels
(camera hits depth-tested against the scene) and its outgoing radiance (DESIGN "Per-frame stages").

Radiance at the shading mesh's vertices = albedo x (indirect SH9 volume x the object's own
self-occlusion transfer (precomputed radiance transfer, kept per shape in the object's frame)
+ the emitters with visibility + the change of the room's patches in the object's shadow), plus
two bounces between the object's own parts (vertex_light); interpolated at the camera hits. Units: radiance.

ObjectShading is built once per scene from the camera, the scene's occluders, the patch mesh and the
room's light; per frame `object_shape` gives the proxy and the shading mesh at the pose,
`object_hits` the object's pixels and `shade` its radiance there (a ShadedObject).
"""
from __future__ import annotations

import functools
import hashlib
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from app.runtime import split as _split
from app.config import ObjectConfig
from kernels.buffers import Workspaces
from kernels.raycast import cast_rays
from kernels.shade import CameraHits, SampledPatchSum, patch_groups, self_transfer
from kernels.vec import same_key
from kernels.visibility import Occluder
from lighting.irradiance import RoomLight
from lighting.sun import SunLight
from lighting.envmap import CubeMap, cube_directions, phong_prefilter, reflect
from recon.patches import PatchMesh
from recon.proxy import simplify, subdivide
from recon.response import luminance
from recon.scene import SceneObject
from app.stages.own_contacts import CONTACT_LIFT, lift_off_own_contacts
from app.stages.own_cuts import cut_along_own_contacts
from app.stages.spread import spread_subsets

SPLIT_PAIRS = 1024  # (point, patch) pairs a concurrent part of a gather over patches gets at least (the
# item count from which app.runtime.parts splits a launch of one-patch items): pair_split


def pair_split(device: str, n_patches: int):
    """app.runtime.split for a gather of every one of n_patches patches at each point (the emitters', the
    sun's lost patches', dB's), sized by work, not by points: a part gets at least SPLIT_PAIRS (point,
    patch) pairs, an exact form factor each, so a few hundred points of tens of patches already outweigh
    a thread's hand-off (app.runtime.parts' default counts items of one patch: ~900 such points ran on
    one core)."""
    return functools.partial(_split, device=device, min_items=max(1, SPLIT_PAIRS // max(n_patches, 1)))




@dataclass
class ObjectHits:
    """Sub-pixel camera hits on the object inside the rectangle (u0, v0, u1, v1), s x s per pixel."""

    H: int
    W: int
    s: int
    rect: tuple[int, int, int, int]
    tri: np.ndarray  # (n,) object triangle per sub-sample (-1 none)
    bary: np.ndarray  # (n,3)
    hit: np.ndarray  # (n,) bool: object seen (in front of the scene)

    def average(self, sub: np.ndarray) -> np.ndarray:
        """Mean of per-sub-sample values (n,3) over each pixel's hits -> (H,W,3)."""
        u0, v0, u1, v1 = self.rect
        out = np.zeros((self.H, self.W, 3))
        if u1 < u0:
            return out
        hh, ww, s = v1 - v0 + 1, u1 - u0 + 1, self.s
        hitm = self.hit.reshape(hh, s, ww, s)
        total = (sub * self.hit[:, None]).reshape(hh, s, ww, s, 3).sum(axis=(1, 3))
        out[v0:v1 + 1, u0:u1 + 1] = total / np.maximum(hitm.sum(axis=(1, 3)), 1)[..., None]
        return out

    def coverage(self) -> np.ndarray:
        """Fraction (H,W) of each pixel's sub-samples that see the object."""
        u0, v0, u1, v1 = self.rect
        cov = np.zeros((self.H, self.W))
        if u1 >= u0:
            hh, ww, s = v1 - v0 + 1, u1 - u0 + 1, self.s
            cov[v0:v1 + 1, u0:u1 + 1] = self.hit.reshape(hh, s, ww, s).mean(axis=(1, 3))
        return cov



def _interpolate_on_surface(v: np.ndarray, n: np.ndarray, sub: np.ndarray, values: np.ndarray, k: int = 6
                            ) -> np.ndarray:
    """Values (V,C) at every vertex from values (len(sub),C) at vertices `sub`: inverse-distance
    weights over the k nearest samples, times the cosine between normals squared (so a seat's top
    does not take the value of its underside)."""
    if len(sub) == len(v):
        return values
    k = min(k, len(sub))
    d, j = cKDTree(v[sub]).query(v, k=k)
    d, j = d.reshape(len(v), k), j.reshape(len(v), k)
    cos = np.einsum("vc,vkc->vk", n, n[sub][j])
    w = np.maximum(cos, 0.0) ** 2 / (d + 1e-3)
    w[w.sum(1) == 0, 0] = 1.0  # no sample faces the same way: take the nearest
    return np.einsum("vk,vkc->vc", w / w.sum(1, keepdims=True), values[j])


def _fill_from_neighbours(values: np.ndarray, faces: np.ndarray, missing: np.ndarray, rounds: int = 8
                          ) -> np.ndarray:
    """Values (V,C) with the `missing` vertices replaced by the mean of their known mesh
    neighbours, grown over `rounds` rings (what is still missing then gets the known mean)."""
    if not missing.any() or missing.all():
        return values
    out = values.copy()
    known = ~missing
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    e = np.concatenate([e, e[:, ::-1]])
    for _ in range(rounds):
        src = known[e[:, 0]] & ~known[e[:, 1]]
        if not src.any():
            break
        acc = np.zeros_like(out)
        cnt = np.zeros(len(out))
        np.add.at(acc, e[src, 1], out[e[src, 0]])
        np.add.at(cnt, e[src, 1], 1)
        new = cnt > 0
        out[new] = acc[new] / cnt[new, None]
        known = known | new
    out[~known] = out[known].mean(0)
    return out


SELF_BOUNCES = 2  # bounces between the object's own parts (vertex_light)


def vertex_light(L_room: np.ndarray, L_sun: np.ndarray | None, fill, bounce, albedo: np.ndarray) -> np.ndarray:
    """Radiance (V,3) at the shading mesh's vertices from the room's part L_room (V,3) and each vertex's own
    direct sun L_sun (V,3; None: no sun), both albedo x E, the one place the frame at rest and the drag frame
    (app.stages.object_drag) make it. Buried vertices (ShapeShading.buried) see almost nothing: their room part
    and the bounce come from their neighbours (fill(values) -> values: _fill_from_neighbours or the drag frame's
    FillOperator), never their direct sun: each vertex keeps its own, the share that a camera hit's own sun
    (shade's per-hit correction, the drag frame's SunAtHits) replaces, so a face's hits get the sun per hit and
    not a neighbour's sun blended over them. Two bounces between the object's own parts (bounce (V,V) sparse,
    None: none; SELF_BOUNCES) see the object's radiance with that sun: a chair's seat in the back's shadow is lit
    by the back, which the sunlit rest of the seat lights (one bounce left the crease at the back's own room light)."""
    room = fill(L_room)
    sun = 0.0 if L_sun is None else L_sun
    lit = room + sun
    if bounce is None:
        return lit
    for _ in range(SELF_BOUNCES):
        lit = fill(room + albedo * (bounce @ lit)) + sun
    return lit


def _facing(p: np.ndarray, n: np.ndarray, polys: np.ndarray, pn: np.ndarray) -> np.ndarray:
    """(N,) bool: the point p (N,3) with normal n lies in front of some polygon (G,4,3) (pn (G,3): its
    emitting side, pn . (p - v0) > 0) with a corner above p's horizon (n . (corner - p) > 0), as
    kernels.shade's _faces. Both as products of small matrices (no (N,G,4,3) differences); a point
    whose answer a value within rounding of 0 could change is decided by the differences themselves."""
    N, G = len(p), len(polys)
    reach = np.abs(p).max() + np.abs(polys).max()
    tf, ta = 1e-12 * reach * np.abs(pn).max(), 1e-12 * reach  # far above these products' rounding
    front = p @ pn.T - np.einsum("gc,gc->g", pn, polys[:, 0])[None]  # (N,G)
    above = (n @ polys.reshape(-1, 3).T).reshape(N, G, 4) - np.einsum("nc,nc->n", n, p)[:, None, None]
    facing = ((front > tf) & (above > ta).any(2)).any(1)
    unsure = np.flatnonzero(~facing & ((front > -tf) & (above > -ta).any(2)).any(1))
    if len(unsure):
        q, m = p[unsure], n[unsure]
        f_ = np.einsum("gc,ngc->ng", pn, q[:, None] - polys[:, 0][None]) > 0
        a_ = (np.einsum("nc,ngkc->ngk", m, polys[None] - q[:, None, None]) > 0).any(2)
        facing[unsure] = (f_ & a_).any(1)
    return facing


class _TriangleBoxes:
    """Each triangle's box, the triangles sorted into buckets (a 4 x 4 x 4 grid over their centres) with
    each bucket's box: `overlapping` tests the buckets first, then only the triangles of those a box meets."""

    def __init__(self, tris: np.ndarray, k: int = 4):
        lo, hi = tris.min(1), tris.max(1)
        c = 0.5 * (lo + hi)
        c0, span = (c.min(0), np.ptp(c, 0)) if len(c) else (np.zeros(3), np.zeros(3))
        cell = np.clip(((c - c0) / np.maximum(span, 1e-12) * k).astype(np.int64), 0, k - 1)
        key = (cell[:, 0] * k + cell[:, 1]) * k + cell[:, 2]
        self.order = np.argsort(key, kind="stable")
        key = key[self.order]
        self.lo, self.hi = lo[self.order], hi[self.order]
        self.start = np.flatnonzero(np.r_[True, key[1:] != key[:-1]]) if len(key) else np.zeros(0, np.int64)
        self.end = np.r_[self.start[1:], len(key)].astype(np.int64)
        self.blo = np.minimum.reduceat(self.lo, self.start) if len(key) else np.zeros((0, 3))
        self.bhi = np.maximum.reduceat(self.hi, self.start) if len(key) else np.zeros((0, 3))

    def overlapping(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """Indices of the triangles whose box meets the box lo..hi (3,), in the triangles' own order."""
        buckets = np.flatnonzero(((self.bhi >= lo) & (self.blo <= hi)).all(1))
        if len(buckets) == 0:
            return np.zeros(0, np.int64)
        rows = np.concatenate([np.arange(self.start[b], self.end[b]) for b in buckets])
        rows = rows[((self.hi[rows] >= lo) & (self.lo[rows] <= hi)).all(1)]
        return np.sort(self.order[rows])


def shaft_clear(tris: np.ndarray, p: np.ndarray, n: np.ndarray, polys: np.ndarray, poly_normals: np.ndarray,
                eps: float, tol: float = 1e-7, boxes: _TriangleBoxes | None = None) -> bool:
    """True when no triangle of `tris` (T,3,3) can cut a visibility segment of kernels.shade's patch sums:
    from a point p (N,3) lifted by eps along its normal n (N,3), where it faces some polygon, to a point of
    a polygon (G,4,3) lifted by eps along its normal (G,3). Every such segment lies in the convex hull of
    the lifted starts' box and the lifted polygons; a triangle with all its corners on or outside one
    face plane of that hull (within `tol` m) can meet a segment at most at an end point, which the open
    segment excludes (the floor under an object standing on it). Exact, from geometry; conservative.
    boxes: `tris` in buckets (_TriangleBoxes, e.g. room_triangle_boxes: kept per engine), None: made here."""
    from scipy.spatial import ConvexHull, QhullError

    if len(tris) == 0:
        return True
    pn = np.cross(polys[:, 1] - polys[:, 0], polys[:, 2] - polys[:, 0])  # emitting side
    facing = _facing(p, n, polys, pn)
    if not facing.any():
        return True
    a = p[facing] + n[facing] * eps
    lo, hi = a.min(0), a.max(0)
    box = np.array([[(hi if (k >> c) & 1 else lo)[c] for c in range(3)] for k in range(8)])
    pts = np.concatenate([box, (polys + poly_normals[:, None] * eps).reshape(-1, 3)])
    try:
        eq = ConvexHull(pts, qhull_options="QJ" if np.ptp(pts, 0).min() < 1e-9 else "").equations
    except QhullError:
        return False
    plo, phi = pts.min(0) - tol, pts.max(0) + tol
    boxes = _TriangleBoxes(tris) if boxes is None else boxes
    cand = tris[boxes.overlapping(plo, phi)]  # overlapping the hull's box
    if len(cand) == 0:
        return True
    dist = cand @ eq[:, :3].T + eq[:, 3]  # (T,3,F) signed, outside > 0
    return bool((dist >= -tol).all(1).any(1).all())


DB_FAR = 2.0  # bounding radii (nearest point of the patch to the object's box centre) beyond which a
# shadowed patch's loss is gathered as a far field (far_field_sh; trilinear over DB_PROBES per axis: the
# relative parallax error of its 1/r^2 falls as (radius / (DB_FAR (DB_PROBES - 1)))^2, ~3 % here)
DB_PROBES = 4  # probes per axis of the far field's grid over the object's box


def lift_off_contacts(p: np.ndarray, n: np.ndarray, centre: np.ndarray, normal: np.ndarray, radius: np.ndarray,
                      eps: float) -> np.ndarray:
    """Points (N,3) moved within their own tangent plane (normals n (N,3)) to a height h above each
    room patch (centre, unit normal (M,3), bounding radius (M,) m) they touch, i.e. lie within h of
    its plane over its extent; h = CONTACT_LIFT x the patch's radius, at least 2 x the rays' eps.
    A point on the foot of a chair's leg lies in the floor's plane, where the floor's form factor is
    0, while at any height above it the floor fills the lower half of the hemisphere (a half-plane's
    form factor does not depend on the height): the vertex stands for the surface above it, so it
    takes the limit from above. At a tenth of the patch's radius the contacting patch still holds
    about 90 % of that light. Points whose face lies in the patch's plane (|n . normal| within 1e-3
    of 1: a foot's sole, a face against a wall) are left: no point of such a face sees the surface."""
    out = np.array(p, np.float64, copy=True)
    if len(p) == 0 or len(centre) == 0:
        return out
    radius = np.asarray(radius, np.float64)
    h = np.maximum(CONTACT_LIFT * radius, 2.0 * eps)
    reach = radius + 2.0 * h  # a touching point lies within this of the patch's centre
    for _ in range(2):  # a point in a corner touches two surfaces
        # only the patches within reach of the points' box can touch one (a frame's list holds every patch the
        # sun's change touches, mostly far from the object): only those are tested against the points, in their order
        cand = _within_box(centre, reach, out.min(0), out.max(0))
        if not len(cand):
            break
        pi, pj = _pairs_within(out, centre[cand], reach[cand], normal[cand], h[cand])  # the points that may touch
        if not len(pi):
            break
        pj = cand[pj]
        rel = out[pi] - centre[pj]
        d = np.einsum("kc,kc->k", rel, normal[pj])
        inplane = np.linalg.norm(rel - d[:, None] * normal[pj], axis=1) < radius[pj] + h[pj]
        cos = np.einsum("kc,kc->k", n[pi], normal[pj])
        touch = (np.abs(d) < h[pj] - 1e-9) & inplane & (np.abs(cos) < 1.0 - 1e-3)
        if not touch.any():
            break
        pi, pj, d, cos = pi[touch], pj[touch], d[touch], cos[touch]
        first = np.lexsort((d, pi))  # per point, its deepest contact first
        keep = first[np.r_[True, pi[first][1:] != pi[first][:-1]]]
        pi, pj, d, cos = pi[keep], pj[keep], d[keep], cos[keep]
        t = normal[pj] - cos[:, None] * n[pi]  # the face's direction rising off the surface
        out[pi] += ((h[pj] - d) / np.einsum("kc,kc->k", t, t))[:, None] * t
    return out


LIFT_BRUTE_PAIRS = 1 << 18  # (patch, point) pairs up to which _pairs_within tests every pair, not a tree


def _pairs_within(points: np.ndarray, centre: np.ndarray, reach: np.ndarray, normal: np.ndarray, h: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """(point rows, centre rows) of the pairs with the point within h (M,) of the patch's plane (centre (M,3),
    unit normal (M,3)) and within reach (M,) of its centre: a superset of lift_off_contacts's touching pairs
    (margins of 1e-9 m on the plane's distance, 1e-6 relative on reach, over the rounding of other formulas),
    patch-major and ascending points within a patch. Every pair tested where they are few (a drag frame: the
    patches near the object's box; the plane's distance of all pairs as one product), a cKDTree otherwise."""
    if len(centre) * len(points) <= LIFT_BRUTE_PAIRS:
        off = normal @ points.T - np.einsum("mc,mc->m", normal, centre)[:, None]  # (M,N) signed plane distance
        rows, cols = np.nonzero(np.abs(off) < (h + 1e-9)[:, None])
        gap = points[cols] - centre[rows]
        keep = np.einsum("kc,kc->k", gap, gap) <= (reach[rows] * (1.0 + 1e-6)) ** 2
        return cols[keep], rows[keep]
    near = cKDTree(points).query_ball_point(centre, reach * (1.0 + 1e-6))
    cnt = np.fromiter((len(a) for a in near), np.int64, len(near))
    if not cnt.sum():
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    return (np.concatenate([np.sort(np.asarray(a, np.int64)) for a in near if len(a)]),
            np.repeat(np.arange(len(centre)), cnt))


def _within_box(centre: np.ndarray, reach: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(K,) the rows of centre (M,3) within reach (M,) of the box [lo, hi] (3,), ascending: a superset of the
    patches a point in the box can lie within reach of (the distance to the box is at most any of its points';
    rounding is monotonic, and the 1e-6 relative margin covers the tree's own distance test)."""
    gap = centre - np.clip(centre, lo, hi)
    return np.flatnonzero(np.einsum("mc,mc->m", gap, gap) <= (reach * (1.0 + 1e-6)) ** 2)


def _probe_grid(lo: np.ndarray, hi: np.ndarray, points: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """(probes (n^3,3), weights (N,n^3)): an n x n x n grid spanning the box lo..hi and the trilinear
    weights of the points (N,3) inside it (a flat axis puts all its weight on its first level)."""
    axes = [np.linspace(lo[a], hi[a], n) for a in range(3)]
    probes = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    span = np.maximum(hi - lo, 1e-12)
    t = np.clip((points - lo) / span * (n - 1), 0.0, n - 1)
    i0 = np.minimum(np.floor(t).astype(int), n - 2) if n > 1 else np.zeros_like(t, int)
    fr = t - i0
    weights = np.zeros((len(points), n ** 3))
    rows = np.arange(len(points))
    for corner in range(8):
        bits = [(corner >> a) & 1 for a in range(3)]
        w = np.prod([fr[:, a] if b else 1.0 - fr[:, a] for a, b in enumerate(bits)], axis=0)
        idx = ((i0[:, 0] + bits[0]) * n + i0[:, 1] + bits[1]) * n + i0[:, 2] + bits[2]
        np.add.at(weights, (rows, np.minimum(idx, n ** 3 - 1)), w)
    return probes, weights


SUN_NEAR = 1.0  # patch diameters: a sunlit patch whose centre lies within this many of its own diameters (plus its
# radius) of the object's box is gathered as its sun sample points' cells (ObjectShading._sun_loss_cells), each with
# its own sun and lost share; beyond, the form factor varies over the patch by O((diameter / distance)^2) and the
# patch's mean serves (0.5 gives the same figures: docs/unseen.md, objsun110)


def sun_cells(corners: np.ndarray, values: np.ndarray, lost: np.ndarray, keys: np.ndarray | None = None
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The patches (corners (M,4,3), a parallelogram c0 + u U + v V with U = c1 - c0, V = c3 - c0; values (M,3),
    the sun each loses, mean over its sample points) split into the n x n cells of the sun's sample points (lost
    (M,n*n): each point's lost share, in app.stages.sun's order: point k at u = (k % n + 0.5) / n,
    v = (k // n + 0.5) / n), each cell the patch's value x its own point's share over the patch's mean (the patch's
    mean is kept: the cells' area-weighted mean is `values`). Neighbouring cells with equal keys (M,n*n,C)
    (default: lost) are merged into rectangles (runs along u, then equal runs along v; the form factor is additive,
    so the sum is the cells' to rounding, a ray fewer per merged cell). Returns (polygons (R,4,3), their values
    (R,3), the sample point each one's value is taken from (R,): index into the M*n*n points)."""
    M, K = lost.shape
    n = int(round(np.sqrt(K)))
    if n * n != K:
        raise ValueError(f"sun_cells: {K} sample points per patch is not a square grid")
    keys = lost[..., None] if keys is None else keys
    rects = []  # (patch, u0, u1, v0, v1, point)
    for m in range(M):
        g = keys[m].reshape(n, n, -1)  # [v, u]
        open_: dict = {}  # (u0, u1, key bytes) -> [v0, v1, point] of the rectangle still growing along v
        for v in range(n):
            runs, u0 = [], 0
            for u in range(1, n + 1):
                if u == n or not np.array_equal(g[v, u], g[v, u0]):
                    runs.append((u0, u, g[v, u0].tobytes()))
                    u0 = u
            nxt = {}
            for r in runs:
                if r in open_ and open_[r][1] == v:
                    open_[r][1] = v + 1
                    nxt[r] = open_.pop(r)
                else:
                    nxt[r] = [v, v + 1, m * K + v * n + r[0]]
            for r, (v0, v1, k) in open_.items():
                rects.append((m, r[0], r[1], v0, v1, k))
            open_ = nxt
        for r, (v0, v1, k) in open_.items():
            rects.append((m, r[0], r[1], v0, v1, k))
    R = np.array(rects, np.int64).reshape(-1, 6)
    c0 = corners[R[:, 0], 0]
    U, V = corners[R[:, 0], 1] - c0, corners[R[:, 0], 3] - c0
    uu = np.stack([R[:, 1], R[:, 2], R[:, 2], R[:, 1]], 1) / n  # the rectangle's corners, in the patch's winding
    vv = np.stack([R[:, 3], R[:, 3], R[:, 4], R[:, 4]], 1) / n
    polys = c0[:, None] + uu[..., None] * U[:, None] + vv[..., None] * V[:, None]
    mean = lost.mean(1)
    share = np.where(mean[:, None] > 0, lost / np.where(mean > 0, mean, 1.0)[:, None], 1.0).reshape(-1)
    return polys, values[R[:, 0]] * share[R[:, 5], None], R[:, 5]


DB_CLUSTER = 0.25  # a far patch cluster's side over its distance (angular size ~14 deg: seen as one point,
# the SH9 irradiance of its area-weighted centroid errs by O(size^2 / distance^2), ~1.5 %)


def cluster_patches(pc: np.ndarray, pn: np.ndarray, area: np.ndarray, quad: np.ndarray, radiance: np.ndarray,
                    dist: np.ndarray, base: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Far patches (centres (M,3), normals (M,3), areas (M,), surface `quad` (M,), radiance (M,3), distance
    (M,) m from the object) merged per surface into cells of side base * 2^k <= DB_CLUSTER * distance:
    (centroids, normals, areas, area-weighted mean radiance) of the cells, for far_field_sh."""
    level = np.floor(np.log2(np.maximum(DB_CLUSTER * dist / base, 1.0))).astype(np.int64)
    cell = np.floor(pc / (base * 2.0 ** level)[:, None]).astype(np.int64)
    _, inv = np.unique(np.c_[quad, level, cell], axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    k = inv.max() + 1
    a = np.bincount(inv, area, k)
    centroid = np.stack([np.bincount(inv, area * pc[:, c], k) for c in range(3)], 1) / a[:, None]
    rad = np.stack([np.bincount(inv, area * radiance[:, c], k) for c in range(3)], 1) / a[:, None]
    normal = np.zeros((k, 3))
    normal[inv] = pn  # one surface per cell: one normal
    return centroid, normal, a, rad


def _object_above(p: np.ndarray, n: np.ndarray, mesh_points: np.ndarray, tol: float = 1e-6,
                  block: int = 512) -> np.ndarray:
    """(N,) bool: some of the mesh's points lie more than `tol` metres above the plane through
    p (N,3) with normal n (N,3), i.e. the mesh can block a ray leaving p upwards."""
    out = np.zeros(len(p), bool)
    for s in range(0, len(p), block):
        e = min(len(p), s + block)
        h = n[s:e] @ mesh_points.T - np.einsum("vc,vc->v", n[s:e], p[s:e])[:, None]
        out[s:e] = h.max(axis=1) > tol
    return out


def _visibility_samples(p: np.ndarray, faces: np.ndarray, samples: np.ndarray, hidden: np.ndarray,
                        rings: int = 3, k: int = 6, tol: float = 0.2) -> tuple[np.ndarray, np.ndarray]:
    """(samples, nbr): the sample indices (S,) and, for each of the N points, its k nearest samples
    (N,k; -1: none) among those at most `rings` edges away on the mesh (faces (F,3) over the
    points) whose share of the hemisphere the object hides (`hidden` (N,), from the self-occlusion
    transfer) is within `tol` of the point's, SampledPatchSum's inputs: a neighbour on the same
    surface and in the same place with respect to the object's other parts, never one across a gap,
    on another face of a sharp corner or under a part that stands on this one."""
    import scipy.sparse as sp

    N = len(p)
    samples = np.asarray(samples, np.int32)
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    A = sp.csr_matrix((np.ones(2 * len(e)), (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])), shape=(N, N))
    A = (A + sp.identity(N, format="csr")).astype(bool).astype(np.float32)
    R = A
    for _ in range(rings - 1):
        R = (R @ A).astype(bool).astype(np.float32)
    R = R[:, samples].tocoo()  # (N,S): sample within `rings` edges
    nbr = np.full((N, k), -1, np.int32)
    if R.nnz:
        d = np.linalg.norm(p[R.row] - p[samples[R.col]], axis=1)
        d[np.abs(hidden[R.row] - hidden[samples[R.col]]) > tol] = np.inf
        order = np.lexsort((d, R.row))
        rows, cols = R.row[order], R.col[order]
        rank = np.arange(len(rows)) - np.searchsorted(rows, rows)
        keep = (rank < k) & np.isfinite(d[order])
        nbr[rows[keep], rank[keep]] = cols[keep]
    return samples, nbr


def _near_samples(p: np.ndarray, n: np.ndarray, samples: np.ndarray, hidden: np.ndarray, k: int = 10,
                  tol: float = 0.2) -> tuple[np.ndarray, np.ndarray]:
    """_visibility_samples for points with no mesh between them: each point's k nearest samples
    (N,k; -1: none) that face the same way (normal cosine > 0) and whose hidden share is within
    `tol` of the point's."""
    samples = np.asarray(samples, np.int32)
    if len(samples) == 0:
        return samples, np.full((len(p), 1), -1, np.int32)
    k = min(k, len(samples))
    _, j = cKDTree(p[samples]).query(p, k=k)
    j = j.reshape(len(p), k)
    s = samples[j]
    ok = (np.einsum("vc,vkc->vk", n, n[s]) > 0) & (np.abs(hidden[:, None] - hidden[s]) <= tol)
    return samples, np.where(ok, j, -1).astype(np.int32)


def _knn_weights(lu: np.ndarray, nu: np.ndarray, sub: np.ndarray, k: int = 6) -> tuple[np.ndarray, np.ndarray]:
    """_interpolate_on_surface's neighbours (U,k) into `sub` and their weights (U,k) summing to 1."""
    k = min(k, len(sub))
    d, j = cKDTree(lu[sub]).query(lu, k=k)
    d, j = d.reshape(len(lu), k), j.reshape(len(lu), k)
    cos = np.einsum("vc,vkc->vk", nu, nu[sub][j])
    w = np.maximum(cos, 0.0) ** 2 / (d + 1e-3)
    w[w.sum(1) == 0, 0] = 1.0
    return j, w / w.sum(1, keepdims=True)


def gathered_rows(buried: np.ndarray, inv: np.ndarray, samples: np.ndarray) -> np.ndarray | slice:
    """The distinct vertices whose radiance is read (sorted indices into the distinct vertices; slice(None):
    all of them): those with a copy that is not buried (buried (V,) per vertex, inv (V,) each vertex's
    distinct one), and the visibility `samples` (S,). A distinct vertex whose every copy is buried gets its
    neighbours' values (_fill_from_neighbours) unless every vertex is buried: then all are kept."""
    all_buried = np.ones(int(inv.max()) + 1 if len(inv) else 0, bool)
    np.logical_and.at(all_buried, inv, buried)
    if all_buried.all() or not all_buried.any():
        return slice(None)
    keep = ~all_buried
    keep[samples] = True
    return np.flatnonzero(keep)


def shading_mesh(v: np.ndarray, n: np.ndarray, f: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """The shading mesh (vertices (V,3) m, unit normals (V,3), faces (F,3)) of an object mesh: subdivided to edges of
    0.08 m at most (3000 faces), then cut along the contact lines between its own parts (own_cuts), so the vertices
    on either side of a contact are shaded separately; and each face's face before the cut (F,) (None: nothing
    cut), ObjectShading.face_groups."""
    sv, sn, sf = subdivide(v, n, f, max_edge=0.08, max_faces=3000)
    return cut_along_own_contacts(sv, sn, sf)


class ShapeShading:
    """What the shading needs of one object shape, made once in its own frame (centred: a
    translation changes none of it): the distinct (position, normal) vertices, where each is shaded (lift: off a
    contact line between two of the object's parts, own_contacts.lift_off_own_contacts), their self-occlusion
    transfer (kernels.shade.self_transfer), which of them are buried, the self-bounce operator, and
    the sample vertices of the dB gather with their interpolation weights (skip_buried False: the
    emitters' and the sun's gathers run at every distinct vertex, the buried ones too; the answer is the same)."""

    def __init__(self, local: np.ndarray, n: np.ndarray, f: np.ndarray, prt_dirs: int, dB_samples: int, device,
                 vis_stride: int = 4, n_emitters: int = 512, skip_buried: bool = True):
        import scipy.sparse as sp

        key = np.round(np.concatenate([local, n], 1), 6)
        _, self.uniq, self.inv = np.unique(key, axis=0, return_index=True, return_inverse=True)
        self.inv = self.inv.reshape(-1)
        own = Occluder(local, f, device)
        # a vertex on a contact line between two parts (a chair's back on its seat) is shaded just off the
        # contact (own_contacts.lift_off_own_contacts); lift (U,3) m: its offset from the distinct vertex
        self.lift = lift_off_own_contacts(local, n, f)[self.uniq]
        at = local + self.lift[self.inv]
        T, hit_face, hit_bary = self_transfer(at, n, own, prt_dirs, device=device)
        self.transfer = (T, hit_face, hit_bary)  # at every vertex
        self.T = T[self.uniq].astype(np.float64)
        hit = hit_face >= 0
        self.buried = hit.mean(axis=1) > 0.7
        self.bounce = None
        if hit.any():
            rows, k = np.nonzero(hit)
            cols = f[hit_face[rows, k]]  # (m,3)
            self.bounce = sp.csr_matrix((hit_bary[rows, k].reshape(-1).astype(np.float64) / hit.shape[1],
                                         (np.repeat(rows, 3), cols.reshape(-1))), shape=(len(local), len(local)))
        lu, nu = local[self.uniq] + self.lift, n[self.uniq]
        self.normals = nu
        self.key = ""  # shape_shading's key
        self._sun_self: tuple | None = None  # (sun direction, sun_self_lit of the distinct vertices)
        # the spread subsets (app.stages.spread: chosen by position and normal, whatever the mesh's order):
        # the patch sums' visibility samples, the dB gather's vertices and that gather's own samples
        vis_samples, self.sub, sub_samples = self.subsets(lu, nu, vis_stride, dB_samples)
        self._knn = _knn_weights(lu, nu, self.sub)
        # emitter and dB light with the visibility cast at a spread subset (kernels.shade.SampledPatchSum);
        # a vertex whose tangent plane has the whole object behind it (a convex part) tests against the
        # object only the rays that go below that plane
        own_u = _object_above(lu, nu, local)
        hidden_u = hit.mean(axis=1)[self.uniq]
        fu = self.inv[f]  # faces over the distinct vertices
        samples, nbr = _visibility_samples(lu, fu, vis_samples, hidden_u)
        self.samples, self.sub_samples = samples, sub_samples  # (S,) into the distinct vertices; (s,) into sub
        # the per-vertex gathers (emitters, the sun's lost patches) skip the distinct vertices whose every
        # copy is buried: vertex_radiance replaces those vertices' values by their neighbours'
        # (_fill_from_neighbours) before anything reads them; the samples stay (their neighbours vote)
        self.gathered = gathered_rows(self.buried, self.inv, samples) if skip_buried else slice(None)
        g = self.gathered
        rows = np.arange(len(lu)) if isinstance(g, slice) else g
        at = np.full(len(lu), -1, np.int32)
        at[rows] = np.arange(len(rows), dtype=np.int32)
        g_samples = (at[samples], nbr[rows])
        self.direct_sum = SampledPatchSum(own_u[rows], *g_samples, device, max_patches=max(n_emitters, 1))
        self.sun_dB_sum = SampledPatchSum(own_u[rows], *g_samples, device)  # the sun the object blocks from the room
        sub = self.sub  # spread thinly over the mesh: neighbours by distance, not by mesh edges
        self.dB_sum = SampledPatchSum(own_u[sub], *_near_samples(lu[sub], nu[sub], sub_samples, hidden_u[sub]), device)

    def subsets(self, lu: np.ndarray, nu: np.ndarray, vis_stride: int, dB_samples: int
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(visibility samples, dB vertices `sub`, sub's own samples): spread.spread_subsets of the
        distinct vertices at their shaded points lu (U,3) with normals nu (U,3)."""
        return spread_subsets(lu, nu, vis_stride, dB_samples)

    def sun_self_lit(self, d: np.ndarray, vu: np.ndarray, nu: np.ndarray, own: Occluder, eps: float = 1e-3
                     ) -> np.ndarray:
        """(U,) float: 1 where the distinct vertex (vu, nu: this pose's positions, normals) sees the sun
        (direction d) past the object's own mesh `own` (at the same pose), else 0 (and 0 where it faces
        away). Cast once per shape and sun direction: a translation changes none of it."""
        key = tuple(np.round(d, 9))
        if self._sun_self is None or self._sun_self[0] != key:
            lit = np.zeros(len(vu))
            up = np.flatnonzero(nu @ d > 0)
            if len(up):
                start = vu[up] + nu[up] * eps
                _, _, depth = cast_rays(own, start, np.broadcast_to(d, start.shape))
                lit[up] = ~np.isfinite(depth)
            self._sun_self = (key, lit)
        return self._sun_self[1]

    def interpolate(self, values: np.ndarray) -> np.ndarray:
        """Values (U,C) at the distinct vertices from values (len(sub),C) at `sub` (as
        _interpolate_on_surface: inverse distance x normal cosine squared, 6 nearest)."""
        j, w = self._knn
        return np.einsum("vk,vkc->vc", w, values[j])


@dataclass
class ShadedObject:
    """ObjectShading.shade's result."""

    radiance: np.ndarray  # (H,W,3) the object's radiance averaged over each pixel's camera hits
    L_vert: np.ndarray | None  # (V,3) radiance at the shading mesh's vertices (None: the object is unseen)
    sun_vis: np.ndarray | None  # (V,) each vertex's sun share, cos x visibility (None: no sun)


class ObjectShading:
    """The object's shape, its pixels and its outgoing radiance, for one scene: built once from the
    camera and the scene's occluders, the patch mesh, the room's light (SH9 volume and emitters),
    the radiance receivers gather and the sun (None: none lights the room); owns the per-shape
    caches (proxy, shading mesh and BVHs; ShapeShading) and its kernels' buffers. Radiance units."""

    def __init__(self, config: ObjectConfig, camera, cam_occ: Occluder, scene_occ: Occluder, patches: PatchMesh,
                 room_light: RoomLight, B_src: np.ndarray, device: str, sun: SunLight | None = None,
                 local_light: tuple | None = None):
        """cam_occ: the scene as the camera sees it (depth test); scene_occ: the room's occluder (shadows
        of the changed patches); B_src (P,3): the room's radiance (the specular map); local_light: photo
        light's (lighting.photolocal.LocalLight, emitter patches (P,) bool it scales), None: no scale."""
        self.config = config  # reassignable: its keys are part of the per-shape caches' keys
        self.camera, self.cam_occ, self.scene_occ, self.device = camera, cam_occ, scene_occ, device
        self.patches, self.room_light, self.B_src, self.sun = patches, room_light, B_src, sun
        self.n_shape_builds = 0  # object shapes simplified/subdivided so far
        self._workspaces = Workspaces()
        self._shape: dict | None = None  # the last shape's proxy, shading mesh and BVHs (object_shape)
        self.face_groups: np.ndarray | None = None  # the shading mesh's faces before own_cuts' cut (object_shape)
        self._shade_occ: tuple | None = None  # (shading-mesh vertices, their Occluder) of the current frame
        self._prt: tuple | None = None  # (key, ShapeShading) of the last shape (shape_shading)
        self._camera_hits: CameraHits | None = None
        self._emitter_groups: tuple | None = None
        self._room_tris: list | None = None  # [occluder, its triangles, their _TriangleBoxes]
        self._no_room: Occluder | None = None  # an empty occluder: no room triangle in the way
        self.local_light = local_light
        self.emitter_scale = 1.0  # the last frame's photo-light emitter scale at the object (lighting.photolocal)

    def object_shape(self, obj: SceneObject):
        """(proxy vertices, proxy faces, proxy Occluder, shading mesh (v, n, f), shading-mesh Occluder)
        of the object at its pose. The simplification, the subdivision and both BVHs are made once
        per object shape, kept in the shape's own frame (centred: the key is the centred mesh to
        1 um, as shape_shading's); a pose that only moves the object translates them and refits
        the BVHs (Warp Mesh.refit) instead (shape_cache False: made afresh every frame)."""
        p, v = self.config, obj.vertices
        offset = v.mean(0)
        # the key's arrays compared with the kept shape's, not hashed every frame (docs/benchmarks.md, "glue111")
        key = (np.round(v - offset, 6), np.round(obj.normals, 6), np.array(obj.faces, copy=True), p.proxy_faces)
        sh = self._shape if self.config.shape_cache else None
        if sh is None or not same_key(sh["key"], key):
            pv, pf, _ = simplify(v, obj.faces, p.proxy_faces)
            sv, sn, sf, groups = shading_mesh(v, obj.normals, obj.faces)
            sh = {"key": key, "offset": offset, "pv": pv - offset, "pf": pf, "sv": sv - offset, "sn": sn, "sf": sf,
                  "groups": groups,
                  "proxy_occ": Occluder(pv, pf, self.device), "shade_occ": Occluder(sv, sf, self.device)}
            if self.config.shape_cache:
                self._shape = sh
            self.n_shape_builds += 1
        pv, sv = sh["pv"] + offset, sh["sv"] + offset
        if not np.array_equal(offset, sh["offset"]):  # moved: translate the BVHs' points and refit
            sh["proxy_occ"].move(pv)
            sh["shade_occ"].move(sv)
            sh["offset"] = offset
        self._shade_occ = (sv, sh["shade_occ"])  # vertex_radiance's own-shadow mesh, this frame
        self.face_groups = sh["groups"]  # the shading mesh's faces before the cut (None: nothing cut), this frame
        return pv, sh["pf"], sh["proxy_occ"], (sv, sh["sn"], sh["sf"]), sh["shade_occ"]

    def object_hits(self, verts: np.ndarray, faces: np.ndarray, camera=None, supersample: int | None = None,
                     occluder: Occluder | None = None, caster: CameraHits | None = None) -> "ObjectHits":
        """Sub-pixel camera rays against the object mesh, depth-tested against the scene model
        (camera: default the scene's; another one sees the same world, e.g. the full-resolution
        photo's, app.workres; caster: the rays' CameraHits, default the stage's own; a drag frame's keeps the
        scene's depth, kernels.scene_depth.SceneDepth)."""
        cam = camera or self.camera
        H, W, s = cam.height, cam.width, max(1, supersample or self.config.supersample)
        uv, z = cam.project(verts)
        if np.any(z <= 1e-6):
            u0, v0, u1, v1 = 0, 0, W - 1, H - 1
        else:
            u0, v0 = np.floor(uv.min(0) - 1).astype(int)
            u1, v1 = np.ceil(uv.max(0) + 1).astype(int)
            u0, v0, u1, v1 = max(u0, 0), max(v0, 0), min(u1, W - 1), min(v1, H - 1)
        if u0 > u1 or v0 > v1:
            return ObjectHits(H, W, s, (0, 0, -1, -1), np.zeros(0, np.int32), np.zeros((0, 3)), np.zeros(0, bool))
        ch = caster or self._camera_hits
        if ch is None:
            ch = self._camera_hits = CameraHits(self.device)
        tri, bary, hit = ch(occluder or Occluder(verts, faces, self.device), self.cam_occ, cam.centre,
                            cam.R.T @ np.linalg.inv(cam.K), (u0, v0, u1, v1), s,
                            functools.partial(_split, device=self.device))
        return ObjectHits(H, W, s, (u0, v0, u1, v1), tri, bary, hit)

    def vertex_radiance(self, obj: SceneObject, mesh, proxy_occ: Occluder, dB: np.ndarray | None = None,
                        sun_dB: np.ndarray | None = None, sun_lost: tuple | None = None) -> np.ndarray:
        """Outgoing radiance (V,3) at the shading mesh's vertices (mesh = (verts, normals, faces)).

        albedo x (indirect SH9 x self-occlusion transfer + exact emitters + dB, the change of the
        room's patches in the object's shadow (P,3)), plus two bounces between the object's own parts (vertex_light);
        with a sun, its direct light with the object's self-shadowing and sun_dB (P,3), the sun the
        object blocks from each patch this frame. Everything is evaluated once per distinct (position,
        normal) of the mesh (ShapeShading.uniq), a vertex on a contact between two parts just off it
        (ShapeShading.lift); the buried vertices' fill and each vertex's own sun as vertex_light. sun_lost:
        SunStage's (c_patch, lost, c_vis, E_perp) of this frame: the sunlit patches near the object are gathered
        per sun sample point's cell (_sun_loss_cells); None: every patch whole."""
        return self._vertex_radiance(obj, mesh, proxy_occ, dB, sun_dB, sun_lost)[0]

    def _vertex_radiance(self, obj: SceneObject, mesh, proxy_occ: Occluder, dB: np.ndarray | None,
                         sun_dB: np.ndarray | None, sun_lost: tuple | None = None
                         ) -> tuple[np.ndarray, np.ndarray | None]:
        """(vertex_radiance, each vertex's sun share (V,) cos x visibility, None without a sun)."""
        v, n, f = mesh
        pm = self.patches
        # the shading mesh shadows itself: the coarse proxy would cut through its surface and
        # shadow vertices that lie outside it
        cached = self._shade_occ
        own = cached[1] if cached is not None and cached[0] is v else Occluder(v, f, self.device)
        ss = self.shape_shading(v, n, f)
        vu, nu = v[ss.uniq] + ss.lift, n[ss.uniq]  # a vertex on a contact between parts: just off it
        E_ind = np.einsum("vk,vkc->vc", ss.T, self.room_light.indirect_sh(vu))
        rl = self.room_light  # the emitters, exact form factors, visibility cast at samples (ShapeShading)
        em, groups = self.emitter_groups()
        room = rl.occluder
        if self.config.shaft_cull and len(em) and \
                shaft_clear(self.room_triangles(room), vu, nu, groups[1], pm.normal[em[groups[0][:-1]]], 2e-3,
                            boxes=self.room_triangle_boxes(room)):
            room = Occluder(None, None, self.device) if self._no_room is None else self._no_room
            self._no_room = room  # no room triangle between the object and the emitters: no room rays
        g = ss.gathered  # the distinct vertices whose radiance is read (the buried ones get their neighbours')
        vg, ng = vu[g], nu[g]
        ch = np.flatnonzero(np.abs(sun_dB).sum(1) > 0) if self.sun is not None and sun_dB is not None else []
        touch = np.union1d(em, ch).astype(np.int64)  # the patches gathered exactly: where a vertex touches one,
        vg = lift_off_contacts(vg, ng, pm.centre[touch], pm.normal[touch], pm.radius[touch], 2e-3)  # from above
        E = np.zeros((len(vu), 3))
        rad_em = rl.radiance[em]
        if self.local_light is not None:  # photo light: the emitters' strength the surfaces around it show
            local, scalable = self.local_light
            c = 0.5 * (vu.min(0) + vu.max(0))
            self.emitter_scale = local.scale(c, float(np.linalg.norm(vu - c, axis=1).max()))
            rad_em = np.where(scalable[em][:, None], self.emitter_scale * rad_em, rad_em)
        E[g] = ss.direct_sum(vg, ng, pm.corners[em], pm.normal[em], rad_em, [room, own], 2e-3,
                             pair_split(self.device, len(em)), groups)
        sun_u = sun_vis = None
        if self.sun is not None:  # sun: direct, with the object's self-shadowing
            # the object's own shadow is kept per shape (the sun's rays are parallel: a move changes none
            # of it); per frame only the room's shadow is tested
            self_lit = ss.sun_self_lit(self.sun.d, vu, nu, own)
            on = np.flatnonzero(self_lit > 0)  # the room's shadow tested only where the object's own leaves the sun
            vis_u = np.zeros(len(vu))
            vis_u[on] = self.sun.visibility(vu[on], nu[on], disk=True) * self_lit[on]  # the openings' penumbra
            sun_u = vis_u[:, None] * (self.sun.sun.irradiance / np.pi)
            sun_vis = vis_u[ss.inv]  # each vertex's sun share, cos x visibility (sharpened per camera hit later)
            # the sun the object blocks from the floor: a large, sharp loss right beside it, gathered at
            # every vertex (a sparse sample would interpolate it past the SH9 light and clip to black)
            if len(ch):  # exact form factors at every vertex, visibility cast at samples (as the emitters')
                corners, normals, values = self._sun_loss_cells(vu, ch, sun_dB, sun_lost)
                E[g] += ss.sun_dB_sum(vg, ng, corners, normals, values, [self.scene_occ, own],
                                      2e-3, pair_split(self.device, len(corners)))
        if dB is not None:
            # the shadowed patches that hold 95 % of the lost power (the rest is too faint to matter)
            loss = np.abs(luminance(dB)) * pm.area
            order = np.argsort(-loss)
            order = order[loss[order] > 0]
            keep = int(np.searchsorted(np.cumsum(loss[order]), 0.95 * loss.sum())) + 1 if len(order) else 0
            changed = order[:keep]
            far = np.zeros(0, np.int64)
            if len(changed) and self.config.dB_far_field:
                # beyond DB_FAR bounding radii a patch's loss reaches the object as a far field: radiance SH9
                # at a probe grid over the object's box, through the cached self-occlusion transfer
                lo, hi = vu.min(0), vu.max(0)
                centre = 0.5 * (lo + hi)
                radius = float(np.linalg.norm(vu - centre, axis=1).max())
                pr = pm.radius
                d = np.linalg.norm(pm.centre[changed] - centre, axis=1) - pr[changed]
                is_far = (d >= DB_FAR * radius) & (2.0 * pr[changed] <= DB_CLUSTER * (d + pr[changed]))
                far, changed = changed[is_far], changed[~is_far]
                if len(far):
                    probes, weights = _probe_grid(lo, hi, vu, DB_PROBES)
                    pc, pn, pa, prad = cluster_patches(pm.centre[far], pm.normal[far], pm.area[far], pm.quad[far],
                                                       dB[far], d[is_far] + pr[far], 2.0 * float(pr.min()))
                    L = self.far_field_sh(probes, lo, hi, pc, pn, pa, prad)
                    E += np.einsum("vk,vkc->vc", ss.T, np.einsum("vq,qkc->vkc", weights, L))
            if len(changed):
                # the loss varies slowly over the object (the shadowed patches are beyond it):
                # gather it at a spread subset of vertices and interpolate by position and normal
                sub = ss.sub
                E += ss.interpolate(ss.dB_sum(vu[sub], nu[sub], pm.corners[changed], pm.normal[changed], dB[changed],
                                              [self.scene_occ, own], 2e-3, pair_split(self.device, len(changed))))
        E += E_ind
        S = obj.albedo * sun_u[ss.inv] if sun_u is not None else None
        L_vert = vertex_light(obj.albedo * np.maximum(E, 0.0)[ss.inv], S,
                              functools.partial(_fill_from_neighbours, faces=f, missing=ss.buried), ss.bounce,
                              obj.albedo)
        return L_vert, sun_vis

    def _sun_loss_cells(self, vu: np.ndarray, ch: np.ndarray, sun_dB: np.ndarray, sun_lost: tuple | None
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(corners (M,4,3), normals (M,3), values (M,3)) of the sun's loss the object gathers: the patches ch
        whole, but the sunlit patches near the object (centre within SUN_NEAR diameters plus a radius of the
        box of the vertices vu) as the cells of their sun sample points (sun_cells), where those differ (a patch
        whose points all lose, and all receive, the same share is its cells' sum already). Beside an object's foot
        its own sun shadow's edge, and the opening's, cross a patch, and the floor right at the foot is what
        a vertex near the contact sees most of (a vertical face's point at height z takes 3/4 of the floor's
        form factor from within 4 z). Such a patch is gathered exactly whole (RoomLight.gather_exactly, its
        mean radiance B): here it comes back as -B whole (cancelling that term) plus its cells at B + rho
        E_sun (s_k - mean s) - rho E_sun lost_k, s_k the sun's share (cos x visibility past the room) at cell
        k's point, lost_k the share the object takes there: the sun lies on the cells the room lets it reach
        and is taken from those the object shades, never below the patch's indirect part.
        sun_lost: (patch ids (Pc,), lost (Pc,K), the sun's share s (Pc,K), E_sun (3,) irradiance/pi): SunStage's
        c_patch, lost, c_vis and E_perp this frame."""
        pm, rl = self.patches, self.room_light
        whole = (pm.corners[ch], pm.normal[ch], sun_dB[ch])
        if sun_lost is None or not self.config.sun_cells:
            return whole
        ids, lost, share, E_sun = sun_lost
        row = np.full(pm.n_patches, -1, np.int64)
        row[ids] = np.arange(len(ids))
        exact = np.zeros(pm.n_patches, bool)
        exact[rl.emitters] = True
        cand = ids[exact[ids] & ~pm.is_emitter[ids]]  # sunlit, gathered exactly whole
        gap = pm.centre[cand] - np.clip(pm.centre[cand], vu.min(0), vu.max(0))
        nr = cand[np.linalg.norm(gap, axis=1) < (2.0 * SUN_NEAR + 1.0) * pm.radius[cand]]
        nr = nr[(np.ptp(lost[row[nr]], 1) > 0) | (np.ptp(share[row[nr]], 1) > 0)]  # uniform: its cells are the patch
        if not len(nr):
            return whole
        far = ch[~np.isin(ch, nr)]
        r = row[nr]
        K = lost.shape[1]
        rhoE = pm.albedo[nr] * np.asarray(E_sun, np.float64).reshape(1, 3)  # (M,3)
        B = rl.radiance[nr]
        sun = rhoE[:, None, :] * (share[r] - share[r].mean(1, keepdims=True))[..., None]  # (M,K,3)
        vals = (np.maximum(B[:, None, :] + sun, 0.0) - rhoE[:, None, :] * lost[r][..., None]).reshape(-1, 3)
        cells, _, k = sun_cells(pm.corners[nr], np.zeros((len(nr), 3)), lost[r],
                                np.stack([lost[r], share[r]], -1))  # equal cells merged
        return (np.concatenate([pm.corners[far], pm.corners[nr], cells]),
                np.concatenate([pm.normal[far], pm.normal[nr], pm.normal[nr][k // K]]),
                np.concatenate([sun_dB[far], -B, vals[k]]))

    def room_triangles(self, occ: Occluder) -> np.ndarray:
        """The room occluder's triangles (T,3,3) float64, read back once per engine."""
        cached = self._room_tris
        if cached is None or cached[0] is not occ:
            cached = self._room_tris = [occ, occ.triangles(), None]
        return cached[1]

    def room_triangle_boxes(self, occ: Occluder) -> "_TriangleBoxes":
        """The room occluder's triangles in buckets (_TriangleBoxes), made once per engine beside room_triangles."""
        tris = self.room_triangles(occ)
        cached = self._room_tris
        if cached[2] is None:
            cached[2] = _TriangleBoxes(tris)
        return cached[2]

    def far_field_sh(self, probes: np.ndarray, lo: np.ndarray, hi: np.ndarray, pc: np.ndarray, pn: np.ndarray,
                     area: np.ndarray, radiance: np.ndarray, eps: float = 2e-3) -> np.ndarray:
        """Radiance SH9 coefficients (Q,9,3) at the probes (Q,3, inside the box lo..hi) of far patches (centres
        pc (M,3), unit normals pn (M,3), areas (M,) m^2, radiance (M,3)), each a point of solid angle
        A cos / r^2 from every probe, seen past the room (self.scene_occ) as from the box's 8 corners (one ray
        per corner and patch, cast from 1 mm towards the box centre: a corner may lie on the floor the object
        stands on), interpolated trilinearly: a room shadow's edge across the box gives a partial share."""
        from lighting import sh

        if len(pc) == 0:
            return np.zeros((len(probes), 9, 3))
        b = pc + pn * eps
        corners, vis_w = _probe_grid(lo, hi, probes, 2)  # (8,3), (Q,8)
        centre = 0.5 * (lo + hi)
        to_c = centre - corners
        lc = np.linalg.norm(to_c, axis=1, keepdims=True)
        o = corners + to_c / np.maximum(lc, 1e-12) * np.minimum(1e-3, 0.5 * lc)
        dv = b[None] - o[:, None]
        dist = np.linalg.norm(dv, axis=2)
        faces = np.einsum("qmc,mc->qm", dv, pn) < 0  # the patch's emitting side towards the corner
        seen = np.flatnonzero(faces.reshape(-1))
        vis = np.zeros(faces.size)
        if len(seen):
            q = seen // len(pc)
            d = (dv / dist[..., None]).reshape(-1, 3)[seen]
            _, _, depth = cast_rays(self.scene_occ, o[q], d, workspace=self._workspaces.get("dB_far"))
            vis[seen] = depth >= dist.reshape(-1)[seen]
        vis = vis_w @ vis.reshape(faces.shape)  # (Q,M)
        dv = b[None] - probes[:, None]  # (Q,M,3)
        dist = np.linalg.norm(dv, axis=2)
        w = dv / dist[..., None]
        cos_j = -np.einsum("qmc,mc->qm", w, pn)
        omega = np.where(cos_j > 0, area * cos_j / dist ** 2, 0.0) * vis
        Yw = sh.basis(w) * omega[..., None]  # (Q,M,9)
        return np.matmul(Yw.transpose(0, 2, 1), np.asarray(radiance, np.float64))  # (Q,9,3)

    def emitter_groups(self) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray]]:
        """The room's emitter patches in kernels.shade.patch_groups order (one group per surface and
        radiance that tiles a rectangle) and the groups (start, polys), made once per engine."""
        cached = self._emitter_groups
        if cached is None:
            rl, pm = self.room_light, self.patches
            em = rl.emitters
            order, start, polys = patch_groups(pm.corners[em], pm.quad[em], rl.radiance[em])
            cached = self._emitter_groups = (em[order], (start, polys))
        return cached

    def shape_shading(self, v: np.ndarray, n: np.ndarray, f: np.ndarray) -> ShapeShading:
        """ShapeShading of the mesh, kept for the last shape: self-occlusion does not change when the
        object slides, only when it turns or changes (the key is the centred mesh to 1 um). Centred,
        the float32 ray casts give the same answer at every position: in world coordinates 3-4 % of
        the rays grazing a neighbouring face flipped between positions 0.4 m apart, up to 13 levels on
        the object while dragging."""
        local = v - v.mean(0)
        key = hashlib.sha1(np.round(local, 6).tobytes() + np.round(n, 6).tobytes()
                           + np.ascontiguousarray(f).tobytes()
                           + f"{self.config.prt_dirs} {self.config.vis_stride}".encode()).hexdigest()
        cached = self._prt
        if cached is None or cached[0] != key:
            self._prt = cached = (key, ShapeShading(local, n, f, self.config.prt_dirs, self.config.dB_samples,
                                                    self.device, self.config.vis_stride,
                                                    len(self.room_light.emitters)))
            cached[1].key = key
        return cached[1]

    def forget_shapes(self) -> None:
        """Drop the per-shape caches (proxy, shading mesh, BVHs, ShapeShading): the next frame makes
        them afresh."""
        self._shape = self._shade_occ = self._prt = None

    def shade(self, obj: SceneObject, mesh, hits: ObjectHits, proxy_occ: Occluder, dB: np.ndarray,
              sun_dB: np.ndarray | None = None, vertex: tuple | None = None, sun_lost: tuple | None = None
              ) -> ShadedObject:
        """The object's radiance from vertex_radiance, interpolated at the camera hits (with a sun, its
        direct light per hit; with a specular lobe, the room's reflection). vertex: (L_vert, sun_vis) of
        this shading mesh to use instead of vertex_radiance's (the drag frame's, app.dragframe); sun_lost:
        vertex_radiance's."""
        if not hits.hit.any():
            return ShadedObject(np.zeros((hits.H, hits.W, 3)), None, None)
        L_vert, sun_vis = vertex if vertex is not None else self._vertex_radiance(obj, mesh, proxy_occ, dB, sun_dB,
                                                                                           sun_lost)
        v, n, f = mesh
        h = hits.hit
        sub = np.zeros((len(h), 3))
        corners = f[hits.tri[h]]
        sub[h] = np.einsum("nk,nkc->nc", hits.bary[h], L_vert[corners])
        if self.sun is not None:  # sun: its direct light per camera hit (a sharp edge
            # across a face, not a vertex blend), on the faces with a sunlit corner (on the others both the
            # per-hit sun and the vertex blend it replaces are 0); rays where a shadow edge crosses a face
            this_frame = self._shade_occ is not None and self._shade_occ[0] is v  # object_shape's mesh
            own = self._shade_occ[1] if this_frame else Occluder(v, f, self.device)
            hh = np.flatnonzero(h)
            groups = self.face_groups if this_frame else None
            k, delta = self.sun.hit_correction(v, n, f, sun_vis, hits.tri[hh], hits.bary[hh], [own], groups)
            if len(k):
                hk = hh[k]
                sub[hk] = np.maximum(sub[hk] + obj.albedo * (delta[:, None] * (self.sun.sun.irradiance / np.pi)),
                                     0.0)
        if self.config.specular > 0:
            pos = np.einsum("nk,nkc->nc", hits.bary[h], v[corners])
            nrm = np.einsum("nk,nkc->nc", hits.bary[h], n[corners])
            nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-12)
            view = pos - self.camera.centre
            view /= np.linalg.norm(view, axis=1, keepdims=True)
            env = self.specular_map(0.5 * (v.min(0) + v.max(0)))
            sub[h] += self.config.specular * env.lookup(reflect(view, nrm))
        return ShadedObject(hits.average(sub), L_vert, sun_vis)

    def specular_map(self, centre: np.ndarray) -> CubeMap:
        """The room's radiance seen from `centre` (the object's centre, object absent), pre-filtered
        with the Phong lobe of `shininess` (seed sec. 5, fig. 9)."""
        p, pm = self.config, self.patches
        res_in = max(2 * p.envmap_res, int(np.ceil(2 * np.sqrt(p.shininess))))
        dirs, _ = cube_directions(res_in)
        tri, _, _ = cast_rays(self.cam_occ, np.asarray(centre, np.float64), dirs,
                              workspace=self._workspaces.get("specular_map"))
        L = np.where((tri >= 0)[:, None], self.B_src[pm.tri_patch[np.maximum(tri, 0)]], 0.0)
        return phong_prefilter(L, res_in, p.shininess, p.envmap_res)
