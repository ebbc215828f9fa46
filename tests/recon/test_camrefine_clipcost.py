"""recon/camrefine.py: the focal recheck ranks its fits on the samples both cameras can measure (cam110).

cam108's recheck compared the accepted camera with the widened search's fits by the completed objective over every
common sample, a sample without a sub-pixel edge charged the profile's reach. A sample that a camera projects by a
clipped pixel has no profile (edgesnap refuses it): charging it the reach made a camera that moves a blown-out
window's edge, or a box edge beside a sunlit patch, 3 px off the clipped pixels (where the profile finds the glow's
ramp) look cheaper than the true one. Analytic: `_measurable` against the clipped block's own geometry; without
clipped pixels the new ranking is the old one to the bit. Rendered: clean sun_109, whose refined camera was
-0.78 % off in focal length, 4.0 cm and 5.8 px at the object."""
from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import numpy as np
import pytest

from recon import camrefine as cr
from tests.recon.test_camrefine import PRIMS, _look_at, _perturbed, _render

FULL = Path(os.environ.get("PHOTOAR_ROOMS_FULL", Path.home() / ".cache" / "photoar" / "rooms_full"))


@pytest.fixture(scope="module")
def room():
    cam = _look_at(np.array([3.2, 1.5, 4.4]), [1.0, 0.9, 0.5])
    faces = cr.room_faces(PRIMS)
    return cam, _render(cam), cr.room_edges(faces), cr._Occluder(faces)


def test_measurable_is_the_clipped_block_grown_by_the_profile_rule(room):
    """A block of the photo set to 255 (clipped): a sample is unmeasurable exactly where its rounded pixel lies within
    edgesnap's CLIP_RADIUS_PX (3 px, Chebyshev) of the block; every other sample of the room is measurable."""
    from recon.edgesnap import CLIP_RADIUS_PX

    cam, img, edges, occ = room
    img = img.copy()
    r0, r1, c0, c1 = 150, 260, 250, 400  # rows, columns of the block (inclusive start, exclusive end)
    img[r0:r1, c0:c1] = 255
    photo = cr.PhotoEdges(img)
    S = cr._sample_edges(cam, edges, occ)
    uv, _ = cr._project(cam, S)
    iu = np.rint(uv).astype(int)
    du = np.maximum(np.maximum(c0 - iu[:, 0], iu[:, 0] - (c1 - 1)), 0)
    dv = np.maximum(np.maximum(r0 - iu[:, 1], iu[:, 1] - (r1 - 1)), 0)
    expect = np.maximum(du, dv) > CLIP_RADIUS_PX
    got = cr._measurable(cam, S, photo)
    assert (~expect).sum() > 20 and expect.sum() > 200  # the block crosses room edges, most lie elsewhere
    np.testing.assert_array_equal(got, expect)


def test_without_clipped_pixels_the_ranking_is_the_old_one(room, monkeypatch):
    """The synthetic room has no clipped pixel (its faces are 40-224 levels): with the first search made to stop in a
    wrong basin (test_camrefine_focal.py's case), recheck_samples="measurable" (the default) and "all" (cam108's
    rule) return the same camera to the bit, the recheck's (within 0.2 % of the true focal length)."""
    truth, img, edges, occ = room
    start = dataclasses.replace(_perturbed(truth, deg=0.5, dc=(0.06, 0.0, -0.05), focal=0.965), focal_rel_sigma=0.015)
    decoy = cr.PhotoEdges(_render(_perturbed(truth, deg=0.0, dc=(0.04, 0.0, 0.0), focal=0.985)))
    orig = cr._search

    def wrong_basin(model, edges, occ, photo, lines, fine_stage):
        return orig(model, edges, occ, decoy, lines, fine_stage)

    monkeypatch.setattr(cr, "_search", wrong_basin)
    a = cr.refine_camera(start, PRIMS, img, None)
    b = cr.refine_camera(start, PRIMS, img, None, recheck_samples="all")
    assert a.accepted and a.start == "focal search", a.reason
    assert abs(a.camera.K[0, 0] / truth.K[0, 0] - 1) < 0.002
    np.testing.assert_array_equal(a.camera.K, b.camera.K)
    np.testing.assert_array_equal(a.camera.R, b.camera.R)
    np.testing.assert_array_equal(a.camera.t, b.camera.t)


def test_an_unknown_recheck_samples_mode_is_refused():
    """recheck_samples takes "measurable" or "all": anything else stops with the choices named, before any work."""
    cam = _look_at(np.array([3.2, 1.5, 4.4]), [1.0, 0.9, 0.5])
    img = np.zeros((cam.height, cam.width, 3), np.uint8)
    with pytest.raises(ValueError, match="recheck_samples: expected one of"):
        cr.refine_camera(cam, PRIMS, img, None, recheck_samples="found")


@pytest.mark.skipif(not (FULL / "sun_109" / "scene.json").exists(), reason="clean sun_109 not rendered")
def test_sun_109_calibrated_camera_comes_within_a_pixel():
    """Clean sun_109 (rooms_full; a blown-out window, a sunlit patch beside the box), the own-room flow's calibrated
    camera (-6.07 % of focal, 3.8 cm; 14.2 px at the object; calibrate's sigma 3.9 %): cam108's ranking kept the
    first fit at -0.78 %, 4.0 cm, 5.8 px (its completed objective about 3 below the truth's basin, by the window's and a
    box edge's samples the truth's camera projects by clipped pixels); now within 1 % of focal, 2 cm and 1 px
    (measured -0.50 %, 1.2 cm, 0.53 px), and the old ranking is still more than 4 px off."""
    from bench.bench_camrefine import calibrated_room

    room = calibrated_room(FULL / "sun_109")
    r = cr.refine_camera(room.cam, room.prims, room.img, room.cal.to_json())
    assert r.accepted, r.reason
    e = room.errors(r.camera)
    assert abs(e["focal_pct"]) < 1.0 and e["centre_cm"] < 2.0 and e["object_px"] < 1.0, e
    old = cr.refine_camera(room.cam, room.prims, room.img, room.cal.to_json(), recheck_samples="all")
    assert room.errors(old.camera)["object_px"] > 4.0
