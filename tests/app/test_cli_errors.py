"""Bad input: one-line error naming the file/field, exit status 2, nothing left in --out."""
import json
import shutil

import pytest

from app.cli import demo_scene_dir, main as cli


@pytest.fixture
def scene(tmp_path):
    """A writable copy of the bundled demo scene."""
    dst = tmp_path / "scene"
    shutil.copytree(demo_scene_dir(), dst)
    return dst


def _run(capsys, scene, out):
    code = cli(["-q", "composite", str(scene), "--out", str(out), "--cache", str(out.parent / "cache")])
    err = capsys.readouterr().err.strip()
    return code, err


def _assert_clean_failure(code, err, out, *needles):
    assert code == 2
    assert len(err.splitlines()) == 1 and err.startswith("photoar: error: "), err
    for n in needles:
        assert n in err, (n, err)
    assert not out.exists()
    assert not [p for p in out.parent.iterdir() if ".partial-" in p.name]


def test_missing_scene_json(capsys, scene, tmp_path):
    (scene / "scene.json").unlink()
    code, err = _run(capsys, scene, tmp_path / "out")
    _assert_clean_failure(code, err, tmp_path / "out", "scene.json", "not found")


def test_missing_photo(capsys, scene, tmp_path):
    (scene / "background.png").unlink()
    code, err = _run(capsys, scene, tmp_path / "out")
    _assert_clean_failure(code, err, tmp_path / "out", "background.png", "not found")


def test_malformed_json(capsys, scene, tmp_path):
    (scene / "scene.json").write_text('{"name": "x", "world": ')
    code, err = _run(capsys, scene, tmp_path / "out")
    _assert_clean_failure(code, err, tmp_path / "out", "scene.json", "malformed JSON")


def test_missing_field(capsys, scene, tmp_path):
    d = json.loads((scene / "scene.json").read_text())
    del d["main_camera"]["R"]
    (scene / "scene.json").write_text(json.dumps(d))
    code, err = _run(capsys, scene, tmp_path / "out")
    _assert_clean_failure(code, err, tmp_path / "out", "scene.json", "main_camera.R")


def test_wrong_shape_field(capsys, scene, tmp_path):
    d = json.loads((scene / "scene.json").read_text())
    d["primitives"][0]["corners"] = [[0, 0, 0], [1, 0, 0]]
    (scene / "scene.json").write_text(json.dumps(d))
    code, err = _run(capsys, scene, tmp_path / "out")
    _assert_clean_failure(code, err, tmp_path / "out", "primitives[0].corners")


def test_mesh_fails_to_load(capsys, scene, tmp_path):
    (scene / "object_chair.ply").write_bytes(b"ply\nformat garbage\nend_header\n\x00\x01")
    code, err = _run(capsys, scene, tmp_path / "out")
    _assert_clean_failure(code, err, tmp_path / "out", "object_chair.ply")


def test_object_outside_room(capsys, scene, tmp_path):
    d = json.loads((scene / "scene.json").read_text())
    d["synthetic_object"]["object_to_world"][0][3] = 50.0
    (scene / "scene.json").write_text(json.dumps(d))
    code, err = _run(capsys, scene, tmp_path / "out")
    _assert_clean_failure(code, err, tmp_path / "out", "synthetic_object.object_to_world", "outside the room")


def test_existing_output_untouched_on_failure(capsys, scene, tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "keep.txt").write_text("old")
    (scene / "scene.json").write_text("[]")
    code, err = cli(["-q", "composite", str(scene), "--out", str(out)]), capsys.readouterr().err
    assert code == 2 and "scene.json" in err
    assert [p.name for p in out.iterdir()] == ["keep.txt"]


def test_bad_option_value(capsys, tmp_path):
    with pytest.raises(SystemExit) as e:
        cli(["composite", "x", "--out", str(tmp_path / "o"), "--passes", "0"])
    assert e.value.code == 2
    assert "--passes" in capsys.readouterr().err


def _strip(scene, *, radiance=False, response=False):
    d = json.loads((scene / "scene.json").read_text())
    if radiance:
        for p in d["primitives"]:
            p.pop("emitted_radiance", None)
    if response:
        del d["camera_response"]
    (scene / "scene.json").write_text(json.dumps(d))


