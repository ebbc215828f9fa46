"""Kernel wrappers given a kernels.buffers.Workspace (issue 17, item 2): the same numbers as a fresh
call, bit for bit, with the work cut into blocks smaller than the request, and no Warp array
allocated once the workspace has its buffers (sizes that change from call to call included)."""
from __future__ import annotations

import numpy as np
import warp as wp

from kernels import runtime
from kernels.buffers import Workspace
from kernels.raycast import cast_rays
from kernels.visibility import Occluder, distance_to, emitter_sum, transfer_matrix


def _box(lo, hi):
    """A closed axis-aligned box (8 vertices, 12 triangles, outward CCW)."""
    x0, y0, z0 = lo
    x1, y1, z1 = hi
    v = np.array([[x, y, z] for x in (x0, x1) for y in (y0, y1) for z in (z0, z1)], np.float64)
    f = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                  [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]], np.int32)
    return v, f


class _Allocations:
    """Counts Warp arrays that own new memory made inside the block."""

    def __enter__(self):
        self.n, self._init = 0, wp.array.__init__
        init = self._init

        def counting(arr, *a, **k):
            init(arr, *a, **k)
            if getattr(arr, "deleter", None) is not None and getattr(arr, "ptr", None):
                self.n += 1
        wp.array.__init__ = counting
        return self

    def __exit__(self, *exc):
        wp.array.__init__ = self._init


