"""Radiance mesh from captured light: the mirror-ball probe, the photo, and gathering (seed sec. 4.2).

The seed builds its radiance mesh from HDR captures: every patch of the scene model gets the
radiance that the light probe (or the photo) sees on it; reflectivity is the photo's radiance
divided by the irradiance gathered from that mesh; patches that neither the probe nor the photo
sees gather irradiance and reflect it with reflectivity 0.5. Emitters are simply bright patches:
those brighter than a perfect reflector could be under the light they gather (`emitters`).

Per patch, in order of preference:
1. the photo: the mean of the camera-seen, unsaturated pixels on the patch (at least
   `min_pixels`; the photo is far finer than the probe and seen from the model's own camera);
2. the probe: probe pixels are traced from the ball's surface (the reflection point, not its
   centre) into the model; each patch gets the flux the probe saw on it divided by the solid
   angle it subtends at the ball. Tiny bright patches (a ceiling lamp covering one or two probe
   pixels) would be smeared over their neighbours by a plain per-pixel assignment, so each
   pixel's flux is split over the patches its sub-rays hit in proportion to their current
   radiance estimate and re-estimated a few times (an EM / Richardson-Lucy deconvolution over
   the pixel footprints). The sum over a pixel is conserved, so the split never invents light;
3. gathering: B = 0.5 * (G @ B) over the transfers G, iterated.

Units: radiance in the scene's units (W/(m^2 sr) up to one scale), reflectivity in [0, 1].
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from kernels.raycast import cast_rays
from kernels.visibility import Occluder
from lighting import probe as probe_maps
from recon.patches import PatchMesh

log = logging.getLogger("photoar")

PHOTO, PROBE, GATHERED = 2, 1, 0


@dataclass
class RadianceMesh:
    """Per-patch radiance (P,3), reflectivity (P,3) and where each radiance came from (P,) int8
    (PHOTO, PROBE or GATHERED)."""

    radiance: np.ndarray
    reflectivity: np.ndarray
    origin: np.ndarray
    emitter: np.ndarray | None = None  # (P,) bool: patches that emit (see `emitters`)

    def summary(self) -> dict:
        out = {"patches_from_photo": int(np.sum(self.origin == PHOTO)),
               "patches_from_probe": int(np.sum(self.origin == PROBE)),
               "patches_gathered": int(np.sum(self.origin == GATHERED))}
        if self.emitter is not None:
            out["emitter_patches"] = int(np.sum(self.emitter))
        return out


def probe_rays(light_probe: dict, size: int, rim: float = probe_maps.DEFAULT_RIM, sub: int = 3
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Rays leaving the mirror ball of a scene's `light_probe` block (scene.json), sub x sub per pixel.

    Returns origins (N,3) m (points on the ball), dirs (N,3) unit world directions, solid angle
    (N,) sr per ray, pixel (N,) flat index into the size x size probe image; only valid pixels.
    """
    R = np.asarray(light_probe["camera"]["R"], np.float64)
    centre = np.asarray(light_probe["centre"], np.float64)
    radius = float(light_probe["radius"])
    _, sa, valid = probe_maps.mirrorball_directions(size, R.T, rim)
    c, r = (size - 1) / 2, size / 2
    offs = (np.arange(sub) + 0.5) / sub - 0.5
    vv, uu = np.nonzero(valid)
    oy, ox = np.meshgrid(offs, offs, indexing="ij")
    U = (uu[:, None, None] + ox[None]).reshape(-1)
    V = (vv[:, None, None] + oy[None]).reshape(-1)
    x, y = (U - c) / r, (V - c) / r
    n_cam = np.stack([x, y, -np.sqrt(np.clip(1 - x * x - y * y, 0, 1))], -1)
    w_cam = np.array([0.0, 0.0, 1.0]) - 2 * n_cam[:, 2:3] * n_cam
    dirs = w_cam @ R  # R^T applied to row vectors
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    origins = centre + radius * (n_cam @ R)
    pixel = np.repeat(vv * size + uu, sub * sub)
    return origins, dirs, np.repeat(sa[vv, uu] / sub ** 2, sub * sub), pixel


