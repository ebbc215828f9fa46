"""Scene precompute: the per-scene artefacts every frame reads, each cached on disk by its inputs.

  patches + scene meshes ─► transfers G_c (patch centres), G_v (receiver vertices), camera ID
  buffer, radiance mesh B            (Precomputed; key: hash_scene(scene, PrecomputeConfig))
                         ─► shaft hierarchy (lighting.frame_sources.ShadowSources; key: its inputs)
                         ─► SH irradiance volume (lighting.irradiance.RoomLight's; key: its inputs)

PrecomputeConfig is frozen and holds exactly the knobs the precompute reads: its fields are the
cache key (EngineParams.precompute). The shafts and the SH volume are keyed by a digest of the
arrays they are built from and the source files of the code that builds them (artefact_cache).
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Literal

import numpy as np
from tqdm import tqdm

from app.config import LIGHTING, Lighting, PrecomputeConfig  # noqa: F401 (LIGHTING, Lighting: re-exported)
from app.stages import artefact_cache
from kernels.raycast import cast_rays
from kernels.visibility import Occluder, transfer_matrix
from lighting.frame_sources import ShadowSources
from lighting.irradiance import RoomLight
from lighting.radiance import captured_radiance_mesh
from lighting.radiosity import gather
from lighting.sources import select_sources
from lighting.sun import gather_with_sun
from recon.io import write_npz
from recon.patches import PatchMesh, build_patches
from recon.scene import Scene

log = logging.getLogger("photoar")
CACHE_VERSION = 6
@dataclass
class Precomputed:
    """Per-scene data that does not depend on the object (cached on disk)."""

    patches: PatchMesh
    G_c: np.ndarray  # (P,P) float32 patch-centre -> patch transfers
    recv_vert: np.ndarray  # (Vr,) vertex ids of receiver vertices (vertices of camera-seen patches)
    G_v: np.ndarray  # (Vr,P) float32 receiver-vertex -> patch transfers
    B: np.ndarray  # (bounces+1, P, 3) radiosity iterates
    pix_tri: np.ndarray  # (H*W,) int32 scene triangle per pixel (-1 none)
    pix_bary: np.ndarray  # (H*W,3) float32
    pix_depth: np.ndarray  # (H*W,) float32 metres along the ray
    albedo: np.ndarray  # (P,3) patch reflectivity used (declared, or recovered from captured light)
    origin: np.ndarray  # (P,) int8 where each patch's radiance came from (lighting.radiance codes; known: -1)
    seconds: float = 0.0
    emitter: np.ndarray | None = None  # (P,) bool patches that emit (captured: decided from the radiance)
    key: str = ""  # hash_scene of its inputs (names its cache file; keys the artefacts built from it)


def hash_scene(scene: Scene, config) -> str:
    """sha256 hex of every input the precompute reads: config.cache_key() (PrecomputeConfig, or
    EngineParams), the primitives, the sun, the camera, the photo, the response, and with captured
    light the probe's files and pose."""
    h = hashlib.sha256()
    h.update(json.dumps({"v": CACHE_VERSION, **config.cache_key()}, sort_keys=True).encode())
    for q in scene.quads:
        h.update(q.name.encode())
        h.update(f"{q.role}|{q.declared_emitter}".encode())  # how finely it is cut, whether it is lifted
        for a in (q.corners, q.normal, q.albedo, q.emission):
            h.update(np.ascontiguousarray(a, np.float64).tobytes())
        if q.texture is not None:
            h.update(hashlib.sha256(np.ascontiguousarray(q.texture).tobytes()).digest())
    if scene.sun is not None:  # sun: direction, size, strength, and which quads are openings
        h.update(np.concatenate([scene.sun.direction, [scene.sun.angular_diameter_deg], scene.sun.irradiance,
                                 [float(q.opening) for q in scene.quads]]).astype(np.float64).tobytes())
    cam = scene.camera
    for a in (cam.K, cam.R, cam.t):
        h.update(np.ascontiguousarray(a, np.float64).tobytes())
    h.update(f"{cam.width}x{cam.height} exposure {cam.exposure_time!r}".encode())
    h.update(hashlib.sha256(np.ascontiguousarray(scene.photo).tobytes()).digest())
    if scene.response is not None:
        for a in (scene.response.forward_table, scene.response.inverse_table):
            h.update(np.ascontiguousarray(a, np.float64).tobytes())
    if config.lighting == "captured":
        # the probe's files, and everything scene.json says about them: pose (centre, radius,
        # camera R/t/pixel size/principal point), exposure times, file names
        from lighting.hdr import scene_probe_files

        files, times, meta = scene_probe_files(scene.root)
        h.update(json.dumps(meta.get("light_probe"), sort_keys=True, default=str).encode())
        for f in files:
            h.update(hashlib.sha256(f.read_bytes()).digest())
    return h.hexdigest()


