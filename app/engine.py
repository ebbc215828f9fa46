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
import functools
import hashlib
import logging
import time
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from app.runtime import split as split_launches  # the two-core split (sources: kernels of few, long items)
from app.stages import precompute as scene_precompute
from app.stages.compose import ComposeStage
from app.stages.precompute import (LIGHTING, Lighting, PrecomputeConfig,  # noqa: F401 (re-exported)
                                   Precomputed, hash_scene as _hash_scene)
from app.stages.receiver_map import receiver_map, reflectance
from kernels import runtime
from app.stages import object_light, object_shading
from app.stages.object_shading import ObjectHits
from kernels.visibility import Occluder
from lighting.envmap import CubeMap
from lighting.irradiance import RoomLight
from lighting.radiance import load_captured_probe
from lighting.sun import SunLight, estimate_sun, no_sun_reason, openings, surface_albedo
from app.stages.sun import SunStage, upright_box
from recon.assemble import SUN_DECLARED_BY_USER
from recon.patches import PatchMesh
from recon.proxy import bounding_sphere
from recon.response import luminance
from recon.scene import Scene, SceneObject
from app.stages.shadow_pass import ShadowPass, window_pairs as _window_pairs

log = logging.getLogger("photoar")


Mode = Literal["hdr", "ldr"]
SunSource = Literal["auto", "estimate", "declared"]
SUN_SOURCES = {
    "auto": "declared under --lighting known; under captured the declared sun when the user gave it "
            "(`photoar scene --sun-*`: its entry says \"declared_by\": \"user\"), else the estimate; under "
            "photo the estimate",
    "estimate": "estimated from the photo's sunlit patches (--lighting captured or photo)",
    "declared": "scene.json's sun entry as given, also under captured light (not photo: light from the photo alone); "
                "an entry with \"strength\": \"estimate\" gives the direction, its strength is estimated from the photo",
}


def _knob(default, doc: str):
    """A config field with its documentation (the command line's help is made from it, cli.py)."""
    return field(default=default, metadata={"doc": doc})


def _check_literals(cfg) -> None:
    """ValueError naming the field when a Literal-typed field of the dataclass `cfg` holds a value
    outside its choices."""
    hints = _LITERAL_FIELDS.get(type(cfg))
    if hints is None:
        hints = _LITERAL_FIELDS[type(cfg)] = {
            k: typing.get_args(t) for k, t in typing.get_type_hints(type(cfg)).items()
            if typing.get_origin(t) is Literal}
    for name, choices in hints.items():
        value = getattr(cfg, name)
        if value not in choices:
            raise ValueError(f"{name} must be one of {', '.join(map(repr, choices))}, got {value!r}")


_LITERAL_FIELDS: dict[type, dict[str, tuple]] = {}


def _check_frame(passes, fps) -> None:
    if fps is not None and not fps > 0:
        raise ValueError(f"fps must be positive, got {fps!r}")
    if passes is not None and (isinstance(passes, bool) or not isinstance(passes, (int, np.integer)) or passes < 1):
        raise ValueError(f"passes must be an integer of at least 1 or None (all sources), got {passes!r}")


