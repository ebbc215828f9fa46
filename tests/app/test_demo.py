"""`photoar demo` on the bundled scene (no ../shared needed): the picture and its report."""
import json

import numpy as np

from app.cli import demo_scene_dir, main as cli
from recon.io import read_exr
from recon.scene import load_scene


def test_demo_writes_picture(tmp_path, capsys):
    out = tmp_path / "demo"
    assert cli(["-q", "demo", "--out", str(out)]) == 0
    assert str(out / "composite.png") in capsys.readouterr().out
    rep = json.loads((out / "report.json").read_text())
    assert rep["n_sources"] > 0 and rep["frame_s"] > 0
    scene = load_scene(demo_scene_dir())
    import cv2

    img = cv2.imread(str(out / "composite.png"))[..., ::-1]
    assert img.shape == scene.photo.shape
    diff = np.abs(img.astype(int) - scene.photo.astype(int)).max(-1)
    # the chair covers some pixels and darkens the floor around it; the far room is untouched
    assert 0.005 < (diff > 2).mean() < 0.2
    assert diff[:20].max() <= 1  # ceiling strip, far from the chair: at most a level of second-order light
    hdr = read_exr(out / "composite.exr")
    assert hdr.shape == scene.photo.shape and np.isfinite(hdr).all() and hdr.min() >= 0
