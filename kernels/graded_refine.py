"""The graded lattice's refine step (app.stages.shadow_pass.ShadowPass._run_graded) in one launch per spacing.

Points are receiver points (indices into the shadow pass's receiver pixels). Per pending point p of a spacing
(one thread each), with the frame's flags known (summed so far), allowed (wanted) and shadow fractions frac (R,3):

  test 0: none, every point stays pending;
  test 1: the square of p (sq_of[p]) is tested: its four corners sq_corners[sq_of[p]] (-1: none);
  test 2: p's own spacing-2 corners corners[p] are tested (-2: a corner of bilinear weight 0, replaced by the
          first corner, which never has weight 0; -1: none);
  a tested square agrees when every corner used is >= 0 and known and, per channel, the largest and smallest
  fraction of its corners differ by at most tol (no NaN): the numpy rule (frac.max(1) - frac.min(1)).max(1) <= tol,
  the same float64 arithmetic;

  state[t] = 0 where p is known (summed already), 1 where its square agrees (filled), 2 pending;
  a pending point then flags (need = 1) the corners summed next that are wanted and not known:
  mark 1: the corners of its square of the next spacing (next_corners[next_sq[p]]);
  mark 2: its own spacing-2 corners (next_corners[p]), or p itself (if not known) where none of them is wanted;
  mark 0: none.

np.flatnonzero(need) is then the ascending, duplicate-free list numpy's np.unique gave. The writes of 1 by several
threads to one flag are the same value (no race on the result).
"""
from __future__ import annotations

import numpy as np
import warp as wp


@wp.func
def _agree(row: int, cs: wp.array2d(dtype=wp.int32), known: wp.array(dtype=wp.uint8),
           frac: wp.array2d(dtype=wp.float64), tol: wp.float64) -> bool:
    """Whether the corners cs[row] are all summed and their shadow fractions agree within tol (module doc)."""
    first = cs[row, 0]
    if first < 0:
        return False
    if known[first] == wp.uint8(0):
        return False
    for ch in range(3):
        lo = frac[first, ch]
        hi = lo
        if wp.isnan(lo):
            return False
        for k in range(1, 4):
            c = cs[row, k]
            if c == -2:
                c = first
            if c < 0:
                return False
            if known[c] == wp.uint8(0):
                return False
            f = frac[c, ch]
            if wp.isnan(f):
                return False
            lo = wp.min(lo, f)
            hi = wp.max(hi, f)
        if not (hi - lo <= tol):
            return False
    return True


POINTS_PER_THREAD = wp.constant(16)  # consecutive pending points per thread of refine_kernel


@wp.func
def _mark(row: int, next_corners: wp.array2d(dtype=wp.int32), known: wp.array(dtype=wp.uint8),
          allowed: wp.array(dtype=wp.uint8), need: wp.array(dtype=wp.uint8)) -> bool:
    """need = 1 at the corners next_corners[row] that are wanted and not known; whether any is wanted."""
    wanted = False
    for k in range(4):
        c = next_corners[row, k]
        if c >= 0:
            if allowed[c] != wp.uint8(0):
                wanted = True
                if known[c] == wp.uint8(0):
                    need[c] = wp.uint8(1)
    return wanted


@wp.kernel
def refine_kernel(n: int, pend: wp.array(dtype=wp.int64), test: int, sq_of: wp.array(dtype=wp.int64),
                  test_corners: wp.array2d(dtype=wp.int32), known: wp.array(dtype=wp.uint8),
                  frac: wp.array2d(dtype=wp.float64), tol: wp.float64, mark: int,
                  next_sq: wp.array(dtype=wp.int64), next_corners: wp.array2d(dtype=wp.int32),
                  allowed: wp.array(dtype=wp.uint8), state: wp.array(dtype=wp.uint8),
                  need: wp.array(dtype=wp.uint8)):
    """Pending points pend[POINTS_PER_THREAD tid ..] (of n): state and the need flags of the corners summed next
    (module doc). sq_of / next_sq (R,) each point's square of a spacing; test_corners / next_corners (squares
    or points, 4) int32. Consecutive points mostly share their squares (pend ascends in scan order): a square
    tested or marked by the thread's point before is not read again (known, frac and allowed do not change
    during the launch: the same state and flags)."""
    t0 = wp.tid() * POINTS_PER_THREAD
    t1 = wp.min(t0 + POINTS_PER_THREAD, n)
    tested = int(-1)  # the last square tested, and its result
    good = bool(False)
    marked = int(-1)  # the last square of the next spacing marked
    for t in range(t0, t1):
        p = int(pend[t])
        st = int(2)
        if test != 0:
            if known[p] != wp.uint8(0):
                st = 0
            else:
                row = p
                if test == 1:
                    row = int(sq_of[p])
                if row != tested:
                    good = _agree(row, test_corners, known, frac, tol)
                    tested = row
                if good:
                    st = 1
        state[t] = wp.uint8(st)
        if st == 2 and mark == 1:
            row = int(next_sq[p])
            if row != marked:
                _mark(row, next_corners, known, allowed, need)
                marked = row
        elif st == 2 and mark == 2:
            if not _mark(p, next_corners, known, allowed, need) and known[p] == wp.uint8(0):
                need[p] = wp.uint8(1)

