"""recon/camrefine.py: the camera refined against the photo's edges of the room.

Analytic: a room box with a table-sized box, each face a flat grey, rendered by ray casting (3x3
supersampled, so edges are exact to a tenth of a pixel) with a known camera; the camera perturbed by
a known amount comes back. Shared: calibrate's camera of window_room refined against the taped room
gets closer to the truth. Guards: a true camera stays put, a blank photo falls back."""
from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from recon import assemble as asm
from recon.camera import Camera
from recon.camrefine import _exclusive, _Occluder, _project, _sample_edges, refine_camera, room_edges, room_faces
from tests.conftest import shared_scene

LO, HI = np.array([0.0, 0.0, 0.0]), np.array([4.0, 2.6, 5.0])
PRIMS = asm.room_quads(LO, HI) + [
    {"name": "table", "type": "box", "center": [1.2, 0.375, 1.0], "size": [1.2, 0.75, 0.7], "role": "furniture"},
    {"name": "window", "type": "quad", "role": "window", "corners": [[4.0, 0.9, 1.5], [4.0, 0.9, 3.0],
                                                                     [4.0, 2.2, 3.0], [4.0, 2.2, 1.5]],
     "normal": [-1.0, 0.0, 0.0]},
]


def _look_at(C, target, f=520.0, w=640, h=480) -> Camera:
    z = np.asarray(target, float) - C
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 1.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    K = np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1.0]])
    return Camera(K, R, -R @ np.asarray(C, float), w, h)