def scene_json(scene: Scene) -> str:
    return str(scene.meta.get("json_path", Path(scene.root) / "scene.json"))


def need_declared(scene: Scene) -> None:
    """Known lighting on a scene whose response or some emitter's radiance is not declared."""
    if scene.response is None:
        raise ValueError(f"{scene_json(scene)}: missing field 'camera_response'; --lighting known needs the "
                         f"camera's response (or use --lighting captured, which recovers it from the probe "
                         f"bracket, or --lighting photo, which assumes one)")
    if scene.meta.get("emitters_without_radiance"):
        raise ValueError(f"{scene_json(scene)}: no emitters of declared strength for --lighting known "
                         f"(emitters without emitted_radiance: {', '.join(scene.meta['emitters_without_radiance'])});"
                         f" use --lighting captured or --lighting photo, which estimate them")


def progress_bar(total: int, desc: str, quiet: bool):
    return tqdm(total=total, desc=desc, unit="pt", disable=quiet or not sys.stderr.isatty(), leave=False,
                dynamic_ncols=True)


def scene_patches(scene: Scene, config: PrecomputeConfig) -> PatchMesh:
    """The scene cut into patches, with the emitters the lighting allows."""
    patches = build_patches(scene, config.patch_size, config.emitter_patch_size)
    if config.lighting == "captured":
        patches.emission[:] = 0.0  # declared radiance is never read: emitters come from the capture
    elif config.lighting == "known" and not patches.is_emitter.any() and scene.sun is None:
        raise ValueError(f"{scene_json(scene)}: no emitters (no primitive declares emitted_radiance), so "
                         f"--lighting known would leave the room dark; use --lighting captured")
    return patches


def scene_meshes(patches: PatchMesh, device: str, lift: np.ndarray | None = None,
                 holes: np.ndarray | None = None) -> tuple[Occluder, Occluder]:
    """(occluder for light: non-emitting patches, less the openings `holes` (P,) bool, which light
    passes through; camera mesh: every patch, emitters (or the patches `lift` (P,) bool: quads that
    may emit, Quad.light_shaped) lifted 1 mm off the wall they sit on so the ID buffer and the probe's
    rays see them rather than the wall)."""
    solid = ~patches.is_emitter if holes is None else ~patches.is_emitter & ~holes
    solid_tri = solid[patches.tri_patch]
    lifted = patches.is_emitter if lift is None else lift
    emit = patches.tris[lifted[patches.tri_patch]].ravel()
    lift = np.zeros_like(patches.vert_pos)
    lift[emit] = patches.vert_normal[emit] * 1e-3
    return (Occluder(patches.vert_pos, patches.tris[solid_tri], device),
            Occluder(patches.vert_pos + lift, patches.tris, device))


def scene_occluders(scene: Scene, patches: PatchMesh, device: str) -> tuple[Occluder, Occluder]:
    """scene_meshes with the scene's light-shaped quads lifted and its openings open."""
    shaped = np.array([q.light_shaped for q in scene.quads], bool)[patches.quad]
    holes = np.array([q.opening for q in scene.quads], bool)[patches.quad]
    return scene_meshes(patches, device, lift=shaped | patches.is_emitter, holes=holes)


