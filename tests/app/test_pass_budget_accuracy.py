"""Issue 17's accuracy point for a pass budget, scored against the path-traced truth with the shared
scorer: at 50 passes rmse_affected <= 1.25 x the all-sources frame's + 0.25 levels and energy_ratio
within 0.95-1.05, on the engine's cached precompute at the object's own pose.

Measured (evaluate --passes 50,all): window_room 50 passes 0.957 / 0.872 against all sources
0.954 / 0.767 (1.269 before the clusters' maps got their penumbra: one sharp copy of the shadow per
cluster banded the soft shadow); lamps_room 0.975 / 1.552 against 0.988 / 1.237 (1.394 before).
With the depth range pyramid's early outs and a blocker search shared by a cell's points
(kernels.masked_sums._run_blockers): window_room 0.957 / 0.875, lamps_room 0.975 / 1.553.

sun_room does not meet it today (strict xfail: the test fails once the bound holds, so the mark comes
off then): 50 passes 1.226 / 2.957 against all sources 1.033 / 1.501 (bound 2.13). The 50-pass
clusters are too dark near the object: a cluster's one map, seen from an eye beside (or inside) the
object's box, darkens the light of all its members, most of which the object cannot block (the sunlit
floor patches beside the chair joined with the rest of the floor). Vertex-level model (receiver
vertices, exact rays to the chair): the clusters block 1.11 x the light the sources block one by one
(window_room 0.995)."""
import pytest

from recon.io import write_png
from tests.conftest import score, shared_scene


def _fifty_and_all(name: str, cache, tmp_path) -> dict:
    """The shared scorer's figures of the 50-pass and the all-sources (None) frame at the object's pose."""
    from app.engine import Engine, EngineParams, FrameConfig
    from recon.scene import load_scene

    scene_dir = shared_scene(name)
    eng = Engine(load_scene(scene_dir), EngineParams(), cache_dir=cache, quiet=True)
    s = {}
    for passes in (50, None):
        write_png(tmp_path / f"{passes}.png", eng.render(eng.scene.obj, FrameConfig(passes=passes)).pixels)
        s[passes] = score(scene_dir, tmp_path / f"{passes}.png")
    return s


def _assert_within_bound(s: dict) -> None:
    assert s[50]["rmse_affected"] <= 1.25 * s[None]["rmse_affected"] + 0.25, s
    assert 0.95 <= s[50]["energy_ratio"] <= 1.05, s


@pytest.mark.parametrize("name", ["window_room", "lamps_room"])
def test_fifty_passes_close_to_all_sources(name, shared_scenes_cache, tmp_path):
    s = _fifty_and_all(name, shared_scenes_cache, tmp_path)
    _assert_within_bound(s)
    assert s[50]["spurious"] < 0.01, s


@pytest.mark.xfail(strict=True, raises=AssertionError, reason="sun_room's 50-pass frame is 1.226 / 2.957 against the "
                                                           "bound 2.13 (energy 0.95-1.05): the clusters near the "
                                                           "object darken too much")
def test_fifty_passes_close_to_all_sources_in_the_sun(shared_scenes_cache, tmp_path):
    _assert_within_bound(_fifty_and_all("sun_room", shared_scenes_cache, tmp_path))
