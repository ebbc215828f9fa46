"""Simplified occluder proxy of a synthetic object (seed sec. 6.3.3: 100-500 triangles).

Decimation is fast-simplification's quadric edge collapse; meshes already under the budget are
kept as they are (a 72-triangle chair of boxes needs no simplification).
"""
from __future__ import annotations

import numpy as np


def simplify(vertices: np.ndarray, faces: np.ndarray, target: int = 300, max_faces: int = 500
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Proxy (vertices (V,3), faces (F,3) int32, unit vertex normals (V,3)) with at most `max_faces`."""
    import fast_simplification

    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int32)
    if len(f) > max_faces:
        v, f = weld(v, f)  # seams of duplicated vertices would otherwise open into holes
        v, f = fast_simplification.simplify(v.astype(np.float32), f, target_reduction=1.0 - target / len(f))
        v = np.asarray(v, np.float64)
        f = np.asarray(f, np.int32)
    return v, f, vertex_normals(v, f)


def vertex_normals(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals (V,3) of a triangle mesh with outward CCW faces."""
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    n = np.zeros_like(v)
    for k in range(3):
        np.add.at(n, f[:, k], fn)
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)


def weld(v: np.ndarray, f: np.ndarray, tol: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
    """Merge vertices closer than `tol` metres (on a grid) and drop faces that collapse."""
    _, first, inv = np.unique(np.round(v / tol).astype(np.int64), axis=0, return_index=True, return_inverse=True)
    f2 = inv.reshape(-1)[f]
    keep = (f2[:, 0] != f2[:, 1]) & (f2[:, 1] != f2[:, 2]) & (f2[:, 2] != f2[:, 0])
    return v[first], f2[keep].astype(np.int32)