def cache_file(cache_dir: Path | None, scene: Scene, what: str, key: str) -> Path | None:
    """The cache file of one artefact of `scene` (None: no cache folder, nothing is cached)."""
    return cache_dir / f"{scene.name}-{what}{key[:20]}.npz" if cache_dir is not None else None


def cached_probe_response(cache_dir: Path | None, scene: Scene):
    """recover(files, times) -> the inverse response (256,3) of a probe bracket (lighting.photolight.
    recover_response), cached in `cache_dir` keyed by the bracket's file contents, its exposure times and the code
    that fits it (lighting.hdr): photo light's and captured light's response is recovered once per bracket, not on
    every run (the same fit, mitsunaga: one cached table serves both)."""
    from lighting.photolight import recover_response

    def recover(files: list[Path], times: list[float]) -> np.ndarray:
        key = artefact_cache.digest("probe-response", artefact_cache.code_digest("lighting.hdr", "lighting.photolight"),
                                    [float(x) for x in times], [Path(f).read_bytes() for f in files])
        g, _ = artefact_cache.cached(cache_file(cache_dir, scene, "response-", key),
                                     lambda: recover_response(files, times), what="probe response")
        return np.asarray(g, np.float64)

    return recover


def _load(cache: Path, patches: PatchMesh, key: str) -> Precomputed:
    with np.load(cache) as z:
        return Precomputed(patches, z["G_c"], z["recv_vert"], z["G_v"], z["B"], z["pix_tri"], z["pix_bary"],
                           z["pix_depth"], z["albedo"], z["origin"], float(z["seconds"]), z["emitter"], key)


def precompute(scene: Scene, config: PrecomputeConfig, patches: PatchMesh, scene_occ: Occluder,
               cam_occ: Occluder, *, device: str, cache_dir: Path | None = None, probe=None,
               sun_patch_light: Callable[[], np.ndarray | None] = lambda: None,
               progress: Callable[[int, int], None] | None = None, quiet: bool = True
               ) -> tuple[Precomputed, bool, int]:
    """(Precomputed, cache hit, steps reported to `progress`): transfers, camera ID buffer and
    radiance mesh of the scene, loaded from `cache_dir` when its key is there, else computed (and
    written there). probe: the captured probe (lighting "captured"); sun_patch_light: the sun's
    direct irradiance/pi per patch (None: no sunlit patch), joined to the radiosity (known)."""
    p = config
    key = hash_scene(scene, p)
    cache = cache_file(cache_dir, scene, "", key)
    if cache is not None and cache.is_file():
        try:
            pre = _load(cache, patches, key)
            log.debug("precompute: cache hit %s", cache)
            return pre, True, 1
        except (OSError, KeyError, ValueError, EOFError) as e:
            log.warning("precompute: ignoring unreadable cache %s (%s)", cache, e)
    log.info("precompute: the room's light transport (once for this scene and settings%s)",
             f", cached in {cache.parent}" if cache is not None else "")
    t0 = time.perf_counter()
    solid = ~patches.is_emitter
    cam = scene.camera
    pix_tri, pix_bary, pix_depth = cast_rays(cam_occ, cam.centre, cam.pixel_rays().reshape(-1, 3))

    seen = np.unique(patches.tri_patch[pix_tri[pix_tri >= 0]])
    seen = seen[solid[seen]]
    recv_vert = np.unique(patches.tris[np.isin(patches.tri_patch, seen)].ravel()).astype(np.int32)

    n_c, n_v = patches.n_patches, len(recv_vert)
    with progress_bar(n_c + n_v, "precompute transfers", quiet) as bar:
        done = [0]

        def step(k: int) -> None:  # the progress bar and the caller's progress(done, total)
            bar.update(k)
            done[0] += k
            if progress is not None:
                progress(min(done[0], n_c + n_v), n_c + n_v)

        G_c = transfer_matrix(patches.centre, patches.normal, patches.corners, patches.normal, [scene_occ],
                              n_side=1, device=device, progress=step)
        np.fill_diagonal(G_c, 0.0)
        G_v = transfer_matrix(patches.vert_inset[recv_vert], patches.vert_normal[recv_vert], patches.corners,
                              patches.normal, [scene_occ], n_side=p.vis_side, device=device, progress=step)
    if p.lighting == "captured":
        pix_patch = np.where(pix_tri >= 0, patches.tri_patch[np.maximum(pix_tri, 0)], -1)
        rm = captured_radiance_mesh(patches, G_c, cam_occ, probe, scene, pix_patch)
        log.debug("radiance mesh from captured light: %s", rm.summary())
        B = np.stack([rm.radiance] * (p.bounces + 1))
        albedo, origin, emitter = rm.reflectivity, rm.origin, rm.emitter
    elif p.lighting == "photo":  # filled in by use_lighting (cheap; redone on a cache hit)
        B, albedo, origin = np.zeros((p.bounces + 1, n_c, 3)), patches.albedo, np.full(n_c, -1, np.int8)
        emitter = patches.is_emitter
    else:
        sun = sun_patch_light()
        if sun is not None:  # sun: its patch light joins the radiosity
            B = np.stack(gather_with_sun(G_c, patches.albedo, patches.emission, sun, p.bounces))
        else:
            B = np.stack(gather(G_c, patches.albedo, patches.emission, p.bounces))
        albedo, origin, emitter = patches.albedo, np.full(n_c, -1, np.int8), patches.is_emitter
    seconds = time.perf_counter() - t0
    pre = Precomputed(patches, G_c, recv_vert, G_v, B, pix_tri, pix_bary, pix_depth, albedo, origin, seconds,
                      emitter, key)
    if cache is not None:
        write_npz(cache, G_c=G_c, recv_vert=recv_vert, G_v=G_v, B=B, pix_tri=pix_tri, pix_bary=pix_bary,
                  pix_depth=pix_depth, albedo=albedo, origin=origin, seconds=seconds, emitter=emitter)
    log.info("precompute: %d patches, %d receiver vertices, %.1f s", n_c, n_v, seconds)
    return pre, False, n_c + n_v


