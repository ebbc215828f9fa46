"""Radiance-transfer kernels: form factor x ray-cast visibility (seed sec. 6.1).

`transfer_matrix` gives, for receiver points i and source patches j, the dimensionless
G_ij = F_ij * V_ij: the analytic point-to-patch form factor (kernels.formfactor) times the fraction
of `n_vis` stratified points on patch j visible from point i. The radiance patch j sends to i and
i reflects towards the camera is then L_ij = rho_i * B_j * G_ij.

Occluders are one or two Warp meshes: the scene model, and optionally the synthetic object's
proxy (for the object's own self-occlusion when it is the receiver). Ray ends are pulled back by
`eps` metres along both surface normals so surfaces touching at a corner do not occlude
themselves.
"""
from __future__ import annotations

import numpy as np
import warp as wp

from kernels import runtime
from kernels.formfactor import polygon_ff


@wp.func
def segment_blocked(mesh: wp.uint64, a: wp.vec3, b: wp.vec3) -> bool:
    """True when the open segment a->b hits a triangle of `mesh` (mesh 0 = no occluder)."""
    if mesh == wp.uint64(0):
        return False
    d = b - a
    dist = wp.length(d)
    if dist <= 1.0e-9:
        return False
    q = wp.mesh_query_ray(mesh, a, d / dist, dist * 0.9999)
    return q.result


@wp.kernel
def _transfer_kernel(
    points: wp.array(dtype=wp.vec3d),
    normals: wp.array(dtype=wp.vec3d),
    polys: wp.array2d(dtype=wp.vec3d),
    poly_normals: wp.array(dtype=wp.vec3),
    mesh_a: wp.uint64,
    mesh_b: wp.uint64,
    n_side: int,
    eps: float,
    out: wp.array2d(dtype=wp.float32),
):
    i, j = wp.tid()
    p = points[i]
    n = normals[i]
    f = polygon_ff(p, n, polys, j, 4)
    if f <= wp.float64(0.0):
        out[i, j] = 0.0
        return
    a = wp.vec3(p) + wp.vec3(n) * eps
    c0 = wp.vec3(polys[j, 0])
    eu = wp.vec3(polys[j, 1]) - c0
    ev = wp.vec3(polys[j, 3]) - c0
    ns = poly_normals[j] * eps
    seen = int(0)
    for su in range(n_side):
        for sv in range(n_side):
            fu = (float(su) + 0.5) / float(n_side)
            fv = (float(sv) + 0.5) / float(n_side)
            b = c0 + eu * fu + ev * fv + ns
            if not segment_blocked(mesh_a, a, b):
                if not segment_blocked(mesh_b, a, b):
                    seen += 1
    out[i, j] = float(f) * float(seen) / float(n_side * n_side)


@wp.kernel
def _visibility_kernel(mesh: wp.uint64, a: wp.array(dtype=wp.vec3), b: wp.array(dtype=wp.vec3),
                       out: wp.array(dtype=wp.int32)):
    i = wp.tid()
    out[i] = wp.where(segment_blocked(mesh, a[i], b[i]), 0, 1)


class Occluder:
    """A Warp BVH mesh kept alive with its buffers; `id` is 0 when empty (nothing occludes)."""

    def __init__(self, vertices: np.ndarray | None, triangles: np.ndarray | None, device: str | None = None):
        self.device = runtime.device(device)
        self.mesh = None
        if vertices is not None and triangles is not None and len(triangles):
            self._pts = wp.array(np.asarray(vertices, np.float32), dtype=wp.vec3, device=self.device)
            self._idx = wp.array(np.asarray(triangles, np.int32).reshape(-1), dtype=wp.int32, device=self.device)
            self.mesh = wp.Mesh(points=self._pts, indices=self._idx)

    @property
    def id(self) -> int:
        return int(self.mesh.id) if self.mesh is not None else 0


def transfer_matrix(points: np.ndarray, normals: np.ndarray, patch_corners: np.ndarray,
                    patch_normals: np.ndarray, occluders: list[Occluder], n_side: int = 2,
                    eps: float = 1e-4, device: str | None = None, progress=None,
                    chunk: int = 256) -> np.ndarray:
    """G (N,M) float32 = form factor x visibility from points (N,3) [normals (N,3)] to quads (M,4,3).

    `occluders`: up to two Occluder meshes; `n_side`^2 visibility samples per patch;
    `progress`: optional callable(n_done) called after each chunk of receiver points.
    """
    device = runtime.device(device)
    n, m = len(points), len(patch_corners)
    out = np.zeros((n, m), np.float32)
    if n == 0 or m == 0:
        return out
    occ = list(occluders) + [Occluder(None, None, device)] * (2 - len(occluders))
    polys = wp.array(np.asarray(patch_corners, np.float64), dtype=wp.vec3d, device=device)
    pn = wp.array(np.asarray(patch_normals, np.float32), dtype=wp.vec3, device=device)
    def run(s: int) -> int:
        e = min(n, s + chunk)
        res = wp.zeros((e - s, m), dtype=wp.float32, device=device)
        wp.launch(_transfer_kernel, dim=(e - s, m),
                  inputs=[wp.array(np.asarray(points[s:e], np.float64), dtype=wp.vec3d, device=device),
                          wp.array(np.asarray(normals[s:e], np.float64), dtype=wp.vec3d, device=device),
                          polys, pn, wp.uint64(occ[0].id), wp.uint64(occ[1].id), int(n_side), float(eps)],
                  outputs=[res], device=device)
        out[s:e] = res.numpy()
        return e - s

    starts = list(range(0, n, chunk))
    for k in range(0, len(starts), 2):  # two chunks at a time: one per core on the CPU
        done = runtime.run_parallel([lambda s=s: run(s) for s in starts[k:k + 2]])
        if progress is not None:
            for d in done:
                progress(d)
    return out


