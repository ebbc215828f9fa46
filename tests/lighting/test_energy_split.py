"""bench/bench_photoneg109.split: score.py's energy, split by region, on an analytic room (photoneg109)."""
import cv2
import numpy as np
import pytest

from bench.bench_photoneg109 import split
from tests.conftest import score


def _room(tmp_path, glow: float):
    """A 120x160 grey room: a clipped floor band (bg 255) with a 40-level shadow in the truth, a wall patch the
    object lights (truth +10 levels), the object a square; the composite has the truth's shadow and the wall patch
    lit by 10 + glow levels."""
    bg = np.full((120, 160, 3), 100, np.uint8)
    bg[80:] = 255
    mask = np.zeros((120, 160), np.uint8)
    mask[50:70, 70:90] = 255
    tr = bg.copy()
    tr[85:110, 60:100] = 215  # the shadow on the clipped floor
    tr[10:40, 100:150] = 110  # the wall the object lights
    tr[mask > 0] = 60
    co = tr.copy()
    co[10:40, 100:150] = 110 + int(glow)
    co[mask > 0] = 60
    for name, im in (("background", bg), ("truth", tr), ("truth_mask", mask), ("composite", co)):
        cv2.imwrite(str(tmp_path / f"{name}.png"), im)
    return tmp_path


@pytest.mark.parametrize("glow", [0.0, 6.0])
def test_split_matches_scorer_and_adds_up(tmp_path, glow):
    """The energy equals score.py's (1e-9); clipped + unclipped and ring + beyond each sum to d_ours / d_truth
    (relative 1e-9); the object's pixels are the truth's, so swapping them in changes nothing. With the truth's own
    composite the energy is 1; with the lit wall 6 levels too bright (the clipped shadow exact) it drops by the
    unclipped excess alone: 1 - 6 x 1500 px / d_truth, within the blur's edge (5 %)."""
    room = _room(tmp_path, glow)
    d = split(str(room), str(room / "composite.png"))
    s = score(room, room / "composite.png")
    assert d["energy"] == pytest.approx(s["energy_ratio"], rel=1e-9)
    assert d["bg_clipped"]["d_ours"] == pytest.approx(d["bg_clipped"]["d_truth"], rel=1e-9)
    excess = d["bg_unclipped"]["d_truth"] - d["bg_unclipped"]["d_ours"]
    assert excess == pytest.approx(6.0 * 1500 * (glow > 0), rel=0.05, abs=1e-6)
    tot_t = d["ring"]["d_truth"] + d["beyond"]["d_truth"]
    tot_o = d["ring"]["d_ours"] + d["beyond"]["d_ours"]
    assert d["bg_clipped"]["d_truth"] + d["bg_unclipped"]["d_truth"] == pytest.approx(tot_t, rel=1e-9)
    assert d["bg_clipped"]["d_ours"] + d["bg_unclipped"]["d_ours"] == pytest.approx(tot_o, rel=1e-9)
    assert tot_o / tot_t == pytest.approx(d["energy"], rel=1e-9)
    assert d["energy"] == pytest.approx(1.0 - excess / tot_t, rel=1e-9)
    assert d["object_swapped_energy"] == pytest.approx(d["energy"], rel=1e-9)
