"""lighting.radiance.probe_shadowed: the patches the probe's ball hides from the sun (analytic cases)."""
import numpy as np

from lighting.radiance import probe_shadowed

BALL = {"centre": [0.0, 0.3, 0.0], "radius": 0.1}


def floor_patch(x: float, z: float, half: float = 0.05) -> np.ndarray:
    """(4,3) corners of a floor square centred at (x, 0, z), corners 0-1-2-3 around it."""
    return np.array([[x - half, 0, z - half], [x + half, 0, z - half], [x + half, 0, z + half],
                     [x - half, 0, z + half]], float)


def test_the_ball_shades_the_patch_below_it_from_an_overhead_sun():
    c = np.stack([floor_patch(0, 0), floor_patch(0.5, 0), floor_patch(0.12, 0)])
    # overhead sun: the shadow is the ball's 0.1 m disc; the 0.1 m patch at x = 0.12 reaches x = 0.07..0.17,
    # its sample points (4 x 4, 0.025 m apart) at x = 0.0825.. are within 0.1 m of the axis only at z = +-0.0125
    # and +-0.0375: shaded in part, so flagged
    assert probe_shadowed(c, BALL, np.array([0.0, 1.0, 0.0])).tolist() == [True, False, True]


def test_a_low_sun_moves_the_shadow_along_its_direction():
    d = np.array([1.0, 1.0, 0.0]) / np.sqrt(2.0)  # 45 deg towards +x: the shadow's centre at x = -0.3
    c = np.stack([floor_patch(-0.3, 0), floor_patch(0.0, 0)])
    # (0,0,0): the ray towards the sun passes the centre at sqrt(0.09 - 0.045) = 0.212 m > 0.1 m
    assert probe_shadowed(c, BALL, d).tolist() == [True, False]


def test_a_ball_behind_the_sunward_side_shades_nothing():
    # the sun below the horizon side: the ball is behind every floor point's ray
    c = np.stack([floor_patch(0, 0)])
    assert probe_shadowed(c, BALL, np.array([0.0, -1.0, 0.0])).tolist() == [False]
