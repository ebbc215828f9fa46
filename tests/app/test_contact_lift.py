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
