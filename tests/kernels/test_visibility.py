"""Tests for kernels.visibility: transfer_matrix, Occluder, segments_visible, emitter_sum.

References: the analytic form factors of kernels.formfactor.point_to_polygon (itself checked against
closed forms and quadrature in test_formfactor.py), hand-placed occluders whose effect on the
stratified visibility samples is known exactly, the enclosure rule (form factors from a point inside
a closed room sum to 1), and Open3D's Embree ray caster for segment visibility.
"""
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from kernels.formfactor import point_to_polygon  # noqa: E402
from kernels.visibility import Occluder, emitter_sum, segments_visible, transfer_matrix  # noqa: E402
from recon.patches import build_patches  # noqa: E402
from recon.scene import Quad, Scene, box_faces  # noqa: E402


# ----------------------------------------------------------------------------------------------------------
# geometry helpers (independent of the code under test)
# ----------------------------------------------------------------------------------------------------------

def _unit(v):
    v = np.asarray(v, np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _quad_normal(c):
    return _unit(np.cross(c[..., 1, :] - c[..., 0, :], c[..., 3, :] - c[..., 0, :]))


def _plate_y(x0, x1, z0, z1, y, up=True):
    """Axis-aligned rectangle in the plane y as (4 vertices, 2 triangles); lit side +y if up else -y."""
    v = np.array([[x0, y, z0], [x1, y, z0], [x1, y, z1], [x0, y, z1]], np.float64)
    # (v1-v0) x (v3-v0) = (+x) x (+z) = -y, so reverse the winding for an upward normal
    if up:
        v = v[[0, 3, 2, 1]]
    tris = np.array([[0, 1, 2], [0, 2, 3]], np.int32)
    return v, tris


def _box_mesh(lo, hi):
    """Closed axis-aligned box (8 vertices, 12 triangles); winding is irrelevant for ray hits."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    v = np.array([[(lo, hi)[i][0], (lo, hi)[j][1], (lo, hi)[k][2]] for i in (0, 1) for j in (0, 1) for k in (0, 1)])
    faces = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    tris = np.array([t for a, b, c, d in faces for t in ((a, b, c), (a, c, d))], np.int32)
    return v, tris


def _merge(*meshes):
    vs, ts, off = [], [], 0
    for v, t in meshes:
        vs.append(v)
        ts.append(t + off)
        off += len(v)
    return np.concatenate(vs), np.concatenate(ts).astype(np.int32)


def _room_quads(lo, hi):
    """Six inward-facing quads of the box [lo, hi] (corners CCW seen from inside)."""
    return [Quad(f"wall{axis}{side}", c, n, np.full(3, 0.5), np.zeros(3))
            for axis, side, c, n in box_faces(lo, hi, inward=True)]


def _cube_quads(lo, hi):
    """Six outward-facing quads of a floating cube."""
    return [Quad(f"cubewall{axis}{side}", c, n, np.full(3, 0.5), np.zeros(3)) for axis, side, c, n in box_faces(lo, hi)]


def _scene(quads):
    """A Scene holding only quads: all build_patches needs."""
    return Scene("box", Path("."), None, quads, None, None, None, np.zeros(3), np.ones(3))


def _random_quads(rng, m):
    """Random planar parallelograms (M,4,3) around the origin, CCW about their own normal."""
    o = rng.uniform(-1.5, 1.5, (m, 3))
    e1 = rng.normal(size=(m, 3)) * rng.uniform(0.2, 1.0, (m, 1))
    e2 = rng.normal(size=(m, 3)) * rng.uniform(0.2, 1.0, (m, 1))
    return np.stack([o, o + e1, o + e1 + e2, o + e2], axis=1)


# ----------------------------------------------------------------------------------------------------------
# transfer_matrix
# ----------------------------------------------------------------------------------------------------------

def test_unoccluded_transfer_equals_form_factor(device):
    # with no occluders G is exactly the analytic point-to-polygon form factor (to float32 rounding)
    rng = np.random.default_rng(1)
    quads = _random_quads(rng, 40)
    pts = rng.uniform(-2.0, 2.0, (60, 3))
    nrm = _unit(rng.normal(size=(60, 3)))
    ref = point_to_polygon(pts, nrm, quads, device=device)
    for n_side in (1, 3):
        G = transfer_matrix(pts, nrm, quads, _quad_normal(quads), [], n_side=n_side, device=device)
        assert G.dtype == np.float32 and G.shape == (60, 40)
        assert (ref > 1e-3).sum() > 200  # the sample actually exercises non-trivial form factors
        np.testing.assert_allclose(G, ref, rtol=2e-6, atol=1e-7)
    # chunked evaluation (chunk smaller than N) reports progress per chunk and gives the same matrix
    done = []
    G3 = transfer_matrix(pts, nrm, quads, _quad_normal(quads), [], n_side=1, device=device, progress=done.append,
                         chunk=16)
    assert done == [16, 16, 16, 12]
    np.testing.assert_array_equal(G3, transfer_matrix(pts, nrm, quads, _quad_normal(quads), [], n_side=1,
                                                      device=device))
    # two empty occluders are the same as none
    empty = Occluder(None, None, device)
    assert empty.id == 0
    G2 = transfer_matrix(pts, nrm, quads, _quad_normal(quads), [empty, empty], n_side=2, device=device)
    np.testing.assert_allclose(G2, ref, rtol=2e-6, atol=1e-7)


def test_half_covered_source(device):
    # a plate hiding exactly the two x<0 samples (of 2x2) of the source gives G = F/2; a full plate gives 0
    p = np.array([[0.0, 0.0, 0.0]])
    n = np.array([[0.0, 1.0, 0.0]])
    src_v, _ = _plate_y(-0.5, 0.5, -0.5, 0.5, 2.0, up=False)  # source quad at y=2 facing down
    src = src_v[None]
    F = point_to_polygon(p, n, src, device=device)[0, 0]
    assert F > 0.05
    # samples sit at x = +-0.25 on the source, i.e. x = +-0.125 where the ray crosses y = 1
    half = Occluder(*_plate_y(-0.3, 0.0, -0.3, 0.3, 1.0), device)
    G = transfer_matrix(p, n, src, _quad_normal(src), [half], n_side=2, device=device)
    assert G[0, 0] == pytest.approx(0.5 * F, rel=1e-6)
    # the same plate in the second occluder slot counts too
    G = transfer_matrix(p, n, src, _quad_normal(src), [Occluder(None, None, device), half], n_side=2,
                        device=device)
    assert G[0, 0] == pytest.approx(0.5 * F, rel=1e-6)
    # left half in slot 0 and right half in slot 1 together hide everything
    right = Occluder(*_plate_y(0.0, 0.3, -0.3, 0.3, 1.0), device)
    G = transfer_matrix(p, n, src, _quad_normal(src), [half, right], n_side=2, device=device)
    assert G[0, 0] == 0.0
    full = Occluder(*_plate_y(-1.0, 1.0, -1.0, 1.0, 1.0), device)
    G = transfer_matrix(p, n, src, _quad_normal(src), [full], n_side=2, device=device)
    assert G[0, 0] == 0.0
    # a plate beyond the source (y=3) or behind the receiver (y=-1) hides nothing
    for y in (3.0, -1.0):
        G = transfer_matrix(p, n, src, _quad_normal(src), [Occluder(*_plate_y(-1, 1, -1, 1, y), device)],
                            n_side=2, device=device)
        assert G[0, 0] == pytest.approx(F, rel=1e-6)
    # with 4x4 samples the same half plate hides 8 of 16 samples (x = -0.375, -0.125 columns)
    G = transfer_matrix(p, n, src, _quad_normal(src), [half], n_side=4, device=device)
    assert G[0, 0] == pytest.approx(0.5 * F, rel=1e-6)


def _room_transfers(quads, device, patch_size=0.25, n_side=1):
    pm = build_patches(_scene(quads), patch_size, patch_size)
    occ = Occluder(pm.vert_pos, pm.tris, device)
    G = transfer_matrix(pm.centre, pm.normal, pm.corners, pm.normal, [occ], n_side=n_side, device=device)
    return pm, G


def test_closed_room_row_sums(device):
    # enclosure rule: from every patch centre of an empty closed box, the form factors to all patches sum to 1
    pm, G = _room_transfers(_room_quads([0, 0, 0], [2.0, 1.5, 1.0]), device)
    assert pm.n_patches == 2 * (8 * 6 + 8 * 4 + 6 * 4)
    assert np.all(np.diag(G) == 0.0)  # a planar patch does not see itself
    rows = G.astype(np.float64).sum(1)
    np.testing.assert_allclose(rows, 1.0, atol=2e-3)


def test_closed_room_with_cube_row_sums(device):
    # with a floating cube inside, rows still sum to 1 through the visibility term: within 2% with 2x2
    # visibility samples, 1% with 4x4; one centre sample (the engine's G_c) is right on average
    quads = _room_quads([0, 0, 0], [2.0, 1.5, 1.0]) + _cube_quads([0.75, 0.5, 0.25], [1.25, 1.0, 0.75])
    for n_side, tol_max, tol_mean in ((1, 0.07, 0.02), (2, 0.02, 0.006), (4, 0.01, 0.003)):
        pm, G = _room_transfers(quads, device, n_side=n_side)
        rows = G.astype(np.float64).sum(1)
        cube = pm.quad >= 6
        # the cube does take a real share of the view of the room patches
        assert G[~cube][:, cube].sum(1).max() > 0.05
        np.testing.assert_allclose(rows[cube], 1.0, atol=2e-3)  # the convex cube sees only the bare room
        assert np.abs(rows - 1.0).max() < tol_max, n_side
        assert np.abs(rows - 1.0).mean() < tol_mean, n_side


# ----------------------------------------------------------------------------------------------------------
# segments_visible against Open3D
# ----------------------------------------------------------------------------------------------------------

def test_segments_visible_matches_open3d(device):
    # segment visibility in a furnished room agrees with Open3D's RaycastingScene on >= 99.9% of segments
    o3d = pytest.importorskip("open3d")
    lo, hi = np.array([0.0, 0.0, 0.0]), np.array([5.0, 2.6, 4.0])
    room = _box_mesh(lo, hi)
    furniture = [_box_mesh([1.0, 0.0, 1.0], [2.0, 0.8, 2.0]),  # table block
                 _box_mesh([3.5, 0.0, 0.2], [4.5, 1.8, 0.8]),  # shelf
                 _box_mesh([2.5, 1.2, 2.5], [3.0, 1.7, 3.5]),  # floating box
                 _box_mesh([0.5, 0.0, 3.0], [0.6, 2.6, 3.1])]  # pillar
    v, t = _merge(room, *furniture)
    rng = np.random.default_rng(7)
    n = 20000
    a = rng.uniform(lo + 0.01, hi - 0.01, (n, 3))
    b = rng.uniform(lo + 0.01, hi - 0.01, (n, 3))
    vis = segments_visible(Occluder(v, t, device), a, b)
    assert vis.shape == (n,) and set(np.unique(vis)) <= {0, 1}

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(v.astype(np.float32)), o3d.core.Tensor(t.astype(np.uint32)))
    rays = np.concatenate([a, b - a], axis=1).astype(np.float32)
    blocked = scene.test_occlusions(o3d.core.Tensor(rays), tnear=0.0, tfar=0.9999).numpy()
    ref = np.where(blocked, 0, 1)
    assert 0.1 < (ref == 0).mean() < 0.9  # the scene blocks a real share of the segments
    assert (vis == ref).mean() >= 0.999
    # no occluder: every segment is visible
    assert np.all(segments_visible(Occluder(None, None, device), a[:100], b[:100]) == 1)


# ----------------------------------------------------------------------------------------------------------
# emitter_sum
# ----------------------------------------------------------------------------------------------------------

def test_emitter_sum_single_triangle(device):
    # one emitting triangle: sum = B * point_to_polygon(triangle); with a plate in between, 0
    tri = np.array([[[-0.4, 2.0, -0.3], [0.1, 2.0, 0.5], [0.5, 2.0, -0.2]]])  # in the plane y=2
    if np.cross(tri[0, 1] - tri[0, 0], tri[0, 2] - tri[0, 0])[1] > 0:
        tri = tri[:, [0, 2, 1]]  # emit downwards
    B = np.array([[2.0, 3.5, 0.25]])
    rng = np.random.default_rng(3)
    pts = np.column_stack([rng.uniform(-1.5, 1.5, 50), rng.uniform(0.0, 1.2, 50), rng.uniform(-1.5, 1.5, 50)])
    nrm = _unit(np.column_stack([rng.uniform(-0.5, 0.5, 50), np.ones(50), rng.uniform(-0.5, 0.5, 50)]))
    F = point_to_polygon(pts, nrm, tri, device=device)[:, 0]
    assert (F > 1e-3).all()
    out = emitter_sum(pts, nrm, tri, B, None, device=device)
    assert out.shape == (50, 3) and out.dtype == np.float64
    np.testing.assert_allclose(out, F[:, None] * B, rtol=1e-5, atol=1e-9)
    # an occluder that does not cross the point->centroid segments changes nothing
    aside = Occluder(*_plate_y(10.0, 11.0, 10.0, 11.0, 1.5), device)
    np.testing.assert_allclose(emitter_sum(pts, nrm, tri, B, aside, device=device), F[:, None] * B,
                               rtol=1e-5, atol=1e-9)
    # a large plate between the points and the triangle blocks the centroid: nothing arrives
    plate = Occluder(*_plate_y(-20.0, 20.0, -20.0, 20.0, 1.6), device)
    assert np.all(emitter_sum(pts, nrm, tri, B, plate, device=device) == 0.0)
    # points on the back side of the emitter get nothing either
    back = emitter_sum(pts + [0.0, 3.0, 0.0], nrm, tri, B, None, device=device)
    assert np.all(back == 0.0)


def test_emitter_sum_is_linear_over_triangles(device):
    # several triangles: the sum is the B-weighted sum of their individual form factors
    rng = np.random.default_rng(5)
    T = 12
    c = np.column_stack([rng.uniform(-1, 1, T), rng.uniform(1.5, 2.5, T), rng.uniform(-1, 1, T)])
    tri = c[:, None, :] + rng.normal(scale=0.2, size=(T, 3, 3))
    nrm_t = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    flip = nrm_t[:, 1] > 0  # make them all emit downwards
    tri[flip] = tri[flip][:, [0, 2, 1]]
    B = rng.uniform(0.1, 5.0, (T, 3))
    pts = np.column_stack([rng.uniform(-1, 1, 30), np.zeros(30), rng.uniform(-1, 1, 30)])
    nrm = np.tile([0.0, 1.0, 0.0], (30, 1))
    F = point_to_polygon(pts, nrm, tri, device=device)
    out = emitter_sum(pts, nrm, tri, B, None, device=device)
    np.testing.assert_allclose(out, F @ B, rtol=1e-5, atol=1e-9)
    assert emitter_sum(pts[:0], nrm[:0], tri, B, device=device).shape == (0, 3)
    assert np.all(emitter_sum(pts, nrm, tri[:0], B[:0], device=device) == 0.0)
    # split over two launches (CPU threads): the same numbers, in order
    np.testing.assert_array_equal(emitter_sum(pts, nrm, tri, B, None, device=device, split=7), out)


def test_ray_hit_barycentrics_rebuild_the_hit_point(device):
    # the weights cast_rays returns, applied to the triangle's vertices, give back the hit point
    from kernels.raycast import cast_rays

    v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]])
    f = np.array([[0, 1, 2], [1, 3, 2]])
    occ = Occluder(v, f, device)
    targets = np.array([[0.6, 0.2, 0.0], [0.1, 0.7, 0.0], [0.8, 0.9, 0.0], [0.3, 0.3, 0.0]])
    origins = targets + [0.0, 0.0, 1.0]
    tri, bary, depth = cast_rays(occ, origins, np.tile([0.0, 0.0, -1.0], (4, 1)))
    assert np.all(tri >= 0)
    np.testing.assert_allclose(np.einsum("nk,nkc->nc", bary, v[f[tri]]), targets, atol=1e-5)
    np.testing.assert_allclose(depth, 1.0, atol=1e-5)


def test_cube_cell_matches_cube_bin():
    """kernels.visibility.cube_cell (branches) against app.stages.object_light._cube_bin (numpy) on random
    directions and on ties between axes (the first largest axis wins in both), at 4 and 16 cells a side."""
    import warp as wp
    from app.stages.object_light import _cube_bin
    from kernels.visibility import cube_cell

    @wp.kernel
    def _cells(d: wp.array(dtype=wp.vec3), r: int, out: wp.array(dtype=wp.int32)):
        i = wp.tid()
        out[i] = cube_cell(d[i], r)

    rng = np.random.default_rng(2)
    d = np.concatenate([rng.normal(size=(5000, 3)), np.round(rng.normal(size=(2000, 3))),
                        [[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [-1.0, 1.0, -1.0]]]).astype(np.float32)
    for r in (4, 16):
        out = wp.zeros(len(d), dtype=wp.int32, device="cpu")
        wp.launch(_cells, dim=len(d), inputs=[wp.array(d, dtype=wp.vec3, device="cpu"), r, out], device="cpu")
        np.testing.assert_array_equal(out.numpy(), _cube_bin(d, r))
