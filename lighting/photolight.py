"""Radiance mesh from the photo alone: no probe, no declared response, no declared emitters (issue 19).

The scene model gives the geometry, the camera and which quads emit (role window / lamp); the
photo gives everything else, read through the camera's response where the folder measures it:

* **Response.** The camera's, where the folder has it: the scene's declared camera_response, else
  the one recovered from its probe bracket (lighting.hdr.calibrate_response, as captured light
  recovers it; the bracket's images are used for nothing else: the light still comes from the photo
  alone). Otherwise the standard sRGB curve (IEC 61966-2-1), optionally raised to `gamma_scale` (the
  response prior varied by the sensitivity bench). Radiance is linear / exposure_time, in the
  response's arbitrary units. A measured response matters twice: the camera curves of the
  unseen rooms differ from sRGB by up to 1.5x in linear ratio between level 40 and level 160
  (docs/unseen.md), which the object's light, read off walls at other levels, inherits; and the walls'
  albedo can be read off the interreflections only through the response's slope (below).
* **Photo-seen patches** (at least `min_pixels` pixels, fewer than `clipped_share` of them clipped)
  take the photo's mean radiance over all their pixels, a clipped one at the radiance its level
  reads (lighting.radiance.photo_radiance with clipped_share): one clipped pixel of a window seen
  through no longer throws away the rest of its patch, as it must in captured light, which has
  the probe to fall back on. Except on an emitter quad whose seen pixels mostly clip: there the
  unclipped pixels are the border's, mixed with the frame, and a patch with any clipped pixel
  stays unknown.
* **Emitters** are the model's window / lamp quads and the clipped regions of the photo (patches
  most of whose pixels have a channel at 255). A patch the photo measures keeps its measured
  radiance; the rest of each emitter quad (mostly clipped, or out of view) is one unknown RGB
  radiance per quad, at least as bright as its clipped pixels show and as the photo measures the
  quad's seen patches (a lower bound: the model's window or lamp is one uniform emitter), so a
  window the photo shows is never fitted darker than it looks, and never to 0.
* **A sun's patches out of view.** Given the sun's share per patch (`sunlit`: the engine passes it once
  the sun stage has found a sun in the photo, and fits again), every sunlit patch the photo does not see,
  on a surface whose sunlit part in view clips, joins that clipped region at its share of the region's
  radiance: the walls see the whole sunlit patch, and gathered as an unlit reflector its out-of-view part
  left its light to the part in view (sun_107: a third out of view, the sun 2.3x; docs/unseen.md "photo108").
* **Inverse radiosity.** The walls show how strong the unknown emitters are: a photo-seen wall
  patch i has radiance L_i = rho * E_i with E_i = sum_j G_ij B_j (irradiance/pi through the
  transfers G, visibility included) and the wall albedo prior rho. Unseen patches gather,
  B_U = r (G_U. B), solved exactly: (I - r G_UU) B_U = r G_U,rest B_rest, r each unseen patch's
  reflectivity: that of its own surface where the photo shows part of it (one material per quad:
  least squares of L against E over its seen patches, refitted with the unseen light; the walls' albedo on a wall
  not in view), `ceiling_albedo` on a ceiling not in view, the unseen reflectivity prior elsewhere
  (`unseen_by_surface`, lighting.photoalbedo; off: the prior everywhere).
* **The walls' albedo** is the one that best explains every seen surface's interreflections
  (lighting.photoalbedo) when the response is measured (`fit_albedo` None, the default; True / False
  force it), else the prior. The fit compares the light a patch gets from the other surfaces with
  the light it gets from the emitters, two parts of one photo at different levels, so its answer is
  only as good as the response's slope between those levels: with the sRGB assumption it biases the
  albedo low (window_101 0.49 for a true 0.61), with the measured one it recovers it (docs/unseen.md).
  E_i is then linear in the unknown radiances e; e is the bounded linear least-squares solution
  (scipy.optimize.lsq_linear, e >= the lower bound) of rho E_i(e) = L_i, with residuals
  relative to L_i (every wall counts alike, not only the bright ones near the window).
* **Every seen surface, each with its own albedo** (`surface_albedos`; by default only when the walls'
  fit leaves a modelled window or lamp dark, _dark_emitters: always on, it tells lamps apart in two
  unseen lamp rooms but costs the shared lamps_room 7.7 -> 11.8 rmse_object, docs/unseen.md "Photo
  light"; lamps_104's walls leave its ceiling lamp dark, docs/unseen.md "photo34, tenth round"). The walls (vertical room
  surfaces) carry the albedo prior, which sets the light's scale. The floor, the ceiling and each
  furniture face join the fit with an RGB albedo of their own, the per-channel median of L / E over
  their patches under the current light, alternated with the emitters' fit (a few rounds). The
  walls see the lamps from afar and at grazing angles, so from them alone a small bright lamp and
  a large dim one trade light freely; the pool of light on the floor under a lamp, the glow on the
  ceiling around it and the lit table top tell them apart (their albedo being free, they add the
  light's shape, not its scale, and their colour goes into their albedo, not into the lamps').
* **Uncertainty.** The covariance sigma^2 (J^T J)^-1 of the fit (sigma^2 from the residual, J the
  weighted design matrix) gives a 1-sigma relative error per emitter; it ignores the priors. The
  fit is repeated with the wall albedo prior at -20 % / +20 % (the transfers' solve is shared, so
  this costs two more small fits) and each emitter's relative change is reported beside it;
  bench/bench_photolight.py measures all three priors' effect on the composite.

Priors (not fitted to any scene): wall albedo 0.55 (a mid-grey painted wall; interior walls are
0.5-0.8, floors 0.2-0.5, so one grey value for every seen surface; with a measured response it is
only the fit's start), unseen reflectivity 0.5 (the seed's value for patches nobody sees), an unseen
ceiling 0.8 (white ceiling paint; the lighting handbooks' recommended ceiling reflectance is
0.7-0.9), response sRGB where the folder measures none.
"""
from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from lighting.photoalbedo import (fit_albedo_scale, seen_transfers as _seen_transfers, solve_emitters as _solve_emitters,
                                  walls_test)
