"""The drag frame: the room's change computed at a coarser working resolution, the object at full.

While the pose changes (FrameConfig.drag = s), the per-pixel stages of the room (shadow pass,
object light onto the room, the sun's pixels, compose) run on a camera of 1/s the size each way
(DragStages: the same precompute's transfers, a coarse camera ID buffer and receiver map); the
per-patch work (source list, patch centres, second order) is the full frame's. The room's change
is kept as the ratio room / photo (HDR radiance) at the coarse pixels, brought back bilinearly to
the full size and applied to the full-resolution photo; the object's own pixels (coverage, depth,
shading) are always computed at full resolution and composited over it (finish).

Why a ratio: it is smooth where the photo has texture (shadows do not follow texture), so bilinear
upsampling of it loses little (DESIGN "A coarser drag frame": +0.07-0.13 levels rmse_affected from
1/2, +0.7-0.9 from 1/4); the coarse stages see no coverage, so the shadow under the object is
computed too and the ratio has no hole at the object's outline to bleed into the contact shadow.

The at-rest frames (FrameConfig.drag None) never touch this module: they stay byte-identical.
"""
from __future__ import annotations

import dataclasses
import functools

import cv2
import numpy as np

from app import runtime
from app.config import DRAG_PASSES_NO_SUN
from app.stages.object_light import DRAG_FAR_CELLS
from app.stages.receiver_map import ReceiverMap, receiver_map, reflectance
from kernels.drag_compose import RATIO_EPS, DragCompose
from kernels.raycast import cast_rays
from recon.camera import Camera
from recon.scene import Scene


# Cluster-map size of the drag frame at 1/s resolution: the size a map per source gets at 1/s (ShadowConfig.map_res,
# 256, over s), at least 64, not the frames at rest's cluster size (CLUSTER_MAP_RES 128) over s. Where the object
# touches a receiver every penumbra shrinks to nothing (PCSS: width ~ (d_receiver - d_blocker) / d_blocker), so a
# cluster's contact shadow is as hard as one source's, and it meets the object's outline, which the drag frame draws
# at full resolution; 128 / s px maps (64 at 1/3) leaked light into the contact band of lamps_102's torus (the drag
# row +3.2 levels brighter than the all-sources frame within 3 px of the outline; rmse_affected 5.37 against its
# bound 5.03; docs/benchmarks.md "lamps_102's drag row"). 64 is the smallest size whose penumbra filter
# (kernels.masked_sums.penumbra) keeps the clusters' soft shadows smooth.
MIN_DRAG_MAP_RES = 64


# The drag frame's object light onto the room is evaluated per pixel within this many bounding radii of the
# object (ObjectConfig.near_factor, 2 at rest), the vertices' light interpolated farther out: within the
# bounding sphere a receiver may touch the object (contact light), the shadow pass's exact reach in a graded
# frame too (ShadowPass.graded_near). 64-pass drag frames at 1 against 2 (bench: loaded, same process): object
# light 1338 -> 869 ms on lamps_room, 355 -> 267 window_room, 306 -> 239 sun_room, rmse_affected 1.72 -> 1.60,
# 1.38 -> 1.38, 1.26 -> 1.24, the unseen lamps_101 1.31 -> 1.40 (its bound 1.75)
DRAG_LIGHT_NEAR_FACTOR = 1.0


# The drag frame's object light groups the object's light for the room's share (how much of it the room's walls
# and furniture hide from a receiver: app.stages.object_light.room_share) by the axis its faces face alone (at most
# 6 point sources), not also by cell of its box (ROOM_CELLS 2 a side: up to 48, chosen at rest on sun_102, a torus
# in front of a sofa). A receiver the room hides the object from partly is rare while dragging over the floor;
# one cell: object light 0.59 of two cells' ms on lamps_room, the frame within 1 level, rmse 0.004 level of it
# (docs/benchmarks.md "The drag frame at 1/3")
DRAG_ROOM_CELLS = 1


