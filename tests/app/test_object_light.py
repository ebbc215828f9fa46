"""The object-light stage's coarse evaluations against the exact ones they replace
(app/stages/object_light.py, kernels/farfield.py): the proxy triangles' light gathered over patch
blocks, the far field's point emitters as one kernel. The bundled demo scene (no ../shared needed)
and analytic cases."""
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from app.cli import demo_scene_dir  # noqa: E402
from app.engine import Engine, EngineParams  # noqa: E402
from app.stages import object_light as OL  # noqa: E402
from kernels.farfield import point_emitter_sum  # noqa: E402
from kernels.visibility import Occluder, emitter_sum, transfer_matrix  # noqa: E402
from recon.proxy import bounding_sphere  # noqa: E402
from recon.response import luminance  # noqa: E402
from recon.scene import load_scene  # noqa: E402

FAST = dict(patch_size=0.25, emitter_patch_size=0.2)


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    scene = load_scene(demo_scene_dir())
    eng = Engine(scene, EngineParams(**FAST), cache_dir=tmp_path_factory.mktemp("c"), device="cpu", quiet=True)
    frame = eng.render(scene.obj)
    pv, pf, proxy_occ, _, _ = eng.object_shading.object_shape(scene.obj)
    return scene, eng, frame, pv, pf, proxy_occ


@pytest.mark.parametrize("level", range(len(OL.BLOCKS)))
def test_patch_blocks_span_their_patches(demo, level):
    # each block is the rectangle of its patches: with no occluder a block's form factor is the sum of
    # its patches' (form factors add over area), so a radiance uniform over it gathers exactly
    _, eng, _, pv, pf, proxy_occ = demo
    pm = eng.pre.patches
    blocks = eng.object_light.patch_blocks().levels[level]
    inb = np.flatnonzero(blocks.block_of >= 0)
    assert len(blocks.centre) > 4 and len(inb) > 3 * len(blocks.centre)
    assert not pm.is_emitter[inb].any()
    np.testing.assert_allclose(np.bincount(blocks.block_of[inb], pm.area[inb], len(blocks.centre)),
                               np.linalg.norm(np.cross(blocks.corners[:, 1] - blocks.corners[:, 0],
                                                       blocks.corners[:, 3] - blocks.corners[:, 0]), axis=1),
                               rtol=1e-9)
    pts = pv[pf].mean(1)
    nrm = eng.object_light.proxy_shape(pv, pf, proxy_occ).normals
    fine = transfer_matrix(pts, nrm, pm.corners, pm.normal, [], n_side=1, device="cpu")
    coarse = transfer_matrix(pts, nrm, blocks.corners, blocks.normal, [], n_side=1, device="cpu")
    summed = np.zeros_like(coarse)
    np.add.at(summed.T, blocks.block_of[inb], fine[:, inb].T)
    # patches behind a point's plane clip to 0 one by one: compare blocks wholly in front
    front = (np.einsum("tc,bkc->tbk", nrm, blocks.corners) - (nrm * pts).sum(1)[:, None, None] > 0).all(2)
    assert front.sum() > 100
    np.testing.assert_allclose(coarse[front], summed[front], rtol=2e-3, atol=1e-7)


def test_patch_grid_rejects_patches_off_a_grid(demo):
    _, eng, *_ = demo
    pm = eng.pre.patches
    q = np.bincount(pm.quad).argmax()
    idx = np.flatnonzero(pm.quad == q)
    nu, nv = OL._patch_grid(pm, idx)
    assert nu * nv == len(idx) and nu > 1 and nv > 1
    assert OL._patch_grid(pm, idx[::-1]) is None  # reversed order: not build_patches' grid
    assert OL._patch_grid(pm, idx[:1]) is None


