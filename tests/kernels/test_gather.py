"""kernels.gather: a batch's scattered columns of host tables, against numpy's fancy index."""
import numpy as np
import warp as wp

from kernels.gather import ColumnGather, host_table
from lighting.frame_sources import ColumnView


def test_columns_and_flags_match_numpys_gather():
    rng = np.random.default_rng(3)
    R, S, n = 37, 200, 23
    table = rng.normal(size=(R + 5, S + 11, 3)).astype(np.float32)
    cand = rng.random((R, S)) < 0.3
    cols = np.sort(rng.choice(S, n, replace=False))[::-1].copy()  # scattered, out of order
    g = ColumnGather(R, 64, "cpu")

    dst = wp.zeros((R + 4, 64), dtype=wp.vec3, device="cpu")
    rows = rng.choice(R, 15, replace=False)
    plain = table[:R, :S]  # a view, not C-contiguous: refused, nothing written
    assert host_table(plain) is None and not g.vec3(plain, rows, rows + 4, cols, dst)
    assert np.all(dst.numpy() == 0)
    full = np.ascontiguousarray(plain)
    assert g.vec3(full, rows, rows + 4, cols, dst)
    out = dst.numpy()
    assert np.array_equal(out[rows + 4, :n], full[rows][:, cols])
    untouched = np.setdiff1d(np.arange(R + 4), rows + 4)
    assert np.all(out[untouched] == 0) and np.all(out[:, n:] == 0)

    # a ColumnView (rows r0.., columns pos) reads its own table's rows and columns
    pos = rng.permutation(S + 11)[:S]
    view = ColumnView(table, 5, 5 + R, pos)
    dst.zero_()
    assert g.vec3(view, rows, rows, cols, dst)
    assert np.array_equal(dst.numpy()[rows, :n], view[rows][:, cols])
    assert np.array_equal(view[rows][:, cols], table[5 + rows][:, pos[cols]])

    flags = wp.zeros((R, 64), dtype=wp.uint8, device="cpu")
    assert g.flags(cand, cols, flags)
    assert np.array_equal(flags.numpy()[:, :n], cand[:, cols].astype(np.uint8))
