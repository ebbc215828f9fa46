"""recon/camrefine.py with a known sun: the sunlit patch's outline and the openings' own edges
(recon/sunoutline.py) against the truth of the shared sun_room, and the outline's bias model on an
analytic step."""
from __future__ import annotations

import dataclasses

import numpy as np

from tests.conftest import shared_scene


def _sun_room():
    """The shared sun_room as the own-room flow has it: the tape room with its window marked as an opening,
    the scene's sun (what `scene --sun-direction` declares), the bracket's response, the object's points."""
    from bench.bench_camrefine import object_points
    from bench.own_room_flow import sunlit_room
    from recon.camera import Camera
    from recon.io import read_image_rgb

    root = shared_scene("sun_room")
    _, prims, _, _, sun, g = sunlit_room(root)
    return Camera.load(root / "scene.json"), read_image_rgb(root / "background.png"), prims, sun, g, \
        object_points(root)


def _object_px(cam, truth, P) -> float:
    return float(np.sqrt(np.mean(np.sum((cam.project(P)[0] - truth.project(P)[0]) ** 2, axis=1))))


def test_sun_room_outline_keeps_a_perturbed_camera_close():
    """The truth's camera of sun_room perturbed (focal +1.2 %, centre 7.8 cm, 0.44 deg: 14.2 px at the
    object) and refined on the room's edges alone comes within 0.44 px of the truth at the object (measured);
    with the declared sun (its outline and the opening's edges measured and fitted) within 0.6 px (measured
    0.46 px: no gain in this room, whose room edges already hold the camera), the focal length within 1 % and
    the centre within 4 cm (measured 0.81 %, 3.4 cm), every clip fraction f_c in (0, 1)."""
    from recon.camrefine import refine_camera

    truth, img, prims, sun, g, P = _sun_room()
    import cv2

    R = cv2.Rodrigues(np.array([0.004, -0.006, 0.003]))[0] @ truth.R
    C = truth.centre + np.array([0.06, 0.0, -0.05])
    K = truth.K.copy()
    K[0, 0] *= 1.012
    K[1, 1] *= 1.012
    cam = dataclasses.replace(truth, K=K, R=R, t=-R @ C)
    assert _object_px(cam, truth, P) > 10.0
    plain = refine_camera(cam, prims, img, None)
    r = refine_camera(cam, prims, img, None, sun=sun, response=g)
    assert plain.accepted and r.accepted, (plain.reason, r.reason)
    assert r.sun_edges and plain.sun_edges is None
    assert {e["kind"] for e in r.sun_edges} == {"outline", "opening"}, r.sun_edges
    assert all(0.0 < e["f_c"] < 1.0 for e in r.sun_edges), r.sun_edges
    assert _object_px(plain.camera, truth, P) < 0.6 and _object_px(r.camera, truth, P) < 0.6
    assert abs(r.camera.K[0, 0] / truth.K[0, 0] - 1) < 0.01
    assert np.linalg.norm(r.camera.centre - truth.centre) < 0.04


def test_sun_103_outline_brings_the_calibrated_camera_back():
    """sun_103, an unseen room (bench_unseen's, 2 x 24 spp; skipped where not rendered): calibrate's camera
    (+1.02 % focal, 22.8 cm, 7.3 px at the object) refined on the room's edges alone ends 1.74 px off at the
    object (-1.10 %, 7.7 cm: measured); with the sun typed in (the truth's direction, as `scene
    --sun-direction` takes it) and the bracket's response, within 0.6 px (measured 0.36 px), the focal length
    within 0.5 % and the centre within 2 cm (measured +0.19 %, 0.4 cm)."""
    import os
    from pathlib import Path

    import pytest

    root = Path(os.environ.get("PHOTOAR_ROOMS", Path.home() / ".cache" / "photoar" / "rooms")) / "sun_103"
    if not (root / "scene.json").is_file():
        pytest.skip(f"unseen room {root} not rendered (bench/bench_unseen.py --render)")
    from bench.bench_camrefine import object_points
    from bench.own_room_flow import sunlit_room
    from recon import assemble as asm
    from recon.camera import Camera
    from recon.camrefine import refine_camera
    from recon.io import read_image_rgb
    from recon.vanishing import calibrate_lines, lines_from_scene, parse_lines

    sc, prims, lo, hi, sun, g = sunlit_room(root)
    truth = Camera.load(root / "scene.json")
    img = read_image_rgb(root / "background.png")
    cal = calibrate_lines(parse_lines(lines_from_scene(sc)), truth.width, truth.height,
                          camera_height=truth.centre[1], image=img)
    cam = cal.camera
    if not asm.camera_in_room(cam, lo, hi):
        cam = asm.turned_about_y(cam)
    P = object_points(root)
    r = refine_camera(cam, prims, img, cal.to_json(), sun=sun, response=g)
    assert r.accepted and r.sun_edges, r.reason
    assert _object_px(r.camera, truth, P) < 0.6
    assert abs(r.camera.K[0, 0] / truth.K[0, 0] - 1) < 0.005
    assert np.linalg.norm(r.camera.centre - truth.centre) < 0.02


