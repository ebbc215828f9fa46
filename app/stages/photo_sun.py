"""Photo light in a sunny room: the object lit by the sun the estimate found (issue 34, item 4).

Under photo light (lighting.photolight) the sunlit floor clips, so the fit makes it an emitter
group (a "clipped region") whose radiance is whatever the walls ask of it, held at least at the
white level: a floor as bright as the photo's white, not as the sun makes it. Once the sun is
estimated from the photo (app.stages.sun.SunSetup), those patches are reflectors lit by it. The
object then gathers the room as under captured light (SunSetup.object_radiance, sunlit_patches):
a sunlit patch the photo does not measure (origin not PHOTO: its pixels mostly clip) takes the
model's radiance rho x (E_ind + E_sun) (rho its surface's reflectivity, E_ind = G_c B_src the light
it gathers from the room, E_sun the sun's share on it), and every sunlit reflector is gathered
exactly (lighting.irradiance.RoomLight.gather_exactly), not through the 0.25 m SH9 volume.
A separate call so that the captured-light path in app/stages/sun.py stays as it is.
"""
from __future__ import annotations

import logging

import numpy as np

from lighting.radiance import PHOTO
from lighting.sources import luminance

log = logging.getLogger("photoar")


def photo_object_light(sun, pre, B_src: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(B_lit (P,3), near (P,) bool) for photo light: the radiance the object gathers the room from,
    and the sunlit reflectors it gathers exactly (module docstring). `sun` is the engine's SunSetup
    after apply(); without a sun that lights a surface, (B_src, none)."""
    P = len(B_src)
    none = np.zeros(P, bool)
    if sun.lighting != "photo" or not sun.on or pre.origin is None:
        return B_src, none
    pm, E_sun = sun.patches, sun.patch_light()
    lit = E_sun.any(1) & ~pm.is_emitter
    model = lit & (np.asarray(pre.origin) != PHOTO) & (luminance(pm.albedo) > 0)
    out = np.array(B_src, np.float64, copy=True)
    if model.any():
        E_ind = pre.G_c[model].astype(np.float64) @ np.asarray(B_src, np.float64)
        out[model] = pm.albedo[model] * (E_ind + E_sun[model])
        log.info("photo light: the sun lights %d patches the photo shows clipped; the object sees them as "
                 "lit by the estimated sun (mean luminance %.3g, the photo's clipped value %.3g)",
                 int(model.sum()), float(luminance(out[model]).mean()),
                 float(luminance(np.asarray(B_src)[model]).mean()))
    return out, lit