from lighting.radiance import GATHERED, PHOTO, photo_radiance
from lighting.sources import luminance
from lighting.tonemap import CameraResponse
from recon.patches import PatchMesh

log = logging.getLogger("photoar")

FITTED = 3  # origin code: emitter radiance estimated by inverse radiosity (next to radiance.PHOTO/PROBE/GATHERED)
EMITTER_ROLES = ("window", "lamp", "ceiling_lamp", "point_lamp")


@dataclass
class PhotoPriors:
    """What photo light assumes instead of measuring (module docstring)."""

    wall_albedo: float = 0.55  # reflectivity of every photo-seen surface in the inverse radiosity
    unseen_reflectivity: float = 0.5  # reflectivity of patches the photo does not see
    gamma_scale: float = 1.0  # linear = sRGB^-1(z) ** gamma_scale (1: plain sRGB)
    min_pixels: int = 4  # unclipped pixels a patch needs to be measured by the photo
    clipped_share: float = 0.5  # a patch is a clipped region when this share of its pixels is clipped
    relative: bool = True  # residuals relative to each wall's radiance (False: absolute)
    surface_albedos: bool | None = None  # floors, ceilings, furniture join the fit, each with its own albedo;
    # None: when the walls alone leave a modelled window or lamp dark (_dark_emitters), True / False: always / never
    fit_albedo: bool | None = None  # the walls' albedo from the interreflections (lighting.photoalbedo);
    # None: when the response is measured (it needs the response's slope), True / False: always / never
    albedo_test: bool = False  # with fit_albedo: the walls keep the prior unless the interreflections explain the photo
    # significantly better with their own albedo (lighting.photoalbedo.walls_test, a likelihood-ratio test at 95 %);
    # Opt-in: lamps_110 27.7 -> 7.9 rmse_object, window_room 1.86 -> 1.51, but sun_108 energy 0.566 -> 0.163 and
    # lamps_109 19.2 -> 20.9 (docs/unseen.md "photolamp111"); off: the fitted albedo always
    unseen_by_surface: bool = True  # unseen patches reflect as their surface's seen part (lighting.photoalbedo)
    ceiling_albedo: float = 0.8  # an unseen ceiling's reflectivity with unseen_by_surface / fit_albedo
    bounce_levels: int = 0  # > 0: the photo holds this many light bounces, the camera hit one of them (a path
    # tracer's cap: the benchmark truth 4); the interreflection fit then gathers one level less (lighting.photoalbedo)
    # 0: every bounce (a camera). Opt-in: measured in docs/unseen.md "photosun34b", not the default
    sun_bounces: bool = False  # once a sun is found in the photo, the fit again with bounce_levels = the engine's
    # bounce count and the sun's strength by the same bounce model (app.engine.Engine._sun_bounces). Opt-in:
    # measured in docs/unseen.md "photo109" (the bright sun rooms right, the darker ones too dark), not the default
    sun_ramp: bool = True  # once a sun is found in the photo, a clipped sunlit surface takes the level its penumbra
    # measures (lighting.sunramp) where that is below the walls' fit's (app.engine.Engine._sunlit_levels; docs/unseen.md
    # "photosun111"). Pinned always (photosun110's opt-in) it set the bright sun rooms right and the darker ones and the
    # shared sun_room worse, where the fit reads the level lower than the penumbra; False: the walls' fit's level


