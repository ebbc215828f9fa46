"""Tests for kernels.formfactor.point_to_polygon (differential area -> polygon form factors).

References used here are independent of the implementation under test:
  * closed-form catalogue cases (parallel / perpendicular rectangle with the receiver's foot at a corner,
    coaxial disk),
  * adaptive 2-D quadrature (scipy dblquad) of the defining integrand
        1/pi * max(cos_r, 0) * max(cos_s, 0) / r^2
    over a fan triangulation of the polygon; the polygon is first cut along the receiver's tangent plane so
    that the quadrature never has to resolve the kink of the clamped cosine,
  * Monte-Carlo: fraction of cosine-weighted hemisphere rays that hit the polygon's emitting side.
"""
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import dblquad

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from kernels.formfactor import point_to_polygon  # noqa: E402

ANALYTIC_TOL = 1e-4
HARD_TOL = 1e-3


# ----------------------------------------------------------------------------------------------------------
# independent reference helpers
# ----------------------------------------------------------------------------------------------------------

def _unit(v):
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


def _poly_normal(poly):
    poly = np.asarray(poly, dtype=np.float64)
    return _unit(np.cross(poly[1] - poly[0], poly[2] - poly[0]))


def _rect(origin, e1, e2):
    """Parallelogram origin, origin+e1, origin+e1+e2, origin+e2; emitting normal is e1 x e2."""
    o, e1, e2 = (np.asarray(a, dtype=np.float64) for a in (origin, e1, e2))
    return np.stack([o, o + e1, o + e1 + e2, o + e2])


def _ngon(radius, n, z=0.0):
    """Regular n-gon inscribed in a circle of the given radius in the plane z, emitting normal +z."""
    ang = 2.0 * np.pi * np.arange(n) / n
    return np.stack([radius * np.cos(ang), radius * np.sin(ang), np.full(n, float(z))], axis=1)


def _clip_to_halfspace(poly, p, n):
    """Part of the convex polygon with n.(x - p) >= 0 (vertex list, may have < 3 vertices)."""
    out = []
    k = len(poly)
    for i in range(k):
        a, b = poly[i], poly[(i + 1) % k]
        da, db = float(n @ (a - p)), float(n @ (b - p))
        if da >= 0.0:
            out.append(a)
        if (da >= 0.0) != (db >= 0.0):
            t = da / (da - db)
            out.append(a + t * (b - a))
    return np.array(out, dtype=np.float64).reshape(-1, 3)


def _quad_ff(p, n, poly, tol=1e-11):
    """Point-to-polygon form factor by adaptive quadrature of the clamped integrand."""
    p, n, poly = (np.asarray(a, dtype=np.float64) for a in (p, n, poly))
    ns = _poly_normal(poly)
    part = _clip_to_halfspace(poly, p, n)
    total = 0.0
    for k in range(1, len(part) - 1):
        v0, e1, e2 = part[0], part[k] - part[0], part[k + 1] - part[0]
        jac = np.linalg.norm(np.cross(e1, e2))
        if jac == 0.0:
            continue

        def f(t, s, v0=v0, e1=e1, e2=e2):
            w = v0 + s * e1 + t * e2 - p
            r2 = w @ w
            return max(n @ w, 0.0) * max(-(ns @ w), 0.0) / (np.pi * r2 * r2)

        val, _ = dblquad(f, 0.0, 1.0, 0.0, lambda s: 1.0 - s, epsabs=tol, epsrel=tol)
        total += jac * val
    return total


def _mc_ff(p, n, poly, nrays=200_000, seed=0):
    """Monte-Carlo form factor: share of cosine-weighted rays hitting the front of the polygon; (F, stderr)."""
    p, n, poly = (np.asarray(a, dtype=np.float64) for a in (p, n, poly))
    n = _unit(n)
    helper = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    t1 = _unit(np.cross(n, helper))
    t2 = np.cross(n, t1)
    rng = np.random.default_rng(seed)
    u1, u2 = rng.random(nrays), rng.random(nrays)
    rad, phi = np.sqrt(u1), 2.0 * np.pi * u2
    d = ((rad * np.cos(phi))[:, None] * t1 + (rad * np.sin(phi))[:, None] * t2
         + np.sqrt(1.0 - u1)[:, None] * n)
    ns = _poly_normal(poly)
    dn = d @ ns
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (ns @ (poly[0] - p)) / dn
    hit = (dn < 0.0) & (t > 0.0)          # travelling against the emitting normal = arriving on the front
    x = p + np.where(hit, t, 0.0)[:, None] * d
    k = len(poly)
    for i in range(k):
        edge = poly[(i + 1) % k] - poly[i]
        hit &= (np.cross(edge, x - poly[i]) @ ns) >= 0.0
    f = float(hit.mean())
    return f, float(np.sqrt(f * (1.0 - f) / nrays))