def use_lighting(pre: Precomputed, lighting: str, fit_photo: Callable[[Precomputed], None]) -> None:
    """Make the patch mesh carry the reflectivity and emitter radiance the precompute used
    (photo: after `fit_photo(pre)` fills in pre.B, pre.albedo, pre.origin from the photo)."""
    pm = pre.patches
    if lighting == "photo":
        fit_photo(pre)
    pm.albedo = np.asarray(pre.albedo, np.float64)
    if lighting in ("captured", "photo"):
        # which patches emit and how bright: captured, both from the captured radiance
        # (lighting.radiance.emitters); photo, the fitted groups and the model's emitters
        emit = np.asarray(pre.emitter, bool) if lighting == "captured" else pm.is_emitter
        pm.emission = np.where(emit[:, None], np.maximum(pre.B[-1], 1e-12), 0.0)


def fit_photo_light(pre: Precomputed, scene: Scene, bounces: int, priors, sunlit: np.ndarray | None = None,
                    pinned: dict | None = None) -> dict:
    """Radiance mesh from the photo alone into `pre` (B, albedo, origin); returns the fit's report
    (lighting.photolight; `sunlit` (P,) each patch's share in a sun found in the photo, or None; `pinned`
    {quad: (3,) radiance} clipped regions whose level the photo's penumbra measured, or None)."""
    from lighting.photolight import fit_photo_light as fit_light

    pm = pre.patches
    pm.emission = np.array([q.emission for q in scene.quads])[pm.quad]  # the model's emitters
    pix_patch = np.where(pre.pix_tri >= 0, pm.tri_patch[np.maximum(pre.pix_tri, 0)], -1)
    where = str(scene.root / "background.png")
    fit = fit_light(pm, pre.G_c, pix_patch, scene.photo, scene.response, priors,
                    [q.name for q in scene.quads], where, [q.role for q in scene.quads], sunlit=sunlit,
                    pinned=pinned)
    pre.B = np.stack([fit.radiance] * (bounces + 1))
    pre.albedo, pre.origin = fit.reflectivity, fit.origin
    emit = (fit.origin == 3) | pm.is_emitter  # fitted groups and the model's emitters
    pm.emission = np.where(emit[:, None], 1.0, 0.0)
    return fit.report


