"""The object's radiance per pixel from its vertex radiance at the camera's sub-pixel hits (the drag frame's,
app.stages.object_drag): one thread per pixel of the object's screen rectangle.

  radiance(pixel) = mean over its s x s sub-samples that hit the object of
                    sum_k bary_k L_vert[face_k] + add x colour
where add (per sub-sample, scalar) is a share computed per hit (the sun's: cos x visibility) of a light of
`colour` (3,), 0 where none. Pixels with no hit are 0. The layout of the sub-samples is
app.stages.object_shading.ObjectHits': row-major over (rows, s, cols, s).

The sun's share per hit (SunAtHits, the drag frame's) is made in a launch of its own before the average, into
the buffer the average reads `add` from: the interpolated normal's cos toward the sun, the object's own shadow
read from its sun depth map (2 x 2 texels, percentage closer), the room's shadow interpolated from the vertices,
and the exit through an opening (kernels.sunshadow's _exit_t), all in float64 (the map's bias in float32, as
the numpy it replaces did).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from kernels.buffers import Workspace
from kernels.sunshadow import _disk_share, _exit_t


@dataclass
class SunAtHits:
    """The sun per camera hit of an object (world frame unless said): its mesh's vertices v (V,3), vertex
    normals n (V,3) and the room's share of the sun at each vertex room (V,), the unit direction to the sun d
    (3,), the openings it enters through (kernels.sunshadow.exit_arrays: device arrays, made once per sun), and
    the object's own sun depth map in its frame (local = (p - mean) @ R: DragShape.sun_map's axes e1, e2 (3,),
    corner lo (2,), texel and top (m), unit direction d_local (3,), depth (res, res) as a device array float32,
    inf where empty; a point is lit where its depth from the top plane is <= the texel's + 2 texels + 2 mm)."""

    v: np.ndarray
    n: np.ndarray
    room: np.ndarray
    d: np.ndarray
    exits: list
    mean: np.ndarray
    R: np.ndarray
    e1: np.ndarray
    e2: np.ndarray
    lo: np.ndarray
    texel: float
    top: float
    d_local: np.ndarray
    depth: wp.array
    tan_a: float = 0.0  # tan of the sun disk's angular radius: > 0, the share of the disk the openings pass
    # (kernels.sunshadow._disk_share) in place of the exit of the ray toward its centre


@wp.func
def _own_lit(p: wp.vec3d, e1: wp.vec3d, e2: wp.vec3d, dl: wp.vec3d, lo0: wp.float64, lo1: wp.float64,
             texel: wp.float64, top: wp.float64, bias: wp.float32, bias_mm: wp.float32,
             depth: wp.array2d(dtype=wp.float32)) -> wp.float64:
    """DragShape.sun_lit_at for one point p in the object's frame: bilinear share of the 4 nearest texels lit."""
    res = depth.shape[0]
    t = top - wp.dot(p, dl)
    fu = (wp.dot(p, e1) - lo0) / texel - wp.float64(0.5)
    fv = (wp.dot(p, e2) - lo1) / texel - wp.float64(0.5)
    i0 = int(wp.floor(fu))
    j0 = int(wp.floor(fv))
    au = fu - wp.float64(i0)
    av = fv - wp.float64(j0)
    out = wp.float64(0.0)
    for dj in range(2):  # numpy's order of the taps: (0, 0), (1, 0), (0, 1), (1, 1)
        for di in range(2):
            wu = au
            if di == 0:
                wu = wp.float64(1.0) - au
            wv = av
            if dj == 0:
                wv = wp.float64(1.0) - av
            i = wp.clamp(i0 + di, 0, res - 1)
            j = wp.clamp(j0 + dj, 0, res - 1)
            if t <= wp.float64((depth[i, j] + bias) + bias_mm):
                out += wu * wv
    return out