def _corner_parallel(a, b, c):
    """Receiver at height c facing a parallel a x b rectangle, foot of its normal at a corner (Howell cat.)."""
    A, B = a / c, b / c
    sa, sb = np.sqrt(1.0 + A * A), np.sqrt(1.0 + B * B)
    return (A / sa * np.arctan(B / sa) + B / sb * np.arctan(A / sb)) / (2.0 * np.pi)


def _corner_perp(a, b, c):
    """Receiver at the origin, normal +z; rectangle in the plane x = c, y in [0, a], z in [0, b].

    From Lambert's contour integral: only the two edges parallel to y contribute,
    F = 1/(2 pi) [atan(a/c) - c/sqrt(b^2+c^2) * atan(a/sqrt(b^2+c^2))].
    """
    A, B = a / c, b / c
    sb = np.sqrt(1.0 + B * B)
    return (np.arctan(A) - np.arctan(A / sb) / sb) / (2.0 * np.pi)


def _perp_rect(c, y0, y1, z0, z1):
    """Rectangle in the plane x = c, y in [y0, y1], z in [z0, z1], emitting towards -x (towards the origin)."""
    return _rect([c, y0, z0], [0.0, 0.0, z1 - z0], [0.0, y1 - y0, 0.0])


def _ff(p, n, poly):
    """Single form factor through the function under test."""
    out = point_to_polygon(np.asarray(p, dtype=np.float64).reshape(1, 3),
                           np.asarray(n, dtype=np.float64).reshape(1, 3),
                           np.asarray(poly, dtype=np.float64)[None])
    assert out.shape == (1, 1)
    return float(out[0, 0])


def _rotation(seed):
    q, _ = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
    return q * np.sign(np.linalg.det(q))


_IDENTITY = (np.eye(3), np.zeros(3))
_RIGID = (_rotation(7), np.array([0.3, -1.2, 2.5]))


def _move(transform, p, n, poly):
    rot, shift = transform
    return (np.asarray(p, float) @ rot.T + shift, np.asarray(n, float) @ rot.T,
            np.asarray(poly, float) @ rot.T + shift)


# ----------------------------------------------------------------------------------------------------------
# 1. analytic / quadrature references
# ----------------------------------------------------------------------------------------------------------

# Sanity of the reference helpers themselves (quadrature reproduces the catalogue closed forms).
def test_reference_helpers_agree():
    for a, b, c in [(1.0, 1.0, 1.0), (0.3, 3.0, 0.7)]:
        poly = _rect([0, 0, 0], [a, 0, 0], [0, b, 0])
        assert abs(_quad_ff([0, 0, c], [0, 0, -1], poly) - _corner_parallel(a, b, c)) < 1e-9
        assert abs(_quad_ff([0, 0, 0], [0, 0, 1], _perp_rect(c, 0, a, 0, b)) - _corner_perp(a, b, c)) < 1e-9


@pytest.mark.parametrize("transform", [_IDENTITY, _RIGID], ids=["axis", "rigid"])
@pytest.mark.parametrize("a,b,c", [(1.0, 1.0, 1.0), (2.0, 0.5, 1.0), (0.3, 3.0, 0.7), (5.0, 5.0, 0.2),
                                   (0.1, 0.2, 3.0), (10.0, 0.05, 0.5)])
# Parallel rectangle, receiver on the normal through a corner: Howell closed form.
def test_parallel_rectangle_corner(a, b, c, transform):
    p, n, poly = _move(transform, [0, 0, c], [0, 0, -1], _rect([0, 0, 0], [a, 0, 0], [0, b, 0]))
    assert abs(_ff(p, n, poly) - _corner_parallel(a, b, c)) < ANALYTIC_TOL


