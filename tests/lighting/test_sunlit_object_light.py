"""The sunlit patches the object gathers under captured light (app.stages.sun.SunSetup.object_radiance,
lighting.irradiance.RoomLight.gather_exactly): the model's radiance where the photo clips, gathered
exactly, against sun_room's true radiance (background.exr, the same units as the engine's)."""
import numpy as np
import pytest

from lighting.radiance import PHOTO
from recon.io import read_exr
from recon.response import luminance
from recon.scene import load_scene
from tests.conftest import shared_scene


@pytest.fixture(scope="module")
def captured(tmp_path_factory):
    from app.engine import Engine, EngineParams

    s = load_scene(shared_scene("sun_room"), load_textures=False)
    e = Engine(s, EngineParams(patch_size=0.4, emitter_patch_size=0.3, passes=8, lighting="captured",
                               sun="estimate"), cache_dir=tmp_path_factory.mktemp("c"), quiet=True)
    return s, e


def test_sunlit_patches_light_the_object_with_the_models_radiance(captured):
    """The sunlit floor clips in sun_room's photo, so its patches' captured radiance is the probe's
    coarse view (one patch 4.7x its truth: the sun patch's edge smeared over it). The object gathers
    them at rho (E_ind + E_sun) from the estimated sun instead, and exactly (not through the SH
    volume). Per patch against the truth's mean radiance over its pixels (luminance): measured mean
    |rel err| 0.142 (the probe's 0.285), worst 0.43 (the probe's 3.73)."""
    s, e = captured
    assert e.sun.on
    pm, pp = e.pre.patches, e.receivers.pix_patch
    exr = read_exr(s.root / "background.exr").reshape(-1, 3).astype(np.float64)
    ok = pp >= 0
    cnt = np.bincount(pp[ok], minlength=pm.n_patches)
    truth = np.stack([np.bincount(pp[ok], exr[ok, c], minlength=pm.n_patches) for c in range(3)], 1)
    truth /= np.maximum(cnt, 1)[:, None]
    # the engine's units are the truth's: the photo-measured patches agree (measured ratio 1.004)
    photo = (e.pre.origin == PHOTO) & (cnt > 50)
    ratio = np.median(luminance(e.B_src[photo]) / np.maximum(luminance(truth[photo]), 1e-9))
    assert 0.95 <= ratio <= 1.05, ratio
    lit = e.sun.patch_light().any(1) & ~pm.is_emitter & (e.pre.origin != PHOTO) & (cnt > 20)
    assert lit.sum() >= 15, lit.sum()  # measured 25 (the sunlit floor at 0.4 m patches)
    assert np.isin(np.flatnonzero(lit), e.room_light.emitters).all()  # gathered exactly
    rel = luminance(e.room_light.radiance[lit]) / luminance(truth[lit]) - 1
    print(f"sunlit patches: mean |rel err| {np.abs(rel).mean():.3f}, worst {np.abs(rel).max():.3f}")
    assert np.abs(rel).mean() <= 0.2, rel
    assert np.abs(rel).max() <= 0.6, rel
    # the room's own receivers keep the measured radiance (B_src: the sun stage's E_x is built on it)
    assert not np.allclose(e.B_src[lit], e.room_light.radiance[lit])


def test_gather_exactly_moves_patches_out_of_the_volume_only(captured):
    """RoomLight.gather_exactly: the moved patches join the exact gather at the given radiance; the
    emitters and every other patch's radiance are kept; an all-False mask changes nothing."""
    _, e = captured
    rl = e.room_light
    em0, rad0 = rl.emitters.copy(), rl.radiance.copy()
    rl.gather_exactly(np.zeros(len(rad0), bool), rad0 * 2)
    assert np.array_equal(rl.emitters, em0) and np.array_equal(rl.radiance, rad0)
    k = int(np.setdiff1d(np.arange(len(rad0)), em0)[0])
    near = np.zeros(len(rad0), bool)
    near[k] = True
    new = rad0.copy()
    new[k] = [5.0, 4.0, 3.0]
    try:
        rl.gather_exactly(near, new)
        assert k in rl.emitters and set(em0) <= set(rl.emitters) and len(rl.emitters) == len(em0) + 1
        np.testing.assert_allclose(rl.radiance[k], [5.0, 4.0, 3.0])
        others = np.arange(len(rad0)) != k
        assert np.array_equal(rl.radiance[others], rad0[others])
    finally:
        rl.emitters, rl.radiance = em0, rad0


def test_partly_clipped_sunlit_pixels_keep_their_measured_channels(captured):
    """A sunlit pixel that clips in some channels only (a darker grain of the floor) takes the model's
    radiance in those channels; the others are measurements and stay the photo's, so a pixel nothing
    changes composites back to its photo levels (sun_102's planks, clipped in red only, were brightened
    where the truth does not change: spurious 0.198 -> 0.049 on its benchmark folder)."""
    from app.stages.sun import CLIP_LEVEL

    s, e = captured
    sp, resp = e.sun_pixels, s.response
    photo = s.photo.reshape(-1, 3)
    clip = photo[sp.pix] >= CLIP_LEVEL
    part = clip.any(1) & ~clip.all(1)
    assert part.sum() >= 50, part.sum()  # measured 1 % of sun_room's clipped sunlit pixels
    idx, kept = sp.pix[part], ~clip[part]
    levels = resp.to_levels(e.receivers.L_b[idx])
    # the measured channels back to the photo's levels within 1 (L_b is the engine's photo radiance,
    # 0.5 % off the curve's inverse of the 8-bit level); the clipped ones at least at the clip level
    assert np.abs(levels[kept] - photo[idx][kept]).max() <= 1.0, np.abs(levels[kept] - photo[idx][kept]).max()
    assert (levels[~kept] >= CLIP_LEVEL - 1).all()


def test_known_light_gathers_the_sunlit_patches_exactly(tmp_path_factory):
    """Under known light the sunlit floor lit the object through the 0.25 m SH9 grid, which spread it
    (sun_room's chair: 0.78 from the volume against 0.43 gathered per patch; rmse_object 5.47 -> 3.31 with
    the exact gather): the sunlit patches are gathered exactly at the radiosity's radiance, which holds
    the sun (the engine builds the SH volume without them)."""
    from app.engine import Engine, EngineParams

    s = load_scene(shared_scene("sun_room"), load_textures=False)
    e = Engine(s, EngineParams(patch_size=0.4, emitter_patch_size=0.3, passes=8, lighting="known"),
               cache_dir=tmp_path_factory.mktemp("k"), quiet=True)
    lit = e.sun.sunlit_patches()
    assert lit.sum() >= 15, lit.sum()
    assert np.isin(np.flatnonzero(lit), e.room_light.emitters).all()
    np.testing.assert_allclose(e.room_light.radiance[lit], np.asarray(e.B_src)[lit], rtol=1e-12)
