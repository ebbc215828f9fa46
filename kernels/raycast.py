"""ID/depth buffer: first triangle hit along each camera ray, with barycentrics (Warp kernel).

For pixel rays the result gives, per pixel, the receiver triangle and the weights that
interpolate per-vertex transfers across it (the seed lets graphics hardware do this; here a
ray cast does it exactly at pixel centres).
"""
from __future__ import annotations

import numpy as np
import warp as wp

from kernels import runtime
from kernels.buffers import Workspace, call_buffers
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


def cast_rays(mesh: Occluder, origin: np.ndarray, dirs: np.ndarray, max_t: float = 1e6,
              workspace: Workspace | None = None):
    """Rays from one origin (3,), or one origin per ray (N,3), along unit dirs (N,3).

    Returns tri (N,) int32 (-1 = miss), bary (N,3) float32 weights of the triangle's 3 vertices,
    depth (N,) float32 distance along the ray in metres (inf on a miss). `workspace`: the call
    site's buffers (kernels.buffers.Workspace), kept between calls: the rays are cast in blocks of
    its capacity and nothing is allocated after its first call (None: fresh buffers, one launch).
    """
    device = mesh.device
    n = len(dirs)
    origins = np.asarray(origin).reshape(-1, 3)
    if len(origins) not in (1, n):
        raise ValueError(f"cast_rays: {len(origins)} origins for {n} rays")
    ws, block = call_buffers(workspace, n)
    tri_out = np.empty(n, np.int32)
    bary_out = np.empty((n, 3), np.float32)
    depth_out = np.empty(n, np.float32)
    tri = ws.buffer("tri", block, wp.int32, device)
    bary = ws.buffer("bary", block, wp.vec3, device)
    depth = ws.buffer("depth", block, wp.float32, device)
    dirs = np.asarray(dirs)  # cast to float32 as it is copied into the buffer
    for s in range(0, n, block):
        e = min(n, s + block)
        o = origins if len(origins) == 1 else origins[s:e]
        wp.launch(_cast_kernel, dim=e - s,
                  inputs=[wp.uint64(mesh.id), ws.upload("origins", o, wp.vec3, device, block),
                          int(len(origins) > 1), ws.upload("dirs", dirs[s:e], wp.vec3, device, block), float(max_t)],
                  outputs=[tri.dev[:e - s], bary.dev[:e - s], depth.dev[:e - s]], device=device)
        tri_out[s:e], bary_out[s:e], depth_out[s:e] = tri.pull(e - s), bary.pull(e - s), depth.pull(e - s)
    return tri_out, bary_out, depth_out


__all__ = ["cast_rays", "runtime"]