@wp.kernel
def _sun_at_hits_kernel(tri: wp.array(dtype=wp.int32), bary: wp.array(dtype=wp.vec3), hit: wp.array(dtype=wp.uint8),
                        faces: wp.array(dtype=wp.vec3i), v: wp.array(dtype=wp.vec3d), n: wp.array(dtype=wp.vec3d),
                        room: wp.array(dtype=wp.float64), d: wp.vec3d, ex_c0: wp.array(dtype=wp.vec3d),
                        ex_n: wp.array(dtype=wp.vec3d), ex_inv: wp.array(dtype=wp.float64),
                        ex_u: wp.array(dtype=wp.vec3d), ex_v: wp.array(dtype=wp.vec3d), mean: wp.vec3d,
                        R: wp.mat33d, e1: wp.vec3d, e2: wp.vec3d, dl: wp.vec3d, lo0: wp.float64, lo1: wp.float64,
                        texel: wp.float64, top: wp.float64, bias: wp.float32, bias_mm: wp.float32,
                        depth: wp.array2d(dtype=wp.float32), tan_a: wp.float64, add: wp.array(dtype=wp.float64)):
    k = wp.tid()
    add[k] = wp.float64(0.0)
    if hit[k] == wp.uint8(0):
        return
    f = faces[tri[k]]
    w = bary[k]
    b0 = wp.float64(w[0])
    b1 = wp.float64(w[1])
    b2 = wp.float64(w[2])
    nh = b0 * n[f[0]] + b1 * n[f[1]] + b2 * n[f[2]]
    cos = wp.max(wp.dot(nh, d), wp.float64(0.0)) / wp.max(wp.length(nh), wp.float64(1e-12))
    if cos <= wp.float64(0.0):
        return
    p = b0 * v[f[0]] + b1 * v[f[1]] + b2 * v[f[2]]
    through = wp.float64(1.0)
    if tan_a > wp.float64(0.0):
        through = _disk_share(p, d, tan_a, ex_c0, ex_n, ex_inv, ex_u, ex_v)[0]
        if through <= wp.float64(0.0):
            return
    elif _exit_t(p, d, ex_c0, ex_n, ex_inv, ex_u, ex_v) <= wp.float64(0.0):
        return
    own = _own_lit(wp.mul(wp.transpose(R), p - mean), e1, e2, dl, lo0, lo1, texel, top, bias, bias_mm, depth)
    add[k] = cos * own * (b0 * room[f[0]] + b1 * room[f[1]] + b2 * room[f[2]]) * through


def _v3(x) -> wp.vec3d:
    return wp.vec3d(*np.asarray(x, np.float64))


@wp.kernel
def _hit_average_kernel(ww: int, s: int, tri: wp.array(dtype=wp.int32), bary: wp.array(dtype=wp.vec3),
                        hit: wp.array(dtype=wp.uint8), faces: wp.array(dtype=wp.vec3i),
                        L: wp.array(dtype=wp.vec3d), add: wp.array(dtype=wp.float64), colour: wp.vec3d,
                        out: wp.array(dtype=wp.vec3d)):
    p = wp.tid()
    r = p / ww
    c = p - r * ww
    acc = wp.vec3d(wp.float64(0.0), wp.float64(0.0), wp.float64(0.0))
    count = int(0)
    for a in range(s):
        for b in range(s):
            k = ((r * s + a) * ww + c) * s + b
            if hit[k] != wp.uint8(0):
                f = faces[tri[k]]
                w = bary[k]
                acc = acc + wp.float64(w[0]) * L[f[0]] + wp.float64(w[1]) * L[f[1]] + wp.float64(w[2]) * L[f[2]] \
                    + add[k] * colour
                count += 1
    if count > 0:
        acc = acc / wp.float64(count)
    out[p] = acc