@dataclass
class PhotoLight:
    """Per-patch radiance (P,3), reflectivity (P,3), origin (P,) int8 and the report of the fit."""

    radiance: np.ndarray
    reflectivity: np.ndarray
    origin: np.ndarray
    report: dict = field(default_factory=dict)


def srgb_response(exposure_time: float = 1.0, gamma_scale: float = 1.0) -> CameraResponse:
    """The sRGB transfer curve as a CameraResponse (linear X in [0,1] <-> 8-bit), optionally with the
    linear value raised to `gamma_scale` (X = srgb^-1(z) ** gamma_scale)."""
    if not gamma_scale > 0 or not exposure_time > 0:
        raise ValueError(f"gamma_scale and exposure_time must be positive, got {gamma_scale}, {exposure_time}")
    z = np.arange(256) / 255.0
    inv = np.where(z <= 0.04045, z / 12.92, ((z + 0.055) / 1.055) ** 2.4) ** gamma_scale
    xl = z ** (1.0 / gamma_scale)  # forward samples at X = i/255
    fwd = np.where(xl <= 0.0031308, 12.92 * xl, 1.055 * xl ** (1 / 2.4) - 0.055)
    src = "sRGB (assumed)" if gamma_scale == 1 else f"sRGB^-1 ** {gamma_scale} (assumed)"
    return PhotoResponse(np.tile(fwd, (3, 1)), np.tile(inv, (3, 1)), exposure_time, source=src)


@dataclass
class PhotoResponse(CameraResponse):
    """The response photo light reads the photo through: where it came from (`source`, for the report)
    and whether it was measured (declared or recovered from a bracket) or assumed (sRGB)."""

    source: str = "sRGB (assumed)"
    measured: bool = False


def recover_response(files: list[Path], times: list[float]) -> np.ndarray:
    """The inverse response (256,3) recovered from a probe bracket (lighting.hdr.calibrate_response): seconds
    (docs/benchmarks.md), so the engine caches it per bracket (app.stages.precompute.cached_probe_response)."""
    from lighting import hdr
    from recon.io import read_image_rgb

    return hdr.calibrate_response([read_image_rgb(f) for f in files], times)


def photo_response(scene, priors: PhotoPriors | None = None,
                   recover: Callable[[list[Path], list[float]], np.ndarray] = recover_response) -> PhotoResponse:
    """The response photo light reads the photo through (module docstring): the scene's declared
    camera_response, else the one recovered from its probe bracket (measured; recover(files, times): the
    inverse response (256,3), e.g. a cached recover_response), else sRGB (`gamma_scale`). A bracket that
    cannot be read or fitted falls back to sRGB with a warning."""
    priors = priors or PhotoPriors()
    t = scene.camera.exposure_time
    r = scene.response
    if isinstance(r, PhotoResponse):  # a scene photo light prepared before: measured stays, sRGB takes gamma_scale
        return r if r.measured else srgb_response(t, priors.gamma_scale)
    if r is not None:
        return PhotoResponse(r.forward_table, r.inverse_table, t, source="declared (scene.json camera_response)",
                             measured=True)
    root = Path(scene.root) if getattr(scene, "root", None) is not None else None
    sj = _scene_json(root) if root is not None else {}
    if "light_probe" in sj:
        from lighting import hdr

        try:
            g = recover(*hdr.probe_bracket(root / "scene.json", sj))
            return PhotoResponse(hdr.forward_table(g), g.T, t, source="recovered from the probe bracket",
                                 measured=True)
        except (OSError, ValueError, RuntimeError) as e:
            log.warning("photo light: %s: the probe bracket gives no response (%s); the photo is read as sRGB",
                        root / "scene.json", e)
    return srgb_response(t, priors.gamma_scale)


def _scene_json(root) -> dict:
    import json

    try:
        return json.loads((root / "scene.json").read_text())
    except (OSError, ValueError):
        return {}


def prepare_scene(scene, priors: PhotoPriors | None = None,
                  recover: Callable[[list[Path], list[float]], np.ndarray] = recover_response):
    """The scene as photo light sees it: its response (photo_response, `recover` its bracket's), window / lamp
    quads marked as emitters (placeholder radiance 1, replaced by the fit) and nothing declared. Returns (scene,
    declared): declared = {quad name: emitted_radiance} from scene.json, for the report only."""
    priors = priors or PhotoPriors()
    declared = {q.name: [float(v) for v in q.emission] for q in scene.quads if np.any(q.emission > 0)}
    quads = [dataclasses.replace(q, emission=np.ones(3) if q.role in EMITTER_ROLES else np.zeros(3),
                                 albedo=np.zeros(3), texture=None)  # declared albedos are not used
             for q in scene.quads]
    return dataclasses.replace(scene, quads=quads, response=photo_response(scene, priors, recover)), declared


