"""The LDR compositing path (`composite --mode ldr`: I_b - sum_j S_ij M_ij, seed sec. 6.3.1-6.3.2)
scored against the path-traced truth with the shared scorer, next to the HDR path on the same
engine precompute.

Measured (all sources, 640x480; the HDR path in brackets):
  window_room: energy 1.006 (0.953), rmse_affected 1.08 (0.77; untouched 9.86), spurious 0.0064 (0.0013),
               rmse_object 1.27 (1.20)
  lamps_room:  energy 0.954 (0.988), rmse_affected 6.32 (1.24; untouched 36.2), spurious 0.0153 (0.0048),
               rmse_object 3.24 (2.20)
The LDR path is the seed's approximation (exact only when the occluded sources are one of its two
sets); on lamps_room it has 5x the HDR error (cause not yet investigated: an open item, xfail below).
"""
import json

import pytest

from app.cli import main as cli
from recon.io import write_png
from tests.conftest import score, shared_scene


@pytest.fixture(scope="module")
def scored(tmp_path_factory, shared_scenes_cache):
    """{scene: (LDR scores, HDR scores, report.json)}: the LDR composite from the command line, the
    HDR frame from an engine on the same cached precompute."""
    from app.engine import Engine, EngineParams, FrameConfig
    from recon.scene import load_scene

    out = {}
    for name in ("window_room", "lamps_room"):
        scene_dir = shared_scene(name)
        tmp = tmp_path_factory.mktemp(name)
        assert cli(["-q", "composite", str(scene_dir), "--out", str(tmp / "ldr"), "--cache", str(shared_scenes_cache),
                    "--mode", "ldr"]) == 0
        eng = Engine(load_scene(scene_dir), EngineParams(), cache_dir=shared_scenes_cache, quiet=True)
        assert eng.cache_hit
        write_png(tmp / "hdr.png", eng.render(eng.scene.obj, FrameConfig(passes=None, mode="hdr")).pixels)
        rep = json.loads((tmp / "ldr" / "report.json").read_text())
        out[name] = (score(scene_dir, tmp / "ldr" / "composite.png"), score(scene_dir, tmp / "hdr.png"), rep)
    return out


@pytest.mark.parametrize("name", ["window_room", "lamps_room"])
def test_ldr_composite_against_truth(scored, name):
    ldr, hdr, rep = scored[name]
    assert rep["mode"] == "ldr" and rep["passes"] == rep["n_sources"]  # the all-sources LDR frame
    # the shadow's strength: within 10 % of the truth's, as the HDR path
    assert 0.9 <= ldr["energy_ratio"] <= 1.1, (ldr, hdr)
    # it removes most of the error of leaving the photo untouched (both scenes: 83-89 %)
    assert ldr["rmse_affected"] <= 0.2 * ldr["rmse_affected_if_untouched"], (ldr, hdr)
    # the object is composited the same way in both paths; only the room behind its edges differs
    assert ldr["rmse_object"] <= hdr["rmse_object"] + 1.5, (ldr, hdr)
    assert ldr["spurious"] < 0.02, (ldr, hdr)


def test_ldr_close_to_hdr_on_window_room(scored):
    # one source region (the window): the two-set split is nearly exact
    ldr, hdr, _ = scored["window_room"]
    assert ldr["rmse_affected"] <= 1.5 * hdr["rmse_affected"] + 0.05, (ldr, hdr)
    assert ldr["spurious"] < 0.01, (ldr, hdr)
    assert ldr["rmse_object"] <= hdr["rmse_object"] + 0.25, (ldr, hdr)


@pytest.mark.xfail(strict=True, reason="open: on lamps_room the LDR path's rmse_affected is 6.3 against the HDR "
                                       "path's 1.24, and spurious 0.015 (cause not investigated; the intensity "
                                       "transfers' two-set split is the first suspect)")
def test_ldr_close_to_hdr_on_lamps_room(scored):
    ldr, hdr, _ = scored["lamps_room"]
    assert ldr["rmse_affected"] <= 1.5 * hdr["rmse_affected"] + 0.05, (ldr, hdr)
    assert ldr["spurious"] < 0.01, (ldr, hdr)