@dataclass(frozen=True)
class EngineParams:
    """Knobs of the engine; every one trades accuracy against time (see bench/). Frozen: a changed
    knob is a new EngineParams (dataclasses.replace). The knobs of the scene precompute are its
    cache key (`precompute`); the field docs are the command line's help (app.cli)."""

    patch_size: float = _knob(0.18, "metres, receiver/source patches (bench/bench_patch_size.py)")
    emitter_patch_size: float = _knob(0.1, "metres, emitters are cut finer: one hard shadow per patch")
    vis_side: int = _knob(2, "visibility samples per patch side for receiver transfers (n^2 rays)")
    bounces: int = _knob(4, "light bounces the camera sees (the benchmark truth: 4)")
    source_fraction: float = _knob(1.0, "share of total patch power kept as shadow sources (seed: 0.7)")
    passes: int | None = _knob(None, "shadow maps per frame; sources are grouped into this many representatives "
                                     "(default: one per source)")
    map_res: int = _knob(256, "shadow-map size")
    batch: int = _knob(64, "shadow maps rendered at once")
    mode: Mode = _knob("hdr", "hdr: T(L_b - eps) in floating point; ldr: subtract intensity transfers S_ij from "
                              "the 8-bit photo (seed fig. 13)")
    object_light: bool = _knob(True, "light the object reflects onto the room")
    second_order: bool = _knob(True, "re-propagate the object's effect once (the change of patch radiance)")
    proxy_faces: int = _knob(300, "target size of the occluder proxy")
    supersample: int = _knob(2, "object coverage rays per pixel side")
    volume_spacing: float = _knob(0.25, "metres, SH irradiance volume grid")
    prt_dirs: int = _knob(128, "directions per vertex for the object's self-occlusion transfer")
    specular: float = _knob(0.0, "k_s of the object's Phong-like specular lobe, in [0, 1] (0: Lambertian, as in "
                                 "the benchmarks)")
    shininess: float = _knob(32.0, "Phong exponent")
    envmap_res: int = _knob(16, "face size of the pre-filtered cube map looked up per pixel")
    lighting: Lighting = _knob("known", "; ".join(f"{k}: {v}" for k, v in LIGHTING.items()) + ". A room with a sun "
                               "entry: known uses the declared sun, captured estimates it from the photo unless "
                               "it is the user's (--sun chooses, where offered)")
    sun: SunSource = _knob("auto", "which sun lights a room with openings (scene.json's sun entry or the photo's): "
                           + "; ".join(f"{k}: {v}" for k, v in SUN_SOURCES.items()))
    fps: float | None = _knob(None, "target frame rate: the pass count is chosen from the measured cost per pass "
                                    "(at most --passes)")
    leaf_size: int = _knob(8, "receiver octree leaf size (sec. 6.2)")
    shaft_threshold: float = _knob(0.02, "stop refining a shaft below this share of each receiver's light")

    def __post_init__(self):
        _check_literals(self)
        if self.sun == "estimate" and self.lighting == "known":
            raise ValueError("--sun estimate: the sun is estimated from the photo with captured or photo light: use "
                             "it with --lighting captured or photo (known light uses scene.json's sun)")
        if self.sun == "declared" and self.lighting == "photo":
            raise ValueError("--sun declared: --lighting photo takes its light, the sun's too, from the photo alone; "
                             "use --lighting captured or known for a declared sun")
        if not 0.0 <= self.specular <= 1.0 or self.shininess < 0:
            raise ValueError(f"specular must be in [0, 1] and shininess >= 0, got {self.specular}, "
                             f"{self.shininess}")
        # passes and fps are checked by the FrameConfig a frame is made with (frame_config)

    @classmethod
    def doc(cls, name: str) -> str:
        """The documentation of field `name` (the command line's help)."""
        return cls.__dataclass_fields__[name].metadata["doc"]

    @property
    def precompute(self) -> PrecomputeConfig:
        """The knobs the scene precompute reads: exactly its cache key."""
        return PrecomputeConfig(**{f.name: getattr(self, f.name) for f in dataclasses.fields(PrecomputeConfig)})

    def cache_key(self) -> dict:
        return self.precompute.cache_key()


@dataclass(frozen=True)
class FrameConfig:
    """Per-frame settings for Engine.render: a new one per change, never mutated (a frame and
    the key it is kept under read the same values)."""

    passes: int | None = None  # shadow maps per frame (None = one per source, the all-sources frame)
    mode: Mode = "hdr"  # hdr: T(L_b - eps); ldr: I_b - sum S_ij M_ij
    fps: float | None = None  # target frame rate: passes from the measured per-pass cost (passes caps it)
    full_maps: bool = False  # cluster maps at the all-sources map size (EngineParams.map_res), not the drag
    # frames' smaller one: Engine.refine's intermediate frames at rest (hard lamp shadows need it)

    def __post_init__(self):
        _check_literals(self)
        _check_frame(self.passes, self.fps)


# Progressive refinement at rest (Engine.refine): before the all-sources frame, one frame of
# REFINE_STEP times the drag frame's passes (one level of the source tree finer), when that is at
# most REFINE_MAX_SHARE of the all-sources frame's maps (else the exact frame comes soon enough) and,
# once both were timed, when it takes less time than the all-sources frame (else it would show
# nothing sooner and only delay the exact frame).
REFINE_STEP = 2
REFINE_MAX_SHARE = 1 / 8


@dataclass
class _Refinement:
    """Engine.refine's state: the frames of one pose at rest (refine_schedule), each composited a
    batch at a time, the last the all-sources frame."""

    key: tuple  # (pose key, mode)
    steps: object  # the generator of Engine._frame_steps of the frame being made
    todo: list = field(default_factory=list)  # FrameConfigs of the frames after it (the last: all sources)
    shown: int = 0  # intermediate frames returned so far
    stage_s: float = 0.0  # compute seconds of the frame being made (refine calls only)
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
class Frame:
    radiance: np.ndarray  # (H,W,3) float32 composite radiance (HDR path estimate)
    pixels: np.ndarray  # (H,W,3) uint8 composite photo
    stats: dict = field(default_factory=dict)
    room: np.ndarray | None = None  # (H,W,3) float32 radiance of the room with the object's effect, object unseen
    coverage: np.ndarray | None = None  # (H,W) float32 share of each pixel the object covers



