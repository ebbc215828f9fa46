"""The engine's knobs as frozen configs, one block per consumer:

  PrecomputeConfig  the scene precompute (app.stages.precompute); its fields are the cache key
  ShadowConfig      shadow sources and occlusion masks (lighting.frame_sources, app.stages.shadow_pass)
  ObjectConfig      the object's shape, shading and the light it reflects (app.stages.object_shading,
                    app.stages.object_light), with the knobs the command line does not offer
  FrameConfig       one frame: passes, mode, fps (Engine.render)

EngineParams is the command line's flat view of them (one field per option; the help is each
field's one-line doc, app.cli) and hands each consumer its block. Every block is frozen: a changed
knob is a new block (dataclasses.replace), so a frame and the key it is kept under read the same
values.
"""
from __future__ import annotations

import dataclasses
import typing
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

Mode = Literal["hdr", "ldr"]
SunSource = Literal["auto", "estimate", "declared"]
Lighting = Literal["known", "captured", "photo"]
# How the room is lit (EngineParams.lighting; the one list the command line and the engine use):
LIGHTING = {
    "known": "the scene's declared emitters (emitted_radiance) and radiosity",
    "captured": "the bracketed mirror-ball probe and the photo; emitters are the patches brighter than any "
                "reflector could be, the camera response is recovered from the bracket",
    "photo": "the photo alone: sRGB assumed, window/lamp radiance fitted to the walls (lighting.photolight)",
}
SUN_SOURCES = {
    "auto": "declared under --lighting known; under captured the declared sun when the user gave it "
            "(`photoar scene --sun-*`: its entry says \"declared_by\": \"user\"), else the estimate; under "
            "photo the estimate",
    "estimate": "estimated from the photo's sunlit patches (--lighting captured or photo)",
    "declared": "scene.json's sun entry as given, also under captured light (not photo: light from the photo alone); "
                "an entry with \"strength\": \"estimate\" gives the direction, its strength is estimated from the photo",
}


def knob(default, doc: str):
    """A config field with its one-line documentation (the command line's help is made from it)."""
    return field(default=default, metadata={"doc": doc})


def doc(cls, name: str) -> str:
    """The documentation of field `name` of the config class `cls`."""
    return cls.__dataclass_fields__[name].metadata["doc"]


_LITERAL_FIELDS: dict[type, dict[str, tuple]] = {}


def check_literals(cfg) -> None:
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


@dataclass(frozen=True)
class PrecomputeConfig:
    """What the scene precompute reads, and nothing else: its fields are the precompute's cache key
    (with the scene's inputs, app.stages.precompute.hash_scene)."""

    patch_size: float = knob(0.18, "metres, receiver/source patches (bench/bench_patch_size.py)")
    emitter_patch_size: float = knob(0.1, "metres, emitters are cut finer: one hard shadow per patch")
    vis_side: int = knob(2, "visibility samples per patch side for receiver transfers (n^2 rays)")
    bounces: int = knob(4, "light bounces the camera sees (the benchmark truth: 4)")
    lighting: Lighting = knob("known", "; ".join(f"{k}: {v}" for k, v in LIGHTING.items()) + ". A room with a sun "
                              "entry: known uses the declared sun, captured estimates it from the photo unless "
                              "it is the user's (--sun chooses, where offered)")

    def cache_key(self) -> dict:
        return dataclasses.asdict(self)


@dataclass(frozen=True)
class ShadowConfig:
    """The shadow sources (shaft hierarchy) and the occlusion masks of every frame."""

    source_fraction: float = knob(1.0, "share of total patch power kept as shadow sources (seed: 0.7)")
    leaf_size: int = knob(8, "receiver octree leaf size (sec. 6.2)")
    shaft_threshold: float = knob(0.02, "stop refining a shaft below this share of each receiver's light")
    map_res: int = knob(256, "shadow-map size")
    batch: int = knob(64, "shadow maps rendered at once")