@pytest.mark.parametrize("transform", [_IDENTITY, _RIGID], ids=["axis", "rigid"])
@pytest.mark.parametrize("x0,x1,y0,y1,c", [(-1.0, 1.0, -1.0, 1.0, 1.0), (-0.4, 1.7, -2.2, 0.3, 0.8),
                                           (-3.0, 0.5, -0.25, 0.6, 2.0)])
# Rectangle whose interior contains the receiver's foot = sum of 4 corner pieces.
def test_parallel_rectangle_off_corner(x0, x1, y0, y1, c, transform):
    ref = sum(_corner_parallel(a, b, c) for a in (-x0, x1) for b in (-y0, y1))
    p, n, poly = _move(transform, [0, 0, c], [0, 0, -1], _rect([x0, y0, 0], [x1 - x0, 0, 0], [0, y1 - y0, 0]))
    assert abs(_ff(p, n, poly) - ref) < ANALYTIC_TOL


@pytest.mark.parametrize("transform", [_IDENTITY, _RIGID], ids=["axis", "rigid"])
@pytest.mark.parametrize("a,b,c", [(1.0, 1.0, 1.0), (2.0, 0.5, 1.0), (0.3, 3.0, 0.7), (5.0, 5.0, 0.2),
                                   (0.1, 0.2, 3.0)])
# Perpendicular rectangle with one edge in the receiver's plane, the receiver on the normal to that edge's
# end point (corner): contour-integral closed form (checked against quadrature in test_reference_helpers_agree).
def test_perpendicular_rectangle_corner(a, b, c, transform):
    p, n, poly = _move(transform, [0, 0, 0], [0, 0, 1], _perp_rect(c, 0.0, a, 0.0, b))
    assert abs(_ff(p, n, poly) - _corner_perp(a, b, c)) < ANALYTIC_TOL


# Perpendicular rectangle straddling the receiver's horizon and its foot: only the upper half counts.
@pytest.mark.parametrize("c", [0.5, 1.0, 2.0])
def test_perpendicular_rectangle_straddling_horizon(c):
    poly = _perp_rect(c, -0.7, 1.3, -2.0, 0.9)
    ref = _corner_perp(0.7, 0.9, c) + _corner_perp(1.3, 0.9, c)
    assert abs(_ff([0, 0, 0], [0, 0, 1], poly) - ref) < ANALYTIC_TOL


@pytest.mark.parametrize("transform", [_IDENTITY, _RIGID], ids=["axis", "rigid"])
@pytest.mark.parametrize("radius,h", [(1.0, 1.0), (0.5, 0.1), (2.0, 0.5), (1.0, 4.0), (5.0, 2.0)])
# Coaxial disk (regular 256-gon, inscribed; its deviation from the disk is < 3e-5 here): F = R^2/(R^2+h^2).
def test_coaxial_disk(radius, h, transform):
    p, n, poly = _move(transform, [0, 0, h], [0, 0, -1], _ngon(radius, 256))
    assert abs(_ff(p, n, poly) - radius ** 2 / (radius ** 2 + h ** 2)) < ANALYTIC_TOL


@pytest.mark.parametrize("tilt_deg", [30.0, 45.0, 60.0])
@pytest.mark.parametrize("azim_deg", [0.0, 110.0, 235.0])
# Tilted receiver under a parallel rectangle (horizon may cut the rectangle) vs quadrature.
def test_tilted_receiver(tilt_deg, azim_deg):
    t, az = np.radians(tilt_deg), np.radians(azim_deg)
    n = [np.sin(t) * np.cos(az), np.sin(t) * np.sin(az), -np.cos(t)]
    poly = _rect([-1.0, -0.6, 0.0], [2.5, 0.0, 0.0], [0.0, 1.8, 0.0])
    p = [0.2, 0.1, 0.9]
    assert abs(_ff(p, n, poly) - _quad_ff(p, n, poly)) < ANALYTIC_TOL


