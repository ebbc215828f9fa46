"""Compose stage: the second order and the compositing of a frame (HDR or LDR), on what changed.

The reference it reproduces (compose_reference, the numpy form), per pixel x of the frame:

  dE_v   = G_v dB                              second order at receiver vertices, dB = the change of
                                               patch radiance (shadowed patches, object light) (P,3)
  add_x  = rho_x (R_x + sum_k b_k dE_v[row_k])  object light R plus second order, irradiance/pi
  HDR:   room = max(L_b - shadow + add, 0), shadow = L_b x clip(O_x / E_x, 0, 1) on the listed
         pixels (and the filled ones); levels = T(room) where shadow or add is non-zero, else T(L_b)
  LDR:   levels = I_b - O_x (+ T(max(L_b + add, 0)) - T(L_b)); room = T^-1(clip(levels, 0, 255))
  pixel  = (1 - c) levels + c T(L_obj)  (c: the object's coverage), or T of the radiance mix where
         either side clips

Per scene (ComposeStage.__init__): the pixel -> receiver-vertex rows restricted to receiver pixels,
T(L_b), the LDR frame's unchanged radiance, G_v in the kernel's buffer (a frame sums over the
changed patches only), the response's breakpoints and lookup grids, and every per-pixel
buffer at full-frame size (kernels.pixel_compose.Compositor). Per frame the host work is a few launches:
the shadows' share computed and written at pix_sel by a kernel (share_kernel), the fill's values
written by the fill's own kernel straight into the frame's shadow buffer, a sparse object light
scattered by a kernel (scatter_kernel), the sun's pixels and the object's
coverage into a compact table (one row per pixel that has them); one kernel (one launch per core)
then composes every pixel and leaves the per-frame buffers cleared as it reads them (no reset pass).
The returned images are arrays the kernel writes directly on the CPU (no copy), from a small pool
reused only once nothing outside the stage references them: the Frame owns them while it lives (a
kept frame, Engine.refine's, never changes under the next one), and a drag allocates no new ones.

Object light R comes in one of three forms (the object-light stage's choice):
  - an (N,3) array: dense, every pixel (the engine's form today);
  - (idx, values): per-pixel values at pixels idx, zero elsewhere;
  - (R_v, idx, values): R_v (Vr,3) at receiver vertices, interpolated at receiver pixels like the
    transfers, and per-pixel values at pixels idx in its place there.
"""
from __future__ import annotations

import functools
from typing import Callable

import numpy as np

from app import runtime
from kernels.pixel_compose import EX_COV, EX_OBJ, EX_SUN, Compositor, changed_patches
from lighting.transfer import intensity_transfers

# the second order's least work per launch in (receiver vertex, changed patch) pairs (~1.7 ns each on this CPU), or
# None: its launches cut by the receiver vertices' count (app.runtime.split's min_items), which leaves a drag frame's
# ~1200 vertices at 1/3 one launch on the rendering thread (4-7 ms of CPU in sun_room). 1 << 17 (~0.2 ms a part) cuts
# them in two, the same bytes; on the loaded machine that was slower (sun_room 21.1 -> 25.4 ms wall median, +0.7 ms of
# CPU: docs/benchmarks.md, "glue111"), so it stays off until an idle machine measures it
SO_MIN_PAIRS: int | None = None

FillFn = Callable[..., "np.ndarray | None"]  # fill(known, values, missing, out=None): the values at missing,
# or, given out (an image-sized wp.array of vec3d), written there at their pixels (returns None)