def _calls(rng, occ, n_pts, n_src):
    """Each wrapper on random points and n_src random quads / triangles, with and without `ws`."""
    pts = rng.uniform(-2, 2, (n_pts, 3))
    nrm = rng.normal(size=(n_pts, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    c = rng.uniform(-2, 2, (n_src, 1, 3))
    quads = c + np.array([[0, 0, 0], [0.3, 0, 0], [0.3, 0.3, 0], [0, 0.3, 0]])
    qn = np.tile([0.0, 0.0, 1.0], (n_src, 1))
    tris = quads[:, :3]
    rad = rng.uniform(0, 1, (n_src, 3))
    return [
        lambda ws: cast_rays(occ, np.zeros(3), nrm, workspace=ws),
        lambda ws: cast_rays(occ, pts, nrm, workspace=ws),
        lambda ws: transfer_matrix(pts, nrm, quads, qn, [occ], n_side=2, chunk=16, workspace=ws),
        lambda ws: emitter_sum(pts, nrm, tris, rad, occ, split=40, workspace=ws),
        lambda ws: distance_to(occ, pts, workspace=ws),
    ]


def test_workspace_gives_the_same_numbers_in_blocks():
    device = runtime.device()
    occ = Occluder(*_box((-0.5, -0.5, -0.5), (0.5, 0.5, 0.5)), device)
    rng = np.random.default_rng(3)
    # blocks of 32 points and 7 patches: every wrapper runs several launches (and two in parallel)
    calls = _calls(rng, occ, 100, 20)
    for call in calls:
        ws = Workspace(rows=32, sources=7)
        fresh, reused = call(None), call(ws)
        for a, b in zip(*(x if isinstance(x, tuple) else (x,) for x in (fresh, reused))):
            assert a.shape == b.shape and np.array_equal(a, b)
        assert np.abs(np.asarray(fresh[0] if isinstance(fresh, tuple) else fresh)).sum() > 0  # real work


def test_workspace_allocates_nothing_after_its_first_call():
    device = runtime.device()
    occ = Occluder(*_box((-0.5, -0.5, -0.5), (0.5, 0.5, 0.5)), device)
    rng = np.random.default_rng(4)
    workspaces = [Workspace(rows=64, sources=16) for _ in _calls(rng, occ, 1, 1)]
    for i, call in enumerate(_calls(rng, occ, 50, 40)):
        call(workspaces[i])
    # more points and more patches than the first call: blocks of the same capacity; fewer: views
    for n_pts, n_src in ((200, 40), (7, 40), (130, 40)):
        for i, call in enumerate(_calls(rng, occ, n_pts, n_src)):
            with _Allocations() as count:
                out = call(workspaces[i])
            assert count.n == 0, f"call {i} with {n_pts} points allocated {count.n} arrays"
            assert len(out[0] if isinstance(out, tuple) else out) == n_pts
    # without a workspace every call allocates, as before
    with _Allocations() as count:
        _calls(rng, occ, 10, 4)[2](None)
    assert count.n > 0


def test_workspace_uploads_scalar_and_vector_rows():
    # a scalar dtype's rows are the array's own (Warp's scalars have _length_ 1, as a 1-vector would)
    ws = Workspace()
    dev = runtime.device(None)
    x = np.array([0.5, 1.5, 2.5])
    a = ws.upload("x", x, wp.float64, dev, capacity=8)
    assert a.shape == (3,)
    np.testing.assert_array_equal(a.numpy(), x)
    v = np.arange(12.0).reshape(4, 3)
    b = ws.upload("v", v, wp.vec3d, dev, capacity=8)
    assert b.shape == (4,)
    np.testing.assert_array_equal(b.numpy(), v)
    t = np.arange(6, dtype=np.int32).reshape(2, 3)
    c = ws.upload("t", t, wp.int32, dev, capacity=8)
    assert c.shape == (2, 3)
    np.testing.assert_array_equal(c.numpy(), t)


def test_workspace_upload_holds_a_column_capacity():
    # Workspace.upload(col_capacity=): a table whose columns vary from call to call (the drag's sunlit patches,
    # kernels.drag_gather's weights) gets a buffer of at least col_capacity columns on its first call, so calls of
    # up to that many columns allocate nothing; a call past it grows the buffer 1.5x along what it outgrew, and the
    # calls after it up to that size allocate nothing again. Each call's view is its values, exactly
    ws = Workspace()
    dev = runtime.device(None)
    rng = np.random.default_rng(7)
    first = rng.uniform(size=(5, 3))
    a = ws.upload("w", first, wp.float64, dev, col_capacity=8)
    assert a.shape == (5, 3) and ws.buffer("w", 1, wp.float64, dev, (1,)).dev.shape == (5, 8)
    np.testing.assert_array_equal(a.numpy(), first)
    for m in (8, 1, 6):
        w = rng.uniform(size=(4, m))
        with _Allocations() as count:
            a = ws.upload("w", w, wp.float64, dev, col_capacity=8)
        assert count.n == 0, f"{m} columns allocated {count.n} arrays"
        np.testing.assert_array_equal(a.numpy(), w)
    w = rng.uniform(size=(5, 10))
    a = ws.upload("w", w, wp.float64, dev, col_capacity=8)
    assert ws.buffer("w", 1, wp.float64, dev, (1,)).dev.shape == (5, 15)
    np.testing.assert_array_equal(a.numpy(), w)
    with _Allocations() as count:
        a = ws.upload("w", w[:, :2], wp.float64, dev, col_capacity=8)
        b = ws.upload("w", rng.uniform(size=(3, 15)), wp.float64, dev, col_capacity=8)
    assert count.n == 0 and a.shape == (5, 2) and b.shape == (3, 15)
    # a 1-d table has no columns: col_capacity leaves it as upload made it before
    x = ws.upload("x", np.arange(4.0), wp.float64, dev, col_capacity=8)
    assert x.shape == (4,)


def test_workspace_upload_reuses_its_views_and_holds_each_calls_values():
    # Buffer.view (dragpy110): a call of a shape asked before returns the same Warp view (no wp.array made), whose
    # data are this call's values; a buffer that grew gives views of its new array; at most VIEW_CACHE are kept
    from kernels import buffers

    ws = Workspace()
    dev = runtime.device(None)
    rng = np.random.default_rng(3)
    x = rng.uniform(size=(6, 3))
    a = ws.upload("p", x, wp.vec3d, dev, capacity=8)
    y = rng.uniform(size=(6, 3))
    b = ws.upload("p", y, wp.vec3d, dev, capacity=8)
    assert b is a and b.shape == (6,)
    np.testing.assert_array_equal(b.numpy(), y)
    c = ws.upload("p", y[:4], wp.vec3d, dev, capacity=8)
    assert c is not a and c.shape == (4,)
    np.testing.assert_array_equal(c.numpy(), y[:4])
    z = rng.uniform(size=(20, 3))  # past the capacity: a new buffer, its own views
    d = ws.upload("p", z, wp.vec3d, dev, capacity=8)
    e = ws.upload("p", z[:6], wp.vec3d, dev, capacity=8)
    assert e is not a and e.ptr == d.ptr
    np.testing.assert_array_equal(e.numpy(), z[:6])
    buf = ws.buffer("p", 1, wp.vec3d, dev)
    for n in range(1, buffers.VIEW_CACHE + 5):
        buf.view((n % 20 + 1,))
    assert len(buf._views) <= buffers.VIEW_CACHE
