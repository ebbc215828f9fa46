"""A batch's columns of per-source tables gathered into the shadow pass's batch buffers.

The all-sources frame (app.stages.shadow_pass, `order`) draws its sources out of list order (the
full-size maps' first), so each batch takes 64 scattered columns of the (rows, S, 3) transfer tables
and the (P, S) candidate flags. numpy's 2-D fancy index copies those element by element: 15-27 ms a
batch on the loaded 2-core machine (window_room, 64 columns of 3205), against 5-6 ms for these kernels
(one thread per row copies its columns; one launch each: split over the thread pool they waited for a
core longer than they ran). The source tables are read in place (a Warp array over the host memory of a
C-contiguous numpy table: CPU only; ShadowPass keeps the numpy path on CUDA, where the tables are host
memory).
"""
from __future__ import annotations

import numpy as np
import warp as wp

from kernels.buffers import Buffer


@wp.kernel
def _gather_vec3(src: wp.array2d(dtype=wp.vec3), src_rows: wp.array(dtype=wp.int32),
                 dst_rows: wp.array(dtype=wp.int32), cols: wp.array(dtype=wp.int32), n: int,
                 dst: wp.array2d(dtype=wp.vec3)):
    r = wp.tid()
    a = src_rows[r]
    b = dst_rows[r]
    for j in range(n):
        dst[b, j] = src[a, cols[j]]


@wp.kernel
def _gather_u8(src: wp.array2d(dtype=wp.uint8), cols: wp.array(dtype=wp.int32), n: int,
               dst: wp.array2d(dtype=wp.uint8)):
    r = wp.tid()
    for j in range(n):
        dst[r, j] = src[r, cols[j]]


def host_table(a) -> tuple[np.ndarray, int, np.ndarray | None] | None:
    """(table, first row, column positions or None) of an (R,S,3) float32 ndarray or a ColumnView
    (lighting.frame_sources) over a C-contiguous float32 table; None when neither (the caller gathers
    with numpy)."""
    if hasattr(a, "table"):
        t, r0, pos = a.table, a.r0, a.pos
    else:
        t, r0, pos = a, 0, None
    if not isinstance(t, np.ndarray) or t.dtype != np.float32 or t.ndim != 3 or t.shape[2] != 3 \
            or not t.flags.c_contiguous:
        return None
    return t, r0, pos


class ColumnGather:
    """Gathers columns of host tables into a batch buffer on the CPU device (module docstring; the
    tables are read where they lie, so `device` is "cpu"). rows: the most rows one call gathers; batch:
    the most columns."""

    def __init__(self, rows: int, batch: int, device: str):
        self.device = device
        self.src_rows = Buffer(rows, wp.int32, device)
        self.dst_rows = Buffer(rows, wp.int32, device)
        self.cols = Buffer(batch, wp.int32, device)

    def vec3(self, table, src_rows: np.ndarray, dst_rows: np.ndarray, cols: np.ndarray, dst: wp.array) -> bool:
        """dst[dst_rows[i], j] = table[src_rows[i], cols[j]] for an (R,S,3) table or ColumnView
        (its own rows and columns: the view's); False (nothing written) when the table is not a
        host float32 table (host_table)."""
        h = host_table(table)
        if h is None:
            return False
        t, r0, pos = h
        n = len(src_rows)
        if n == 0 or len(cols) == 0:
            return True
        self.src_rows.upload(np.asarray(src_rows) + r0)
        self.dst_rows.upload(np.asarray(dst_rows))
        self.cols.upload(np.asarray(cols) if pos is None else pos[cols])
        src = wp.array(ptr=t.ctypes.data, dtype=wp.vec3, shape=t.shape[:2], device="cpu")  # t outlives the launch
        wp.launch(_gather_vec3, dim=n, inputs=[src, self.src_rows.dev, self.dst_rows.dev, self.cols.dev, len(cols)],
                  outputs=[dst], device=self.device)
        return True

    def flags(self, cand: np.ndarray, cols: np.ndarray, dst: wp.array) -> bool:
        """dst[r, j] = cand[r, cols[j]] for every row of a C-contiguous (P,S) bool/uint8 array; False
        (nothing written) otherwise."""
        if not isinstance(cand, np.ndarray) or cand.ndim != 2 or cand.itemsize != 1 or not cand.flags.c_contiguous:
            return False
        self.cols.upload(np.asarray(cols))
        c = cand.view(np.uint8)
        src = wp.array(ptr=c.ctypes.data, dtype=wp.uint8, shape=c.shape, device="cpu")  # c outlives the launch
        wp.launch(_gather_u8, dim=len(c), inputs=[src, self.cols.dev, len(cols)], outputs=[dst], device=self.device)
        return True
