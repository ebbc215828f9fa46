"""Order-2 (9-coefficient) real spherical harmonics and irradiance from them.

Ramamoorthi & Hanrahan, "An efficient representation for irradiance environment maps",
SIGGRAPH 2001: projecting radiance L(w) onto Y_lm (l <= 2) and convolving with the clamped
cosine (A_0 = pi, A_1 = 2pi/3, A_2 = pi/4) gives irradiance E(n) = sum_lm A_l L_lm Y_lm(n)
with at most ~1-3 % error for any lighting.

Coefficient order: (0,0), (1,-1), (1,0), (1,1), (2,-2), (2,-1), (2,0), (2,1), (2,2); directions
are unit vectors in world coordinates; radiance in the scene's units.
"""
from __future__ import annotations

import numpy as np

from kernels.sh9 import C0, C1, C2, C3, C4  # noqa: F401 (normalisation constants of the real SH basis, l <= 2)

BAND = np.array([0, 1, 1, 1, 2, 2, 2, 2, 2])
A_HAT = np.array([np.pi, 2 * np.pi / 3, np.pi / 4])[BAND]  # clamped-cosine convolution per coefficient


def basis(d: np.ndarray) -> np.ndarray:
    """Y_lm at unit directions d (...,3) -> (...,9)."""
    d = np.asarray(d, np.float64)
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    return np.stack([np.full_like(x, C0), C1 * y, C1 * z, C1 * x, C2 * x * y, C2 * y * z,
                     C3 * (3 * z * z - 1), C2 * x * z, C4 * (x * x - y * y)], axis=-1)


def project(dirs: np.ndarray, radiance: np.ndarray, solid_angle: np.ndarray) -> np.ndarray:
    """SH coefficients (9,3) of radiance (N,3) arriving from dirs (N,3) over solid angles (N,) sr."""
    Y = basis(dirs)
    return np.einsum("nk,nc,n->kc", Y, np.asarray(radiance, np.float64), np.asarray(solid_angle, np.float64))


def irradiance(coeffs: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Irradiance E (...,3) for normals (...,3) from radiance coefficients (...,9,3) (or (9,3))."""
    Y = basis(normals)  # (...,9)
    return np.einsum("...k,...kc->...c", Y * A_HAT, coeffs)
