"""The compositing engine: precompute once per scene, then one call per object pose.

Differential rendering in the seed's form (sec. 6.3, eq. 3), with the terms DESIGN.md found the
path-traced truth to need:

  L_final(x) = L_b(x) - eps(x)
  eps(x)     = L_b(x) * sum_j G_xj B_j M_xj / E_x          (shadows: occluded share of the light)
             - rho_x * sum_t B_t F_xt V_xt                  (light the object reflects onto x)
             - rho_x * sum_k G_xk dB_k                      (second order: patches the object
                                                             darkens or lights pass it on)
  E_x = sum_j G_xj B_j, rho_x = L_b(x) / E_x (reflectance from the photo, capped at 1)

L_b is the photo through the inverse camera response, G the form-factor x visibility transfers
(kernels.visibility) stored at receiver vertices and interpolated per pixel, B the patch radiance
(lighting.radiosity), M the occlusion masks from shadow maps of the object proxy
(kernels.shadowmap), dB_k = rho_k (sum_t B_t F_kt - sum_j G_kj B_j M_kj) at patch centres.
Writing the shadow term as a ratio of the photo makes it independent of how well the radiosity
reproduces the absolute brightness of the room; only the split of light between sources matters.

Sun (a `sun` primitive and an opening; lighting.sun, kernels.sunshadow; per frame app.stages.sun):
the sun's direct light rho E_sun on the patches joins the radiosity; E_x includes E_sun, and where
the photo clips L_b is the model's rho E_x (rho: the surface's albedo), so the sun's shadow there is
absolute, rho E_sun x occluded share (PCSS on an orthographic map, one pass of the budget). The sun
the object blocks and the sunlit object's light (from small lit pieces of its faces) are first-bounce
changes, passed on for every bounce the camera sees (not once); the object gets the sun per camera
hit with self-shadowing, and its outline beside clipping light is sampled finely.

The LDR path replaces L_ij by intensity transfers S_ij (lighting.transfer, fig. 13) subtracted
from the 8-bit photo.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import warp as wp
from scipy.spatial import cKDTree
from tqdm import tqdm

from kernels import runtime
from kernels.composite import MaskedSum
from kernels.raycast import cast_rays
from kernels.shadowmap import ShadowMaps
from kernels.shade import self_transfer
from kernels.visibility import Occluder, emitter_sum, transfer_matrix
from lighting.frame_sources import ShadowSources
from lighting.envmap import CubeMap, cube_directions, phong_prefilter, reflect
from lighting.irradiance import RoomLight
from lighting.radiance import captured_radiance_mesh, load_captured_probe
from lighting.radiosity import gather
from lighting.sources import select_sources
from lighting.sun import SunLight, estimate_sun, gather_with_sun, openings, surface_albedo
from app.stages.sun import SunStage
from lighting.transfer import intensity_transfers
from recon.io import write_npz
from recon.patches import PatchMesh, build_patches
from recon.proxy import simplify, subdivide
from recon.response import luminance
from recon.scene import Scene, SceneObject

log = logging.getLogger("photoar")
CACHE_VERSION = 6
# How the room is lit (EngineParams.lighting; the one list the command line and the engine use):
LIGHTING = {
    "known": "the scene's declared emitters (emitted_radiance) and radiosity",
    "captured": "the bracketed mirror-ball probe and the photo; emitters are the patches brighter than any "
                "reflector could be, the camera response is recovered from the bracket",
    "photo": "the photo alone: sRGB assumed, window/lamp radiance fitted to the walls (lighting.photolight)",
}


@dataclass
class EngineParams:
    """Knobs of the engine; every one trades accuracy against time (see bench/)."""

    patch_size: float = 0.18  # m, receiver/source patches (bench/bench_patch_size.py)
    emitter_patch_size: float = 0.1  # m, emitters are cut finer: one hard shadow per patch
    vis_side: int = 2  # visibility samples per patch side for receiver transfers (n^2 rays)
    bounces: int = 4  # light bounces the camera sees (the benchmark truth: 4)
    source_fraction: float = 1.0  # share of total power kept in the source set (seed: 0.7)
    passes: int | None = None  # shadow maps per frame (None = one per source)
    map_res: int = 256  # shadow-map resolution
    batch: int = 64  # shadow maps rendered at once
    mode: str = "hdr"  # hdr: T(L_b - eps); ldr: I_b - sum S_ij M_ij
    object_light: bool = True  # light reflected by the object onto the room
    second_order: bool = True  # re-propagate the change of patch radiance once
    proxy_faces: int = 300  # target size of the occluder proxy
    supersample: int = 2  # object coverage rays per pixel side
    volume_spacing: float = 0.25  # m, SH irradiance volume grid
    prt_dirs: int = 128  # directions per vertex for the object's self-occlusion transfer
    specular: float = 0.0  # k_s of the object's Phong-like specular lobe (0: Lambertian, as in the benchmarks)
    shininess: float = 32.0  # Phong exponent n of that lobe
    envmap_res: int = 16  # face size of the pre-filtered cube map looked up per pixel
    lighting: str = "known"  # known: declared emitters + radiosity; captured: probe bracket + photo (sec. 4.2);
    # photo: the photo alone, emitters fitted to the walls (lighting.photolight)
    fps: float | None = None  # target frame rate: choose the pass count from measured per-pass cost
    leaf_size: int = 8  # receiver octree leaf size (sec. 6.2)
    shaft_threshold: float = 0.02  # stop refining a shaft below this share of each receiver's light

    def cache_key(self) -> dict:
        return {k: getattr(self, k) for k in ("patch_size", "emitter_patch_size", "vis_side", "bounces", "lighting")}


@dataclass(frozen=True)
class FrameConfig:
    """Per-frame settings for Engine.render: a new one per change, never mutated (a frame and
    the key it is kept under read the same values)."""

    passes: int | None = None  # shadow maps per frame (None = one per source, the all-sources frame)
    mode: str = "hdr"  # hdr: T(L_b - eps); ldr: I_b - sum S_ij M_ij
    fps: float | None = None  # target frame rate: passes from the measured per-pass cost (passes caps it)

    def __post_init__(self):
        if self.fps is not None and not self.fps > 0:
            raise ValueError(f"fps must be positive, got {self.fps!r}")
        if self.mode not in ("hdr", "ldr"):
            raise ValueError(f"mode must be 'hdr' or 'ldr', got {self.mode!r}")
        if self.passes is not None and (isinstance(self.passes, bool) or not isinstance(self.passes, (int, np.integer))
                                        or self.passes < 1):
            raise ValueError(f"passes must be an integer of at least 1 or None (all sources), got {self.passes!r}")


@dataclass
class _Refinement:
    """Engine.refine's state: the all-sources frame of one pose, composited a batch at a time."""

    key: tuple  # (pose key, mode)
    steps: object  # the generator of Engine._frame_steps
    compute_s: float = 0.0  # seconds spent in refine calls on this pose
    calls: int = 0  # refine calls on this pose
    frames_seen: int = -1  # Engine._frames_started after its last step (another frame in between: restart)
    frame: "Frame | None" = None  # the finished frame


def _pose_key(obj: SceneObject) -> bytes:
    """What makes two objects the same for a frame: geometry, normals and albedo."""
    h = hashlib.sha1()
    for a in (obj.vertices, obj.normals, obj.faces, obj.albedo):
        h.update(np.ascontiguousarray(a).tobytes())
    return h.digest()


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


@dataclass
class Frame:
    radiance: np.ndarray  # (H,W,3) float32 composite radiance (HDR path estimate)
    pixels: np.ndarray  # (H,W,3) uint8 composite photo
    stats: dict = field(default_factory=dict)
    room: np.ndarray | None = None  # (H,W,3) float32 radiance of the room with the object's effect, object unseen
    coverage: np.ndarray | None = None  # (H,W) float32 share of each pixel the object covers


def _hash_scene(scene: Scene, params: EngineParams) -> str:
    h = hashlib.sha256()
    h.update(json.dumps({"v": CACHE_VERSION, **params.cache_key()}, sort_keys=True).encode())
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
    if params.lighting == "captured":
        # the probe's files, and everything scene.json says about them: pose (centre, radius,
        # camera R/t/pixel size/principal point), exposure times, file names
        from lighting.hdr import scene_probe_files

        files, times, meta = scene_probe_files(scene.root)
        h.update(json.dumps(meta.get("light_probe"), sort_keys=True, default=str).encode())
        for f in files:
            h.update(hashlib.sha256(f.read_bytes()).digest())
    return h.hexdigest()


def _scene_json(scene: Scene) -> str:
    return str(scene.meta.get("json_path", Path(scene.root) / "scene.json"))


