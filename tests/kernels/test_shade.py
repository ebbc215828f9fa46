"""kernels.shade's per-frame pieces of object shading against their exact forms: the patch sum with
visibility cast at samples (SampledPatchSum, patch_groups) against transfer_matrix's form factor x
visibility, and the object's camera hits (CameraHits) against rays cast one by one."""
import numpy as np
import pytest
from scipy.spatial import cKDTree

from kernels.raycast import cast_rays
from kernels.shade import CameraHits, SampledPatchSum, patch_groups
from kernels.visibility import Occluder, transfer_matrix


def _grid_quads(x0, x1, z0, z1, y, n):
    """n x n patches tiling the rectangle [x0,x1] x [z0,z1] at height y, emitting downwards (CCW seen from below)."""
    xs, zs = np.linspace(x0, x1, n + 1), np.linspace(z0, z1, n + 1)
    q = [[(xs[i], y, zs[j]), (xs[i + 1], y, zs[j]), (xs[i + 1], y, zs[j + 1]), (xs[i], y, zs[j + 1])]
         for i in range(n) for j in range(n)]
    return np.array(q, np.float64)


def _plate(x0, x1, z0, z1, y):
    v = np.array([[x0, y, z0], [x1, y, z0], [x1, y, z1], [x0, y, z1]], np.float64)
    return v, np.array([[0, 1, 2], [0, 2, 3]], np.int32)


@pytest.fixture(scope="module")
def setup():
    lamp = _grid_quads(-0.4, 0.4, -0.4, 0.4, 2.0, 6)  # one surface, one radiance: one group
    normals = np.tile([0.0, -1.0, 0.0], (len(lamp), 1))
    colors = np.tile([3.0, 2.0, 1.0], (len(lamp), 1))
    g = np.linspace(-1.0, 1.0, 24)
    pts = np.array([(x, 0.0, z) for x in g for z in g])
    nrm = np.tile([0.0, 1.0, 0.0], (len(pts), 1))
    room = Occluder(*_plate(-2.0, 0.05, -2.0, 2.0, 1.0), "cpu")  # a straight shadow edge across the floor
    G = transfer_matrix(pts, nrm, lamp, normals, [room], n_side=1, eps=2e-3, device="cpu")
    return lamp, normals, colors, pts, nrm, room, G.astype(np.float64) @ colors


def test_patch_groups_tile_and_split():
    lamp = _grid_quads(0, 1, 0, 1, 2.0, 4)
    quad = np.zeros(len(lamp), int)
    colors = np.ones((len(lamp), 3))
    order, start, polys = patch_groups(lamp, quad, colors)
    assert len(start) == 2 and sorted(order) == list(range(len(lamp)))
    assert np.allclose(sorted(map(tuple, polys[0])), sorted(map(tuple, np.array(
        [[0, 2, 0], [1, 2, 0], [1, 2, 1], [0, 2, 1]], float))))
    colors[5] = 2.0  # another radiance: it is alone, and the rest (with a hole) tiles no rectangle
    order, start, polys = patch_groups(lamp, quad, colors)
    assert len(start) - 1 == len(lamp) and np.all(np.diff(start) == 1)


@pytest.mark.parametrize("grouped", [False, True])
def test_every_point_a_sample_is_exact(setup, grouped):
    lamp, normals, colors, pts, nrm, room, exact = setup
    n = len(pts)
    s = SampledPatchSum(np.zeros(n, bool), np.arange(n), np.full((n, 1), -1), "cpu", max_patches=len(lamp))
    groups = None
    if grouped:
        order, start, polys = patch_groups(lamp, np.zeros(len(lamp), int), colors)
        lamp, normals, colors, groups = lamp[order], normals[order], colors[order], (start, polys)
    got = s(pts, nrm, lamp, normals, colors, [room], 2e-3, groups=groups)
    assert s.rays_cast == 0
    assert np.abs(got - exact).max() <= 1e-5 * np.abs(exact).max()
    assert exact[:, 0].min() < 0.5 * exact[:, 0].max()  # the plate does shadow part of the floor


def test_sampled_visibility_casts_few_rays_and_keeps_the_edge(setup):
    lamp, normals, colors, pts, nrm, room, exact = setup
    n = len(pts)
    samples = np.arange(0, n, 4)
    _, j = cKDTree(pts[samples]).query(pts, k=6)
    order, start, polys = patch_groups(lamp, np.zeros(len(lamp), int), colors)
    s = SampledPatchSum(np.zeros(n, bool), samples, j, "cpu", max_patches=len(lamp))
    got = s(pts, nrm, lamp[order], normals[order], colors[order], [room], 2e-3, groups=(start, polys))
    # rays only where the samples around a point disagree: along the shadow's edge
    assert 0 < s.rays_cast < 0.25 * n * len(lamp)
    assert np.abs(got - exact).max() <= 1e-5 * np.abs(exact).max()


