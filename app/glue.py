"""A frame's Python and numpy glue, measured (issue 36: `stages_ms["python"]`): the rendering thread's time
outside Warp kernels.

KernelClock times, on the thread that started it, every outermost `warp.launch` and every
`kernels.runtime.run_parallel` (the launches app.runtime cuts over the cores: the thread waits on them);
launches made from inside those (pooled threads, nested calls) are part of the enclosing one. What a stage
spends outside them is its glue: interpreter time, numpy work, copies to and from the kernels' buffers,
BVH refits, and the waits for the shadow pass's side thread (counted as glue: an upper bound). The wrappers
are installed once, the first time a clock is made; on a thread with no running clock they only pass the
call on (one attribute lookup).
"""
from __future__ import annotations

import functools
import threading
import time

from app import blas

_state = threading.local()
_installed = False


def _timed(fn):
    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        clock = getattr(_state, "clock", None)
        if clock is None or clock._depth:
            return fn(*args, **kwargs)
        clock._depth += 1
        t = time.perf_counter()
        try:
            return fn(*args, **kwargs)
        finally:
            clock.seconds += time.perf_counter() - t
            clock._depth -= 1
    wrapper.__wrapped_by_glue__ = True
    return wrapper


def _install() -> None:
    global _installed
    if _installed:
        return
    import warp as wp

    from kernels import runtime

    if not getattr(wp.launch, "__wrapped_by_glue__", False):
        wp.launch = _timed(wp.launch)
    if not getattr(runtime.run_parallel, "__wrapped_by_glue__", False):
        runtime.run_parallel = _timed(runtime.run_parallel)
    _installed = True


class KernelClock:
    """Seconds the current thread spends in Warp kernels while the clock runs (`with clock:`; re-entrant
    per thread: an inner clock pauses the outer one's count, the outer resumes when it ends)."""

    def __init__(self) -> None:
        _install()
        self.seconds = 0.0
        self._depth = 0
        self._outer = None

    def __enter__(self) -> "KernelClock":
        self._outer = getattr(_state, "clock", None)
        _state.clock = self
        return self

    def __exit__(self, *exc) -> None:
        _state.clock = self._outer
        self._outer = None


class FrameTimer:
    """A frame's stage timer: `tick(name, t)` records the seconds since t as stage `name` (timings) and, of
    them, the seconds outside Warp kernels (glue), from a KernelClock running on this thread from the
    timer's start; `close()` stops the clock. A frame abandoned mid-way leaves its clock on the thread's
    stack until the next clock replaces it: it then counts nothing that matters."""

    def __init__(self) -> None:
        blas.one_thread()  # a frame's matrix products on one BLAS thread until close() (app.blas)
        self.clock = KernelClock().__enter__()
        self.timings: dict[str, float] = {}
        self.glue: dict[str, float] = {}
        self.start = self.last = time.perf_counter()  # the timer's start, the last tick's end
        self._k_last = 0.0

    def tick(self, name: str, t: float) -> float:
        """Record stage `name` as the time since t (perf_counter seconds); returns now."""
        now = time.perf_counter()
        self.timings[name] = now - t
        k = self.clock.seconds
        self.glue[name] = self.timings[name] - (k - self._k_last)
        self._k_last = k
        self.last = now
        return now

    def close(self) -> float:
        """Stop the clock; returns the frame's seconds from the timer's start to its last tick: the ticks
        enclose the frame exactly (a frame ends at its last tick; a thread switch before close() would
        otherwise add a few unstaged microseconds to the frame, more on a loaded machine)."""
        frame_s = self.last - self.start
        self.clock.__exit__(None, None, None)
        blas.own_threads()
        return frame_s