@pytest.mark.parametrize("case", range(4))
# Polygon crossing the receiver's tangent plane (partly below the horizon) vs quadrature of the clamped integrand.
def test_polygon_crossing_horizon(case):
    p = np.zeros(3)
    if case == 0:    # tilted receiver under a wide parallel square: horizon cuts it at x = -0.577
        n = [np.sin(np.pi / 3), 0.0, -np.cos(np.pi / 3)]
        poly = _rect([-2.0, -2.0, -1.0], [4.0, 0.0, 0.0], [0.0, 4.0, 0.0])   # emitting +z, towards p
    elif case == 1:  # wall facing the receiver, half below its horizon, receiver normal tilted
        n = _unit([0.3, 0.2, 0.9])
        poly = _perp_rect(1.0, -1.0, 1.0, -0.5, 1.0)
    elif case == 2:  # triangle with one vertex below the horizon, two above
        n = [0.0, 0.0, 1.0]
        poly = np.array([[1.0, -0.5, -0.8], [0.7, 0.6, 0.5], [1.2, 0.1, 1.1]])
        if _poly_normal(poly) @ (p - poly[0]) < 0:
            poly = poly[::-1].copy()
    else:            # hexagon tilted w.r.t. everything, horizon through its middle
        rot = _rotation(3)
        poly = _ngon(0.8, 6) @ rot.T + np.array([0.4, 0.3, 1.0])
        if _poly_normal(poly) @ (p - poly[0]) < 0:
            poly = poly[::-1].copy()
        n = _unit(np.cross(_poly_normal(poly), [0.0, 0.0, 1.0]) + 0.3 * np.array([0.4, 0.3, 1.0]))
    n = _unit(n)
    # make sure this really is a horizon-crossing configuration and the visible part is not empty
    side = (poly - p) @ n
    assert side.min() < 0.0 < side.max()
    ref = _quad_ff(p, n, poly)
    assert ref > 1e-3
    assert abs(_ff(p, n, poly) - ref) < ANALYTIC_TOL


# Reversed vertex order: the emitter faces away from the receiver -> exactly 0.
@pytest.mark.parametrize("k", [3, 4, 7])
def test_reversed_polygon_is_zero(k):
    facing = _ngon(1.0, k, z=1.0)[::-1].copy()        # emitting normal -z, towards the receivers below
    away = facing[::-1].copy()                       # same polygon, vertex order reversed: emits +z
    assert _poly_normal(away)[2] > 0
    for p, n in [([0.1, -0.2, 0.0], [0, 0, 1]), ([0.1, -0.2, 0.0], _unit([0.2, 0.1, 1.0]))]:
        assert _ff(p, n, facing) > 0.1
        assert abs(_ff(p, n, away)) <= 1e-12


# Receiver behind the emitter (even though it faces the polygon) -> exactly 0; also polygon fully below horizon.
def test_receiver_behind_or_facing_away_is_zero():
    poly = _rect([-1, -1, 0], [2, 0, 0], [0, 2, 0])   # emitting normal +z
    assert abs(_ff([0.2, 0.1, -0.5], [0, 0, 1], poly)) <= 1e-12          # behind, facing it
    assert abs(_ff([3.0, 0.1, -0.5], _unit([-1, 0, 1]), poly)) <= 1e-12  # behind, off to the side
    assert abs(_ff([0.2, 0.1, 0.5], [0, 0, 1], poly)) <= 1e-12           # in front but looking away
    assert _ff([0.0, 0.0, 0.5], [1, 0, 0], poly) >= 0.0          # sanity: perpendicular sees half-ish
    assert _ff([0.0, 0.0, 0.5], [1, 0, 0], poly) > 0.05


# Splitting a quadrilateral into two triangles: form factors add up (also across the horizon).
@pytest.mark.parametrize("n", [[0, 0, -1], [0.8, 0.0, -0.6], [0.0, 0.95, 0.31225]])
def test_additivity_of_triangles(n):
    n = _unit(n)
    quad = np.array([[-1.0, -0.5, 0.0], [1.2, -0.8, 0.0], [0.9, 1.1, 0.0], [-0.7, 0.8, 0.0]])
    p = np.array([0.1, 0.2, 0.6])
    tris = np.stack([quad[[0, 1, 2]], quad[[0, 2, 3]]])
    f_tri = point_to_polygon(p[None], n[None], tris)
    f_quad = _ff(p, n, quad)
    assert abs(f_tri.sum() - f_quad) < 1e-9 + 1e-6 * f_quad
    assert abs(f_quad - _quad_ff(p, n, quad)) < ANALYTIC_TOL


