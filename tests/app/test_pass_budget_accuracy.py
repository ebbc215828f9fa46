"""Issue 17's accuracy point for a pass budget, scored against the path-traced truth with the shared
scorer: at 50 passes rmse_affected <= 1.25 x the all-sources frame's + 0.25 levels and energy_ratio
within 0.95-1.05, on the engine's cached precompute at the object's own pose.

Measured (evaluate --passes 50,all): window_room 50 passes 0.957 / 0.872 against all sources
0.954 / 0.767 (1.269 before the clusters' maps got their penumbra: one sharp copy of the shadow per
cluster banded the soft shadow); lamps_room 0.975 / 1.552 against 0.988 / 1.237 (1.394 before).
With the depth range pyramid's early outs and a blocker search shared by a cell's points
(kernels.composite._run_blockers): window_room 0.957 / 0.875, lamps_room 0.975 / 1.553.

sun_room (a sunlit floor patch beside the object lights the room): 50 passes 0.927 / 2.211 against all
sources 0.886 / 1.793 (1.081 / 3.232 before the representatives' priority counted the light a cluster's
map darkens of members the object cannot block: the sunlit patch shared one map with the rest of the
floor, seen from beside the chair); window_room 0.964 / 0.875, lamps_room 0.979 / 1.426 with it."""
import pytest

from recon.io import write_png
from tests.conftest import score, shared_scene


@pytest.mark.parametrize("name", ["window_room", "lamps_room"])
def test_fifty_passes_close_to_all_sources(name, shared_scenes_cache, tmp_path):
    from app.engine import Engine, EngineParams, FrameConfig
    from recon.scene import load_scene

    scene_dir = shared_scene(name)
    eng = Engine(load_scene(scene_dir), EngineParams(), cache_dir=shared_scenes_cache, quiet=True)
    s = {}
    for passes in (50, None):
        write_png(tmp_path / f"{passes}.png", eng.render(eng.scene.obj, FrameConfig(passes=passes)).pixels)
        s[passes] = score(scene_dir, tmp_path / f"{passes}.png")
    assert s[50]["rmse_affected"] <= 1.25 * s[None]["rmse_affected"] + 0.25, s
    assert 0.95 <= s[50]["energy_ratio"] <= 1.05, s
    assert s[50]["spurious"] < 0.01, s


def test_fifty_passes_close_to_all_sources_in_a_sunny_room(shared_scenes_cache, tmp_path):
    """The same bound on rmse_affected in sun_room. Its all-sources frame itself scores energy 1.032
    (0.886 before the sun's bounces were counted right) and moves 8 % of the 'rest' pixels (the sunlit
    patch the object shades is the room's main indirect source): energy is held to issue 20's band
    0.9-1.1, spurious to the truth's noise floor rule (below)."""
    from app.engine import Engine, EngineParams, FrameConfig
    from recon.scene import load_scene

    scene_dir = shared_scene("sun_room")
    eng = Engine(load_scene(scene_dir), EngineParams(), cache_dir=shared_scenes_cache, quiet=True)
    s = {}
    for passes in (50, None):
        write_png(tmp_path / f"{passes}.png", eng.render(eng.scene.obj, FrameConfig(passes=passes)).pixels)
        s[passes] = score(scene_dir, tmp_path / f"{passes}.png")
    assert s[50]["rmse_affected"] <= 1.25 * s[None]["rmse_affected"] + 0.25, s
    assert 0.9 <= s[50]["energy_ratio"] <= 1.1, s
    # spurious: both frames are below what an exact answer scores against sun_room's noisy truth (0.104,
    # tests/lighting/test_sun.py::_spurious_noise_floor): the 50-pass frame is held to that floor's rule
    # (once it was the all-sources frame's + 0.01: 0.100 and 0.100; since the sun's bounces were counted
    # right the all-sources frame scores 0.082 and the 50-pass frame 0.099)
    from tests.lighting.test_sun import _spurious_noise_floor

    assert s[50]["spurious"] <= 1.2 * _spurious_noise_floor(scene_dir), s
