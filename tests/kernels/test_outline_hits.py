"""kernels.sunshadow.OutlineHits (SunStage.refine_clipped_edges's rays): the adaptive form (4 corner rays a
pixel, all 4 x 4 only where they disagree) against every ray on every pixel, on a known polygon seen by a
pinhole camera, whose pixel coverage is also known exactly (the polygon's area in each pixel)."""
import numpy as np
import pytest
from types import SimpleNamespace

from kernels.sunshadow import OutlineHits, first_samples
from kernels.visibility import Occluder

F, CX, CY, Z = 100.0, 32.0, 32.0, 5.0  # focal length and principal point (px), the polygon's depth (m)
K = np.array([[F, 0.0, CX], [0.0, F, CY], [0.0, 0.0, 1.0]])
NO_SCENE = SimpleNamespace(id=0)  # no room in front of the object


def _lift(uv: np.ndarray) -> np.ndarray:
    """Pixel positions (N,2) -> points (N,3) m on the plane z = Z that the camera (at the origin, looking
    down +z, R = I) sees there."""
    return np.column_stack([(uv[:, 0] - CX) / F * Z, (uv[:, 1] - CY) / F * Z, np.full(len(uv), Z)])


def _polygon(uv: np.ndarray) -> Occluder:
    """A convex polygon (N,2) px in front of the camera as a triangle fan."""
    n = len(uv)
    return Occluder(_lift(uv), np.array([[0, i, i + 1] for i in range(1, n - 1)], np.int32), "cpu")


def _cast(occ, px, py, s=4, first=None):
    hits = OutlineHits("cpu")
    tri, bary, hit, full = hits(occ, NO_SCENE, np.zeros(3), np.linalg.inv(K), px, py, s, None, first)
    return tri, hit, full, hits.rays


def _outline(uv: np.ndarray, w: int = 64) -> tuple[np.ndarray, np.ndarray]:
    """The pixels (px, py) within 1.5 px of the polygon's boundary (the outline band)."""
    yy, xx = np.mgrid[0:w, 0:w]
    c = np.column_stack([xx.ravel(), yy.ravel()]).astype(np.float64)
    d = np.full(len(c), np.inf)
    for a, b in zip(uv, np.roll(uv, -1, 0)):
        t = np.clip(((c - a) @ (b - a)) / ((b - a) @ (b - a)), 0.0, 1.0)
        d = np.minimum(d, np.linalg.norm(c - (a + t[:, None] * (b - a)), axis=1))
    m = d < 1.5
    return xx.ravel()[m], yy.ravel()[m]


def test_first_samples_are_the_grids_corners_nested_in_it():
    o = first_samples(4)
    assert sorted(o.tolist()) == list(range(16))  # every sub-sample once: none cast twice
    assert sorted(o[:4].tolist()) == [0, 3, 12, 15]
    for s in range(1, 9):
        o = first_samples(s)
        assert sorted(o.tolist()) == list(range(s * s))
        if s >= 3:
            assert sorted(o[:4].tolist()) == sorted({0, s - 1, s * (s - 1), s * s - 1})
    assert first_samples(2).tolist() == [0, 1, 2, 3]  # s x s <= 4: every ray first


def _truth(uv: np.ndarray, px: np.ndarray, py: np.ndarray, n: int = 64) -> np.ndarray:
    """The convex polygon uv's area in each pixel (px, py), from n x n points a pixel."""
    g = (np.arange(n) + 0.5) / n
    gu = px[:, None, None] - 0.5 + g[None, None, :]
    gv = py[:, None, None] - 0.5 + g[None, :, None]
    inside = np.ones((len(px), n, n), bool)
    turn = np.sign((uv[1, 0] - uv[0, 0]) * (uv[2, 1] - uv[1, 1]) - (uv[1, 1] - uv[0, 1]) * (uv[2, 0] - uv[1, 0]))
    for a, b in zip(uv, np.roll(uv, -1, 0)):
        inside &= ((b[0] - a[0]) * (gv - a[1]) - (b[1] - a[1]) * (gu - a[0])) * turn >= 0
    return inside.mean((1, 2))


def _vertex_pixels(uv: np.ndarray, px: np.ndarray, py: np.ndarray) -> np.ndarray:
    """(len(px),) bool: the pixels holding one of the polygon's vertices."""
    return np.any((np.abs(px[:, None] - uv[None, :, 0]) <= 0.5) & (np.abs(py[:, None] - uv[None, :, 1]) <= 0.5), 1)


@pytest.mark.parametrize("uv", [np.array([[32, 8.3], [55.7, 32.0], [32, 55.7], [8.3, 32]]) + [0.21, -0.13],
                                np.array([[10.4, 50.2], [52.9, 44.6], [27.3, 9.8]]),
                                np.array([[9.8, 9.8], [54.3, 9.8], [54.3, 54.3], [9.8, 54.3]])])
