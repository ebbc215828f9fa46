"""Tests for lighting/: camera response (tonemap), intensity transfers, source selection, radiosity.

References: the closed-form `gamma_s` response written in the shared scenes' scene.json, the
telescoping identity behind the intensity transfers (fig. 13), a brute-force prefix search for the
source set, and the furnace test B = E / (1 - rho) of a closed room with uniform albedo and emission.
"""
import json
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from app.cli import demo_scene_dir  # noqa: E402
from kernels.visibility import Occluder, transfer_matrix  # noqa: E402
from lighting.radiosity import gather  # noqa: E402
from lighting.sources import select_sources  # noqa: E402
from lighting.transfer import intensity_transfers  # noqa: E402
from recon.patches import build_patches  # noqa: E402
from recon.response import LUMA  # noqa: E402
from recon.scene import Quad, Scene, box_faces, load_scene  # noqa: E402
from tests.conftest import shared_scene  # noqa: E402

SCENES = ["demo", "window_room", "lamps_room"]


def _scene_dir(name: str) -> Path:
    return Path(demo_scene_dir()) if name == "demo" else shared_scene(name)


@pytest.fixture(scope="module", params=SCENES)
def scene_response(request):
    """(scene folder, CameraResponse) for each scene available here."""
    d = _scene_dir(request.param)
    return d, load_scene(d, load_textures=False).response


# ----------------------------------------------------------------------------------------------------------
# tonemap
# ----------------------------------------------------------------------------------------------------------

def test_response_round_trip_all_levels(scene_response):
    # T(T^-1(z)) == z for every 8-bit level of every channel (continuous and quantised)
    _, r = scene_response
    z = np.tile(np.arange(256, dtype=np.uint8)[:, None], (1, 3))
    L = r.to_radiance(z)
    assert L.shape == (256, 3) and np.isfinite(L).all()
    np.testing.assert_array_equal(r.to_pixels(L), z)
    np.testing.assert_allclose(r.to_levels(L), z.astype(float), atol=1e-9)
    # the float path (levels as numbers) inverts the same way
    np.testing.assert_allclose(r.to_levels(r.to_radiance(z.astype(np.float64))), z.astype(float), atol=1e-9)
    # T^-1 is increasing in the level, 0 maps to 0
    assert np.all(np.diff(L, axis=0) > 0) and np.all(L[0] == 0)


def test_response_monotone_and_invertible(scene_response):
    # f is non-decreasing on [0,1] (strictly where it matters) and f_inv(f(x)) recovers x
    _, r = scene_response
    x = np.tile(np.geomspace(1e-6, 1.0, 20001)[:, None], (1, 3))
    y = r.f(x)
    assert np.all(np.diff(y, axis=0) >= 0)
    assert np.all(np.diff(y, axis=0) > 0)  # no flat spots: the inverse is unique
    assert np.all(r.f(np.zeros((1, 3))) == 0) and np.allclose(r.f(np.ones((1, 3))), 1.0)
    np.testing.assert_allclose(r.f_inv(y), x, rtol=1e-9, atol=1e-15)
    # out-of-range input clips: over-exposure saturates, negative radiance is black
    assert np.allclose(r.f(np.full((1, 3), 7.0)), 1.0) and np.all(r.f(np.full((1, 3), -1.0)) == 0)


def test_saturated_pixel_finite(scene_response):
    # a saturated pixel (255) comes back as a finite positive radiance, the top of the range (a lower bound)
    _, r = scene_response
    L = r.to_radiance(np.full((2, 3), 255, np.uint8))
    assert np.isfinite(L).all() and np.all(L > 0)
    np.testing.assert_allclose(L * r.exposure_time, 1.0, rtol=1e-12)
    assert np.all(r.to_pixels(L) == 255) and np.all(r.to_pixels(10 * L) == 255)