def _need_declared(scene: Scene) -> None:
    """Known lighting on a scene whose response or some emitter's radiance is not declared."""
    if scene.response is None:
        raise ValueError(f"{_scene_json(scene)}: missing field 'camera_response'; --lighting known needs the "
                         f"camera's response (or use --lighting captured, which recovers it from the probe "
                         f"bracket, or --lighting photo, which assumes one)")
    if scene.meta.get("emitters_without_radiance"):
        raise ValueError(f"{_scene_json(scene)}: no emitters of declared strength for --lighting known "
                         f"(emitters without emitted_radiance: {', '.join(scene.meta['emitters_without_radiance'])});"
                         f" use --lighting captured or --lighting photo, which estimate them")


def _bar(total: int, desc: str, quiet: bool):
    return tqdm(total=total, desc=desc, unit="pt", disable=quiet or not sys.stderr.isatty(), leave=False,
                dynamic_ncols=True)


class Engine:
    """Owns one scene's precomputed data and composites object poses into its photo."""

    def __init__(self, scene: Scene, params: EngineParams | None = None, cache_dir: str | Path | None = None,
                 device: str | None = None, quiet: bool = False, photo_priors=None, progress=None):
        """progress: optional callable(done, total) during the precompute (transfer rows; called with
        (total, total) once the engine is ready, also on a cache hit), from the constructing thread."""
        self.scene = scene
        self._progress = progress
        self.params = params or EngineParams()
        if self.params.mode not in ("hdr", "ldr"):
            raise ValueError(f"mode must be 'hdr' or 'ldr', got {self.params.mode!r}")
        if self.params.lighting not in LIGHTING:
            raise ValueError(f"lighting must be one of {sorted(LIGHTING)}, got {self.params.lighting!r}")
        if not 0.0 <= self.params.specular <= 1.0 or self.params.shininess < 0:
            raise ValueError(f"specular must be in [0, 1] and shininess >= 0, got {self.params.specular}, "
                             f"{self.params.shininess}")
        self.device = runtime.device(device)
        self.quiet = quiet
        self.photo_priors = photo_priors  # lighting "photo": lighting.photolight.PhotoPriors (None: defaults)
        self.cache_dir = Path(cache_dir) if cache_dir else None
        self.n_precompute = 0  # per-scene work done (precompute, SH volume): no frame may add to it
        self._progress_total = 1  # precompute steps (transfer rows) reported to `progress`
        t0 = time.perf_counter()
        self.probe = None
        self.photo_light: dict = {}  # lighting "photo": the fit's report (lighting.photolight)
        if self.params.lighting == "captured":
            # the camera response comes from the probe bracket too: nothing declared is used
            self.probe = load_captured_probe(scene)
            self.scene = scene = dataclasses.replace(scene, response=self.probe.response)
        elif self.params.lighting == "photo":
            self.scene = scene = self._photo_scene(scene)
        elif self.params.lighting == "known" and (scene.response is None
                                                  or scene.meta.get("emitters_without_radiance")):
            _need_declared(scene)  # captured: the probe gives the response and the emitters
        self.pre, self.cache_hit = self._precompute()
        self._setup()
        self._refining: _Refinement | None = None  # refine(): the pose being refined
        self._frames_started = 0  # frames begun (render and refine): refine restarts after another
        self.room_light  # the SH volume is per-scene work too
        self.precompute_s = time.perf_counter() - t0
        if progress is not None:
            progress(self._progress_total, self._progress_total)

    # ------------------------------------------------------------------ precompute
    def _precompute(self) -> tuple[Precomputed, bool]:
        self.n_precompute += 1
        p = self.params
        scene = self.scene
        patches = build_patches(scene, p.patch_size, p.emitter_patch_size)
        if p.lighting == "captured":
            patches.emission[:] = 0.0  # declared radiance is never read: emitters come from the capture
        elif p.lighting == "known" and not patches.is_emitter.any() and scene.sun is None:
            raise ValueError(f"{_scene_json(scene)}: no emitters (no primitive declares emitted_radiance), so "
                             f"--lighting known would leave the room dark; use --lighting captured")
        shaped = np.array([q.light_shaped for q in scene.quads], bool)[patches.quad]
        holes = np.array([q.opening for q in scene.quads], bool)[patches.quad]
        self.scene_occ, self.cam_occ = _scene_meshes(patches, self.device, lift=shaped | patches.is_emitter,
                                                     holes=holes)
        self._sun_init(patches)
        key = _hash_scene(scene, p)
        cache = self.cache_dir / f"{scene.name}-{key[:20]}.npz" if self.cache_dir else None
        if cache is not None and cache.is_file():
            try:
                z = np.load(cache)
                pre = Precomputed(patches, z["G_c"], z["recv_vert"], z["G_v"], z["B"], z["pix_tri"], z["pix_bary"],
                                  z["pix_depth"], z["albedo"], z["origin"], float(z["seconds"]), z["emitter"])
                log.info("precompute: cache hit %s", cache)
                self._use_lighting(pre)
                return pre, True
            except (OSError, KeyError, ValueError, EOFError) as e:
                log.warning("precompute: ignoring unreadable cache %s (%s)", cache, e)
        t0 = time.perf_counter()
        dev = self.device
        solid = ~patches.is_emitter
        cam = scene.camera
        pix_tri, pix_bary, pix_depth = cast_rays(self.cam_occ, cam.centre, cam.pixel_rays().reshape(-1, 3))

        seen = np.unique(patches.tri_patch[pix_tri[pix_tri >= 0]])
        seen = seen[solid[seen]]
        recv_vert = np.unique(patches.tris[np.isin(patches.tri_patch, seen)].ravel()).astype(np.int32)

        n_c, n_v = patches.n_patches, len(recv_vert)
        self._progress_total = n_c + n_v
        with _bar(n_c + n_v, "precompute transfers", self.quiet) as bar:
            done = [0]

            def step(k: int) -> None:  # the progress bar and the caller's progress(done, total)
                bar.update(k)
                done[0] += k
                if self._progress is not None:
                    self._progress(min(done[0], n_c + n_v), n_c + n_v)

            G_c = transfer_matrix(patches.centre, patches.normal, patches.corners, patches.normal, [self.scene_occ],
                                  n_side=1, device=dev, progress=step)
            np.fill_diagonal(G_c, 0.0)
            G_v = transfer_matrix(patches.vert_inset[recv_vert], patches.vert_normal[recv_vert], patches.corners,
                                  patches.normal, [self.scene_occ], n_side=p.vis_side, device=dev,
                                  progress=step)
        if p.lighting == "captured":
            pix_patch = np.where(pix_tri >= 0, patches.tri_patch[np.maximum(pix_tri, 0)], -1)
            rm = captured_radiance_mesh(patches, G_c, self.cam_occ, self.probe, scene, pix_patch)
            log.info("radiance mesh from captured light: %s", rm.summary())
            B = np.stack([rm.radiance] * (p.bounces + 1))
            albedo, origin, emitter = rm.reflectivity, rm.origin, rm.emitter
        elif p.lighting == "photo":  # filled in by _use_lighting (cheap; redone on a cache hit)
            B, albedo, origin = np.zeros((p.bounces + 1, n_c, 3)), patches.albedo, np.full(n_c, -1, np.int8)
            emitter = patches.is_emitter
        else:
            if self.sun_light is not None and self.sun_light.active:  # sun: its patch light joins the radiosity
                B = np.stack(gather_with_sun(G_c, patches.albedo, patches.emission, self._sun_patch_light(),
                                             p.bounces))
            else:
                B = np.stack(gather(G_c, patches.albedo, patches.emission, p.bounces))
            albedo, origin, emitter = patches.albedo, np.full(n_c, -1, np.int8), patches.is_emitter
        seconds = time.perf_counter() - t0
        pre = Precomputed(patches, G_c, recv_vert, G_v, B, pix_tri, pix_bary, pix_depth, albedo, origin, seconds,
                          emitter)
        self._use_lighting(pre)
        if cache is not None:
            write_npz(cache, G_c=G_c, recv_vert=recv_vert, G_v=G_v, B=B, pix_tri=pix_tri, pix_bary=pix_bary,
                      pix_depth=pix_depth, albedo=albedo, origin=origin, seconds=seconds, emitter=emitter)
        log.info("precompute: %d patches, %d receiver vertices, %.1f s", n_c, n_v, seconds)
        return pre, False

    def _use_lighting(self, pre: Precomputed) -> None:
        """Make the patch mesh carry the reflectivity and emitter radiance the precompute used."""
        pm = pre.patches
        if self.params.lighting == "photo":
            self._fit_photo_light(pre)
        pm.albedo = np.asarray(pre.albedo, np.float64)
        if self.params.lighting in ("captured", "photo"):
            # which patches emit and how bright: captured, both from the captured radiance
            # (lighting.radiance.emitters); photo, the fitted groups and the model's emitters
            emit = np.asarray(pre.emitter, bool) if self.params.lighting == "captured" else pm.is_emitter
            pm.emission = np.where(emit[:, None], np.maximum(pre.B[-1], 1e-12), 0.0)

    def _photo_scene(self, scene: Scene) -> Scene:
        """The scene with the assumed response and the model's emitters of unknown strength
        (lighting.photolight.prepare_scene); the declared emitters are kept for the report only."""
        from lighting.photolight import prepare_scene

        scene, declared = prepare_scene(scene, self.photo_priors)
        self.photo_light = {"declared_emitters_unused": declared}
        return scene

    def _fit_photo_light(self, pre: Precomputed) -> None:
        """Radiance mesh from the photo alone into `pre` (B, albedo, origin), report in photo_light."""
        from lighting.photolight import fit_photo_light

        pm, scene = pre.patches, self.scene
        pm.emission = np.array([q.emission for q in scene.quads])[pm.quad]  # the model's emitters
        pix_patch = np.where(pre.pix_tri >= 0, pm.tri_patch[np.maximum(pre.pix_tri, 0)], -1)
        where = str(scene.root / "background.png")
        fit = fit_photo_light(pm, pre.G_c, pix_patch, scene.photo, scene.response, self.photo_priors,
                              [q.name for q in scene.quads], where, [q.role for q in scene.quads])
        pre.B = np.stack([fit.radiance] * (self.params.bounces + 1))
        pre.albedo, pre.origin = fit.reflectivity, fit.origin
        emit = (fit.origin == 3) | pm.is_emitter  # fitted groups and the model's emitters
        pm.emission = np.where(emit[:, None], 1.0, 0.0)
        self.photo_light = {**fit.report, **{k: v for k, v in self.photo_light.items() if k.startswith("declared")}}
        log.info("photo light: %s", {k: v for k, v in self.photo_light.items() if k != "warnings"})

    def _setup(self) -> None:
        """Per-scene arrays derived from the precompute, shared by every frame."""
        pre, pm, scene = self.pre, self.pre.patches, self.scene
        dev = self.device
        cam = scene.camera
        self.dirs = cam.pixel_rays().reshape(-1, 3)
        self.L_b = scene.response.to_radiance(scene.photo).reshape(-1, 3)  # (H*W,3)
        self.L_b_levels = scene.response.to_levels(self.L_b)  # T(L_b): the frame where nothing changes
        hit = pre.pix_tri >= 0
        self.pix_patch = np.where(hit, pm.tri_patch[np.maximum(pre.pix_tri, 0)], -1)
        vert_row = np.full(len(pm.vert_pos), -1, np.int64)
        vert_row[pre.recv_vert] = np.arange(len(pre.recv_vert))
        self.pix_rows = np.where(hit[:, None], vert_row[pm.tris[np.maximum(pre.pix_tri, 0)]], -1)
        self.pix_pos = (cam.centre + self.dirs * np.where(hit, pre.pix_depth, 0.0)[:, None]).astype(np.float32)
        # receiver pixels: seen surface that is a non-emitter receiver patch with all vertices known
        self.recv_pix = hit & (self.pix_rows.min(1) >= 0) & ~pm.is_emitter[np.maximum(self.pix_patch, 0)]
        b = self.params.bounces
        self.B_src = pre.B[b - 1]  # what receivers gather (one bounce less than the camera sees)
        self.B_obj = pre.B[max(b - 2, 0)]  # light that reaches the camera via the object has one bounce less
        self.E_v = pre.G_v.astype(np.float64) @ self.B_src  # (Vr,3) irradiance/pi at receiver vertices
        self.E_x = np.zeros_like(self.L_b)
        rp = self.recv_pix
        self.E_x[rp] = np.einsum("nk,nkc->nc", pre.pix_bary[rp], self.E_v[self.pix_rows[rp]])
        self._sun_setup_pixels()  # sun: its direct light joins E_x; clipped sunlit pixels get model radiance
        with np.errstate(divide="ignore", invalid="ignore"):
            self.rho_x = np.where(self.E_x > 0, np.minimum(self.L_b / self.E_x, 1.0), 0.0)
        if self.sun_pix is not None:
            self.rho_x[self.sun_clipped] = self.sun_rho_clipped
        self.maps = ShadowMaps(self.params.batch, self.params.map_res, device=dev)
        self._room_light = None
        t0 = time.perf_counter()
        src = select_sources(self.B_src, pm.area, self.params.source_fraction)
        receivers = np.flatnonzero(~pm.is_emitter)
        self.shadow_sources = ShadowSources(src, pm.centre, pm.normal, pm.corners, receivers, pre.G_c, pre.G_v,
                                            self.B_src, self.params.leaf_size, self.params.shaft_threshold)
        self.shaft_build_s = time.perf_counter() - t0
        log.debug("shaft hierarchy: %s, %.1f s", self.shadow_sources.stats(), self.shaft_build_s)
        self._cost: dict | None = None  # measured fixed and per-pass frame cost (--fps), refined every frame
        self._passes_override: int | None = None  # pass count of the calibration frame
        self.dB_samples = 400  # object vertices that gather the second-order loss (the rest interpolate)
        self._prt_cache = None  # (key, self_transfer result) of the last object shape (_self_transfer)
        self.shape_cache = True  # keep the object's proxy, shading mesh and BVHs per shape (_object_shape)
        self._shape: dict | None = None  # the last shape's (_object_shape)
        self._shade_occ = None  # (shading-mesh vertices, their Occluder) of the current frame
        self.n_shape_builds = 0  # object shapes simplified/subdivided so far
        self.near_factor = 2.0  # object light per pixel within this many bounding radii
        # occlusion masks: every pixel within mask_near_factor bounding radii of the object, farther
        # out (soft, slowly varying shadows) every second pixel in x and y, the rest filled in from
        # looked-up neighbours on the same quad
        self.mask_near_factor = 1.5
        H, W = cam.height, cam.width
        yy, xx = np.mgrid[0:H, 0:W]
        lattice = ((yy % 2 == 0) & (xx % 2 == 0)).reshape(-1)
        self.pix_quad = np.where(self.pix_patch >= 0, pm.quad[np.maximum(self.pix_patch, 0)], -1)
        self.lattice = lattice & self.recv_pix
        cover = np.zeros(H * W, bool)
        for dy, dx, ok_src, ok_dst in _window_pairs(H, W):
            cover[ok_dst] |= self.lattice[ok_src] & (self.pix_quad[ok_src] == self.pix_quad[ok_dst])
        self.lattice_cover = cover

    # ------------------------------------------------------------------ per frame
    @property
    def lighting(self) -> str:
        """How the room is lit (a key of LIGHTING), fixed for the engine's life: another lighting is
        another precompute, i.e. another Engine."""
        return self.params.lighting

    def frame_config(self) -> FrameConfig:
        """The FrameConfig of the engine's params (what render uses when given none)."""
        return FrameConfig(self.params.passes, self.params.mode, self.params.fps)

    def render(self, obj: SceneObject, config: FrameConfig | None = None) -> Frame:
        """Composite the object at its pose within `config` (default: frame_config()); returns the
        frame with per-phase timings in stats."""
        steps = self._frame_steps(obj, config or self.frame_config())
        while True:
            try:
                next(steps)
            except StopIteration as done:
                return done.value

    def refine(self, obj: SceneObject, config: FrameConfig | None = None, budget_s: float | None = None
               ) -> Frame | None:
        """Progressive refinement at rest: advance the all-sources frame of this pose (config's mode;
        its passes are ignored) by batches of shadow maps for about `budget_s` seconds (None: to the
        end). Returns that frame once every source is in (again at once on later calls for the same
        pose), None before. A call for another pose or mode starts over, and so does a call after
        another frame was rendered in between (it re-aims the shared shadow maps and BVHs). Its stats add refine_s (compute in refine calls) and refine_calls."""
        cfg = FrameConfig(None, (config or self.frame_config()).mode)  # every source, no --fps budget
        key = (_pose_key(obj), cfg.mode)
        st = self._refining
        if st is not None and st.frame is None and st.frames_seen not in (-1, self._frames_started):
            # another frame ran since the last step: it re-aimed the shared shadow maps and the object's
            # BVHs at its own pose, so this one starts over
            st = None
        if st is None or st.key != key:
            self._refining = st = _Refinement(key, self._frame_steps(obj, cfg))
        if st.frame is not None:
            return st.frame
        t0 = time.perf_counter()
        cost = self._cost  # gaps between calls must not enter the --fps cost model
        st.calls += 1
        try:
            while True:
                try:
                    next(st.steps)
                except StopIteration as done:
                    st.frame = done.value
                    break
                if budget_s is not None and time.perf_counter() - t0 >= budget_s:
                    break
        except BaseException:
            self._refining = None
            raise
        finally:
            self._cost = cost
            st.compute_s += time.perf_counter() - t0
            st.frames_seen = self._frames_started
        if st.frame is not None:
            st.frame.stats.update(refine_s=st.compute_s, refine_calls=st.calls)
        return st.frame

    def _frame_steps(self, obj: SceneObject, config: FrameConfig):
        """render()'s work as a generator: yields after each batch of shadow maps, returns the Frame."""
        self._frames_started += 1
        calibration_s = 0.0
        if config.fps is not None and self._cost is None and self._passes_override is None:
            calibration_s = self._calibrate(obj, config)
        p = dataclasses.replace(self.params, passes=config.passes, mode=config.mode, fps=config.fps)  # never written
        pre, pm, scene = self.pre, self.pre.patches, self.scene
        cam = scene.camera
        H, W = cam.height, cam.width
        timings: dict[str, float] = {}
        t_all = time.perf_counter()

        def tick(name: str, t: float) -> float:
            now = time.perf_counter()
            timings[name] = now - t
            return now

        t = time.perf_counter()
        pv, pf, proxy_occ, shade_mesh, shade_occ = self._object_shape(obj)
        centre = 0.5 * (pv.min(0) + pv.max(0))
        radius = float(np.linalg.norm(pv - centre, axis=1).max())
        t = tick("proxy", t)

        # ---- object pixels: coverage and depth against the scene model
        hits = self._object_hits(shade_mesh[0], shade_mesh[2], occluder=shade_occ)
        cov = hits.coverage()
        t = tick("object", t)

        # ---- source list from the shaft hierarchy, grouped into the frame's passes (sec. 6.2.1, 6.4)
        fs = self.shadow_sources.select(pv.min(0), pv.max(0), self._passes_for_frame(p))
        eyes, W_v, W_c, cand = fs.eyes, fs.W_v, fs.W_c, fs.cand
        t = tick("sources", t)

        # ---- occlusion masks: pixels and patch centres
        want = self.recv_pix & (cov.reshape(-1) < 1.0) & cand.any(1)[np.maximum(self.pix_patch, 0)]
        near = np.linalg.norm(self.pix_pos - centre, axis=1) < self.mask_near_factor * radius
        exact = want & (near | self.lattice | ~self.lattice_cover)
        pix_sel = np.flatnonzero(exact)
        fill_sel = np.flatnonzero(want & ~exact)
        halves = np.array_split(pix_sel, 2)  # two accumulators: each launch runs on its own core
        pix_sums = [MaskedSum(self.pix_pos[h], self.pix_rows[h], pre.pix_bary[h], self.pix_patch[h], self.device)
                    for h in halves]
        cen_sel = np.flatnonzero(cand.any(1) & ~pm.is_emitter)
        cen_sum = MaskedSum(pm.centre[cen_sel] + pm.normal[cen_sel] * 1e-3, np.repeat(cen_sel[:, None], 3, 1),
                            np.tile([1.0, 0.0, 0.0], (len(cen_sel), 1)), cen_sel, self.device)
        if p.mode == "ldr":
            S_v = self._ldr_weights(W_v)
        self.maps.set_proxy(pv, pf)
        cand_wp = wp.array(cand.astype(np.uint8), dtype=wp.uint8, device=self.device)
        wv_wp = wp.array((S_v if p.mode == "ldr" else W_v).astype(np.float32), dtype=wp.vec3, device=self.device)
        wc_wp = wp.array(W_c.astype(np.float32), dtype=wp.vec3, device=self.device)
        n_src = len(eyes)
        for first in tqdm(range(0, n_src, p.batch), desc="shadow passes", unit="batch", leave=False,
                          disable=self.quiet or n_src <= 4 * p.batch or not sys.stderr.isatty()):
            n = self.maps.render(eyes[first:first + p.batch])
            runtime.run_parallel([
                lambda: pix_sums[0].add(self.maps, n, first, cand_wp, wv_wp),
                lambda: (pix_sums[1].add(self.maps, n, first, cand_wp, wv_wp),
                         cen_sum.add(self.maps, n, first, cand_wp, wc_wp))])
            yield first + n  # sources done: refine() may stop here and resume on its next call
        wp.synchronize_device(self.device)
        O_pix = np.concatenate([ps.result()[0] for ps in pix_sums])
        O_cen, _ = cen_sum.result()
        t = tick("masks", t)

        # ---- the object lit by the room, whose patches in its shadow send it less light
        dB_shadow = np.zeros((pm.n_patches, 3))
        dB_shadow[cen_sel] = -pm.albedo[cen_sel] * O_cen
        sun_loss = None
        if self.sun_pix is not None:  # sun: one pass, its loss on pixels and patches (second order)
            sun_loss, sun_loss_c = self.sun_stage.frame(obj.vertices, obj.faces)
            self._sun_dB = -pm.albedo * sun_loss_c  # the object gathers it exactly (object_vertex_radiance)
            t = tick("sun", t)
        obj_rad = self._shade_object(obj, shade_mesh, hits, proxy_occ, dB_shadow)
        if sun_loss is not None:
            dB_shadow = dB_shadow + self._sun_dB
            if self._last_L_vert is not None:  # sun: the outline where sunlight clips, sampled finely
                self.sun_stage.refine_clipped_edges(cam, self.cam_occ, shade_mesh, shade_occ, self._last_L_vert,
                                                    self._obj_sun_vert, obj.albedo, cov, obj_rad, self.sun_photo_clip)
        t = tick("object_shading", t)

        # ---- light the object reflects, onto pixels and patch centres
        R_pix = np.zeros((H * W, 3))
        R_cen = np.zeros((pm.n_patches, 3))
        if p.object_light:
            tri_rad = self._object_triangle_radiance(obj, pv, pf, proxy_occ, self.B_obj + dB_shadow)
            pv_l, pf_l = pv, pf
            if self.sun_pix is not None:  # sun: the object's sunlit parts light the room too (small pieces)
                pv_l, pf_l, tri_rad = self.sun_stage.object_emitters(pv, pf, tri_rad, obj.albedo, proxy_occ, radius)
            R_pix, R_cen = self._object_light(pv_l, pf_l, tri_rad, proxy_occ, centre, radius)
        t = tick("object_light", t)

        # ---- second order: change of patch radiance, passed on once to receiver vertices
        dE_x = np.zeros((H * W, 3))
        if p.second_order:
            dB = dB_shadow + pm.albedo * R_cen
            nz = np.flatnonzero(np.abs(dB).sum(1) > 0)
            dE_v = pre.G_v[:, nz].astype(np.float64) @ dB[nz]
            if sun_loss is not None:  # sun: the sunlit patch light the object blocks (the room's main
                # source) and the sunlit object's own light are first-bounce changes: passed on for every
                # bounce the camera sees, not once
                more = self.sun_stage.more_bounces(pm.albedo * (R_cen - sun_loss_c), pm.albedo, pre.G_c, p.bounces)
                dE_v += pre.G_v @ more.astype(np.float32)
            rp = self.recv_pix
            dE_x[rp] = np.einsum("nk,nkc->nc", pre.pix_bary[rp], dE_v[self.pix_rows[rp]])
        t = tick("second_order", t)

        # ---- compose
        L_b, E_x, rho = self.L_b, self.E_x, self.rho_x
        add = rho * (R_pix + dE_x)  # light gained (object reflection) or lost second-hand
        resp = scene.response
        if p.mode == "hdr":
            shadow = np.zeros_like(L_b)
            with np.errstate(divide="ignore", invalid="ignore"):
                frac = np.where(E_x[pix_sel] > 0, np.clip(O_pix / E_x[pix_sel], 0.0, 1.0), 0.0)
            frac_fill = self._fill(pix_sel, frac, fill_sel)
            shadow[pix_sel] = L_b[pix_sel] * frac
            shadow[fill_sel] = L_b[fill_sel] * frac_fill
            if sun_loss is not None:  # sun: its occluded share of the (model, where clipped) radiance
                sp = self.sun_pix
                shadow[sp] += L_b[sp] * np.clip(sun_loss / np.maximum(E_x[sp], 1e-12), 0.0, 1.0)
            room = np.maximum(L_b - shadow + add, 0.0)
            # the response only where the room changed (the rest of the frame is T(L_b))
            changed = np.flatnonzero((shadow != 0).any(1) | (add != 0).any(1))
            room_levels = self.L_b_levels.copy()
            room_levels[changed] = resp.to_levels(room[changed])
        else:
            levels = scene.photo.reshape(-1, 3).astype(np.float64)
            levels[pix_sel] -= O_pix
            levels[fill_sel] -= self._fill(pix_sel, O_pix, fill_sel)
            if sun_loss is not None:  # sun: levels lost from its occluded share
                sp = self.sun_pix
                share = np.clip(sun_loss / np.maximum(E_x[sp], 1e-12), 0.0, 1.0)
                levels[sp] += resp.to_levels(L_b[sp] * (1 - share)) - resp.to_levels(L_b[sp])
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
        # where the object or the room behind it clips (a sunlit face, a sunlit floor) a level is only
        # a floor: the camera averages radiance over the pixel before its response, so mix the edge
        # pixels in radiance there
        edge = on[((obj_levels >= 255) | (room_levels[on] >= 255)).any(1) & (c[on, 0] < 1)]
        levels[edge] = resp.to_levels(radiance[edge])
        pixels = np.clip(np.rint(levels), 0, 255).astype(np.uint8).reshape(H, W, 3)
        tick("compose", t)
        frame_s = time.perf_counter() - t_all
        if n_src:
            self._cost = {"per_pass_s": timings["masks"] / n_src, "fixed_s": frame_s - timings["masks"]}
        n_sun = int(sun_loss is not None)  # sun: one more source and pass
        stats = {"frame_s": frame_s, "timings": timings, "n_sources": int(fs.n_listed) + n_sun,
                 "passes": int(n_src) + n_sun,
                 "n_patches": int(pm.n_patches), "n_receiver_patches": fs.n_receivers,
                 "n_receiver_vertices": int(len(pre.recv_vert)), "n_mask_pixels": int(len(pix_sel)),
                 "n_filled_pixels": int(len(fill_sel)), "proxy_triangles": int(len(pf)), "mode": p.mode,
                 "shaft_build_s": self.shaft_build_s, **self.shadow_sources.stats()}
        if self.sun_estimate is not None:  # sun: the captured estimate against the declared sun
            stats["sun_estimate"] = self.sun_estimate
        if calibration_s:
            stats["fps_calibration_s"] = calibration_s
        self._last_shading = (shade_mesh, self._last_L_vert, obj.albedo) if hits.hit.any() else None
        return Frame(radiance.reshape(H, W, 3).astype(np.float32), pixels, stats,
                     room.reshape(H, W, 3).astype(np.float32), cov.astype(np.float32))

    # ------------------------------------------------------------------ pieces
    def _object_shape(self, obj: SceneObject):
        """(proxy vertices, proxy faces, proxy Occluder, shading mesh (v, n, f), shading-mesh Occluder)
        of the object at its pose. The simplification, the subdivision and both BVHs are made once
        per object shape, kept in the shape's own frame (centred: the key is the centred mesh to
        1 um, as _self_transfer's); a pose that only moves the object translates them and refits
        the BVHs (Warp Mesh.refit) instead (shape_cache False: made afresh every frame)."""
        p, v = self.params, obj.vertices
        offset = v.mean(0)
        key = hashlib.sha1(np.round(v - offset, 6).tobytes() + np.round(obj.normals, 6).tobytes()
                           + np.ascontiguousarray(obj.faces).tobytes() + str(p.proxy_faces).encode()).hexdigest()
        sh = self._shape if self.shape_cache else None
        if sh is None or sh["key"] != key:
            pv, pf, _ = simplify(v, obj.faces, p.proxy_faces)
            sv, sn, sf = subdivide(v, obj.normals, obj.faces, max_edge=0.08, max_faces=3000)
            sh = {"key": key, "offset": offset, "pv": pv - offset, "pf": pf, "sv": sv - offset, "sn": sn, "sf": sf,
                  "proxy_occ": Occluder(pv, pf, self.device), "shade_occ": Occluder(sv, sf, self.device)}
            if self.shape_cache:
                self._shape = sh
            self.n_shape_builds += 1
        pv, sv = sh["pv"] + offset, sh["sv"] + offset
        if not np.array_equal(offset, sh["offset"]):  # moved: translate the BVHs' points and refit
            for occ, pts in ((sh["proxy_occ"], pv), (sh["shade_occ"], sv)):
                if occ.mesh is not None:
                    occ._pts.assign(pts.astype(np.float32))
                    occ.mesh.refit()
            sh["offset"] = offset
        self._shade_occ = (sv, sh["shade_occ"])  # object_vertex_radiance's own-shadow mesh, this frame
        return pv, sh["pf"], sh["proxy_occ"], (sv, sh["sn"], sh["sf"]), sh["shade_occ"]

    def _object_hits(self, verts: np.ndarray, faces: np.ndarray, camera=None, supersample: int | None = None,
                     occluder: Occluder | None = None) -> "ObjectHits":
        """Sub-pixel camera rays against the object mesh, depth-tested against the scene model
        (camera: default the scene's; another one sees the same world, e.g. the full-resolution
        photo's, app.workres)."""
        cam = camera or self.scene.camera
        H, W, s = cam.height, cam.width, max(1, supersample or self.params.supersample)
        uv, z = cam.project(verts)
        if np.any(z <= 1e-6):
            u0, v0, u1, v1 = 0, 0, W - 1, H - 1
        else:
            u0, v0 = np.floor(uv.min(0) - 1).astype(int)
            u1, v1 = np.ceil(uv.max(0) + 1).astype(int)
            u0, v0, u1, v1 = max(u0, 0), max(v0, 0), min(u1, W - 1), min(v1, H - 1)
        if u0 > u1 or v0 > v1:
            return ObjectHits(H, W, s, (0, 0, -1, -1), np.zeros(0, np.int32), np.zeros((0, 3)), np.zeros(0, bool))
        offs = (np.arange(s) + 0.5) / s - 0.5
        uu = (np.arange(u0, u1 + 1)[:, None] + offs).reshape(-1)
        vv = (np.arange(v0, v1 + 1)[:, None] + offs).reshape(-1)
        U, V = np.meshgrid(uu, vv)
        d = np.stack([U, V, np.ones_like(U)], -1).reshape(-1, 3) @ np.linalg.inv(cam.K).T @ cam.R
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        tri, bary, depth = cast_rays(occluder or Occluder(verts, faces, self.device), cam.centre, d)
        _, _, scene_depth = cast_rays(self.cam_occ, cam.centre, d)
        return ObjectHits(H, W, s, (u0, v0, u1, v1), tri, bary, (tri >= 0) & (depth < scene_depth))

    @property
    def room_light(self) -> RoomLight:
        """SH9 volume of the indirect light plus the emitters (built on first use, ~2-5 s)."""
        if self._room_light is None:
            self.n_precompute += 1
            pm, sc = self.pre.patches, self.scene
            self._room_light = RoomLight(pm, self.B_src, sc.room_min, sc.room_max, self.scene_occ,
                                         self.params.volume_spacing, self.device)
        return self._room_light

    def object_vertex_radiance(self, obj: SceneObject, mesh, proxy_occ: Occluder,
                               dB: np.ndarray | None = None) -> np.ndarray:
        """Outgoing radiance (V,3) at the shading mesh's vertices (mesh = (verts, normals, faces)).

        albedo x (indirect SH9 x self-occlusion transfer + exact emitters + dB, the change of the
        room's patches in the object's shadow), plus one bounce between the object's own parts.
        """
        v, n, f = mesh
        pm = self.pre.patches
        # the shading mesh shadows itself: the coarse proxy would cut through its surface and
        # shadow vertices that lie outside it
        cached = self._shade_occ
        own = cached[1] if cached is not None and cached[0] is v else Occluder(v, f, self.device)
        T, hit_face, hit_bary = self._self_transfer(v, n, f)
        E = np.einsum("vk,vkc->vc", T.astype(np.float64), self.room_light.indirect_sh(v))
        E += self.room_light.direct(v, n, [own], n_side=1)
        if getattr(self, "sun_pix", None) is not None:  # sun: direct, with the object's self-shadowing
            self._obj_sun_vert = self.sun_light.irradiance(v, n, [own])  # (sharpened per camera hit later)
            E += self._obj_sun_vert
            # the sun the object blocks from the floor: a large, sharp loss right beside it, gathered at
            # every vertex (a sparse sample would interpolate it past the SH9 light and clip to black)
            ch = np.flatnonzero(np.abs(self._sun_dB).sum(1) > 0) if self._sun_dB is not None else []
            if len(ch):
                E += transfer_matrix(v, n, pm.corners[ch], pm.normal[ch], [self.scene_occ, own], n_side=1,
                                     eps=2e-3, device=self.device).astype(np.float64) @ self._sun_dB[ch]
        if dB is not None:
            # the shadowed patches that hold 95 % of the lost power (the rest is too faint to matter)
            loss = np.abs(luminance(dB)) * pm.area
            order = np.argsort(-loss)
            order = order[loss[order] > 0]
            keep = int(np.searchsorted(np.cumsum(loss[order]), 0.95 * loss.sum())) + 1 if len(order) else 0
            changed = order[:keep]
            if len(changed):
                # the loss varies slowly over the object (the shadowed patches are beyond it):
                # gather it at a spread subset of vertices and interpolate by position and normal
                sub = np.arange(0, len(v), max(1, len(v) // self.dB_samples))
                G = transfer_matrix(v[sub], n[sub], pm.corners[changed], pm.normal[changed],
                                    [self.scene_occ, own], n_side=1, eps=2e-3, device=self.device)
                E += _interpolate_on_surface(v, n, sub, G.astype(np.float64) @ dB[changed])
        L_vert = obj.albedo * np.maximum(E, 0.0)
        # vertices buried inside another part of the object (a chair's back-rest inside its seat)
        # see almost nothing; their values would darken the visible triangles they belong to
        hit = hit_face >= 0
        buried = hit.mean(axis=1) > 0.7
        L_vert = _fill_from_neighbours(L_vert, f, buried)
        # one bounce between the object's own parts: occluded directions see the object's radiance
        if hit.any():
            bounce = np.zeros(hit_face.shape + (3,))
            bounce[hit] = np.einsum("mk,mkc->mc", hit_bary[hit], L_vert[f[hit_face[hit]]])
            L_vert = _fill_from_neighbours(L_vert + obj.albedo * bounce.mean(axis=1), f, buried)
        return L_vert

    def _self_transfer(self, v: np.ndarray, n: np.ndarray, f: np.ndarray):
        """kernels.shade.self_transfer in the object's own frame (centred), kept for the last mesh
        shape: self-occlusion does not change when the object slides, only when it turns or changes
        (the key is the centred mesh to 1 um). Centred, the float32 ray casts give the same answer at
        every position: in world coordinates 3-4 % of the rays grazing a neighbouring face flipped
        between positions 0.4 m apart, up to 13 levels on the object while dragging."""
        local = v - v.mean(0)
        key = hashlib.sha1(np.round(local, 6).tobytes() + np.round(n, 6).tobytes()
                           + np.ascontiguousarray(f).tobytes() + str(self.params.prt_dirs).encode()).hexdigest()
        cached = self._prt_cache
        if cached is None or cached[0] != key:
            own = Occluder(local, f, self.device)
            self._prt_cache = cached = (key, self_transfer(local, n, own, self.params.prt_dirs, device=self.device))
        return cached[1]

    def _shade_object(self, obj: SceneObject, mesh, hits: "ObjectHits", proxy_occ, dB: np.ndarray) -> np.ndarray:
        """Object radiance (H,W,3) from `object_vertex_radiance`, interpolated at the camera hits."""
        self._last_L_vert = None
        if not hits.hit.any():
            return np.zeros((hits.H, hits.W, 3))
        L_vert = self.object_vertex_radiance(obj, mesh, proxy_occ, dB)
        self._last_L_vert = L_vert
        v, n, f = mesh
        h = hits.hit
        sub = np.zeros((len(h), 3))
        corners = f[hits.tri[h]]
        sub[h] = np.einsum("nk,nkc->nc", hits.bary[h], L_vert[corners])
        if getattr(self, "sun_pix", None) is not None:  # sun: its direct light per camera hit (a sharp edge
            pos = np.einsum("nk,nkc->nc", hits.bary[h], v[corners])  # across a face, not a vertex blend)
            nrm = np.einsum("nk,nkc->nc", hits.bary[h], n[corners])
            nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-12)
            own = self._shade_occ[1] if self._shade_occ is not None and self._shade_occ[0] is v else \
                Occluder(v, f, self.device)
            E_hit = self.sun_light.irradiance(pos, nrm, [own])
            E_interp = np.einsum("nk,nkc->nc", hits.bary[h], self._obj_sun_vert[corners])
            sub[h] = np.maximum(sub[h] + obj.albedo * (E_hit - E_interp), 0.0)
        if self.params.specular > 0:
            pos = np.einsum("nk,nkc->nc", hits.bary[h], v[corners])
            nrm = np.einsum("nk,nkc->nc", hits.bary[h], n[corners])
            nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-12)
            view = pos - self.scene.camera.centre
            view /= np.linalg.norm(view, axis=1, keepdims=True)
            env = self.specular_map(0.5 * (v.min(0) + v.max(0)))
            sub[h] += self.params.specular * env.lookup(reflect(view, nrm))
        return hits.average(sub)

    def specular_map(self, centre: np.ndarray) -> CubeMap:
        """The room's radiance seen from `centre` (the object's centre, object absent), pre-filtered
        with the Phong lobe of `shininess` (seed sec. 5, fig. 9)."""
        p, pm = self.params, self.pre.patches
        res_in = max(2 * p.envmap_res, int(np.ceil(2 * np.sqrt(p.shininess))))
        dirs, _ = cube_directions(res_in)
        tri, _, _ = cast_rays(self.cam_occ, np.asarray(centre, np.float64), dirs)
        L = np.where((tri >= 0)[:, None], self.B_src[pm.tri_patch[np.maximum(tri, 0)]], 0.0)
        return phong_prefilter(L, res_in, p.shininess, p.envmap_res)

    def _fill(self, known: np.ndarray, values: np.ndarray, missing: np.ndarray) -> np.ndarray:
        """Values (len(missing),3) at pixels `missing`: mean of the known pixels in their 3x3
        window that lie on the same quad (every missing pixel has one, see lattice_cover)."""
        if len(missing) == 0:
            return np.zeros((0, 3))
        n = len(self.L_b)
        val = np.zeros((n, 3))
        has = np.zeros(n, bool)
        val[known] = values
        has[known] = True
        H, W = self.scene.camera.height, self.scene.camera.width
        my, mx = np.divmod(missing, W)
        acc = np.zeros((len(missing), 3))
        cnt = np.zeros(len(missing))
        for dy in (-1, 0, 1):  # only the missing pixels' windows, not the whole frame
            for dx in (-1, 0, 1):
                sy, sx = my + dy, mx + dx
                src = sy * W + sx
                good = (sy >= 0) & (sy < H) & (sx >= 0) & (sx < W)
                good[good] = has[src[good]] & (self.pix_quad[src[good]] == self.pix_quad[missing[good]])
                acc[good] += val[src[good]]
                cnt[good] += 1
        return acc / np.maximum(cnt, 1)[:, None]

    def _object_irradiance(self, pts: np.ndarray, nrm: np.ndarray, proxy_occ: Occluder, B: np.ndarray
                           ) -> np.ndarray:
        """Irradiance/pi (N,3) at object surface points from patches of radiance B (P,3), with
        self-occlusion."""
        pm = self.pre.patches
        G = transfer_matrix(pts, nrm, pm.corners, pm.normal, [self.scene_occ, proxy_occ], n_side=1,
                            eps=2e-3, device=self.device)
        return G.astype(np.float64) @ B

    def _object_triangle_radiance(self, obj: SceneObject, pv, pf, proxy_occ, B: np.ndarray) -> np.ndarray:
        """Outgoing radiance (T,3) of each proxy triangle, lit at its centroid by patches of radiance B."""
        c = pv[pf].mean(1)
        n = np.cross(pv[pf[:, 1]] - pv[pf[:, 0]], pv[pf[:, 2]] - pv[pf[:, 0]])
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
        return obj.albedo * self._object_irradiance(c, n, proxy_occ, B)

    def _object_light(self, pv, pf, tri_rad, proxy_occ, centre, radius):
        """Light reflected by the object onto pixels (H*W,3) and patch centres (P,3), as irradiance/pi.

        Far from the object the reflected light varies slowly: it is evaluated at receiver vertices
        and interpolated like the transfers. Within `near_factor` bounding radii of the object's
        centre, where it changes fast (contact, under a seat), it is evaluated per pixel; there only
        pixels whose upper bound of gain exceeds a quarter level are computed.
        """
        pre, pm = self.pre, self.pre.patches
        resp = self.scene.response
        tris = pv[pf]
        rv = pre.recv_vert
        R_v = emitter_sum(pm.vert_inset[rv], pm.vert_normal[rv], tris, tri_rad, proxy_occ, device=self.device)
        R_pix = np.zeros((len(self.L_b), 3))
        rp = np.flatnonzero(self.recv_pix)
        R_pix[rp] = np.einsum("nk,nkc->nc", pre.pix_bary[rp], R_v[self.pix_rows[rp]])
        dist = np.linalg.norm(self.pix_pos[rp] - centre, axis=1)
        near = dist < self.near_factor * radius
        rp, dist = rp[near], dist[near]
        f_bound = np.minimum(1.0, (radius / np.maximum(dist, 1e-6)) ** 2)
        bound = self.rho_x[rp] * tri_rad.max(0) * f_bound[:, None]
        gain = (resp.to_levels(self.L_b[rp] + bound) - resp.to_levels(self.L_b[rp])).max(1)
        sel = rp[gain > 0.25]
        normals = pm.normal[self.pix_patch[sel]]
        R_pix[sel] = emitter_sum(self.pix_pos[sel], normals, tris, tri_rad, proxy_occ, device=self.device)
        # patch centres, for the second-order term
        dist_c = np.linalg.norm(pm.centre - centre, axis=1)
        reach = np.minimum(1.0, (radius / np.maximum(dist_c, 1e-6)) ** 2) * luminance(tri_rad.max(0))
        near_c = np.flatnonzero((reach > 1e-4 * luminance(self.B_src).mean()) & ~pm.is_emitter)
        R_cen = np.zeros((pm.n_patches, 3))
        R_cen[near_c] = emitter_sum(pm.centre[near_c], pm.normal[near_c], tris, tri_rad, proxy_occ, device=self.device)
        self._n_object_light_pixels = len(sel)
        return R_pix, R_cen

    def _calibrate(self, obj: SceneObject, config: FrameConfig | None = None) -> float:
        """Measure the frame's fixed and per-pass cost before --fps chooses a pass count: one
        frame of this object at one batch of passes (its result is discarded). Returns seconds."""
        t0 = time.perf_counter()
        config = config or self.frame_config()
        self._passes_override = self.params.batch if config.passes is None else \
            min(self.params.batch, config.passes)
        try:
            self.render(obj, config)
        finally:
            self._passes_override = None
        return time.perf_counter() - t0

    # ------------------------------------------------------------------ sun (lighting.sun, kernels.sunshadow)
    def _sun_init(self, patches: PatchMesh) -> None:
        """The scene's sun seen through its openings (None without a sun)."""
        sun = self.scene.sun
        self.sun_light = None
        self._sun_patch = None
        self._sun_pm = patches
        if sun is not None and self.params.lighting == "known":  # captured: estimated in _sun_captured
            where = self.scene.meta.get("json_path", self.scene.name)
            self.sun_light = SunLight(sun, openings(self.scene), self.scene_occ, where=f"{where}: sun")

    @property
    def sun_on(self) -> bool:
        """True when the sun lights some surface: it then takes one pass of every frame."""
        return self.sun_light is not None and self.sun_light.active and self._sun_patch_light().any()

    def _sun_patch_light(self) -> np.ndarray:
        """Direct sun irradiance/pi (P,3) averaged over each patch (computed once)."""
        if self._sun_patch is None:
            pm = self._sun_pm
            self._sun_patch = np.zeros((pm.n_patches, 3))
            if self.sun_light is not None and self.sun_light.active:
                self._sun_patch = self.sun_light.patch_irradiance(pm.corners, pm.normal, ~pm.is_emitter)
        return self._sun_patch

    def _sun_setup_pixels(self) -> None:
        """Per-pixel direct sun E_sun (added to E_x), the sample points of sunlit patches, the sun map.

        The sunlit patch clips in the photo: there L_b is a floor, not the radiance, and a shadow
        term that is a share of L_b would be far too small. On clipped sunlit pixels L_b is
        replaced by the model's radiance rho x (E_x + E_sun), rho the surface's albedo (declared
        texture, or the patch reflectivity the captured light recovered), so the sun's shadow
        there is the absolute rho x E_sun x occluded share."""
        self.sun_pix = None
        self.sun_stage: SunStage | None = None  # the sun's per-frame work (app.stages.sun)
        self._sun_dB = None  # the sun the object blocks from each patch, this frame (P,3)
        self.sun_estimate = None
        if self.params.lighting == "captured":
            self._sun_captured()
        if not self.sun_on:
            return
        pre, pm, cam = self.pre, self.pre.patches, self.scene.camera
        rp = np.flatnonzero(self.recv_pix)
        nrm = pm.normal[self.pix_patch[rp]]
        vis = self.sun_light.visibility(self.pix_pos[rp], nrm)
        lit = vis > 0
        self.sun_pix = rp[lit]
        E_sun = vis[lit, None] * (self.sun_light.sun.irradiance / np.pi)  # the estimate with captured light
        self.sun_E = E_sun
        self.E_x[self.sun_pix] += E_sun
        # pixel footprint on the surface (m): filter radius of the shadow lookup (box ~ disk)
        depth = pre.pix_depth[self.sun_pix].astype(np.float64)
        cos_v = np.abs(np.einsum("nc,nc->n", self.dirs[self.sun_pix], nrm[lit]))
        self.sun_fp = 0.5 * depth / cam.K[0, 0] / np.sqrt(np.maximum(cos_v, 0.05))
        self.sun_pts = self.pix_pos[self.sun_pix] + nrm[lit] * 1e-3
        # clipped sunlit pixels: model radiance instead of the photo's floor
        sat = (self.scene.photo.reshape(-1, 3)[self.sun_pix] >= 254).any(1)
        idx = self.sun_pix[sat]
        quad = pm.quad[self.pix_patch[idx]]
        if self.params.lighting == "known":
            rho = surface_albedo(self.scene, quad, self.pix_pos[idx].astype(np.float64), pm.albedo[self.pix_patch[idx]])
        else:
            rho = pm.albedo[self.pix_patch[idx]]
        # pixels next to the sunlit ones (partly sunlit, centre in shade) and the clipped ones: the
        # photo's L_b / E_x is no reflectance there; take the surface's albedo
        H, W = cam.height, cam.width
        lit_img = np.zeros(H * W, bool)
        lit_img[self.sun_pix] = True
        near = np.zeros(H * W, bool)
        for dy, dx, src, dst in _window_pairs(H, W):
            near[dst] |= lit_img[src]
        edge = np.flatnonzero(near & ~lit_img & self.recv_pix)
        quad_e = pm.quad[self.pix_patch[edge]]
        rho_e = surface_albedo(self.scene, quad_e, self.pix_pos[edge].astype(np.float64),
                               pm.albedo[self.pix_patch[edge]]) if self.params.lighting == "known" \
            else pm.albedo[self.pix_patch[edge]]
        self.sun_clipped = np.concatenate([idx, edge])
        self.sun_rho_clipped = np.concatenate([rho, rho_e])
        self.L_b[idx] = np.maximum(self.L_b[idx], rho * self.E_x[idx])
        # sample points of sunlit patches (second order: the patches' lost sun)
        lit_c = np.flatnonzero(self._sun_patch_light().any(1))
        n_side = 4
        f = (np.arange(n_side) + 0.5) / n_side
        fu, fv = [a.ravel() for a in np.meshgrid(f, f)]
        c0 = pm.corners[lit_c, 0]
        pts = (c0[:, None] + fu[None, :, None] * (pm.corners[lit_c, 1] - c0)[:, None]
               + fv[None, :, None] * (pm.corners[lit_c, 3] - c0)[:, None]).reshape(-1, 3)
        nrm_c = np.repeat(pm.normal[lit_c], len(fu), axis=0)
        self.sun_c_patch = lit_c
        self.sun_c_vis = self.sun_light.visibility(pts, nrm_c).reshape(len(lit_c), len(fu))
        self.sun_c_pts = pts + nrm_c * 1e-3
        self.sun_photo_clip = (self.scene.photo.reshape(-1, 3) >= 254).any(1)
        self.sun_stage = SunStage(self.sun_light, self.sun_pts, self.sun_fp, self.sun_E, self.sun_c_patch,
                                  self.sun_c_pts, self.sun_c_vis, pm.n_patches, self.device)

    def _sun_captured(self) -> None:
        """Captured light: the sun estimated from the photo and the radiance mesh (lighting.sun
        .estimate_sun) replaces the declared one; the sunlit patches take the reflectivity of their
        surface's unlit patches. The declared sun, if any, is only reported against."""
        pre, pm, scene = self.pre, self.pre.patches, self.scene
        if not openings(scene):
            self.sun_light = None
            return
        sat = np.any(scene.photo.reshape(-1, 3) >= 255, axis=1)
        # the captured radiance flags the sunlit patch as an emitter (brighter than the mesh, which
        # holds no sun, can light it); the sun is looked for on every surface but windows and lamps
        shaped = np.array([q.light_shaped for q in scene.quads], bool)[pm.quad]
        recv_any = (pre.pix_tri >= 0) & (self.pix_rows.min(1) >= 0) & ~shaped[np.maximum(self.pix_patch, 0)]
        flagged = pm.is_emitter & ~shaped  # plain surfaces the radiance test flagged: tried as sunlit
        kept = pm.emission[flagged].copy()
        pm.emission[flagged] = 0.0
        sun, info = estimate_sun(scene, pm, self.pix_patch, self.pix_pos.astype(np.float64), self.dirs, self.L_b,
                                 sat, recv_any, pre.B[-1], pre.G_c, self.scene_occ)
        self._sun_patch = None
        self.sun_light = SunLight(sun, openings(scene), self.scene_occ, where="sun estimate") if sun else None
        if sun is not None and scene.sun is not None:
            d0 = scene.sun.direction / np.linalg.norm(scene.sun.direction)
            info["declared_direction"] = d0.tolist()
            info["direction_error_deg"] = float(np.degrees(np.arccos(np.clip(sun.direction @ d0, -1, 1))))
            info["declared_irradiance_perpendicular"] = scene.sun.irradiance.tolist()
            info["strength_ratio"] = float(luminance(sun.irradiance) / max(luminance(scene.sun.irradiance), 1e-12))
        self.sun_estimate = info
        log.info("sun estimate: %s", info)
        if self.sun_light is not None and self.sun_light.active:
            # patches the sun lights are reflectors, not emitters: receivers of the object's shadows;
            # the other flagged ones emit again
            lit = self._sun_patch_light().any(1)
            pm.emission[flagged & ~lit] = kept[~lit[flagged]]
            new = recv_any & ~self.recv_pix & lit[np.maximum(self.pix_patch, 0)]
            self.recv_pix |= new
            self.E_x[new] = np.einsum("nk,nkc->nc", pre.pix_bary[new], self.E_v[self.pix_rows[new]])
            # sunlit patches: the photo clips there and the probe sees them coarsely; take the
            # reflectivity of the unlit patches of the same surface (as the strength estimate does)
            for q in np.unique(pm.quad[lit]):
                same = (pm.quad == q) & ~pm.is_emitter
                if (same & ~lit).sum() >= 3:
                    pm.albedo[same & lit] = np.median(pm.albedo[same & ~lit], axis=0)
        else:
            pm.emission[flagged] = kept  # no sun: what the radiance flagged emits

    def _passes_for_frame(self, p: EngineParams | None = None) -> int | None:
        """The pass budget: --passes, or the passes that fit 1/--fps from the measured costs
        (p: this frame's params, default the engine's)."""
        p = self.params if p is None else p
        if self._passes_override is not None:
            return self._passes_override
        sun = int(self.sun_on)  # sun: one pass of the budget, never dropped
        if p.fps is None or self._cost is None:
            return None if p.passes is None else max(1, p.passes - sun)
        budget = 1.0 / p.fps - self._cost["fixed_s"]
        n = int(budget / max(self._cost["per_pass_s"], 1e-6))
        return max(1, min(n, p.passes or n) - sun)

    def _ldr_weights(self, W_v: np.ndarray) -> np.ndarray:
        """Intensity transfers S_ij (Vr,S,3) in levels at receiver vertices (fig. 13)."""
        pre = self.pre
        rp = np.flatnonzero(self.recv_pix)
        rows, bary = self.pix_rows[rp], pre.pix_bary[rp].astype(np.float64)
        n = len(pre.recv_vert)
        num = np.zeros((n, 3))
        den = np.zeros(n)
        for k in range(3):
            np.add.at(num, rows[:, k], bary[:, k:k + 1] * self.rho_x[rp])
            np.add.at(den, rows[:, k], bary[:, k])
        albedo_v = np.zeros((n, 3))
        vert_patch = np.zeros(len(pre.patches.vert_pos), np.int64)
        vert_patch[pre.patches.tris.ravel()] = np.repeat(pre.patches.tri_patch, 3)
        albedo_v[:] = pre.patches.albedo[vert_patch[pre.recv_vert]]
        rho_v = np.where(den[:, None] > 0, num / np.maximum(den, 1e-12)[:, None], albedo_v)
        L_i = rho_v * self.E_v
        return intensity_transfers(L_i, rho_v[:, None, :] * W_v, self.scene.response.to_levels)


