"""Captured light per bounce count (lighting.radiance.bounce_levels): the probe sees one bounce fewer than the
photo, and reflectivities reproduce each measurement at its own bounce count (issue 34, sun_103's spurious)."""
import numpy as np
import pytest

from lighting import radiance as R
from lighting.radiosity import gather

BOUNCES = 4


def _room(seed: int = 0, P: int = 40):
    """A closed room's transfers G (rows sum to 0.95: little escapes), albedos 0.3-0.8 and one
    source patch (a window) of radiance 10; patch 1 is lit by a source the mesh does not hold (a
    sunlit patch: radiance from B^(1) on)."""
    rng = np.random.default_rng(seed)
    G = rng.random((P, P))
    np.fill_diagonal(G, 0.0)
    G *= 0.95 / G.sum(1, keepdims=True)
    rho = rng.uniform(0.3, 0.8, (P, 3))
    rho[:2] = 0.0
    E0 = np.zeros((P, 3))
    E0[0] = 10.0
    return G, rho, E0


def _truth(G, rho, E0, sun):
    """[B^(0) .. B^(BOUNCES)] with the window from B^(0) and patch 1's light `sun` from B^(1) on."""
    B = [E0.copy()]
    E1 = E0.copy()
    E1[1] = sun
    for _ in range(BOUNCES):
        B.append(E1 + rho * (G @ B[-1]))
    return np.stack(B)


def test_reflectivity_and_levels_from_photo_and_probe_measurements():
    # half the patches measured by the photo (the light after 4 bounces), half through the probe
    # (after 3: its mirror ball is one reflection of every path): the reflectivity comes back to
    # 1e-6 and so does every level; the rule of build_radiance_mesh (L / G L, every measurement
    # taken as the converged light) reads it 6 % low (median) on this room
    G, rho, E0 = _room()
    P = len(G)
    B = _truth(G, rho, E0, sun=np.array([6.0, 5.0, 4.0]))
    probe = np.arange(P) % 2 == 1
    L = np.where(probe[:, None], B[BOUNCES - 1], B[BOUNCES])
    omega = np.where(probe, 0.01, 0.0)
    count = np.where(probe, 0, 100)
    emit = np.zeros(P, bool)
    emit[:2] = True
    rm = R.build_radiance_mesh(G, L, omega, L, count, emit)
    levels, got = R.bounce_levels(G, rm, sources=np.arange(P) == 0, bounces=BOUNCES, tol=1e-12, iterations=500)
    plain = ~emit
    np.testing.assert_allclose(got[plain], rho[plain], rtol=1e-6)
    np.testing.assert_allclose(levels, B, rtol=1e-6, atol=1e-9)
    old = np.median(rm.reflectivity[plain] / rho[plain])
    assert old < 0.96, old  # what the rule corrects: measured 0.942


def test_without_a_probe_every_patch_is_the_photos_level():
    # all patches seen by the photo: levels B^(k) of the truth, and B^(4) is the measurement itself
    G, rho, E0 = _room(seed=1)
    P = len(G)
    B = _truth(G, rho, E0, sun=np.zeros(3))
    emit = np.arange(P) < 1
    rm = R.build_radiance_mesh(G, B[BOUNCES], np.zeros(P), B[BOUNCES], np.full(P, 100), emit)
    levels, got = R.bounce_levels(G, rm, sources=emit, bounces=BOUNCES, tol=1e-12, iterations=500)
    np.testing.assert_allclose(levels[-1][~emit], B[BOUNCES][~emit], rtol=1e-9)
    np.testing.assert_allclose(got[~emit], rho[~emit], rtol=1e-6)


def test_too_few_bounces_is_an_error():
    G, rho, E0 = _room()
    rm = R.build_radiance_mesh(G, E0, np.zeros(len(G)), E0, np.full(len(G), 100), np.arange(len(G)) < 1)
    with pytest.raises(ValueError, match="bounces must be >= 2"):
        R.bounce_levels(G, rm, sources=np.arange(len(G)) < 1, bounces=1)


def test_sun_room_captured_reflectivity_and_levels_against_the_truth(shared_scenes_cache):
    # sun_room under captured light against its declared albedos and its known radiosity (the
    # declared sun joined, lighting.sun.gather_with_sun): per large surface (>= 40 measured unlit
    # patches), the median reflectivity / declared albedo within 4 % (measured 0.98-1.01; the rule
    # before, every measurement taken as the converged light, read 0.82-0.98: 0.84-0.87 on the
    # surfaces only the probe sees, one bounce short), and the light receivers gather, B[3], against
    # the truth's B^(3) within 4 % (measured 0.97-1.01; 0.97-1.16 before: the photo's surfaces gave
    # their 4-bounce light)
    from app.engine import Engine, EngineParams
    from lighting.sources import luminance
    from lighting.sun import SunLight, gather_with_sun, openings
    from recon.patches import build_patches
    from recon.scene import load_scene
    from tests.conftest import shared_scene

    d = shared_scene("sun_room")
    s = load_scene(d)
    e = Engine(s, EngineParams(lighting="captured"), cache_dir=shared_scenes_cache, quiet=True)
    truth = build_patches(load_scene(d), e.params.patch_size, e.params.emitter_patch_size)
    assert np.array_equal(truth.quad, e.pre.patches.quad)
    direct = SunLight(s.sun, openings(s), e.scene_occ).patch_irradiance(truth.corners, truth.normal,
                                                                       ~truth.is_emitter)
    known = gather_with_sun(e.pre.G_c, truth.albedo, truth.emission, direct, BOUNCES)
    unlit = ~truth.is_emitter & ~e.pre.emitter & (luminance(direct) == 0) & (e.pre.origin != R.GATHERED)
    rows = {}
    for q in np.unique(truth.quad[unlit]):
        m = unlit & (truth.quad == q)
        if m.sum() >= 40:
            rows[s.quads[q].name] = (np.median(luminance(e.pre.albedo[m]) / luminance(truth.albedo[m])),
                                     np.median(luminance(e.pre.B[BOUNCES - 1][m]) / luminance(known[BOUNCES - 1][m])))
    assert len(rows) >= 6, rows
    for name, (rho, gathered) in rows.items():
        assert abs(rho - 1) <= 0.04 and abs(gathered - 1) <= 0.04, (name, rho, gathered)
