"""How a frame's kernel launches are split over the CPU cores: the one place that decides it.

Warp runs a CPU launch on one thread but releases the GIL while it runs, so launches of disjoint
index ranges from two Python threads use two cores (DESIGN "Per-frame masks on Warp CPU":
1.6-1.8x on the 2-core machine). On CUDA a launch is asynchronous and uses the whole device:
one range, no threads. A kernel wrapper takes an index range (lo, hi) and writes its own part of
buffers it was given; `split` cuts [0, n) and runs the parts.
"""
from __future__ import annotations

import os
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Callable

import warp as wp

from kernels import runtime as _kernels_runtime

MAX_PARTS = 8  # never more launches than this at once (the thread pool's size)


def cores() -> int:
    """CPU cores this process may run on."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


def parts(device: str, n: int, min_items: int = 1024) -> int:
    """Launches that `n` items of one kernel are cut into: 1 on CUDA or for small `n` (below
    `min_items` per part a thread costs more than it saves), else one per core."""
    if n <= 0 or not wp.get_device(device).is_cpu:
        return 1
    return max(1, min(cores(), MAX_PARTS, n // max(min_items, 1)))


def ranges(n: int, k: int) -> list[tuple[int, int]]:
    """[0, n) cut into k contiguous ranges of near-equal size (empty ones dropped)."""
    k = max(1, k)
    cuts = [n * i // k for i in range(k + 1)]
    return [(a, b) for a, b in zip(cuts[:-1], cuts[1:]) if b > a]


def split(launch: Callable[[int, int], object], n: int, device: str, min_items: int = 1024) -> None:
    """Run launch(lo, hi) over ranges covering [0, n), one per core on the CPU, concurrently."""
    run([lambda a=a, b=b: launch(a, b) for a, b in ranges(n, parts(device, n, min_items))])


def run(jobs: list[Callable[[], object]]) -> list[object]:
    """Run independent launches concurrently (kernels.runtime's thread pool); their results in order."""
    return _kernels_runtime.run_parallel(jobs)


_background: ThreadPoolExecutor | None = None


def background(work: Callable[[], object]) -> Future:
    """Start `work` on the frame's side thread and return its Future (`.result()` joins it).

    For work that can run while a frame's split launches leave a core idle (the shadow pass draws the
    next batch's maps here while the batch before is summed: app.stages.shadow_pass). One thread, apart
    from the launch pool that `split` and `run` use, so that neither queues behind the other; its tasks
    run one at a time in the order given. The caller joins it before it yields or returns (also on an
    error), so no two frames' work shares a buffer."""
    global _background
    if _background is None:
        _background = ThreadPoolExecutor(max_workers=1, thread_name_prefix="photoar-frame")
    return _background.submit(work)
