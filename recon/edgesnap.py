"""Snap hand-clicked line segments to the photo's edges, to sub-pixel accuracy (for recon/vanishing.py).

Why: a clicked endpoint is off by about half a pixel (the scenes' annotations: N(0, 0.5^2) px per
coordinate), and with two endpoints per segment that noise is what limits the focal length from
vanishing points (window_room: 1.1 % RMS over noise draws). The edge the user clicked is in the photo
along its whole length: measured at every pixel along it, its line is known to about 0.05-0.1 px.
No library call does "refine this given segment"; OpenCV's line detectors find their own segments,
which then need matching and are no more accurate. So, per segment:

1. the photo is made roughly linear (gray, sRGB-like gamma 2.2: the camera's response is not known
   at calibration time) and its gradient taken (Sobel);
2. the gradient along the segment's normal is sampled (bilinear) at every pixel along the middle
   84 % of the segment, at offsets -1.75 ... +1.75 px (3.5 sigma of the click noise) every 0.25 px;
3. the edge's polarity is the sign most samples agree on; each sample's edge is the centroid of the
   gradient above half its peak; samples whose peak lies on the window's border (another edge, or
   none), that see a second edge in the window over half as strong (a thin leg's two sides: which
   one was meant is ambiguous, and the far side drags the near one's peak), or that see a clipped pixel (>= 250 in any channel) within
   3 px, are skipped: clipping moves the apparent edge of a bright emitter by up to half a pixel;
4. a robust line (cv2.fitLine, Huber) through the sample edges. The snap is accepted when at least
   60 % of the samples found the edge, their robust spread is at most 0.25 px and the click's
   endpoints lie within the click noise of the line (chi-square, 2 dof, 99 %); the segment's
   endpoints are the clicked ones projected onto the fitted line.

Each segment gets a noise figure sigma (px, per endpoint, across the line): the click's noise for
segments left as clicked, max(0.1, 2 spread / sqrt(n)) for snapped ones; the 0.1 px floor stands for
what the sample spread does not show (texture next to the edge, the unknown response, interpolation).
A snap can still lock onto a neighbouring edge (a leg's far side, a shadow): `calibrate` puts each
snapped segment back to its click when the joint fit disagrees with it (recon/vanishing.py).

Conventions: pixel (0,0) is the centre of the top-left pixel (as recon/camera.py).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

SEARCH_PX = 1.75  # half-width of the search across the clicked line, px
STEP_PX = 0.25  # sampling step across the line, px
CLIP_LEVEL = 250  # an 8-bit pixel at or above this (any channel) counts as clipped
CLIP_RADIUS_PX = 3.0
AMBIGUOUS = 0.5  # a second gradient peak this strong (relative) makes a sample ambiguous
MIN_FOUND = 0.6  # fraction of the samples that must find the edge
MAX_SPREAD_PX = 0.25  # robust spread of the sample edges about the fitted line
SIGMA_FLOOR_PX = 0.1
LOCATORS = ("centroid", "step", "kink")
LOCATOR = "centroid"  # the sub-pixel rule of EdgeImage.snap and recon.photoedges.PhotoEdges.subpixel: "centroid"
# (the gradient's centroid above half its peak), "step" (step_offsets: a blurred two-level step fitted to the
# linear profile) or "kink" (the same with each side's own linear shading); measured worse, see step_offsets
STEP_HALF_PX = 2.0  # step_offsets: the profile fitted spans +-this about the gradient's peak (px)
KINK_HALF_PX = 3.0  # step_offsets with slopes ("kink"): the profile fitted spans +-this (px): each side's slope
# needs pixels past the step's blur
STEP_REACH_PX = 1.0  # step_offsets: the step's centre is searched within +-this of the gradient's peak (px)
STEP_GRID_PX = 0.05  # step_offsets: grid of the candidate centres (px), refined by a parabola
STEP_SIGMA_PX = 0.55  # step_offsets: the model step's blur (erf sigma, px): a box-filtered pixel (variance 1/12 at
# any angle) read by bilinear interpolation (a tent over two pixels: 1/6 on average); a wrong width costs precision,
# not bias (the model and the blurred step are both odd about their centres)
CHI2_2DOF_99 = 9.21  # 99 % point of the chi-square distribution with 2 degrees of freedom


@dataclass
class SnapResult:
    segments: np.ndarray  # (N,4) u1,v1,u2,v2: snapped, or as clicked where `snapped` is False
    sigma_px: np.ndarray  # (N,) noise per endpoint across the line, px
    snapped: np.ndarray  # (N,) bool
    spread_px: np.ndarray  # (N,) robust spread of the sample edges (NaN where not snapped)


class EdgeImage:
    """The photo prepared once for snapping: linear gray gradient and the clipped-pixel mask."""

    def __init__(self, image: np.ndarray):
        import cv2

        img = np.asarray(image)
        if img.ndim not in (2, 3) or img.dtype != np.uint8:
            raise ValueError(f"edge snapping needs an 8-bit gray or RGB image, got {img.dtype} {img.shape}")
        from recon.response import luminance

        rgb = img if img.ndim == 3 else img[:, :, None]
        lin = (rgb[:, :, :3].astype(np.float32) / 255.0) ** 2.2
        gray = (luminance(lin) if lin.shape[2] == 3 else lin[:, :, 0]).astype(np.float32)
        self.gray = gray  # linear gray (gamma 2.2): the profiles step_offsets fits
        self.gx = cv2.Sobel(gray, cv2.CV_32F, 1, 0, ksize=3) / 8.0
        self.gy = cv2.Sobel(gray, cv2.CV_32F, 0, 1, ksize=3) / 8.0
        clipped = (rgb.max(axis=2) >= CLIP_LEVEL).astype(np.uint8)
        r = int(np.ceil(CLIP_RADIUS_PX))
        self.near_clip = cv2.dilate(clipped, np.ones((2 * r + 1, 2 * r + 1), np.uint8)) > 0
        self.shape = gray.shape

    def _sample(self, img: np.ndarray, P: np.ndarray) -> np.ndarray:
        import cv2

        return cv2.remap(img, P[..., 0].astype(np.float32), P[..., 1].astype(np.float32), cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_CONSTANT, borderValue=0)

    def snap(self, seg: np.ndarray, click_sigma_px: float = 0.5, search_px: float = SEARCH_PX,
             clipped_ok: bool = False, opposite_px: float | None = None) -> tuple[np.ndarray, float, int] | None:
        """(snapped segment (4,), robust spread px, samples used), or None when the edge is not found.

        search_px: half-width of the search across the line (px; SEARCH_PX for calibrate's 0.5 px
        clicks, wider for noisier ones); clipped_ok: keep samples next to clipped pixels (the edge
        of a clipped emitter, which is all there is to find there, moves out by under a pixel);
        opposite_px: an edge of the opposite polarity makes a sample ambiguous only within this
        distance (px) of its peak (None: anywhere in the search window, as for thin bars; a
        textured floor next to a long edge has such edges a few pixels off, too far to drag it)."""
        import cv2

        a, b = np.asarray(seg[:2], float), np.asarray(seg[2:], float)
        length = float(np.linalg.norm(b - a))
        if length < 8:
            return None
        d = (b - a) / length
        n = np.array([-d[1], d[0]])
        ts = np.arange(0.08 * length, 0.92 * length, 1.0)
        ss = np.arange(-search_px, search_px + 1e-9, STEP_PX)
        base = a + ts[:, None] * d  # (T,2)
        P = base[:, None, :] + ss[None, :, None] * n  # (T,S,2)
        inside = np.all((P[..., 0] >= 1) & (P[..., 0] <= self.shape[1] - 2) & (P[..., 1] >= 1)
                        & (P[..., 1] <= self.shape[0] - 2), axis=1)
        g = self._sample(self.gx, P) * n[0] + self._sample(self.gy, P) * n[1]  # (T,S)
        iu = np.clip(np.rint(base).astype(int), 0, [self.shape[1] - 1, self.shape[0] - 1])
        ok = inside if clipped_ok else inside & ~self.near_clip[iu[:, 1], iu[:, 0]]
        if ok.sum() < MIN_FOUND * len(ts):
            return None
        peak = g[np.arange(len(ts)), np.argmax(np.abs(g), axis=1)]
        sgn = 1.0 if np.median(peak[ok]) >= 0 else -1.0
        g = g * sgn
        k = np.argmax(g, axis=1)
        gmax = g[np.arange(len(ts)), k]
        ok &= (k > 0) & (k < len(ss) - 1) & (gmax > 0)
        # ambiguous: a second edge in the window over half as strong: of the opposite polarity anywhere
        # (a thin bar: its far side's response also drags the peak), of the same over 1 px away
        locmax = np.zeros_like(g, bool)
        locmax[:, 1:-1] = (g[:, 1:-1] >= g[:, :-2]) & (g[:, 1:-1] >= g[:, 2:])
        near = np.abs(ss[None, :] - ss[k][:, None]) <= 1.0  # within 1 px of the sample's peak
        opp = g < -AMBIGUOUS * gmax[:, None]
        if opposite_px is not None:
            opp &= np.abs(ss[None, :] - ss[k][:, None]) <= opposite_px
        second = opp | (locmax & ~near & (g > AMBIGUOUS * gmax[:, None]))
        ok &= ~np.any(second, axis=1)
        # centroid of the gradient above half its peak, within +-1 px of the peak
        w = np.where(near, np.clip(g - 0.5 * gmax[:, None], 0, None), 0.0)
        wsum = w.sum(axis=1)
        ok &= wsum > 0
        if ok.sum() < MIN_FOUND * len(ts):
            return None
        off = (w[ok] * ss[None, :]).sum(axis=1) / wsum[ok]
        pts = base[ok] + off[:, None] * n
        if LOCATOR in ("step", "kink"):
            off, found = step_offsets(self, base[ok], n, ss[k[ok]], np.full(int(ok.sum()), sgn),
                                      slopes=LOCATOR == "kink")
            pts = base[ok][found] + off[found, None] * n
        if len(pts) < 3:
            return None
        vx, vy, x0, y0 = cv2.fitLine(pts.astype(np.float32), cv2.DIST_HUBER, 0, 0.01, 0.01).ravel()
        dd, p0 = np.array([vx, vy], float), np.array([x0, y0], float)
        nn = np.array([-dd[1], dd[0]])  # the fitted line's normal
        r = (pts - p0) @ nn
        spread = 1.4826 * float(np.median(np.abs(r - np.median(r))))
        if spread > MAX_SPREAD_PX:
            return None
        # the click must agree with the edge found: its endpoints' distances from the fitted line are
        # N(0, click sigma^2) if it is the same edge (chi-square, 2 dof, 99 %)
        if ((a - p0) @ nn) ** 2 + ((b - p0) @ nn) ** 2 > CHI2_2DOF_99 * click_sigma_px ** 2:
            return None
        proj = lambda q: p0 + np.dot(q - p0, dd) * dd  # noqa: E731
        return np.concatenate([proj(a), proj(b)]), spread, int(len(pts))


def step_offsets(E: EdgeImage, base: np.ndarray, n: np.ndarray, s0: np.ndarray, polarity: np.ndarray,
                 reach: float = STEP_REACH_PX, slopes: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """The edge across each sample by a blurred two-level step fitted to its linear profile: the offset (N,) along n
    from base (N,2) of the step's centre, and which samples found one. n: unit normal(s) (2,) or (N,2); s0 (N,): the
    gradient's peak along n (px), the window's centre; polarity (N,): +1 where the photo is brighter along +n.

    Why it was built (issue 34 item 6, edge111): every edge class's photo edge sits 0.05-0.2 px toward its brighter
    side at the true camera (docs/unseen.md, cam110b), and the centroid of the gradient above half its peak is a
    nonlinear rule (the clip at half the peak, the argmax that places the window) that could lean toward the
    noisier, brighter side. A least-squares step is the principled alternative. Measured (docs/unseen.md, edge111):
    on rendered box-filtered steps both rules are within 0.025 px of the truth without noise, and both lean alike
    (0.1-0.3 px) when the bright side carries 30 % texture (the window still follows the noisy side, and a fit
    whose noise differs between its two sides is not unbiased either); on the shared rooms at the true camera
    the two find every floor-wall line's lean to within 0.02 px. The lean is the photo's (a dark seam row of
    roomgen's floor texture along the z = 0 wall, +0.29-0.35 px toward the wall in all three shared rooms), not the
    rule's, and the step's extra scatter (0.06 px rms on a clean step against the centroid's 0.03) made the
    cameras worse (window_room object 0.16 -> 1.01 px, sun_room 0.33 -> 0.83, sun_110 0.28 -> 0.53). So LOCATOR
    stays "centroid"; this is kept for the measurement (bench_camrefine / bench_cam110b --locator step).

    The model: I(s) = a + d Phi((s - c) / STEP_SIGMA_PX) over s0 +- STEP_HALF_PX (STEP_PX apart, bilinear on the
    linear gray), d > 0 along the polarity; for each centre c on a STEP_GRID_PX grid within STEP_REACH_PX of s0
    the levels a, d are solved in closed form and the c with the least squared residual wins, refined by a
    parabola. Not found: the best c on the grid's border, or no c with d > 0. slopes ("kink"): each side also gets
    its own linear shading, I = a + d Phi + k1 (s - c)(1 - Phi) + k2 (s - c) Phi over +-KINK_HALF_PX (a floor darkening
    toward the wall that holds the light leans a two-level fit toward the wall); measured: the floor-wall lines'
    lean at the truth +0.219 -> +0.131 px, but three times the centroid's scatter and worse cameras in three rooms
    of six (docs/unseen.md, edge111)."""
    from scipy.special import erf

    base = np.asarray(base, float).reshape(-1, 2)
    N = len(base)
    if N == 0:
        return np.zeros(0), np.zeros(0, bool)
    nn = np.broadcast_to(np.asarray(n, float), (N, 2))
    half = KINK_HALF_PX if slopes else STEP_HALF_PX
    o = np.arange(-half, half + 1e-9, STEP_PX)  # (O,)
    P = base[:, None, :] + (np.asarray(s0, float)[:, None] + o[None, :])[..., None] * nn[:, None, :]
    I = E._sample(E.gray, P).astype(np.float64) * np.asarray(polarity, float)[:, None]  # rising along +o
    c = np.arange(-reach, reach + 1e-9, STEP_GRID_PX)  # (C,)
    M = 0.5 * (1.0 + erf((o[None, :] - c[:, None]) / (np.sqrt(2.0) * STEP_SIGMA_PX)))  # (C,O)
    if slopes:  # each side's own linear shading: I = a + d Phi + k1 (s - c)(1 - Phi) + k2 (s - c) Phi
        x = o[None, :] - c[:, None]
        X = np.stack([np.ones_like(M), M, x * (1 - M), x * M], axis=2)  # (C,O,4)
        Pinv = np.linalg.pinv(X)  # (C,4,O)
        beta = np.einsum("no,cko->nck", I, Pinv)  # (N,C,4)
        XtI = np.einsum("no,cok->nck", I, X)
        gain = np.where(beta[..., 1] > 0, np.sum(beta * XtI, axis=2), -np.inf)
    else:
        Mc = M - M.mean(axis=1, keepdims=True)
        den = np.sum(Mc * Mc, axis=1)  # (C,)
        cov = I @ Mc.T  # (N,C): the step's height times den
        gain = np.where(cov > 0, cov * cov / den, -np.inf)  # the squared residual the step removes (d > 0 only)
    j = np.argmax(gain, axis=1)
    r = np.arange(N)
    ok = (j > 0) & (j < len(c) - 1) & np.isfinite(gain[r, j])
    jj = np.clip(j, 1, len(c) - 2)
    lo, mid, hi = gain[r, jj - 1], gain[r, jj], gain[r, jj + 1]
    with np.errstate(invalid="ignore", divide="ignore"):
        curv = lo - 2 * mid + hi
        sub = np.where(ok & (curv < 0), np.clip(0.5 * (lo - hi) / curv, -0.5, 0.5), 0.0)
    sub = np.nan_to_num(sub)
    return np.asarray(s0, float) + c[jj] + STEP_GRID_PX * sub, ok


def line_sigma(spread_px: float, used: int) -> float:
    """Noise (px, per endpoint, across the line) of a line snapped with robust spread spread_px from
    `used` samples: max(SIGMA_FLOOR_PX, 2 spread / sqrt(used)) (see the module docstring)."""
    return max(SIGMA_FLOOR_PX, 2.0 * float(spread_px) / float(np.sqrt(used)))


def snap_segments(image: np.ndarray | EdgeImage, segs: np.ndarray, click_sigma_px: float = 0.5) -> SnapResult:
    """Snap each clicked segment (N,4 pixels) to the photo's edge under it; see the module docstring."""
    edges = image if isinstance(image, EdgeImage) else EdgeImage(image)
    segs = np.asarray(segs, float).reshape(-1, 4)
    out, sig = segs.copy(), np.full(len(segs), float(click_sigma_px))
    snapped, spread = np.zeros(len(segs), bool), np.full(len(segs), np.nan)
    for i, s in enumerate(segs):
        r = edges.snap(s, click_sigma_px)
        if r is None:
            continue
        out[i], spread[i], used = r
        sig[i] = line_sigma(spread[i], used)
        snapped[i] = True
    return SnapResult(out, sig, snapped, spread)
