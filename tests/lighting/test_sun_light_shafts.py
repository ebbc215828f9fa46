"""The shaft test that lets the object's patch sums skip the room's rays (app.stages.object_shading
.shaft_clear) in its cheaper form: the same facing points as the plain differences (also on points
lying exactly in a patch's plane, which decide whether the floor under an object is inside the hull),
the same triangles overlapping a box as a test of every triangle, and a clear shaft only where no
room triangle can cut a visibility segment."""
import numpy as np

from app.stages import object_shading as os_


def _plain_facing(p, n, polys):
    pn = np.cross(polys[:, 1] - polys[:, 0], polys[:, 2] - polys[:, 0])
    front = np.einsum("gc,ngc->ng", pn, p[:, None] - polys[:, 0][None]) > 0
    above = (np.einsum("nc,ngkc->ngk", n, polys[None] - p[:, None, None]) > 0).any(2)
    return (front & above).any(1)


def _floor_patches(rng, m):
    c0 = np.round(rng.uniform(-2, 2, (m, 3)), 1)
    c0[:, 1] = 0.0
    s = rng.uniform(0.05, 0.3, (m, 1))
    # CCW seen from above: the emitting side is +y
    return np.stack([c0, c0 + s * [0, 0, 1], c0 + s * [1, 0, 1], c0 + s * [1, 0, 0]], 1)


def test_facing_equals_the_plain_differences_on_hard_cases():
    rng = np.random.default_rng(0)
    for _ in range(30):
        p = np.round(rng.uniform(-2, 2, (400, 3)), 1)
        p[::3, 1] = 0.0  # on the patches' plane: pn . (p - v0) is exactly 0 there
        n = np.eye(3)[rng.integers(0, 3, len(p))] * rng.choice([-1.0, 1.0], (len(p), 1))
        n[::5] = rng.normal(size=(len(n[::5]), 3))
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        polys = _floor_patches(rng, 25)
        if rng.uniform() < 0.5:  # tilted patches too
            a = rng.uniform(0, 0.5)
            R = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
            polys = polys @ R.T
        pn = np.cross(polys[:, 1] - polys[:, 0], polys[:, 2] - polys[:, 0])
        assert np.array_equal(os_._facing(p, n, polys, pn), _plain_facing(p, n, polys))
    # a point on the floor with its normal down faces nothing (both values exactly 0)
    polys = _floor_patches(np.random.default_rng(1), 4)
    pn = np.cross(polys[:, 1] - polys[:, 0], polys[:, 2] - polys[:, 0])
    assert not os_._facing(np.array([[0.3, 0.0, 0.2]]), np.array([[0.0, -1.0, 0.0]]), polys, pn).any()


def test_triangle_buckets_find_every_overlapping_triangle():
    rng = np.random.default_rng(2)
    tris = rng.uniform(-3, 3, (3000, 1, 3)) + rng.uniform(-0.3, 0.3, (3000, 3, 3))
    tris[:20] *= 4  # a few large ones (walls) spanning many buckets
    boxes = os_._TriangleBoxes(tris)
    lo_all, hi_all = tris.min(1), tris.max(1)
    for _ in range(200):
        a = rng.uniform(-4, 4, (2, 3))
        lo, hi = a.min(0), a.max(0)
        if rng.uniform() < 0.4:
            hi = lo + rng.uniform(0, 0.1, 3)
        want = np.flatnonzero(((hi_all >= lo) & (lo_all <= hi)).all(1))
        assert np.array_equal(boxes.overlapping(lo, hi), want)
    assert len(os_._TriangleBoxes(tris[:0]).overlapping(np.zeros(3), np.ones(3))) == 0


def test_shaft_is_clear_only_where_no_triangle_can_cut():
    # an object standing on a floor, lost patches on the floor beside it: the floor (its triangles in the
    # patches' plane) and a far wall leave the shaft clear; a post between them does not
    rng = np.random.default_rng(3)
    box = rng.uniform([-0.2, 0.0, -0.2], [0.2, 0.8, 0.2], (300, 3))
    box[:, 1] = np.maximum(box[:, 1], 0.01)
    box[:40, 1] = 0.0  # vertices on the floor, normals down: they face nothing
    n = rng.normal(size=box.shape)
    n[:40] = [0.0, -1.0, 0.0]
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    c0 = np.array([[0.4 + 0.1 * i, 0.0, -0.2 + 0.1 * j] for i in range(4) for j in range(4)])
    polys = np.stack([c0, c0 + [0, 0, 0.1], c0 + [0.1, 0, 0.1], c0 + [0.1, 0, 0]], 1)
    pnorm = np.tile([0.0, 1.0, 0.0], (len(polys), 1))
    floor = np.array([[[-5, 0, -5], [5, 0, -5], [5, 0, 5]], [[-5, 0, -5], [5, 0, 5], [-5, 0, 5]]], float)
    wall = np.array([[[3, 0, -5], [3, 3, -5], [3, 3, 5]]], float)
    post = np.array([[[0.3, 0.0, 0.0], [0.3, 0.5, 0.0], [0.3, 0.5, 0.05]]])
    assert os_.shaft_clear(np.concatenate([floor, wall]), box, n, polys, pnorm, 2e-3)
    assert not os_.shaft_clear(np.concatenate([floor, wall, post]), box, n, polys, pnorm, 2e-3)
