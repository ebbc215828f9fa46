"""recon/camrefine.py edge_synth: each edge weighed by the synthetic's predicted grain scatter plus a
per-photo edge error tau measured from the edges' offsets (edge_tau).

Analytic: edge offsets drawn with a known tau on top of known per-edge noise variances give tau back;
offsets of noise alone give tau near 0; a tenth of the edges far off do not set tau. The analytic room of
tests/recon/test_camrefine.py (flat faces, pixel noise) refined from a perturbed camera with
edge_synth="tau" comes back as the default does."""
from __future__ import annotations

import numpy as np
import pytest

from recon.camrefine import edge_tau, refine_camera
from tests.recon.test_camrefine import PRIMS, _image_shift, _perturbed, noisy, synthetic  # noqa: F401 (fixtures)


def _offsets(rng, E: int, tau: float) -> tuple[np.ndarray, np.ndarray]:
    v = rng.uniform(0.01, 0.09, E)  # predicted variances of the edges' medians, px^2 (0.1-0.3 px)
    return rng.normal(0.0, np.sqrt(v + tau ** 2)), v


@pytest.mark.parametrize("tau", [0.15, 0.3, 0.6])
def test_edge_tau_recovers_a_known_edge_error(tau):
    """400 edges: tau comes back within 15 % (the median's standard error over 400 edges is ~6 %)."""
    m, v = _offsets(np.random.default_rng(3), 400, tau)
    assert edge_tau(m, v, 6) == pytest.approx(tau, rel=0.15)


@pytest.mark.parametrize("seed", [4, 5, 6, 7, 8, 9])
def test_edge_tau_of_noise_alone_is_small(seed):
    """Offsets the predicted noise explains: tau under the smallest predicted scatter (0.1 px), where the
    median over 400 edges leaves it (measured 0-0.07 px over these seeds)."""
    m, v = _offsets(np.random.default_rng(seed), 400, 0.0)
    assert 0.0 <= edge_tau(m, v, 6) < 0.1


def test_edge_tau_is_robust_to_a_few_edges_far_off():
    """A tenth of the edges 5 px off (furniture matched to the wrong edge) move tau = 0.3 px by under 25 %."""
    rng = np.random.default_rng(5)
    m, v = _offsets(rng, 400, 0.3)
    m[:40] = 5.0 * rng.choice([-1.0, 1.0], 40)
    assert edge_tau(m, v, 6) == pytest.approx(0.3, rel=0.25)


def test_edge_tau_dof_correction_raises_it_with_few_edges():
    """With E edges and p parameters the fit absorbs p of the offsets' degrees of freedom: the same offsets
    give a larger tau with more parameters (E / (E - p) inflation)."""
    m, v = _offsets(np.random.default_rng(6), 12, 0.3)
    assert edge_tau(m, v, 6) > edge_tau(m, v, 0)


def test_noisy_photo_perturbed_camera_comes_back_with_edge_synth(noisy):  # noqa: F811
    """In the grain, the camera 0.6 deg, 7.8 cm and 2 % of focal off returns to within 0.3 px of image
    motion with each edge weighed by its predicted scatter plus the measured tau (the default's bound in
    test_camrefine.test_noisy_photo_perturbed_camera_comes_back)."""
    truth, img = noisy
    r = refine_camera(_perturbed(truth), PRIMS, img, edge_synth="tau")
    assert r.accepted, r.reason
    assert _image_shift(r.camera, truth) < 0.3


def test_unknown_edge_synth_is_an_error(synthetic):  # noqa: F811
    truth, img = synthetic
    with pytest.raises(ValueError, match="edge_synth"):
        refine_camera(truth, PRIMS, img, edge_synth="grain")
