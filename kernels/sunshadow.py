"""The object's sun shadow: an orthographic depth map toward the sun, looked up with
percentage-closer soft shadows (PCSS) for the penumbra of the sun's disk.

Map: the object's triangles projected along -d (d = unit direction to the sun) onto a square
res x res grid covering the object's bounding sphere; each texel keeps the smallest depth
z = (p - c) . (-d) (metres, growing away from the sun), +inf where empty. Rasterised one thread per
triangle with `atomic_min` (as kernels.shadowmap).

Lookup at a receiver point p (depth z_r) with a footprint radius r_fp (m, the pixel's size on the
surface; 0 for a point):
1. blocker search over a disk of radius (z_r - z_min) tan(a) + r_fp (a = the disk's angular radius,
   z_min the map's smallest depth): the mean depth z_b of the taps closer than z_r - bias;
2. the penumbra radius w = (z_r - z_b) tan(a); the occluded share is the fraction of taps, over a disk
   of radius sqrt(w^2 + r_fp^2), closer than z_r - bias.
Taps are a fixed golden-angle (Vogel) spiral. A point outside the map is unoccluded. Each block of
BLOCK x BLOCK texels keeps its depth range (per render): a lookup whose texels are all nearer than
the receiver (1) or none (0) answers without its taps, the same answer.

Also the sun's rays (lighting.sun.SunLight's per-frame questions, each in one launch with its host-side
arithmetic moved in, in float64 as numpy did it): SunVisibility (a point's cos toward the sun, its exit
through an opening and its ray past the room and the object), HitSun (the sun per camera hit against its
corners' blend) and OutlineShade (the clipped outline's adaptive sub-pixel rays, each hit shaded with it).
"""
from __future__ import annotations

import hashlib

import numpy as np
import warp as wp

from kernels import runtime
from kernels.buffers import Workspace
from kernels.shade import camera_hit, camera_ray


@wp.struct
class SunMap:
    centre: wp.vec3  # map origin (object bounding-sphere centre), world
    right: wp.vec3
    up: wp.vec3
    fwd: wp.vec3  # -d: from the sun into the room
    half: float  # half-width of the map, metres
    res: int
    depth: wp.array2d(dtype=wp.float32)
    z_min: float
    tan_a: float  # tan of the sun disk's angular radius
    bias: float
    taps: wp.array(dtype=wp.vec2)  # unit-disk tap pattern
    block: int  # texels per side of a block of bmin/bmax
    bmin: wp.array2d(dtype=wp.float32)  # smallest depth of each block of texels
    bmax: wp.array2d(dtype=wp.float32)  # largest depth of each block (inf where a texel is empty)


@wp.func
def _project(m: SunMap, p: wp.vec3) -> wp.vec3:
    """World point -> (texel x, texel y, depth)."""
    d = p - m.centre
    s = float(m.res) / (2.0 * m.half)
    return wp.vec3(wp.dot(d, m.right) * s + float(m.res) * 0.5 - 0.5,
                   wp.dot(d, m.up) * s + float(m.res) * 0.5 - 0.5, wp.dot(d, m.fwd))


@wp.func
def _edge(a: wp.vec3, b: wp.vec3, x: float, y: float) -> float:
    return (b[0] - a[0]) * (y - a[1]) - (b[1] - a[1]) * (x - a[0])


@wp.kernel
def _raster(m: SunMap, verts: wp.array(dtype=wp.vec3), tris: wp.array2d(dtype=wp.int32)):
    t = wp.tid()
    a = _project(m, verts[tris[t, 0]])
    b = _project(m, verts[tris[t, 1]])
    c = _project(m, verts[tris[t, 2]])
    area = _edge(a, b, c[0], c[1])
    if wp.abs(area) < 1.0e-12:
        return
    x0 = wp.max(int(wp.ceil(wp.min(wp.min(a[0], b[0]), c[0]))), 0)
    x1 = wp.min(int(wp.floor(wp.max(wp.max(a[0], b[0]), c[0]))), m.res - 1)
    y0 = wp.max(int(wp.ceil(wp.min(wp.min(a[1], b[1]), c[1]))), 0)
    y1 = wp.min(int(wp.floor(wp.max(wp.max(a[1], b[1]), c[1]))), m.res - 1)
    for iy in range(y0, y1 + 1):
        for ix in range(x0, x1 + 1):
            w0 = _edge(b, c, float(ix), float(iy)) / area
            w1 = _edge(c, a, float(ix), float(iy)) / area
            w2 = 1.0 - w0 - w1
            if w0 >= -1.0e-6 and w1 >= -1.0e-6 and w2 >= -1.0e-6:
                wp.atomic_min(m.depth, iy, ix, w0 * a[2] + w1 * b[2] + w2 * c[2])


@wp.kernel
def _block_range(m: SunMap):
    """bmin/bmax of one block of texels (after _raster)."""
    by, bx = wp.tid()
    lo = float(wp.inf)
    hi = float(-wp.inf)
    for iy in range(by * m.block, wp.min((by + 1) * m.block, m.res)):
        for ix in range(bx * m.block, wp.min((bx + 1) * m.block, m.res)):
            z = m.depth[iy, ix]
            lo = wp.min(lo, z)
            hi = wp.max(hi, z)
    m.bmin[by, bx] = lo
    m.bmax[by, bx] = hi


