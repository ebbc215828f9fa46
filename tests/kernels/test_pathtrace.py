"""Tests of the Monte-Carlo differential renderer (kernels/pathtrace.py) and `photoar reference`."""
from __future__ import annotations

import json
import subprocess
import sys
from types import SimpleNamespace

import numpy as np
import pytest

from tests.conftest import ROOT, score, shared_scene


def _quad(name, corners, albedo, emission=(0, 0, 0), role="room"):
    c = np.asarray(corners, np.float64)
    n = np.cross(c[1] - c[0], c[3] - c[0])
    from recon.scene import Quad

    return Quad(name, c, n / np.linalg.norm(n), np.asarray(albedo, float), np.asarray(emission, float), role)


def _lamp_scene(obj=None):
    """A 10 x 10 m floor (albedo 0.5) under a 0.4 x 0.4 m emitter 1 m up facing down (L_e = 10),
    seen from 0.5 m above the floor by a camera looking straight down with a narrow view."""
    from recon.camera import Camera
    from recon.patches import build_patches

    floor = _quad("floor", [[-5, 0, -5], [-5, 0, 5], [5, 0, 5], [5, 0, -5]], [0.5, 0.5, 0.5])
    lamp = _quad("lamp", [[-0.2, 1, -0.2], [0.2, 1, -0.2], [0.2, 1, 0.2], [-0.2, 1, 0.2]], [0, 0, 0],
                 [10.0, 10.0, 10.0], "ceiling_lamp")
    assert floor.normal[1] > 0 and lamp.normal[1] < 0
    pm = build_patches(SimpleNamespace(quads=[floor, lamp]), 1.0, 0.1)
    # camera at (0, 0.5, 0) looking down -y; image x = world +x, image y = world +z
    R = np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]])
    cam = Camera(np.array([[2000.0, 0, 15.5], [0, 2000.0, 15.5], [0, 0, 1]]), R, -R @ np.array([0, 0.5, 0]), 32, 32)
    return pm, cam


def test_direct_light_matches_analytic_form_factor(device):
    """One bounce under a square lamp: L = rho * L_e * F(point -> lamp), F in closed form."""
    from kernels.pathtrace import PathTracer

    pm, cam = _lamp_scene()
    pt = PathTracer(pm, cam, device=device)
    pix = np.array([r * 32 + c for r in range(12, 20) for c in range(12, 20)])
    res = pt.render(pix, 64, seed=3, bounces=1)
    L = res.noobj.mean(0) / 64
    # the pixels cover about 2 mm of floor round the origin: the form factor at the origin to the
    # lamp, four corner rectangles of X = Y = 0.2 (half side / height), each
    # F = 1/(2 pi) [X/sqrt(1+X^2) atan(Y/sqrt(1+X^2)) + Y/sqrt(1+Y^2) atan(X/sqrt(1+Y^2))]
    X = Y = 0.2
    F = 4 / (2 * np.pi) * (X / np.sqrt(1 + X * X) * np.arctan(Y / np.sqrt(1 + X * X))
                           + Y / np.sqrt(1 + Y * Y) * np.arctan(X / np.sqrt(1 + Y * Y)))
    expected = 0.5 * 10.0 * F  # rho * L_e * F
    np.testing.assert_allclose(L, expected, rtol=0.01)
    np.testing.assert_array_equal(res.noobj, res.obj)  # no object: both renders are the same


def test_object_shadow_and_exact_zero_difference_where_untouched(device):
    """A plate under the lamp blacks out the floor below it; an object far from every light path
    leaves I_obj bit-identical to I_noobj (correlated sampling)."""
    from kernels.pathtrace import PathTracer

    pm, cam = _lamp_scene()
    plate_v = np.array([[-0.5, 0.7, -0.5], [0.5, 0.7, -0.5], [0.5, 0.7, 0.5], [-0.5, 0.7, 0.5]])
    plate_f = np.array([[0, 1, 2], [0, 2, 3]])
    n = np.tile([0, 1.0, 0], (4, 1))
    pix = np.arange(0, 32 * 32, 7)
    pt = PathTracer(pm, cam, plate_v, n, plate_f, [0.6, 0.6, 0.6], device=device)
    r = pt.render(pix, 8, seed=5, bounces=1)  # one bounce: the plate's own reflection never reaches the camera
    assert np.all(r.obj == 0.0) and np.all(r.noobj > 0)
    np.testing.assert_allclose(r.diff, r.noobj)
    far_v = np.array([[4.0, 0.05, 4.0], [4.2, 0.05, 4.0], [4.0, 0.25, 4.0]])
    pt = PathTracer(pm, cam, far_v, np.tile([0, 0, -1.0], (3, 1)), np.array([[0, 1, 2]]), [0.6] * 3, device=device)
    r = pt.render(pix, 8, seed=5, bounces=1)
    np.testing.assert_array_equal(r.obj, r.noobj)
    assert np.all(r.diff == 0.0)


def _affected_pixels(scene_dir):
    """Flat indices of score.py's affected and object regions (what the energy ratio looks at)."""
    from lighting import metrics
    from recon.io import read_image_rgb
    import cv2

    bg, tr = read_image_rgb(scene_dir / "background.png"), read_image_rgb(scene_dir / "truth.png")
    r = metrics.regions(bg, tr, cv2.imread(str(scene_dir / "truth_mask.png"), cv2.IMREAD_GRAYSCALE))
    return np.flatnonzero((r["affected"] | r["mask"]).reshape(-1))