# The drag frame's object light sums the proxy's triangles near the object (the receiver vertices, the patch centres
# and the near pixels) beyond its bounding sphere with each triangle's visibility from the shape's per-direction
# table (app.stages.object_light.LightTables: the directions its centroid sees out of the object, as the far field
# and the sun's lit pieces already do), no ray per (receiver, triangle), and a triangle as a point emitter (or its
# quarters' mid-point rule) where the bound of that error is within this share of its unoccluded light: the sun's
# lit pieces' tolerance (app.stages.sun.PIECE_POINT_TOLERANCE), the same rule. Within the sphere (contact: a 14 deg
# cell is wider than the gap) and with the sun's emitters a ray each (the floor the sun lights beside the object
# lights its faces turned from the sun as brightly: with those alone through the tables sun_room's drag row still
# lost 24 levels between 1 and 1.5 radii; docs/benchmarks.md "The sun rooms' drag object light (sunobj37)"). None:
# a ray each everywhere (the frames at rest). docs/benchmarks.md "The drag frame's object light (objlight37)"
DRAG_LIGHT_TABLES: float | None = 0.05


# The drag frame's object light at the patch centres is summed as near the pixels within this many bounding radii
# of the object, beyond it from the far field's groups (at most 6 DRAG_FAR_CELLS^3 point emitters, each bounded by
# the object's sphere bound), with no room share (app.stages.object_light.ObjectLight._coarse_centres): while
# dragging the object is shaded from its tables before its light is summed (Engine.drag_object_tables), so the
# centres' light only feeds the second order. 2: the frames' per-pixel reach (ObjectConfig.near_factor), within
# which a group's spread (up to the object's size) is not small against the distance. On the bundled scene the
# centres' total light 1.026 x the rays' (the far groups' points nearer than FAR_FIELD); window_room's stage CPU
# 28.2 -> 24 ms (loaded). None: as at rest (FAR_FIELD, room share)
DRAG_CENTRE_NEAR: float | None = 2.0


# The drag frame's near pixels (within DRAG_LIGHT_NEAR_FACTOR radii, where the object's light may pass a quarter
# level) are each summed, not on the adaptive screen grid (ObjectLight._near_pixels: strides 16 to 2 px, blended
# where a cell lies GRID_CLEARANCE diagonals from the object): at 1/3 within one radius a 16 px cell spans more than
# the object's reach, so the grid blended none of window_room's 342 near pixels along its drag and only added its
# clearance and node passes (False: each summed; True: the grid, as at rest)
DRAG_LIGHT_GRID = False


# The drag frame takes the room's share of the object's light (ObjectLight's room_share: a segment per receiver and
# facing group) only at the receiver vertices whose light passes the level at which their patches are drawn
# (5e-4 of the room's mean radiance over the brightest reflectance, the frames' own threshold); the share is at most
# 1, so a vertex below it stays below, and keeps at most that much light more (True; False: every lit vertex)
DRAG_SHARE_DRAWN = True


# The drag frame's receiver vertices see the proxy's far groups (DRAG_FAR_CELLS a side, point emitters) beyond this
# many bounding radii, not FAR_FIELD's 3: the same reach as the centres' (DRAG_CENTRE_NEAR) and the frames'
# per-pixel reach; a group spans at most half the object's box, so from 2 radii it is seen from at least its own
# size. Drag rows, 3 -> 2: window_room rmse_affected 1.035 -> 1.035, lamps_room 1.550 -> 1.546 (loaded, one
# process; docs/benchmarks.md "The drag frame's object light (objlight37)")
DRAG_FAR_FIELD = 2.0


