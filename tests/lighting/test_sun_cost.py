"""The sun's per-frame shortcuts give the answers of the plain computations they replace (issue 20:
the frame's cost with the sun).

- SunLight.visibility casts the room and the object in one launch (kernels.sunshadow.SunVisibility): the
  same lit points as a ray cast per mesh with its depth against the exit distance;
- SunLight.hit_correction (the sun per camera hit) equals irradiance_on_mesh minus the vertex blend.
"""
import numpy as np
import pytest

from recon.scene import Sun


@pytest.fixture(scope="module")
def lit_room(room):
    """sun_room (conftest's `room`) and a sun through its opening."""
    from lighting.sun import SunLight, openings

    s, _, occ = room
    d = np.array([-0.74, 0.62, 0.27])
    # the centre's rule (disk=False): these tests hold the per-hit and outline launches to the numpy they replaced;
    # the disk's share: test_hit_correction_with_the_disk
    light = SunLight(Sun(d / np.linalg.norm(d), 0.53, np.array([50.0, 40.0, 30.0]), np.zeros(3)), openings(s), occ,
                     disk=False)
    return s, light


def _chair(s):
    from kernels.visibility import Occluder

    obj = s.obj
    return obj.vertices, obj.normals, obj.faces, Occluder(obj.vertices, obj.faces, "cpu")


def _old_visibility(light, p, n, occluders, eps=1e-3):
    """SunLight.visibility as a cast per mesh (kernels.raycast), depth < exit distance."""
    from kernels.raycast import cast_rays

    cos = n @ light.d
    out = np.zeros(len(p))
    cand = np.flatnonzero(cos > 0)
    start = p[cand] + n[cand] * eps
    t = light.exit_distance(start)
    go = np.isfinite(t)
    idx, start, t = cand[go], start[go], t[go]
    free = np.ones(len(idx), bool)
    for o in occluders:
        free &= ~(cast_rays(o, start, np.broadcast_to(light.d, start.shape), max_t=float(t.max()) + 1.0)[2] < t)
    out[idx[free]] = cos[idx[free]]
    return out


def test_sun_rays_equal_a_cast_per_mesh(lit_room):
    # points over the sunlit floor and on the chair standing in it: the room's shadow (window frame,
    # walls) and the chair's own both matter; every answer the same as a ray cast per mesh
    s, light = lit_room
    v, n, f, own = _chair(s)
    rng = np.random.default_rng(5)
    floor = np.column_stack([rng.uniform(-3, 3, 6000), np.full(6000, 1e-3), rng.uniform(-3, 3, 6000)])
    p = np.concatenate([floor, v])
    nrm = np.concatenate([np.tile([0.0, 1.0, 0.0], (len(floor), 1)), n])
    ours = light.visibility(p, nrm, [own])
    ref = _old_visibility(light, p, nrm, [light.occluder, own])
    lit = ref > 0
    assert lit[:len(floor)].sum() > 100 and (~lit[:len(floor)] & (floor @ [0, 1, 0] >= 0)).sum() > 100
    assert lit[len(floor):].any() and (~lit[len(floor):] & (n @ light.d > 0)).any()  # chair: lit and self-shadowed
    # the same points lit (ray hits: exact); the cosines come from a Warp kernel and from numpy's
    # matrix product, whose last bits may differ with the CPU's FMA and BLAS: 1e-12 relative
    assert np.array_equal(ours > 0, lit)
    np.testing.assert_allclose(ours, ref, rtol=1e-12, atol=0)
    # many rays (two launches side by side on the CPU) and none at all: each point's answer is its
    # own kernel thread's, so the split launches give the one launch's values exactly
    big = np.repeat(p, 3, axis=0)
    assert np.array_equal(light.visibility(big, np.repeat(nrm, 3, axis=0), [own]), np.repeat(ours, 3))
    assert light.visibility(p[:0], nrm[:0], [own]).shape == (0,)


