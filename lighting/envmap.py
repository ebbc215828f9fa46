"""Low-resolution cube maps of the radiance mesh, pre-filtered with a Phong lobe (seed sec. 5, fig. 9).

The seed approximates an object's specular reflection with a cubic environment map rendered
from the radiance mesh at the object's centre once per frame, combined with the diffuse term.
We keep it in HDR (the seed tone-mapped the mesh first because of 8-bit OpenGL) and pre-filter
the map with a normalised Phong lobe, so a lookup in the mirror direction r gives

    L_s(r) = k_s * integral L(w) (n+1)/(2 pi) max(0, r.w)^n dw

(the lobe integrates to 1 over the hemisphere around r: a uniform environment of radiance L
reflects k_s * L). Reflected directions are looked up bilinearly within a cube face.

Cube layout: faces in the order +X, -X, +Y, -Y, +Z, -Z (world axes); on each face texel (i, j)
(row i, column j) of a res x res grid has face coordinates a = (j + 0.5)/res*2-1 (columns),
b = (i + 0.5)/res*2-1 (rows), and direction normalize(axis + a*U + b*V) with the (U, V) of
`_FACES`. Radiance in the scene's units, directions unit vectors in world coordinates.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# (major axis, U, V) per face: direction = axis + a U + b V for a, b in [-1, 1]
_FACES = np.array([
    [[1, 0, 0], [0, 0, -1], [0, -1, 0]],
    [[-1, 0, 0], [0, 0, 1], [0, -1, 0]],
    [[0, 1, 0], [1, 0, 0], [0, 0, 1]],
    [[0, -1, 0], [1, 0, 0], [0, 0, -1]],
    [[0, 0, 1], [1, 0, 0], [0, -1, 0]],
    [[0, 0, -1], [-1, 0, 0], [0, -1, 0]],
], np.float64)


def cube_directions(res: int) -> tuple[np.ndarray, np.ndarray]:
    """Texel directions (6*res*res, 3) and exact solid angles (6*res*res,) sr (sum 4 pi).

    A face rectangle [a0,a1]x[b0,b1] at unit distance subtends F(a1,b1)-F(a0,b1)-F(a1,b0)+F(a0,b0)
    with F(a,b) = atan(ab / sqrt(1+a^2+b^2)).
    """
    if res < 1:
        raise ValueError(f"cube-map resolution must be at least 1, got {res}")
    c = (np.arange(res) + 0.5) / res * 2 - 1
    b, a = np.meshgrid(c, c, indexing="ij")  # rows, columns
    d = (_FACES[:, 0, None, None, :] + a[None, ..., None] * _FACES[:, 1, None, None, :]
         + b[None, ..., None] * _FACES[:, 2, None, None, :])
    e = np.linspace(-1, 1, res + 1)
    F = np.arctan(np.outer(e, e) / np.sqrt(1 + e[:, None] ** 2 + e[None, :] ** 2))
    sa = np.broadcast_to(F[1:, 1:] - F[:-1, 1:] - F[1:, :-1] + F[:-1, :-1], (6, res, res))
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    return d.reshape(-1, 3), np.ascontiguousarray(sa).reshape(-1)


@dataclass
class CubeMap:
    """A cube map (6, res, res, 3) of radiance in the layout of the module docstring."""

    texels: np.ndarray

    @property
    def res(self) -> int:
        return self.texels.shape[1]

    def lookup(self, dirs: np.ndarray) -> np.ndarray:
        """Bilinear lookup (N,3) at directions (N,3) (need not be unit; clamped at face edges)."""
        d = np.asarray(dirs, np.float64).reshape(-1, 3)
        ax = np.argmax(np.abs(d), axis=1)
        sign = d[np.arange(len(d)), ax] < 0
        face = 2 * ax + sign
        m = np.abs(d[np.arange(len(d)), ax])
        m = np.where(m > 0, m, 1.0)
        a = np.einsum("nk,nk->n", d, _FACES[face, 1]) / m
        b = np.einsum("nk,nk->n", d, _FACES[face, 2]) / m
        res = self.res
        x = np.clip((a + 1) / 2 * res - 0.5, 0, res - 1)
        y = np.clip((b + 1) / 2 * res - 0.5, 0, res - 1)
        x0 = np.minimum(np.floor(x).astype(int), res - 2) if res > 1 else np.zeros(len(d), int)
        y0 = np.minimum(np.floor(y).astype(int), res - 2) if res > 1 else np.zeros(len(d), int)
        x1, y1 = np.minimum(x0 + 1, res - 1), np.minimum(y0 + 1, res - 1)
        fx, fy = (x - x0)[:, None], (y - y0)[:, None]
        t = self.texels
        return ((1 - fy) * ((1 - fx) * t[face, y0, x0] + fx * t[face, y0, x1])
                + fy * ((1 - fx) * t[face, y1, x0] + fx * t[face, y1, x1]))


def phong_prefilter(radiance: np.ndarray, res_in: int, exponent: float, res_out: int) -> CubeMap:
    """Cube map (res_out) of the Phong-lobe integral of a cube map of radiance (6*res_in^2, 3).

    Each output texel in direction r holds sum_w L(w) dw (n+1)/(2 pi) max(0, r.w)^n. For the
    lobe to be resolved the input texels must be finer than its width (about 1/sqrt(n) rad);
    `res_in` >= 2*sqrt(n) is enough (bench/bench_shading.py measures it).
    """
    if exponent < 0:
        raise ValueError(f"Phong exponent must be >= 0, got {exponent}")
    L = np.asarray(radiance, np.float64).reshape(-1, 3)
    w_in, sa = cube_directions(res_in)
    if len(L) != len(w_in):
        raise ValueError(f"radiance has {len(L)} texels, a cube map of {res_in} needs {len(w_in)}")
    r, _ = cube_directions(res_out)
    cosines = np.maximum(r @ w_in.T, 0.0)
    lobe = (exponent + 1) / (2 * np.pi) * cosines ** exponent * sa[None, :]
    # renormalise each row: the discrete lobe must integrate to 1 like the continuous one
    lobe /= np.maximum(lobe.sum(1, keepdims=True), 1e-300)
    return CubeMap((lobe @ L).reshape(6, res_out, res_out, 3))


def reflect(view: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Mirror directions (N,3) of view directions (N,3, from the eye towards the surface)."""
    return view - 2 * np.einsum("nk,nk->n", view, normal)[:, None] * normal
