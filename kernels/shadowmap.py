"""Shadow maps of the object proxy, one per source (seed sec. 6.3.3), and their lookup.

A map is a perspective depth image from the source's point looking at the object's bounding
sphere, its field of view fitted to the sphere (so the proxy always fills it). Rasterisation is
one thread per (map, triangle) writing view-space depth with `atomic_min`; 1/z is interpolated
linearly in screen space (perspective-correct). The occlusion mask of a point x for map s is
M = 1 when x lies behind the stored depth (plus a bias), else 0.

A source inside (or nearly inside) the bounding sphere cannot be covered by one perspective map;
for those the lookup casts the exact ray x -> source against the proxy instead (flag `ray`).

Map layout: depth (S, res, res) float32 metres along the map's forward axis, +inf = empty.

Buffers are allocated once at the batch capacity (kernels.buffers); a frame's proxy is the
object's BVH kept per shape (set_proxy takes it), so rendering a batch allocates nothing.
`may_occlude` bounds a map's shadow: only points inside the cone from the eye around the
proxy's bounding sphere, behind its nearest depth, and whose texels lie in a COARSE x COARSE
block of the map that some triangle's row span touched (`coarse`, marked while rasterising; its summed-area
table `coarse_sat` answers for a box of blocks at once)
can be occluded; the masked sums skip the rest (kernels.masked_sums).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from kernels import runtime
from kernels.buffers import Buffer
from kernels.vec import cross3
from kernels.visibility import Occluder, segment_blocked, segment_meets_box


COARSE = 8  # texels per side of the blocks of `MapSet.coarse`
RASTER_EPS = 1e-3  # texels: a texel centre this close outside a triangle's edge is drawn (no gap between triangles)
BOX_MARGIN = 1e-3  # m: the proxy's bounding box in MapSet is widened by this (float32 points and rays)


@wp.struct
class MapSet:
    origin: wp.array(dtype=wp.vec3)  # (S,) map eye, world
    right: wp.array(dtype=wp.vec3)
    up: wp.array(dtype=wp.vec3)
    fwd: wp.array(dtype=wp.vec3)
    inv_tan: wp.array(dtype=wp.float32)  # 1 / tan(half field of view)
    ray: wp.array(dtype=wp.int32)  # 1: resolve by ray casting against the proxy
    near: wp.array(dtype=wp.float32)  # view depth below which nothing of the proxy lies (m)
    spread: wp.array(dtype=wp.float32)  # half-width of the cluster of sources the map stands for (m; 0: a point)
    axis1: wp.array(dtype=wp.vec3)  # the cluster's half-axes across the view (m; |axis1| = spread)
    axis2: wp.array(dtype=wp.vec3)
    cone_tan: wp.array(dtype=wp.float32)  # may_occlude's cone around the proxy: tan of its half-angle
    cone_sec: wp.array(dtype=wp.float32)  # and 1 / cos of it (ShadowMaps.prepare)
    depth: wp.array3d(dtype=wp.float32)
    coarse: wp.array3d(dtype=wp.int32)  # (S, ceil(res/COARSE), same): 1 where a triangle may have drawn
    coarse_sat: wp.array3d(dtype=wp.int32)  # (S, nc + 1, nc + 1) its summed-area table: blocks set in any box
    sat: int  # 1: may_occlude reads coarse_sat; 0: it loops over the box's blocks (the same answer; A/B)
    # depth range pyramid (ShadowMaps.build_mips): level l >= 1 holds the min and max depth of
    # texel blocks of side 2^l, side mip_side[l] = ceil(mip_side[l-1] / 2), flat at mip_off[l]
    mip_min: wp.array2d(dtype=wp.float32)  # (S, mip_off[mip_levels])
    mip_max: wp.array2d(dtype=wp.float32)
    mip_off: wp.array(dtype=wp.int32)  # (mip_levels + 1,): offset of level l (level 0 = depth itself)
    mip_side: wp.array(dtype=wp.int32)
    mip_levels: int  # the coarsest level (side 1)
    res: int
    bias: float
    proxy: wp.uint64
    box_lo: wp.vec3  # the proxy's bounding box, widened by BOX_MARGIN: what a ray-mode map's segments must meet
    box_hi: wp.vec3
    cull: int  # 1: skip triangles facing away from the eye (closed proxies cast the same shadow)
    taps: int  # samples per axis of a cluster map's PCSS blocker search and filter (kernels.masked_sums.penumbra)


@wp.func
def _to_map(ms: MapSet, s: int, p: wp.vec3) -> wp.vec3:
    """World point -> (pixel x, pixel y, view depth z) in map s (z <= 0: behind the eye)."""
    d = p - ms.origin[s]
    z = wp.dot(d, ms.fwd[s])
    if z <= 1.0e-6:
        return wp.vec3(0.0, 0.0, z)
    half = float(ms.res) * 0.5
    x = wp.dot(d, ms.right[s]) / z * ms.inv_tan[s] * half + half - 0.5
    y = wp.dot(d, ms.up[s]) / z * ms.inv_tan[s] * half + half - 0.5
    return wp.vec3(x, y, z)


@wp.func
def occluded(ms: MapSet, s: int, p: wp.vec3) -> bool:
    """Occlusion mask M for point p and source s: True when the object hides the source from p."""
    if ms.ray[s] == 1:
        return segment_blocked(ms.proxy, p, ms.origin[s])
    q = _to_map(ms, s, p)
    if q[2] <= 1.0e-6:
        return False
    return q[2] > texel_depth(ms, s, q[0], q[1]) + ms.bias


@wp.func
def texel_depth(ms: MapSet, s: int, x: float, y: float) -> float:
    """Map s's depth at the texel nearest pixel position (x, y) (_to_map's), 1e30 off the map
    (nothing drawn there)."""
    ix = int(wp.floor(x + 0.5))
    iy = int(wp.floor(y + 0.5))
    if ix < 0 or iy < 0 or ix >= ms.res or iy >= ms.res:
        return float(1.0e30)
    return ms.depth[s, iy, ix]


@wp.func
def depth_range(ms: MapSet, s: int, x0: int, x1: int, y0: int, y1: int) -> wp.vec2:
    """(min, max) of map s's depth over texels x0..x1, y0..y1 (inside the map) or over a block
    of the pyramid holding them: a lower and an upper bound of every texel there. At most four
    reads, at the finest level where the range spans at most two blocks per axis."""
    if x0 == x1 and y0 == y1:
        d = ms.depth[s, y0, x0]
        return wp.vec2(d, d)
    lv = int(1)
    while lv < ms.mip_levels and ((x1 >> lv) - (x0 >> lv) > 1 or (y1 >> lv) - (y0 >> lv) > 1):
        lv += 1
    off = ms.mip_off[lv]
    side = ms.mip_side[lv]
    lo = float(1.0e30)
    hi = float(-1.0e30)
    for by in range(y0 >> lv, (y1 >> lv) + 1):
        for bx in range(x0 >> lv, (x1 >> lv) + 1):
            lo = wp.min(lo, ms.mip_min[s, off + by * side + bx])
            hi = wp.max(hi, ms.mip_max[s, off + by * side + bx])
    return wp.vec2(lo, hi)


@wp.func
def _block_minmax(ms: MapSet, s: int, lv: int, by: int, bx: int) -> wp.vec2:
    """(min, max) of block (by, bx) of level lv >= 2 over its (up to) four blocks one level finer."""
    cside = ms.mip_side[lv - 1]
    coff = ms.mip_off[lv - 1]
    lo = float(1.0e30)
    hi = float(-1.0e30)
    for dy in range(2):
        for dx in range(2):
            cy = 2 * by + dy
            cx = 2 * bx + dx
            if cy < cside and cx < cside:
                lo = wp.min(lo, ms.mip_min[s, coff + cy * cside + cx])
                hi = wp.max(hi, ms.mip_max[s, coff + cy * cside + cx])
    return wp.vec2(lo, hi)


@wp.kernel
def _mip_kernel(ms: MapSet, first: int, lv: int):
    k, by, bx = wp.tid()
    s = first + k
    side = ms.mip_side[lv]
    if by >= side or bx >= side or not _reads_pyramid(ms, s):
        return
    lo = float(1.0e30)
    hi = float(-1.0e30)
    if lv == 1:
        for dy in range(2):
            for dx in range(2):
                cy = 2 * by + dy
                cx = 2 * bx + dx
                if cy < ms.mip_side[0] and cx < ms.mip_side[0]:
                    d = ms.depth[s, cy, cx]
                    lo = wp.min(lo, d)
                    hi = wp.max(hi, d)
    else:
        m = _block_minmax(ms, s, lv, by, bx)
        lo = m[0]
        hi = m[1]
    ms.mip_min[s, ms.mip_off[lv] + by * side + bx] = lo
    ms.mip_max[s, ms.mip_off[lv] + by * side + bx] = hi


@wp.kernel
def _coarse_sat_kernel(ms: MapSet, first: int):
    # one thread per map: the summed-area table of its coarse blocks (sat[y, x] = blocks set above and left of
    # (y, x)), what may_occlude reads in place of a loop over a box's blocks
    s = first + wp.tid()
    n = ms.coarse.shape[1]
    for y in range(n + 1):
        ms.coarse_sat[s, y, 0] = 0
    for x in range(n + 1):
        ms.coarse_sat[s, 0, x] = 0
    for y in range(n):
        row = int(0)
        for x in range(n):
            row += ms.coarse[s, y, x]
            ms.coarse_sat[s, y + 1, x + 1] = ms.coarse_sat[s, y, x + 1] + row


@wp.func
def _reads_pyramid(ms: MapSet, s: int) -> bool:
    """True when map s's lookups read its depth range pyramid: a cluster map (a spread) drawn by raster (not ray
    mode). A map of spread 0 takes the hard lookup (one texel) and a ray-mode map casts rays: build_mips skips
    their pyramids (whatever they held stays; nothing reads it)."""
    return ms.ray[s] == 0 and ms.spread[s] > 0.0


@wp.kernel
def _mip12_kernel(ms: MapSet, first: int):
    # levels 1 and 2 of the pyramid at once, one thread per level-2 block: its (up to) four level-1 blocks from
    # their texels, then itself from them; the values of _mip_kernel's launches for lv = 1 and 2 (min and max are
    # exact), with a quarter of the threads
    k, by, bx = wp.tid()
    s = first + k
    side2 = ms.mip_side[2]
    if by >= side2 or bx >= side2 or not _reads_pyramid(ms, s):
        return
    side1 = ms.mip_side[1]
    off1 = ms.mip_off[1]
    lo2 = float(1.0e30)
    hi2 = float(-1.0e30)
    for qy in range(2):
        for qx in range(2):
            y1 = 2 * by + qy
            x1 = 2 * bx + qx
            if y1 < side1 and x1 < side1:
                lo = float(1.0e30)
                hi = float(-1.0e30)
                for dy in range(2):
                    for dx in range(2):
                        cy = 2 * y1 + dy
                        cx = 2 * x1 + dx
                        if cy < ms.res and cx < ms.res:
                            d = ms.depth[s, cy, cx]
                            lo = wp.min(lo, d)
                            hi = wp.max(hi, d)
                ms.mip_min[s, off1 + y1 * side1 + x1] = lo
                ms.mip_max[s, off1 + y1 * side1 + x1] = hi
                lo2 = wp.min(lo2, lo)
                hi2 = wp.max(hi2, hi)
    ms.mip_min[s, ms.mip_off[2] + by * side2 + bx] = lo2
    ms.mip_max[s, ms.mip_off[2] + by * side2 + bx] = hi2


@wp.kernel
def _mip_rest_kernel(ms: MapSet, first: int, lv0: int):
    # levels lv0 (>= 2) .. mip_levels of one map per thread, coarsest last, each block from its (up to) four blocks
    # one level finer: the values of _mip_kernel's launches for those levels (min and max are exact) in one launch.
    # From level 3 on a map holds few blocks (85 texels a side: 171 in all), so one thread a map is little work
    # and spares a launch per level
    s = first + wp.tid()
    if not _reads_pyramid(ms, s):
        return
    for lv in range(lv0, ms.mip_levels + 1):
        side = ms.mip_side[lv]
        off = ms.mip_off[lv]
        for by in range(side):
            for bx in range(side):
                m = _block_minmax(ms, s, lv, by, bx)
                ms.mip_min[s, off + by * side + bx] = m[0]
                ms.mip_max[s, off + by * side + bx] = m[1]


@wp.func
def may_occlude(ms: MapSet, s: int, c: wp.vec3, r: float) -> bool:
    """False when no point of the sphere (c, r) can be occluded in map s (conservative): the sphere lies outside the cone from the eye that
    holds the proxy's bounding sphere (widened by a texel for the nearest-texel lookup), or
    wholly in front of the proxy's nearest depth. A ray-mode map: False when no segment from the
    sphere to the eye can meet the proxy's bounding box (then no ray of the lookup hits the proxy)."""
    if ms.ray[s] == 1:
        e = wp.vec3(r, r, r)
        return segment_meets_box(ms.origin[s], c, ms.box_lo - e, ms.box_hi + e)
    d = c - ms.origin[s]
    z = wp.dot(d, ms.fwd[s])
    if z + r <= ms.near[s]:
        return False
    # the cone (cone_tan: the proxy's bounding sphere widened by a texel, and a cluster map's
    # penumbra, which kernels.masked_sums.penumbra reaches spread / near farther out): the signed
    # distance of c from the cone's surface (a lower bound behind the apex) times sec
    lateral = wp.length(d - ms.fwd[s] * z)
    if lateral - z * ms.cone_tan[s] > r * ms.cone_sec[s]:
        return False
    if z - r <= 1.0e-6:
        return True
    # the texels the sphere's points look up: within `ext` of the centre's projection, as
    # |(a+e)/(z+f) - a/z| <= r (z + |a|) / (z (z - r)) for |e|, |f| <= r; +1 for the rounding
    a = wp.dot(d, ms.right[s])
    b = wp.dot(d, ms.up[s])
    k = ms.inv_tan[s] * float(ms.res) * 0.5
    half = float(ms.res) * 0.5 - 0.5
    pen = ms.spread[s] / wp.max(ms.near[s], 1.0e-3)
    iz = 1.0 / z
    ext = r * (z + wp.max(wp.abs(a), wp.abs(b))) * iz / (z - r) * k + 1.0 + pen * k
    xc = a * iz * k + half
    yc = b * iz * k + half
    x0 = wp.max(int(wp.floor(xc - ext)), 0)
    x1 = wp.min(int(wp.floor(xc + ext)), ms.res - 1)
    y0 = wp.max(int(wp.floor(yc - ext)), 0)
    y1 = wp.min(int(wp.floor(yc + ext)), ms.res - 1)
    if x0 > x1 or y0 > y1:
        return False
    # some block of the texels' box was drawn in: from the summed-area table, one box sum (sat 0: block by block)
    if ms.sat == 0:
        for cy in range(y0 / COARSE, y1 / COARSE + 1):
            for cx in range(x0 / COARSE, x1 / COARSE + 1):
                if ms.coarse[s, cy, cx] != 0:
                    return True
        return False
    cx0 = x0 / COARSE
    cx1 = x1 / COARSE + 1
    cy0 = y0 / COARSE
    cy1 = y1 / COARSE + 1
    sat = ms.coarse_sat
    return sat[s, cy1, cx1] - sat[s, cy0, cx1] - sat[s, cy1, cx0] + sat[s, cy0, cx0] > 0


