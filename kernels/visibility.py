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
from kernels.buffers import Workspace, call_buffers
from kernels.formfactor import polygon_ff
from kernels.vec import cross3


@wp.func
def segment_blocked(mesh: wp.uint64, a: wp.vec3, b: wp.vec3) -> bool:
    """True when the open segment a->b hits a triangle of `mesh` (mesh 0 = no occluder). An any-hit
    query: it stops at the first triangle met, not the nearest (the same yes/no)."""
    if mesh == wp.uint64(0):
        return False
    d = b - a
    dist = wp.length(d)
    if dist <= 1.0e-9:
        return False
    return wp.mesh_query_ray_anyhit(mesh, a, d / dist, dist * 0.9999)


@wp.func
def segment_meets_box(p: wp.vec3, q: wp.vec3, lo: wp.vec3, hi: wp.vec3) -> bool:
    """True when the segment p-q meets the box lo..hi (slab test: else nothing inside the box can block
    it; a segment from p to any point within r of q lies within r of p-q, so a box widened by r bounds
    the segments from p to a sphere (q, r))."""
    t0 = float(0.0)
    t1 = float(1.0)
    d = q - p
    meets = bool(True)
    for k in range(3):
        if wp.abs(d[k]) < 1.0e-12:
            if p[k] < lo[k] or p[k] > hi[k]:
                meets = False
        else:
            ta = (lo[k] - p[k]) / d[k]
            tb = (hi[k] - p[k]) / d[k]
            t0 = wp.max(t0, wp.min(ta, tb))
            t1 = wp.min(t1, wp.max(ta, tb))
    return meets and t0 <= t1


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
    free: wp.array2d(dtype=wp.uint8),
    res: int,
    row0: int,
    out: wp.array2d(dtype=wp.float32),
):
    # free (res > 0): per point row0 + i the cube cells where no ray can meet mesh_b (no ray there)
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
                ab = b - a
                clear = False
                if res > 0 and wp.dot(ab, wp.vec3(n)) > 0.0:  # the segment stays in front of the point's surface
                    clear = free[row0 + i, cube_cell(ab, res)] != wp.uint8(0)
                if clear:
                    seen += 1
                elif not segment_blocked(mesh_b, a, b):
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

    def triangles(self) -> np.ndarray:
        """The mesh's triangles (T,3,3) float64 m, read back from its buffers ((0,3,3) when empty)."""
        if self.mesh is None:
            return np.zeros((0, 3, 3))
        return self._pts.numpy().astype(np.float64)[self._idx.numpy().reshape(-1, 3)]

    def move(self, vertices: np.ndarray) -> None:
        """The same triangles at new vertex positions (V,3) m: copied into the mesh's buffer and the
        BVH refit (Warp Mesh.refit; nothing allocated). No-op when empty."""
        if self.mesh is not None:
            self._pts.assign(np.asarray(vertices, np.float32))
            self.mesh.refit()


def transfer_matrix(points: np.ndarray, normals: np.ndarray, patch_corners: np.ndarray,
                    patch_normals: np.ndarray, occluders: list[Occluder], n_side: int = 2,
                    eps: float = 1e-4, device: str | None = None, progress=None,
                    chunk: int = 256, workspace: Workspace | None = None, free: np.ndarray | None = None,
                    free_res: int = 0) -> np.ndarray:
    """G (N,M) float32 = form factor x visibility from points (N,3) [normals (N,3)] to quads (M,4,3).

    `occluders`: up to two Occluder meshes; `n_side`^2 visibility samples per patch;
    `progress`: optional callable(n_done) called after each chunk of receiver points;
    `workspace`: the call site's buffers (kernels.buffers.Workspace), kept between calls: the
    patches go in blocks of its capacity and nothing is allocated after its first call (None:
    fresh buffers, every patch in one launch). `free`: optional (N, 6 free_res^2) bool, per point the
    cube cells (cube_cell) of directions from it + eps x its normal in which no ray can meet the
    second occluder (e.g. the points are an object's triangles, the second occluder the object:
    app.stages.object_light.free_cells): no ray against it there (the same G, fewer rays).
    """
    device = runtime.device(device)
    n, m = len(points), len(patch_corners)
    out = np.zeros((n, m), np.float32)
    if n == 0 or m == 0:
        return out
    occ = list(occluders) + [Occluder(None, None, device)] * (2 - len(occluders))
    if workspace is None:  # every patch in one launch per chunk, fresh buffers
        ws, rows, cols = Workspace(), min(n, chunk), m
    else:  # the workspace's capacity: `chunk` points x ws.sources patches per launch
        ws, rows, cols = workspace, chunk, workspace.sources
    points, normals = np.asarray(points, np.float64), np.asarray(normals, np.float64)
    patch_corners, patch_normals = np.asarray(patch_corners, np.float64), np.asarray(patch_normals, np.float32)
    table = seen_table(ws, free, wp.uint8, device) if free is not None else _no_table(device)
    free_res = free_res if free is not None else 0
    for c0 in range(0, m, cols):
        c1 = min(m, c0 + cols)
        polys = ws.upload("polys", patch_corners[c0:c1], wp.vec3d, device, cols)
        pn = ws.upload("poly_normals", patch_normals[c0:c1], wp.vec3, device, cols)

        def run(s: int, slot: int) -> int:  # slot: which of the two concurrent launches (its own buffers)
            e = min(n, s + chunk)
            res = ws.buffer(f"out{slot}", rows, wp.float32, device, (cols,))
            inputs = [ws.upload(f"points{slot}", points[s:e], wp.vec3d, device, rows),
                      ws.upload(f"normals{slot}", normals[s:e], wp.vec3d, device, rows),
                      polys, pn, wp.uint64(occ[0].id), wp.uint64(occ[1].id), int(n_side), float(eps)]
            wp.launch(_transfer_kernel, dim=(e - s, c1 - c0), inputs=[*inputs, table, int(free_res), s],
                      outputs=[res.dev[:e - s, :c1 - c0]], device=device)
            out[s:e, c0:c1] = res.pull(e - s)[:, :c1 - c0]
            return e - s

        starts = list(range(0, n, chunk))
        for k in range(0, len(starts), 2):  # two chunks at a time: one per core on the CPU
            done = runtime.run_parallel([lambda s=s, i=i: run(s, i) for i, s in enumerate(starts[k:k + 2])])
            if progress is not None and c1 == m:
                for d in done:
                    progress(d)
    return out


