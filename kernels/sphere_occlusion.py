"""The light a set of spheres blocks at receiver points: order-3 SH (16 coefficients) for the room's
broad light, cone overlap for a few compact sources (app.dragshadow's drag frame, no shadow maps).

Units: light is in the transfers' units (sum_j G_xj B_j: irradiance / pi); directions are unit vectors
in world coordinates; angles in radians.

SH part. sh (n,16) holds, per receiver point x, the real SH projection (l <= 3, the basis of `sh16`)
of its incident light as a point set, c_lm(x) = sum_j G_xj B_j Y_lm(w_xj) (w_xj: x towards source j;
G already holds the cosine at x and the room's visibility). The light a cap of half-angle a about d
holds is the cap's projection dotted with it (Sloan's zonal rotation):

  blocked(d, a) = sum_l A_l(a) sum_m Y_lm(d) c_lm,  A_l(a) = 2 pi int_{cos a}^1 P_l(t) dt

(exact for light of bandwidth <= 3; the broad light of walls and ceiling is, the compact sources
are kept apart for that reason). Several spheres combine as independent occluders: the visible share
is the product of each one's (1 - blocked_k / E_sh), each clamped to [0, 1].

Compact sources (lamps, window cells): per point their light w (n,G,3) and its centroid c (n,G,3),
each a disk of radius r (G,) facing the point; the share of it the parts hide is that of N_DISK points
on the disk (a Vogel spiral) whose segment from the point meets a part: exact for the ellipsoids, so
the shadow of a slab under oblique light is the slab's, not a round blob's. Sources whose cone misses
the parts' bounding sphere are skipped.

The object's own light: each part fills the cosine-weighted share of the hemisphere its cap takes,
sin^2 a max(n.d, 0) (exact for a cap above the horizon), with the radiance of its side that faces the
point (an ambient cube per part); the caps' union as independent caps.

ratio(x) = r0 (1 + reflected / E_x), r0 = 1 - (blocked_sh + blocked_compact) / E_x, per colour, clamped at 0:
the parts' side facing x is lit by x's surroundings, which their shadow darkens by about r0 too (the object's
shading, L_vert, sees the room unshadowed); E_x the point's whole light (with the sun's, which
app.dragshadow takes at full resolution). Points with E_x = 0 keep 1; a point inside a part gets 0.
"""
from __future__ import annotations

import numpy as np
import warp as wp


N_DISK = 12  # samples of a compact source's disk (sphere_ratio_kernel)
MAX_PARTS = 31  # parts per object (a bit each in an int32 mask)
N_SH = 16  # order 3: (l, m) = (0,0), (1,-1..1), (2,-2..2), (3,-3..3)

# real SH normalisation constants, l <= 3
_K00 = 0.28209479177387814
_K1 = 0.4886025119029199
_K2a = 1.0925484305920792  # xy, yz, xz
_K20 = 0.31539156525252005  # 3z^2 - 1
_K22 = 0.5462742152960396  # x^2 - y^2
_K3a = 0.5900435899266435  # y(3x^2 - y^2), x(x^2 - 3y^2)
_K3b = 2.890611442640554  # xyz
_K3c = 0.4570457994644658  # y(5z^2 - 1), x(5z^2 - 1)
_K30 = 0.3731763325901154  # z(5z^2 - 3)
_K32 = 1.445305721320277  # z(x^2 - y^2)


def sh16_np(d: np.ndarray) -> np.ndarray:
    """(..., 16) real SH basis at unit directions d (..., 3) (the order of the module docstring)."""
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    return np.stack([
        np.full_like(x, _K00),
        _K1 * y, _K1 * z, _K1 * x,
        _K2a * x * y, _K2a * y * z, _K20 * (3 * z * z - 1), _K2a * x * z, _K22 * (x * x - y * y),
        _K3a * y * (3 * x * x - y * y), _K3b * x * y * z, _K3c * y * (5 * z * z - 1), _K30 * z * (5 * z * z - 3),
        _K3c * x * (5 * z * z - 1), _K32 * z * (x * x - y * y), _K3a * x * (x * x - 3 * y * y)], axis=-1)


