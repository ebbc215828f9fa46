"""The bottom layer's I/O (recon/io.py), camera parser (recon/camera.py) and primitive parser
(recon/scene.py): atomic writes, valid JSON, one clear error per bad field."""
import json
import math

import numpy as np
import pytest

from recon.camera import Camera
from recon.io import AtomicFolder, AtomicOutput, SceneError, dumps_json, read_exr, read_image_rgb, read_json, write_exr, \
    write_json, write_npz, write_png
from recon.primitives import primitive_from_json
from recon.scene import parse_primitive
from tests.conftest import shared_scene


def strict_json(text: str):
    """json.loads that refuses NaN / Infinity (Python's json accepts them by default)."""
    def refuse(const):
        raise ValueError(f"not valid JSON: {const}")

    return json.loads(text, parse_constant=refuse)


def leftovers(folder):
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


# ---------------------------------------------------------------------------------------------
# Atomic writes

@pytest.mark.parametrize("writer, name", [
    (lambda p: write_json(p, {"a": object()}), "out.json"),  # not serialisable: fails before writing
    (lambda p: write_png(p, np.zeros((4, 4, 7), np.uint8)), "out.png"),  # OpenCV refuses 7 channels
    (lambda p: write_npz(p, a=np.zeros(3), b=_Boom()), "out.npz"),  # fails while writing
])
def test_failed_write_keeps_the_old_file_and_leaves_nothing(tmp_path, writer, name):
    target = tmp_path / name
    target.write_bytes(b"old content")
    with pytest.raises(Exception):
        writer(target)
    assert target.read_bytes() == b"old content"
    assert leftovers(tmp_path) == []


class _Boom:
    """An 'array' whose conversion fails half-way through np.savez."""

    def __array__(self, *a, **k):
        raise RuntimeError("disk full (simulated)")


def test_atomic_output_is_all_or_nothing(tmp_path):
    out = tmp_path / "run"
    with pytest.raises(RuntimeError):
        with AtomicOutput(out) as stage:
            write_json(stage / "a.json", {"x": 1})
            raise RuntimeError("fails after the first file")
    assert not out.exists() and leftovers(tmp_path) == []
    with AtomicOutput(out) as stage:
        write_json(stage / "a.json", {"x": 1})
        write_png(stage / "b.png", np.full((2, 3, 3), 7, np.uint8))
    assert sorted(p.name for p in out.iterdir()) == ["a.json", "b.png"] and leftovers(tmp_path) == []


def test_atomic_folder_replaces_the_whole_folder_and_keeps_the_users_files(tmp_path):
    """AtomicFolder: a new version replaces the folder whole (a file the old version had and the new
    one does not is gone), files `ours` does not claim stay, and a failed run changes nothing."""
    out = tmp_path / "room"
    ours = lambda name: name.startswith("gen_")  # noqa: E731
    with AtomicFolder(out, ours) as stage:
        for name in ("gen_a.json", "gen_old.json"):
            write_json(stage / name, {"v": 1})
    (out / "notes.txt").write_text("the user's")
    with pytest.raises(RuntimeError):
        with AtomicFolder(out, ours) as stage:
            write_json(stage / "gen_a.json", {"v": 2})
            raise RuntimeError("fails half-way")
    assert sorted(p.name for p in out.iterdir()) == ["gen_a.json", "gen_old.json", "notes.txt"]
    assert read_json(out / "gen_a.json") == {"v": 1} and leftovers(tmp_path) == []
    with AtomicFolder(out, ours) as stage:
        write_json(stage / "gen_a.json", {"v": 2})
    assert sorted(p.name for p in out.iterdir()) == ["gen_a.json", "notes.txt"]
    assert read_json(out / "gen_a.json") == {"v": 2} and (out / "notes.txt").read_text() == "the user's"
    assert leftovers(tmp_path) == []


def test_image_round_trips(tmp_path):
    rgb = np.random.default_rng(0).integers(0, 256, (5, 6, 3), dtype=np.uint8)
    write_png(tmp_path / "x.png", rgb)
    assert np.array_equal(read_image_rgb(tmp_path / "x.png"), rgb)  # RGB in, RGB out
    hdr = np.random.default_rng(1).random((5, 6, 3)).astype(np.float32) * 100
    write_exr(tmp_path / "x.exr", hdr)
    assert np.array_equal(read_exr(tmp_path / "x.exr"), hdr)
    assert leftovers(tmp_path) == []


