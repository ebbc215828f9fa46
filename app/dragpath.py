"""A drag of the scene's object over the floor, for timing interactive frames (`evaluate --path N`).

The path is a straight line through the object's pose (scene.json's synthetic_object) in the
floor plane (+Y up). Of a set of directions, the one with the longest free stretch is taken:
every pose on it keeps the object's bounding box inside the room (ROOM_MARGIN from the walls),
off the furniture boxes (by more than 1 mm, as PlacementController.collides), and its footprint
centre in the photo (a drag the user could make by pointing). The stretch is the contiguous free
interval around the object's own pose, so the pose itself is on the path even where it touches
furniture (a chair tucked under a desk).
"""
from __future__ import annotations

import dataclasses

import numpy as np

from recon.scene import Scene, SceneObject, furniture_boxes

ROOM_MARGIN = 2e-3  # m between the object's bounding box and the walls (as app.placement)
MAX_LENGTH = 2.0  # m: the longest drag sampled (a user's stroke across a room, not the room's diagonal)


def _free(scene: Scene, lo: np.ndarray, hi: np.ndarray, offsets: np.ndarray, pivot: np.ndarray) -> np.ndarray:
    """(N,) bool: the box [lo, hi] moved by each offset (N,3) stays in the room, off furniture, and
    its bottom centre `pivot` moved likewise projects inside the photo."""
    l, h = lo + offsets, hi + offsets
    xz = [0, 2]  # it rests on the floor: only the walls bound it
    ok = np.all(l[:, xz] >= scene.room_min[xz] + ROOM_MARGIN, axis=1) & np.all(h[:, xz] <= scene.room_max[xz] - ROOM_MARGIN, axis=1)
    for b_lo, b_hi in furniture_boxes(scene):
        ok &= ~np.all((l < b_hi - 1e-3) & (h > b_lo + 1e-3), axis=1)
    cam = scene.camera
    uv, z = cam.project(pivot + offsets)
    ok &= (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] <= cam.width - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= cam.height - 1)
    return ok


def drag_offsets(scene: Scene, obj: SceneObject, n: int, directions: int = 16, step: float = 0.01) -> np.ndarray:
    """(n,3) offsets (m, y = 0) of n evenly spaced poses along the longest free straight drag
    through the object's pose; raises ValueError when the object cannot move at all."""
    if n < 2:
        raise ValueError(f"a path needs at least 2 positions (the first frame is excluded), got {n}")
    lo, hi = obj.vertices.min(0), obj.vertices.max(0)
    pivot = np.array([(lo[0] + hi[0]) / 2, lo[1], (lo[2] + hi[2]) / 2])
    ts = np.arange(-MAX_LENGTH, MAX_LENGTH + step / 2, step)
    i0 = int(np.argmin(np.abs(ts)))
    best = None
    for k in range(directions // 2):  # a line and its reverse are the same path
        a = np.pi * k / (directions // 2)
        d = np.array([np.cos(a), 0.0, np.sin(a)])
        free = _free(scene, lo, hi, ts[:, None] * d, pivot)
        free[i0] = True  # the object's own pose
        i, j = i0, i0
        while i > 0 and free[i - 1]:
            i -= 1
        while j < len(ts) - 1 and free[j + 1]:
            j += 1
        # the longest contiguous stretch around the pose, no longer than MAX_LENGTH
        a_t, b_t = ts[i], ts[j]
        if b_t - a_t > MAX_LENGTH:
            half = MAX_LENGTH / 2
            c = float(np.clip(0.0, a_t + half, b_t - half))
            a_t, b_t = c - half, c + half
        if best is None or b_t - a_t > best[1] - best[0]:
            best = (a_t, b_t, d)
    a_t, b_t, d = best
    if b_t - a_t <= 0:
        raise ValueError("the object has no free straight drag over the floor (walls or furniture on every side)")
    return np.linspace(a_t, b_t, n)[:, None] * d


def moved(obj: SceneObject, offset: np.ndarray) -> SceneObject:
    """The object translated by `offset` (3,) m (normals unchanged)."""
    M = obj.object_to_world.copy()
    M[:3, 3] += offset
    return dataclasses.replace(obj, vertices=obj.vertices + offset, object_to_world=M)
