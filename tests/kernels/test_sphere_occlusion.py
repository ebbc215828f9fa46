"""kernels.sphere_occlusion (the sphere drag frame's kernel) against exact occlusion: a ball over a plane
under a uniform sky (SH part) and under a small disk light (compact part); the ellipsoid's shadow area;
app.dragshadow's part fit on a ball and on two boxes."""
import numpy as np
import pytest

from kernels.sphere_occlusion import N_SH, SphereRatio, sh16_np


def _sky_sh(n: int = 40000) -> tuple[np.ndarray, float]:
    """(16,3) SH of a uniform sky over +y as a point set (Fibonacci hemisphere, cosine-weighted; the
    transfers' units: E = 1 for radiance 1), and its E."""
    i = np.arange(n) + 0.5
    y = 1.0 - i / n  # uniform in cos over the hemisphere
    phi = i * np.pi * (3.0 - np.sqrt(5.0))
    s = np.sqrt(1.0 - y * y)
    d = np.stack([s * np.cos(phi), y, s * np.sin(phi)], 1)
    w = 2.0 * d[:, 1] / n  # cos-weighted share of the hemisphere (solid angle 2 pi / n each, / pi)
    return np.einsum("nk,n->k", sh16_np(d), w)[:, None].repeat(3, 1), float(w.sum())


def _ratio(points, normals, E, sh, centres, axes, device, cw=None, cc=None, cr=None, radiance=None):
    n = len(points)
    cw = np.zeros((n, 0, 3)) if cw is None else cw
    cc = np.zeros((n, 0, 3)) if cc is None else cc
    cr = np.zeros(0) if cr is None else cr
    k = SphereRatio(points, normals, E, sh, cw, cc, cr, device)
    lo = np.zeros((len(centres), 6, 3)) if radiance is None else radiance
    return k.run(np.asarray(centres, float), np.asarray(axes, float), lo, lambda f, m: f(0, m))


def test_ball_under_uniform_sky_blocks_its_cap(device):
    # a ball of radius R at distance h from a point on the floor, its centre tilted t from the normal: the
    # exact blocked share of a uniform sky is sin^2(a) cos(t), sin a = R / h (a cap above the horizon).
    # Order-3 SH of the cosine-weighted sky: within 8 % of the blocked share (+0.002) up to 45 degrees, 15 %
    # at 70 degrees (the cosine lobe's kink at the horizon is what order 3 truncates)
    sh, E = _sky_sh()
    assert abs(E - 1.0) < 1e-3
    R = 0.2
    for h in (0.3, 0.6, 1.0, 2.0):
        for tilt, tol in ((0.0, 0.08), (45.0, 0.08), (70.0, 0.15)):
            t = np.radians(tilt)
            c = np.array([[np.sin(t) * h, np.cos(t) * h, 0.0]])
            r = _ratio(np.zeros((1, 3)), np.array([[0.0, 1.0, 0.0]]), np.full((1, 3), E), sh[None], c,
                       R * np.eye(3)[None], device)
            exact = (R / h) ** 2 * np.cos(t)
            assert abs((1.0 - r[0, 0]) - exact) <= tol * exact + 0.002, (h, tilt, 1 - r[0, 0], exact)


