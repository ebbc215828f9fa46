"""SH9 irradiance volume over the room (seed sec. 5), gathered from the radiance mesh in Warp.

Each grid point projects the radiance of every patch onto 9 real SH coefficients (see
lighting/sh.py): L_lm = sum_j B_j * Omega_j * V_j * Y_lm(w_j), with Omega_j the exact solid
angle of patch j (two triangles, Van Oosterom & Strackee 1983), w_j the direction to its centre
and V_j one ray-cast visibility test. Grid points sit at cell centres, so none lies on a wall;
points inside furniture (the first hit straight up is a face seen from behind) are flagged and
filled from valid neighbours so trilinear lookups near solid geometry do not go dark.

Layout: coeffs (nx, ny, nz, 9, 3) float32, radiance units; origin = room_min, cell = spacing.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from kernels import runtime
from kernels.sh9 import sh9
from kernels.visibility import Occluder, segment_blocked


@wp.func
def _tri_solid_angle(p: wp.vec3, a: wp.vec3, b: wp.vec3, c: wp.vec3) -> float:
    ra = a - p
    rb = b - p
    rc = c - p
    la = wp.length(ra)
    lb = wp.length(rb)
    lc = wp.length(rc)
    num = wp.dot(ra, wp.cross(rb, rc))
    den = la * lb * lc + wp.dot(ra, rb) * lc + wp.dot(ra, rc) * lb + wp.dot(rb, rc) * la
    return wp.abs(2.0 * wp.atan2(num, den))


@wp.func
def _accumulate(out: wp.array2d(dtype=wp.vec3), g: int, d: wp.vec3, w: wp.vec3):
    """Add radiance w (already times solid angle) from direction d to point g's 9 coefficients."""
    for k in range(9):
        out[g, k] += w * sh9(d, k)


@wp.kernel
def _gather_kernel(points: wp.array(dtype=wp.vec3), first: int, corners: wp.array2d(dtype=wp.vec3),
                   normals: wp.array(dtype=wp.vec3), radiance: wp.array(dtype=wp.vec3), mesh: wp.uint64,
                   out: wp.array2d(dtype=wp.vec3)):
    k = wp.tid()
    g = first + k
    p = points[g]
    for j in range(corners.shape[0]):
        B = radiance[j]
        if B[0] + B[1] + B[2] <= 0.0:
            continue
        c00 = corners[j, 0]
        eu = corners[j, 1] - c00
        ev = corners[j, 3] - c00
        c = c00 + (eu + ev) * 0.5
        if wp.dot(normals[j], p - c) <= 0.0:
            continue  # one-sided: p is behind the patch
        # near patches are split so one direction and one visibility ray per piece stay accurate
        ns = int(1)
        if wp.length(c - p) < 3.0 * wp.length(eu + ev):
            ns = 4
        for su in range(ns):
            for sv in range(ns):
                a = c00 + eu * (float(su) / float(ns)) + ev * (float(sv) / float(ns))
                b = a + eu / float(ns)
                cc = b + ev / float(ns)
                dd = a + ev / float(ns)
                m = (a + cc) * 0.5
                if segment_blocked(mesh, p, m + normals[j] * 1.0e-4):
                    continue
                om = _tri_solid_angle(p, a, b, cc) + _tri_solid_angle(p, a, cc, dd)
                _accumulate(out, g, wp.normalize(m - p), B * om)


@wp.kernel
def _inside_kernel(points: wp.array(dtype=wp.vec3), mesh: wp.uint64, normals: wp.array(dtype=wp.vec3),
                   tri_patch: wp.array(dtype=wp.int32), out: wp.array(dtype=wp.int32)):
    g = wp.tid()
    q = wp.mesh_query_ray(mesh, points[g], wp.vec3(0.0, 1.0, 0.0), 1.0e6)
    inside = int(0)
    if q.result:
        if normals[tri_patch[q.face]][1] > 0.0:
            inside = 1  # hit a face from behind: the point is inside a solid
    out[g] = inside