def test_unreadable_images_name_the_file(tmp_path):
    bad = tmp_path / "bad.exr"
    bad.write_bytes(b"not an exr")
    with pytest.raises(SceneError, match="bad.exr: not a readable OpenEXR image"):
        read_exr(bad)
    with pytest.raises(SceneError, match="bad.exr: not a readable image"):
        read_image_rgb(bad)
    with pytest.raises(SceneError, match="missing.png: file not found"):
        read_image_rgb(tmp_path / "missing.png")


# ---------------------------------------------------------------------------------------------
# JSON

def test_write_json_turns_non_finite_floats_into_null(tmp_path):
    data = {"sigma": float("inf"), "neg": -np.inf, "nan": np.float32("nan"), "arr": np.array([1.0, np.inf]),
            "ok": np.float64(2.5), "n": np.int64(3), "flag": np.bool_(True), "nested": [{"x": math.nan}]}
    write_json(tmp_path / "a.json", data)
    got = strict_json((tmp_path / "a.json").read_text())
    assert got == {"sigma": None, "neg": None, "nan": None, "arr": [1.0, None], "ok": 2.5, "n": 3, "flag": True,
                   "nested": [{"x": None}]}
    assert strict_json(dumps_json(data)) == got


def test_strict_parser_refuses_infinity():
    with pytest.raises(ValueError):
        strict_json(json.dumps({"x": float("inf")}))


def test_read_json_errors_name_the_file(tmp_path):
    (tmp_path / "bad.json").write_text("{")
    with pytest.raises(ValueError, match="bad.json: malformed JSON"):
        read_json(tmp_path / "bad.json")
    with pytest.raises(SceneError, match="none.json: file not found"):
        read_json(tmp_path / "none.json", SceneError)


def test_metrics_prints_and_writes_valid_json_for_equal_images(tmp_path, capsys):
    """Equal images have an infinite PSNR; the outputs say null, not Infinity."""
    from app.cli import main

    img = np.random.default_rng(2).integers(0, 256, (8, 8, 3), dtype=np.uint8)
    write_png(tmp_path / "a.png", img)
    assert main(["-q", "metrics", str(tmp_path / "a.png"), str(tmp_path / "a.png"), "--out",
                 str(tmp_path / "m")]) == 0
    printed = strict_json(capsys.readouterr().out)
    written = strict_json((tmp_path / "m" / "metrics.json").read_text())
    assert printed["psnr_db"] is None and written["psnr_db"] is None and printed["rmse"] == 0.0


# ---------------------------------------------------------------------------------------------
# Camera parsing: one parser for scene.json, camera.json and cameras.json entries

CAM = {"K": {"fx": 500.0, "fy": 500.0, "cx": 319.5, "cy": 239.5, "width": 640, "height": 480},
       "R": np.eye(3).tolist(), "t": [0.0, -1.5, 4.0], "exposure_time": 0.25}


def test_camera_forms_agree(tmp_path):
    a = Camera.from_json(CAM, "scene.json", "main_camera.")
    K = [[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]]
    b = Camera.from_json({"K": K, "R": CAM["R"], "t": CAM["t"], "width": 640, "height": 480}, "cameras.json")
    write_json(tmp_path / "camera.json", {**CAM["K"], "K": CAM["K"], "K_matrix": K, "R": CAM["R"], "t": CAM["t"]})
    c = Camera.load(tmp_path / "camera.json")
    write_json(tmp_path / "scene.json", {"main_camera": CAM})
    d = Camera.load(tmp_path / "scene.json")
    for cam in (b, c, d):
        assert np.array_equal(cam.K, a.K) and np.array_equal(cam.R, a.R) and np.array_equal(cam.t, a.t)
        assert (cam.width, cam.height) == (640, 480)
    assert a.exposure_time == d.exposure_time == 0.25 and b.exposure_time == 1.0
    assert np.allclose(a.centre, [0.0, 1.5, -4.0])