def test_ball_under_a_disk_light_casts_umbra_and_penumbra(device):
    # a disk light of radius 0.1 m at 2 m over the floor, a ball of radius 0.2 m at 1 m: every floor point's
    # hidden share against a brute-force count over 4000 points of the disk: within 0.15 (the kernel's 12
    # samples: a shadow edge across the disk moves the count in steps of 1/12, and 12 points cover a disk's
    # halves unevenly by about one more), 0.05 on average over the penumbra; the umbra's centre hides all of
    # it, a point 1.5 m aside none
    light, rl = np.array([0.0, 2.0, 0.0]), 0.1
    ball, R = np.array([0.0, 1.0, 0.0]), 0.2
    xs = np.linspace(-0.5, 0.5, 41)
    pts = np.stack([xs, np.zeros_like(xs), np.zeros_like(xs)], 1)
    pts = np.concatenate([pts, [[1.5, 0.0, 0.0]]])
    n = len(pts)
    w = np.full((n, 1, 3), 0.5)  # the disk's light at each point; the sky's SH is empty
    r = _ratio(pts, np.tile([0.0, 1.0, 0.0], (n, 1)), np.full((n, 3), 0.5), np.zeros((n, N_SH, 3)), ball[None],
               R * np.eye(3)[None], device, cw=w, cc=np.tile(light, (n, 1, 1)), cr=np.array([rl]))
    hidden = 1.0 - r[:, 0]
    rng = np.random.default_rng(0)
    a = rng.uniform(0, 2 * np.pi, 4000)
    q = rl * np.sqrt(rng.uniform(0, 1, 4000))
    disk = light + np.stack([q * np.cos(a), np.zeros_like(q), q * np.sin(a)], 1)  # facing down (the kernel's disk
    # faces each point; from under it the two agree within the brute force's noise)
    errs = []
    for p, hk in zip(pts, hidden):
        v = disk - p
        t = np.clip(((ball - p) @ v.T) / (v * v).sum(1), 0, 1)
        exact = np.mean(np.linalg.norm(p + t[:, None] * v - ball, axis=1) < R)
        assert abs(hk - exact) <= 0.15, (p, hk, exact)
        if 0.0 < exact < 1.0:
            errs.append(abs(hk - exact))
    assert len(errs) >= 4 and np.mean(errs) <= 0.05
    assert hidden[20] == pytest.approx(1.0) and hidden[-1] == pytest.approx(0.0)


def test_ellipsoid_shadow_area():
    # the equivalent radius's projected area pi |det A| |A^-1 d|: a flat disk ellipsoid (R, R, c) seen face-on
    # casts pi R^2, edge-on pi R c; a ball pi r^2 from anywhere
    from kernels.sphere_occlusion import equivalent_radius  # noqa: F401 (the kernel's function)

    def area(A, d):
        return np.pi * abs(np.linalg.det(A)) * np.linalg.norm(np.linalg.inv(A) @ d)

    R, c = 0.3, 0.01
    A = np.diag([R, c, R])
    assert area(A, np.array([0.0, 1.0, 0.0])) == pytest.approx(np.pi * R * R)
    assert area(A, np.array([1.0, 0.0, 0.0])) == pytest.approx(np.pi * R * c)
    d = np.array([1.0, 2.0, -0.5]) / np.linalg.norm([1.0, 2.0, -0.5])
    assert area(0.2 * np.eye(3), d) == pytest.approx(np.pi * 0.04)


def _box(lo, hi):
    v = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])], float)
    f = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1], [2, 3, 7], [2, 7, 6],
                  [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    return v, f


def test_fit_parts_ball_and_two_boxes():
    # a ball is one part, its own ellipsoid of inertia: semi-axes within 3 % of its radius (the voxels);
    # two boxes apart are two parts, each at its box's centre, its semi-axes sqrt(5/12) x its sides
    import open3d as o3d

    from app.dragshadow import fit_parts

    m = o3d.geometry.TriangleMesh.create_sphere(0.3, 40)
    c, A = fit_parts(np.asarray(m.vertices) + [1.0, 0.5, 2.0], np.asarray(m.triangles))
    assert len(c) == 1
    np.testing.assert_allclose(c[0], [1.0, 0.5, 2.0], atol=5e-3)
    np.testing.assert_allclose(np.linalg.norm(A[0], axis=0), 0.3, rtol=0.03)
    v1, f1 = _box([0, 0, 0], [0.4, 0.05, 0.4])
    v2, f2 = _box([1, 0, 0], [1.05, 0.5, 0.05])
    c, A = fit_parts(np.concatenate([v1, v2]), np.concatenate([f1, f2 + 8]))
    assert len(c) == 2
    order = np.argsort(c[:, 0])
    np.testing.assert_allclose(c[order], [[0.2, 0.025, 0.2], [1.025, 0.25, 0.025]], atol=0.01)
    for j, sides in zip(order, ([0.4, 0.05, 0.4], [0.05, 0.5, 0.05])):
        np.testing.assert_allclose(np.sort(np.linalg.norm(A[j], axis=0)), np.sort(np.sqrt(5 / 12) * np.array(sides)),
                                   rtol=0.1)
