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
    pv, pf, proxy_occ, mesh, _ = eng._object_shape(scene.obj)
    return scene, eng, frame, pv, pf, proxy_occ, mesh



def test_distance_to_a_triangle():
    occ = Occluder(np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]), np.array([[0, 1, 2]]), "cpu")
    pts = np.array([[0.2, 0.2, 0.5], [2.0, 0.0, 0.0], [-1.0, -1.0, 0.0], [0.25, 0.25, 0.0]])
    want = [0.5, 1.0, np.sqrt(2.0), 0.0]
    np.testing.assert_allclose(distance_to(occ, pts), want, atol=1e-5)
    assert np.all(distance_to(Occluder(None, None, "cpu"), pts, max_dist=7.0) == 7.0)


def test_pixel_table_lists_the_pixels_of_patches(demo):
    _, eng, *_ = demo
    table = OL.pixel_table(eng)
    patches = np.unique(eng.pix_patch[eng.recv_pix])[::3]
    brute = np.flatnonzero(eng.recv_pix & np.isin(eng.pix_patch, patches))
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
    tvis = OL.proxy_shape(eng, pv, pf, proxy_occ).visibility
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
    tri_rad = eng._object_triangle_radiance(scene.obj, pv, pf, proxy_occ, eng.B_obj)
    covered = frame.coverage.reshape(-1) >= 1.0
    grid, _ = eng._object_light(pv, pf, tri_rad, proxy_occ, centre, radius, covered)
    n_exact = eng._n_object_light_exact
    monkeypatch.setattr(OL, "GRID_STRIDES", ())
    exact, _ = eng._object_light(pv, pf, tri_rad, proxy_occ, centre, radius, covered)
    sel = np.abs(exact).sum(1) > 0
    assert sel.sum() > 500 and n_exact < 0.5 * eng._n_object_light_exact
    resp = scene.response
    d = resp.to_levels(eng.L_b + eng.rho_x * grid) - resp.to_levels(eng.L_b + eng.rho_x * exact)
    assert np.abs(d).max() <= 1.0 and np.sqrt((d[sel] ** 2).mean()) <= 0.05


def test_shading_once_per_distinct_vertex_equals_every_vertex(demo):
    # the distinct (position, normal) vertices carry every vertex's value: the exact emitter light
    # at every vertex equals the distinct vertices' expanded
    scene, eng, _, _, _, _, mesh = demo
    v, n, f = mesh
    ss = OS.shape_shading(eng, v, n, f)
    assert len(ss.uniq) < len(v)
    own = Occluder(v, f, "cpu")
    every = eng.room_light.direct(v, n, [own], n_side=1)
    distinct = eng.room_light.direct(v[ss.uniq], n[ss.uniq], [own], n_side=1)[ss.inv]
    np.testing.assert_allclose(distinct, every, rtol=1e-5, atol=1e-7)
