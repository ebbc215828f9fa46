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
from kernels.formfactor import polygon_ff
from kernels.sh9 import sh9
from kernels.visibility import Occluder, segment_blocked


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
                acc[c] += sh9(d, c)
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


# ---------------------------------------------------------------- patch light with sampled visibility
# sum_j F(x_i -> patch j) V(x_i, j) c_j at the object's vertices, where the visibility V (one ray to
# each patch's centre against the room and, where the object can shadow itself, the object) is cast
# only at a spread subset of the vertices ("samples"); a vertex whose nearest samples on the same
# side all agree about patch j takes their answer, and only where they disagree (a shadow's edge)
# or too few of them face the patch is the ray cast.
#
# Patches come in groups of one colour that tile a convex polygon (an emitter's quad cut into
# patches): the form factor is additive over a partition of the polygon (horizon clipping
# included), so a group adds c_g (F(polygon) - sum of F over its hidden patches), exact, with a
# form factor per group and per hidden patch instead of one per patch.

_MIN_AGREE = 2  # samples that must agree before a vertex takes their visibility without a ray


@wp.func
def _faces(p: wp.vec3d, n: wp.vec3d, polys: wp.array2d(dtype=wp.vec3d), j: int) -> bool:
    """True when p lies in front of quad j (its emitting side) and some of the quad above p's
    horizon: exactly where polygon_ff can be positive."""
    v0 = polys[j, 0]
    ns = wp.cross(polys[j, 1] - v0, polys[j, 2] - v0)
    if wp.dot(ns, p - v0) <= wp.float64(0.0):
        return False
    for e in range(4):
        if wp.dot(n, polys[j, e] - p) > wp.float64(0.0):
            return True
    return False


@wp.func
def _patch_visible(mesh_a: wp.uint64, mesh_b: wp.uint64, own: int, p: wp.vec3d, n: wp.vec3d,
                   polys: wp.array2d(dtype=wp.vec3d), poly_normals: wp.array(dtype=wp.vec3), j: int,
                   eps: float) -> int:
    """1 when the segment from p (lifted by eps along n) to patch j's centre (lifted along its
    normal) is blocked by neither mesh, else 0. `own` 0 says mesh_b lies wholly behind p's tangent
    plane: a segment leaving p upwards cannot meet it, and only one going below the plane is tested."""
    a = wp.vec3(p) + wp.vec3(n) * eps
    c0 = wp.vec3(polys[j, 0])
    b = c0 + (wp.vec3(polys[j, 1]) - c0) * 0.5 + (wp.vec3(polys[j, 3]) - c0) * 0.5 + poly_normals[j] * eps
    if segment_blocked(mesh_a, a, b):
        return 0
    if (own != 0 or wp.dot(wp.vec3(n), b - a) <= 0.0) and segment_blocked(mesh_b, a, b):
        return 0
    return 1


@wp.kernel
def _sample_visibility_kernel(points: wp.array(dtype=wp.vec3d), normals: wp.array(dtype=wp.vec3d),
                              samples: wp.array(dtype=wp.int32), own: wp.array(dtype=wp.int32),
                              polys: wp.array2d(dtype=wp.vec3d), poly_normals: wp.array(dtype=wp.vec3),
                              mesh_a: wp.uint64, mesh_b: wp.uint64, eps: float, lo: int,
                              vis: wp.array2d(dtype=wp.int8)):
    s0, j = wp.tid()
    s = s0 + lo
    i = samples[s]
    p = points[i]
    n = normals[i]
    if not _faces(p, n, polys, j):
        vis[s, j] = wp.int8(-1)  # faces away: says nothing about its neighbours
    else:
        vis[s, j] = wp.int8(_patch_visible(mesh_a, mesh_b, own[i], p, n, polys, poly_normals, j, eps))