@dataclass
class ObjectHits:
    """Sub-pixel camera hits on the object inside the rectangle (u0, v0, u1, v1), s x s per pixel."""

    H: int
    W: int
    s: int
    rect: tuple[int, int, int, int]
    tri: np.ndarray  # (n,) object triangle per sub-sample (-1 none)
    bary: np.ndarray  # (n,3)
    hit: np.ndarray  # (n,) bool: object seen (in front of the scene)

    def average(self, sub: np.ndarray) -> np.ndarray:
        """Mean of per-sub-sample values (n,3) over each pixel's hits -> (H,W,3)."""
        u0, v0, u1, v1 = self.rect
        out = np.zeros((self.H, self.W, 3))
        if u1 < u0:
            return out
        hh, ww, s = v1 - v0 + 1, u1 - u0 + 1, self.s
        hitm = self.hit.reshape(hh, s, ww, s)
        total = (sub * self.hit[:, None]).reshape(hh, s, ww, s, 3).sum(axis=(1, 3))
        out[v0:v1 + 1, u0:u1 + 1] = total / np.maximum(hitm.sum(axis=(1, 3)), 1)[..., None]
        return out

    def coverage(self) -> np.ndarray:
        """Fraction (H,W) of each pixel's sub-samples that see the object."""
        u0, v0, u1, v1 = self.rect
        cov = np.zeros((self.H, self.W))
        if u1 >= u0:
            hh, ww, s = v1 - v0 + 1, u1 - u0 + 1, self.s
            cov[v0:v1 + 1, u0:u1 + 1] = self.hit.reshape(hh, s, ww, s).mean(axis=(1, 3))
        return cov