def project_probe(patches: PatchMesh, mesh: Occluder, light_probe: dict, probe_rgb: np.ndarray,
                  iterations: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """Per-patch radiance (P,3) seen by the probe and the solid angle (P,) sr it covers.

    probe_rgb: (S,S,3) HDR mirror-ball image in the probe camera's pixel grid; mesh: the model
    the camera sees (emitters included). Patches the probe does not see get radiance 0, omega 0.
    """
    S = probe_rgb.shape[0]
    origins, dirs, sa, pixel = probe_rays(light_probe, S)
    tri, _, _ = cast_rays(mesh, origins, dirs)
    hit = tri >= 0
    patch, sa, pixel = patches.tri_patch[tri[hit]], sa[hit], pixel[hit]
    P = patches.n_patches
    flux = sa[:, None] * probe_rgb.reshape(-1, 3).astype(np.float64)[pixel]  # (N,3) per sub-ray
    omega = np.bincount(patch, sa, minlength=P)
    seen = omega > 0
    pix_flux = np.zeros((S * probe_rgb.shape[1], 3))
    np.add.at(pix_flux, pixel, flux)
    # start from the plain average, then split each pixel's flux by the current estimate
    rad = _sum_per_patch(patch, flux, P)
    rad[seen] /= omega[seen, None]
    for _ in range(iterations):
        w = sa[:, None] * rad[patch]  # expected flux of each sub-ray
        norm = np.zeros_like(pix_flux)
        np.add.at(norm, pixel, w)
        new = _sum_per_patch(patch, w / np.maximum(norm[pixel], 1e-30) * pix_flux[pixel], P)
        rad[seen] = new[seen] / omega[seen, None]
    return rad, omega


def _sum_per_patch(patch: np.ndarray, values: np.ndarray, n_patches: int) -> np.ndarray:
    """Sums (P,3) of values (N,3) grouped by patch id (N,)."""
    return np.stack([np.bincount(patch, values[:, c], minlength=n_patches) for c in range(3)], axis=1)


def photo_radiance(pix_patch: np.ndarray, L_b: np.ndarray, saturated: np.ndarray, n_patches: int,
                   clipped_share: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Mean photo radiance (P,3) per patch and the count (P,) of pixels it is measured from.

    pix_patch (H*W,) patch per pixel (-1 none); L_b (H*W,3) radiance; saturated (H*W,) bool.
    clipped_share None (captured light): the mean over the unsaturated pixels, and a patch with any
    saturated pixel gets count 0 (its radiance is only a lower bound).
    clipped_share s in (0, 1] (photo light, which has no probe to fall back on): a patch fewer than
    s of whose pixels saturate is measured from all its pixels, each saturated one at the radiance
    its clipped level reads (a lower bound of its true value, so the mean is one too, exact where
    nothing clips); count = its pixels. A patch with a share s or more keeps count 0."""
    ok = pix_patch >= 0
    cnt = np.bincount(pix_patch[ok & ~saturated], minlength=n_patches).astype(np.float64)
    sat = np.bincount(pix_patch[ok & saturated], minlength=n_patches)
    rad = np.zeros((n_patches, 3))
    if clipped_share is not None:
        if not 0 < clipped_share <= 1:
            raise ValueError(f"clipped_share must be in (0, 1], got {clipped_share}")
        total = cnt + sat
        for c in range(3):
            rad[:, c] = np.bincount(pix_patch[ok], L_b[ok, c], minlength=n_patches)
        rad /= np.maximum(total, 1)[:, None]
        return rad, np.where(sat < clipped_share * np.maximum(total, 1), total, 0.0)
    good = ok & ~saturated
    for c in range(3):
        rad[:, c] = np.bincount(pix_patch[good], L_b[good, c], minlength=n_patches)
    rad /= np.maximum(cnt, 1)[:, None]
    cnt[sat > 0] = 0
    return rad, cnt


def build_radiance_mesh(G: np.ndarray, probe_rad: np.ndarray, probe_omega: np.ndarray, photo_rad: np.ndarray,
                        photo_count: np.ndarray, is_emitter: np.ndarray | None = None, min_pixels: int = 4,
                        min_omega: float = 1e-6, unseen_reflectivity: float = 0.5, iterations: int = 20
                        ) -> RadianceMesh:
    """Combine photo, probe and gathering (module docstring) into one radiance mesh.

    G (P,P): patch -> patch transfers (irradiance/pi at row patch per unit radiance of column
    patch, visibility included). Reflectivity of measured non-emitting patches is
    L / (G @ L), clipped to [0, 1]; emitters get 0, unseen patches `unseen_reflectivity`.
    Emitters are `is_emitter` where given, else decided from the radiance (`emitters`).
    """
    P = len(G)
    origin = np.full(P, GATHERED, np.int8)
    origin[probe_omega > min_omega] = PROBE
    origin[photo_count >= min_pixels] = PHOTO
    L = np.zeros((P, 3))
    L[origin == PROBE] = probe_rad[origin == PROBE]
    L[origin == PHOTO] = photo_rad[origin == PHOTO]
    unseen = origin == GATHERED
    G64 = np.asarray(G, np.float64)
    if unseen.any():
        for _ in range(iterations):
            L[unseen] = unseen_reflectivity * (G64[unseen] @ L)
    E = G64 @ L
    with np.errstate(divide="ignore", invalid="ignore"):
        rho = np.where(E > 0, L / E, unseen_reflectivity)
    rho = np.clip(np.nan_to_num(rho, nan=unseen_reflectivity), 0.0, 1.0)
    rho[unseen] = unseen_reflectivity
    if not np.all(np.isfinite(L)):
        raise RuntimeError("radiance mesh: non-finite patch radiance (check the probe image)")
    emit = emitters(L, E, origin, G64.sum(1)) if is_emitter is None else np.asarray(is_emitter, bool)
    rho[emit] = 0.0
    return RadianceMesh(L, rho, origin, emit)


def measured_levels(origin: np.ndarray, bounces: int) -> np.ndarray:
    """(P,) int: the bounce level each patch's captured radiance holds (origin: build_radiance_mesh's). The photo
    sees `bounces` reflections; the probe's ball is the probe camera's first, so the room in it holds one less
    (the benchmark truth: a path tracer capped at `bounces` reflections after the camera hit; in sun_110 the probe's
    patches are the known radiosity's B^(3) to 0.97-1.05 and the photo's its B^(4) to 1.00-1.01, in sun_room
    0.975-0.999 and 1.001); a gathered patch reflects the mesh's light once more: `bounces`."""
    return np.where(np.asarray(origin) == PROBE, bounces - 1, bounces)


def emitters(radiance: np.ndarray, gathered: np.ndarray, origin: np.ndarray, openness: np.ndarray) -> np.ndarray:
    """(P,) bool: measured patches brighter than any reflector could be where they are.

    A surface of reflectivity rho reflects rho * E (E = G @ L, irradiance/pi gathered at the
    patch centre from the rest of the mesh); no reflector exceeds rho = 1, so a patch whose
    captured luminance exceeds its gathered luminance emits. This is the seed's "emitters are
    simply bright patches" as a physical bound, with no declared radiance and no role: a window,
    a lamp or a lit screen. Not judged (never emitters): gathered patches (their radiance is 0.5 E
    by construction) and patches whose centre is buried (openness, the sum of the centre's form
    factors, is 1 for a point that sees the closed room over its whole hemisphere; below 1/2 the
    centre lies mostly behind a lamp 2 mm off the ceiling or under a box, and its irradiance says
    nothing about the uncovered rim that the probe or the photo saw).
    """
    from lighting.sources import luminance

    judged = (origin != GATHERED) & (np.asarray(openness) >= 0.5)
    return judged & (luminance(radiance) > luminance(gathered))


# ----------------------------------------------------------------------------- scenes

@dataclass
class CapturedProbe:
    """A scene's merged probe bracket and the camera response recovered from it."""

    radiance: np.ndarray  # (S,S,3) float32, mirror-ball image in the probe camera's grid
    inverse_response: np.ndarray  # (256,3) level -> relative exposure, g(255) = 1
    response: "CameraResponse"
    light_probe: dict  # scene.json's light_probe block (pose, radius, files)


def probe_shadowed(corners: np.ndarray, light_probe: dict, to_sun: np.ndarray, n_side: int = 4) -> np.ndarray:
    """(P,) bool: the patches (corners (P,4,3), m) some of whose n_side x n_side sample points the probe's ball
    (light_probe's centre and radius, m) hides from the sun (to_sun: unit direction towards it). The probe
    is rendered with its ball in the room, so on such a patch it sees the ball's own sun shadow, not the
    sunlit surface the room has without it."""
    c = np.asarray(light_probe["centre"], np.float64)
    r = float(light_probe["radius"])
    d = np.asarray(to_sun, np.float64) / np.linalg.norm(to_sun)
    f = (np.arange(n_side) + 0.5) / n_side
    fu, fv = [a.ravel() for a in np.meshgrid(f, f)]
    c0 = corners[:, 0]
    pts = (c0[:, None] + fu[None, :, None] * (corners[:, 1] - c0)[:, None]
           + fv[None, :, None] * (corners[:, 3] - c0)[:, None])  # (P,S,3)
    oc = c - pts
    t = oc @ d  # distance along the ray to the closest approach to the centre
    miss2 = np.einsum("psk,psk->ps", oc, oc) - t * t
    return ((t > 0) & (miss2 < r * r)).any(1)


def _light_probe(scene) -> tuple[dict, list[Path], list[float]]:
    """The scene's light_probe block (pose checked), its bracket files and exposure times."""
    from lighting import hdr

    files, times, meta = hdr.scene_probe_files(scene.root)
    lp = meta["light_probe"]
    missing = [k for k in ("centre", "radius", "camera") if k not in lp]
    if missing:
        raise ValueError(f"{scene.root / 'scene.json'}: light_probe: missing {missing}; --lighting captured needs "
                         f"the probe's pose and its bracket")
    _check_probe_pose(lp, scene.root / "scene.json")
    return lp, files, times


def _check_probe_pose(lp: dict, path: Path) -> None:
    """The probe pose's fields, checked before any work: centre (3,) m, radius > 0 m, camera.R a
    rotation (det +1); SceneError naming the file and field (never a KeyError deep inside)."""
    from recon.io import SceneError, json_array, json_field

    json_array(lp["centre"], (3,), "light_probe.centre", path)
    if not float(json_array(lp["radius"], (), "light_probe.radius", path)) > 0:
        raise SceneError(f"{path}: field 'light_probe.radius' must be positive")
    R = json_array(json_field(lp["camera"], "R", "light_probe.camera.", path), (3, 3), "light_probe.camera.R", path)
    if not (np.allclose(R @ R.T, np.eye(3), atol=1e-5) and np.linalg.det(R) > 0):
        raise SceneError(f"{path}: field 'light_probe.camera.R' is not a rotation matrix")


def captured_files(scene) -> list[Path]:
    """The bracket files (probe_*.png) of a scene's light probe, in exposure order."""
    return _light_probe(scene)[1]


def load_captured_probe(scene, recover=None) -> CapturedProbe:
    """Merge the scene's probe bracket with a response recovered from the bracket itself: by recover(files,
    times) -> the inverse response (256,3) (the engine's: app.stages.precompute.cached_probe_response, the same
    fit cached per bracket, as photo light's), or, with None, by merge_bracket's own fit."""
    from lighting import hdr
    from recon.io import read_image_rgb
    from recon.response import CameraResponse

    lp, files, times = _light_probe(scene)
    images = [read_image_rgb(f) for f in files]
    try:
        rad, g = hdr.merge_bracket(images, times, None if recover is None else recover(files, times))
    except ValueError as e:
        raise ValueError(f"{scene.root / 'scene.json'}: light_probe bracket: {e}") from None
    response = CameraResponse(hdr.forward_table(g), g.T, scene.camera.exposure_time)
    return CapturedProbe(rad, g, response, lp)


def captured_radiance_mesh(patches: PatchMesh, G: np.ndarray, mesh: Occluder, probe: CapturedProbe, scene,
                           pix_patch: np.ndarray) -> RadianceMesh:
    """The radiance mesh of a scene from its probe and photo (module docstring).

    pix_patch (H*W,): patch seen by each photo pixel (-1 none); the photo is read through the
    recovered response. Saturated photo pixels (any channel 255) are not used.
    """
    probe_rad, omega = project_probe(patches, mesh, probe.light_probe, probe.radiance)
    photo = scene.photo.reshape(-1, 3)
    L_b = probe.response.to_radiance(photo)
    sat = np.any(photo >= 255, axis=1)
    photo_rad, count = photo_radiance(pix_patch, L_b, sat, patches.n_patches)
    return build_radiance_mesh(G, probe_rad, omega, photo_rad, count)