def _unknown_groups(patches: PatchMesh, photo_count: np.ndarray, clipped: np.ndarray
                    ) -> tuple[np.ndarray, list[int]]:
    """Group id (P,) of each patch whose radiance the fit must find (-1: none) and the quad of each
    group: the unmeasured patches of an emitter quad, and the clipped patches of any other quad."""
    unknown = (patches.is_emitter & (photo_count == 0)) | clipped
    quads = sorted(set(patches.quad[unknown].tolist()))
    lut = {q: g for g, q in enumerate(quads)}
    group = np.full(patches.n_patches, -1, np.int64)
    group[unknown] = [lut[q] for q in patches.quad[unknown]]
    return group, quads


def fit_photo_light(patches: PatchMesh, G: np.ndarray, pix_patch: np.ndarray, photo: np.ndarray,
                    response: CameraResponse, priors: PhotoPriors | None = None,
                    quad_names: list[str] | None = None, where: str = "photo",
                    quad_roles: list[str] | None = None, sunlit: np.ndarray | None = None,
                    pinned: dict[int, np.ndarray] | None = None) -> PhotoLight:
    """The radiance mesh from the photo (module docstring).

    patches: the scene's patch mesh, is_emitter = the model's window / lamp quads; G (P,P) patch ->
    patch transfers (irradiance/pi at the row patch per unit radiance of the column patch);
    pix_patch (N,) patch seen by each photo pixel (-1 none); photo (N,3) uint8; `where` names the
    photo in errors; quad_roles (one per quad, None: all "room") pick the walls the fit reads (the
    vertical room surfaces; floors, ceilings and furniture vary too much in albedo for one prior).
    sunlit (P,) in [0, 1], optional: each patch's share in a sun found in this photo (app.stages.sun.SunSetup
    .sun_share); the sunlit patches the photo does not see, on a quad whose seen sunlit part clips, join that
    quad's clipped region (the same surface in the same sun: the region's radiance times their share) instead of
    gathering as unlit reflectors (_sunlit_unseen).
    pinned {quad: (3,) radiance}, optional: clipped regions whose level was measured from the photo's own pixels
    (lighting.sunramp: the sunlit floor's penumbra). Their patches (and the sunlit ones out of view that join them, at
    their share) take that radiance as known, not fitted: the walls' albedo is then read against a measured source,
    which takes the fit's scale out of the region (docs/unseen.md "photosun110").
    Raises ValueError when the photo holds no usable light.
    """
    pr = priors or PhotoPriors()
    if not 0 < pr.wall_albedo < 1 or not 0 <= pr.unseen_reflectivity < 1 or not 0 <= pr.ceiling_albedo < 1:
        raise ValueError(f"wall albedo must be in (0, 1), unseen reflectivity and ceiling albedo in [0, 1), got "
                         f"{pr.wall_albedo}, {pr.unseen_reflectivity}, {pr.ceiling_albedo}")
    measured_response = bool(getattr(response, "measured", False))
    if pr.fit_albedo is None:
        pr = dataclasses.replace(pr, fit_albedo=measured_response)
    P = patches.n_patches
    photo = np.asarray(photo).reshape(-1, 3)
    L_b = response.to_radiance(photo)
    sat = np.any(photo >= 255, axis=1)
    rad, count = photo_radiance(pix_patch, L_b, sat, P, pr.clipped_share)
    ok = pix_patch >= 0
    n_all = np.bincount(pix_patch[ok], minlength=P)
    n_sat = np.bincount(pix_patch[ok & sat], minlength=P)
    emit = patches.is_emitter
    # an emitter quad the photo shows mostly clipped (a window seen bright): the unclipped pixels of
    # its patches are the frame's mixed border pixels, so any clipped pixel leaves the patch unknown
    nq = int(patches.quad.max()) + 1
    q_all = np.maximum(np.bincount(patches.quad, n_all, nq), 1)
    q_sat = np.bincount(patches.quad, n_sat, nq) >= pr.clipped_share * q_all
    strict = emit & q_sat[patches.quad] & (n_sat > 0)
    rad_s, _ = photo_radiance(pix_patch, L_b, sat, P)
    rad[strict], count[strict] = rad_s[strict], 0
    clipped = ~emit & (n_sat >= pr.min_pixels) & (n_sat >= pr.clipped_share * np.maximum(n_all, 1))
    measured = (count >= pr.min_pixels) & ~clipped
    joined = _sunlit_unseen(patches.quad, clipped, measured, emit, sunlit)
    clipped |= joined
    pin, pin_rad = _pinned(patches.quad, clipped, emit, joined, sunlit, pinned)
    count = np.where(measured, count, 0)
    seen_wall = measured & ~emit
    if not seen_wall.any():
        raise ValueError(f"{where}: no surface of the room model is seen unclipped in the photo; photo light "
                         f"needs the walls")
    wall_lum = luminance(rad[seen_wall])
    wall_px = ok & seen_wall[np.maximum(pix_patch, 0)]
    if np.median(photo[wall_px].max(axis=1)) < 1:
        raise ValueError(f"{where}: the photo is black where it sees the walls (median wall level < 1): "
                         f"no light to read")
    group, gquads = _unknown_groups(patches, count, clipped & ~pin)
    ng = len(gquads)
    modelled = np.array([emit[patches.quad == q].any() for q in gquads], bool)  # a modelled window or lamp, per
    # group (else a clipped region: a surface the sun or a lamp lights)
    names = [(quad_names[q] if quad_names else f"quad {q}") + ("" if m else " (clipped region)")
             for q, m in zip(gquads, modelled)]

    # ---- sets: S measured walls, K measured emitters, X unknown (grouped), U unseen reflectors
    S = np.flatnonzero(seen_wall)
    roles = np.array(quad_roles if quad_roles is not None else ["room"] * (patches.quad.max() + 1))
    vertical = (roles[patches.quad] == "room") & (np.abs(patches.normal[:, 1]) < 0.5)
    fit_on = vertical[S]
    if fit_on.sum() < max(ng, 1):
        fit_on[:] = True  # no wall in view: every seen surface carries the prior (warned below)
    K = np.flatnonzero(measured & emit)
    X = np.flatnonzero(group >= 0)
    U = np.flatnonzero(~measured & (group < 0) & ~emit & ~pin)
    known = np.zeros((P, 3))
    known[S], known[K], known[pin] = rad[S], rad[K], pin_rad[pin]
    M = np.zeros((P, ng))
    M[X, group[X]] = 1.0
    jf = joined & ~pin
    if sunlit is not None and jf.any():  # a partly sunlit patch out of view: its sunlit share of the region's
        M[jf, group[jf]] = np.clip(np.asarray(sunlit, np.float64)[jf], 0.0, 1.0)
    G64 = np.asarray(G, np.float64)
    r = pr.unseen_reflectivity
    L_S = rad[S]
    w = 1.0 / np.maximum(wall_lum, 1e-3 * np.median(wall_lum))  # relative residuals
    if not pr.relative:
        w = np.full(len(S), 1.0 / np.median(wall_lum))
    w_all, w = w, np.where(fit_on, w, 0.0)
    lower, lower_from = _lower_bounds(patches, group, gquads, pix_patch, L_b, sat, rad, count, measured)
    qS = patches.quad[S]
    rho = np.full(3, pr.wall_albedo)  # the walls' albedo (RGB)
    albedo_fit, albedo_test = None, None
    r_patch = np.full(P, r)  # reflectivity of each unseen patch
    if pr.fit_albedo or pr.unseen_by_surface:
        ceiling_q = (roles == "room") & (np.bincount(patches.quad, patches.normal[:, 1], nq)
                                         < -0.5 * np.maximum(np.bincount(patches.quad, minlength=nq), 1))
        fa_args = (G64, S, U, known, M, qS, fit_on, w_all, L_S, lower, patches.quad, vertical, ceiling_q, pr)
        fa_kw = dict(levels=pr.bounce_levels, reflected=~modelled)
        albedo_fit = fit_albedo_scale(*fa_args, fit_walls=pr.fit_albedo, **fa_kw)
        if pr.fit_albedo and pr.albedo_test:  # the walls' albedo from the interreflections only where they tell it
            held = fit_albedo_scale(*fa_args, fit_walls=False, **fa_kw)
            stat, thr = walls_test(albedo_fit, held)
            albedo_test = {"likelihood_ratio": round(stat, 2), "threshold": round(thr, 2),
                           "walls_fitted": [round(float(v), 4) for v in albedo_fit.wall],
                           "kept": "interreflections" if stat > thr else "prior"}
            if stat <= thr:
                albedo_fit = held
        rho, r_patch = albedo_fit.wall, albedo_fit.r_patch
        a0, A1, Z0, Z1 = albedo_fit.a0, albedo_fit.A1, albedo_fit.Z0, albedo_fit.Z1
    else:
        a0, A1, Z0, Z1 = _seen_transfers(G64, S, U, r_patch, known, M)
    reach = np.abs(w[:, None] * A1).sum(0)
    unresolved = reach <= 1e-9 * max(reach.max(initial=0.0), 1e-300)  # no measured wall sees the group
    J1 = w[:, None] * A1
    rho_rows = np.broadcast_to(rho, (len(S), 3))
    e, std, at_bound, resid = _solve_emitters(J1, w, L_S, a0, rho_rows, lower, unresolved)
    # the prior's share of the uncertainty: the same fit with the walls' albedo -20 % / +20 %
    e_lo = _solve_emitters(J1, w, L_S, a0, 0.8 * rho_rows, lower, unresolved)[0]
    e_hi = _solve_emitters(J1, w, L_S, a0, np.minimum(1.2 * rho_rows, 0.999), lower, unresolved)[0]
    rho_S = np.array(rho_rows)
    rho = float(luminance(rho))
    dark = _dark_emitters(at_bound, lower, unresolved, modelled)
    surface = bool(dark) if pr.surface_albedos is None else pr.surface_albedos
    if surface and not fit_on.all():
        rho_S, e = _surface_albedos(qS, fit_on, A1, w_all, L_S, a0, rho, lower, unresolved)
        e_lo = _surface_albedos(qS, fit_on, A1, w_all, L_S, a0, 0.8 * rho, lower, unresolved)[1]
        e_hi = _surface_albedos(qS, fit_on, A1, w_all, L_S, a0, min(1.2 * rho, 0.999), lower, unresolved)[1]
        at_bound = e <= lower * (1 + 1e-9) + 1e-300
        res = w[:, None] * (rho * (a0 + A1 @ e) - L_S)
        resid = np.sqrt(np.mean(res[fit_on] ** 2, axis=0))
    if not np.all(np.isfinite(e)):
        raise RuntimeError(f"{where}: inverse radiosity gave non-finite emitter radiance")

    B = known + M @ e
    if len(U):
        B[U] = Z0 + Z1 @ e
    E = G64 @ B
    with np.errstate(divide="ignore", invalid="ignore"):
        refl = np.where(E > 0, B / E, r)
    refl = np.clip(np.nan_to_num(refl, nan=r), 0.0, 1.0)
    refl[U] = r_patch[U, None]
    refl[emit | (group >= 0) | pin] = 0.0
    origin = np.full(P, GATHERED, np.int8)
    origin[measured] = PHOTO
    origin[X] = FITTED
    origin[pin] = FITTED  # a clipped region still, its radiance measured (lighting.sunramp) rather than fitted
    if not np.all(np.isfinite(B)) or not np.all(np.isfinite(refl)):
        raise RuntimeError(f"{where}: photo light gave non-finite patch radiance")

    # ---- what the walls say about the prior: the albedo they imply with the fitted light
    E_S = a0 + A1 @ e
    implied = float(np.median(luminance(L_S[fit_on]) / np.maximum(luminance(E_S[fit_on]), 1e-300)))
    emitters = []
    for g, nm in enumerate(names):
        lum = float(luminance(e[g]))
        rel = float(luminance(np.nan_to_num(std[g])) / lum) if lum > 0 else float("nan")
        prior = [float(luminance(x[g])) / lum - 1 if lum > 0 else float("nan") for x in (e_lo, e_hi)]
        emitters.append({"name": nm, "radiance": [round(float(v), 4) for v in e[g]],
                         "lower_bound": [round(float(v), 4) for v in lower[g]], "lower_bound_from": lower_from[g],
                         "rel_std": None if not np.isfinite(rel) else round(rel, 4),
                         "albedo_prior_x0.8_x1.2": [None if not np.isfinite(v) else round(v, 4) for v in prior],
                         "at_lower_bound": bool(at_bound[g].all()), "seen_by_walls": bool(not unresolved[g]),
                         "patches": int(np.sum(group == g))})
    report = {"response": getattr(response, "source", "given by the caller"),
              "wall_albedo_prior": pr.wall_albedo, "unseen_reflectivity": r,
              "wall_albedo": [round(float(v), 4) for v in rho_S[fit_on][0]] if fit_on.any() else None,
              "wall_albedo_from": ("interreflections" if pr.fit_albedo and albedo_fit is not None
                                   and (albedo_test is None or albedo_test["kept"] == "interreflections") else "prior"),
              "wall_albedo_test": albedo_test,
              "albedo_fit": albedo_fit.report(quad_names) if albedo_fit is not None else None,
              "implied_wall_albedo": round(implied, 4),
              "fit_rms_relative_residual": [round(float(v), 4) for v in resid],
              "fitted_on": "walls" if not fit_on.all() or vertical[S].all() else "all seen surfaces (no wall in view)",
              "surface_albedos": {(quad_names[q] if quad_names else f"quad {q}"):
                                  [round(float(v), 3) for v in rho_S[qS == q][0]]
                                  for q in np.unique(qS[~fit_on])} if surface else {},
              "surface_albedos_for": [names[g] for g in dark] if surface and pr.surface_albedos is None else [],
              "wall_patches_fitted": int(fit_on.sum()), "patches_from_photo": int(measured.sum()), "patches_gathered": int(len(U)),
              "patches_fitted": int(len(X)), "clipped_region_patches": int(clipped.sum()),
              "sunlit_unseen_joined": int(joined.sum()),
              "emitters": emitters}
    if pin.any():
        report["pinned_regions"] = {(quad_names[q] if quad_names else f"quad {q}"): [round(float(v), 4) for v in
                                                                                      pinned[q]]
                                    for q in sorted(pinned) if (pin & (patches.quad == q)).any()}
    _warn(report, where, emit, count, quiet=sunlit is not None)
    return PhotoLight(B, refl, origin, report)


