"""Photo light in a sunny room (app/stages/photo_sun.py): the object gathers the sunlit patches the
photo shows clipped with the estimated sun's model radiance, and every sunlit reflector exactly.
Analytic: three patches and a hand-made sun share; the full flow is tests/lighting/test_photolight_sun.py."""
from types import SimpleNamespace

import numpy as np

from app.stages.photo_sun import photo_object_light
from lighting.photolight import FITTED
from lighting.radiance import GATHERED, PHOTO


def _setup(lighting="photo", on=True):
    # patch 0: sunlit, clipped (fitted as a clipped region); 1: sunlit, measured; 2: in shade; 3: a window
    pm = SimpleNamespace(is_emitter=np.array([False, False, False, True]),
                         albedo=np.array([[0.4, 0.3, 0.2], [0.5, 0.5, 0.5], [0.6, 0.6, 0.6], [0.0, 0.0, 0.0]]))
    E_sun = np.array([[10.0, 9.0, 8.0], [5.0, 5.0, 5.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    sun = SimpleNamespace(lighting=lighting, on=on, patches=pm, patch_light=lambda: E_sun)
    G = np.array([[0, 0.1, 0.2, 0.3], [0.1, 0, 0.2, 0.3], [0.2, 0.1, 0, 0.3], [0, 0, 0, 0]], np.float32)
    pre = SimpleNamespace(origin=np.array([FITTED, PHOTO, GATHERED, FITTED], np.int8), G_c=G)
    B = np.array([[2.0, 2.0, 2.0], [1.5, 1.4, 1.3], [0.5, 0.5, 0.5], [8.0, 8.0, 8.0]])
    return sun, pre, B, E_sun, G


def test_clipped_sunlit_patch_takes_the_model_radiance():
    sun, pre, B, E_sun, G = _setup()
    out, near = photo_object_light(sun, pre, B)
    expect = sun.patches.albedo[0] * (G[0].astype(float) @ B + E_sun[0])
    assert np.allclose(out[0], expect, rtol=1e-12)
    assert np.array_equal(out[1:], B[1:])  # measured, in shade, the window: as fitted
    assert near.tolist() == [True, True, False, False]  # the sunlit reflectors, gathered exactly


def test_no_change_without_photo_light_or_sun():
    for kw in ({"lighting": "captured"}, {"on": False}):
        sun, pre, B, _, _ = _setup(**kw)
        out, near = photo_object_light(sun, pre, B)
        assert out is B and not near.any()