def test_gamma_s_closed_form(scene_response):
    # the tables reproduce the closed-form gamma_s response of scene.json to 0.5/255 over X in [1e-4, 1]
    d, r = scene_response
    cr = json.loads((d / "scene.json").read_text())["camera_response"]
    if "gamma" not in cr:
        pytest.skip(f"{d.name}: scene.json gives no gamma_s parameters")
    assert cr["family"] == "gamma_s"
    g, w = np.asarray(cr["gamma"], float), np.asarray(cr["w"], float)
    X = np.concatenate([np.geomspace(1e-4, 1e-2, 5000), np.linspace(1e-2, 1.0, 50000)])
    X = np.tile(X[:, None], (1, 3))
    y = X ** (1.0 / g)
    f_ref = (1 - w) * y + w * (3 * y ** 2 - 2 * y ** 3)
    err = np.abs(r.f(X) - f_ref).max()
    assert err < 0.5 / 255, err * 255
    # and through the radiance interface with the exposure time
    np.testing.assert_allclose(r.to_levels(X / r.exposure_time), 255 * f_ref, atol=0.5)


# ----------------------------------------------------------------------------------------------------------
# intensity transfers (fig. 13)
# ----------------------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def demo_response():
    return load_scene(demo_scene_dir(), load_textures=False).response


def _transfers_case(rng, n, s, exposure):
    """Vertex radiance L_i and source transfers L_ij with sum_j L_ij <= L_i, spread over the response."""
    L_ij = rng.uniform(0.0, 1.0, (n, s, 3)) * rng.uniform(0.05, 1.0, (n, 1, 1))
    ambient = rng.uniform(0.0, 0.3, (n, 3))
    L_i = L_ij.sum(1) + ambient
    scale = rng.uniform(0.02, 0.95, (n, 1)) / exposure / L_i.max(1, keepdims=True)  # X in (0, 0.95]
    return L_i * scale, L_ij * scale[:, :, None]


@pytest.mark.parametrize("parity", [0, 1])
def test_transfers_exact_for_each_set(demo_response, parity):
    # occluding exactly the even (odd) sources: photo - sum S M equals T(L_i - sum L M) to 1e-9 levels
    T = demo_response.to_levels
    rng = np.random.default_rng(20 + parity)
    L_i, L_ij = _transfers_case(rng, 300, 7, demo_response.exposure_time)
    S = intensity_transfers(L_i, L_ij, T)
    assert S.shape == L_ij.shape and np.all(S >= 0)
    M = (np.arange(7) % 2 == parity).astype(float)
    got = T(L_i) - np.einsum("nsc,s->nc", S, M)
    ref = T(L_i - np.einsum("nsc,s->nc", L_ij, M))
    assert np.ptp(ref) > 50  # the case spans a good part of the response
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-9)
    # still exact when the set's transfers exceed the vertex radiance (the response clips at black)
    S2 = intensity_transfers(L_i, 1.5 * L_ij * L_i[:, None, :] / L_ij.sum(1)[:, None, :], T)
    got2 = T(L_i) - np.einsum("nsc,s->nc", S2, M)
    ref2 = T(np.maximum(L_i - np.einsum("nsc,s->nc", 1.5 * L_ij * L_i[:, None, :] / L_ij.sum(1)[:, None, :], M), 0))
    assert np.isfinite(S2).all() and np.all(S2 >= 0)
    np.testing.assert_allclose(got2, ref2, rtol=0, atol=1e-9)


def test_transfers_all_occluded_error_bounded(demo_response, record_property):
    # all sources occluded: the error is the second difference of T, bounded by the true darkening
    T = demo_response.to_levels
    rng = np.random.default_rng(30)
    L_i, L_ij = _transfers_case(rng, 300, 7, demo_response.exposure_time)
    S = intensity_transfers(L_i, L_ij, T)
    got = T(L_i) - S.sum(1)
    ref = T(L_i - L_ij.sum(1))
    err = got - ref
    assert np.isfinite(err).all()
    # never off by more than the true darkening itself
    assert np.all(np.abs(err) <= T(L_i) - ref + 1e-9)
    # closed form of the error: T(L-A) + T(L-B) - T(L) - T(L-A-B) (A, B: the two sets' summed transfers)
    A, B = L_ij[:, 0::2].sum(1), L_ij[:, 1::2].sum(1)
    np.testing.assert_allclose(err, T(L_i - A) + T(L_i - B) - T(L_i) - T(L_i - A - B), atol=1e-9)
    record_property("all_occluded_max_abs_err_levels", float(np.abs(err).max()))
    record_property("all_occluded_mean_abs_err_levels", float(np.abs(err).mean()))
    print(f"all sources occluded: max |err| {np.abs(err).max():.2f} levels, mean {np.abs(err).mean():.3f}")


