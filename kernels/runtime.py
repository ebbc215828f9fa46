"""Warp initialisation and device choice shared by every kernel wrapper."""
from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from typing import Callable

import warp as wp

_initialised = False


def init() -> None:
    """Initialise Warp once (kernels/__init__ silences its banner)."""
    global _initialised
    if not _initialised:
        wp.init()
        _initialised = True


def device(name: str | None = None) -> str:
    """Resolve a device name: explicit argument, else $PHOTOAR_DEVICE, else "cpu"."""
    init()
    name = name or os.environ.get("PHOTOAR_DEVICE", "cpu")
    if name.startswith("cuda") and not wp.is_cuda_available():
        raise RuntimeError(f"device {name!r} requested but no CUDA device is available")
    return name


_pool: ThreadPoolExecutor | None = None


def run_parallel(jobs: list[Callable[[], object]]) -> list[object]:
    """Run independent kernel launches concurrently.

    Warp runs a CPU launch on one thread but releases the GIL while it runs, so launches from
    two Python threads use two cores (measured 1.6-1.8x on this 2-core machine). On CUDA the
    launches are asynchronous anyway; the pool costs nothing there.
    """
    global _pool
    if len(jobs) <= 1:
        return [j() for j in jobs]
    if _pool is None:
        _pool = ThreadPoolExecutor(max_workers=max(2, min(8, os.cpu_count() or 2)), thread_name_prefix="photoar")
    futures = [_pool.submit(j) for j in jobs]
    return [f.result() for f in futures]