@wp.func
def _region_range(m: SunMap, x: float, y: float, r: float) -> wp.vec2:
    """(smallest, largest) depth of every texel a tap within r texels of (x, y) can read (nearest
    texel: floor(. + 0.5)); largest is inf when some of them lie outside the map (empty there)."""
    x0 = int(wp.floor(x - r + 0.5))
    x1 = int(wp.floor(x + r + 0.5))
    y0 = int(wp.floor(y - r + 0.5))
    y1 = int(wp.floor(y + r + 0.5))
    lo = float(wp.inf)
    hi = float(-wp.inf)
    if x0 < 0 or y0 < 0 or x1 >= m.res or y1 >= m.res:
        hi = float(wp.inf)
    x0 = wp.clamp(x0, 0, m.res - 1)
    x1 = wp.clamp(x1, 0, m.res - 1)
    y0 = wp.clamp(y0, 0, m.res - 1)
    y1 = wp.clamp(y1, 0, m.res - 1)
    for by in range(y0 // m.block, y1 // m.block + 1):
        for bx in range(x0 // m.block, x1 // m.block + 1):
            lo = wp.min(lo, m.bmin[by, bx])
            hi = wp.max(hi, m.bmax[by, bx])
    return wp.vec2(lo, hi)


@wp.func
def _tap_depth(m: SunMap, x: float, y: float) -> float:
    ix = int(wp.floor(x + 0.5))
    iy = int(wp.floor(y + 0.5))
    if ix < 0 or iy < 0 or ix >= m.res or iy >= m.res:
        return wp.inf
    return m.depth[iy, ix]


@wp.kernel
def _pcss(m: SunMap, pos: wp.array(dtype=wp.vec3), footprint: wp.array(dtype=wp.float32), first: int,
          out: wp.array(dtype=wp.float32)):
    i = wp.tid() + first
    q = _project(m, pos[i])
    zr = q[2]
    out[i] = 0.0
    if zr - m.bias <= m.z_min:
        return
    s = float(m.res) / (2.0 * m.half)  # texels per metre
    n = m.taps.shape[0]
    r_fp = footprint[i]
    r_search = ((zr - m.z_min) * m.tan_a + r_fp) * s
    lo = -0.5 - r_search  # every tap of a point this far outside the map falls outside it: unoccluded
    hi = float(m.res) - 0.5 + r_search
    if q[0] < lo or q[1] < lo or q[0] > hi or q[1] > hi:
        return
    # every texel the taps can read (both disks lie within r_search) nearer than the receiver, or none:
    # the taps' answer without reading them (1 or 0)
    span = _region_range(m, q[0], q[1], r_search)
    if span[0] >= zr - m.bias:
        return
    if span[1] < zr - m.bias:
        out[i] = 1.0
        return
    zsum = float(0.0)
    nb = float(0.0)
    for k in range(n):
        t = m.taps[k]
        z = _tap_depth(m, q[0] + t[0] * r_search, q[1] + t[1] * r_search)
        if z < zr - m.bias:
            zsum += z
            nb += 1.0
    if nb == 0.0:
        return
    w = (zr - zsum / nb) * m.tan_a
    r = wp.sqrt(w * w + r_fp * r_fp) * s
    blocked = float(0.0)
    for k in range(n):
        t = m.taps[k]
        if _tap_depth(m, q[0] + t[0] * r, q[1] + t[1] * r) < zr - m.bias:
            blocked += 1.0
    out[i] = blocked / float(n)


PCSS_SPLIT = 4096  # lookups from which occlusion_at runs two launches side by side on the CPU


BLOCK = 16  # texels per side of the blocks whose depth range lets a lookup skip its taps (_region_range)


def vogel_disk(n: int) -> np.ndarray:
    """n points (n,2) spread evenly over the unit disk (golden-angle spiral)."""
    k = np.arange(n) + 0.5
    r = np.sqrt(k / n)
    a = k * np.pi * (3.0 - np.sqrt(5.0))
    return np.stack([r * np.cos(a), r * np.sin(a)], 1)


class SunShadowMap:
    """One orthographic map of an occluder toward the sun, re-rendered per pose."""

    def __init__(self, direction: np.ndarray, angular_radius: float, res: int = 1024, taps: int = 48,
                 bias: float = 2e-3, device: str | None = None, block: int = BLOCK):
        self.device = runtime.device(device)
        d = np.asarray(direction, np.float64)
        d /= np.linalg.norm(d)
        fwd = -d
        helper = np.array([0.0, 1.0, 0.0]) if abs(fwd[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
        right = np.cross(helper, fwd)
        right /= np.linalg.norm(right)
        up = np.cross(fwd, right)
        self.m = SunMap()
        self.m.right, self.m.up, self.m.fwd = (wp.vec3(*map(float, a)) for a in (right, up, fwd))
        self.m.res = int(res)
        self.m.tan_a = float(np.tan(angular_radius))
        self.m.bias = float(bias)
        self.m.depth = wp.zeros((res, res), dtype=wp.float32, device=self.device)
        self.m.taps = wp.array(vogel_disk(taps).astype(np.float32), dtype=wp.vec2, device=self.device)
        self.m.centre = wp.vec3(0.0, 0.0, 0.0)
        self.m.half = 1.0
        self.m.z_min = float("inf")
        self.m.block = int(min(block, res))
        nb = (int(res) + self.m.block - 1) // self.m.block
        self.m.bmin = wp.zeros((nb, nb), dtype=wp.float32, device=self.device)
        self.m.bmax = wp.zeros((nb, nb), dtype=wp.float32, device=self.device)
        self._buffers = Workspace()  # the occluder's vertices and triangles, grown only when a shape needs more
        self._key: bytes | None = None  # the shape the map holds (render)
        self.n_renders = 0  # rasterisations so far (a translation needs none)

    def render(self, vertices: np.ndarray, faces: np.ndarray) -> None:
        """Rasterise the occluder (world coordinates) into the map (buffers kept between calls).

        The map is centred on the occluder's box and its depths are measured from that centre, so a
        translated occluder has the same map: it is rasterised again only when its shape (the mesh
        relative to its box centre, to 1 um, and its faces) changes; a move only moves the centre."""
        v = np.asarray(vertices, np.float64)
        c = 0.5 * (v.min(0) + v.max(0))
        self.m.centre = wp.vec3(*map(float, c))
        key = hashlib.sha1(np.round(v - c, 6).tobytes() + np.ascontiguousarray(faces, np.int64).tobytes()).digest()
        if key == self._key:
            return
        self._key = key
        self.n_renders += 1
        r = float(np.linalg.norm(v - c, axis=1).max()) * 1.01 + 1e-3
        self.m.half = r
        self.m.depth.fill_(float("inf"))
        fwd = np.array(self.m.fwd, np.float64)
        self.m.z_min = float(((v - c) @ fwd).min())
        verts = self._buffers.upload("verts", v.astype(np.float32), wp.vec3, self.device)
        tris = self._buffers.upload("tris", np.asarray(faces, np.int32), wp.int32, self.device)
        wp.launch(_raster, dim=len(faces), inputs=[self.m, verts, tris], device=self.device)
        wp.launch(_block_range, dim=self.m.bmin.shape, inputs=[self.m], device=self.device)

    def points(self, points: np.ndarray, footprint: np.ndarray | None = None) -> "LookupPoints":
        """A fixed set of receiver points (N,3) [footprints (N,) m] kept on the device, for
        `occlusion_at` every frame without new buffers."""
        return LookupPoints(points, footprint, self.device)

    def occlusion_at(self, pts: "LookupPoints") -> np.ndarray:
        """occlusion() of a kept point set (N,) (a view of the kept output buffer: copy to keep)."""
        n = pts.n
        if n == 0:
            return np.zeros(0)
        # on the CPU two halves side by side (one per core) when there are enough points to pay a thread
        cuts = [(0, n // 2), (n // 2, n)] if n >= PCSS_SPLIT and wp.get_device(self.device).is_cpu else [(0, n)]
        runtime.run_parallel([lambda a=a, b=b: wp.launch(_pcss, dim=b - a, inputs=[self.m, pts.pos, pts.fp, a],
                                                         outputs=[pts.out], device=self.device) for a, b in cuts])
        return pts.out.numpy()[:n]

    def occlusion(self, points: np.ndarray, footprint: np.ndarray | None = None) -> np.ndarray:
        """Share (N,) in [0,1] of the sun's disk the occluder hides from each point, averaged over a
        disk of radius `footprint` (N,) m around it (0: the point itself)."""
        return self.occlusion_at(self.points(points, footprint)).astype(np.float64)


class LookupPoints:
    """Receiver points, their footprints and an output buffer on the device (SunShadowMap.points)."""

    def __init__(self, points: np.ndarray, footprint: np.ndarray | None, device: str):
        self.n = len(points)
        fp = np.zeros(self.n, np.float32) if footprint is None else np.asarray(footprint, np.float32)
        self.pos = wp.array(np.asarray(points, np.float32).reshape(-1, 3), dtype=wp.vec3, device=device)
        self.fp = wp.array(fp, dtype=wp.float32, device=device)
        self.out = wp.zeros(max(self.n, 1), dtype=wp.float32, device=device)


# ----------------------------------------------------------------------------- outline rays
@wp.kernel
def _outline_hits_kernel(obj: wp.uint64, scene: wp.uint64, centre: wp.vec3, pix_to_dir: wp.mat33,
                         px: wp.array(dtype=wp.int32), py: wp.array(dtype=wp.int32), s: int,
                         order: wp.array(dtype=wp.int32), n_first: int, lo: int, tri: wp.array(dtype=wp.int32),
                         bary: wp.array(dtype=wp.vec3), hit: wp.array(dtype=wp.uint8), full: wp.array(dtype=wp.uint8)):
    """One pixel a thread: its sub-samples order[0:n_first] first, then order[n_first:] only where those
    disagree (some reach the object, some do not: the pixel is crossed by the outline); the rest are
    written as misses (tri -1) and full[j] = 0. Entry j s^2 + q holds sub-sample q = b s + a."""
    j = wp.tid() + lo  # pixel within the block
    k0 = j * s * s
    n_hit = int(0)
    for i in range(n_first):
        k = k0 + order[i]
        q = order[i]
        u = float(px[j]) + (float(q % s) + 0.5) / float(s) - 0.5
        v = float(py[j]) + (float(q // s) + 0.5) / float(s) - 0.5
        camera_hit(obj, scene, centre, wp.normalize(pix_to_dir * wp.vec3(u, v, 1.0)), k, tri, bary, hit)
        n_hit += int(hit[k])
    rest = n_hit > 0 and n_hit < n_first
    for i in range(n_first, s * s):
        q = order[i]
        k = k0 + q
        if rest:
            u = float(px[j]) + (float(q % s) + 0.5) / float(s) - 0.5
            v = float(py[j]) + (float(q // s) + 0.5) / float(s) - 0.5
            camera_hit(obj, scene, centre, wp.normalize(pix_to_dir * wp.vec3(u, v, 1.0)), k, tri, bary, hit)
        else:
            tri[k] = -1
            bary[k] = wp.vec3(0.0, 0.0, 0.0)
            hit[k] = wp.uint8(0)
    full[j] = wp.uint8(0)
    if rest or n_first == s * s:
        full[j] = wp.uint8(1)


def first_samples(s: int, n: int = 4) -> np.ndarray:
    """The order (s*s,) int32 in which OutlineHits casts a pixel's s x s sub-samples (q = b s + a for
    column a, row b): its first min(n, s*s) entries are the sub-samples it casts on every pixel, the rest
    follow only where those disagree. Nested in the full s x s grid, so no ray is cast twice.

    n = 4 (default): the grid's 4 corner sub-samples. They span the convex hull of all s x s, so a straight
    edge that leaves the 4 on one side leaves every one of the s x s there too (a half-plane holding the
    hull's corners holds the hull): on a pixel that one straight edge crosses, or none, the adaptive
    coverage is the full grid's exactly; it can differ only where a corner of the outline or a part
    thinner than the pixel lies between them. Other n: the first n in row order."""
    if s < 1:
        raise ValueError(f"first_samples: s = {s}, at least 1")
    if n >= s * s:
        return np.arange(s * s, dtype=np.int32)
    first = [0, s - 1, (s - 1) * s, s * s - 1] if n == 4 else list(range(max(n, 1)))
    rest = [q for q in range(s * s) if q not in set(first)]
    return np.asarray(first + rest, np.int32)


class _SampleOrder:
    """first_samples' order on the device for OutlineHits and OutlineShade, uploaded when (s, first) changes."""

    MAX = 1024  # s*s at most (s <= 32)

    def __init__(self, device: str):
        from kernels.buffers import Buffer

        self.buf = Buffer(self.MAX, wp.int32, device)
        self._key: tuple[int, int] | None = None

    def set(self, who: str, s: int, first: int | None) -> int:
        """The rays cast on every pixel (first_samples(s, first); None: all s*s), with the order uploaded;
        ValueError naming `who` above MAX rays a pixel."""
        k = s * s
        if k > self.MAX:
            raise ValueError(f"{who}: {s} x {s} rays a pixel, at most {self.MAX}")
        n_first = k if first is None else max(1, min(int(first), k))
        if self._key != (s, n_first):
            self.buf.upload(first_samples(s, n_first))
            self._key = (s, n_first)
        return n_first


class OutlineHits:
    """s x s sub-pixel camera rays through a list of pixels against the object's mesh, each
    depth-tested against the scene model only where it hits the object (one launch for both, as
    kernels.shade.CameraHits over a rectangle), adaptively: a few first rays a pixel, all s x s only on
    the pixels whose first rays disagree (first_samples). Buffers of `block` rays are made once; more
    rays go in blocks of whole pixels."""

    MAX_SAMPLES = _SampleOrder.MAX

    def __init__(self, device: str, block: int = 32768):
        from kernels.buffers import Buffer

        self.device, self.block = device, block
        self._px = Buffer(block, wp.int32, device)
        self._py = Buffer(block, wp.int32, device)
        self._tri = Buffer(block, wp.int32, device)
        self._bary = Buffer(block, wp.vec3, device)
        self._hit = Buffer(block, wp.uint8, device)
        self._full = Buffer(block, wp.uint8, device)
        self._order = _SampleOrder(device)
        self.rays = 0  # rays cast by the last call

    def __call__(self, obj, scene, centre: np.ndarray, pix_to_dir: np.ndarray, px: np.ndarray, py: np.ndarray,
                 s: int, split=None, first: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(tri (n,) int32 (-1: none), bary (n,3) float32, hit (n,) bool, full (len(px),) bool) of the
        n = len(px) s^2 sub-samples of pixels (px, py) (columns, rows), pixel by pixel, sub-sample (a, b) at
        (px + (a + 0.5)/s - 0.5, py + (b + 0.5)/s - 0.5) as entry b s + a, the ray of pixel position
        (u, v) being pix_to_dir @ (u, v, 1) normalised (pix_to_dir = R^T K^-1). `first`: rays cast on
        every pixel (first_samples(s, first)); the others only on pixels where some of those reach the
        object and some do not (full True there); a pixel not full has its other entries as misses, so
        its coverage is its hits over len(first) rays (None or >= s^2: every ray on every pixel, full
        all True). obj, scene: kernels.visibility.Occluder. `split(launch, n)` runs launch(lo, hi) over
        ranges of pixels covering [0, n) (None: one launch)."""
        k = s * s
        n_first = self._order.set("OutlineHits", s, first)
        per = max(1, self.block // k)  # whole pixels a block
        n = len(px) * k
        tri, bary, hit = np.empty(n, np.int32), np.empty((n, 3), np.float32), np.empty(n, bool)
        full = np.empty(len(px), bool)
        run = split or (lambda launch, m: launch(0, m))
        M = wp.mat33(*np.asarray(pix_to_dir, np.float32).reshape(-1))
        c = wp.vec3(*np.asarray(centre, np.float32))
        for p0 in range(0, len(px), per):
            p1 = min(len(px), p0 + per)
            self._px.upload(np.asarray(px[p0:p1], np.int32))
            self._py.upload(np.asarray(py[p0:p1], np.int32))
            first_ray, m = p0 * k, (p1 - p0) * k

            def launch(lo: int, hi: int) -> None:
                wp.launch(_outline_hits_kernel, dim=hi - lo,
                          inputs=[wp.uint64(obj.id), wp.uint64(scene.id), c, M, self._px.dev, self._py.dev, int(s),
                                  self._order.buf.dev, int(n_first), int(lo)],
                          outputs=[self._tri.dev, self._bary.dev, self._hit.dev, self._full.dev], device=self.device)

            run(launch, p1 - p0)
            tri[first_ray:first_ray + m] = self._tri.pull(m)
            bary[first_ray:first_ray + m] = self._bary.pull(m)
            hit[first_ray:first_ray + m] = self._hit.pull(m) != 0
            full[p0:p1] = self._full.pull(p1 - p0) != 0
        self.rays = int(len(px) * n_first + full.sum() * (k - n_first))
        return tri, bary, hit, full


# ----------------------------------------------------------------------------- rays toward the sun
SUN_RAYS_SPLIT = 4096  # points (rays) from which SunVisibility and HitSun run two launches side by side on the CPU


MAX_SUN_MESHES = 8  # meshes a ray toward the sun is tested against at most (SunVisibility, HitSun, OutlineShade)


def _sun_meshes(ws, device: str, mesh_ids: list[int], who: str) -> tuple[wp.array, int]:
    """The meshes a ray toward the sun must pass (Warp ids, 0s skipped) in the workspace's "meshes" buffer,
    and how many; ValueError naming `who` above MAX_SUN_MESHES."""
    ids = [int(i) for i in mesh_ids if int(i) != 0]
    if len(ids) > MAX_SUN_MESHES:
        raise ValueError(f"{who}: {len(ids)} meshes, at most {MAX_SUN_MESHES}")
    return ws.upload("meshes", np.asarray(ids or [0], np.uint64), wp.uint64, device, capacity=MAX_SUN_MESHES), len(ids)


# ----------------------------------------------------------------------------- the sun per camera hit
@wp.func
def _exit_t(p: wp.vec3d, d: wp.vec3d, ex_c0: wp.array(dtype=wp.vec3d), ex_n: wp.array(dtype=wp.vec3d),
            ex_inv: wp.array(dtype=wp.float64), ex_u: wp.array(dtype=wp.vec3d), ex_v: wp.array(dtype=wp.vec3d)) -> wp.float64:
    """Distance (m) along d from p to the first opening the ray leaves through, -1 when none (lighting.sun
    .SunLight.exit_distance's arithmetic, in float64: opening e's corner ex_c0, normal ex_n, 1 / -(d . n) ex_inv,
    edges over their squared lengths ex_u, ex_v)."""
    best = wp.float64(-1.0)
    for e in range(ex_c0.shape[0]):
        pc = p - ex_c0[e]
        t = wp.dot(pc, ex_n[e]) * ex_inv[e]
        h = pc + t * d
        u = wp.dot(h, ex_u[e])
        v = wp.dot(h, ex_v[e])
        if t > wp.float64(0.0) and u >= wp.float64(0.0) and u <= wp.float64(1.0) and v >= wp.float64(0.0) \
                and v <= wp.float64(1.0) and (best < wp.float64(0.0) or t < best):
            best = t
    return best


@wp.func
def _half_plane_share(u: wp.float64) -> wp.float64:
    """Share of a uniform disk lying on the inner side of a line at u disk radii from its centre (u > 0: the
    centre inside): 1 at u >= 1, 0 at u <= -1, 1/2 at 0 (a circular segment's area over the disk's)."""
    if u >= wp.float64(1.0):
        return wp.float64(1.0)
    if u <= wp.float64(-1.0):
        return wp.float64(0.0)
    return (wp.float64(wp.pi) - wp.acos(u) + u * wp.sqrt(wp.float64(1.0) - u * u)) / wp.float64(wp.pi)


@wp.func
def _disk_through(p: wp.vec3d, d: wp.vec3d, tan_a: wp.float64, e: int, ex_c0: wp.array(dtype=wp.vec3d),
                  ex_n: wp.array(dtype=wp.vec3d), ex_inv: wp.array(dtype=wp.float64), ex_u: wp.array(dtype=wp.vec3d),
                  ex_v: wp.array(dtype=wp.vec3d)) -> wp.vec2d:
    """(share of the sun's disk (angular radius atan(tan_a)) seen from p through opening e, the distance m along
    d to the opening's plane; (0, -1) behind it). The disk's directions d + delta (|delta| <= tan_a, delta _|_ d)
    meet the plane at h + t (delta - (delta . n) / (d . n) d): across an edge of in-plane unit direction e the
    footprint's half-width is t tan_a |e - n (d . e) / (d . n)| and its share inside the edge a circular
    segment's (_half_plane_share); the four edges' shares multiplied (exact but within a footprint of a corner)."""
    pc = p - ex_c0[e]
    t = wp.dot(pc, ex_n[e]) * ex_inv[e]
    if t <= wp.float64(0.0):
        return wp.vec2d(wp.float64(0.0), wp.float64(-1.0))
    h = pc + t * d
    nrm = ex_n[e]
    dn = -wp.float64(1.0) / ex_inv[e]  # d . n
    share = wp.float64(1.0)
    for k in range(2):
        a = ex_u[e]
        if k == 1:
            a = ex_v[e]
        la = wp.sqrt(wp.dot(a, a))  # 1 / the edge's length
        ea = a / la
        g = ea - nrm * (wp.dot(d, ea) / dn)
        r = t * tan_a * wp.sqrt(wp.dot(g, g)) * la  # the footprint's half-width in edge lengths
        x = wp.dot(h, a)  # the centre's place along the edge, in edge lengths (0..1 inside)
        share = share * _half_plane_share(x / r) * _half_plane_share((wp.float64(1.0) - x) / r)
    return wp.vec2d(share, t)


@wp.func
def _disk_share(p: wp.vec3d, d: wp.vec3d, tan_a: wp.float64, ex_c0: wp.array(dtype=wp.vec3d),
                ex_n: wp.array(dtype=wp.vec3d), ex_inv: wp.array(dtype=wp.float64), ex_u: wp.array(dtype=wp.vec3d),
                ex_v: wp.array(dtype=wp.vec3d)) -> wp.vec2d:
    """(share of the sun's disk seen from p through the openings (the openings' shares summed, at most 1), the
    distance m along d to the plane of the opening passing the largest share; (0, -1): none)."""
    total = wp.float64(0.0)
    best = wp.float64(0.0)
    t_best = wp.float64(-1.0)
    for e in range(ex_c0.shape[0]):
        st = _disk_through(p, d, tan_a, e, ex_c0, ex_n, ex_inv, ex_u, ex_v)
        total = total + st[0]
        if st[0] > best:
            best = st[0]
            t_best = st[1]
    return wp.vec2d(wp.min(total, wp.float64(1.0)), t_best)


@wp.func
def _sun_soft(p: wp.vec3d, d: wp.vec3d, d32: wp.vec3, tan_a: wp.float64, ex_c0: wp.array(dtype=wp.vec3d),
              ex_n: wp.array(dtype=wp.vec3d), ex_inv: wp.array(dtype=wp.float64), ex_u: wp.array(dtype=wp.vec3d),
              ex_v: wp.array(dtype=wp.vec3d), meshes: wp.array(dtype=wp.uint64), n_meshes: int) -> wp.float64:
    """The share of the sun's disk p sees: tan_a 0, _sun_free (its centre, 0 or 1); else the disk's share through
    the openings (_disk_share: the openings' edges soften into their penumbra) where the ray toward the disk's
    centre meets none of the meshes before that opening's plane (the meshes' own shadows stay hard)."""
    if tan_a <= wp.float64(0.0):
        return wp.float64(_sun_free(p, d, d32, ex_c0, ex_n, ex_inv, ex_u, ex_v, meshes, n_meshes))
    st = _disk_share(p, d, tan_a, ex_c0, ex_n, ex_inv, ex_u, ex_v)
    if st[0] <= wp.float64(0.0):
        return wp.float64(0.0)
    start = wp.vec3(wp.float32(p[0]), wp.float32(p[1]), wp.float32(p[2]))
    for k in range(n_meshes):
        if wp.mesh_query_ray_anyhit(meshes[k], start, d32, wp.float32(st[1] * wp.float64(0.9999))):
            return wp.float64(0.0)
    return st[0]


@wp.func
def _sun_delta(v: wp.array(dtype=wp.vec3d), n: wp.array(dtype=wp.vec3d), f: wp.array2d(dtype=wp.int32),
               vis_v: wp.array(dtype=wp.float64), code: wp.array(dtype=wp.uint8), t: int, b0: wp.float64,
               b1: wp.float64, b2: wp.float64, d: wp.vec3d, d32: wp.vec3, eps: wp.float64, tan_a: wp.float64,
               ex_c0: wp.array(dtype=wp.vec3d), ex_n: wp.array(dtype=wp.vec3d), ex_inv: wp.array(dtype=wp.float64),
               ex_u: wp.array(dtype=wp.vec3d), ex_v: wp.array(dtype=wp.vec3d), meshes: wp.array(dtype=wp.uint64),
               n_meshes: int) -> wp.float64:
    """A camera hit's sun share (face t of code 1: the cos of its interpolated normal; code 2: that cos where
    the ray from the hit, moved eps m along that normal, toward the sun is free (_sun_free), else 0) minus its
    corners' blend of vis_v (barycentrics b0, b1, b2): what HitSun returns and OutlineShade adds per hit. tan_a > 0:
    the share of the sun's disk (angular radius atan(tan_a)) the openings pass (_sun_soft, _disk_share) in
    place of the ray's 0 or 1, on code 1 too (its corners may lie in an opening's penumbra)."""
    c0 = f[t, 0]
    c1 = f[t, 1]
    c2 = f[t, 2]
    nrm = b0 * n[c0] + b1 * n[c1] + b2 * n[c2]
    nrm = nrm / wp.max(wp.sqrt(wp.dot(nrm, nrm)), wp.float64(1.0e-12))
    cos = wp.dot(nrm, d)
    vis = wp.float64(0.0)
    if code[t] == wp.uint8(1):  # every corner sunlit: the interpolated normal's cos
        vis = wp.max(cos, wp.float64(0.0))
        if tan_a > wp.float64(0.0) and vis > wp.float64(0.0):  # x the disk's share the openings pass
            p1 = b0 * v[c0] + b1 * v[c1] + b2 * v[c2] + nrm * eps
            vis = vis * _disk_share(p1, d, tan_a, ex_c0, ex_n, ex_inv, ex_u, ex_v)[0]
    elif cos > wp.float64(0.0):  # a shadow's edge crosses the face: a ray toward the sun
        p = b0 * v[c0] + b1 * v[c1] + b2 * v[c2] + nrm * eps
        vis = cos * _sun_soft(p, d, d32, tan_a, ex_c0, ex_n, ex_inv, ex_u, ex_v, meshes, n_meshes)
    return vis - (b0 * vis_v[c0] + b1 * vis_v[c1] + b2 * vis_v[c2])


@wp.kernel
def _hit_sun_kernel(v: wp.array(dtype=wp.vec3d), n: wp.array(dtype=wp.vec3d), f: wp.array2d(dtype=wp.int32),
                    vis_v: wp.array(dtype=wp.float64), code: wp.array(dtype=wp.uint8), tri: wp.array(dtype=wp.int32),
                    bary: wp.array(dtype=wp.vec3), d: wp.vec3d, d32: wp.vec3, eps: wp.float64, tan_a: wp.float64,
                    ex_c0: wp.array(dtype=wp.vec3d), ex_n: wp.array(dtype=wp.vec3d), ex_inv: wp.array(dtype=wp.float64),
                    ex_u: wp.array(dtype=wp.vec3d), ex_v: wp.array(dtype=wp.vec3d), meshes: wp.array(dtype=wp.uint64),
                    n_meshes: int, lo: int, delta: wp.array(dtype=wp.float64)):
    """One camera hit a thread (HitSun): _sun_delta."""
    i = wp.tid() + lo
    bf = bary[i]
    delta[i] = _sun_delta(v, n, f, vis_v, code, tri[i], wp.float64(bf[0]), wp.float64(bf[1]), wp.float64(bf[2]),
                          d, d32, eps, tan_a, ex_c0, ex_n, ex_inv, ex_u, ex_v, meshes, n_meshes)


def exit_arrays(exits: list, device: str) -> list[wp.array]:
    """lighting.sun.SunLight's openings that the sun enters through ((corner c0, normal, 1 / -(d . normal),
    (3,2) edges over their squared lengths) each) as _exit_t's device arrays."""
    c0 = np.array([e[0] for e in exits], np.float64).reshape(-1, 3)
    nrm = np.array([e[1] for e in exits], np.float64).reshape(-1, 3)
    inv = np.array([e[2] for e in exits], np.float64)
    uv = np.array([e[3] for e in exits], np.float64).reshape(-1, 3, 2)
    return [wp.array(a, dtype=t, device=device) for a, t in
            ((c0, wp.vec3d), (nrm, wp.vec3d), (inv, wp.float64),
             (np.ascontiguousarray(uv[:, :, 0]), wp.vec3d), (np.ascontiguousarray(uv[:, :, 1]), wp.vec3d))]


@wp.func
def _sun_free(p: wp.vec3d, d: wp.vec3d, d32: wp.vec3, ex_c0: wp.array(dtype=wp.vec3d), ex_n: wp.array(dtype=wp.vec3d),
              ex_inv: wp.array(dtype=wp.float64), ex_u: wp.array(dtype=wp.vec3d), ex_v: wp.array(dtype=wp.vec3d),
              meshes: wp.array(dtype=wp.uint64), n_meshes: int) -> int:
    """1 where the ray from p toward the sun leaves through an opening (_exit_t) before meeting any of the
    meshes (the start and the exit distance rounded to float32 for Warp's ray query), else 0. The query
    stops 1e-4 of the way short of the opening: the wall the opening is cut from lies in its plane, and
    in float32 its hit there falls before or after the exit by rounding alone (a speckled sunlit patch)."""
    te = _exit_t(p, d, ex_c0, ex_n, ex_inv, ex_u, ex_v)
    if te <= wp.float64(0.0):
        return 0
    start = wp.vec3(wp.float32(p[0]), wp.float32(p[1]), wp.float32(p[2]))
    for k in range(n_meshes):
        if wp.mesh_query_ray_anyhit(meshes[k], start, d32, wp.float32(te * wp.float64(0.9999))):
            return 0
    return 1


@wp.kernel
def _sun_vis_kernel(p: wp.array(dtype=wp.vec3d), n: wp.array(dtype=wp.vec3d), d: wp.vec3d, d32: wp.vec3,
                    eps: wp.float64, tan_a: wp.float64, ex_c0: wp.array(dtype=wp.vec3d), ex_n: wp.array(dtype=wp.vec3d),
                    ex_inv: wp.array(dtype=wp.float64), ex_u: wp.array(dtype=wp.vec3d), ex_v: wp.array(dtype=wp.vec3d),
                    meshes: wp.array(dtype=wp.uint64), n_meshes: int, lo: int, vis: wp.array(dtype=wp.float64)):
    """One point a thread (SunVisibility): max(n.d, 0) x its ray toward the sun free (from p + eps n); tan_a > 0:
    x the share of the sun's disk it sees (_sun_soft)."""
    i = wp.tid() + lo
    cos = wp.dot(n[i], d)
    vis[i] = wp.float64(0.0)
    if cos > wp.float64(0.0):
        vis[i] = cos * _sun_soft(p[i] + n[i] * eps, d, d32, tan_a, ex_c0, ex_n, ex_inv, ex_u, ex_v, meshes, n_meshes)


class SunVisibility:
    """lighting.sun.SunLight.visibility in one launch: per point its cos toward the sun, the exit through an
    opening and the ray past the meshes (what its numpy passes, exit_distance and a launch of rays did, in the same
    float64 arithmetic up to the order of a dot product's terms). Buffers of a Workspace's rows; more points
    go in blocks."""

    def __init__(self, device: str, exits: list, d: np.ndarray):
        from kernels.buffers import Workspace

        self.device = device
        self.ws = Workspace()
        self.d = np.asarray(d, np.float64)
        self.exits = exit_arrays(exits, device)

    def __call__(self, points: np.ndarray, normals: np.ndarray, mesh_ids: list[int], eps: float,
                 parallel: bool = True, tan_a: float = 0.0) -> np.ndarray:
        """(N,) float64: max(n.d, 0) where the ray from points + eps normals (N,3) m toward the sun leaves
        through an opening past every mesh of mesh_ids (Warp ids, 0s skipped), else 0. parallel: two
        launches side by side on the CPU from SUN_RAYS_SPLIT points on (False from inside a pooled thread).
        tan_a > 0 (tan of the sun disk's angular radius): max(n.d, 0) x the disk's share (_sun_soft)."""
        m = len(points)
        out = np.zeros(m)
        if m == 0:
            return out
        ws, dev = self.ws, self.device
        md, n_ids = _sun_meshes(ws, dev, mesh_ids, "SunVisibility")
        d, d32 = wp.vec3d(*self.d), wp.vec3(*map(float, self.d))
        rows = ws.rows
        cpu = wp.get_device(dev).is_cpu
        for s in range(0, m, rows):
            e = min(m, s + rows)
            b = e - s
            pd = ws.upload("p", points[s:e], wp.vec3d, dev, capacity=rows)
            nd = ws.upload("n", normals[s:e], wp.vec3d, dev, capacity=rows)
            vd = ws.buffer("vis", rows, wp.float64, dev)
            cuts = [(0, b // 2), (b // 2, b)] if parallel and cpu and b >= SUN_RAYS_SPLIT else [(0, b)]
            runtime.run_parallel([lambda a=a, z=z: wp.launch(
                _sun_vis_kernel, dim=z - a, inputs=[pd, nd, d, d32, wp.float64(eps), wp.float64(tan_a), *self.exits,
                                                    md, n_ids, a],
                outputs=[vd.dev], device=dev) for a, z in cuts])
            out[s:e] = vd.pull(b)
        return out


class HitSun:
    """The sun per camera hit on a mesh against its corners' blend, one thread a hit and its ray toward the
    sun in the same launch (lighting.sun.SunLight.hit_correction: what its numpy passes, exit_distance and
    the rays' launch did, in the same float64 arithmetic up to the order of a dot product's terms). The mesh's
    positions and sun shares are uploaded every call, its normals and faces when they are other arrays than the
    last call's (as SunLight._flat_faces keeps them); the openings once."""

    def __init__(self, device: str, exits: list, d: np.ndarray):
        from kernels.buffers import Workspace

        self.device = device
        self.ws = Workspace()
        self.d = np.asarray(d, np.float64)
        self.exits = exit_arrays(exits, device)
        self._shape: tuple | None = None  # (n, f) of the normals and faces uploaded, by identity

    def _upload(self, v: np.ndarray, n: np.ndarray, f: np.ndarray, vis_v: np.ndarray) -> tuple:
        """The mesh's device arrays: positions and sun shares every call, normals and faces when they are
        other arrays than the last call's (a shape's shading mesh keeps them from frame to frame)."""
        ws, dev = self.ws, self.device
        if self._shape is None or self._shape[0] is not n or self._shape[1] is not f:
            self._shape = (n, f, ws.upload("n", np.asarray(n, np.float64), wp.vec3d, dev),
                           ws.upload("f", np.asarray(f, np.int32), wp.int32, dev))
        return (ws.upload("v", np.asarray(v, np.float64), wp.vec3d, dev), self._shape[2], self._shape[3],
                ws.upload("vis", np.asarray(vis_v, np.float64), wp.float64, dev))

    def __call__(self, v: np.ndarray, n: np.ndarray, f: np.ndarray, vis_v: np.ndarray, code: np.ndarray,
                 tri: np.ndarray, bary: np.ndarray, mesh_ids: list[int], eps: float, rays: int = 0,
                 parallel: bool = True, tan_a: float = 0.0) -> np.ndarray:
        """delta (M,) float64 of the hits (tri (M,) into f (F,3), bary (M,3)) on a mesh (v (V,3) m, unit
        vertex normals n (V,3)) whose vertices' sun shares are vis_v (V,): the hit's sun share (code[tri] 1:
        cos of its interpolated normal; 2: that cos where a ray from the hit (moved eps m along it) toward the
        sun leaves through an opening past every mesh of mesh_ids (Warp ids, 0s skipped), else 0) minus
        the blend of its corners' vis_v. code (F,) uint8, nonzero on every face of a hit. rays: how many
        hits are code 2 (two launches side by side on the CPU from SUN_RAYS_SPLIT of them, when parallel).
        tan_a > 0: the hit's sun share with the disk's share the openings pass (_sun_delta)."""
        m = len(tri)
        if m == 0:
            return np.zeros(0)
        ws, dev = self.ws, self.device
        vd, nd, fd, visd = self._upload(v, n, f, vis_v)
        cd = ws.upload("code", np.asarray(code, np.uint8), wp.uint8, dev)
        md, n_ids = _sun_meshes(ws, dev, mesh_ids, "HitSun")
        d, d32 = wp.vec3d(*self.d), wp.vec3(*map(float, self.d))
        rows = ws.rows  # hits a launch: fixed buffers, more hits in blocks
        out = np.empty(m)
        split = parallel and rays >= SUN_RAYS_SPLIT and wp.get_device(dev).is_cpu
        for s in range(0, m, rows):
            e = min(m, s + rows)
            b = e - s
            td = ws.upload("tri", np.asarray(tri[s:e], np.int32), wp.int32, dev, capacity=rows)
            bd = ws.upload("bary", np.asarray(bary[s:e], np.float32), wp.vec3, dev, capacity=rows)
            dd = ws.buffer("delta", rows, wp.float64, dev)
            cuts = [(0, b // 2), (b // 2, b)] if split else [(0, b)]
            runtime.run_parallel([lambda a=a, z=z: wp.launch(
                _hit_sun_kernel, dim=z - a, inputs=[vd, nd, fd, visd, cd, td, bd, d, d32, wp.float64(eps),
                                                    wp.float64(tan_a), *self.exits,
                                                    md, n_ids, a], outputs=[dd.dev], device=dev) for a, z in cuts])
            out[s:e] = dd.pull(b)
        return out


# ----------------------------------------------------------------------------- the outline, shaded
@wp.struct
class HitShading:
    """What a camera hit's radiance is made of (OutlineShade): the shading mesh (positions v m, unit normals
    n, faces f), its vertices' radiance L, and the sun per hit (sun 1: its vertices' sun shares vis_v, each
    face's code (HitSun: 0 none, 1 wholly lit curved, 2 a shadow's edge crosses it), the sun direction d,
    albedo x irradiance/pi `sun_rgb`, the openings and the meshes a ray toward the sun must pass)."""
    v: wp.array(dtype=wp.vec3d)
    n: wp.array(dtype=wp.vec3d)
    f: wp.array2d(dtype=wp.int32)
    L: wp.array(dtype=wp.vec3d)
    sun: int
    vis_v: wp.array(dtype=wp.float64)
    code: wp.array(dtype=wp.uint8)
    d: wp.vec3d
    d32: wp.vec3
    eps: wp.float64
    tan_a: wp.float64  # tan of the sun disk's angular radius (0: its centre only; _sun_delta)
    albedo: wp.vec3d
    E: wp.vec3d
    ex_c0: wp.array(dtype=wp.vec3d)
    ex_n: wp.array(dtype=wp.vec3d)
    ex_inv: wp.array(dtype=wp.float64)
    ex_u: wp.array(dtype=wp.vec3d)
    ex_v: wp.array(dtype=wp.vec3d)
    meshes: wp.array(dtype=wp.uint64)
    n_meshes: int


@wp.func
def _hit_radiance(h: HitShading, t: int, bf: wp.vec3) -> wp.vec3d:
    """A camera hit's radiance (face t, barycentrics bf): its corners' L blended, plus the sun per hit on a
    face of code 1 or 2 (its sun share minus the corners' blend of vis_v, x albedo irradiance/pi; at least 0),
    as refine_clipped_edges's numpy and SunLight.hit_correction (HitSun) compute it."""
    c0 = h.f[t, 0]
    c1 = h.f[t, 1]
    c2 = h.f[t, 2]
    b0 = wp.float64(bf[0])
    b1 = wp.float64(bf[1])
    b2 = wp.float64(bf[2])
    rad = b0 * h.L[c0] + b1 * h.L[c1] + b2 * h.L[c2]
    if h.sun != 0:
        if h.code[t] != wp.uint8(0):
            delta = _sun_delta(h.v, h.n, h.f, h.vis_v, h.code, t, b0, b1, b2, h.d, h.d32, h.eps, h.tan_a, h.ex_c0, h.ex_n,
                               h.ex_inv, h.ex_u, h.ex_v, h.meshes, h.n_meshes)
            rad = wp.vec3d(wp.max(rad[0] + h.albedo[0] * (delta * h.E[0]), wp.float64(0.0)),
                           wp.max(rad[1] + h.albedo[1] * (delta * h.E[1]), wp.float64(0.0)),
                           wp.max(rad[2] + h.albedo[2] * (delta * h.E[2]), wp.float64(0.0)))
    return rad


@wp.func
def _outline_ray(obj: wp.uint64, scene: wp.uint64, centre: wp.vec3, pix_to_dir: wp.mat33, x: float, y: float,
                 s: int, q: int, h: HitShading, acc: wp.vec3d) -> wp.vec4d:
    """Sub-sample q of the pixel (x, y)'s s x s grid (kernels.shade.camera_ray): (its radiance added
    to acc, 1) where it reaches the object unhidden by the scene, else (acc, 0)."""
    u = x + (float(q % s) + 0.5) / float(s) - 0.5
    v = y + (float(q // s) + 0.5) / float(s) - 0.5
    t, b, seen = camera_ray(obj, scene, centre, wp.normalize(pix_to_dir * wp.vec3(u, v, 1.0)))
    if seen != 0:
        c = acc + _hit_radiance(h, t, b)
        return wp.vec4d(c[0], c[1], c[2], wp.float64(1.0))
    return wp.vec4d(acc[0], acc[1], acc[2], wp.float64(0.0))


@wp.kernel
def _outline_shade_kernel(obj: wp.uint64, scene: wp.uint64, centre: wp.vec3, pix_to_dir: wp.mat33,
                          px: wp.array(dtype=wp.int32), py: wp.array(dtype=wp.int32), s: int,
                          order: wp.array(dtype=wp.int32), n_first: int, h: HitShading, lo: int,
                          cov: wp.array(dtype=wp.float64), rad: wp.array(dtype=wp.vec3d), full: wp.array(dtype=wp.uint8)):
    """One pixel a thread (OutlineShade): _outline_hits_kernel's rays (order[0:n_first] first, the rest only
    where those disagree), each hit shaded (_hit_radiance); the pixel's coverage (hits over the rays cast:
    all s^2 where full, else n_first) and its hits' mean radiance."""
    j = wp.tid() + lo
    x = float(px[j])
    y = float(py[j])
    acc = wp.vec3d(wp.float64(0.0), wp.float64(0.0), wp.float64(0.0))
    n_hit = int(0)
    for i in range(n_first):
        r = _outline_ray(obj, scene, centre, pix_to_dir, x, y, s, order[i], h, acc)
        acc = wp.vec3d(r[0], r[1], r[2])
        n_hit += int(r[3])
    rest = n_hit > 0 and n_hit < n_first
    if rest:
        for i in range(n_first, s * s):
            r = _outline_ray(obj, scene, centre, pix_to_dir, x, y, s, order[i], h, acc)
            acc = wp.vec3d(r[0], r[1], r[2])
            n_hit += int(r[3])
    cast = n_first
    full[j] = wp.uint8(0)
    if rest or n_first == s * s:
        full[j] = wp.uint8(1)
        cast = s * s
    cov[j] = wp.float64(n_hit) / wp.float64(cast)
    rad[j] = acc / wp.float64(wp.max(n_hit, 1))


class OutlineShade:
    """OutlineHits's adaptive s x s rays a pixel with each hit shaded in the same launch (the shading mesh's
    vertex radiance blended, the sun per hit as SunLight.hit_correction: a ray toward the sun where a shadow's
    edge crosses the face), summed per pixel: what SunStage.refine_clipped_edges read back per ray and
    shaded in numpy, read back per pixel (its coverage and mean radiance). The mesh's arrays are uploaded per
    call (its faces when they change); pixels go in blocks of a Workspace's rows."""

    def __init__(self, device: str, exits: list, d: np.ndarray):
        from kernels.buffers import Workspace

        self.device = device
        self.ws = Workspace()
        self.d = np.asarray(d, np.float64)
        self.exits = exit_arrays(exits, device)
        self._order = _SampleOrder(device)
        self._faces = None  # the faces array uploaded (by identity)
        self.rays = 0  # camera rays cast by the last call

    def __call__(self, obj, scene, centre: np.ndarray, pix_to_dir: np.ndarray, px: np.ndarray, py: np.ndarray,
                 s: int, mesh: tuple, L: np.ndarray, sun: tuple | None = None, split=None,
                 first: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(coverage (n,) float64, mean radiance of the hits (n,3) float64 (0 where none), full (n,) bool) of
        the n pixels (px, py) (columns, rows): their s x s sub-samples cast as OutlineHits casts them (`first`
        on every pixel, the rest where those disagree: full), each hit's radiance its face's corners' L (V,3)
        blended (mesh = (v (V,3) m, unit normals n (V,3), faces f (F,3))), and with sun = (vis_v (V,), code
        (F,) uint8 (SunLight.hit_codes), albedo (3,), irradiance/pi (3,), Warp mesh ids, eps m[, tan_a]) the sun per hit
        added as SunLight.hit_correction's delta x albedo x irradiance/pi, at least 0. obj, scene:
        kernels.visibility.Occluder. `split(launch, n)` runs launch(lo, hi) over ranges of pixels covering
        [0, n) (None: one launch)."""
        k = s * s
        n_first = self._order.set("OutlineShade", s, first)
        ws, dev = self.ws, self.device
        v, nrm, f = mesh
        h = HitShading()
        h.v = ws.upload("v", np.asarray(v, np.float64), wp.vec3d, dev)
        h.n = ws.upload("n", np.asarray(nrm, np.float64), wp.vec3d, dev)
        if self._faces is not f:
            self._fd = ws.upload("f", np.asarray(f, np.int32), wp.int32, dev)
            self._faces = f
        h.f = self._fd
        h.L = ws.upload("L", np.asarray(L, np.float64), wp.vec3d, dev)
        h.d, h.d32 = wp.vec3d(*self.d), wp.vec3(*map(float, self.d))
        h.ex_c0, h.ex_n, h.ex_inv, h.ex_u, h.ex_v = self.exits
        if sun is None:
            h.sun = 0
            h.vis_v = ws.upload("vis", np.zeros(1), wp.float64, dev)
            h.code = ws.upload("code", np.zeros(1, np.uint8), wp.uint8, dev)
            h.albedo = h.E = wp.vec3d(0.0, 0.0, 0.0)
            ids, h.eps, h.tan_a = [], wp.float64(0.0), wp.float64(0.0)
        else:
            vis_v, code, albedo, E, ids, eps = sun[:6]
            h.tan_a = wp.float64(sun[6] if len(sun) > 6 else 0.0)
            h.sun = 1
            h.vis_v = ws.upload("vis", np.asarray(vis_v, np.float64), wp.float64, dev)
            h.code = ws.upload("code", np.asarray(code, np.uint8), wp.uint8, dev)
            h.albedo = wp.vec3d(*np.asarray(albedo, np.float64).reshape(3))
            h.E = wp.vec3d(*np.asarray(E, np.float64).reshape(3))
            h.eps = wp.float64(eps)
        h.meshes, h.n_meshes = _sun_meshes(ws, dev, ids, "OutlineShade")
        M = wp.mat33(*np.asarray(pix_to_dir, np.float32).reshape(-1))
        c = wp.vec3(*np.asarray(centre, np.float32))
        run = split or (lambda launch, m: launch(0, m))
        n = len(px)
        cov, rad, full = np.empty(n), np.empty((n, 3)), np.empty(n, bool)
        rows = ws.rows
        for p0 in range(0, n, rows):
            p1 = min(n, p0 + rows)
            b = p1 - p0
            pxd = ws.upload("px", np.asarray(px[p0:p1], np.int32), wp.int32, dev, capacity=rows)
            pyd = ws.upload("py", np.asarray(py[p0:p1], np.int32), wp.int32, dev, capacity=rows)
            cb, rb, fb = (ws.buffer("cov", rows, wp.float64, dev), ws.buffer("rad", rows, wp.vec3d, dev),
                          ws.buffer("full", rows, wp.uint8, dev))

            def launch(lo: int, hi: int) -> None:
                wp.launch(_outline_shade_kernel, dim=hi - lo,
                          inputs=[wp.uint64(obj.id), wp.uint64(scene.id), c, M, pxd, pyd, int(s), self._order.buf.dev,
                                  int(n_first), h, int(lo)], outputs=[cb.dev, rb.dev, fb.dev], device=dev)

            run(launch, b)
            cov[p0:p1] = cb.pull(b)
            rad[p0:p1] = rb.pull(b)
            full[p0:p1] = fb.pull(b) != 0
        self.rays = int(n * n_first + full.sum() * (k - n_first))
        return cov, rad, full
