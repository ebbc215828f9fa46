"""The drag frame's full-resolution compose: the coarse room's ratio to the photo brought back
bilinearly, applied to the photo, the object mixed over it (app.dragframe).

Two launches: the coarse pixels' ratios room_c / L_b_c (float32, 1 where L_b_c is 0), one thread per
coarse pixel; then the full-resolution pixels, each thread a run of PIXELS_PER_THREAD consecutive ones
(0.54-0.68x the CPU time of a thread per pixel that formed its four neighbours' ratios itself, on three
rooms: docs/benchmarks.md), float64 after the ratio, the camera response as kernels.pixel_compose evaluates it:

  ratio  = bilinear over the coarse pixels' ratios, pixel centres as cv2.resize's INTER_LINEAR
           (coarse x = (x + 0.5) / s - 0.5, clamped at the edges; float32, as cv2.resize)
  room   = max(L_b x (ratio - u), 0) where the pixel is a receiver and the ratio moves it by more than
           RATIO_EPS or the sun's share u (the share of its light the object takes from the sun, computed
           at full resolution: the sun's shadow is hard-edged) is not 0; else L_b with the photo's own levels
  pixel  = (1 - c) T(room) + c T(L_obj), or T((1 - c) room + c L_obj) where either side clips
"""
from __future__ import annotations

import numpy as np
import warp as wp

from kernels.pixel_compose import PX_LB, PX_STILL, _Mirror, mix_levels, mix_radiance, to_levels, to_pixel

PIXELS_PER_THREAD = wp.constant(16)  # consecutive full pixels per thread of drag_compose_kernel
RATIO_EPS = 1e-6  # a ratio this close to 1 leaves the photo's level (float32 noise of the coarse room)


@wp.kernel
def coarse_ratio_kernel(room_c: wp.array2d(dtype=wp.float32), inv_c: wp.array2d(dtype=wp.float32),
                        ratio: wp.array(dtype=wp.vec3f)):
    """ratio[j] = room_c[j] / L_b_c[j] per channel (inv_c = 1 / L_b_c; 1 where inv_c is 0): once per coarse
    pixel, so that a full pixel reads its four neighbours' ratios only."""
    j = wp.tid()
    r = wp.vec3f(1.0, 1.0, 1.0)
    for c in range(3):
        inv = inv_c[j, c]
        if inv > wp.float32(0.0):
            r[c] = room_c[j, c] * inv
    ratio[j] = r


@wp.func
def _compose_pixel(i: int, rf: wp.vec3f, rec: bool, sun: wp.array2d(dtype=wp.float32),
                   px: wp.array2d(dtype=wp.float64), cov: wp.array(dtype=wp.float32),
                   obj: wp.array2d(dtype=wp.float32), tab: wp.array2d(dtype=wp.float64),
                   grid: wp.array2d(dtype=wp.int32), rtab: wp.array2d(dtype=wp.int16), exposure: wp.float64,
                   out: wp.array2d(dtype=wp.float32), out_room: wp.array2d(dtype=wp.float32),
                   out_pix: wp.array2d(dtype=wp.uint8)):
    """Full pixel i of drag_compose_kernel, given its bilinear ratio rf (read where rec: the pixel is a receiver)."""
    zero = wp.float64(0.0)
    one = wp.float64(1.0)
    full = wp.float64(255.0)
    moved = False
    ratio = wp.vec3d(one, one, one)
    if rec:
        for c in range(3):
            r = wp.float64(rf[c])
            ratio[c] = r
            if wp.abs(r - one) > wp.float64(RATIO_EPS):
                moved = True
            u = wp.float64(sun[i, c])
            if u != zero:
                ratio[c] = r - u
                sun[i, c] = wp.float32(0.0)  # left cleared for the next frame
                moved = True
    cv = wp.float64(cov[i])
    rad = wp.vec3d()
    lev = wp.vec3d()
    q = wp.vec3i()
    rounded = False
    if moved:
        rounded = cv == zero
        for c in range(3):
            rad[c] = wp.max(px[i, PX_LB + c] * ratio[c], zero)
            if rounded:
                q[c] = to_pixel(rad[c], c, exposure, rtab, tab, grid)
            else:
                lev[c] = to_levels(rad[c], c, exposure, tab, grid)
    else:
        for c in range(3):
            rad[c] = px[i, PX_LB + c]
            lev[c] = px[i, PX_STILL + c]
    pr = wp.vec3d(rad[0], rad[1], rad[2])
    pl = wp.vec3d(lev[0], lev[1], lev[2])
    if cv > zero:  # the object over it, as compose_kernel mixes it
        o = wp.vec3d(wp.float64(obj[i, 0]), wp.float64(obj[i, 1]), wp.float64(obj[i, 2]))
        pr = mix_radiance(rad, cv, o)
        pl = mix_levels(rad, lev, cv, o, exposure, tab, grid)
    for c in range(3):
        out[i, c] = wp.float32(pr[c])
        out_room[i, c] = wp.float32(rad[c])
        if rounded:
            out_pix[i, c] = wp.uint8(q[c])
        else:
            out_pix[i, c] = wp.uint8(int(wp.clamp(wp.rint(pl[c]), zero, full)))


