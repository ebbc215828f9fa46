"""The object while dragging, from per-shape tables: its shading and its light on the room, no rays per vertex.

Used by the drag frame only (FrameConfig.drag; app.engine), in every room (Engine.drag_object_sun False: not in
rooms a sun lights); at rest app.stages.object_shading and app.stages.object_light run as before. Everything per
vertex is computed once per object shape in the shape's own frame (canonical: centred, yaw 0; a pose that translates
the object or turns it about the up axis +Y keeps every table; a tilted object's frame is the world's orientation,
frame_yaw), and per frame only the room's light is looked up:

- indirect light and the room's change in the object's shadow: radiance SH9 at a PROBES^3 grid over the object's box
  (the SH volume looked up there, the changed patches projected as small disks), rotated into the object's frame for
  its yaw (sh_yaw_matrix: each band's (m, -m) pair turns by cos / sin of m x yaw), interpolated trilinearly and
  dotted with each vertex's cached self-occlusion transfer (PRT, kernels.shade.self_transfer: the same transfer the
  frame at rest uses);
- the exact emitters (lamps, windows, the sunlit floor patches): unoccluded polygon form factors at the vertices
  (kernels.formfactor) x the object's own visibility toward each emitter, read from the cached PRT rays binned by
  direction (VIS_RES^2 octahedral cells) x the room's visibility, one ray per probe and emitter group, interpolated,
  summed per vertex in one kernel (kernels.drag_gather; so are the near changed patches' form factors below, the
  sun's loss on a sunlit patch seen past the room as that patch is); a vertex touching a patch gathered so (a leg's
  foot on the sunlit floor) gathers from just above it (lift_off_contacts, as at rest);
- the changed patches: the room's that hold DB_SHARE of its loss (the later bounces of the sun's loss on the walls
  included: app.stages.sun.SunStage.later_at_patches) and every patch the sun's loss takes from, as at rest;
- the sun: cos x the object's own shadow (rays cast once per shape and sun direction in the object's frame: a
  translation casts none) x the room's shadow: the opening the sun comes through, per vertex (a plane and a quad: no
  ray), and what else blocks it, at the probes, interpolated.

The object's light on the room: the frame's proxy (the same triangles as at rest) takes its triangles' radiance from
the shaded vertices (the area-weighted mean of those nearest each, a sparse map made once per shape and proxy)
instead of gathering the room at each triangle by rays; the sun's part is the frame at rest's sunlit pieces
(app.engine: SunStage.object_emitters, made once per shape). A coarser proxy (48 triangles simplified from the
shading mesh) was tried and not kept: facets near a contact sent several times the light (docs/benchmarks.md).

Units: radiance; E as irradiance / pi, as in app.stages.object_shading.
"""
from __future__ import annotations

import functools
import hashlib
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import warp as wp
from scipy.spatial import cKDTree

from app.runtime import split as split_launches
from kernels.buffers import Workspaces
from kernels.disk_sh import disk_sh_launch
from kernels.drag_gather import gather_seen
from kernels.hit_average import FrameImage, SunAtHits, hit_average
from kernels.raycast import cast_rays
from kernels.sunshadow import exit_arrays
from kernels.vec import cross3, same_key
from kernels.visibility import Occluder
from lighting import sh

# Probes per axis of the grid over the object's box where the room's light is looked up: 3 (27 probes)
# resolves a change across the box to second order (a light gradient, the sun patch's edge halfway up),
# which the 2 corners of a 2^3 grid cannot; each probe costs one SH lookup and one ray per emitter group.
PROBES = 3
# The probes' lowest level lies this far above the box's bottom (m): the object stands on a surface, and a
# probe in its plane would see half of it edge-on (and start its rays inside it).
PROBE_LIFT = 0.02
# Octahedral cells a side of the per-vertex self-visibility table (VIS_RES^2 cells over the sphere, about
# half of them over a vertex's hemisphere, ~4 of its 128 PRT rays each: the table's angular resolution,
# ~30 deg, is the PRT rays' own spacing times two).
VIS_RES = 8
# Texels a side of the object's own sun shadow map (per shape and sun direction, in its frame): the camera hits
# read the sun's edge across a face from it (the frame at rest casts a ray per hit there); 256 over the object's
# extent puts a texel at ~4 mm on a 1 m chair, below a 640 px frame's pixel at 2 m.
SUN_MAP_RES = 256
# Proxy triangles whose centroids a shading vertex considers for its radiance (the nearest ones, the first
# facing its way taken): a vertex's own triangle lies among the few nearest.
PROXY_CANDIDATES = 8
# The changed patches (the object's shadow) projected at the probes: those holding this share of the lost
# power, at most DB_MAX of them (the frame at rest keeps the same 95 %: ObjectShading._vertex_radiance).
DB_SHARE = 0.95
# Bounding radii (nearest point of a patch to the object's centre) within which a changed patch's loss is
# gathered with exact form factors at the vertices (app.stages.object_shading's DB_FAR, the same rule).
DB_NEAR = 2.0
KEY_OFFSET = 1.0 / 3.0  # DragObject.shape's key: coordinates to 10 um on a grid offset by a third of a step
DB_MAX = 512
# A tilted object (turned about another axis than +Y) shaded from its tables while dragging (frame_yaw), not as at
# rest (DragObject.tilted; docs/benchmarks.md "drag109")
DRAG_TILTED = True


