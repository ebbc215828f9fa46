"""The object's camera hits with the scene's depth kept per sub-sample (the drag frame's "object" stage).

kernels.shade.CameraHits casts each sub-sample ray of the object's rectangle against the object's mesh and,
where it meets the object, against the scene model (is the room in front?). The second query depends on the
camera alone: SceneDepth casts it once per sub-sample (a tile of the frame the first time the object's rectangle
reaches it) and keeps the distance; a frame then reads it. The same ray (the same floats: the sub-sample's position and
direction are formed as CameraHits forms them), the same scene, the same closest hit: CameraHits's test, a
scene hit at 0 <= t < the object's t (its query stops at the object's distance), is t_scene < t_object here,
bit for bit the same hits. On window_room the scene's query was 6 of the stage's 14 ms of CPU (40 880 rays,
24 388 of them on the object; docs/benchmarks.md "The drag frame's glue (glue37)"); the table is 4 bytes a
sub-sample (4.9 MB at 640 x 480, 2 x 2), cast by tiles as the object's rectangle first reaches them.
"""
from __future__ import annotations

import numpy as np
import warp as wp

from kernels import runtime
from kernels.shade import CameraHits

NO_HIT = 1.0e30  # the table's distance where the scene has no surface (the kernel's literal)
# The table is cast by tiles of TILE x TILE pixels, the first time the object's rectangle reaches one: a drag pays
# as it goes (a tile is 16 x 16 px, 1024 rays at 2 x 2; the object's rectangle, ~70 x 150 px on window_room, spans
# ~50), never the whole frame (sun_room's: 0.47 s of CPU, loaded) nor whole rows of it on its first frame
TILE = 16