def segments_visible(occluder: Occluder, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(N,) int32: 1 where segment a_i->b_i is unblocked by the occluder mesh (throughput benchmarks)."""
    device = occluder.device
    out = wp.zeros(len(a), dtype=wp.int32, device=device)
    wp.launch(_visibility_kernel, dim=len(a),
              inputs=[wp.uint64(occluder.id), wp.array(np.asarray(a, np.float32), dtype=wp.vec3, device=device),
                      wp.array(np.asarray(b, np.float32), dtype=wp.vec3, device=device)],
              outputs=[out], device=device)
    return out.numpy()


@wp.kernel
def _emitter_sum_kernel(points: wp.array(dtype=wp.vec3d), normals: wp.array(dtype=wp.vec3d),
                        tris: wp.array2d(dtype=wp.vec3d), radiance: wp.array(dtype=wp.vec3),
                        tri_normals: wp.array(dtype=wp.vec3), mesh: wp.uint64, eps: float,
                        out: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    p = points[i]
    n = normals[i]
    a = wp.vec3(p) + wp.vec3(n) * eps
    total = wp.vec3(0.0, 0.0, 0.0)
    for t in range(tris.shape[0]):
        f = polygon_ff(p, n, tris, t, 3)
        if f > wp.float64(0.0):
            centroid = wp.vec3((tris[t, 0] + tris[t, 1] + tris[t, 2]) / wp.float64(3.0))
            if not segment_blocked(mesh, a, centroid + tri_normals[t] * eps):
                total += radiance[t] * float(f)
    out[i] = total


def emitter_sum(points: np.ndarray, normals: np.ndarray, triangles: np.ndarray, radiance: np.ndarray,
                occluder: Occluder | None = None, eps: float = 1e-3, device: str | None = None,
                split: int = 2048) -> np.ndarray:
    """sum_t B_t F(x -> t) V(x, t): radiance-weighted form factors to emitting triangles.

    points/normals (N,3); triangles (T,3,3) vertices CCW seen from the emitting side; radiance (T,3);
    visibility of each triangle's centroid is tested against `occluder` (e.g. the object itself, so
    its hidden faces do not count). Returns (N,3) float64 (= irradiance / pi). On the CPU more than
    `split` points are run as two launches, one per core (runtime.run_parallel).
    """
    device = runtime.device(device)
    n = len(points)
    if n == 0 or len(triangles) == 0:
        return np.zeros((n, 3))
    tri = np.asarray(triangles, np.float64)
    tn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    tn /= np.maximum(np.linalg.norm(tn, axis=1, keepdims=True), 1e-12)
    shared = [wp.array(tri, dtype=wp.vec3d, device=device),
              wp.array(np.asarray(radiance, np.float32), dtype=wp.vec3, device=device),
              wp.array(tn.astype(np.float32), dtype=wp.vec3, device=device),
              wp.uint64(occluder.id if occluder is not None else 0), float(eps)]
    points, normals = np.asarray(points, np.float64), np.asarray(normals, np.float64)

    def run(s: int, e: int) -> np.ndarray:
        out = wp.zeros(e - s, dtype=wp.vec3, device=device)
        wp.launch(_emitter_sum_kernel, dim=e - s,
                  inputs=[wp.array(points[s:e], dtype=wp.vec3d, device=device),
                          wp.array(normals[s:e], dtype=wp.vec3d, device=device), *shared],
                  outputs=[out], device=device)
        return out.numpy().astype(np.float64)

    if n <= split or not wp.get_device(device).is_cpu:
        return run(0, n)
    return np.concatenate(runtime.run_parallel([lambda: run(0, n // 2), lambda: run(n // 2, n)]))


@wp.kernel
def _distance_kernel(mesh: wp.uint64, points: wp.array(dtype=wp.vec3), max_dist: float,
                     out: wp.array(dtype=wp.float32)):
    i = wp.tid()
    p = points[i]
    q = wp.mesh_query_point_no_sign(mesh, p, max_dist)
    if q.result:
        out[i] = wp.length(wp.mesh_eval_position(mesh, q.face, q.u, q.v) - p)
    else:
        out[i] = max_dist


def distance_to(occluder: Occluder, points: np.ndarray, max_dist: float = 1.0e3) -> np.ndarray:
    """(N,) float32 distance from points (N,3) to the nearest triangle of the occluder mesh (m;
    `max_dist` where none lies within it or the mesh is empty)."""
    n = len(points)
    if n == 0 or occluder.mesh is None:
        return np.full(n, max_dist, np.float32)
    device = occluder.device
    out = wp.empty(n, dtype=wp.float32, device=device)
    wp.launch(_distance_kernel, dim=n, inputs=[wp.uint64(occluder.id),
                                               wp.array(np.asarray(points, np.float32), dtype=wp.vec3, device=device),
                                               float(max_dist)], outputs=[out], device=device)
    return out.numpy()

