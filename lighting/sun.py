"""Direct sunlight through openings: the sunlit region, sun irradiance, and its share of radiosity.

The sun (recon.scene.Sun) is a far disk of angular diameter ~0.53 deg. Its direct light at a point p
with normal n is, in irradiance/pi (the units of the rest of photoar: the radiance a white
Lambertian surface would reflect):

    E_sun(p) = E_perp / pi * max(n . d, 0) * V(p)

d = direction_to_sun, E_perp = irradiance_perpendicular, V = 1 when the ray p -> sun leaves the
room through an opening quad before hitting anything solid (the scene model; optionally the object).
Rays are parallel: the sun's finite distance moves its direction by < 0.1 deg inside a room. The
0.53 deg disk only matters for penumbrae, which kernels.sunshadow handles.

A sun below the horizon (d_y <= 0: the ground outside hides it), a scene without openings, or a sun
whose rays miss every opening give zero direct light everywhere, with a warning, never NaN.
"""
from __future__ import annotations

import logging
import threading

import numpy as np

from kernels.raycast import cast_rays
from kernels.sunshadow import HitSun, SunVisibility
from kernels.visibility import Occluder
from recon.scene import Quad, Scene, Sun

log = logging.getLogger("photoar")


NO_OPENING = 'the scene has no opening (window with "opening": true): no direct sun'  # the warning's words,
# under known light (SunLight) and captured light (app.engine) alike


def openings(scene: Scene) -> list[Quad]:
    """The scene's opening quads (windows that are holes in their wall)."""
    return [q for q in scene.quads if q.opening]


def gather_with_sun(G: np.ndarray, albedo: np.ndarray, emission: np.ndarray, sun_direct: np.ndarray,
                    bounces: int) -> list[np.ndarray]:
    """Radiosity iterates [B^(0) .. B^(bounces)] (each (P,3)) with the sun as one more emitter.

    sun_direct (P,3) = the sun's direct irradiance/pi on each patch. The sun's disk is B^(0) (not
    a patch), so its reflection rho * sun_direct enters from B^(1) on, one bounce like any emitter's:
    B^(k) = E + rho * (sun_direct + G @ B^(k-1)) (lighting.radiosity.gather with one more source).
    """
    if G.shape[0] != G.shape[1] or G.shape[0] != len(albedo) or len(sun_direct) != len(albedo):
        raise ValueError(f"transfer matrix {G.shape} / sun light {np.shape(sun_direct)} do not match "
                         f"{len(albedo)} patches")
    G64 = G.astype(np.float64)
    B = [np.asarray(emission, np.float64)]
    for _ in range(bounces):
        B.append(emission + albedo * (sun_direct + G64 @ B[-1]))
    return B


def no_sun_reason(direction: np.ndarray, irradiance: np.ndarray, opening_normals: list[np.ndarray],
                  where: str = "sun") -> str:
    """Why a sun (unit `direction` towards it, world +Y up; RGB `irradiance` on a surface facing it) can
    light nothing through openings whose room-side normals are `opening_normals`: below the horizon,
    no opening, no light, or every opening faces away (its rays cannot enter); "" when it may light
    the room. SunLight's test, shared with `photoar scene`'s warnings."""
    d = np.asarray(direction, np.float64)
    if d[1] <= 0.0:
        return f"{where}: the sun is below the horizon (direction_to_sun y = {d[1]:.3g}): no direct sun"
    if not len(opening_normals):
        return f"{where}: {NO_OPENING}"
    if not np.any(np.asarray(irradiance) > 0):
        return f"{where}: irradiance_perpendicular is zero: no direct sun"
    if not any(np.dot(n, d) < -1e-9 for n in opening_normals):
        return f"{where}: the sun is parallel to or behind every opening: no direct sun"
    return ""


FLAT_COS = 1.0 - 1e-7  # corner normals of a face this close (cosine; ~0.03 deg apart) make it flat for
# SunLight.hit_correction: on a wholly sunlit flat face the per-hit sun and the corners' blend differ by less
# than 1 / FLAT_COS - 1 ~ 1e-7 of irradiance/pi (the blend's own float32 barycentric rounding)


def _half_plane_share(u: np.ndarray) -> np.ndarray:
    """Share of a uniform disk on the inner side of a line u disk radii from its centre (kernels.sunshadow's)."""
    u = np.clip(u, -1.0, 1.0)
    return (np.pi - np.arccos(u) + u * np.sqrt(1.0 - u * u)) / np.pi


