"""The object stages' shortcuts against the exact evaluations they replace (app/stages/object_light.py,
app/stages/object_shading.py), on the bundled demo scene (no ../shared needed)."""
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from app.cli import demo_scene_dir  # noqa: E402
from app.engine import Engine, EngineParams  # noqa: E402
from app.stages import object_light as OL  # noqa: E402
from app.stages import object_shading as OS  # noqa: E402
from kernels.shade import SampledPatchSum  # noqa: E402
from kernels.visibility import Occluder, distance_to, emitter_sum  # noqa: E402
from recon.proxy import bounding_sphere  # noqa: E402
from recon.response import luminance  # noqa: E402
from recon.scene import load_scene  # noqa: E402

FAST = dict(patch_size=0.5, emitter_patch_size=0.2)


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    scene = load_scene(demo_scene_dir())
    eng = Engine(scene, EngineParams(**FAST), cache_dir=tmp_path_factory.mktemp("c"), device="cpu", quiet=True)
    frame = eng.render(scene.obj)
    pv, pf, proxy_occ, mesh, _ = eng.object_shading.object_shape(scene.obj)
    return scene, eng, frame, pv, pf, proxy_occ, mesh



def test_distance_to_a_triangle():
    occ = Occluder(np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]), np.array([[0, 1, 2]]), "cpu")
    pts = np.array([[0.2, 0.2, 0.5], [2.0, 0.0, 0.0], [-1.0, -1.0, 0.0], [0.25, 0.25, 0.0]])
    want = [0.5, 1.0, np.sqrt(2.0), 0.0]
    np.testing.assert_allclose(distance_to(occ, pts), want, atol=1e-5)
    assert np.all(distance_to(Occluder(None, None, "cpu"), pts, max_dist=7.0) == 7.0)


def test_pixel_table_lists_the_pixels_of_patches(demo):
    _, eng, *_ = demo
    table = eng.object_light.pixel_table()
    patches = np.unique(eng.receivers.pix_patch[eng.receivers.recv_pix])[::3]
    brute = np.flatnonzero(eng.receivers.recv_pix & np.isin(eng.receivers.pix_patch, patches))
    np.testing.assert_array_equal(table.pixels_of(patches), brute)
    assert len(table.pixels_of(np.zeros(0, int))) == 0


def test_far_field_matches_the_exact_sum(demo):
    # beyond FAR_FIELD radii the proxy's triangles as point sources with their per-shape visibility
    # table give what emitter_sum gives (ray per triangle): within 10 % in total, 25 % at 95 % of the
    # brighter points (the table's cells are ~11 degrees: a point may see a triangle the table hides)
    _, eng, _, pv, pf, proxy_occ, _ = demo
    centre, radius = bounding_sphere(pv)
    pm = eng.pre.patches
    far = np.flatnonzero((np.linalg.norm(pm.centre - centre, axis=1) > OL.FAR_FIELD * radius) & ~pm.is_emitter)
    rng = np.random.default_rng(0)
    tri_rad = rng.uniform(0.2, 1.0, (len(pf), 3))
    tvis = eng.object_light.proxy_shape(pv, pf, proxy_occ).visibility
    ours = luminance(OL._reflected(pm.centre[far], pm.normal[far], pv[pf], tri_rad, proxy_occ, centre, radius,
                                   "cpu", tvis))
    exact = luminance(emitter_sum(pm.centre[far], pm.normal[far], pv[pf], tri_rad, proxy_occ, device="cpu"))
    assert exact.sum() > 0
    assert abs(ours.sum() / exact.sum() - 1) < 0.10
    big = exact > 0.1 * exact.max()
    err = np.abs(ours[big] - exact[big]) / exact[big]
    assert np.percentile(err, 95) <= 0.25 and err.max() <= 0.6, (np.percentile(err, 95), err.max())


