"""The object's own interreflection (app.stages.object_light.object_self_light) against analytic form factors."""
import numpy as np

from app.stages.object_light import object_self_light
from kernels.visibility import Occluder


def point_polygon_ff(p: np.ndarray, n: np.ndarray, poly: np.ndarray) -> float:
    """Lambert's contour formula: form factor from a point p (unit normal n) to a polygon seen from its front,
    1/(2 pi) sum over edges of the angle the edge subtends times n . (the edge plane's unit normal)."""
    r = poly - p
    total = 0.0
    for i in range(len(poly)):
        a, b = r[i], r[(i + 1) % len(poly)]
        g = np.cross(a, b)
        ang = np.arctan2(np.linalg.norm(g), a @ b)
        total += ang * (n @ g) / np.linalg.norm(g)
    return abs(total) / (2 * np.pi)


def corner():
    """Two unit squares meeting at a right angle along the x axis (an open book at 90 deg), both facing into
    the corner: the floor y = 0 (normal +y, z in [0, 1]) and the wall z = 0 (normal +z, y in [0, 1])."""
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 0, 1], [0, 0, 1],  # floor
                  [0, 0, 0], [0, 1, 0], [1, 1, 0], [1, 0, 0]], float)  # wall
    f = np.array([[0, 2, 1], [0, 3, 2], [4, 6, 5], [4, 7, 6]], np.int32)  # CCW seen from the inside of the corner
    return v, f


def test_corner_one_bounce_matches_lambert():
    """The wall's two triangles lit by the floor at radiance 1 (albedo 0.5, one bounce) get 0.5 x the exact
    point-to-square form factor from their centroids, within 1e-4 (the kernel's polygon form factor in float64;
    the centroid rays are unblocked); the floor, lit by nothing, stays 0."""
    v, f = corner()
    occ = Occluder(v, f, "cpu")
    L = np.zeros((4, 3))
    L[:2] = 1.0
    (out,) = object_self_light(v, f, occ, [L], np.array([0.5, 0.5, 0.5]), bounces=1, device="cpu")
    floor = v[[0, 1, 2, 3]]
    for t in (2, 3):
        c = v[f[t]].mean(0)
        want = 0.5 * point_polygon_ff(c, np.array([0.0, 0.0, 1.0]), floor)
        assert 0.05 < want < 0.2
        np.testing.assert_allclose(out[t], want, atol=1e-4)
    np.testing.assert_allclose(out[:2], 0.0, atol=1e-12)


def test_corner_two_bounces_and_linearity():
    """Two bounces: the second is the first sent back (albedo x F of the first), so the floor gets
    0.5 x sum_t F(floor centroid -> wall triangle t) x the wall's first bounce (to 1e-4); the parts add (the
    result of L1 + L2 equals the sum of the results, 1e-9)."""
    v, f = corner()
    occ = Occluder(v, f, "cpu")
    L = np.zeros((4, 3))
    L[:2] = 1.0
    rho = np.array([0.5, 0.5, 0.5])
    (one,) = object_self_light(v, f, occ, [L], rho, bounces=1, device="cpu")
    (two,) = object_self_light(v, f, occ, [L], rho, bounces=2, device="cpu")
    for t in (0, 1):
        c = v[f[t]].mean(0)
        back = sum(0.5 * point_polygon_ff(c, np.array([0.0, 1.0, 0.0]), v[f[s]]) * one[s, 0] for s in (2, 3))
        np.testing.assert_allclose(two[t], back, atol=1e-4)
    L2 = np.zeros((4, 3))
    L2[2:, 1] = 3.0
    a, b, ab = object_self_light(v, f, occ, [L, L2, L + L2], rho, bounces=2, device="cpu")
    np.testing.assert_allclose(a + b, ab, atol=1e-9)


def test_convex_object_gets_nothing():
    """A cube's faces do not see each other: its self-light is 0 (1e-12)."""
    v = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float)
    q = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    f = np.array([t for a, b, c, d in q for t in ((a, b, c), (a, c, d))], np.int32)
    occ = Occluder(v, f, "cpu")
    (out,) = object_self_light(v, f, occ, [np.ones((12, 3))], np.array([0.8, 0.8, 0.8]), device="cpu")
    np.testing.assert_allclose(out, 0.0, atol=1e-12)
