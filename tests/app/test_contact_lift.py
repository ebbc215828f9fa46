"""app.stages.object_shading.lift_off_contacts: a vertex that touches a room surface gathered exactly
(a chair's foot on the sunlit floor) takes that surface's light from just above the contact, where a
point in the surface's own plane sees it at a form factor of 0."""
import numpy as np
from scipy import integrate

from app.stages.object_shading import CONTACT_LIFT, lift_off_contacts
from kernels.visibility import transfer_matrix


def _floor(size: float = 4.0, step: float = 0.1):
    """A floor y = 0 of step x step quads over [-size/2, size/2]^2, normals up: (corners, centres, normals,
    radii)."""
    e = np.arange(-size / 2, size / 2, step)
    x0, z0 = [a.ravel() for a in np.meshgrid(e, e)]
    c = np.stack([np.stack([x0, 0 * x0, z0], 1), np.stack([x0, 0 * x0, z0 + step], 1),
                  np.stack([x0 + step, 0 * x0, z0 + step], 1), np.stack([x0 + step, 0 * x0, z0], 1)], 1)
    centre = c.mean(1)
    normal = np.tile([0.0, 1.0, 0.0], (len(c), 1))
    radius = np.linalg.norm(c - centre[:, None], axis=2).max(1)
    return c, centre, normal, radius


def _wall_point_ff(h: float, half: float = 2.0) -> float:
    """Form factor from a point at height h facing +x at the centre of the floor square [-half, half]^2
    (the floor element at (x, -h, z) relative to it: cos at the point x / r, at the floor h / r)."""
    f = lambda z, x: x * h / (np.pi * (x * x + h * h + z * z) ** 2)  # noqa: E731
    return integrate.dblquad(f, 0.0, half, -half, half, epsabs=1e-10)[0]


def test_a_foot_on_the_floor_gathers_the_floor_from_just_above():
    corners, centre, normal, radius = _floor()
    p = np.array([[0.013, 0.0, 0.027], [0.013, 0.0, 0.027], [0.5, 1.0, 0.5], [0.2, 0.0, 0.2],
                  [0.3, 0.0, 0.3]])
    n = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0],
                  [np.sqrt(0.5), -np.sqrt(0.5), 0.0]])
    q = lift_off_contacts(p, n, centre, normal, radius, eps=2e-3)
    h = CONTACT_LIFT * radius[0]
    # a side face at the contact rises along its own plane to h; the sole (facing into the floor), a
    # point off the floor and a face whose back is the floor stay where they are
    np.testing.assert_allclose(q[0], p[0] + [0.0, h, 0.0], atol=1e-12)
    np.testing.assert_allclose(q[1:4], p[1:4], atol=0)
    # a face tilted 45 degrees down stays in its plane, at height h
    assert abs(np.dot(q[4] - p[4], n[4])) < 1e-12 and abs(q[4, 1] - h) < 1e-12
    # the floor radiance 1: in the floor's plane the form factor is 0; lifted it is the analytic one at
    # that height, within 1 % (n_side 4 samples per quad; no occluder)
    G = transfer_matrix(np.stack([p[0], q[0]]), n[:2] * 0 + n[0], corners, normal, [], n_side=4, eps=2e-3)
    at_floor, lifted = G.astype(np.float64).sum(1)
    ref = _wall_point_ff(h)
    assert at_floor < 1e-6, at_floor
    assert 0.45 < ref < 0.5 and abs(lifted - ref) <= 0.01 * ref, (lifted, ref)


def test_the_box_prefilter_keeps_every_patch_a_point_can_touch():
    """lift_off_contacts asks its tree only about the patches within reach of the points' box
    (object_shading._within_box): a superset of those within reach of some point (brute force, every pair),
    and the lifted points are bit for bit those with far patches added to the list, which it skips."""
    from app.stages.object_shading import _within_box
    rng = np.random.default_rng(3)
    p = rng.uniform(-0.3, 0.3, (400, 3))
    centre = rng.uniform(-1.0, 1.0, (3000, 3))
    reach = rng.uniform(0.01, 0.2, 3000)
    cand = _within_box(centre, reach, p.min(0), p.max(0))
    d = np.linalg.norm(centre[:, None] - p[None], axis=2).min(1)
    must = np.flatnonzero(d <= reach)
    assert len(must) > 50 and np.isin(must, cand).all() and (np.diff(cand) > 0).all()
    assert len(cand) < 0.5 * len(centre)  # it does leave out the far ones
    # a chair's feet on a floor, the floor's patches listed with far wall patches between them
    _, fc, fn, fr = _floor()
    feet = np.array([[0.013, 0.0, 0.027], [0.41, 0.004, 0.33], [0.2, 0.5, 0.2], [0.05, 0.001, 0.0]])
    fnrm = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [np.sqrt(0.5), -np.sqrt(0.5), 0.0]])
    wc = np.stack([np.full(500, 3.0), rng.uniform(0, 2, 500), rng.uniform(-2, 2, 500)], 1)
    wn = np.tile([-1.0, 0.0, 0.0], (500, 1))
    mixed = [np.concatenate([a[:800], b, a[800:]]) for a, b in ((fc, wc), (fn, wn), (fr, np.full(500, 0.07)))]
    q0 = lift_off_contacts(feet, fnrm, fc, fn, fr, eps=2e-3)
    q1 = lift_off_contacts(feet, fnrm, *mixed, eps=2e-3)
    assert np.array_equal(q0, q1) and not np.array_equal(q0, feet)


def test_every_pair_tested_gives_the_tree_s_lift(monkeypatch):
    """_pairs_within tests every (patch, point) pair where they are few and asks a cKDTree otherwise: both give
    the same lifted points, bit for bit (a floor's patches under feet and points just above it, two passes)."""
    import app.stages.object_shading as osh
    _, fc, fn, fr = _floor(2.0, 0.05)
    rng = np.random.default_rng(5)
    p = np.concatenate([rng.uniform(-0.9, 0.9, (300, 3)) * [1.0, 0.0, 1.0],
                        rng.uniform(-0.9, 0.9, (300, 3)) * [1.0, 0.004, 1.0]])
    nrm = rng.normal(size=(600, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    monkeypatch.setattr(osh, "LIFT_BRUTE_PAIRS", 10 ** 9)
    brute = lift_off_contacts(p, nrm, fc, fn, fr, eps=2e-3)
    monkeypatch.setattr(osh, "LIFT_BRUTE_PAIRS", 0)
    tree = lift_off_contacts(p, nrm, fc, fn, fr, eps=2e-3)
    assert np.array_equal(brute, tree) and (np.abs(brute - p).max(1) > 0).sum() > 200