def test_known_light_without_emitters(capsys, scene, tmp_path):
    # a user's room declares no emitted radiance: known light would give a black object
    _strip(scene, radiance=True)
    code, err = _run(capsys, scene, tmp_path / "out")
    _assert_clean_failure(code, err, tmp_path / "out", "scene.json", "no emitters", "--lighting captured")


def test_known_light_without_a_response(capsys, scene, tmp_path):
    _strip(scene, response=True)
    code, err = _run(capsys, scene, tmp_path / "out")
    _assert_clean_failure(code, err, tmp_path / "out", "scene.json", "camera_response", "--lighting captured")


def test_cuda_device_without_cuda(capsys, scene, tmp_path):
    import warp as wp

    if wp.is_cuda_available():
        pytest.skip("this machine has CUDA")
    out = tmp_path / "out"
    for cmd in (["composite", str(scene), "--out", str(out)], ["demo", "--out", str(out)],
                ["evaluate", str(scene), "--out", str(out)], ["reference", str(scene), "--out", str(out)]):
        code = cli(["-q", *cmd, "--device", "cuda:0", "--cache", str(tmp_path / "cache")])
        err = capsys.readouterr().err.strip()
        _assert_clean_failure(code, err, out, "cuda:0", "no CUDA device")


def test_device_reaches_the_engine(capsys, scene, tmp_path, monkeypatch):
    # every command that runs kernels hands --device to the engine it builds
    from app.engine import Engine

    seen = []

    def fake_init(self, scene, params=None, cache_dir=None, device=None, quiet=False):
        seen.append(device)
        raise RuntimeError("stop here")

    monkeypatch.setattr(Engine, "__init__", fake_init)
    out = tmp_path / "out"
    cmds = [["composite", str(scene), "--out", str(out)], ["demo", "--out", str(out)],
            ["evaluate", str(scene), "--out", str(out)],
            ["reference", str(scene), "--out", str(out), "--lighting", "captured"]]
    for cmd in cmds:
        assert cli(["-q", *cmd, "--device", "cpu"]) == 2
        assert "stop here" in capsys.readouterr().err
    assert seen == ["cpu"] * len(cmds)


def test_object_inside_a_wall(capsys, scene, tmp_path):
    # --place half into the back wall (z = 0): one line naming the mesh and the room
    out = tmp_path / "out"
    code = cli(["-q", "composite", str(scene), "--out", str(out), "--object", str(scene / "object_chair.ply"),
                "--place", "2.0,0,0.05", "--cache", str(tmp_path / "cache")])
    _assert_clean_failure(code, capsys.readouterr().err.strip(), out, "object_chair.ply", "outside the room")


def test_no_synthetic_object_needs_a_placement(capsys, scene, tmp_path):
    d = json.loads((scene / "scene.json").read_text())
    del d["synthetic_object"]
    (scene / "scene.json").write_text(json.dumps(d))
    code, err = _run(capsys, scene, tmp_path / "out")
    _assert_clean_failure(code, err, tmp_path / "out", "scene.json", "synthetic_object", "--place")


# ---------------------------------------------------------------------------------------------
# scene.json's types: a string, boolean or null where a number or a flag belongs is one error line

SUN = {"name": "sun", "type": "sun", "direction_to_sun": [-0.74, 0.62, 0.27], "angular_diameter_deg": 0.53,
       "irradiance_perpendicular": [51.8, 48.7, 43.5]}


def _with_sun(scene, **changes):
    """The demo scene with a sun entry (changed by `changes`; None removes a key) after its primitives;
    returns the sun's index."""
    d = json.loads((scene / "scene.json").read_text())
    sun = dict(SUN)
    for k, v in changes.items():
        sun.pop(k) if v is None else sun.update({k: v})
    d["primitives"].append(sun)
    (scene / "scene.json").write_text(json.dumps(d, allow_nan=True))
    return len(d["primitives"]) - 1


