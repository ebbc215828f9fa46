"""Tests of the display tone-mapping operators in lighting/tonemap.py and `photoar tonemap`."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from tests.conftest import ROOT, shared_scene


def _jnd(L):
    """Blackwell's threshold (Ward 1994): just-noticeable luminance difference at adaptation L."""
    return 0.0594 * (1.219 + L ** 0.4) ** 2.5


@pytest.mark.parametrize("L_wa", [0.01, 1.0, 50.0, 3000.0])
def test_ward_factor_maps_world_jnd_to_display_jnd(L_wa):
    """Ward's m makes a just-visible step in the world a just-visible step on the display
    (display adaptation L_dmax / 2); m = 1 when the world adapts like the display."""
    from lighting.tonemap import ward_scale_factor

    m = ward_scale_factor(L_wa, L_dmax=100.0)
    assert m * _jnd(L_wa) == pytest.approx(_jnd(50.0), rel=1e-12)
    assert ward_scale_factor(50.0, 100.0) == pytest.approx(1.0, rel=1e-12)
    with pytest.raises(ValueError):
        ward_scale_factor(0.0)


def test_ward_operator_on_a_uniform_field():
    """A uniform 50 cd/m^2 field shown on a 100 cd/m^2 display: m = 1, half white, then gamma."""
    from lighting.tonemap import tonemap_ward

    out = tonemap_ward(np.full((4, 5, 3), 25.0), nits_per_unit=2.0, L_dmax=100.0, gamma=2.2, L_wa=50.0)
    np.testing.assert_allclose(out, 0.5 ** (1 / 2.2), rtol=1e-6)
    dark = tonemap_ward(np.full((4, 5, 3), 0.01), nits_per_unit=1.0)  # a dark scene stays dark (sec. 9.1.3)
    bright = tonemap_ward(np.full((4, 5, 3), 1000.0), nits_per_unit=1.0)
    assert dark.max() < 0.1 < 0.8 < bright.min()


@pytest.mark.parametrize("op", ["reinhard", "drago", "mantiuk", "ward"])
def test_operators_range_and_global_monotonicity(op):
    """Every operator returns display values in [0, 1]; the global ones keep the order of a
    luminance ramp over five decades."""
    from lighting.tonemap import display_tonemap, to_display_pixels

    ramp = np.logspace(-2, 3, 256)
    img = np.tile(ramp[None, :, None], (16, 1, 3)).astype(np.float32)
    img[..., 0] *= 0.8  # a little colour
    out = display_tonemap(img, op)
    assert out.shape == img.shape and out.dtype == np.float32
    assert np.all(np.isfinite(out)) and out.min() >= 0.0 and out.max() <= 1.0
    lum = out[8] @ np.array([0.2126, 0.7152, 0.0722])
    if op != "mantiuk":  # a local (gradient-domain) operator need not be monotone
        assert np.all(np.diff(lum) >= -1e-6)
    assert lum[-1] > lum[0]
    assert to_display_pixels(out).dtype == np.uint8


def test_bad_input():
    from lighting.tonemap import display_tonemap

    img = np.ones((4, 4, 3), np.float32)
    with pytest.raises(ValueError, match="unknown tone-mapping operator"):
        display_tonemap(img, "filmic")
    img[0, 0, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        display_tonemap(img, "drago")
    with pytest.raises(ValueError, match="RGB"):
        display_tonemap(np.ones((4, 4)), "reinhard")


def test_tonemap_cli(tmp_path):
    exr = shared_scene("lamps_room") / "truth.exr"
    out = tmp_path / "t" / "shown.png"
    cmd = [sys.executable, "-m", "app.cli", "-q", "tonemap"]
    p = subprocess.run(cmd + [str(exr), "--op", "drago", "--out", str(out)], cwd=ROOT, capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    import cv2

    img = cv2.imread(str(out))
    assert img is not None and img.shape == (480, 640, 3) and 30 < img.mean() < 230
    p = subprocess.run(cmd + [str(tmp_path / "none.exr"), "--op", "ward", "--out", str(tmp_path / "x.png")],
                       cwd=ROOT, capture_output=True, text=True)
    assert p.returncode == 2 and "none.exr" in p.stderr and not (tmp_path / "x.png").exists()
