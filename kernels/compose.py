"""Per-pixel compositing of a frame (engine compose stage): room radiance, camera response, object mix.

One thread per pixel of the frame, float64 throughout, so that it reproduces the numpy reference
(app.stages.compose docstring) to the last bit of the levels:

  add      = rho x (R + sum_k b_k dE_v[row_k])            (object light + second order, irradiance/pi)
  HDR:  room = max(L_b - shadow + add, 0); levels = T(room) where anything changed, else T(L_b)
  LDR:  levels = photo + dlev (+ T(max(L_b + add, 0)) - T(L_b)); room = T^-1(clip(levels, 0, 255))
  pixel    = (1 - c) levels + c T(L_obj), or T((1 - c) room + c L_obj) where either clips

T is the camera response as recon.response.CameraResponse evaluates it: np.interp over the merged
breakpoints, here found through a uniform grid of start indices (`response_grid`) so that a lookup
is one load and a short scan instead of a bisection. Its result is the same segment and the same
formula as np.interp's.
"""
from __future__ import annotations

import numpy as np
import warp as wp

GRID_CELLS = 4096  # uniform cells per channel over [0, 1] in the lookup grid


def response_grid(xp: np.ndarray, cells: int = GRID_CELLS) -> np.ndarray:
    """(C, cells) int32: per channel, the last breakpoint index j with xp[c, j] <= k / cells."""
    starts = np.arange(cells) / cells
    return np.stack([np.maximum(np.searchsorted(x, starts, side="right") - 1, 0) for x in xp]).astype(np.int32)


@wp.func
def interp(x: wp.float64, c: int, xp: wp.array2d(dtype=wp.float64), fp: wp.array2d(dtype=wp.float64),
           grid: wp.array2d(dtype=wp.int32)) -> wp.float64:
    """np.interp(x, xp[c], fp[c]) for sorted xp (ties allowed): the last j with xp[j] <= x."""
    n = xp.shape[1]
    if x < xp[c, 0]:
        return fp[c, 0]
    if x >= xp[c, n - 1]:
        return fp[c, n - 1]
    ng = grid.shape[1]
    k = int(x * wp.float64(ng))
    k = wp.clamp(k, 0, ng - 1)
    j = grid[c, k]
    while xp[c, j + 1] <= x:  # x < xp[n-1]: stops before the end
        j += 1
    while xp[c, j] > x:  # the cell's start rounded above x
        j -= 1
    if xp[c, j] == x:
        return fp[c, j]
    slope = (fp[c, j + 1] - fp[c, j]) / (xp[c, j + 1] - xp[c, j])
    return slope * (x - xp[c, j]) + fp[c, j]


@wp.func
def to_levels(L: wp.float64, c: int, exposure: wp.float64, xs: wp.array2d(dtype=wp.float64),
              ys: wp.array2d(dtype=wp.float64), gx: wp.array2d(dtype=wp.int32)) -> wp.float64:
    """T(L): radiance -> continuous level in [0, 255] (CameraResponse.to_levels)."""
    x = wp.clamp(L * exposure, wp.float64(0.0), wp.float64(1.0))
    return wp.float64(255.0) * interp(x, c, xs, ys, gx)


@wp.struct
class Response:
    """The camera response's breakpoints and their lookup grids (one row per channel)."""

    xs: wp.array2d(dtype=wp.float64)  # exposure-scaled radiance, sorted
    ys: wp.array2d(dtype=wp.float64)  # response in [0, 1], sorted
    gx: wp.array2d(dtype=wp.int32)  # response_grid(xs)
    gy: wp.array2d(dtype=wp.int32)  # response_grid(ys)
    exposure: wp.float64


@wp.struct
class Room:
    """Per-scene, pose-independent pixel data (H*W rows)."""

    L_b: wp.array2d(dtype=wp.float64)  # photo radiance (model radiance where the sun clips)
    T_Lb: wp.array2d(dtype=wp.float64)  # T(L_b)
    still: wp.array2d(dtype=wp.float64)  # levels where nothing changes (HDR: Engine.L_b_levels; LDR: photo)
    still_room: wp.array2d(dtype=wp.float64)  # room radiance where nothing changes (HDR: L_b; LDR: T^-1(photo))
    rho: wp.array2d(dtype=wp.float64)  # reflectance L_b / E_x
    rows: wp.array2d(dtype=wp.int32)  # receiver-vertex rows per pixel (-1: not a receiver pixel)
    bary: wp.array2d(dtype=wp.float64)  # barycentric weights of those rows