# Cyclic relabelling of the vertices does not change the result.
def test_cyclic_vertex_shift_invariance():
    poly = np.array([[1.0, -0.5, -0.8], [0.7, 0.6, 0.5], [1.2, 0.1, 1.1], [1.3, -0.7, 0.2]])
    p, n = np.zeros(3), _unit([0.2, 0.1, 1.0])
    # planarise: project onto the plane of the first three vertices
    ns = _poly_normal(poly)
    poly = poly - np.outer((poly - poly[0]) @ ns, ns)
    if ns @ (p - poly[0]) < 0:
        poly = poly[::-1].copy()
    shifted = np.stack([np.roll(poly, s, axis=0) for s in range(4)])
    out = point_to_polygon(p[None], n[None], shifted)
    assert np.ptp(out) < 1e-9
    assert abs(out[0, 0] - _quad_ff(p, n, poly)) < ANALYTIC_TOL


# ----------------------------------------------------------------------------------------------------------
# 2. Monte-Carlo cross-check on random configurations
# ----------------------------------------------------------------------------------------------------------

def _random_config(seed):
    rng = np.random.default_rng(1000 + seed)
    k = int(rng.integers(3, 7))
    ang = np.sort(rng.uniform(0.0, 2.0 * np.pi, k))
    ang[1:] += 0.15 * np.arange(1, k) / k                            # avoid near-duplicate vertices
    radius = rng.uniform(0.5, 1.5)
    flat = np.stack([radius * np.cos(ang), radius * np.sin(ang), np.zeros(k)], axis=1)
    p = rng.normal(size=3)
    n = _unit(rng.normal(size=3))
    # place the polygon centre in the receiver's hemisphere (up to 75 deg off the normal), 0.5..1.3 away
    while True:
        d = _unit(rng.normal(size=3))
        if d @ n > np.cos(np.radians(75.0)):
            break
    centre = p + rng.uniform(0.5, 1.3) * d
    poly = flat @ _rotation(2000 + seed).T + centre
    if _poly_normal(poly) @ (p - poly[0]) < 0:
        poly = poly[::-1].copy()
    return p, n, poly


@pytest.mark.parametrize("seed", range(6))
# Random polygon / receiver pairs: implementation vs Monte-Carlo ray casting (3 sigma or 2e-3).
def test_monte_carlo_random(seed):
    p, n, poly = _random_config(seed)
    f_mc, se = _mc_ff(p, n, poly, nrays=200_000, seed=seed)
    assert f_mc > 0.01                                              # a non-trivial configuration
    got = _ff(p, n, poly)
    assert abs(got - f_mc) <= max(3.0 * se, 2e-3), (got, f_mc, se)


# All random configurations in one batched call: every (receiver, polygon) pair matches its own MC estimate.
def test_monte_carlo_batch():
    cfgs = [_random_config(s) for s in range(4)]
    # polygons must share K in a batch: use the triangles / re-generate with the same K by fanning to K=3
    pts = np.stack([c[0] for c in cfgs])
    nrm = np.stack([c[1] for c in cfgs])
    tris = np.stack([c[2][:3] for c in cfgs])                        # first 3 vertices = a sub-triangle
    out = point_to_polygon(pts, nrm, tris)
    assert out.shape == (4, 4) and out.dtype == np.float64
    for i in range(4):
        for j in range(4):
            f_mc, se = _mc_ff(pts[i], nrm[i], tris[j], nrays=200_000, seed=10 * i + j)
            assert abs(out[i, j] - f_mc) <= max(3.0 * se, 2e-3), (i, j, out[i, j], f_mc, se)


# ----------------------------------------------------------------------------------------------------------
# 3. hard cases
# ----------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("c", [1e-4, 1e-5, 1e-6])
# Receiver on a perpendicular plane touching the middle of a source edge (edge lies in its horizon): -> 0.5.
def test_receiver_touching_edge_middle(c):
    poly = _perp_rect(c, -1.0, 1.0, 0.0, 1.5)
    ref = 2.0 * _corner_perp(1.0, 1.5, c)
    got = _ff([0, 0, 0], [0, 0, 1], poly)
    assert np.isfinite(got)
    assert abs(got - ref) < HARD_TOL
    assert abs(ref - 0.5) < 1e-3