def cap_factors_np(a: np.ndarray) -> np.ndarray:
    """(..., 4) A_l(a), l = 0..3, for caps of half-angle a (...,): 2 pi int_{cos a}^1 P_l(t) dt."""
    c = np.cos(a)
    s2 = 1.0 - c * c
    return 2 * np.pi * np.stack([1 - c, s2 / 2, c * s2 / 2, s2 * (5 * c * c - 1) / 8], axis=-1)


def blocked_sh_np(sh: np.ndarray, d: np.ndarray, a: np.ndarray) -> np.ndarray:
    """(n,3) the light of sh (n,16,3) inside caps about d (n,3) of half-angle a (n,) (the kernel's
    `_cap_light`, numpy: tests)."""
    Y = sh16_np(d)
    A = cap_factors_np(a)
    Al = np.concatenate([A[:, :1], np.repeat(A[:, 1:2], 3, 1), np.repeat(A[:, 2:3], 5, 1),
                         np.repeat(A[:, 3:4], 7, 1)], axis=1)
    return np.einsum("nk,nkc->nc", Y * Al, sh)


@wp.func
def _cap_light(sh: wp.array2d(dtype=wp.vec3), i: int, d: wp.vec3, c: float) -> wp.vec3:
    """The light of point i's SH (sh[i, 0:16]) inside the cap about d whose half-angle has cosine c."""
    s2 = 1.0 - c * c
    tp = 2.0 * 3.141592653589793
    A0 = tp * (1.0 - c)
    A1 = tp * s2 * 0.5
    A2 = tp * c * s2 * 0.5
    A3 = tp * s2 * (5.0 * c * c - 1.0) * 0.125
    x = d[0]
    y = d[1]
    z = d[2]
    r = sh[i, 0] * (A0 * _K00)
    r += (sh[i, 1] * y + sh[i, 2] * z + sh[i, 3] * x) * (A1 * _K1)
    r += (sh[i, 4] * (_K2a * x * y) + sh[i, 5] * (_K2a * y * z) + sh[i, 6] * (_K20 * (3.0 * z * z - 1.0))
          + sh[i, 7] * (_K2a * x * z) + sh[i, 8] * (_K22 * (x * x - y * y))) * A2
    r += (sh[i, 9] * (_K3a * y * (3.0 * x * x - y * y)) + sh[i, 10] * (_K3b * x * y * z)
          + sh[i, 11] * (_K3c * y * (5.0 * z * z - 1.0)) + sh[i, 12] * (_K30 * z * (5.0 * z * z - 3.0))
          + sh[i, 13] * (_K3c * x * (5.0 * z * z - 1.0)) + sh[i, 14] * (_K32 * z * (x * x - y * y))
          + sh[i, 15] * (_K3a * x * (x * x - 3.0 * y * y))) * A3
    return r


@wp.func
def disk_overlap(a: float, b: float, g: float) -> float:
    """Share of a disk of radius b covered by a disk of radius a whose centre is g away (flat)."""
    if b <= 0.0:
        return 0.0
    if g >= a + b:
        return 0.0
    if g <= wp.abs(a - b):
        m = wp.min(a, b)
        return wp.min(m * m / (b * b), 1.0)
    ca = wp.clamp((g * g + a * a - b * b) / (2.0 * g * a), -1.0, 1.0)
    cb = wp.clamp((g * g + b * b - a * a) / (2.0 * g * b), -1.0, 1.0)
    k = (-g + a + b) * (g + a - b) * (g - a + b) * (g + a + b)
    area = a * a * wp.acos(ca) + b * b * wp.acos(cb) - 0.5 * wp.sqrt(wp.max(k, 0.0))
    return wp.clamp(area / (3.141592653589793 * b * b), 0.0, 1.0)


