"""bench/bench_patch_info's measurement and bias model against analytic cases (issue 34 item 6, cam48)."""
import numpy as np

from bench.bench_patch_info import boundary_offset, disk_fraction, model_offset


def test_disk_fraction_is_the_chord_area():
    u = np.array([-1.0, -0.5, 0.0, 0.5, 1.0, 2.0])
    F = disk_fraction(u)
    assert abs(F[2] - 0.5) < 1e-12 and F[0] == 0.0 and abs(F[4] - 1.0) < 1e-12 and abs(F[5] - 1.0) < 1e-12
    assert abs(F[1] + F[3] - 1.0) < 1e-12
    rng = np.random.default_rng(0)
    p = rng.uniform(-1, 1, (400000, 2))
    p = p[np.hypot(p[:, 0], p[:, 1]) <= 1]
    assert abs(np.mean(p[:, 0] < 0.5) - F[3]) < 0.003  # Monte Carlo over the disk


def test_model_offset_of_a_sharp_edge_is_the_pixel_box():
    # no penumbra: the box-averaged step crosses f_c at f_c - 0.5 px (8 sub-samples: steps of 1/8 px)
    n = np.array([[1.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    off = model_offset(np.zeros(3), n, np.array([0.5, 0.1, 0.9]))
    assert np.all(np.abs(off - np.array([0.0, -0.4, 0.4])) <= 0.07)


def test_model_offset_grows_with_the_penumbra():
    # a wide penumbra (w = 3 px) and a low clip fraction put the boundary near its unlit end
    n = np.array([[1.0, 0.0]])
    off = model_offset(np.array([3.0]), n, np.array([0.05]))
    F = disk_fraction(np.array(off / 3.0))
    assert -3.0 < off[0] < -1.5 and abs(F[0] - 0.05) < 0.02


def test_boundary_offset_of_a_step():
    img = np.zeros((100, 200), np.float32)
    img[:, 101:] = 1.0  # clipped from pixel 101 on: the bilinear indicator crosses 0.5 at u = 100.5
    uv = np.array([[100.3, 50.0], [103.0, 20.0]])
    off = boundary_offset(img, uv, np.array([[1.0, 0.0], [1.0, 0.0]]))
    assert np.all(np.abs(off - np.array([0.2, -2.5])) < 0.01)