def test_transfers_saturating_source(demo_response):
    # one source 1e5 x brighter than the rest saturates the response: S stays finite and >= 0, sets stay exact
    T = demo_response.to_levels
    rng = np.random.default_rng(40)
    n, s = 50, 6
    L_ij = rng.uniform(0.01, 0.1, (n, s, 3))
    L_ij[:, 0] *= 1e5
    L_i = L_ij.sum(1) + 0.05
    S = intensity_transfers(L_i, L_ij, T)
    assert np.isfinite(S).all() and np.all(S >= 0)
    assert np.all(T(L_i) == 255.0)
    assert np.all(S[:, 0::2].sum(1) <= 255 + 1e-9) and np.all(S[:, 1::2].sum(1) <= 255 + 1e-9)
    for parity in (0, 1):
        M = (np.arange(s) % 2 == parity).astype(float)
        got = T(L_i) - np.einsum("nsc,s->nc", S, M)
        ref = T(L_i - np.einsum("nsc,s->nc", L_ij, M))
        np.testing.assert_allclose(got, ref, atol=1e-9)
    # hiding the odd (dim) sources changes nothing visible under the saturating one
    assert np.all(S[:, 1::2] == 0.0)


def test_transfers_empty_source_list(demo_response):
    # no sources: an (N,0,3) array
    S = intensity_transfers(np.ones((4, 3)), np.zeros((4, 0, 3)), demo_response.to_levels)
    assert S.shape == (4, 0, 3)


# ----------------------------------------------------------------------------------------------------------
# source selection
# ----------------------------------------------------------------------------------------------------------

def _power(rad, area):
    return (rad * LUMA).sum(1) * area


def test_select_sources_all_and_prefix():
    # fraction 1 keeps all positive-power patches by decreasing power; 0.7 keeps the shortest prefix reaching 70%
    rng = np.random.default_rng(50)
    P = 400
    rad = rng.uniform(0.0, 3.0, (P, 3))
    rad[rng.uniform(size=P) < 0.2] = 0.0  # dark patches
    area = rng.uniform(0.01, 0.06, P)
    power = _power(rad, area)
    src = select_sources(rad, area, 1.0)
    assert set(src.tolist()) == set(np.flatnonzero(power > 0).tolist())
    assert np.all(np.diff(power[src]) <= 0)
    for frac in (0.7, 0.3, 0.95):
        sub = select_sources(rad, area, frac)
        np.testing.assert_array_equal(sub, src[:len(sub)])  # a prefix of the sorted list
        total = power.sum()
        assert power[sub].sum() >= frac * total
        assert power[sub[:-1]].sum() < frac * total  # one patch fewer does not reach the fraction
    # brute force: the smallest k whose k largest powers reach 70%
    p_sorted = np.sort(power)[::-1]
    k = next(k for k in range(1, P + 1) if p_sorted[:k].sum() >= 0.7 * power.sum())
    assert len(select_sources(rad, area, 0.7)) == k


def test_select_sources_dominant_emitter():
    # an emitter 1e5 x brighter than all walls: the 0.7 set holds only its patches
    rng = np.random.default_rng(51)
    rad = rng.uniform(0.1, 1.0, (300, 3))
    area = np.full(300, 0.0625)
    emitter = np.arange(100, 116)
    rad[emitter] = 1e5
    area[emitter] = 0.01
    sub = select_sources(rad, area, 0.7)
    assert 0 < len(sub) <= len(emitter) and set(sub.tolist()) <= set(emitter.tolist())
    assert len(sub) == int(np.ceil(0.7 * len(emitter) - 1e-9))  # equal patches: ceil(70%) of them


