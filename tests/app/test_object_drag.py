"""The drag frame's object from per-shape tables (app.stages.object_drag): SH rotation about +Y, the PRT
transfer of a convex shape, the self-visibility table, the yaw read from a pose."""
import numpy as np
import pytest

from app.stages.object_drag import (_fib_sphere, frame_yaw, prt_directions, rot_y, sh_yaw_matrix,
                                    visibility_table, yaw_of)
from lighting import sh


def _radiance(w: np.ndarray) -> np.ndarray:
    """A test environment (N,3) at unit directions w (N,3): a sharp lobe, a broad one and a floor, per channel."""
    a = np.array([0.3, 0.8, 0.52]) / np.linalg.norm([0.3, 0.8, 0.52])
    b = np.array([-0.7, -0.2, 0.4]) / np.linalg.norm([-0.7, -0.2, 0.4])
    lobe = np.maximum(w @ a, 0.0) ** 6
    broad = np.exp(2.0 * (w @ b - 1.0))
    return np.stack([lobe + 0.2, broad, lobe * broad + 0.5 * (w[:, 1] < 0)], 1)


def _project(f, n: int = 40000) -> np.ndarray:
    """SH9 coefficients (9,3) of f over n equal-area directions (quadrature error ~1e-4 for these lobes)."""
    D = _fib_sphere(n)
    return sh.project(D, f(D), np.full(n, 4 * np.pi / n))


@pytest.mark.parametrize("yaw", [0.0, 0.4, -1.3, 2.9])
def test_yaw_rotated_sh_is_the_sh_of_the_rotated_function(yaw):
    # the coefficients of g(c) = f(R_y(yaw) c), projected directly, against sh_yaw_matrix(yaw) @ f's: equal
    # within the quadrature's error (1e-3 of the largest coefficient); projection commutes with a rotation,
    # so the identity is exact for any f, band-limited or not
    R = rot_y(yaw)
    f_c = _project(_radiance)
    g_c = _project(lambda c: _radiance(c @ R.T))
    rotated = sh_yaw_matrix(yaw) @ f_c
    np.testing.assert_allclose(rotated, g_c, atol=1e-3 * np.abs(f_c).max())


def test_yaw_matrices_compose_and_keep_the_zonal_terms():
    # a turn by a then b is a turn by a + b; the up axis' zonal terms (l, m = 0 about +Y) never move; orthogonal
    a, b = 0.7, -2.1
    np.testing.assert_allclose(sh_yaw_matrix(a) @ sh_yaw_matrix(b), sh_yaw_matrix(a + b), atol=1e-12)
    np.testing.assert_allclose(sh_yaw_matrix(0.0), np.eye(9), atol=1e-12)
    A = sh_yaw_matrix(1.1)
    np.testing.assert_allclose(A @ A.T, np.eye(9), atol=1e-12)
    up = sh.basis(np.array([0.0, 1.0, 0.0]))  # a function of y alone: its projection is kept
    np.testing.assert_allclose(A.T @ up, up, atol=1e-12)


