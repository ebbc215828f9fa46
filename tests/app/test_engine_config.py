"""The engine's configs (issue 17, item 3): EngineParams frozen, its Literal fields validated when
made, the precompute's knobs exactly the cache key, and the command line's help made from the
field documentation."""
import dataclasses
import typing

import pytest

from app.engine import LIGHTING, EngineParams, FrameConfig, Lighting, PrecomputeConfig, _hash_scene


def test_params_are_frozen_and_literals_validated_once():
    p = EngineParams()
    with pytest.raises(dataclasses.FrozenInstanceError):
        p.passes = 3
    assert dataclasses.replace(p, passes=3).passes == 3 and p.passes is None
    for bad, field in (({"mode": "sdr"}, "mode"), ({"lighting": "sunny"}, "lighting"),
                       ({"specular": 1.5}, "specular")):
        with pytest.raises(ValueError, match=field):
            EngineParams(**bad)
    with pytest.raises(ValueError, match="mode must be one of 'hdr', 'ldr', got 'sdr'"):
        FrameConfig(mode="sdr")
    with pytest.raises(ValueError, match="--sun estimate: .*--lighting captured"):
        EngineParams(sun="estimate")  # known light: the declared sun; the estimate is captured light's
    assert EngineParams(sun="estimate", lighting="captured").sun == "estimate"
    with pytest.raises(ValueError, match="--sun declared: --lighting photo takes its light, the sun's too, from the photo"):
        EngineParams(sun="declared", lighting="photo")
    assert EngineParams(sun="estimate", lighting="photo").sun == "estimate"  # what photo light does
    for ok in ("known", "captured", "photo"):
        assert EngineParams(lighting=ok).lighting == ok
    assert set(typing.get_args(Lighting)) == set(LIGHTING)  # the Literal and the documented list agree


def test_precompute_config_is_exactly_the_cache_key(tmp_path):
    # every knob of the precompute changes the key; no other knob does (a frame knob reuses the
    # precompute); and the precompute reads no knob outside its config
    from app.cli import demo_scene_dir
    from app.stages import precompute as stage
    from recon.scene import load_scene

    scene = load_scene(demo_scene_dir())
    base = EngineParams(patch_size=0.4, emitter_patch_size=0.3, vis_side=1)
    key = _hash_scene(scene, base)
    assert _hash_scene(scene, base.precompute) == key
    pre_fields = {f.name for f in dataclasses.fields(PrecomputeConfig)}
    assert set(base.cache_key()) == pre_fields
    changed = {"patch_size": 0.3, "emitter_patch_size": 0.2, "vis_side": 2, "bounces": 3, "lighting": "photo",
               "source_fraction": 0.7, "passes": 5, "map_res": 128, "batch": 16, "mode": "ldr", "object_light": False,
               "second_order": False, "proxy_faces": 100, "supersample": 1, "volume_spacing": 0.5, "prt_dirs": 64,
               "specular": 0.5, "shininess": 8.0, "envmap_res": 8, "fps": 10.0, "leaf_size": 4,
               "shaft_threshold": 0.05, "sun": "declared"}
    assert set(changed) == {f.name for f in dataclasses.fields(EngineParams)}  # a new knob is listed here
    for name, value in changed.items():
        other = _hash_scene(scene, dataclasses.replace(base, **{name: value}))
        assert (other != key) == (name in pre_fields), name

    read = set()

    class Spy:  # the config, recording which knobs the precompute reads
        def __getattr__(self, name):
            read.add(name)
            return getattr(base.precompute, name)

        def cache_key(self):
            return base.precompute.cache_key()

    patches = stage.scene_patches(scene, Spy())
    occ, cam = stage.scene_occluders(scene, patches, "cpu")
    pre, hit, _ = stage.precompute(scene, Spy(), patches, occ, cam, device="cpu", cache_dir=tmp_path)
    assert not hit and pre.key == key
    assert read == pre_fields, read


def test_cli_help_and_defaults_come_from_the_fields():
    # the engine options' help is the field's documentation and their defaults the field's
    from app.cli import build_parser

    ap = build_parser()
    sub = next(a for a in ap._actions if a.dest == "command").choices["composite"]
    opts = {a.option_strings[0]: a for a in sub._actions if a.option_strings}
    d = EngineParams()
    for flag in ("--mode", "--passes", "--fps", "--source-fraction", "--patch-size", "--map-res", "--lighting",
                 "--specular", "--shininess"):
        name = flag[2:].replace("-", "_")
        assert opts[flag].help.startswith(EngineParams.doc(name)), flag
        assert opts[flag].default == getattr(d, name), flag
    assert opts["--mode"].choices == ["hdr", "ldr"] and opts["--lighting"].choices == ["known", "captured", "photo"]
    assert EngineParams.doc("object_light") in opts["--no-object-light"].help
    assert EngineParams.doc("second_order") in opts["--no-second-order"].help
    a = ap.parse_args(["composite", "s", "--out", "o"])
    from app.cli import _params

    assert _params(a) == d  # the command line's defaults are the config's
