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


# Per-pixel data packed one row per pixel (one memory stream, not twenty): columns of Compositor.px
# (per scene) and Compositor.chg (per frame), 3 per quantity unless noted.
PX_LB, PX_TLB, PX_STILL_HDR, PX_STILL_LDR, PX_ROOM_LDR, PX_RHO = 0, 3, 6, 9, 12, 15  # PX_WIDTH 18
PX_WIDTH = 18
CH_SHADE, CH_SUN, CH_R, CH_OBJ, CH_COV = 0, 3, 6, 9, 12  # CH_COV: 1 column; CH_WIDTH 13
CH_WIDTH = 13


@wp.kernel
def compose_kernel(first: int, ldr: int, px: wp.array2d(dtype=wp.float64), rows: wp.array2d(dtype=wp.int32),
                   bary: wp.array2d(dtype=wp.float32), chg: wp.array2d(dtype=wp.float64),
                   r_flag: wp.array(dtype=wp.uint8), all_r: int, dE_v: wp.array2d(dtype=wp.float64),
                   add_v: wp.array2d(dtype=wp.float64), tab: wp.array2d(dtype=wp.float64),
                   grid: wp.array2d(dtype=wp.int32), exposure: wp.float64, out: wp.array2d(dtype=wp.float32),
                   out_pix: wp.array2d(dtype=wp.uint8)):
    """px: L_b, T(L_b), the unchanged levels (HDR, LDR), the LDR unchanged radiance, rho (PX_*);
    rows/bary: receiver-vertex rows (-1: no receiver) and weights; chg: this frame's occluded share
    (HDR; LDR: levels taken), the sun's occluded share, object light where r_flag (or all_r), object
    radiance and coverage (CH_*); dE_v/add_v (Vr,3) second order (plus object light) at receiver
    vertices. out: radiance (0-2) and room radiance (3-5) float32; out_pix the 8-bit frame."""
    i = first + wp.tid()
    zero = wp.float64(0.0)
    one = wp.float64(1.0)
    full = wp.float64(255.0)
    use_r = all_r != 0 or r_flag[i] != wp.uint8(0)
    r0 = rows[i, 0]
    # light added: rho x (object light + second order), irradiance/pi -> radiance
    g = wp.vec3d()
    for c in range(3):
        a = zero
        if use_r:
            a = chg[i, CH_R + c]
        if r0 >= 0:
            b0 = wp.float64(bary[i, 0])
            b1 = wp.float64(bary[i, 1])
            b2 = wp.float64(bary[i, 2])
            r1 = rows[i, 1]
            r2 = rows[i, 2]
            if use_r:
                a = a + (b0 * dE_v[r0, c] + b1 * dE_v[r1, c] + b2 * dE_v[r2, c])
            else:
                a = b0 * add_v[r0, c] + b1 * add_v[r1, c] + b2 * add_v[r2, c]
        g[c] = px[i, PX_RHO + c] * a
    added = g[0] != zero or g[1] != zero or g[2] != zero
    f = wp.vec3d(chg[i, CH_SHADE], chg[i, CH_SHADE + 1], chg[i, CH_SHADE + 2])
    u = wp.vec3d(chg[i, CH_SUN], chg[i, CH_SUN + 1], chg[i, CH_SUN + 2])
    rad = wp.vec3d()  # room radiance
    lev = wp.vec3d()  # its level
    if ldr == 0:
        # the radiance the shadows take: the occluded share of L_b, then the sun's
        s = wp.vec3d()
        for c in range(3):
            s[c] = px[i, PX_LB + c] * f[c] + px[i, PX_LB + c] * u[c]
        if added or s[0] != zero or s[1] != zero or s[2] != zero:
            for c in range(3):
                rad[c] = wp.max(px[i, PX_LB + c] - s[c] + g[c], zero)
                lev[c] = to_levels(rad[c], c, exposure, tab, grid)
        else:
            for c in range(3):
                rad[c] = px[i, PX_LB + c]
                lev[c] = px[i, PX_STILL_HDR + c]
    else:
        # the photo's level less the shadows' levels, the sun's and plus the added light's change
        if added or f[0] != zero or f[1] != zero or f[2] != zero or u[0] != zero or u[1] != zero or u[2] != zero:
            for c in range(3):
                L = px[i, PX_LB + c]
                z = px[i, PX_STILL_LDR + c] - f[c]
                if u[c] != zero:
                    z = z + (to_levels(L * (one - u[c]), c, exposure, tab, grid) - px[i, PX_TLB + c])
                if added:
                    z = z + (to_levels(wp.max(L + g[c], zero), c, exposure, tab, grid) - px[i, PX_TLB + c])
                z = wp.clamp(z, zero, full)
                lev[c] = z
                rad[c] = to_radiance(z, c, exposure, tab, grid)
        else:
            for c in range(3):
                rad[c] = px[i, PX_ROOM_LDR + c]
                lev[c] = px[i, PX_STILL_LDR + c]
    pr = wp.vec3d(rad[0], rad[1], rad[2])  # the pixel's radiance
    pl = wp.vec3d(lev[0], lev[1], lev[2])  # its level
    cov = chg[i, CH_COV]
    if cov > zero:
        # the object: mix levels, or radiance where a level is only a floor (it clips on either side)
        clips = lev[0] >= full or lev[1] >= full or lev[2] >= full
        for c in range(3):
            o = chg[i, CH_OBJ + c]
            pr[c] = (one - cov) * rad[c] + cov * o
            t = to_levels(o, c, exposure, tab, grid)
            pl[c] = (one - cov) * lev[c] + cov * t
            if t >= full:
                clips = True
        if clips and cov < one:
            for c in range(3):
                pl[c] = to_levels(pr[c], c, exposure, tab, grid)
    for c in range(3):
        out[i, c] = wp.float32(pr[c])
        out[i, 3 + c] = wp.float32(rad[c])
        out_pix[i, c] = wp.uint8(int(wp.clamp(wp.rint(pl[c]), zero, full)))


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

    The caller writes this frame's changes into the host views (`shade`, `sun`, `r_pix`, `obj`:
    (N,3), `cov`, `r_flag`: (N,) numpy views; `dE_v`, `add_v`: (Vr,3)) and resets what it wrote
    before; `run` composes the whole frame into `rad`, `room` (float32) and `pix` (uint8), (N,3)
    numpy views owned here."""

    def __init__(self, L_b: np.ndarray, T_Lb: np.ndarray, rho: np.ndarray, rows: np.ndarray, bary: np.ndarray,
                 still: dict, xs: np.ndarray, ys: np.ndarray, exposure: float, G_v: np.ndarray, device: str):
        """still: {"hdr": (levels, room radiance), "ldr": (levels, room radiance)} where nothing changes
        (the HDR room radiance is L_b); rows: (N,3) receiver-vertex rows, -1 for pixels that are no
        receiver; G_v (Vr,P) the receiver-vertex transfers (second_order)."""
        self.device = d = runtime.device(device)
        n = len(L_b)
        self.n = n
        f64 = wp.float64
        self._keep = []  # the static arrays

        def static(a, dtype=f64):
            m = _Mirror.of(np.ascontiguousarray(a), dtype, d)
            self._keep.append(m)
            return m.dev

        px = np.empty((n, PX_WIDTH))
        for col, a in ((PX_LB, L_b), (PX_TLB, T_Lb), (PX_STILL_HDR, still["hdr"][0]), (PX_STILL_LDR, still["ldr"][0]),
                       (PX_ROOM_LDR, still["ldr"][1]), (PX_RHO, rho)):
            px[:, col:col + 3] = a
        self._px = static(px)
        self._rows = static(rows.astype(np.int32), wp.int32)
        self._bary = static(bary.astype(np.float32), wp.float32)  # the precompute's float32 weights
        # the response packed for `lookup`: rows 0-2 T per channel, 3-5 T^-1; [xp | fp | slope]
        tab, grid = pack_response(xs, ys)
        self._tab, self._grid = static(tab), static(grid, wp.int32)
        self._exposure = float(exposure)
        n_vert, n_patch = G_v.shape
        self.n_vert = n_vert
        self._G_v = static(np.asarray(G_v, np.float32), wp.float32)
        self._nz = _Mirror((max(n_patch, 1),), wp.int32, d)
        self._dB = _Mirror((max(n_patch, 1), 3), f64, d)
        self._m = {"chg": _Mirror((n, CH_WIDTH), f64, d), "r_flag": _Mirror((n,), wp.uint8, d),
                   "dE_v": _Mirror((max(n_vert, 1), 3), f64, d), "add_v": _Mirror((max(n_vert, 1), 3), f64, d)}
        chg = self._m["chg"].np
        self.shade, self.sun = chg[:, CH_SHADE:CH_SHADE + 3], chg[:, CH_SUN:CH_SUN + 3]
        self.r_pix, self.obj, self.cov = chg[:, CH_R:CH_R + 3], chg[:, CH_OBJ:CH_OBJ + 3], chg[:, CH_COV]
        self.r_flag, self.dE_v, self.add_v = self._m["r_flag"].np, self._m["dE_v"].np, self._m["add_v"].np
        self._out = _Mirror((n, 6), wp.float32, d)
        self._out_pix = _Mirror((n, 3), wp.uint8, d)
        self.rad, self.room, self.pix = self._out.np[:, 0:3], self._out.np[:, 3:6], self._out_pix.np

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
        m = self._m

        def launch(lo: int, hi: int) -> None:
            wp.launch(compose_kernel, dim=hi - lo, device=self.device,
                      inputs=[lo, int(ldr), self._px, self._rows, self._bary, m["chg"].dev, m["r_flag"].dev,
                              int(all_r), m["dE_v"].dev, m["add_v"].dev, self._tab, self._grid, self._exposure,
                              self._out.dev, self._out_pix.dev])

        split(launch, self.n)
        wp.synchronize_device(self.device)
        self._out.pull()
        self._out_pix.pull()
