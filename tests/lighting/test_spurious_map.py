"""bench.bench_spurious_map: its per-region split of `spurious` adds up to the shared scorer's figure.

A composite made from sun_room's background with a known change (3 levels added over a rectangle of
its wall, 1.5 over one of its floor: only the first exceeds the scorer's 2 levels) is scored by
../shared/tools/score.py; the map's report of the same image, split into two regions that tile the
frame, must give the same spurious share in total and as the sum of its regions; the spurious pixels
must cover the first rectangle (less the blur's fringe), none of the second, and be brighter.
"""
import json
import subprocess
import sys

import cv2
import numpy as np

from bench.bench_spurious_map import LUM_BGR, _blur, report, scorer_maps
from tests.conftest import SHARED, shared_scene


def test_map_split_adds_up_to_the_scorers_spurious(tmp_path):
    scene = shared_scene("sun_room")
    bg = cv2.imread(str(scene / "background.png"))
    H, W = bg.shape[:2]
    img = bg.astype(np.float64)
    img[40:120, 300:440] += 3.0  # over the threshold where the truth is unchanged
    img[360:420, 60:220] += 1.5  # under it
    comp = np.clip(np.rint(img), 0, 255).astype(np.uint8)
    path = tmp_path / "composite.png"
    cv2.imwrite(str(path), comp)
    ref = json.loads(subprocess.check_output([sys.executable, str(SHARED / "tools" / "score.py"), str(scene),
                                              str(path)]))
    frames = {k: _blur(comp.astype(np.float64) @ LUM_BGR, 2.0)
              for k in ("full", "no object light", "no second order", "shadows only")}
    top = np.zeros((H, W), bool)
    top[: H // 2] = True
    rep = report(frames, {"top half": top, "bottom half": ~top}, scene)
    assert abs(rep["spurious"] - ref["spurious"]) < 1e-12, (rep["spurious"], ref["spurious"])
    rows = rep["rows"]
    assert abs(rows["top half"]["spurious"] + rows["bottom half"]["spurious"] - rep["spurious"]) < 1e-12
    assert abs(rows["all"]["spurious"] - rep["spurious"]) < 1e-12
    # where it lands: the 3-level rectangle (less the blur's fringe, where it falls under 2), brighter only
    lb, _, _, rest = scorer_maps(scene)
    d = frames["full"] - lb
    sp = rest & (np.abs(d) > 2.0)
    inner = np.zeros((H, W), bool)
    inner[46:114, 306:434] = True
    assert sp[inner & rest].mean() > 0.99 and not sp[360:420, 60:220].any()
    assert rows["all"]["darker"] < 0.2 * rows["all"]["brighter"], rows["all"]
