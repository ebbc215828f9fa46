"""recon/scene.py's sun entry and flags: a hand-typed direction of any length is normalised, a value
of the wrong type is refused with the primitive's index and name."""
import json
import shutil

import numpy as np
import pytest

from app.cli import demo_scene_dir
from recon.scene import SceneError, load_scene

SUN = {"name": "sun", "type": "sun", "direction_to_sun": [-0.74, 0.62, 0.27], "angular_diameter_deg": 0.53,
       "irradiance_perpendicular": [51.8, 48.7, 43.5]}


def _scene(tmp_path, sun=None, edit=None):
    dst = tmp_path / "scene"
    shutil.copytree(demo_scene_dir(), dst)
    d = json.loads((dst / "scene.json").read_text())
    if sun is not None:
        d["primitives"].append(sun)
    if edit:
        edit(d)
    (dst / "scene.json").write_text(json.dumps(d))
    return dst


@pytest.mark.parametrize("direction", [[-0.74, 0.62, 0.27], [-7.4, 6.2, 2.7], [-1, 1, 0], [0, 0.001, 0]])
def test_any_finite_nonzero_direction_is_normalised(tmp_path, direction):
    # [-0.74, 0.62, 0.27] has length 1.00245 (typed by hand): it was refused with a 1e-3 tolerance
    s = load_scene(_scene(tmp_path, dict(SUN, direction_to_sun=direction)), load_textures=False)
    d = np.asarray(direction, float)
    assert np.linalg.norm(s.sun.direction) == pytest.approx(1.0, abs=1e-12)
    assert s.sun.direction == pytest.approx(d / np.linalg.norm(d), abs=1e-12)


def test_sun_is_named_by_index_and_name(tmp_path):
    root = _scene(tmp_path, dict(SUN, name="noon", angular_diameter_deg="0.53"))
    with pytest.raises(SceneError) as e:
        load_scene(root, load_textures=False)
    n = len(json.loads((root / "scene.json").read_text())["primitives"]) - 1
    assert str(e.value).startswith(f"{root / 'scene.json'}: field 'primitives[{n}] ('noon').angular_diameter_deg'")


def test_unnamed_sun_is_named_by_index(tmp_path):
    sun = {k: v for k, v in SUN.items() if k != "name"}
    root = _scene(tmp_path, dict(sun, direction_to_sun=[0, 0, 0]))
    with pytest.raises(SceneError, match=r"field 'primitives\[\d+\]\.direction_to_sun' must not be the zero vector"):
        load_scene(root, load_textures=False)


def test_opening_flag_false_and_absent_are_no_opening(tmp_path):
    def edit(d):
        d["primitives"][0]["opening"] = False
        d["primitives"][1]["opening"] = True

    s = load_scene(_scene(tmp_path, edit=edit), load_textures=False)
    assert [q.name for q in s.quads if q.opening] == [json.loads((demo_scene_dir() / "scene.json").read_text())
                                                      ["primitives"][1]["name"]]