def test_triangle_radiance_on_blocks_matches_every_patch(demo, monkeypatch):
    # the proxy's light gathered over the coarse set against every patch gathered one by one: within
    # 1 % in total and 5 % at 95 % of the triangles (brighter than a tenth of the brightest)
    scene, eng, _, pv, pf, proxy_occ = demo
    B = eng.B_obj
    ours = luminance(eng.object_light.triangle_radiance(scene.obj, pv, pf, proxy_occ, B))
    n_set = len(eng.object_light.patch_blocks().gather_set(B, *bounding_sphere(pv))[0])
    monkeypatch.setattr(OL, "BLOCK_NEAR", np.inf)  # every block split: the exact gather
    exact = luminance(eng.object_light.triangle_radiance(scene.obj, pv, pf, proxy_occ, B))
    assert n_set < 0.8 * eng.pre.patches.n_patches  # the coarse set is coarser
    assert abs(ours.sum() / exact.sum() - 1) < 0.01
    big = exact > 0.1 * exact.max()
    err = np.abs(ours[big] - exact[big]) / exact[big]
    assert np.percentile(err, 95) < 0.05, np.percentile(err, 95)




def test_point_emitters_analytic():
    # one emitter of area A facing a receiver at distance r straight on: B A / (pi r^2); tilted by t at
    # the emitter: x cos t; behind the receiver or facing away: 0; a table cell seen at half: x 0.5
    A, r = 0.02, 2.0
    pts = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    nrm = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [0.0, 0.0, 1.0]])
    t = 0.4
    centres = np.array([[0.0, 0.0, r]])
    res = 4
    for tn, want in (([0.0, 0.0, -2 * A], [1.0, 1.0, 0.0, 1.0]),
                     ([0.0, 2 * A * np.sin(t), -2 * A * np.cos(t)], [np.cos(t), np.cos(t), 0.0, np.cos(t)]),
                     ([0.0, 0.0, 2 * A], [0.0, 0.0, 0.0, 0.0])):
        seen = np.ones((1, 6 * res * res), np.float32)
        got = point_emitter_sum(pts, nrm, centres, np.array([tn]), np.array([[1.0, 2.0, 3.0]]), seen, res,
                                device="cpu")
        np.testing.assert_allclose(got[:, 0], np.array(want) * A / (np.pi * r * r), rtol=1e-5, atol=1e-12)
        np.testing.assert_allclose(got[:, 2], 3 * got[:, 0], rtol=1e-6)
    seen = np.zeros((1, 6 * res * res), np.float32)
    seen[0, OL._cube_bin(np.array([[0.0, 0.0, -1.0]]), res)[0]] = 0.5  # the direction emitter -> receiver
    got = point_emitter_sum(pts[:1], nrm[:1], centres, np.array([[0.0, 0.0, -2 * A]]), np.ones((1, 3)), seen, res,
                            device="cpu")
    np.testing.assert_allclose(got[0], 0.5 * A / (np.pi * r * r), rtol=1e-5)


def _far_case(demo):
    """The far-field tests' case: the demo's engine, patches and proxy, its bounding sphere, the non-emitting
    patches beyond FAR_FIELD radii (indices), the proxy's triangles and a seeded radiance per triangle."""
    _, eng, _, pv, pf, proxy_occ = demo
    centre, radius = bounding_sphere(pv)
    pm = eng.pre.patches
    far = np.flatnonzero((np.linalg.norm(pm.centre - centre, axis=1) > OL.FAR_FIELD * radius) & ~pm.is_emitter)
    rad = np.random.default_rng(1).uniform(0.2, 1.0, (len(pf), 3))
    return eng, pm, far, pv, pf, proxy_occ, centre, radius, pv[pf], rad


