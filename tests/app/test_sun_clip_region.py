"""app.stages.sun.clipped_sunlit: a clipped sunlit patch is clipped as a whole, channel by channel,
whatever its grain does pixel by pixel."""
import numpy as np

from app.stages.sun import CLIP_LEVEL, clipped_sunlit


def test_grain_in_a_clipped_patch_is_clipped_too():
    # patch 0: 90 % of its pixels clip in red and green, 10 % are grain draws at 230-253; blue clips
    # on 30 % only. Patch 1: nothing clips but 5 % stray pixels. Per channel, the patch decides.
    rng = np.random.default_rng(0)
    n = 1000
    lv = np.zeros((2 * n, 3), np.uint8)
    lv[:n, :2] = np.where(rng.random((n, 2)) < 0.9, 255, rng.integers(230, CLIP_LEVEL, (n, 2)))
    lv[:n, 2] = np.where(rng.random(n) < 0.3, 255, 200)
    lv[n:] = np.where(rng.random((n, 1)) < 0.05, 255, 120)
    patch = np.r_[np.zeros(n, int), np.full(n, 7)]
    region, pixel = clipped_sunlit(lv, patch)
    assert region[:n, :2].all() and not region[:n, 2].any()  # red, green: the whole patch; blue: none
    assert not region[n:].any()
    np.testing.assert_array_equal(pixel, lv >= CLIP_LEVEL)  # each pixel's own clip, unchanged


def test_no_sunlit_pixels():
    region, pixel = clipped_sunlit(np.zeros((0, 3), np.uint8), np.zeros(0, int))
    assert region.shape == (0, 3) and pixel.shape == (0, 3)
