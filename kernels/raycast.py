"""ID/depth buffer: first triangle hit along each camera ray, with barycentrics (Warp kernel).

For pixel rays the result gives, per pixel, the receiver triangle and the weights that
interpolate per-vertex transfers across it (the seed lets graphics hardware do this; here a
ray cast does it exactly at pixel centres).
"""
from __future__ import annotations

import numpy as np
import warp as wp

from kernels import runtime
from kernels.visibility import Occluder


@wp.kernel
def _cast_kernel(mesh: wp.uint64, origins: wp.array(dtype=wp.vec3), stride: int, dirs: wp.array(dtype=wp.vec3),
                 max_t: float,
                 tri: wp.array(dtype=wp.int32), bary: wp.array(dtype=wp.vec3), depth: wp.array(dtype=wp.float32)):
    i = wp.tid()
    q = wp.mesh_query_ray(mesh, origins[i * stride], dirs[i], max_t)
    if q.result:
        tri[i] = q.face
        bary[i] = wp.vec3(q.u, q.v, 1.0 - q.u - q.v)  # Warp: p = u p0 + v p1 + (1-u-v) p2
        depth[i] = q.t
    else:
        tri[i] = -1
        bary[i] = wp.vec3(0.0, 0.0, 0.0)
        depth[i] = wp.inf


def cast_rays(mesh: Occluder, origin: np.ndarray, dirs: np.ndarray, max_t: float = 1e6):
    """Rays from one origin (3,), or one origin per ray (N,3), along unit dirs (N,3).

    Returns tri (N,) int32 (-1 = miss), bary (N,3) float32 weights of the triangle's 3 vertices,
    depth (N,) float32 distance along the ray in metres (inf on a miss).
    """
    device = mesh.device
    n = len(dirs)
    origins = np.asarray(origin, np.float32).reshape(-1, 3)
    if len(origins) not in (1, n):
        raise ValueError(f"cast_rays: {len(origins)} origins for {n} rays")
    tri = wp.empty(n, dtype=wp.int32, device=device)
    bary = wp.empty(n, dtype=wp.vec3, device=device)
    depth = wp.empty(n, dtype=wp.float32, device=device)
    wp.launch(_cast_kernel, dim=n,
              inputs=[wp.uint64(mesh.id), wp.array(origins, dtype=wp.vec3, device=device),
                      int(len(origins) > 1), wp.array(np.asarray(dirs, np.float32), dtype=wp.vec3, device=device), float(max_t)],
              outputs=[tri, bary, depth], device=device)
    return tri.numpy(), bary.numpy(), depth.numpy()


__all__ = ["cast_rays", "runtime"]
