"""kernels.room_share: the share of an object's light that reaches receivers past the room, one thread per
receiver, against the numpy it replaced (app.stages.object_light.room_share_numpy)."""
import numpy as np

from app.stages.object_light import ROOM_EPS, room_share, room_share_numpy
from kernels.room_share import room_share_launch
from kernels.buffers import Workspace
from kernels.visibility import Occluder


def _box(lo, hi):
    """(vertices (8,3), triangles (12,3)) of an axis-aligned box."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    v = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    f = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1], [2, 3, 7], [2, 7, 6],
                  [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    return v, f


def _scene(rng):
    """A room occluder of two boxes (a sofa, a table) and an object's proxy of random triangles above the floor."""
    (v1, f1), (v2, f2) = _box([-1.0, 0.0, 0.6], [1.0, 0.8, 1.0]), _box([0.5, 0.0, -0.6], [0.9, 0.5, -0.2])
    room = Occluder(np.concatenate([v1, v2]), np.concatenate([f1, f2 + 8]))
    c = rng.uniform([-0.3, 0.2, -0.3], [0.3, 0.7, 0.3], (300, 3))
    tris = c[:, None] + rng.normal(scale=0.05, size=(300, 3, 3))
    rad = rng.uniform(0.0, 1.0, (300, 3))
    rad[::7] = 0.0  # unlit faces
    return room, tris, rad


def test_room_share_kernel_matches_the_numpy_it_replaced():
    rng = np.random.default_rng(11)
    room, tris, rad = _scene(rng)
    # receivers on the floor (up), on the sofa's front (-z) and back (+z: the object behind the sofa), on walls
    # facing away from the object (no group weighs anything: share 1), some in the boxes' shadow
    n = 3000
    pts = np.concatenate([rng.uniform([-2, 0, -2], [2, 0, 2], (n, 3)),
                          rng.uniform([-1, 0, 0.6], [1, 0.8, 0.6], (500, 3)),
                          rng.uniform([-1, 0, 1.0], [1, 0.8, 1.0], (500, 3)),
                          rng.uniform([2, 0, -2], [2, 2, 2], (200, 3))])
    nrm = np.concatenate([np.tile([0.0, 1.0, 0.0], (n, 1)), np.tile([0.0, 0.0, -1.0], (500, 1)),
                          np.tile([0.0, 0.0, 1.0], (500, 1)), np.tile([1.0, 0.0, 0.0], (200, 1))])
    for cells, extra in ((2, None), (1, None), (3, None)):
        ref = room_share_numpy(pts, nrm, tris, rad, room, extra, None, cells)
        ws = Workspace(rows=1024)  # several launches, the buffers kept
        got = room_share(pts, nrm, tris, rad, room, extra, ws, cells)
        assert np.abs(got - ref).max() <= 1e-12, (cells, np.abs(got - ref).max())
        # the case holds each branch: blocked, partly and wholly seen, and no weight at all
        assert (ref == 0).sum() > 50 and ((ref > 0.05) & (ref < 0.95)).sum() > 10 and (ref[-200:] == 1).all()
        again = room_share(pts[:700], nrm[:700], tris, rad, room, extra, ws, cells)  # a smaller call, same buffers
        assert np.abs(again - ref[:700]).max() <= 1e-12
    # no light at all: every share 1; no receivers: empty
    assert (room_share(pts[:50], nrm[:50], tris, rad * 0, room) == 1).all()
    assert room_share(pts[:0], nrm[:0], tris, rad, room).shape == (0,)
    assert (room_share_launch(pts[:5], nrm[:5], np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), room,
                              ROOM_EPS) == 1).all()

