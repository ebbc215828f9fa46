"""Shaft culling: which (receiver patch, source) pairs can the object come between?

The light paths between a receiver patch and a source patch lie inside the convex hull of the
two patches' bounding spheres, which is the union over t in [0,1] of spheres centred at
lerp(c_r, c_s, t) with radius lerp(r_r, r_s, t). That hull meets the object's bounding sphere
(c, R) iff min_t |c - lerp(c_r, c_s, t)| - lerp(r_r, r_s, t) < R; the function is convex in t, so
a ternary search finds the minimum. This is the leaf level of the seed's shaft hierarchy
(sec. 6.2, Haines & Wallace 1994), evaluated flat for every pair.
"""
from __future__ import annotations

import numpy as np
import warp as wp

from kernels import runtime


@wp.func
def _gap(c: wp.vec3, a: wp.vec3, b: wp.vec3, ra: float, rb: float, t: float) -> float:
    return wp.length(c - (a + (b - a) * t)) - (ra + (rb - ra) * t)


@wp.kernel
def _shaft_kernel(recv_c: wp.array(dtype=wp.vec3), recv_r: wp.array(dtype=wp.float32),
                  src_c: wp.array(dtype=wp.vec3), src_r: wp.array(dtype=wp.float32),
                  c: wp.vec3, R: float, out: wp.array2d(dtype=wp.uint8)):
    i, j = wp.tid()
    a = recv_c[i]
    b = src_c[j]
    ra = recv_r[i]
    rb = src_r[j]
    # cheap bounds first: the segment's closest point to c decides most pairs
    d = b - a
    t0 = wp.clamp(wp.dot(c - a, d) / wp.max(wp.dot(d, d), 1.0e-12), 0.0, 1.0)
    if wp.length(c - (a + d * t0)) - wp.max(ra, rb) >= R:
        out[i, j] = wp.uint8(0)
        return
    if _gap(c, a, b, ra, rb, t0) < R:
        out[i, j] = wp.uint8(1)
        return
    lo = float(0.0)
    hi = float(1.0)
    for _ in range(24):
        m1 = lo + (hi - lo) / 3.0
        m2 = hi - (hi - lo) / 3.0
        if _gap(c, a, b, ra, rb, m1) < _gap(c, a, b, ra, rb, m2):
            hi = m2
        else:
            lo = m1
    g = wp.min(_gap(c, a, b, ra, rb, 0.5 * (lo + hi)), wp.min(_gap(c, a, b, ra, rb, 0.0), _gap(c, a, b, ra, rb, 1.0)))
    out[i, j] = wp.where(g < R, wp.uint8(1), wp.uint8(0))


def shaft_candidates(recv_centres: np.ndarray, recv_radii: np.ndarray, src_centres: np.ndarray,
                     src_radii: np.ndarray, centre: np.ndarray, radius: float, device: str | None = None
                     ) -> np.ndarray:
    """(Nr, Ns) bool: can the object's bounding sphere (centre (3,), radius m) block any light from
    source sphere j to receiver sphere i? Centres (N,3) m, radii (N,) m."""
    device = runtime.device(device)
    nr, ns = len(recv_centres), len(src_centres)
    if nr == 0 or ns == 0:
        return np.zeros((nr, ns), bool)
    out = wp.zeros((nr, ns), dtype=wp.uint8, device=device)
    f32 = lambda a: np.asarray(a, np.float32)
    wp.launch(_shaft_kernel, dim=(nr, ns),
              inputs=[wp.array(f32(recv_centres), dtype=wp.vec3, device=device),
                      wp.array(f32(recv_radii), dtype=wp.float32, device=device),
                      wp.array(f32(src_centres), dtype=wp.vec3, device=device),
                      wp.array(f32(src_radii), dtype=wp.float32, device=device),
                      wp.vec3(*f32(centre)), float(radius)], outputs=[out], device=device)
    return out.numpy().astype(bool)