# The drag frame's cluster maps are looked up with 3 x 3 PCSS taps (blocker search and filter), not 5 x 5
# (kernels.masked_sums.PCSS_TAPS, the frames at rest's): a penumbra point costs 18 taps, not 50. Against the
# mean of 21 x 21 point sources of a square light a penumbra point errs by 0.085 on average, not 0.054, with
# the same sum (tests/kernels/test_shadowmap.py); at 1/3 a coarse pixel spans 3 full ones and the upsampled
# ratio averages the steps further. bench/bench_drag.py `taps5` against `taps3` (one process, loaded, frames'
# CPU time): window_room 337 -> 316 ms, rmse_affected 0.97 -> 1.02 (bound 1.61); lamps_room 316 -> 295, 1.96 ->
# 1.96 (2.33); sun_room 539 -> 512, 1.40 -> 1.39, energy 1.037 -> 1.024; unseen sun_101 541 -> 494, 4.09 -> 4.07
# (6.01), window_101 250 -> 228, 0.79 -> 0.80 (1.63) (docs/benchmarks.md, "The drag frame's per-pixel stages").
# 4 taps fell between the two, within the load's noise.
DRAG_PCSS_TAPS = 3


# The drag frame's shadow pass sums every receiver pixel exactly within this many bounding radii of the object
# (ShadowPass.graded_near; 1 at rest: within the bounding sphere a receiver may touch the object), the graded
# lattice beyond. The lattice's squares (spacing 8, 4, 2 working pixels) are filled where their corners agree;
# at 1/s a square spans s times as many full pixels, so a small object's hard shadow beyond its bounding sphere
# (a lamp's, near the contact) can fall between four lit corners and vanish: lamps_101's box at 1/3, rmse_affected
# 4.71 against its bound 1.74, 1.32 exact within 2 radii. 2 is the frames at rest's per-pixel reach of the
# object's light (ObjectConfig.near_factor) and of their weak passes' fine lattice (ShadowPass.weak_far)
# (docs/benchmarks.md "lamps_102's drag row")
DRAG_GRADED_NEAR = 2.0


# The drag frame's weak cluster maps take the hard lookup of their cluster's eye, no PCSS penumbra (ShadowPass.
# weak_clusters): a pass is weak when its largest share of any receiver vertex's light is at most drag_weak_budget
# (WEBER x the scale: below; WEBER, 2 %, app.rest_maps, until drag110). Where the penumbra and the hard shadow of such
# a cluster differ, the pixel moves by at most that share, a step that the upsampling spreads over `scale` full pixels;
# the lookup costs one texel, not a blocker search and a filter of 3 x 3 taps each, and the cluster's cone loses its
# penumbra's reach (shorter lists). At WEBER 8 (window_room) to 27 (lamps_room, lamps_101) of the 64 passes were
# weak, the masks' CPU 0.76-1.0x (docs/benchmarks.md, "The drag frame's masks (masks37)"); at 6 % 12-30 of 48-63
# (window_room 12 of 48, lamps_room 26 of 48, sun_room 30 of 63, against 4, 15 and 14 at WEBER; drag110).
DRAG_HARD_WEAK = True


def drag_weak_budget(scale: int) -> float:
    """The largest share of a receiver's light (app.rest_maps: share_j, luminance) of a drag frame's weak pass at
    1/scale resolution (DRAG_HARD_WEAK): WEBER x scale. A weak pass's hard shadow differs from its penumbra by a
    step of at most share_j of a pixel's light, and in the drag frame that step lies between two coarse pixels: the
    ratio room / photo is brought back to full resolution bilinearly (DragStages.finish), so the step becomes a ramp
    across `scale` full pixels, and two neighbouring full pixels differ by at most share_j / scale, WEBER at this
    budget (the frames at rest's rule for a visible step, app.rest_maps). At 1/3: 6 %. bench/bench_drag110.py,
    `weber2` (WEBER: main's before drag110) against `base`: the masks' CPU 0.78-0.93x on ten rooms, the drag rows
    within the bound (docs/benchmarks.md "drag110")."""
    from app.rest_maps import WEBER

    return WEBER * int(scale)


