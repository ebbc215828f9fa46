"""Photo light in a sunny room (app.stages.sun.SunSetup.object_radiance, sunlit_patches): the object
gathers the sunlit patches the photo shows clipped with the estimated sun's model radiance, and every
sunlit reflector exactly, as under captured light.
Analytic: three patches and a hand-made sun share; the full flow is tests/lighting/test_photolight_sun.py."""
from types import SimpleNamespace

import numpy as np

from app.stages.sun import SunSetup
from lighting.photolight import FITTED
from lighting.radiance import GATHERED, PHOTO


def _setup(lighting="photo", on=True):
    # patch 0: sunlit, clipped (fitted as a clipped region); 1: sunlit, measured; 2: in shade; 3: a window
    pm = SimpleNamespace(is_emitter=np.array([False, False, False, True]),
                         albedo=np.array([[0.4, 0.3, 0.2], [0.5, 0.5, 0.5], [0.6, 0.6, 0.6], [0.0, 0.0, 0.0]]))
    E_sun = np.array([[10.0, 9.0, 8.0], [5.0, 5.0, 5.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    pm.n_patches = len(pm.is_emitter)
    sun = SimpleNamespace(lighting=lighting, on=on, patches=pm, patch_light=lambda: E_sun)
    G = np.array([[0, 0.1, 0.2, 0.3], [0.1, 0, 0.2, 0.3], [0.2, 0.1, 0, 0.3], [0, 0, 0, 0]], np.float32)
    pre = SimpleNamespace(origin=np.array([FITTED, PHOTO, GATHERED, FITTED], np.int8), G_c=G)
    B = np.array([[2.0, 2.0, 2.0], [1.5, 1.4, 1.3], [0.5, 0.5, 0.5], [8.0, 8.0, 8.0]])
    return sun, pre, B, E_sun, G


def photo_object_light(sun, pre, B):
    """The engine's two calls (SunSetup's methods on a stand-in)."""
    return SunSetup.object_radiance(sun, pre, B), SunSetup.sunlit_patches(sun)


def test_clipped_sunlit_patch_takes_the_model_radiance():
    sun, pre, B, E_sun, G = _setup()
    out, near = photo_object_light(sun, pre, B)
    expect = sun.patches.albedo[0] * (G[0].astype(float) @ B + E_sun[0])
    assert np.allclose(out[0], expect, rtol=1e-12)
    assert np.array_equal(out[1:], B[1:])  # measured, in shade, the window: as fitted
    assert near.tolist() == [True, True, False, False]  # the sunlit reflectors, gathered exactly


def test_no_change_without_a_sun_and_under_known_light():
    sun, pre, B, _, _ = _setup(on=False)
    out, near = photo_object_light(sun, pre, B)
    assert out is B and not near.any()
    sun, pre, B, _, _ = _setup(lighting="known")  # the sun is in the radiosity: gathered exactly as it is
    out, near = photo_object_light(sun, pre, B)
    assert out is B and near.tolist() == [True, True, False, False]


def test_captured_light_takes_the_same_rule():
    photo, captured = (photo_object_light(*_setup(lighting=k)[:3]) for k in ("photo", "captured"))
    assert np.array_equal(photo[0], captured[0]) and np.array_equal(photo[1], captured[1])
