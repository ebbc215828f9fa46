"""Display tone mapping of HDR outputs (seed sec. 9.1); the camera response itself is
recon.response.CameraResponse.
"""
from __future__ import annotations

import numpy as np

from recon.response import CameraResponse, luminance  # noqa: F401  (CameraResponse: kept importable here)


# ---------------------------------------------------------------------------------------------
# Display tone mapping of HDR outputs (seed sec. 9.1): scene radiance -> display values in [0, 1].
# Images are (H,W,3) linear RGB float (scene units); results (H,W,3) float32 in [0, 1], already
# gamma-encoded for the display (`to_display_pixels` quantises them to 8 bits).
# ---------------------------------------------------------------------------------------------

DISPLAY_OPERATORS = ("reinhard", "drago", "mantiuk", "ward")


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
    return _finish(_process(cv2_tonemap("Reinhard", gamma, intensity, light_adapt, color_adapt), hdr))


def tonemap_drago(hdr: np.ndarray, gamma: float = 2.2, saturation: float = 1.0, bias: float = 0.85) -> np.ndarray:
    """Drago et al. 2003 adaptive logarithmic mapping (OpenCV), `bias` in [0.7, 0.9]."""
    return _finish(_process(cv2_tonemap("Drago", gamma, saturation, bias), hdr))


def tonemap_mantiuk(hdr: np.ndarray, gamma: float = 2.2, scale: float = 0.7, saturation: float = 1.0) -> np.ndarray:
    """Mantiuk et al. 2006 contrast-domain operator (OpenCV): compresses contrast in a
    multi-scale gradient pyramid, `scale` the contrast factor."""
    return _finish(_process(cv2_tonemap("Mantiuk", gamma, scale, saturation), hdr))


def _process(op, hdr: np.ndarray) -> np.ndarray:
    """op.process on the BGR image with OpenCV's own log at errors only: its tone mappers trip an
    internal "processing of multi-channel arrays might be changed" warning that is no concern of
    the user's (the level is restored afterwards)."""
    import cv2

    bgr = _hdr_bgr(hdr)
    level = cv2.utils.logging.getLogLevel()
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)
    try:
        return op.process(bgr)
    finally:
        cv2.utils.logging.setLogLevel(level)


def cv2_tonemap(name: str, *args):
    """OpenCV's createTonemap<name>(*args)."""
    import cv2

    return getattr(cv2, f"createTonemap{name}")(*args)


def log_average_luminance(hdr: np.ndarray, delta: float = 1e-4) -> float:
    """exp(mean(log(delta + L))) of the Rec.709 luminance L: the world adaptation luminance L_wa."""
    lum = np.maximum(luminance(np.asarray(hdr, np.float64)[..., :3]), 0.0)
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