def _render(cam: Camera) -> np.ndarray:
    """Each face a flat grey (40 + 23 k levels, face k), 3x3 supersampled, as an RGB uint8 photo."""
    import open3d as o3d

    faces = room_faces(PRIMS)
    occ = _Occluder(faces)
    C = cam.centre
    d = cam.pixel_rays(scale=3).reshape(-1, 3)
    rays = np.concatenate([np.broadcast_to(C, d.shape), d], 1).astype(np.float32)
    tri = occ.scene.cast_rays(o3d.core.Tensor(rays))["primitive_ids"].numpy().astype(np.int64)
    levels = 40.0 + 23.0 * ((np.arange(len(faces)) * 7) % 9)
    v = levels[tri // 2].reshape(cam.height, 3, cam.width, 3).mean(axis=(1, 3))
    return np.repeat(np.clip(np.rint(v), 0, 255).astype(np.uint8)[:, :, None], 3, axis=2)


def _perturbed(cam: Camera, deg=0.6, dc=(0.06, 0.0, -0.05), focal=1.02) -> Camera:
    R = cv2.Rodrigues(np.radians(deg) * np.array([0.6, 0.8, 0.0]).reshape(3, 1))[0] @ cam.R
    C = cam.centre + np.asarray(dc)
    K = cam.K.copy()
    K[0, 0] *= focal
    K[1, 1] *= focal
    return dataclasses.replace(cam, K=K, R=R, t=-R @ C)


def _image_shift(a: Camera, b: Camera) -> float:
    """rms px between the two cameras' images of the room's visible edge samples (of `b`)."""
    faces = room_faces(PRIMS)
    S = _sample_edges(b, room_edges(faces), _Occluder(faces))
    ua, _ = _project(a, S)
    ub, _ = _project(b, S)
    return float(np.sqrt(np.mean(np.sum((ua - ub) ** 2, axis=1))))


@pytest.fixture(scope="module")
def synthetic():
    cam = _look_at(np.array([3.2, 1.5, 4.4]), [1.0, 0.9, 0.5])
    return cam, _render(cam)


def test_synthetic_perturbed_camera_comes_back(synthetic):
    """A camera 0.6 deg, 7.8 cm and 2 % of focal off (about 9 px at the edges) returns to within
    0.3 % of focal, 1.5 cm and 0.25 px of image motion."""
    truth, img = synthetic
    start = _perturbed(truth)
    assert _image_shift(start, truth) > 5.0
    r = refine_camera(start, PRIMS, img)
    assert r.accepted, r.reason
    assert abs(r.camera.K[0, 0] / truth.K[0, 0] - 1) < 0.003
    assert np.linalg.norm(r.camera.centre - truth.centre) < 0.015
    assert r.camera.centre[1] == pytest.approx(start.centre[1], abs=1e-9)  # the height is held
    assert _image_shift(r.camera, truth) < 0.25
    assert r.n_edge_samples >= 200 and r.rms_edge_px < 0.3
    assert r.chamfer_after_px < r.chamfer_before_px


def test_synthetic_far_centre_and_principal_point_come_back(synthetic):
    """A centre 0.25 m off (beyond the ICP's first basin in a room of flat faces) and a principal point
    25 px off, as calibrate reports it from three vanishing points: the centre search and the freed
    principal point bring the camera back to within 0.5 px of image motion."""
    truth, img = synthetic
    start = _perturbed(truth, deg=0.3, dc=(0.2, 0.0, -0.15), focal=1.01)
    K = start.K.copy()
    K[0, 2] += 25.0
    K[1, 2] -= 10.0
    start = dataclasses.replace(start, K=K)
    assert _image_shift(start, truth) > 10.0
    r = refine_camera(start, PRIMS, img, {"principal_point_from": "three vanishing points"})
    assert r.accepted, r.reason
    assert _image_shift(r.camera, truth) < 0.5
    assert np.linalg.norm(r.camera.K[:2, 2] - truth.K[:2, 2]) < 2.0
    held = refine_camera(start, PRIMS, img)  # the principal point held: it stays where calibrate put it
    assert np.allclose(held.camera.K[:2, 2], start.K[:2, 2])


@pytest.fixture(scope="module")
def noisy(synthetic):
    """The synthetic photo with N(0, 20^2) levels of pixel noise, as a path-traced room at a few samples
    per pixel (sun_101, sun_103: 16-23 levels): the faces' steps of 23-46 levels are about one noise
    sigma per pixel."""
    truth, img = synthetic
    rng = np.random.default_rng(7)
    return truth, np.clip(np.rint(img + rng.normal(0.0, 20.0, img.shape[:2])[:, :, None]), 0, 255).astype(np.uint8)


@pytest.mark.parametrize("stage", ["profiles", "lines"])
def test_noisy_photo_perturbed_camera_comes_back(noisy, stage):
    """In the grain, the camera 0.6 deg, 7.8 cm and 2 % of focal off returns to within 0.3 px of image
    motion, 0.2 % of focal and 1.5 cm with either sub-pixel stage (measured: profiles 0.11 px, -0.03 %,
    0.4 cm; lines 0.16 px, -0.04 %, 0.6 cm)."""
    truth, img = noisy
    start = _perturbed(truth)
    r = refine_camera(start, PRIMS, img, fine_stage=stage)
    assert r.accepted, r.reason
    assert _image_shift(r.camera, truth) < 0.3
    assert abs(r.camera.K[0, 0] / truth.K[0, 0] - 1) < 0.002
    assert np.linalg.norm(r.camera.centre - truth.centre) < 0.015


@pytest.mark.parametrize("stage", ["profiles", "lines"])
def test_noisy_photo_true_camera_stays_put(noisy, stage):
    """In the grain the true camera still fits: the refinement would move the edges under 0.3 px
    (measured: 0.10 / 0.15 px), and the camera comes back as it was."""
    truth, img = noisy
    r = refine_camera(truth, PRIMS, img, fine_stage=stage)
    assert r.moved_px < 0.3, r.summary()
    assert not r.accepted and r.camera is truth


def test_unknown_fine_stage_is_an_error(synthetic):
    truth, img = synthetic
    with pytest.raises(ValueError, match="fine_stage"):
        refine_camera(truth, PRIMS, img, fine_stage="edges")


def test_exclusive_one_photo_edge_per_room_edge():
    """Two parallel vertical room edges 6 px apart (u = 100 and 106), samples 3 px apart along v; every
    sample matched to the photo edge at u = 101: only the nearer room edge keeps its matches. A crossing
    (horizontal) room edge nearer to the point does not count: only parallel edges compete."""
    v = np.arange(0.0, 30.0, 3.0)
    uv = np.concatenate([np.stack([np.full_like(v, 100.0), v], 1), np.stack([np.full_like(v, 106.0), v], 1),
                         np.stack([np.arange(90.0, 120.0, 3.0), np.full_like(v, 15.0)], 1)])
    n = np.concatenate([np.tile([1.0, 0.0], (20, 1)), np.tile([0.0, 1.0], (10, 1))])
    edge = np.repeat([0, 1, 2], 10)
    q = uv.copy()
    q[:20, 0] = 101.0
    keep = _exclusive(uv, n, edge, q)
    assert keep[:10].all() and not keep[10:20].any() and keep[20:].all()


def test_synthetic_true_camera_stays_put(synthetic):
    """The true camera already fits: the refinement moves the edges under 0.1 px, and the camera
    comes back as it was (`fits`)."""
    truth, img = synthetic
    r = refine_camera(truth, PRIMS, img)
    assert r.moved_px < 0.1
    assert r.fits and not r.accepted and r.camera is truth


def test_blank_photo_falls_back(synthetic):
    """No edges in the photo: the input camera comes back unchanged, with the reason."""
    truth, _ = synthetic
    start = _perturbed(truth)
    r = refine_camera(start, PRIMS, np.full((truth.height, truth.width, 3), 128, np.uint8))
    assert not r.accepted and not r.fits
    assert "too few of the room's edges" in r.reason
    assert r.camera is start


def test_photo_of_another_size_is_an_error(synthetic):
    truth, img = synthetic
    with pytest.raises(ValueError, match="640x480"):
        refine_camera(truth, PRIMS, img[::2, ::2])


def test_shared_window_room_calibrated_camera_gets_closer():
    """window_room: calibrate's camera (clicked lines snapped to the photo + the camera height) is
    +0.65 % in focal and 3.1 cm off; refined against the taped room (with the same clicked lines) it
    is within 0.45 % and 2 cm (measured +0.27 %, 1.4 cm), closer in both, and the true camera of the
    same room stays as it is."""
    from bench.own_room_flow import calibrated_from_lines

    truth, img, cal, prims, lo, hi = calibrated_from_lines(shared_scene("window_room"))
    cam = cal.camera
    r = refine_camera(cam, prims, img, cal.to_json())
    assert r.accepted, r.reason
    f0, f1 = (abs(c.K[0, 0] / truth.K[0, 0] - 1) for c in (cam, r.camera))
    c0, c1 = (np.linalg.norm(c.centre - truth.centre) for c in (cam, r.camera))
    assert f1 < f0 and f1 < 0.0045
    assert c1 < c0 and c1 < 0.02
    assert r.n_lines == 16 and r.rms_lines_px < 1.0
    t = refine_camera(truth, prims, img)
    assert t.camera is truth and t.fits, t.reason


def _with_pp(cam: Camera, du: float, dv: float) -> Camera:
    K = cam.K.copy()
    K[0, 2] += du
    K[1, 2] -= dv
    return dataclasses.replace(cam, K=K)


def test_principal_point_off_centre_is_freed():
    """A photo whose principal point really is off the image centre (+30, -20 px), calibrated with it
    from three vanishing points 9 px further off: held at the image centre no camera fits every edge,
    so the model selection (recon/campp.py) frees it, and it comes back within 1.5 px of the truth's,
    the image within 0.3 px. (At +18, -12 px the held fit's rotation absorbs it: freeing it dropped the
    chi-square by 13.5, under the 13.8 that frees it: the room's ~20 edges, each with the room model's
    0.3 px of error, cannot tell a 22 px principal point shift from a rotation.)"""
    truth = _with_pp(_look_at(np.array([3.2, 1.5, 4.4]), [1.0, 0.9, 0.5]), 30.0, 20.0)
    img = _render(truth)
    start = _with_pp(_perturbed(truth, deg=0.3, dc=(0.04, 0.0, -0.03), focal=1.01), 8.0, -5.0)
    r = refine_camera(start, PRIMS, img, {"principal_point_from": "three vanishing points"})
    assert r.accepted, r.reason
    assert r.principal_point.startswith("freed"), r.principal_point
    assert np.linalg.norm(r.camera.K[:2, 2] - truth.K[:2, 2]) < 1.5
    assert _image_shift(r.camera, truth) < 0.3


def test_noisy_photo_principal_point_at_centre_is_held(noisy):
    """In the grain, with the principal point at the image centre and calibrate's 25 px off (from three
    vanishing points): freeing it does not fit the edges significantly better, so it is held at the
    image centre, and the camera comes back within 0.3 px of image motion."""
    truth, img = noisy
    start = _with_pp(_perturbed(truth), 25.0, 10.0)
    r = refine_camera(start, PRIMS, img, {"principal_point_from": "three vanishing points"})
    assert r.accepted, r.reason
    assert r.principal_point.startswith("held"), r.principal_point
    np.testing.assert_allclose(r.camera.K[:2, 2], [(truth.width - 1) / 2, (truth.height - 1) / 2], atol=1e-9)
    assert _image_shift(r.camera, truth) < 0.3


def test_at_image_centre_keeps_the_principal_ray():
    """campp.at_image_centre: the direction seen at the old principal point stays at that pixel."""
    from recon.campp import at_image_centre

    cam = _with_pp(_look_at(np.array([3.2, 1.5, 4.4]), [1.0, 0.9, 0.5]), 30.0, -12.0)
    c = at_image_centre(cam)
    assert c.K[0, 2] == pytest.approx(319.5) and c.K[1, 2] == pytest.approx(239.5)
    X = cam.centre + 3.0 * (cam.R.T @ np.array([0.0, 0.0, 1.0]))  # on the old optical axis
    uv, _ = c.project(X[None])
    np.testing.assert_allclose(uv[0], cam.K[:2, 2], atol=1e-6)
    np.testing.assert_allclose(c.centre, cam.centre, atol=1e-12)


def test_bench_object_image_error_of_a_turned_camera(tmp_path):
    """bench_camrefine's object image error: 0 for the truth's own camera; a camera turned by 0.2 deg about
    its own vertical axis images a point on the principal ray f tan(0.2 deg) px off (1.815 px at f 520),
    within 0.01 px; the object's world points come from the scene's mesh through object_to_world."""
    import json

    from bench.bench_camrefine import camera_errors, object_points

    truth = _look_at(np.array([3.2, 1.5, 4.4]), [1.0, 0.9, 0.5])
    X = truth.centre + 3.0 * truth.R[2]  # on the principal ray, 3 m ahead
    (tmp_path / "object.ply").write_text("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                                         "property float z\nelement face 1\nproperty list uchar int vertex_indices\n"
                                         "end_header\n0 0 0\n0.001 0 0\n0 0.001 0\n3 0 1 2\n")
    M = np.eye(4)
    M[:3, 3] = X
    (tmp_path / "scene.json").write_text(json.dumps({"synthetic_object": {"mesh": "object.ply",
                                                                          "object_to_world": M.tolist()}}))
    P = object_points(tmp_path)
    assert np.allclose(P[0], X)
    S = _sample_edges(truth, room_edges(room_faces(PRIMS)), _Occluder(room_faces(PRIMS)))
    assert camera_errors(truth, truth, S, P)["object_px"] == pytest.approx(0.0, abs=1e-9)
    R = cv2.Rodrigues(np.radians(0.2) * truth.R[1].reshape(3, 1))[0]
    turned = dataclasses.replace(truth, R=truth.R @ R.T, t=-(truth.R @ R.T) @ truth.centre)
    e = camera_errors(turned, truth, S, P)
    assert e["object_px"] == pytest.approx(520.0 * np.tan(np.radians(0.2)), abs=0.01)
    assert e["rot_deg"] == pytest.approx(0.2, abs=1e-6)


def _clicked_lines_json(cam: Camera) -> dict:
    """A camera.json's "vanishing_points" with three segments per axis, as `cam` sees them (exact)."""
    world = {"x": [((0.5, 0.2, 0.4), (1.8, 0.2, 0.4)), ((0.5, 1.5, 0.3), (1.8, 1.5, 0.3)),
                   ((0.6, 2.0, 1.0), (1.9, 2.0, 1.0))],
             "y": [((0.5, 0.2, 0.4), (0.5, 1.8, 0.4)), ((1.8, 0.2, 0.6), (1.8, 1.8, 0.6)),
                   ((1.2, 0.2, 1.5), (1.2, 1.8, 1.5))],
             "z": [((0.5, 0.2, 0.3), (0.5, 0.2, 1.6)), ((1.8, 1.0, 0.3), (1.8, 1.0, 1.6)),
                   ((1.0, 2.0, 0.3), (1.0, 2.0, 1.6))]}
    vps = {}
    for a, segs in world.items():
        uv = [cam.project(np.array(seg, float))[0].ravel().tolist() for seg in segs]
        vps[a] = {"segments": uv, "inliers": [True] * 3, "snapped": [False] * 3}
    return {"vanishing_points": vps}


def test_failed_search_widened_over_the_focal_sigma(synthetic, monkeypatch):
    """When the first search's camera fails the guard on the clicked lines (here forced: it returns the
    input camera, 2 deg, 4 % of focal and 0.5 m off, about 45 px of image motion, which the exact
    clicked lines refuse), refine_camera searches again from centre-search starts with the focal length moved by
    -2..+2 of calibrate's sigma (camera.json's focal_rel_sigma) and takes the best the guard accepts,
    when it brings the room's edges closer by more than the room model's own edge error: the camera
    comes back within 0.3 px and 0.3 % of focal. Without a sigma there is no second search: the input
    is kept."""
    from recon import camrefine

    truth, img = synthetic
    start = _perturbed(truth, deg=2.0, dc=(0.35, 0.0, -0.35), focal=0.96)
    assert _image_shift(start, truth) > 30.0
    cj = _clicked_lines_json(truth)
    lines = camrefine.clicked_lines(cj)
    assert camrefine._lines_chi2(truth, lines)[0] < 1e-6
    chi2, lim = camrefine._lines_chi2(start, lines)
    assert chi2 > lim  # the clicked lines refuse the input camera
    monkeypatch.setattr(camrefine, "_search", lambda *a, **k: None)
    kept = refine_camera(start, PRIMS, img, cj)
    assert not kept.accepted and kept.camera is start
    r = refine_camera(dataclasses.replace(start, focal_rel_sigma=0.02), PRIMS, img, cj)
    assert r.accepted, r.reason
    assert r.start == "focal search"
    assert _image_shift(r.camera, truth) < 0.3
    assert abs(r.camera.K[0, 0] / truth.K[0, 0] - 1) < 0.003
