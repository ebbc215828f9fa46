"""Issue 20: the sun in a user's own room. `photoar scene` keeps a window's `"opening": true`, takes
the sun from --sun-direction/--sun-irradiance or from a sun entry of --primitives (marked
"declared_by": "user"), and warns when it cannot come in; under --lighting captured that declared
sun is the one used (--sun auto), scored against sun_room's truth; --sun estimate still estimates it.
"""
import json
import logging

import numpy as np
import pytest

from app.cli import main
from tests.conftest import score, shared_scene
from tests.own_room import fmt, scene_argv, sunlit_inputs


@pytest.fixture(scope="module")
def sun_inputs(tmp_path_factory):
    """sun_room's user files (tests/own_room.py), the tape room's window flagged as an opening, the
    true camera as camera.json, and the declared sun's numbers as the user would type them."""
    return sunlit_inputs(shared_scene("sun_room"), tmp_path_factory.mktemp("own_sun"))


def _sun_args(direction, irradiance):
    return [f"--sun-direction={fmt(direction)}", "--sun-irradiance", fmt(irradiance)]


def _replace(argv, flag, value):
    i = argv.index(flag)
    return argv[:i + 1] + [value] + argv[i + 2:]


def _warnings(caplog):
    return [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]


@pytest.fixture(scope="module")
def sun_room_folder(sun_inputs):
    """The room folder `photoar scene` writes with the declared sun given on the command line."""
    room = sun_inputs["tmp"] / "room"
    argv = scene_argv(sun_inputs, room, sun_inputs["camera"]) + _sun_args(
        sun_inputs["sun"]["direction_to_sun"], sun_inputs["sun"]["irradiance_perpendicular"])
    assert main(["-q", *argv]) == 0
    return room


def test_scene_keeps_the_opening_and_marks_the_users_sun(sun_room_folder, sun_inputs):
    d = json.loads((sun_room_folder / "scene.json").read_text())
    win = next(p for p in d["primitives"] if p["name"] == "window")
    assert win["opening"] is True
    sun = [p for p in d["primitives"] if p["type"] == "sun"]
    assert len(sun) == 1 and sun[0]["declared_by"] == "user"
    np.testing.assert_allclose(sun[0]["direction_to_sun"], sun_inputs["sun"]["direction_to_sun"], atol=1e-9)
    from recon.scene import load_scene

    scene = load_scene(sun_room_folder)
    assert [q.name for q in scene.quads if q.opening] == ["window"]
    assert scene.meta["sun_declared_by"] == "user"


