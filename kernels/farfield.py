"""Point emitters with a per-emitter visibility table: the far field of a small object's light.

Beyond a few bounding radii each emitting triangle (or lit piece) of an object subtends a small
solid angle and acts as a point source: B_t A_t cos_x cos_t / (pi r^2), times the fraction of the
direction from the emitter towards the receiver that leaves the object (a cube-map table per
emitter, kernels.visibility.cube_cell's layout, made once per object shape). Irradiance / pi.
"""
from __future__ import annotations

import numpy as np
import warp as wp

from kernels import runtime
from kernels.buffers import Buffer, Workspace, call_buffers
from kernels.visibility import _point_launches, cube_cell, seen_table


@wp.kernel
def _point_emitters_kernel(points: wp.array(dtype=wp.vec3d), normals: wp.array(dtype=wp.vec3d),
                           centres: wp.array(dtype=wp.vec3d), area_normals: wp.array(dtype=wp.vec3d),
                           radiance: wp.array(dtype=wp.vec3), seen: wp.array2d(dtype=wp.float32), res: int,
                           out: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    p = points[i]
    n = normals[i]
    total = wp.vec3(0.0, 0.0, 0.0)
    for t in range(centres.shape[0]):
        d = centres[t] - p  # receiver -> emitter
        cos_x = wp.dot(d, n)
        cos_t = -wp.dot(d, area_normals[t])  # |area_normals| = 2 area; both cosines carry 1/r
        if cos_x > wp.float64(0.0) and cos_t > wp.float64(0.0):
            w = seen[t, cube_cell(wp.vec3(-d), res)]
            if w > 0.0:
                r2 = wp.dot(d, d)
                g = cos_x * cos_t * wp.float64(0.5) / (wp.float64(wp.pi) * r2 * r2)
                total += radiance[t] * (float(g) * w)
    out[i] = total


def point_emitter_sum(points: np.ndarray, normals: np.ndarray, centres: np.ndarray, area_normals: np.ndarray,
                      radiance: np.ndarray, seen: np.ndarray, res: int, device: str | None = None,
                      split: int = 2048, workspace: Workspace | None = None, capacity: int = 0) -> np.ndarray:
    """sum_t B_t A_t cos_x cos_t / (pi r^2) seen_t(x) (N,3) float64 (= irradiance / pi) at points (N,3)
    [unit normals (N,3)] from point emitters at centres (F,3) with area_normals (F,3) = twice the area x
    the unit normal, radiance (F,3) and visibility table seen (F, 6 res^2) (bool or the fraction of
    the cell's directions that leave the occluder). workspace: the call site's buffers, nothing
    allocated after the first call while F <= max(capacity, the first F); None: fresh buffers."""
    device = runtime.device(device)
    n = len(points)
    if n == 0 or len(centres) == 0:
        return np.zeros((n, 3))
    ws, block = call_buffers(workspace, n)
    shared = [ws.upload("centres", np.asarray(centres, np.float64), wp.vec3d, device, capacity),
              ws.upload("area_normals", np.asarray(area_normals, np.float64), wp.vec3d, device, capacity),
              ws.upload("radiance", np.asarray(radiance, np.float32), wp.vec3, device, capacity),
              seen_table(ws, seen, wp.float32, device, capacity), int(res)]
    return _point_launches(_point_emitters_kernel, points, normals, shared, ws, block, device, split)


@wp.kernel
def _interpolate_kernel(pix_patch: wp.array(dtype=wp.int32), pix_rows: wp.array2d(dtype=wp.int32),
                        pix_bary: wp.array2d(dtype=wp.float32), patch_on: wp.array(dtype=wp.uint8),
                        values: wp.array(dtype=wp.vec3), out: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    p = pix_patch[i]
    v = wp.vec3(0.0, 0.0, 0.0)
    if p >= 0:
        if patch_on[p] != wp.uint8(0):
            for k in range(3):
                v += values[pix_rows[i, k]] * pix_bary[i, k]
    out[i] = v


class VertexInterpolation:
    """Per-vertex values interpolated onto the pixels of a set of patches (one kernel over the frame,
    no pixel list): pixel i of patch pix_patch[i] >= 0 takes sum_k pix_bary[i,k] values[pix_rows[i,k]].
    The per-scene tables are uploaded once; per frame the patches and the values (buffers made on
    the first call at the scene's size: nothing allocated after)."""

    def __init__(self, pix_patch: np.ndarray, pix_rows: np.ndarray, pix_bary: np.ndarray, n_patches: int,
                 n_values: int, device: str | None = None):
        self.device = runtime.device(device)
        n = len(pix_patch)
        self._patch = Buffer(n, wp.int32, self.device, fill=np.asarray(pix_patch, np.int32))
        self._rows = Buffer((n, 3), wp.int32, self.device, fill=np.maximum(np.asarray(pix_rows), 0).astype(np.int32))
        self._bary = Buffer((n, 3), wp.float32, self.device, fill=np.asarray(pix_bary, np.float32))
        self._on = Buffer(max(n_patches, 1), wp.uint8, self.device)
        self._values = Buffer(max(n_values, 1), wp.vec3, self.device)
        self._out = Buffer(n, wp.vec3, self.device)

    def run(self, patch_on: np.ndarray, values: np.ndarray) -> np.ndarray:
        """(N,3) float64: the interpolated values on the pixels of the patches where patch_on (P,) bool,
        0 elsewhere; values (n_values,3)."""
        self._on.upload(np.asarray(patch_on, np.uint8))
        self._values.upload(np.asarray(values, np.float32))
        wp.launch(_interpolate_kernel, dim=self._out.capacity,
                  inputs=[self._patch.dev, self._rows.dev, self._bary.dev, self._on.dev, self._values.dev],
                  outputs=[self._out.dev], device=self.device)
        return self._out.pull().astype(np.float64)
