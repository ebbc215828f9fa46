"""Blocked transfer kernel (kernels/blocked.py) against an exhaustive numpy slab test."""
import numpy as np

from kernels.blocked import BlockedTransfer


def _meets(p, q, lo, hi):
    d = q - p
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = (lo - p) / d, (hi - p) / d
    inside = (p >= lo) & (p <= hi)
    tmin = np.where(d == 0, np.where(inside, -np.inf, np.inf), np.minimum(t1, t2))
    tmax = np.where(d == 0, np.where(inside, np.inf, -np.inf), np.maximum(t1, t2))
    return np.maximum(tmin.max(-1), 0.0) <= np.minimum(tmax.min(-1), 1.0)


def test_blocked_transfer_sums_the_segments_through_the_box(device):
    rng = np.random.default_rng(2)
    pts = rng.uniform(-2, 2, (400, 3))
    pts[:50, 2] = 0.0  # receivers on a floor plane, sources level with the box edge: grazing cases
    eyes = rng.uniform(-2, 2, (300, 3))
    eyes[:30, 2] = 0.4
    g = rng.uniform(0, 1, (300, 400)) * (rng.random((300, 400)) < 0.8)
    bt = BlockedTransfer(pts, eyes, g, device)
    for lo, hi in (([-0.3, -0.2, 0.0], [0.4, 0.5, 0.4]), ([1.0, 1.0, -1.0], [1.2, 1.9, 1.5])):
        lo, hi = np.array(lo), np.array(hi)
        hit = _meets(pts[None, :, :], eyes[:, None, :], lo, hi)
        want = (g * hit).sum(1)
        assert hit.mean() > 0.02  # the box does block some segments
        np.testing.assert_allclose(bt(lo, hi), want, rtol=1e-4, atol=1e-3)
    # a box far from every segment blocks nothing
    assert not bt(np.array([10.0, 10, 10]), np.array([11.0, 11, 11])).any()


def test_point_groups_partition_the_points_into_small_compact_groups():
    from kernels.blocked import GROUP_POINTS, point_groups

    rng = np.random.default_rng(4)
    pts = rng.uniform(-3, 3, (1000, 3))
    groups = point_groups(pts)
    allidx = np.sort(np.concatenate(groups))
    np.testing.assert_array_equal(allidx, np.arange(1000))  # every point once
    assert max(len(g) for g in groups) <= GROUP_POINTS
    # a kd leaf of 16 of 1000 uniform points spans a small part of the cube (its radius well below the cube's)
    radii = [np.linalg.norm(pts[g] - pts[g].mean(0), axis=1).max() for g in groups]
    assert np.median(radii) < 0.3 * np.linalg.norm(pts - pts.mean(0), axis=1).max()


def test_group_culling_keeps_every_blocked_segment(device):
    # receivers in tight clusters far apart (most groups culled for most eyes) and a box between them: the
    # kernel's sums equal the exhaustive slab test's, i.e. no group holding a blocked segment was culled
    rng = np.random.default_rng(6)
    centres = rng.uniform(-3, 3, (12, 3))
    pts = (centres[:, None, :] + rng.normal(0, 0.05, (12, 40, 3))).reshape(-1, 3)
    eyes = rng.uniform(-3, 3, (200, 3))
    g = rng.uniform(0.1, 1, (200, len(pts)))
    bt = BlockedTransfer(pts, eyes, g, device)
    for lo, hi in (([-0.5, -0.5, -0.5], [0.5, 0.5, 0.5]), ([0.5, -2.0, 0.0], [1.5, 2.0, 0.3])):
        lo, hi = np.array(lo), np.array(hi)
        hit = _meets(pts[None, :, :], eyes[:, None, :], lo, hi)
        assert 0.01 < hit.mean() < 0.5
        np.testing.assert_allclose(bt(lo, hi), (g * hit).sum(1), rtol=1e-4, atol=1e-4)
