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

A drag frame (FrameConfig.drag = s, app.dragframe) runs the room's per-pixel stages at 1/s resolution
(HDR) and brings the room's ratio to the photo back bilinearly; the object, the sun's pass and the
per-patch work stay the full frame's. Frames at rest (drag None) never use it.
"""
from __future__ import annotations

import dataclasses
import functools
import logging
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from app.config import (LIGHTING, SUN_SOURCES, EngineParams, FrameConfig, Lighting, Mode,  # noqa: F401
                        ObjectConfig, PrecomputeConfig, ShadowConfig, SunSource)  # (re-exported)
from app.dragframe import DragStages, sphere_stages, uses_spheres
from app.frame_budget import FrameBudget
from app.glue import FrameTimer
from app.progressive import REFINE_MAX_SHARE, REFINE_STEP, Refiner, finer_near_split  # noqa: F401 (re-exported)
from app.rest_maps import RestMaps
from app.runtime import split as split_launches  # the two-core split (sources: kernels of few, long items)
from app.stages import precompute as scene_precompute
from app.stages.compose import ComposeStage
from app.stages.object_light import ObjectLight
from app.stages.object_drag import DragObject
from app.stages.object_shading import ObjectShading
from app.stages.precompute import Precomputed, hash_scene as _hash_scene  # noqa: F401 (re-exported)
from app.stages.receiver_map import ReceiverMap, receiver_map, reflectance
from app.stages.shadow_pass import ShadowPass
from app.stages.sun import SunPixels, SunSetup, estimate_line as _sun_estimate_line, upright_box  # noqa: F401
from app.stages.second_order import BlockedSecondOrder
from kernels import runtime
from lighting.irradiance import RoomLight
from lighting.radiance import GATHERED, load_captured_probe, probe_shadowed
from recon.proxy import bounding_sphere
from recon.scene import Scene, SceneObject

log = logging.getLogger("photoar")


@dataclass
class Frame:
    radiance: np.ndarray  # (H,W,3) float32 composite radiance (HDR path estimate)
    pixels: np.ndarray  # (H,W,3) uint8 composite photo
    stats: dict = field(default_factory=dict)
    room: np.ndarray | None = None  # (H,W,3) float32 radiance of the room with the object's effect, object unseen
    coverage: np.ndarray | None = None  # (H,W) float32 share of each pixel the object covers


class Engine:
    """Owns one scene's precomputed data and its stages, and composites object poses into its photo."""

    # captured light in a sunlit room: the unmeasured sunlit patches' model radiance as sources too (class
    # default; bench_sun_energy --captured-sun-sources off sets it False for an A/B)
    captured_sun_sources = True

    def __init__(self, scene: Scene, params: EngineParams | None = None, cache_dir: str | Path | None = None,
                 device: str | None = None, quiet: bool = False, photo_priors=None, progress=None):
        """progress: optional callable(done, total) during the precompute (transfer rows; called with
        (total, total) once the engine is ready, also on a cache hit), from the constructing thread.
        photo_priors: lighting "photo"'s lighting.photolight.PhotoPriors (None: defaults)."""
        t0 = time.perf_counter()
        self.params = p = params or EngineParams()  # frozen, validated when made
        self.device = dev = runtime.device(device)
        self.cache_dir = Path(cache_dir) if cache_dir else None
        self.n_precompute = 0  # per-scene work done, not read from the cache (precompute, shafts, SH volume):
        # no frame may add to it
        self.n_cache_loads = 0  # per-scene artefacts read from the cache: no frame may add to it either
        self.photo_light: dict = {}  # lighting "photo": the fit's report (lighting.photolight)
        probe = None
        if p.lighting == "captured":
            # the camera response comes from the probe bracket too: nothing declared is used
            probe = load_captured_probe(scene, scene_precompute.cached_probe_response(self.cache_dir, scene))
            scene = dataclasses.replace(scene, response=probe.response)
        elif p.lighting == "photo":
            from lighting.photolight import prepare_scene

            scene, declared = prepare_scene(scene, photo_priors,
                                            scene_precompute.cached_probe_response(self.cache_dir, scene))
            self.photo_light = {"declared_emitters_unused": declared}
        elif p.lighting == "known" and (scene.response is None or scene.meta.get("emitters_without_radiance")):
            scene_precompute.need_declared(scene)  # captured: the probe gives the response and the emitters
        self.scene = scene

        # ---- the scene precompute (app.stages.precompute), from the cache when its key is there
        patches = scene_precompute.scene_patches(scene, p.precompute)
        self.scene_occ, self.cam_occ = scene_precompute.scene_occluders(scene, patches, dev)
        self.sun = SunSetup(scene, p.lighting, p.sun, self.scene_occ, patches)  # which sun, if any
        pre, self.cache_hit, total = scene_precompute.precompute(
            scene, p.precompute, patches, self.scene_occ, self.cam_occ, device=dev, cache_dir=self.cache_dir,
            probe=probe, sun_patch_light=lambda: self.sun.patch_light() if self.sun.light is not None
            and self.sun.light.active else None, progress=progress, quiet=quiet)
        self._count(self.cache_hit)
        scene_precompute.use_lighting(pre, p.lighting, functools.partial(self._fit_photo_light, priors=photo_priors))

        # ---- per-scene arrays: the receiver map, with the sun's changes (app.stages.receiver_map, sun)
        def relit(pre: Precomputed, bounces: int | None = None) -> tuple[np.ndarray, ReceiverMap]:
            """(B_src, receiver map) of `pre`, with the sun set up again from them (a refit changed B)."""
            B_src = pre.B[p.bounces - 1]
            rm = receiver_map(scene, pre, B_src)
            self.sun = SunSetup(scene, p.lighting, p.sun, self.scene_occ, pre.patches, bounces=bounces)
            self.sun_pixels = self.sun.apply(pre, rm, dev)
            return B_src, rm

        B_src = pre.B[p.bounces - 1]  # what receivers gather (Engine.B_src)
        rm = receiver_map(scene, pre, B_src)
        self.sun_pixels: SunPixels = self.sun.apply(pre, rm, dev)
        if p.lighting == "photo" and self.sun.on:  # the sun found: its out-of-view sunlit patches join the fit's
            # clipped regions (lighting.photolight._sunlit_unseen), with PhotoPriors.sun_bounces the fit and the sun's
            # strength take the camera's bounce count (_sun_bounces), and the fit and the sun are made again
            sunlit = self.sun.sun_share()
            sun_priors, levels = self._sun_bounces(photo_priors)
            refit = self._refit_sunlit(pre, sunlit, sun_priors, force=levels > 0)
            # the sunlit level from its penumbra (lighting.sunramp), where it reads below the walls' fit's
            pinned, ramp_report = self._sunlit_levels(pre, rm, photo_priors)
            if pinned:
                refit = self._refit_sunlit(pre, sunlit, sun_priors, force=True, pinned=pinned)
            if refit:
                B_src, rm = relit(pre, levels or None)
            if ramp_report:
                self.photo_light["sunlit_levels"] = ramp_report
        if p.lighting == "captured" and self.captured_sun_sources and self.sun.on:
            # the sunlit patches neither the photo nor the probe sees (lighting.radiance's GATHERED: their radiance
            # gathered from the room without the sun) carry the sun's model radiance rho (E_ind + E_sun)
            # (SunSetup.object_radiance) as the room's sources and in E_x too, not only as the object's light:
            # else the object hides about 0.1x of their light from the walls (docs/unseen.md "glow110b")
            # and so do those the probe's ball shades from the sun in its own image (probe_shadowed: the probe
            # sees its own sun shadow there, not the empty room's sunlit floor)
            unmeasured = (np.asarray(pre.origin) == GATHERED) | probe_shadowed(
                pre.patches.corners, probe.light_probe, self.sun.light.d)
            B_mod = np.where(unmeasured[:, None], self.sun.object_radiance(pre, B_src), B_src)
            if not np.array_equal(B_mod, B_src):
                pre = dataclasses.replace(pre, B=np.stack([B_mod] * len(pre.B)))
                B_src, rm = relit(pre)
        if p.lighting == "photo":
            self.photo_light = self.sun.photo_report(self.photo_light)
        sp = self.sun_pixels
        self.pre_lit = pre  # the precompute before the sun's changes (app.dragframe builds its own from it)
        self.pre = pre = dataclasses.replace(pre, patches=sp.patches)
        self.receivers: ReceiverMap = dataclasses.replace(
            rm, recv_pix=sp.recv_pix, E_x=sp.E_x, L_b=sp.L_b, rho_x=sp.reflectance(reflectance(sp.L_b, sp.E_x)))

        # ---- the stages, each built once from data and its config block
        self.seconds = {"precompute": 0.0}  # per-scene build times: precompute (all), shafts, single_table
        self.shadow_sources = self._shadow_sources(B_src)
        r, cam, pm, oc, sc = self.receivers, scene.camera, pre.patches, p.object, p.shadow
        self.shadow_pass = ShadowPass(r.pix_pos, r.pix_rows, pre.pix_bary, r.pix_patch, r.recv_pix, pm,
                                      len(pre.recv_vert), cam.width, cam.height, sc.batch, sc.map_res, dev, quiet=quiet)
        self.compose = ComposeStage(L_b=r.L_b, L_b_levels=r.L_b_levels, E_x=r.E_x, rho_x=r.rho_x, recv_pix=r.recv_pix,
                                    pix_rows=r.pix_rows, pix_bary=pre.pix_bary, photo=scene.photo,
                                    response=scene.response, G_v=pre.G_v, E_v=r.E_v, recv_vert=pre.recv_vert,
                                    patches=pm, shape=(cam.height, cam.width), device=dev)
        # the object gathers the room from the measured radiance, with the sun's model radiance on the
        # sunlit patches the photo does not measure (SunSetup.object_radiance), and the sunlit patches
        # gathered exactly, not through the SH volume (B_src and the volume alone without a sunlit patch)
        B_lit, near = self.sun.object_radiance(pre, B_src), self.sun.sunlit_patches()
        self.room_light = self._room_light(np.where(near[:, None], 0.0, B_lit) if near.any() else B_lit,
                                           oc.volume_spacing)  # SH9 volume of the indirect light
        # photo light: the fitted emitters' strength at the object, read off the surfaces around it
        local = self._local_light(pre, B_lit, near) if p.lighting == "photo" else None
        self.room_light.gather_exactly(near, B_lit)
        sun_light = self.sun.light if sp.pix is not None else None  # None: no sun lights the room
        self.object_shading = ObjectShading(oc, cam, self.cam_occ, self.scene_occ, pm, self.room_light, B_lit, dev,
                                            sun=sun_light, local_light=local)
        self.object_light = ObjectLight(oc, pm, pre.recv_vert, pre.pix_bary, r.pix_pos, r.pix_patch, r.pix_rows,
                                        r.recv_pix, r.rho_x, r.L_b, B_src, self.scene_occ, scene.response, cam, dev,
                                        sun_dir=sun_light.d if sun_light is not None else None)
        rv = pre.recv_vert  # the second order's blocked pairs at rest (_blocked_second_order), one Warp launch
        self._blocked = BlockedSecondOrder(pre.G_v, pm.vert_inset[rv], pm.vert_normal[rv], pm.centre, pm.normal,
                                           pm.area, dev)
        # the all-sources frame's map size per source (app.rest_maps; None: every map map_res, for A/B)
        self.rest_maps: RestMaps | None = RestMaps(r.E_v)
        # refine's finer frames in rooms a sun lights: clusters split near the object first (app.progressive.
        # finer_near_split; False: the plain key, for A/B)
        self.rest_near_split = True
        self._drag: dict[int, DragStages] = {}  # drag frames' coarse pixel stages, per scale (made on first use)
        # drag frames shade the object and send its light from per-shape tables (app.stages.object_drag);
        # False: as at rest (bench/bench_drag_object.py's A/B)
        self.drag_object_tables = True
        # in rooms a sun lights too (False: those rooms' drag frames shade the object as at rest)
        self.drag_object_sun = True
        # at rest in a sunlit room the object's faces light each other before their light reaches the room
        # (ObjectLight.self_light): True takes known light's energy to 0.965-1.064 in the five sun rooms off by
        # 5-22 % and matches a brute-force gather (docs/unseen.md "sunglow110"); with captured light's sources fixed
        # (captured_sun_sources) it still takes sun_108 under both lights below its energy bound (captured 0.846 ->
        # 0.768, known 0.979 -> 0.899) and sun_room's captured energy 0.930 -> 0.859 (docs/unseen.md "glow110b"): off
        self.object_self_light = False
        rest = ~pm.is_emitter
        self.object_drag = DragObject(self.object_shading, dev, (pm.area[rest] @ self.B_obj[rest]) / np.maximum(
            pm.area[rest] @ B_src[rest], 1e-30))
        self.budget = FrameBudget()  # --fps: the measured frame cost
        self.frames_started = 0  # frames begun (render and refine): refine restarts after another
        self.refiner = Refiner(self._frame_steps, self.shadow_sources.traverse, self.shadow_sources.empty,
                               lambda: self.frames_started, self.budget)
        self.last_shading: tuple | None = None  # (shading mesh, its vertex radiance, albedo, each vertex's sun
        # share or None) of the last frame that saw the object (app.workres shades the full-resolution photo)
        self.seconds["precompute"] = time.perf_counter() - t0
        if progress is not None:
            progress(total, total)

    # ------------------------------------------------------------------ per-scene pieces
    def _count(self, hit: bool) -> None:
        """Count one per-scene artefact: read from the cache (hit) or built (real per-scene work)."""
        if hit:
            self.n_cache_loads += 1
        else:
            self.n_precompute += 1

    def _fit_photo_light(self, pre: Precomputed, priors=None, sunlit: np.ndarray | None = None,
                         pinned: dict | None = None) -> None:
        """Radiance mesh from the photo alone into `pre` (B, albedo, origin), report in photo_light (`sunlit`,
        `pinned`: lighting.photolight.fit_photo_light's)."""
        report = scene_precompute.fit_photo_light(pre, self.scene, self.params.bounces, priors, sunlit, pinned)
        self.photo_light = {**report, **{k: v for k, v in self.photo_light.items() if k.startswith("declared")}}
        log.debug("photo light: %s", {k: v for k, v in self.photo_light.items() if k != "warnings"})

    def _sun_bounces(self, priors=None):
        """(priors for photo light's fit once a sun is found, the bounce levels the sun's strength takes: 0 none).

        With PhotoPriors.sun_bounces (opt-in): the photo holds the light of `EngineParams.bounces` reflections, the
        camera's hit one of them (../shared/DESIGN.md "Bounces"), so a seen patch reflects its neighbours' light of
        one bounce less than the photo shows them. Gathered at the photo's level, the light between the surfaces
        looks weaker than the walls' albedo gives and the interreflection fit lowers that albedo, the more so the
        brighter the room (sun_104: 0.70x the truth's); the sun's strength from the clipped sunlit patch carries
        that scale to about the power 2.6 (docs/unseen.md "photosun34b"), and the floor's reflectivity, gathered
        the same way, once more (docs "refl108"). So the fit takes bounce_levels = EngineParams.bounces and the
        strength the bounce rule (docs "photo109": right in the bright sun rooms, too dark in the darker ones).
        Without it: the priors as given, 0."""
        from lighting.photolight import PhotoPriors

        pr = priors or PhotoPriors()
        if not pr.sun_bounces:
            return priors, 0
        return dataclasses.replace(pr, bounce_levels=self.params.bounces), self.params.bounces

    def _refit_sunlit(self, pre: Precomputed, sunlit: np.ndarray, priors=None, force: bool = False,
                      pinned: dict | None = None) -> bool:
        """Photo light's fit again with the sunlit patches (`sunlit` (P,): their sun share) that it gathered as
        unseen reflectors joined to their surface's clipped region, and the clipped regions `pinned` ({quad: (3,)
        radiance}, _sunlit_levels) at their measured level; False (nothing done) when none joins and not `force`
        (the priors differ from the first fit's: the bounce levels, _sun_bounces; or a level is pinned)."""
        from lighting.photolight import FITTED

        origin = np.asarray(pre.origin)
        region_q = np.unique(pre.patches.quad[origin == FITTED])
        if not force and not ((sunlit > 0) & (origin == GATHERED) & np.isin(pre.patches.quad, region_q)).any():
            return False
        scene_precompute.use_lighting(pre, self.params.lighting, functools.partial(
            self._fit_photo_light, priors=priors, sunlit=sunlit, pinned=pinned))
        return force or self.photo_light.get("sunlit_unseen_joined", 0) > 0

    def _sunlit_levels(self, pre: Precomputed, rm: ReceiverMap, priors=None
                       ) -> tuple[dict[int, np.ndarray], dict[str, dict]]:
        """Photo light with a sun found: ({quad: (3,) radiance} the sunlit level to pin of each clipped region the sun
        lights, {quad name: sunramp's report, with the walls' fit's level and which one is used}),
        from its own penumbra (lighting.sunramp.sunlit_step: shadow level + the step its unclipped ramp pixels
        give); {} where the ramp gives none (too few unclipped ramp pixels, PhotoPriors.sun_ramp off). The walls'
        fit measures rho_wall x rho_floor x sun, so its region level carries the albedo's scale (docs/unseen.md
        "photosun34b"); the penumbra's does not.

        A level is pinned only where the penumbra reads it below the walls' fit's (self.photo_light, the fit as made
        so far). The fit's large errors have one sign: the photo holds a capped number of bounces, the walls' light
        between them looks weaker than their albedo gives, and the fit lowers the albedo and raises the emitters
        that light them, the more so the brighter the room (photo109: the sunlit floor 1.13-1.63x in the bright
        rooms). Where the fit reads the level lower than the penumbra it also read the floor's reflectivity low by
        about as much, and the sun, their ratio, came out right (0.92-1.03x in sun_101-105); the penumbra's level
        there leaves the reflectivity's error alone in the sun (1.33-1.53x, docs "photosun110"; the shared sun_room
        1.20x -> 1.44x). The one-sided rule: docs "photosun111"."""
        from lighting.photolight import EMITTER_ROLES, FITTED, PhotoPriors
        from lighting.sources import luminance
        from lighting.sun import SunLight, openings
        from lighting.sunramp import sunlit_step

        report: dict[str, dict] = {}
        if not (priors or PhotoPriors()).sun_ramp or self.sun.light is None:
            return {}, report
        scene, pm, sun = self.scene, pre.patches, self.sun.light
        holes = openings(scene)
        pix_quad = np.where(rm.pix_patch >= 0, pm.quad[np.maximum(rm.pix_patch, 0)], -1)
        share = self.sun.sun_share()
        region = (np.asarray(pre.origin) == FITTED) & (share > 0)
        fitted = {e["name"]: np.asarray(e["radiance"], np.float64) for e in self.photo_light.get("emitters", [])}
        out = {}
        for q in np.unique(pm.quad[region]).tolist():
            quad = scene.quads[q]
            if quad.role in EMITTER_ROLES:
                continue
            step = sunlit_step(
                lambda d: SunLight(dataclasses.replace(sun.sun, direction=d), holes, self.scene_occ,
                                   where="sun penumbra"),
                scene.camera, scene.photo, rm.L_b, pix_quad, rm.pix_pos, rm.pix_patch >= 0, q,
                (quad.corners[0], quad.normal), sun.d)
            if step is None:
                log.debug("photo light: %s: no sunlit level from its penumbra", quad.name)
                continue
            fit = fitted.get(f"{quad.name} (clipped region)")
            pin = fit is None or luminance(step.lit) < luminance(fit)
            report[quad.name] = {**step.report(), "used": "penumbra" if pin else "walls' fit",
                                 "fit_level": None if fit is None else [round(float(v), 5) for v in fit]}
            lit = "({:.3g}, {:.3g}, {:.3g})".format(*step.lit)
            if not pin:
                log.info("photo light: %s: its penumbra reads the sunlit level %s, not below the walls' fit's "
                         "(%.3g): the fit's kept", quad.name, lit, luminance(fit))
                continue
            out[q] = step.lit
            log.info("photo light: %s: sunlit level %s from its penumbra (%d unclipped ramp pixels; the walls' fit "
                     "gave %s)", quad.name, lit, step.n_ramp, "none" if fit is None else f"{luminance(fit):.3g}")
        return out, report

    def _local_light(self, pre: Precomputed, B_lit: np.ndarray, sunlit: np.ndarray):
        """Photo light: (lighting.photolocal.LocalLight, the emitter patches (P,) bool it scales: the room
        light's, before the sunlit reflectors join them)."""
        from lighting.photolocal import local_light
        from lighting.radiance import PHOTO

        emit = np.zeros(pre.patches.n_patches, bool)
        emit[self.room_light.emitters] = True
        emit &= ~sunlit  # a sunlit patch fitted as a clipped region has the sun's model radiance: not scaled
        return local_light(pre.patches, pre.G_c, B_lit, emit, np.asarray(pre.origin) == PHOTO, sunlit), emit

    def _shadow_sources(self, B_src: np.ndarray):
        """The shaft hierarchy of the shadow sources (lighting.frame_sources), from the cache when there,
        aimed at the receiver vertices, with the all-sources frame's single-source transfer table."""
        t0 = time.perf_counter()
        pre, r, sc, dev = self.pre, self.receivers, self.params.shadow, self.device
        args = (pre, B_src, sc.source_fraction, sc.leaf_size, sc.shaft_threshold)
        key = scene_precompute.shadow_sources_key(*args) if self.cache_dir is not None else ""
        sources, hit = scene_precompute.shadow_sources(
            *args, scene_precompute.cache_file(self.cache_dir, self.scene, "shafts-", key))
        self._count(hit)
        st = self.sun_pixels.stage
        if st is not None and not sources.empty and st.c_patch.size:  # the sunlit patches seen from their sun
            ids, eyes = st.source_eyes(B_src, pre.patches.albedo, sources.eye_pos)
            sources.eye_pos = sources.eye_pos.copy()  # the cached artefact's array stays as built
            sources.eye_pos[ids] = eyes
        # each receiver vertex's pixel footprint (the representatives' key counts the light the camera sees)
        vert_pixels = np.bincount(r.pix_rows[r.recv_pix].ravel(), pre.pix_bary[r.recv_pix].ravel(),
                                  len(pre.recv_vert))
        sources.use_receivers(pre.patches.vert_pos[pre.recv_vert], dev, vert_pixels)
        self.seconds["shafts"] = time.perf_counter() - t0  # built, or read from the cache (hit)
        # the single-source transfer table the all-sources frame reads (made here: cheaper than reading it)
        sources.keep_single_transfers(functools.partial(split_launches, device=dev, min_items=64))
        self.seconds["single_table"] = time.perf_counter() - t0 - self.seconds["shafts"]
        log.debug("shaft hierarchy: %s, %.1f s", sources.stats(), self.seconds["shafts"])
        return sources

    def _room_light(self, B_src: np.ndarray, spacing: float) -> RoomLight:
        """SH9 volume of the indirect light plus the emitters (lighting.irradiance), from the cache when there."""
        pm, sc = self.pre.patches, self.scene
        key = scene_precompute.room_light_key(pm, B_src, sc.room_min, sc.room_max, self.scene_occ,
                                              spacing) if self.cache_dir is not None else ""
        light, hit = scene_precompute.room_light(pm, B_src, sc.room_min, sc.room_max, self.scene_occ, spacing, self.device,
                                                 scene_precompute.cache_file(self.cache_dir, sc, "sh-", key))
        self._count(hit)
        return light

    @property
    def precompute_s(self) -> float:
        """Seconds the engine took to build (the precompute, the stages, the SH volume)."""
        return self.seconds["precompute"]

    @property
    def B_src(self) -> np.ndarray:
        """(P,3) the radiance receivers gather: one bounce less than the camera sees."""
        return self.pre.B[self.params.bounces - 1]

    @property
    def B_obj(self) -> np.ndarray:
        """(P,3) light that reaches the camera via the object: one bounce less than receivers gather."""
        return self.pre.B[max(self.params.bounces - 2, 0)]

    @property
    def lighting(self) -> str:
        """How the room is lit (a key of LIGHTING), fixed for the engine's life: another lighting is
        another precompute, i.e. another Engine."""
        return self.params.lighting

    # ------------------------------------------------------------------ per frame
    def frame_config(self) -> FrameConfig:
        """The FrameConfig of the engine's params (what render uses when given none)."""
        return self.params.frame

    def render(self, obj: SceneObject, config: FrameConfig | None = None, stop=None) -> Frame | None:
        """Composite the object at its pose within `config` (default: frame_config()); returns the
        frame with per-phase timings in stats. stop: callable() -> bool, asked between steps (a stage
        or a batch of maps): True abandons the frame and returns None (the GUI's frame of a pose a
        newer one replaced)."""
        steps = self._frame_steps(obj, config or self.frame_config())
        while True:
            try:
                next(steps)
            except StopIteration as done:
                return done.value
            if stop is not None and stop():
                steps.close()
                return None

    def refine(self, obj: SceneObject, config: FrameConfig | None = None, budget_s: float | None = None,
               stop=None) -> Frame | None:
        """Progressive refinement at rest (app.progressive): advance the frames of this pose at rest
        (refine_schedule: intermediate frames, then the all-sources frame in config's mode) by batches
        of shadow maps for about `budget_s` seconds (None: to the end). config.passes is the budget of
        the frame shown while dragging (it sets the intermediate frames; None: none). Returns a frame as
        soon as one is complete: an intermediate frame (stats["exact"] False; with budget_s None none is
        made, the call goes straight on to the all-sources frame), or the all-sources frame
        (stats["exact"] True, again at once on later calls for the same pose); None when the call
        completed no frame. A call for another pose or mode starts over, and so does a call after
        another frame was rendered in between (it re-aims the shared shadow maps and BVHs). Its stats
        add refine_s (compute in refine calls so far), refine_calls and refine_frames (intermediate
        frames returned before it). stop: callable() -> bool, checked between steps (a batch of maps or a
        stage): True ends the call at once, returning None (the GUI's next edit waits for no long slice)."""
        return self.refiner.refine(obj, config or self.frame_config(), budget_s, stop)

    def refine_schedule(self, obj: SceneObject, config: FrameConfig | None = None) -> list[FrameConfig]:
        """The frames Engine.refine makes of `obj`'s pose at rest, in order (Refiner.schedule)."""
        return self.refiner.schedule(obj, config or self.frame_config())

    def _frame_steps(self, obj: SceneObject, config: FrameConfig):
        """render()'s work as a generator: yields after each batch of shadow maps, returns the Frame.
        The stages in DESIGN's per-frame order; each phase's seconds in stats["timings"]."""
        self.frames_started += 1
        calibration_s = 0.0
        if config.fps is not None and self.budget.cost is None and self.budget.override is None:
            calibration_s = self._calibrate(obj, config)
        if uses_spheres(self, config):  # a drag frame with no shadow maps (app.dragshadow)
            return (yield from sphere_stages(self, config.drag).frame_steps(obj, config, Frame))
        px = self.pixel_stages(config.drag)  # the room's per-pixel stages: full resolution or the drag's coarse
        # the sun's pass is always the full frame's (its shadow is hard-edged, and cheap at full size)
        pm, oc, r, sun = self.pre.patches, self.params.object, px.receivers, self.sun_pixels.stage
        ft = FrameTimer()
        tick, timings = ft.tick, ft.timings
        pv, pf, proxy_occ, shade_mesh, shade_occ, centre, radius, hits, cov = self.frame_object(
            obj, ft, px.scene_depth() if px is not self else None, px.supersample if px is not self else None)
        t = ft.last
        cov_px = cov if px is self else px.zero_cov  # the drag's coarse room is computed under the object too

        # ---- source list from the shaft hierarchy, grouped into the frame's passes (sec. 6.2.1, 6.4)
        passes = self.budget.passes(config, sun is not None)
        if px is not self and sun is None and passes is not None and px.passes_no_sun is not None:
            passes = min(passes, px.passes_no_sun)  # a drag frame without a sun: its ceiling (DRAG_PASSES_NO_SUN)
        near = px.near_split if px is not self else finer_near_split(self, config, passes, sun is not None)
        src_split = functools.partial(split_launches, device=self.device, min_items=64)
        if px is self:
            fs = self.shadow_sources.select(pv.min(0), pv.max(0), passes, src_split, near_split=near)
        else:  # a drag frame: the selection of a box grown to a grid, kept while it holds (DragStages.frame_sources)
            fs = px.frame_sources(self.shadow_sources, pv.min(0), pv.max(0), radius, passes, src_split, near,
                                  sun is not None)
        order = None  # the all-sources frame: its weak sources on half-size maps (app.rest_maps), drawn last
        if px is self and config.passes is None and self.rest_maps is not None and len(fs.eyes):
            order = self.rest_maps.order(fs)
        t = tick("sources", t)
        yield  # a pause between stages: Engine.refine's stop and budget are checked here too

        # ---- occlusion masks: listed pixels and patch centres (app.stages.shadow_pass; yields per batch)
        ldr = config.mode == "ldr" and px is self  # a drag frame is composed in HDR
        masks = yield from px.shadow_pass.run((pv, pf, proxy_occ), centre, radius, cov_px, fs.cand, fs.eyes,
                                                px.compose.ldr_weights(fs.W_v) if ldr else fs.W_v, fs.W_c,
                                                fs.n_listed == len(fs.eyes), spread=fs.spread,
                                                full_maps=config.full_maps, scale=r.L_b_levels if ldr else r.E_x,
                                                order=order)
        t = tick("masks", t)

        # ---- the object lit by the room, whose patches in its shadow send it less light (and the sun's pass)
        dB_shadow = np.zeros((pm.n_patches, 3))
        dB_shadow[masks.cen_sel] = -pm.albedo[masks.cen_sel] * masks.O_cen
        sun_loss = sun_dB = None
        if sun is not None:  # sun: one pass, its loss on pixels and patches (second order)
            sun_loss, sun_loss_c = sun.frame(obj.vertices, obj.faces)
            sun_dB = -pm.albedo * sun_loss_c  # the object gathers it exactly (ObjectShading.vertex_radiance)
            t = tick("sun", t)
        dB_room = dB_shadow  # the room's light the object's shadow takes from the patches (the sun's apart)
        if sun is not None:
            dB_shadow = dB_shadow + sun_dB
        # a drag frame: the object from per-shape tables (a tilted one too: object_drag.frame_yaw), in sun rooms too
        # (drag_object_sun; docs/benchmarks.md, "sunobj36")
        later = sun.later_at_patches(sun_dB, pm.albedo, self.pre.G_c, self.pre.G_v, self.params.bounces) \
            if sun is not None else None  # the walls the object's sun shadow darkens (the object sees them darker)
        tables = self.object_drag.shade(obj, shade_mesh, hits, dB_room if later is None else dB_room + later, sun_dB) \
            if px is not self and self.drag_object_tables and (sun is None or self.drag_object_sun) else None

        # ---- light the object reflects, onto pixels and patch centres (app.stages.object_light): before the
        # object's own shading, which gathers it back from the patches (the object's light the room reflects)
        R_pix, R_cen, R_cen_sun = self._object_light(px, obj, pv, pf, proxy_occ, centre, radius, cov_px, dB_shadow,
                                                     tables) if oc.object_light else (np.zeros((r.L_b.shape[0], 3)), np.zeros((pm.n_patches, 3)), None)
        t = tick("object_light", t)
        yield  # a pause between stages: Engine.refine's stop and budget are checked here too

        # ---- the object's radiance (app.stages.object_shading): the room's light, less what its shadow takes
        # from the patches, plus its own light the patches reflect back to it
        dB_obj = self._object_sees(dB_room, R_cen, later)
        shade = functools.partial(self.object_shading.shade, obj, shade_mesh, hits, proxy_occ, dB_obj, sun_dB,
                                  sun_lost=None if sun is None else (sun.c_patch, sun.lost, sun.c_vis, sun.E_perp))
        if tables is not None:
            shaded = tables.shaded
        elif px is not self and sun is None and hits.hit.any():  # a drag frame: the vertex radiance of a near pose
            # (with a sun the object's light changes sharply at the sunlit patch's edge: computed every frame)
            fresh = []
            vertex = px.near_pose("object radiance", lambda: (fresh.append(shade()) or (fresh[0].L_vert, None)),
                                  shade_mesh[0], shade_mesh[2], centre, oc.volume_spacing)
            shaded = fresh[0] if fresh else shade(vertex=vertex)
        else:
            shaded = shade()
        obj_rad = shaded.radiance
        if sun is not None and shaded.L_vert is not None:  # sun: the outline where sunlight
            # clips, sampled finely (full size; while dragging too: without it sun_room's drag object 4.9 levels rmse)
            sun.refine_clipped_edges(self.scene.camera, self.cam_occ, shade_mesh, shade_occ, shaded.L_vert,
                                     shaded.sun_vis, obj.albedo, cov, obj_rad, self.sun_pixels.photo_clip,
                                     groups=self.object_shading.face_groups)
        t = tick("object_shading", t)
        yield  # a pause between stages: Engine.refine's stop and budget are checked here too

        # ---- second order: change of patch radiance, passed on once to receiver vertices (app.stages.compose)
        dE_v = None
        if oc.second_order:
            dB = dB_shadow + pm.albedo * R_cen
            # the pairs the object blocks (the shadow pass took those patches whole): in the all-sources frame
            # at rest (a frame of fewer passes or a drag frame skips it: 1-2 s a frame on the loaded 2-core
            # machine); the sun's loss has its own (SunStage.later_bounces)
            blk = self._blocked_second_order(dB_room + pm.albedo * R_cen, proxy_occ, pv) \
                if px is self and config.passes is None else None
            more = None if sun is None else self._sun_later_bounces(sun, sun_dB, R_cen_sun, proxy_occ, pv, dB)
            if blk is not None:
                more = -blk if more is None else more - blk
            dE_v = px.compose.second_order(dB, dE_more=more)
        t = tick("second_order", t)
        yield  # a pause between stages: Engine.refine's stop and budget are checked here too

        # ---- compose (app.stages.compose): HDR or LDR, on the pixels that changed
        if px is self:
            radiance, pixels, room = self.compose.frame(config.mode, masks.pix_sel, masks.O_pix, masks.fill_sel,
                                                        self.shadow_pass.fill, R_pix, dE_v, cov, obj_rad,
                                                        self.sun_pixels.pix, sun_loss)
            tick("compose", t)
        else:  # the drag frame: the coarse room (HDR), its ratio to the photo upsampled, the object over it
            _, _, room_c = px.compose.frame("hdr", masks.pix_sel, masks.O_pix, masks.fill_sel, px.shadow_pass.fill,
                                            R_pix, dE_v, px.zero_cov, px.zero_rad)
            t = tick("compose", t)
            radiance, pixels, room = px.finish(room_c, cov, obj_rad, self._sun_share(sun_loss), hits.rect)
            tick("upsample", t)
        frame_s = ft.close()
        self.budget.measured(frame_s, timings["masks"], len(fs.eyes))
        self.last_shading = (shade_mesh, shaded.L_vert, obj.albedo, shaded.sun_vis) if hits.hit.any() else None
        stats = self._stats(fs, masks, frame_s, timings, len(pf), config.mode, sun is not None)
        stats["glue"] = ft.glue
        stats["kernel_s"] = ft.clock.seconds
        if calibration_s:
            stats["fps_calibration_s"] = calibration_s
        return Frame(radiance, pixels, stats, room, cov.astype(np.float32))

    def frame_object(self, obj: SceneObject, timer: FrameTimer, caster=None, supersample: int | None = None) -> tuple:
        """Every frame's first steps (the map frames here, the sphere drag frame in app.dragshadow): the object's
        proxy and shading mesh (app.stages.object_shading), its bounding sphere, and its pixels (camera hits
        against the scene model, coverage (H,W)); timed as the frame's stages "proxy" and "object" from the
        timer's last tick (app.glue.FrameTimer: their glue too); caster: the camera hits' (ObjectShading.object_hits;
        a drag frame's keeps the scene's depth); supersample: its rays per pixel side (None: ObjectConfig.supersample).
        Returns (pv, pf, proxy_occ, shade_mesh, shade_occ, centre, radius,
        hits, cov)."""
        pv, pf, proxy_occ, shade_mesh, shade_occ = self.object_shading.object_shape(obj)
        centre, radius = bounding_sphere(pv)
        t = timer.tick("proxy", timer.last)
        hits = self.object_shading.object_hits(shade_mesh[0], shade_mesh[2], supersample=supersample,
                                               occluder=shade_occ, caster=caster)
        cov = hits.coverage()
        timer.tick("object", t)
        return pv, pf, proxy_occ, shade_mesh, shade_occ, centre, radius, hits, cov

    def _object_sees(self, dB_room: np.ndarray, R_cen: np.ndarray, later: np.ndarray | None = None) -> np.ndarray:
        """(P,3) the change of the patches' radiance the object gathers this frame, besides sun_dB (the sun
        its shadow takes from the floor, gathered exactly): the room's light its shadow takes (dB_room), its
        own light the patches reflect (rho R_cen: object -> patch -> object, a path of the truth's within
        its bounces), and with a sun `later`, the later bounces of sun_dB (SunStage.later_at_patches: the walls
        and ceiling that the shadowed floor no longer lights; computed once per frame, the drag frame's tables
        read it too). R_cen's room-lit part is the object lit by B_obj,
        one bounce more than this path leaves it (B[bounces - 3], not kept): a little too much. Measured
        (known light, rmse_object / bias): with the room-lit part left out sun_room's chair came out darker
        (3.54 / -1.95 against 3.33 / -1.62 with it); with it window_room's and lamps_room's objects, already
        bright, gain 0.3-0.4 levels of bias (docs/unseen.md)."""
        pm = self.pre.patches
        dB = dB_room + pm.albedo * R_cen
        if later is not None:
            dB = dB + later
        return dB

    def _sun_share(self, sun_loss: np.ndarray | None) -> tuple[np.ndarray, np.ndarray] | None:
        """(the sun's pixels, the share of each one's light E_x the object takes from it (n,3), clipped to
        [0, 1]) at full resolution, as compose takes it; None without a sun."""
        if sun_loss is None:
            return None
        pix = self.sun_pixels.pix
        return pix, np.clip(sun_loss / np.maximum(self.receivers.E_x[pix], 1e-12), 0.0, 1.0)

    def pixel_stages(self, drag: int | None):
        """The room's per-pixel stages of a frame (receivers, sun_pixels, shadow_pass, compose,
        object_light): the engine's own at full resolution (drag None), else the drag frame's at
        1/drag resolution (app.dragframe.DragStages, made on the first frame at that scale)."""
        if drag is None:
            return self
        if drag not in self._drag:
            self._drag[drag] = DragStages(self, drag)
        return self._drag[drag]

    def _object_light(self, px, obj: SceneObject, pv, pf, proxy_occ, centre, radius, cov, dB_shadow, tables=None):
        """(R_pix (H*W,3), R_cen (P,3), R_cen_sun: R_cen's part from the sun alone or None): the light the
        object reflects, lit by the room's light B_obj + dB_shadow (and the sun: its sunlit parts light
        the room too, as small pieces; SunStage.object_emitters). tables: a drag frame's DragShaded
        (app.stages.object_drag): the proxy's triangles take its vertex radiance (no rays), and send it."""
        ol, sun = px.object_light, self.sun_pixels.stage
        covered = cov.reshape(-1) >= 1.0
        if tables is not None:
            tri_room, tri_sun = self.object_drag.proxy_radiance(pv, pf, tables.L_proxy, tables.L_sun)
            if tri_sun is None:
                return (*ol.light(pv, pf, tri_room, proxy_occ, centre, radius, covered), None)
            # the sun's part as at rest, the proxy's sunlit pieces (SunStage.object_emitters: made once per shape):
            # from the vertices' sun (tri_sun) the room got 11 % more of it (sun_room's drag energy 0.92, docs)
            tri_rad, extra = sun.object_emitters(pv, pf, tri_room, obj.albedo, proxy_occ, radius)
            R_pix, _ = ol.light(pv, pf, tri_rad, proxy_occ, centre, radius, covered, extra, centres=False)
            R_cen_room, R_cen_sun = ol.centre_light_parts(pv, pf, tri_room, tri_rad - tri_room, proxy_occ, centre,
                                                          radius, extra)
            return R_pix, R_cen_room + R_cen_sun, R_cen_sun
        if px is self:
            tri_rad = ol.triangle_radiance(obj, pv, pf, proxy_occ, self.B_obj + dB_shadow)
        else:  # a drag frame: the proxy's radiance of a pose near this one (DragStages.near_pose)
            tri_rad = px.near_pose("proxy light", lambda: ol.triangle_radiance(obj, pv, pf, proxy_occ,
                                                                               self.B_obj + dB_shadow),
                                   pv, pf, centre, self.params.object.volume_spacing)
        if sun is None:
            return (*ol.light(pv, pf, tri_rad, proxy_occ, centre, radius, covered), None)
        room_tri_rad = tri_rad
        tri_rad, extra = sun.object_emitters(pv, pf, tri_rad, obj.albedo, proxy_occ, radius)
        if self.object_self_light and px is self:
            # the object's own interreflection of both parts (ObjectLight.self_light), each kept with its part
            s_room, s_sun = ol.self_light(pv, pf, proxy_occ, [room_tri_rad, sun.face_sun], obj.albedo)
            room_tri_rad = room_tri_rad + s_room
            tri_rad = tri_rad + s_room + s_sun
        R_pix, _ = ol.light(pv, pf, tri_rad, proxy_occ, centre, radius, covered, extra, centres=False)
        # at the patches in two parts, the room's and the sun's alone (the latter's later bounces:
        # SunStage.later_bounces), summed: one pass over the proxy's faces
        R_cen_room, R_cen_sun = ol.centre_light_parts(pv, pf, room_tri_rad, tri_rad - room_tri_rad, proxy_occ,
                                                      centre, radius, extra)
        return R_pix, R_cen_sun + R_cen_room, R_cen_sun

    def _blocked_second_order(self, dB: np.ndarray, proxy_occ, pv: np.ndarray) -> np.ndarray | None:
        """(Vr,3) the second order's pass of dB (P,3) over the (receiver vertex, patch) pairs the object (its
        proxy: occluder proxy_occ, vertices pv) blocks, or None (app.stages.second_order.BlockedSecondOrder:
        a Warp launch over both cores; blocked_pass is its numpy reference)."""
        return self._blocked(dB, proxy_occ, (pv.min(0) - 1e-3, pv.max(0) + 1e-3), obb=upright_box(pv),
                             split=functools.partial(split_launches, device=self.device, min_items=256))

    def _sun_later_bounces(self, sun, sun_dB, R_cen_sun, proxy_occ, pv, dB: np.ndarray) -> np.ndarray | None:
        """The sunlit patch light the object blocks (the room's main source) and the sunlit object's own
        light, passed on for the bounces each has left, not once (the later ones at the receiver vertices
        directly), the loss not counted twice where the object also hides the shadowed floor
        (SunStage.later_bounces); their later bounces are added to dB (compose's one pass through G_v)."""
        pre, pm = self.pre, self.pre.patches
        return sun.later_bounces(
            sun_dB, pm.albedo, pre.G_c, pre.G_v, self.params.bounces,
            dB2=pm.albedo * R_cen_sun if R_cen_sun is not None else None, occluder=proxy_occ,
            recv_points=pm.vert_inset[pre.recv_vert], box=(pv.min(0) - 1e-3, pv.max(0) + 1e-3),
            split=functools.partial(split_launches, device=self.device, min_items=256), first=dB, onto=dB,
            obb=upright_box(pv))  # the object turned on the floor: fewer rays, the same answer

    def _stats(self, fs, masks, frame_s: float, timings: dict, n_proxy: int, mode: str, sun: bool) -> dict:
        """A frame's stats: timings, sources and passes (a sun: one more of each), sizes, the sun used."""
        pre = self.pre
        stats = {"frame_s": frame_s, "timings": timings, "n_sources": int(fs.n_listed) + int(sun),
                 "passes": len(fs.eyes) + int(sun), "n_patches": int(pre.patches.n_patches),
                 "n_receiver_patches": fs.n_receivers, "n_receiver_vertices": int(len(pre.recv_vert)),
                 "n_mask_pixels": int(len(masks.pix_sel)), "n_filled_pixels": int(len(masks.fill_sel)),
                 "proxy_triangles": n_proxy, "mode": mode, "shaft_build_s": self.seconds["shafts"],
                 **self.shadow_sources.stats()}
        if self.sun.estimate is not None:  # sun: the captured estimate against the declared sun
            stats["sun_estimate"] = self.sun.estimate
        if self.sun.light is not None:  # sun: the one used (EngineParams.sun)
            stats["sun"] = self.sun.report()
        return stats

    def _calibrate(self, obj: SceneObject, config: FrameConfig | None = None) -> float:
        """Measure the frame's fixed and per-pass cost before --fps chooses a pass count: one
        frame of this object at one batch of passes (its result is discarded). Returns seconds."""
        t0 = time.perf_counter()
        config = config or self.frame_config()
        batch = self.params.shadow.batch
        self.budget.override = batch if config.passes is None else min(batch, config.passes)
        try:
            self.render(obj, config)
        finally:
            self.budget.override = None
        return time.perf_counter() - t0