def test_no_sun_no_response_no_change():
    """Without a response (no bracket) the sun is not used: the refinement is the room's edges' alone,
    to the bit, and its report has no sun_edges (scene.json unchanged for rooms without a sun)."""
    from recon.camrefine import refine_camera

    truth, img, prims, sun, _, _ = _sun_room()
    cam = dataclasses.replace(truth, t=truth.t + np.array([0.02, 0.0, 0.01]))
    a = refine_camera(cam, prims, img, None)
    b = refine_camera(cam, prims, img, None, sun=sun, response=None)
    assert np.array_equal(a.camera.R, b.camera.R) and np.array_equal(a.camera.t, b.camera.t)
    assert np.array_equal(a.camera.K, b.camera.K)
    assert "sun_edges" not in a.to_json() and "sun_edges" not in b.to_json()


def test_bias_model_on_a_rendered_step():
    """measure_edges on a synthetic penumbra rendered by the model itself (a straight outline at a known
    sub-pixel position x0, the disk's half-width w = 0, 1 or 2.5 px, sun-lit 4x the clip level over a shade
    of 0.2: f_c = 0.21; 200 samples at random places along it): the geometric outline comes back within
    0.15 px (measured 0.00-0.14: the clipped boundary's pixel quantisation over the samples' phases) and
    f_c within 0.05 (measured 0.20-0.24); the raw boundary alone is 0.3-1.0 px off for w > 0."""
    from recon.sunoutline import _box_profiles, boundary_offset, measure_edges

    H = W = 100
    rest, lit = 0.2, 4.0
    rng = np.random.default_rng(1)
    for n in (np.array([0.6, 0.8]), np.array([0.28, 0.96])):
        for w in (0.0, 1.0, 2.5):
            x0 = 0.37
            v, u = np.mgrid[0:H, 0:W].astype(float)
            s = (u - 50) * n[0] + (v - 50) * n[1] - x0  # signed distance of each pixel centre, lit positive
            ss = np.arange(-12, 12, 0.01)
            frac = np.interp(s, ss, _box_profiles(np.array([w]), n[None], ss)[0])
            lin = (rest + (lit - rest) * frac).astype(np.float32)
            clip = (lin >= 1.0).astype(np.float32)
            t = np.sort(rng.uniform(-38, 38, 200))
            uv = np.array([50.0, 50.0]) + t[:, None] * np.array([-n[1], n[0]])
            nn = np.broadcast_to(n, uv.shape).copy()
            off, keep, info = measure_edges(uv, nn, np.full(len(uv), w), np.zeros(len(uv), int), clip, lin, "outline")
            assert keep.all()
            assert abs(info[0]["offset_px"] - x0) < 0.15, (n, w, info)
            assert abs(info[0]["f_c"] - (1 - rest) / (lit - rest)) < 0.05, (n, w, info)
            if w > 0:
                assert abs(np.mean(boundary_offset(clip, uv, nn)) - x0) > 0.3


def test_sun_107_true_camera_stays_with_the_sun_typed_in():
    """sun_107 rendered clean (~/.cache/photoar/rooms_full, PHOTOAR_ROOMS_FULL; skipped where not rendered), the
    truth's camera with the truth's sun typed in: the room's edges alone move it 0.45 px (< MIN_MOVE_PX, "already
    fits"), and the fit with the sunlit outline moves the room's edges about as little; the guard's move is
    measured on the room's edges alone, so the true camera is kept to the bit (before, the outline's own samples
    on the floor near the camera counted in it: 1.35 px, and the camera went -0.63 % in focal, 2.2 cm, 1.43 px at
    the object)."""
    import os
    from pathlib import Path

    import pytest

    root = Path(os.environ.get("PHOTOAR_ROOMS_FULL", Path.home() / ".cache" / "photoar" / "rooms_full")) / "sun_107"
    if not (root / "scene.json").is_file():
        pytest.skip(f"clean unseen room {root} not rendered")
    from bench.own_room_flow import benchmark_camera_json, sunlit_room
    from recon.camera import Camera
    from recon.camrefine import MIN_MOVE_PX, refine_camera
    from recon.io import read_image_rgb

    sc, prims, _, _, sun, g = sunlit_room(root)
    truth = Camera.load(root / "scene.json")
    img = read_image_rgb(root / "background.png")
    r = refine_camera(truth, prims, img, benchmark_camera_json(sc), sun=sun, response=g)
    assert not r.accepted and r.fits and r.moved_px < MIN_MOVE_PX, (r.reason, r.moved_px)
    assert np.array_equal(r.camera.K, truth.K) and np.array_equal(r.camera.R, truth.R)
    assert np.array_equal(r.camera.t, truth.t)