@wp.kernel
def _scene_depth_kernel(scene: wp.uint64, centre: wp.vec3, pix_to_dir: wp.mat33, cols: int, rows: int, s: int,
                        tiles: wp.array(dtype=wp.int32), tiles_x: int, tile: int, lo: int,
                        depth: wp.array(dtype=wp.float32)):
    """Sub-sample k of the listed tiles (tile x tile pixels each, numbered row-major, tiles_x a row; the frame
    cols x rows pixels): the distance to the scene along its camera ray (NO_HIT where none) written at its place
    in the frame's row-major (rows s) x (cols s) grid, the ray formed as kernels.shade._object_hits_kernel forms
    it."""
    k = wp.tid() + lo
    side = tile * s  # sub-samples a tile side
    t = k // (side * side)
    j = k - t * side * side
    ty = tiles[t] // tiles_x
    tx = tiles[t] - ty * tiles_x
    r = ty * side + j // side
    c = tx * side + j - (j // side) * side
    if r < rows * s and c < cols * s:
        u = float(c // s) + (float(c % s) + 0.5) / float(s) - 0.5
        v = float(r // s) + (float(r % s) + 0.5) / float(s) - 0.5
        d = wp.normalize(pix_to_dir * wp.vec3(u, v, 1.0))
        q = wp.mesh_query_ray(scene, centre, d, 1.0e6)
        z = float(1.0e30)  # NO_HIT
        if q.result:
            z = q.t
        depth[r * (cols * s) + c] = z


@wp.kernel
def _object_hits_depth_kernel(obj: wp.uint64, depth: wp.array(dtype=wp.float32), centre: wp.vec3,
                              pix_to_dir: wp.mat33, u0: int, v0: int, cols: int, W: int, s: int, first: int, lo: int,
                              tri: wp.array(dtype=wp.int32), bary: wp.array(dtype=wp.vec3),
                              hit: wp.array(dtype=wp.uint8)):
    """kernels.shade._object_hits_kernel with the scene's distance read from `depth` (SceneDepth's table)."""
    k = wp.tid() + lo  # within the block
    i = first + k  # sub-sample, row-major over the rectangle's (rows * s) x (cols * s) grid
    r = i // (cols * s)
    c = i - r * (cols * s)
    u = float(u0 + c // s) + (float(c % s) + 0.5) / float(s) - 0.5
    v = float(v0 + r // s) + (float(r % s) + 0.5) / float(s) - 0.5
    d = wp.normalize(pix_to_dir * wp.vec3(u, v, 1.0))
    q = wp.mesh_query_ray(obj, centre, d, 1.0e6)
    if q.result:
        seen = int(1)
        if depth[(v0 * s + r) * (W * s) + u0 * s + c] < q.t:
            seen = 0
        tri[k] = q.face
        bary[k] = wp.vec3(q.u, q.v, 1.0 - q.u - q.v)  # Warp: p = u p0 + v p1 + (1-u-v) p2
        hit[k] = wp.uint8(seen)
    else:
        tri[k] = -1
        bary[k] = wp.vec3(0.0, 0.0, 0.0)
        hit[k] = wp.uint8(0)


class SceneDepth(CameraHits):
    """CameraHits for one camera (centre, pix_to_dir, W x H pixels) and sub-sampling s, with the scene's distance
    per sub-sample cast where a call first needs it and kept. A call for another camera, s or scene is
    CameraHits's own."""

    def __init__(self, scene, centre: np.ndarray, pix_to_dir: np.ndarray, width: int, height: int, s: int,
                 device: str, block: int = 65536):
        super().__init__(device, block)
        self.scene, self.W, self.H, self.s = scene, int(width), int(height), int(s)
        self.centre = np.asarray(centre, np.float64).copy()
        self.pix_to_dir = np.asarray(pix_to_dir, np.float64).copy()
        self._depth: wp.array | None = None
        self._done: np.ndarray | None = None  # (tiles down, tiles across) bool: cast
        self._tiles = None  # the Buffer of a call's tile numbers (int32, capacity every tile)

    def _same(self, scene, centre, pix_to_dir, s: int) -> bool:
        return (scene is self.scene and s == self.s and np.array_equal(np.asarray(centre, np.float64), self.centre)
                and np.array_equal(np.asarray(pix_to_dir, np.float64), self.pix_to_dir))

    def depth(self, rect: tuple[int, int, int, int] | None = None, split=None) -> wp.array:
        """(H s * W s,) float32 the scene's distance per sub-sample (NO_HIT: none), cast where the pixel
        rectangle (u0, v0, u1, v1) (inclusive; default the frame) was not yet: by tiles of TILE x TILE pixels."""
        tx, ty = -(-self.W // TILE), -(-self.H // TILE)
        if self._depth is None:
            from kernels.buffers import Buffer

            self._depth = wp.full(self.H * self.s * self.W * self.s, NO_HIT, dtype=wp.float32, device=self.device)
            self._done = np.zeros((ty, tx), bool)
            self._tiles = Buffer(tx * ty, wp.int32, self.device)
        u0, v0, u1, v1 = (0, 0, self.W - 1, self.H - 1) if rect is None else rect
        y0, y1 = max(int(v0), 0) // TILE, min(int(v1), self.H - 1) // TILE
        x0, x1 = max(int(u0), 0) // TILE, min(int(u1), self.W - 1) // TILE
        todo = np.flatnonzero(~self._done[y0:y1 + 1, x0:x1 + 1].ravel()) if y1 >= y0 and x1 >= x0 else []
        if len(todo):
            nx = x1 - x0 + 1
            ids = (y0 + todo // nx) * tx + x0 + todo % nx  # row-major tile numbers
            self._tiles.host[:len(ids)] = ids
            tiles = self._tiles.push(len(ids))
            M = wp.mat33(*np.asarray(self.pix_to_dir, np.float32).reshape(-1))
            c = wp.vec3(*np.asarray(self.centre, np.float32))

            def launch(lo: int, hi: int) -> None:
                wp.launch(_scene_depth_kernel, dim=hi - lo, inputs=[wp.uint64(self.scene.id), c, M, self.W, self.H,
                                                                    self.s, tiles, tx, TILE, int(lo), self._depth],
                          device=self.device)

            runtime.launch_split(launch, len(ids) * (TILE * self.s) ** 2, split)
            self._done.ravel()[ids] = True
        return self._depth

    def __call__(self, obj, scene, centre: np.ndarray, pix_to_dir: np.ndarray, rect: tuple[int, int, int, int],
                 s: int, split=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """CameraHits.__call__'s (tri, bary, hit), the scene's distance read from the kept table."""
        if scene is None or scene.id == 0 or not self._same(scene, centre, pix_to_dir, s):
            return super().__call__(obj, scene, centre, pix_to_dir, rect, s, split)
        u0, v0, u1, v1 = rect
        depth = self.depth(rect, split)
        cols, rows = u1 - u0 + 1, v1 - v0 + 1
        M = wp.mat33(*np.asarray(pix_to_dir, np.float32).reshape(-1))
        c = wp.vec3(*np.asarray(centre, np.float32))
        return self.in_blocks(_object_hits_depth_kernel, rows * s * cols * s,
                              [wp.uint64(obj.id), depth, c, M, int(u0), int(v0), int(cols), self.W, int(s)], split)