@dataclass(frozen=True)
class ObjectConfig:
    """The object's shape, its shading and the light it reflects onto the room."""

    object_light: bool = knob(True, "light the object reflects onto the room")
    second_order: bool = knob(True, "re-propagate the object's effect once (the change of patch radiance)")
    proxy_faces: int = knob(300, "target size of the occluder proxy")
    supersample: int = knob(2, "object coverage rays per pixel side")
    volume_spacing: float = knob(0.25, "metres, SH irradiance volume grid")
    prt_dirs: int = knob(128, "directions per vertex for the object's self-occlusion transfer")
    specular: float = knob(0.0, "k_s of the object's Phong-like specular lobe, in [0, 1] (0: Lambertian, as in "
                                "the benchmarks)")
    shininess: float = knob(32.0, "Phong exponent")
    envmap_res: int = knob(16, "face size of the pre-filtered cube map looked up per pixel")
    dB_samples: int = knob(400, "object vertices that gather the second-order loss (the rest interpolate)")
    vis_stride: int = knob(4, "distinct vertices per visibility sample of the object's patch sums (1: a ray "
                              "per pair)")
    near_factor: float = knob(2.0, "object light is computed per pixel within this many bounding radii")
    shaft_cull: bool = knob(True, "skip the room's rays when no room triangle lies between object and emitters")
    dB_far_field: bool = knob(True, "far shadowed patches reach the object as an SH9 far field")
    sun_cells: bool = knob(True, "the sun's loss on patches near the object gathered per sample point's cell")
    shape_cache: bool = knob(True, "keep the object's proxy, shading mesh and BVHs per shape (False: made "
                                   "afresh every frame)")

    def __post_init__(self):
        if not 0.0 <= self.specular <= 1.0 or self.shininess < 0:
            raise ValueError(f"specular must be in [0, 1] and shininess >= 0, got {self.specular}, "
                             f"{self.shininess}")


# The drag frame (app.dragframe; the GUI's frames while the object moves, evaluate's drag row): the
# room at 1/DRAG_SCALE resolution each way with DRAG_PASSES passes whose clusters are split near the
# object first (ShadowSources.near_factor): of bench/bench_drag.py's configurations (docs/benchmarks.md,
# "The drag frame at 1/3"), the coarsest within issue 36's error bound (rmse_affected <= 1.5 x the
# all-sources frame's + 0.5, energy 0.93-1.07) on every room measured with a margin left for rooms not
# measured: 1/4 holds too, but with lamps_room's hard lamp shadows within 0.2 level of the bound, for 6-19 %
# fewer mask ms; 48 passes leave sun_room and sun_101 at energy 1.09-1.11; 64 is also one batch of maps
# (ShadowConfig.batch), whose frame sums on the graded lattice (ShadowPass._run_graded)
DRAG_SCALE = 3
DRAG_PASSES = 64
# A drag frame in a room no sun lights takes at most this many passes (Engine._frame_steps; a ceiling on
# FrameConfig.passes, the GUI's slider included). The drag frame's energy drifts at few passes where a cluster's
# eye lies on a strong patch touching the object's box, which then blocks its far members' light too: the sunlit
# floor around the object (docs/benchmarks.md "passes48"); without a sun no patch near the object is that strong.
# 48 against 64, the drag rows (energy / rmse_affected): window_room 0.952 / 1.13 against 0.940 / 1.04 (bound
# 1.61), lamps_room 1.000 / 1.54 against 1.000 / 1.54 (2.33), unseen lamps_101 0.987 / 1.32, lamps_102 0.960 /
# 3.86 (5.03), window_101 0.985 / 1.01, window_102 1.053 / 0.83 (docs/benchmarks.md "passes48"); the masks' CPU
# ~0.85x (docs/benchmarks.md "drag107")
DRAG_PASSES_NO_SUN = 48
# How a drag frame computes the room's change (FrameConfig.drag_shadow): "maps" (clustered shadow maps,
# DRAG_PASSES of them), "spheres" (app.dragshadow: the object as ellipsoids against the room's SH light and
# its compact sources, no maps) or "auto": spheres in a room no sun lights, else maps (app.dragframe.
# uses_spheres). evaluate and the GUI drag with DRAG_SHADOW: maps, the only one within issue 36's error bound
# on every room measured (the sphere frame holds it on window_room and lamps_room at 0.27-0.47 of the time and
# misses it on sun_room and three unseen rooms: docs/benchmarks.md "The sphere drag frame")
DRAG_SHADOW = "maps"
DragShadow = Literal["maps", "spheres", "auto"]


@dataclass(frozen=True)
class FrameConfig:
    """Per-frame settings for Engine.render: a new one per change, never mutated."""

    passes: int | None = knob(None, "shadow maps per frame; sources are grouped into this many representatives "
                                    "(default: one per source)")
    mode: Mode = knob("hdr", "hdr: T(L_b - eps) in floating point; ldr: subtract intensity transfers S_ij from "
                             "the 8-bit photo (seed fig. 13)")
    fps: float | None = knob(None, "target frame rate: the pass count is chosen from the measured cost per pass "
                                   "(at most --passes)")
    full_maps: bool = knob(False, "cluster maps at the all-sources map size, not the drag frames' smaller one "
                                  "(Engine.refine's intermediate frames at rest: hard lamp shadows need it)")
    drag: int | None = knob(None, "drag frame: the room's change at 1/drag resolution each way, upsampled as the "
                                  "ratio to the photo; the object at full resolution (app.dragframe). None: the "
                                  "frame at full resolution (at rest)")
    drag_shadow: DragShadow = knob("maps", "a drag frame's room change: maps (clustered shadow maps, `passes`), "
                                           "spheres (the object as ellipsoids against the room's SH light, "
                                           "app.dragshadow) or auto (spheres where no sun lights the room)")

    def __post_init__(self):
        check_literals(self)
        fps, passes = self.fps, self.passes
        if fps is not None and not fps > 0:
            raise ValueError(f"fps must be positive, got {fps!r}")
        if passes is not None and (isinstance(passes, bool) or not isinstance(passes, (int, np.integer))
                                   or passes < 1):
            raise ValueError(f"passes must be an integer of at least 1 or None (all sources), got {passes!r}")
        drag = self.drag
        if drag is not None and (isinstance(drag, bool) or not isinstance(drag, (int, np.integer)) or drag < 2):
            raise ValueError(f"drag must be an integer of at least 2 (1/drag resolution) or None, got {drag!r}")


