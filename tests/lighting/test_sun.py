"""The sun: parsing, the sunlit region, the PCSS sun shadow, hard cases, and sun_room end to end.

Analytic: the sunlit floor of an opening has area A_open |n_open.d| / (n_floor.d); a plate's sun
shadow edge lies where the plate's edge projects along d, its penumbra 2 h tan(0.265 deg) / sin(elev).
Scenes: sun_room composited with --lighting known and scored against the path-traced truth.
"""
import dataclasses
import json

import numpy as np
import pytest

from bench.own_room_flow import spurious_noise_floor
from recon.proxy import bounding_sphere
from recon.scene import SceneError, Sun, load_scene
from tests.conftest import score, shared_scene


# ---------------------------------------------------------------- parsing
def _scene_with_sun(tmp_path, edit):
    src = shared_scene("sun_room")
    d = json.loads((src / "scene.json").read_text())
    sun = next(p for p in d["primitives"] if p.get("type") == "sun")
    edit(sun)
    (tmp_path / "scene.json").write_text(json.dumps(d))
    return tmp_path


def test_sun_and_opening_parsed():
    s = load_scene(shared_scene("sun_room"), load_textures=False)
    assert s.sun is not None and abs(np.linalg.norm(s.sun.direction) - 1) < 1e-9
    assert s.sun.angular_diameter_deg == pytest.approx(0.53)
    assert np.all(s.sun.irradiance > 40)
    assert [q.name for q in s.quads if q.opening] == ["window"]


@pytest.mark.parametrize("edit, words", [
    (lambda s: s.pop("direction_to_sun"), "direction_to_sun"),
    (lambda s: s.update(direction_to_sun=[0, 0, 0]), "zero vector"),
    (lambda s: s.update(direction_to_sun=[0, "up", 0]), "direction_to_sun"),
    (lambda s: s.update(irradiance_perpendicular=[-1, 1, 1]), "non-negative"),
    (lambda s: s.pop("irradiance_perpendicular"), "irradiance_perpendicular"),
    (lambda s: s.update(angular_diameter_deg=-0.5), "angular_diameter_deg"),
])
def test_malformed_sun_names_file_and_field(tmp_path, edit, words):
    root = _scene_with_sun(tmp_path, edit)
    with pytest.raises(SceneError) as e:
        load_scene(root, load_textures=False)
    assert str(root / "scene.json") in str(e.value) and words in str(e.value)


# ---------------------------------------------------------------- sunlit region and hard cases
def _light(room, direction):
    from lighting.sun import SunLight, openings

    s, pm, occ = room
    d = np.asarray(direction, float)
    sun = Sun(d / np.linalg.norm(d), 0.53, np.array([50.0, 50.0, 50.0]), np.zeros(3))
    return SunLight(sun, openings(s), occ)


@pytest.mark.parametrize("direction", [[-0.74, 0.62, 0.27], [-0.5, 0.8, -0.2], [-0.6, 0.75, -0.2]])
def test_sunlit_floor_area_is_the_openings_projection(room, direction):
    # any direction through the opening: lit floor area = A_open |n_open.d| / (n_floor.d)
    s, pm, _ = room
    light = _light(room, direction)
    d = light.d
    E = light.patch_irradiance(pm.corners, pm.normal, ~pm.is_emitter, n_side=12)
    floor = np.array([s.quads[q].name == "floor" for q in pm.quad])
    lit_area = (E[floor, 0] / (50 / np.pi) / d[1] * pm.area[floor]).sum()
    win = next(q for q in s.quads if q.opening)
    A = np.linalg.norm(np.cross(win.corners[1] - win.corners[0], win.corners[3] - win.corners[0]))
    expected = A * abs(win.normal @ d) / d[1]
    # the patch lands wholly on the floor for these directions (room 5 x 4.5 m)
    assert lit_area == pytest.approx(expected, rel=0.03)


@pytest.mark.parametrize("direction, why", [
    ([-0.7, -0.3, 0.2], "below the horizon"),
    ([0.7, 0.6, 0.2], "behind every opening"),       # the sun on the far side of the opening wall
    ([0.0, 0.6, 0.8], "parallel"),                   # exactly parallel to the opening's wall
])
def test_sun_that_cannot_enter_gives_zero_and_says_why(room, direction, why, caplog):
    s, pm, _ = room
    light = _light(room, direction)
    assert not light.active and why in light.reason
    E = light.patch_irradiance(pm.corners, pm.normal, ~pm.is_emitter)
    assert np.all(E == 0) and np.all(np.isfinite(E))


@pytest.mark.parametrize("case, why", [
    ("below", "below the horizon"),
    ("behind", "behind every opening"),
    ("no opening", "no opening"),
    ("zero irradiance", "irradiance_perpendicular is zero"),
])
def test_sun_hard_cases_warn_with_the_file(room, case, why, caplog):
    # one warning each, naming scene.json and the sun; the CLI's log shows it as
    # `photoar: warning: <file>: sun: ...` (a working frame with no direct sun, not an error)
    import logging

    from app.cli import LogFormatter
    from lighting.sun import SunLight, openings

    s, pm, occ = room
    d = {"below": [-0.7, -0.3, 0.2], "behind": [0.7, 0.6, 0.2]}.get(case, [-0.74, 0.62, 0.27])
    E = np.zeros(3) if case == "zero irradiance" else np.full(3, 50.0)
    sun = Sun(np.asarray(d) / np.linalg.norm(d), 0.53, E, np.zeros(3))
    where = f"{s.meta['json_path']}: sun"
    with caplog.at_level(logging.WARNING, logger="photoar"):
        light = SunLight(sun, [] if case == "no opening" else openings(s), occ, where=where)
    recs = [r for r in caplog.records if r.levelno == logging.WARNING]
    assert not light.active and len(recs) == 1
    line = LogFormatter().format(recs[0])
    assert line.startswith(f"photoar: warning: {s.meta['json_path']}: sun: ") and why in line, line
    assert line.endswith("no direct sun") and "\n" not in line


@pytest.mark.parametrize("declared", [True, False])
def test_captured_light_warns_when_the_declared_sun_has_no_opening(caplog, declared):
    # --lighting captured estimates the sun through the openings; a scene that declares a sun but
    # flags no opening warns as known light does (and a scene without a sun says nothing)
    import logging
    from types import SimpleNamespace

    from app.stages.sun import SunSetup

    s = load_scene(shared_scene("sun_room"), load_textures=False)
    for q in s.quads:
        q.opening = False
    if not declared:
        s.sun = None
    setup = SunSetup(s, "captured", "auto", None, None)
    none = np.zeros((1, 3))
    pre = SimpleNamespace(patches=SimpleNamespace(emission=none, albedo=none))
    rm = SimpleNamespace(E_x=none, L_b=none, recv_pix=np.zeros(1, bool))
    with caplog.at_level(logging.WARNING, logger="photoar"):
        out = setup.apply(pre, rm, "cpu")  # returns before any use of the precompute's arrays
    assert setup.light is None and out.stage is None
    msgs = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    if declared:
        assert msgs == [f"{s.meta['json_path']}: sun: the scene has no opening (window with \"opening\": true): "
                        "no direct sun"]
    else:
        assert msgs == []


