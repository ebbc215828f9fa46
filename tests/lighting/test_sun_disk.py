"""The object's sun through an opening with the sun's disk (issue 34, branch sunobj109): the share of the disk
an opening passes (kernels.sunshadow._disk_share) against a quadrature over the disk, and sun_108's object under
known light, where the window edge's penumbra crosses the torus."""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from recon.scene import Quad, Sun


def _window_light(direction: np.ndarray, diameter_deg: float):
    """A SunLight through a 1 m x 1 m opening in the wall z = 0 (x 0..1, y 1..2; the room at z > 0), no room mesh."""
    from kernels.visibility import Occluder
    from lighting.sun import SunLight

    win = Quad("window", np.array([[0, 1, 0], [1, 1, 0], [1, 2, 0], [0, 2, 0]], float), np.array([0.0, 0.0, 1.0]),
               np.zeros(3), np.zeros(3), role="window", opening=True)
    d = direction / np.linalg.norm(direction)
    return SunLight(Sun(d, diameter_deg, np.full(3, 30.0), np.zeros(3)), [win], Occluder(None, None, "cpu")), win


def _disk_quadrature(light, win: Quad, points: np.ndarray, n_r: int = 60, n_phi: int = 120) -> np.ndarray:
    """Share (N,) of the sun's disk (directions within its angular radius of d, equal solid angle per sample)
    whose ray from each point leaves through the opening: a polar grid over the disk, midpoint rule."""
    d, a = light.d, light.sun.half_angle
    e1 = np.cross(d, [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(d, e1)
    r = np.sqrt((np.arange(n_r) + 0.5) / n_r) * np.tan(a)  # equal-area rings
    phi = (np.arange(n_phi) + 0.5) / n_phi * 2 * np.pi
    off = (r[:, None, None] * (np.cos(phi)[None, :, None] * e1 + np.sin(phi)[None, :, None] * e2)).reshape(-1, 3)
    dirs = d + off  # (K,3), not normalised: the plane's hit is the same
    c0, lo, hi = win.corners[0], win.corners[0][:2], win.corners[2][:2]
    t = -(points[:, None, 2] - c0[2]) / dirs[None, :, 2]  # to the plane z = 0
    h = points[:, None, :2] + t[..., None] * dirs[None, :, :2]
    inside = (t > 0) & np.all((h >= lo) & (h <= hi), axis=2)
    return inside.mean(1)


@pytest.mark.parametrize("direction, diameter", [((-0.4, 0.5, -0.77), 0.53), ((0.55, 0.3, -0.78), 0.53),
                                                 ((-0.2, 0.25, -0.95), 3.0)])
def test_disk_share_through_an_opening_matches_the_quadrature(direction, diameter):
    # points 1.5-3 m into the room on lines across the opening's left and bottom edges' shadows (an oblique sun: the
    # footprint is stretched across each edge by |e - n (d . e) / (d . n)|), far from the corners
    light, win = _window_light(np.array(direction, float), diameter)
    d = light.d
    pts = []
    for depth in (1.5, 3.0):
        w = depth * np.tan(light.sun.half_angle) * 3  # about 3 penumbra radii either side
        for edge_pt, across in (((0.0, 1.5, 0.0), (1, 0, 0)), ((0.5, 1.0, 0.0), (0, 1, 0))):
            s = np.linspace(-w, w, 41)
            on_edge = np.asarray(edge_pt) + s[:, None] * np.asarray(across, float)
            t = depth / -d[2]  # back along d from the opening's plane into the room
            pts.append(on_edge - t * d)
    pts = np.concatenate(pts)
    nrm = np.broadcast_to(d, pts.shape).copy()
    soft = light.visibility(pts, nrm, disk=True)  # cos = 1
    hard = light.visibility(pts, nrm)
    ref = _disk_quadrature(light, win, pts)
    assert np.abs(soft - ref).max() < 0.01  # the quadrature's own error is ~1e-3
    # the numpy twin (the drag frame's), at the points visibility casts from (1 mm along the normal)
    assert np.allclose(light.disk_through(pts + 1e-3 * nrm), soft, rtol=0, atol=1e-9)
    assert ((ref > 0.02) & (ref < 0.98)).sum() > 40  # the lines cross the penumbra
    assert np.all((hard == 0) | np.isclose(hard, 1.0, rtol=0, atol=1e-12))  # the centre's rule: 0 or cos (1)
    assert np.abs(hard - ref).max() > 0.4
    # across an edge the penumbra keeps the lit area: per line (41 points, the middle one on the edge, where the
    # centre's rule counts 1 and the disk 1/2) the soft and the hard profiles sum alike
    per_line = soft.reshape(-1, 41).sum(1) - hard.reshape(-1, 41).sum(1)
    assert np.abs(per_line).max() <= 0.55


def _centre_only(light):
    """The same sun and openings with the centre's rule (disk=False)."""
    from lighting.sun import SunLight

    return SunLight(light.sun, light.openings, light.occluder, disk=False)


def test_zero_disk_is_the_centre_ray():
    # tan_a 0 (an estimated sun: SunLight(disk=False)) is the centre's ray: cos where the ray from the point (moved
    # 1 mm along its normal) leaves through the opening (exit_distance), else 0
    light, _ = _window_light(np.array([-0.4, 0.5, -0.77]), 0.53)
    hard = _centre_only(light)
    assert hard.tan_a == 0.0 and light.tan_a == pytest.approx(np.tan(np.radians(0.265)))
    rng = np.random.default_rng(3)
    pts = np.c_[rng.uniform(-1, 2, 3000), rng.uniform(0, 3, 3000), rng.uniform(0.5, 3, 3000)]
    nrm = rng.normal(size=(3000, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    cos = np.maximum(nrm @ light.d, 0.0)
    ref = np.where(np.isfinite(light.exit_distance(pts + 1e-3 * nrm)), cos, 0.0)
    for vis in (light.visibility(pts, nrm), hard.visibility(pts, nrm, disk=True)):
        assert np.array_equal(vis > 0, ref > 0) and (ref > 0).sum() > 50
        assert np.allclose(vis, ref, rtol=0, atol=1e-12)


def test_sun_108_known_light_object_in_the_window_edge_penumbra():
    """sun_108 rendered clean (~/.cache/photoar/rooms_full, PHOTOAR_ROOMS_FULL; skipped where not rendered): the
    torus lies in the sunlit patch and the window's edge crosses it; with the centre ray's hard edge the penumbra
    band (truth 198-226 levels, ours 150-166) held 77 % of the squared error and rmse_object was 6.36 (bias -1.36);
    with the disk's share it is 3.30 (bias -0.32). Bound 4.0 (the issue's: 6)."""
    import dataclasses

    import cv2

    from app.composite import default_cache_dir
    from app.engine import Engine, EngineParams
    from lighting import metrics
    from recon.io import read_image_rgb
    from recon.scene import load_scene

    root = Path(os.environ.get("PHOTOAR_ROOMS_FULL", Path.home() / ".cache" / "photoar" / "rooms_full")) / "sun_108"
    if not (root / "truth.png").is_file():
        pytest.skip(f"{root} not rendered")
    scene = load_scene(root)
    engine = Engine(scene, EngineParams(lighting="known"), cache_dir=default_cache_dir(), quiet=True)
    fr = engine.render(scene.obj, dataclasses.replace(engine.frame_config(), passes=None))
    sc = metrics.score_regions(fr.pixels, scene.photo, read_image_rgb(root / "truth.png"),
                               cv2.imread(str(root / "truth_mask.png"), cv2.IMREAD_GRAYSCALE))
    assert sc["rmse_object"] < 4.0
    assert 0.9 <= sc["energy_ratio"] <= 1.1
