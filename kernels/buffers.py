"""Device buffers allocated once at capacity, with a host mirror for uploads and downloads.

A per-frame upload writes into `host` (a numpy view) and calls `push`; nothing is allocated
after construction. On the CPU the mirror is the device array itself (zero copy); on CUDA it is
a pinned host array and push/pull copy the first `count` elements (wp.copy, no temporaries).
"""
from __future__ import annotations

import numpy as np
import warp as wp


class Buffer:
    """A Warp array `dev` of fixed shape and its host mirror `host` (numpy, same shape; vector
    dtypes add a trailing axis)."""

    def __init__(self, shape: int | tuple[int, ...], dtype, device: str, fill=None):
        self.device = device
        self.dev = wp.zeros(shape, dtype=dtype, device=device)
        self._cpu = wp.get_device(device).is_cpu
        self._mirror = self.dev if self._cpu else wp.zeros(shape, dtype=dtype, device="cpu", pinned=True)
        self.host: np.ndarray = self._mirror.numpy()  # a view: writes go straight into the mirror
        if fill is not None:
            self.host[...] = fill
            self.push()

    @property
    def capacity(self) -> int:
        return self.dev.shape[0]

    def push(self, count: int | None = None) -> wp.array:
        """Copy the host mirror's first `count` rows (default all) to the device; returns `dev`."""
        if not self._cpu and count != 0:
            wp.copy(self.dev, self._mirror, count=self._elements(count))
        return self.dev

    def pull(self, count: int | None = None) -> np.ndarray:
        """The device's first `count` rows (default all) as a numpy view of the host mirror
        (valid until the next pull or upload)."""
        n = self.dev.shape[0] if count is None else count
        if not self._cpu and n != 0:
            wp.copy(self._mirror, self.dev, count=self._elements(count))
            wp.synchronize_device(self.device)
        return self.host[:n]

    def upload(self, values: np.ndarray) -> int:
        """Write `values` (n rows, n <= capacity) into the first rows and push them; returns n."""
        n = len(values)
        if n > self.capacity:
            raise ValueError(f"{n} rows exceed the buffer's capacity {self.capacity}")
        self.host[:n] = values
        self.push(n)
        return n

    def _elements(self, rows: int | None) -> int:
        """Elements in `rows` leading rows (0: the whole array, wp.copy's convention)."""
        if rows is None:
            return 0
        per_row = int(np.prod(self.dev.shape[1:])) if self.dev.ndim > 1 else 1
        return rows * per_row