class SunLight:
    """The scene's sun seen through its openings, against the scene model's solid surfaces."""

    def __init__(self, sun: Sun, holes: list[Quad], occluder: Occluder, where: str = "sun", disk: bool = True):
        """`where` starts the warning when the sun lights nothing: "<scene.json>: sun" (the CLI's log
        prefixes "photoar: warning: "). disk: the object's sun through the openings is the share of the sun's
        disk they pass (tan_a; their edges' penumbra); False: its centre's ray alone (tan_a 0), for a direction
        fitted with that hard edge to the photo's sunlit outline (estimate_sun), which already stands part of
        the penumbra out."""
        self.sun = sun
        self.disk = disk
        self.where = where
        self.d = np.asarray(sun.direction, np.float64) / np.linalg.norm(sun.direction)
        self.openings = list(holes)
        self.occluder = occluder
        self.device = occluder.device
        self.reason = ""
        self._flat: tuple | None = None  # (n, f, flat faces) of hit_correction's last mesh (_flat_faces)
        self._hit_sun: HitSun | None = None  # hit_correction's launch (made on its first call)
        # exit_distance's openings that the sun enters through: (corner c0, normal, 1 / -(d . normal) 1/m,
        # (3,2) the edges U, V from c0 over their squared lengths 1/m); parallel ones or backs: no passage
        self._exits = []
        for q in self.openings:
            denom = float(np.dot(self.d, q.normal))
            if denom < -1e-9:
                c0 = np.asarray(q.corners[0], np.float64)
                U, V = q.corners[1] - c0, q.corners[3] - c0
                self._exits.append((c0, np.asarray(q.normal, np.float64), 1.0 / -denom,
                                    np.stack([U / (U @ U), V / (V @ V)], 1)))
        self._vis = SunVisibility(self.device, self._exits, self.d)  # visibility's launch and buffers, kept from
        # call to call (not shared between threads: one caller at a time)
        self.reason = no_sun_reason(self.d, sun.irradiance, [q.normal for q in self.openings], where)
        if self.reason:
            log.warning("%s", self.reason)

    @property
    def tan_a(self) -> float:
        """tan of the sun disk's angular radius (the openings' penumbra on the object: visibility(disk=True),
        hit_correction)."""
        return float(np.tan(self.sun.half_angle)) if self.disk else 0.0

    @property
    def entries(self) -> list:
        """The openings the sun enters through, as the launches toward the sun take them (kernels.sunshadow
        .exit_arrays): [(corner (3,), normal (3,), 1 / -(d . normal), (3,2) edges over their squared
        lengths)]; none when the sun is not active (no ray then leaves the room)."""
        return self._exits if self.active else []

    @property
    def active(self) -> bool:
        """False when the sun cannot light anything (see `reason`)."""
        return not self.reason

    def exit_distance(self, points: np.ndarray) -> np.ndarray:
        """Distance (N,) m along d from each point to the first opening it leaves through (inf: none)."""
        p = np.asarray(points, np.float64)
        best = np.full(len(p), np.inf)
        for c0, nrm, inv_denom, UV in self._exits:
            pc = p - c0
            t = pc @ nrm
            t *= inv_denom
            pc += t[:, None] * self.d  # the hit point, from c0
            uv = pc @ UV  # (N,2): its place along the edges U and V, in their lengths
            ok = (t > 0) & (uv[:, 0] >= 0) & (uv[:, 0] <= 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= 1) & (t < best)
            best[ok] = t[ok]
        return best

    def disk_through(self, points: np.ndarray) -> np.ndarray:
        """(N,) float64: the share of the sun's disk each point sees through the openings (the edges' penumbra,
        kernels.sunshadow._disk_share's arithmetic in numpy: each opening's four edges' circular-segment shares
        multiplied, the openings' summed, at most 1), no ray past the room; 0 where the sun is not active."""
        p = np.asarray(points, np.float64).reshape(-1, 3)
        total = np.zeros(len(p))
        for c0, nrm, inv_denom, UV in self.entries:
            pc = p - c0
            t = (pc @ nrm) * inv_denom
            h = pc + t[:, None] * self.d
            share = np.where(t > 0, 1.0, 0.0)
            for k in range(2):
                a = UV[:, k]
                la = np.linalg.norm(a)  # 1 / the edge's length
                g = a / la - nrm * (self.d @ (a / la)) / (-1.0 / inv_denom)
                r = np.where(t > 0, t, 1.0) * (self.tan_a * np.linalg.norm(g) * la)  # the footprint's half-width,
                x = h @ a  # the centre's place along the edge; both in edge lengths (0..1 inside)
                if self.tan_a > 0:
                    share = share * _half_plane_share(x / r) * _half_plane_share((1.0 - x) / r)
                else:  # the centre's exit (exit_distance's test)
                    share = share * ((x >= 0) & (x <= 1))
            total += share
        return np.minimum(total, 1.0)

    def visibility(self, points: np.ndarray, normals: np.ndarray, extra: list[Occluder] = (),
                   eps: float = 1e-3, disk: bool = False) -> np.ndarray:
        """(N,) float: max(n.d, 0) x [sun's centre seen through an opening, unblocked]; disk: x the share of
        the sun's disk the openings pass in place of its centre's 0 or 1 (their edges' penumbra; the meshes'
        shadows stay the centre's: kernels.sunshadow._sun_soft)."""
        p = np.asarray(points, np.float64)
        n = np.asarray(normals, np.float64)
        if not self.active or len(p) == 0:
            return np.zeros(len(p))
        # the cos, the exit through an opening and the ray past the room and the object in one launch
        # (kernels.sunshadow.SunVisibility); split over the cores for many points, not from inside a pooled launch
        pooled = threading.current_thread().name.startswith("photoar")
        return self._vis(p, n, self.mesh_ids(extra), eps, parallel=not pooled, tan_a=self.tan_a if disk else 0.0)

    def mesh_ids(self, extra: list[Occluder] = ()) -> list[int]:
        """The Warp mesh ids a ray toward the sun must pass: the room's and those of `extra` (e.g. the object)."""
        return [o.id for o in (self.occluder, *extra) if o is not None and o.id != 0]

    def irradiance(self, points: np.ndarray, normals: np.ndarray, extra: list[Occluder] = ()) -> np.ndarray:
        """Direct sun irradiance/pi (N,3) at points with normals."""
        return self.visibility(points, normals, extra)[:, None] * (self.sun.irradiance / np.pi)

    def irradiance_on_mesh(self, points: np.ndarray, normals: np.ndarray, corner_lit: np.ndarray,
                           extra: list[Occluder] = (), disk: bool = False) -> np.ndarray:
        """Direct sun irradiance/pi (N,3) at points (N,3) on a mesh's faces whose corners' sun is known:
        corner_lit (N,3) bool, True where a corner of the point's face sees the sun. A face with all three
        corners in the sun is taken as wholly lit and one with none as wholly dark (no ray: n.d alone);
        the points of faces in between, where a shadow's edge crosses, are tested (irradiance). A shadow
        narrower than the mesh's edges that crosses a face without reaching a corner is missed. disk: the share
        of the sun's disk the openings pass, on the wholly lit faces too (from 1 mm along the normal: hit_correction's
        reference)."""
        n_lit = np.asarray(corner_lit).sum(1)
        nrm = np.asarray(normals, np.float64)
        cos = np.maximum(nrm @ self.d, 0.0)
        vis = np.where(n_lit == 3, cos, 0.0)
        if disk and self.tan_a > 0:
            vis = vis * np.where(n_lit == 3, self.disk_through(np.asarray(points, np.float64) + 1e-3 * nrm), 1.0)
        mixed = np.flatnonzero((n_lit > 0) & (n_lit < 3))
        if len(mixed):
            vis[mixed] = self.visibility(np.asarray(points)[mixed], nrm[mixed], extra, disk=disk)
        return vis[:, None] * (self.sun.irradiance / np.pi)

    def hit_correction(self, v: np.ndarray, n: np.ndarray, f: np.ndarray, vis_v: np.ndarray, tri: np.ndarray,
                       bary: np.ndarray, extra: list[Occluder] = (), groups: np.ndarray | None = None
                       ) -> tuple[np.ndarray, np.ndarray]:
        """The sun per camera hit on a mesh (v (V,3), unit vertex normals n (V,3), faces f (F,3)) against the
        blend of its vertices' sun that the hit's radiance holds: (k (K,), the hits (tri (M,), bary (M,3))
        on faces with a sunlit corner; delta (K,), their sun minus that blend, as a share of
        irradiance/pi (x sun.irradiance / pi: the irradiance/pi to add)). vis_v (V,): each vertex's sun
        share (cos x visibility, 0 in shadow). The hit's sun is irradiance_on_mesh's: cos of the
        interpolated normal on a face with all corners sunlit, a ray (visibility, past the room and
        `extra`) on a face that a shadow's edge crosses; faces with no sunlit corner have both 0, and
        so, to within 1 / FLAT_COS - 1, have wholly sunlit flat faces (corner normals equal): neither
        is in k. groups: as hit_codes. The openings' penumbra: the hit's sun is the share of the sun's disk
        they pass (visibility(disk=True); flat faces wholly lit keep their corners' blend, which holds it)."""
        code = self.hit_codes(n, f, vis_v, groups)
        ch = code[tri]
        k = np.flatnonzero(ch)
        if len(k) == 0:
            return k, np.zeros(0)
        # per hit, one launch (kernels.sunshadow.HitSun): the interpolated normal's cos on a wholly lit face,
        # a ray toward the sun (past the room and `extra`) on a face that a shadow's edge crosses
        if self._hit_sun is None:
            self._hit_sun = HitSun(self.device, self.entries, self.d)
        pooled = threading.current_thread().name.startswith("photoar")
        delta = self._hit_sun(v, n, f, vis_v, code, tri[k], bary[k], self.mesh_ids(extra), 1e-3,
                              rays=int(np.count_nonzero(ch[k] == 2)), parallel=not pooled, tan_a=self.tan_a)
        return k, delta

    def hit_codes(self, n: np.ndarray, f: np.ndarray, vis_v: np.ndarray, groups: np.ndarray | None = None
                  ) -> np.ndarray:
        """(F,) uint8: what hit_correction does on each face f (F,3) of a mesh (unit vertex normals n (V,3),
        the vertices' sun shares vis_v (V,)): 0 nothing (no sunlit corner, or all sunlit and flat: a hit's
        sun is its corners' blend to within 1 / FLAT_COS - 1), 1 the interpolated normal's cos (all
        corners sunlit, not flat), 2 a ray toward the sun (a shadow's edge crosses the face). groups (F,) int:
        the face each one was cut from (app.stages.own_cuts; None: none cut): a piece with no sunlit corner of its
        own gets rays where another piece of its face has one (the sun's edge may pass between the cut's new
        corners, which lie in shadow at a contact line, as it passed across the whole face)."""
        lit_f = (vis_v > 0)[f].sum(1)  # sunlit corners per face
        if groups is not None:
            lit_g = np.bincount(groups, weights=lit_f, minlength=int(groups.max()) + 1) > 0
            lit_f = np.where((lit_f == 0) & lit_g[groups], 1, lit_f)
        return np.where(lit_f == 3, np.where(self._flat_faces(n, f), 0, 1), np.where(lit_f > 0, 2, 0)).astype(np.uint8)

    def _flat_faces(self, n: np.ndarray, f: np.ndarray) -> np.ndarray:
        """(F,) bool: the faces f (F,3) whose corner normals (n (V,3), unit) agree within FLAT_COS, kept for
        the last (n, f) pair given (a shape's shading mesh: the same arrays every frame of that shape)."""
        c = self._flat
        if c is None or c[0] is not n or c[1] is not f:
            nf = n[f]  # (F,3,3)
            agree = np.minimum(np.minimum(np.einsum("fc,fc->f", nf[:, 0], nf[:, 1]),
                                          np.einsum("fc,fc->f", nf[:, 1], nf[:, 2])),
                               np.einsum("fc,fc->f", nf[:, 0], nf[:, 2]))
            c = self._flat = (n, f, agree >= FLAT_COS)
        return c[2]

    def triangle_irradiance(self, tris: np.ndarray, extra: list[Occluder] = (), n: int = 6) -> np.ndarray:
        """Mean direct sun irradiance/pi (T,3) over triangles (T,3,3) (CCW seen from the lit side),
        from n(n+1)/2 barycentric points each: a face half in its own shadow gets half."""
        tris = np.asarray(tris, np.float64)
        nt = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
        nt /= np.maximum(np.linalg.norm(nt, axis=1, keepdims=True), 1e-12)
        bary = np.array([(i + 1 / 3, j + 1 / 3) for i in range(n) for j in range(n - i)]) / n
        w = np.stack([1 - bary.sum(1), bary[:, 0], bary[:, 1]], 1)  # (K,3)
        pts = np.einsum("kc,tcx->tkx", w, tris).reshape(-1, 3)
        vis = self.visibility(pts, np.repeat(nt, len(w), axis=0), extra).reshape(len(tris), len(w)).mean(1)
        return vis[:, None] * (self.sun.irradiance / np.pi)

    def sunlit_elements(self, tris: np.ndarray, extra: list[Occluder] = (), size: float = 0.05,
                        max_split: int = 12, n: int = 2) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The sunlit parts of an emitting surface (triangles (T,3,3), CCW seen from the lit side) as
        small triangles: (sub-triangles (S,3,3), their mean direct sun irradiance/pi (S,3)), only the
        lit ones. Each triangle is split regularly into m^2 pieces, m = ceil(longest edge / size)
        (at most max_split); each piece's irradiance is the mean over n(n+1)/2 points. Also returns
        the index (S,) of the triangle each piece comes from.

        Why: light a sunlit object throws onto the room has sharp structure on its faces (its own
        shadows, e.g. a seat's over its legs). Emitted as whole faces with their mean sun and one
        visibility test each (kernels.visibility.emitter_sum), a floor point beside a chair got
        0.3x-1.8x the light of a dense Monte Carlo reference; the pieces keep both the lit part's
        position and partial visibility."""
        tris = np.asarray(tris, np.float64)
        if not self.active or len(tris) == 0:
            return np.zeros((0, 3, 3)), np.zeros((0, 3)), np.zeros(0, np.int64)
        sub, parent = _sun_facing_pieces(tris, self.d, size, max_split)
        E = self.triangle_irradiance(sub, extra, n=n)
        lit = np.flatnonzero(E.any(1))
        return sub[lit], E[lit], parent[lit]

    def patch_irradiance(self, corners: np.ndarray, normals: np.ndarray, solid: np.ndarray,
                         n_side: int = 6) -> np.ndarray:
        """Mean direct sun irradiance/pi (P,3) over each patch (corners (P,4,3)), from n_side^2
        stratified points; zero on patches where `solid` is False (emitters)."""
        P = len(corners)
        out = np.zeros((P, 3))
        if not self.active:
            return out
        idx = np.flatnonzero(solid & (normals @ self.d > 0))
        f = (np.arange(n_side) + 0.5) / n_side
        fu, fv = [a.ravel() for a in np.meshgrid(f, f)]
        c0 = corners[idx, 0]
        U, V = corners[idx, 1] - c0, corners[idx, 3] - c0
        pts = c0[:, None] + fu[None, :, None] * U[:, None] + fv[None, :, None] * V[:, None]
        nrm = np.repeat(normals[idx], len(fu), axis=0)
        vis = self.visibility(pts.reshape(-1, 3), nrm).reshape(len(idx), len(fu)).mean(1)
        out[idx] = vis[:, None] * (self.sun.irradiance / np.pi)
        if not out.any():
            self.reason = f"{self.where}: its rays miss every opening or reach no surface: no direct sun"
            log.warning("%s", self.reason)
        return out


class SunlitPieces:
    """The sun-facing faces of one object shape split into small pieces once, in object space, with
    the object's own shadow on them; per frame only the room's part of the sun (openings, walls)
    is tested (issue 20: the frame's cost of the sunlit object's light).

    Each sun-facing triangle (T,3,3) is split regularly into m^2 pieces, m = ceil(longest edge /
    size) (at most max_split); each piece carries n(n+1)/2 barycentric sample points. A translation
    changes neither the pieces nor the object's shadow on them (the sun's rays are parallel), so
    both are kept per shape and moved with the object (`offset`). Pieces hold `parent` (S,) (the
    index of their triangle), `area` (S,) m^2, `self_lit` (S,K) bool (sample points the object itself
    leaves in the sun)."""

    def __init__(self, light: "SunLight", tris: np.ndarray, own: Occluder | None, size: float,
                 max_split: int = 12, n: int = 2, eps: float = 1e-3):
        tris = np.asarray(tris, np.float64)
        self.light = light
        self.origin = tris.reshape(-1, 3).mean(0) if len(tris) else np.zeros(3)
        nt = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]) if len(tris) else np.zeros((0, 3))
        sub, self.parent = (_sun_facing_pieces(tris, light.d, size, max_split) if light.active and len(tris)
                            else (np.zeros((0, 3, 3)), np.zeros(0, np.int64)))
        self.tris0 = sub - self.origin  # (S,3,3) relative to the shape's origin
        nrm = nt[self.parent] if len(self.parent) else np.zeros((0, 3))
        self.area = 0.5 * np.linalg.norm(nrm, axis=1) / np.maximum(
            np.bincount(self.parent, minlength=len(tris))[self.parent], 1) if len(self.parent) else np.zeros(0)
        self.normal = nrm / np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-12)
        self.cos = self.normal @ light.d
        bary = np.array([(i + 1 / 3, j + 1 / 3) for i in range(n) for j in range(n - i)]) / n
        w = np.stack([1 - bary.sum(1), bary[:, 0], bary[:, 1]], 1)  # (K,3)
        self.k = len(w)
        self.pts0 = (np.einsum("kc,scx->skx", w, self.tris0) + self.normal[:, None] * eps).reshape(-1, 3)
        self.self_lit = np.ones((len(sub), self.k), bool)
        if own is not None and own.id != 0 and len(sub):
            _, _, depth = cast_rays(own, self.pts0 + self.origin, np.broadcast_to(light.d, self.pts0.shape))
            self.self_lit = ~np.isfinite(depth).reshape(len(sub), self.k)
        self._room = np.zeros(len(self.pts0), bool)
        self._start = np.zeros_like(self.pts0)
        self._cand = np.flatnonzero(self.self_lit.ravel())  # points the object leaves in the sun
        self._cand_nrm = np.repeat(self.normal, self.k, axis=0)[self._cand]

    def __len__(self) -> int:
        return len(self.parent)

    def tris(self, origin: np.ndarray) -> np.ndarray:
        """The pieces (S,3,3) with the shape's origin at `origin` (3,)."""
        return self.tris0 + origin

    def lit_share(self, origin: np.ndarray) -> np.ndarray:
        """(S,) the share of each piece's sample points in the sun with the shape's origin at
        `origin`: the object's own shadow (per shape) and the room's (openings, walls; per frame)."""
        if len(self.parent) == 0:
            return np.zeros(0)
        np.add(self.pts0, origin, out=self._start)
        self._room[:] = False
        c = self._cand
        self._room[c] = self.light.visibility(self._start[c], self._cand_nrm, eps=0.0) > 0
        return self._room.reshape(len(self.parent), self.k).mean(1)