@pytest.mark.parametrize("c", [1e-4, 1e-5, 1e-6])
# Same, close to a source vertex (-> 0.25), and with the source straddling the horizon (-> 0.5).
def test_receiver_touching_vertex_and_straddling(c):
    got = _ff([0, 0, 0], [0, 0, 1], _perp_rect(c, 0.0, 2.0, 0.0, 2.0))
    assert np.isfinite(got) and abs(got - _corner_perp(2.0, 2.0, c)) < HARD_TOL
    got = _ff([0, 0, 0], [0, 0, 1], _perp_rect(c, -1.0, 2.0, -1.5, 2.0))
    ref = _corner_perp(1.0, 2.0, c) + _corner_perp(2.0, 2.0, c)
    assert np.isfinite(got) and abs(got - ref) < HARD_TOL


# Edge-touching receiver in a rotated frame, cross-checked against Monte-Carlo at the same point.
def test_receiver_touching_edge_rotated_vs_mc():
    c = 1e-5
    p, n, poly = _move(_RIGID, [0, 0, 0], [0, 0, 1], _perp_rect(c, -1.0, 1.0, 0.0, 1.5))
    got = _ff(p, n, poly)
    f_mc, se = _mc_ff(p, n, poly, nrays=200_000, seed=5)
    assert np.isfinite(got)
    assert abs(got - 2.0 * _corner_perp(1.0, 1.5, c)) < HARD_TOL
    assert abs(got - f_mc) <= max(3.0 * se, 2e-3)


_SQUARE = _rect([0, 0, 0], [1, 0, 0], [0, 1, 0])          # emitting normal +z, exact coordinates
_RECEIVER_NORMALS = [[0, 0, 1], [0, 0, -1], _unit([1, 1, 1]), _unit([1, 1, -1]), [-1, 0, 0], [1, 0, 0]]


@pytest.mark.parametrize("p", [[0, 0, 0], [1, 1, 0], [0.5, 0, 0], [1, 0.3, 0], [2, 0, 0], [-3, 1, 0], [0.5, 0.5, 0]],
                         ids=["vertex0", "vertex2", "edge_mid", "edge_pt", "edge_line", "edge_line_neg", "inside"])
# Receiver exactly in the source plane (at a vertex, on an edge, on an edge line, inside): finite, exactly 0.
def test_receiver_in_source_plane(p):
    pts = np.repeat(np.asarray(p, dtype=np.float64)[None], len(_RECEIVER_NORMALS), axis=0)
    out = point_to_polygon(pts, np.asarray(_RECEIVER_NORMALS, dtype=np.float64), _SQUARE[None])
    assert np.all(np.isfinite(out))
    assert np.all((out >= 0.0) & (out <= 1.0))
    assert np.all(np.abs(out) < 1e-12), out.ravel()
    for i, n in enumerate(_RECEIVER_NORMALS):
        assert _mc_ff(p, n, _SQUARE, nrays=20_000, seed=i)[0] == 0.0


# Receiver at a vertex / on an edge of a rotated polygon (in-plane only up to rounding): finite, in [0, 1].
@pytest.mark.parametrize("which", ["vertex", "edge", "edge_line"])
def test_receiver_on_vertex_or_edge_rotated(which):
    p, _, poly = _move(_RIGID, [0, 0, 0], [0, 0, 1], _ngon(1.0, 5))
    if which == "vertex":
        p = poly[2].copy()
    elif which == "edge":
        p = 0.3 * poly[1] + 0.7 * poly[2]
    else:
        p = 1.6 * poly[1] - 0.6 * poly[2]
    ns = _poly_normal(poly)
    normals = np.stack([ns, -ns, _unit(np.cross(ns, poly[0] - poly[1])), _unit(-ns + 0.5 * (poly[3] - p))])
    out = point_to_polygon(np.repeat(p[None], 4, axis=0), normals, poly[None])
    assert np.all(np.isfinite(out))
    assert np.all((out >= 0.0) & (out <= 1.0)), out.ravel()


# Coplanar receiver outside the polygon (exactly in its plane): exactly 0, and Monte-Carlo agrees.
@pytest.mark.parametrize("n", [[0, 0, 1], [0, 0, -1], _unit([-1, 0, 1]), [-1, 0, 0]])
def test_coplanar_receiver_outside(n):
    p = [2.5, 0.5, 0.0]
    assert abs(_ff(p, n, _SQUARE)) <= 1e-12
    assert _mc_ff(p, n, _SQUARE, nrays=20_000)[0] == 0.0