def _icosphere(level: int = 2) -> tuple[np.ndarray, np.ndarray]:
    t = (1 + 5 ** 0.5) / 2
    v = np.array([[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t], [0, -1, -t], [0, 1, -t],
                  [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]], float)
    f = [[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4], [11, 10, 2], [10, 7, 6],
         [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10],
         [8, 6, 7], [9, 8, 1]]
    v = list(v / np.linalg.norm(v, axis=1, keepdims=True))
    for _ in range(level):
        mid: dict = {}
        nf = []
        for a, b, c in f:
            def m(i, j):
                k = (min(i, j), max(i, j))
                if k not in mid:
                    p = v[i] + v[j]
                    v.append(p / np.linalg.norm(p))
                    mid[k] = len(v) - 1
                return mid[k]
            ab, bc, ca = m(a, b), m(b, c), m(c, a)
            nf += [[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]
        f = nf
    return np.array(v), np.array(f, np.int32)


@pytest.mark.parametrize("yaw", [0.0, 0.9])
def test_prt_of_a_convex_shape_gives_the_cosine_irradiance(yaw):
    # a sphere of 0.3 m (convex: nothing of it hides the sky from its own vertices): its PRT transfer (the
    # frame's kernels.shade.self_transfer, 128 cosine-distributed rays) in its own frame, under an environment
    # turned into that frame by sh_yaw_matrix, gives irradiance / pi. Constant radiance L0: L0 exactly (to the
    # rays' quadrature); a linear environment a + b.w: (pi a + 2 pi / 3 b.n) / pi at the world normal n, within
    # 2 % of the constant term (128 stratified rays integrate a linear function to ~1e-3; the rest is rounding)
    from kernels.shade import self_transfer
    from kernels.visibility import Occluder

    v, f = _icosphere(2)
    v = v * 0.3
    n = v / np.linalg.norm(v, axis=1, keepdims=True)
    T, hit, _ = self_transfer(v, n, Occluder(v, f, "cpu"), 128, device="cpu")
    assert (hit < 0).all()  # convex: every ray leaves
    R = rot_y(yaw)
    A = sh_yaw_matrix(yaw)
    a, b = np.array([0.4, 1.0, 2.0]), np.array([[0.3, 0.1, -0.5], [0.2, 0.6, 0.1], [-0.4, 0.0, 0.3]])  # b[c] per channel
    # the environment in world coordinates: L(w) = a + b w (coefficients: 4 pi C0 a and 4 pi / 3 C1 b)
    L = np.zeros((9, 3))
    L[0] = 4 * np.pi * sh.C0 * a
    L[1], L[2], L[3] = (4 * np.pi / 3 * sh.C1 * b[:, k] for k in (1, 2, 0))
    E = T.astype(np.float64) @ (A @ L)  # (V,3) at the vertices, in the sphere's frame
    n_world = n @ R.T  # the sphere's vertices turned by yaw
    expected = a + (2.0 / 3.0) * (n_world @ b.T)
    np.testing.assert_allclose(E, expected, atol=0.02 * a.min())
    L0 = np.zeros((9, 3))
    L0[0] = 4 * np.pi * sh.C0 * a
    np.testing.assert_allclose(T.astype(np.float64) @ (A @ L0), np.broadcast_to(a, E.shape), rtol=2e-3)


def test_visibility_table_reads_the_prt_rays_by_direction():
    # a vertex on a plane's top with a wall beside it: rays toward the wall's side are blocked; the table says 1
    # above the open side and 0 toward the wall, and the directions it bins are self_transfer's own
    from kernels.shade import self_transfer
    from kernels.visibility import Occluder

    # a floor point at the origin, a wall x = 0.05 from y = 0 up to 2 m, 4 m wide: blocks nearly all of +x's half
    wall = np.array([[0.05, 0.0, -2.0], [0.05, 0.0, 2.0], [0.05, 2.0, 2.0], [0.05, 2.0, -2.0]])
    p = np.array([[0.0, 0.0, 0.0]])
    nrm = np.array([[0.0, 1.0, 0.0]])
    occ = Occluder(wall, np.array([[0, 1, 2], [0, 2, 3]], np.int32), "cpu")
    T, hit, _ = self_transfer(p, nrm, occ, 128, device="cpu")
    D = prt_directions(nrm, 128)[0]
    np.testing.assert_array_equal(hit[0] >= 0, (D[:, 0] > 0) & (D[:, 1] * 0.05 / np.maximum(D[:, 0], 1e-9) < 2.0)
                                  & (np.abs(D[:, 2]) * 0.05 / np.maximum(D[:, 0], 1e-9) < 2.0))
    tab = visibility_table(nrm, hit < 0)[0]
    from app.stages.object_drag import VIS_RES, _octa_cell

    toward_wall = _octa_cell(np.array([0.7, 0.3, 0.0]) / np.linalg.norm([0.7, 0.3, 0.0]), VIS_RES)
    away = _octa_cell(np.array([-0.7, 0.3, 0.0]) / np.linalg.norm([-0.7, 0.3, 0.0]), VIS_RES)
    assert tab[toward_wall] == 0.0 and tab[away] == 1.0


def test_yaw_of_reads_a_placed_pose_and_refuses_a_tilt():
    from app.placement import _rot_y

    M = np.eye(4)
    M[:3, :3] = _rot_y(37.0) * 1.7
    M[:3, 3] = [1, 2, 3]
    assert yaw_of(M) == pytest.approx(np.radians(37.0), abs=1e-12)
    c, s = np.cos(0.2), np.sin(0.2)
    M[:3, :3] = _rot_y(37.0) @ np.array([[1, 0, 0], [0, c, -s], [0, s, c]])  # tilted about x
    assert yaw_of(M) is None
    # the drag frame's canonical frame (frame_yaw): the yaw taken out of an upright pose, none of a tilted one (its
    # tables are made in the world's orientation, the tilt in the shape)
    assert frame_yaw(M) == 0.0
    M[:3, :3] = _rot_y(37.0) * 1.7
    assert frame_yaw(M) == pytest.approx(np.radians(37.0), abs=1e-12)


def test_fill_operator_is_fill_from_neighbours():
    # the sparse operator gives _fill_from_neighbours' values for any values: a subdivided sphere with a cap of
    # buried vertices (filled over rings), and with a far vertex left after one round (the known mean)
    from app.stages.object_drag import fill_operator
    from app.stages.object_shading import _fill_from_neighbours

    v, f = _icosphere(3)
    rng = np.random.default_rng(1)
    values = rng.random((len(v), 3))
    for missing, rounds in ((v[:, 1] > 0.6, 8), (v[:, 1] > -0.5, 1)):
        F = fill_operator(f, missing, len(v), rounds)
        np.testing.assert_allclose(F @ values, _fill_from_neighbours(values, f, missing, rounds), atol=1e-12)


def test_kernel_clock_counts_launches_once_and_only_on_its_thread():
    # app.glue.KernelClock: a launch on the clock's thread is counted; launches that app.runtime runs in the
    # pool are counted once, as the wait of the thread that made them (not twice, not per pooled thread);
    # an inner clock takes its launches from the outer one; no clock, no count
    from app.glue import KernelClock
    from app.runtime import run
    from kernels.formfactor import point_to_polygon

    pts = np.random.default_rng(0).random((20000, 3)) * [1, 0, 1]
    nrm = np.broadcast_to([0.0, 1.0, 0.0], pts.shape).copy()
    poly = np.array([[[0, 1, 0], [0, 1, 1], [1, 1, 1], [1, 1, 0]]], float)
    point_to_polygon(pts, nrm, poly, device="cpu")  # compiled before the clocks run
    calls = []

    with KernelClock() as outer:
        point_to_polygon(pts, nrm, poly, device="cpu")
        one = outer.seconds
        assert one > 0
        run([lambda: calls.append(point_to_polygon(pts, nrm, poly, device="cpu")) for _ in range(2)])
        assert len(calls) == 2 and outer.seconds > one
        before = outer.seconds
        with KernelClock() as inner:
            point_to_polygon(pts, nrm, poly, device="cpu")
        assert inner.seconds > 0 and outer.seconds == before
    after = outer.seconds
    point_to_polygon(pts, nrm, poly, device="cpu")
    assert outer.seconds == after


def test_frame_timer_splits_each_stage_into_kernels_and_glue():
    # app.glue.FrameTimer: each tick's stage time is the time since the tick before; its glue is that time less the
    # kernels launched within it (the stage with a launch has less glue than time, the one without has glue equal
    # to its time); the stages add up to the frame; after close the clock counts nothing more
    from app.glue import FrameTimer
    from kernels.formfactor import point_to_polygon

    pts = np.random.default_rng(1).random((20000, 3)) * [1, 0, 1]
    nrm = np.broadcast_to([0.0, 1.0, 0.0], pts.shape).copy()
    poly = np.array([[[0, 1, 0], [0, 1, 1], [1, 1, 1], [1, 1, 0]]], float)
    point_to_polygon(pts, nrm, poly, device="cpu")  # compiled before the timer runs
    ft = FrameTimer()
    point_to_polygon(pts, nrm, poly, device="cpu")
    t = ft.tick("kernel", ft.last)
    np.sort(pts, axis=0)  # numpy only
    ft.tick("numpy", t)
    frame_s = ft.close()
    k = ft.clock.seconds
    assert k > 0 and ft.glue["kernel"] == pytest.approx(ft.timings["kernel"] - k, abs=1e-9)
    assert ft.glue["numpy"] == pytest.approx(ft.timings["numpy"], abs=1e-9)
    assert sum(ft.timings.values()) == pytest.approx(frame_s, abs=1e-12)  # the ticks enclose the frame
    point_to_polygon(pts, nrm, poly, device="cpu")
    assert ft.clock.seconds == k


def test_gather_seen_kernel_matches_the_numpy_gather():
    # kernels.drag_gather against what object_drag computed before it, in numpy: point_to_polygon's (N,M) form
    # factors x the visibility table read at each (vertex, polygon)'s octahedral cell of the direction in the
    # object's frame x a weight, times the polygons' radiance; float64 both, so within 1e-12 relative (sum order)
    import warp as wp

    from app.stages.object_drag import VIS_RES, _octa_cell
    from kernels.buffers import Workspace
    from kernels.drag_gather import gather_seen
    from kernels.formfactor import point_to_polygon

    rng = np.random.default_rng(3)
    N, M = 200, 37
    pts = rng.uniform(-0.4, 0.4, (N, 3)) + [0.0, 0.5, 0.0]
    nrm = rng.normal(size=(N, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    # floor-like quads below and around the points, emitting upward (counter-clockwise seen from above)
    c = np.stack([rng.uniform(-1.5, 1.5, M), rng.uniform(-0.1, 0.05, M), rng.uniform(-1.5, 1.5, M)], 1)
    h = rng.uniform(0.05, 0.3, (M, 1, 1))
    polys = c[:, None] + h * np.array([[-1.0, 0, -1], [-1, 0, 1], [1, 0, 1], [1, 0, -1]])
    rad = rng.uniform(0.0, 2.0, (M, 3))
    vis = rng.uniform(0.0, 1.0, (N, VIS_RES ** 2)).astype(np.float32)
    w = rng.uniform(0.0, 1.0, (N, M))
    R = rot_y(0.83)
    rows = rng.permutation(N)
    F = point_to_polygon(pts, nrm, polys, device="cpu")
    own = np.take_along_axis(vis[rows], _octa_cell((polys.mean(1)[None] - pts[:, None]) @ R, VIS_RES), axis=1)
    ref = (F * own * w) @ rad
    assert (F > 0).mean() > 0.3  # the case exercises the sum
    got = gather_seen(pts, nrm, rows, wp.array(vis, dtype=wp.float32, device="cpu"), polys, rad, R, VIS_RES, "cpu",
                      Workspace(), weights=w)
    np.testing.assert_allclose(got, ref, rtol=1e-10, atol=1e-14)
    got = gather_seen(pts, nrm, rows, wp.array(vis, dtype=wp.float32, device="cpu"), polys, rad, R, VIS_RES, "cpu",
                      Workspace())
    np.testing.assert_allclose(got, (F * own) @ rad, rtol=1e-10, atol=1e-14)


def test_hit_average_into_a_kept_image_equals_a_fresh_one():
    # the drag frame's object radiance is written into a kept image (kernels.hit_average.FrameImage) whose last
    # rectangle is cleared, not the frame: two calls with rectangles that overlap in part give, each, exactly
    # the image a fresh call gives (zero outside its own rectangle, the hits' mean inside)
    from types import SimpleNamespace

    from kernels.buffers import Workspace
    from kernels.hit_average import FrameImage, hit_average

    rng = np.random.default_rng(5)
    H, W, s = 24, 32, 2
    faces = rng.integers(0, 40, (60, 3))
    L = rng.uniform(0.0, 3.0, (40, 3))

    def hits(rect):
        u0, v0, u1, v1 = rect
        n = (v1 - v0 + 1) * s * (u1 - u0 + 1) * s
        bary = rng.dirichlet(np.ones(3), n).astype(np.float32)
        return SimpleNamespace(H=H, W=W, s=s, rect=rect, tri=rng.integers(0, 60, n), bary=bary,
                               hit=rng.uniform(size=n) < 0.7)

    kept, ws = FrameImage(), Workspace()
    for rect in ((3, 2, 20, 15), (10, 8, 30, 22), (0, 0, 5, 4)):
        h = hits(rect)
        got = hit_average(h, faces, L, None, None, "cpu", ws, kept)
        ref = hit_average(h, faces, L, None, None, "cpu", Workspace())
        assert got is kept.image and np.abs(ref).sum() > 1.0
        np.testing.assert_array_equal(got, ref)
        # no add: the kept zero buffer gives the image an uploaded `add` of zeros gives, bit for bit
        zeros = hit_average(h, faces, L, np.zeros(len(h.hit)), np.zeros(3), "cpu", Workspace())
        np.testing.assert_array_equal(got, zeros)


@pytest.mark.parametrize("yaw", [0.0, 1.2])
def test_sun_per_hit_kernel_matches_the_numpy_it_replaced(yaw):
    # kernels.hit_average.SunAtHits (one launch) against the numpy per-hit sun block it replaced, on a sphere
    # shadowed by a smaller one above it (the object's own shadow crosses faces), lit through a skylight that
    # a part of the hits' rays toward the sun miss, with a room share varying per vertex: per hit equal within
    # 1e-12 (float64 both; the dot products' order differs), and the pixels' radiance within 1e-12 relative
    from types import SimpleNamespace

    from app.stages.object_drag import DragShape, SunAtHits, sun_per_hit_numpy
    from kernels.buffers import Workspace
    from kernels.hit_average import hit_average
    from kernels.sunshadow import exit_arrays
    from kernels.visibility import Occluder
    from lighting.sun import SunLight
    from recon.scene import Quad, Sun

    s_v, s_f = _icosphere(3)
    big, small = 0.3 * s_v, 0.12 * s_v + [0.05, 0.45, 0.02]
    v = np.concatenate([big, small]) + [1.0, 0.3, -0.5]
    n = np.concatenate([s_v, s_v])
    f = np.concatenate([s_f, s_f + len(s_v)]).astype(np.int32)
    R, mean = rot_y(yaw), v.mean(0)
    ds = DragShape.__new__(DragShape)  # only the sun map's parts: the local mesh, its occluder, the maps
    ds.local, ds._sun = (v - mean) @ R, {}
    ds.own = Occluder(ds.local, f, "cpu")
    d = np.array([0.35, 0.85, 0.25]) / np.linalg.norm([0.35, 0.85, 0.25])
    corners = np.array([[1.9, 2.5, -2.0], [3.0, 2.5, -2.0], [3.0, 2.5, 2.0], [1.9, 2.5, 2.0]])
    sky = Quad("sky", corners, np.array([0.0, -1.0, 0.0]), np.zeros(3), np.zeros(3), role="window", opening=True)
    sun = SunLight(Sun(d, 0.53, np.array([3.0, 2.5, 2.0]), np.zeros(3)), [sky], Occluder(None, None, "cpu"))
    room = np.random.default_rng(1).uniform(0.2, 1.0, len(v))

    rng = np.random.default_rng(7)
    H, W, s, rect = 40, 50, 2, (4, 3, 45, 36)
    m = (rect[3] - rect[1] + 1) * s * (rect[2] - rect[0] + 1) * s
    hits = SimpleNamespace(H=H, W=W, s=s, rect=rect, tri=rng.integers(0, len(f), m),
                           bary=rng.dirichlet(np.ones(3), m).astype(np.float32), hit=rng.uniform(size=m) < 0.8)
    ref, own, through = sun_per_hit_numpy(ds, sun, v, n, f, room, hits, mean, R)
    d_local = R.T @ d
    e1, e2, lo, texel, top, _ = ds.sun_map(d_local)
    at = SunAtHits(v, n, room, d, exit_arrays(sun.entries, "cpu"), mean, R, e1, e2, lo, texel, top,
                   d_local / np.linalg.norm(d_local), ds.sun_map_on(d_local, "cpu"), sun.tan_a)
    ws = Workspace()
    L = np.zeros((len(v), 3))
    got_px = hit_average(hits, f, L, at, np.ones(3), "cpu", ws)
    got = ws.buffer("add", m, __import__("warp").float64, "cpu").host[:m]
    # the case holds every branch: hits facing the sun inside and outside the skylight's beam, in the small
    # sphere's shadow, out of it and on its edge (a share between 0 and 1)
    assert 0.2 < through.mean() < 0.8 and (own == 0).sum() > 50 and (own == 1).sum() > 50
    assert ((own > 0.05) & (own < 0.95)).sum() > 20 and (ref > 0).sum() > 300
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-12)
    ref_px = hit_average(hits, f, L, ref, np.ones(3), "cpu", Workspace())
    np.testing.assert_allclose(got_px, ref_px, rtol=1e-12, atol=1e-15)


def test_disk_sh_kernel_matches_the_numpy_disk_sh():
    # kernels.disk_sh (one launch, a thread per probe) against object_drag.disk_sh (numpy) on 27 probes and 400
    # patches around them, some facing away (cos <= 0: none of their light), one probe close to a patch: float64
    # both, the sum over the patches in another order, so equal within 1e-12 of the largest coefficient
    from app.stages.object_drag import disk_sh
    from kernels.buffers import Workspace
    from kernels.disk_sh import disk_sh_launch

    rng = np.random.default_rng(3)
    g = np.linspace(-0.3, 0.3, 3)
    probes = np.stack(np.meshgrid(g, g + 0.5, g, indexing="ij"), -1).reshape(-1, 3)
    centres = rng.uniform(-3.0, 3.0, (400, 3))
    centres[0] = probes[4] + [0.0, 0.0, 0.01]
    normals = rng.normal(size=(400, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    areas = rng.uniform(0.01, 0.5, 400)
    rad = rng.uniform(-1.0, 2.0, (400, 3))
    ref = disk_sh(probes, centres, normals, areas, rad)
    ws = Workspace()
    got = disk_sh_launch(probes, centres, normals, areas, rad, "cpu", ws, 512)
    facing = -np.einsum("qmc,mc->qm", centres[None] - probes[:, None], normals) > 0
    assert 0.3 < facing.mean() < 0.7
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-12 * np.abs(ref).max())
    # a smaller second call into the same buffers: only its own patches
    np.testing.assert_allclose(disk_sh_launch(probes, centres[:50], normals[:50], areas[:50], rad[:50], "cpu", ws, 512),
                               disk_sh(probes, centres[:50], normals[:50], areas[:50], rad[:50]), rtol=0,
                               atol=1e-12 * np.abs(ref).max())