def _sunlit_unseen(quad: np.ndarray, clipped: np.ndarray, measured: np.ndarray, emit: np.ndarray,
                   sunlit: np.ndarray | None) -> np.ndarray:
    """(P,) bool: the sunlit patches (`sunlit` (P,) their sun share > 0) the photo does not see, on a quad with a
    clipped region: they join it. The walls see the whole sunlit patch; gathered as unlit reflectors, its out-of-view part
    leaves the walls' light from it to the part in view, whose fitted radiance rises to make up for it (sun_107:
    a third of the sunlit floor out of view, docs/unseen.md "photo108"). None: no patch joins."""
    if sunlit is None:
        return np.zeros(len(quad), bool)
    region_q = np.unique(quad[clipped])
    return (np.asarray(sunlit) > 0) & ~clipped & ~measured & ~emit & np.isin(quad, region_q)


def _pinned(quad: np.ndarray, clipped: np.ndarray, emit: np.ndarray, joined: np.ndarray, sunlit: np.ndarray | None,
            pinned: dict[int, np.ndarray] | None) -> tuple[np.ndarray, np.ndarray]:
    """((P,) bool, (P,3)): the clipped patches of the `pinned` quads and their known radiance (a joined patch out of
    view at its sunlit share); none without `pinned`."""
    pin, rad = np.zeros(len(quad), bool), np.zeros((len(quad), 3))
    for q, v in (pinned or {}).items():
        m = clipped & ~emit & (quad == int(q))
        pin |= m
        rad[m] = np.asarray(v, np.float64)
    if sunlit is not None and (pin & joined).any():
        j = pin & joined
        rad[j] *= np.clip(np.asarray(sunlit, np.float64)[j], 0.0, 1.0)[:, None]
    return pin, rad


