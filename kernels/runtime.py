"""Warp initialisation and device choice shared by every kernel wrapper."""
from __future__ import annotations

import logging
import os
import sys
from concurrent.futures import ThreadPoolExecutor
from typing import Callable

import warp as wp

from kernels.quiet import CapturedText, captured_stderr  # noqa: F401 (captured_stderr: used here and re-exported)

_initialised = False
log = logging.getLogger("photoar")
# What Warp's native library prints (C stdio, not Python logging) when a machine has no NVIDIA
# driver: expected on CPU-only machines, so a normal run does not show it. Asking for a CUDA device
# there is still an error (device()).
_NO_DRIVER = "Could not find or load the NVIDIA CUDA driver"


def init() -> None:
    """Initialise Warp once, quietly: kernels/__init__ silences its banner, and the native
    library's missing-driver line is dropped (anything else it prints is passed on)."""
    global _initialised
    if not _initialised:
        with captured_stderr() as cap:
            wp.init()
        rest = [ln for ln in cap.lines() if _NO_DRIVER not in ln]
        if rest:
            print("\n".join(rest), file=sys.stderr)
        _initialised = True
        if kernel_cache_cold():
            log.info("first run: Warp compiles photoar's kernels into %s (once; a minute or two on a CPU)",
                     wp.config.kernel_cache_dir)


def kernel_cache_cold() -> bool:
    """True when Warp's kernel cache holds no compiled module of this package (a first run after
    installing, or an emptied cache): the first precompute and frame then spend most of their time
    compiling. A cache with older builds after a code change is not detected (each changed module
    recompiles in a few seconds)."""
    folder = wp.config.kernel_cache_dir
    try:
        return not any(e.name.startswith(f"wp_{__package__}.") for e in os.scandir(folder))
    except OSError:  # no folder yet
        return True


def device(name: str | None = None) -> str:
    """Resolve a device name: explicit argument, else $PHOTOAR_DEVICE, else "cpu"."""
    init()
    name = name or os.environ.get("PHOTOAR_DEVICE", "cpu")
    if name.startswith("cuda") and not wp.is_cuda_available():
        raise RuntimeError(f"device {name!r} requested but no CUDA device is available")
    return name


def launch_split(launch: Callable[[int, int], object], n: int,
                 split: Callable[[Callable[[int, int], object], int], object] | None = None) -> None:
    """Run launch(lo, hi) over [0, n): as one launch, or cut by `split` (app.runtime.split, which
    decides how a frame's launches use the cores) where the caller was given one."""
    if split is None:
        launch(0, n)
    else:
        split(launch, n)


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
