"""Per-vertex self-occlusion transfer of the object (precomputed radiance transfer, diffuse).

Sloan, Kautz & Snyder, "Precomputed radiance transfer", SIGGRAPH 2002: a vertex with normal n
sees the room's radiance L(w) only where the object does not hide it, so its irradiance / pi is
sum_lm L_lm T_lm with the transfer vector T_lm = (1/pi) int V(w) max(0, n.w) Y_lm(w) dw. Here T is
estimated with `n_dirs` cosine-distributed directions (a Fibonacci spiral, deterministic):
T_lm = mean_k V(w_k) Y_lm(w_k). Unoccluded, T_lm = A_l Y_lm(n) / pi exactly as in lighting/sh.py.

Shapes: points/normals (V,3) world; returns (V,9) float32, dimensionless.
"""
from __future__ import annotations

import numpy as np
import warp as wp

from kernels import runtime
from kernels.visibility import Occluder


@wp.func
def _sh9(d: wp.vec3, k: int) -> float:
    x = d[0]
    y = d[1]
    z = d[2]
    if k == 0:
        return 0.282094791773878
    if k == 1:
        return 0.488602511902920 * y
    if k == 2:
        return 0.488602511902920 * z
    if k == 3:
        return 0.488602511902920 * x
    if k == 4:
        return 1.092548430592079 * x * y
    if k == 5:
        return 1.092548430592079 * y * z
    if k == 6:
        return 0.315391565252520 * (3.0 * z * z - 1.0)
    if k == 7:
        return 1.092548430592079 * x * z
    return 0.546274215296040 * (x * x - y * y)


@wp.kernel
def _transfer_kernel(points: wp.array(dtype=wp.vec3), normals: wp.array(dtype=wp.vec3), mesh: wp.uint64,
                     n_dirs: int, eps: float, max_dist: float, out: wp.array2d(dtype=wp.float32),
                     hit_face: wp.array2d(dtype=wp.int32), hit_bary: wp.array2d(dtype=wp.vec3)):
    i = wp.tid()
    n = normals[i]
    p = points[i] + n * eps
    helper = wp.vec3(1.0, 0.0, 0.0)
    if wp.abs(n[0]) > 0.9:
        helper = wp.vec3(0.0, 1.0, 0.0)
    t1 = wp.normalize(wp.cross(helper, n))
    t2 = wp.cross(n, t1)
    acc = wp.vector(dtype=wp.float32, length=9)
    for k in range(n_dirs):
        u = (float(k) + 0.5) / float(n_dirs)
        phi = float(k) * 2.399963229728653  # golden angle
        r = wp.sqrt(u)
        d = t1 * (r * wp.cos(phi)) + t2 * (r * wp.sin(phi)) + n * wp.sqrt(1.0 - u)
        q = wp.mesh_query_ray(mesh, p, d, max_dist)
        if not q.result:
            for c in range(9):
                acc[c] += _sh9(d, c)
            hit_face[i, k] = -1
        else:
            hit_face[i, k] = q.face
            hit_bary[i, k] = wp.vec3(q.u, q.v, 1.0 - q.u - q.v)  # Warp: p = u p0 + v p1 + (1-u-v) p2
    for c in range(9):
        out[i, c] = acc[c] / float(n_dirs)


def self_transfer(points: np.ndarray, normals: np.ndarray, mesh: Occluder, n_dirs: int = 128,
                  eps: float = 1e-3, device: str | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Transfer vectors (V,9) of the object's own occlusion at its vertices, and for every
    direction the object triangle it hits (V,n_dirs) int32 (-1: none) with barycentrics
    (V,n_dirs,3), for one bounce of light between the object's parts."""
    device = runtime.device(device)
    n = len(points)
    if n == 0:
        return np.zeros((0, 9), np.float32), np.zeros((0, n_dirs), np.int32), np.zeros((0, n_dirs, 3), np.float32)
    out = wp.zeros((n, 9), dtype=wp.float32, device=device)
    face = wp.zeros((n, n_dirs), dtype=wp.int32, device=device)
    bary = wp.zeros((n, n_dirs), dtype=wp.vec3, device=device)
    pts = wp.array(np.asarray(points, np.float32), dtype=wp.vec3, device=device)
    nrm = wp.array(np.asarray(normals, np.float32), dtype=wp.vec3, device=device)
    wp.launch(_transfer_kernel, dim=n, inputs=[pts, nrm, wp.uint64(mesh.id), int(n_dirs), float(eps), 1.0e3],
              outputs=[out, face, bary], device=device)
    return out.numpy(), face.numpy(), bary.numpy()