@wp.struct
class Changes:
    """This frame's changes (H*W rows unless noted); zero where nothing changes."""

    shade: wp.array2d(dtype=wp.float64)  # HDR: radiance the shadows take; LDR: level change of the shadows
    r_pix: wp.array2d(dtype=wp.float64)  # object light per pixel where r_flag (irradiance/pi)
    r_flag: wp.array(dtype=wp.uint8)  # 1: r_pix holds the pixel's object light, the vertices give dE only
    all_r: int  # 1: every pixel's object light is in r_pix (the dense form)
    dE_v: wp.array2d(dtype=wp.float64)  # (Vr,3) second-order irradiance/pi at receiver vertices
    add_v: wp.array2d(dtype=wp.float64)  # (Vr,3) dE_v plus the object light at receiver vertices
    cov: wp.array(dtype=wp.float64)  # object coverage
    obj: wp.array2d(dtype=wp.float64)  # object radiance where cov > 0


@wp.kernel
def compose_kernel(first: int, ldr: int, room: Room, ch: Changes, resp: Response,
                   out_rad: wp.array2d(dtype=wp.float32), out_room: wp.array2d(dtype=wp.float32),
                   out_pix: wp.array2d(dtype=wp.uint8)):
    i = first + wp.tid()
    zero = wp.float64(0.0)
    one = wp.float64(1.0)
    full = wp.float64(255.0)
    use_r = ch.all_r != 0 or ch.r_flag[i] != wp.uint8(0)
    r0 = room.rows[i, 0]
    add = wp.vec3d()
    for c in range(3):
        a = zero
        if use_r:
            a = ch.r_pix[i, c]
        if r0 >= 0:
            b0 = room.bary[i, 0]
            b1 = room.bary[i, 1]
            b2 = room.bary[i, 2]
            r1 = room.rows[i, 1]
            r2 = room.rows[i, 2]
            if use_r:
                a = a + (b0 * ch.dE_v[r0, c] + b1 * ch.dE_v[r1, c] + b2 * ch.dE_v[r2, c])
            else:
                a = b0 * ch.add_v[r0, c] + b1 * ch.add_v[r1, c] + b2 * ch.add_v[r2, c]
        add[c] = room.rho[i, c] * a
    added = add[0] != zero or add[1] != zero or add[2] != zero
    changed = ch.shade[i, 0] != zero or ch.shade[i, 1] != zero or ch.shade[i, 2] != zero
    rad = wp.vec3d()
    lev = wp.vec3d()
    for c in range(3):
        if ldr == 0:
            if changed or added:
                rad[c] = wp.max(room.L_b[i, c] - ch.shade[i, c] + add[c], zero)
                lev[c] = to_levels(rad[c], c, resp.exposure, resp.xs, resp.ys, resp.gx)
            else:
                rad[c] = room.still_room[i, c]
                lev[c] = room.still[i, c]
        else:
            z = room.still[i, c] + ch.shade[i, c]
            if added:
                z = z + (to_levels(wp.max(room.L_b[i, c] + add[c], zero), c, resp.exposure, resp.xs, resp.ys,
                                   resp.gx) - room.T_Lb[i, c])
            if changed or added:
                lev[c] = wp.clamp(z, zero, full)
                y = wp.clamp(lev[c] / full, zero, one)
                rad[c] = interp(y, c, resp.ys, resp.xs, resp.gy) / resp.exposure
            else:
                lev[c] = z
                rad[c] = room.still_room[i, c]
    out = lev
    cov = ch.cov[i]
    px = rad
    if cov > zero:
        clips = lev[0] >= full or lev[1] >= full or lev[2] >= full
        ol = wp.vec3d()
        for c in range(3):
            px[c] = (one - cov) * rad[c] + cov * ch.obj[i, c]
            ol[c] = to_levels(ch.obj[i, c], c, resp.exposure, resp.xs, resp.ys, resp.gx)
            out[c] = (one - cov) * lev[c] + cov * ol[c]
            if ol[c] >= full:
                clips = True
        if clips and cov < one:  # a level there is only a floor: mix in radiance
            for c in range(3):
                out[c] = to_levels(px[c], c, resp.exposure, resp.xs, resp.ys, resp.gx)
    for c in range(3):
        out_rad[i, c] = wp.float32(px[c])
        out_room[i, c] = wp.float32(rad[c])
        out_pix[i, c] = wp.uint8(int(wp.clamp(wp.rint(out[c]), zero, full)))


