"""Patch mesh over the scene model's quads (seed sec. 6: source and receiver patches).

Every quad is cut into a grid of rectangular patches no larger than `patch_size`. Quads that may
emit (Quad.light_shaped: a declared emitter or a window/lamp role, radiance declared or not) use
the finer `emitter_patch_size`, since a soft shadow is built from one hard shadow per patch.
Each patch is also split into two triangles for ray casting and per-pixel interpolation; grid
vertices are not shared between quads (normals differ), so per-vertex data is one-sided.

Arrays (P patches, V vertices, T = 2P triangles):
  corners (P,4,3) m, CCW seen from the lit side;  centre (P,3);  normal (P,3);  area (P,) m^2
  albedo (P,3) mean linear reflectance over the patch (from the texture when there is one)
  emission (P,3) emitted radiance;  quad (P,) index into scene.quads
  vert_pos (V,3), vert_normal (V,3), vert_inset (V,3) = vertex moved 1 mm into its quad (a point
    where form factors from perpendicular neighbours are finite and physical)
  tris (T,3) vertex indices;  tri_patch (T,) patch of each triangle
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from recon.scene import Quad, Scene


@dataclass
class PatchMesh:
    corners: np.ndarray
    centre: np.ndarray
    normal: np.ndarray
    area: np.ndarray
    albedo: np.ndarray
    emission: np.ndarray
    quad: np.ndarray
    vert_pos: np.ndarray
    vert_normal: np.ndarray
    vert_inset: np.ndarray
    tris: np.ndarray
    tri_patch: np.ndarray

    @property
    def n_patches(self) -> int:
        return len(self.area)

    @property
    def is_emitter(self) -> np.ndarray:
        return np.any(self.emission > 0, axis=1)

    @functools.cached_property
    def radius(self) -> np.ndarray:
        """Bounding radius of each patch about its centre, (P,) m (computed once: the stages read it
        every frame)."""
        return np.linalg.norm(self.corners - self.centre[:, None, :], axis=2).max(1)


def _texture_means(tex: np.ndarray, nu: int, nv: int) -> np.ndarray:
    """Mean texel value over each (iu, iv) cell of an nu x nv grid -> (nu, nv, 3).

    Texel (r, c) centre sits at (c+0.5)/Wt along c0->c1 and (r+0.5)/Ht along c0->c3.
    """
    ht, wt = tex.shape[:2]
    cs = np.zeros((ht + 1, wt + 1, 3))
    cs[1:, 1:] = tex.astype(np.float64).cumsum(0).cumsum(1)
    cb = np.clip(np.rint(np.arange(nu + 1) / nu * wt).astype(int), 0, wt)
    rb = np.clip(np.rint(np.arange(nv + 1) / nv * ht).astype(int), 0, ht)
    out = np.empty((nu, nv, 3))
    for iu in range(nu):
        c0, c1 = cb[iu], max(cb[iu + 1], cb[iu] + 1)
        for iv in range(nv):
            r0, r1 = rb[iv], max(rb[iv + 1], rb[iv] + 1)
            s = cs[r1, c1] - cs[r0, c1] - cs[r1, c0] + cs[r0, c0]
            out[iu, iv] = s / ((r1 - r0) * (c1 - c0))
    return out


def build_patches(scene: Scene, patch_size: float = 0.25, emitter_patch_size: float = 0.1) -> PatchMesh:
    """Triangulate every quad of the scene into patches (sizes in metres)."""
    if patch_size <= 0 or emitter_patch_size <= 0:
        raise ValueError("patch sizes must be positive")
    parts: dict[str, list] = {k: [] for k in ("corners", "albedo", "emission", "quad", "vpos", "vnorm", "vin",
                                              "tris")}
    n_vert = 0
    for qi, q in enumerate(scene.quads):
        size = emitter_patch_size if q.light_shaped else patch_size
        U, V = q.corners[1] - q.corners[0], q.corners[3] - q.corners[0]
        nu = max(1, int(np.ceil(np.linalg.norm(U) / size - 1e-9)))
        nv = max(1, int(np.ceil(np.linalg.norm(V) / size - 1e-9)))
        a = np.linspace(0, 1, nu + 1)
        b = np.linspace(0, 1, nv + 1)
        grid = q.corners[0] + a[:, None, None] * U + b[None, :, None] * V  # (nu+1, nv+1, 3)
        # vertex pushed 1 mm towards the quad centre (clamped to stay inside small quads)
        centre = q.corners.mean(0)
        to_c = centre - grid
        dist = np.linalg.norm(to_c, axis=2, keepdims=True)
        inset = grid + to_c / np.maximum(dist, 1e-12) * np.minimum(1e-3, 0.5 * dist)
        idx = n_vert + np.arange((nu + 1) * (nv + 1)).reshape(nu + 1, nv + 1)
        c = np.stack([grid[:-1, :-1], grid[1:, :-1], grid[1:, 1:], grid[:-1, 1:]], axis=2).reshape(-1, 4, 3)
        v00, v10, v11, v01 = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
        tri = np.stack([np.stack([v00, v10, v11], 1), np.stack([v00, v11, v01], 1)], axis=1).reshape(-1, 3)
        if q.texture is not None:
            alb = _texture_means(q.texture, nu, nv).reshape(-1, 3)
        else:
            alb = np.tile(q.albedo, (nu * nv, 1))
        parts["corners"].append(c)
        parts["albedo"].append(alb)
        parts["emission"].append(np.tile(q.emission, (nu * nv, 1)))
        parts["quad"].append(np.full(nu * nv, qi))
        parts["vpos"].append(grid.reshape(-1, 3))
        parts["vnorm"].append(np.tile(q.normal, ((nu + 1) * (nv + 1), 1)))
        parts["vin"].append(inset.reshape(-1, 3))
        parts["tris"].append(tri)
        n_vert += (nu + 1) * (nv + 1)
    corners = np.concatenate(parts["corners"])
    normal = np.concatenate([np.tile(scene.quads[qi].normal, (len(c), 1))
                             for qi, c in zip(range(len(scene.quads)), parts["corners"])])
    area = np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 3] - corners[:, 0]), axis=1)
    n_p = len(corners)
    return PatchMesh(corners=corners, centre=corners.mean(1), normal=normal, area=area,
                     albedo=np.concatenate(parts["albedo"]), emission=np.concatenate(parts["emission"]),
                     quad=np.concatenate(parts["quad"]), vert_pos=np.concatenate(parts["vpos"]),
                     vert_normal=np.concatenate(parts["vnorm"]), vert_inset=np.concatenate(parts["vin"]),
                     tris=np.concatenate(parts["tris"]).astype(np.int32),
                     tri_patch=np.repeat(np.arange(n_p), 2).astype(np.int32))
