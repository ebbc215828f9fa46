"""The drag frame's gather of polygons' light at an object's vertices, with the object's own visibility by
direction (app.stages.object_drag): one thread per vertex, no (vertices x polygons) array.

  E(i) = sum_j F(p_i, n_i -> polygon j) x vis[row_i, cell(R^T (c_j - p_i))] x w_ij x rad_j

F the unoccluded point-to-polygon form factor (kernels.formfactor.polygon_ff), vis the per-shape table of
the share of vertex row_i's PRT rays that leave the object per octahedral cell of direction (res^2 cells,
app.stages.object_drag.visibility_table), w an optional (vertices, polygons) factor (the room's
visibility of polygon j, interpolated to vertex i; 1 without), cell the octahedral cell of a direction in the object's own frame
(R: object to world rotation; object_drag._octa_cell's mapping), c_j the polygon's centre. Units: rad_j's
(radiance: E is irradiance / pi); positions in metres, float64 throughout.
"""
from __future__ import annotations

import numpy as np
import warp as wp

from kernels.buffers import Workspace
from kernels.formfactor import polygon_ff


@wp.func
def octa_cell(d: wp.vec3d, res: int) -> int:
    """The octahedral cell index in [0, res^2) of a direction d (object_drag._octa_cell)."""
    s = wp.abs(d[0]) + wp.abs(d[1]) + wp.abs(d[2])
    s = wp.max(s, wp.float64(1.0e-12))
    x = d[0] / s
    z = d[2] / s
    ox = x
    oz = z
    if d[1] / s < wp.float64(0.0):
        sx = wp.float64(1.0)
        if x + wp.float64(1.0e-30) < wp.float64(0.0):
            sx = wp.float64(-1.0)
        sz = wp.float64(1.0)
        if z + wp.float64(1.0e-30) < wp.float64(0.0):
            sz = wp.float64(-1.0)
        ox = (wp.float64(1.0) - wp.abs(z)) * sx
        oz = (wp.float64(1.0) - wp.abs(x)) * sz
    i = wp.clamp(int((ox + wp.float64(1.0)) * wp.float64(0.5) * wp.float64(res)), 0, res - 1)
    j = wp.clamp(int((oz + wp.float64(1.0)) * wp.float64(0.5) * wp.float64(res)), 0, res - 1)
    return i * res + j


@wp.kernel
def _gather_kernel(lo: int, points: wp.array(dtype=wp.vec3d), normals: wp.array(dtype=wp.vec3d),
                   rows: wp.array(dtype=wp.int32), vis: wp.array2d(dtype=wp.float32),
                   polys: wp.array2d(dtype=wp.vec3d), centres: wp.array(dtype=wp.vec3d),
                   rad: wp.array(dtype=wp.vec3d), m: int, k: int, Rt: wp.mat33d, res: int,
                   use_w: int, w: wp.array2d(dtype=wp.float64), out: wp.array(dtype=wp.vec3d)):
    i = lo + wp.tid()
    p = points[i]
    n = normals[i]
    acc = wp.vec3d(wp.float64(0.0), wp.float64(0.0), wp.float64(0.0))
    for j in range(m):
        f = polygon_ff(p, n, polys, j, k)
        if f > wp.float64(0.0):
            c = octa_cell(Rt * (centres[j] - p), res)
            g = f * wp.float64(vis[rows[i], c])
            if use_w != 0:
                g = g * w[i, j]
            acc = acc + rad[j] * g
    out[i] = acc


def gather_seen(points: np.ndarray, normals: np.ndarray, rows: np.ndarray, vis: wp.array, polygons: np.ndarray,
                radiance: np.ndarray, R: np.ndarray, res: int, device: str, workspace: Workspace,
                split=None, capacity: int = 0, weights: np.ndarray | None = None) -> np.ndarray:
    """(N,3) float64 E at points (N,3) with unit normals (N,3), each reading row rows[i] of the visibility
    table vis (a Warp (V, res^2) float32 array on `device`), of the polygons (M,K,3) (convex, emitting on the
    side of (v1-v0)x(v2-v0)) of radiance (M,3), R (3,3) the object's rotation (module docstring). workspace:
    the call site's buffers (kept); split(launch(lo, hi), N): how the launch is cut over the cores (None:
    one launch); capacity: the polygons the buffers hold at least; weights: w (N,M) or None (1)."""
    n, m = len(points), len(polygons)
    if n == 0 or m == 0:
        return np.zeros((n, 3))
    ws = workspace
    args = [ws.upload("points", np.asarray(points, np.float64), wp.vec3d, device),
            ws.upload("normals", np.asarray(normals, np.float64), wp.vec3d, device),
            ws.upload("rows", np.asarray(rows, np.int32), wp.int32, device), vis,
            ws.upload("polys", np.asarray(polygons, np.float64), wp.vec3d, device, capacity),
            ws.upload("centres", np.asarray(polygons, np.float64).mean(1), wp.vec3d, device, capacity),
            ws.upload("rad", np.asarray(radiance, np.float64), wp.vec3d, device, capacity),
            m, polygons.shape[1], wp.mat33d(*np.asarray(R, np.float64).T.ravel()), int(res), int(weights is not None),
            ws.upload("w", np.asarray(weights, np.float64), wp.float64, device, col_capacity=capacity)
            if weights is not None
            else ws.buffer("w0", 1, wp.float64, device, (1,)).dev]
    out = ws.buffer("out", n, wp.vec3d, device)

    def launch(a: int, b: int) -> None:
        wp.launch(_gather_kernel, dim=b - a, inputs=[a, *args], outputs=[out.dev], device=device)

    if split is None:
        launch(0, n)
    else:
        split(launch, n)
    return out.pull(n).copy()

