"""Values at image pixels from their known neighbours on the same surface (the shadow pass's fill).

A missing pixel takes the mean of the known pixels in its 3x3 window whose surface id (the scene
quad the pixel sees) equals its own; none known: 0. Pixels are flat indices y * W + x.

Three launches per call, over the listed pixels only: the known pixels write their slot into
an image-sized index map, the missing ones gather, the known ones clear their slot again (the
map is -1 everywhere between calls). Buffers are allocated once at the image size.
"""
from __future__ import annotations

import numpy as np
import warp as wp

from kernels import runtime
from kernels.buffers import Buffer


@wp.kernel
def _mark_kernel(known: wp.array(dtype=wp.int32), slot: wp.array(dtype=wp.int32), value: int):
    i = wp.tid()
    if value < 0:
        slot[known[i]] = -1
    else:
        slot[known[i]] = i


@wp.kernel
def _gather_kernel(lo: int, width: int, height: int, missing: wp.array(dtype=wp.int32),
                   slot: wp.array(dtype=wp.int32), surface: wp.array(dtype=wp.int32),
                   values: wp.array(dtype=wp.vec3d), out: wp.array(dtype=wp.vec3d)):
    i = lo + wp.tid()
    q = missing[i]
    y = q / width
    x = q - y * width
    acc = wp.vec3d(0.0, 0.0, 0.0)
    n = int(0)
    for dy in range(-1, 2):
        for dx in range(-1, 2):
            sy = y + dy
            sx = x + dx
            if sy >= 0 and sy < height and sx >= 0 and sx < width:
                o = sy * width + sx
                k = slot[o]
                if k >= 0 and surface[o] == surface[q]:
                    acc += values[k]
                    n += 1
    if n > 0:
        acc = acc / wp.float64(n)
    out[i] = acc


class WindowFill:
    """The fill for one image: width x height pixels, `surface` (H*W,) int32 id per pixel."""

    def __init__(self, width: int, height: int, surface: np.ndarray, device: str | None = None):
        self.device = d = runtime.device(device)
        self.width, self.height = int(width), int(height)
        n = self.width * self.height
        self.surface = Buffer(n, wp.int32, d)
        self.surface.upload(np.asarray(surface, np.int32).reshape(-1))
        self.slot = Buffer(n, wp.int32, d, fill=-1)
        self.known = Buffer(n, wp.int32, d)
        self.missing = Buffer(n, wp.int32, d)
        self.values = Buffer(n, wp.vec3d, d)
        self.out = Buffer(n, wp.vec3d, d)

    def fill(self, known: np.ndarray, values: np.ndarray, missing: np.ndarray, split=None) -> np.ndarray:
        """(len(missing),3) float64 at pixels `missing` from `values` (len(known),3) at pixels
        `known` (distinct); a view of a reused buffer, valid until the next call.
        split: optional callable(launch(lo, hi), n) that runs the gather over index ranges
        (app.runtime.split); default one launch."""
        m = len(missing)
        if m == 0:
            return self.out.host[:0]
        nk = self.known.upload(np.asarray(known).reshape(-1))
        self.values.upload(np.asarray(values).reshape(-1, 3))
        self.missing.upload(np.asarray(missing).reshape(-1))
        d = self.device
        if nk:
            wp.launch(_mark_kernel, dim=nk, inputs=[self.known.dev, self.slot.dev, 0], device=d)

        def gather(lo: int, hi: int) -> None:
            wp.launch(_gather_kernel, dim=hi - lo,
                      inputs=[lo, self.width, self.height, self.missing.dev, self.slot.dev, self.surface.dev,
                              self.values.dev], outputs=[self.out.dev], device=d)

        if split is None:
            gather(0, m)
        else:
            split(gather, m)
        if nk:
            wp.launch(_mark_kernel, dim=nk, inputs=[self.known.dev, self.slot.dev, -1], device=d)
        wp.synchronize_device(d)
        return self.out.pull(m)
