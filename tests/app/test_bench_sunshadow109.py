"""bench/bench_sunshadow109.py's split of the energy ratio, on a synthetic room with known sums."""
from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np

from recon.io import write_exr, write_png

ROOT = Path(__file__).resolve().parents[2]


def _bench():
    spec = importlib.util.spec_from_file_location("bench_sunshadow109", ROOT / "bench" / "bench_sunshadow109.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _room(tmp: Path) -> tuple[Path, np.ndarray, np.ndarray]:
    """A 120 x 160 room: a sunlit square (exr 10x the rest, png 255: clipped), a shadow in it (png 60), a glow band
    far from the object (truth 10 levels over the photo), the object a small block."""
    H, W = 120, 160
    ex = np.full((H, W, 3), 0.1, np.float32)
    ex[20:100, 80:150] = 1.0
    bg = np.full((H, W, 3), 100, np.uint8)
    bg[20:100, 80:150] = 255
    tr = bg.copy()
    tr[40:80, 95:135] = 60  # the sun shadow, inside the sunlit square
    tr[10:110, 5:40] = 110  # glow on a wall far from the object
    mk = np.zeros((H, W), np.uint8)
    mk[50:70, 60:70] = 255
    write_exr(tmp / "background.exr", ex)
    write_png(tmp / "background.png", bg)
    write_png(tmp / "truth.png", tr)
    write_png(tmp / "truth_mask.png", np.repeat(mk[..., None], 3, 2))
    return tmp, bg, tr


def test_split_sums_and_ratios(tmp_path):
    b = _bench()
    room, bg, tr = _room(tmp_path)
    ours = tr.copy()
    ours[10:110, 5:40] = 105  # half the truth's glow
    write_png(tmp_path / "ours.png", ours)
    s = b.split(room, tmp_path / "ours.png")
    n, t, o, clip = s["all affected"]
    # the sun shadow's darkening counts the same in truth and ours; ours has half the glow: the whole excess
    # (ours - truth) is half the truth's glow, all of it in "unlit, ours brighter" (linear blur: exact)
    glow = s["unlit, ours brighter"]
    assert glow[0] > 30 * 90 and abs((o - t) + 0.5 * glow[1]) < 1e-6 * abs(glow[1])
    core = s["sunlit core"]
    assert core[0] > 0.5 * 30 * 30 and abs(core[2] / core[1] - 1.0) < 1e-9 and core[3] > 0.99  # clipped photo
    assert abs(s["unlit, ours brighter"][2] / s["unlit, ours brighter"][1] - 0.5) < 0.02
    # the parts cover the affected set once (the near/far rows and the last row are sub- or other sets)
    parts = ("sunlit core", "sunlit edge", "sunlit rest", "unlit, ours brighter", "unlit, ours darker")
    assert sum(s[k][0] for k in parts) == n
    assert abs(sum(s[k][1] for k in parts) - t) < 1e-6 * abs(t)


def test_otsu_splits_two_levels():
    b = _bench()
    x = np.concatenate([np.full(500, np.log(0.1)), np.full(300, np.log(1.0))])
    th = b._otsu(x)
    assert np.log(0.1) < th < np.log(1.0)
