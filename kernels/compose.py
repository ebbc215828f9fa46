"""Per-pixel compositing of a frame (engine compose stage): room radiance, camera response, object mix.

One thread per pixel of the frame, float64 throughout, so that it reproduces the numpy reference
(app.stages.compose docstring) to the last bit of the levels:

  add      = rho x (R + sum_k b_k dE_v[row_k])            (object light + second order, irradiance/pi)
  HDR:  room = max(L_b - shadow + add, 0); levels = T(room) where anything changed, else T(L_b)
  LDR:  levels = photo + dlev (+ T(max(L_b + add, 0)) - T(L_b)); room = T^-1(clip(levels, 0, 255))
  pixel    = (1 - c) levels + c T(L_obj), or T((1 - c) room + c L_obj) where either clips

T is the camera response as recon.response.CameraResponse evaluates it: np.interp over the merged
breakpoints, here found through a uniform grid of start indices (`response_grid`) so that a lookup
is one load and a short scan instead of a bisection, with the segment slopes precomputed as np.interp
computes them (`segment_slopes`). Its result is the same segment and the same formula as np.interp's.
"""
from __future__ import annotations

from typing import Callable

import numpy as np
import warp as wp

from kernels import runtime

GRID_CELLS = 4096  # uniform cells per channel over [0, 1] in the lookup grid
Split = Callable[[Callable[[int, int], None], int], None]  # split(launch(lo, hi), n): runs [0, n) in ranges


def response_grid(xp: np.ndarray, cells: int = GRID_CELLS) -> np.ndarray:
    """(C, cells) int32: per channel, the last breakpoint index j with xp[c, j] <= k / cells."""
    starts = np.arange(cells) / cells
    return np.stack([np.maximum(np.searchsorted(x, starts, side="right") - 1, 0) for x in xp]).astype(np.int32)


def segment_slopes(xp: np.ndarray, fp: np.ndarray) -> np.ndarray:
    """(C, n) float64: (fp[j+1] - fp[j]) / (xp[j+1] - xp[j]) as np.interp computes it (ties and the last
    entry: 0, never used)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (fp[:, 1:] - fp[:, :-1]) / (xp[:, 1:] - xp[:, :-1])
    return np.concatenate([np.where(np.isfinite(s), s, 0.0), np.zeros((len(xp), 1))], axis=1)


def pack_response(xs: np.ndarray, ys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The response's breakpoints (xs, ys) (C,n) packed for `lookup`: tables (2C, 3n) float64, rows
    0..C-1 [xs | ys | slopes] (T), rows C..2C-1 [ys | xs | slopes] (T^-1); grids (2C, GRID_CELLS)."""
    tab = np.concatenate([np.concatenate([xs, ys, segment_slopes(xs, ys)], 1),
                          np.concatenate([ys, xs, segment_slopes(ys, xs)], 1)])
    return tab, np.concatenate([response_grid(xs), response_grid(ys)])


@wp.func
def lookup(x: wp.float64, row: int, tab: wp.array2d(dtype=wp.float64), grid: wp.array2d(dtype=wp.int32)
           ) -> wp.float64:
    """np.interp(x, xp, fp) for sorted xp (ties allowed; the last j with xp[j] <= x) on row `row` of
    the packed tables (pack_response: [xp | fp | slope]; rows 0-2: T per channel, 3-5: T^-1)."""
    n = tab.shape[1] // 3
    if x < tab[row, 0]:
        return tab[row, n]
    if x >= tab[row, n - 1]:
        return tab[row, 2 * n - 1]
    ng = grid.shape[1]
    k = wp.clamp(int(x * wp.float64(ng)), 0, ng - 1)
    j = grid[row, k]
    while tab[row, j + 1] <= x:  # x < xp[n-1]: stops before the end
        j += 1
    while tab[row, j] > x:  # the cell's start rounded above x
        j -= 1
    if tab[row, j] == x:
        return tab[row, n + j]
    return tab[row, 2 * n + j] * (x - tab[row, j]) + tab[row, n + j]