def _strongest(change: np.ndarray, area: np.ndarray, share: float = DB_SHARE) -> np.ndarray:
    """The patches (indices) of a radiance change (P,3) that hold `share` of its loss |change| x area, at most
    DB_MAX of them, strongest first."""
    loss = np.abs(change).sum(1) * area
    order = np.argsort(-loss)[:DB_MAX]
    order = order[loss[order] > 0]
    if len(order) == 0:
        return order
    keep = int(np.searchsorted(np.cumsum(loss[order]), share * loss[order].sum())) + 1
    return order[:keep]


def rot_y(yaw: float) -> np.ndarray:
    """(3,3) rotation by yaw radians about +Y (app.placement's convention: counter-clockwise from above)."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def yaw_of(object_to_world: np.ndarray, tol: float = 1e-6) -> float | None:
    """The yaw (radians) of an object_to_world (4,4) whose linear part is a uniform scale times a
    rotation about +Y; None when it is not (a tilted object: the drag frame then shades it as at rest)."""
    L = np.asarray(object_to_world, np.float64)[:3, :3]
    s = float(np.cbrt(abs(np.linalg.det(L))))
    if s <= 0:
        return None
    R = L / s
    yaw = float(np.arctan2(R[0, 2], R[0, 0]))
    return yaw if np.abs(R - rot_y(yaw)).max() < tol else None


def frame_yaw(object_to_world: np.ndarray) -> float:
    """The yaw (radians) that DragObject takes out of a pose to find its shape's canonical frame: yaw_of's for a
    pose turned about +Y only, 0 for a tilted one. A tilted object's canonical frame is then the world's own
    orientation, the tilt kept in the shape's local coordinates: a drag (which translates the object) keeps its
    tables, and a new tilt or a turn of a tilted object makes new ones (DragObject.shape's key). Before drag109 a
    tilted object was shaded as at rest on every drag frame (its full ObjectShading and the proxy's rays: the
    tilted tori of sun_107 / sun_108, ~410-460 ms of a drag frame's CPU; docs/benchmarks.md "drag109")."""
    yaw = yaw_of(object_to_world)
    return 0.0 if yaw is None else yaw


def _fib_sphere(n: int) -> np.ndarray:
    k = np.arange(n) + 0.5
    y = 1.0 - 2.0 * k / n
    r = np.sqrt(1.0 - y * y)
    phi = k * 2.399963229728653
    return np.stack([r * np.cos(phi), y, r * np.sin(phi)], 1)


def _y_polar_basis_change() -> np.ndarray:
    """P (9,9) orthogonal: the real SH9 basis with +Y as its polar axis (lighting.sh's functions of the
    coordinates (z, x, y)) in terms of lighting.sh's basis, Y'(d) = P Y(d) (a least-squares fit on 400
    directions, exact: both span the same bands)."""
    D = _fib_sphere(400)
    Pt, *_ = np.linalg.lstsq(sh.basis(D), sh.basis(D[:, [2, 0, 1]]), rcond=None)
    return Pt.T


_P = _y_polar_basis_change()
_PAIRS = ((3, 1, 1), (7, 5, 1), (8, 4, 2))  # in the Y-polar basis: (cos m phi index, sin m phi index, m)


def sh_yaw_matrix(yaw: float) -> np.ndarray:
    """A (9,9): the SH9 coefficients of g(c) = f(R_y(yaw) c) are A @ (f's), i.e. a world radiance
    function seen in the frame of an object turned by yaw about +Y. In the Y-polar basis each band's
    (m, -m) pair turns by cos / sin of m x yaw (the zonal terms stay)."""
    Z = np.eye(9)
    for ci, si, m in _PAIRS:
        c, s = np.cos(m * yaw), np.sin(m * yaw)
        Z[ci, ci], Z[ci, si], Z[si, si], Z[si, ci] = c, s, c, -s
    return _P.T @ Z @ _P


def _octa_cell(d: np.ndarray, res: int) -> np.ndarray:
    """Octahedral cell index (...) in [0, res^2) of unit directions d (...,3)."""
    d = d / np.maximum(np.abs(d).sum(-1, keepdims=True), 1e-12)
    x, z = d[..., 0], d[..., 2]
    neg = d[..., 1] < 0
    ox = np.where(neg, (1.0 - np.abs(z)) * np.sign(x + 1e-30), x)
    oz = np.where(neg, (1.0 - np.abs(x)) * np.sign(z + 1e-30), z)
    i = np.clip(((ox + 1.0) * 0.5 * res).astype(np.int64), 0, res - 1)
    j = np.clip(((oz + 1.0) * 0.5 * res).astype(np.int64), 0, res - 1)
    return i * res + j


def prt_directions(normals: np.ndarray, n_dirs: int) -> np.ndarray:
    """(V,n_dirs,3) the directions kernels.shade.self_transfer casts at vertices of these unit normals
    (its tangent frame and golden-angle spiral, cosine-distributed), so its hit table can be read by direction."""
    n = np.asarray(normals, np.float64)
    helper = np.where((np.abs(n[:, 0]) > 0.9)[:, None], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0])
    t1 = cross3(helper, n)
    t1 /= np.maximum(np.linalg.norm(t1, axis=1, keepdims=True), 1e-12)
    t2 = cross3(n, t1)
    k = np.arange(n_dirs)
    u = (k + 0.5) / n_dirs
    phi = k * 2.399963229728653
    r = np.sqrt(u)
    a, b, c = r * np.cos(phi), r * np.sin(phi), np.sqrt(1.0 - u)
    return t1[:, None] * a[None, :, None] + t2[:, None] * b[None, :, None] + n[:, None] * c[None, :, None]


def visibility_table(normals: np.ndarray, unblocked: np.ndarray, res: int = VIS_RES) -> np.ndarray:
    """(U, res^2) float32: per vertex (unit normals (U,3)) the share of its PRT rays (unblocked (U,K) bool)
    that leave the object, per octahedral cell of direction; 1 in cells none of its rays fall in."""
    U, K = unblocked.shape
    cell = _octa_cell(prt_directions(normals, K), res)  # (U,K)
    flat = (np.arange(U)[:, None] * res * res + cell).ravel()
    cnt = np.bincount(flat, minlength=U * res * res).reshape(U, -1)
    free = np.bincount(flat, unblocked.ravel().astype(np.float64), U * res * res).reshape(U, -1)
    return np.where(cnt > 0, free / np.maximum(cnt, 1), 1.0).astype(np.float32)


def disk_sh(probes: np.ndarray, centres: np.ndarray, normals: np.ndarray, areas: np.ndarray,
            radiance: np.ndarray) -> np.ndarray:
    """Radiance SH9 (Q,9,3) at the probes (Q,3) of patches as disks (centres, unit normals (M,3), areas (M,) m^2,
    radiance (M,3)) seen from their emitting side: solid angle 2 pi (1 - r / sqrt(r^2 + a / pi)) x cos (the
    on-axis disk's, finite where a probe comes close), no visibility (the patches lie around the object). The numpy
    reference of kernels.disk_sh.disk_sh_launch, which DragObject.shade calls."""
    dv = centres[None] - probes[:, None]  # (Q,M,3)
    r = np.linalg.norm(dv, axis=2)
    w = dv / np.maximum(r, 1e-9)[..., None]
    cos = -np.einsum("qmc,mc->qm", w, normals)
    omega = np.where(cos > 0, 2 * np.pi * (1 - r / np.sqrt(r * r + areas / np.pi)) * cos, 0.0)
    Yw = sh.basis(w) * omega[..., None]  # (Q,M,9)
    return np.matmul(Yw.transpose(0, 2, 1), np.asarray(radiance, np.float64))


class FillOperator:
    """app.stages.object_shading._fill_from_neighbours(values, faces, missing, rounds) for any values (n,C) as
    `F @ values`: the rounds of neighbour means as one sparse matrix (it is linear), then the rows no round
    reached set to the mean of the others (done at apply time: as matrix rows they would be dense)."""

    def __init__(self, faces: np.ndarray, missing: np.ndarray, n: int, rounds: int = 8):
        self.identity = not missing.any() or missing.all()
        if self.identity:
            return
        e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
        e = np.concatenate([e, e[:, ::-1]])
        known = ~missing
        F = sp.identity(n, format="csr")
        for _ in range(rounds):
            src = known[e[:, 0]] & ~known[e[:, 1]]
            if not src.any():
                break
            dst, frm = e[src, 1], e[src, 0]
            cnt = np.bincount(dst, minlength=n)
            S = sp.csr_matrix((1.0 / cnt[dst], (dst, frm)), shape=(n, n))  # duplicates summed, as np.add.at
            F = (sp.diags((cnt == 0).astype(np.float64)) @ F + S @ F).tocsr()
            known = known | (cnt > 0)
        self.F, self.known = F, known
        self.left = np.flatnonzero(~known)

    def __matmul__(self, values: np.ndarray) -> np.ndarray:
        if self.identity:
            return values
        out = self.F @ values
        if len(self.left):
            out[self.left] = out[self.known].mean(0)
        return out


def fill_operator(faces: np.ndarray, missing: np.ndarray, n: int, rounds: int = 8) -> FillOperator:
    """FillOperator(faces, missing, n, rounds)."""
    return FillOperator(faces, missing, n, rounds)


class DragShape:
    """The tables of one object shape in its canonical frame (centred, yaw 0): the shading mesh's
    ShapeShading (distinct vertices, PRT transfer, buried vertices, self-bounce), the self-visibility
    table by direction, the probe weights, the coarse proxy and its vertex map, the object's own sun
    shadow per sun direction."""

    def __init__(self, local: np.ndarray, normals: np.ndarray, faces: np.ndarray, shading, device: str):
        from app.stages.object_shading import ShapeShading, _probe_grid

        cfg = shading.config
        self.local, self.normals, self.faces = local, normals, faces
        self.ss = ss = ShapeShading(local, normals, faces, cfg.prt_dirs, cfg.dB_samples, device, cfg.vis_stride,
                                    len(shading.room_light.emitters))
        T, hit_face, _ = ss.transfer
        self.lu, self.nu = local[ss.uniq] + ss.lift, normals[ss.uniq]  # a vertex on a contact between parts: off it
        self.vis = visibility_table(self.nu, hit_face[ss.uniq] < 0)
        self.fill = fill_operator(faces, ss.buried, len(local))  # _fill_from_neighbours as one sparse product
        lo, hi = self.lu.min(0), self.lu.max(0)
        lo = lo + np.array([0.0, min(PROBE_LIFT, 0.5 * (hi[1] - lo[1])), 0.0])
        self.probes, self.weights = _probe_grid(lo, hi, self.lu, PROBES)
        self.own = Occluder(local, faces, device)  # for the sun's self-shadow, cast in this frame
        self._sun: dict[tuple, np.ndarray] = {}
        self._to_proxy: tuple[str, sp.csr_matrix] | None = None  # (proxy key, its map) of the last proxy
        self.all_rows = np.arange(len(self.lu))  # every distinct vertex's row of `vis`
        self._vis_dev: dict[str, wp.array] = {}  # `vis` on a device (kernels.drag_gather), made once

    def vis_on(self, device: str) -> wp.array:
        """The visibility table `vis` as a Warp array on `device` (uploaded once per shape)."""
        if device not in self._vis_dev:
            self._vis_dev[device] = wp.array(self.vis, dtype=wp.float32, device=device)
        return self._vis_dev[device]

    def to_proxy(self, pv_local: np.ndarray, pf: np.ndarray) -> sp.csr_matrix:
        """(T,V) sparse: the radiance of each triangle of a proxy (vertices pv_local (Tv,3) in this frame, faces
        pf (T,3)) as the area-weighted mean of the shading vertices nearest it among those facing its way
        (each vertex to the triangle whose centroid is nearest of those whose normal is within 90 deg of its
        own; a triangle no vertex chose takes its nearest vertex's), made once per proxy."""
        key = hashlib.sha1(np.floor(pv_local * 1e5 + KEY_OFFSET).tobytes() + np.ascontiguousarray(pf).tobytes()
                           ).hexdigest()
        if self._to_proxy is not None and self._to_proxy[0] == key:
            return self._to_proxy[1]
        local, normals, faces = self.local, self.normals, self.faces
        tris = pv_local[pf]
        tn = cross3(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
        tn /= np.maximum(np.linalg.norm(tn, axis=1, keepdims=True), 1e-12)
        tc = tris.mean(1)
        fa = 0.5 * np.linalg.norm(cross3(local[faces[:, 1]] - local[faces[:, 0]],
                                           local[faces[:, 2]] - local[faces[:, 0]]), axis=1)
        va = np.bincount(faces.ravel(), np.repeat(fa / 3.0, 3), len(local))
        _, cand = cKDTree(tc).query(local, k=min(PROXY_CANDIDATES, len(tc)))
        cand = cand.reshape(len(local), -1)  # nearest centroids first
        facing = np.einsum("vc,vkc->vk", normals, tn[cand]) > 0.0
        first = np.where(facing.any(1), facing.argmax(1), 0)
        best = cand[np.arange(len(local)), first]
        M = sp.csr_matrix((va, (best, np.arange(len(local)))), shape=(len(pf), len(local)))
        rows = np.asarray(M.sum(1)).ravel()
        empty = np.flatnonzero(rows <= 0)
        if len(empty):
            _, near = cKDTree(local).query(tc[empty])
            M = M + sp.csr_matrix((np.ones(len(empty)), (empty, near)), shape=M.shape)
            rows = np.asarray(M.sum(1)).ravel()
        M = (sp.diags(1.0 / rows) @ M).tocsr()
        self._to_proxy = (key, M)
        return M

    def sun_map(self, d_local: np.ndarray) -> tuple:
        """The object's orthographic depth map toward the sun direction d_local (this frame), made once per
        direction (to 1e-4): (e1, e2 (3,) the map's axes, lo (2,) its corner, texel (m), top (m) the origin
        plane's offset along d_local, depth (SUN_MAP_RES, SUN_MAP_RES) float32 from that plane, inf: empty)."""
        key = ("map",) + tuple(np.round(d_local, 4))
        got = self._sun.get(key)
        if got is None:
            d = d_local / np.linalg.norm(d_local)
            e1 = cross3(d, [0.0, 1.0, 0.0] if abs(d[1]) < 0.9 else [1.0, 0.0, 0.0])
            e1 /= np.linalg.norm(e1)
            e2 = cross3(d, e1)
            uv = np.stack([self.local @ e1, self.local @ e2], 1)
            lo, hi = uv.min(0), uv.max(0)
            texel = float((hi - lo).max()) / (SUN_MAP_RES - 2)
            lo = lo - texel
            top = float((self.local @ d).max()) + 0.01
            g = (np.arange(SUN_MAP_RES) + 0.5) * texel
            gu, gv = np.meshgrid(lo[0] + g, lo[1] + g, indexing="ij")
            origins = gu.reshape(-1, 1) * e1 + gv.reshape(-1, 1) * e2 + top * d
            _, _, depth = cast_rays(self.own, origins, np.broadcast_to(-d, origins.shape).copy())
            got = self._sun[key] = (e1, e2, lo, texel, top, depth.reshape(SUN_MAP_RES, SUN_MAP_RES))
        return got

    def sun_map_on(self, d_local: np.ndarray, device: str) -> wp.array:
        """sun_map(d_local)'s depth as a Warp array (res, res) float32 on `device`, uploaded once per direction."""
        key = ("map on", device) + tuple(np.round(d_local, 4))
        got = self._sun.get(key)
        if got is None:
            got = self._sun[key] = wp.array(np.ascontiguousarray(self.sun_map(d_local)[5], np.float32),
                                            dtype=wp.float32, device=device)
        return got

    def sun_lit_at(self, points: np.ndarray, d_local: np.ndarray) -> np.ndarray:
        """(N,) share in [0, 1] of the object's own sun at points (N,3, this frame) on its surface: the depth map's
        test, bilinear over the 4 nearest texels (percentage closer), a bias of 2 texels + 2 mm along the sun."""
        e1, e2, lo, texel, top, depth = self.sun_map(d_local)
        t = top - points @ (d_local / np.linalg.norm(d_local))
        fu = (points @ e1 - lo[0]) / texel - 0.5
        fv = (points @ e2 - lo[1]) / texel - 0.5
        i0, j0 = np.floor(fu).astype(np.int64), np.floor(fv).astype(np.int64)
        au, av = fu - i0, fv - j0
        out = np.zeros(len(points))
        for di, dj, w in ((0, 0, (1 - au) * (1 - av)), (1, 0, au * (1 - av)), (0, 1, (1 - au) * av), (1, 1, au * av)):
            i = np.clip(i0 + di, 0, SUN_MAP_RES - 1)
            j = np.clip(j0 + dj, 0, SUN_MAP_RES - 1)
            out += w * (t <= depth[i, j] + 2 * texel + 2e-3)
        return out

    def sun_self_lit(self, d_local: np.ndarray, eps: float = 1e-3) -> np.ndarray:
        """(U,) 1 where the distinct vertex sees the sun direction d_local (this frame) past the object, else 0;
        cast once per direction (to 1e-4 rad)."""
        key = tuple(np.round(d_local, 4))
        lit = self._sun.get(key)
        if lit is None:
            lit = np.zeros(len(self.lu))
            up = np.flatnonzero(self.nu @ d_local > 0)
            if len(up):
                start = self.lu[up] + self.nu[up] * eps
                _, _, depth = cast_rays(self.own, start, np.broadcast_to(d_local, start.shape).copy())
                lit[up] = ~np.isfinite(depth)
            if len(self._sun) > 64:
                self._sun.clear()
            self._sun[key] = lit
        return lit


def sun_per_hit_numpy(ds: DragShape, sun, v: np.ndarray, n: np.ndarray, f: np.ndarray, room: np.ndarray, hits,
                      mean: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The sun's share per camera hit in numpy, as DragObject.shade computed it before kernels.hit_average's
    SunAtHits did it in one launch (the reference its test and bench/bench_glue48.py's A/B hold it to): per
    sub-sample (n,) the interpolated normal's cos x the object's own shadow (DragShape.sun_lit_at) x the room's
    share (room (V,) per vertex of the mesh v, n, f, world) blended from the corners x the share of the sun's disk
    the openings pass (sun: lighting.sun.SunLight, its disk_through); and, for the hits facing the sun (in order),
    their own shadow's share and that disk share. The object's frame: local = (p - mean) @ R."""
    d = sun.d
    h = np.flatnonzero(hits.hit)
    corners, bary = f[hits.tri[h]], hits.bary[h].astype(np.float64)
    nh = np.einsum("nk,nkc->nc", bary, n[corners])
    cos = np.maximum(nh @ d, 0.0) / np.maximum(np.linalg.norm(nh, axis=1), 1e-12)
    on = np.flatnonzero(cos > 0)
    add = np.zeros(len(hits.hit))
    hk, ck, bk = h[on], corners[on], bary[on]
    p = np.einsum("nk,nkc->nc", bk, v[ck])
    room_h = np.einsum("nk,nk->n", bk, room[ck])
    own, through = ds.sun_lit_at((p - mean) @ R, R.T @ d), sun.disk_through(p)
    add[hk] = cos[on] * own * room_h * through
    return add, own, through


@dataclass
class DragShaded:
    """DragObject.shade's result: the ShadedObject, and the vertex radiance's sun part (V,3) (None: no sun)."""

    shaded: object  # app.stages.object_shading.ShadedObject
    L_sun: np.ndarray | None
    L_proxy: np.ndarray  # (V,3) the radiance the proxy sends to the room (DragObject.shade: a bounce fewer)


class DragObject:
    """The drag frame's object shading and object proxy for one scene (built on an ObjectShading: its
    room light, emitters, sun and config)."""

    def __init__(self, shading, device: str, bounce_scale: np.ndarray | None = None):
        """bounce_scale (3,): the room's indirect light one bounce fewer over the light the object is shaded
        with (the object's light on the room is a bounce later: Engine.B_obj over B_src, area-weighted over
        the non-emitting patches); the proxy's radiance takes the indirect part so scaled, and no self-bounce."""
        self.bounce_scale = np.ones(3) if bounce_scale is None else np.asarray(bounce_scale, np.float64)
        self.shading, self.device = shading, device
        self._shape: tuple[tuple, DragShape] | None = None
        self.last: DragShaded | None = None
        self._pose: tuple | None = None  # (yaw, R, mean) of the last shaded pose
        # a tilted object shaded from its tables too, its canonical frame the world's orientation (frame_yaw; False:
        # as before drag109, shade returns None and the frame shades it as at rest)
        self.tilted = DRAG_TILTED
        self._disk_made = 0  # probes disk_sh's buffers hold (made at DB_MAX patches)
        self._ws = Workspaces()  # per call site: a drag allocates nothing after its first frame
        self._split = functools.partial(split_launches, device=device, min_items=64)
        self._radiance = FrameImage()  # the per-pixel radiance, kept: only the object's rectangle is rewritten
        self._group_of: np.ndarray | None = None  # each patch's emitter group (emitter_group_of)
        self._exit_dev: tuple | None = None  # (the SunLight, its openings as kernels.sunshadow.exit_arrays)

    def _exits(self, sun) -> list:
        """The openings the sun (lighting.sun.SunLight) enters through as device arrays, made once per sun."""
        if self._exit_dev is None or self._exit_dev[0] is not sun:
            self._exit_dev = (sun, exit_arrays(sun.entries, self.device))
        return self._exit_dev[1]

    def emitter_group_of(self) -> np.ndarray:
        """(P,) int64: each patch's emitter group (ObjectShading.emitter_groups' order), -1 for a patch in none;
        made on first use and kept (the groups are the engine's, made once)."""
        if self._group_of is None:
            em, (start, _) = self.shading.emitter_groups()
            group = np.full(self.shading.patches.n_patches, -1)
            group[em] = np.repeat(np.arange(len(start) - 1), np.diff(start))
            self._group_of = group
        return self._group_of

    def shape(self, v: np.ndarray, n: np.ndarray, f: np.ndarray, R: np.ndarray) -> tuple[DragShape, np.ndarray]:
        """(the DragShape of the shading mesh (v, n, f) at a pose of rotation R, its centre (3,))."""
        mean = v.mean(0)
        local, nl = (v - mean) @ R, n @ R
        cfg = self.shading.config
        # to 10 um, the grid offset by a third of a step: a shape of round sizes (a box, its subdivision's midpoints)
        # puts no coordinate on a rounding boundary, where float noise of the pose would flip it. The key's arrays
        # are compared with the last shape's, not hashed (a SHA-1 of the shared rooms' chair, 3564 vertices, took
        # ~0.38 ms a frame, the comparison ~0.05: docs/benchmarks.md, "glue111")
        key = (np.floor(local * 1e5 + KEY_OFFSET), np.floor(nl * 1e5 + KEY_OFFSET), np.array(f, copy=True),
               (cfg.prt_dirs, cfg.vis_stride))
        if self._shape is None or not same_key(self._shape[0], key):
            self._shape = (key, DragShape(local, nl, np.asarray(f), self.shading, self.device))
        return self._shape[1], mean

    def shade(self, obj, mesh, hits, dB: np.ndarray | None = None, sun_dB: np.ndarray | None = None
              ) -> DragShaded | None:
        """The object's radiance at its camera hits from the per-shape tables (module docstring; a tilted
        object's tables in the world's orientation, frame_yaw); None for a tilted object when `tilted` is False (the
        caller then shades it as at rest). The per-pixel radiance
        (shaded.radiance) is a kept image, valid until the next call (the frame composes it before then)."""
        from app.stages.object_shading import ShadedObject, lift_off_contacts, vertex_light

        if not self.tilted and yaw_of(obj.object_to_world) is None:
            return None
        yaw = frame_yaw(obj.object_to_world)
        R = rot_y(yaw)
        v, n, f = mesh
        ds, mean = self.shape(v, n, f, R)
        self._pose = (yaw, R, mean)
        ss, osh = ds.ss, self.shading
        rl, pm = osh.room_light, osh.patches
        probes = mean + ds.probes @ R.T  # world
        vu, nu = mean + ds.lu @ R.T, ds.nu @ R.T
        # ---- SH: the volume's indirect light and the object's shadow on the room, rotated into the object's frame
        L = rl.indirect_sh(probes)  # (Q,9,3)
        near_light = None  # (patches, corners, centres, radiance change) of the near changed patches
        change = dB if dB is not None else None
        if sun_dB is not None:
            change = sun_dB if change is None else change + sun_dB
        if change is not None:
            # the room's change: the patches holding DB_SHARE of its loss; the sun's: every patch it takes from (as
            # at rest: the room's loss, its later bounces on the walls included, is spread thin; a cut of the two
            # summed would keep the sun's patches alone and leave the object seeing the walls as lit)
            k = _strongest(dB, pm.area) if dB is not None else np.zeros(0, np.int64)
            if sun_dB is not None:
                k = np.union1d(k, _strongest(sun_dB, pm.area, 1.0))
            if len(k):
                # near the object (within DB_NEAR bounding radii of its centre) a patch is a polygon, its form
                # factor exact at every vertex (the floor under the object fills half of a low vertex's view,
                # which no disk at a probe resolves), farther a disk at the probes (SH)
                centre = 0.5 * (vu.min(0) + vu.max(0))
                radius = float(np.linalg.norm(vu - centre, axis=1).max())
                near = np.linalg.norm(pm.centre[k] - centre, axis=1) - pm.radius[k] < DB_NEAR * radius
                kn, kf = k[near], k[~near]
                if len(kf):  # disk_sh in one launch (kernels.disk_sh)
                    L = L + disk_sh_launch(probes, pm.centre[kf], pm.normal[kf], pm.area[kf], change[kf], self.device,
                                           self._ws.get("drag.disk"), DB_MAX)
                    self._disk_made = len(probes)
                if len(kn):
                    near_light = (kn, pm.corners[kn], pm.centre[kn], change[kn])
        if self._disk_made < len(probes):  # disk_sh's buffers made on a shape's first frame even when it has no far
            # changed patch (a launch over none), so that a later frame that has some allocates nothing
            e = np.zeros((0, 3))
            disk_sh_launch(probes, e, e, np.zeros(0), e, self.device, self._ws.get("drag.disk"), DB_MAX)
            self._disk_made = len(probes)
        A = sh_yaw_matrix(yaw)
        Lc = np.einsum("kj,qjc->qkc", A, L)  # (Q,9,3) in the object's frame
        Lv = (ds.weights @ Lc.reshape(len(probes), 27)).reshape(-1, 9, 3)
        E = np.einsum("uk,ukc->uc", ss.T, Lv)
        E_proxy = E * self.bounce_scale  # the indirect a bounce fewer; the emitters' and the sun's as they are
        # ---- the exact emitters: form factors x own visibility by direction x the room's at the probes
        em, (start, polys) = osh.emitter_groups()
        # a vertex touching a patch gathered exactly (a leg's foot on the sunlit floor) gathers it from just above
        # the surface, as at rest (object_shading.lift_off_contacts: in the surface's plane its form factor is 0)
        ch = np.flatnonzero(np.abs(sun_dB).sum(1) > 0) if sun_dB is not None else np.zeros(0, np.int64)
        touch = np.union1d(em, ch).astype(np.int64)
        vg = lift_off_contacts(vu, nu, pm.centre[touch], pm.normal[touch], pm.radius[touch], 2e-3)
        w_em = None  # (U,G) the room's visibility of each emitter group at the vertices
        if len(em):
            rad = rl.radiance[em[start[:-1]]]  # (G,3) one radiance per group
            cen = polys.mean(1)  # (G,3)
            dp = cen[None] - probes[:, None]  # (Q,G,3)
            dist = np.linalg.norm(dp, axis=2)
            _, _, depth = cast_rays(rl.occluder, np.repeat(probes, len(cen), 0), (dp / dist[..., None]).reshape(-1, 3),
                                    workspace=self._ws.get("drag.probe_rays"))
            seen = (depth.reshape(dist.shape) >= dist * (1 - 1e-2) - 1e-2).astype(np.float64)  # (Q,G)
            # form factors x own visibility by direction x the room's, summed per vertex in one kernel
            E_em = gather_seen(vg, nu, ds.all_rows, ds.vis_on(self.device), polys, rad, R, VIS_RES, self.device,
                               self._ws.get("drag.ff"), self._split, weights=(w_em := ds.weights @ seen))
            E += E_em
            E_proxy += E_em
        if near_light is not None:  # the near changed patches: exact form factors x own visibility (no room's); the
            # sun's loss (a large, sharp loss right beside the object) at every vertex, the rest at the spread subset
            # of vertices the frame at rest gathers them at, interpolated (ShapeShading.sub), as at rest
            kn, corners, _, rad = near_light
            sunny = np.abs(sun_dB[kn]).sum(1) > 0 if sun_dB is not None else np.zeros(len(kn), bool)
            for part, rows in ((~sunny, ss.sub), (sunny, ds.all_rows)):
                if not part.any():
                    continue
                w = None
                if part is sunny and w_em is not None:
                    # the sun's loss on an emitter patch (a sunlit floor patch in the object's shadow) seen past the
                    # room as that patch's emitter group is: the two nearly cancel, and the same visibility on both
                    # keeps their difference's error the difference's, not the larger terms'
                    g_k = self.emitter_group_of()[kn[part]]
                    w = np.where(g_k[None] >= 0, w_em[:, np.maximum(g_k, 0)], 1.0)
                E_near = gather_seen(vg[rows], nu[rows], rows, ds.vis_on(self.device), corners[part], rad[part], R,
                                     VIS_RES, self.device, self._ws.get(f"drag.near_ff.{part is sunny}"), self._split,
                                     capacity=DB_MAX, weights=w)
                if part is not sunny:
                    E_near = ss.interpolate(E_near)
                E += E_near
                E_proxy += E_near
        # ---- the sun: cos x the object's own shadow (per shape and direction) x the room's at the probes
        E_sun = None
        sun_vis = None
        if osh.sun is not None:
            # the room's shadow: the share of the sun's disk the openings pass, per vertex and exact (a plane and a
            # quad's edges each, no ray: SunLight.disk_through; an estimated sun's centre alone, 0 or 1), times what
            # else of the room blocks it, seen at the probes (a ray each) and interpolated (1 at a probe whose ray
            # leaves through no opening)
            d = osh.sun.d
            through = osh.sun.disk_through(vu)
            probe_sun = osh.sun.visibility(probes, np.broadcast_to(d, probes.shape).copy())
            probe_open = np.isfinite(osh.sun.exit_distance(probes))
            blocked = np.where(probe_open, probe_sun, 1.0)
            room_u = ds.weights @ blocked  # (U,) what else of the room leaves of the sun
            share = np.maximum(nu @ d, 0.0) * ds.sun_self_lit(R.T @ d) * through * room_u
            E_sun = share[:, None] * (osh.sun.sun.irradiance / np.pi)
            sun_vis = share[ss.inv]
        albedo = obj.albedo
        L_room = albedo * np.maximum(E, 0.0)[ss.inv]
        L_proxy = ds.fill @ (albedo * np.maximum(E_proxy, 0.0)[ss.inv])
        L_sun = albedo * E_sun[ss.inv] if E_sun is not None else None  # each vertex's own sun
        L_vert = vertex_light(L_room, L_sun, ds.fill.__matmul__, ss.bounce, albedo)  # as at rest
        add = colour = None
        if L_sun is not None and hits.hit.any():  # the sun per camera hit (its edge across a face: one launch,
            # kernels.hit_average.SunAtHits), the rest blended from the vertices
            d_local = R.T @ d
            e1, e2, lo, texel, top, _ = ds.sun_map(d_local)
            add = SunAtHits(v, n, room_u[ss.inv], d, self._exits(osh.sun), mean, R, e1, e2, lo, texel, top,
                            d_local / np.linalg.norm(d_local), ds.sun_map_on(d_local, self.device), osh.sun.tan_a)
            colour = albedo * (osh.sun.sun.irradiance / np.pi)
        radiance = hit_average(hits, f, L_vert - L_sun if L_sun is not None else L_vert, add, colour, self.device,
                               self._ws.get("drag.hits"), self._radiance)
        shaded = ShadedObject(radiance, L_vert, sun_vis)
        self.last = DragShaded(shaded, L_sun, L_proxy + L_sun if L_sun is not None else L_proxy)
        return self.last

    def proxy_radiance(self, pv: np.ndarray, pf: np.ndarray, L_vert: np.ndarray, L_sun: np.ndarray | None
                       ) -> tuple[np.ndarray, np.ndarray | None]:
        """(the room's part of each proxy triangle's radiance (T,3), the sun's part (T,3) or None) for the frame's
        proxy (pv (Tv,3) at the last shaded pose, pf (T,3)) from the shaded vertex radiance: no rays."""
        ds = self._shape[1]
        _, R, mean = self._pose
        M = ds.to_proxy((pv - mean) @ R, pf)
        tri = M @ L_vert
        tri_sun = M @ L_sun if L_sun is not None else None
        # a triangle facing a room surface closer than its own size (a foot's sole, a sphere's bottom on the floor)
        # sees mostly the dark contact under it, which its vertices' SH light does not resolve: its light is
        # scaled by that distance over its size (one ray along its normal; 0 at contact, whole from its size on)
        t = pv[pf]
        nt = cross3(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
        size = np.sqrt(0.5 * np.linalg.norm(nt, axis=1))
        nt /= np.maximum(2.0 * size[:, None] ** 2, 1e-18)
        _, _, depth = cast_rays(self.shading.scene_occ, t.mean(1) + nt * 1e-4, nt,
                                workspace=self._ws.get("drag.contact"))
        k = np.minimum(np.maximum(depth.astype(np.float64), 0.0) / np.maximum(size, 1e-9), 1.0)[:, None]
        tri = tri * k
        tri_sun = tri_sun * k if tri_sun is not None else None
        return (tri - tri_sun if tri_sun is not None else tri), tri_sun