def test_grazing_sun_is_finite_and_tiny(room):
    # 0.01 deg off parallel to the opening's wall: a sliver of light, finite, never NaN
    s, pm, _ = room
    light = _light(room, [-1e-4, 0.6, 0.8])
    E = light.patch_irradiance(pm.corners, pm.normal, ~pm.is_emitter)
    assert np.all(np.isfinite(E))
    assert (E[:, 0] * pm.area).sum() < 1e-3 * (50 / np.pi)


def test_opening_blocked_by_geometry_is_no_sun(room):
    # a wall slab just inside the opening: the sun misses every opening -> zero and a warning
    from kernels.visibility import Occluder
    from lighting.sun import SunLight, openings
    from recon.scene import box_faces

    s, pm, occ = room
    tris, verts = [], []
    for _, _, c, _ in box_faces([0.01, 0.0, 0.0], [0.05, 2.75, 4.5]):
        k = len(verts)
        verts += list(c)
        tris += [[k, k + 1, k + 2], [k, k + 2, k + 3]]
    slab = Occluder(np.vstack([pm.vert_pos, verts]), np.vstack([occ._idx.numpy().reshape(-1, 3),
                                                                 np.asarray(tris) + len(pm.vert_pos)]), "cpu")
    sun = Sun(np.array([-0.74, 0.62, 0.27]) / np.linalg.norm([-0.74, 0.62, 0.27]), 0.53, np.full(3, 50.0),
              np.zeros(3))
    light = SunLight(sun, openings(s), slab)
    E = light.patch_irradiance(pm.corners, pm.normal, ~pm.is_emitter)
    assert np.all(E == 0) and "miss every opening" in light.reason


def test_irradiance_on_mesh_tests_only_the_faces_a_shadow_edge_crosses(room):
    # a 0.1 m floor grid over the sunlit patch: points on faces whose corners agree take the sun from n.d
    # (lit) or none (dark), the rest a ray each; the same light as a ray per point wherever the patch's
    # straight edges cross the faces (only a corner of the lit polygon inside a face could differ)
    s, pm, _ = room
    light = _light(room, [-0.74, 0.62, 0.27])
    E = light.patch_irradiance(pm.corners, pm.normal, ~pm.is_emitter)
    floor = np.array([s.quads[q].name == "floor" for q in pm.quad]) & (E[:, 0] > 0)
    lo, hi = pm.centre[floor].min(0) - 0.4, pm.centre[floor].max(0) + 0.4
    xs, zs = np.arange(lo[0], hi[0], 0.1), np.arange(lo[2], hi[2], 0.1)
    X, Z = np.meshgrid(xs, zs, indexing="ij")
    v = np.stack([X.ravel(), np.full(X.size, 1e-3), Z.ravel()], 1)
    nx, nz = len(xs), len(zs)
    i, j = np.meshgrid(np.arange(nx - 1), np.arange(nz - 1), indexing="ij")
    a, b, c, d = (i * nz + j).ravel(), ((i + 1) * nz + j).ravel(), ((i + 1) * nz + j + 1).ravel(), (i * nz + j + 1).ravel()
    f = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    up = np.tile([0.0, 1.0, 0.0], (len(v), 1))
    lit_v = light.visibility(v, up) > 0
    rng = np.random.default_rng(3)
    tri = rng.integers(0, len(f), 20000)
    w = rng.dirichlet(np.ones(3), len(tri))
    pts = np.einsum("nk,nkc->nc", w, v[f[tri]])
    nrm = np.tile([0.0, 1.0, 0.0], (len(tri), 1))
    ours = light.irradiance_on_mesh(pts, nrm, lit_v[f[tri]])
    ref = light.irradiance(pts, nrm)
    mixed = (lit_v[f[tri]].sum(1) % 3) > 0
    assert ref[:, 0].max() > 0 and (ref[:, 0] == 0).any() and 0 < mixed.mean() < 0.3
    assert (np.abs(ours - ref).max(1) > 0).mean() < 0.005
    assert np.array_equal(ours[mixed], ref[mixed])


# ---------------------------------------------------------------- PCSS kernel, analytic
def test_sunlit_pieces_keep_the_power_and_the_self_shadow(room):
    # a 1 m x 1 m floor square lit whole: pieces carry its power, area x E_perp cos / pi; with a plate
    # 0.2 m above covering its left half (x < 0), the pieces' power is the lit area's and no piece
    # lies in the plate's shadow (the sun goes straight up through a roof opening here)
    from kernels.visibility import Occluder
    from lighting.sun import SunLight

    s, pm, _ = room
    roof = dataclasses.replace(next(q for q in s.quads if q.opening), corners=np.array(
        [[-5, 3, -5], [5, 3, -5], [5, 3, 5], [-5, 3, 5]], float), normal=np.array([0.0, -1.0, 0.0]))
    sun = Sun(np.array([0.0, 1.0, 0.0]), 0.53, np.array([30.0, 30.0, 30.0]), np.zeros(3))
    sq = np.array([[[-0.5, 0, -0.5], [0.5, 0, 0.5], [0.5, 0, -0.5]], [[-0.5, 0, -0.5], [-0.5, 0, 0.5], [0.5, 0, 0.5]]])
    open_sky = SunLight(sun, [roof], Occluder(None, None, "cpu"))
    pieces, E, parent = open_sky.sunlit_elements(sq, size=0.1)
    area = 0.5 * np.linalg.norm(np.cross(pieces[:, 1] - pieces[:, 0], pieces[:, 2] - pieces[:, 0]), axis=1)
    assert set(parent) == {0, 1} and area.sum() == pytest.approx(1.0)
    assert (area[:, None] * E).sum(0) == pytest.approx(np.full(3, 30.0 / np.pi))
    plate = np.array([[-0.6, 0.2, -0.6], [0.0, 0.2, -0.6], [0.0, 0.2, 0.6], [-0.6, 0.2, 0.6]])
    shaded = SunLight(sun, [roof], Occluder(plate, np.array([[0, 1, 2], [0, 2, 3]]), "cpu"))
    pieces, E, _ = shaded.sunlit_elements(sq, size=0.1)
    area = 0.5 * np.linalg.norm(np.cross(pieces[:, 1] - pieces[:, 0], pieces[:, 2] - pieces[:, 0]), axis=1)
    assert (area[:, None] * E).sum(0)[0] == pytest.approx(0.5 * 30.0 / np.pi, rel=0.05)
    assert pieces.mean(1)[:, 0].min() > -0.05  # lit pieces lie right of the shadow edge (x = 0)