@wp.func
def to_levels(L: wp.float64, c: int, exposure: wp.float64, tab: wp.array2d(dtype=wp.float64),
              grid: wp.array2d(dtype=wp.int32)) -> wp.float64:
    """T(L): radiance -> continuous level in [0, 255] (CameraResponse.to_levels)."""
    x = wp.clamp(L * exposure, wp.float64(0.0), wp.float64(1.0))
    return wp.float64(255.0) * lookup(x, c, tab, grid)


@wp.func
def to_radiance(z: wp.float64, c: int, exposure: wp.float64, tab: wp.array2d(dtype=wp.float64),
                grid: wp.array2d(dtype=wp.int32)) -> wp.float64:
    """T^-1(z) of a continuous level (CameraResponse.to_radiance on float input)."""
    y = wp.clamp(z / wp.float64(255.0), wp.float64(0.0), wp.float64(1.0))
    return lookup(y, 3 + c, tab, grid) / exposure


@wp.struct
class Room:
    """Per-scene, pose-independent pixel data (H*W rows)."""

    L_b: wp.array2d(dtype=wp.float64)  # photo radiance (model radiance where the sun clips)
    T_Lb: wp.array2d(dtype=wp.float64)  # T(L_b)
    still: wp.array2d(dtype=wp.float64)  # levels where nothing changes (HDR: Engine.L_b_levels; LDR: photo)
    still_room: wp.array2d(dtype=wp.float64)  # room radiance where nothing changes (HDR: L_b; LDR: T^-1(photo))
    rho: wp.array2d(dtype=wp.float64)  # reflectance L_b / E_x
    rows: wp.array2d(dtype=wp.int32)  # receiver-vertex rows per pixel (-1: not a receiver pixel)
    bary: wp.array2d(dtype=wp.float32)  # barycentric weights of those rows


@wp.struct
class Changes:
    """This frame's changes (H*W rows unless noted); zero where nothing changes."""

    shade: wp.array2d(dtype=wp.float64)  # HDR: the share of L_b the shadows take; LDR: the levels they take
    sun: wp.array2d(dtype=wp.float64)  # the sun's occluded share of L_b (sunlit pixels)
    r_pix: wp.array2d(dtype=wp.float64)  # object light per pixel where r_flag (irradiance/pi)
    r_flag: wp.array(dtype=wp.uint8)  # 1: r_pix holds the pixel's object light, the vertices give dE only
    all_r: int  # 1: every pixel's object light is in r_pix (the dense form)
    dE_v: wp.array2d(dtype=wp.float64)  # (Vr,3) second-order irradiance/pi at receiver vertices
    add_v: wp.array2d(dtype=wp.float64)  # (Vr,3) dE_v plus the object light at receiver vertices
    cov: wp.array(dtype=wp.float64)  # object coverage
    obj: wp.array2d(dtype=wp.float64)  # object radiance where cov > 0