class ComposeStage:
    """One scene's compose stage: per-scene tables and per-frame buffers, made once."""

    def __init__(self, *, L_b: np.ndarray, L_b_levels: np.ndarray, E_x: np.ndarray, rho_x: np.ndarray,
                 recv_pix: np.ndarray, pix_rows: np.ndarray, pix_bary: np.ndarray, photo: np.ndarray, response,
                 G_v: np.ndarray, E_v: np.ndarray, recv_vert: np.ndarray, patches, shape: tuple[int, int],
                 device: str):
        """Arrays are the engine's per-scene ones (N = H*W pixels; Vr receiver vertices; P patches):
        L_b, L_b_levels, E_x, rho_x (N,3); recv_pix (N,) bool; pix_rows (N,3) receiver-vertex rows;
        pix_bary (N,3); photo (H,W,3) uint8; G_v (Vr,P) float32; E_v (Vr,3); patches the PatchMesh."""
        self.H, self.W = shape
        self.L_b, self.E_x, self.rho_x = L_b, E_x, rho_x
        self.response = response
        self.E_v, self.recv_vert, self.patches = E_v, recv_vert, patches
        self.recv_pix, self.pix_rows, self.pix_bary = recv_pix, pix_rows, pix_bary
        self._rho_v = None  # LDR: reflectance at receiver vertices (ldr_weights), made on first use
        self._sun_den = None  # (sun_pix, max(E_x[sun_pix], 1e-12)): _sun_denominator's, per scene
        self.photo_levels = photo.reshape(-1, 3).astype(np.float64)
        rows = np.where(recv_pix[:, None], pix_rows, -1)
        T_Lb = response.to_levels(L_b)
        xs, ys = response.breakpoints()
        still = {"hdr": (L_b_levels, L_b), "ldr": (self.photo_levels, response.to_radiance(self.photo_levels))}
        self.split = functools.partial(runtime.split, device=device)  # the two-core split (app.runtime)
        self.k = Compositor(L_b, T_Lb, rho_x, rows, pix_bary, still, xs, ys, response.exposure_time, G_v, device,
                            E_x=E_x)

    # ------------------------------------------------------------------ second order
    def second_order(self, dB: np.ndarray, more: np.ndarray | None = None, dE_more: np.ndarray | None = None
                     ) -> np.ndarray:
        """dE_v (Vr,3) float64: the change of patch radiance dB (P,3) passed on once to the receiver
        vertices, G_v dB over the changed patches only, plus `more` (P,3) passed on the same way and
        `dE_more` (Vr,3) added as it is (the sun's later bounces, already at the receiver vertices).
        Returns the stage's own buffer (valid until the next frame)."""
        dB = dB if more is None else dB + more
        nz = changed_patches(dB)
        split = self.split if SO_MIN_PAIRS is None else \
            functools.partial(self.split, min_items=-(-SO_MIN_PAIRS // max(len(nz), 1)))  # cut by work (SO_MIN_PAIRS)
        self.k.second_order(dB, split, nz)
        if dE_more is not None:
            self.k.dE_v += dE_more
            self.k.add_v += dE_more
        return self.k.dE_v

    # ------------------------------------------------------------------ LDR weights
    def ldr_weights(self, W_v: np.ndarray) -> np.ndarray:
        """Intensity transfers S_ij (Vr,S,3) in levels at receiver vertices (fig. 13) from the
        radiance transfers W_v (Vr,S,3)."""
        rho_v = self.rho_v
        return intensity_transfers(rho_v * self.E_v, rho_v[:, None, :] * W_v, self.response.to_levels)

    @property
    def rho_v(self) -> np.ndarray:
        """(Vr,3) reflectance at receiver vertices: the barycentric-weighted mean of the receiver pixels'
        rho_x around each vertex, the patch albedo where no pixel sees it (per scene, made once)."""
        if self._rho_v is None:
            pm = self.patches
            rp = np.flatnonzero(self.recv_pix)
            rows, bary = self.pix_rows[rp], self.pix_bary[rp].astype(np.float64)
            n = len(self.recv_vert)
            num = np.zeros((n, 3))
            den = np.zeros(n)
            for k in range(3):
                np.add.at(num, rows[:, k], bary[:, k:k + 1] * self.rho_x[rp])
                np.add.at(den, rows[:, k], bary[:, k])
            vert_patch = np.zeros(len(pm.vert_pos), np.int64)
            vert_patch[pm.tris.ravel()] = np.repeat(pm.tri_patch, 3)
            albedo_v = pm.albedo[vert_patch[self.recv_vert]]
            self._rho_v = np.where(den[:, None] > 0, num / np.maximum(den, 1e-12)[:, None], albedo_v)
        return self._rho_v

    def _sun_denominator(self, sun_pix: np.ndarray) -> np.ndarray:
        """max(E_x, 1e-12) (irradiance/pi) at the sun's pixels sun_pix, (len(sun_pix),3), which a frame's
        sun share divides its loss by: made on the first frame with this sun_pix array (the same object;
        another array makes it anew), as E_x is fixed once the stage is made (the Compositor keeps its
        own copy of it too)."""
        if self._sun_den is None or self._sun_den[0] is not sun_pix:
            self._sun_den = (sun_pix, np.maximum(self.E_x[sun_pix], 1e-12))
        return self._sun_den[1]

    # ------------------------------------------------------------------ compose
    def frame(self, mode: str, pix_sel: np.ndarray, O_pix: np.ndarray, fill_sel: np.ndarray, fill: FillFn,
              R_pix, dE_v: np.ndarray | None, cov: np.ndarray, obj_rad: np.ndarray,
              sun_pix: np.ndarray | None = None, sun_loss: np.ndarray | None = None
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(radiance (H,W,3) float32, pixels (H,W,3) uint8, room (H,W,3) float32) of the frame.

        pix_sel, O_pix: the shadow pass's pixels and their occluded sums (HDR: irradiance/pi, LDR:
        levels); fill_sel and `fill`, which fills a value at fill_sel from known pix_sel values (HDR:
        the occluded share, LDR: O), called as fill(known, values, missing, out=buffer) (FillFn: it
        writes into the stage's image-sized buffer at the pixels); R_pix the object light (module
        docstring: dense, (idx, values) or (R_v, idx, values)); dE_v the second order (None: off); cov
        (H,W) and obj_rad (H,W,3) the object's coverage and radiance; sun_pix, sun_loss (len(sun_pix),3)
        the sun's lost irradiance/pi.
"""
        k, ldr, split = self.k, mode == "ldr", self.split
        k.begin()
        # ---- shadows on the listed pixels (HDR: the share of L_b taken; LDR: the levels taken), then
        # the filled ones from them (disjoint)
        vals = k.shade_from(pix_sel, O_pix, not ldr, split)
        if len(fill_sel):
            fill(pix_sel, vals, fill_sel, out=k.shade_px)  # straight into the frame's shadows
        if sun_loss is not None:  # sun: its occluded share of the (model, where clipped) radiance, written
            # only where the object takes some
            nz = np.flatnonzero(nonzero_rows(sun_loss))
            share = sun_loss[nz] / self._sun_denominator(sun_pix)[nz]
            k.extra[k.rows_for(sun_pix[nz]), EX_SUN:EX_SUN + 3] = np.clip(share, 0.0, 1.0, out=share)
        # ---- object light and second order
        r_dense = None
        add_v = k.add_v
        if dE_v is None:
            k.dE_v[:] = 0.0
        elif dE_v is not k.dE_v:
            k.dE_v[:] = dE_v
        if isinstance(R_pix, np.ndarray):  # dense
            r_dense = R_pix
            add_v[:] = k.dE_v
        else:
            if len(R_pix) == 3:
                R_v, idx, vals = R_pix
                np.add(k.dE_v, R_v, out=add_v)
            else:
                idx, vals = R_pix
                add_v[:] = k.dE_v
            idx = np.asarray(idx)
            if idx.dtype == bool:
                idx = np.flatnonzero(idx)
            k.scatter("r", idx, np.broadcast_to(vals, (len(idx), 3)), split)
        # ---- the object
        c = cov.reshape(-1)
        on = np.flatnonzero(c > 0)
        rows = k.rows_for(on)
        k.extra[rows, EX_COV] = c[on]
        k.extra[rows, EX_OBJ:EX_OBJ + 3] = obj_rad.reshape(-1, 3)[on]
        rad, room, pix = k.run(ldr, r_dense, split)
        H, W = self.H, self.W
        return rad.reshape(H, W, 3), pix.reshape(H, W, 3), room.reshape(H, W, 3)


def nonzero_rows(a: np.ndarray) -> np.ndarray:
    """(n,) bool: the rows of a (n,3) that hold a non-zero (a.any(1), NaN counting as non-zero): three
    column compares, ~7x faster than numpy's reduction over an axis of three (0.03 against 0.23 ms for
    the sun's 15k pixels a frame)."""
    return (a[:, 0] != 0) | (a[:, 1] != 0) | (a[:, 2] != 0)


def compose_reference(mode: str, L_b, L_b_levels, E_x, rho_x, recv_pix, pix_rows, pix_bary, photo, response,
                      pix_sel, O_pix, fill_sel, fill: FillFn, R_pix, dE_v, cov, obj_rad, sun_pix=None,
                      sun_loss=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The numpy form of the second order's interpolation and the compose step, over full-frame
    arrays: the specification ComposeStage.frame reproduces (tests/kernels/test_compose.py,
    bench/bench_compose.py). R_pix dense (N,3); returns (radiance, pixels, room) (N,3)."""
    resp = response
    dE_x = np.zeros_like(L_b)
    if dE_v is not None:
        rp = recv_pix
        dE_x[rp] = np.einsum("nk,nkc->nc", pix_bary[rp], dE_v[pix_rows[rp]])
    add = rho_x * (R_pix + dE_x)  # light gained (object reflection) or lost second-hand
    if mode == "hdr":
        shadow = np.zeros_like(L_b)
        with np.errstate(divide="ignore", invalid="ignore"):
            frac = np.where(E_x[pix_sel] > 0, np.clip(O_pix / E_x[pix_sel], 0.0, 1.0), 0.0)
        shadow[pix_sel] = L_b[pix_sel] * frac
        shadow[fill_sel] = L_b[fill_sel] * fill(pix_sel, frac, fill_sel)
        if sun_loss is not None:
            shadow[sun_pix] += L_b[sun_pix] * np.clip(sun_loss / np.maximum(E_x[sun_pix], 1e-12), 0.0, 1.0)
        room = np.maximum(L_b - shadow + add, 0.0)
        changed = np.flatnonzero((shadow != 0).any(1) | (add != 0).any(1))
        room_levels = L_b_levels.copy()
        room_levels[changed] = resp.to_levels(room[changed])
    else:
        levels = photo.reshape(-1, 3).astype(np.float64)
        levels[pix_sel] -= O_pix
        levels[fill_sel] -= fill(pix_sel, O_pix, fill_sel)
        if sun_loss is not None:
            share = np.clip(sun_loss / np.maximum(E_x[sun_pix], 1e-12), 0.0, 1.0)
            levels[sun_pix] += resp.to_levels(L_b[sun_pix] * (1 - share)) - resp.to_levels(L_b[sun_pix])
        extra = np.abs(add).sum(1) > 0
        levels[extra] += resp.to_levels(np.maximum(L_b[extra] + add[extra], 0.0)) - resp.to_levels(L_b[extra])
        room_levels = np.clip(levels, 0, 255)
        room = resp.to_radiance(room_levels)
    c = cov.reshape(-1, 1)
    obj_rad = obj_rad.reshape(-1, 3)
    on = np.flatnonzero(c[:, 0] > 0)
    radiance = (1 - c) * room + c * obj_rad
    levels = (1 - c) * room_levels
    obj_levels = resp.to_levels(obj_rad[on])
    levels[on] += c[on] * obj_levels
    # where the object or the room behind it clips a level is only a floor: mix in radiance there
    edge = on[((obj_levels >= 255) | (room_levels[on] >= 255)).any(1) & (c[on, 0] < 1)]
    levels[edge] = resp.to_levels(radiance[edge])
    pixels = np.clip(np.rint(levels), 0, 255).astype(np.uint8)
    return radiance.astype(np.float32), pixels, room.astype(np.float32)