# ---------------------------------------------------------------------------------------------
# artefacts built from the precompute, cached by their inputs

# the code each artefact's build runs (its source files are part of the key)
_SHAFT_CODE = ("lighting.frame_sources", "lighting.shafts", "lighting.hierarchy", "lighting.sources", "recon.response")
_VOLUME_CODE = ("kernels.irradiance_volume", "kernels.visibility", "lighting.irradiance")


def shadow_sources(pre: Precomputed, B_src: np.ndarray, source_fraction: float, leaf_size: int,
                   shaft_threshold: float, cache: Path | None = None) -> tuple[ShadowSources, bool]:
    """(the shaft hierarchy between the source set and the receivers, cache hit). Built from the
    source set (select_sources of B_src, source_fraction), the patches' geometry, the transfers
    G_c, G_v (keyed by pre.key: the precompute they were loaded or computed as), B_src, leaf_size
    and shaft_threshold; `cache` (shadow_sources_key names it) holds it for the next engine."""
    pm = pre.patches

    def build() -> ShadowSources:
        src = select_sources(B_src, pm.area, source_fraction)
        receivers = np.flatnonzero(~pm.is_emitter)
        return ShadowSources(src, pm.centre, pm.normal, pm.corners, receivers, pre.G_c, pre.G_v, B_src,
                             leaf_size, shaft_threshold)

    return artefact_cache.cached(cache, build, {"G_c": pre.G_c, "G_v": pre.G_v, "B": B_src}, "shaft hierarchy")


def shadow_sources_key(pre: Precomputed, B_src: np.ndarray, source_fraction: float, leaf_size: int,
                       shaft_threshold: float) -> str:
    """Digest of exactly what shadow_sources reads (and of the code that builds it)."""
    pm = pre.patches
    return artefact_cache.digest("shafts", artefact_cache.code_digest(*_SHAFT_CODE), pre.key, B_src, pm.area,
                                 pm.centre, pm.normal, pm.corners, pm.is_emitter, float(source_fraction),
                                 int(leaf_size), float(shaft_threshold))


def room_light(patches: PatchMesh, B_src: np.ndarray, room_min: np.ndarray, room_max: np.ndarray,
               scene_occ: Occluder, spacing: float, device: str, cache: Path | None = None
               ) -> tuple[RoomLight, bool]:
    """(RoomLight: the SH9 volume of the indirect light plus the emitters, cache hit); the volume
    is read from `cache` (room_light_key names it) when there."""
    def build():
        return RoomLight(patches, B_src, room_min, room_max, scene_occ, spacing, device).volume

    volume, hit = artefact_cache.cached(cache, build, what="SH volume")
    return RoomLight(patches, B_src, room_min, room_max, scene_occ, spacing, device, volume=volume), hit


def room_light_key(patches: PatchMesh, B_src: np.ndarray, room_min: np.ndarray, room_max: np.ndarray,
                   scene_occ: Occluder, spacing: float) -> str:
    """Digest of exactly what the SH volume reads: the room box, the grid spacing, the patches'
    quads, normals, triangles and radiance (emitters zeroed), the occluder mesh, and the code."""
    occ = scene_occ.mesh
    occ_arrays = (occ.points.numpy(), occ.indices.numpy()) if occ is not None else ()
    return artefact_cache.digest("sh-volume", artefact_cache.code_digest(*_VOLUME_CODE),
                                 np.asarray(room_min, np.float64), np.asarray(room_max, np.float64), float(spacing),
                                 patches.corners, patches.normal, patches.tri_patch, patches.is_emitter,
                                 np.asarray(B_src, np.float64), *occ_arrays)