@wp.func
def _edge(a: wp.vec3, b: wp.vec3, x: float, y: float) -> float:
    return (b[0] - a[0]) * (y - a[1]) - (b[1] - a[1]) * (x - a[0])


@wp.func
def _row_cross(p: wp.vec3, q: wp.vec3, y: float, lo: float, hi: float):
    """(lo, hi) widened to hold where the edge p-q meets the row y, if it does (a horizontal edge on
    the row: both ends)."""
    if y < wp.min(p[1], q[1]) or y > wp.max(p[1], q[1]):
        return lo, hi
    dy = q[1] - p[1]
    if dy != 0.0:
        x = p[0] + (y - p[1]) / dy * (q[0] - p[0])
        x = wp.clamp(x, wp.min(p[0], q[0]), wp.max(p[0], q[0]))
        return wp.min(lo, x), wp.max(hi, x)
    return wp.min(lo, wp.min(p[0], q[0])), wp.max(hi, wp.max(p[0], q[0]))


@wp.kernel
def _raster_kernel(ms: MapSet, first: int, verts: wp.array(dtype=wp.vec3), tris: wp.array(dtype=wp.int32)):
    k, t = wp.tid()
    s = first + k
    if ms.ray[s] == 1:
        return
    v0 = verts[tris[3 * t]]
    v1 = verts[tris[3 * t + 1]]
    v2 = verts[tris[3 * t + 2]]
    if ms.cull == 1:
        if wp.dot(wp.cross(v1 - v0, v2 - v0), v0 - ms.origin[s]) > 0.0:
            return
    a = _to_map(ms, s, v0)
    b = _to_map(ms, s, v1)
    c = _to_map(ms, s, v2)
    if a[2] <= 1.0e-6 or b[2] <= 1.0e-6 or c[2] <= 1.0e-6:
        return
    area = _edge(a, b, c[0], c[1])
    if wp.abs(area) < 1.0e-12:
        return
    x0 = wp.max(int(wp.ceil(wp.min(wp.min(a[0], b[0]), c[0]))), 0)
    x1 = wp.min(int(wp.floor(wp.max(wp.max(a[0], b[0]), c[0]))), ms.res - 1)
    y0 = wp.max(int(wp.ceil(wp.min(wp.min(a[1], b[1]), c[1]))), 0)
    y1 = wp.min(int(wp.floor(wp.max(wp.max(a[1], b[1]), c[1]))), ms.res - 1)
    if x0 > x1 or y0 > y1:
        return
    ia = 1.0 / area
    za = 1.0 / a[2]
    zb = 1.0 / b[2]
    zc = 1.0 / c[2]
    for iy in range(y0, y1 + 1):
        py = float(iy)
        # the texels of the row whose centres lie in the triangle: between the edges' crossings of the
        # row, those within RASTER_EPS texels of an edge included (the triangles of a mesh leave no gap)
        lo = float(ms.res)
        hi = -1.0
        lo, hi = _row_cross(a, b, py, lo, hi)
        lo, hi = _row_cross(b, c, py, lo, hi)
        lo, hi = _row_cross(c, a, py, lo, hi)
        xs = wp.max(int(wp.ceil(lo - RASTER_EPS)), x0)
        xe = wp.min(int(wp.floor(hi + RASTER_EPS)), x1)
        if xs <= xe:  # the blocks this row of the triangle draws in
            for cx in range(xs / COARSE, xe / COARSE + 1):
                ms.coarse[s, iy / COARSE, cx] = 1
        # 1/z along the row: linear in x (perspective-correct), from the barycentrics
        # w0 = _edge(b, c, x, py) / area = (e0 - k0 x) / area, w1 likewise, w2 = 1 - w0 - w1
        k0 = c[1] - b[1]
        e0 = (c[0] - b[0]) * (py - b[1]) + k0 * b[0]
        k1 = a[1] - c[1]
        e1 = (a[0] - c[0]) * (py - c[1]) + k1 * c[0]
        iz0 = zc + (e0 * (za - zc) + e1 * (zb - zc)) * ia
        diz = -(k0 * (za - zc) + k1 * (zb - zc)) * ia
        ix = xs
        while ix <= xe:
            wp.atomic_min(ms.depth, s, iy, ix, 1.0 / (iz0 + diz * float(ix)))
            ix += 1