@pytest.mark.parametrize("change, needles", [
    ({"angular_diameter_deg": "0.53"}, ["angular_diameter_deg", "a number", '"0.53"', "a string"]),
    ({"direction_to_sun": [-0.74, "0.62", 0.27]}, ["direction_to_sun", "3 numbers", "a string"]),
    ({"direction_to_sun": "west"}, ["direction_to_sun", '"west"']),
    ({"direction_to_sun": [-0.74, 0.62]}, ["direction_to_sun", "3 numbers", "[-0.74, 0.62]"]),
    ({"direction_to_sun": [float("nan"), 0.6, 0.2]}, ["direction_to_sun", "must be finite", "[nan, 0.6, 0.2]"]),
    ({"angular_diameter_deg": float("nan")}, ["angular_diameter_deg", "must be finite", "got nan"]),
    ({"irradiance_perpendicular": [float("inf"), 1, 1]}, ["irradiance_perpendicular", "must be finite", "inf"]),
    ({"direction_to_sun": [0, 0, 0]}, ["direction_to_sun", "zero vector"]),
    ({"angular_diameter_deg": True}, ["angular_diameter_deg", "a boolean"]),
])
def test_sun_field_of_the_wrong_type_is_one_error(capsys, scene, tmp_path, change, needles):
    i = _with_sun(scene, **change)
    code, err = _run(capsys, scene, tmp_path / "out")
    _assert_clean_failure(code, err, tmp_path / "out", "scene.json", f"primitives[{i}] ('sun')", *needles)
    assert "shape" not in err  # the value itself, not numpy's shape, is shown


def test_null_sun_direction_says_null(capsys, scene, tmp_path):
    d = json.loads((scene / "scene.json").read_text())
    d["primitives"].append(dict(SUN, direction_to_sun=None))
    (scene / "scene.json").write_text(json.dumps(d))
    code, err = _run(capsys, scene, tmp_path / "out")
    _assert_clean_failure(code, err, tmp_path / "out", "direction_to_sun", "got null", "null is not a number")


@pytest.mark.parametrize("key, value", [("opening", "false"), ("opening", "yes"), ("opening", 1),
                                        ("emitter", "false")])
def test_flag_that_is_not_a_boolean_is_one_error(capsys, scene, tmp_path, key, value):
    # "opening": "false" was taken for an opening (a non-empty string is true in Python)
    d = json.loads((scene / "scene.json").read_text())
    i = next(k for k, p in enumerate(d["primitives"]) if p["type"] == "quad")
    d["primitives"][i][key] = value
    (scene / "scene.json").write_text(json.dumps(d))
    code, err = _run(capsys, scene, tmp_path / "out")
    _assert_clean_failure(code, err, tmp_path / "out", "scene.json", f"primitives[{i}].{key}", "true or false",
                          json.dumps(value))


def test_numeric_string_in_another_field_is_one_error(capsys, scene, tmp_path):
    # the same validator reads every numeric field: a box's size, the camera's exposure time
    d = json.loads((scene / "scene.json").read_text())
    d["main_camera"]["exposure_time"] = "0.01"
    (scene / "scene.json").write_text(json.dumps(d))
    code, err = _run(capsys, scene, tmp_path / "out")
    _assert_clean_failure(code, err, tmp_path / "out", "main_camera.exposure_time", "a string")


# ---------------------------------------------------------------------------------------------
# argparse errors: one line `photoar <subcommand>: error: <problem> (photoar <subcommand> --help)`

SCENE_ARGS = ["scene", "room", "--photo", "p.png", "--camera", "c.json", "--primitives", "q.json"]