def test_sunlit_pieces_kept_per_shape_follow_the_object(room):
    # SunlitPieces splits once and keeps the object's own shadow; moved with the object and its
    # room shadow tested per frame, the lit pieces and their sun are sunlit_elements' of the moved
    # object, piece for piece (three poses, one of them partly out of the sunlit patch)
    from kernels.visibility import Occluder
    from lighting.sun import SunLight, SunlitPieces, openings

    s, pm, occ = room
    light = SunLight(s.sun, openings(s), occ)
    V, F = s.obj.vertices, s.obj.faces
    pieces = SunlitPieces(light, V[F], Occluder(V, F, "cpu"), size=0.1)
    origin = V[F].reshape(-1, 3).mean(0)
    E_perp = s.sun.irradiance / np.pi
    counts = []
    for off in ([0.0, 0.0, 0.0], [0.4, 0.0, -0.3], [-1.2, 0.0, 0.8]):
        off = np.asarray(off)
        sub, E, parent = light.sunlit_elements(V[F] + off, [Occluder(V + off, F, "cpu")], size=0.1)
        share = pieces.lit_share(origin + off)
        lit = np.flatnonzero(share > 0)
        np.testing.assert_allclose(pieces.tris(origin + off)[lit], sub, atol=1e-9)
        np.testing.assert_allclose((share * pieces.cos)[lit, None] * E_perp, E, rtol=1e-9)
        np.testing.assert_array_equal(pieces.parent[lit], parent)
        counts.append(len(lit))
    assert min(counts) > 0 and len(set(counts)) > 1, counts


def test_emitter_sum_with_a_visibility_table_matches_rays():
    # small emitting triangles on a floor square half under a plate 0.1 m above it: receivers on a
    # wall beside it gather the same light with each emitter's visibility from its per-direction
    # table (32 cells a cube side) as with a ray per emitter; with nothing in the way, exactly
    from app.stages.object_light import TriangleVisibility
    from kernels.visibility import Occluder, emitter_sum, emitter_sum_seen
    from lighting.sun import _split_triangles

    sq = np.array([[[-0.5, 0, -0.5], [-0.5, 0, 0.5], [0.5, 0, 0.5]], [[-0.5, 0, -0.5], [0.5, 0, 0.5], [0.5, 0, -0.5]]])
    tris = _split_triangles(sq, 6)
    rad = np.random.default_rng(0).uniform(0.5, 1.0, (len(tris), 3))
    plate = Occluder(np.array([[-0.7, 0.1, -0.7], [0.0, 0.1, -0.7], [0.0, 0.1, 0.7], [-0.7, 0.1, 0.7]]),
                     np.array([[0, 2, 1], [0, 3, 2]]), "cpu")
    y, z = np.meshgrid(np.linspace(0.05, 1.0, 12), np.linspace(-0.8, 0.8, 12))
    pts = np.stack([np.full(y.size, -1.0), y.ravel(), z.ravel()], 1)
    nrm = np.tile([1.0, 0.0, 0.0], (len(pts), 1))
    none = Occluder(None, None, "cpu")
    total = []
    for occ, tol in ((none, 1e-9), (plate, 0.05)):
        table = TriangleVisibility(tris, occ, res=32)
        rays = emitter_sum(pts, nrm, tris, rad, occ, device="cpu")
        seen = emitter_sum_seen(pts, nrm, tris, rad, table.seen, 32, device="cpu")
        assert rays[:, 0].max() > 0
        np.testing.assert_allclose(seen, rays, rtol=tol, atol=tol * rays.max())
        total.append(rays.sum())
    assert total[1] < 0.9 * total[0]  # the plate matters


def test_point_emitters_within_their_bound_of_the_exact_form_factors():
    # emitter_sum_seen_bounded: triangles far enough from a receiver are point emitters at their
    # centroid; each one's error stays within tolerance x its unoccluded light A h / (pi r^3), at
    # receivers near and far, facing, grazing and straddling the triangles' horizon; 0 is exact
    from kernels.visibility import emitter_sum_seen, emitter_sum_seen_bounded
    from lighting.sun import _split_triangles

    rng = np.random.default_rng(1)
    sq = np.array([[[-0.5, 0, -0.5], [-0.5, 0, 0.5], [0.5, 0, 0.5]], [[-0.5, 0, -0.5], [0.5, 0, 0.5], [0.5, 0, -0.5]]])
    tris = _split_triangles(sq, 4)  # 32 pieces facing +y, edges 0.25-0.35 m
    rad = rng.uniform(0.5, 2.0, (len(tris), 3))
    seen = np.ones((len(tris), 6 * 4 * 4), bool)
    pts = np.concatenate([rng.uniform([-6, 0.01, -6], [6, 4, 6], (400, 3)),  # near and far
                          rng.uniform([-2, 0.001, -2], [2, 0.05, 2], (100, 3))])  # grazing, over the pieces
    nrm = rng.normal(size=(len(pts), 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    exact = emitter_sum_seen(pts, nrm, tris, rad, seen, 4, device="cpu")
    np.testing.assert_allclose(emitter_sum_seen_bounded(pts, nrm, tris, rad, seen, 4, 0.0, device="cpu"), exact,
                               rtol=1e-6, atol=1e-12)
    c = tris.mean(1)
    A = 0.5 * np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]), axis=1)
    r = np.linalg.norm(pts[:, None] - c[None], axis=-1)
    h = pts[:, 1][:, None]
    scale = (h * A[None] / (np.pi * r ** 3))[..., None] * rad[None]  # (N,S,3) unoccluded light at a facing receiver
    n_far = 0
    for tol in (0.02, 0.2):
        approx = emitter_sum_seen_bounded(pts, nrm, tris, rad, seen, 4, tol, device="cpu")
        err = np.abs(approx - exact)
        assert np.all(err <= tol * scale.sum(1) + 1e-12)
        n_far = max(n_far, int((err > 1e-9).any(1).sum()))
    assert n_far > 100  # the point emitters are used


