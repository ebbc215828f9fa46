"""Radiance SH9 at probe points of patches seen as disks (the drag frame's far changed patches,
app.stages.object_drag.disk_sh's launch): one thread per probe, a loop over the patches.

Per probe q and patch m (centre c, unit normal n, area a, radiance L (3,)), from the patch's emitting side:
  w = (c - q) / r, r = |c - q|;  cos = -(w . n);  omega = 2 pi (1 - r / sqrt(r^2 + a / pi)) cos  (cos > 0, else 0)
  SH[q, k, :] += Y_k(w) omega L
in float64 (lighting.sh.basis' products; the sum over the patches in patch order, where numpy's matmul blocks it).
"""
from __future__ import annotations

import numpy as np
import warp as wp

from kernels.buffers import Workspace
from kernels.sh9 import sh9_64


@wp.kernel
def _disk_sh_kernel(probes: wp.array(dtype=wp.vec3d), centres: wp.array(dtype=wp.vec3d),
                    normals: wp.array(dtype=wp.vec3d), areas: wp.array(dtype=wp.float64),
                    radiance: wp.array(dtype=wp.vec3d), m_count: int, pi: wp.float64, two_pi: wp.float64,
                    out: wp.array2d(dtype=wp.float64)):
    q = wp.tid()
    for k in range(27):
        out[q, k] = wp.float64(0.0)
    for m in range(m_count):
        dv = centres[m] - probes[q]
        r = wp.length(dv)
        w = dv / wp.max(r, wp.float64(1e-9))
        cos = -wp.dot(w, normals[m])
        if cos > wp.float64(0.0):
            omega = two_pi * (wp.float64(1.0) - r / wp.sqrt(r * r + areas[m] / pi)) * cos
            L = radiance[m]
            for k in range(9):
                y = sh9_64(w, k) * omega
                out[q, 3 * k + 0] += y * L[0]
                out[q, 3 * k + 1] += y * L[1]
                out[q, 3 * k + 2] += y * L[2]


def disk_sh_launch(probes: np.ndarray, centres: np.ndarray, normals: np.ndarray, areas: np.ndarray,
                   radiance: np.ndarray, device: str, workspace: Workspace, capacity: int = 0) -> np.ndarray:
    """(Q,9,3) float64: the module's sum for probes (Q,3) and patches centres, unit normals (M,3), areas (M,) m^2,
    radiance (M,3). workspace: the call site's buffers (kept; capacity: patches a call may bring, so that a
    later, larger call allocates nothing)."""
    Q, M = len(probes), len(centres)
    ws = workspace
    out = ws.buffer("sh", Q, wp.float64, device, (27,))
    wp.launch(_disk_sh_kernel, dim=Q, device=device,
              inputs=[ws.upload("probes", np.asarray(probes, np.float64), wp.vec3d, device),
                      ws.upload("centres", np.asarray(centres, np.float64), wp.vec3d, device, capacity),
                      ws.upload("normals", np.asarray(normals, np.float64), wp.vec3d, device, capacity),
                      ws.upload("areas", np.asarray(areas, np.float64), wp.float64, device, capacity),
                      ws.upload("radiance", np.asarray(radiance, np.float64), wp.vec3d, device, capacity), M, np.pi,
                      2 * np.pi],
              outputs=[out.dev[:Q]])
    return out.pull(Q)[:, :27].reshape(Q, 9, 3).copy()