class GradedRefine:
    """refine_kernel's launches for one shadow pass: the lattice's tables (each point's squares of spacing 4 and 8,
    the squares' corners, each point's spacing-2 corners) uploaded once; the frame's flags and fractions read in
    place on the CPU (views of the pass's numpy scratch arrays, which it updates between the steps), copied per
    step on CUDA; the state and need flags in buffers made once."""

    def __init__(self, pt_sq: dict[int, np.ndarray], sq_corners: dict[int, np.ndarray], corners: np.ndarray,
                 known: np.ndarray, allowed: np.ndarray, frac: np.ndarray, device: str):
        """pt_sq[s] (R,) and sq_corners[s] (squares, 4) for s in 4, 8; corners (R, 4); known, allowed (R,) bool and
        frac (R, 3) float64: the pass's scratch arrays, updated in place by it (never replaced)."""
        self.device = device
        self.cpu = wp.get_device(device).is_cpu
        self._sq = {s: wp.array(np.ascontiguousarray(pt_sq[s], np.int64), dtype=wp.int64, device=device)
                    for s in (4, 8)}
        self._sq_c = {s: wp.array(np.ascontiguousarray(sq_corners[s], np.int32), dtype=wp.int32, device=device)
                      for s in (4, 8)}
        self._sq_c[2] = wp.array(np.ascontiguousarray(corners, np.int32), dtype=wp.int32, device=device)
        self._host = (known, allowed, frac)
        R = len(known)
        if not (known.dtype == allowed.dtype == np.bool_ and frac.dtype == np.float64 and frac.flags.c_contiguous
                and known.flags.c_contiguous and allowed.flags.c_contiguous):
            raise ValueError("GradedRefine: known and allowed must be contiguous bool arrays, frac contiguous float64")
        if self.cpu:  # views of the pass's arrays: the kernel reads what the pass wrote last
            self._in = (wp.array(known.view(np.uint8), dtype=wp.uint8, device=device, copy=False),
                        wp.array(allowed.view(np.uint8), dtype=wp.uint8, device=device, copy=False),
                        wp.array(frac, dtype=wp.float64, device=device, copy=False))
        self._state = wp.zeros(R, dtype=wp.uint8, device=device)
        self._need = wp.zeros(R, dtype=wp.uint8, device=device)
        self._need_np = self._need.numpy() if self.cpu else None  # on the CPU a view of the device array
        self._need_host = None if self.cpu else np.zeros(R, np.uint8)  # CUDA: the flags' host copy
        self._state_np = self._state.numpy() if self.cpu else None
        self._pend = wp.zeros(R, dtype=wp.int64, device=device)
        self._pend_np = self._pend.numpy() if self.cpu else None

    def _inputs(self):
        if self.cpu:
            return self._in
        known, allowed, frac = self._host
        d = self.device
        return (wp.array(known.view(np.uint8), dtype=wp.uint8, device=d),
                wp.array(allowed.view(np.uint8), dtype=wp.uint8, device=d), wp.array(frac, dtype=wp.float64, device=d))

    def step(self, pend: np.ndarray, test: int, mark: int, tol: float, extra: np.ndarray | None = None
             ) -> tuple[np.ndarray, np.ndarray]:
        """(state (len(pend),) uint8, new: the flagged points, ascending) of refine_kernel over the points pend
        (int64). test: 0 none, 8 or 4 each point's square of that spacing, 2 its own corners; mark: 0 none, 8 or 4
        the corners of each pending point's square of that spacing, 2 its own spacing-2 corners (or itself);
        tol: the refine tolerance; extra: points flagged as well (None: none). Leaves the flags cleared."""
        n, d = len(pend), self.device
        known, allowed, frac = self._inputs()
        if self.cpu:
            self._pend_np[:n] = pend
            need = self._need_np
        else:
            if n:
                wp.copy(self._pend, wp.array(np.ascontiguousarray(pend, np.int64), dtype=wp.int64, device=d),
                        count=n)
            need = self._need_host
        if extra is not None:
            need[extra] = 1
        if not self.cpu:
            self._need.assign(need)
        if n:
            wp.launch(refine_kernel, dim=-(-n // POINTS_PER_THREAD), device=d,
                      inputs=[n, self._pend, _MODE[test], self._sq[test if test in (4, 8) else 4],
                              self._sq_c[test or 2], known, frac, float(tol), _MODE[mark],
                              self._sq[mark if mark in (4, 8) else 4], self._sq_c[mark or 2], allowed,
                              self._state, self._need])
        if self.cpu:
            state = self._state_np[:n].copy()
        else:
            state = self._state.numpy()[:n]
            need[:] = self._need.numpy()
            self._need.zero_()
        new = np.flatnonzero(need)
        need[new] = 0
        return state, new


_MODE = {0: 0, 8: 1, 4: 1, 2: 2}  # step's test / mark -> refine_kernel's