def test_pcss_edge_and_penumbra_of_a_plate(device):
    from kernels.sunshadow import SunShadowMap

    h = 1.0
    v = np.array([[0, h, 0], [1, h, 0], [1, h, 1], [0, h, 1]], float)
    f = np.array([[0, 1, 2], [0, 2, 3]])
    d = np.array([0.3, 1.0, 0.0]) / np.linalg.norm([0.3, 1.0])
    a = np.radians(0.265)
    m = SunShadowMap(d, a, res=1024, device=device)
    m.render(v, f)
    x = np.linspace(-0.6, -0.0, 6001)
    occ = m.occlusion(np.stack([x, np.zeros_like(x), np.full_like(x, 0.5)], 1))
    edge = -h * d[0] / d[1]
    x50 = x[np.argmax(occ >= 0.5)]
    assert abs(x50 - edge) < 1.5e-3  # one texel of 1.4 mm
    # penumbra (2-98 %) on the floor: 2 h tan(a) / sin(elevation) along x, plus the texel
    pen = x[(occ > 0.02) & (occ < 0.98)]
    width = pen.max() - pen.min()
    expect = 2 * h / d[1] * np.tan(a) / d[1]
    assert 0.6 * expect < width < 1.6 * expect + 2e-3


def test_sun_map_allocates_nothing_after_the_first_frame(monkeypatch):
    # the sun's per-frame pass (render + lookups on kept points) makes no Warp arrays once its
    # buffers exist: a moved object of the same size reuses them
    import warp as wp

    from kernels import runtime
    from kernels.sunshadow import SunShadowMap

    runtime.init()
    m = SunShadowMap(np.array([0.3, 1.0, 0.0]), np.radians(0.265), res=64, device="cpu")
    pts = m.points(np.random.default_rng(0).uniform(-1, 1, (500, 3)) * [1, 0, 1], np.full(500, 1e-3))
    v = np.array([[-0.2, 0.5, -0.2], [0.2, 0.5, -0.2], [0.2, 0.5, 0.2], [-0.2, 0.5, 0.2]])
    f = np.array([[0, 1, 2], [0, 2, 3]])
    m.render(v, f)
    first = m.occlusion_at(pts).copy()
    made = []
    for name in ("array", "empty", "zeros", "full", "clone"):
        orig = getattr(wp, name)
        monkeypatch.setattr(wp, name, lambda *a, _o=orig, _n=name, **k: made.append(_n) or _o(*a, **k))
    m.render(v + [0.05, 0, 0], f)
    moved = m.occlusion_at(pts)
    assert made == [] and first.max() > 0.5 and not np.array_equal(first, moved)


# ---------------------------------------------------------------- the sun's per-frame work on sun_room
@pytest.fixture(scope="module")
def sun_drag(tmp_path_factory):
    """A coarse sun_room engine, its first drag frame made, and the Warp allocations of frames 2..5."""
    from app.dragpath import drag_offsets, moved
    from app.engine import Engine, EngineParams, FrameConfig
    from tests.app.test_frame_allocations import counting_allocations

    s = load_scene(shared_scene("sun_room"), load_textures=False)
    e = Engine(s, EngineParams(patch_size=0.4, emitter_patch_size=0.3), cache_dir=tmp_path_factory.mktemp("c"),
               quiet=True)
    offs = drag_offsets(s, s.obj, 5)
    e.render(moved(s.obj, offs[0]), FrameConfig(passes=8))
    with counting_allocations() as events:
        frames = [e.render(moved(s.obj, o), FrameConfig(passes=8)) for o in offs[1:]]
    return s, e, frames, events


def test_sun_frame_allocates_nothing_after_the_first_frame(sun_drag):
    # the sun's map, its lookups, the sunlit pieces (per shape) and their light, the clipped outline:
    # no Warp array or BVH made over frames 2..N of a drag (the whole frame, the sun's stages included)
    from tests.app.test_frame_allocations import _report

    s, e, frames, events = sun_drag
    assert e.sun.on and all(f.stats["timings"]["sun"] > 0 for f in frames)
    assert not events, _report(events)


def test_adaptive_outline_matches_every_ray(sun_drag):
    # SunStage.refine_clipped_edges with 4 corner rays a pixel (the other 12 where they disagree) against
    # all 16 everywhere, 3 x 3 and 8 x 8 (the reference) everywhere, on the chair's whole outline (its
    # radiance set bright: every outline pixel is refined): the same pixels; coverage equal to the 4 x 4's
    # on nearly every pixel (all 1629 here: it can differ only where a corner of the outline or a part
    # thinner than a pixel passes between the 4), so as close to 8 x 8; with fewer rays than 3 x 3
    # (13860 against 14661 here; 4 x 4: 26064)
    from app.dragpath import drag_offsets, moved

    s, e, frames, _ = sun_drag
    obj = moved(s.obj, drag_offsets(s, s.obj, 5)[-1])  # the last frame's: e's L_vert and sun share are its
    _, _, _, mesh, occ = e.object_shading.object_shape(obj)
    cov0 = e.object_shading.object_hits(mesh[0], mesh[2], occluder=occ).coverage()
    H, W = cov0.shape
    st = e.sun_pixels.stage

    def refine(s_: int, first):
        cov, rad = cov0.copy(), np.full((H, W, 3), 2.0)
        st.edge_first = first
        try:
            pix = st.refine_clipped_edges(s.camera, e.cam_occ, mesh, occ, e.last_shading[1], e.last_shading[3],
                                          obj.albedo, cov, rad, np.zeros(H * W, bool), s=s_)
        finally:
            st.edge_first = 4
        return pix, cov.reshape(-1)[pix], rad.reshape(-1, 3)[pix], st.edge_rays

    pix, c, r, rays = refine(4, 4)
    pix4, c4, r4, rays4 = refine(4, None)
    pix3, c3, _, rays3 = refine(3, None)
    pix8, c8, _, _ = refine(8, None)
    assert len(pix) > 100 and np.array_equal(pix, pix4) and np.array_equal(pix, pix3) and np.array_equal(pix, pix8)
    assert rays < 0.6 * rays4 and rays < rays3
    d = np.abs(c - c4)
    assert np.mean(d > 0) < 0.01 and d.max() <= 4 / 16
    err, err4, err3 = (np.abs(x - c8).mean() for x in (c, c4, c3))
    assert err <= err4 + 1e-3 and err < err3
    # radiance: the same where all 16 were cast; a wholly covered pixel's is its 4 corner hits' mean (the
    # sun's self-shadow edge or a crease within it moves that: 0.14 % of the mean on average here)
    both = (d == 0) & (c > 0)
    assert both.sum() > 100 and np.abs(r[both] - r4[both]).mean() < 0.01 * np.abs(r4[both]).mean()


