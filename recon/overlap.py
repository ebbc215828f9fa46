"""How far a triangle mesh cuts into the scene's furniture boxes.

Exact triangle / oriented-box overlap by the separating axis theorem (13 axes per triangle: the
box's three face normals, the triangle's normal and the nine cross products of box and triangle
edges), vectorised over the triangles. For a translation t along a direction d each axis's
overlap condition is linear in t, so each triangle overlaps the box for one interval of t; the
depth of the overlap is the shortest push along one of the box's six face directions after which
no triangle overlaps it (0 when none does now). Touching (a box resting on a table top) is
depth 0. Units: metres, world frame of the scene.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

_CHUNK = 1 << 15  # triangles per vectorised block (13 axes x 3 vertices each: ~10 MB of float64)


@dataclass
class OrientedBox:
    """A furniture box: `centre` (3,), `axes` (3,3) rows the box's unit axes in the world,
    `half` (3,) half extents along them (m)."""
    name: str
    centre: np.ndarray
    axes: np.ndarray
    half: np.ndarray


@dataclass
class Overlap:
    """The mesh cuts `depth` metres into box `name`; pushing it `depth` along `push` (3,) (a unit
    world vector, one of the box's face normals) frees it."""
    name: str
    depth: float
    push: np.ndarray


def furniture_boxes(quads) -> list[OrientedBox]:
    """The furniture boxes of a scene's quads (faces named '<box>.x-' etc., role 'furniture'),
    turned ones included: the axes are the faces' normals, the extents those of the corners."""
    groups: dict[str, list] = {}
    for q in quads:
        if q.role == "furniture":
            groups.setdefault(q.name.rsplit(".", 1)[0], []).append(q)
    boxes = []
    for name, faces in groups.items():
        u0 = np.asarray(faces[0].normal, float)
        u1 = next((np.asarray(f.normal, float) for f in faces[1:] if abs(float(np.dot(f.normal, u0))) < 0.5),
                  np.cross(u0, [0.0, 1.0, 0.0]) if abs(u0[1]) < 0.9 else np.cross(u0, [1.0, 0.0, 0.0]))
        u1 = u1 - np.dot(u1, u0) * u0
        u1 /= np.linalg.norm(u1)
        axes = np.stack([u0, u1, np.cross(u0, u1)])
        local = np.concatenate([f.corners for f in faces]) @ axes.T
        lo, hi = local.min(0), local.max(0)
        boxes.append(OrientedBox(name, 0.5 * (lo + hi) @ axes, axes, 0.5 * (hi - lo)))
    return boxes


def _intervals(tri: np.ndarray, half: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For triangles `tri` (N,3,3) in the box's frame (box = [-half, half]) moved by t along each
    of the frame's six directions +x, -x, +y, -y, +z, -z: (a, b) (6, N) such that triangle i
    overlaps the box exactly for a <= t <= b (a > b: never)."""
    n = len(tri)
    edges = tri[:, [1, 2, 0]] - tri                                   # (N,3,3) triangle edges
    box_axes = np.broadcast_to(np.eye(3), (n, 3, 3))
    normal = np.cross(edges[:, 0], edges[:, 1])[:, None]              # (N,1,3)
    cross = np.cross(np.eye(3)[None, :, None, :], edges[:, None, :, :]).reshape(n, 9, 3)
    axes = np.concatenate([box_axes, normal, cross], axis=1)           # (N,13,3); zero rows: no condition
    proj = np.einsum("nkd,nvd->nkv", axes, tri)
    pmin, pmax = proj.min(2), proj.max(2)
    r = np.abs(axes) @ half                                            # box's projected radius
    hi_lim, lo_lim = r - pmin, -r - pmax                               # need pmin + tk <= r, pmax + tk >= -r
    fixed_ok = (hi_lim >= 0) & (lo_lim <= 0)
    scale = np.maximum(np.abs(axes).sum(2), 1e-300)
    a, b = np.empty((6, n)), np.empty((6, n))
    for i in range(6):
        k = axes[:, :, i // 2] * (1.0 if i % 2 == 0 else -1.0)        # projection speed along the push
        moving = np.abs(k) > 1e-12 * scale
        ks = np.where(moving, k, 1.0)
        up = np.where(k > 0, hi_lim / ks, lo_lim / ks)                # upper bound on t
        dn = np.where(k > 0, lo_lim / ks, hi_lim / ks)                # lower bound on t
        up = np.where(moving, up, np.where(fixed_ok, np.inf, -np.inf))
        dn = np.where(moving, dn, np.where(fixed_ok, -np.inf, np.inf))
        a[i], b[i] = dn.max(1), up.min(1)
    return a, b


def _clear_push(a: np.ndarray, b: np.ndarray) -> float:
    """The smallest t >= 0 outside every open interval (a_i, b_i): sweep the intervals in order of
    their start; t is the furthest end so far until an interval starts at or beyond it."""
    keep = (b > 0) & (a < b)
    order = np.argsort(a[keep])
    a, b = a[keep][order], b[keep][order]
    if len(a) == 0:
        return 0.0
    reach = np.maximum(np.maximum.accumulate(b), 0.0)
    before = np.concatenate([[0.0], reach[:-1]])
    gap = np.flatnonzero(a >= before)
    return float(before[gap[0]] if len(gap) else reach[-1])


def mesh_box_overlap(vertices: np.ndarray, faces: np.ndarray, box: OrientedBox) -> Overlap | None:
    """How deep the mesh (vertices (V,3) world m, faces (F,3)) cuts into `box`: None when no
    triangle overlaps it by more than touching, else the shortest freeing push along a box axis."""
    tri = (np.asarray(vertices, float)[np.asarray(faces)] - box.centre) @ box.axes.T  # (F,3,3) box frame
    tlo, thi = tri.min(1), tri.max(1)
    inside_now = np.all((tlo < box.half) & (thi > -box.half), axis=1)
    if not inside_now.any():
        return None
    # Only triangles whose extent overlaps the box across a push can ever meet it along that push.
    across = (tlo <= box.half) & (thi >= -box.half)
    cand = tri[across.sum(1) >= 2]
    ab = [_intervals(cand[i:i + _CHUNK], box.half) for i in range(0, len(cand), _CHUNK)]
    a, b = np.concatenate([x[0] for x in ab], 1), np.concatenate([x[1] for x in ab], 1)
    best: Overlap | None = None
    for i in range(6):
        t = _clear_push(a[i], b[i])
        if best is None or t < best.depth:
            best = Overlap(box.name, t, (1.0 if i % 2 == 0 else -1.0) * box.axes[i // 2])
    return best if best is not None and best.depth > 0 else None


def furniture_overlaps(vertices: np.ndarray, faces: np.ndarray, quads, min_depth: float = 0.0) -> list[Overlap]:
    """Every furniture box of `quads` the mesh cuts into by more than `min_depth` metres."""
    out = []
    for box in furniture_boxes(quads):
        o = mesh_box_overlap(vertices, faces, box)
        if o is not None and o.depth > min_depth:
            out.append(o)
    return out


def push_words(push: np.ndarray) -> str:
    """A push direction in words: 'up', 'down', '+x', '-z', ... (world axes; nearest axis)."""
    i = int(np.argmax(np.abs(push)))
    if i == 1:
        return "up" if push[1] > 0 else "down"
    return ("+" if push[i] > 0 else "-") + "xyz"[i]
