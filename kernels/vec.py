"""Small numpy helpers for the per-frame glue (kernels/ imports nothing of ours: every layer may use them)."""
from __future__ import annotations

import numpy as np


def cross3(a, b) -> np.ndarray:
    """np.cross of 3-vectors along the last axis (broadcast), the same bytes: numpy's own formula per component
    (a1 b2 - a2 b1, a2 b0 - a0 b2, a0 b1 - a1 b0, each product rounded, then the difference), without np.cross's
    axis handling (moveaxis, broadcast, temporaries): ~12 us against ~40 for a proxy's few hundred triangles, and
    a drag frame takes ~14 (docs/benchmarks.md, "glue111")."""
    a, b = np.asarray(a), np.asarray(b)
    if a.shape[-1] != 3 or b.shape[-1] != 3:
        return np.cross(a, b)
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], -1)


def same_key(a: tuple, b: tuple) -> bool:
    """Two cache keys (tuples of numpy arrays and plain values) equal: each array's shape, dtype and values, each
    other entry by ==. The per-frame shape caches compare their keys so instead of hashing the arrays every frame
    (docs/benchmarks.md, "glue111")."""
    if len(a) != len(b):
        return False
    for x, y in zip(a, b):
        if isinstance(x, np.ndarray) or isinstance(y, np.ndarray):
            if not (isinstance(x, np.ndarray) and isinstance(y, np.ndarray) and x.shape == y.shape
                    and x.dtype == y.dtype and np.array_equal(x, y)):
                return False
        elif x != y:
            return False
    return True