def _sun_estimate_line(info: dict) -> str:
    """One short line of a sun estimate (lighting.sun.estimate_sun's info; report.json holds it whole)."""
    if "irradiance_perpendicular" not in info:
        return f"sun estimate: no sun ({info.get('reason', 'none found')})"
    line = "sun estimate: direction ({:.3f}, {:.3f}, {:.3f}), irradiance ({:.3g}, {:.3g}, {:.3g})".format(
        *info["direction"], *info["irradiance_perpendicular"])
    if "direction_error_deg" in info:
        line += f"; {info['direction_error_deg']:.2f} deg and {info['strength_ratio']:.2f}x against the declared sun"
    return line


class Engine:
    """Owns one scene's precomputed data and composites object poses into its photo."""

    def __init__(self, scene: Scene, params: EngineParams | None = None, cache_dir: str | Path | None = None,
                 device: str | None = None, quiet: bool = False, photo_priors=None, progress=None):
        """progress: optional callable(done, total) during the precompute (transfer rows; called with
        (total, total) once the engine is ready, also on a cache hit), from the constructing thread."""
        self.scene = scene
        self._progress = progress
        self.params = params or EngineParams()  # frozen, validated when made
        self.device = runtime.device(device)
        self.quiet = quiet
        self.photo_priors = photo_priors  # lighting "photo": lighting.photolight.PhotoPriors (None: defaults)
        self.cache_dir = Path(cache_dir) if cache_dir else None
        self.n_precompute = 0  # per-scene work done, not read from the cache (precompute, shafts, SH volume):
        # no frame may add to it
        self.n_cache_loads = 0  # per-scene artefacts read from the cache: no frame may add to it either
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
            scene_precompute.need_declared(scene)  # captured: the probe gives the response and the emitters
        self.pre, self.cache_hit = self._precompute()
        self._setup()
        self.compose = self._compose_stage()  # per-scene tables and per-frame buffers of the compose stage
        self._refining: _Refinement | None = None  # refine(): the pose being refined
        self._frames_started = 0  # frames begun (render and refine): refine restarts after another
        self._rest_s: dict[str, float] = {}  # refine's last measured compute seconds: "finer", "exact" frame
        self.room_light  # the SH volume is per-scene work too
        self.precompute_s = time.perf_counter() - t0
        if progress is not None:
            progress(self._progress_total, self._progress_total)

    # ------------------------------------------------------------------ precompute
    def _precompute(self) -> tuple[Precomputed, bool]:
        """The scene precompute (app.stages.precompute), from the cache when its key is there."""
        cfg, scene = self.params.precompute, self.scene
        patches = scene_precompute.scene_patches(scene, cfg)
        self.scene_occ, self.cam_occ = scene_precompute.scene_occluders(scene, patches, self.device)
        self._sun_init(patches)
        pre, hit, self._progress_total = scene_precompute.precompute(
            scene, cfg, patches, self.scene_occ, self.cam_occ, device=self.device, cache_dir=self.cache_dir,
            probe=self.probe, sun_patch_light=lambda: self._sun_patch_light() if self.sun_light is not None
            and self.sun_light.active else None, progress=self._progress, quiet=self.quiet)
        self._count(hit)
        self._use_lighting(pre)
        return pre, hit

    def _count(self, hit: bool) -> None:
        """Count one per-scene artefact: read from the cache (hit) or built (real per-scene work)."""
        if hit:
            self.n_cache_loads += 1
        else:
            self.n_precompute += 1

    def _use_lighting(self, pre: Precomputed) -> None:
        """Make the patch mesh carry the reflectivity and emitter radiance the precompute used."""
        scene_precompute.use_lighting(pre, self.params.lighting, self._fit_photo_light)

    def _photo_scene(self, scene: Scene) -> Scene:
        """The scene with the assumed response and the model's emitters of unknown strength
        (lighting.photolight.prepare_scene); the declared emitters are kept for the report only."""
        from lighting.photolight import prepare_scene

        scene, declared = prepare_scene(scene, self.photo_priors)
        self.photo_light = {"declared_emitters_unused": declared}
        return scene

    def _fit_photo_light(self, pre: Precomputed) -> None:
        """Radiance mesh from the photo alone into `pre` (B, albedo, origin), report in photo_light."""
        report = scene_precompute.fit_photo_light(pre, self.scene, self.params.bounces, self.photo_priors)
        self.photo_light = {**report, **{k: v for k, v in self.photo_light.items() if k.startswith("declared")}}
        log.debug("photo light: %s", {k: v for k, v in self.photo_light.items() if k != "warnings"})

    def _setup(self) -> None:
        """Per-scene arrays derived from the precompute, shared by every frame."""
        pre, pm, scene = self.pre, self.pre.patches, self.scene
        dev = self.device
        cam = scene.camera
        b = self.params.bounces
        self.B_src = pre.B[b - 1]  # what receivers gather (one bounce less than the camera sees)
        self.B_obj = pre.B[max(b - 2, 0)]  # light that reaches the camera via the object has one bounce less
        rm = receiver_map(scene, pre, self.B_src)  # pixels <-> receiver vertices (app.stages.receiver_map)
        self.dirs, self.L_b, self.L_b_levels = rm.dirs, rm.L_b, rm.L_b_levels  # (H*W,3) rays, photo radiance, T(L_b)
        self.pix_patch, self.pix_rows, self.pix_pos = rm.pix_patch, rm.pix_rows, rm.pix_pos
        self.recv_pix = rm.recv_pix  # seen non-emitter surface with all three receiver vertices known
        self.E_v, self.E_x = rm.E_v, rm.E_x  # irradiance/pi at receiver vertices and per receiver pixel
        self._sun_setup_pixels()  # sun: its direct light joins E_x; clipped sunlit pixels get model radiance
        self.rho_x = reflectance(self.L_b, self.E_x)
        if self.sun_pix is not None:
            self.rho_x[self.sun_clipped] = self.sun_rho_clipped
        self._room_light = None
        t0 = time.perf_counter()
        p = self.params
        key = scene_precompute.shadow_sources_key(pre, self.B_src, p.source_fraction, p.leaf_size,
                                                  p.shaft_threshold) if self.cache_dir is not None else ""
        self.shadow_sources, hit = scene_precompute.shadow_sources(
            pre, self.B_src, p.source_fraction, p.leaf_size, p.shaft_threshold,
            scene_precompute.cache_file(self.cache_dir, scene, "shafts-", key))
        self._count(hit)
        # each receiver vertex's pixel footprint (the representatives' key counts the light the camera sees)
        vert_pixels = np.bincount(self.pix_rows[self.recv_pix].ravel(), pre.pix_bary[self.recv_pix].ravel(),
                                  len(pre.recv_vert))
        self.shadow_sources.use_receivers(pm.vert_pos[pre.recv_vert], dev, vert_pixels)
        self.shaft_build_s = time.perf_counter() - t0  # built, or read from the cache (hit)
        # the single-source transfer table the all-sources frame reads (made here: cheaper than reading it)
        self.shadow_sources.keep_single_transfers(functools.partial(split_launches, device=dev, min_items=64))
        self.single_table_s = time.perf_counter() - t0 - self.shaft_build_s
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
        # occlusion masks (app.stages.shadow_pass): exact near the object and on a lattice farther out
        self.shadow_pass = ShadowPass(self.pix_pos, self.pix_rows, pre.pix_bary, self.pix_patch, self.recv_pix, pm,
                                      len(pre.recv_vert), cam.width, cam.height, self.params.batch,
                                      self.params.map_res, dev, quiet=self.quiet)

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
        """Progressive refinement at rest: advance the frames of this pose at rest (refine_schedule:
        intermediate frames, then the all-sources frame in config's mode) by batches of shadow maps
        for about `budget_s` seconds (None: to the end). config.passes is the budget of the frame
        shown while dragging (it sets the intermediate frames; None: none). Returns a frame as soon
        as one is complete: an intermediate frame (stats["exact"] False; with budget_s None none is
        made, the call goes straight on to the all-sources frame), or the all-sources frame (stats["exact"] True, again at once on
        later calls for the same pose); None when the call completed no frame. A call for another
        pose or mode starts over, and so does a call after another frame was rendered in between (it
        re-aims the shared shadow maps and BVHs). Its stats add refine_s (compute in refine calls so
        far), refine_calls and refine_frames (intermediate frames returned before it)."""
        config = config or self.frame_config()
        cfg = FrameConfig(None, config.mode)  # every source, no --fps budget
        key = (_pose_key(obj), cfg.mode)
        st = self._refining
        if st is not None and st.frame is None and st.frames_seen not in (-1, self._frames_started):
            # another frame ran since the last step: it re-aimed the shared shadow maps and the object's
            # BVHs at its own pose, so this one starts over
            st = None
        if st is None or st.key != key:
            first, *todo = self.refine_schedule(obj, config)
            self._refining = st = _Refinement(key, self._frame_steps(obj, first), todo)
        if st.frame is not None:
            return st.frame
        if budget_s is None and st.todo:  # to the end: no intermediate frame would be shown, skip them
            st.steps, st.todo = self._frame_steps(obj, st.todo[-1]), []
        t0 = time.perf_counter()
        cost = self._cost  # gaps between calls must not enter the --fps cost model
        st.calls += 1
        out = None
        mark = t0
        try:
            while True:
                try:
                    next(st.steps)
                except StopIteration as done:
                    now = time.perf_counter()
                    self._rest_s["finer" if st.todo else "exact"] = st.stage_s + now - mark  # refine_schedule's
                    st.stage_s, mark = 0.0, now
                    if not st.todo:
                        st.frame = out = done.value
                        break
                    st.steps = self._frame_steps(obj, st.todo.pop(0))  # the next frame of the schedule
                    if budget_s is not None:  # show the intermediate frame now
                        out = done.value
                        out.stats.update(exact=False, refine_frames=st.shown)
                        st.shown += 1
                        break
                    continue
                if budget_s is not None and time.perf_counter() - t0 >= budget_s:
                    break
        except BaseException:
            self._refining = None
            raise
        finally:
            self._cost = cost
            now = time.perf_counter()
            st.compute_s += now - t0
            st.stage_s += now - mark
            st.frames_seen = self._frames_started
        if out is st.frame and out is not None:
            out.stats.update(exact=True, refine_frames=st.shown)
        if out is not None:
            out.stats.update(refine_s=st.compute_s, refine_calls=st.calls)
        return out

    def refine_schedule(self, obj: SceneObject, config: FrameConfig | None = None) -> list[FrameConfig]:
        """The frames Engine.refine makes of `obj`'s pose at rest, in order: the last is the
        all-sources frame; before it, when the drag budget config.passes is set, a frame of
        REFINE_STEP x that many passes on maps of the all-sources size, if that is at most
        REFINE_MAX_SHARE of the pose's listed sources (a cluster frame that fine is within a few
        hundredths of the all-sources rmse on the benchmark rooms and costs a fraction of it;
        bench/bench_interactive.py --refine measures both), and unless the last such frame refine
        made took at least the time of the last all-sources frame it made (then it would show no
        quality sooner, only delay the exact frame). Per pose: a traversal of the shafts with the
        object's box (no per-scene work)."""
        config = config or self.frame_config()
        out = [FrameConfig(None, config.mode)]
        if config.passes is None or self.shadow_sources.empty:
            return out
        t = self._rest_s
        if "finer" in t and "exact" in t and t["finer"] >= t["exact"]:
            return out
        n = REFINE_STEP * config.passes
        listed = int(self.shadow_sources.traverse(obj.vertices.min(0), obj.vertices.max(0))[0].sum())
        if n <= REFINE_MAX_SHARE * listed:
            out.insert(0, FrameConfig(n, config.mode, full_maps=True))
        return out

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
        centre, radius = bounding_sphere(pv)
        t = tick("proxy", t)

        # ---- object pixels: coverage and depth against the scene model
        hits = self._object_hits(shade_mesh[0], shade_mesh[2], occluder=shade_occ)
        cov = hits.coverage()
        t = tick("object", t)

        # ---- source list from the shaft hierarchy, grouped into the frame's passes (sec. 6.2.1, 6.4)
        fs = self.shadow_sources.select(pv.min(0), pv.max(0), self._passes_for_frame(p),
                                        functools.partial(split_launches, device=self.device, min_items=64))
        eyes, W_v, W_c, cand = fs.eyes, fs.W_v, fs.W_c, fs.cand
        t = tick("sources", t)

        # ---- occlusion masks: listed pixels and patch centres (app.stages.shadow_pass; yields per batch)
        if p.mode == "ldr":
            S_v = self._ldr_weights(W_v)
        n_src = len(eyes)
        masks = yield from self.shadow_pass.run((pv, pf, proxy_occ), centre, radius, cov, cand, eyes,
                                                S_v if p.mode == "ldr" else W_v, W_c, fs.n_listed == n_src,
                                                spread=fs.spread, full_maps=config.full_maps,
                                                scale=self.L_b_levels if p.mode == "ldr" else self.E_x)
        pix_sel, fill_sel, cen_sel, O_pix, O_cen = (masks.pix_sel, masks.fill_sel, masks.cen_sel, masks.O_pix,
                                                    masks.O_cen)
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
                                                    self._obj_sun_vis, obj.albedo, cov, obj_rad, self.sun_photo_clip)
        t = tick("object_shading", t)

        # ---- light the object reflects, onto pixels and patch centres
        R_pix = np.zeros((H * W, 3))
        R_cen = np.zeros((pm.n_patches, 3))
        if p.object_light:
            tri_rad = self._object_triangle_radiance(obj, pv, pf, proxy_occ, self.B_obj + dB_shadow)
            extra = None
            room_tri_rad = tri_rad
            if self.sun_pix is not None:  # sun: the object's sunlit parts light the room too (small pieces)
                tri_rad, extra = self.sun_stage.object_emitters(pv, pf, tri_rad, obj.albedo, proxy_occ, radius)
            if self.sun_pix is None:
                R_pix, R_cen = self._object_light(pv, pf, tri_rad, proxy_occ, centre, radius,
                                                  cov.reshape(-1) >= 1.0, extra)
            else:  # sun: the object's light at the patches in two parts, the room's and the sun's alone (the
                # latter's later bounces: SunStage.later_bounces), summed: one pass over the proxy's faces
                R_pix, _ = object_light.object_light(self, pv, pf, tri_rad, proxy_occ, centre, radius,
                                                     cov.reshape(-1) >= 1.0, extra, centres=False)
                R_cen_room, R_cen_sun = object_light.centre_light_parts(self, pv, pf, room_tri_rad,
                                                                        tri_rad - room_tri_rad, proxy_occ, centre,
                                                                        radius, extra)
                R_cen = R_cen_sun + R_cen_room
        t = tick("object_light", t)

        # ---- second order: change of patch radiance, passed on once to receiver vertices (app.stages.compose)
        dE_v = None
        if p.second_order:
            more = None
            dB = dB_shadow + pm.albedo * R_cen
            if sun_loss is not None:  # sun: the sunlit patch light the object blocks (the room's main
                # source) and the sunlit object's own light are passed on for the bounces each has left,
                # not once (the later ones at the receiver vertices directly), the loss not counted twice
                # where the object also hides the shadowed floor (SunStage.later_bounces)
                more = self.sun_stage.later_bounces(
                    self._sun_dB, pm.albedo, pre.G_c, pre.G_v, p.bounces,
                    dB2=pm.albedo * R_cen_sun if p.object_light else None, occluder=proxy_occ,
                    recv_points=pm.vert_inset[pre.recv_vert], box=(pv.min(0) - 1e-3, pv.max(0) + 1e-3),
                    split=functools.partial(split_launches, device=self.device, min_items=256), first=dB,
                    onto=dB,  # its later bounces too: compose's one pass through G_v carries them
                    obb=upright_box(pv))  # the object turned on the floor: fewer rays, the same answer
            dE_v = self.compose.second_order(dB, dE_more=more)
        t = tick("second_order", t)

        # ---- compose (app.stages.compose): HDR or LDR, on the pixels that changed
        radiance, pixels, room = self.compose.frame(p.mode, pix_sel, O_pix, fill_sel, self._fill, R_pix, dE_v, cov,
                                                    obj_rad, self.sun_pix, sun_loss)
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
        if self.sun_light is not None:  # sun: the one used (EngineParams.sun)
            stats["sun"] = self.sun_report
        if calibration_s:
            stats["fps_calibration_s"] = calibration_s
        self._last_shading = (shade_mesh, self._last_L_vert, obj.albedo) if hits.hit.any() else None
        return Frame(radiance, pixels, stats, room, cov.astype(np.float32))

    # ------------------------------------------------------------------ pieces
    def _object_shape(self, obj: SceneObject):
        """object_shading.object_shape (app/stages/object_shading.py)."""
        return object_shading.object_shape(self, obj)

    def _object_hits(self, verts: np.ndarray, faces: np.ndarray, camera=None, supersample: int | None = None,
                     occluder: Occluder | None = None) -> "ObjectHits":
        """object_shading.object_hits (app/stages/object_shading.py)."""
        return object_shading.object_hits(self, verts, faces, camera=camera, supersample=supersample, occluder=occluder)

    @property
    def room_light(self) -> RoomLight:
        """SH9 volume of the indirect light plus the emitters (built on first use, ~2-5 s)."""
        if self._room_light is None:
            pm, sc, spacing = self.pre.patches, self.scene, self.params.volume_spacing
            key = scene_precompute.room_light_key(pm, self.B_src, sc.room_min, sc.room_max, self.scene_occ,
                                                  spacing) if self.cache_dir is not None else ""
            self._room_light, hit = scene_precompute.room_light(
                pm, self.B_src, sc.room_min, sc.room_max, self.scene_occ, spacing, self.device,
                scene_precompute.cache_file(self.cache_dir, sc, "sh-", key))
            self._count(hit)
        return self._room_light

    def object_vertex_radiance(self, obj: SceneObject, mesh, proxy_occ: Occluder,
                               dB: np.ndarray | None = None) -> np.ndarray:
        """object_shading.vertex_radiance (app/stages/object_shading.py)."""
        return object_shading.vertex_radiance(self, obj, mesh, proxy_occ, dB)

    def _self_transfer(self, v: np.ndarray, n: np.ndarray, f: np.ndarray):
        """object_shading.self_transfer_cached (app/stages/object_shading.py)."""
        return object_shading.self_transfer_cached(self, v, n, f)

    def _shade_object(self, obj: SceneObject, mesh, hits: "ObjectHits", proxy_occ, dB: np.ndarray) -> np.ndarray:
        """object_shading.shade_object (app/stages/object_shading.py)."""
        return object_shading.shade_object(self, obj, mesh, hits, proxy_occ, dB=dB)

    def specular_map(self, centre: np.ndarray) -> CubeMap:
        """object_shading.specular_map (app/stages/object_shading.py)."""
        return object_shading.specular_map(self, centre)

    def _fill(self, known: np.ndarray, values: np.ndarray, missing: np.ndarray, out=None) -> np.ndarray | None:
        """Values (len(missing),3) at pixels `missing`: mean of the known pixels in their 3x3
        window that lie on the same quad (ShadowPass.fill; a reused buffer, use it at once; or
        written into `out` at their pixels: the compose stage's buffer)."""
        return self.shadow_pass.fill(known, values, missing, out=out)

    def _object_triangle_radiance(self, obj: SceneObject, pv, pf, proxy_occ, B: np.ndarray) -> np.ndarray:
        """object_light.triangle_radiance (app/stages/object_light.py)."""
        return object_light.triangle_radiance(self, obj, pv, pf, proxy_occ, B)

    def _object_light(self, pv, pf, tri_rad, proxy_occ, centre, radius, covered=None, extra=None):
        """object_light.object_light (app/stages/object_light.py)."""
        return object_light.object_light(self, pv, pf, tri_rad, proxy_occ, centre, radius, covered, extra)

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
        """The scene's sun seen through its openings (None without a sun), and which sun is used
        (sun_from, EngineParams.sun): known light lights the precompute with the declared sun;
        captured light takes the declared one or the estimate in _sun_captured, after it."""
        sun = self.scene.sun
        self.sun_light = None
        self._sun_patch = None
        self._sun_pm = patches
        self.sun_from = self._sun_source()
        if self.sun_from == "declared" and self.params.lighting == "known":
            self.sun_light = SunLight(sun, openings(self.scene), self.scene_occ, where=f"{self._sun_where}: sun")

    @property
    def _sun_where(self) -> str:
        return str(self.scene.meta.get("json_path", self.scene.name))

    def _sun_source(self) -> str | None:
        """"declared" (scene.json's sun), "estimate" (captured or photo light: from the photo) or None (no
        sun) for EngineParams.sun under this lighting; ValueError when --sun declared has no sun entry."""
        sun, choice, lighting = self.scene.sun, self.params.sun, self.params.lighting
        if choice == "declared" and sun is None:
            raise ValueError(f"{self._sun_where}: --sun declared: the scene has no sun entry (`photoar scene "
                             "--sun-direction/--sun-irradiance` writes one)")
        if lighting == "known":
            if sun is not None and sun.strength_estimated:
                raise ValueError(f"{self._sun_where}: sun: its strength is to be estimated from the photo "
                                 "(\"strength\": \"estimate\"): use --lighting captured, or give `photoar scene "
                                 "--sun-irradiance`")
            return "declared" if sun is not None else None
        if lighting == "captured":
            if choice == "auto":
                user = sun is not None and self.scene.meta.get("sun_declared_by") == SUN_DECLARED_BY_USER
                return "declared" if user else "estimate"
            return choice
        return "estimate"  # photo: from the photo alone (_sun_captured, as captured light's estimate)

    @property
    def sun_report(self) -> dict:
        """The sun used (report.json "sun"): from "declared" or "estimate", its unit direction towards
        the sun (world, +Y up), irradiance_perpendicular (RGB, scene radiance units x sr), and whether
        it lights some surface (lights_room; else no_direct_sun says why)."""
        sun = self.sun_light.sun
        d = {"from": self.sun_from, "direction": (sun.direction / np.linalg.norm(sun.direction)).tolist(),
             "irradiance_perpendicular": np.asarray(sun.irradiance, float).tolist(), "lights_room": bool(self.sun_on)}
        if self.sun_from == "declared" and self.scene.sun.strength_estimated:
            d["strength_from"] = "estimate"  # the declared direction, the strength estimated from the photo
        if self.sun_light.reason:
            d["no_direct_sun"] = self.sun_light.reason
        return d

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
        if self.params.lighting in ("captured", "photo"):  # the sun estimated from the photo (no probe: photo)
            self._sun_captured()
            if self.params.lighting == "photo":
                self._photo_sun_report()
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
                                  self.sun_c_pts, self.sun_c_vis, pm.n_patches, self.device, patches=pm)

    def _photo_sun_report(self) -> None:
        """Photo light with openings: photo_light["sun"] says whether the sun estimated from the photo
        (sun_estimate, as with captured light) lights the room and how many patches it lights (the
        fit's clipped-region emitters among them are sunlit reflectors instead); a declared sun that
        the photo does not show is warned about (it is never used)."""
        if not openings(self.scene):
            return
        lit = self._sun_patch_light().any(1)
        self.photo_light["sun"] = {"modelled": bool(self.sun_on), "sunlit_patches": int(lit.sum()),
                                   "estimate": "sun_estimate"}
        lit_quads = {self.scene.quads[q].name for q in np.unique(self._sun_pm.quad[lit])}
        for em in self.photo_light.get("emitters", []):  # clipped regions the sun explains
            name, clip = em["name"].removesuffix(" (clipped region)"), em["name"].endswith(" (clipped region)")
            if clip and name in lit_quads:
                em["sunlit_reflector"] = True  # its sunlit patches reflect the sun, they do not emit
        if not self.sun_on and self.scene.sun is not None:
            reason = (self.sun_estimate or {}).get("reason", "its estimate lights no surface")
            log.warning("%s: sun: --lighting photo found no sun in the photo (%s); the "
                        "declared sun is not used", self._sun_where, reason)

    def _sun_captured(self) -> None:
        """Captured light: the sun estimated from the photo and the radiance mesh (lighting.sun
        .estimate_sun) replaces the declared one; the sunlit patches take the reflectivity of their
        surface's unlit patches. The declared sun, if any, is only reported against."""
        pre, pm, scene = self.pre, self.pre.patches, self.scene
        if not openings(scene):
            self.sun_light = None
            if scene.sun is not None:  # a sun with no way in (lighting.sun.no_sun_reason)
                log.warning("%s", no_sun_reason(scene.sun.direction, scene.sun.irradiance, [],
                                                f"{self._sun_where}: sun"))
            return
        sat = np.any(scene.photo.reshape(-1, 3) >= 255, axis=1)
        # the captured radiance flags the sunlit patch as an emitter (brighter than the mesh, which
        # holds no sun, can light it); the sun is looked for on every surface but windows and lamps
        shaped = np.array([q.light_shaped for q in scene.quads], bool)[pm.quad]
        recv_any = (pre.pix_tri >= 0) & (self.pix_rows.min(1) >= 0) & ~shaped[np.maximum(self.pix_patch, 0)]
        flagged = pm.is_emitter & ~shaped  # plain surfaces the radiance test flagged: tried as sunlit
        kept = pm.emission[flagged].copy()
        pm.emission[flagged] = 0.0
        if self.sun_from == "declared" and scene.sun.strength_estimated:  # its direction; strength from the photo
            sun, info = estimate_sun(scene, pm, self.pix_patch, self.pix_pos.astype(np.float64), self.dirs, self.L_b,
                                     sat, recv_any, pre.B[-1], pre.G_c, self.scene_occ, direction=scene.sun.direction)
            where = f"{self._sun_where}: sun (strength estimated)"
        elif self.sun_from == "declared":  # the user's sun as given (--sun); no estimate
            sun, info, where = scene.sun, None, f"{self._sun_where}: sun"
        else:
            sun, info = estimate_sun(scene, pm, self.pix_patch, self.pix_pos.astype(np.float64), self.dirs, self.L_b,
                                     sat, recv_any, pre.B[-1], pre.G_c, self.scene_occ)
            where = f"{self._sun_where}: sun estimate"
        self._sun_patch = None
        self.sun_light = SunLight(sun, openings(scene), self.scene_occ, where=where) if sun else None
        if sun is None and self.sun_from == "declared":
            log.warning("%s: its strength could not be estimated from the photo (%s): no direct sun; give "
                        "`photoar scene --sun-irradiance`", where, info.get("reason"))
        if info is not None and sun is not None and scene.sun is not None and not scene.sun.strength_estimated:
            d0 = scene.sun.direction / np.linalg.norm(scene.sun.direction)
            info["declared_direction"] = d0.tolist()
            info["direction_error_deg"] = float(np.degrees(np.arccos(np.clip(sun.direction @ d0, -1, 1))))
            info["declared_irradiance_perpendicular"] = scene.sun.irradiance.tolist()
            info["strength_ratio"] = float(luminance(sun.irradiance) / max(luminance(scene.sun.irradiance), 1e-12))
        if info is not None:
            self.sun_estimate = info
            log.info("%s", _sun_estimate_line(info))
            log.debug("sun estimate: %s", info)
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
        """Intensity transfers S_ij (Vr,S,3) in levels at receiver vertices (fig. 13; app.stages.compose)."""
        return self.compose.ldr_weights(W_v)

    def _compose_stage(self) -> ComposeStage:
        """The compose stage over this scene's per-pixel arrays (after _setup: the sun's changes are in)."""
        pre, cam = self.pre, self.scene.camera
        return ComposeStage(L_b=self.L_b, L_b_levels=self.L_b_levels, E_x=self.E_x, rho_x=self.rho_x,
                            recv_pix=self.recv_pix, pix_rows=self.pix_rows, pix_bary=pre.pix_bary,
                            photo=self.scene.photo, response=self.scene.response, G_v=pre.G_v, E_v=self.E_v,
                            recv_vert=pre.recv_vert, patches=pre.patches, shape=(cam.height, cam.width),
                            device=self.device)