@pytest.mark.parametrize("change, field", [
    (lambda c: c.pop("R"), "main_camera.R"),
    (lambda c: c["K"].pop("fy"), "main_camera.K.fy"),
    (lambda c: c.update(R=[[1, 0, 0], [0, 1, 0], [0, 0, -1]]), "main_camera.R"),  # a reflection
    (lambda c: c.update(R=[[1, 0], [0, 1]]), "main_camera.R"),
    (lambda c: c.update(t=[0, "x", 1]), "main_camera.t"),
    (lambda c: c["K"].update(fx=-500.0), "main_camera.K"),
    (lambda c: c["K"].update(width=640.5), "main_camera.K.width"),
    (lambda c: c.update(exposure_time=0), "main_camera.exposure_time"),
    (lambda c: c.pop("K"), "main_camera.K"),
])
def test_bad_camera_names_file_and_field(change, field):
    cam = json.loads(json.dumps(CAM))
    change(cam)
    with pytest.raises(SceneError) as e:
        Camera.from_json(cam, "room/scene.json", "main_camera.")
    assert str(e.value).startswith("room/scene.json: ") and f"'{field}" in str(e.value), e.value


def test_camera_json_of_calibrate_loads():
    """`photoar calibrate`'s own output format (Calibration.to_json) reads back through Camera.load."""
    from recon.vanishing import Calibration

    cam = Camera.from_json(CAM, "x")
    d = Calibration(cam, {}, float("inf"), True, "image centre", "camera height", 0.5).to_json()
    back = Camera.from_json(strict_json(dumps_json(d)), "camera.json")
    assert np.array_equal(back.K, cam.K) and np.array_equal(back.R, cam.R) and np.array_equal(back.t, cam.t)
    assert back.focal_rel_sigma is None and back.ill_conditioned is True  # inf is written as null
    d.update(focal_rel_sigma=0.08, ill_conditioned=False)
    back = Camera.from_json(d, "camera.json")
    assert back.focal_rel_sigma == 0.08 and back.ill_conditioned is False
    with pytest.raises(SceneError, match="camera.json: field 'ill_conditioned'"):
        Camera.from_json(dict(d, ill_conditioned="yes"), "camera.json")


# ---------------------------------------------------------------------------------------------
# Primitive parsing: scene.json and model files go through one parser

@pytest.mark.parametrize("prim, field", [
    ({"type": "box", "center": [0, 0, 0]}, "primitives[0].size"),
    ({"type": "box", "center": [0, 0, 0], "size": [1, 0, 1]}, "primitives[0].size"),
    ({"type": "quad", "corners": [[0, 0, 0], [1, 0, 0], [1, 1, 0]]}, "primitives[0].corners"),
    ({"type": "quad", "corners": [[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]]}, "primitives[0].corners"),
    ({"type": "quad", "corners": [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], "normal": [0, 0, 0]},
     "primitives[0].normal"),
    ({"type": "sphere"}, "primitives[0].type"),
    ({"type": "box", "center": [0, 0, 0], "size": [1, 1, 1], "albedo": [1, 1]}, "primitives[0].albedo"),
])
def test_bad_primitive_same_error_from_both_loaders(prim, field):
    msgs = []
    for parse in (lambda: parse_primitive(prim, "primitives[0]", "m.json"),
                  lambda: primitive_from_json(prim, "primitives[0]", "m.json")):
        with pytest.raises(ValueError) as e:
            parse()
        msgs.append(str(e.value))
    assert msgs[0] == msgs[1] and msgs[0].startswith("m.json: ") and f"'{field}" in msgs[0], msgs


def test_scene_and_model_give_the_same_quads():
    """load_scene and PrimitiveModel.to_quads build the engine's quads the same way (every primitive
    'free', so that the model's scene graph does not move any)."""
    from recon.primitives import model_from_dict
    from recon.scene import load_scene

    root = shared_scene("lamps_room")
    scene = load_scene(root)
    d = read_json(root / "scene.json")
    prims = [dict(p, attach="free") for p in d["primitives"]]
    quads = model_from_dict({"primitives": prims}, "scene.json").to_quads(scene.room_min, scene.room_max, root)
    assert [q.name for q in quads] == [q.name for q in scene.quads]
    for a, b in zip(quads, scene.quads):
        assert np.allclose(a.corners, b.corners, atol=1e-9) and np.allclose(a.normal, b.normal, atol=1e-9)
        assert a.role == b.role and np.array_equal(a.emission, b.emission) and np.array_equal(a.albedo, b.albedo)
        assert (a.texture is None) == (b.texture is None)


