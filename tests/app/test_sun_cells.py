"""The sun's loss beside an object's foot gathered per sun sample point's cell (object_shading.sun_cells; issue 34,
sun_106's box: its foot on the floor its own sun shadow darkens, branch objsun110).

A box's face stands at z = 0 (normal +z, x in [-0.2, 0.2], height 0.4 m) on a floor y = 0; a distant sun from
behind it at elevation e with tan e = 0.4 / 0.09 shades the floor in front of the face for z < 0.09 m (|x| < 0.2).
The floor patch x in [-0.09, 0.09], z in [0, 0.18] (the room's 0.18 m patch) carries the sun's 4 x 4 sample points
(app.stages.sun): its two rows nearer the face lost, the two farther lit. At a point of the face 1 cm above the floor
the floor's sunlit radiance L = 1 gives irradiance/pi = the integral over the lit part of cos cos / (pi r^2) dA,
here by a 600 x 600 midpoint quadrature (brute force). The patch whole at its mean (half lit) is 0.38 over it
relative (it spreads the far, lit half's light onto the near floor the point sees most of); its 16 cells, each
at its own point's share, give it to the quadrature's 0.3 %.
"""
import numpy as np

from app.stages.object_shading import sun_cells

N_SIDE = 4
TAN_E = 0.4 / 0.09
PATCH = np.array([[-0.09, 0.0, 0.0], [-0.09, 0.0, 0.18], [0.09, 0.0, 0.18], [0.09, 0.0, 0.0]])  # c1 - c0 along +z


def _sample_points(corners: np.ndarray) -> np.ndarray:
    """app.stages.sun.SunSetup.apply's sample points of a patch (K,3), in its order."""
    f = (np.arange(N_SIDE) + 0.5) / N_SIDE
    fu, fv = [a.ravel() for a in np.meshgrid(f, f)]
    c0 = corners[0]
    return c0 + fu[:, None] * (corners[1] - c0) + fv[:, None] * (corners[3] - c0)


def _shaded(p: np.ndarray) -> np.ndarray:
    """(N,) bool: the floor point p (N,3) lies in the face's sun shadow (the ray toward the sun meets the face)."""
    return (p[:, 2] * TAN_E < 0.4) & (np.abs(p[:, 0]) < 0.2) & (p[:, 2] >= 0)


def _polygon_ff(p: np.ndarray, n: np.ndarray, poly: np.ndarray) -> float:
    """Lambert's form factor from point p (normal n) to the convex polygon poly (k,3), wholly above p's horizon."""
    r = poly - p
    r /= np.linalg.norm(r, axis=1, keepdims=True)
    total = 0.0
    for i in range(len(r)):
        a, b = r[i], r[(i + 1) % len(r)]
        c = np.cross(a, b)
        total += np.arccos(np.clip(a @ b, -1, 1)) * (c / np.linalg.norm(c)) @ n
    return abs(total) / (2 * np.pi)


def test_cells_are_the_sample_points_and_keep_the_patch_mean():
    lost = np.random.default_rng(3).random((1, N_SIDE * N_SIDE))
    cells, vals, k = sun_cells(PATCH[None], np.array([[-0.6, -0.5, -0.4]]), lost)
    assert cells.shape == (16, 4, 3) and vals.shape == (16, 3)  # all different: 16 cells
    np.testing.assert_allclose(cells.mean(1), _sample_points(PATCH)[k], atol=1e-12)  # each holds its sample point
    np.testing.assert_allclose(vals.mean(0), [-0.6, -0.5, -0.4], rtol=1e-12)  # equal areas: the mean is the patch's
    np.testing.assert_allclose(vals[:, 0] / -0.6, lost[0][k] / lost[0].mean(), rtol=1e-12)
    # a patch that loses nothing keeps its value (no division by its zero mean), merged into one rectangle
    whole, flat, _ = sun_cells(PATCH[None], np.array([[0.2, 0.2, 0.2]]), np.zeros((1, 16)))
    np.testing.assert_allclose(flat, 0.2, rtol=1e-12)
    np.testing.assert_allclose(whole[0], PATCH, atol=1e-12)
    # an L-shaped shadow: 3 rectangles covering the patch once (area kept), each of one value
    lshape = np.zeros((1, 16))
    lshape[0, [0, 1, 4, 5, 8, 9, 12, 13, 2, 3]] = 1.0  # two columns, and the rest of the first row
    polys, v, _ = sun_cells(PATCH[None], np.array([[1.0, 1.0, 1.0]]), lshape)
    area = lambda q: 0.5 * np.linalg.norm(np.cross(q[:, 2] - q[:, 0], q[:, 3] - q[:, 1]), axis=1)
    assert len(polys) == 3
    np.testing.assert_allclose(area(polys).sum(), 0.18 ** 2, rtol=1e-12)
    np.testing.assert_allclose((area(polys) * v[:, 0]).sum() / 0.18 ** 2, 1.0, rtol=1e-12)