@wp.kernel
def compose_kernel(first: int, ldr: int, room: Room, ch: Changes, tab: wp.array2d(dtype=wp.float64),
                   grid: wp.array2d(dtype=wp.int32), exposure: wp.float64,
                   out_rad: wp.array2d(dtype=wp.float32), out_room: wp.array2d(dtype=wp.float32),
                   out_pix: wp.array2d(dtype=wp.uint8)):
    # (no struct goes to a wp.func: Warp passes it by value, which costs more than the pixel's work)
    i = first + wp.tid()
    zero = wp.float64(0.0)
    one = wp.float64(1.0)
    full = wp.float64(255.0)
    use_r = ch.all_r != 0 or ch.r_flag[i] != wp.uint8(0)
    r0 = room.rows[i, 0]
    # light added: rho x (object light + second order), irradiance/pi -> radiance
    g = wp.vec3d()
    for c in range(3):
        a = zero
        if use_r:
            a = ch.r_pix[i, c]
        if r0 >= 0:
            b0 = wp.float64(room.bary[i, 0])
            b1 = wp.float64(room.bary[i, 1])
            b2 = wp.float64(room.bary[i, 2])
            r1 = room.rows[i, 1]
            r2 = room.rows[i, 2]
            if use_r:
                a = a + (b0 * ch.dE_v[r0, c] + b1 * ch.dE_v[r1, c] + b2 * ch.dE_v[r2, c])
            else:
                a = b0 * ch.add_v[r0, c] + b1 * ch.add_v[r1, c] + b2 * ch.add_v[r2, c]
        g[c] = room.rho[i, c] * a
    added = g[0] != zero or g[1] != zero or g[2] != zero
    f = wp.vec3d(ch.shade[i, 0], ch.shade[i, 1], ch.shade[i, 2])
    u = wp.vec3d(ch.sun[i, 0], ch.sun[i, 1], ch.sun[i, 2])
    rad = wp.vec3d()  # room radiance
    lev = wp.vec3d()  # its level
    if ldr == 0:
        # the radiance the shadows take: the occluded share of L_b, then the sun's
        s = wp.vec3d()
        for c in range(3):
            s[c] = room.L_b[i, c] * f[c] + room.L_b[i, c] * u[c]
        if added or s[0] != zero or s[1] != zero or s[2] != zero:
            for c in range(3):
                rad[c] = wp.max(room.L_b[i, c] - s[c] + g[c], zero)
                lev[c] = to_levels(rad[c], c, exposure, tab, grid)
        else:
            for c in range(3):
                rad[c] = room.L_b[i, c]
                lev[c] = room.still[i, c]
    else:
        # the photo's level less the shadows' levels, the sun's and plus the added light's change
        if added or f[0] != zero or f[1] != zero or f[2] != zero or u[0] != zero or u[1] != zero or u[2] != zero:
            for c in range(3):
                z = room.still[i, c] - f[c]
                if u[c] != zero:
                    z = z + (to_levels(room.L_b[i, c] * (one - u[c]), c, exposure, tab, grid) - room.T_Lb[i, c])
                if added:
                    z = z + (to_levels(wp.max(room.L_b[i, c] + g[c], zero), c, exposure, tab, grid) - room.T_Lb[i, c])
                z = wp.clamp(z, zero, full)
                lev[c] = z
                rad[c] = to_radiance(z, c, exposure, tab, grid)
        else:
            for c in range(3):
                rad[c] = room.still_room[i, c]
                lev[c] = room.still[i, c]
    px = wp.vec3d(rad[0], rad[1], rad[2])  # the pixel's radiance
    out = wp.vec3d(lev[0], lev[1], lev[2])  # its level
    cov = ch.cov[i]
    if cov > zero:
        # the object: mix levels, or radiance where a level is only a floor (it clips on either side)
        clips = lev[0] >= full or lev[1] >= full or lev[2] >= full
        for c in range(3):
            px[c] = (one - cov) * rad[c] + cov * ch.obj[i, c]
            t = to_levels(ch.obj[i, c], c, exposure, tab, grid)
            out[c] = (one - cov) * lev[c] + cov * t
            if t >= full:
                clips = True
        if clips and cov < one:
            for c in range(3):
                out[c] = to_levels(px[c], c, exposure, tab, grid)
    for c in range(3):
        out_rad[i, c] = wp.float32(px[c])
        out_room[i, c] = wp.float32(rad[c])
        out_pix[i, c] = wp.uint8(int(wp.clamp(wp.rint(out[c]), zero, full)))