@wp.func
def equivalent_radius(ainv: wp.mat33, det: float, d: wp.vec3) -> float:
    """Radius of the sphere whose shadow along unit d has the area of the ellipsoid {c + A s: |s| <= 1}'s:
    its projection perpendicular to d has area pi |det A| |A^-1 d|, a sphere's pi r^2."""
    return wp.sqrt(det * wp.length(ainv * d))


@wp.func
def _ambient_cube(lo: wp.array2d(dtype=wp.vec3), k: int, m: wp.vec3) -> wp.vec3:
    """Part k's radiance towards unit m from its ambient cube lo[k] (+x, -x, +y, -y, +z, -z): the faces'
    values weighted by m_i^2 on the side m points to (the weights sum to 1)."""
    r = wp.vec3(0.0, 0.0, 0.0)
    for i in range(3):
        w = m[i] * m[i]
        if m[i] >= 0.0:
            r = r + lo[k, 2 * i] * w
        else:
            r = r + lo[k, 2 * i + 1] * w
    return r


@wp.func
def _cones_meet(cd: float, sa: float, ca: float, sb: float, cb: float) -> bool:
    """Whether cones of half-angles a, b (sines, cosines) whose axes have cosine cd overlap:
    angle between axes < a + b, i.e. cd > cos(a + b), trig-free (a + b >= pi: always)."""
    cab = ca * cb - sa * sb  # cos(a + b)
    if sa * cb + ca * sb < 0.0 and cab < 0.0:  # a + b > pi
        return True
    return cd > cab


