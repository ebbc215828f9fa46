"""Find a mirror ball in a wider photo and crop it to a square, ball-inscribed probe image.

Detection: OpenCV's Hough transform (cv2.HoughCircles) gives a coarse circle; it is refined to
sub-pixel accuracy on the edge: along rays from the coarse centre, the grey-level gradient's peak
(parabolic interpolation) gives one edge point per ray, and a circle is fitted to those points by
least squares (algebraic fit, then geometric refinement with scipy), dropping points more than
3 robust sigmas off, twice. Pixel convention: the centre of the top-left pixel is (0, 0).
"""
from __future__ import annotations

import numpy as np

from kernels.luma import LUMA

CROP_SIZE = 256  # px, the size of the ball-inscribed crops written for the engine


def _grey(img: np.ndarray) -> np.ndarray:
    g = img.astype(np.float32)
    return g @ LUMA.astype(np.float32) if g.ndim == 3 else g


def hough_circles(img: np.ndarray, n_max: int = 12) -> list[tuple[float, float, float]]:
    """Candidate circles (cx, cy, r) px of an RGB/grey uint8 image by cv2.HoughCircles (both
    gradient variants), strongest first."""
    import cv2

    g = cv2.GaussianBlur(np.clip(_grey(img), 0, 255).astype(np.uint8), (0, 0), 1.5)
    h, w = g.shape
    n = min(h, w)
    rmin, rmax = max(8, n // 20), n // 2
    out: list[tuple[float, float, float]] = []
    for method, p1, p2 in ((cv2.HOUGH_GRADIENT_ALT, 60, 0.6), (cv2.HOUGH_GRADIENT, 80, 30)):
        c = cv2.HoughCircles(g, method, dp=1.5 if method == cv2.HOUGH_GRADIENT_ALT else 1.0, minDist=n / 16,
                             param1=p1, param2=p2, minRadius=rmin, maxRadius=rmax)
        if c is not None:
            out += [(float(x), float(y), float(r)) for x, y, r in c[0][:n_max]]
    return out


def _fit_circle(pts: np.ndarray) -> np.ndarray:
    """Least-squares circle (cx, cy, r) through points (N,2): algebraic start, geometric refinement."""
    from scipy.optimize import least_squares

    A = np.column_stack([2 * pts, np.ones(len(pts))])
    b = (pts ** 2).sum(1)
    sol = np.linalg.lstsq(A, b, rcond=None)[0]
    x0 = np.array([sol[0], sol[1], np.sqrt(max(sol[2] + sol[0] ** 2 + sol[1] ** 2, 1e-12))])
    res = least_squares(lambda p: np.hypot(pts[:, 0] - p[0], pts[:, 1] - p[1]) - p[2], x0, method="lm")
    return res.x


def _edge_points(g: np.ndarray, p: np.ndarray, band: float, n_rays: int) -> tuple[np.ndarray, np.ndarray]:
    """Per ray from centre p[:2], the sub-pixel radius of the strongest grey-level step within
    p[2](1 +- band) -> edge points (N,2) and their gradient magnitudes (N,)."""
    from scipy.ndimage import map_coordinates

    th = np.linspace(0, 2 * np.pi, n_rays, endpoint=False)
    s = np.arange(p[2] * (1 - band), p[2] * (1 + band), 0.25)
    X = p[0] + np.cos(th)[:, None] * s[None]
    Y = p[1] + np.sin(th)[:, None] * s[None]
    d = 0.0
    for c in range(g.shape[2]):  # colour edges count too: sum of the channels' gradient magnitudes
        prof = map_coordinates(g[..., c], [Y.ravel(), X.ravel()], order=1, mode="nearest").reshape(X.shape)
        d = d + np.abs(np.gradient(prof, 0.25, axis=1))
    k = np.clip(np.argmax(d, axis=1), 1, len(s) - 2)
    rows = np.arange(n_rays)
    y0, y1, y2 = d[rows, k - 1], d[rows, k], d[rows, k + 1]
    den = y0 - 2 * y1 + y2
    off = np.where(np.abs(den) > 1e-12, 0.5 * (y0 - y2) / np.where(den == 0, 1, den), 0.0)
    rad = s[k] + np.clip(off, -1, 1) * 0.25
    return np.column_stack([p[0] + np.cos(th) * rad, p[1] + np.sin(th) * rad]), y1


def refine_circle(img: np.ndarray, cx: float, cy: float, r: float, n_rays: int = 720,
                  bands: tuple[float, ...] = (0.3, 0.15, 0.05, 0.02)) -> tuple[tuple[float, float, float], float]:
    """Sub-pixel circle from gradient peaks along rays, in narrowing bands around the current
    circle; returns (cx, cy, r) px and its support: the median gradient magnitude (grey levels per
    px) of the edge points within 1 px of the circle times their share of the rays."""
    from scipy.ndimage import gaussian_filter

    g = np.asarray(img, np.float64)
    g = gaussian_filter(g[..., None] if g.ndim == 2 else g, (1.0, 1.0, 0))
    p = np.array([cx, cy, r], float)
    support = 0.0
    for band in bands:
        pts, mag = _edge_points(g, p, band, n_rays)
        keep = mag > 0
        q = p
        for _ in range(3):
            if keep.sum() < 10:
                break
            q = _fit_circle(pts[keep])
            e = np.hypot(pts[:, 0] - q[0], pts[:, 1] - q[1]) - q[2]
            mad = 1.4826 * np.median(np.abs(e[keep] - np.median(e[keep]))) + 1e-6
            keep = (np.abs(e) < max(3 * mad, 0.5)) & (mag > 0)
        if not (np.all(np.isfinite(q)) and q[2] > 2):
            return (float(p[0]), float(p[1]), float(p[2])), 0.0
        p = q
        on = np.abs(np.hypot(pts[:, 0] - p[0], pts[:, 1] - p[1]) - p[2]) < 1.0
        support = float(np.median(mag[on]) * on.mean()) if on.any() else 0.0
    return (float(p[0]), float(p[1]), float(p[2])), support


def find_ball(img: np.ndarray, src: str = "<probe>") -> tuple[float, float, float]:
    """(cx, cy, r) px of the mirror ball in a photo: of the Hough candidates, refined, the circle with
    the strongest, most complete edge. ValueError naming `src` if there is none."""
    return find_ball_scored(img, src)[0]


def find_ball_in_bracket(images: list[np.ndarray], names: list[str]) -> tuple[float, float, float]:
    """The ball's circle in a bracket shot from a tripod: the best-supported detection over the
    exposures (a dark or washed-out exposure may show too little edge), checked on every image with
    a clear edge (support at least half the best): re-fitted in a narrow band, it must stay within
    2 px (else the camera moved)."""
    found = [find_ball_scored(img, n) for img, n in zip(images, names)]
    best, top = max(found, key=lambda f: f[1])
    for img, n in zip(images, names):
        (x, y, r), support = refine_circle(img, *best, bands=(0.05, 0.02))
        off = max(np.hypot(x - best[0], y - best[1]), abs(r - best[2]))
        if support > 0.5 * top and off > 2.0:
            raise ValueError(f"{n}: the ball moved between exposures (its circle is {off:.1f} px off the best "
                             "exposure's); shoot the bracket from a tripod")
    return best


def find_ball_scored(img: np.ndarray, src: str = "<probe>") -> tuple[tuple[float, float, float], float]:
    """find_ball's circle and its edge support (refine_circle)."""
    best, best_support = None, 0.0
    for c in hough_circles(img):
        circle, support = refine_circle(img, *c)
        if support > best_support:
            best, best_support = circle, support
    if best is None:
        raise ValueError(f"{src}: --probe-circle auto found no circle (the mirror ball) in the image")
    return best, best_support


def crop_ball(img: np.ndarray, cx: float, cy: float, r: float, size: int = CROP_SIZE) -> np.ndarray:
    """Square size x size crop (bilinear resampling) with the ball as the inscribed circle."""
    import cv2

    s = r / (size / 2.0)  # source px per crop px
    M = np.array([[s, 0, cx - s * (size - 1) / 2.0], [0, s, cy - s * (size - 1) / 2.0]])
    return cv2.warpAffine(img, M, (size, size), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                          borderMode=cv2.BORDER_REPLICATE)
