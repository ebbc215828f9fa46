"""The sun's strength from a radiance that holds `bounces` bounces (lighting.sun._sun_strength; issue 34, refl108).

Analytic case: sun_room's own radiosity under its declared sun and albedo (known light: B^(4) of
lighting.sun.gather_with_sun, exactly the bounce model) stands in for the measured radiance. Each reflector's
radiance there is rho (sun + G B^(3)); gathering G B^(4) counts one bounce too many, so the old rule (bounces
None) reads the floor's reflectivity low and the sun too strong, and the bounce rule gets both back."""
from __future__ import annotations

import numpy as np
import pytest

from recon.scene import load_scene
from tests.conftest import shared_scene


def _lum(a):
    return float(np.asarray(a) @ np.array([0.2126, 0.7152, 0.0722]))


@pytest.fixture(scope="module")
def known_engine(tmp_path_factory):
    from app.engine import Engine, EngineParams

    s = load_scene(shared_scene("sun_room"), load_textures=False)
    e = Engine(s, EngineParams(patch_size=0.3, emitter_patch_size=0.2), cache_dir=tmp_path_factory.mktemp("c"),
               quiet=True)
    return s, e


def _strength(s, e, bounces):
    from lighting.sun import _sun_strength, openings

    d = s.sun.direction / np.linalg.norm(s.sun.direction)
    return _sun_strength(d, openings(s), e.scene_occ, e.pre.patches, e.pre.B[-1], e.pre.G_c, {}, bounces)


def test_strength_from_the_bounce_model_is_the_declared_sun(known_engine):
    s, e = known_engine
    assert len(e.pre.B) - 1 == 4
    old, _ = _strength(s, e, None)
    new, info = _strength(s, e, 4)
    r_old = _lum(old.irradiance) / _lum(s.sun.irradiance)
    r_new = _lum(new.irradiance) / _lum(s.sun.irradiance)
    print(f"strength ratio: gathered from B^(4) {r_old:.4f}, one bounce less {r_new:.4f}; "
          f"bounce ratio {info['bounce_ratio_median']:.4f}")
    assert r_old > 1.03  # one bounce too many: the sun too strong
    assert abs(r_new - 1.0) <= 0.02  # the fixed point of the exact model
    assert 0.7 < info["bounce_ratio_median"] < 1.0
    # the floor's reflectivity the strength used is the declared albedo (sun_room's floor: 0.5 0.45 0.35 ...)
    pm = e.pre.patches
    for q, rho in info["reflectivity_by_quad"].items():
        truth = np.median(pm.albedo[pm.quad == int(q)], axis=0)
        print(f"{s.quads[int(q)].name}: rho {np.round(rho, 4)} against {np.round(truth, 4)}")
        assert np.allclose(rho, truth, rtol=0.02), (q, rho, truth)


def test_one_bounce_or_none_keeps_the_rule_before(known_engine):
    s, e = known_engine
    old, _ = _strength(s, e, None)
    for b in (0, 1):
        same, _ = _strength(s, e, b)
        assert np.allclose(same.irradiance, old.irradiance, rtol=1e-12, atol=0)


def test_photo_lights_emitter_markers_take_their_radiance(known_engine):
    """Photo light marks its emitters with emission 1 (app.stages.precompute.fit_photo_light); the bounce model
    needs their radiance. SunSetup._emitting gives it back: the strength is then the captured convention's to
    1e-9, while the markers as radiance give another sun (docs/unseen.md "photo109")."""
    import copy

    from app.stages.sun import SunSetup
    from lighting.sun import _sun_strength, openings

    s, e = known_engine
    pm = copy.copy(e.pre.patches)
    pm.emission = np.where(np.any(e.pre.patches.emission > 0, axis=1)[:, None], 1.0, 0.0)
    d = s.sun.direction / np.linalg.norm(s.sun.direction)

    def strength(mesh):
        return _lum(_sun_strength(d, openings(s), e.scene_occ, mesh, e.pre.B[-1], e.pre.G_c, {}, 4)[0].irradiance)

    ref = strength(e.pre.patches)
    setup = SunSetup(s, "photo", "auto", e.scene_occ, pm, bounces=4)
    assert abs(strength(setup._emitting(pm, e.pre.B[-1])) / ref - 1) < 1e-9
    assert abs(strength(pm) / ref - 1) > 0.02  # the markers as radiance: a different sun
    assert SunSetup(s, "photo", "auto", e.scene_occ, pm)._emitting(pm, e.pre.B[-1]) is pm  # no bounces: as given


def test_photo_fit_under_a_sun_takes_the_engines_bounces_when_asked():
    """Engine._sun_bounces: PhotoPriors.sun_bounces gives the fit the engine's bounce count (the other priors
    kept); off (the default) the priors pass as given and the strength takes no bounce rule."""
    from types import SimpleNamespace

    from app.engine import Engine
    from lighting.photolight import PhotoPriors

    eng = SimpleNamespace(params=SimpleNamespace(bounces=4))
    assert Engine._sun_bounces(eng, None) == (None, 0)
    given = PhotoPriors(bounce_levels=3)
    assert Engine._sun_bounces(eng, given) == (given, 0)
    pr, levels = Engine._sun_bounces(eng, PhotoPriors(sun_bounces=True, wall_albedo=0.6))
    assert levels == 4 and pr.bounce_levels == 4 and pr.wall_albedo == 0.6


def test_mixed_levels_probe_one_bounce_less(known_engine):
    """The probe's ball is the probe camera's first reflection: the room in it holds one bounce less than the photo
    (lighting.radiance.measured_levels). Analytic case: sun_room's known radiosity ladder, the "measured" radiance
    B^(3) on every other patch (the probe's) and B^(4) on the rest (the photo's). With each patch's level the
    rule gets the declared sun and the floor's albedo back (2 %); taking every patch at B^(4) (levels None) reads
    the sun too strong; all patches at level 4 is exactly the rule without levels."""
    from lighting.radiance import PHOTO, PROBE, measured_levels
    from lighting.sun import _sun_strength, level_ratio, openings

    s, e = known_engine
    pm = e.pre.patches
    n = len(e.pre.B) - 1
    origin = np.where(np.arange(pm.n_patches) % 2 == 0, PROBE, PHOTO)
    levels = measured_levels(origin, n)
    assert set(np.unique(levels)) == {n - 1, n}
    B = np.where((levels == n - 1)[:, None], e.pre.B[n - 1], e.pre.B[n])
    d = s.sun.direction / np.linalg.norm(s.sun.direction)

    def strength(lv):
        sun, info = _sun_strength(d, openings(s), e.scene_occ, pm, B, e.pre.G_c, {}, n, lv)
        return _lum(sun.irradiance) / _lum(s.sun.irradiance), info

    r_lv, info = strength(levels)
    r_all, _ = strength(None)
    print(f"strength ratio: levels {r_lv:.4f}, all at B^({n}) {r_all:.4f}")
    assert abs(r_lv - 1.0) <= 0.02, r_lv
    assert r_all > r_lv + 0.02  # the probe's patches gathered one level too high: rho low, the sun strong
    for q, rho in info["reflectivity_by_quad"].items():
        truth = np.median(pm.albedo[pm.quad == int(q)], axis=0)
        assert np.allclose(rho, truth, rtol=0.02), (q, rho, truth)
    lv = [np.asarray(b, np.float64) for b in e.pre.B]
    G = np.asarray(e.pre.G_c, np.float64)
    np.testing.assert_allclose(level_ratio(G, lv, n, np.full(pm.n_patches, n)), level_ratio(G, lv, n, None),
                               rtol=1e-12, atol=0)
