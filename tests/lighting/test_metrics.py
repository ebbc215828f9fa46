"""Tests of lighting/metrics.py and `photoar metrics`."""
from __future__ import annotations

import json
import subprocess
import sys

import cv2
import numpy as np
import pytest

from tests.conftest import ROOT, score, shared_scene


def _photo():
    from recon.io import read_image_rgb

    return read_image_rgb(shared_scene("window_room") / "truth.png")


def test_identical_images_score_zero_error_and_ssim_one():
    from lighting import metrics

    img = _photo()
    c = metrics.compare(img, img.copy())
    assert c["rmse"] == 0.0 and c["mae"] == 0.0 and c["max_abs"] == 0.0 and c["psnr_db"] == float("inf")
    assert c["ssim"] == pytest.approx(1.0, abs=1e-12)
    assert c["flip"] is None and "flip-evaluator" in c["flip_note"]  # not installed here: said, not faked
    hdr = img.astype(np.float64) / 255 * 3.0  # radiance-like float images too
    assert metrics.ssim(hdr, hdr) == pytest.approx(1.0, abs=1e-12) and metrics.rmse(hdr, hdr) == 0.0


def test_constant_offset_gives_its_size_and_blur_offset_ordering():
    """+5 levels everywhere -> RMSE 5 exactly; stronger blur and larger shifts -> larger RMSE and lower SSIM."""
    from lighting import metrics

    img = _photo()
    inner = np.zeros(img.shape[:2], bool)
    inner[10:-10, 10:-10] = True  # away from the borders the shifts wrap over
    up = np.clip(img.astype(np.int16) + 5, 0, 255).astype(np.uint8)
    unclipped = (img < 250).all(-1)
    assert metrics.rmse(up, img, unclipped) == pytest.approx(5.0, abs=1e-9)
    blur = [cv2.GaussianBlur(img, (0, 0), s) for s in (0.7, 1.5, 3.0)]
    shift = [np.roll(img, k, axis=1) for k in (1, 2, 4)]
    for series in (blur, shift):
        e = [metrics.rmse(x, img, inner) for x in series]
        s = [metrics.ssim(x, img, inner) for x in series]
        assert e[0] < e[1] < e[2], e
        assert 1.0 > s[0] > s[1] > s[2], s


def test_score_regions_mirrors_the_shared_scorer(tmp_path):
    """The same figures as ../shared/tools/score.py on a perturbed composite (a blurred,
    darkened truth), to 1e-9."""
    from lighting import metrics
    from recon.io import read_image_rgb, write_png

    scene_dir = shared_scene("lamps_room")
    tr = read_image_rgb(scene_dir / "truth.png")
    bg = read_image_rgb(scene_dir / "background.png")
    ours = np.clip(cv2.GaussianBlur(tr, (0, 0), 1.0).astype(np.float64) * 0.97, 0, 255).astype(np.uint8)
    write_png(tmp_path / "ours.png", ours)
    want = score(scene_dir, tmp_path / "ours.png")
    got = metrics.score_regions(ours, bg, tr, cv2.imread(str(scene_dir / "truth_mask.png"), cv2.IMREAD_GRAYSCALE))
    assert got.keys() == want.keys()
    for k in want:
        assert got[k] == pytest.approx(want[k], rel=1e-9, abs=1e-9), k
    # the truth against itself: full shadow energy, no error; the background: none of it
    same = metrics.score_regions(tr, bg, tr, cv2.imread(str(scene_dir / "truth_mask.png"), cv2.IMREAD_GRAYSCALE))
    assert same["energy_ratio"] == pytest.approx(1.0) and same["rmse_affected"] == 0.0
    assert metrics.shadow_energy_ratio(bg, bg, tr, metrics.regions(bg, tr, np.zeros(bg.shape[:2], np.uint8))
                                       ["affected"]) == 0.0


def test_heatmap_scale():
    """Zero error is the map's darkest colour, errors at or above vmax its brightest."""
    from lighting import metrics

    a = np.zeros((20, 30, 3), np.uint8)
    b = a.copy()
    b[:, 15:] = 40
    h = metrics.error_heatmap(a, b, vmax=10.0)
    assert h.shape == (20, 30 + 90, 3) and h.dtype == np.uint8
    lum = h[..., :3].astype(float) @ [0.2126, 0.7152, 0.0722]
    assert lum[:, 15:30].min() > 200 and lum[:, :15].max() < 10
    with pytest.raises(ValueError, match="shapes differ"):
        metrics.compare(a, b[:10])


def test_metrics_cli(tmp_path):
    scene_dir = shared_scene("window_room")
    out = tmp_path / "m"
    cmd = [sys.executable, "-m", "app.cli", "-q", "metrics"]
    p = subprocess.run(cmd + [str(scene_dir / "background.png"), str(scene_dir / "truth.png"), "--mask",
                              str(scene_dir / "truth_mask.png"), "--scene", str(scene_dir), "--out", str(out)],
                       cwd=ROOT, capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    r = json.loads(p.stdout.strip().splitlines()[-1])
    assert r["rmse"] > 0 and r["ssim"] < 1 and r["score"]["energy_ratio"] == 0.0
    assert {f.name for f in out.iterdir()} == {"error.png", "ssim.png", "metrics.json"}
    p = subprocess.run(cmd + [str(scene_dir / "background.png"), str(scene_dir / "probe_00.png")], cwd=ROOT,
                       capture_output=True, text=True)
    assert p.returncode == 2 and "probe_00.png" in p.stderr and "differs" in p.stderr
