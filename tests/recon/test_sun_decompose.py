"""bench/bench_sun_decompose.py: the object's image moved from one camera to another, on analytic cases."""
from __future__ import annotations

import numpy as np

from bench.bench_sun_decompose import displacement, registered
from recon.camera import Camera


def _box(lo, hi) -> tuple[np.ndarray, np.ndarray]:
    """An axis-aligned box's 8 vertices and 12 outward triangles."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    V = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    F = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                  [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]], np.uint32)
    return V, F


def _cams(du: float, dv: float) -> tuple[Camera, Camera]:
    """A 64 x 48 camera at the origin looking down +z, and the same with its principal point moved (du, dv) px."""
    K = np.array([[60.0, 0, 31.5], [0, 60.0, 23.5], [0, 0, 1]])
    K2 = K.copy()
    K2[0, 2] += du
    K2[1, 2] += dv
    return (Camera(K2, np.eye(3), np.zeros(3), 64, 48), Camera(K, np.eye(3), np.zeros(3), 64, 48))


def test_displacement_of_a_moved_principal_point_is_that_move():
    cal, true = _cams(1.0, -0.5)
    V, _ = _box([-0.2, -0.2, 2.0], [0.2, 0.2, 2.4])
    d, spread = displacement(cal, true, V)
    np.testing.assert_allclose(d, [1.0, -0.5], atol=1e-9)
    assert spread < 1e-9


def test_registered_looks_up_the_object_where_the_other_camera_saw_it():
    """A composite that is a linear ramp over the image: bilinear lookup is exact, so on the object's fully
    covered pixels (away from its outline) the registered image is the ramp at the pixel moved by the
    principal point's offset, to the rounding to 8 bits; away from the object it is the composite itself."""
    cal, true = _cams(1.0, -0.5)
    V, F = _box([-0.2, -0.2, 2.0], [0.2, 0.2, 2.4])
    v, u = np.mgrid[0:48, 0:64].astype(float)
    ramp = np.stack([2 * u + 40, 3 * v + 20, u + v + 10], -1)
    out = registered(np.rint(ramp).astype(np.uint8), cal, true, V, F, sub=4).astype(float)
    want = np.stack([2 * (u + 1) + 40, 3 * (v - 0.5) + 20, (u + 1) + (v - 0.5) + 10], -1)
    inner = (np.abs(u - 31.5) <= 3) & (np.abs(v - 23.5) <= 3)  # the box's front face spans +-6 px
    assert np.abs(out[inner] - want[inner]).max() <= 0.51
    far = (np.abs(u - 31.5) > 12) | (np.abs(v - 23.5) > 12)
    assert np.array_equal(out[far], np.rint(ramp)[far])