# The drag frame's patch centres look every cluster map up with the hard lookup of its eye, no PCSS penumbra
# (ShadowPass.hard_centres). Their occlusion feeds only the second order and the object's own shading (the room's
# pixels take theirs from the pixels' own sums), both averages over many patches, where a penumbra's shape is not
# seen; a centre is a run of one point, so each (centre, cluster map) pair paid a blocker search and a filter of its
# own: ~14 % of the masks' PCSS pairs at about twice a pixel's cost (docs/benchmarks.md "masks48").
# docs/benchmarks.md "drag107": the masks' CPU and the drag rows, True against False
DRAG_HARD_CENTRES = True


# The drag frame's object pixels: camera rays per pixel side (Engine.frame_object, kernels.scene_depth; None:
# ObjectConfig.supersample, the frames at rest's 2). One ray a pixel: the object's camera hits, its coverage and the
# sub-samples its shading averages (kernels.hit_average) are a quarter of 2 x 2's, and its outline is not
# antialiased while it moves; the frame at rest draws it with 2 x 2 again. bench/bench_drag36b.py `ss1` against
# `ss2` (one process, loaded): the object stage's process CPU 0.4-0.5x, the drag rows within 0.001 of energy and
# 0.01 level of rmse_affected on every room measured (docs/benchmarks.md "drag36b")
DRAG_SUPERSAMPLE: int | None = 1


# The drag frame's source list (ShadowSources.select) is made for the object's box grown outward, across the floor
# (x and z), to a grid of this many bounding radii (rounded to 1 cm), and kept while the grown box stays the same
# (DragStages.frame_sources). The selection is then a function of the grown box alone: a pose reached after others
# gives the frame of the same pose rendered first, and consecutive poses of a drag share one selection until a side
# of the box crosses a grid line (at a step d per frame, a share ~1 - 2 d / grid of the frames reuse it). The grown
# box is a superset of the object's: every source whose shaft reaches the object and every receiver pair it can
# shadow are still listed (the masks test the object itself), at the cost of a few more of each and of clusters
# chosen for a box up to one grid step larger per side. Only in a room no sun lights: the drag frame's energy drifts
# where a cluster's eye lies on a strong patch touching the object's box (passes48, DRAG_PASSES_NO_SUN's rule), and
# the grown box touches more of the sunlit floor (sun_101's drag row 1.054 -> 1.095, outside 0.93-1.07; sun_105
# 0.973 -> 1.008). None: the object's own box every frame (as at rest). evaluate's path (--path 30), sunless rooms:
# 0.64-0.90 of the frames reuse it, the sources stage's CPU 6-10 -> 1.5-2.9 ms a frame; the drag rows move by at most
# 0.02 of energy and 0.07 level of rmse_affected, inside issue 36's bound wherever the frame without it was. 2 radii
# took window_room's energy to 0.935; 0.5 reused 0.52-0.76 of the frames (docs/benchmarks.md "drag108")
DRAG_SOURCE_GRID: float | None = 1.0


