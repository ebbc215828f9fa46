"""The sunlit floor's level from the penumbra of its own sun patch (issue 34 item 4; docs/unseen.md "photosun110").

Where the sun clips the photo, the sunlit level itself is not in the photo, and photo light fitted it through the
walls' albedo, which measures rho_wall x rho_floor x sun: the sun came out with the albedo's scale to about its
power 2.6 (docs "photosun34b", "photo109"). The penumbra holds the level unclipped. The sun's 0.53 deg disk seen
past an opening's edge from a floor point d metres away spans d tan(0.265 deg) either side of the edge (2-4 px in
these photos), and a pixel there reads

    L = L_sh + s A,   A = rho E_sun cos / pi (the sunlit step), s = the pixel's share of the disk

with L_sh the shadow level beside it. s is geometry (lighting.sun.SunLight.disk_through, averaged over the pixel's
footprint: a box pixel); the pixels below the clip give A, the clipped ones bound it from below. The shadow level
is the mean of the unclipped s = 0 pixels of the same surface outside the band and within SHADOW_WINDOW / 2 px (the
floor's texture varies).

The estimated direction was fitted with a hard edge to the clipped outline, whose split lies inside the ramp, and
the calibrated camera is a pixel or so off: a ramp 2-4 px wide misplaced by a pixel reads a step off by 2x or
more. So the direction is moved (Nelder-Mead, a few tenths of a degree at most) with A to fit the ramp's own
shape; the direction kept by the rest of the product is not changed.

Constants (none fitted to a room): CLIP = 250 (an 8-bit level at or above it in any channel is taken as clipped:
the response's top levels are where its inverse is steepest and a floor's grain clips one channel first),
BAND = 4 px about the modelled penumbra, NEAR_MESH = 8 px kept off the meshes' own shadows (their edges are the
centre's ray only in SunLight), SUB = 3 (3 x 3 rays per pixel), MIN_RAMP = 50 unclipped ramp pixels, MAX_MOVE_DEG
= 1 (a move beyond it means the ramp is not the opening's penumbra).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lighting.sources import luminance

CLIP = 250
BAND = 4
NEAR_MESH = 8
SHADOW_WINDOW = 21
SUB = 3
MIN_RAMP = 50
MAX_MOVE_DEG = 1.0


@dataclass
class SunlitStep:
    """The sunlit step A (3,) (radiance: rho E_sun cos / pi on the quad), the shadow level (3,) next to the ramp,
    the quad, the direction the ramp was fitted with (3,), its move from the given one (deg) and pixel counts."""

    quad: int
    step: np.ndarray
    shadow: np.ndarray
    direction: np.ndarray
    moved_deg: float
    n_ramp: int
    n_clipped: int
    shadow_irradiance: np.ndarray | None = None  # (3,) the gathered irradiance/pi under the shadow level (given E)

    @property
    def lit(self) -> np.ndarray:
        """The sunlit level (3,): shadow + step."""
        return self.shadow + self.step

    def report(self) -> dict:
        return {"quad": self.quad, "step": [round(float(v), 5) for v in self.step],
                "shadow": [round(float(v), 5) for v in self.shadow], "lit": [round(float(v), 5) for v in self.lit],
                "moved_deg": round(self.moved_deg, 3), "ramp_pixels": self.n_ramp, "clipped_pixels": self.n_clipped}


def _dir(az: float, el: float) -> np.ndarray:
    return np.array([np.cos(el) * np.cos(az), np.sin(el), np.cos(el) * np.sin(az)])


def footprint_points(camera, idx: np.ndarray, c0: np.ndarray, n: np.ndarray, sub: int = SUB) -> np.ndarray:
    """(N, sub*sub, 3) points where sub x sub rays through each pixel idx (flat, row-major) meet the plane
    (c0, n): the pixel's footprint on the surface."""
    offs = (np.arange(sub) + 0.5) / sub - 0.5
    ou, ov = np.meshgrid(offs, offs)
    u = (idx % camera.width)[:, None] + ou.reshape(1, -1)
    v = (idx // camera.width)[:, None] + ov.reshape(1, -1)
    pix = np.stack([u, v, np.ones_like(u)], -1).reshape(-1, 3)
    d = (pix @ np.linalg.inv(camera.K).T) @ camera.R
    C = camera.centre
    t = ((np.asarray(c0, np.float64) - C) @ n) / (d @ n)
    return (C + d * t[:, None]).reshape(len(idx), sub * sub, 3)


def _clad(s: np.ndarray, rise: np.ndarray, clipped: np.ndarray) -> tuple[float, float]:
    """(A, cost): the step A that minimises sum |rise - A s| over the unclipped pixels plus sum max(0, rise - A s) over
    the clipped ones (their rise is at least what they read): censored least absolute deviations (Powell's CLAD), exact
    as a weighted median of rise / s with weights s. A clip censors the top of a textured floor's spread first, so a
    least-squares fit of the unclipped pixels alone reads low; the median is not moved by it. A leaves out the pixels
    with s <= 0.02 (their ratio is noise); the cost counts them. (NaN, inf) with fewer than 5 unclipped pixels."""
    m = s > 0.02
    if (m & ~clipped).sum() < 5:
        return float("nan"), float("inf")
    r, w, c = rise[m] / s[m], s[m], clipped[m]
    o = np.argsort(r)
    r, w, c = r[o], w[o], c[o]
    wu, wc = np.where(c, 0.0, w), np.where(c, w, 0.0)
    below_u = np.cumsum(wu)
    slope = below_u - (wu.sum() - below_u) - (wc.sum() - np.cumsum(wc))  # the cost's slope just above each r
    A = float(r[int(np.argmax(slope >= 0))])
    P = A * s  # the cost over every pixel, those at s <= 0.02 too (else a move that empties the toe would pay less)
    return A, float(np.sum(np.abs(rise - P)[~clipped]) + np.sum(np.maximum(rise - P, 0.0)[clipped]))


def sunlit_step(light_of, camera, photo: np.ndarray, L_b: np.ndarray, pix_quad: np.ndarray, pix_pos: np.ndarray,
                recv: np.ndarray, quad: int, plane: tuple[np.ndarray, np.ndarray], d: np.ndarray,
                move: bool = True, E: np.ndarray | None = None) -> SunlitStep | None:
    """The sunlit step of `quad` from its penumbra (module docstring).

    light_of(d): a lighting.sun.SunLight for the unit direction d (the room's openings and occluder); camera: the
    photo's (recon.camera.Camera); photo (N,3) uint8 and L_b (N,3) its radiance, N = H*W row-major; pix_quad (N,)
    the quad each pixel sees (-1 none); pix_pos (N,3) the point it sees; recv (N,) the pixels the model may read;
    plane = (a corner, the unit normal) of the quad; d the sun's unit direction. move: fit the direction's small
    move with the step (False: the direction as given). None when the quad shows fewer than MIN_RAMP unclipped
    penumbra pixels, the fit moves the direction more than MAX_MOVE_DEG or gives no positive step. E (N,3): an
    irradiance/pi per pixel (the model's indirect); the step then holds its mean over the same shadow pixels as the
    shadow level (shadow_irradiance: the shadow side's reflectivity is shadow / shadow_irradiance)."""
    from scipy.ndimage import binary_dilation, uniform_filter
    from scipy.optimize import minimize

    H, W = camera.height, camera.width
    c0, n = (np.asarray(x, np.float64) for x in plane)
    photo = np.asarray(photo).reshape(-1, 3)
    clip = np.any(photo >= CLIP, axis=1)
    on = np.flatnonzero((pix_quad == quad) & recv)
    if len(on) < MIN_RAMP:
        return None
    L0 = light_of(d)
    pts_c = np.asarray(pix_pos, np.float64)[on]
    s_c = L0.disk_through(pts_c)
    vis = L0.visibility(pts_c, np.repeat(n[None], len(on), 0)) > 0
    blocked = np.zeros(H * W, bool)
    blocked[on[(s_c > 0.5) & ~vis]] = True  # the opening passes the sun, a mesh blocks it
    near_mesh = binary_dilation(blocked.reshape(H, W), iterations=NEAR_MESH).reshape(-1)
    band = np.zeros(H * W, bool)
    band[on[(s_c > 1e-6) & (s_c < 1 - 1e-6)]] = True
    band = binary_dilation(band.reshape(H, W), iterations=BAND).reshape(-1)
    dark = np.zeros(H * W, bool)
    dark[on[(s_c <= 1e-6) & ~clip[on]]] = True
    dark &= ~near_mesh & ~band  # off the band: the given direction's penumbra may be a pixel or two off
    den = uniform_filter(dark.astype(np.float64).reshape(H, W), SHADOW_WINDOW).reshape(-1)
    sel = on[band[on] & ~near_mesh[on] & (den[on] > 0.02)]
    if len(sel) < MIN_RAMP:
        return None
    L_b = np.asarray(L_b, np.float64)
    L_sh = np.stack([uniform_filter(np.where(dark, L_b[:, c], 0.0).reshape(H, W), SHADOW_WINDOW).reshape(-1)[sel]
                     for c in range(3)], -1) / den[sel, None]
    pts = footprint_points(camera, sel, c0, n).reshape(-1, 3)
    lum, lsh, cl = luminance(L_b[sel]), luminance(L_sh), clip[sel]
    az0, el0 = float(np.arctan2(d[2], d[0])), float(np.arcsin(np.clip(d[1], -1, 1)))

    def share(dd):
        return light_of(dd).disk_through(pts).reshape(len(sel), -1).mean(1)

    x = np.zeros(2)
    if move:
        res = minimize(lambda a: _clad(share(_dir(az0 + a[0], el0 + a[1])), lum - lsh, cl)[1], x,
                       method="Nelder-Mead", options={"initial_simplex": [[0, 0], [2e-3, 0], [0, 2e-3]],
                                                      "xatol": 2e-5, "fatol": 1e-12, "maxiter": 120})
        x = res.x
    dd = _dir(az0 + x[0], el0 + x[1])
    moved = float(np.degrees(np.arccos(np.clip(dd @ (d / np.linalg.norm(d)), -1.0, 1.0))))
    s = share(dd)
    u = ~cl & (s > 0.02)
    A = _clad(s, lum - lsh, cl)[0]
    if not np.isfinite(A) or A <= 0 or u.sum() < MIN_RAMP or moved > MAX_MOVE_DEG:
        return None
    # the colour: the same per channel (a channel clips where the luminance's any-channel test says so)
    Ac = np.array([_clad(s, L_b[sel, c] - L_sh[:, c], cl)[0] for c in range(3)])
    if not np.all(np.isfinite(Ac)) or np.any(Ac <= 0):
        return None
    Ac *= A / float(luminance(Ac))
    E_sh = None
    if E is not None:
        E = np.asarray(E, np.float64)
        E_sh = np.median(np.stack([uniform_filter(np.where(dark, E[:, c], 0.0).reshape(H, W), SHADOW_WINDOW)
                                   .reshape(-1)[sel] for c in range(3)], -1) / den[sel, None], axis=0)
    return SunlitStep(int(quad), Ac, np.median(L_sh, axis=0), dd, moved, int(u.sum()), int(cl.sum()), E_sh)
