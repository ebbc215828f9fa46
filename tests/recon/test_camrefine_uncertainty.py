"""recon/camrefine.py: the refined camera's own uncertainty (camera_covariance, point_std_px, edge_jackknife).

Analytic: a known focal-length variance gives the image uncertainty a zoom predicts. Synthetic: the flat-grey
room of tests/recon/test_camrefine.py, clean and with pixel noise, refined from a perturbed camera: the fit's
covariance and the jackknife over its edges are there, and both bound the camera's actual error at a table-top
object."""
from __future__ import annotations

import numpy as np
import pytest

from recon.camrefine import _Model, edge_jackknife, point_std_px, refine_camera
from tests.recon.test_camrefine import PRIMS, _perturbed, noisy, synthetic  # noqa: F401

OBJECT = np.array([[1.2, 0.75, 1.0], [1.4, 0.95, 1.1], [1.0, 0.85, 0.9], [1.3, 0.75, 1.2]])  # on the table, m


def _object_px(a, b) -> float:
    return float(np.sqrt(np.mean(np.sum((a.project(OBJECT)[0] - b.project(OBJECT)[0]) ** 2, axis=1))))


def test_point_std_of_a_focal_variance(synthetic):  # noqa: F811
    """A 1 % (1 sigma) focal-length uncertainty moves a point d px from the principal point by 0.01 d px: the
    rms over points is 0.01 times their rms offset from the principal point (to 0.1 %)."""
    cam, _ = synthetic
    uv, _ = cam.project(OBJECT)
    d = np.linalg.norm(uv - cam.K[:2, 2], axis=1)
    cov = np.zeros((6, 6))
    cov[5, 5] = 0.01 ** 2
    assert point_std_px(_Model(cam).camera, np.zeros(6), cov, OBJECT) == pytest.approx(
        0.01 * np.sqrt(np.mean(d ** 2)), rel=1e-3)


def test_uncertainty_of_a_refined_camera(noisy):  # noqa: F811
    """In the grain (N(0, 20^2) levels), the camera refined from 0.6 deg, 7.8 cm and 2 % of focal off: the
    fit's covariance is positive definite, its 1-sigma at the object and the jackknife over the room's edges are
    finite, under 0.3 px (the edges are many and clean), and the actual error at the object is within 3 of the
    jackknife's sigmas; removing any one edge moves the object under 0.3 px (measured: own 0.06 px, jackknife
    0.15 px over 14 edges, one edge at most 0.08 px; actual 0.05 px)."""
    truth, img = noisy
    r = refine_camera(_perturbed(truth), PRIMS, img)
    assert r.accepted, r.reason
    assert np.all(np.linalg.eigvalsh(r.covariance) > 0)
    own = point_std_px(r.camera_at, np.asarray(r.x), r.covariance, OBJECT)
    jk, worst, edge = edge_jackknife(r, OBJECT)
    assert 0 < own < 0.3 and 0 < jk < 0.3, (own, jk)
    assert 0 <= worst < 0.3 and edge in set(int(e) for e in r.edge_ids)
    assert _object_px(r.camera, truth) <= 3 * jk + 0.05, (_object_px(r.camera, truth), jk)


def test_jackknife_needs_a_fit(synthetic):  # noqa: F811
    """A camera kept without a sub-pixel fit (a blank photo) has no jackknife: nan, not a number made up."""
    truth, img = synthetic
    r = refine_camera(truth, PRIMS, np.full_like(img, 128))
    assert not r.accepted
    jk, worst, edge = edge_jackknife(r, OBJECT)
    assert np.isnan(jk) and np.isnan(worst) and edge == -1
