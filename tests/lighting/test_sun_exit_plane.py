"""The sun's ray leaves through an opening cut from a wall that lies in the opening's own plane: the
wall's hit there must not block it, whatever the sun's direction (in float32 that hit falls just
before or just after the exit by rounding alone, which speckled the sunlit floor and the object's
sun shadow)."""
import math

import numpy as np
import pytest

from recon.scene import Sun, load_scene
from tests.conftest import shared_scene
from tests.own_room import fmt, scene_argv, sunlit_inputs


@pytest.fixture(scope="module")
def own_room(tmp_path_factory):
    """sun_room as a user assembles it (`photoar scene`: the tape-measured room box, whose x = 0 wall
    is one whole quad, and the window in it flagged as an opening), its patches and the engine's
    occluder for light (openings open)."""
    from app.cli import main
    from app.stages.precompute import scene_occluders
    from kernels import runtime
    from recon.patches import build_patches

    inp = sunlit_inputs(shared_scene("sun_room"), tmp_path_factory.mktemp("exit_plane"))
    tmp, cam, sun = inp["tmp"], inp["camera"], inp["sun"]
    assert main(["-q", *scene_argv(inp, tmp / "room", cam), "--skip-probe-check", "--sun-direction",
                 fmt(sun["direction_to_sun"]), "--sun-irradiance", fmt(sun["irradiance_perpendicular"])]) == 0
    runtime.init()
    s = load_scene(tmp / "room", load_textures=False)
    pm = build_patches(s, 0.18, 0.1)
    return s, pm, scene_occluders(s, pm, "cpu")[0]


def _turned(d: np.ndarray, deg: float) -> np.ndarray:
    """d turned by deg about +Y."""
    a = math.radians(deg)
    c, s = math.cos(a), math.sin(a)
    return np.array([c * d[0] + s * d[2], d[1], -s * d[0] + c * d[2]])


@pytest.mark.parametrize("turn_deg", [0.0, -0.2, 0.5, 3.0])
def test_floor_inside_the_openings_projection_sees_the_sun(own_room, turn_deg):
    """Floor points under the middle 80 % of the window, projected along the sun: every one sees the
    sun (visibility = cos to the floor normal, d_y). Measured before the exit margin: 49, 124, 38 and
    184 of the 625 points dark for these turns."""
    from lighting.sun import SunLight, openings

    s, pm, occ = own_room
    d = _turned(s.sun.direction, turn_deg)
    light = SunLight(Sun(d, 0.53, np.full(3, 50.0), np.zeros(3)), openings(s), occ)
    win = openings(s)[0]
    c0, U, V = win.corners[0], win.corners[1] - win.corners[0], win.corners[3] - win.corners[0]
    g = np.linspace(0.1, 0.9, 25)
    on_window = np.array([c0 + a * U + b * V for a in g for b in g])
    floor = on_window - (on_window[:, 1] / d[1])[:, None] * d  # along -d down to y = 0
    lo, hi = np.asarray(s.room_min, float), np.asarray(s.room_max, float)
    xz = [0, 2]
    inside = np.all((floor[:, xz] >= lo[xz] + 0.05) & (floor[:, xz] <= hi[xz] - 0.05), axis=1)
    assert inside.sum() > 300
    vis = light.visibility(floor[inside], np.tile([0.0, 1.0, 0.0], (int(inside.sum()), 1)))
    dark = int((np.abs(vis - d[1]) > 1e-9).sum())
    assert dark == 0, f"{dark} of {inside.sum()} floor points under the opening see no sun"