def test_far_field_kernel_matches_ray_per_triangle(demo):
    # the kernel's far field against emitter_sum (a ray per triangle) beyond FAR_FIELD radii, and
    # against the same point-source sum in numpy (per-shape table of the triangles' visibility)
    eng, pm, far, pv, pf, proxy_occ, centre, radius, tris, rad = _far_case(demo)
    tvis = eng.object_light.proxy_shape(pv, pf, proxy_occ).visibility
    ours = OL._reflected(pm.centre[far], pm.normal[far], tris, rad, proxy_occ, centre, radius, "cpu", tvis)
    d = tris.mean(1)[None] - pm.centre[far][:, None]
    tn = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    g = (np.maximum(np.einsum("ntc,nc->nt", d, pm.normal[far]), 0) * np.maximum(-np.einsum("ntc,tc->nt", d, tn), 0)
         * 0.5 / (np.pi * np.einsum("ntc,ntc->nt", d, d) ** 2)) * tvis.lookup(-d)
    np.testing.assert_allclose(ours, g @ rad, rtol=1e-3, atol=1e-6 * np.abs(g @ rad).max())
    exact = luminance(emitter_sum(pm.centre[far], pm.normal[far], tris, rad, proxy_occ, device="cpu"))
    assert abs(luminance(ours).sum() / exact.sum() - 1) < 0.10


def test_object_light_coarse_against_exact_on_the_frame(demo, monkeypatch):
    # the whole stage (blocks, far field, adaptive grid) against its exact evaluation (every patch
    # gathered, every near pixel exact): within a level on every pixel, 0.05 rms over the lit ones
    scene, eng, frame, pv, pf, proxy_occ = demo
    centre, radius = bounding_sphere(pv)
    covered = frame.coverage.reshape(-1) >= 1.0
    tri_rad = eng.object_light.triangle_radiance(scene.obj, pv, pf, proxy_occ, eng.B_obj)
    ours, ours_c = eng.object_light.light(pv, pf, tri_rad, proxy_occ, centre, radius, covered)
    monkeypatch.setattr(OL, "BLOCK_NEAR", np.inf)
    monkeypatch.setattr(OL, "GRID_STRIDES", ())
    tri_exact = eng.object_light.triangle_radiance(scene.obj, pv, pf, proxy_occ, eng.B_obj)
    exact, exact_c = eng.object_light.light(pv, pf, tri_exact, proxy_occ, centre, radius, covered)
    resp = scene.response
    d = resp.to_levels(eng.receivers.L_b + eng.receivers.rho_x * ours) - resp.to_levels(eng.receivers.L_b + eng.receivers.rho_x * exact)
    lit = np.abs(exact).sum(1) > 0
    assert lit.sum() > 500
    worst, rms = np.abs(d).max(), np.sqrt((d[lit] ** 2).mean())
    assert worst <= 1.0 and rms <= 0.05, (worst, rms)
    assert abs(luminance(ours_c).sum() / luminance(exact_c).sum() - 1) < 0.02