def hit_average(hits, faces: np.ndarray, L_vert: np.ndarray, add: "np.ndarray | SunAtHits | None",
                colour: np.ndarray | None, device: str, workspace: Workspace, out: "FrameImage | None" = None
                ) -> np.ndarray:
    """(H,W,3) float64: the object's radiance per pixel (module docstring) from the camera hits `hits`
    (app.stages.object_shading.ObjectHits), the shading mesh's faces (F,3) and vertex radiance L_vert (V,3),
    and per sub-sample `add` (n,) of `colour` (3,) (None: none; a SunAtHits: the sun's share per hit, made on the
    device in a launch of its own). workspace: the call site's buffers (kept).
    out: a kept FrameImage to write into (no full-frame array made or cleared per call; the result is its
    array, valid until the next call with it), or None (a new array)."""
    kept = out
    out = np.zeros((hits.H, hits.W, 3)) if kept is None else kept.clear(hits.H, hits.W)
    u0, v0, u1, v1 = hits.rect
    if u1 < u0 or not hits.hit.any():
        return out
    hh, ww = v1 - v0 + 1, u1 - u0 + 1
    n = len(hits.hit)
    ws = workspace
    cap = hits.H * hits.W * hits.s * hits.s  # the whole frame's sub-samples: a later, larger rectangle allocates nothing
    res = ws.buffer("out", hits.H * hits.W, wp.vec3d, device)
    tri = ws.upload("tri", np.maximum(hits.tri, 0).astype(np.int32), wp.int32, device, cap)
    bary = ws.upload("bary", hits.bary.astype(np.float32), wp.vec3, device, cap)
    hit = ws.upload("hit", hits.hit.astype(np.uint8), wp.uint8, device, cap)
    faces_d = ws.upload("faces", np.asarray(faces, np.int32), wp.vec3i, device)
    if add is None:  # no add: a kept buffer of zeros (made zeroed, never written), no array made or uploaded
        add_d, colour = ws.buffer("zero_add", max(n, cap), wp.float64, device).dev[:n], np.zeros(3)
    elif isinstance(add, SunAtHits):
        add_d = ws.buffer("add", max(n, cap), wp.float64, device).dev[:n]
        _sun_at_hits(add, tri, bary, hit, faces_d, add_d, ws, device)
    else:
        add_d = ws.upload("add", np.asarray(add, np.float64), wp.float64, device, cap)
    wp.launch(_hit_average_kernel, dim=hh * ww, device=device,
              inputs=[ww, hits.s, tri, bary, hit, faces_d, ws.upload("L", np.asarray(L_vert, np.float64), wp.vec3d,
                                                                     device),
                      add_d, wp.vec3d(*np.asarray(colour, np.float64))],
              outputs=[res.dev[:hh * ww]])
    out[v0:v1 + 1, u0:u1 + 1] = res.pull(hh * ww).reshape(hh, ww, 3)
    if kept is not None:
        kept.written(hits.rect)
    return out


def _sun_at_hits(sun: SunAtHits, tri: wp.array, bary: wp.array, hit: wp.array, faces: wp.array, add: wp.array,
                 ws: Workspace, device: str) -> None:
    """Write the sun's share per sub-sample (SunAtHits; 0 where no hit) into `add` (n,) on the device."""
    texel = float(sun.texel)
    wp.launch(_sun_at_hits_kernel, dim=add.shape[0], device=device,
              inputs=[tri, bary, hit, faces, ws.upload("sun_v", np.asarray(sun.v, np.float64), wp.vec3d, device),
                      ws.upload("sun_n", np.asarray(sun.n, np.float64), wp.vec3d, device),
                      ws.upload("sun_room", np.asarray(sun.room, np.float64), wp.float64, device),
                      _v3(sun.d), *sun.exits, _v3(sun.mean), wp.mat33d(*np.asarray(sun.R, np.float64).ravel()),
                      _v3(sun.e1), _v3(sun.e2), _v3(sun.d_local), float(sun.lo[0]), float(sun.lo[1]), texel,
                      float(sun.top), float(np.float32(2 * texel)), float(np.float32(2e-3)), sun.depth,
                      wp.float64(sun.tan_a)],
              outputs=[add])


class FrameImage:
    """A kept (H,W,3) float64 image of which only a rectangle is non-zero: `clear` zeroes the rectangle the
    last `written` named (not the frame) and returns the image; hit_average's `out`."""

    def __init__(self) -> None:
        self.image: np.ndarray | None = None
        self.rect: tuple[int, int, int, int] | None = None  # (u0, v0, u1, v1) inclusive, the last written

    def clear(self, H: int, W: int) -> np.ndarray:
        if self.image is None or self.image.shape[:2] != (H, W):
            self.image, self.rect = np.zeros((H, W, 3)), None
        elif self.rect is not None:
            u0, v0, u1, v1 = self.rect
            self.image[v0:v1 + 1, u0:u1 + 1] = 0.0
            self.rect = None
        return self.image

    def written(self, rect: tuple[int, int, int, int]) -> None:
        self.rect = tuple(int(x) for x in rect)