@wp.kernel
def sphere_ratio_kernel(first: int, pos: wp.array(dtype=wp.vec3), nrm: wp.array(dtype=wp.vec3),
                        E: wp.array(dtype=wp.vec3), sh: wp.array2d(dtype=wp.vec3), e_sh: wp.array(dtype=wp.vec3),
                        cw: wp.array2d(dtype=wp.vec3), cc: wp.array2d(dtype=wp.vec3), cr: wp.array(dtype=float),
                        sc: wp.array(dtype=wp.vec3), sa: wp.array(dtype=wp.mat33), sdet: wp.array(dtype=float),
                        sreach: wp.array(dtype=float),
                        lo: wp.array2d(dtype=wp.vec3), bound: wp.vec4, out: wp.array(dtype=wp.vec3)):
    """out[i] = ratio of point i (module docstring): pos, nrm (n,) the point and its normal, E (n,) its
    whole light, sh (n,16) and e_sh (n,) the SH light and its total, cw / cc (n,G) the compact sources'
    light and centroids, cr (G,) their radii; the parts: sc (K,) centres, sa (K,) inverse axes matrices A^-1,
    sdet (K,) |det A| (equivalent_radius), sreach (K,) their longest semi-axes; lo (K,6) their radiance as
    an ambient cube (_ambient_cube) read at the side facing the point; bound (centre, radius) a sphere holding
    them all (a compact source its cone misses is skipped)."""
    i = first + wp.tid()
    x = pos[i]
    n = nrm[i]
    Ex = E[i]
    one = wp.vec3(1.0, 1.0, 1.0)
    if Ex[0] <= 0.0 and Ex[1] <= 0.0 and Ex[2] <= 0.0:
        out[i] = one
        return
    K = sc.shape[0]
    G = cr.shape[0]
    Es = e_sh[i]
    vis = one  # SH light left visible (share, per colour)
    refl = float(1.0)  # cosine-weighted hemisphere share not covered by a sphere
    lsum = wp.vec3(0.0, 0.0, 0.0)  # the spheres' radiance weighted by their cosine-weighted share
    wsum = float(0.0)
    inside = int(0)
    for k in range(K):
        v = sc[k] - x
        D = wp.length(v)
        if wp.length(sa[k] * v) <= 1.0:
            inside = 1
        else:
            d = v / D
            s = wp.min(equivalent_radius(sa[k], sdet[k], d) / D, 0.999)
            b = _cap_light(sh, i, d, wp.sqrt(1.0 - s * s))
            for c in range(3):
                if Es[c] > 0.0:
                    vis[c] = vis[c] * (1.0 - wp.clamp(b[c] / Es[c], 0.0, 1.0))
            nd = wp.dot(n, d)
            if nd > 0.0:
                f = wp.min(s * s * nd, 1.0)
                refl = refl * (1.0 - f)
                lsum = lsum + _ambient_cube(lo, k, -d) * f
                wsum = wsum + f
    if inside != 0:  # a receiver inside the object: nothing reaches it
        out[i] = wp.vec3(0.0, 0.0, 0.0)
        return
    blocked = wp.cw_mul(Es, one - vis)
    vb = wp.vec3(bound[0], bound[1], bound[2]) - x
    Db = wp.length(vb)
    sbb = wp.min(bound[3] / Db, 1.0)
    cbb = wp.sqrt(1.0 - sbb * sbb)
    for g in range(G):
        w = cw[i, g]
        if w[0] + w[1] + w[2] <= 0.0:
            continue
        u = cc[i, g] - x
        Ls = wp.length(u)
        if Ls <= 0.0 or Db - bound[3] > Ls:  # at the source, or the object lies beyond it
            continue
        us = u / Ls
        ssrc = wp.min(cr[g] / Ls, 1.0)
        csrc = wp.sqrt(1.0 - ssrc * ssrc)
        if not _cones_meet(wp.dot(vb, us) / Db, sbb, cbb, ssrc, csrc):
            continue
        near = int(0)  # bit k: part k's bounding sphere meets the source's cone
        for k in range(K):
            v = sc[k] - x
            D = wp.length(v)
            sk = wp.min(sreach[k] / D, 1.0)
            if D - sreach[k] <= Ls and _cones_meet(wp.dot(v, us) / D, sk, wp.sqrt(1.0 - sk * sk), ssrc, csrc):
                near = near | (1 << k)
        if near == 0:
            continue
        # the source's disk (radius cr, facing the point) sampled on a Vogel spiral; a sample is hidden
        # when the segment towards it meets a part (in the part's unit-sphere coordinates)
        t1 = wp.normalize(wp.cross(us, wp.vec3(0.0, 1.0, 0.0)))
        if wp.abs(us[1]) > 0.9:
            t1 = wp.normalize(wp.cross(us, wp.vec3(1.0, 0.0, 0.0)))
        t2 = wp.cross(us, t1)
        hidden = float(0.0)
        for j in range(N_DISK):
            rho = cr[g] * wp.sqrt((float(j) + 0.5) / float(N_DISK))
            phi = float(j) * 2.399963229728653
            ps = u + (wp.cos(phi) * rho) * t1 + (wp.sin(phi) * rho) * t2
            for k in range(K):
                if (near & (1 << k)) == 0:
                    continue
                o = sa[k] * (x - sc[k])
                vv = sa[k] * ps
                tt = wp.clamp(-wp.dot(o, vv) / wp.max(wp.dot(vv, vv), 1e-20), 0.0, 1.0)
                q = o + tt * vv
                if wp.dot(q, q) < 1.0:
                    hidden += 1.0
                    break
        seen = 1.0 - hidden / float(N_DISK)
        blocked = blocked + w * (1.0 - seen)
    r = one
    for c in range(3):
        if Ex[c] > 0.0:
            r[c] = wp.max(1.0 - blocked[c] / Ex[c], 0.0)
    if wsum > 0.0:  # the spheres' own light over the share of the hemisphere they cover
        Lr = lsum * ((1.0 - refl) / wsum)
        for c in range(3):
            if Ex[c] > 0.0:  # the side facing the point is lit by its shadowed surroundings: times r
                r[c] = r[c] * (1.0 + Lr[c] / Ex[c])
    out[i] = r