def _box(lo, hi):
    """A closed box's 12 triangles (CCW seen from outside), vertices (8,3)."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    v = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    f = []
    for a, b, c, d in quads:
        f += [(a, b, c), (a, c, d)]
    f = np.array(f)
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    out = ((v[f].mean(1) - v.mean(0)) * n).sum(1) < 0
    f[out] = f[out][:, ::-1]  # outward normals
    return v, f


def test_free_cells_convex_frees_every_front_direction():
    # a convex shape: every other triangle lies behind each triangle's plane, so every cell is free
    v, f = _box([0, 0, 0], [0.3, 0.5, 0.4])
    assert OL.free_cells(v[f]).all()


def _cell_directions(cells: np.ndarray, r: int, fu, fv) -> np.ndarray:
    """Directions (n,3) inside cube cells `cells` (OL._cube_bin's layout, r x r a face) at the
    fractions fu, fv (in [0, 1)) of each cell's two in-face coordinates."""
    face, rem = np.divmod(cells, r * r)
    iu, iv = np.divmod(rem, r)
    ax, neg = np.divmod(face, 2)
    d = np.zeros((len(cells), 3))
    rows = np.arange(len(cells))
    d[rows, ax] = np.where(neg == 1, -1.0, 1.0)
    d[rows, (ax + 1) % 3] = (iu + fu) / r * 2 - 1
    d[rows, (ax + 2) % 3] = (iv + fv) / r * 2 - 1
    return d


def test_free_cells_never_free_a_blocked_ray():
    # an L of two boxes (concave): 48 random rays per free cell, from apexes anywhere in the table's
    # eps range, in front of their triangle: none meets the shape; a blocked share is really cut out;
    # the exact sum and the gather with the table equal those with a ray each
    v1, f1 = _box([0, 0, 0], [0.4, 0.1, 0.4])
    v2, f2 = _box([0, 0.1, 0], [0.1, 0.5, 0.4])
    v, f = np.concatenate([v1, v2]), np.concatenate([f1, f2 + 8])
    tris = v[f]
    eps = (OL.EXACT_EPS, OL.GATHER_EPS)
    free = OL.free_cells(tris, eps)
    assert 0.3 < free.mean() < 0.99  # the table frees most, not all (the inner corner blocks)
    occ = Occluder(v, f, "cpu")
    rng = np.random.default_rng(3)
    r = OL.FREE_RES
    t, c = np.nonzero(free)
    t, c = np.repeat(t, 48), np.repeat(c, 48)
    fu, fv = rng.random(len(t)), rng.random(len(t))
    d = _cell_directions(c, r, fu, fv)
    assert (OL._cube_bin(d, r) == c).all()
    n = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    apex = tris.mean(1)[t] + n[t] * rng.uniform(*eps, (len(t), 1))
    front = (d * n[t]).sum(1) > 0
    from kernels.visibility import segments_visible
    assert segments_visible(occ, apex[front], apex[front] + 10.0 * d[front]).all()
    # the cells left out do hold blocked rays (the same check fails on them): the table is not all-free
    tb, cb = np.nonzero(~free)
    db = _cell_directions(cb, r, 0.5, 0.5)
    ab = tris.mean(1)[tb] + n[tb] * OL.EXACT_EPS
    fr = (db * n[tb]).sum(1) > 0
    assert (segments_visible(occ, ab[fr], ab[fr] + 10.0 * db[fr]) == 0).sum() > 10
    pts = rng.uniform([-0.3, -0.3, -0.3], [0.8, 0.9, 0.8], (3000, 3))
    nrm = rng.normal(size=(3000, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    rad = rng.uniform(0.2, 1.0, (len(f), 3))
    plain = emitter_sum(pts, nrm, tris, rad, occ, eps=OL.EXACT_EPS, device="cpu")
    fast = emitter_sum(pts, nrm, tris, rad, occ, eps=OL.EXACT_EPS, device="cpu", free=free, free_res=r)
    assert np.abs(plain).max() > 0
    np.testing.assert_array_equal(plain, fast)
    quads = np.array([[[-1, -1, -0.2], [2, -1, -0.2], [2, 2, -0.2], [-1, 2, -0.2]],
                      [[-1, 2, -0.2], [2, 2, -0.2], [2, 2, 2], [-1, 2, 2]]], float)
    qn = np.array([[0, 0, 1.0], [0, -1.0, 0]])
    args = (tris.mean(1), n, quads, qn, [Occluder(None, None, "cpu"), occ])
    G0 = transfer_matrix(*args, n_side=2, eps=OL.GATHER_EPS, device="cpu")
    G1 = transfer_matrix(*args, n_side=2, eps=OL.GATHER_EPS, device="cpu", free=free, free_res=r)
    assert (G0 > 0).sum() > 10
    np.testing.assert_array_equal(G0, G1)


def test_headroom_matches_the_response(demo):
    # s > headroom(levels) exactly where T(L_b + s) - T(L_b) > levels (away from the boundary itself)
    scene, eng, *_ = demo
    resp = scene.response
    rng = np.random.default_rng(5)
    idx = rng.choice(len(eng.receivers.L_b), 20000)
    for levels in (0.25, 2.0):
        h = eng.object_light.headroom(levels, np.unique(idx))[np.searchsorted(np.unique(idx), idx)].astype(np.float64)
        assert np.isfinite(h).any()
        s = np.where(np.isfinite(h), h, 1.0) * rng.uniform(0.5, 1.5, (len(idx), 3)) + rng.uniform(0, 1e-3, (len(idx), 3))
        gain = resp.to_levels(eng.receivers.L_b[idx] + s) - resp.to_levels(eng.receivers.L_b[idx])
        clear = np.abs(s - h) > 1e-5 * np.maximum(h, 1e-9)  # not at the boundary (float32 headroom)
        clear &= np.abs(gain - levels) > 1e-6
        assert clear.mean() > 0.9
        np.testing.assert_array_equal((s > h)[clear], (gain > levels)[clear])


def test_headroom_is_worked_out_once_for_every_receiver(demo, monkeypatch):
    # a level's first call works out every receiver pixel (a drag frame's new pixels are only looked up),
    # with the values of a pixel at a time; a pixel outside the receivers is worked out when asked
    scene, eng, *_ = demo
    rp = np.flatnonzero(eng.receivers.recv_pix)
    other = np.flatnonzero(~eng.receivers.recv_pix)
    assert len(other)
    rng = np.random.default_rng(8)
    calls = []
    work = OL._headroom_at
    monkeypatch.setattr(OL, "_headroom_at", lambda resp, L, levels: calls.append(len(L)) or work(resp, L, levels))
    # private reach: the stage's headroom table dropped, so that this test sees its first call (the
    # fixture's frames already made it)
    monkeypatch.setattr(eng.object_light, "_headroom", None)
    eng.object_light.headroom(0.5, rp[:3])
    assert len(calls) == 1
    later = np.sort(rng.choice(rp, 5000))
    got = eng.object_light.headroom(0.5, later)
    assert len(calls) == 1  # a lookup
    one = np.concatenate([work(scene.response, eng.receivers.L_b[[p]], 0.5) for p in later[:300]])
    np.testing.assert_array_equal(got[:300], one)
    out = eng.object_light.headroom(0.5, other[:4])
    assert calls[1:] == [4]
    np.testing.assert_array_equal(out, work(scene.response, eng.receivers.L_b[other[:4]], 0.5))


def test_light_bound_holds_with_pieces():
    # _light_bound with extra emitters (small bright pieces on the object) is at least the light the
    # triangles and pieces send, unoccluded, to points around them (any receiver normal), and its
    # distances from the sphere's centre (one product per point) give the (N,3)-difference form's bound
    rng = np.random.default_rng(3)
    tris = rng.normal(size=(40, 3, 3)) * 0.2
    pieces = 0.3 + rng.normal(size=(25, 3, 3)) * 0.03
    tri_rad, piece_rad = rng.random((40, 3)), 4.0 * rng.random((25, 3))
    centre, radius = bounding_sphere(np.concatenate([tris, pieces]).reshape(-1, 3))
    pts = centre + rng.normal(size=(3000, 3)) * 0.8
    nrm = rng.normal(size=pts.shape)
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    dist = np.linalg.norm(pts - centre, axis=1)
    extra = OL.ExtraEmitters(pieces, piece_rad, np.ones((25, 6), bool), 1, 25, np.zeros((0, 3)), np.zeros((0, 3)),
                             np.zeros((0, 3)), np.zeros((0, 6), bool))
    out = dist > radius  # outside the object's sphere (inside it the bound is the brightest radiance)
    light = (emitter_sum(pts, nrm, tris, tri_rad, device="cpu")
             + emitter_sum(pts, nrm, pieces, piece_rad, device="cpu"))
    bound = OL._light_bound(pts, dist, tri_rad, radius, extra, centre)
    assert (bound[out] >= light[out] - 1e-12).all()
    # the same bound with the distances to the pieces' sphere from the (N,3) differences
    v = pieces.reshape(-1, 3)
    c = 0.5 * (v.min(0) + v.max(0))
    f_pc = OL._sphere_ff(float(np.linalg.norm(v - c, axis=1).max()), np.linalg.norm(pts - c, axis=1))
    t, pr = tri_rad.max(0), piece_rad.max(0)
    f_obj = OL._sphere_ff(radius, dist)[:, None]
    plain = np.minimum(np.maximum(t, pr) * f_obj, t * f_obj + pr * f_pc[:, None])
    np.testing.assert_allclose(bound, plain, rtol=1e-8)
    pieces_only = (bound < np.maximum(tri_rad.max(0), piece_rad.max(0)) * OL._sphere_ff(radius, dist)[:, None])
    assert pieces_only.any()  # the pieces' own sphere tightened the bound somewhere


def test_bilinear_blend_reproduces_a_bilinear_function():
    # _near_pixels' blend of a cell's four nodes: exact for f = a + b x + c y + d x y at every pixel of the
    # cell (its first node included)
    W, s = 37, 4
    f = lambda y, x: np.stack([1.0 + 0.5 * x - 0.25 * y + 0.125 * x * y, 2.0 - x, 3.0 + y * x], -1)
    y0, x0 = 8, 12
    yy, xx = (a.ravel() for a in np.meshgrid(np.arange(y0, y0 + s), np.arange(x0, x0 + s), indexing="ij"))
    corner = np.stack([f(y0, x0), f(y0, x0 + s), f(y0 + s, x0), f(y0 + s, x0 + s)])  # (4,3)
    got = OL._bilinear(np.broadcast_to(corner, (len(yy), 4, 3)), yy * W + xx, W, s)
    np.testing.assert_allclose(got, f(yy, xx), rtol=1e-12, atol=1e-12)


def _grid_box(lo, hi, k: int):
    """A closed box of k x k quads a face (2 k^2 triangles, CCW seen from outside): vertices, faces."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    t = np.linspace(0.0, 1.0, k + 1)
    verts, faces = [], []
    for ax in range(3):
        for side in (0, 1):
            u, w = (ax + 1) % 3, (ax + 2) % 3
            g = np.zeros((k + 1, k + 1, 3))
            g[..., ax] = hi[ax] if side else lo[ax]
            g[..., u] = lo[u] + (hi[u] - lo[u]) * t[:, None]
            g[..., w] = lo[w] + (hi[w] - lo[w]) * t[None, :]
            base = sum(len(x) for x in verts)
            verts.append(g.reshape(-1, 3))
            i = np.arange(k)[:, None] * (k + 1) + np.arange(k)[None, :]
            a, b, c, d = i, i + k + 1, i + k + 2, i + 1
            q = np.stack([np.stack([a, b, c], -1), np.stack([a, c, d], -1)], 2).reshape(-1, 3) + base
            n = np.zeros(3)
            n[ax] = 1.0 if side else -1.0
            v = np.concatenate(verts)
            flip = np.cross(v[q[:, 1]] - v[q[:, 0]], v[q[:, 2]] - v[q[:, 0]]) @ n < 0
            q[flip] = q[flip][:, ::-1]
            faces.append(q)
    return np.concatenate(verts), np.concatenate(faces)


@pytest.mark.parametrize("cells", [2, 1])  # object_light.ROOM_CELLS (at rest), app.dragframe.DRAG_ROOM_CELLS
def test_room_between_takes_its_share_of_the_object_light(cells):
    # an emitting box (the object, 0.4 m) 2 m in front of a wall of receivers, and a low screen (the room's
    # furniture) between them: the object's light on the wall with the room's share (room_share, its light
    # grouped in `cells` a side of its box) against the exact sum with a ray per (receiver, triangle) past the
    # object and the screen together
    v, f = _grid_box([-0.2, 0.0, -0.2], [0.2, 0.4, 0.2], 6)
    tris = v[f]
    rad = np.tile([[1.0, 0.8, 0.6]], (len(f), 1))
    obj = Occluder(v, f, "cpu")
    # the receivers: a vertical wall at z = -2 facing +z, heights 0 .. 1.2 m; the screen: a quad at
    # z = -1, 0.3 m high, across the whole width (from a receiver low on the wall it hides the object)
    ys = np.linspace(0.02, 1.2, 60)
    pts = np.stack([np.zeros_like(ys), ys, np.full_like(ys, -2.0)], 1)
    nrm = np.tile([[0.0, 0.0, 1.0]], (len(ys), 1))
    sv = np.array([[-3, 0, -1], [3, 0, -1], [3, 0.3, -1], [-3, 0.3, -1]], float)
    sf = np.array([[0, 1, 2], [0, 2, 3], [0, 2, 1], [0, 3, 2]])  # both sides
    room = Occluder(sv, sf, "cpu")
    both = Occluder(np.concatenate([v, sv]), np.concatenate([f, sf + len(v)]), "cpu")
    alone = emitter_sum(pts, nrm, tris, rad, obj, eps=OL.EXACT_EPS, device="cpu")
    exact = emitter_sum(pts, nrm, tris, rad, both, eps=OL.EXACT_EPS, device="cpu")
    share = OL.room_share(pts, nrm, tris, rad, room, cells=cells)
    ours = alone * share[:, None]
    lum_a, lum_e, lum_o = luminance(alone), luminance(exact), luminance(ours)
    hidden, seen = lum_e < 1e-6 * lum_a.max(), lum_e > 0.999 * lum_a
    assert hidden.sum() >= 5 and seen.sum() >= 20  # the screen hides the object from the wall's foot only
    assert (share[seen] == 1).all()
    np.testing.assert_allclose(lum_o[seen], lum_a[seen], rtol=1e-12)
    # through the screen's shadow edge the groups give a step, not the exact ramp: within 0.3 of the
    # object's unblocked light of the exact value with 2 cells (measured 0.25), 0.55 with 1 (measured 0.50: one
    # point per face axis steps where half the box is hidden), and the wall's total within 2 % (measured 0.9 %
    # and 1.5 %; ignoring the screen: +54 %)
    if cells == 2:
        assert (share[hidden] == 0).all()
    assert np.abs(lum_o - lum_e).max() <= (0.3 if cells == 2 else 0.55) * lum_a.max()
    assert abs(lum_o.sum() / lum_e.sum() - 1) < 0.02
    assert lum_a.sum() / lum_e.sum() > 1.3
    # without the room's share the screen would be ignored: the object's light on the wall's foot
    assert lum_a[hidden].min() > 0.3 * lum_a.max()
    # no room between (an empty room): every share is 1
    np.testing.assert_array_equal(OL.room_share(pts, nrm, tris, rad, Occluder(None, None, "cpu"), cells=cells), 1.0)


def test_grouped_far_field_against_a_ray_per_triangle(demo):
    # the drag frame's far field (ObjectLight.far_cells: FarGroups, the proxy's triangles merged 2 cells a side
    # by facing axis) beyond FAR_FIELD radii against emitter_sum (a ray per triangle), on the bundled scene's far
    # patch centres: the total within 10 %, as the per-triangle far field's (test_far_field_kernel_matches_ray_
    # per_triangle), and per centre lit above a hundredth of the largest, the 90th percentile of the relative
    # error within 0.01 of the per-triangle far field's and its largest within 0.2 of that one's (a grazing
    # centre, where a group's mean normal stands for members on both sides of the horizon); at most 48 emitters
    eng, pm, far, pv, pf, proxy_occ, centre, radius, tris, rad = _far_case(demo)
    shape = eng.object_light.proxy_shape(pv, pf, proxy_occ)
    tn = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    groups = OL.FarGroups(tris.mean(1), tn, shape.visibility.seen, OL.DRAG_FAR_CELLS)
    assert len(groups.tn) <= 6 * OL.DRAG_FAR_CELLS ** 3 < len(pf)
    ours = luminance(OL._reflected(pm.centre[far], pm.normal[far], tris, rad, proxy_occ, centre, radius, "cpu",
                                   shape.visibility, far_groups=groups))
    exact = luminance(emitter_sum(pm.centre[far], pm.normal[far], tris, rad, proxy_occ, device="cpu"))
    assert abs(ours.sum() / exact.sum() - 1) < 0.10
    lit = exact > 0.01 * exact.max()
    assert lit.sum() > 20
    rel = np.abs(ours[lit] / exact[lit] - 1)
    each = luminance(OL._reflected(pm.centre[far], pm.normal[far], tris, rad, proxy_occ, centre, radius, "cpu",
                                   shape.visibility))
    rel_each = np.abs(each[lit] / exact[lit] - 1)
    # measured: grouped total 0.990, p90 0.043, max 0.73 (a grazing centre); per triangle 0.991, 0.041, 0.59
    assert np.quantile(rel, 0.9) < np.quantile(rel_each, 0.9) + 0.01
    assert rel.max() < rel_each.max() + 0.2


def test_drag_object_light_against_the_frames_at_rest(demo):
    # the drag frame's object light (app.dragframe: its near sums through the shape's visibility tables with rays
    # kept within the bounding sphere, its centres from the far groups beyond DRAG_CENTRE_NEAR radii with no room
    # share, its near pixels each summed, the room's share only at drawn vertices, its vertices' far field from
    # DRAG_FAR_FIELD radii) against the same stage as at rest (a ray per triangle, FAR_FIELD, the grid) at the drag
    # frame's reach: within a level on every pixel and 0.05 rms over the lit ones (the coarse stage's own bar,
    # test_object_light_coarse_against_exact_on_the_frame), the centres' total within 5 % (measured 0.30 level,
    # 0.018 rms, centres 1.025: the far groups' points nearer than FAR_FIELD); without the sphere's rays the tables
    # alone lose 28 levels at contact (26 pixels at 0.91-1 radii), so that split is what holds the first bound;
    # the vertices' and centres' sums merged (ObjectLight._drag_sums) give what they give apart
    import dataclasses

    from app import dragframe as DF

    scene, eng, frame, pv, pf, proxy_occ = demo
    ol = eng.object_light
    centre, radius = bounding_sphere(pv)
    covered = frame.coverage.reshape(-1) >= 1.0
    tri_rad = ol.triangle_radiance(scene.obj, pv, pf, proxy_occ, eng.B_obj)
    saved = (ol.config, ol.room_cells, ol.far_cells)
    drag = dict(table_tolerance=DF.DRAG_LIGHT_TABLES, centre_near=DF.DRAG_CENTRE_NEAR, near_grid=DF.DRAG_LIGHT_GRID,
                share_drawn=DF.DRAG_SHARE_DRAWN, far_field=DF.DRAG_FAR_FIELD)
    rest = {k: getattr(ol, k) for k in drag}
    try:
        ol.config = dataclasses.replace(ol.config, near_factor=DF.DRAG_LIGHT_NEAR_FACTOR)
        ol.room_cells, ol.far_cells = DF.DRAG_ROOM_CELLS, DF.DRAG_FAR_CELLS
        ref, ref_c = ol.light(pv, pf, tri_rad, proxy_occ, centre, radius, covered)
        for k, v in drag.items():
            setattr(ol, k, v)
        ours, ours_c = ol.light(pv, pf, tri_rad, proxy_occ, centre, radius, covered)
        assert ol._light_tables is not None and ol.n_pixels > 100  # the tables ran, over a near region
        # the vertices' and the centres' sums in one launch each (_drag_sums) or apart: the same bytes
        ol.merge_sums = False
        apart, apart_c = ol.light(pv, pf, tri_rad, proxy_occ, centre, radius, covered)
        assert np.array_equal(apart, ours) and np.array_equal(apart_c, ours_c)
    finally:
        ol.merge_sums = True
        ol.config, ol.room_cells, ol.far_cells = saved
        for k, v in rest.items():
            setattr(ol, k, v)
    resp, rc = scene.response, eng.receivers
    d = resp.to_levels(rc.L_b + rc.rho_x * ours) - resp.to_levels(rc.L_b + rc.rho_x * ref)
    lit = np.abs(ref).sum(1) > 0
    assert lit.sum() > 500
    worst, rms = np.abs(d).max(), np.sqrt((d[lit] ** 2).mean())
    assert worst <= 1.0 and rms <= 0.05, (worst, rms)
    assert abs(luminance(ours_c).sum() / luminance(ref_c).sum() - 1) < 0.05