def test_near_pixels_on_the_grid_match_per_pixel(demo, monkeypatch):
    # the adaptive grid's blends against every pixel evaluated exactly: within a level everywhere
    scene, eng, frame, pv, pf, proxy_occ, _ = demo
    centre, radius = bounding_sphere(pv)
    tri_rad = eng.object_light.triangle_radiance(scene.obj, pv, pf, proxy_occ, eng.B_obj)
    covered = frame.coverage.reshape(-1) >= 1.0
    grid, _ = eng.object_light.light(pv, pf, tri_rad, proxy_occ, centre, radius, covered)
    n_exact = eng.object_light.n_exact
    monkeypatch.setattr(OL, "GRID_STRIDES", ())
    exact, _ = eng.object_light.light(pv, pf, tri_rad, proxy_occ, centre, radius, covered)
    sel = np.abs(exact).sum(1) > 0
    assert sel.sum() > 500 and n_exact < 0.5 * eng.object_light.n_exact
    resp = scene.response
    d = resp.to_levels(eng.receivers.L_b + eng.receivers.rho_x * grid) - resp.to_levels(eng.receivers.L_b + eng.receivers.rho_x * exact)
    assert np.abs(d).max() <= 1.0 and np.sqrt((d[sel] ** 2).mean()) <= 0.05


def test_shading_once_per_distinct_vertex_equals_every_vertex(demo):
    # the distinct (position, normal) vertices carry every vertex's value: the exact emitter light
    # at every vertex equals the distinct vertices' expanded
    scene, eng, _, _, _, _, mesh = demo
    v, n, f = mesh
    ss = eng.object_shading.shape_shading(v, n, f)
    assert len(ss.uniq) < len(v)
    own = Occluder(v, f, "cpu")
    every = eng.room_light.direct(v, n, [own], n_side=1)
    distinct = eng.room_light.direct(v[ss.uniq], n[ss.uniq], [own], n_side=1)[ss.inv]
    np.testing.assert_allclose(distinct, every, rtol=1e-5, atol=1e-7)


def test_far_field_loss_matches_the_exact_gather(demo):
    # the room's loss beyond DB_FAR radii as SH9 at the probe grid through the self-occlusion transfer
    # (clustered patches) against the exact gather at every distinct vertex (a ray per vertex and patch)
    scene, eng, _, _, _, _, mesh = demo
    v, n, f = mesh
    ss = eng.object_shading.shape_shading(v, n, f)
    vu, nu = v[ss.uniq] + ss.lift, n[ss.uniq]  # where the product gathers (a vertex on a contact line: just off it)
    pm = eng.pre.patches
    lo, hi = vu.min(0), vu.max(0)
    centre = 0.5 * (lo + hi)
    radius = np.linalg.norm(vu - centre, axis=1).max()
    d = np.linalg.norm(pm.centre - centre, axis=1) - pm.radius
    far = np.flatnonzero((d >= OS.DB_FAR * radius) & (2 * pm.radius <= OS.DB_CLUSTER * (d + pm.radius))
                         & ~pm.is_emitter)
    assert len(far) > 20
    dB = -0.5 * eng.B_obj[far]  # half their light lost: larger than any shadow's
    probes, weights = OS._probe_grid(lo, hi, vu, OS.DB_PROBES)
    cl = OS.cluster_patches(pm.centre[far], pm.normal[far], pm.area[far], pm.quad[far], dB, d[far] + pm.radius[far],
                            2.0 * float(pm.radius.min()))
    assert len(cl[0]) < len(far)
    ours = np.einsum("vk,vkc->vc", ss.T, np.einsum("vq,qkc->vkc", weights, eng.object_shading.far_field_sh(probes, lo, hi, *cl)))
    U = len(vu)
    exact_sum = SampledPatchSum(np.ones(U, bool), np.arange(U), np.full((U, 1), -1), "cpu", max_patches=len(far))
    exact = exact_sum(vu, nu, pm.corners[far], pm.normal[far], dB, [eng.scene_occ, Occluder(v, f, "cpu")], 2e-3)
    ours, exact = luminance(ours), luminance(exact)
    # SH9 (the indirect light's own order) holds the total; per vertex its error is measured against the
    # vertex's irradiance without any loss (what a pixel shows): measured 0.9 % mean, 5 % at the 95th
    assert exact.min() < 0 and abs(ours.sum() / exact.sum() - 1) < 0.10, ours.sum() / exact.sum()
    pv, pf, proxy_occ, *_ = eng.object_shading.object_shape(scene.obj)
    E = luminance(eng.object_shading.vertex_radiance(scene.obj, mesh, proxy_occ, None))[ss.uniq] / luminance(scene.obj.albedo)
    rel = np.abs(ours - exact) / E
    assert rel.mean() < 0.02 and np.percentile(rel, 95) < 0.08, (rel.mean(), np.percentile(rel, 95))


