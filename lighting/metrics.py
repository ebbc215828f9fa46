"""Image error metrics for composites against a truth or a reference (seed sec. 8.2).

The seed notes that mean squared error says little about what a viewer sees (sec. 8.2) and
describes perceptual metrics (VDP, sec. 8.2.4). photoar reports:
  * the benchmark scorer's figures (../shared/tools/score.py, mirrored by `score_regions`):
    on 8-bit Rec.709 luminance blurred with a Gaussian of sigma 2 px, regions
      mask     = truth mask > 127 dilated by a 5x5 square (the object),
      affected = outside the mask, |truth - background| > 2 levels (shadows, interreflections),
      rest     = everything else;
    energy_ratio = sum_affected(bg - ours) / sum_affected(bg - truth) (shadow energy),
    rmse_affected, spurious (share of rest pixels moved by > 2 levels), rmse_object, bias_object;
  * RMSE over any region, and SSIM (Wang, Bovik, Sheikh, Simoncelli 2004: Gaussian window
    sigma 1.5, K1 = 0.01, K2 = 0.03) on luminance, with its per-pixel map;
  * error heat-maps (|difference| in levels, or 1 - SSIM) as colour PNGs with a scale bar.
FLIP (Andersson et al. 2020) would be the perceptual metric of choice; its maintained package
(`flip-evaluator`) is not installed in this environment and none may be installed here, so
`compare` reports it as unavailable and the heat-maps stand in for its error map.

Images: (H,W,3) RGB, uint8 (8-bit levels) or float (linear radiance); regions (H,W) bool.
"""
from __future__ import annotations

import numpy as np

from recon.response import LUMA

LUM_RGB = LUMA  # Rec.709, RGB order (recon.response.LUMA)
FLIP_NOTE = ("FLIP not computed: the maintained package (flip-evaluator) is not installed here and "
             "packages may not be installed; see the error heat-map instead")


def luminance(img: np.ndarray) -> np.ndarray:
    """Rec.709 luminance (H,W) float64 of an RGB image (H,W,3) (levels stay levels)."""
    img = np.asarray(img, np.float64)
    if img.ndim == 2:
        return img
    return img[..., :3] @ LUM_RGB


def _blur(x: np.ndarray, sigma: float) -> np.ndarray:
    import cv2

    return cv2.GaussianBlur(np.asarray(x, np.float64), (0, 0), sigma) if sigma > 0 else np.asarray(x, np.float64)


def _check(a: np.ndarray, b: np.ndarray, what: str = "images") -> None:
    if a.shape[:2] != b.shape[:2]:
        raise ValueError(f"{what}: shapes differ, {a.shape} vs {b.shape}")