@wp.kernel
def _sampled_sum_kernel(points: wp.array(dtype=wp.vec3d), normals: wp.array(dtype=wp.vec3d),
                        own: wp.array(dtype=wp.int32), sample_of: wp.array(dtype=wp.int32),
                        nbr: wp.array2d(dtype=wp.int32), vis: wp.array2d(dtype=wp.int8),
                        polys: wp.array2d(dtype=wp.vec3d), poly_normals: wp.array(dtype=wp.vec3),
                        colors: wp.array(dtype=wp.vec3), group_start: wp.array(dtype=wp.int32),
                        group_polys: wp.array2d(dtype=wp.vec3d), n_groups: int, mesh_a: wp.uint64,
                        mesh_b: wp.uint64, eps: float, min_agree: int, lo: int, out: wp.array(dtype=wp.vec3),
                        cast: wp.array(dtype=wp.int32)):
    i = wp.tid() + lo
    p = points[i]
    n = normals[i]
    me = sample_of[i]
    total = wp.vec3(0.0, 0.0, 0.0)
    rays = int(0)
    for g in range(n_groups):
        j0 = group_start[g]
        j1 = group_start[g + 1]
        facing = int(0)
        hidden_ff = wp.float64(0.0)
        seen_ff = wp.float64(0.0)
        for j in range(j0, j1):
            if not _faces(p, n, polys, j):
                continue
            facing += 1
            v = int(-1)
            if me >= 0:
                v = int(vis[me, j])
            if v < 0:
                seen = int(0)
                hidden = int(0)
                for k in range(nbr.shape[1]):
                    s = nbr[i, k]
                    if s >= 0:
                        x = int(vis[s, j])
                        if x == 1:
                            seen += 1
                        elif x == 0:
                            hidden += 1
                if seen >= min_agree and hidden == 0:
                    v = 1
                elif hidden >= min_agree and seen == 0:
                    v = 0
                else:
                    v = _patch_visible(mesh_a, mesh_b, own[i], p, n, polys, poly_normals, j, eps)
                    rays += 1
            if j1 - j0 == 1:
                if v == 1:
                    seen_ff = polygon_ff(p, n, polys, j, 4)
            elif v == 0:
                hidden_ff += polygon_ff(p, n, polys, j, 4)
        if facing > 0:
            f = seen_ff
            if j1 - j0 > 1:
                f = wp.max(polygon_ff(p, n, group_polys, g, 4) - hidden_ff, wp.float64(0.0))
            total += colors[j0] * float(f)
    out[i] = total
    cast[i] = rays


