import numpy as np

from kernels.vec import cross3


def test_cross3_gives_np_cross_bytes():
    # triangle normals, broadcast rows against one vector, float32 with float64, 3-D stacks: np.cross's bytes
    rng = np.random.default_rng(7)
    t = rng.normal(size=(500, 3, 3)) * 10.0 ** rng.integers(-4, 4, (500, 1, 1))
    cases = [(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), (t[:, 0], np.array([0.0, 1.0, 0.0])),
             ([1.0, 0.0, 0.0], t[:, 1]), (t[:, 0].astype(np.float32), t[:, 1]), (t, t[:, ::-1]),
             (t[0, 0], t[0, 1])]
    for a, b in cases:
        want, got = np.cross(a, b), cross3(a, b)
        assert got.dtype == want.dtype and got.shape == want.shape
        assert got.tobytes() == want.tobytes()
    assert not np.array_equal(cross3(t[:, 0], t[:, 1]), cross3(t[:, 1], t[:, 0]))  # the order matters