def object_region(mask: np.ndarray) -> np.ndarray:
    """score.py's object region: mask (8-bit grey, or bool) > 127, dilated by a 5x5 square."""
    import cv2

    m = np.asarray(mask)
    binary = (m > 127) if m.dtype != bool else m
    return cv2.dilate(binary.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0


def regions(background: np.ndarray, truth: np.ndarray, mask: np.ndarray, sigma: float = 2.0,
            threshold: float = 2.0) -> dict[str, np.ndarray]:
    """score.py's regions {'mask', 'affected', 'rest'} (H,W) bool from 8-bit background/truth."""
    _check(background, truth)
    m = object_region(mask)
    lb, lt = _blur(luminance(background), sigma), _blur(luminance(truth), sigma)
    affected = ~m & (np.abs(lt - lb) > threshold)
    return {"mask": m, "affected": affected, "rest": ~m & ~affected}


def rmse(a: np.ndarray, b: np.ndarray, region: np.ndarray | None = None, sigma: float = 0.0) -> float:
    """RMSE of luminance(a) - luminance(b) (blurred by `sigma` px first) over `region` (all if None).
    Units: those of the images (8-bit levels for uint8). 0.0 for an empty region."""
    _check(a, b)
    d = _blur(luminance(a), sigma) - _blur(luminance(b), sigma)
    d = d[region] if region is not None else d.ravel()
    return float(np.sqrt(np.mean(d ** 2))) if d.size else 0.0


def shadow_energy_ratio(ours: np.ndarray, background: np.ndarray, truth: np.ndarray, region: np.ndarray,
                        sigma: float = 2.0) -> float:
    """sum_region(bg - ours) / sum_region(bg - truth) on blurred luminance (1 = right shadow
    strength); NaN when the truth removes no energy there."""
    lb = _blur(luminance(background), sigma)
    d_ours = (lb - _blur(luminance(ours), sigma))[region].sum()
    d_truth = (lb - _blur(luminance(truth), sigma))[region].sum()
    return float(d_ours / d_truth) if abs(d_truth) > 1e-9 else float("nan")


def score_regions(ours: np.ndarray, background: np.ndarray, truth: np.ndarray, mask: np.ndarray) -> dict:
    """The figures of ../shared/tools/score.py for 8-bit RGB images (same definitions)."""
    _check(ours, background, "composite vs background")
    r = regions(background, truth, mask)
    lb, lt, lc = (_blur(luminance(x), 2.0) for x in (background, truth, ours))
    aff, rest, m = r["affected"], r["rest"], r["mask"]
    return {
        "affected_px": int(aff.sum()),
        "energy_ratio": shadow_energy_ratio(ours, background, truth, aff),
        "rmse_affected": rmse(lc, lt, aff),
        "rmse_affected_if_untouched": rmse(lb, lt, aff),
        "spurious": float((np.abs(lc - lb)[rest] > 2.0).mean()) if rest.any() else 0.0,
        "rmse_object": rmse(lc, lt, m),
        "bias_object": float(np.mean((lc - lt)[m])) if m.any() else 0.0,
    }


def ssim_map(a: np.ndarray, b: np.ndarray, data_range: float | None = None, sigma: float = 1.5) -> np.ndarray:
    """Per-pixel SSIM (H,W) of the luminances of a and b (Wang et al. 2004, Gaussian window).

    data_range: L of the constants C1 = (0.01 L)^2, C2 = (0.03 L)^2; default 255 for uint8 input,
    else the larger maximum of the two luminances.
    """
    _check(a, b)
    x, y = luminance(a), luminance(b)
    if data_range is None:
        data_range = 255.0 if np.asarray(a).dtype == np.uint8 else float(max(x.max(), y.max(), 1e-12))
    c1, c2 = (0.01 * data_range) ** 2, (0.03 * data_range) ** 2
    mx, my = _blur(x, sigma), _blur(y, sigma)
    sxx = _blur(x * x, sigma) - mx * mx
    syy = _blur(y * y, sigma) - my * my
    sxy = _blur(x * y, sigma) - mx * my
    return ((2 * mx * my + c1) * (2 * sxy + c2)) / ((mx * mx + my * my + c1) * (sxx + syy + c2))


def ssim(a: np.ndarray, b: np.ndarray, region: np.ndarray | None = None, data_range: float | None = None) -> float:
    """Mean SSIM over `region` (all pixels if None); 1.0 for identical images."""
    s = ssim_map(a, b, data_range)
    s = s[region] if region is not None else s
    return float(np.mean(s)) if s.size else 1.0


def compare(a: np.ndarray, b: np.ndarray, region: np.ndarray | None = None) -> dict:
    """RMSE, mean absolute error, largest error, PSNR and SSIM of luminance, a against b, over
    `region`. Units: 8-bit levels for uint8 images, else the images' radiance units."""
    _check(a, b)
    d = luminance(a) - luminance(b)
    d = d[region] if region is not None else d.ravel()
    peak = 255.0 if np.asarray(b).dtype == np.uint8 else float(max(luminance(b).max(), 1e-12))
    e = float(np.sqrt(np.mean(d ** 2))) if d.size else 0.0
    return {
        "pixels": int(d.size),
        "rmse": e,
        "mae": float(np.mean(np.abs(d))) if d.size else 0.0,
        "max_abs": float(np.max(np.abs(d))) if d.size else 0.0,
        "psnr_db": float(20 * np.log10(peak / e)) if e > 0 else float("inf"),
        "ssim": ssim(a, b, region),
        "flip": None,
        "flip_note": FLIP_NOTE,
    }


def heatmap(values: np.ndarray, vmax: float, label: str = "", region: np.ndarray | None = None) -> np.ndarray:
    """Colour heat-map (H,W+bar,3) uint8 RGB of non-negative `values` (H,W) scaled to [0, vmax]
    (OpenCV's perceptually ordered 'inferno' map), with a scale bar and `label` at the right;
    pixels outside `region` are drawn grey."""
    import cv2

    v = np.clip(np.nan_to_num(np.asarray(values, np.float64)) / max(vmax, 1e-12), 0.0, 1.0)
    img = cv2.applyColorMap(np.rint(v * 255).astype(np.uint8), cv2.COLORMAP_INFERNO)  # BGR
    if region is not None:
        img[~region] = (96, 96, 96)
    H = img.shape[0]
    bar = np.full((H, 90, 3), 255, np.uint8)
    top = min(20, H // 4)
    ramp = np.linspace(255, 0, max(H - 2 * top, 1)).astype(np.uint8)[:, None]
    bar[top:top + len(ramp), 10:30] = cv2.applyColorMap(np.repeat(ramp, 20, 1), cv2.COLORMAP_INFERNO)
    font = cv2.FONT_HERSHEY_SIMPLEX
    cv2.putText(bar, f"{vmax:.3g}", (33, top + 6), font, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(bar, "0", (33, top + len(ramp)), font, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
    if label:
        cv2.putText(bar, label[:12], (2, H - 5), font, 0.35, (0, 0, 0), 1, cv2.LINE_AA)
    return np.concatenate([img, bar], 1)[..., ::-1].copy()


def error_heatmap(a: np.ndarray, b: np.ndarray, vmax: float | None = None, sigma: float = 0.0,
                  region: np.ndarray | None = None) -> np.ndarray:
    """Heat-map of |luminance(a) - luminance(b)| (blurred by sigma px); vmax default 10 levels for
    uint8 images, else the 99th percentile of the error."""
    _check(a, b)
    d = np.abs(_blur(luminance(a), sigma) - _blur(luminance(b), sigma))
    if vmax is None:
        vmax = 10.0 if np.asarray(a).dtype == np.uint8 else float(np.percentile(d, 99) or 1.0)
    return heatmap(d, vmax, "|dL|", region)


def ssim_heatmap(a: np.ndarray, b: np.ndarray, region: np.ndarray | None = None) -> np.ndarray:
    """Heat-map of 1 - SSIM (0 = identical structure) on a fixed [0, 0.5] scale."""
    return heatmap(1.0 - ssim_map(a, b), 0.5, "1-SSIM", region)