def test_sunlit_object_light_matches_a_ray_per_piece(sun_drag):
    # the object-light stage's sunlit emitters (wholly lit faces folded into the proxy, partly lit
    # faces' pieces with their per-shape visibility table, one point per face in the far field)
    # against every lit piece as its own triangle with a ray per receiver (the form before issue
    # 20's cost work): the same light on the pixels and patch centres within a few per cent

    s, e, frames, _ = sun_drag
    obj = s.obj
    pv, pf, occ, _, _ = e.object_shading.object_shape(obj)
    centre, radius = bounding_sphere(pv)
    tri_rad = e.object_light.triangle_radiance(obj, pv, pf, occ, e.B_obj)
    cov = np.zeros(len(e.receivers.L_b), bool)
    base_p, base_c = e.object_light.light(pv, pf, tri_rad, occ, centre, radius, cov)
    sub, E, _ = e.sun.light.sunlit_elements(pv[pf], [occ], size=radius / 4.0)
    v = np.concatenate([pv, sub.reshape(-1, 3)])
    f = np.concatenate([pf, len(pv) + np.arange(3 * len(sub)).reshape(-1, 3)])
    ref_p, ref_c = e.object_light.light(v, f, np.concatenate([tri_rad, obj.albedo * E]), occ, centre, radius, cov)
    rad2, extra = e.sun_pixels.stage.object_emitters(pv, pf, tri_rad, obj.albedo, occ, radius)
    ours_p, ours_c = e.object_light.light(pv, pf, rad2, occ, centre, radius, cov, extra)
    assert extra is not None and len(extra.tris) < len(sub)
    sun_p = np.abs(ref_p - base_p).sum()
    assert sun_p > 0.5 * np.abs(base_p).sum()  # the sun's share of the object's light is large here
    assert np.abs(ours_p - ref_p).sum() < 0.05 * sun_p
    area = e.pre.patches.area[:, None]
    assert (ours_c * area).sum() == pytest.approx((ref_c * area).sum(), rel=0.04)


def test_later_bounces_on_clusters_match_the_dense_sum(sun_drag):
    # SunStage.later_bounces (LaterBounces: the first pass from the sunlit patches exact, the rest on
    # clusters of patches) against G_v sum_k (rho G)^k dB1 with the dense matrices, for the frame's own
    # first-bounce change (the object's sun shadow and its light) and for one on the sunlit patches only
    s, e, frames, _ = sun_drag
    pm = e.pre.patches
    pv, pf, occ, _, _ = e.object_shading.object_shape(s.obj)
    loss, loss_c = e.sun_pixels.stage.frame(s.obj.vertices, s.obj.faces)
    centre, radius = bounding_sphere(pv)
    _, R_cen = e.object_light.light(pv, pf, e.object_light.triangle_radiance(s.obj, pv, pf, occ, e.B_obj), occ, centre, radius)
    G, G_v = e.pre.G_c.astype(np.float64), e.pre.G_v.astype(np.float64)
    for dB1 in (pm.albedo * (R_cen - loss_c), -pm.albedo * loss_c):
        assert np.abs(dB1).sum() > 0
        ours = e.sun_pixels.stage.later_bounces(dB1, pm.albedo, e.pre.G_c, e.pre.G_v, 4)
        cur, more = dB1, np.zeros_like(dB1)
        for _ in range(2):
            cur = pm.albedo * (G @ cur)
            more += cur
        ref = G_v @ more
        err = np.abs(ours - ref) / np.maximum(e.receivers.E_v, 1e-12)
        assert np.abs(ref).max() > 0.01 * e.receivers.E_v.max()  # a change worth carrying
        assert np.percentile(err, 99) < 0.01 and err.max() < 0.03
    assert e.sun_pixels.stage.later_bounces(dB1, pm.albedo, e.pre.G_c, e.pre.G_v, 2) is None  # no later bounce


def test_pcss_block_ranges_give_the_taps_answer():
    # a lookup whose texels are all nearer than the receiver (or none) answers from the blocks' depth
    # ranges without its taps: the same occlusion as with one block for the whole map (taps nearly
    # always read), in the shadow, its penumbra, beside it and off the map
    from kernels.sunshadow import SunShadowMap

    d, a = np.array([0.3, 1.0, 0.2]), np.radians(0.265)
    v = np.array([[-0.2, 0.5, -0.2], [0.2, 0.5, -0.2], [0.2, 0.6, 0.2], [-0.2, 0.5, 0.2], [0.0, 0.9, 0.0]])
    f = np.array([[0, 1, 2], [0, 2, 3], [0, 1, 4], [1, 2, 4]])
    rng = np.random.default_rng(2)
    pts = rng.uniform(-0.8, 0.8, (40000, 3)) * [1, 0, 1]
    pts[:, 1] = rng.uniform(0.0, 0.45, len(pts))
    fp = rng.uniform(0.0, 4e-3, len(pts))
    out = []
    for block in (16, 256):
        m = SunShadowMap(d, a, res=256, device="cpu", block=block)
        m.render(v, f)
        out.append(m.occlusion(pts, fp))
    assert ((out[1] > 0) & (out[1] < 1)).sum() > 60 and (out[1] == 1).sum() > 1000 and (out[1] == 0).sum() > 1000
    assert np.array_equal(out[0], out[1])


def test_sun_map_is_kept_for_a_moved_object():
    # the orthographic map is measured from the object's box centre: a moved object of the same shape
    # reuses it (no rasterisation) and gives the lookups a fresh map gives; a turned one is drawn anew
    from kernels.sunshadow import SunShadowMap

    d, a = np.array([0.3, 1.0, 0.2]), np.radians(0.265)
    v = np.array([[-0.2, 0.5, -0.2], [0.2, 0.5, -0.2], [0.2, 0.6, 0.2], [-0.2, 0.5, 0.2]])
    f = np.array([[0, 1, 2], [0, 2, 3]])
    pts = np.random.default_rng(1).uniform(-0.6, 0.6, (400, 3)) * [1, 0, 1]
    fp = np.full(400, 2e-3)
    m = SunShadowMap(d, a, res=256, device="cpu")
    m.render(v, f)
    t = np.array([0.13, 0.0, -0.07])
    m.render(v + t, f)
    fresh = SunShadowMap(d, a, res=256, device="cpu")
    fresh.render(v + t, f)
    assert m.n_renders == 1 and fresh.n_renders == 1
    ours, ref = m.occlusion(pts + t, fp), fresh.occlusion(pts + t, fp)
    assert ref.max() > 0.5 and np.abs(ours - ref).max() < 1e-6
    R = np.array([[0.0, 0, 1], [0, 1, 0], [-1, 0, 0]])
    m.render(v @ R.T, f)
    fresh.render(v @ R.T, f)
    assert m.n_renders == 2 and np.abs(m.occlusion(pts, fp) - fresh.occlusion(pts, fp)).max() < 1e-6