class _Mirror:
    """A buffer at capacity on the device, written from the host through a numpy view: on the CPU
    device the view is the device array's own memory; on CUDA a pinned host copy is pushed/pulled."""

    def __init__(self, shape: tuple, dtype, device: str):
        self.dev = wp.zeros(shape, dtype=dtype, device=device)
        self.host_arr = self.dev if self.dev.device.is_cpu else wp.zeros(shape, dtype=dtype, device="cpu",
                                                                          pinned=True)
        self.np = self.host_arr.numpy()  # the host view to read and write

    @classmethod
    def of(cls, values: np.ndarray, dtype, device: str) -> "_Mirror":
        m = cls(values.shape, dtype, device)
        m.np[...] = values
        m.push()
        return m

    def push(self) -> None:
        if self.host_arr is not self.dev:
            wp.copy(self.dev, self.host_arr)

    def pull(self) -> None:
        if self.host_arr is not self.dev:
            wp.copy(self.host_arr, self.dev)


class Compositor:
    """compose_kernel's inputs and outputs, allocated once per scene at full frame size.

    The caller writes this frame's changes into the host views (`shade`, `r_pix`, `r_flag`, `cov`,
    `obj`: (N,...) numpy; `dE_v`, `add_v`: (Vr,3)) and resets what it wrote before; `run` composes
    the whole frame into `rad`, `room` (float32) and `pix` (uint8), (N,3) numpy views owned here."""

    def __init__(self, L_b: np.ndarray, T_Lb: np.ndarray, rho: np.ndarray, rows: np.ndarray, bary: np.ndarray,
                 still: dict, xs: np.ndarray, ys: np.ndarray, exposure: float, n_vert: int, device: str):
        """still: {"hdr": (levels, room radiance), "ldr": (levels, room radiance)} where nothing changes;
        rows: (N,3) receiver-vertex rows, -1 for pixels that are no receiver."""
        from kernels import runtime

        self.device = d = runtime.device(device)
        n = len(L_b)
        self.n = n
        f64 = wp.float64
        self._keep = []  # the static arrays the structs point to

        def static(a, dtype=f64):
            m = _Mirror.of(np.ascontiguousarray(a), dtype, d)
            self._keep.append(m)
            return m.dev

        base = dict(L_b=static(L_b), T_Lb=static(T_Lb), rho=static(rho), rows=static(rows.astype(np.int32), wp.int32),
                    bary=static(bary.astype(np.float64)))
        self.rooms = {}
        for mode, (lev, rad) in still.items():
            r = Room()
            for k, v in base.items():
                setattr(r, k, v)
            r.still, r.still_room = static(lev), static(rad)
            self.rooms[mode] = r
        self.resp = Response()
        self.resp.xs, self.resp.ys = static(xs), static(ys)
        self.resp.gx, self.resp.gy = static(response_grid(xs), wp.int32), static(response_grid(ys), wp.int32)
        self.resp.exposure = float(exposure)
        self._m = {"shade": _Mirror((n, 3), f64, d), "r_pix": _Mirror((n, 3), f64, d),
                   "r_flag": _Mirror((n,), wp.uint8, d), "cov": _Mirror((n,), f64, d), "obj": _Mirror((n, 3), f64, d),
                   "dE_v": _Mirror((max(n_vert, 1), 3), f64, d), "add_v": _Mirror((max(n_vert, 1), 3), f64, d)}
        self.ch = Changes()
        for k, m in self._m.items():
            setattr(self.ch, k, m.dev)
            setattr(self, k, m.np)
        self.ch.all_r = 0
        self._out = {"rad": _Mirror((n, 3), wp.float32, d), "room": _Mirror((n, 3), wp.float32, d),
                     "pix": _Mirror((n, 3), wp.uint8, d)}
        for k, m in self._out.items():
            setattr(self, k, m.np)

    def run(self, ldr: bool, all_r: bool) -> None:
        """Compose every pixel from the host views into rad, room and pix; two launches, one per core."""
        from kernels import runtime

        for m in self._m.values():
            m.push()
        self.ch.all_r = int(all_r)
        room, o = self.rooms["ldr" if ldr else "hdr"], self._out
        half = self.n // 2

        def launch(first: int, dim: int):
            return lambda: wp.launch(compose_kernel, dim=dim, device=self.device,
                                     inputs=[first, int(ldr), room, self.ch, self.resp, o["rad"].dev, o["room"].dev,
                                             o["pix"].dev])

        runtime.run_parallel([launch(0, half), launch(half, self.n - half)])
        wp.synchronize_device(self.device)
        for m in o.values():
            m.pull()
