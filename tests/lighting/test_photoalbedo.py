"""The walls' albedo from the interreflections, and unseen patches reflecting as their surface
(lighting.photoalbedo, photo light, issue 34).

Analytic: the closed box room of test_photolight (a window, its photo rendered from a converged
radiosity through sRGB, the window clipped), with walls brighter than the 0.55 prior or an unseen
ceiling brighter than the 0.5 unseen prior.
"""
import json

import numpy as np
import pytest

from lighting import photolight as PL
from tests.lighting.test_photolight import WINDOW, _box_room, _fit, _photo, _solved


@pytest.fixture(scope="module")
def bright_walls():
    """Walls 0.7 (the prior says 0.55), floor (0.35, 0.3, 0.25)."""
    return _solved(*_box_room(floor=[0.35, 0.3, 0.25], wall=0.7))


@pytest.fixture(scope="module")
def white_ceiling():
    """Walls 0.55 (the prior), floor 0.35, ceiling 0.85."""
    return _solved(*_box_room(floor=0.35, wall=0.55, ceiling=0.85))


def test_wall_albedo_found_from_the_interreflections(bright_walls):
    # on an exact model the light between the surfaces (measured) fixes the albedo: walls within 2 %
    # of 0.7 (measured 0.3 %), the floor's RGB within 3 %, the window within 3 % of its radiance; the
    # 0.55 prior instead makes the window > 50 % too bright (measured 70 %)
    _, pm, G, B = bright_walls
    pix_patch, photo, resp = _photo(pm, B, exposure=0.4)
    fit = _fit(pm, G, pix_patch, photo, resp, fit_albedo=True)
    assert np.abs(np.array(fit.report["wall_albedo"]) / 0.7 - 1).max() < 0.02, fit.report["wall_albedo"]
    floor = f"q{pm.quad[np.flatnonzero(np.isclose(pm.albedo[:, 0], 0.35))[0]]}"
    assert np.abs(np.array(fit.report["albedo_fit"]["surfaces"][floor]) / [0.35, 0.3, 0.25] - 1).max() < 0.03
    assert np.abs(np.array(fit.report["emitters"][0]["radiance"]) / WINDOW - 1).max() < 0.03, fit.report["emitters"]
    assert fit.report["wall_albedo_from"] == "interreflections"
    prior = _fit(pm, G, pix_patch, photo, resp)
    assert prior.report["wall_albedo_from"] == "prior"
    assert prior.report["emitters"][0]["radiance"][1] / WINDOW > 1.5


def test_unseen_ceiling_and_wall_reflect_as_their_surface(white_ceiling):
    # the ceiling (0.85) out of view: gathered with the ceiling prior 0.8 its radiance is within 8 %
    # of the radiosity's; with the old one 0.5 for every unseen patch it is > 25 % low
    _, pm, G, B = white_ceiling
    ceiling = int(pm.quad[np.flatnonzero(np.isclose(pm.albedo[:, 0], 0.85))[0]])
    pix_patch, photo, resp = _photo(pm, B, exposure=0.4, unseen_quad=ceiling)
    new = _fit(pm, G, pix_patch, photo, resp)
    old = _fit(pm, G, pix_patch, photo, resp, unseen_by_surface=False)
    on = pm.quad == ceiling
    err_new = np.median(new.radiance[on, 1] / B[on, 1]) - 1
    err_old = np.median(old.radiance[on, 1] / B[on, 1]) - 1
    assert abs(err_new) < 0.08 and err_old < -0.25, (err_new, err_old)
    assert np.allclose(new.reflectivity[on], 0.8)
    # the window: within 5 % with the ceiling's light right; the 0.5 prior asks more of it
    assert np.abs(np.array(new.report["emitters"][0]["radiance"]) / WINDOW - 1).max() < 0.05, new.report["emitters"]
    assert old.report["emitters"][0]["radiance"][1] > new.report["emitters"][0]["radiance"][1]


def _gamma_response(exposure: float, gamma: float = 1.6):
    """A camera that is not sRGB (z = X ** (1 / gamma)), marked measured as a bracket's would be."""
    from lighting.photolight import PhotoResponse

    z = np.arange(256) / 255.0
    return PhotoResponse(np.tile(z ** (1 / gamma), (3, 1)), np.tile(z ** gamma, (3, 1)), exposure,
                         source="test camera", measured=True)