def _same(cls, name: str):
    """EngineParams' copy of field `name` of block `cls`: the same default and doc."""
    f = cls.__dataclass_fields__[name]
    return field(default=f.default, metadata=f.metadata)


@dataclass(frozen=True)
class EngineParams:
    """The engine's knobs as the command line sees them: one flat field per option, each with the
    doc and default of the block it belongs to. The engine hands each stage its block (precompute,
    shadow, object, frame) and reads only how the room is lit (lighting, sun, bounces) itself.
    Frozen: a changed knob is a new EngineParams (dataclasses.replace). The knobs of a block the
    command line does not offer (ObjectConfig's vis_stride, ...) keep their defaults here; a stage's
    `config` takes another block."""

    patch_size: float = _same(PrecomputeConfig, "patch_size")
    emitter_patch_size: float = _same(PrecomputeConfig, "emitter_patch_size")
    vis_side: int = _same(PrecomputeConfig, "vis_side")
    bounces: int = _same(PrecomputeConfig, "bounces")
    source_fraction: float = _same(ShadowConfig, "source_fraction")
    passes: int | None = _same(FrameConfig, "passes")
    map_res: int = _same(ShadowConfig, "map_res")
    batch: int = _same(ShadowConfig, "batch")
    mode: Mode = _same(FrameConfig, "mode")
    object_light: bool = _same(ObjectConfig, "object_light")
    second_order: bool = _same(ObjectConfig, "second_order")
    proxy_faces: int = _same(ObjectConfig, "proxy_faces")
    supersample: int = _same(ObjectConfig, "supersample")
    volume_spacing: float = _same(ObjectConfig, "volume_spacing")
    prt_dirs: int = _same(ObjectConfig, "prt_dirs")
    specular: float = _same(ObjectConfig, "specular")
    shininess: float = _same(ObjectConfig, "shininess")
    envmap_res: int = _same(ObjectConfig, "envmap_res")
    lighting: Lighting = _same(PrecomputeConfig, "lighting")
    sun: SunSource = knob("auto", "which sun lights a room with openings (scene.json's sun entry or the photo's): "
                          + "; ".join(f"{k}: {v}" for k, v in SUN_SOURCES.items()))
    fps: float | None = _same(FrameConfig, "fps")
    leaf_size: int = _same(ShadowConfig, "leaf_size")
    shaft_threshold: float = _same(ShadowConfig, "shaft_threshold")

    def __post_init__(self):
        check_literals(self)
        if self.sun == "estimate" and self.lighting == "known":
            raise ValueError("--sun estimate: the sun is estimated from the photo with captured or photo light: use "
                             "it with --lighting captured or photo (known light uses scene.json's sun)")
        if self.sun == "declared" and self.lighting == "photo":
            raise ValueError("--sun declared: --lighting photo takes its light, the sun's too, from the photo alone; "
                             "use --lighting captured or known for a declared sun")
        self.object  # specular and shininess checked by their block; passes and fps by the frame's

    @classmethod
    def doc(cls, name: str) -> str:
        """The documentation of field `name` (the command line's help)."""
        return doc(cls, name)

    def _block(self, cls):
        """The config block `cls` made of these fields (the block's own defaults for the others)."""
        return cls(**{f.name: getattr(self, f.name) for f in dataclasses.fields(cls)
                      if f.name in self.__dataclass_fields__})

    precompute = property(lambda self: self._block(PrecomputeConfig),
                          doc="The knobs the scene precompute reads: exactly its cache key.")
    shadow = property(lambda self: self._block(ShadowConfig), doc="The shadow sources' and masks' knobs.")
    object = property(lambda self: self._block(ObjectConfig),
                      doc="The object stages' knobs (those the command line does not offer at their defaults).")
    frame = property(lambda self: self._block(FrameConfig), doc="The frame Engine.render makes when given none.")

    def cache_key(self) -> dict:
        return self.precompute.cache_key()