def source_box(box_min: np.ndarray, box_max: np.ndarray, grid: float) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) the box grown outward in x and z to multiples of `grid` (m; the world's origin on the grid), y as
    given: the box a drag frame's source list is made for (DRAG_SOURCE_GRID)."""
    lo = np.asarray(box_min, np.float64).copy()
    hi = np.asarray(box_max, np.float64).copy()
    for a in (0, 2):
        lo[a] = np.floor(lo[a] / grid) * grid
        hi[a] = np.ceil(hi[a] / grid) * grid
    return lo, hi


# (A frame with a map per source, when the room has no more sources than the passes, takes the same size.)


def drag_map_res(scale: int, map_res: int) -> int:
    """The drag frame's map size at 1/scale resolution, for clusters and single sources alike, from the full
    frame's map size per source map_res (px; MIN_DRAG_MAP_RES's rule): max(64, map_res // scale)."""
    return max(MIN_DRAG_MAP_RES, map_res // scale)


def coarse_camera(cam: Camera, s: int) -> Camera:
    """The camera of 1/s the size each way (width, height rounded up) whose pixel (i, j) covers the
    full camera's s x s block starting at (s i, s j): focal lengths / s, principal point mapped with
    pixel centres at integers ((c + 0.5) / s - 0.5)."""
    K = cam.K.astype(np.float64).copy()
    K[0, 0] /= s
    K[1, 1] /= s
    K[0, 2] = (K[0, 2] + 0.5) / s - 0.5
    K[1, 2] = (K[1, 2] + 0.5) / s - 0.5
    return dataclasses.replace(cam, K=K, width=-(-cam.width // s), height=-(-cam.height // s))


def coarse_scene(scene: Scene, s: int) -> Scene:
    """`scene` seen by coarse_camera(s), its photo averaged over each s x s block (cv2.INTER_AREA on
    the image padded by edge replication to a multiple of s)."""
    cam = coarse_camera(scene.camera, s)
    H, W = scene.camera.height, scene.camera.width
    photo = cv2.copyMakeBorder(scene.photo, 0, cam.height * s - H, 0, cam.width * s - W, cv2.BORDER_REPLICATE)
    photo = cv2.resize(photo, (cam.width, cam.height), interpolation=cv2.INTER_AREA)
    return dataclasses.replace(scene, camera=cam, photo=photo)


class DragStages:
    """The room's per-pixel stages of an Engine at 1/scale resolution (the attributes Engine's frame
    reads: receivers, sun_pixels, shadow_pass, compose, object_light), and the finish that brings the
    room's change back to full resolution. Made once per scale, on the first drag frame at it."""

    def __init__(self, engine, scale: int, map_res: int | None = None, plain: bool = False):
        """map_res: the drag frame's cluster map size (default: drag_map_res(scale, the shadow's map_res)); plain: the frames at
        rest's cluster key and object-light reach (no near split, ObjectConfig.near_factor; the drag frame
        before they were chosen, bench/bench_drag.py's A/B)."""
        from app.rest_maps import RestMaps
        from app.stages.compose import ComposeStage
        from app.stages.object_light import ObjectLight
        from app.stages.shadow_pass import ShadowPass
        from app.stages.sun import SunSetup

        if scale < 2:
            raise ValueError(f"a drag frame's working resolution is 1/scale with scale >= 2, got {scale}")
        self.scale = s = scale
        # the frame's clusters split near the object first (ShadowSources.near_factor; read by Engine)
        self.near_split = not plain
        p, dev, pre = engine.params, engine.device, engine.pre_lit
        self.scene = sc = coarse_scene(engine.scene, s)
        cam = sc.camera
        pix_tri, pix_bary, pix_depth = cast_rays(engine.cam_occ, cam.centre, cam.pixel_rays().reshape(-1, 3))
        pre = dataclasses.replace(pre, pix_tri=pix_tri, pix_bary=pix_bary, pix_depth=pix_depth)
        B_src = pre.B[p.bounces - 1]
        rm = receiver_map(sc, pre, B_src)
        sun = SunSetup(sc, p.lighting, p.sun, engine.scene_occ, pre.patches)
        self.sun_pixels = sp = sun.apply(pre, rm, dev)
        self.pre = pre = dataclasses.replace(pre, patches=sp.patches)
        r = dataclasses.replace(
            rm, recv_pix=sp.recv_pix, E_x=sp.E_x, L_b=sp.L_b, rho_x=sp.reflectance(reflectance(sp.L_b, sp.E_x)))
        self.receivers: ReceiverMap = r
        pm, sh, oc = pre.patches, p.shadow, p.object
        self.shadow_pass = ShadowPass(r.pix_pos, r.pix_rows, pre.pix_bary, r.pix_patch, r.recv_pix, pm,
                                      len(pre.recv_vert), cam.width, cam.height, sh.batch,
                                      drag_map_res(s, sh.map_res), dev, quiet=True,
                                      cluster_map_res=map_res or drag_map_res(s, sh.map_res))
        self.compose = ComposeStage(L_b=r.L_b, L_b_levels=r.L_b_levels, E_x=r.E_x, rho_x=r.rho_x, recv_pix=r.recv_pix,
                                    pix_rows=r.pix_rows, pix_bary=pre.pix_bary, photo=sc.photo,
                                    response=sc.response, G_v=pre.G_v, E_v=r.E_v, recv_vert=pre.recv_vert,
                                    patches=pm, shape=(cam.height, cam.width), device=dev)
        sun_light = sun.light if sp.pix is not None else None
        oc_drag = oc if plain else dataclasses.replace(oc, near_factor=min(oc.near_factor, DRAG_LIGHT_NEAR_FACTOR))
        self.object_light = ObjectLight(oc_drag, pm, pre.recv_vert, pre.pix_bary, r.pix_pos, r.pix_patch, r.pix_rows,
                                        r.recv_pix, r.rho_x, r.L_b, B_src, engine.scene_occ, sc.response, cam, dev,
                                        sun_dir=sun_light.d if sun_light is not None else None)
        if not plain:
            self.object_light.room_cells = DRAG_ROOM_CELLS
            self.object_light.table_tolerance = DRAG_LIGHT_TABLES
            self.object_light.centre_near = DRAG_CENTRE_NEAR
            self.object_light.near_grid = DRAG_LIGHT_GRID
            self.object_light.share_drawn = DRAG_SHARE_DRAWN
            self.object_light.far_field = DRAG_FAR_FIELD
            self.object_light.far_cells = DRAG_FAR_CELLS  # its far field merged (app.stages.object_light.FarGroups)
            self.shadow_pass.set_taps(DRAG_PCSS_TAPS)
            self.shadow_pass.graded_near = DRAG_GRADED_NEAR
            self.shadow_pass.hard_centres = DRAG_HARD_CENTRES
            if DRAG_HARD_WEAK:  # in the drag frame's HDR units: W_v and E_v irradiance/pi
                self.shadow_pass.weak_clusters = RestMaps(r.E_v, drag_weak_budget(s))
        self.shape = (cam.height, cam.width)
        self.zero_cov = np.zeros(self.shape, np.float32)  # the coarse stages see the room without the object
        self.zero_rad = np.zeros((*self.shape, 3), np.float32)
        self.full_shape = (engine.scene.camera.height, engine.scene.camera.width)
        L_b_c = r.L_b.reshape(*self.shape, 3)
        self._inv_Lb = np.where(L_b_c > 0, 1.0 / np.maximum(L_b_c, 1e-30), 0.0).astype(np.float32)
        self._no_ratio = ~engine.receivers.recv_pix.reshape(self.full_shape)  # keep the photo (emitters, sky)
        self._compose = DragCompose(engine.compose.k, self.full_shape, self.shape, s, self._inv_Lb.reshape(-1, 3),
                                    engine.receivers.recv_pix, dev)
        self._split = functools.partial(runtime.split, device=dev)
        self._near: dict[str, tuple] = {}  # near_pose: (shape, centre, value) of the last computed pose
        # the object's camera rays per pixel side while dragging (Engine.frame_object; DRAG_SUPERSAMPLE)
        self.supersample = engine.params.object.supersample if DRAG_SUPERSAMPLE is None else DRAG_SUPERSAMPLE
        self._engine_cam = (engine.cam_occ, engine.scene.camera, dev)
        # the most passes a drag frame takes in a room no sun lights (Engine._frame_steps; None: as asked)
        self.passes_no_sun: int | None = DRAG_PASSES_NO_SUN
        self._scene_depth = None  # scene_depth(), made on first use
        self.source_grid: float | None = DRAG_SOURCE_GRID  # frame_sources' grid in bounding radii (None: no reuse)
        self._sources: tuple | None = None  # frame_sources: (key, FrameSources) of the last grown box
        self.sources_reused = 0  # frames that took the kept selection (bench / tests)

    def scene_depth(self):
        """The object's camera hits at full resolution with the scene's depth per sub-sample kept
        (kernels.scene_depth.SceneDepth: cast on the first drag frame, the same hits as the frames at rest's)."""
        if self._scene_depth is None:
            from kernels.scene_depth import SceneDepth

            occ, cam, dev = self._engine_cam
            self._scene_depth = SceneDepth(occ, cam.centre, cam.R.T @ np.linalg.inv(cam.K), cam.width, cam.height,
                                           self.supersample, dev)
        return self._scene_depth

    def near_pose(self, what: str, compute, vertices: np.ndarray, faces: np.ndarray, centre: np.ndarray,
                  reach: float):
        """compute()'s value for `what` while dragging: computed when the object has moved by `reach`
        metres or more since the pose it was last computed at (or its mesh (vertices, faces) changed
        shape), else that pose's value. reach is the SH volume's spacing (ObjectConfig.volume_spacing):
        the room light the object's shading reads is itself sampled that finely, so the object's own
        light (its radiance per vertex, its proxy's per triangle) is not resolved more finely while it
        moves either."""
        key = (faces.shape, len(vertices), float(np.round(np.ptp(vertices, axis=0).sum(), 6)))
        last = self._near.get(what)
        if last is None or last[0] != key or np.linalg.norm(centre - last[1]) >= reach:
            last = self._near[what] = (key, np.asarray(centre, np.float64).copy(), compute())
        return last[2]

    def frame_sources(self, sources, box_min: np.ndarray, box_max: np.ndarray, radius: float, passes: int | None,
                      split, near_split: bool, sun: bool = False):
        """The drag frame's FrameSources (sources: the engine's ShadowSources) for an object in the box (box_min,
        box_max) of bounding radius `radius` (m): select()'s for the box grown by source_box to a grid of
        source_grid radii (1 cm steps), the kept one while the grown box, passes and near split stay the same.
        The object's own box every frame in a room a sun lights (`sun`; DRAG_SOURCE_GRID's rule) and in a drag
        frame of every source (passes None), whose passes a larger box would add to."""
        if self.source_grid is None or passes is None or sun:
            return sources.select(box_min, box_max, passes, split, near_split=near_split)
        grid = max(round(self.source_grid * float(radius), 2), 0.01)
        lo, hi = source_box(box_min, box_max, grid)
        # the grown box on select's own 1 mm grid: a float's last bit does not force a new selection
        key = (id(sources), tuple(np.round(np.concatenate([lo, hi]) * 1e3).astype(np.int64)), passes, near_split)
        if self._sources is not None and self._sources[0] == key:
            self.sources_reused += 1
            return self._sources[1]
        fs = sources.select(lo, hi, passes, split, near_split=near_split)
        self._sources = (key, fs)
        return fs

    def ratio(self, room_c: np.ndarray) -> np.ndarray:
        """(H,W,3) float32 full-resolution ratio room / photo from the coarse room (h,w,3) radiance:
        1 where the coarse photo is black or the full pixel is no receiver; bilinear between the coarse
        pixels' centres (cv2.resize, half-pixel centres: the block layout of coarse_camera)."""
        s = self.scale
        ratio_c = np.where(self._inv_Lb > 0, room_c * self._inv_Lb, np.float32(1.0))
        h, w = self.shape
        up = cv2.resize(ratio_c, (w * s, h * s), interpolation=cv2.INTER_LINEAR)
        H, W = self.full_shape
        up = up[:H, :W]
        up[self._no_ratio] = 1.0
        return up

    def finish(self, room_c: np.ndarray, cov: np.ndarray, obj_rad: np.ndarray, sun=None,
               rect: tuple[int, int, int, int] | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(radiance (H,W,3) float32, pixels (H,W,3) uint8, room (H,W,3) float32) at full resolution
        from the coarse room room_c (h,w,3) without the sun, the object's cov (H,W), obj_rad (H,W,3), and
        sun: None or (pixels (n,), the share of their light the object takes from the sun (n,3)) at full
        resolution (Engine._sun_share); rect: None or the object's rectangle (u0, v0, u1, v1) (inclusive, full
        pixels; ObjectHits.rect) outside which cov and obj_rad are 0. One kernel (kernels.drag_compose), the form
        finish_reference specifies."""
        H, W = self.full_shape
        rad, room, pix = self._compose.run(room_c, cov, obj_rad, self._split, sun, rect)
        return rad.reshape(H, W, 3), pix.reshape(H, W, 3), room.reshape(H, W, 3)

    def finish_reference(self, engine, room_c: np.ndarray, cov: np.ndarray, obj_rad: np.ndarray, sun=None
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """finish in numpy (its specification; tests): at full resolution:
        the photo's radiance L_b times the upsampled ratio less the sun's share u (max(L_b (ratio - u), 0)),
        in levels T(room) where the ratio moves it
        (else the photo's own levels), and the object (coverage cov (H,W), radiance obj_rad (H,W,3))
        mixed over it as compose_reference does (levels, or radiance where either side clips)."""
        rc = engine.receivers
        resp = engine.scene.response
        H, W = self.full_shape
        ratio = self.ratio(room_c).reshape(-1, 3).astype(np.float64)
        L_b = rc.L_b
        changed = np.abs(ratio - 1.0).max(1) > RATIO_EPS
        if sun is not None:
            ratio[sun[0]] -= sun[1]
            changed[sun[0]] |= sun[1].any(1)
        room = np.maximum(L_b * ratio, 0.0).astype(np.float32)
        changed = np.flatnonzero(changed)
        levels = rc.L_b_levels.copy()
        levels[changed] = resp.to_levels(room[changed])
        c = cov.reshape(-1)
        on = np.flatnonzero(c > 0)
        radiance = room.copy()
        if len(on):
            cc = c[on, None].astype(np.float64)
            o = obj_rad.reshape(-1, 3)[on]
            radiance[on] = (1 - cc) * room[on] + cc * o
            obj_levels = resp.to_levels(o)
            room_levels = levels[on]
            mix = (1 - cc) * room_levels + cc * obj_levels
            edge = ((obj_levels >= 255) | (room_levels >= 255)).any(1) & (cc[:, 0] < 1)
            if edge.any():
                mix[edge] = resp.to_levels(radiance[on[edge]])
            levels[on] = mix
        pixels = np.clip(np.rint(levels), 0, 255).astype(np.uint8)
        return radiance.reshape(H, W, 3), pixels.reshape(H, W, 3), room.reshape(H, W, 3)


def uses_spheres(engine, config) -> bool:
    """Whether a frame of `config` is a sphere drag frame: a drag frame with drag_shadow "spheres", or
    "auto" in a room no sun lights (config.DRAG_SHADOW's rule)."""
    if config.drag is None:
        return False
    return config.drag_shadow == "spheres" or (config.drag_shadow == "auto" and engine.sun_pixels.stage is None)


def sphere_stages(engine, scale: int):
    """The sphere drag frame's per-scene data of `engine` at 1/scale (app.dragshadow.SphereShadow, made on
    the first frame and kept with the coarse stages; FrameConfig.drag_shadow "spheres")."""
    from app.dragshadow import SphereShadow

    key = ("spheres", scale)
    if key not in engine._drag:
        engine._drag[key] = SphereShadow(engine, scale)
    return engine._drag[key]
