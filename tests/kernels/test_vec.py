import numpy as np

from kernels.vec import cross3, same_key


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


def test_same_key_compares_arrays_by_shape_dtype_and_values():
    a = np.arange(6.0).reshape(2, 3)
    key = (a, np.array([[0, 1, 2]]), (24, 2))
    assert same_key(key, (a.copy(), np.array([[0, 1, 2]]), (24, 2)))
    assert not same_key(key, (a + 1e-9, np.array([[0, 1, 2]]), (24, 2)))  # a value
    assert not same_key(key, (a.reshape(3, 2), np.array([[0, 1, 2]]), (24, 2)))  # a shape
    assert not same_key(key, (a.astype(np.float32), np.array([[0, 1, 2]]), (24, 2)))  # a dtype
    assert not same_key(key, (a, np.array([[0, 1, 2]]), (24, 3)))  # the plain entry
    assert not same_key(key, (a, np.array([[0, 1, 2]])))  # a length
    assert not same_key((a,), ([[0.0, 1.0, 2.0], [3.0, 4.0, 5.0]],))  # an array against a list