def test_adaptive_coverage_matches_every_ray_on_a_polygon_outline(uv):
    # a rotated square, a triangle and an axis-aligned square (edges at many slopes and along the grid's
    # rows and columns): on every pixel that no vertex lies in (crossed by one straight edge or none) the
    # adaptive coverage is the full 4 x 4's exactly (the 4 corner rays span the hull of all 16: a line
    # that leaves them on one side leaves all 16 there; or the pixel got all 16, the same rays); on the
    # vertex pixels within 4/16
    occ = _polygon(uv)
    px, py = _outline(uv)
    tri4, hit4, full4, rays4 = _cast(occ, px, py, first=None)
    tri, hit, full, rays = _cast(occ, px, py, first=4)
    assert full4.all() and rays4 == 16 * len(px)
    c4 = hit4.reshape(-1, 16).mean(1)
    c = hit.reshape(-1, 16).sum(1) / np.where(full, 16, 4)
    vert = _vertex_pixels(uv, px, py)
    assert vert.sum() <= len(uv)
    assert np.array_equal(c[~vert], c4[~vert])
    assert np.abs(c - c4).max() <= 4 / 16
    # against the truth (the polygon's area in each pixel): the same error as 4 x 4, for 40-51 % of its
    # rays (the band is ~3 px wide and the edge crosses ~1 of them), fewer than 3 x 3's
    truth = _truth(uv, px, py)
    _, hit3, _, rays3 = _cast(occ, px, py, s=3, first=None)
    err4, err3, err = (np.abs(x - truth).mean() for x in (c4, hit3.reshape(-1, 9).mean(1), c))
    assert err <= err4 + 1e-3 and err < err3
    assert rays < 0.55 * rays4 and rays < rays3


def test_straight_edge_bound():
    # the reason: every line through the unit pixel (a fine sweep of angle and offset) that leaves the 4
    # first points on one side leaves all 16 there
    q = np.arange(16)
    p = np.column_stack([(q % 4 + 0.5) / 4, (q // 4 + 0.5) / 4])
    first = p[first_samples(4)[:4]]
    ang = np.linspace(0.0, 2 * np.pi, 720, endpoint=False)
    n = np.column_stack([np.cos(ang), np.sin(ang)])
    off = np.linspace(-1.5, 1.5, 1201)
    side_f = (first @ n.T)[:, :, None] > off  # (4, angles, offsets)
    side_p = (p @ n.T)[:, :, None] > off
    agree = side_f.all(0) | (~side_f).all(0)
    other = np.where(side_f[0], ~side_p, side_p).sum(0)
    assert agree.any() and (~agree).any() and other[agree].max() == 0


def test_a_pixel_whose_first_rays_disagree_gets_all_its_rays():
    # a vertical edge through pixel (20, 30)'s middle: its corner rays (columns 0 and 3) split 2/2, so all
    # 16 are cast, the same as the full 4 x 4 (coverage 1/2); a pixel wholly inside and one wholly outside
    # get their 4 corner rays only, the other 12 entries misses
    uv = np.array([[20.0, 10.0], [50.0, 10.0], [50.0, 50.0], [20.0, 50.0]])  # left edge at u = 19.5 + 0.5
    occ = _polygon(uv)
    px, py = np.array([20, 35, 5]), np.array([30, 30, 30])
    tri, hit, full, rays = _cast(occ, px, py, first=4)
    tri4, hit4, _, _ = _cast(occ, px, py, first=None)
    assert full.tolist() == [True, False, False]
    assert rays == 16 + 4 + 4
    assert np.array_equal(hit[:16], hit4[:16]) and np.array_equal(tri[:16], tri4[:16])
    assert hit[:16].sum() == 8  # columns 2 and 3 of the 4 x 4 lie right of u = 20
    first = first_samples(4)[:4]
    rest = np.setdiff1d(np.arange(16), first)
    inside, outside = hit[16:32], hit[32:48]
    assert inside[first].all() and not inside[rest].any() and (tri[16:32][rest] == -1).all()
    assert not outside.any()


def test_more_rays_than_the_largest_grid_are_refused():
    with pytest.raises(ValueError, match="at most"):
        _cast(_polygon(np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])), np.array([0]), np.array([0]), s=33)


def test_a_grid_of_no_samples_is_refused():
    with pytest.raises(ValueError, match="first_samples: s = 0, at least 1"):
        first_samples(0)


def test_outline_rays_and_sun_meshes_refuse_too_many_with_their_names():
    # the sample-order and sun-mesh limits OutlineHits shares with OutlineShade, SunVisibility and HitSun
    from kernels.sunshadow import HitSun, MAX_SUN_MESHES, OutlineShade, SunVisibility

    uv = np.array([[10.0, 10.0], [50.0, 10.0], [30.0, 50.0]])
    occ = _polygon(uv)
    px, py = np.array([30], np.int32), np.array([30], np.int32)
    d = np.array([0.0, 0.0, -1.0])
    shade = OutlineShade("cpu", [], d)
    mesh = (_lift(uv), np.tile(d, (3, 1)), np.array([[0, 1, 2]], np.int32))
    with pytest.raises(ValueError, match=r"OutlineShade: 33 x 33 rays a pixel, at most 1024"):
        shade(occ, NO_SCENE, np.zeros(3), np.linalg.inv(K), px, py, 33, mesh, np.zeros((3, 3)))
    too_many = [occ.id] * (MAX_SUN_MESHES + 1)
    with pytest.raises(ValueError, match=rf"OutlineShade: {MAX_SUN_MESHES + 1} meshes, at most {MAX_SUN_MESHES}"):
        shade(occ, NO_SCENE, np.zeros(3), np.linalg.inv(K), px, py, 4, mesh, np.zeros((3, 3)),
              sun=(np.zeros(3), np.ones(1, np.uint8), np.ones(3), np.ones(3), too_many, 1e-4))
    with pytest.raises(ValueError, match=rf"SunVisibility: {MAX_SUN_MESHES + 1} meshes"):
        SunVisibility("cpu", [], d)(np.zeros((1, 3)), np.tile(-d, (1, 1)), too_many, 1e-4)
    with pytest.raises(ValueError, match=rf"HitSun: {MAX_SUN_MESHES + 1} meshes"):
        HitSun("cpu", [], d)(mesh[0], mesh[1], mesh[2], np.zeros(3), np.ones(1, np.uint8), np.zeros(1, np.int32),
                             np.full((1, 3), 1 / 3), too_many, 1e-4)
