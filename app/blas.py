"""One BLAS thread while a frame runs: numpy's (and scipy's) OpenBLAS threads a matrix product of a few
thousand rows over every core, and on the 2-core machine those threads compete with the frame's own Warp
launches (app.runtime splits them over both cores) and with each other. A drag frame's small products
(the object's probe weights (U,27) @ (27,27) and (U,27) @ (27,G), app.stages.object_drag) then took 12-20 ms
each on the loaded machine against 0.1-0.4 ms on one thread (docs/benchmarks.md, "The drag frame's glue
(glue37)"). A frame's parallelism is the launches'; a frame's products are small, so one BLAS thread costs
them nothing. The per-scene precompute keeps the process's own setting (one_thread is called per frame).

The OpenBLAS libraries are found among the process's loaded shared objects (Linux: /proc/self/maps; others:
none found, nothing is changed) and driven through their own get/set calls (what threadpoolctl does).
Results do not change: OpenBLAS cuts a product's rows and columns over its threads, never the sums.
"""
from __future__ import annotations

import ctypes
import threading

# (get, set) names of the OpenBLAS builds numpy and scipy ship (64-bit integer and plain), then upstream's
_CALLS = (("scipy_openblas_get_num_threads64_", "scipy_openblas_set_num_threads64_"),
          ("scipy_openblas_get_num_threads", "scipy_openblas_set_num_threads"),
          ("openblas_get_num_threads64_", "openblas_set_num_threads64_"),
          ("openblas_get_num_threads", "openblas_set_num_threads"))

_lock = threading.Lock()
_libs: list[tuple[object, object, int]] | None = None  # (get, set, the process's own thread count) per library


def _loaded() -> list[tuple[object, object, int]]:
    """The loaded OpenBLAS libraries' (get, set, own thread count), found once (numpy's and scipy's are loaded
    by the time a frame runs: the engine imports both)."""
    global _libs
    if _libs is None:
        found: list[tuple[object, object, int]] = []
        seen: set[str] = set()
        try:
            with open("/proc/self/maps") as f:
                paths = [ln.split()[-1] for ln in f if "openblas" in ln.lower()]
        except OSError:
            paths = []
        for p in paths:
            if p in seen or not p.startswith("/"):
                continue
            seen.add(p)
            try:
                lib = ctypes.CDLL(p)
            except OSError:
                continue
            for g, s in _CALLS:
                if hasattr(lib, g) and hasattr(lib, s):
                    get, put = getattr(lib, g), getattr(lib, s)
                    get.restype = ctypes.c_int
                    found.append((get, put, int(get())))
                    break
        _libs = found
    return _libs


def one_thread() -> None:
    """BLAS on one thread (a frame starts: app.glue.FrameTimer)."""
    with _lock:
        for _, put, _own in _loaded():
            put(1)


def own_threads() -> None:
    """BLAS on the process's own thread count again (a frame ends; a frame abandoned mid-way leaves one thread
    until the next frame ends)."""
    with _lock:
        for _, put, own in _loaded():
            put(own)


def threads() -> list[int]:
    """The loaded OpenBLAS libraries' thread counts now (tests)."""
    return [int(get()) for get, _, _ in _loaded()]
