"""Values at image pixels from their known neighbours on the same surface (the shadow pass's fill).

A missing pixel takes the mean of the known pixels in its 3x3 window whose surface id (the scene
quad the pixel sees) equals its own; none known: 0. Pixels are flat indices y * W + x.
A missing pixel given a lattice spacing s > 2 (`spacing`, per pixel) instead takes the bilinear
interpolation of the corners of its s x s lattice square (x0 = s floor(x / s), x0 + s, and the
same in y), over the corners that are known and on its surface, their weights renormalised;
none such: the 3x3 mean above.

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
                   values: wp.array(dtype=wp.vec3d), spacing: wp.array(dtype=wp.int32), by_pixel: int,
                   out: wp.array(dtype=wp.vec3d)):
    """out[i] (by_pixel: out[missing[i]], an image-sized array) = the fill's value at missing[i]."""
    i = lo + wp.tid()
    q = missing[i]
    at = i
    if by_pixel != 0:
        at = q
    y = q / width
    x = q - y * width
    own = surface[q]
    s = spacing[q]
    if s > 2:  # bilinear over the known corners of the pixel's s x s lattice square on its surface
        x0 = (x / s) * s
        y0 = (y / s) * s
        fx = wp.float64(x - x0) / wp.float64(s)
        fy = wp.float64(y - y0) / wp.float64(s)
        bl = wp.vec3d(0.0, 0.0, 0.0)
        wsum = wp.float64(0.0)
        for cy in range(2):
            for cx in range(2):
                w = wp.float64(1.0)
                if cx == 0:
                    w = w * (wp.float64(1.0) - fx)
                else:
                    w = w * fx
                if cy == 0:
                    w = w * (wp.float64(1.0) - fy)
                else:
                    w = w * fy
                sx = x0 + cx * s
                sy = y0 + cy * s
                if w > wp.float64(0.0) and sx < width and sy < height:
                    o = sy * width + sx
                    k = slot[o]
                    if k >= 0 and surface[o] == own:
                        bl += values[k] * w
                        wsum += w
        if wsum > wp.float64(0.0):
            out[at] = bl / wsum
            return
    acc = wp.vec3d(0.0, 0.0, 0.0)
    n = int(0)
    for dy in range(-1, 2):
        for dx in range(-1, 2):
            sy = y + dy
            sx = x + dx
            if sy >= 0 and sy < height and sx >= 0 and sx < width:
                o = sy * width + sx
                k = slot[o]
                if k >= 0 and surface[o] == own:
                    acc += values[k]
                    n += 1
    if n > 0:
        acc = acc / wp.float64(n)
    out[at] = acc


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
        self.spacing = Buffer(n, wp.int32, d, fill=2)  # per pixel: > 2 bilinear on that lattice (set_spacing)
        self._spaced = np.zeros(0, np.int64)  # pixels whose spacing is not 2

    def set_spacing(self, pixels: np.ndarray, spacing: np.ndarray | int) -> None:
        """Lattice spacing (px) of the fill at `pixels` from now on; every other pixel's is 2 (the 3x3 mean)."""
        h = self.spacing.host
        h[self._spaced] = 2
        pixels = np.asarray(pixels, np.int64).reshape(-1)
        h[pixels] = spacing
        self._spaced = pixels[h[pixels] != 2]
        self.spacing.push()

    def fill(self, known: np.ndarray, values: np.ndarray, missing: np.ndarray, split=None,
             out: wp.array | None = None) -> np.ndarray | None:
        """(len(missing),3) float64 at pixels `missing` from `values` (len(known),3) at pixels
        `known` (distinct); a view of a reused buffer, valid until the next call. With `out`, an
        image-sized wp.array of vec3d on the device, the values are written there at their pixels
        instead (no copy, no scatter) and None is returned.
        split: optional callable(launch(lo, hi), n) that runs the gather over index ranges
        (app.runtime.split); default one launch."""
        m = len(missing)
        if m == 0:
            return None if out is not None else self.out.host[:0]
        nk = self.known.upload(np.asarray(known).reshape(-1))
        self.values.upload(np.asarray(values).reshape(-1, 3))
        self.missing.upload(np.asarray(missing).reshape(-1))
        d = self.device
        if nk:
            wp.launch(_mark_kernel, dim=nk, inputs=[self.known.dev, self.slot.dev, 0], device=d)

        def gather(lo: int, hi: int) -> None:
            wp.launch(_gather_kernel, dim=hi - lo,
                      inputs=[lo, self.width, self.height, self.missing.dev, self.slot.dev, self.surface.dev,
                              self.values.dev, self.spacing.dev, int(out is not None)],
                      outputs=[self.out.dev if out is None else out], device=d)

        runtime.launch_split(gather, m, split)
        if nk:
            wp.launch(_mark_kernel, dim=nk, inputs=[self.known.dev, self.slot.dev, -1], device=d)
        wp.synchronize_device(d)
        return None if out is not None else self.out.pull(m)