def _lower_bounds(patches: PatchMesh, group: np.ndarray, gquads: list[int], pix_patch: np.ndarray,
                  L_b: np.ndarray, sat: np.ndarray, rad: np.ndarray, count: np.ndarray, measured: np.ndarray
                  ) -> tuple[np.ndarray, list[str]]:
    """(G,3) the least radiance each unknown group can have: the median of its own clipped pixels
    (a clipped pixel reads its true value or less), and for an emitter quad also the mean radiance
    the photo measures on the quad's measured patches (the model's window or lamp is one uniform
    emitter, so its unmeasured rest, out of view or clipped, is at least as bright as what the photo
    shows of it). 0 where neither exists (an emitter wholly out of view, with no clipped pixel).
    Also where each bound comes from: "clipped pixels", "the photo's view of it" or "none"."""
    ng = len(gquads)
    lower, source = np.zeros((ng, 3)), ["none"] * ng
    ok = pix_patch >= 0
    gpix = np.where(ok, group[np.maximum(pix_patch, 0)], -1)
    for g, q in enumerate(gquads):
        px = np.flatnonzero(sat & (gpix == g))
        if len(px):
            lower[g], source[g] = np.median(L_b[px], axis=0), "clipped pixels"
        seen = measured & (patches.quad == q) & patches.is_emitter
        if seen.any():
            shown = np.average(rad[seen], axis=0, weights=count[seen])
            if luminance(shown) > luminance(lower[g]):
                source[g] = "the photo's view of it"
            lower[g] = np.maximum(lower[g], shown)
    return lower, source