@pytest.mark.parametrize("h", [1e-3, 1e-5, 1e-6])
@pytest.mark.parametrize("foot", [(10.0, 10.0), (3.0, 17.5), (0.01, 10.0)], ids=["centre", "offcentre", "nearedge"])
# Receiver just above the interior of a large 20x20 square, facing it: ~1 (corner decomposition reference).
def test_receiver_very_close_above_interior(h, foot):
    x0, y0 = foot
    poly = _rect([0, 0, 0], [20.0, 0, 0], [0, 20.0, 0])
    ref = sum(_corner_parallel(a, b, h) for a in (x0, 20.0 - x0) for b in (y0, 20.0 - y0))
    got = _ff([x0, y0, h], [0, 0, -1], poly)
    assert np.isfinite(got)
    assert abs(got - ref) < HARD_TOL
    if foot != (0.01, 10.0):
        assert got > 0.99


# Horizon passing exactly through a vertex / along an edge of the source: matches quadrature.
def test_horizon_through_vertex_and_edge():
    p, n = np.zeros(3), np.array([0.0, 0.0, 1.0])
    tri = np.array([[1.0, -0.5, 0.0], [1.0, 0.5, 1.0], [1.0, 0.5, -1.0]])   # vertex 0 exactly on horizon
    if _poly_normal(tri) @ (p - tri[0]) < 0:
        tri = tri[::-1].copy()
    assert abs(_ff(p, n, tri) - _quad_ff(p, n, tri)) < ANALYTIC_TOL
    sq = _perp_rect(1.0, -0.5, 0.5, -1.0, 0.0)                             # entirely below, top edge on horizon
    got = _ff(p, n, sq)
    assert np.isfinite(got) and abs(got) < 1e-9


# Empty inputs: N=0 or M=0 give correctly shaped empty float64 arrays.
@pytest.mark.parametrize("n_pts,n_polys", [(0, 3), (4, 0), (0, 0)])
def test_empty_inputs(n_pts, n_polys):
    pts = np.zeros((n_pts, 3))
    nrm = np.tile([0.0, 0.0, 1.0], (n_pts, 1))
    polys = np.tile(_ngon(1.0, 4, z=1.0)[::-1][None], (n_polys, 1, 1))
    out = point_to_polygon(pts, nrm, polys)
    assert isinstance(out, np.ndarray)
    assert out.shape == (n_pts, n_polys)
    assert out.dtype == np.float64


# ----------------------------------------------------------------------------------------------------------
# 4. shapes / dtypes / batching
# ----------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("k", [3, 4, 5, 8])
# Output is float64 (N, M) for K = 3, 4, 5, 8 and each entry equals its own quadrature reference.
def test_shapes_and_batch_values(k):
    rng = np.random.default_rng(k)
    base = _ngon(0.7, k, z=0.0)
    polys = []
    for j in range(3):
        poly = base @ _rotation(50 + j).T + rng.normal(size=3) * 0.3 + np.array([0.0, 0.0, 2.0])
        if _poly_normal(poly)[2] > 0:                                  # face the receivers below
            poly = poly[::-1].copy()
        polys.append(poly)
    polys = np.stack(polys)
    pts = rng.normal(size=(5, 3)) * 0.4
    nrm = np.stack([_unit([*(rng.normal(size=2) * 0.5), 1.0]) for _ in range(5)])
    out = point_to_polygon(pts, nrm, polys)
    assert isinstance(out, np.ndarray) and out.dtype == np.float64 and out.shape == (5, 3)
    for i in range(5):
        for j in range(3):
            assert abs(out[i, j] - _quad_ff(pts[i], nrm[i], polys[j])) < ANALYTIC_TOL, (i, j)