def test_cells_against_a_brute_force_gather_at_the_foot():
    p = np.array([0.0, 0.01, 0.0])  # on the face, 1 cm above the floor
    n = np.array([0.0, 0.0, 1.0])
    m = 600
    t = (np.arange(m) + 0.5) / m
    gx, gz = np.meshgrid(-0.09 + 0.18 * t, 0.18 * t)
    q = np.stack([gx.ravel(), np.zeros(m * m), gz.ravel()], 1)
    r = q - p
    d2 = np.einsum("nc,nc->n", r, r)
    kern = (r @ n) * (-r[:, 1]) / (np.pi * d2 ** 2) * (0.18 / m) ** 2  # cos_i cos_j / (pi r^2) dA
    brute = float(kern[~_shaded(q)].sum())
    lit = (~_shaded(_sample_points(PATCH))).astype(float)[None]  # the sun's share per sample point (L = 1 lit)
    assert lit.mean() == 0.5
    whole = _polygon_ff(p, n, PATCH) * lit.mean()
    cells, vals, _ = sun_cells(PATCH[None], np.array([[lit.mean()] * 3]), lit)
    assert len(cells) == 2  # the shaded half and the lit half
    gathered = sum(_polygon_ff(p, n, c) * v for c, v in zip(cells, vals[:, 0]))
    assert abs(gathered - brute) < 3e-3 * brute, (gathered, brute)
    assert whole > 1.3 * brute, (whole, brute)  # the patch whole: far too much light at the foot


def _stage(radius: float = 0.127):
    """A stand-in ObjectShading (the attributes _sun_loss_cells reads) with the one sunlit floor patch PATCH, gathered
    exactly at B = 0.6 (albedo 0.5, sun irradiance/pi 1.6 on the lit half of its sample points: 0.4 of sun, 0.2
    indirect)."""
    from types import SimpleNamespace

    pm = SimpleNamespace(n_patches=1, corners=PATCH[None], normal=np.array([[0.0, 1.0, 0.0]]),
                         centre=PATCH.mean(0)[None], radius=np.array([radius]), albedo=np.full((1, 3), 0.5),
                         is_emitter=np.zeros(1, bool))
    rl = SimpleNamespace(emitters=np.array([0]), radiance=np.full((1, 3), 0.6))
    return SimpleNamespace(patches=pm, room_light=rl, config=SimpleNamespace(sun_cells=True))


def test_the_patch_comes_back_as_its_cells_never_below_its_indirect_light():
    from app.stages.object_shading import ObjectShading

    u = np.arange(16) % 4
    s = (u >= 2).astype(float)[None]  # the opening's stripe: the far two columns sunlit
    v = np.arange(16) // 4
    lost = s * (v < 2)  # the object shades the near two rows
    E_sun = np.full(3, 1.6)
    sun_dB = -0.5 * E_sun * lost.mean()  # as the engine: -albedo x mean lost share x E_sun
    vu = np.array([[0.0, 0.01, -0.001], [0.0, 0.4, -0.4]])  # the object's vertices' box beside the patch
    corners, normals, values = ObjectShading._sun_loss_cells(_stage(), vu, np.array([0]), sun_dB[None],
                                                             (np.array([0]), lost, s, E_sun))
    area = 0.5 * np.linalg.norm(np.cross(corners[:, 2] - corners[:, 0], corners[:, 3] - corners[:, 1]), axis=1)
    np.testing.assert_allclose(values[0], -0.6, rtol=1e-12)  # the exact gather's whole patch cancelled
    np.testing.assert_allclose(area[0], 0.18 ** 2, rtol=1e-12)
    cells, vals = slice(1, None), values[1:, 0]
    assert len(vals) == 3  # the unlit half (one rectangle), the lit quarter the object shades, the lit quarter
    np.testing.assert_allclose(area[cells].sum(), 0.18 ** 2, rtol=1e-12)
    # the cells' mean is the patch's radiance plus its sun loss: nothing added or lost
    np.testing.assert_allclose((area[cells] * vals).sum() / 0.18 ** 2, 0.6 + sun_dB[0], rtol=1e-12)
    assert vals.min() >= 0.2 - 1e-12  # the indirect part stays: the shaded sunlit quarter is 0.2, not 0.6 - 0.8
    np.testing.assert_allclose(np.sort(vals), [0.2, 0.2, 1.0], rtol=1e-12)
    # the loss's cells alone on the patch's mean (the first version): the shaded sunlit quarter goes negative
    assert 0.6 - 0.8 * lost.max() < 0
    # a patch farther than SUN_NEAR diameters from the vertices stays whole
    far = ObjectShading._sun_loss_cells(_stage(), vu + np.array([0.0, 0.0, -1.0]), np.array([0]), sun_dB[None],
                                        (np.array([0]), lost, s, E_sun))
    assert len(far[0]) == 1 and np.allclose(far[2], sun_dB)