# ---------------------------------------------------------------- sun_room end to end
@pytest.fixture(scope="module")
def sun_composite(tmp_path_factory):
    from app.cli import main as cli

    scene = shared_scene("sun_room")
    out = tmp_path_factory.mktemp("sun")
    assert cli(["-q", "composite", str(scene), "--out", str(out / "o"), "--cache", str(out / "c"),
                "--passes", "64"]) == 0
    return scene, out / "o"


def test_sun_room_known_scores(sun_composite):
    scene, out = sun_composite
    s = score(scene, out / "composite.png")
    assert s["rmse_affected"] <= 0.5 * s["rmse_affected_if_untouched"], s
    rep = json.loads((out / "report.json").read_text())
    assert rep["passes"] == 64  # the sun is one of the 64 passes


@pytest.fixture(scope="module")
def sun_composite_all(tmp_path_factory, shared_scenes_cache):
    """`photoar composite` on sun_room as issue 20 runs it: the all-sources frame (no --passes)."""
    from app.cli import main as cli

    scene = shared_scene("sun_room")
    out = tmp_path_factory.mktemp("sun_all")
    assert cli(["-q", "composite", str(scene), "--out", str(out / "o"), "--cache", str(shared_scenes_cache)]) == 0
    return scene, out / "o"


def test_sun_room_known_energy(sun_composite_all):
    # issue 20's band on the all-sources frame, `photoar composite`'s default (0.886 before the sun's
    # changes were passed on by the bounces each has left and its loss was no longer counted twice where
    # the object also hides the shadowed floor; 1.033 after). The cluster frames are not held to it:
    # with the physics right, the 64-pass frame scores 1.19 (one map darkens a cluster that joins the
    # sunlit patch beside the chair to the rest of the floor; docs/benchmarks.md, "Sunlight")
    scene, out = sun_composite_all
    s = score(scene, out / "composite.png")
    assert 0.9 <= s["energy_ratio"] <= 1.1, s


def test_sun_room_known_affected_along_the_sunlit_outline(sun_composite_all):
    # the sun's share on the two pixel rings along the sunlit patch's outline is the photo's
    # (app.stages.sun SunSetup._ring_share): taken whole or nil at each pixel's centre, the chair's
    # shadow crossing the patch's edge left a bright line and a dark stair: rmse_affected 1.50 of 21.4
    # untouched; 0.98 with the measured share
    scene, out = sun_composite_all
    s = score(scene, out / "composite.png")
    assert s["rmse_affected"] <= 1.2, s


def test_sun_room_known_object(sun_composite):
    # the object: sunlit faces that clip, their self-shadows, and the outline beside clipping light.
    # Measured 3.41 (bias -1.62); 5.47 (-0.08) when the sunlit floor reached the chair through the SH
    # volume (2.4x too much) and its feet, in the floor's plane, got none of it from the exact gather.
    # The bias: the chair's room-lit faces about 1.5 levels dark under known and captured light alike
    # (docs/unseen.md, "Sun light on the object"), not found yet
    scene, out = sun_composite
    s = score(scene, out / "composite.png")
    assert s["rmse_object"] <= 4.5 and abs(s["bias_object"]) <= 2.0, s


_spurious_noise_floor = spurious_noise_floor  # the model: bench/own_room_flow.py


def test_spurious_noise_floor_of_the_truth():
    # the floor is what the scorer's noise allows: small on the window and lamps rooms (whose
    # composites score 0.001-0.006), ~0.1 on sun_room (light through a small opening renders
    # noisily, and the change is near 2 levels over much of the room)
    assert _spurious_noise_floor(shared_scene("window_room")) < 0.005
    assert _spurious_noise_floor(shared_scene("sun_room")) > 0.05


def test_sun_room_known_spurious_at_the_noise_floor(sun_composite_all):
    scene, out = sun_composite_all
    s = score(scene, out / "composite.png")
    assert s["spurious"] <= 1.2 * _spurious_noise_floor(scene), s


@pytest.mark.xfail(strict=True, reason="acceptance spurious < 0.005 is below the noise floor of sun_room's truth "
                                       "(~0.10 for an exact answer, _spurious_noise_floor); we score ~0.107")
def test_sun_room_known_spurious_acceptance(sun_composite):
    scene, out = sun_composite
    s = score(scene, out / "composite.png")
    assert s["spurious"] < 0.005, s


def test_sun_room_captured_estimate_and_scores(tmp_path):
    # --lighting captured: the sun estimated from the photo (the declared one only reported against)
    from app.cli import main as cli

    scene = shared_scene("sun_room")
    assert cli(["-q", "composite", str(scene), "--out", str(tmp_path / "o"), "--cache", str(tmp_path / "c"),
                "--passes", "64", "--lighting", "captured"]) == 0
    rep = json.loads((tmp_path / "o" / "report.json").read_text())
    est = rep["sun_estimate"]
    assert rep["sun"]["from"] == "estimate"  # --sun auto: a
    # benchmark sun (no "declared_by") is the truth the estimate is compared against, not used; the two
    # directions are one vector written by two code paths: equal to float64 rounding, not bit for bit
    np.testing.assert_allclose(rep["sun"]["direction"], est["direction"], rtol=0, atol=1e-12)
    assert est["direction_error_deg"] <= 2.0, est
    assert abs(est["strength_ratio"] - 1.0) <= 0.25, est
    s = score(scene, tmp_path / "o" / "composite.png")
    assert 0.75 <= s["energy_ratio"] <= 1.3, s
    assert s["rmse_affected"] <= 0.6 * s["rmse_affected_if_untouched"], s


def test_captured_sun_without_a_declared_one(tmp_path):
    # a sunny photo whose scene.json declares no sun (as a user's room): the estimate alone drives
    # the sun's shadow, its loss and its bounce (the declared sun must not be needed anywhere)
    from app.cli import main as cli

    src = shared_scene("sun_room")
    room = tmp_path / "room"
    room.mkdir()
    for f in src.iterdir():
        if f.name != "scene.json":
            (room / f.name).symlink_to(f)
    d = json.loads((src / "scene.json").read_text())
    d["primitives"] = [p for p in d["primitives"] if p.get("type") != "sun"]
    (room / "scene.json").write_text(json.dumps(d))
    assert cli(["-q", "composite", str(room), "--out", str(tmp_path / "o"), "--cache", str(tmp_path / "c"),
                "--passes", "64", "--lighting", "captured"]) == 0
    rep = json.loads((tmp_path / "o" / "report.json").read_text())
    assert "irradiance_perpendicular" in rep["sun_estimate"] and "strength_ratio" not in rep["sun_estimate"]
    s = score(src, tmp_path / "o" / "composite.png")
    assert 0.75 <= s["energy_ratio"] <= 1.3 and s["rmse_affected"] <= 0.6 * s["rmse_affected_if_untouched"], s