def _interpolate_on_surface(v: np.ndarray, n: np.ndarray, sub: np.ndarray, values: np.ndarray, k: int = 6
                            ) -> np.ndarray:
    """Values (V,C) at every vertex from values (len(sub),C) at vertices `sub`: inverse-distance
    weights over the k nearest samples, times the cosine between normals squared (so a seat's top
    does not take the value of its underside)."""
    if len(sub) == len(v):
        return values
    k = min(k, len(sub))
    d, j = cKDTree(v[sub]).query(v, k=k)
    d, j = d.reshape(len(v), k), j.reshape(len(v), k)
    cos = np.einsum("vc,vkc->vk", n, n[sub][j])
    w = np.maximum(cos, 0.0) ** 2 / (d + 1e-3)
    w[w.sum(1) == 0, 0] = 1.0  # no sample faces the same way: take the nearest
    return np.einsum("vk,vkc->vc", w / w.sum(1, keepdims=True), values[j])


def _fill_from_neighbours(values: np.ndarray, faces: np.ndarray, missing: np.ndarray, rounds: int = 8
                          ) -> np.ndarray:
    """Values (V,C) with the `missing` vertices replaced by the mean of their known mesh
    neighbours, grown over `rounds` rings (what is still missing then gets the known mean)."""
    if not missing.any() or missing.all():
        return values
    out = values.copy()
    known = ~missing
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    e = np.concatenate([e, e[:, ::-1]])
    for _ in range(rounds):
        src = known[e[:, 0]] & ~known[e[:, 1]]
        if not src.any():
            break
        acc = np.zeros_like(out)
        cnt = np.zeros(len(out))
        np.add.at(acc, e[src, 1], out[e[src, 0]])
        np.add.at(cnt, e[src, 1], 1)
        new = cnt > 0
        out[new] = acc[new] / cnt[new, None]
        known = known | new
    out[~known] = out[known].mean(0)
    return out


def _scene_meshes(patches: PatchMesh, device: str, lift: np.ndarray | None = None,
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


def _window_pairs(H: int, W: int):
    """(dy, dx, src, dst) flat pixel index pairs for every offset of a 3x3 window (cached)."""
    key = (H, W)
    if key not in _WINDOW_CACHE:
        yy, xx = np.mgrid[0:H, 0:W]
        pairs = []
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                sy, sx = yy + dy, xx + dx
                ok = (sy >= 0) & (sy < H) & (sx >= 0) & (sx < W)
                pairs.append((dy, dx, (sy * W + sx)[ok], (yy * W + xx)[ok]))
        _WINDOW_CACHE[key] = pairs
    return _WINDOW_CACHE[key]


_WINDOW_CACHE: dict = {}