@wp.kernel
def second_order_kernel(first: int, G_v: wp.array2d(dtype=wp.float32), nz: wp.array(dtype=wp.int32), n_nz: int,
                        dB: wp.array2d(dtype=wp.float64), dE_v: wp.array2d(dtype=wp.float64),
                        add_v: wp.array2d(dtype=wp.float64)):
    """dE_v[v] = sum_k G_v[v, nz[k]] dB[nz[k]] (float64 sums of the float32 transfers); add_v = dE_v."""
    v = first + wp.tid()
    a0 = wp.float64(0.0)
    a1 = wp.float64(0.0)
    a2 = wp.float64(0.0)
    for k in range(n_nz):
        p = nz[k]
        g = wp.float64(G_v[v, p])
        a0 += g * dB[p, 0]
        a1 += g * dB[p, 1]
        a2 += g * dB[p, 2]
    dE_v[v, 0] = a0
    dE_v[v, 1] = a1
    dE_v[v, 2] = a2
    add_v[v, 0] = a0
    add_v[v, 1] = a1
    add_v[v, 2] = a2


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

    The caller writes this frame's changes into the host views (`shade`, `sun`, `r_pix`, `r_flag`, `cov`,
    `obj`: (N,...) numpy; `dE_v`, `add_v`: (Vr,3)) and resets what it wrote before; `run` composes
    the whole frame into `rad`, `room` (float32) and `pix` (uint8), (N,3) numpy views owned here."""

    def __init__(self, L_b: np.ndarray, T_Lb: np.ndarray, rho: np.ndarray, rows: np.ndarray, bary: np.ndarray,
                 still: dict, xs: np.ndarray, ys: np.ndarray, exposure: float, G_v: np.ndarray, device: str):
        """still: {"hdr": (levels, room radiance), "ldr": (levels, room radiance)} where nothing changes;
        rows: (N,3) receiver-vertex rows, -1 for pixels that are no receiver; G_v (Vr,P) the
        receiver-vertex transfers (second_order)."""
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
                    bary=static(bary.astype(np.float32), wp.float32))  # the precompute's float32 weights
        self.rooms = {}
        for mode, (lev, rad) in still.items():
            r = Room()
            for k, v in base.items():
                setattr(r, k, v)
            r.still, r.still_room = static(lev), static(rad)
            self.rooms[mode] = r
        # the response packed for `lookup`: rows 0-2 T per channel, 3-5 T^-1; [xp | fp | slope]
        tab, grid = pack_response(xs, ys)
        self._tab, self._grid = static(tab), static(grid, wp.int32)
        self._exposure = float(exposure)
        n_vert, n_patch = G_v.shape
        self.n_vert = n_vert
        self._G_v = static(np.asarray(G_v, np.float32), wp.float32)
        self._nz = _Mirror((max(n_patch, 1),), wp.int32, d)
        self._dB = _Mirror((max(n_patch, 1), 3), f64, d)
        self._m = {"shade": _Mirror((n, 3), f64, d), "sun": _Mirror((n, 3), f64, d), "r_pix": _Mirror((n, 3), f64, d),
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

    def second_order(self, dB: np.ndarray, split: Split) -> None:
        """dE_v = G_v dB over the patches where dB (P,3) is non-zero, into `dE_v` (and `add_v`), the
        receiver vertices cut into index ranges by `split` (one launch per range)."""
        nz = np.flatnonzero(np.abs(dB).sum(1) > 0)
        self._nz.np[:len(nz)] = nz
        self._dB.np[:] = dB
        self._nz.push()
        self._dB.push()
        m = self._m

        def launch(lo: int, hi: int) -> None:
            wp.launch(second_order_kernel, dim=hi - lo, device=self.device,
                      inputs=[lo, self._G_v, self._nz.dev, len(nz), self._dB.dev, m["dE_v"].dev, m["add_v"].dev])

        split(launch, self.n_vert)
        wp.synchronize_device(self.device)
        m["dE_v"].pull()
        m["add_v"].pull()

    def run(self, ldr: bool, all_r: bool, split: Split) -> None:
        """Compose every pixel from the host views into rad, room and pix, the pixels cut into index
        ranges by `split` (one launch per range)."""
        for m in self._m.values():
            m.push()
        self.ch.all_r = int(all_r)
        room, o = self.rooms["ldr" if ldr else "hdr"], self._out

        def launch(lo: int, hi: int) -> None:
            wp.launch(compose_kernel, dim=hi - lo, device=self.device,
                      inputs=[lo, int(ldr), room, self.ch, self._tab, self._grid, self._exposure, o["rad"].dev,
                              o["room"].dev, o["pix"].dev])

        split(launch, self.n)
        wp.synchronize_device(self.device)
        for m in o.values():
            m.pull()