def test_hit_correction_is_the_per_hit_sun_minus_the_vertex_blend(lit_room):
    # every hit on a face with a sunlit corner gets irradiance_on_mesh minus its vertex blend; those it
    # leaves out (wholly sunlit flat faces: the chair's are flat) differ from their blend by < 1/FLAT_COS - 1
    from lighting.sun import FLAT_COS

    s, light = lit_room
    v, n, f, own = _chair(s)
    vis_v = light.visibility(v, n, [own])
    rng = np.random.default_rng(2)
    tri = rng.integers(0, len(f), 5000).astype(np.int32)
    bary = rng.dirichlet(np.ones(3), len(tri)).astype(np.float32)
    k, delta = light.hit_correction(v, n, f, vis_v, tri, bary, [own])
    lit_c = vis_v[f[tri]] > 0
    want = np.flatnonzero(lit_c.any(1))
    assert np.isin(k, want).all() and 0 < len(k) < len(want) and ((lit_c.sum(1) % 3) > 0).any()
    b = bary[want].astype(np.float64)
    ck = f[tri[want]]
    pos = np.einsum("nk,nkc->nc", b, v[ck])
    nrm = np.einsum("nk,nkc->nc", b, n[ck])
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    E = light.sun.irradiance / np.pi
    ref = light.irradiance_on_mesh(pos, nrm, lit_c[want], [own]) - np.einsum("nk,nkc->nc", b, vis_v[ck][:, :, None] * E)
    got = np.zeros_like(ref)
    got[np.searchsorted(want, k)] = delta[:, None] * E
    left = ~np.isin(want, k)
    assert lit_c[want[left]].all() and np.abs(got - ref)[left].max() <= (1 / FLAT_COS - 1) * E.max() + 1e-12
    assert np.abs(got - ref)[~left].max() < 1e-12


def test_hit_correction_with_the_disk(lit_room):
    # the sun's disk (issue 34, sunobj109): every hit the correction takes gets irradiance_on_mesh(disk=True) minus
    # its vertex blend (the disk's share the openings pass, on wholly lit curved faces and where an edge crosses)
    import dataclasses

    from lighting.sun import SunLight

    s, hard = lit_room
    # a disk of 10 deg: its penumbra (about 0.17 m wide 2 m from the opening) reaches the chair
    light = SunLight(dataclasses.replace(hard.sun, angular_diameter_deg=10.0), hard.openings, hard.occluder)
    v, n, f, own = _chair(s)
    vis_v = light.visibility(v, n, [own], disk=True)
    assert ((vis_v > 0) & (vis_v < np.maximum(n @ light.d, 0) - 1e-6)).any()  # some vertices in a penumbra
    rng = np.random.default_rng(2)
    tri = rng.integers(0, len(f), 5000).astype(np.int32)
    bary = rng.dirichlet(np.ones(3), len(tri)).astype(np.float32)
    k, delta = light.hit_correction(v, n, f, vis_v, tri, bary, [own])
    lit_c = vis_v[f[tri[k]]] > 0
    b = bary[k].astype(np.float64)
    ck = f[tri[k]]
    pos = np.einsum("nk,nkc->nc", b, v[ck])
    nrm = np.einsum("nk,nkc->nc", b, n[ck])
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    E = light.sun.irradiance / np.pi
    ref = light.irradiance_on_mesh(pos, nrm, lit_c, [own], disk=True) - np.einsum("nk,nkc->nc", b, vis_v[ck][:, :, None] * E)
    assert len(k) > 100
    assert np.abs(delta[:, None] * E - ref).max() < 1e-12


