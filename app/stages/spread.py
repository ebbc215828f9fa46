"""Spread subsets of an object's distinct vertices chosen by position, not by the mesh's order.

ShapeShading casts the visibility of its patch sums at a subset of the distinct (position, normal)
vertices (the rest take their neighbours' vote) and gathers the second-order loss at another subset
(the rest interpolate). Taken in the mesh's own order (every k-th vertex), the same object with its
faces or vertices listed in another order got other subsets, and up to 1.5 levels of rmse_object
moved with the order alone (docs/unseen.md, shade107). Here the subsets are a farthest-point order
(Gonzalez's greedy k-centre): each next vertex is the one farthest from those already taken, in the
distance |dp|^2 + (R |dn|)^2 (positions p in metres, unit normals n, R the object's radius about its
bounding box's centre: on a sphere of radius R it is twice the squared chord, so a smooth surface is
spread evenly, and the faces of a sharp corner count as far apart, as the mesh's rings do).

The points are quantised to `unit` (1 um, the shape keys' rounding) and the distances computed in
exact int64 arithmetic, so ties (regular grids have many) break the same way, by the lowest index,
whatever float noise the vertices' order left in their last bits. The first m of the order are
themselves a farthest-point spread of m: nested subsets come from one order.
"""
from __future__ import annotations

import numpy as np

UNIT = 1e-6  # m: the quantum of positions (and of R x normal) in the distances


def spread_order(points: np.ndarray, normals: np.ndarray, count: int, unit: float = UNIT) -> np.ndarray:
    """(min(count, U),) int64 indices into points (U,3) m with unit normals (U,3): the farthest-point
    order, starting from the point farthest from the bounding box's centre (ties: the lowest index)."""
    U = len(points)
    count = min(max(int(count), 0), U)
    if count == 0:
        return np.zeros(0, np.int64)
    q = np.rint(np.asarray(points, np.float64) / unit).astype(np.int64)
    from_centre = 2 * q - (q.min(0) + q.max(0))  # twice the offset from the box's centre, exact
    r2 = (from_centre * from_centre).sum(1)
    radius = max(int(np.rint(np.sqrt(float(r2.max())) / 2)), 1)  # R in units
    x = np.concatenate([q, np.rint(np.asarray(normals, np.float64) * radius).astype(np.int64)], 1)
    # integers held as float64, one row per coordinate: every difference, square and sum of six stays an exact
    # integer (below 2^53 while every coordinate is below 2^24 units, 16 m), and the row-wise updates run in place
    xt = np.ascontiguousarray(x.T, np.float64)
    if np.abs(xt).max() >= 2.0 ** 24:
        raise ValueError(f"spread_order: a vertex {np.abs(xt).max() * unit:.0f} m from the origin is beyond the exact "
                         "range of the distances (16 m)")
    order = np.empty(count, np.int64)
    order[0] = int(np.argmax(r2))
    d = np.full(U, np.inf)
    t, acc = np.empty(U), np.empty(U)
    for k in range(count):
        if k:
            order[k] = int(np.argmax(d))
        i = order[k]
        acc[:] = 0.0
        for c in range(6):
            np.subtract(xt[c], xt[c, i], out=t)
            np.multiply(t, t, out=t)
            acc += t
        np.minimum(d, acc, out=d)
    return order


def spread_subsets(points: np.ndarray, normals: np.ndarray, vis_stride: int, dB_samples: int
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(vis, sub, sub_vis): sorted indices into the U distinct vertices (points, normals as
    spread_order): `vis` the ceil(U / vis_stride) visibility samples of the patch sums, `sub` the
    min(dB_samples, U) vertices that gather the second-order loss, and `sub_vis` indices into `sub` of
    its own ceil(len(sub) / vis_stride) visibility samples; each the first of one farthest-point order."""
    U, stride = len(points), max(int(vis_stride), 1)
    n_vis = -(-U // stride)
    n_sub = min(max(int(dB_samples), 1), U)
    order = spread_order(points, normals, max(n_vis, n_sub))
    sub = np.sort(order[:n_sub])
    sub_vis = np.searchsorted(sub, np.sort(order[:-(-n_sub // stride)]))
    return np.sort(order[:n_vis]), sub, sub_vis