@wp.func
def _row_of(y: int, s: int):
    """(ay, y0) of full row y: its bilinear weight and upper coarse row, unclamped (module doc; float32)."""
    fy = (wp.float32(y) + wp.float32(0.5)) / wp.float32(s) - wp.float32(0.5)
    y0 = int(wp.floor(fy))
    return fy - wp.float32(y0), y0


@wp.kernel
def drag_compose_kernel(first: int, n: int, W: int, w: int, h: int, s: int, ratio_c: wp.array(dtype=wp.vec3f),
                        recv: wp.array(dtype=wp.uint8), sun: wp.array2d(dtype=wp.float32),
                        px: wp.array2d(dtype=wp.float64), cov: wp.array(dtype=wp.float32),
                        obj: wp.array2d(dtype=wp.float32), tab: wp.array2d(dtype=wp.float64),
                        grid: wp.array2d(dtype=wp.int32), rtab: wp.array2d(dtype=wp.int16), exposure: wp.float64,
                        out: wp.array2d(dtype=wp.float32), out_room: wp.array2d(dtype=wp.float32),
                        out_pix: wp.array2d(dtype=wp.uint8)):
    """Full pixels first + PIXELS_PER_THREAD tid .. (at most first + n - 1), one after the other. ratio_c
    (h*w,) the coarse pixels' ratios (coarse_ratio_kernel); recv (N,) 1 where the full pixel is a receiver;
    sun (N,3) the sun's share u (cleared as read); px the HDR per-scene table (pixel_compose.PX_*); cov (N,)
    and obj (N,3) the object's coverage and radiance at full resolution; out, out_room, out_pix as
    pixel_compose.compose_kernel's. The run's row terms are computed once per row, and its four coarse ratios
    read again only where the left coarse column changes (the same float32 arithmetic per pixel as one
    thread per pixel: the same bytes)."""
    i0 = first + wp.tid() * PIXELS_PER_THREAD
    i1 = wp.min(i0 + PIXELS_PER_THREAD, first + n)
    sf = wp.float32(s)
    y = i0 // W
    row_end = (y + 1) * W
    ay, y0 = _row_of(y, s)
    last_x0 = int(-2)  # the left coarse column whose four ratios ta, tb, ba, bb hold (none yet)
    ta = wp.vec3f()
    tb = wp.vec3f()
    ba = wp.vec3f()
    bb = wp.vec3f()
    for i in range(i0, i1):
        if i == row_end:  # the run goes on in the next row
            y = y + 1
            row_end = row_end + W
            ay, y0 = _row_of(y, s)
            last_x0 = -2
        rf = wp.vec3f(1.0, 1.0, 1.0)
        rec = recv[i] != wp.uint8(0)
        if rec:
            x = i - y * W
            fx = (wp.float32(x) + wp.float32(0.5)) / sf - wp.float32(0.5)
            x0 = int(wp.floor(fx))
            ax = fx - wp.float32(x0)
            if x0 != last_x0:
                xa = wp.clamp(x0, 0, w - 1)
                xb = wp.clamp(x0 + 1, 0, w - 1)
                ya = wp.clamp(y0, 0, h - 1)
                yb = wp.clamp(y0 + 1, 0, h - 1)
                ta = ratio_c[ya * w + xa]
                tb = ratio_c[ya * w + xb]
                ba = ratio_c[yb * w + xa]
                bb = ratio_c[yb * w + xb]
                last_x0 = x0
            top = (wp.float32(1.0) - ax) * ta + ax * tb
            bot = (wp.float32(1.0) - ax) * ba + ax * bb
            rf = (wp.float32(1.0) - ay) * top + ay * bot
        _compose_pixel(i, rf, rec, sun, px, cov, obj, tab, grid, rtab, exposure, out, out_room, out_pix)