def segments_visible(occluder: Occluder, a: np.ndarray, b: np.ndarray, workspace: Workspace | None = None
                     ) -> np.ndarray:
    """(N,) int32: 1 where segment a_i->b_i is unblocked by the occluder mesh. `workspace`: the call site's
    buffers (kernels.buffers.Workspace), launches of at most its `rows` segments, nothing allocated once
    they exist (None: fresh arrays, one launch)."""
    device = occluder.device
    if workspace is not None:
        n, step = len(a), workspace.rows
        out = np.empty(n, np.int32)
        for lo in range(0, n, step):
            hi = min(lo + step, n)
            da = workspace.upload("a", np.asarray(a[lo:hi], np.float32), wp.vec3, device, capacity=step)
            db = workspace.upload("b", np.asarray(b[lo:hi], np.float32), wp.vec3, device, capacity=step)
            ob = workspace.buffer("out", step, wp.int32, device)
            wp.launch(_visibility_kernel, dim=hi - lo, inputs=[wp.uint64(occluder.id), da, db], outputs=[ob.dev],
                      device=device)
            out[lo:hi] = ob.pull(hi - lo)
        return out
    out = wp.zeros(len(a), dtype=wp.int32, device=device)
    wp.launch(_visibility_kernel, dim=len(a),
              inputs=[wp.uint64(occluder.id), wp.array(np.asarray(a, np.float32), dtype=wp.vec3, device=device),
                      wp.array(np.asarray(b, np.float32), dtype=wp.vec3, device=device)],
              outputs=[out], device=device)
    return out.numpy()


def emitter_sum(points: np.ndarray, normals: np.ndarray, triangles: np.ndarray, radiance: np.ndarray,
                occluder: Occluder | None = None, eps: float = 1e-3, device: str | None = None,
                split: int = 2048, workspace: Workspace | None = None, free: np.ndarray | None = None,
                free_res: int = 0) -> np.ndarray:
    """sum_t B_t F(x -> t) V(x, t): radiance-weighted form factors to emitting triangles.

    points/normals (N,3); triangles (T,3,3) vertices CCW seen from the emitting side; radiance (T,3);
    visibility of each triangle's centroid is tested against `occluder` (e.g. the object itself, so
    its hidden faces do not count). Returns (N,3) float64 (= irradiance / pi). On the CPU more than
    `split` points are run as two launches, one per core (runtime.run_parallel). `workspace`: the
    call site's buffers (kernels.buffers.Workspace), kept between calls: launches of at most its
    capacity in points, nothing allocated after its first call for a given set of triangles
    (None: fresh buffers). free: optional (T, 6 free_res^2) bool, per triangle the cube cells
    (cube_cell) of directions from its centroid + eps x its normal in which no ray can meet the
    occluder (a conservative table, e.g. app.stages.object_light.free_cells): a receiver in front
    of the triangle whose direction falls in such a cell needs no ray (the same sum, fewer rays).
    """
    device = runtime.device(device)
    n = len(points)
    if n == 0 or len(triangles) == 0:
        return np.zeros((n, 3))
    ws, block = call_buffers(workspace, n)  # None: fresh buffers, one launch per half
    shared = _ray_inputs(ws, triangles, radiance, occluder, eps, device, free, free_res)
    return _point_launches(_emitter_sum_kernel, points, normals, shared, ws, block, device, split)


