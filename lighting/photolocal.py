"""Photo light at the object: the fitted emitters' strength read off the surfaces around it (issue 34).

Photo light (lighting.photolight) fits the unknown emitters' radiance to the walls at one albedo
prior. The walls see the lamps and windows from afar and at grazing angles, so the fit gets the
light's overall scale from the prior but can split it wrongly between emitters (lamps_101: a small
lamp 2 m from the object 1.8x too bright, relative to the room's response scale, the lamps above the
walls too dim), and then the object, lit mostly by one of them, is far too bright while the walls
fit well.

The photo also shows the surfaces right around the object: the floor it stands on, the wall behind
it. Each surface is one material, so its albedo, read as the median over its measured patches of
L / E (photo radiance over the fitted light's irradiance, luminance), is the same near the object as
elsewhere on it; what the photo shows there, L / rho, is the irradiance the object's surroundings
really receive. The fitted light's irradiance there is E_ind + E_dir: E_ind from the room's patches
(measured by the photo, or gathered from them: no emitter scale in it) and E_dir from the emitters.
The one scale s of the emitters that best gives L / rho over the patches around the object (least
squares, patches weighted alike) is the local emitter scale: the object's emitter light is
multiplied by it. Where the fit is right s is ~1; the walls' fit, the albedo prior and the room's
light away from the object are left as they are.

Which patches: measured by the photo (not emitters, not clipped, not lit by the sun: a sunlit patch's
L holds the sun, which E does not), closer to the object's centre than the nearest scaled emitter
patch is, and than NEAR_RADII bounding radii: the fit's error is a wrong split between emitters, so
its factor changes where the mix of emitters lighting a point changes, on the scale of the distance
to them; within that distance the surfaces see the emitters much as the object does. The widest
such disc is taken because a surface's texture varies by ~10 % from place to place (a floor brighter
by 10 % over half a metre around the object in window_101) and only a wide disc averages it out. At
least MIN_PATCHES patches (the nearest, when fewer lie within): one patch is no measurement. The
scale is clamped to
[1/MAX_SCALE, MAX_SCALE]: beyond that the patches say more about the model (a missing lamp, a surface
modelled wrong) than about the emitters' split.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lighting.sources import luminance

NEAR_RADII = 3.0  # "near" in object bounding radii: the same reach as the near-field light (issue 34 item 3)
MIN_PATCHES = 12  # patches averaged at least: a dozen average a surface texture's ~10 % patch-to-patch spread
MAX_SCALE = 3.0  # the most the patches around the object may change its emitter light, either way


@dataclass
class LocalLight:
    """The measured patches around which the emitter scale is read: centres (n,3) m, the irradiance the
    photo shows there target = L / rho (n,), the fitted light's emitter part e_dir and the rest e_ind (n,),
    all luminance of irradiance/pi in the fit's units."""

    centre: np.ndarray
    target: np.ndarray
    e_dir: np.ndarray
    e_ind: np.ndarray
    emitter_centre: np.ndarray  # (m,3) m, the centres of the emitter patches the scale multiplies

    def scale(self, centre: np.ndarray, radius: float) -> float:
        """The emitter scale at an object with bounding sphere (centre, radius m); 1 with no patch."""
        if len(self.centre) == 0 or len(self.emitter_centre) == 0:
            return 1.0
        centre = np.asarray(centre, np.float64)
        reach = max(NEAR_RADII * max(radius, 0.0), float(np.linalg.norm(self.emitter_centre - centre, axis=1).min()))
        d = np.linalg.norm(self.centre - centre, axis=1)
        near = np.flatnonzero(d <= reach)
        if len(near) < MIN_PATCHES:
            near = np.argsort(d)[:MIN_PATCHES]
        den = float(np.sum(self.e_dir[near] ** 2))
        if not den > 0:
            return 1.0
        s = float(np.sum(self.e_dir[near] * (self.target[near] - self.e_ind[near])) / den)
        return float(np.clip(s, 1.0 / MAX_SCALE, MAX_SCALE)) if np.isfinite(s) else 1.0


def local_light(patches, G: np.ndarray, B: np.ndarray, emitters: np.ndarray, measured: np.ndarray,
                exclude: np.ndarray | None = None) -> LocalLight:
    """The LocalLight of a photo-lit room (module docstring).

    patches: the PatchMesh (quad, centre); G (P,P) transfers (irradiance/pi per unit radiance); B (P,3)
    the room's radiance the object gathers; emitters (P,) bool the patches whose light the scale
    multiplies; measured (P,) bool the patches the photo measures; exclude (P,) bool patches to leave
    out (sunlit ones)."""
    P = patches.n_patches
    use = np.asarray(measured, bool) & ~np.asarray(emitters, bool)
    if exclude is not None:
        use &= ~np.asarray(exclude, bool)
    idx = np.flatnonzero(use)
    if len(idx) == 0:
        z = np.zeros(0)
        return LocalLight(np.zeros((0, 3)), z, z, z, np.zeros((0, 3)))
    Bl = luminance(np.asarray(B, np.float64))
    Gi = np.asarray(G[idx], np.float64)
    em = np.zeros(P, bool)
    em[np.asarray(emitters, bool)] = True
    e_dir = Gi[:, em] @ Bl[em]
    e_ind = Gi[:, ~em] @ Bl[~em]
    E = e_dir + e_ind
    L = Bl[idx]
    ok = E > 0
    ratio = np.where(ok, L / np.where(ok, E, 1.0), np.nan)
    rho = np.full(len(idx), np.nan)
    quad = patches.quad[idx]
    for q in np.unique(quad):
        m = (quad == q) & ok
        if m.sum() >= MIN_PATCHES:  # a surface with too few measured patches has no albedo of its own here
            rho[quad == q] = np.median(ratio[m])
    keep = np.isfinite(rho) & (rho > 0) & ok
    return LocalLight(patches.centre[idx[keep]], L[keep] / rho[keep], e_dir[keep], e_ind[keep], patches.centre[em])