def test_bad_opening_value_is_refused(sun_inputs, capsys):
    room = json.loads(sun_inputs["room"].read_text())
    for p in room["primitives"]:
        if p["role"] == "window":
            p["opening"] = "yes"
    bad = sun_inputs["tmp"] / "in" / "room_bad_opening.json"
    bad.write_text(json.dumps(room))
    out = sun_inputs["tmp"] / "room_bad"
    argv = _replace(scene_argv(sun_inputs, out, sun_inputs["camera"]), "--primitives", str(bad))
    assert main(["-q", *argv, "--skip-probe-check"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"photoar: error: {bad}: field 'primitives[")
    assert ".opening' must be true or false" in err[0]
    assert not out.exists()


@pytest.mark.parametrize("case", ["no_opening", "below_horizon", "facing_away"])
def test_sun_that_cannot_come_in_warns(sun_inputs, caplog, case):
    d = np.array(sun_inputs["sun"]["direction_to_sun"])
    prims = sun_inputs["room_no_opening"] if case == "no_opening" else sun_inputs["room"]
    if case == "below_horizon":
        d = d * [1, -1, 1]
    elif case == "facing_away":
        d = d * [-1, 1, 1]  # from +X: the window in the x = 0 wall faces it with its back
    out = sun_inputs["tmp"] / f"room_{case}"
    argv = _replace(scene_argv(sun_inputs, out, sun_inputs["camera"]), "--primitives", str(prims))
    with caplog.at_level(logging.WARNING, logger="photoar"):
        rc = main(["-q", *argv, "--skip-probe-check", *_sun_args(d, sun_inputs["sun"]["irradiance_perpendicular"])])
    assert rc == 0
    want = {"no_opening": "no opening", "below_horizon": "below the horizon",
            "facing_away": "behind every opening"}[case]
    warn = [w for w in _warnings(caplog) if "--sun-direction" in w and "no direct sun" in w]
    assert len(warn) == 1 and want in warn[0], _warnings(caplog)
    assert (out / "scene.json").is_file()


def test_sun_through_the_opening_gives_no_warning(sun_inputs, caplog):
    out = sun_inputs["tmp"] / "room_quiet"
    with caplog.at_level(logging.WARNING, logger="photoar"):
        rc = main(["-q", *scene_argv(sun_inputs, out, sun_inputs["camera"]), "--skip-probe-check",
                   *_sun_args(sun_inputs["sun"]["direction_to_sun"], sun_inputs["sun"]["irradiance_perpendicular"])])
    assert rc == 0 and not [w for w in _warnings(caplog) if "sun" in w], _warnings(caplog)


def test_sun_entry_of_the_primitives_input(sun_inputs, capsys):
    """sun_room's own scene.json as --primitives: its sun entry is taken (as the user's) and its
    window stays an opening; with --sun-* as well, the sun is given twice: one error line."""
    src = sun_inputs["root"] / "scene.json"
    out = sun_inputs["tmp"] / "room_from_scene_json"
    argv = _replace(scene_argv(sun_inputs, out, sun_inputs["camera"]), "--primitives", str(src))
    assert main(["-q", *argv, "--skip-probe-check"]) == 0, capsys.readouterr().err
    d = json.loads((out / "scene.json").read_text())
    sun = next(p for p in d["primitives"] if p["type"] == "sun")
    assert sun["declared_by"] == "user"
    assert sun["irradiance_perpendicular"] == sun_inputs["sun"]["irradiance_perpendicular"]
    assert next(p for p in d["primitives"] if p["name"] == "window")["opening"] is True
    twice = sun_inputs["tmp"] / "room_twice"
    rc = main(["-q", *_replace(scene_argv(sun_inputs, twice, sun_inputs["camera"]), "--primitives", str(src)),
               "--skip-probe-check", *_sun_args(sun_inputs["sun"]["direction_to_sun"], [50, 48, 43])])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "give the sun once" in err[0] and str(src) in err[0]
    assert not twice.exists()


def test_sun_estimate_under_known_light_is_refused(capsys, tmp_path):
    rc = main(["-q", "composite", str(shared_scene("sun_room")), "--out", str(tmp_path / "o"), "--sun", "estimate"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and err[0].startswith("photoar: error: --sun estimate:")
    assert "--lighting captured" in err[0] and not (tmp_path / "o").exists()


def test_sun_declared_without_a_sun_entry_is_refused(capsys, tmp_path):
    scene = shared_scene("window_room")
    rc = main(["-q", "composite", str(scene), "--out", str(tmp_path / "o"), "--sun", "declared",
               "--cache", str(tmp_path / "c"), "--patch-size", "0.5"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "--sun declared: the scene has no sun entry" in err[0]
    assert str(scene / "scene.json") in err[0] and not (tmp_path / "o").exists()


def test_captured_light_uses_the_users_sun(sun_room_folder, sun_inputs, tmp_path):
    """The own sun room under --lighting captured: --sun auto takes the user's sun (report.json says
    so, with its direction), the sunlit floor is lit and the chair's sun shadow is there (against
    sun_room's truth); --sun estimate on the same folder estimates it instead."""
    import cv2

    inp, root = sun_inputs, sun_inputs["root"]
    common = ["--lighting", "captured", "--object", str(inp["mesh"]), "--place", fmt(inp["place"]),
              "--yaw", repr(inp["yaw"]), "--object-albedo", fmt(inp["albedo"]), "--cache", str(tmp_path / "c")]
    assert main(["-q", "composite", str(sun_room_folder), "--out", str(tmp_path / "auto"), *common]) == 0
    rep = json.loads((tmp_path / "auto" / "report.json").read_text())
    assert rep["sun"]["from"] == "declared" and rep["sun"]["lights_room"] is True and "sun_estimate" not in rep
    np.testing.assert_allclose(rep["sun"]["direction"], inp["sun"]["direction_to_sun"], atol=1e-9)
    np.testing.assert_allclose(rep["sun"]["irradiance_perpendicular"], inp["sun"]["irradiance_perpendicular"])
    s = score(root, tmp_path / "auto" / "composite.png")
    print(f"own sun room, declared sun: {json.dumps(s)}")
    # measured: energy 0.894, rmse_affected 1.39 (untouched 21.4), rmse_object 3.57 (bias -0.9; 7.23 while
    # the chair's feet, in the floor's plane, got none of the sunlit floor's exact gather)
    assert 0.75 <= s["energy_ratio"] <= 1.1, s
    assert s["rmse_affected"] <= 2.8, s
    assert s["rmse_object"] <= 5.0, s
    # the chair's sun shadow on the sunlit floor: where the truth drops by more than 40 levels, ours
    # drops by nearly as much (measured 158.9 against 161.4 levels; no sun would leave ~0)
    lum = lambda p: cv2.imread(str(p)).astype(float).mean(-1)
    bg, truth, ours = lum(root / "background.png"), lum(root / "truth.png"), lum(tmp_path / "auto" / "composite.png")
    mask = cv2.imread(str(root / "truth_mask.png"), cv2.IMREAD_GRAYSCALE) > 127
    shadow = ((bg - truth) > 40) & ~mask
    assert shadow.sum() > 1000
    assert (bg - ours)[shadow].mean() >= 0.9 * (bg - truth)[shadow].mean()

    assert main(["-q", "composite", str(sun_room_folder), "--out", str(tmp_path / "est"), "--sun", "estimate",
                 *common]) == 0
    rep = json.loads((tmp_path / "est" / "report.json").read_text())
    assert rep["sun"]["from"] == "estimate"
    # the sun used is the estimate's (to rounding: the two are written from separately normalised vectors)
    np.testing.assert_allclose(rep["sun"]["direction"], rep["sun_estimate"]["direction"], rtol=0, atol=1e-12)
    assert 0.0 < rep["sun_estimate"]["direction_error_deg"] <= 2.0


def test_sun_option_on_composite_evaluate_and_gui():
    """--sun is EngineParams.sun on every command that composites (help and choices from the field)."""
    from app.cli import build_parser
    from app.engine import EngineParams

    sub = next(a for a in build_parser()._actions if a.dest == "command").choices
    for cmd in ("composite", "evaluate", "gui"):
        opt = next(a for a in sub[cmd]._actions if "--sun" in a.option_strings)
        assert opt.choices == ["auto", "estimate", "declared"] and opt.default == "auto", cmd
        assert opt.help.startswith(EngineParams.doc("sun")), cmd
    with pytest.raises(SystemExit):
        build_parser().parse_args(["composite", "s", "--out", "o", "--sun", "guess"])


def test_users_sun_that_cannot_enter_under_captured_light(sun_room_folder, tmp_path, caplog):
    """A user's sun below the horizon under captured light: used as declared (not replaced by the
    estimate), a warning naming the cause, no sun on any surface; report's sun says it lights nothing."""
    import dataclasses

    from app.engine import Engine, EngineParams
    from recon.scene import load_scene

    s = load_scene(sun_room_folder, load_textures=False)
    s.sun = dataclasses.replace(s.sun, direction=s.sun.direction * [1, -1, 1])
    with caplog.at_level(logging.WARNING, logger="photoar"):
        e = Engine(s, EngineParams(patch_size=0.4, emitter_patch_size=0.3, passes=8, lighting="captured"),
                   cache_dir=tmp_path, quiet=True)
    assert e.sun.source == "declared" and e.sun.estimate is None and not e.sun.on
    assert [w for w in _warnings(caplog) if "below the horizon" in w and str(sun_room_folder) in w]
    rep = e.sun.report()
    assert rep["from"] == "declared" and rep["lights_room"] is False and "below the horizon" in rep["no_direct_sun"]
    np.testing.assert_allclose(rep["direction"], s.sun.direction)


def test_gui_lighting_picker_keeps_a_valid_sun_choice(tmp_path):
    """The gui's lighting picker (PlacementController.set_lighting) from captured light with --sun
    estimate to known or photo light: --sun falls back to auto (the others refuse estimate), and
    back to captured it stays auto."""
    from app.cli import demo_scene_dir
    from app.engine import EngineParams
    from app.placement import PlacementController as PC

    ctl = PC.open(demo_scene_dir(), params=EngineParams(lighting="captured", sun="estimate"),
                  cache_dir=tmp_path / "cache")
    assert ctl.set_lighting("known") and ctl.params.sun == "auto" and ctl.params.lighting == "known"
    assert ctl.set_lighting("photo") and ctl.params.sun == "auto"
    assert ctl.set_lighting("captured") and ctl.params.sun == "auto"
