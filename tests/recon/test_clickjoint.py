"""recon/clickjoint: a clicked wall solved with the pieces held against it."""
import json
import logging
import os
from pathlib import Path

import numpy as np
import pytest

from recon.clickbase import Wall
from recon.clickjoint import joint_walls

ROOMS = Path(os.environ.get("PHOTOAR_ROOMS", Path.home() / ".cache" / "photoar" / "rooms"))


class _P:
    """The two fields of recon.clickbase._Clicks that joint_walls reads and writes."""

    def __init__(self, wall_sd, against):
        self.wall_sd, self.against = wall_sd, against


def _box(name, lo, hi):
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    return {"name": name, "center": ((lo + hi) / 2).tolist(), "size": (hi - lo).tolist()}


def test_wall_and_pieces_by_inverse_variance():
    """Analytic: the left wall at x = 0.04 (sd 2 cm) and two pieces held on it whose own fits of that
    side say 0.00 (sd 2 cm) and 0.01 (sd 1 cm): the plane is their inverse-variance mean, 1.33 cm
    (weights 1 : 1 : 4), its sd 1 / sqrt(1/4 + 1/4 + 1) cm; both pieces' held sides then lie on it,
    their far sides kept, a desk's legs at their inset and size to the stretch's scale (a 6.7 mm
    move on a 1.2 m desk: 0.2 mm)."""
    w = Wall("left", 0, -1, 0.04, ["left"], sd=0.02)
    lo, hi = np.array([0.04, 0.0, np.nan]), np.array([np.nan, 2.5, np.nan])
    P = _P({(0, -1): 0.02}, {(0, -1): [("cabinet", 0.0, 0.02 ** 2), ("desk", 0.01, 0.01 ** 2)]})
    cabinet = [_box("cabinet", [0.03, 0, 1.0], [0.53, 0.9, 2.0])]
    desk = [_box("desk_top", [0.02, 0.7, 3.0], [1.22, 0.74, 4.0]),
            _box("desk_leg0", [0.06, 0.0, 3.04], [0.11, 0.7, 3.09]),
            _box("desk_leg1", [1.13, 0.0, 3.04], [1.18, 0.7, 3.09])]
    moved = joint_walls(P, {"left": w}, lo, hi, {"cabinet": cabinet, "desk": desk})
    want = (0.04 / 0.02 ** 2 + 0.0 / 0.02 ** 2 + 0.01 / 0.01 ** 2) / (2 / 0.02 ** 2 + 1 / 0.01 ** 2)
    assert want == pytest.approx(0.08 / 6, abs=1e-12)
    assert w.offset == pytest.approx(want, abs=1e-12) and lo[0] == pytest.approx(want, abs=1e-12)
    assert moved["left"] == pytest.approx(want - 0.04, abs=1e-12)
    assert P.wall_sd[(0, -1)] == pytest.approx(1 / np.sqrt(1 / 0.02 ** 2 * 2 + 1 / 0.01 ** 2), abs=1e-12)
    for boxes, far in ((cabinet, 0.53), (desk, 1.22)):
        x0 = min(b["center"][0] - b["size"][0] / 2 for b in boxes)
        x1 = max(b["center"][0] + b["size"][0] / 2 for b in boxes)
        assert x0 == pytest.approx(want, abs=1e-12) and x1 == pytest.approx(far, abs=1e-12)
    leg = desk[1]
    assert leg["center"][0] - leg["size"][0] / 2 - want == pytest.approx(0.04, abs=3e-4)
    assert leg["size"][0] == pytest.approx(0.05, abs=3e-4)
    assert desk[0]["center"][1] == pytest.approx(0.72) and cabinet[0]["center"][2] == pytest.approx(1.5)


def test_no_variance_no_move():
    """A wall whose sd is not known (0) keeps its place, and so do the pieces on it."""
    w = Wall("back", 2, -1, 0.02, ["back"])
    lo, hi = np.array([np.nan, 0.0, 0.02]), np.array([np.nan, 2.5, np.nan])
    box = [_box("bench", [1.0, 0, 0.02], [2.0, 0.45, 0.5])]
    P = _P({(2, -1): 0.0}, {(2, -1): [("bench", 0.0, 0.01 ** 2)]})
    assert joint_walls(P, {"back": w}, lo, hi, {"bench": box}) == {}
    assert w.offset == 0.02 and lo[2] == 0.02 and box[0]["center"][2] == pytest.approx(0.26)


def test_grazing_wall_takes_the_bench_against_it():
    """sun_101 (rendered by roomgen, not tuned on): its left wall's foot is seen at a grazing angle (1 px
    = 4.5 cm of floor) and grainy (it snaps on 2 of 10 seeds), and a bench stands against it. Ten seeds
    of 1 px noise, refined against the photo: with the wall solved together with the bench's own fit
    of its wall side, the wall is within 3 cm on at least 9 seeds (measured 9; 8 from the wall's
    clicks and foot alone, worst 4.6 -> 3.2 cm) and its mean error over the seeds is lower (measured
    1.68 -> 0.98 cm)."""
    root = ROOMS / "sun_101"
    if not (root / "scene.json").is_file():
        pytest.skip(f"unseen room {root} not rendered (bench/bench_unseen.py --render)")
    import recon.clickmodel as cm
    from bench.clicks_truth import true_clicks
    from recon.camera import Camera
    from recon.edgesnap import EdgeImage
    from recon.io import read_image_rgb

    sc = json.loads((root / "scene.json").read_text())
    cam = Camera.from_json(sc["main_camera"], str(root), "main_camera.")
    edges = EdgeImage(read_image_rgb(root / "background.png"))
    truth = sc["world"]["room_min"][0]
    errs = {True: [], False: []}
    logging.disable(logging.WARNING)
    original = cm.joint_walls
    try:
        for seed in range(10):
            clicks, done = true_clicks(sc, sigma_px=1.0, seed=seed)
            assert "left" in done["walls"]
            ch = None if done["ceiling"] else sc["world"]["room_max"][1]
            for joint in (True, False):
                cm.joint_walls = original if joint else (lambda *a, **k: {})
                m = cm.model_from_clicks(clicks, cam, "sun_101", ch, photo=edges)
                errs[joint].append(abs(float(m.lo[0]) - truth))
    finally:
        cm.joint_walls = original
        logging.disable(logging.NOTSET)
    e1, e0 = np.array(errs[True]), np.array(errs[False])
    print(f"sun_101 left wall: worst {e0.max() * 100:.1f} -> {e1.max() * 100:.1f} cm, mean {e0.mean() * 100:.2f} -> "
          f"{e1.mean() * 100:.2f} cm, within 3 cm {(e0 <= 0.03).sum()} -> {(e1 <= 0.03).sum()} of 10")
    assert (e1 <= 0.03).sum() >= 9, e1
    assert e1.mean() < e0.mean(), (e1, e0)