@dataclass
class ShadowMaps:
    """Host side of a batch of shadow maps; buffers are allocated once and reused per frame."""

    capacity: int
    res: int = 256
    bias: float = 2e-3
    device: str | None = None
    taps: int = 5  # MapSet.taps: the PCSS taps per axis of these maps' lookups (kernels.masked_sums.PCSS_TAPS)

    def __post_init__(self) -> None:
        self.device = d = runtime.device(self.device)
        cap = self.capacity
        self._frame = {k: Buffer(cap, wp.vec3, d) for k in ("origin", "right", "up", "fwd", "axis1", "axis2")}
        self._frame.update(inv_tan=Buffer(cap, wp.float32, d), near=Buffer(cap, wp.float32, d),
                           cone_tan=Buffer(cap, wp.float32, d), cone_sec=Buffer(cap, wp.float32, d),
                           ray=Buffer(cap, wp.int32, d), spread=Buffer(cap, wp.float32, d))
        self.ms = MapSet()
        for k, b in self._frame.items():
            setattr(self.ms, k, b.dev)
        self.ms.depth = wp.full((cap, self.res, self.res), float("inf"), dtype=wp.float32, device=d)
        n_coarse = -(-self.res // COARSE)
        self.ms.coarse = wp.zeros((cap, n_coarse, n_coarse), dtype=wp.int32, device=d)
        self.ms.coarse_sat = wp.zeros((cap, n_coarse + 1, n_coarse + 1), dtype=wp.int32, device=d)
        self.ms.sat = 1
        side, off = [self.res], [0, 0]
        while side[-1] > 1:
            side.append(-(-side[-1] // 2))
            off.append(off[-1] + side[-1] ** 2)
        self._mip_side = side
        self.ms.mip_levels = len(side) - 1
        self.ms.mip_side = wp.array(np.array(side, np.int32), dtype=wp.int32, device=d)
        self.ms.mip_off = wp.array(np.array(off[:len(side)], np.int32), dtype=wp.int32, device=d)
        self.ms.mip_min = wp.zeros((cap, max(off[-1], 1)), dtype=wp.float32, device=d)
        self.ms.mip_max = wp.zeros_like(self.ms.mip_min)
        self.ms.res = self.res
        self.ms.bias = self.bias
        self.ms.proxy = wp.uint64(0)
        self.ms.box_lo = wp.vec3(0.0, 0.0, 0.0)
        self.ms.box_hi = wp.vec3(0.0, 0.0, 0.0)
        self.ms.cull = 0
        self.ms.taps = int(self.taps)
        self.n = 0  # maps in the current batch
        self.n_ray = 0  # of them in ray mode (the masked sums launch their kernel only if any)
        self._soft = False  # the batch has cluster maps (a spread): raster builds their pyramids
        self.merge_mips = True  # build_mips: two launches (_mip12_kernel, _mip_rest_kernel; False: level by level, A/B)
        self._proxy: Occluder | None = None
        self._closed: tuple[bytes, bool] | None = None  # (mesh key, closed) of the last proxy

    def set_proxy(self, vertices: np.ndarray, triangles: np.ndarray, occluder: Occluder | None = None) -> None:
        """The occluder (object proxy, world coordinates) that every map of the next batches shows.
        occluder: its BVH over these vertices and triangles, if the caller keeps one (the engine's
        per-shape proxy, refit when dragged): then nothing is built or uploaded here."""
        vertices = np.asarray(vertices, np.float64)
        triangles = np.asarray(triangles, np.int32)
        self._proxy = occluder if occluder is not None else Occluder(vertices, triangles, self.device)
        self.ms.proxy = wp.uint64(self._proxy.id)
        mesh = self._proxy.mesh
        self._verts, self._tris = (mesh.points, mesh.indices) if mesh is not None else (None, None)
        self._n_tris = len(triangles) if mesh is not None else 0
        centred = np.round(vertices - vertices.mean(0), 6) if len(vertices) else vertices
        key = triangles.tobytes() + centred.tobytes()  # closedness depends on the shape, not the pose
        if self._closed is None or self._closed[0] != key:
            self._closed = (key, _is_closed(vertices, triangles) if self._n_tris else False)
        self.ms.cull = int(self._closed[1])
        lo, hi = (vertices.min(0), vertices.max(0)) if len(vertices) else (np.zeros(3), np.zeros(3))
        self.ms.box_lo = wp.vec3(*(lo - BOX_MARGIN))
        self.ms.box_hi = wp.vec3(*(hi + BOX_MARGIN))
        self._centre = 0.5 * (vertices.min(0) + vertices.max(0)) if len(vertices) else np.zeros(3)
        self._radius = float(np.linalg.norm(vertices - self._centre, axis=1).max()) if len(vertices) else 0.0

    def prepare(self, eyes: np.ndarray, spread: np.ndarray | None = None, axes: np.ndarray | None = None) -> int:
        """Aim maps 0..n-1 from eye points (n<=capacity, 3) at the proxy; returns n. The maps are
        drawn by raster (over index ranges, app.runtime.split) or render. spread (n,) m: the
        half-width of the cluster of sources each map stands for (default 0: point sources, a
        hard lookup); the masked sums filter a map's lookup by it (kernels.masked_sums.penumbra);
        axes (n,2,3) m: the cluster's half-axes across the view, of lengths <= spread (default
        spread along the map's right and up: a square)."""
        n = len(eyes)
        if n > self.capacity:
            raise ValueError(f"{n} maps exceed the batch capacity {self.capacity}")
        c, r = self._centre, self._radius * 1.02 + 1e-3
        fwd = c - eyes
        dist = np.linalg.norm(fwd, axis=1)
        use_ray = dist < r * 1.05
        fwd = fwd / np.maximum(dist, 1e-12)[:, None]
        helper = np.where(np.abs(fwd[:, 1:2]) < 0.9, [[0.0, 1.0, 0.0]], [[1.0, 0.0, 0.0]])
        right = cross3(helper, fwd)
        right /= np.linalg.norm(right, axis=1, keepdims=True)
        up = cross3(fwd, right)
        sin_h = np.clip(r / np.maximum(dist, 1e-12), 0.0, 0.999)
        inv_tan = np.sqrt(1 - sin_h ** 2) / np.maximum(sin_h, 1e-6)
        sp = np.zeros(n) if spread is None else np.asarray(spread, np.float64)[:n]
        ax = (np.stack([sp[:, None] * right, sp[:, None] * up], 1) if axes is None
              else np.asarray(axes, np.float64)[:n])
        # may_occlude's cone: the field of view widened by a texel each side (the nearest-texel lookup) and
        # by the penumbra's reach spread / near; float32-safe (a hair wider)
        tan_c = (1.0 + 2.0 / self.res) / inv_tan + 1e-5 + sp / np.maximum(dist - r, 1e-3)
        tan_c = np.where(use_ray, 0.0, tan_c * (1 + 1e-6))
        sec_c = np.sqrt(1.0 + tan_c ** 2)
        for k, v in (("origin", eyes), ("right", right), ("up", up), ("fwd", fwd), ("inv_tan", inv_tan),
                     ("near", dist - r), ("ray", use_ray),
                     ("spread", sp), ("axis1", ax[:, 0]), ("axis2", ax[:, 1]), ("cone_tan", tan_c),
                     ("cone_sec", sec_c)):
            self._frame[k].upload(v)
        self.ms.depth.fill_(float("inf"))  # one fill of the whole batch (a kernel per texel costs far more)
        self.ms.coarse.zero_()
        self.ms.coarse_sat.zero_()
        self.n = n
        self.n_ray = int(use_ray.sum())
        self._soft = bool(np.any(sp > 0))
        return n

    def raster(self, lo: int, hi: int) -> None:
        """Draw maps lo..hi-1 of the prepared batch (one launch; disjoint ranges may run
        concurrently), and their depth range pyramids where the batch has a spread."""
        if self._n_tris and hi > lo:
            wp.launch(_raster_kernel, dim=(hi - lo, self._n_tris), inputs=[self.ms, lo, self._verts, self._tris],
                      device=self.device)
            wp.launch(_coarse_sat_kernel, dim=hi - lo, inputs=[self.ms, lo], device=self.device)
        if self._soft and hi > lo:  # the penumbra's lookups read the depth range pyramid
            self.build_mips(lo, hi)

    def build_mips(self, lo: int, hi: int) -> None:
        """The depth range pyramid (depth_range) of drawn maps lo..hi-1 that read one (a spread, not ray mode:
        _reads_pyramid), in two launches (merge_mips: levels 1 and 2 a thread per level-2 block, the coarser ones
        a thread per map) or one per level (merge_mips False, for A/B); disjoint ranges may run concurrently."""
        if self.merge_mips and self.ms.mip_levels >= 2:  # levels 1 and 2 in one launch, the rest in another
            side = self._mip_side[2]
            wp.launch(_mip12_kernel, dim=(hi - lo, side, side), inputs=[self.ms, lo], device=self.device)
            if self.ms.mip_levels >= 3:
                wp.launch(_mip_rest_kernel, dim=hi - lo, inputs=[self.ms, lo, 3], device=self.device)
            return
        for lv in range(1, self.ms.mip_levels + 1):
            side = self._mip_side[lv]
            wp.launch(_mip_kernel, dim=(hi - lo, side, side), inputs=[self.ms, lo, lv], device=self.device)

    def render(self, eyes: np.ndarray) -> int:
        """Render maps from eye points (n<=capacity, 3) towards the proxy, in one launch; returns n."""
        n = self.prepare(eyes)
        self.raster(0, n)
        return n

    def depth_numpy(self) -> np.ndarray:
        return self.ms.depth.numpy()


def _is_closed(vertices: np.ndarray, triangles: np.ndarray) -> bool:
    """True when the welded mesh is closed and consistently wound: every directed edge a->b is
    matched by as many b->a (flat-shaded and UV meshes duplicate vertices along seams, so
    coincident vertices are welded first; closed parts may touch along an edge). Then every
    ray into the solid crosses a front face and back faces can be culled."""
    _, weld = np.unique(np.round(np.asarray(vertices) / 1e-6).astype(np.int64), axis=0, return_inverse=True)
    t = weld.reshape(-1)[np.asarray(triangles, np.int64)]
    e = np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])
    e = e[e[:, 0] != e[:, 1]]
    if len(e) == 0:
        return False
    fwd, cf = np.unique(e, axis=0, return_counts=True)
    rev, cr = np.unique(e[:, ::-1], axis=0, return_counts=True)
    return fwd.shape == rev.shape and bool(np.all(fwd == rev)) and bool(np.all(cf == cr))
