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

An HDR pixel the object does not cover needs only the 8-bit level of its room radiance, rint(T(L)):
`rounding_table` gives it per cell of a uniform grid over the exposure-scaled radiance wherever
every value T takes in the cell rounds to the same level (an exact bound: T is piecewise linear, so
its extremes over a cell are at the cell's ends and the breakpoints inside it); in the other cells
(those holding a half level) `to_pixel` evaluates T as above. The 8-bit frame is bit-equal either way.
"""
from __future__ import annotations

import sys
from typing import Callable

import numpy as np
import warp as wp

from kernels import runtime

GRID_CELLS = 4096  # uniform cells per channel over [0, 1] in the lookup grid
ROUND_CELLS = 1 << 15  # uniform cells per channel over [0, 1] in the rounding table (a power of two:
# x * ROUND_CELLS is exact, so a cell holds exactly the x in [k, k + 1) / ROUND_CELLS)
ROUND_TOL = 1e-6  # levels: the margin kept from a half level, far above T's float64 rounding error
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
    0..C-1 for T, rows C..2C-1 for T^-1, each holding per breakpoint j the triple (xp_j, fp_j,
    slope_j) side by side (a lookup reads one cache line, not three; 3-4% of the compose stage's CPU
    time on window_room and lamps_room); grids (2C, GRID_CELLS)."""
    def triples(xp, fp):
        return np.stack([xp, fp, segment_slopes(xp, fp)], axis=2).reshape(len(xp), -1)

    tab = np.concatenate([triples(xs, ys), triples(ys, xs)])
    return tab, np.concatenate([response_grid(xs), response_grid(ys)])


def rounding_table(xs: np.ndarray, ys: np.ndarray, cells: int = ROUND_CELLS, tol: float = ROUND_TOL
                   ) -> np.ndarray:
    """(C, cells) int16: per channel and cell k of x in [k, k + 1] / cells, the level rint(255 f(x))
    (f: np.interp over the breakpoints (xs, ys) (C, n)) where it is the same for every x of the cell,
    else -1. The extremes of the piecewise-linear f over a cell are at its ends and the breakpoints
    inside (ties: both values); the cell holds one level where no half level lies within `tol` of
    255 x their range."""
    edges = np.arange(cells + 1, dtype=np.float64) / cells
    out = np.empty((len(xs), cells), np.int16)
    for c, (xp, fp) in enumerate(zip(xs, ys)):
        f = np.interp(edges, xp, fp)
        lo, hi = np.minimum(f[:-1], f[1:]), np.maximum(f[:-1], f[1:])
        inside = (xp >= 0.0) & (xp <= 1.0)
        t, v = xp[inside] * cells, fp[inside]
        for cell in (np.minimum(np.floor(t), cells - 1), np.ceil(t) - 1):  # the cells whose closed range holds it
            ok = cell >= 0
            np.minimum.at(lo, cell[ok].astype(np.int64), v[ok])
            np.maximum.at(hi, cell[ok].astype(np.int64), v[ok])
        a, b = np.floor(255.0 * lo - tol + 0.5), np.floor(255.0 * hi + tol + 0.5)
        out[c] = np.where(a == b, np.clip(a, 0, 255), -1)
    return out


@wp.func
def lookup(x: wp.float64, row: int, tab: wp.array2d(dtype=wp.float64), grid: wp.array2d(dtype=wp.int32)
           ) -> wp.float64:
    """np.interp(x, xp, fp) for sorted xp (ties allowed; the last j with xp[j] <= x) on row `row` of
    the packed tables (pack_response: (xp, fp, slope) per breakpoint; rows 0-2: T per channel, 3-5:
    T^-1)."""
    last = tab.shape[1] - 3  # the last breakpoint's triple
    if x < tab[row, 0]:
        return tab[row, 1]
    if x >= tab[row, last]:
        return tab[row, last + 1]
    ng = grid.shape[1]
    k = wp.clamp(int(x * wp.float64(ng)), 0, ng - 1)
    j = 3 * grid[row, k]
    while tab[row, j + 3] <= x:  # x < xp[n-1]: stops before the end
        j += 3
    while tab[row, j] > x:  # the cell's start rounded above x
        j -= 3
    if tab[row, j] == x:
        return tab[row, j + 1]
    return tab[row, j + 2] * (x - tab[row, j]) + tab[row, j + 1]


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


@wp.func
def to_pixel(L: wp.float64, c: int, exposure: wp.float64, rtab: wp.array2d(dtype=wp.int16),
             tab: wp.array2d(dtype=wp.float64), grid: wp.array2d(dtype=wp.int32)) -> int:
    """clamp(rint(T(L)), 0, 255), the 8-bit level of radiance L: from the rounding table where its
    cell holds one level, else T(L) (to_levels) rounded."""
    x = wp.clamp(L * exposure, wp.float64(0.0), wp.float64(1.0))
    nc = rtab.shape[1]
    q = int(rtab[c, wp.min(int(x * wp.float64(nc)), nc - 1)])
    if q >= 0:
        return q
    return int(wp.clamp(wp.rint(wp.float64(255.0) * lookup(x, c, tab, grid)), wp.float64(0.0),
                        wp.float64(255.0)))


# The mode's per-scene table, one row per pixel (one memory stream): HDR [L_b | rho | T(L_b)], LDR
# [L_b | rho | photo levels | T(L_b) | the photo's radiance], 3 columns per quantity.
PX_LB, PX_RHO, PX_STILL, PX_TLB, PX_ROOM_LDR = 0, 3, 6, 9, 12  # PX_STILL: the levels where nothing changes
# This frame's sparse changes (the sun's share, the object), one row of `extra` per pixel that has any
# (the pixel's `slot`; -1: none).
EX_SUN, EX_OBJ, EX_COV = 0, 3, 6
EX_WIDTH = 7


@wp.func
def mix_radiance(rad: wp.vec3d, cov: wp.float64, o: wp.vec3d) -> wp.vec3d:
    """(1 - cov) rad + cov o: a pixel's radiance with the object (radiance o) over its share cov."""
    one = wp.float64(1.0)
    return wp.vec3d((one - cov) * rad[0] + cov * o[0], (one - cov) * rad[1] + cov * o[1],
                    (one - cov) * rad[2] + cov * o[2])


@wp.func
def mix_levels(rad: wp.vec3d, lev: wp.vec3d, cov: wp.float64, o: wp.vec3d, exposure: wp.float64,
               tab: wp.array2d(dtype=wp.float64), grid: wp.array2d(dtype=wp.int32)) -> wp.vec3d:
    """The level of a pixel the object covers by cov > 0 over the room (radiance rad, levels lev): the
    levels mixed, (1 - cov) lev + cov T(o), or T(mix_radiance) where a level is only a floor (either
    side clips) and the object does not cover it all (compose_kernel, drag_compose_kernel)."""
    one = wp.float64(1.0)
    full = wp.float64(255.0)
    clips = lev[0] >= full or lev[1] >= full or lev[2] >= full
    pl = wp.vec3d()
    for c in range(3):
        t = to_levels(o[c], c, exposure, tab, grid)
        pl[c] = (one - cov) * lev[c] + cov * t
        if t >= full:
            clips = True
    if clips and cov < one:
        pr = mix_radiance(rad, cov, o)
        for c in range(3):
            pl[c] = to_levels(pr[c], c, exposure, tab, grid)
    return pl


@wp.kernel
def compose_kernel(first: int, ldr: int, px: wp.array2d(dtype=wp.float64), rows: wp.array2d(dtype=wp.int32),
                   bary: wp.array2d(dtype=wp.float32), shade: wp.array2d(dtype=wp.float64),
                   r_pix: wp.array2d(dtype=wp.float64), r_flag: wp.array(dtype=wp.uint8), all_r: int,
                   slot: wp.array(dtype=wp.int32), extra: wp.array2d(dtype=wp.float64),
                   dE_v: wp.array2d(dtype=wp.float64), add_v: wp.array2d(dtype=wp.float64),
                   tab: wp.array2d(dtype=wp.float64), grid: wp.array2d(dtype=wp.int32),
                   rtab: wp.array2d(dtype=wp.int16), exposure: wp.float64,
                   out: wp.array2d(dtype=wp.float32), out_room: wp.array2d(dtype=wp.float32),
                   out_pix: wp.array2d(dtype=wp.uint8)):
    """px: the mode's per-scene table (PX_*); rows/bary: receiver-vertex rows (-1: no receiver) and
    weights; shade: this frame's occluded share (HDR; LDR: levels taken); r_pix: object light, used
    where r_flag is set (or everywhere: all_r); slot/extra: the sun's occluded share, the object's
    radiance and coverage (EX_*) of the pixels that have them; dE_v/add_v (Vr,3) second order (plus
    object light) at receiver vertices; rtab the rounding table (rounding_table). out: radiance,
    out_room: room radiance (float32); out_pix the 8-bit frame. The frame's inputs it reads are left
    cleared (shade, r_flag and r_pix where r_flag is set (not all_r: r_pix is the caller's), slot)
    for the next frame."""
    i = first + wp.tid()
    zero = wp.float64(0.0)
    one = wp.float64(1.0)
    full = wp.float64(255.0)
    use_r = all_r != 0
    if r_flag[i] != wp.uint8(0):
        use_r = True
        r_flag[i] = wp.uint8(0)
    f = wp.vec3d(shade[i, 0], shade[i, 1], shade[i, 2])
    if f[0] != zero or f[1] != zero or f[2] != zero:
        for c in range(3):
            shade[i, c] = zero
    s = slot[i]
    u = wp.vec3d()
    cov = zero
    o = wp.vec3d()
    if s >= 0:
        slot[i] = -1
        u = wp.vec3d(extra[s, EX_SUN], extra[s, EX_SUN + 1], extra[s, EX_SUN + 2])
        o = wp.vec3d(extra[s, EX_OBJ], extra[s, EX_OBJ + 1], extra[s, EX_OBJ + 2])
        cov = extra[s, EX_COV]
    r0 = rows[i, 0]
    r1 = rows[i, 1]
    r2 = rows[i, 2]
    b0 = wp.float64(bary[i, 0])
    b1 = wp.float64(bary[i, 1])
    b2 = wp.float64(bary[i, 2])
    # light added: rho x (object light + second order), irradiance/pi -> radiance
    g = wp.vec3d()
    for c in range(3):
        a = zero
        if use_r:
            a = r_pix[i, c]
            if all_r == 0:
                r_pix[i, c] = zero
        if r0 >= 0:
            if use_r:
                a = a + (b0 * dE_v[r0, c] + b1 * dE_v[r1, c] + b2 * dE_v[r2, c])
            else:
                a = b0 * add_v[r0, c] + b1 * add_v[r1, c] + b2 * add_v[r2, c]
        g[c] = px[i, PX_RHO + c] * a
    added = g[0] != zero or g[1] != zero or g[2] != zero
    rad = wp.vec3d()  # room radiance
    lev = wp.vec3d()  # its level
    rounded = False  # the 8-bit levels are in q (the room's, HDR, where the object is not)
    q = wp.vec3i()
    if ldr == 0:
        # the radiance the shadows take: the occluded share of L_b, then the sun's
        sh = wp.vec3d()
        for c in range(3):
            sh[c] = px[i, PX_LB + c] * f[c] + px[i, PX_LB + c] * u[c]
        if added or sh[0] != zero or sh[1] != zero or sh[2] != zero:
            rounded = cov == zero
            for c in range(3):
                rad[c] = wp.max(px[i, PX_LB + c] - sh[c] + g[c], zero)
                if rounded:
                    q[c] = to_pixel(rad[c], c, exposure, rtab, tab, grid)
                else:
                    lev[c] = to_levels(rad[c], c, exposure, tab, grid)
        else:
            for c in range(3):
                rad[c] = px[i, PX_LB + c]
                lev[c] = px[i, PX_STILL + c]
    else:
        # the photo's level less the shadows' levels, the sun's and plus the added light's change
        if added or f[0] != zero or f[1] != zero or f[2] != zero or u[0] != zero or u[1] != zero or u[2] != zero:
            for c in range(3):
                L = px[i, PX_LB + c]
                z = px[i, PX_STILL + c] - f[c]
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
                lev[c] = px[i, PX_STILL + c]
    pr = wp.vec3d(rad[0], rad[1], rad[2])  # the pixel's radiance
    pl = wp.vec3d(lev[0], lev[1], lev[2])  # its level
    if cov > zero:  # the object over it
        pr = mix_radiance(rad, cov, o)
        pl = mix_levels(rad, lev, cov, o, exposure, tab, grid)
    for c in range(3):
        out[i, c] = wp.float32(pr[c])
        out_room[i, c] = wp.float32(rad[c])
        if rounded:
            out_pix[i, c] = wp.uint8(q[c])
        else:
            out_pix[i, c] = wp.uint8(int(wp.clamp(wp.rint(pl[c]), zero, full)))


@wp.kernel
def scatter_kernel(first: int, idx: wp.array(dtype=wp.int64), vals: wp.array2d(dtype=wp.float64),
                   out: wp.array2d(dtype=wp.float64), flag: wp.array(dtype=wp.uint8), set_flag: int):
    """out[idx[k]] = vals[k] (and flag[idx[k]] = 1 where set_flag) for k in the launch's range."""
    k = first + wp.tid()
    p = idx[k]
    for c in range(3):
        out[p, c] = vals[k, c]
    if set_flag != 0:
        flag[p] = wp.uint8(1)


@wp.kernel
def share_kernel(first: int, idx: wp.array(dtype=wp.int64), O: wp.array2d(dtype=wp.float64),
                 E_x: wp.array2d(dtype=wp.float64), ratio: int, share: wp.array2d(dtype=wp.float64),
                 out: wp.array2d(dtype=wp.float64)):
    """share[k] = O[k] / E_x[idx[k]] clipped to [0, 1], 0 where E_x is not > 0 (ratio; else O[k] as
    it is), and out[idx[k]] = share[k]: the HDR shadow's occluded share as numpy's
    where(E > 0, clip(O / E, 0, 1), 0) computes it."""
    k = first + wp.tid()
    p = idx[k]
    for c in range(3):
        v = O[k, c]
        if ratio != 0:
            e = E_x[p, c]
            if e > wp.float64(0.0):
                v = wp.clamp(v / e, wp.float64(0.0), wp.float64(1.0))
            else:
                v = wp.float64(0.0)
        share[k, c] = v
        out[p, c] = v


OUTPUT_SETS = 3  # output sets (radiance, room, pixels) the Compositor keeps for reuse (_outputs)
SO_ROWS = 4  # receiver vertices per thread of second_order_kernel


def changed_patches(dB: np.ndarray) -> np.ndarray:
    """(k,) int64 ascending: the patches where dB (P,3) is non-zero, the columns Compositor.second_order sums."""
    return np.flatnonzero(np.abs(dB).sum(1) > 0)


@wp.func
def _store_row(dE_v: wp.array2d(dtype=wp.float64), add_v: wp.array2d(dtype=wp.float64), v: int, last: int,
               a: wp.vec3d):
    """dE_v[v] = add_v[v] = a for a vertex v of the range (v < last)."""
    if v < last:
        for c in range(3):
            dE_v[v, c] = a[c]
            add_v[v, c] = a[c]


@wp.kernel
def second_order_kernel(first: int, last: int, G_v: wp.array2d(dtype=wp.float32), nz: wp.array(dtype=wp.int32),
                        n_nz: int, dB: wp.array2d(dtype=wp.float64), dE_v: wp.array2d(dtype=wp.float64),
                        add_v: wp.array2d(dtype=wp.float64)):
    """dE_v[v] = sum_k G_v[v, nz[k]] dB[nz[k]] (float64 sums of the float32 transfers, in k order);
    add_v = dE_v. Each thread sums SO_ROWS consecutive vertices of [first, last) side by side: twelve
    independent sums, not three, so the additions overlap (the same sums, bit for bit)."""
    v0 = first + SO_ROWS * wp.tid()
    v1 = wp.min(v0 + 1, last - 1)  # past the range: the last row again, not stored
    v2 = wp.min(v0 + 2, last - 1)
    v3 = wp.min(v0 + 3, last - 1)
    a0 = wp.vec3d(0.0, 0.0, 0.0)
    a1 = wp.vec3d(0.0, 0.0, 0.0)
    a2 = wp.vec3d(0.0, 0.0, 0.0)
    a3 = wp.vec3d(0.0, 0.0, 0.0)
    for k in range(n_nz):
        p = nz[k]
        d = wp.vec3d(dB[p, 0], dB[p, 1], dB[p, 2])
        a0 += wp.float64(G_v[v0, p]) * d
        a1 += wp.float64(G_v[v1, p]) * d
        a2 += wp.float64(G_v[v2, p]) * d
        a3 += wp.float64(G_v[v3, p]) * d
    _store_row(dE_v, add_v, v0, last, a0)
    _store_row(dE_v, add_v, v0 + 1, last, a1)
    _store_row(dE_v, add_v, v0 + 2, last, a2)
    _store_row(dE_v, add_v, v0 + 3, last, a3)


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

    def push(self, rows: int | None = None) -> None:
        """Copy the host view to the device (its first `rows` rows only when given)."""
        if self.host_arr is not self.dev:
            if rows is None:
                wp.copy(self.dev, self.host_arr)
            elif rows > 0:
                per_row = int(np.prod(self.np.shape[1:], dtype=np.int64))
                wp.copy(self.dev, self.host_arr, count=rows * per_row)

    def pull(self) -> None:
        """Copy the device array to the host view, and wait for it (a copy to pinned memory may be
        asynchronous)."""
        if self.host_arr is not self.dev:
            wp.copy(self.host_arr, self.dev)
            wp.synchronize_device(self.dev.device)


class Compositor:
    """compose_kernel's inputs and outputs, allocated once per scene at full frame size.

    Per frame the caller writes its changes: the shadows' share (`shade_from`, `scatter`), the object
    light (`scatter` with its flag, or dense to `run`), the sparse sun share and object (`rows_for`
    then `extra`'s columns EX_*), and `dE_v`, `add_v` (Vr,3); `run` composes the whole frame into new
    (N,3) arrays (radiance and room radiance float32, the 8-bit frame), which the caller owns (on the
    CPU the kernel writes them directly: no copy; a set is written again only once nothing outside
    the Compositor references it: `_outputs`), and leaves the per-frame buffers cleared."""

    def __init__(self, L_b: np.ndarray, T_Lb: np.ndarray, rho: np.ndarray, rows: np.ndarray, bary: np.ndarray,
                 still: dict, xs: np.ndarray, ys: np.ndarray, exposure: float, G_v: np.ndarray, device: str,
                 E_x: np.ndarray | None = None):
        """still: {"hdr": (levels, room radiance), "ldr": (levels, room radiance)} where nothing changes
        (the HDR room radiance is L_b); rows: (N,3) receiver-vertex rows, -1 for pixels that are no
        receiver; G_v (Vr,P) the receiver-vertex transfers (second_order); E_x (N,3) irradiance/pi
        (shade_from's ratio; default zeros)."""
        self.device = d = runtime.device(device)
        n = len(L_b)
        self.n = n
        f64 = wp.float64
        self._keep = []  # the static arrays

        def static(a, dtype=f64):
            m = _Mirror.of(np.ascontiguousarray(a), dtype, d)
            self._keep.append(m)
            return m.dev

        def table(cols):
            t = np.empty((n, 3 * len(cols)))
            for k, a in enumerate(cols):
                t[:, 3 * k:3 * k + 3] = a
            return static(t)

        # per mode, only the columns its pixels read (PX_*)
        self._px = {"hdr": table([L_b, rho, still["hdr"][0]]),
                    "ldr": table([L_b, rho, still["ldr"][0], T_Lb, still["ldr"][1]])}
        self._rows = static(rows.astype(np.int32), wp.int32)
        self._bary = static(bary.astype(np.float32), wp.float32)  # the precompute's float32 weights
        self._E_x = static(np.zeros((n, 3)) if E_x is None else E_x)
        # the response packed for `lookup`: rows 0-2 T per channel, 3-5 T^-1; (xp, fp, slope) per breakpoint
        tab, grid = pack_response(xs, ys)
        self._tab, self._grid = static(tab), static(grid, wp.int32)
        self._rtab = static(rounding_table(xs, ys), wp.int16)
        self._exposure = float(exposure)
        n_vert, n_patch = G_v.shape
        self.n_vert = n_vert
        self._G_v = static(np.asarray(G_v, np.float32), wp.float32)
        self._nz = _Mirror((max(n_patch, 1),), wp.int32, d)
        self._dB = _Mirror((max(n_patch, 1), 3), f64, d)
        self._m = {"dE_v": _Mirror((max(n_vert, 1), 3), f64, d), "add_v": _Mirror((max(n_vert, 1), 3), f64, d)}
        self.dE_v, self.add_v = self._m["dE_v"].np, self._m["add_v"].np
        N = max(n, 1)
        # per-frame per-pixel buffers, cleared by compose_kernel as it reads them
        self._shade, self._r_pix = _Mirror((N, 3), f64, d), _Mirror((N, 3), f64, d)
        # the shadows as one vec3d per pixel (the same memory): a fill writes its pixels there
        self.shade_px = wp.array(ptr=self._shade.dev.ptr, dtype=wp.vec3d, shape=(N,), device=self._shade.dev.device)
        self._r_flag = _Mirror((N,), wp.uint8, d)
        self._slot = _Mirror.of(np.full(N, -1, np.int32), wp.int32, d)
        self._extra = _Mirror((N, EX_WIDTH), f64, d)
        self.slot, self.extra = self._slot.np, self._extra.np
        self._share = _Mirror((N, 3), f64, d)  # shade_from's shares
        self._in = {} if self._slot.dev.device.is_cpu else {  # CUDA: the host inputs' device copies
            "idx": _Mirror((N,), wp.int64, d), "vals": _Mirror((N, 3), f64, d)}
        self.used = 0  # rows of extra this frame holds
        self._count = np.arange(N, dtype=np.int32)
        self._dirty = False  # a frame began and did not run (the buffers may hold its changes)
        self._pool: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []  # output sets (_outputs)
        self._out = None if self._slot.dev.device.is_cpu else (
            _Mirror((N, 3), wp.float32, d), _Mirror((N, 3), wp.float32, d), _Mirror((N, 3), wp.uint8, d))

    # ------------------------------------------------------------------ per frame
    def begin(self) -> None:
        """Start a frame: clears what a frame that began and never ran left in the buffers."""
        if self._dirty:
            for m, v in ((self._shade, 0), (self._r_pix, 0), (self._r_flag, 0), (self._slot, -1)):
                m.np.fill(v)
                m.push()
        self._dirty = True
        self.used = 0

    def _input(self, idx: np.ndarray, vals: np.ndarray | None = None) -> tuple:
        """Device arrays of a host index list (int64) and its (k,3) float64 values: on the CPU the
        host arrays themselves (wrapped, not copied), on CUDA copies in the capacity buffers."""
        idx = np.ascontiguousarray(idx, np.int64)
        vals = None if vals is None else np.ascontiguousarray(vals, np.float64)
        if not self._in:
            return (wp.array(idx, dtype=wp.int64, device=self.device, copy=False),
                    None if vals is None else wp.array(vals, dtype=wp.float64, device=self.device, copy=False))
        k = len(idx)
        out = []
        for name, a in (("idx", idx), ("vals", vals)):
            if a is None:
                out.append(None)
                continue
            m = self._in[name]
            m.np[:k] = a
            m.push(k)
            out.append(m.dev[:k])
        return tuple(out)

    def shade_from(self, idx: np.ndarray, O: np.ndarray, ratio: bool, split: Split) -> np.ndarray:
        """Write the shadows at pixels idx (no repeats): the occluded share O / E_x clipped to [0, 1]
        (ratio, HDR; 0 where E_x is not > 0) or O as it is (LDR levels). Returns the values written
        (len(idx),3), a buffer valid until the next call."""
        k = len(idx)
        if k == 0:
            return np.zeros((0, 3))
        i_dev, o_dev = self._input(idx, O)

        def launch(lo: int, hi: int) -> None:
            wp.launch(share_kernel, dim=hi - lo, device=self.device,
                      inputs=[lo, i_dev, o_dev, self._E_x, int(ratio), self._share.dev, self._shade.dev])

        split(launch, k)
        wp.synchronize_device(self.device)
        if self._in:
            wp.copy(self._share.host_arr, self._share.dev, count=3 * k)
            wp.synchronize_device(self.device)
        return self._share.np[:k]

    def scatter(self, what: str, idx: np.ndarray, vals: np.ndarray, split: Split) -> None:
        """Write vals (k,3) at pixels idx (no repeats) into the frame's `what`: "shade" (the shadows)
        or "r" (object light; its flag set there)."""
        if len(idx) == 0:
            return
        i_dev, v_dev = self._input(idx, vals)
        out = (self._shade if what == "shade" else self._r_pix).dev
        flag = int(what == "r")

        def launch(lo: int, hi: int) -> None:
            wp.launch(scatter_kernel, dim=hi - lo, device=self.device,
                      inputs=[lo, i_dev, v_dev, out, self._r_flag.dev, flag])

        split(launch, len(idx))
        wp.synchronize_device(self.device)

    def rows_for(self, idx: np.ndarray) -> np.ndarray:
        """The `extra` rows of pixels idx (int, no repeats), new zeroed rows for those without one."""
        m = self.used
        r = self.slot[idx]
        new = np.flatnonzero(r < 0)
        if len(new):
            r[new] = self._count[m:m + len(new)]
            self.slot[idx[new]] = r[new]
            self.extra[m:m + len(new)] = 0.0
            self.used = m + len(new)
        return r

    def second_order(self, dB: np.ndarray, split: Split, nz: np.ndarray | None = None) -> None:
        """dE_v = G_v dB over the patches where dB (P,3) is non-zero (nz: those patches, ascending, when the
        caller has them; changed_patches(dB)), into `dE_v` (and `add_v`), the receiver vertices cut into index
        ranges by `split` (one launch per range)."""
        nz = changed_patches(dB) if nz is None else nz
        self._nz.np[:len(nz)] = nz
        self._dB.np[:] = dB
        self._nz.push()
        self._dB.push()
        m = self._m

        def launch(lo: int, hi: int) -> None:
            wp.launch(second_order_kernel, dim=-(-(hi - lo) // SO_ROWS), device=self.device,
                      inputs=[lo, hi, self._G_v, self._nz.dev, len(nz), self._dB.dev, m["dE_v"].dev,
                              m["add_v"].dev])

        split(launch, self.n_vert)
        wp.synchronize_device(self.device)
        m["dE_v"].pull()
        m["add_v"].pull()

    def _outputs(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(radiance, room, pixels) arrays for a frame: a set of the pool that nothing else references any
        more (the frames that were given it are gone: it is never written while someone holds it), else a
        new set, kept in the pool while it has fewer than OUTPUT_SETS (a drag holds one frame while the
        next is made). A reused set costs no allocation and no page faults (~3 ms a frame at 640x480)."""
        for outs in self._pool:
            if all(sys.getrefcount(a) <= 3 for a in outs):  # the pool's tuple, `a` and the call's argument
                return outs
        n = self.n
        outs = (np.empty((n, 3), np.float32), np.empty((n, 3), np.float32), np.empty((n, 3), np.uint8))
        if len(self._pool) < OUTPUT_SETS:
            self._pool.append(outs)
        return outs

    def run(self, ldr: bool, r_dense: np.ndarray | None, split: Split) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Compose every pixel, the pixels cut into index ranges by `split` (one launch per range);
        r_dense (N,3): object light at every pixel (None: what `scatter` wrote). Returns arrays no one
        else holds (_outputs): radiance (N,3) float32, room radiance (N,3) float32, pixels (N,3) uint8."""
        for m in self._m.values():
            m.push()
        if self._in:  # CUDA: the slots were written on the host: push them (and the rows in use)
            self._slot.push()
            self._extra.push(self.used)
        n = self.n
        r_in = self._r_pix.dev
        if r_dense is not None:
            if self._in:
                self._r_pix.np[:] = r_dense
                self._r_pix.push()
            else:
                r_in = wp.array(np.ascontiguousarray(r_dense, np.float64), dtype=wp.float64, device=self.device,
                                copy=False)
        rad, room, pix = self._outputs()
        if self._out is None:  # the CPU: the kernel writes the returned arrays (wrapped, not copied)
            outs = [wp.array(a, dtype=dt, device=self.device, copy=False)
                    for a, dt in ((rad, wp.float32), (room, wp.float32), (pix, wp.uint8))]
        else:
            outs = [o.dev for o in self._out]
        m = self._m
        px = self._px["ldr" if ldr else "hdr"]

        def launch(lo: int, hi: int) -> None:
            wp.launch(compose_kernel, dim=hi - lo, device=self.device,
                      inputs=[lo, int(ldr), px, self._rows, self._bary, self._shade.dev, r_in, self._r_flag.dev,
                              int(r_dense is not None), self._slot.dev, self._extra.dev, m["dE_v"].dev,
                              m["add_v"].dev, self._tab, self._grid, self._rtab, self._exposure, *outs])

        split(launch, n)
        wp.synchronize_device(self.device)
        self._dirty = False
        if r_dense is not None and self._in:
            self._r_pix.np.fill(0)
            self._r_pix.push()
        if self._out is not None:
            for o, a in zip(self._out, (rad, room, pix)):
                o.pull()
                a[...] = o.np
            self._slot.pull()  # the kernel cleared them
        return rad, room, pix
