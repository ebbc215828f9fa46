"""The sunlit object's pieces summed run by run (app.stages.sun.piece_runs, kernels.visibility.SeenEmitters
groups): a row of one face's split alike lit is one polygon where every piece's table sees the receiver.
Against the pieces' exact sum (emitter_sum_seen: each piece's polygon form factor and table)."""
import numpy as np

from app.stages.sun import _piece_rows, piece_runs
from kernels.visibility import emitter_sum_seen, emitter_sum_seen_bounded
from lighting.sun import _sun_facing_pieces

RES = 4  # cells per cube side of the pieces' visibility tables


def _case():
    """A 0.6 m face tilted over a floor, split 12 x 12, lit share by a shadow line across it (1, 2/3,
    1/3, 0 bands, as SunlitPieces' three sample points give), each piece's table blocking the
    directions on one side of a plane that moves across the face (an occluder beside it): neighbours
    differ in what they see. Receivers on the floor from 1 cm under the face to 3 m away."""
    face = np.array([[[0.0, 0.0, 0.35], [0.6, 0.0, 0.05], [0.0, 0.6, 0.2]]])
    if np.cross(face[0, 1] - face[0, 0], face[0, 2] - face[0, 0])[2] > 0:  # emit downwards
        face = face[:, [0, 2, 1]]
    pieces, parent = _sun_facing_pieces(face, np.cross(face[0, 1] - face[0, 0], face[0, 2] - face[0, 0]), 0.05, 12)
    assert len(pieces) == 144
    c = pieces.mean(1)
    s = (c[:, 0] - c[:, 1]) / 0.6  # across the face, -1..1
    share = np.clip(np.floor((0.4 - s) * 6.0) / 3.0, 0.0, 1.0)
    share[np.abs(s - 0.7) < 0.05] = 0.0  # a thin unlit band (a window bar's shadow)
    dirs = _cell_dirs(RES)
    seen = (dirs @ np.array([1.0, 0.3, 0.0]))[None, :] < 0.8 - 0.6 * (c[:, 1:2] / 0.6)  # (S, cells)
    rng = np.random.default_rng(3)
    x = rng.uniform(-0.8, 1.4, 3000)
    y = rng.uniform(-0.8, 1.4, 3000)
    far = rng.uniform(1.5, 3.0, 400)
    ang = rng.uniform(0, 2 * np.pi, 400)
    pts = np.concatenate([np.stack([x, y, np.full_like(x, 0.0)], 1),
                          np.stack([far * np.cos(ang), far * np.sin(ang), np.zeros(400)], 1)])
    pts[:200, :2] = rng.uniform(0.02, 0.4, (200, 2))  # under the face, down to ~1 cm
    nrm = np.tile([0.0, 0.0, 1.0], (len(pts), 1))
    return face, pieces, parent, share, seen, pts, nrm


def _cell_dirs(r: int) -> np.ndarray:
    """Unit directions at the centres of kernels.visibility.cube_cell's cells (6 r^2, 3)."""
    from app.stages.object_light import _cube_dirs
    return _cube_dirs(r)


def _runs(face, pieces, parent, share):
    part = np.flatnonzero(share > 0)
    order, groups = piece_runs(part, share, parent, _piece_rows(pieces, parent, face), face)
    return order, groups


def test_runs_tile_their_pieces():
    face, pieces, parent, share, *_ = _case()
    order, (start, count, polys, verts) = _runs(face, pieces, parent, share)
    assert sorted(order) == list(np.flatnonzero(share > 0))
    assert len(start) < 0.5 * len(order)  # runs, not pieces one by one
    area = 0.5 * np.linalg.norm(np.cross(pieces[:, 1] - pieces[:, 0], pieces[:, 2] - pieces[:, 0]), axis=1)
    n_face = np.cross(face[0, 1] - face[0, 0], face[0, 2] - face[0, 0])
    for s, k, poly, v in zip(start, count, polys, verts):
        members = order[s:s + k]
        assert np.all(share[members] == share[members[0]])
        p = poly[:v]
        a = 0.5 * sum(np.cross(p[j] - p[0], p[j + 1] - p[0]) for j in range(1, v - 1))
        assert a @ n_face > 0  # wound as the face
        np.testing.assert_allclose(np.linalg.norm(a), area[members].sum(), rtol=1e-9)
        inside = pieces[members].reshape(-1, 3)  # every member corner in the polygon (convex, coplanar)
        for j in range(v):
            e = np.cross(p[(j + 1) % v] - p[j], inside - p[j]) @ n_face
            assert e.min() > -1e-12


def test_runs_sum_as_their_pieces_within_the_bound():
    face, pieces, parent, share, seen, pts, nrm = _case()
    order, groups = _runs(face, pieces, parent, share)
    tris = pieces[order]
    rad = share[order, None] * np.array([1.0, 0.8, 0.6])
    tab = seen[order]
    exact = emitter_sum_seen(pts, nrm, tris, rad, tab, RES, device="cpu")
    assert exact[:, 0].max() > 0.05 and (exact[:, 0] == 0).mean() < 0.6  # lit, and partly seen
    # tolerance 0: a run's polygon form factor is its pieces' sum exactly (additivity, horizon clipping too)
    grouped = emitter_sum_seen_bounded(pts, nrm, tris, rad, tab, RES, 0.0, device="cpu", groups=groups)
    assert np.abs(grouped - exact).max() <= 1e-6 * exact.max()
    # tolerance 0.05: within the mid-point bound, 0.05 x the light unoccluded at a receiver facing each run
    tol = 0.05
    approx = emitter_sum_seen_bounded(pts, nrm, tris, rad, tab, RES, tol, device="cpu", groups=groups)
    start, count, polys, verts = groups
    bound = np.zeros(len(pts))
    for s, k in zip(start, count):
        t = tris[s:s + k]
        a = 0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1).sum()
        n = np.cross(t[0, 1] - t[0, 0], t[0, 2] - t[0, 0])
        n /= np.linalg.norm(n)
        cen = t.mean(1).mean(0)
        r = pts - cen
        h = np.maximum(r @ n, 0.0)
        bound += rad[s, 0] * a * h / (np.pi * np.linalg.norm(r, axis=1) ** 3)
    err = np.abs(approx[:, 0] - exact[:, 0])
    assert err.max() > 1e-5 * exact[:, 0].max()  # the point form is used somewhere (the test can see it)
    assert np.all(err <= tol * bound + 1e-9), float((err - tol * bound).max())
    # and the run-by-run sum is no worse than the pieces one by one, each within the same bound
    alone = emitter_sum_seen_bounded(pts, nrm, tris, rad, tab, RES, tol, device="cpu")
    assert np.abs(approx - exact).sum() <= 1.5 * np.abs(alone - exact).sum() + 1e-9