def test_camera_hits_match_rays_cast_one_by_one():
    K = np.array([[60.0, 0, 32], [0, 60.0, 24], [0, 0, 1]])
    R, centre = np.eye(3), np.zeros(3)
    # a plate facing the camera...
    obj_v = np.array([[-0.5, -0.4, 2.0], [0.5, -0.4, 2.0], [0.5, 0.4, 2.0], [-0.5, 0.4, 2.0]])
    obj = Occluder(obj_v, np.array([[0, 1, 2], [0, 2, 3]], np.int32), "cpu")
    scene_v = np.array([[0.0, -1, 1.5], [1, -1, 1.5], [1, 1, 1.5], [0.0, 1, 1.5]])  # ...half hidden in front
    scene = Occluder(scene_v, np.array([[0, 1, 2], [0, 2, 3]], np.int32), "cpu")
    rect, s = (10, 8, 50, 40), 2
    tri, bary, hit = CameraHits("cpu", block=1000)(obj, scene, centre, R.T @ np.linalg.inv(K), rect, s)
    offs = (np.arange(s) + 0.5) / s - 0.5
    uu = (np.arange(rect[0], rect[2] + 1)[:, None] + offs).reshape(-1)
    vv = (np.arange(rect[1], rect[3] + 1)[:, None] + offs).reshape(-1)
    U, V = np.meshgrid(uu, vv)
    d = np.stack([U, V, np.ones_like(U)], -1).reshape(-1, 3) @ np.linalg.inv(K).T @ R
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t_ref, b_ref, z_obj = cast_rays(obj, centre, d)
    _, _, z_scene = cast_rays(scene, centre, d)
    hit_ref = (t_ref >= 0) & (z_obj < z_scene)
    assert np.array_equal(tri, t_ref) and np.array_equal(hit, hit_ref)
    assert 0 < hit.sum() < (t_ref >= 0).sum()  # some of the object hidden by the scene, some seen
    assert np.allclose(bary[t_ref >= 0], b_ref[t_ref >= 0], atol=1e-4)


def test_convex_object_tests_its_own_mesh_only_below_the_tangent_plane(setup):
    """Points on a box's faces: the box lies behind every face's plane (object_shading._object_above
    says so), yet a face's points see lamp patches whose centres lie below their horizon through
    the box: those segments are still tested against it, and the sum equals the exact one."""
    from app.stages.object_shading import _object_above

    lamp, normals, colors, _, _, room, _ = setup
    lo, hi = np.array([-0.3, 0.0, -0.3]), np.array([0.35, 0.6, 0.3])  # x = 0.35 cuts a lamp patch
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    faces = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                      [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]], np.int32)
    box = Occluder(corners, faces, "cpu")
    g = np.linspace(-0.25, 0.25, 5)
    side = np.array([(0.35, y, z) for y in np.linspace(0.05, 0.55, 5) for z in g])  # +x face
    top = np.array([(x, 0.6, z) for x in g for z in g])
    pts = np.concatenate([side, top])
    nrm = np.concatenate([np.tile([1.0, 0, 0], (len(side), 1)), np.tile([0, 1.0, 0], (len(top), 1))])
    own = _object_above(pts, nrm, corners)
    assert not own.any()
    far_room = Occluder(*_plate(5.0, 6.0, 5.0, 6.0, 1.0), "cpu")  # nothing of the room in the way
    exact = transfer_matrix(pts, nrm, lamp, normals, [far_room, box], n_side=1, eps=2e-3,
                            device="cpu").astype(np.float64) @ colors
    n = len(pts)
    s = SampledPatchSum(own, np.arange(n), np.full((n, 1), -1), "cpu", max_patches=len(lamp))
    got = s(pts, nrm, lamp, normals, colors, [far_room, box], 2e-3)
    assert np.abs(got - exact).max() <= 1e-5 * np.abs(exact).max()
    no_box = transfer_matrix(pts, nrm, lamp, normals, [far_room], n_side=1, eps=2e-3,
                             device="cpu").astype(np.float64) @ colors
    ns = len(side)  # the box does hide from the side's points the lamp patches their horizon cuts
    assert np.any((no_box[:ns, 0] > 0) & (exact[:ns, 0] < 0.5 * no_box[:ns, 0]))