def _ray_inputs(ws: Workspace, triangles: np.ndarray, radiance: np.ndarray, occluder: Occluder | None, eps: float,
                device: str, free: np.ndarray | None, free_res: int) -> list:
    """_ray_emitters's inputs (emitter_sum's triangles, radiance, normals, occluder, eps and free table)
    pushed into ws's buffers."""
    tri = np.asarray(triangles, np.float64)
    tn = cross3(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    tn /= np.maximum(np.linalg.norm(tn, axis=1, keepdims=True), 1e-12)
    shared = [ws.upload("tris", tri, wp.vec3d, device),
              ws.upload("radiance", np.asarray(radiance, np.float32), wp.vec3, device),
              ws.upload("tri_normals", tn.astype(np.float32), wp.vec3, device),
              wp.uint64(occluder.id if occluder is not None else 0), float(eps)]
    if free is None:
        shared += [_no_table(device), 0]
    else:
        shared += [seen_table(ws, free, wp.uint8, device), int(free_res)]
    return shared


_NO_TABLE: dict[str, wp.array] = {}


def _no_table(device: str) -> wp.array:
    """A 1x1 stand-in for a kernel's `free` table when there is none (res 0), one per device."""
    if device not in _NO_TABLE:
        _NO_TABLE[device] = wp.zeros((1, 1), dtype=wp.uint8, device=device)
    return _NO_TABLE[device]


def _point_launches(kernel, points: np.ndarray, normals: np.ndarray, shared: list, ws: Workspace, block: int,
                    device: str, split: int, outputs: int = 1):
    """kernel(points, normals, *shared, out) over N points in launches of at most `block` points,
    the two halves side by side (one per core) on the CPU when N > split: (N,3) float64 (outputs > 1:
    kernel(..., out, out2, ...), a tuple of that many)."""
    n = len(points)
    points, normals = np.asarray(points, np.float64), np.asarray(normals, np.float64)
    outs = [np.empty((n, 3)) for _ in range(outputs)]
    out = outs[0]

    def run(s: int, e: int, slot: int) -> None:  # slot: which concurrent launch (its own buffers)
        res = [ws.buffer(f"out{slot}" + (f"_{k}" if k else ""), block, wp.vec3, device) for k in range(outputs)]
        wp.launch(kernel, dim=e - s,
                  inputs=[ws.upload(f"points{slot}", points[s:e], wp.vec3d, device, block),
                          ws.upload(f"normals{slot}", normals[s:e], wp.vec3d, device, block), *shared],
                  outputs=[r.dev[:e - s] for r in res], device=device)
        for o, r in zip(outs, res):
            o[s:e] = r.pull(e - s)

    cpu = wp.get_device(device).is_cpu
    halves = [(0, n)] if n <= split or not cpu else [(0, n // 2), (n // 2, n)]
    # a kept workspace (blocks of its rows) gets both slots' buffers on its first call: a later call of more than
    # `split` points (a drag's object light as the object moves) then splits over both without allocating
    for slot in range(2 if cpu and block == ws.rows else 1):
        for k in range(outputs):
            ws.buffer(f"out{slot}" + (f"_{k}" if k else ""), block, wp.vec3, device)
        for name in ("points", "normals"):
            ws.buffer(f"{name}{slot}", block, wp.vec3d, device)
    parts = [[(s, min(e, s + block)) for s in range(a, e, block)] for a, e in halves]
    for k in range(max(len(p) for p in parts)):  # the halves side by side, one per core on the CPU
        runtime.run_parallel([lambda r=p[k], i=i: run(*r, i) for i, p in enumerate(parts) if k < len(p)])
    return out if outputs == 1 else tuple(outs)


@wp.func
def cube_cell(d: wp.vec3, r: int) -> int:
    """Cube-map cell of direction d (any length): face 2 axis + (negative), then r x r cells over
    the other two coordinates in axis order (app.stages.object_light._cube_bin's layout). The axis by
    branches (the first largest |d_k|, with its next two coordinates), not an index modulo 3: the same
    cell, fewer operations (a sunlit piece's table is read once per piece and receiver)."""
    m = wp.abs(d[0])
    u = d[1]
    v = d[2]
    face = int(0)
    if d[0] < 0.0:
        face = 1
    if wp.abs(d[1]) > m:
        m = wp.abs(d[1])
        u = d[2]
        v = d[0]
        face = 2
        if d[1] < 0.0:
            face = 3
    if wp.abs(d[2]) > m:
        m = wp.abs(d[2])
        u = d[0]
        v = d[1]
        face = 4
        if d[2] < 0.0:
            face = 5
    m = wp.max(m, 1.0e-30)
    iu = wp.clamp(int((u / m + 1.0) * 0.5 * float(r)), 0, r - 1)
    iv = wp.clamp(int((v / m + 1.0) * 0.5 * float(r)), 0, r - 1)
    return (face * r + iu) * r + iv


@wp.func
def _ray_emitters(p: wp.vec3d, n: wp.vec3d, tris: wp.array2d(dtype=wp.vec3d), radiance: wp.array(dtype=wp.vec3),
                  radiance2: wp.array(dtype=wp.vec3), two: int, tri_normals: wp.array(dtype=wp.vec3), mesh: wp.uint64,
                  eps: float, free: wp.array2d(dtype=wp.uint8), res: int) -> tuple[wp.vec3, wp.vec3]:
    """emitter_sum at one receiver p (unit normal n): the triangles' form factors, each with a ray, for
    `radiance` and (two != 0) for `radiance2` with the same rays (else its sum is zero)."""
    # free (res > 0): per triangle the cube cells where no ray can be blocked (no ray there)
    a = wp.vec3(p) + wp.vec3(n) * eps
    total = wp.vec3(0.0, 0.0, 0.0)
    total2 = wp.vec3(0.0, 0.0, 0.0)
    for t in range(tris.shape[0]):
        f = polygon_ff(p, n, tris, t, 3)
        if f > wp.float64(0.0):
            centroid = wp.vec3((tris[t, 0] + tris[t, 1] + tris[t, 2]) / wp.float64(3.0))
            b = centroid + tri_normals[t] * eps
            ba = a - b
            clear = False
            if res > 0 and wp.dot(ba, tri_normals[t]) > 0.0:  # the segment stays in front of the triangle
                clear = free[t, cube_cell(ba, res)] != wp.uint8(0)
            if not clear:
                clear = not segment_blocked(mesh, a, b)
            if clear:
                total += radiance[t] * float(f)
                if two != 0:
                    total2 += radiance2[t] * float(f)
    return total, total2


@wp.kernel
def _emitter_sum_kernel(points: wp.array(dtype=wp.vec3d), normals: wp.array(dtype=wp.vec3d),
                        tris: wp.array2d(dtype=wp.vec3d), radiance: wp.array(dtype=wp.vec3),
                        tri_normals: wp.array(dtype=wp.vec3), mesh: wp.uint64, eps: float,
                        free: wp.array2d(dtype=wp.uint8), res: int, out: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    total, unused = _ray_emitters(points[i], normals[i], tris, radiance, radiance, 0, tri_normals, mesh, eps, free, res)
    out[i] = total


@wp.kernel
def _emitter_sum_seen_kernel(points: wp.array(dtype=wp.vec3d), normals: wp.array(dtype=wp.vec3d),
                             tris: wp.array2d(dtype=wp.vec3d), radiance: wp.array(dtype=wp.vec3),
                             seen: wp.array2d(dtype=wp.uint8), res: int, out: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    p = points[i]
    n = normals[i]
    total = wp.vec3(0.0, 0.0, 0.0)
    for t in range(tris.shape[0]):
        centroid = (tris[t, 0] + tris[t, 1] + tris[t, 2]) / wp.float64(3.0)
        if seen[t, cube_cell(wp.vec3(p - centroid), res)] != wp.uint8(0):  # the table first: cheaper
            f = polygon_ff(p, n, tris, t, 3)
            if f > wp.float64(0.0):
                total += radiance[t] * float(f)
    out[i] = total


def emitter_sum_seen(points: np.ndarray, normals: np.ndarray, triangles: np.ndarray, radiance: np.ndarray,
                     seen: np.ndarray, res: int, device: str | None = None, split: int = 2048,
                     workspace: Workspace | None = None, capacity: int = 0) -> np.ndarray:
    """emitter_sum with each triangle's visibility from a table instead of a ray: seen (T, 6 res^2)
    bool/uint8, 1 where the direction from triangle t's centroid (cube_cell) leaves its occluder
    (a per-shape table of small emitters on an object that moves; the occluder is then the object
    alone, as in emitter_sum). Returns (N,3) float64 (= irradiance / pi). capacity: triangles the
    workspace's buffers hold at least (e.g. all the emitters a shape may have: a frame with fewer
    allocates nothing)."""
    device = runtime.device(device)
    n = len(points)
    if n == 0 or len(triangles) == 0:
        return np.zeros((n, 3))
    ws, block = call_buffers(workspace, n)
    shared = [ws.upload("tris", np.asarray(triangles, np.float64), wp.vec3d, device, capacity),
              ws.upload("radiance", np.asarray(radiance, np.float32), wp.vec3, device, capacity),
              seen_table(ws, seen, wp.uint8, device, capacity), int(res)]
    return _point_launches(_emitter_sum_seen_kernel, points, normals, shared, ws, block, device, split)


POINT_HESSIAN = 12.0  # sup of |d^T H d| |r|^5 / h for the point form factor's kernel (r.n_e)(-r.n_x)/|r|^4 along
# unit directions d in the emitter's plane (h: the receiver's height over that plane); reached at grazing


@wp.func
def _point_ff(p: wp.vec3d, n: wp.vec3d, q: wp.vec3d, an: wp.vec3d) -> wp.float64:
    """Point form factor A cos_x cos_t / (pi r^2) from p (unit normal n) to an emitter at q of twice its
    area x unit normal `an` (no horizon or side test: the caller's)."""
    r = p - q
    d2 = wp.dot(r, r)
    return wp.dot(r, an) * (-wp.dot(r, n)) / (wp.float64(6.283185307179586) * d2 * d2)


@wp.func
def _split_ff(p: wp.vec3d, n: wp.vec3d, poly: wp.array2d(dtype=wp.vec3d), j: int, k: int) -> wp.float64:
    """The mid-point rule of polygon j of `poly` (k vertices, convex) on its fan triangles (0, e, e+1) each
    split in 4 at its edges' mid-points: 4 (k - 2) point form factors (_point_ff) at the quarters' centroids."""
    a = poly[j, 0]
    total = wp.float64(0.0)
    sixth = wp.float64(1.0) / wp.float64(6.0)
    for e in range(1, k - 1):
        b = poly[j, e]
        c = poly[j, e + 1]
        an = wp.cross(b - a, c - a) * wp.float64(0.25)  # each quarter's 2 x area x unit normal
        total += _point_ff(p, n, (a * wp.float64(4.0) + b + c) * sixth, an)
        total += _point_ff(p, n, (a + b * wp.float64(4.0) + c) * sixth, an)
        total += _point_ff(p, n, (a + b + c * wp.float64(4.0)) * sixth, an)
        total += _point_ff(p, n, (a + b + c) / wp.float64(3.0), an)
    return total


@wp.func
def _bounded_ff(p: wp.vec3d, n: wp.vec3d, r: wp.vec3d, ct: wp.float64, g: wp.vec3d, poly: wp.array2d(dtype=wp.vec3d),
                j: int, k: int, tolerance: wp.float64) -> wp.float64:
    """Form factor from p (unit normal n) to polygon j of `poly` (k vertices) seen from r = p - its
    centroid, ct = r . (2 x its area x unit normal) > 0: where the polygon lies wholly above the
    receiver's horizon, the point form factor or else the mid-point rule on its quarters (_split_ff) where
    its bound allows (emitter_sum_seen_bounded; g = (rho, 6 J / A, 6 J_4 / A), J_4 = J of the quarters
    about their own centroids), else the exact one."""
    d2 = wp.dot(r, r)
    d = wp.sqrt(d2)
    cr = -wp.dot(r, n)  # |r| cos at the receiver
    if d > g[0] and cr > -g[0]:  # the polygon may lie above the receiver's horizon
        above = int(1)  # its bounding sphere is; else the corners decide (convex: all above, all of it)
        if cr <= g[0]:
            for e in range(k):
                if wp.dot(poly[j, e] - p, n) <= wp.float64(0.0):
                    above = 0
        if above != 0:
            m = d - g[0]
            allow = tolerance * m * m * m * m * m
            if g[1] * d2 * d <= allow:
                return ct * cr / (wp.float64(6.283185307179586) * d2 * d2)
            if g[2] * d2 * d <= allow:
                return _split_ff(p, n, poly, j, k)
    return polygon_ff(p, n, poly, j, k)


@wp.func
def _seen_emitters(p: wp.vec3d, n: wp.vec3d, tris: wp.array2d(dtype=wp.vec3d), centroids: wp.array(dtype=wp.vec3d),
                   area_normals: wp.array(dtype=wp.vec3d), geometry: wp.array(dtype=wp.vec3d),
                   radiance: wp.array(dtype=wp.vec3), seen: wp.array2d(dtype=wp.uint8), res: int,
                   tolerance: wp.float64, polys: wp.array2d(dtype=wp.vec3d), group: wp.array(dtype=wp.vec3i),
                   g_centroids: wp.array(dtype=wp.vec3d), g_area_normals: wp.array(dtype=wp.vec3d),
                   g_geometry: wp.array(dtype=wp.vec3d)) -> wp.vec3:
    """emitter_sum_seen_bounded at one receiver p (unit normal n), group by group (SeenEmitters.set)."""
    # geometry[t] = (rho_t: the farthest corner from the centroid, 6 J_t / A_t = (sum of squared edges) / 6,
    # the same of its quarters (_split_ff): a quarter of it);
    # group[g] = (vertices of its polygon, first member, members), g_*: its polygon's (members' radiance)
    total = wp.vec3(0.0, 0.0, 0.0)
    for g in range(group.shape[0]):
        r = p - g_centroids[g]
        ct = wp.dot(r, g_area_normals[g])  # 2 A h: the receiver in front of the plane (one-sided)
        if ct > wp.float64(0.0):
            info = group[g]
            s = info[1]
            n_seen = int(0)
            for t in range(s, s + info[2]):
                if seen[t, cube_cell(wp.vec3(p - centroids[t]), res)] != wp.uint8(0):
                    n_seen += 1
            if n_seen == info[2]:  # the polygon whole: its form factor is its members' sum
                f = _bounded_ff(p, n, r, ct, g_geometry[g], polys, g, info[0], tolerance)
                if f > wp.float64(0.0):
                    total += radiance[s] * float(f)
            elif n_seen > 0:  # member by member, each as far as its table sees
                for t in range(s, s + info[2]):
                    rt = p - centroids[t]
                    if seen[t, cube_cell(wp.vec3(rt), res)] != wp.uint8(0):
                        f = _bounded_ff(p, n, rt, wp.dot(rt, area_normals[t]), geometry[t], tris, t, 3, tolerance)
                        if f > wp.float64(0.0):
                            total += radiance[t] * float(f)
    return total


@wp.kernel
def _emitter_sum_seen_bounded_kernel(points: wp.array(dtype=wp.vec3d), normals: wp.array(dtype=wp.vec3d),
                                     tris: wp.array2d(dtype=wp.vec3d), centroids: wp.array(dtype=wp.vec3d),
                                     area_normals: wp.array(dtype=wp.vec3d), geometry: wp.array(dtype=wp.vec3d),
                                     radiance: wp.array(dtype=wp.vec3), seen: wp.array2d(dtype=wp.uint8), res: int,
                                     tolerance: wp.float64, polys: wp.array2d(dtype=wp.vec3d),
                                     group: wp.array(dtype=wp.vec3i), g_centroids: wp.array(dtype=wp.vec3d),
                                     g_area_normals: wp.array(dtype=wp.vec3d), g_geometry: wp.array(dtype=wp.vec3d),
                                     out: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    out[i] = _seen_emitters(points[i], normals[i], tris, centroids, area_normals, geometry, radiance, seen, res,
                            tolerance, polys, group, g_centroids, g_area_normals, g_geometry)


@wp.kernel
def _ray_and_seen_emitters_kernel(points: wp.array(dtype=wp.vec3d), normals: wp.array(dtype=wp.vec3d),
                                  tris: wp.array2d(dtype=wp.vec3d), radiance: wp.array(dtype=wp.vec3),
                                  tri_normals: wp.array(dtype=wp.vec3), mesh: wp.uint64, eps: float,
                                  free: wp.array2d(dtype=wp.uint8), free_res: int,
                                  s_tris: wp.array2d(dtype=wp.vec3d), s_centroids: wp.array(dtype=wp.vec3d),
                                  s_area_normals: wp.array(dtype=wp.vec3d), s_geometry: wp.array(dtype=wp.vec3d),
                                  s_radiance: wp.array(dtype=wp.vec3), s_seen: wp.array2d(dtype=wp.uint8),
                                  s_res: int, tolerance: wp.float64, polys: wp.array2d(dtype=wp.vec3d),
                                  group: wp.array(dtype=wp.vec3i), g_centroids: wp.array(dtype=wp.vec3d),
                                  g_area_normals: wp.array(dtype=wp.vec3d), g_geometry: wp.array(dtype=wp.vec3d),
                                  out: wp.array(dtype=wp.vec3)):
    # emitter_sum's triangles (rays) and SeenEmitters' (tables) at once: SeenEmitters.sum_with_rays
    i = wp.tid()
    p = points[i]
    n = normals[i]
    total, unused = _ray_emitters(p, n, tris, radiance, radiance, 0, tri_normals, mesh, eps, free, free_res)
    out[i] = total + _seen_emitters(p, n, s_tris, s_centroids, s_area_normals, s_geometry, s_radiance, s_seen,
                                    s_res, tolerance, polys, group, g_centroids, g_area_normals, g_geometry)


@wp.kernel
def _ray_and_seen_emitters2_kernel(points: wp.array(dtype=wp.vec3d), normals: wp.array(dtype=wp.vec3d),
                                   tris: wp.array2d(dtype=wp.vec3d), radiance: wp.array(dtype=wp.vec3),
                                   radiance2: wp.array(dtype=wp.vec3), tri_normals: wp.array(dtype=wp.vec3),
                                   mesh: wp.uint64, eps: float, free: wp.array2d(dtype=wp.uint8), free_res: int,
                                   s_tris: wp.array2d(dtype=wp.vec3d), s_centroids: wp.array(dtype=wp.vec3d),
                                   s_area_normals: wp.array(dtype=wp.vec3d), s_geometry: wp.array(dtype=wp.vec3d),
                                   s_radiance: wp.array(dtype=wp.vec3), s_seen: wp.array2d(dtype=wp.uint8),
                                   s_res: int, tolerance: wp.float64, polys: wp.array2d(dtype=wp.vec3d),
                                   group: wp.array(dtype=wp.vec3i), g_centroids: wp.array(dtype=wp.vec3d),
                                   g_area_normals: wp.array(dtype=wp.vec3d), g_geometry: wp.array(dtype=wp.vec3d),
                                   out: wp.array(dtype=wp.vec3), out2: wp.array(dtype=wp.vec3)):
    # SeenEmitters.sum_with_rays2: the triangles' sums for two radiances with one ray each (out, out2),
    # the seen emitters' added to the second
    i = wp.tid()
    p = points[i]
    n = normals[i]
    total, total2 = _ray_emitters(p, n, tris, radiance, radiance2, 1, tri_normals, mesh, eps, free, free_res)
    out[i] = total
    out2[i] = total2 + _seen_emitters(p, n, s_tris, s_centroids, s_area_normals, s_geometry, s_radiance, s_seen,
                                      s_res, tolerance, polys, group, g_centroids, g_area_normals, g_geometry)


def emitter_sum_seen_bounded(points: np.ndarray, normals: np.ndarray, triangles: np.ndarray, radiance: np.ndarray,
                             seen: np.ndarray, res: int, tolerance: float, device: str | None = None,
                             split: int = 2048, workspace: Workspace | None = None, capacity: int = 0,
                             groups: tuple | None = None) -> np.ndarray:
    """emitter_sum_seen with a triangle far enough from a receiver taken as a point emitter at its
    centroid (A cos_x cos_t / (pi r^2)), where that is within `tolerance` of its unoccluded light.

    The point form factor is the mid-point rule of the triangle's integral: its first-order error
    vanishes at the centroid, and the second order is at most POINT_HESSIAN h J / (2 pi (r - rho)^5)
    (h: the receiver's height over the triangle's plane, J = A (sum of squared edges) / 36 the polar
    moment about the centroid, rho the centroid's farthest corner, r the receiver's distance to the
    centroid). A triangle is a point where that is at most `tolerance` x A h / (pi r^3) (its light at a
    receiver facing it, unoccluded), i.e. (sum of squared edges / 6) r^3 <= tolerance (r - rho)^5, and
    wholly above the receiver's horizon (r cos_x > rho, or else each corner above it: convex, the whole
    triangle). Where the point is not within that bound, the same rule on the triangle's four quarters
    (split at its edges' mid-points, _split_ff: four point form factors, each quarter's error bounded as
    above with the triangle's own r - rho, which no point of a quarter is nearer than; their J sum to
    J / 4) is used where (sum of squared edges / 24) r^3 <= tolerance (r - rho)^5: a receiver about
    half as far (the same share of its light; four point form factors, a division each, in place of the
    exact one's three arc tangents: on sun_room's drag frames a quarter to a half of the pieces' exact form
    factors beside the object). Else its exact polygon form factor (the same as
    emitter_sum_seen). tolerance 0: exact everywhere. Returns (N,3) float64. (SeenEmitters
    keeps the emitters uploaded for many such sums; groups: runs of triangles summed as one polygon,
    SeenEmitters.set.)"""
    em = SeenEmitters(device, workspace)
    em.set(triangles, radiance, seen, res, tolerance, capacity, groups)
    return em.sum(points, normals, split=split, workspace=workspace)


def _quarters_moment(polys: np.ndarray, verts: np.ndarray) -> np.ndarray:
    """6 x the polar moment (m^4) of the quarters _split_ff evaluates, each about its own centroid, summed
    per polygon: polys (G,4,3) convex with its first verts (G,) corners; its fan triangles (0, e, e+1),
    each in 4 at its edges' mid-points (a quarter's J = (A/4)(E/4)/36 of its triangle's area A and sum of
    squared edges E), i.e. 6 x sum over the fan triangles of A E / 144."""
    polys = np.asarray(polys, np.float64)
    out = np.zeros(len(polys))
    for e in range(1, polys.shape[1] - 1):
        a, b, c = polys[:, 0], polys[:, e], polys[:, e + 1]
        area = 0.5 * np.linalg.norm(cross3(b - a, c - a), axis=1)
        edges = ((b - a) ** 2).sum(1) + ((c - b) ** 2).sum(1) + ((a - c) ** 2).sum(1)
        out += np.where(e + 1 < np.asarray(verts), 6.0 * area * edges / 144.0, 0.0)
    return out


class SeenEmitters:
    """Emitting triangles with their per-direction visibility tables (emitter_sum_seen_bounded),
    uploaded once (`set`) for any number of receiver sums (`sum`): a frame's sums at pixels, vertices
    and patch centres share one upload. Buffers kept between calls (at least `capacity` triangles)."""

    def __init__(self, device: str | None = None, workspace: Workspace | None = None):
        self.device = runtime.device(device)
        self._ws = workspace if workspace is not None else Workspace()
        self._shared: list | None = None
        self.n = 0

    def set(self, triangles: np.ndarray, radiance: np.ndarray, seen: np.ndarray, res: int, tolerance: float,
            capacity: int = 0, groups: tuple | None = None) -> "SeenEmitters":
        """The emitters: triangles (T,3,3) CCW seen from the emitting side, radiance (T,3), seen
        (T, 6 res^2) bool (emitter_sum_seen), tolerance (emitter_sum_seen_bounded).

        groups: optional (start (G,), count (G,), polygons (G,4,3), vertices (G,)): runs of consecutive
        triangles, each run coplanar, of one radiance and tiling a convex polygon (its first `vertices`
        corners, CCW like its triangles). At a receiver in front of their plane that every member's
        table sees, a run is one polygon: its exact form factor is its members' sum (form factors add
        over a partition, the horizon's clipping too), and its mid-point bound (with its polar moment
        J = sum of the members' own and A_t |c_t - C|^2 about the run's centroid C) decides when it is a
        point, and that of its fan triangles' quarters (_quarters_moment) when it is their mid-point rule;
        elsewhere its members are summed one by one as without groups. None: every triangle alone."""
        tri = np.asarray(triangles, np.float64)
        self.n = len(tri)
        if self.n == 0:
            return self
        cen = tri.mean(1)
        tn = cross3(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        rho = np.sqrt(((tri - cen[:, None]) ** 2).sum(-1).max(1))
        edges2 = ((tri - tri[:, [2, 0, 1]]) ** 2).sum((1, 2)) / 6.0  # 6 J_t / A_t
        if groups is None:
            start, count = np.arange(self.n), np.ones(self.n, np.int64)
            polys, verts = np.concatenate([tri, tri[:, :1]], 1), np.full(self.n, 3)
            g_cen, g_tn, g_geom = cen, tn, np.stack([rho, edges2, edges2 / 4.0], 1)
        else:
            start, count, polys, verts = (np.asarray(g) for g in groups)
            area = 0.5 * np.linalg.norm(tn, axis=1)
            g_area = np.add.reduceat(area, start)
            g_cen = np.add.reduceat(area[:, None] * cen, start) / g_area[:, None]
            g_tn = np.add.reduceat(tn, start)
            of = np.repeat(np.arange(len(start)), count)
            J = np.add.reduceat(area * (edges2 / 6.0 + ((cen - g_cen[of]) ** 2).sum(1)), start)
            corner = np.arange(4)[None, :] < verts[:, None]
            g_rho = np.sqrt(np.where(corner, ((polys - g_cen[:, None]) ** 2).sum(-1), 0.0).max(1))
            g_geom = np.stack([g_rho, 6.0 * J / g_area, _quarters_moment(polys, verts) / g_area], 1)
        info = np.stack([verts, start, count], 1).astype(np.int32)
        ws, dev = self._ws, self.device
        self._shared = [ws.upload("tris", tri, wp.vec3d, dev, capacity),
                        ws.upload("centroids", cen, wp.vec3d, dev, capacity),
                        ws.upload("area_normals", tn, wp.vec3d, dev, capacity),
                        ws.upload("geometry", np.stack([rho, edges2, edges2 / 4.0], 1), wp.vec3d, dev, capacity),
                        ws.upload("radiance", np.asarray(radiance, np.float32), wp.vec3, dev, capacity),
                        seen_table(ws, seen, wp.uint8, dev, capacity), int(res), float(tolerance),
                        ws.upload("polys", np.asarray(polys, np.float64), wp.vec3d, dev, capacity),
                        ws.upload("group", info, wp.vec3i, dev, capacity),
                        ws.upload("g_centroids", g_cen, wp.vec3d, dev, capacity),
                        ws.upload("g_area_normals", g_tn, wp.vec3d, dev, capacity),
                        ws.upload("g_geometry", g_geom, wp.vec3d, dev, capacity)]
        self.n_groups = len(start)
        return self

    def sum(self, points: np.ndarray, normals: np.ndarray, split: int = 2048,
            workspace: Workspace | None = None) -> np.ndarray:
        """sum_t B_t F(x -> t) seen_t(x) (N,3) float64 (= irradiance / pi) at points (N,3) [unit normals
        (N,3)]; workspace: the call site's buffers for the points (None: fresh)."""
        n = len(points)
        if n == 0 or self.n == 0:
            return np.zeros((n, 3))
        ws, block = call_buffers(workspace, n)
        # every other point first: the two halves of _point_launches (one per core) get near and far
        # receivers alike (a near one costs exact form factors, a far one points)
        order = np.r_[0:n:2, 1:n:2]
        out = np.empty((n, 3))
        out[order] = _point_launches(_emitter_sum_seen_bounded_kernel, np.asarray(points)[order],
                                     np.asarray(normals)[order], self._shared, ws, block, self.device, split)
        return out

    def sum_with_rays(self, points: np.ndarray, normals: np.ndarray, triangles: np.ndarray, radiance: np.ndarray,
                      occluder: Occluder | None = None, eps: float = 1e-3, split: int = 2048,
                      workspace: Workspace | None = None, free: np.ndarray | None = None,
                      free_res: int = 0) -> np.ndarray:
        """emitter_sum(points, normals, triangles, radiance, occluder, eps, free=, free_res=) + sum(points,
        normals) (N,3) float64 in one launch (a frame's exact sums near the object pay one hand-off to
        the cores, not two); workspace: the call site's buffers, as emitter_sum's."""
        n = len(points)
        if n == 0:
            return np.zeros((n, 3))
        if self.n == 0:
            return emitter_sum(points, normals, triangles, radiance, occluder, eps, self.device, split, workspace,
                               free, free_res)
        if len(triangles) == 0:
            return self.sum(points, normals, split, workspace)
        ws, block = call_buffers(workspace, n)
        shared = _ray_inputs(ws, triangles, radiance, occluder, eps, self.device, free, free_res) + self._shared
        return _point_launches(_ray_and_seen_emitters_kernel, points, normals, shared, ws, block, self.device, split)

    def sum_with_rays2(self, points: np.ndarray, normals: np.ndarray, triangles: np.ndarray, radiance: np.ndarray,
                       radiance2: np.ndarray, occluder: Occluder | None = None, eps: float = 1e-3, split: int = 2048,
                       workspace: Workspace | None = None, free: np.ndarray | None = None,
                       free_res: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """(emitter_sum of `radiance`, emitter_sum of `radiance2` (T,3) + sum) at points (N,3), both (N,3)
        float64, in one launch with one ray per triangle and receiver: a light split in two parts (the
        room's and the sun's) summed for the cost of one."""
        n = len(points)
        ws, block = call_buffers(workspace, n)
        if n == 0 or self.n == 0 or len(triangles) == 0:
            return (emitter_sum(points, normals, triangles, radiance, occluder, eps, self.device, split, workspace,
                                free, free_res),
                    self.sum_with_rays(points, normals, triangles, radiance2, occluder, eps, split, workspace, free,
                                       free_res))
        shared = _ray_inputs(ws, triangles, radiance, occluder, eps, self.device, free, free_res)
        shared.insert(2, ws.upload("radiance2", np.asarray(radiance2, np.float32), wp.vec3, self.device))
        return _point_launches(_ray_and_seen_emitters2_kernel, points, normals, shared + self._shared, ws, block,
                               self.device, split, outputs=2)


def seen_table(ws: Workspace, seen: np.ndarray, dtype, device: str, capacity: int = 0) -> wp.array:
    """A per-emitter visibility table (E, cells) pushed into ws's buffer "seen" (at least `capacity`
    rows, kept between calls); returns the device view of its first E rows."""
    seen = np.asarray(seen)
    table = ws.buffer("seen", max(len(seen), capacity), dtype, device, (seen.shape[1],))
    table.host[:len(seen), :seen.shape[1]] = seen
    table.push(len(seen))
    return table.dev[:len(seen), :seen.shape[1]]


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


def distance_to(occluder: Occluder, points: np.ndarray, max_dist: float = 1.0e3,
                workspace: Workspace | None = None) -> np.ndarray:
    """(N,) float32 distance from points (N,3) to the nearest triangle of the occluder mesh (m;
    `max_dist` where none lies within it or the mesh is empty). `workspace`: the call site's
    buffers (kernels.buffers.Workspace), kept between calls: launches of at most its capacity,
    nothing allocated after its first call (None: fresh buffers, one launch)."""
    n = len(points)
    if n == 0 or occluder.mesh is None:
        return np.full(n, max_dist, np.float32)
    device = occluder.device
    ws, block = call_buffers(workspace, n)
    points = np.asarray(points, np.float32)
    res = ws.buffer("out", block, wp.float32, device)
    out = np.empty(n, np.float32)
    for s in range(0, n, block):
        e = min(n, s + block)
        wp.launch(_distance_kernel, dim=e - s, inputs=[wp.uint64(occluder.id),
                                                       ws.upload("points", points[s:e], wp.vec3, device, block),
                                                       float(max_dist)], outputs=[res.dev[:e - s]], device=device)
        out[s:e] = res.pull(e - s)
    return out