def test_select_sources_degenerate():
    # all-zero radiance gives an empty set; a fraction outside (0, 1] raises ValueError
    out = select_sources(np.zeros((10, 3)), np.ones(10), 0.7)
    assert out.shape == (0,)
    assert select_sources(np.zeros((10, 3)), np.ones(10), 1.0).shape == (0,)
    rad, area = np.ones((5, 3)), np.ones(5)
    for bad in (0.0, -0.2, 1.0001, 2.0, float("nan")):
        with pytest.raises(ValueError):
            select_sources(rad, area, bad)


# ----------------------------------------------------------------------------------------------------------
# radiosity
# ----------------------------------------------------------------------------------------------------------

def _box_room_G(lo, hi, device, patch_size=0.25):
    """Patch-centre transfer matrix of an empty closed box room (6 inward quads) via build_patches."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    quads = [Quad(f"q{axis}{side}", c, n, np.full(3, 0.5), np.zeros(3)) for axis, side, c, n in box_faces(lo, hi, True)]
    pm = build_patches(Scene("box", Path("."), None, quads, None, None, None, lo, hi), patch_size, patch_size)
    G = transfer_matrix(pm.centre, pm.normal, pm.corners, pm.normal, [Occluder(pm.vert_pos, pm.tris, device)], n_side=1,
                         device=device)
    np.fill_diagonal(G, 0.0)
    return pm, G


def test_radiosity_furnace(device):
    # closed box, uniform albedo rho and emission E: B converges to E / (1 - rho); iterates follow the series
    pm, G = _box_room_G([0, 0, 0], [2.0, 1.5, 1.0], device)
    P = pm.n_patches
    rho = np.array([0.3, 0.5, 0.8])
    E = np.array([1.0, 2.0, 0.5])
    Bs = gather(G, np.tile(rho, (P, 1)), np.tile(E, (P, 1)), 80)
    assert len(Bs) == 81 and Bs[0].shape == (P, 3)
    np.testing.assert_allclose(Bs[-1], np.broadcast_to(E / (1 - rho), (P, 3)), rtol=0.02)
    for k in (0, 1, 2, 4, 10):  # B^(k) = E (1 - rho^(k+1)) / (1 - rho): light paths of up to k bounces
        np.testing.assert_allclose(Bs[k], np.broadcast_to(E * (1 - rho ** (k + 1)) / (1 - rho), (P, 3)),
                                   rtol=0.02)
    # more bounces never remove light
    for k in range(80):
        assert np.all(Bs[k + 1] >= Bs[k] - 1e-12)
    # bounces=k is the prefix of a longer run
    short = gather(G, np.tile(rho, (P, 1)), np.tile(E, (P, 1)), 3)
    for a, b in zip(short, Bs):
        np.testing.assert_allclose(a, b, rtol=1e-12)


def test_radiosity_nonuniform_monotone_and_shape_check(device):
    # one emitting patch, random albedos: iterates are monotone and bounded by the furnace limit; bad shapes raise
    pm, G = _box_room_G([0, 0, 0], [2.0, 1.5, 1.0], device, patch_size=0.5)
    P = pm.n_patches
    rng = np.random.default_rng(60)
    albedo = rng.uniform(0.1, 0.9, (P, 3))
    E = np.zeros((P, 3))
    E[3] = [5.0, 4.0, 3.0]
    Bs = gather(G, albedo, E, 30)
    for k in range(30):
        assert np.all(Bs[k + 1] >= Bs[k] - 1e-12)
    assert np.all(Bs[-1] <= 5.0 / (1 - 0.9) + 1e-9)
    # after one bounce every other patch holds exactly albedo * G[:, 3] * E_3
    others = np.arange(P) != 3
    np.testing.assert_allclose(Bs[1][others], albedo[others] * G[others, 3:4].astype(float) * E[3], rtol=1e-12)
    with pytest.raises(ValueError):
        gather(G[:, :-1], albedo, E, 2)
    with pytest.raises(ValueError):
        gather(G, albedo[:-1], E[:-1], 2)
