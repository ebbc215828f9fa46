"""recon/camrefine.py: an accepted camera searched again over the focal length and ranked by the fit's own
completed objective (cam108).

Analytic: the synthetic room of test_camrefine.py (flat grey faces, ray cast 3x3 supersampled, a known camera).
The completed objective (_fit_cost) along the focal length, every other parameter re-fitted, is lowest at the
truth; a camera that has pushed edges beyond the profile's reach pays for them there, where the fit's own cost
(found samples only) does not. The first search is made to end in a wrong basin (its fit made against a photo of
the same room seen 1.5 % off in focal length, as window_107's first fit stopped 0.9 % off): the old rule keeps
that camera, the focal recheck comes back within 0.2 % of focal. Rendered: clean window_107, whose refined
camera was 0.90 % off in focal length, 3.3 cm and 4.5 px at the object, now comes within 0.5 % and 1 px."""
from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import numpy as np
import pytest

from recon import camrefine as cr
from tests.recon.test_camrefine import PRIMS, _image_shift, _look_at, _perturbed, _render

FULL = Path(os.environ.get("PHOTOAR_ROOMS_FULL", Path.home() / ".cache" / "photoar" / "rooms_full"))


class _FixedFocal(cr._Model):
    """The 6-parameter model with the focal length held at exp(lf) x the base camera's (5 free parameters)."""

    def __init__(self, cam, lf: float):
        super().__init__(cam)
        self.lf, self.n = lf, 5

    def camera(self, x):
        return super().camera(np.r_[np.asarray(x, float)[:5], self.lf])


@pytest.fixture(scope="module")
def room():
    cam = _look_at(np.array([3.2, 1.5, 4.4]), [1.0, 0.9, 0.5])
    faces = cr.room_faces(PRIMS)
    return cam, _render(cam), cr.room_edges(faces), cr._Occluder(faces)


def test_completed_objective_lowest_at_the_true_focal(room):
    """Focal length held at -1.5, -0.75, 0, +0.75, +1.5 % of the truth's, rotation and centre re-fitted (ICP at 4, 2
    px, then the profile stage, from the truth's pose): the completed objective is lowest at 0 % and rises on either
    side, by at least 5 % of its value 1.5 % away (measured 489.5, 457.0, 448.0, 465.4, 503.9; most of it the
    constant cost of samples no camera finds an edge for)."""
    cam, img, edges, occ = room
    photo = cr.PhotoEdges(img)
    lines = ({}, {})
    cams = {}
    for fp in (-1.5, -0.75, 0.0, 0.75, 1.5):
        m = _FixedFocal(cam, float(np.log1p(fp / 100)))
        f = cr._fit(m, np.zeros(5), (4.0, 2.0), edges, occ, photo, lines)
        assert f.res is not None
        cams[fp] = m.camera(f.x)
    S = cr._union(*[cr._sample_edges(c, edges, occ) for c in cams.values()])
    cost = {fp: cr._fit_cost(c, S, photo, lines) for fp, c in cams.items()}
    msg = ", ".join(f"{fp:+.2f} %: {c:.1f}" for fp, c in cost.items())
    assert min(cost, key=cost.get) == 0.0, msg
    assert cost[-1.5] > cost[-0.75] > cost[0.0] < cost[0.75] < cost[1.5], msg
    assert min(cost[-1.5], cost[1.5]) > 1.05 * cost[0.0], msg


def test_unfound_samples_are_counted(room):
    """A sample whose edge lies beyond the profile's reach (a camera 2 % off in focal length and 5 cm off: the far
    edges move 3-6 px) costs the reach, PROFILE_HALF_PX: the completed objective of that camera is above the
    truth's, and at least what its unfound samples alone cost."""
    cam, img, edges, occ = room
    photo = cr.PhotoEdges(img)
    off = _perturbed(cam, deg=0.0, dc=(0.05, 0.0, 0.0), focal=1.02)
    S = cr._sample_edges(cam, edges, occ)
    uv, n = cr._project(off, S)
    _, ok, _ = cr._fine_edges(photo, uv, n, S.edge)
    a = cr._edge_weights(S, cr.FINE_SIGMA_PX)
    floor = float(np.sum(a[~ok]) * cr.ROBUST_SIGMAS ** 2
                  * np.log1p((cr.PROFILE_HALF_PX / cr.FINE_SIGMA_PX / cr.ROBUST_SIGMAS) ** 2))
    assert (~ok).sum() > 50
    c_off, c_true = cr._fit_cost(off, S, photo, ({}, {})), cr._fit_cost(cam, S, photo, ({}, {}))
    assert c_off >= floor - 1e-9 and c_off > 2 * c_true, (c_off, c_true, floor)


def test_wrong_basin_rechecked_over_the_focal_length(room, monkeypatch):
    """calibrate's camera 3.5 % off in focal length (sigma 1.5 %), 8 cm and 0.5 deg off; the first search made to stop
    in a wrong basin (fitted to a photo of the room seen by a camera 1.5 % off in focal length and 4 cm off: the
    guard accepts it, the fit having moved the focal length 2 % > sigma). With focal_search="off" (the rule before)
    that camera is kept, more than 1 % off in focal (measured -1.64 %, 5.2 px); by default the widened search's
    fits are ranked by the completed objective and the truth's comes back within 0.2 % of focal and 0.3 px
    (measured -0.11 %, 0.07 px)."""
    truth, img, edges, occ = room
    start = dataclasses.replace(_perturbed(truth, deg=0.5, dc=(0.06, 0.0, -0.05), focal=0.965), focal_rel_sigma=0.015)
    decoy_cam = _perturbed(truth, deg=0.0, dc=(0.04, 0.0, 0.0), focal=0.985)
    decoy = cr.PhotoEdges(_render(decoy_cam))
    orig = cr._search

    def wrong_basin(model, edges, occ, photo, lines, fine_stage):
        return orig(model, edges, occ, decoy, lines, fine_stage)

    monkeypatch.setattr(cr, "_search", wrong_basin)
    old = cr.refine_camera(start, PRIMS, img, None, focal_search="off")
    assert old.accepted, old.reason
    assert abs(old.camera.K[0, 0] / truth.K[0, 0] - 1) > 0.01
    new = cr.refine_camera(start, PRIMS, img, None)
    assert new.accepted, new.reason
    assert new.start == "focal search"
    assert abs(new.camera.K[0, 0] / truth.K[0, 0] - 1) < 0.002
    assert _image_shift(new.camera, truth) < 0.3


@pytest.mark.skipif(not (FULL / "window_107" / "scene.json").exists(), reason="clean window_107 not rendered")
def test_window_107_calibrated_camera_comes_within_half_a_percent():
    """Clean window_107 (rooms_full), the own-room flow's calibrated camera (-3.25 % of focal, 8.8 cm; 8.7 px at the
    object): refined before cam108 to -0.90 %, 3.3 cm, 4.5 px; now within 0.5 % of focal, 2 cm and 1 px
    (measured -0.24 %, 0.7 cm, 0.37 px)."""
    from bench.bench_camrefine import calibrated_room

    room = calibrated_room(FULL / "window_107")
    r = cr.refine_camera(room.cam, room.prims, room.img, room.cal.to_json())
    assert r.accepted, r.reason
    e = room.errors(r.camera)
    assert abs(e["focal_pct"]) < 0.5 and e["centre_cm"] < 2.0 and e["object_px"] < 1.0, e