def test_hit_correction_in_blocks_and_halves_equals_it_hit_by_hit(lit_room):
    # more hits than one launch's buffers hold (blocks), with enough rays for two launches side by side:
    # the same deltas, bit for bit, as small calls of one launch each
    from kernels.sunshadow import SUN_RAYS_SPLIT

    s, light = lit_room
    v, n, f, own = _chair(s)
    vis_v = light.visibility(v, n, [own])
    lit_c = (vis_v[f] > 0).sum(1)
    mixed = np.flatnonzero((lit_c > 0) & (lit_c < 3))
    rng = np.random.default_rng(5)
    tri = np.concatenate([rng.choice(mixed, 12000), rng.integers(0, len(f), 30000)]).astype(np.int32)
    bary = rng.dirichlet(np.ones(3), len(tri)).astype(np.float32)
    k, delta = light.hit_correction(v, n, f, vis_v, tri, bary, [own])
    assert len(tri) > light._hit_sun.ws.rows and np.isin(tri[k], mixed).sum() >= 2 * SUN_RAYS_SPLIT
    parts = [light.hit_correction(v, n, f, vis_v, tri[a:a + 1000], bary[a:a + 1000], [own])
             for a in range(0, len(tri), 1000)]
    assert np.array_equal(k, np.concatenate([kk + a for (kk, _), a in zip(parts, range(0, len(tri), 1000))]))
    assert np.array_equal(delta, np.concatenate([d for _, d in parts]))
    assert (delta != 0).sum() > 1000


