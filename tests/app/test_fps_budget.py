"""--fps (issue 17, item 8): with a given cost model (fixed seconds per frame + seconds per shadow
pass), the frame takes the most passes whose predicted time fits 1/fps; never fewer than one
while there are sources, never more than --passes or the sources listed; fewer as fps rises."""
import numpy as np
import pytest

from app.cli import demo_scene_dir
from app.dragpath import moved
from app.engine import Engine, EngineParams, FrameConfig
from recon.scene import load_scene

FIXED, PER_PASS = 0.05, 0.002  # the injected cost model, seconds


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    scene = load_scene(demo_scene_dir())
    eng = Engine(scene, EngineParams(patch_size=0.35, emitter_patch_size=0.2),
                 cache_dir=tmp_path_factory.mktemp("cache"), device="cpu", quiet=True)
    return scene, eng


def _passes(eng, obj, cfg) -> tuple[int, int]:
    """(passes the frame took under the injected cost model, sources listed for it)."""
    eng.budget.cost = {"fixed_s": FIXED, "per_pass_s": PER_PASS}
    st = eng.render(obj, cfg).stats
    return st["passes"], st["n_sources"]


def _predicted(n: int) -> float:
    return FIXED + n * PER_PASS


def test_chosen_passes_fit_the_budget_and_one_more_would_not(demo):
    scene, eng = demo
    n_all = eng.render(scene.obj, FrameConfig(passes=None)).stats["passes"]
    assert n_all > 40  # enough sources that the budget, not the source count, decides
    seen = []
    for fps in (19.0, 16.0, 12.5, 11.0, 9.0, 8.0):  # budgets of 1..75 passes at the cost above
        n, listed = _passes(eng, scene.obj, FrameConfig(fps=fps))
        assert listed == n_all and 1 <= n <= n_all
        assert _predicted(n) <= 1.0 / fps + 1e-12, (fps, n)  # fits
        assert n == n_all or _predicted(n + 1) > 1.0 / fps, (fps, n)  # and one more pass would not
        seen.append(n)
    assert seen == sorted(seen) and len(set(seen)) > 3  # more time per frame, more passes
    # --passes caps the budget: the frame takes min(cap, what fits)
    assert _passes(eng, scene.obj, FrameConfig(fps=8.0, passes=12))[0] == 12
    assert _passes(eng, scene.obj, FrameConfig(fps=19.0, passes=12))[0] == seen[0]
    # a budget far beyond every source: all of them, the all-sources count
    assert _passes(eng, scene.obj, FrameConfig(fps=0.01))[0] == n_all


def test_budget_below_the_fixed_cost_still_casts_a_shadow(demo):
    scene, eng = demo
    for fps in (1.0 / FIXED, 100.0, 1e4):  # no time left for passes, or less than none
        assert _passes(eng, scene.obj, FrameConfig(fps=fps))[0] == 1


def test_no_sources_no_passes_and_no_cost_learnt(demo):
    # far outside the room the object's box meets no shaft: no source is listed, no pass is drawn
    # under any budget, and the per-pass cost is not learnt from a frame without passes
    scene, eng = demo
    away = moved(scene.obj, np.array([0.0, 50.0, 0.0]))
    for fps in (1.0, 100.0):
        eng.budget.cost = {"fixed_s": FIXED, "per_pass_s": PER_PASS}
        st = eng.render(away, FrameConfig(fps=fps)).stats
        assert st["passes"] == 0 and st["n_sources"] == 0
        assert eng.budget.cost == {"fixed_s": FIXED, "per_pass_s": PER_PASS}
    # the first --fps frame with no cost measured yet: the calibration frame has no passes to time either
    eng.budget.cost = None
    st = eng.render(away, FrameConfig(fps=30.0)).stats
    assert st["passes"] == 0 and st["fps_calibration_s"] > 0 and eng.budget.cost is None
    # with sources again, the next frame measures its costs and keeps to a budget
    st = eng.render(scene.obj, FrameConfig(fps=1e3)).stats
    assert st["fps_calibration_s"] > 0 and st["passes"] == 1 and eng.budget.cost["per_pass_s"] > 0