_SPLIT_CACHE: dict[int, np.ndarray] = {}  # m -> barycentric corners of the m^2 pieces


def _sun_facing_pieces(tris: np.ndarray, d: np.ndarray, size: float, max_split: int
                       ) -> tuple[np.ndarray, np.ndarray]:
    """The triangles (T,3,3) (CCW seen from their front) whose front faces the sun direction d, each
    split regularly into m^2 pieces, m = ceil(longest edge / size) clipped to 1..max_split:
    (pieces (S,3,3), index (S,) of the triangle each comes from). Faces turned from the sun get no
    direct sun, so they have no pieces."""
    nt = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    facing = np.flatnonzero(nt @ d > 0)
    f_tris = tris[facing]
    edge = np.linalg.norm(f_tris - np.roll(f_tris, 1, axis=1), axis=2).max(1) if len(facing) else np.zeros(0)
    m_all = np.clip(np.ceil(edge / size).astype(int), 1, max_split)
    pieces, parent = [np.zeros((0, 3, 3))], [np.zeros(0, np.int64)]
    for m in np.unique(m_all):
        sel = np.flatnonzero(m_all == m)
        pieces.append(_split_triangles(f_tris[sel], int(m)))
        parent.append(np.repeat(facing[sel], int(m) ** 2))
    return np.concatenate(pieces), np.concatenate(parent)