@wp.kernel
def drag_compose_pixelwise_kernel(first: int, n: int, W: int, w: int, h: int, s: int,
                                  ratio_c: wp.array(dtype=wp.vec3f), recv: wp.array(dtype=wp.uint8),
                                  sun: wp.array2d(dtype=wp.float32), px: wp.array2d(dtype=wp.float64),
                                  cov: wp.array(dtype=wp.float32), obj: wp.array2d(dtype=wp.float32),
                                  tab: wp.array2d(dtype=wp.float64), grid: wp.array2d(dtype=wp.int32),
                                  rtab: wp.array2d(dtype=wp.int16), exposure: wp.float64,
                                  out: wp.array2d(dtype=wp.float32), out_room: wp.array2d(dtype=wp.float32),
                                  out_pix: wp.array2d(dtype=wp.uint8)):
    """drag_compose_kernel with each pixel's row, columns and four coarse ratios found on their own (as before
    drag36): its reference (tests, DragCompose.rowwise False for A/B)."""
    i0 = first + wp.tid() * PIXELS_PER_THREAD
    i1 = wp.min(i0 + PIXELS_PER_THREAD, first + n)
    for i in range(i0, i1):
        rf = wp.vec3f(1.0, 1.0, 1.0)
        rec = recv[i] != wp.uint8(0)
        if rec:
            y = i // W
            x = i - y * W
            sf = wp.float32(s)
            fx = (wp.float32(x) + wp.float32(0.5)) / sf - wp.float32(0.5)
            fy = (wp.float32(y) + wp.float32(0.5)) / sf - wp.float32(0.5)
            x0 = int(wp.floor(fx))
            y0 = int(wp.floor(fy))
            ax = fx - wp.float32(x0)
            ay = fy - wp.float32(y0)
            xa = wp.clamp(x0, 0, w - 1)
            xb = wp.clamp(x0 + 1, 0, w - 1)
            ya = wp.clamp(y0, 0, h - 1)
            yb = wp.clamp(y0 + 1, 0, h - 1)
            top = (wp.float32(1.0) - ax) * ratio_c[ya * w + xa] + ax * ratio_c[ya * w + xb]
            bot = (wp.float32(1.0) - ax) * ratio_c[yb * w + xa] + ax * ratio_c[yb * w + xb]
            rf = (wp.float32(1.0) - ay) * top + ay * bot
        _compose_pixel(i, rf, rec, sun, px, cov, obj, tab, grid, rtab, exposure, out, out_room, out_pix)


