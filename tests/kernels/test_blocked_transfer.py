"""kernels.blocked_transfer: the pairs an occluder blocks, against Open3D's ray casts."""
import numpy as np

from kernels.blocked_transfer import BlockedPairs
from kernels.visibility import Occluder
from tests.conftest import segments_blocked


def _box(lo, hi):
    v = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])], float)
    f = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1], [2, 3, 7], [2, 7, 6],
                  [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    return v, f


def _pairs(bp: BlockedPairs, occ: Occluder, targets: np.ndarray, columns: np.ndarray, box, split=None,
           m_short: int | None = None) -> np.ndarray:
    """The pairs (N,m) bool that BlockedPairs.sums weighs, one target a call with weight 1: a row's near
    (its first m_short targets) or far (the rest) sum is T[i, column] > 0 where the pair is blocked, else 0."""
    ms = len(columns) if m_short is None else m_short
    out = np.zeros((bp.n, len(columns)), bool)
    for k in range(len(columns)):
        near, far, _ = bp.sums(occ, targets[k:k + 1], columns[k:k + 1], np.ones((1, 3)), box, split,
                               m_short=1 if k < ms else 0)
        out[:, k] = (near if k < ms else far)[:, 0] > 0
    return out


def test_blocked_pairs_match_ray_casts():
    # the pairs themselves (each target alone through sums): blocked where the transfer's column is > 0,
    # against Open3D; a target's column picks any column of T (two targets may share one)
    from app.runtime import split as split_launches

    rng = np.random.default_rng(5)
    v, f = _box([0.4, 0.2, 0.4], [0.6, 0.7, 0.6])
    points = np.column_stack([rng.uniform(-1, 2, 2000), rng.uniform(0, 1.5, 2000), rng.uniform(-1, 2, 2000)])
    points = points[np.any((points < [0.35, 0.15, 0.35]) | (points > [0.65, 0.75, 0.65]), axis=1)]
    T = rng.uniform(0, 1, (len(points), 30)) * (rng.uniform(size=(len(points), 30)) > 0.3)
    targets = np.column_stack([rng.uniform(0, 1, 45), np.zeros(45), rng.uniform(0, 1, 45)])
    columns = rng.integers(0, 30, 45)
    ref = segments_blocked(v, f, points, targets) & (T[:, columns] > 0)
    bp = BlockedPairs(points, T, "cpu", capacity=60)
    box = (np.array([0.4, 0.2, 0.4]) - 1e-3, np.array([0.6, 0.7, 0.6]) + 1e-3)
    ours = _pairs(bp, Occluder(v, f, "cpu"), targets, columns, box,
                  split=lambda launch, n: split_launches(launch, n, "cpu", 64))
    assert ref.mean() > 0.05 and ours.shape == ref.shape
    assert (ours != ref).mean() < 1e-3  # float32 rays grazing an edge may differ
    assert not _pairs(bp, Occluder(v, f, "cpu"), targets[:10], columns[:10],
                      (np.array([9.0, 9.0, 9.0]), np.array([9.1, 9.1, 9.1]))).any()
    # two sets of points in one launch: the short ones take only the first 12 targets
    short = rng.uniform(size=len(points)) < 0.4
    bp2 = BlockedPairs(points, T, "cpu", capacity=60, short=short)
    ours2 = _pairs(bp2, Occluder(v, f, "cpu"), targets, columns, box,
                   split=lambda launch, n: split_launches(launch, n, "cpu", 64), m_short=12)
    ref2 = ref.copy()
    ref2[short, 12:] = False
    assert (ours2 != ref2).mean() < 1e-3 and ours2[short, :12].any() and ours2[~short, 12:].any()


def test_blocked_sums_weigh_the_pairs_by_the_rows_and_members_transfers():
    # BlockedPairs.sums: the blocked pairs weighed in the launch, against Open3D's pairs weighed by numpy:
    # near/far over a row's first m_short targets / the rest (short rows: none), each member over its
    # owner's first m_short pairs with its own transfer (the owner's T > 0 decides which rays are cast)
    from app.runtime import split as split_launches

    rng = np.random.default_rng(7)
    v, f = _box([0.4, 0.2, 0.4], [0.6, 0.7, 0.6])
    points = np.column_stack([rng.uniform(-1, 2, 1500), rng.uniform(0, 1.5, 1500), rng.uniform(-1, 2, 1500)])
    points = points[np.any((points < [0.35, 0.15, 0.35]) | (points > [0.65, 0.75, 0.65]), axis=1)]
    N, J, m, ms = len(points), 30, 45, 12
    owner = rng.integers(0, N, 3 * N)  # ~3 members a point, some none
    U = rng.uniform(0, 1, (len(owner), J)) * (rng.uniform(size=(len(owner), J)) > 0.4)
    T = np.zeros((N, J))
    np.add.at(T, owner, U)  # > 0 where a member's is
    T[rng.uniform(size=N) < 0.2] = rng.uniform(0, 1, J)  # rows of their own
    short = rng.uniform(size=N) < 0.4
    targets = np.column_stack([rng.uniform(0, 1, m), np.zeros(m), rng.uniform(0, 1, m)])
    columns = rng.integers(0, J, m)
    weights = rng.uniform(-1, 1, (m, 3))
    hit = segments_blocked(v, f, points, targets) & (T[:, columns] > 0)
    hit[short, ms:] = False
    bp = BlockedPairs(points, T, "cpu", capacity=60, short=short, members=(owner, U))
    box = (np.array([0.4, 0.2, 0.4]) - 1e-3, np.array([0.6, 0.7, 0.6]) + 1e-3)
    near, far, mem = bp.sums(Occluder(v, f, "cpu"), targets, columns, weights, box,
                             split=lambda launch, n: split_launches(launch, n, "cpu", 64), m_short=ms)
    Tc, Uc = T[:, columns], U[:, columns]
    ref_near = (Tc[:, :ms] * hit[:, :ms]) @ weights[:ms]
    ref_far = (Tc[:, ms:] * hit[:, ms:]) @ weights[ms:]
    ref_mem = (Uc[:, :ms] * hit[owner, :ms]) @ weights[:ms]
    assert hit[:, :ms].mean() > 0.05 and np.abs(ref_mem).sum() > 0 and not far[short].any()
    for ours, ref in ((near, ref_near), (far, ref_far), (mem, ref_mem)):  # float32 rays grazing an edge may differ
        assert np.mean(np.abs(ours - ref).max(1) > 1e-5) < 5e-3
        assert np.abs(ours - ref).sum() < 5e-3 * np.abs(ref).sum()
    # the same pairs as each target's alone (_pairs)
    bits = _pairs(bp, Occluder(v, f, "cpu"), targets, columns, box, m_short=ms)
    np.testing.assert_allclose(near, (Tc[:, :ms] * bits[:, :ms]) @ weights[:ms], rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(mem, (Uc[:, :ms] * bits[owner, :ms]) @ weights[:ms], rtol=1e-5, atol=1e-5)


def test_blocked_sums_with_an_oriented_box_give_the_same_answer():
    # a box turned 30 degrees about +Y: the oriented box about it (tested instead of the axis-aligned one)
    # casts fewer rays, the sums stay those of the axis-aligned box (a segment that misses a box about the
    # mesh misses it)
    from app.stages.sun import upright_box

    rng = np.random.default_rng(11)
    v, f = _box([-0.3, 0.0, -0.1], [0.3, 0.5, 0.1])
    th = np.radians(30.0)
    Ry = np.array([[np.cos(th), 0, np.sin(th)], [0, 1, 0], [-np.sin(th), 0, np.cos(th)]])
    v = v @ Ry.T + [1.0, 0.0, 2.0]
    points = np.column_stack([rng.uniform(-1, 3, 1500), rng.uniform(0, 2.5, 1500), rng.uniform(0, 4, 1500)])
    T = rng.uniform(0, 1, (len(points), 20)) * (rng.uniform(size=(len(points), 20)) > 0.3)
    targets = np.column_stack([rng.uniform(0, 2, 40), np.zeros(40), rng.uniform(1, 3, 40)])
    columns = rng.integers(0, 20, 40)
    weights = rng.uniform(0, 1, (40, 3))
    bp = BlockedPairs(points, T, "cpu", capacity=40)
    box = (v.min(0) - 1e-3, v.max(0) + 1e-3)
    obb = upright_box(v)
    c, axes, half = obb
    assert np.allclose(axes @ axes.T, np.eye(3)) and np.all(np.abs((v - c) @ axes.T) <= half)
    assert np.prod(2 * half) < 0.7 * np.prod(box[1] - box[0])  # tighter than the axis-aligned box
    occ = Occluder(v, f, "cpu")
    near, _, _ = bp.sums(occ, targets, columns, weights, box)
    near_o, _, _ = bp.sums(occ, targets, columns, weights, box, obb=obb)
    ref = (T[:, columns] * (segments_blocked(v, f, points, targets) & (T[:, columns] > 0))) @ weights
    assert np.abs(ref).sum() > 0 and np.array_equal(near, near_o)
    assert np.abs(near - ref).sum() < 5e-3 * np.abs(ref).sum()


def test_members_with_an_owner_out_of_range_are_refused():
    import pytest

    points, T = np.zeros((4, 3)), np.ones((4, 2))
    with pytest.raises(ValueError, match="members need one owner in \\[0, N\\)"):
        BlockedPairs(points, T, "cpu", capacity=2, members=(np.array([0, 4]), np.ones((2, 2))))
    with pytest.raises(ValueError, match="members need one owner"):
        BlockedPairs(points, T, "cpu", capacity=2, members=(np.array([0, 1, 2]), np.ones((2, 2))))


def test_separating_axis_test_is_the_slab_test():
    # the kernel's segment-box test (separating axes, no divisions) against kernels.visibility's slab test on
    # random segments about a box: the same yes/no but where a segment passes within float32 rounding of
    # the box's surface; segments along an axis (a zero component) included
    import warp as wp

    from kernels.blocked_transfer import _segment_meets_centred_box
    from kernels.visibility import segment_meets_box

    @wp.kernel
    def both(a: wp.array(dtype=wp.vec3), b: wp.array(dtype=wp.vec3), h: wp.vec3,
             sat: wp.array(dtype=wp.int32), slab: wp.array(dtype=wp.int32)):
        i = wp.tid()
        sat[i] = wp.where(_segment_meets_centred_box(a[i], b[i], h), 1, 0)
        slab[i] = wp.where(segment_meets_box(a[i], b[i], -h, h), 1, 0)

    rng = np.random.default_rng(7)
    n = 200000
    h = np.array([0.3, 0.8, 0.15])
    a = rng.uniform(-2, 2, (n, 3))
    b = rng.uniform(-2, 2, (n, 3))
    b[:1000, 0] = a[:1000, 0]  # parallel to a face pair
    b[1000:2000, 1:] = a[1000:2000, 1:]  # along the x axis
    a[2000:3000] = b[2000:3000] = rng.uniform(-0.5, 0.5, (1000, 3))  # a point, inside or not
    sat, slab = wp.zeros(n, dtype=wp.int32), wp.zeros(n, dtype=wp.int32)
    wp.launch(both, dim=n, inputs=[wp.array(a, dtype=wp.vec3), wp.array(b, dtype=wp.vec3), wp.vec3(*h), sat, slab])
    sat, slab = sat.numpy().astype(bool), slab.numpy().astype(bool)
    assert 0.05 < slab.mean() < 0.9 and slab[1000:2000].any() and not slab[1000:2000].all()
    # the segment's distance to the box (sampled finely): the tests may differ only on grazing segments
    t = np.linspace(0.0, 1.0, 4001)
    differ = np.flatnonzero(sat != slab)
    for i in differ:
        pts = a[i] + t[:, None] * (b[i] - a[i])
        gap = np.linalg.norm(np.maximum(np.abs(pts) - h, 0.0), axis=1).min()
        assert gap < 1e-3 * np.linalg.norm(b[i] - a[i]) + 1e-5, (a[i], b[i], sat[i], slab[i])
    assert len(differ) < 1e-4 * n, len(differ)
