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