@pytest.mark.parametrize("argv, prog, needles", [
    (SCENE_ARGS + ["--sun-direction=-0.74,0.62"], "photoar scene", ["--sun-direction", "three", "got 2"]),
    (SCENE_ARGS + ["--sun-direction", "west"], "photoar scene", ["--sun-direction", "'west'"]),
    (SCENE_ARGS + ["--sun-direction", "nan,1,0"], "photoar scene", ["--sun-direction", "finite", "'nan,1,0'"]),
    (SCENE_ARGS + ["--sun-irradiance", "50"], "photoar scene", ["--sun-irradiance", "three", "'50'"]),
    (["composite", "x", "--out", "o", "-q", "--bogus"], "photoar composite", ["unrecognized arguments: --bogus"]),
    (["composite", "x", "--out", "o", "--passes", "abc"], "photoar composite", ["--passes", "an integer", "'abc'"]),
    (["composite", "x", "--out", "o", "--yaw", "nan"], "photoar composite", ["--yaw", "finite"]),
    (["composite", "x"], "photoar composite", ["required", "--out"]),
    (["probe", "sh", "x.exr", "--mapping", "cube"], "photoar probe sh", ["--mapping", "invalid choice"]),
    (["compost", "x"], "photoar", ["invalid choice", "'compost'"]),
])
def test_argparse_error_is_one_line(capsys, argv, prog, needles):
    with pytest.raises(SystemExit) as e:
        cli(argv)
    err = capsys.readouterr().err
    assert e.value.code == 2
    assert len(err.strip().splitlines()) == 1, err
    assert err.startswith(f"{prog}: error: ") and err.rstrip().endswith(f"({prog} --help)"), err
    assert "usage" not in err and "Traceback" not in err
    for n in needles:
        assert n in err, (n, err)
    assert "X,Y,Z" not in err  # --sun-irradiance is R,G,B: the message names no axes


def test_vector_starting_with_minus_needs_no_equals_sign():
    from app.cli import build_parser

    a = build_parser().parse_args(SCENE_ARGS + ["--sun-direction", "-0.74,0.62,0.27", "--sun-irradiance", "5,5,5"])
    assert a.sun_direction == (-0.74, 0.62, 0.27) and a.sun_irradiance == (5.0, 5.0, 5.0)
    a = build_parser().parse_args(["composite", "s", "--out", "o", "--place", "-1,0,-2.5", "--yaw", "-30"])
    assert a.place == (-1.0, 0.0, -2.5) and a.yaw == -30.0


@pytest.mark.parametrize("argv, quiet", [
    (["composite", "s", "--out", "o"], False),
    (["-q", "composite", "s", "--out", "o"], True),
    (["composite", "s", "--out", "o", "-q"], True),
    (["composite", "s", "-q", "--out", "o"], True),
    (["probe", "sh", "x.exr", "--mapping", "latlong", "--quiet"], True),
    (["probe", "sh", "x.exr", "--mapping", "latlong"], False),
])
def test_quiet_before_or_after_the_subcommand(argv, quiet):
    from app.cli import build_parser

    assert build_parser().parse_args(argv).quiet is quiet


# ---------------------------------------------------------------------------------------------
# warnings: one line `photoar: warning: <file>: <problem>`

def test_log_lines_are_prefixed_by_level():
    import logging

    from app.cli import LogFormatter

    def line(level, msg, exc=None):
        return LogFormatter().format(logging.LogRecord("photoar", level, __file__, 1, msg, (), exc))

    assert line(logging.INFO, "wrote x") == "wrote x"
    msg = "s/scene.json: sun: no direct sun"
    assert line(logging.WARNING, msg) == f"photoar: warning: {msg}"
    try:
        raise RuntimeError("bad\nthing")
    except RuntimeError:
        import sys

        exc = sys.exc_info()
    assert line(logging.ERROR, "frame failed", exc) == "photoar: error: frame failed: bad thing"  # no traceback


def test_cli_warning_is_one_prefixed_line(tmp_path):
    # end to end in a fresh process (the CLI's own log setup): an HDR image with a negative value
    # warns, with -q after the subcommand (warnings still show)
    import os
    import subprocess
    import sys

    import numpy as np

    from recon.io import write_exr

    img = np.ones((8, 16, 3), np.float32)
    img[0, 0, 0] = -1.0
    write_exr(tmp_path / "neg.exr", img)
    from tests.conftest import ROOT

    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    r = subprocess.run([sys.executable, "-m", "app.cli", "probe", "sh", str(tmp_path / "neg.exr"), "--mapping",
                        "latlong", "-q"], cwd=ROOT, capture_output=True, text=True, env=env)
    assert r.returncode == 0, r.stderr
    assert r.stderr.splitlines() == [f"photoar: warning: {tmp_path / 'neg.exr'}: 1 negative values clamped to 0"]
