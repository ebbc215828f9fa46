"""Camera response T: radiance -> 8-bit pixel value, and its inverse; Rec.709 luminance.

A scene stores the response per channel as two 256-entry tables: forward f(i/255) and inverse
f^-1(z/255). The forward table alone is too coarse where f is steep (near black, f ~ X^(1/gamma));
the inverse table samples exactly that part densely. Both sample sets together, merged and
interpolated piecewise-linearly, give a continuous f accurate everywhere without assuming the
response family (`gamma_s`, `film`, measured ones alike).

Pixel values: z = round(255 * f(clip(L * exposure_time, 0, 1))).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kernels.luma import LUMA  # noqa: F401 (Rec.709 luminance weights of linear RGB; re-exported)


def luminance(rgb: np.ndarray) -> np.ndarray:
    """Rec.709 luminance of (..., 3) linear RGB."""
    return np.asarray(rgb, np.float64) @ LUMA


@dataclass
class CameraResponse:
    forward_table: np.ndarray  # (3,256) f_c(i/255), in [0,1]
    inverse_table: np.ndarray  # (3,256) f_c^-1(z/255), exposure-scaled radiance X in [0,1]
    exposure_time: float = 1.0

    def __post_init__(self) -> None:
        self.forward_table = np.asarray(self.forward_table, np.float64)
        self.inverse_table = np.asarray(self.inverse_table, np.float64)
        if self.forward_table.shape != (3, 256) or self.inverse_table.shape != (3, 256):
            raise ValueError("camera response tables must be 3 x 256")
        grid = np.arange(256) / 255.0
        self._xs, self._ys = [], []
        for c in range(3):
            x = np.concatenate([grid, self.inverse_table[c]])
            y = np.concatenate([self.forward_table[c], grid])
            order = np.argsort(x, kind="stable")
            x, y = x[order], y[order]
            y = np.maximum.accumulate(y)  # monotone despite rounding in the tables
            self._xs.append(x)
            self._ys.append(y)

    def breakpoints(self) -> tuple[np.ndarray, np.ndarray]:
        """(xs, ys), each (3, 512): the merged, sorted samples f interpolates piecewise-linearly
        per channel (f: np.interp(x, xs[c], ys[c]); f_inv: np.interp(y, ys[c], xs[c]))."""
        return np.stack(self._xs), np.stack(self._ys)

    def f(self, x: np.ndarray) -> np.ndarray:
        """Response on exposure-scaled radiance X (..., 3) -> [0,1] (float, not quantised)."""
        x = np.clip(np.asarray(x, np.float64), 0.0, 1.0)
        out = np.empty_like(x)
        for c in range(3):
            out[..., c] = np.interp(x[..., c], self._xs[c], self._ys[c])
        return out

    def f_inv(self, y: np.ndarray) -> np.ndarray:
        """Inverse response: [0,1] (..., 3) -> exposure-scaled radiance X."""
        y = np.clip(np.asarray(y, np.float64), 0.0, 1.0)
        out = np.empty_like(y)
        for c in range(3):
            out[..., c] = np.interp(y[..., c], self._ys[c], self._xs[c])
        return out

    def to_levels(self, radiance: np.ndarray) -> np.ndarray:
        """T(L): radiance (..., 3) -> continuous pixel levels in [0, 255] (float64)."""
        return 255.0 * self.f(np.asarray(radiance, np.float64) * self.exposure_time)

    def to_pixels(self, radiance: np.ndarray) -> np.ndarray:
        """T(L) quantised to uint8, as the camera does."""
        return np.clip(np.rint(self.to_levels(radiance)), 0, 255).astype(np.uint8)

    def to_radiance(self, pixels: np.ndarray) -> np.ndarray:
        """T^-1: 8-bit pixels (..., 3) -> radiance; exact table inverse so T(T^-1(z)) == z.

        Saturated pixels (255) come back as the radiance at the top of the range: a lower bound.
        """
        z = np.asarray(pixels)
        if z.dtype == np.uint8:
            out = np.empty(z.shape, np.float64)
            for c in range(3):
                out[..., c] = self.inverse_table[c][z[..., c]]
            return out / self.exposure_time
        return self.f_inv(np.asarray(z, np.float64) / 255.0) / self.exposure_time