def test_a_measured_response_fits_the_walls_albedo_by_default(bright_walls):
    # the photo through a gamma-1.6 camera: read through that (measured) response, the default priors
    # fit the albedo from the interreflections (walls within 2 % of 0.7, window within 3 %); read
    # through the assumed sRGB curve they keep the 0.55 prior (the slope it would need is not known)
    _, pm, G, B = bright_walls
    resp = _gamma_response(0.4)
    pix_patch = np.repeat(np.flatnonzero(pm.quad != 1), 10)
    photo = resp.to_pixels(B[pix_patch])
    fit = _fit(pm, G, pix_patch, photo, resp)
    assert fit.report["wall_albedo_from"] == "interreflections" and fit.report["response"] == "test camera"
    assert np.abs(np.array(fit.report["wall_albedo"]) / 0.7 - 1).max() < 0.02, fit.report["wall_albedo"]
    assert np.abs(np.array(fit.report["emitters"][0]["radiance"]) / WINDOW - 1).max() < 0.03, fit.report["emitters"]
    assumed = _fit(pm, G, pix_patch, photo, PL.srgb_response(0.4))
    assert assumed.report["wall_albedo_from"] == "prior" and assumed.report["response"] == "sRGB (assumed)"
    off = _fit(pm, G, pix_patch, photo, resp, fit_albedo=False)
    assert off.report["wall_albedo_from"] == "prior"


def test_photo_light_reads_the_photo_through_the_folders_response(tmp_path):
    # window_room: its declared camera_response is used as is; without it, the one recovered from the
    # probe bracket (its shape within 5 % of the true inverse response over levels 20-235, relative to
    # level 128: the recovered one has its own scale); stripped of the bracket too, sRGB is assumed
    import shutil

    from bench.bench_photolight import strip_scene
    from recon.scene import load_scene
    from tests.conftest import shared_scene

    src = shared_scene("window_room")
    declared = PL.photo_response(load_scene(src))
    assert declared.measured and declared.source.startswith("declared")
    d = json.loads((src / "scene.json").read_text())
    true_inv = np.asarray(d.pop("camera_response")["inverse_table"], float)
    own = tmp_path / "own"
    shutil.copytree(src, own)
    (own / "scene.json").write_text(json.dumps(d))
    rec = PL.photo_response(load_scene(own))
    assert rec.measured and rec.source == "recovered from the probe bracket"
    lv = np.arange(20, 236)
    shape = (rec.inverse_table[:, lv] / rec.inverse_table[:, 128:129]) / (true_inv[:, lv] / true_inv[:, 128:129])
    assert np.abs(shape - 1).max() < 0.05, np.abs(shape - 1).max(axis=1)
    bare = PL.photo_response(load_scene(strip_scene(src, tmp_path / "stripped")))
    assert not bare.measured and bare.source == "sRGB (assumed)"


def test_unreadable_bracket_falls_back_to_srgb_with_one_warning(tmp_path, caplog):
    # a scene.json whose light_probe names images that are not there: photo light says so in one warning
    # naming scene.json and the missing file, and reads the photo through the assumed sRGB curve
    from types import SimpleNamespace

    (tmp_path / "scene.json").write_text(json.dumps(
        {"light_probe": {"ldr_files": ["probe_a.png", "probe_b.png"], "exposure_times": [0.1, 0.01]}}))
    scene = SimpleNamespace(camera=SimpleNamespace(exposure_time=0.02), response=None, root=tmp_path)
    with caplog.at_level("WARNING"):
        r = PL.photo_response(scene)
    assert not r.measured and r.source == "sRGB (assumed)"
    assert r.exposure_time == pytest.approx(0.02, rel=1e-12)
    warned = [m for m in caplog.messages if "probe bracket gives no response" in m]
    assert len(warned) == 1 and str(tmp_path / "scene.json") in warned[0] and "probe_a.png" in warned[0], warned
    np.testing.assert_allclose(r.inverse_table, PL.srgb_response(0.02).inverse_table, rtol=1e-12)
