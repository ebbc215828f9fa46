"""lighting.sun.sunlit_pixels on synthetic photos: a sun patch in a noisy floor is found whole; a
smooth gradient and plain noise are not split (the rules of its docstring)."""
import numpy as np

from lighting.sun import UNIMODAL_SEPARATION, sunlit_pixels

H, W = 120, 160


def _floor(rng, noise: float, zeros: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """A one-quad floor of radiance 0.2 with a sunlit rectangle of 2.0 (10x), multiplicative noise
    `noise` (relative sd) and a share `zeros` of pixels at 0 (a few-spp render's dark draws).
    Returns (L_b (N,3), the true sunlit mask (N,))."""
    true = np.zeros((H, W), bool)
    true[30:80, 50:130] = True
    L = np.where(true, 2.0, 0.2)[..., None] * np.ones(3)
    L = L * np.maximum(1.0 + noise * rng.standard_normal(L.shape[:2]), 0.0)[..., None]
    L[rng.random((H, W)) < zeros] = 0.0
    return L.reshape(-1, 3), true.ravel()


def test_sun_patch_in_a_noisy_floor_with_dark_draws():
    # 1 % of the pixels at 0: without the median they are Otsu's dark class on their own and the
    # whole floor (99 %) comes out "sunlit"
    rng = np.random.default_rng(1)
    L, true = _floor(rng, noise=0.5, zeros=0.01)
    quad, recv, sat = np.zeros(H * W, int), np.ones(H * W, bool), np.zeros(H * W, bool)
    lit = sunlit_pixels(L, sat, quad, recv, shape=(H, W))
    iou = (lit & true).sum() / (lit | true).sum()
    assert iou >= 0.95, iou
    raw = sunlit_pixels(L, sat, quad, recv)  # per pixel, no median: the failure the median removes
    assert raw.mean() >= 0.95, raw.mean()


def test_smooth_gradient_and_noise_are_not_sunlit():
    # log-luminance rising linearly across a wall 4.5x from end to end (a wall beside a window): Otsu's
    # bright class is over 3x the dark one, yet it is one hump (separation 2 sqrt(3))
    x = np.linspace(0.0, np.log(4.5) * 2, W)
    L = (np.exp(x)[None, :] * np.ones((H, 1)))[..., None] * np.ones(3) * 0.1
    rng = np.random.default_rng(2)
    L = L * np.exp(0.05 * rng.standard_normal((H, W)))[..., None]
    quad, recv, sat = np.zeros(H * W, int), np.ones(H * W, bool), np.zeros(H * W, bool)
    assert not sunlit_pixels(L.reshape(-1, 3), sat, quad, recv, shape=(H, W)).any()
    # plain log-normal noise, sd 1.2 (a dark, very noisy surface): one hump
    L2 = np.exp(1.2 * rng.standard_normal((H, W)))[..., None] * np.ones(3)
    assert not sunlit_pixels(L2.reshape(-1, 3), sat, quad, recv).any()


def test_unimodal_separation_is_the_uniform_distributions():
    # Otsu on a uniform sample splits it at the middle: the means' gap over the pooled spread is 2 sqrt(3)
    v = np.linspace(0.0, 1.0, 100001)
    gap, spread = 0.5, np.sqrt(0.5 * (v[v <= 0.5].var() + v[v > 0.5].var()))
    np.testing.assert_allclose(gap / spread, UNIMODAL_SEPARATION, rtol=1e-3)