@pytest.mark.parametrize("name", ["window_room", "lamps_room"])
def test_reference_agrees_with_truth_energy(name, tmp_path):
    """The reference over its own scene model reproduces the path-traced truth's shadow energy:
    rendered at 4 spp where score.py looks (affected + object regions; elsewhere the photo)."""
    from app.cmd_reference import render_reference
    from recon.io import write_png
    from recon.scene import load_scene

    scene_dir = shared_scene(name)
    scene = load_scene(scene_dir)
    ref = render_reference(scene, 4, seed=2, batch_spp=1, pixels=_affected_pixels(scene_dir), quiet=True)
    write_png(tmp_path / "ref.png", ref.pixels)
    s = score(scene_dir, tmp_path / "ref.png")
    assert 0.9 <= s["energy_ratio"] <= 1.1, s
    assert s["rmse_affected"] < 0.5 * s["rmse_affected_if_untouched"], s
    assert s["spurious"] < 2e-3  # pixels not rendered keep the photo (the blur spreads the edge a little)


def test_model_without_object_matches_background_exr():
    """I_noobj (4 bounces, textured model) against the truth renderer's background.exr on a
    pixel subsample: total radiance within 2 %; fewer bounces are darker."""
    from app.cmd_reference import build_tracer
    from recon.io import read_exr
    from recon.scene import load_scene

    scene_dir = shared_scene("window_room")
    scene = load_scene(scene_dir)
    tr = build_tracer(scene)
    pix = np.arange(0, scene.camera.width * scene.camera.height, 151)
    bg = read_exr(scene_dir / "background.exr").reshape(-1, 3)[pix].astype(np.float64)
    r4 = tr.render(pix, 4, seed=1, bounces=4)
    r1 = tr.render(pix, 4, seed=1, bounces=1)
    ratio = r4.noobj.sum(0) / 4 / bg.sum(0)
    np.testing.assert_allclose(ratio, 1.0, atol=0.02)
    assert (r1.noobj.sum() / r4.noobj.sum()) < 0.9


def test_noise_estimate_is_honest():
    """Two seeds differ by about the reported noise: RMS (A - B) / sqrt(2) against the RMS of the
    reported standard errors, over a crop round the object."""
    from app.cmd_reference import build_tracer, render_reference
    from recon.scene import load_scene

    scene = load_scene(shared_scene("window_room"))
    W = scene.camera.width
    uv, _ = scene.camera.project(scene.obj.vertices)
    u0, v0 = np.floor(uv.min(0)).astype(int) - 10
    u1, v1 = np.ceil(uv.max(0)).astype(int) + 10
    pix = np.array([v * W + u for v in range(v0, v1, 2) for u in range(u0, u1, 2)])
    tracer = build_tracer(scene)
    runs = [render_reference(scene, 8, seed=s, batch_spp=1, pixels=pix, tracer=tracer, quiet=True) for s in (21, 22)]
    for key in ("noise", "noise_diff"):
        se = np.concatenate([getattr(r, key).reshape(-1, 3)[pix] for r in runs])
        rep = np.sqrt(np.mean(se ** 2))
        if key == "noise":
            a, b = (r.composite.reshape(-1, 3)[pix] for r in runs)
        else:
            a, b = ((r.I_noobj - r.I_obj).reshape(-1, 3)[pix] for r in runs)
        observed = np.sqrt(np.mean((a - b) ** 2) / 2)
        assert rep > 0
        assert 0.75 < observed / rep < 1.33, (key, observed, rep)


def test_reference_cli(tmp_path):
    """`photoar reference` writes the PNG, EXRs and report; bad input ends with exit 2 and nothing."""
    scene_dir = shared_scene("lamps_room")
    out = tmp_path / "ref"
    cmd = [sys.executable, "-m", "app.cli", "-q", "reference"]
    p = subprocess.run(cmd + [str(scene_dir), "--spp", "2", "--batch-spp", "1", "--bounces", "2", "--out", str(out)],
                       cwd=ROOT, capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    assert {f.name for f in out.iterdir()} == {"reference.png", "reference.exr", "I_obj.exr", "I_noobj.exr",
                                               "noise.exr", "report.json"}
    rep = json.loads((out / "report.json").read_text())
    assert rep["spp"] == 2 and rep["batches"] == 2 and rep["noise_levels_rms"] > 0
    bad = tmp_path / "bad"
    p = subprocess.run(cmd + [str(tmp_path / "missing"), "--spp", "2", "--out", str(bad)], cwd=ROOT,
                       capture_output=True, text=True)
    assert p.returncode == 2 and "photoar: error:" in p.stderr and "missing" in p.stderr
    assert not bad.exists()


def test_noise_target_stops_early_and_noise_falls_with_spp():
    """A loose noise target stops after the third batch; the reported noise falls like 1/sqrt(spp)."""
    from app.cmd_reference import build_tracer, render_reference
    from recon.scene import load_scene

    scene = load_scene(shared_scene("lamps_room"))
    W = scene.camera.width
    uv, _ = scene.camera.project(scene.obj.vertices)
    u0, v0 = np.floor(uv.min(0)).astype(int)
    u1, v1 = np.ceil(uv.max(0)).astype(int)
    pix = np.array([v * W + u for v in range(v0, v1, 3) for u in range(u0, u1, 3)])
    tracer = build_tracer(scene)
    r = render_reference(scene, 64, seed=4, batch_spp=1, noise_target=1e6, pixels=pix, tracer=tracer, quiet=True)
    assert r.stats["stopped_by"] == "noise_target" and r.spp == 3
    lo = render_reference(scene, 4, seed=5, batch_spp=1, pixels=pix, tracer=tracer, quiet=True)
    hi = render_reference(scene, 16, seed=6, batch_spp=2, pixels=pix, tracer=tracer, quiet=True)
    ratio = np.sqrt(np.mean(lo.noise.reshape(-1, 3)[pix] ** 2) / np.mean(hi.noise.reshape(-1, 3)[pix] ** 2))
    assert 1.6 < ratio < 2.5  # 4x the samples: half the noise
