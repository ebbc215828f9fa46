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


def test_blocked_pairs_match_ray_casts():
    # the pairs themselves: blocked where the transfer's column is > 0, against Open3D; a target's
    # column picks any column of T (two targets may share one)
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
    ours = bp(Occluder(v, f, "cpu"), targets, columns, box,
              split=lambda launch, n: split_launches(launch, n, "cpu", 64))
    assert ref.mean() > 0.05 and ours.shape == ref.shape
    assert (ours != ref).mean() < 1e-3  # float32 rays grazing an edge may differ
    assert not bp(Occluder(v, f, "cpu"), targets[:10], columns[:10],
                  (np.array([9.0, 9.0, 9.0]), np.array([9.1, 9.1, 9.1]))).any()
    # two sets of points in one launch: the short ones take only the first 12 targets
    short = rng.uniform(size=len(points)) < 0.4
    bp2 = BlockedPairs(points, T, "cpu", capacity=60, short=short)
    ours2 = bp2(Occluder(v, f, "cpu"), targets, columns, box,
                split=lambda launch, n: split_launches(launch, n, "cpu", 64), m_short=12)
    ref2 = ref.copy()
    ref2[short, 12:] = False
    assert (ours2 != ref2).mean() < 1e-3 and ours2[short, :12].any() and ours2[~short, 12:].any()
