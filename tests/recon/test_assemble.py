"""recon.assemble (issue 20): a window's `opening` flag and a sun entry of the primitives input reach
the room folder `photoar scene` writes; bad values are refused with the field named."""
import numpy as np
import pytest

from recon.assemble import input_sun, parse_primitives
from recon.io import SceneError

ROOM = {"name": "room", "type": "box", "role": "room", "center": [2.5, 1.375, 2.25], "size": [5.0, 2.75, 4.5]}
WINDOW = {"name": "window", "type": "quad", "role": "window", "normal": [1, 0, 0],
          "corners": [[0.0, 2.25, 3.0], [0.0, 2.25, 1.5], [0.0, 0.875, 1.5], [0.0, 0.875, 3.0]]}
SUN = {"name": "sun", "type": "sun", "direction_to_sun": [-0.7405, 0.6157, 0.2695],
       "irradiance_perpendicular": [51.8, 48.7, 43.5]}


def test_opening_flag_is_kept_on_a_window():
    prims, _, _ = parse_primitives({"primitives": [ROOM, {**WINDOW, "opening": True}]}, "m.json")
    win = next(p for p in prims if p["name"] == "window")
    assert win["opening"] is True and win["emitter"] is True
    prims, _, _ = parse_primitives({"primitives": [ROOM, {**WINDOW, "opening": False}]}, "m.json")
    assert "opening" not in next(p for p in prims if p["name"] == "window")  # false: the default, not written
    prims, _, _ = parse_primitives({"primitives": [ROOM, WINDOW]}, "m.json")
    assert not any("opening" in p for p in prims)


@pytest.mark.parametrize("value", ["true", "false", 1, None, [True]])
def test_opening_that_is_no_boolean_is_refused(value):
    with pytest.raises(SceneError, match=r"m.json: field 'primitives\[1\].opening' must be true or false"):
        parse_primitives({"primitives": [ROOM, {**WINDOW, "opening": value}]}, "m.json")


def test_opening_only_on_a_window_quad():
    wall = {**WINDOW, "role": "room", "name": "wall", "opening": True}
    with pytest.raises(SceneError, match=r"primitives\[1\].opening': only a quad with role 'window'"):
        parse_primitives({"primitives": [ROOM, wall]}, "m.json")
    box = {"name": "desk", "type": "box", "center": [3, 0.4, 1], "size": [1, 0.8, 0.5], "opening": True}
    with pytest.raises(SceneError, match="only a quad with role 'window'"):
        parse_primitives({"primitives": [ROOM, box]}, "m.json")


def test_input_sun_is_validated_normalised_and_marked_as_the_users():
    d = {"primitives": [ROOM, WINDOW, SUN]}
    prims, _, _ = parse_primitives(d, "m.json")
    assert not any(p.get("type") == "sun" for p in prims)  # the sun is no room primitive
    sun = input_sun(d, "m.json")
    assert sun["declared_by"] == "user" and sun["irradiance_perpendicular"] == SUN["irradiance_perpendicular"]
    assert np.linalg.norm(sun["direction_to_sun"]) == pytest.approx(1.0, abs=1e-12)
    d = np.array(SUN["direction_to_sun"])
    np.testing.assert_allclose(sun["direction_to_sun"], d / np.linalg.norm(d))
    assert input_sun({"primitives": [ROOM, WINDOW]}, "m.json") is None
    with pytest.raises(SceneError, match=r"m.json: field 'primitives\[2\].irradiance_perpendicular'"):
        input_sun({"primitives": [ROOM, WINDOW, {**SUN, "irradiance_perpendicular": [1, -1, 1]}]}, "m.json")
    with pytest.raises(SceneError, match="a second sun"):
        input_sun({"primitives": [ROOM, SUN, SUN]}, "m.json")


def test_inside_turn_takes_the_turn_only_when_it_alone_lies_inside():
    """inside_turn: a camera inside the box is kept; one at the mirror image of an inside point (the world turned
    180 deg about +Y) is turned back inside; one outside either way is kept unchanged (the caller's check names it)."""
    import numpy as np

    from recon import assemble as asm
    from recon.camera import Camera

    lo, hi = np.array([0.5, 0.0, 0.5]), np.array([4.0, 3.0, 5.0])
    R = np.eye(3)

    def at(c):
        return Camera(K=np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]]), R=R, t=-R @ np.asarray(c, float),
                      width=640, height=480)

    inside, mirrored, outside = at([2.0, 1.5, 3.0]), at([-2.0, 1.5, -3.0]), at([9.0, 1.5, 9.0])
    cam, turned = asm.inside_turn(inside, lo, hi)
    assert cam is inside and not turned
    cam, turned = asm.inside_turn(mirrored, lo, hi)
    assert turned and np.allclose(cam.centre, [2.0, 1.5, 3.0], atol=1e-9)
    cam, turned = asm.inside_turn(outside, lo, hi)
    assert cam is outside and not turned
