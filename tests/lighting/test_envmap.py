"""Cube maps and the Phong-lobe pre-filter for specular reflection (seed sec. 5, fig. 9)."""
import numpy as np
import pytest

from lighting.envmap import CubeMap, cube_directions, phong_prefilter, reflect


def test_cube_solid_angles_cover_the_sphere():
    # texel solid angles sum to 4 pi and every texel direction is a unit vector
    for res in (4, 16, 32):
        d, sa = cube_directions(res)
        assert d.shape == (6 * res * res, 3)
        np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
        assert abs(sa.sum() / (4 * np.pi) - 1) < 1e-12


def test_lookup_returns_texels_at_their_centres():
    # a cube map looked up exactly at its texel directions gives back the texel values
    res = 8
    d, _ = cube_directions(res)
    vals = np.random.default_rng(0).random((6 * res * res, 3))
    cm = CubeMap(vals.reshape(6, res, res, 3))
    np.testing.assert_allclose(cm.lookup(d), vals, atol=1e-12)


@pytest.mark.parametrize("n", [1.0, 8.0, 32.0])
def test_cosine_environment_against_closed_form(n):
    # L(w) = max(0, w.z): the normalised Phong lobe around r = z integrates to (n+1)/(n+2)
    res_in = 32
    d, _ = cube_directions(res_in)
    L = np.repeat(np.maximum(d[:, 2], 0)[:, None], 3, axis=1)
    cm = phong_prefilter(L, res_in, n, 16)
    got = cm.lookup(np.array([[0.0, 0.0, 1.0]]))[0]
    np.testing.assert_allclose(got, (n + 1) / (n + 2), rtol=0.02)


def test_uniform_environment_reflects_its_radiance():
    # a uniform environment of radiance L reflects k_s L in every direction (lobe integrates to 1)
    d, _ = cube_directions(16)
    cm = phong_prefilter(np.full((len(d), 3), 2.5), 16, 20.0, 8)
    dirs = np.random.default_rng(1).normal(size=(100, 3))
    np.testing.assert_allclose(cm.lookup(dirs), 2.5, rtol=1e-9)


def test_bright_source_peaks_in_its_direction():
    # hard case: a small source 1e5 x brighter than the rest; the filtered peak points at it,
    # the lobe falls off away from it, and nothing is NaN or negative
    res_in = 32
    d, _ = cube_directions(res_in)
    src = np.array([0.3, 0.8, -0.52])
    src /= np.linalg.norm(src)
    L = np.ones((len(d), 3))
    L[d @ src > np.cos(0.08)] = 1e5
    cm = phong_prefilter(L, res_in, 64.0, 16)
    assert np.all(np.isfinite(cm.texels)) and cm.texels.min() >= 1.0 - 1e-9
    out_d, _ = cube_directions(16)
    peak = out_d[np.argmax(cm.texels.reshape(-1, 3)[:, 0])]
    assert np.degrees(np.arccos(np.clip(peak @ src, -1, 1))) < 6.0
    off = np.cross(src, [1.0, 0, 0])
    off /= np.linalg.norm(off)
    away = np.cos(0.6) * src + np.sin(0.6) * off
    assert cm.lookup(src[None])[0, 0] > 50 * cm.lookup(away[None])[0, 0]


def test_reflect_is_a_mirror():
    v = np.array([[1.0, -1.0, 0.0]]) / np.sqrt(2)
    n = np.array([[0.0, 1.0, 0.0]])
    np.testing.assert_allclose(reflect(v, n), [[1 / np.sqrt(2), 1 / np.sqrt(2), 0.0]])


def test_bad_input_is_a_clear_error():
    with pytest.raises(ValueError, match="texels"):
        phong_prefilter(np.ones((10, 3)), 4, 8.0, 4)
    with pytest.raises(ValueError, match="exponent"):
        phong_prefilter(np.ones((96, 3)), 4, -1.0, 4)