def _split_triangles(tris: np.ndarray, m: int) -> np.ndarray:
    """Each triangle (T,3,3) split regularly into m^2 congruent pieces (T*m^2,3,3), same winding."""
    if m not in _SPLIT_CACHE:
        up = [((i, j), (i + 1, j), (i, j + 1)) for i in range(m) for j in range(m - i)]
        down = [((i + 1, j), (i + 1, j + 1), (i, j + 1)) for i in range(m) for j in range(m - i - 1)]
        ij = np.array(up + down, np.float64) / m  # (m^2, 3 corners, (b1, b2))
        _SPLIT_CACHE[m] = ij
    ij = _SPLIT_CACHE[m]
    w = np.stack([1.0 - ij[..., 0] - ij[..., 1], ij[..., 0], ij[..., 1]], -1)  # (m^2,3,3) barycentric
    return np.einsum("kcw,twx->tkcx", w, tris).reshape(-1, 3, 3)


def surface_albedo(scene: Scene, quad: np.ndarray, points: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    """Linear albedo (N,3) at surface points on quads `quad` (indices into scene.quads): the texel
    under each point where the quad has a texture, else `fallback` (N,3) (e.g. the patch mean)."""
    out = np.array(fallback, np.float64, copy=True)
    for qi in np.unique(quad):
        if qi < 0:
            continue
        q = scene.quads[int(qi)]
        if q.texture is None:
            continue
        sel = np.flatnonzero(quad == qi)
        c0 = q.corners[0]
        U, V = q.corners[1] - c0, q.corners[3] - c0
        a = (points[sel] - c0) @ U / (U @ U)
        b = (points[sel] - c0) @ V / (V @ V)
        ht, wt = q.texture.shape[:2]
        col = np.clip(np.floor(a * wt).astype(int), 0, wt - 1)
        row = np.clip(np.floor(b * ht).astype(int), 0, ht - 1)
        out[sel] = q.texture[row, col]
    return out


# ----------------------------------------------------------------------------- captured light
SUN_DIAMETER_DEG = 0.53  # the sun's mean apparent diameter seen from the earth (a constant of nature)


# Otsu's separation of a single-humped distribution is at most the uniform one's: split at its
# middle, the class means lie half the range apart and each class's spread is (range / 2) / sqrt(12),
# so (m1 - m0) / spread = 2 sqrt(3). A sun edge makes two humps, separated by more.
UNIMODAL_SEPARATION = 2.0 * np.sqrt(3.0)
DENOISE_PX = 5  # median window (px) of sunlit_pixels: a sun patch is many pixels across, pixel noise is not


def sunlit_pixels(L_b: np.ndarray, saturated: np.ndarray, pix_quad: np.ndarray, recv: np.ndarray,
                  min_ratio: float = 3.0, shape: tuple[int, int] | None = None) -> np.ndarray:
    """(N,) bool: receiver pixels lit by the sun in the photo. Per quad, saturated pixels, and pixels
    above the Otsu split of the quad's log-luminance when the bright class is at least `min_ratio`
    times the dark one (direct sun is many times the sky's light) and the two classes are two humps:
    their means further apart than UNIMODAL_SEPARATION x their pooled spread (a smooth gradient or
    plain noise is one hump and is not split).

    With `shape` (H, W) (N = H W, pixels in image order) the log-luminance is first median-filtered
    over DENOISE_PX x DENOISE_PX pixels: a noisy photo (a few spp render, grain, a pixel at level 0)
    has per-pixel outliers that would become Otsu's dark class on their own; a sun patch, many
    pixels across, keeps its edge through a median."""
    from scipy.ndimage import median_filter

    from lighting.sources import luminance

    out = np.zeros(len(L_b), bool)
    lum = np.log(np.maximum(luminance(L_b), 1e-9))
    if shape is not None and shape[0] * shape[1] == len(lum):
        lum = median_filter(lum.reshape(shape), size=DENOISE_PX, mode="nearest").ravel()
    for q in np.unique(pix_quad[recv]):
        idx = np.flatnonzero(recv & (pix_quad == q))
        if len(idx) < 50:
            continue
        v = lum[idx]
        order = np.sort(v)
        c = np.cumsum(order)
        k = np.arange(1, len(v))
        m0 = c[:-1] / k
        m1 = (c[-1] - c[:-1]) / (len(v) - k)
        between = k * (len(v) - k) * (m1 - m0) ** 2
        i = int(np.argmax(between))
        bright = v > order[i]
        if bright.all() or not bright.any():
            continue
        spread = np.sqrt(0.5 * (v[bright].var() + v[~bright].var()))
        if np.exp(m1[i] - m0[i]) >= min_ratio and m1[i] - m0[i] > UNIMODAL_SEPARATION * spread:
            out[idx[bright]] = True
    out |= saturated & recv
    return out


def estimate_sun(scene: Scene, pm, pix_patch: np.ndarray, pix_pos: np.ndarray, dirs: np.ndarray,
                 L_b: np.ndarray, saturated: np.ndarray, recv: np.ndarray, B: np.ndarray, G_c: np.ndarray,
                 occluder: Occluder, min_overlap: float = 0.5, direction: np.ndarray | None = None,
                 bounces: int | None = None, levels: np.ndarray | None = None) -> tuple[Sun | None, dict]:
    """The sun from the photo and the captured radiance mesh (no declared sun used); with `direction`
    (a known unit vector towards the sun, e.g. from date, time and place) only its strength.

    Direction: the sunlit patch on a plane is the opening projected along d, so the area-weighted
    centroid of the sunlit pixels of the largest lit plane is the opening's centroid moved along
    -d; then (azimuth, elevation) are refined by maximising the overlap of the predicted sunlit pixels
    with the observed ones (Nelder-Mead). Strength: on fully sunlit patches the radiance is
    rho (E_ind + E_perp cos / pi); rho is the reflectivity of the unlit patches of the same quad
    (the same material), E_ind the gathered irradiance of the radiance mesh (the probe sees the patch
    unclipped where the photo clips), so E_perp = pi (L / rho - E_ind) / cos, median over patches;
    with `bounces` (those the camera sees) E_ind is taken one bounce less than B (_sun_strength).
    No sun (None, with info["reason"]) when nothing is lit, or when the best direction's predicted
    sunlit pixels overlap the observed ones less than `min_overlap` (intersection over union).
    Returns (Sun or None, info)."""
    from scipy.optimize import minimize

    from lighting.sources import luminance

    holes = openings(scene)
    info: dict = {}
    if not holes:
        return None, {"reason": "no opening"}
    if direction is not None:
        d = np.asarray(direction, np.float64) / np.linalg.norm(direction)
        info.update(direction=d.tolist(), direction_from="declared")
        return _sun_strength(d, holes, occluder, pm, B, G_c, info, bounces, levels)
    pix_quad = np.where(pix_patch >= 0, pm.quad[np.maximum(pix_patch, 0)], -1)
    lit = sunlit_pixels(L_b, saturated, pix_quad, recv, shape=scene.photo.shape[:2])
    if lit.sum() < 50:
        return None, {"reason": "no sunlit region in the photo"}
    nrm = pm.normal[np.maximum(pix_patch, 0)]
    # surface area per pixel ~ depth^2 / |cos(view, normal)|
    depth = np.linalg.norm(pix_pos - scene.camera.centre, axis=1)
    area = depth ** 2 / np.maximum(np.abs(np.einsum("nc,nc->n", dirs, nrm)), 0.05)
    quads, counts = np.unique(pix_quad[lit], return_counts=True)
    main = quads[np.argmax([area[lit & (pix_quad == q)].sum() for q in quads])]
    sel = lit & (pix_quad == main)
    c_patch = (pix_pos[sel] * area[sel, None]).sum(0) / area[sel].sum()
    cand = []
    for q in holes:
        d = q.corners.mean(0) - c_patch
        d /= np.linalg.norm(d)
        if d @ q.normal < 0 and d[1] > 0:
            cand.append(d)
    if not cand:
        return None, {"reason": "the sunlit region is not in view of an opening"}
    # overlap refinement on pixels near the lit region (on every receiver surface)
    near = recv.copy()
    test = np.flatnonzero(near)
    test = test[:: max(1, len(test) // 60000)]
    observed = lit[test]

    def sun_of(a):
        az, el = a
        return np.array([np.cos(el) * np.cos(az), np.sin(el), np.cos(el) * np.sin(az)])

    def cost(a):
        light = SunLight(Sun(sun_of(a), SUN_DIAMETER_DEG, np.ones(3), np.zeros(3)), holes, occluder,
                         where="sun estimate")
        pred = light.visibility(pix_pos[test], nrm[test]) > 0
        return 1.0 - (pred & observed).sum() / max((pred | observed).sum(), 1)

    best = None
    for d in cand:
        a0 = np.array([np.arctan2(d[2], d[0]), np.arcsin(np.clip(d[1], -1, 1))])
        res = minimize(cost, a0, method="Nelder-Mead",
                       options={"initial_simplex": [a0, a0 + [0.02, 0], a0 + [0, 0.02]], "xatol": 1e-4,
                                "fatol": 1e-5, "maxiter": 80})
        if best is None or res.fun < best[1]:
            best = (res.x, res.fun, a0)
    d = sun_of(best[0])
    info.update(direction=d.tolist(), direction_from_centroid=sun_of(best[2]).tolist(), overlap=float(1.0 - best[1]))
    if info["overlap"] < min_overlap:  # bright surfaces that no sun through the openings explains
        return None, {**info, "reason": f"no sun direction explains the bright region (overlap "
                                        f"{info['overlap']:.2f} < {min_overlap})"}
    return _sun_strength(d, holes, occluder, pm, B, G_c, info, bounces, levels)


def _sun_strength(d: np.ndarray, holes: list[Quad], occluder: Occluder, pm, B: np.ndarray, G_c: np.ndarray,
                  info: dict, bounces: int | None = None, levels: np.ndarray | None = None
                  ) -> tuple[Sun | None, dict]:
    """estimate_sun's strength for the unit direction d (its docstring): the median over fully sunlit
    patches of pi (L / rho - E_ind) / cos; (None, info with a reason) without such patches.

    bounces: the bounces the camera sees (EngineParams.bounces; the truth's 4). The measured radiance B is
    B^(bounces), while a patch reflects the light of one bounce less: B^(bounces) = E + rho (sun + G B^(bounces-1))
    (gather_with_sun). Gathering E_ind = G B^(bounces) instead counts one bounce too many, so rho comes out low
    and the strength high by G B^(bounces) / G B^(bounces-1) (1.05-1.13 in the sun rooms). With `bounces`,
    E_ind is G B scaled per patch by the bounce model's own ratio G B^(bounces-1) / G B^(bounces) (the model:
    gather_with_sun with the current rho, the mesh's emitters and the current sun), iterated to its fixed
    point (_BOUNCE_ROUNDS rounds); None: E_ind = G B as measured (the rule before).
    levels (P,) int: each patch's measured bounce level (lighting.radiance.measured_levels: the probe's patches
    one less than the photo's), the ratio then per patch from its own level and its sources' (level_ratio);
    None: every patch at `bounces`."""
    G64 = np.asarray(G_c, np.float64)
    B = np.asarray(B, np.float64)
    light = SunLight(Sun(d, SUN_DIAMETER_DEG, np.full(3, np.pi), np.zeros(3)), holes, occluder, where="sun estimate")
    e = light.patch_irradiance(pm.corners, pm.normal, ~pm.is_emitter)[:, 0]  # = cos x sunlit share
    cos = np.maximum(pm.normal @ d, 0.0)
    full = (e > 0.98 * cos) & (cos > 0.2)
    E_meas = G64 @ B
    out = _strength_from(B, E_meas, pm, e, cos, full)
    if out is None or not bounces or bounces < 2:
        return _sun_result(d, out, info)
    source = np.any(np.asarray(pm.emission) > 0, axis=1)  # the mesh's emitters (their radiance, rho 0)
    ratio = np.ones_like(B)
    for _ in range(_BOUNCE_ROUNDS):
        E_perp, rho_q, rho_all = out
        rho = np.clip(np.nan_to_num(rho_all), 0.0, 1.0)
        for q, r in rho_q.items():  # sunlit patches (any share) take their surface's unlit reflectivity
            rho[(pm.quad == q) & (e > 0)] = r
        rho[source] = 0.0
        lv = gather_with_sun(G64, rho, np.where(source[:, None], pm.emission, 0.0), e[:, None] * E_perp / np.pi,
                             bounces)
        ratio = level_ratio(G64, lv, bounces, levels)
        out = _strength_from(B, ratio * E_meas, pm, e, cos, full)
        if out is None:
            break
    info["bounce_ratio_median"] = float(np.median(ratio[~source].mean(1))) if (~source).any() else 1.0
    if out is not None:  # the reflectivity the strength used, per sunlit surface (SunSetup gives it its patches)
        info["reflectivity_by_quad"] = {str(q): r.tolist() for q, r in out[1].items()}
    return _sun_result(d, out, info)


def level_ratio(G: np.ndarray, lv: list[np.ndarray], bounces: int, levels: np.ndarray | None = None) -> np.ndarray:
    """(P,3) c = G B^(l-1) / G B_meas per patch (row) and channel: the light a patch measured at bounce level l
    reflects (one level less than its own) over what the measured mesh gathers, by the bounce model's iterates
    lv = [B^(0) .. B^(bounces)] (gather_with_sun). levels (P,) int: each patch's measured level (the photo's
    patches `bounces`; the probe's `bounces` - 1: its ball is the probe camera's first reflection), B_meas the
    mesh of each patch at its own level; None: every patch at `bounces` (c = G B^(n-1) / G B^(n)). 1 where the
    mesh gathers nothing."""
    if levels is None:
        hi, lo = G @ lv[bounces], G @ lv[bounces - 1]
    else:
        lvl = np.clip(np.asarray(levels, np.int64), 1, bounces)
        stack = np.stack(lv)  # (n+1,P,3)
        hi = G @ stack[lvl, np.arange(len(lvl))]
        lo = np.zeros_like(hi)
        for k in np.unique(lvl):
            rows = lvl == k
            lo[rows] = G[rows] @ stack[k - 1]
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(hi > 0, lo / hi, 1.0)


_BOUNCE_ROUNDS = 4  # fixed-point rounds of _sun_strength's bounce ratio (each changes the strength by < 1 % after 3)


def _strength_from(B: np.ndarray, E_ind: np.ndarray, pm, e: np.ndarray, cos: np.ndarray, full: np.ndarray
                   ) -> tuple[np.ndarray, dict, np.ndarray] | None:
    """(E_perp (3,), {quad: its unlit patches' median rho (3,)}, B / E_ind per patch) from the radiance B and
    the gathered irradiance/pi E_ind (each (P,3)); None without a fully sunlit patch that has >= 3 unlit
    patches of its surface."""
    from lighting.sources import luminance

    with np.errstate(divide="ignore", invalid="ignore"):
        rho_all = np.where(E_ind > 0, B / E_ind, 0.0)
    est, rho_q = [], {}
    for q in np.unique(pm.quad[full]):
        unlit = (pm.quad == q) & (e == 0) & ~pm.is_emitter & (luminance(E_ind) > 0)
        on = full & (pm.quad == q)
        if unlit.sum() < 3:
            continue
        rho = np.median(rho_all[unlit], axis=0)
        if np.any(rho <= 0):
            continue
        rho_q[int(q)] = rho
        est.append(np.pi * (B[on] / rho - E_ind[on]) / cos[on, None])
    if not est:
        return None
    return np.maximum(np.median(np.concatenate(est), axis=0), 0.0), rho_q, rho_all


def _sun_result(d: np.ndarray, out, info: dict) -> tuple[Sun | None, dict]:
    """_sun_strength's answer from _strength_from's `out`."""
    if out is None:
        return None, {**info, "reason": "no fully sunlit patch with unlit patches of the same surface"}
    info["irradiance_perpendicular"] = out[0].tolist()
    return Sun(d, SUN_DIAMETER_DEG, out[0], np.zeros(3)), info