def test_shaft_clear_sees_every_triangle_that_can_cut_a_segment():
    # an object standing on the floor under a lamp: the floor it stands on and a wall beside the shaft
    # cannot cut a segment from the object to the lamp; a plate between them or reaching into the shaft can
    g = np.linspace(0.0, 0.5, 6)
    p = np.array([(x, y, z) for x in g for y in g for z in g])
    n = np.tile([0.0, 1.0, 0.0], (len(p), 1))
    n[p[:, 1] == 0.0] = [1.0, 0.0, 0.0]  # the bottom row faces sideways: its starts lie on the floor
    lamp = np.array([[[0.0, 2.0, 0.0], [0.5, 2.0, 0.0], [0.5, 2.0, 0.5], [0.0, 2.0, 0.5]]])  # CCW from below
    ln = np.array([[0.0, -1.0, 0.0]])

    def tri(*c):
        return np.array([c], float)

    floor = np.concatenate([tri((-5, 0, -5), (5, 0, -5), (5, 0, 5)), tri((-5, 0, -5), (5, 0, 5), (-5, 0, 5))])
    ceiling = tri((-5, 2.01, -5), (5, 2.01, 5), (5, 2.01, -5))
    wall = tri((3.0, 0, -5), (3.0, 3, 0), (3.0, 0, 5))
    plate = tri((0.1, 1.0, 0.1), (0.4, 1.0, 0.1), (0.25, 1.0, 0.4))
    corner = tri((0.45, 1.0, 0.45), (1.5, 1.0, 0.45), (1.5, 1.0, 1.5))  # pokes into the shaft's edge
    assert OS.shaft_clear(np.concatenate([floor, ceiling, wall]), p, n, lamp, ln, 2e-3)
    assert OS.shaft_clear(plate, p, n, lamp[:, ::-1], -ln, 2e-3)  # a lamp that emits upwards: nothing faces it
    assert not OS.shaft_clear(np.concatenate([floor, plate]), p, n, lamp, ln, 2e-3)
    assert not OS.shaft_clear(np.concatenate([floor, corner]), p, n, lamp, ln, 2e-3)
    window = np.array([[[3.0, 0.05, 0.0], [3.0, 0.05, 0.5], [3.0, 1.0, 0.5], [3.0, 1.0, 0.0]]])  # CCW from -x
    wn = np.array([[-1.0, 0.0, 0.0]])
    assert OS.shaft_clear(floor, p, n, window, wn, 2e-3)
    n[p[:, 1] == 0.0] = [0.6, -0.8, 0.0]  # starts below the floor that still see the window: the floor cuts
    assert not OS.shaft_clear(floor, p, n, window, wn, 2e-3)


def test_shaft_clear_room_gives_the_exact_emitter_light(demo):
    # where shaft_clear says no room triangle can cut a segment, the emitter light without room rays
    # equals the one with them (every vertex a sample: a ray per vertex and patch)
    scene, eng, _, _, _, _, mesh = demo
    v, n, f = mesh
    ss = eng.object_shading.shape_shading(v, n, f)
    vu, nu = v[ss.uniq], n[ss.uniq]
    pm, rl = eng.pre.patches, eng.room_light
    em, groups = eng.object_shading.emitter_groups()
    tris = eng.object_shading.room_triangles(rl.occluder)
    assert OS.shaft_clear(tris, vu, nu, groups[1], pm.normal[em[groups[0][:-1]]], 2e-3)
    U = len(vu)
    s = SampledPatchSum(np.ones(U, bool), np.arange(U), np.full((U, 1), -1), "cpu", max_patches=len(em))
    own = Occluder(v, f, "cpu")
    args = (vu, nu, pm.corners[em], pm.normal[em], rl.radiance[em])
    with_room = s(*args, [rl.occluder, own], 2e-3, groups=groups)
    without = s(*args, [Occluder(None, None, "cpu"), own], 2e-3, groups=groups)
    assert with_room.max() > 0
    lifted_on_floor = vu[:, 1] + nu[:, 1] * 2e-3 <= vu[:, 1].min() + 1e-9  # a segment starting on the floor
    np.testing.assert_allclose(with_room[~lifted_on_floor], without[~lifted_on_floor], rtol=1e-6, atol=1e-9)