def _tilted_hits(n: np.ndarray, f: np.ndarray, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The chair's normals n (V,3) tilted apart by ~3 degrees (no face flat), and 3000 random camera hits on
    its faces f: (tilted unit normals, tri (3000,) int32, bary (3000,3) float32)."""
    rng = np.random.default_rng(seed)
    nt = n + rng.normal(0.0, 0.03, n.shape)
    nt /= np.linalg.norm(nt, axis=1, keepdims=True)
    tri = rng.integers(0, len(f), 3000).astype(np.int32)
    return nt, tri, rng.dirichlet(np.ones(3), len(tri)).astype(np.float32)


def test_hit_correction_keeps_the_hits_of_curved_faces(lit_room):
    # a wholly sunlit face whose corner normals differ (a smooth mesh) keeps its per-hit cos: the chair's
    # faces with their normals tilted apart by ~3 degrees are all in k and give the plain answer
    s, light = lit_room
    v, n, f, own = _chair(s)
    n, tri, bary = _tilted_hits(n, f, seed=4)
    vis_v = light.visibility(v, n, [own])
    k, delta = light.hit_correction(v, n, f, vis_v, tri, bary, [own])
    lit_c = vis_v[f[tri]] > 0
    assert np.array_equal(k, np.flatnonzero(lit_c.any(1))) and (lit_c[k].all(1)).any()
    whole = lit_c[k].all(1)
    b = bary[k].astype(np.float64)
    nrm = np.einsum("nk,nkc->nc", b, n[f[tri[k]]])
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    ref = np.maximum(nrm @ light.d, 0.0) - np.einsum("nk,nk->n", b, vis_v[f[tri[k]]])
    assert np.abs(delta[whole] - ref[whole]).max() < 1e-12 and np.abs(ref[whole]).max() > 1e-5


def test_exit_distance_is_the_plain_formula(lit_room):
    # the openings prepared once (SunLight._exits) give the distances of the plain per-opening formula: the
    # hit point p + t d, its place along the quad's edges, the nearest opening passed through
    s, light = lit_room
    rng = np.random.default_rng(7)
    p = np.column_stack([rng.uniform(-3, 3, 20000), rng.uniform(0, 2.5, 20000), rng.uniform(-3, 3, 20000)])
    ref = np.full(len(p), np.inf)
    for q in light.openings:
        denom = float(np.dot(light.d, q.normal))
        if denom >= -1e-9:
            continue
        c0 = q.corners[0]
        t = (p - c0) @ q.normal / -denom
        hit = p + t[:, None] * light.d
        U, V = q.corners[1] - c0, q.corners[3] - c0
        u, v = (hit - c0) @ U / (U @ U), (hit - c0) @ V / (V @ V)
        ok = (t > 0) & (u >= 0) & (u <= 1) & (v >= 0) & (v <= 1)
        ref = np.where(ok & (t < ref), t, ref)
    got = light.exit_distance(p)
    fin = np.isfinite(ref)
    assert 500 < fin.sum() < len(p) - 500
    assert np.array_equal(np.isfinite(got), fin) and np.allclose(got[fin], ref[fin], rtol=1e-12, atol=0)


def test_hit_correction_flat_faces_follow_the_mesh_given(lit_room):
    # the flat faces are kept for the last (normals, faces) arrays: a call with other normals (the chair's
    # tilted: no face flat) gets that mesh's answer, as a fresh SunLight's, and the first mesh's again after
    from lighting.sun import SunLight

    s, light = lit_room
    v, n, f, own = _chair(s)
    n2, tri, bary = _tilted_hits(n, f, seed=3)
    fresh = SunLight(light.sun, light.openings, light.occluder, disk=light.disk)
    for nn in (n, n2, n):
        vis_v = light.visibility(v, nn, [own])
        k, delta = light.hit_correction(v, nn, f, vis_v, tri, bary, [own])
        fresh._flat = None
        k_ref, delta_ref = fresh.hit_correction(v, nn, f, vis_v, tri, bary, [own])
        assert np.array_equal(k, k_ref) and np.array_equal(delta, delta_ref)
    assert len(light.hit_correction(v, n2, f, light.visibility(v, n2, [own]), tri, bary, [own])[0]) > len(k)


@pytest.mark.parametrize("with_sun", [True, False])
def test_outline_shade_equals_the_rays_shaded_one_by_one(lit_room, with_sun):
    # kernels.sunshadow.OutlineShade (refine_clipped_edges's launch) against OutlineHits's rays read back and
    # shaded in numpy as refine_clipped_edges did: the vertex blend, the sun per hit from hit_correction (at
    # least 0), each pixel's coverage and its hits' mean radiance
    from kernels.sunshadow import OutlineHits, OutlineShade

    s, light = lit_room
    v, n, f, own = _chair(s)
    vis_v = light.visibility(v, n, [own])
    cam = s.camera
    uv, _ = cam.project(v)
    u0, v0 = np.floor(uv.min(0)).astype(int) - 2
    u1, v1 = np.ceil(uv.max(0)).astype(int) + 2
    gy, gx = np.mgrid[v0:v1, u0:u1]
    px, py = gx.ravel().astype(np.int32), gy.ravel().astype(np.int32)
    rng = np.random.default_rng(7)
    L = rng.uniform(0.0, 2.0, (len(v), 3))
    albedo, E = np.array([0.6, 0.5, 0.4]), light.sun.irradiance / np.pi
    M = cam.R.T @ np.linalg.inv(cam.K)
    tri, bary, hit, full = OutlineHits("cpu")(own, light.occluder, cam.centre, M, px, py, 4, None, 4)
    rad = np.zeros((len(tri), 3))
    h = np.flatnonzero(hit)
    b = bary[h].astype(np.float64)
    rad[h] = np.einsum("nk,nkc->nc", b, L[f[tri[h]]])
    if with_sun:
        k, delta = light.hit_correction(v, n, f, vis_v, tri[h], bary[h], [own])
        rad[h[k]] = np.maximum(rad[h[k]] + albedo * (delta[:, None] * E), 0.0)
        assert len(k) > 100 and (delta < 0).any() and (delta > 0).any()
    hits = hit.reshape(-1, 16)
    cov_ref = hits.sum(1) / np.where(full, 16, 4)
    mean_ref = rad.reshape(-1, 16, 3).sum(1) / np.maximum(hits.sum(1), 1)[:, None]
    shade = OutlineShade("cpu", light.entries, light.d)
    sun = (vis_v, light.hit_codes(n, f, vis_v), albedo, E, [light.occluder.id, own.id], 1e-3) if with_sun else None
    cov, mean, full2 = shade(own, light.occluder, cam.centre, M, px, py, 4, (v, n, f), L, sun, None, 4)
    assert ((cov > 0) & (cov < 1)).sum() > 100 and (cov == 1).sum() > 1000
    assert np.array_equal(full2, full) and np.array_equal(cov, cov_ref)
    assert np.abs(mean - mean_ref).max() < 1e-12
    assert shade.rays == len(px) * 4 + full.sum() * 12