@dataclass
class IrradianceVolume:
    origin: np.ndarray  # (3,) room_min
    cell: np.ndarray  # (3,) cell size, m
    coeffs: np.ndarray  # (nx,ny,nz,9,3)
    valid: np.ndarray  # (nx,ny,nz) bool, False where the point was inside solid geometry (filled)

    @property
    def shape(self) -> tuple[int, int, int]:
        return self.coeffs.shape[:3]

    def points(self) -> np.ndarray:
        return grid_points(self.origin, self.cell, self.shape)

    def lookup(self, p: np.ndarray) -> np.ndarray:
        """Trilinear SH coefficients (N,9,3) at world points (N,3) (clamped to the grid)."""
        f = (np.asarray(p, np.float64) - self.origin) / self.cell - 0.5
        n = np.array(self.shape)
        f = np.clip(f, 0.0, n - 1.0)
        i0 = np.minimum(np.floor(f).astype(int), np.maximum(n - 2, 0))
        t = f - i0
        out = np.zeros((len(f), 9, 3))
        for dx in (0, 1):
            for dy in (0, 1):
                for dz in (0, 1):
                    ix = np.minimum(i0 + [dx, dy, dz], n - 1)
                    w = (np.where(dx, t[:, 0], 1 - t[:, 0]) * np.where(dy, t[:, 1], 1 - t[:, 1]) *
                         np.where(dz, t[:, 2], 1 - t[:, 2]))
                    out += w[:, None, None] * self.coeffs[ix[:, 0], ix[:, 1], ix[:, 2]]
        return out


def grid_points(origin: np.ndarray, cell: np.ndarray, shape) -> np.ndarray:
    ii = np.stack(np.meshgrid(*[np.arange(s) for s in shape], indexing="ij"), -1).reshape(-1, 3)
    return origin + (ii + 0.5) * cell


def build_volume(room_min: np.ndarray, room_max: np.ndarray, spacing: float, corners: np.ndarray,
                 normals: np.ndarray, radiance: np.ndarray, occluder: Occluder, tri_patch: np.ndarray,
                 device: str | None = None, shape: tuple[int, int, int] | None = None) -> IrradianceVolume:
    """Gather the SH9 volume from patches (P,4,3) / normals (P,3) / radiance (P,3); spacing in m
    (or an explicit grid `shape`, e.g. the seed's 20x10x20)."""
    if spacing <= 0:
        raise ValueError("volume spacing must be positive")
    device = runtime.device(device)
    size = np.asarray(room_max, np.float64) - room_min
    if shape is None:
        shape = tuple(int(max(2, np.ceil(s / spacing - 1e-9))) for s in size)
    cell = size / np.array(shape)
    pts = grid_points(np.asarray(room_min, np.float64), cell, shape)
    G = len(pts)
    pts_wp = wp.array(pts.astype(np.float32), dtype=wp.vec3, device=device)
    out = wp.zeros((G, 9), dtype=wp.vec3, device=device)
    args = [wp.array(np.asarray(corners, np.float32), dtype=wp.vec3, device=device),
            wp.array(np.asarray(normals, np.float32), dtype=wp.vec3, device=device),
            wp.array(np.asarray(radiance, np.float32), dtype=wp.vec3, device=device), wp.uint64(occluder.id)]
    half = (G + 1) // 2
    runtime.run_parallel([
        lambda a=a, b=b: wp.launch(_gather_kernel, dim=b - a, inputs=[pts_wp, a, *args], outputs=[out], device=device)
        for a, b in ((0, half), (half, G)) if b > a])
    inside = wp.zeros(G, dtype=wp.int32, device=device)
    wp.launch(_inside_kernel, dim=G, inputs=[pts_wp, wp.uint64(occluder.id), args[1],
                                             wp.array(np.asarray(tri_patch, np.int32), dtype=wp.int32, device=device)],
              outputs=[inside], device=device)
    coeffs = out.numpy().astype(np.float64).reshape(*shape, 9, 3)
    valid = inside.numpy().reshape(shape) == 0
    return IrradianceVolume(np.asarray(room_min, np.float64), cell, _fill_invalid(coeffs, valid), valid)


def _fill_invalid(coeffs: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Replace coefficients of invalid points by the mean of valid 6-neighbours, growing inwards."""
    c = coeffs.copy()
    ok = valid.copy()
    for _ in range(max(c.shape[:3])):
        if ok.all():
            break
        acc = np.zeros_like(c)
        cnt = np.zeros(ok.shape)
        for ax in range(3):
            for sh in (-1, 1):
                okn = np.roll(ok, sh, axis=ax)
                cn = np.roll(c, sh, axis=ax)
                edge = [slice(None)] * 3
                edge[ax] = 0 if sh == 1 else -1
                okn[tuple(edge)] = False  # np.roll wraps around: ignore the wrapped layer
                acc += cn * okn[..., None, None]
                cnt += okn
        grow = ~ok & (cnt > 0)
        c[grow] = acc[grow] / cnt[grow][:, None, None]
        ok = ok | grow
    return c