def test_gathers_over_patches_split_by_point_patch_pairs(demo, monkeypatch):
    # the emitters' and dB's gathers (an exact form factor per point and patch) are cut by (point, patch)
    # pairs (pair_split), not by points: on two cores a few hundred points of tens of patches run in two
    # parts, and the answer is the one of a single part, bit for bit
    import functools

    from app import runtime

    scene, eng, _, _, _, proxy_occ, mesh = demo
    pm = eng.pre.patches
    dB = np.where(pm.is_emitter[:, None], 0.0, -0.3 * eng.B_obj)  # every patch loses light: dB's gather runs
    monkeypatch.setattr(runtime, "cores", lambda: 2)
    seen = []
    real = OS.pair_split

    def recording(device, n_patches):
        split = real(device, n_patches)

        def run(launch, n):
            seen.append((n, n_patches, runtime.parts(device, n, split.keywords["min_items"])))
            split(launch, n)
        return run

    monkeypatch.setattr(OS, "pair_split", recording)
    ours = eng.object_shading.vertex_radiance(scene.obj, mesh, proxy_occ, dB)
    assert {m for _, m, _ in seen} >= {len(eng.object_shading.emitter_groups()[0])} and len({m for _, m, _ in seen}) >= 2
    for n, m, k in seen:  # two parts exactly where each gets SPLIT_PAIRS pairs
        assert k == (2 if n // max(1, OS.SPLIT_PAIRS // m) >= 2 else 1), (n, m, k)
    assert any(k == 2 and n < 1024 for n, _, k in seen)  # under the points' threshold, split by its work
    monkeypatch.setattr(OS, "pair_split", lambda device, m: functools.partial(runtime.split, device=device,
                                                                              min_items=10 ** 9))
    one = eng.object_shading.vertex_radiance(scene.obj, mesh, proxy_occ, dB)
    assert ours.max() > 0
    np.testing.assert_array_equal(ours, one)


def test_gathered_rows_keep_every_vertex_read():
    # distinct vertex 0 has a buried copy and one that is not: kept; 1 is wholly buried: skipped unless a
    # sample; 2 is never buried: kept; all buried (or none): every vertex
    inv = np.array([0, 0, 1, 1, 2])
    buried = np.array([True, False, True, True, False])
    np.testing.assert_array_equal(OS.gathered_rows(buried, inv, np.array([2])), [0, 2])
    np.testing.assert_array_equal(OS.gathered_rows(buried, inv, np.array([1])), [0, 1, 2])
    assert OS.gathered_rows(np.ones(5, bool), inv, np.array([0])) == slice(None)
    assert OS.gathered_rows(np.zeros(5, bool), inv, np.array([0])) == slice(None)


def test_skipping_buried_vertices_keeps_the_vertex_radiance(demo):
    # the emitters' gather skips the distinct vertices whose every copy is buried (their values are
    # replaced by their neighbours'): the radiance at every vertex equals the one gathered everywhere, bit
    # for bit, and the emitters' light at the kept vertices equals the full gather's there
    scene, eng, _, _, _, proxy_occ, mesh = demo
    v, n, f = mesh
    ss = eng.object_shading.shape_shading(v, n, f)
    assert isinstance(ss.gathered, np.ndarray) and len(ss.gathered) < len(ss.uniq)  # some are skipped
    dB = np.where(eng.pre.patches.is_emitter[:, None], 0.0, -0.3 * eng.B_obj)
    skipped = eng.object_shading.vertex_radiance(scene.obj, mesh, proxy_occ, dB)
    oc = eng.object_shading.config
    full = OS.ShapeShading(v - v.mean(0), n, f, oc.prt_dirs, oc.dB_samples, eng.device, oc.vis_stride,
                           len(eng.room_light.emitters), skip_buried=False)
    assert full.gathered == slice(None)
    # private reach: the stage's per-shape ShapeShading swapped for one that gathers at every vertex (no
    # public knob makes one: skipping the buried vertices is not a setting)
    key, saved = eng.object_shading._prt
    full.key = key
    eng.object_shading._prt = (key, full)
    try:
        every = eng.object_shading.vertex_radiance(scene.obj, mesh, proxy_occ, dB)
    finally:
        eng.object_shading._prt = (key, saved)
    assert skipped.max() > 0
    np.testing.assert_array_equal(skipped, every)