def _dark_emitters(at_bound: np.ndarray, lower: np.ndarray, unresolved: np.ndarray, modelled: np.ndarray
                   ) -> list[int]:
    """The groups the walls' fit leaves dark: a modelled window or lamp (`modelled`, per group) that the
    walls see, fitted at its lower bound 0 (no clipped pixel, not in view). The model says it emits, so
    a dark fit is the walls' fit trading its light to another emitter: the walls see the lamps from afar
    and at grazing angles, where a small bright lamp and a large dim one light them alike (module
    docstring, "Every seen surface"). Then the floor, the ceiling and the furniture join the fit."""
    return [g for g in range(len(modelled)) if modelled[g] and not unresolved[g] and at_bound[g].all()
            and not np.any(lower[g] > 0)]


def _surface_albedos(quad: np.ndarray, wall: np.ndarray, A1: np.ndarray, w: np.ndarray, L_S: np.ndarray,
                     a0: np.ndarray, rho: float, lower: np.ndarray, unresolved: np.ndarray, rounds: int = 8
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Albedo (|S|,3) of every seen surface and the emitters' radiance (G,3) fitted on them all.

    The walls carry the albedo prior rho; each other seen quad (floor, ceiling, furniture: too
    varied for one prior) gets its own RGB albedo, the per-channel median of L / E over its patches
    under the current light. Alternated a few rounds with the emitters' bounded fit over all seen
    surfaces, which gives the emitters' relative strengths; each round the light is then scaled,
    per channel, to fit the walls alone (least squares of rho (a0 + s A1 e) = L over the walls), so
    that the walls and the prior still set its scale and colour, as in the walls-only fit."""
    rho_S = np.full((len(wall), 3), rho)
    w_wall = np.where(wall, w, 0.0)
    e = np.zeros((A1.shape[1], 3))
    for _ in range(rounds):
        e = _solve_emitters(w[:, None] * A1, w, L_S, a0, rho_S, lower, unresolved)[0]
        for c in range(3):  # the walls' scale
            p, y = rho * (A1 @ e[:, c]), L_S[:, c] - rho * a0[:, c]
            den = np.sum((w_wall * p) ** 2)
            if den > 0:
                e[:, c] = np.maximum(e[:, c] * max(np.sum(w_wall ** 2 * p * y) / den, 0.0), lower[:, c])
        ratio = L_S / np.maximum(a0 + A1 @ e, 1e-300)
        new = rho_S.copy()
        for q in np.unique(quad[~wall]):
            m = (quad == q) & ~wall
            new[m] = np.clip(np.median(ratio[m], axis=0), 0.02, 0.95)
        if np.allclose(new, rho_S, rtol=1e-3):
            break
        rho_S = new
    return rho_S, e


def _rgb(v) -> str:
    """An RGB radiance for a warning line: '(r, g, b)' to 3 significant digits."""
    return "({:.3g}, {:.3g}, {:.3g})".format(*v)


def _warn(report: dict, where: str, emit: np.ndarray, count: np.ndarray, quiet: bool = False) -> None:
    """Warnings for the hard cases: no light source, emitters the walls cannot pin down, walls darker
    than the albedo prior allows; into report["warnings"], and logged (at debug level when `quiet`: the fit
    made again with a sun's patches, whose first fit has logged them)."""
    ems = report["emitters"]
    report["warnings"] = warn = []
    if not emit.any() and report["clipped_region_patches"] == 0:
        warn.append("no window or lamp in the model and no clipped region in the photo: the room is lit "
                    "only by the light its surfaces show")
    elif not ems and not (emit & (count > 0)).any():
        warn.append("no emitter is seen in the photo or needs fitting")
    for em in ems:
        if not em["seen_by_walls"]:
            warn.append(f"{em['name']}: no wall seen in the photo receives its light; radiance set to its "
                        f"lower bound {em['lower_bound']}")
        elif em["at_lower_bound"] and em.get("lower_bound_from") == "the photo's view of it":
            warn.append(f"{em['name']}: kept as bright as the photo shows it ({_rgb(em['lower_bound'])}); the "
                        f"walls alone would make it dimmer (they look darker than a wall of albedo "
                        f"{report['wall_albedo_prior']} lit by it)")
        elif em["at_lower_bound"] and any(v > 0 for v in em["lower_bound"]):
            warn.append(f"{em['name']}: kept at the least brightness its clipped pixels allow "
                        f"({_rgb(em['lower_bound'])}); the walls alone would make it dimmer: they look darker than the "
                        f"albedo prior {report['wall_albedo_prior']} allows (implied {report['implied_wall_albedo']})")
        elif em["at_lower_bound"]:
            warn.append(f"{em['name']}: left dark (radiance 0): the photo does not show it and the walls "
                        f"need no light from it")
        elif em["rel_std"] is not None and em["rel_std"] > 0.5:
            warn.append(f"{em['name']}: radiance poorly determined by the walls (+-{100 * em['rel_std']:.0f} %)")
    if report["fitted_on"] != "walls":
        warn.append("no wall of the room is seen: the albedo prior is applied to floor, ceiling and furniture")
    if report["implied_wall_albedo"] < 0.5 * report["wall_albedo_prior"]:
        warn.append(f"the walls are darker than the albedo prior {report['wall_albedo_prior']} allows: with the "
                    f"light the photo shows they reflect only {report['implied_wall_albedo']}")
    for msg in warn:  # quiet: the fit again with the sun's patches (its first fit has said the same in words)
        (log.debug if quiet else log.warning)("photo light: %s: %s", where, msg)
