"""recon/camrefine.py: the edges' own errors as random effects (refine_camera(edge_errors=...)) and the fit's
own uncertainty of the camera (camera_covariance, point_std_px).

Analytic: residuals drawn with a known sample noise and known per-edge offsets and tilts give back those
variance components; a known focal-length variance gives the image uncertainty a zoom predicts. Synthetic:
the flat-grey room of tests/recon/test_camrefine.py with pixel noise, refined with the random-effect fit."""
from __future__ import annotations

import numpy as np
import pytest

from recon.camrefine import (_edge_basis, _Model, _Samples, _variance_components, point_std_px, refine_camera)
from tests.recon.test_camrefine import PRIMS, _image_shift, _look_at, _perturbed, noisy, synthetic  # noqa: F401


def _draw(rng, E=60, n=40, s=0.3, tau=(0.5, 0.2)):
    """Residuals of E edges of n samples: each edge's offset ~ N(0, tau0^2) and tilt ~ N(0, tau1^2) (px at its
    ends), each sample's noise ~ N(0, s^2); the samples lie evenly along a 1 m edge."""
    inv = np.repeat(np.arange(E), n)
    t = np.tile(np.linspace(0.0, 1.0, n), E)
    X = np.stack([t, np.zeros_like(t), np.zeros_like(t)], 1)
    S = _Samples(X, np.tile([1.0, 0.0, 0.0], (len(t), 1)), inv)
    T = _edge_basis(S, inv, tilt=True)
    b = np.stack([rng.normal(0, tau[0], E), rng.normal(0, tau[1], E)], 1)
    raw = np.sum(b[inv] * T, axis=1) + rng.normal(0, s, len(inv))
    return S, inv, T, b, raw


def test_variance_components_recover_noise_offset_and_tilt():
    """s = 0.3 px, tau = 0.5 px (offset) and 0.2 px (tilt) over 60 edges of 40 samples come back within 20 %
    (the robust median over 60 edges has a standard error of about 15 %), the edges' errors taken as known."""
    S, inv, T, b, raw = _draw(np.random.default_rng(3))
    s, tau = _variance_components(raw, inv, b, 0, per_edge=False, T=T)
    assert s == pytest.approx(0.3, rel=0.1)
    assert tau[0] == pytest.approx(0.5, rel=0.2)
    assert tau[1] == pytest.approx(0.2, rel=0.2)
    se, _ = _variance_components(raw, inv, b, 0, per_edge=True, T=T)
    assert se.shape == (60,) and np.all(np.abs(se - 0.3) < 0.15)


def test_variance_components_without_edge_errors_floor():
    """No edge error at all: tau falls to its floor, the precision of the best-measured edge's coefficient
    (s / sqrt(sum T^2) over 40 samples: 0.3 / sqrt(40) = 0.047 px for the offset), not to 0."""
    S, inv, T, b, raw = _draw(np.random.default_rng(5), tau=(0.0, 0.0))
    s, tau = _variance_components(raw, inv, np.zeros_like(b), 0, T=T)
    assert tau[0] == pytest.approx(s / np.sqrt(40), rel=1e-6)
    assert tau[1] < 0.15


def test_edge_basis_centred_and_scaled():
    """The tilt's basis runs -1 .. 1 along each edge, centred on the edge's samples."""
    inv = np.array([0, 0, 0, 1, 1])
    X = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [5, 0, 0], [6, 0, 0]])
    T = _edge_basis(_Samples(X, np.tile([1.0, 0, 0], (5, 1)), inv), inv, tilt=True)
    assert np.allclose(T[:, 0], 1.0)
    assert np.allclose(T[:, 1], [-1, 0, 1, -1, 1])


def test_point_std_of_a_focal_variance(synthetic):
    """A 1 % (1 sigma) focal-length uncertainty moves a point d px from the principal point by 0.01 d px: the
    rms over points at known offsets is 0.01 times their rms offset."""
    cam, _ = synthetic
    m = _Model(cam)
    P = np.array([[1.0, 0.9, 0.5], [2.0, 1.2, 1.0], [0.5, 0.3, 1.5]])
    uv, _ = cam.project(P)
    d = np.linalg.norm(uv - cam.K[:2, 2], axis=1)
    cov = np.zeros((6, 6))
    cov[5, 5] = 0.01 ** 2
    assert point_std_px(m.camera, np.zeros(6), cov, P) == pytest.approx(0.01 * np.sqrt(np.mean(d ** 2)), rel=1e-3)


def test_random_tilt_noisy_photo_perturbed_camera_comes_back(noisy):  # noqa: F811
    """The random-effect fit (offset and tilt per edge) in the grain brings the camera 0.6 deg, 7.8 cm and 2 %
    of focal off back within 0.3 px of image motion, as the default does, and says what it measured; its own
    uncertainty is there and positive."""
    truth, img = noisy
    r = refine_camera(_perturbed(truth), PRIMS, img, edge_errors="random_tilt")
    assert r.accepted, r.reason
    assert _image_shift(r.camera, truth) < 0.3
    assert "random effect per edge" in r.edge_errors
    assert r.covariance is not None and np.all(np.diag(r.covariance) > 0)


def test_unknown_edge_errors_is_an_error(synthetic):  # noqa: F811
    truth, img = synthetic
    with pytest.raises(ValueError, match="edge_errors"):
        refine_camera(truth, PRIMS, img, edge_errors="fixed")