class SphereRatio:
    """Per-scene inputs of sphere_ratio_kernel uploaded once (points, SH, compact sources), per-frame
    spheres in small arrays; run() launches over the points, split over the cores."""

    def __init__(self, pos: np.ndarray, nrm: np.ndarray, E: np.ndarray, sh: np.ndarray, cw: np.ndarray,
                 cc: np.ndarray, cr: np.ndarray, device: str):
        """pos, nrm, E (n,3); sh (n,16,3); cw, cc (n,G,3); cr (G,) (module docstring's units)."""
        self.device = d = device
        f = lambda a: np.ascontiguousarray(a, np.float32)  # noqa: E731
        self.n = n = len(pos)
        if cr.shape[0] == 0:  # no compact source: one of no light (the kernel skips it)
            cw, cc, cr = np.zeros((n, 1, 3)), np.zeros((n, 1, 3)), np.zeros(1)
        G = cr.shape[0]
        self._pos = wp.array(f(pos), dtype=wp.vec3, device=d)
        self._nrm = wp.array(f(nrm), dtype=wp.vec3, device=d)
        self._E = wp.array(f(E), dtype=wp.vec3, device=d)
        self._sh = wp.array(f(sh.reshape(n, N_SH, 3)), dtype=wp.vec3, device=d)
        self._esh = wp.array(f(sh[:, 0, :] / _K00), dtype=wp.vec3, device=d)  # E_sh = c_00 / Y_00
        self._cw = wp.array(f(cw.reshape(n, G, 3)), dtype=wp.vec3, device=d)
        self._cc = wp.array(f(cc.reshape(n, G, 3)), dtype=wp.vec3, device=d)
        self._cr = wp.array(f(cr), dtype=float, device=d)
        self._out = wp.zeros(n, dtype=wp.vec3, device=d)
        self._spheres: tuple | None = None

    def run(self, centres: np.ndarray, axes: np.ndarray, radiance: np.ndarray, split) -> np.ndarray:
        """(n,3) float32 ratios for ellipsoids centres (K,3), axes (K,3,3) (columns: semi-axes, m; a sphere
        of radius r: r I), radiance (K,6,3) (ambient cubes: +x, -x, +y, -y, +z, -z)."""
        d, K = self.device, len(centres)
        if self._spheres is None or self._spheres[0].shape[0] != K:  # per part count (a shape), then reused
            if K > MAX_PARTS:
                raise ValueError(f"at most {MAX_PARTS} parts (the kernel's bit mask), got {K}")
            self._spheres = (wp.zeros(K, dtype=wp.vec3, device=d), wp.zeros(K, dtype=wp.mat33, device=d),
                             wp.zeros(K, dtype=float, device=d), wp.zeros(K, dtype=float, device=d),
                             wp.zeros((K, 6), dtype=wp.vec3, device=d))
        sc, sa, sdet, sreach, lo = self._spheres
        reach = np.linalg.norm(axes, axis=1).max(1)  # the longest semi-axis: a sphere holding each part
        bc = centres.mean(0)
        bnd = wp.vec4(*[float(v) for v in bc], float((np.linalg.norm(centres - bc, axis=1) + reach).max()))
        for arr, v in ((sc, centres), (sa, np.linalg.inv(axes)), (sdet, np.abs(np.linalg.det(axes))), (sreach, reach),
                       (lo, radiance)):
            arr.assign(np.ascontiguousarray(v, np.float32))

        def launch(a: int, b: int) -> None:
            wp.launch(sphere_ratio_kernel, dim=b - a, device=d,
                      inputs=[a, self._pos, self._nrm, self._E, self._sh, self._esh, self._cw, self._cc, self._cr,
                              sc, sa, sdet, sreach, lo, bnd, self._out])

        split(launch, self.n)
        wp.synchronize_device(d)
        return self._out.numpy()
