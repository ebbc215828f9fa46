"""Point-to-polygon form factors (differential area to finite polygon), Warp kernels.

Lambert's contour integral (Cohen & Wallace, *Radiosity and Realistic Image Synthesis*, 1993,
eq. 4.22; Baum, Rushmeier & Winget 1989 for the horizon clipping):

    F = -1/(2 pi) * sum_edges  gamma_e * n . (r_a x r_b) / |r_a x r_b|

with r_a, r_b the edge's end points relative to the receiver point, gamma_e the angle they
subtend and n the receiver normal. The polygon is first clipped to the receiver's horizon
(the half-space n . (x - p) >= 0); the clipping is streamed edge by edge so a convex polygon of
any vertex count needs no scratch storage. Emitters are one-sided: a receiver on or behind the
polygon's plane gets F = 0 (this also makes receivers lying in the source's plane exact).

Everything is evaluated in float64: near a touching edge the two edge vectors are almost
antiparallel and their cross product loses most of its digits in float32.

Conventions: a polygon emits on the side of (v1 - v0) x (v2 - v0) (counter-clockwise seen from
the lit side). Form factors are dimensionless; irradiance/pi from a patch of radiance B is B * F.
"""
from __future__ import annotations

import numpy as np
import warp as wp

from kernels import runtime

_TWO_PI = 6.283185307179586


@wp.func
def _edge_term(ra: wp.vec3d, rb: wp.vec3d, n: wp.vec3d) -> wp.float64:
    """gamma * n.(ra x rb)/|ra x rb| for one polygon edge (0 for a degenerate edge)."""
    c = wp.cross(ra, rb)
    s = wp.length(c)
    if s <= wp.float64(1.0e-300):
        return wp.float64(0.0)
    gamma = wp.atan2(s, wp.dot(ra, rb))
    return gamma * wp.dot(n, c) / s


@wp.func
def _horizon_point(a: wp.vec3d, b: wp.vec3d, ha: wp.float64, hb: wp.float64) -> wp.vec3d:
    """Point where segment a-b crosses the horizon plane (ha, hb signed heights, opposite signs)."""
    t = ha / (ha - hb)
    return a + (b - a) * t


@wp.func
def polygon_ff(p: wp.vec3d, n: wp.vec3d, poly: wp.array2d(dtype=wp.vec3d), j: int, k: int) -> wp.float64:
    """Form factor from point p (unit normal n) to polygon j of `poly` (k vertices, convex)."""
    v0 = poly[j, 0]
    ns = wp.cross(poly[j, 1] - v0, poly[j, 2] - v0)
    # one-sided emitter: receivers on or behind the source plane see nothing
    if wp.dot(ns, p - v0) <= wp.float64(0.0):
        return wp.float64(0.0)
    total = wp.float64(0.0)
    exit_pt = wp.vec3d()
    entry_pt = wp.vec3d()
    clipped = int(0)
    for e in range(k):
        a = poly[j, e] - p
        b = poly[j, (e + 1) % k] - p
        ha = wp.dot(n, a)
        hb = wp.dot(n, b)
        if ha >= wp.float64(0.0) and hb >= wp.float64(0.0):
            total += _edge_term(a, b, n)
        elif ha >= wp.float64(0.0):
            q = _horizon_point(a, b, ha, hb)
            total += _edge_term(a, q, n)
            exit_pt = q
            clipped = 1
        elif hb >= wp.float64(0.0):
            q = _horizon_point(a, b, ha, hb)
            total += _edge_term(q, b, n)
            entry_pt = q
            clipped = 1
    if clipped == 1:
        # the clipped polygon is closed along the horizon, from where it left to where it re-entered
        total += _edge_term(exit_pt, entry_pt, n)
    f = -total / wp.float64(_TWO_PI)
    return wp.max(f, wp.float64(0.0))


@wp.kernel
def _point_to_polygon_kernel(
    points: wp.array(dtype=wp.vec3d),
    normals: wp.array(dtype=wp.vec3d),
    polys: wp.array2d(dtype=wp.vec3d),
    k: int,
    out: wp.array2d(dtype=wp.float64),
):
    i, j = wp.tid()
    out[i, j] = polygon_ff(points[i], normals[i], polys, j, k)


def point_to_polygon(points: np.ndarray, normals: np.ndarray, polygons: np.ndarray,
                     device: str | None = None, workspace=None, capacity: int = 0) -> np.ndarray:
    """Unoccluded form factors from receiver points to convex polygons.

    points (N,3), normals (N,3) unit receiver normals, polygons (M,K,3) vertices in metres, emitting
    on the side of (v1-v0)x(v2-v0). Returns (N,M) float64, dimensionless. workspace: the call site's
    kernels.buffers.Workspace (its buffers kept: nothing allocated once they hold the sizes asked), or None;
    capacity: the polygons its buffers hold at least (a caller whose count varies from call to call).
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    normals = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
    polygons = np.asarray(polygons, dtype=np.float64)
    if polygons.ndim != 3 or polygons.shape[-1] != 3 or (polygons.shape[0] and polygons.shape[1] < 3):
        raise ValueError(f"polygons must have shape (M, K>=3, 3), got {polygons.shape}")
    if points.shape != normals.shape:
        raise ValueError(f"points {points.shape} and normals {normals.shape} differ in shape")
    n, m = len(points), len(polygons)
    if n == 0 or m == 0:
        return np.zeros((n, m), dtype=np.float64)
    device = runtime.device(device)
    if workspace is not None:
        out = workspace.buffer("ff", n, wp.float64, device, (max(m, capacity),))
        wp.launch(_point_to_polygon_kernel, dim=(n, m),
                  inputs=[workspace.upload("points", points, wp.vec3d, device),
                          workspace.upload("normals", normals, wp.vec3d, device),
                          workspace.upload("polys", polygons, wp.vec3d, device, capacity), polygons.shape[1]],
                  outputs=[out.dev[:n, :m]], device=device)
        return out.pull(n)[:, :m].copy()
    out = wp.zeros((n, m), dtype=wp.float64, device=device)
    wp.launch(_point_to_polygon_kernel, dim=(n, m),
              inputs=[wp.array(points, dtype=wp.vec3d, device=device),
                      wp.array(normals, dtype=wp.vec3d, device=device),
                      wp.array(polygons, dtype=wp.vec3d, device=device), polygons.shape[1]],
              outputs=[out], device=device)
    return out.numpy()

