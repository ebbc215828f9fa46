"""The object's radiance per pixel from its vertex radiance at the camera's sub-pixel hits (the drag frame's,
app.stages.object_drag): one thread per pixel of the object's screen rectangle.

  radiance(pixel) = mean over its s x s sub-samples that hit the object of
                    sum_k bary_k L_vert[face_k] + add x colour
where add (per sub-sample, scalar) is a share computed per hit (the sun's: cos x visibility) of a light of
`colour` (3,), 0 where none. Pixels with no hit are 0. The layout of the sub-samples is
app.stages.object_shading.ObjectHits': row-major over (rows, s, cols, s).
"""
from __future__ import annotations

import numpy as np
import warp as wp

from kernels.buffers import Workspace


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


def hit_average(hits, faces: np.ndarray, L_vert: np.ndarray, add: np.ndarray | None, colour: np.ndarray | None,
                device: str, workspace: Workspace, out: "FrameImage | None" = None) -> np.ndarray:
    """(H,W,3) float64: the object's radiance per pixel (module docstring) from the camera hits `hits`
    (app.stages.object_shading.ObjectHits), the shading mesh's faces (F,3) and vertex radiance L_vert (V,3),
    and per sub-sample `add` (n,) of `colour` (3,) (None: none). workspace: the call site's buffers (kept).
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
    if add is None:
        add, colour = np.zeros(n), np.zeros(3)
    res = ws.buffer("out", hits.H * hits.W, wp.vec3d, device)
    wp.launch(_hit_average_kernel, dim=hh * ww, device=device,
              inputs=[ww, hits.s, ws.upload("tri", np.maximum(hits.tri, 0).astype(np.int32), wp.int32, device, cap),
                      ws.upload("bary", hits.bary.astype(np.float32), wp.vec3, device, cap),
                      ws.upload("hit", hits.hit.astype(np.uint8), wp.uint8, device, cap),
                      ws.upload("faces", np.asarray(faces, np.int32), wp.vec3i, device),
                      ws.upload("L", np.asarray(L_vert, np.float64), wp.vec3d, device),
                      ws.upload("add", np.asarray(add, np.float64), wp.float64, device, cap),
                      wp.vec3d(*np.asarray(colour, np.float64))],
              outputs=[res.dev[:hh * ww]])
    out[v0:v1 + 1, u0:u1 + 1] = res.pull(hh * ww).reshape(hh, ww, 3)
    if kept is not None:
        kept.written(hits.rect)
    return out


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