class DragCompose:
    """The drag frame's compose at full resolution for one scale: the per-scene inputs uploaded once
    (the coarse photo's inverse radiance, the receiver flags; the response tables and the HDR pixel
    table are the full compositor's, kernels.pixel_compose.Compositor), the per-frame inputs in buffers
    made once, the outputs from the compositor's pool (Compositor._outputs: a frame that is still held
    keeps its arrays); per frame one launch per core and no allocation."""

    rowwise = True  # drag_compose_kernel; False: drag_compose_pixelwise_kernel, the same bytes (A/B: bench/)

    def __init__(self, compositor, shape: tuple[int, int], coarse: tuple[int, int], scale: int,
                 inv_Lb_c: np.ndarray, recv: np.ndarray, device: str):
        """compositor: the full frame's Compositor; shape (H,W), coarse (h,w); inv_Lb_c (h*w,3) float32;
        recv (H*W,) bool."""
        self.k, self.device = compositor, device
        self.H, self.W = shape
        self.h, self.w = coarse
        self.s = scale
        n, m, f32 = self.H * self.W, self.h * self.w, wp.float32
        self._inv = _Mirror.of(np.ascontiguousarray(inv_Lb_c, np.float32), f32, device)
        self._recv = _Mirror.of(recv.astype(np.uint8), wp.uint8, device)
        self._sun = _Mirror((n, 3), f32, device)  # the sun's share, cleared by the kernel as it reads it
        self._room = _Mirror((m, 3), f32, device)
        self._ratio = wp.zeros(m, dtype=wp.vec3f, device=device)  # the coarse pixels' ratios, per frame
        self._cov = _Mirror((n,), f32, device)
        self._obj = _Mirror((n, 3), f32, device)
        self._rect: tuple[int, int, int, int] | None = None  # the object's rectangle written last (run)

    def _object(self, cov: np.ndarray, obj_rad: np.ndarray, rect: tuple[int, int, int, int] | None) -> None:
        """The object's coverage and radiance into their buffers: the whole frame (rect None), or only the
        rectangle (u0, v0, u1, v1) (inclusive) outside which both are 0, the last call's rectangle zeroed
        first (a drag frame copies its object's ~1-10 % of the frame, not 1.2 M floats)."""
        H, W = self.H, self.W
        cv, ob = self._cov.np.reshape(H, W), self._obj.np.reshape(H, W, 3)
        if rect is None or self._rect is None and (cv.any() or ob.any()):
            cv[...] = cov.reshape(H, W)
            ob[...] = obj_rad.reshape(H, W, 3)
        else:
            if self._rect is not None:
                u0, v0, u1, v1 = self._rect
                cv[v0:v1 + 1, u0:u1 + 1] = 0.0
                ob[v0:v1 + 1, u0:u1 + 1] = 0.0
            u0, v0, u1, v1 = rect
            cv[v0:v1 + 1, u0:u1 + 1] = cov.reshape(H, W)[v0:v1 + 1, u0:u1 + 1]
            ob[v0:v1 + 1, u0:u1 + 1] = obj_rad.reshape(H, W, 3)[v0:v1 + 1, u0:u1 + 1]
        self._rect = None if rect is None else tuple(int(x) for x in rect)

    def run(self, room_c: np.ndarray, cov: np.ndarray, obj_rad: np.ndarray, split, sun=None,
            rect: tuple[int, int, int, int] | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(radiance (N,3) float32, room (N,3) float32, pixels (N,3) uint8) from the coarse room
        room_c (h*w,3), the object's coverage cov (N,) and radiance obj_rad (N,3) (float32); sun: None or
        (pixels (n,), the sun's share there (n,3)); rect: None, or the rectangle (u0, v0, u1, v1) (inclusive)
        outside which cov and obj_rad are 0 (only it is copied)."""
        d, n, k = self.device, self.H * self.W, self.k
        self._room.np[:] = room_c.reshape(-1, 3)
        self._object(cov, obj_rad, rect)
        for m in (self._room, self._cov, self._obj):
            m.push()
        if sun is not None:
            self._sun.np[sun[0]] = sun[1]
            self._sun.push()
            if not wp.get_device(d).is_cpu:
                self._sun.np[sun[0]] = 0.0  # CUDA: the host copy is cleared here, the device's by the kernel
        rad, room, pix = k._outputs()
        if k._out is None:  # the CPU: the kernel writes the returned arrays (wrapped, not copied)
            outs = [wp.array(a, dtype=dt, device=d, copy=False)
                    for a, dt in ((rad, wp.float32), (room, wp.float32), (pix, wp.uint8))]
        else:
            outs = [o.dev for o in k._out]

        wp.launch(coarse_ratio_kernel, dim=self.h * self.w, device=d, inputs=[self._room.dev, self._inv.dev, self._ratio])

        def launch(lo: int, hi: int) -> None:
            kernel = drag_compose_kernel if self.rowwise else drag_compose_pixelwise_kernel
            wp.launch(kernel, dim=-(-(hi - lo) // PIXELS_PER_THREAD), device=d,
                      inputs=[lo, hi - lo, self.W, self.w, self.h, self.s, self._ratio, self._recv.dev,
                              self._sun.dev, k._px["hdr"], self._cov.dev, self._obj.dev,
                              k._tab, k._grid, k._rtab, k._exposure, *outs])

        split(launch, n)
        wp.synchronize_device(d)
        if k._out is not None:
            for o, a in zip(k._out, (rad, room, pix)):
                o.pull()
                a[...] = o.np
        return rad, room, pix