def _edge_crossings(lum, shadow, lit):
    """Per row: x positions (sub-pixel) where the luminance crosses halfway between the shadow's
    and the lit floor's level, at the ends of each run of `shadow` pixels bordered by `lit` ones."""
    out = {}
    H, W = lum.shape
    for y in range(H):
        xs = np.flatnonzero(shadow[y])
        if len(xs) == 0:
            continue
        runs = np.split(xs, np.flatnonzero(np.diff(xs) > 1) + 1)
        for r in runs:
            for x_in, step in ((r[0], -1), (r[-1], 1)):
                x_out = x_in + 3 * step
                if not (0 <= x_out < W and lit[y, x_out]):
                    continue
                lo, hi = np.median(lum[y, r]), lum[y, x_out]
                half = 0.5 * (lo + hi)
                seg = np.arange(x_in - 3 * step, x_out + step, step)
                seg = seg[(seg >= 0) & (seg < W)]
                p = lum[y, seg]
                k = np.flatnonzero((p[:-1] - half) * (p[1:] - half) <= 0)
                if len(k) == 0:
                    continue
                k = k[0]
                t = (half - p[k]) / (p[k + 1] - p[k]) if p[k + 1] != p[k] else 0.5
                out[(y, step)] = seg[k] + t * step
    return out


def test_sun_shadow_edge_within_1_5_px(sun_composite):
    # 50 % crossings of the step along rows across the chair's sun-shadow edges, in the truth and
    # the composite; the offset measured perpendicular to the edge (the edge's slope from the rows)
    import cv2

    scene, out = sun_composite
    w = np.array([0.0722, 0.7152, 0.2126])
    bg = cv2.imread(str(scene / "background.png")).astype(float) @ w
    tr = cv2.imread(str(scene / "truth.png")).astype(float) @ w
    co = cv2.imread(str(out / "composite.png")).astype(float) @ w
    mask = cv2.dilate((cv2.imread(str(scene / "truth_mask.png"), 0) > 0).astype(np.uint8), np.ones((7, 7))) > 0
    lit = (bg >= 250) & ~mask  # the sunlit (clipped) patch of the photo
    shadow_t = lit & (cv2.medianBlur(tr.astype(np.uint8), 3) < 128)
    shadow_c = lit & (co < 128)
    ct = _edge_crossings(tr, shadow_t, lit & ~shadow_t)
    cc = _edge_crossings(co, shadow_c, lit & ~shadow_c)
    keys = sorted(set(ct) & set(cc))
    dx = np.array([cc[k] - ct[k] for k in keys])
    xs = np.array([ct[k] for k in keys])
    # edge slope per row pair on the same side: perpendicular distance = dx / sqrt(1 + slope^2)
    perp = []
    for i, (y, side) in enumerate(keys):
        nb = [j for j, (y2, s2) in enumerate(keys) if s2 == side and abs(y2 - y) == 1 and abs(xs[j] - xs[i]) < 8]
        slope = np.mean([abs(xs[j] - xs[i]) for j in nb]) if nb else 0.0
        perp.append(abs(dx[i]) / np.sqrt(1 + slope ** 2))
    perp = np.array(perp)
    assert len(perp) >= 40, len(perp)  # the edge is measured along a real length
    assert np.percentile(perp, 90) <= 1.5, (np.median(perp), np.percentile(perp, 90), perp.max())


@pytest.mark.parametrize("direction", [[-0.6, 0.75, -0.2], [-0.85, 0.45, 0.27]])
def test_captured_estimate_recovers_other_suns(tmp_path, direction):
    # suns sun_room was not rendered with: the room's photo made from the model itself (radiosity with
    # that sun, each pixel rho x irradiance, clipped at the exposure); the estimator sees only
    # the photo, the openings and the radiance mesh, and must find the sun again
    import dataclasses

    from app.engine import Engine, EngineParams
    from lighting.sun import estimate_sun

    s = load_scene(shared_scene("sun_room"), load_textures=False)
    d = np.asarray(direction, float) / np.linalg.norm(direction)
    s.sun = dataclasses.replace(s.sun, direction=d, irradiance=np.array([40.0, 38.0, 33.0]))
    e = Engine(s, EngineParams(patch_size=0.3, emitter_patch_size=0.2), cache_dir=tmp_path, quiet=True)
    pm = e.pre.patches
    rho = pm.albedo[np.maximum(e.receivers.pix_patch, 0)]
    L = np.where(e.receivers.recv_pix[:, None], rho * e.receivers.E_x, 0.0)
    sat = np.any(L * s.camera.exposure_time >= 1.0, axis=1) & e.receivers.recv_pix
    sun, info = estimate_sun(s, pm, e.receivers.pix_patch, e.receivers.pix_pos.astype(float), e.receivers.dirs, L, sat, e.receivers.recv_pix, e.pre.B[-1],
                             e.pre.G_c, e.scene_occ)
    assert sun is not None, info
    err = np.degrees(np.arccos(np.clip(sun.direction @ d, -1, 1)))
    print(f"sun {np.round(d, 3)}: direction error {err:.3f} deg, strength ratio "
          f"{luminance_ratio(sun.irradiance, s.sun.irradiance):.3f}")
    assert err <= 2.0, info
    assert abs(luminance_ratio(sun.irradiance, s.sun.irradiance) - 1) <= 0.25, info


def luminance_ratio(a, b):
    w = np.array([0.2126, 0.7152, 0.0722])
    return float(a @ w / (b @ w))


@pytest.mark.parametrize("direction, why", [([-0.7, -0.3, 0.2], "below the horizon"),
                                            ([0.0, 0.6, 0.8], "parallel")])
def test_engine_with_a_sun_that_cannot_enter(tmp_path, direction, why, caplog):
    # the whole frame with such a sun: a warning naming the cause, no sun pass, a finite picture
    import dataclasses
    import logging

    from app.engine import Engine, EngineParams

    s = load_scene(shared_scene("sun_room"), load_textures=False)
    d = np.asarray(direction, float) / np.linalg.norm(direction)
    s.sun = dataclasses.replace(s.sun, direction=d)
    with caplog.at_level(logging.WARNING, logger="photoar"):
        e = Engine(s, EngineParams(patch_size=0.4, emitter_patch_size=0.3, passes=8), cache_dir=tmp_path, quiet=True)
        fr = e.render(s.obj)
    assert any(why in r.getMessage() for r in caplog.records)
    assert not e.sun.on and fr.stats["passes"] == 8
    assert np.all(np.isfinite(fr.radiance))