# ---------------------------------------------------------------------------------------------
# File modes: every written file honours the umask (mkstemp alone would leave it 0600)

@pytest.fixture(params=[0o022, 0o027, 0o002])
def umask(request):
    import os

    old = os.umask(request.param)
    yield request.param
    os.umask(old)


def test_written_files_honour_the_umask(tmp_path, umask):
    import os
    import stat

    from recon.io import current_umask

    assert current_umask() == umask
    write_png(tmp_path / "a.png", np.zeros((4, 4, 3), np.uint8))
    write_exr(tmp_path / "a.exr", np.zeros((4, 4, 3), np.float32))
    write_json(tmp_path / "a.json", {"a": 1})
    write_npz(tmp_path / "a.npz", a=np.zeros(3))
    with AtomicOutput(tmp_path / "out") as stage:
        write_json(stage / "report.json", {})
        write_png(stage / "composite.png", np.zeros((4, 4, 3), np.uint8))
    with AtomicFolder(tmp_path / "room", lambda name: True) as stage:
        write_json(stage / "scene.json", {})
    files = [tmp_path / n for n in ("a.png", "a.exr", "a.json", "a.npz")] + \
        [tmp_path / "out" / "report.json", tmp_path / "out" / "composite.png", tmp_path / "room" / "scene.json"]
    want = 0o666 & ~umask
    assert {f.name: oct(stat.S_IMODE(os.stat(f).st_mode)) for f in files} == {f.name: oct(want) for f in files}
    assert stat.S_IMODE(os.stat(tmp_path / "room").st_mode) == 0o777 & ~umask
    assert not leftovers(tmp_path)


# ---------------------------------------------------------------------------------------------
# json_array / json_bool: a JSON number is a number, not a string, boolean or null

@pytest.mark.parametrize("value, shape, words", [
    ("0.53", (), ['a number, got "0.53"', "a string is not a number"]),
    ([-0.74, "0.62", 0.27], (3,), ["3 numbers", "a string is not a number"]),
    ([1, True, 0], (3,), ["a boolean is not a number"]),
    (None, (3,), ["got null"]),
    ([[1, 2], [3]], (2, 2), ["2x2 numbers", "[[1, 2], [3]]"]),
    ([1.0, 2.0], (3,), ["3 numbers, got [1, 2]"]),
    ([float("nan"), 0.6, 0.2], (3,), ["must be finite, got [nan, 0.6, 0.2]"]),
    (float("-inf"), (), ["must be finite, got -inf"]),
])
def test_json_array_refuses_and_shows_the_value(value, shape, words):
    from recon.io import json_array

    with pytest.raises(SceneError) as e:
        json_array(value, shape, "f.g", "x.json")
    msg = str(e.value)
    assert msg.startswith("x.json: field 'f.g' must be") and "\n" not in msg
    for w in words:
        assert w in msg, (w, msg)


def test_json_array_takes_numbers_and_arrays():
    from recon.io import json_array

    assert json_array([1, 2.5, -3], (3,), "f", "x").tolist() == [1.0, 2.5, -3.0]
    assert json_array(np.eye(3), (3, 3), "f", "x").tolist() == np.eye(3).tolist()
    assert float(json_array(7, (), "f", "x")) == 7.0


@pytest.mark.parametrize("value, expected", [(True, True), (False, False), (None, False), ("absent", False)])
def test_json_bool_takes_json_booleans(value, expected):
    from recon.io import json_bool

    d = {} if value == "absent" else {"opening": value}
    assert json_bool(d, "opening", "p[1].", "x.json") is expected


@pytest.mark.parametrize("value", ["false", "true", 0, 1, [True]])
def test_json_bool_refuses_anything_else(value):
    from recon.io import json_bool

    with pytest.raises(SceneError, match=r"x\.json: field 'p\[1\]\.opening' must be true or false, got "):
        json_bool({"opening": value}, "opening", "p[1].", "x.json")
