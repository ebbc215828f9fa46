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