def test_captured_estimate_finds_no_sun_in_a_sunless_photo(tmp_path):
    # the same room lit by its sky alone: no sun is invented
    from app.engine import Engine, EngineParams
    from lighting.sun import estimate_sun

    s = load_scene(shared_scene("sun_room"), load_textures=False)
    s.sun = None
    e = Engine(s, EngineParams(patch_size=0.3, emitter_patch_size=0.2), cache_dir=tmp_path, quiet=True)
    pm = e.pre.patches
    L = np.where(e.receivers.recv_pix[:, None], pm.albedo[np.maximum(e.receivers.pix_patch, 0)] * e.receivers.E_x, 0.0)
    sat = np.any(L * s.camera.exposure_time >= 1.0, axis=1) & e.receivers.recv_pix
    sun, info = estimate_sun(s, pm, e.receivers.pix_patch, e.receivers.pix_pos.astype(float), e.receivers.dirs, L, sat, e.receivers.recv_pix, e.pre.B[-1],
                             e.pre.G_c, e.scene_occ)
    assert sun is None and info["reason"], info


def test_quarter_rule_within_its_bound_of_the_exact_form_factor():
    # emitter_sum_seen_bounded between the point emitter and the exact form factor: a polygon (a triangle, a
    # quad run of two) wholly above the receiver's horizon whose point bound fails but whose quarters' holds
    # is summed as the point form factors of its fan triangles' quarters (split at the edges' mid-points):
    # that is what it gives there, and its error is within the quarters' mid-point bound
    # 6 h J_4 / (pi (r - rho)^5), itself within tolerance x A h / (pi r^3)
    from kernels.visibility import emitter_sum_seen, emitter_sum_seen_bounded

    rng = np.random.default_rng(3)
    quad = np.array([[-0.3, 0, -0.2], [0.4, 0, -0.2], [0.25, 0, 0.3], [-0.15, 0, 0.3]])  # a trapezoid facing +y
    cases = [(quad[[0, 2, 1]][None], None),  # one triangle, CCW seen from +y
             (np.stack([quad[[0, 2, 1]], quad[[0, 3, 2]]]), ([0], [2], quad[None, [0, 3, 2, 1]], [4]))]
    tol = 0.05
    for tris, groups in cases:
        poly = tris[0] if groups is None else groups[2][0]
        fan = [poly[[0, e, e + 1]] for e in range(1, len(poly) - 1)]
        area = sum(0.5 * np.linalg.norm(np.cross(t[1] - t[0], t[2] - t[0])) for t in fan)
        cen = sum(0.5 * np.linalg.norm(np.cross(t[1] - t[0], t[2] - t[0])) * t.mean(0) for t in fan) / area
        rho = np.linalg.norm(poly - cen, axis=1).max()
        J = sum(0.5 * np.linalg.norm(np.cross(t[1] - t[0], t[2] - t[0])) * ((t - t[[2, 0, 1]]) ** 2).sum() / 36.0
                for t in fan)  # the polar moment of the fan triangles about their own centroids (the group's is more)
        J_4 = J / 4.0
        J_point = J + sum(0.5 * np.linalg.norm(np.cross(t[1] - t[0], t[2] - t[0])) * ((t.mean(0) - cen) ** 2).sum()
                          for t in fan)  # the polygon's about its centroid (the point emitter's)
        pts = cen + rng.uniform([-3, 0.02, -3], [3, 2.5, 3], (4000, 3))
        nrm = rng.normal(size=(len(pts), 3))
        nrm[:, 1] = np.abs(nrm[:, 1])
        nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
        r = np.linalg.norm(pts - cen, axis=1)
        h = pts[:, 1]
        above = (((poly[None] - pts[:, None]) * nrm[:, None]).sum(-1) > 0).all(1)
        m = np.maximum(r - rho, 1e-9)
        quarters = above & (r > rho) & (6 * J_4 / area * r ** 3 <= tol * m ** 5) \
            & (6 * J_point / area * r ** 3 > tol * m ** 5)  # and not a point
        assert quarters.sum() > 200
        p, n = pts[quarters], nrm[quarters]
        seen = np.ones((len(tris), 6 * 4 * 4), bool)
        rad = np.ones((len(tris), 3))
        exact = emitter_sum_seen(p, n, tris, rad, seen, 4, device="cpu")[:, 0]
        got = emitter_sum_seen_bounded(p, n, tris, rad, seen, 4, tol, device="cpu", groups=groups)[:, 0]
        want = np.zeros(len(p))
        for t in fan:
            a, b, c = t
            an = np.cross(b - a, c - a) / 4.0
            for q in ((4 * a + b + c) / 6, (a + 4 * b + c) / 6, (a + b + 4 * c) / 6, (a + b + c) / 3):
                d = p - q
                want += (d @ an) * -(d * n).sum(1) / (2 * np.pi * (d * d).sum(1) ** 2)
        np.testing.assert_allclose(got, want, rtol=1e-5)  # the quarters' point form factors (float32 out)
        err = np.abs(got - exact)
        bound = 6 * h[quarters] * J_4 / (np.pi * (r[quarters] - rho) ** 5)
        assert np.all(err <= bound + 1e-7 * exact.max())
        assert np.all(bound <= tol * area * h[quarters] / (np.pi * r[quarters] ** 3) * (1 + 1e-9))
        assert err.max() > 1e-4 * exact.max()  # not the exact form factor


def test_no_sun_found_in_a_photo_that_clips_under_an_opening_warns(tmp_path, caplog, monkeypatch):
    # sun_room's photo clips on its sunlit floor; an estimate that finds no sun there leaves the sun's
    # shadow out of the composite, which the user must hear (a warning, shown under -q), not an info line
    import logging

    import app.stages.sun as sun_stage
    from app.engine import Engine, EngineParams

    why = "no sun direction explains the bright region (overlap 0.10 < 0.5)"
    monkeypatch.setattr(sun_stage, "estimate_sun", lambda *a, **k: (None, {"reason": why}))
    s = load_scene(shared_scene("sun_room"), load_textures=False)
    with caplog.at_level(logging.WARNING, logger="photoar"):
        e = Engine(s, EngineParams(patch_size=0.4, emitter_patch_size=0.3, passes=8, lighting="captured"),
                   cache_dir=tmp_path, quiet=True)
    msgs = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert any(why in m and "no sun was found" in m for m in msgs), msgs
    assert not e.sun.on
