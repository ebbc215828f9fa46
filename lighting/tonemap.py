"""Camera response T: radiance -> 8-bit pixel value, and its inverse.

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


# ---------------------------------------------------------------------------------------------
# Display tone mapping of HDR outputs (seed sec. 9.1): scene radiance -> display values in [0, 1].
# Images are (H,W,3) linear RGB float (scene units); results (H,W,3) float32 in [0, 1], already
# gamma-encoded for the display (`to_display_pixels` quantises them to 8 bits).
# ---------------------------------------------------------------------------------------------

DISPLAY_OPERATORS = ("reinhard", "drago", "mantiuk", "ward")
_LUM709 = np.array([0.2126, 0.7152, 0.0722])


def _hdr_bgr(hdr: np.ndarray) -> np.ndarray:
    """Validated float32 BGR copy of an RGB radiance image for OpenCV's operators."""
    img = np.asarray(hdr, np.float64)
    if img.ndim != 3 or img.shape[2] < 3:
        raise ValueError(f"tone mapping needs an (H,W,3) RGB image, got shape {img.shape}")
    if not np.all(np.isfinite(img[..., :3])):
        raise ValueError("tone mapping: image has NaN or infinite values")
    return np.ascontiguousarray(np.maximum(img[..., 2::-1], 0.0), np.float32)


def _finish(bgr: np.ndarray) -> np.ndarray:
    return np.clip(np.nan_to_num(bgr[..., ::-1], nan=0.0), 0.0, 1.0).astype(np.float32)


def tonemap_reinhard(hdr: np.ndarray, gamma: float = 2.2, intensity: float = 0.0, light_adapt: float = 1.0,
                     color_adapt: float = 0.0) -> np.ndarray:
    """Reinhard et al. 2002 (photographic zone system, seed sec. 9.1.2), OpenCV's global form
    with its light/colour adaptation controls."""
    return _finish(cv2_tonemap("Reinhard", gamma, intensity, light_adapt, color_adapt).process(_hdr_bgr(hdr)))


def tonemap_drago(hdr: np.ndarray, gamma: float = 2.2, saturation: float = 1.0, bias: float = 0.85) -> np.ndarray:
    """Drago et al. 2003 adaptive logarithmic mapping (OpenCV), `bias` in [0.7, 0.9]."""
    return _finish(cv2_tonemap("Drago", gamma, saturation, bias).process(_hdr_bgr(hdr)))


def tonemap_mantiuk(hdr: np.ndarray, gamma: float = 2.2, scale: float = 0.7, saturation: float = 1.0) -> np.ndarray:
    """Mantiuk et al. 2006 contrast-domain operator (OpenCV): compresses contrast in a
    multi-scale gradient pyramid, `scale` the contrast factor."""
    return _finish(cv2_tonemap("Mantiuk", gamma, scale, saturation).process(_hdr_bgr(hdr)))


def cv2_tonemap(name: str, *args):
    """OpenCV's createTonemap<name>(*args)."""
    import cv2

    return getattr(cv2, f"createTonemap{name}")(*args)


def log_average_luminance(hdr: np.ndarray, delta: float = 1e-4) -> float:
    """exp(mean(log(delta + L))) of the Rec.709 luminance L: the world adaptation luminance L_wa."""
    lum = np.maximum(np.asarray(hdr, np.float64)[..., :3] @ _LUM709, 0.0)
    return float(np.exp(np.mean(np.log(delta + lum))))


def ward_scale_factor(L_wa: float, L_dmax: float = 100.0) -> float:
    """Ward's (1994) contrast-based scale factor m (seed sec. 9.1.3), display nits per world nit.

    A just-noticeable difference at the world adaptation luminance L_wa maps to one at the
    display adaptation L_da = L_dmax / 2 (Blackwell's threshold data,
    dL(L_a) = 0.0594 (1.219 + L_a^0.4)^2.5):
        m = [(1.219 + (L_dmax/2)^0.4) / (1.219 + L_wa^0.4)]^2.5
    L_wa and L_dmax in cd/m^2.
    """
    if not (np.isfinite(L_wa) and L_wa > 0 and L_dmax > 0):
        raise ValueError(f"Ward scale factor needs L_wa > 0 and L_dmax > 0, got {L_wa}, {L_dmax}")
    return float(((1.219 + (L_dmax / 2.0) ** 0.4) / (1.219 + L_wa ** 0.4)) ** 2.5)


def tonemap_ward(hdr: np.ndarray, nits_per_unit: float = 1.0, L_dmax: float = 100.0, gamma: float = 2.2,
                 L_wa: float | None = None) -> np.ndarray:
    """Ward's global operator: display luminance L_d = m * L_w, shown as L_d / L_dmax, clipped,
    gamma-encoded. `nits_per_unit` converts the scene's radiance units to cd/m^2 (the absolute
    level decides how dark or bright the scene looks); L_wa defaults to the log-average."""
    img = np.maximum(np.asarray(_hdr_bgr(hdr)[..., ::-1], np.float64), 0.0) * nits_per_unit
    L_wa = log_average_luminance(img) if L_wa is None else L_wa
    m = ward_scale_factor(L_wa, L_dmax)
    return (np.clip(m * img / L_dmax, 0.0, 1.0) ** (1.0 / gamma)).astype(np.float32)


def display_tonemap(hdr: np.ndarray, op: str, **kwargs) -> np.ndarray:
    """Tone-map with one of DISPLAY_OPERATORS (keyword arguments go to that operator)."""
    ops = {"reinhard": tonemap_reinhard, "drago": tonemap_drago, "mantiuk": tonemap_mantiuk, "ward": tonemap_ward}
    if op not in ops:
        raise ValueError(f"unknown tone-mapping operator {op!r}; choose one of {', '.join(DISPLAY_OPERATORS)}")
    return ops[op](hdr, **kwargs)


def to_display_pixels(display: np.ndarray) -> np.ndarray:
    """Display values in [0, 1] -> uint8 (H,W,3)."""
    return np.clip(np.rint(np.asarray(display, np.float64) * 255.0), 0, 255).astype(np.uint8)
