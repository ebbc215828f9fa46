"""The shadow fill written straight into the compose stage's buffer (kernels.maskfill.WindowFill.fill's
`out`): at every filled pixel the same value as the fill's own list, bit for bit, on the 3x3 means and
on graded lattices (bilinear over the corners of spacing 4 and 8, the engine's 50-pass frames), over
two launch ranges; every other pixel of the buffer keeps what it held."""
import numpy as np
import warp as wp

from kernels.maskfill import WindowFill


def test_fill_into_a_pixel_buffer_is_the_fill_at_its_pixels(device):
    rng = np.random.default_rng(11)
    W, H = 41, 29
    surface = (np.arange(W)[None, :] // 11 + 7 * (np.arange(H)[:, None] // 9)).reshape(-1).astype(np.int32)
    surface[rng.uniform(size=W * H) < 0.03] = -1
    order = rng.permutation(W * H)
    known, missing = np.sort(order[:260]), np.sort(order[260:900])
    lattice = np.flatnonzero(((np.arange(W * H) % W) % 4 == 0) & ((np.arange(W * H) // W) % 4 == 0))
    known = np.union1d(known, lattice)  # the corners of the lattice squares are known
    missing = np.setdiff1d(missing, known)
    values = rng.uniform(0, 1, (len(known), 3))
    f = WindowFill(W, H, surface, device)
    halves = lambda launch, n: [launch(a, b) for a, b in ((0, n // 2), (n // 2, n))]  # noqa: E731
    for spacing in (2, 4, 8):
        f.set_spacing(missing[::2], spacing)  # half of them on the lattice (2: the 3x3 mean only)
        want = f.fill(known, values, missing).copy()
        assert (np.abs(want).sum(1) > 0).sum() > len(missing) // 2
        for split in (None, halves):
            before = rng.uniform(5, 6, (W * H, 3))  # what the buffer held (no fill value is above 1)
            buf = wp.array(before, dtype=wp.vec3d, device=device)
            assert f.fill(known, values, missing, split=split, out=buf) is None
            got = buf.numpy()
            assert np.array_equal(got[missing], want)
            rest = np.setdiff1d(np.arange(W * H), missing)
            assert np.array_equal(got[rest], before[rest])
