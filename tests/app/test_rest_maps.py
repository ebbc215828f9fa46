"""The all-sources frame at rest (issue 36, item 5) on the shared rooms, scored against the path-traced
truth with the shared scorer: its weak sources on half-size maps (app.rest_maps) and its second order's
blocked pairs from one Warp launch (app.stages.second_order.BlockedSecondOrder).

Measured (bench/bench_rest.py, energy / rmse_affected / spurious / rmse_object, every map 256 px ->
the weak ones 128 px): window_room 0.9556 / 0.7438 / 0.0014 / 1.174 -> 0.9567 / 0.7391 / 0.0013 / 1.176
(342 of 3205 sources full-size), lamps_room 0.9893 / 1.2234 / 0.0050 / 2.204 -> 0.9893 / 1.2212 / 0.0050 /
2.204 (322 of 3462; every map at 128 px: rmse_affected 1.2777). The frames differ by 0.15 and 0.03 levels
RMS over the image. The frame now also leaves the weak sources' sums at the near ring's off-lattice
pixels to the fill (ShadowPass.weak_ring; bench_rest, against the same frame with the ring summed): window_room
rmse_affected 0.7392 -> 0.7421, lamps_room 1.2205 -> 1.2224, 0.12 and 0.02 levels RMS over the image; and
beyond 2 bounding radii sums them on the spacing-4 lattice only (ShadowPass.weak_coarse; bench_rest `ring`
-> `after`): window_room 0.7421 -> 0.7430, lamps_room 1.2224 -> 1.2223, 0.11 and 0.02 levels RMS."""
import numpy as np
import pytest

from recon.io import write_png
from tests.conftest import score, shared_scene


@pytest.mark.parametrize("name", ["window_room", "lamps_room"])
def test_half_size_maps_of_weak_sources_score_as_the_full_size(name, shared_scenes_cache, tmp_path):
    from app.engine import Engine, EngineParams, FrameConfig
    from app.rest_maps import WEBER
    from app.stages.second_order import blocked_pass
    from recon.proxy import bounding_sphere
    from recon.response import luminance
    from recon.scene import load_scene

    scene_dir = shared_scene(name)
    eng = Engine(load_scene(scene_dir), EngineParams(), cache_dir=shared_scenes_cache, quiet=True)
    obj, pre, pm = eng.scene.obj, eng.pre, eng.pre.patches
    pv = eng.object_shading.object_shape(obj)[0]
    fs = eng.shadow_sources.select(pv.min(0), pv.max(0), None)
    weak = eng.rest_maps.weak(fs)
    assert 0 < (~weak).sum() < 0.3 * len(weak)  # a mix: most sources weak, the strong ones full-size
    # the rule against its definition, source by source (a sample of them)
    W = np.asarray(fs.W_v)
    E = np.maximum(luminance(eng.receivers.E_v), 1e-30)  # a vertex no light reaches: every share 0
    for j in np.random.default_rng(0).choice(len(weak), 40, replace=False):
        assert weak[j] == (np.max(luminance(W[:, j].astype(np.float64)) / E) <= WEBER)

    # the second order's blocked pairs: the kernel's sums equal the numpy reference's (float32 sums)
    kernel, checked = eng._blocked, []

    def both(dB, occ, box, obb=None, split=None):
        got = kernel(dB, occ, box, obb=obb, split=split)
        rv = pre.recv_vert
        want = blocked_pass(dB, pre.G_v, pm.vert_inset[rv], pm.vert_normal[rv], pm.centre, pm.normal, pm.area,
                            occ, bounding_sphere(pv))
        assert want is not None and got is not None
        np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-6 * np.abs(want).max())
        checked.append(True)
        return got

    eng._blocked = both
    new = eng.render(obj, FrameConfig(passes=None))
    assert checked
    eng._blocked, rest = kernel, eng.rest_maps
    eng.rest_maps = None  # every map map_res: the frame before
    old = eng.render(obj, FrameConfig(passes=None))
    eng.rest_maps = rest
    write_png(tmp_path / "new.png", new.pixels)
    write_png(tmp_path / "old.png", old.pixels)
    s_new, s_old = score(scene_dir, tmp_path / "new.png"), score(scene_dir, tmp_path / "old.png")
    # within a stated tolerance of the full-size frame: 0.3 levels RMS over the image (measured 0.15 / 0.03)
    assert np.sqrt(np.mean((new.pixels.astype(np.float64) - old.pixels) ** 2)) <= 0.3
    # and no worse against the truth (beyond 0.02 levels of rmse, 0.005 of energy)
    assert s_new["rmse_affected"] <= s_old["rmse_affected"] + 0.02, (s_new, s_old)
    assert abs(s_new["energy_ratio"] - s_old["energy_ratio"]) <= 0.005, (s_new, s_old)
    assert s_new["rmse_object"] <= s_old["rmse_object"] + 0.02, (s_new, s_old)
    assert s_new["spurious"] <= s_old["spurious"] + 0.001, (s_new, s_old)
