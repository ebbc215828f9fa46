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


def bounding_sphere(v: np.ndarray) -> tuple[np.ndarray, float]:
    """(centre (3,), radius m) of vertices v (V,3): the box centre and the farthest vertex from it
    (the object's "bounding radius" of the per-frame stages)."""
    centre = 0.5 * (v.min(0) + v.max(0))
    return centre, float(np.linalg.norm(v - centre, axis=1).max())


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


def subdivide(v: np.ndarray, n: np.ndarray, f: np.ndarray, max_edge: float = 0.06, max_faces: int = 20000
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Midpoint-subdivide until no edge exceeds `max_edge` metres (or the face budget is reached).

    Shading is evaluated per vertex and interpolated, so a flat 0.5 m box face with four vertices
    cannot show the shadow of the seat on a chair's leg; more vertices can. Vertex normals are
    interpolated and renormalised; vertices are not shared between triangles (flat faces stay
    flat). Returns vertices (V,3), normals (V,3), faces (F,3).
    """
    v, n, f = np.asarray(v, np.float64), np.asarray(n, np.float64), np.asarray(f, np.int64)
    tv, tn = v[f], n[f]  # (F,3,3) per-triangle corners and normals
    while True:
        edges = np.linalg.norm(tv - np.roll(tv, 1, axis=1), axis=2).max()
        if edges <= max_edge or 4 * len(tv) > max_faces:
            break
        mv = 0.5 * (tv + np.roll(tv, -1, axis=1))  # midpoints of edges (0,1), (1,2), (2,0)
        mn = 0.5 * (tn + np.roll(tn, -1, axis=1))
        a, b, c = tv[:, 0], tv[:, 1], tv[:, 2]
        ab, bc, ca = mv[:, 0], mv[:, 1], mv[:, 2]
        na, nb, nc = tn[:, 0], tn[:, 1], tn[:, 2]
        nab, nbc, nca = mn[:, 0], mn[:, 1], mn[:, 2]
        tv = np.concatenate([np.stack(t, 1) for t in ((a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca))])
        tn = np.concatenate([np.stack(t, 1) for t in ((na, nab, nca), (nab, nb, nbc), (nca, nbc, nc),
                                                      (nab, nbc, nca))])
    if len(tv) == len(f):
        return v, n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12), f.astype(np.int32)
    tn = tn / np.maximum(np.linalg.norm(tn, axis=2, keepdims=True), 1e-12)
    return tv.reshape(-1, 3), tn.reshape(-1, 3), np.arange(3 * len(tv)).reshape(-1, 3).astype(np.int32)