def patch_groups(corners: np.ndarray, quad: np.ndarray, colors: np.ndarray, rtol: float = 1e-6
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(order, start, polys): the patches (corners (M,4,3), their surface `quad` (M,), colours
    (M,3)) ordered so that each group of one surface and one colour whose patches tile a rectangle
    is contiguous: group g is order[start[g]:start[g+1]], its rectangle polys[g] (4,3), CCW as the
    patches. A group that tiles no rectangle is split into single patches (their own corners)."""
    if len(corners) == 0:
        return np.zeros(0, np.int64), np.zeros(1, np.int32), np.zeros((0, 4, 3))
    key = np.c_[quad, colors]
    _, gid = np.unique(key, axis=0, return_inverse=True)
    gid = gid.reshape(-1)
    order, start, polys = [], [0], []
    for g in np.unique(gid):
        idx = np.flatnonzero(gid == g)
        rect = None
        if len(idx) > 1:
            c = corners[idx]
            o = c[0, 0]
            e0, e1 = c[0, 1] - c[0, 0], c[0, 3] - c[0, 0]
            u0, u1 = e0 / np.linalg.norm(e0), e1 / np.linalg.norm(e1)
            pu, pv = (c - o) @ u0, (c - o) @ u1
            area = np.linalg.norm(np.cross(c[:, 2] - c[:, 0], c[:, 3] - c[:, 1]), axis=1).sum() / 2
            r = [o + u0 * a + u1 * b for a, b in ((pu.min(), pv.min()), (pu.max(), pv.min()),
                                                   (pu.max(), pv.max()), (pu.min(), pv.max()))]
            r_area = np.linalg.norm(np.cross(r[2] - r[0], r[3] - r[1])) / 2
            if abs(np.dot(u0, u1)) < 1e-9 and abs(r_area - area) <= rtol * max(area, 1e-30):
                rect = np.array(r)
        if rect is not None:
            order.extend(idx)
            start.append(len(order))
            polys.append(rect)
        else:
            for j in idx:
                order.append(j)
                start.append(len(order))
                polys.append(corners[j])
    return (np.array(order, np.int64), np.array(start, np.int32),
            np.array(polys, np.float64).reshape(-1, 4, 3) if polys else np.zeros((0, 4, 3)))


class SampledPatchSum:
    """sum_j F_ij V_ij c_j (irradiance/pi for colours in radiance) from patches j at fixed points
    (one object shape's distinct vertices, in the world at this frame's pose), the visibility ray
    cast at `samples` and, elsewhere, only where the `nbr` samples of a point disagree (module
    note above). Buffers are made once at capacity (`max_patches` per launch; more patches go in
    blocks), so a frame allocates nothing.

    own (N,) bool: False where the object's mesh (occluders[1]) lies wholly behind the point's
    tangent plane (then only segments going below that plane are tested against it); samples (S,)
    indices into the points; nbr (N,k) indices into `samples` of each point's neighbours (-1: none).
    """

    def __init__(self, own: np.ndarray, samples: np.ndarray, nbr: np.ndarray, device: str,
                 max_patches: int = 512):
        from kernels.buffers import Buffer

        self.device = device
        self.n, self.m = len(own), max(int(max_patches), 1)
        sample_of = np.full(self.n, -1, np.int32)
        sample_of[samples] = np.arange(len(samples), dtype=np.int32)
        dev = device
        self._own = Buffer(max(self.n, 1), wp.int32, dev, fill=np.asarray(own, np.int32) if self.n else None)
        self._samples = Buffer(max(len(samples), 1), wp.int32, dev)
        self._samples.upload(np.asarray(samples, np.int32))
        self._sample_of = Buffer(max(self.n, 1), wp.int32, dev)
        self._sample_of.upload(sample_of)
        self._nbr = Buffer((max(self.n, 1), nbr.shape[1]), wp.int32, dev)
        self._nbr.upload(np.asarray(nbr, np.int32))
        self.n_samples = len(samples)
        self._vis = Buffer((max(self.n_samples, 1), self.m), wp.int8, dev)
        self._points = Buffer(max(self.n, 1), wp.vec3d, dev)
        self._normals = Buffer(max(self.n, 1), wp.vec3d, dev)
        self._polys = Buffer((self.m, 4), wp.vec3d, dev)
        self._pn = Buffer(self.m, wp.vec3, dev)
        self._colors = Buffer(self.m, wp.vec3, dev)
        self._start = Buffer(self.m + 1, wp.int32, dev)
        self._gpolys = Buffer((self.m, 4), wp.vec3d, dev)
        self._out = Buffer(max(self.n, 1), wp.vec3, dev)
        self._cast = Buffer(max(self.n, 1), wp.int32, dev)
        self.rays_cast = 0  # visibility rays of the last call outside the samples (a measure of coherence)

    def __call__(self, points: np.ndarray, normals: np.ndarray, corners: np.ndarray, patch_normals: np.ndarray,
                 colors: np.ndarray, occluders: list[Occluder], eps: float, split=None,
                 groups: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
        """(N,3) float64 sum over patches (corners (M,4,3), normals (M,3), colors (M,3)) at the
        points (N,3) with unit normals (N,3); occluders: [room, object]. `split(launch, n)` runs
        launch(lo, hi) over ranges covering [0, n) (app.runtime.split; None: one launch).
        groups: (start (G+1,), polys (G,4,3)) of patch_groups, the patches given in its order
        (then at most `max_patches` of them); None: every patch alone."""
        n = len(points)
        if n != self.n:
            raise ValueError(f"{n} points, the sum was made for {self.n}")
        out = np.zeros((n, 3))
        self.rays_cast = 0
        if n == 0 or len(corners) == 0:
            return out
        if groups is not None and len(corners) > self.m:
            raise ValueError(f"{len(corners)} grouped patches exceed the capacity {self.m}")
        dev = self.device
        mesh_a = wp.uint64(occluders[0].id)
        mesh_b = wp.uint64(occluders[1].id if len(occluders) > 1 else 0)
        self._points.upload(np.asarray(points, np.float64))
        self._normals.upload(np.asarray(normals, np.float64))
        for c0 in range(0, len(corners), self.m):
            c1 = min(len(corners), c0 + self.m)
            m = c1 - c0
            self._polys.upload(np.asarray(corners[c0:c1], np.float64))
            self._pn.upload(np.asarray(patch_normals[c0:c1], np.float32))
            self._colors.upload(np.asarray(colors[c0:c1], np.float32))
            if groups is None:
                self._start.host[:m + 1] = np.arange(m + 1)
                self._start.push(m + 1)
                n_groups = m
            else:
                n_groups = len(groups[0]) - 1
                self._start.upload(np.asarray(groups[0], np.int32))
                self._gpolys.upload(np.asarray(groups[1], np.float64))

            def sample(lo: int, hi: int) -> None:
                wp.launch(_sample_visibility_kernel, dim=(hi - lo, m),
                          inputs=[self._points.dev, self._normals.dev, self._samples.dev, self._own.dev,
                                  self._polys.dev, self._pn.dev, mesh_a, mesh_b, float(eps), int(lo)],
                          outputs=[self._vis.dev], device=dev)

            def gather(lo: int, hi: int) -> None:
                wp.launch(_sampled_sum_kernel, dim=hi - lo,
                          inputs=[self._points.dev, self._normals.dev, self._own.dev, self._sample_of.dev,
                                  self._nbr.dev, self._vis.dev, self._polys.dev, self._pn.dev, self._colors.dev,
                                  self._start.dev, self._gpolys.dev, int(n_groups), mesh_a, mesh_b, float(eps),
                                  _MIN_AGREE, int(lo)],
                          outputs=[self._out.dev, self._cast.dev], device=dev)

            if self.n_samples:
                runtime.launch_split(sample, self.n_samples, split)
            runtime.launch_split(gather, n, split)
            out += self._out.pull(n)
            self.rays_cast += int(self._cast.pull(n).sum())
        return out


# ---------------------------------------------------------------- the object's camera hits
@wp.func
def camera_ray(obj: wp.uint64, scene: wp.uint64, centre: wp.vec3, d: wp.vec3) -> tuple[int, wp.vec3, int]:
    """The camera ray from centre along unit d against the object's mesh: (its triangle (-1 none),
    barycentrics, 1 where it meets the object and the scene model does not lie in front, else 0); the
    scene is only asked where the object is hit."""
    q = wp.mesh_query_ray(obj, centre, d, 1.0e6)
    if q.result:
        seen = int(1)
        if scene != wp.uint64(0):
            qs = wp.mesh_query_ray(scene, centre, d, q.t)
            if qs.result and qs.t <= q.t:
                seen = 0
        return q.face, wp.vec3(q.u, q.v, 1.0 - q.u - q.v), seen  # Warp: p = u p0 + v p1 + (1-u-v) p2
    return -1, wp.vec3(0.0, 0.0, 0.0), 0


@wp.func
def camera_hit(obj: wp.uint64, scene: wp.uint64, centre: wp.vec3, d: wp.vec3, k: int, tri: wp.array(dtype=wp.int32),
               bary: wp.array(dtype=wp.vec3), hit: wp.array(dtype=wp.uint8)):
    """camera_ray written to entry k of tri, bary and hit."""
    t, b, seen = camera_ray(obj, scene, centre, d)
    tri[k] = t
    bary[k] = b
    hit[k] = wp.uint8(seen)


@wp.kernel
def _object_hits_kernel(obj: wp.uint64, scene: wp.uint64, centre: wp.vec3, pix_to_dir: wp.mat33, u0: int, v0: int,
                        cols: int, s: int, first: int, lo: int, tri: wp.array(dtype=wp.int32),
                        bary: wp.array(dtype=wp.vec3), hit: wp.array(dtype=wp.uint8)):
    k = wp.tid() + lo  # within the block
    i = first + k  # sub-sample, row-major over the rectangle's (rows * s) x (cols * s) grid
    r = i // (cols * s)
    c = i - r * (cols * s)
    u = float(u0 + c // s) + (float(c % s) + 0.5) / float(s) - 0.5
    v = float(v0 + r // s) + (float(r % s) + 0.5) / float(s) - 0.5
    camera_hit(obj, scene, centre, wp.normalize(pix_to_dir * wp.vec3(u, v, 1.0)), k, tri, bary, hit)


class CameraHits:
    """Sub-pixel camera rays through a pixel rectangle against the object's mesh, each depth-tested
    against the scene model only where it hits the object (the frame's "object" stage). Buffers of
    `block` rays are made once; a larger rectangle goes in blocks."""

    def __init__(self, device: str, block: int = 65536):
        from kernels.buffers import Buffer

        self.device, self.block = device, block
        self._tri = Buffer(block, wp.int32, device)
        self._bary = Buffer(block, wp.vec3, device)
        self._hit = Buffer(block, wp.uint8, device)

    def __call__(self, obj: Occluder, scene: Occluder, centre: np.ndarray, pix_to_dir: np.ndarray,
                 rect: tuple[int, int, int, int], s: int, split=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(tri (n,) int32 (-1: none), bary (n,3) float32, hit (n,) bool) for the s x s sub-samples
        of the pixels u0..u1, v0..v1 (inclusive), row-major over the sub-sample grid, the ray of
        pixel position (u, v) being pix_to_dir @ (u, v, 1) normalised (pix_to_dir = R^T K^-1).
        `split(launch, n)` runs launch(lo, hi) over ranges covering [0, n) (None: one launch)."""
        u0, v0, u1, v1 = rect
        cols, rows = u1 - u0 + 1, v1 - v0 + 1
        M = wp.mat33(*np.asarray(pix_to_dir, np.float32).reshape(-1))
        c = wp.vec3(*np.asarray(centre, np.float32))
        return self.in_blocks(_object_hits_kernel, rows * s * cols * s,
                              [wp.uint64(obj.id), wp.uint64(scene.id), c, M, int(u0), int(v0), int(cols), int(s)], split)

    def in_blocks(self, kernel, n: int, inputs: list, split=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(tri, bary, hit) of n sub-samples, `block` at a time: `kernel` launched with inputs + [first, lo] (the
        block's first sub-sample, the range's first thread) into the kept buffers, each block pulled to the host."""
        tri, bary, hit = np.empty(n, np.int32), np.empty((n, 3), np.float32), np.empty(n, bool)
        for first in range(0, n, self.block):
            m = min(self.block, n - first)

            def launch(lo: int, hi: int) -> None:
                wp.launch(kernel, dim=hi - lo, inputs=[*inputs, int(first), int(lo)],
                          outputs=[self._tri.dev, self._bary.dev, self._hit.dev], device=self.device)

            runtime.launch_split(launch, m, split)
            tri[first:first + m] = self._tri.pull(m)
            bary[first:first + m] = self._bary.pull(m)
            hit[first:first + m] = self._hit.pull(m) != 0
        return tri, bary, hit