# Mixed batch: visible, reversed, behind, coplanar and horizon-cut polygons together equal single calls.
def test_mixed_batch_matches_single_calls():
    polys = np.stack([
        _rect([-1, -1, 1], [2, 0, 0], [0, 2, 0])[::-1],     # facing down, above the receivers
        _rect([-1, -1, 1], [2, 0, 0], [0, 2, 0]),           # same but facing up (away) -> 0
        _perp_rect(1.0, -1.0, 1.0, -0.5, 1.0),              # wall, partly below horizon
        _rect([-1, -1, 0], [2, 0, 0], [0, 2, 0]),           # coplanar with the receivers at z=0
    ])
    pts = np.array([[0.0, 0.0, 0.0], [0.3, -0.2, 0.0], [5.0, 5.0, 0.0]])
    nrm = np.array([[0.0, 0.0, 1.0], _unit([0.5, 0.0, 1.0]), _unit([-1.0, -1.0, 0.5])])
    out = point_to_polygon(pts, nrm, polys)
    assert out.shape == (3, 4) and out.dtype == np.float64
    assert np.all(np.isfinite(out))
    for i in range(3):
        for j in range(4):
            single = _ff(pts[i], nrm[i], polys[j])
            assert abs(out[i, j] - single) < 1e-9, (i, j)
            assert abs(out[i, j] - _quad_ff(pts[i], nrm[i], polys[j])) < ANALYTIC_TOL, (i, j)
    assert np.all(np.abs(out[:, [1, 3]]) <= 1e-12)


# float32 / non-contiguous inputs are accepted and still produce float64 results.
def test_float32_and_strided_inputs():
    pts = np.array([[0.0, 0.0, 0.0], [9.0, 9.0, 9.0], [0.2, 0.1, 0.0], [9.0, 9.0, 9.0]])
    nrm = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], _unit([0.3, 0.0, 1.0]), [1.0, 0.0, 0.0]])
    polys = np.stack([_ngon(1.0, 6, z=1.0)[::-1], _ngon(0.5, 6, z=2.0)[::-1]])
    ref = point_to_polygon(np.ascontiguousarray(pts[::2]), np.ascontiguousarray(nrm[::2]), polys)
    strided = point_to_polygon(pts[::2], nrm[::2], polys)
    assert strided.dtype == np.float64 and strided.shape == (2, 2)
    assert np.allclose(strided, ref, rtol=0, atol=1e-12)
    f32 = point_to_polygon(pts[::2].astype(np.float32), nrm[::2].astype(np.float32), polys.astype(np.float32))
    assert f32.dtype == np.float64 and f32.shape == (2, 2)
    assert np.allclose(f32, ref, rtol=0, atol=1e-5)


def _cuda_available():
    try:
        import warp as wp
        wp.init()
        return bool(wp.is_cuda_available())
    except Exception:  # pragma: no cover - no warp / no driver
        return False


# device="cuda" (when a GPU is present) reproduces the CPU results, including the near-singular cases.
@pytest.mark.skipif(not _cuda_available(), reason="no CUDA device")
def test_cuda_matches_cpu():
    cfgs = [_random_config(s) for s in range(6)]
    pts = np.stack([c[0] for c in cfgs] + [np.zeros(3), np.array([0.5, 0.5, 1e-6]), np.array([2.0, 0.0, 0.0])])
    nrm = np.stack([c[1] for c in cfgs] + [np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.0, -1.0]),
                                           np.array([0.0, 0.0, 1.0])])
    polys = np.stack([c[2][:3] for c in cfgs] + [_perp_rect(1e-6, -1.0, 1.0, 0.0, 1.5)[:3], _SQUARE[:3]])
    cpu = point_to_polygon(pts, nrm, polys, device="cpu")
    gpu = point_to_polygon(pts, nrm, polys, device="cuda")
    assert gpu.dtype == np.float64 and gpu.shape == cpu.shape
    assert np.all(np.isfinite(gpu))
    assert np.allclose(gpu, cpu, rtol=0, atol=1e-8), np.abs(gpu - cpu).max()
    quads = np.stack([_perp_rect(1e-6, -1.0, 1.0, 0.0, 1.5), _rect([0, 0, 0], [20.0, 0, 0], [0, 20.0, 0])])
    g = point_to_polygon(np.array([[0.0, 0.0, 0.0], [10.0, 10.0, 1e-5]]),
                         np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]]), quads, device="cuda")
    assert abs(g[0, 0] - 2.0 * _corner_perp(1.0, 1.5, 1e-6)) < HARD_TOL
    assert abs(g[1, 1] - sum(_corner_parallel(10.0, 10.0, 1e-5) for _ in range(4))) < HARD_TOL
