"""Find a room edge's line in a noisy photo: integrate the gradient along the whole projected edge.

Why: recon/camrefine.py's sub-pixel stage measured the edge at every sample on its own (edgesnap's
centroid of a 4 px gradient profile). In a photo whose pixel noise is comparable to an edge's contrast
(a path-traced room at 24 samples per pixel: ~16-23 levels of noise against a wall-floor crease of a few
levels) each profile's peak is mostly noise, and the fit chases grain. A projected room edge is a
straight line, and a small camera error moves it to another straight line: its offset across the edge
varies linearly along it. So the edge is measured as one line, by summing the gradient along every
candidate line near the projection, and its significance is judged against the photo's own noise,
measured on the same strip:

1. the strip: the linear gray gradient (recon/edgesnap.EdgeImage) across the edge (along its image
   normal n), sampled (bilinear) at each edge sample (SAMPLE spacing, ~3 px, about independent after
   the 3x3 Sobel) at offsets -R ... +R px every STEP_PX;
2. every line whose two end offsets lie on that grid is scored by the mean gradient along it; the best
   |score| wins (polarity: either);
3. the strip's noise sigma_g is the robust spread (1.4826 MAD) of its gradients about their per-offset
   median; the mean over S samples has noise sigma_g / sqrt(S); the line counts as found when its score
   exceeds what pure noise reaches over the lines tried with at most 1 % probability (Bonferroni over
   the M = (2R / STEP_PX + 1)^2 lines tried: z = Phi^-1(1 - 0.01 / (2M)), 4.4 at R = 4 px; counting
   only lines whose ends lie INDEPENDENT_PX apart, 3.4, let 3 of 40 pure-noise strips pass): no
   threshold in levels, the photo's noise sets it;
4. not found when its peak lies on the grid's border (the edge is outside the window), or when a
   second significant line parallel to it, over 1 px away, of the same polarity, scores over
   edgesnap's AMBIGUOUS fraction (0.5) of the best (two parallel edges: which one the room edge is
   cannot be told); S counts independent samples only (INDEPENDENT_PX apart along the edge: an edge
   running towards the camera is sampled more densely than that);
5. sub-pixel: a parabola through the score's three grid values about the peak, per end offset;
6. the line's noise: each sample's own peak within 1 px of the line (parabolic) spreads about it by
   the robust spread s; the noise of the line's mean offset is s / sqrt(S) (S independent samples). No
   floor here: what the spread does not show (the room model's own offsets) is the caller's to add.

Conventions: pixel (0,0) is the centre of the top-left pixel (recon/camera.py); offsets along the
edge's unit normal n (px).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from recon.edgesnap import AMBIGUOUS

STEP_PX = 0.25  # grid step of the end offsets, px (edgesnap's profile step)
FALSE_ALARM = 0.01  # probability that pure noise passes the significance test on one edge
INDEPENDENT_PX = 3.0  # gradients this far apart along the edge share no pixel of the 3x3 Sobel: independent noise
MIN_SAMPLES = 8  # an edge with fewer samples is skipped: the MAD of fewer values is itself ~30 % noise


@dataclass
class EdgeLine:
    """A room edge's line found in the photo: offsets a0, a1 (px, along n) of the line at the first
    and last sample, the noise of its mean offset (px, 1 sigma), the score in noise sigmas of a mean,
    and the polarity (+1: brighter along +n)."""
    a0: float
    a1: float
    sigma_px: float
    z: float
    polarity: float

    def offset(self, t: np.ndarray) -> np.ndarray:
        """The line's offset (px along n) at fraction t in [0, 1] from the first to the last sample."""
        return self.a0 + (self.a1 - self.a0) * np.asarray(t, float)


def significance_z(n_lines: int, false_alarm: float = FALSE_ALARM) -> float:
    """The score (in noise sigmas of a mean) that pure Gaussian noise exceeds in |value| with
    probability `false_alarm` over `n_lines` lines tried (Bonferroni)."""
    from scipy.stats import norm

    return float(norm.isf(false_alarm / (2.0 * max(n_lines, 1))))


def _strip(edge_img, uv: np.ndarray, n: np.ndarray, ss: np.ndarray) -> np.ndarray:
    """(S,O) gradient along n at each sample uv (S,2) offset by ss (O,) px along n."""
    P = uv[:, None, :] + ss[None, :, None] * n[None, None, :]
    return (edge_img._sample(edge_img.gx, P) * n[0] + edge_img._sample(edge_img.gy, P) * n[1]).astype(np.float64)


def _noise(G: np.ndarray) -> float:
    """A strip's gradient noise: the robust spread (1.4826 MAD) of its values about their per-offset
    median (the edge itself is the same at every sample; what differs from sample to sample is noise
    and texture)."""
    resid = G - np.median(G, axis=0, keepdims=True)
    sig = 1.4826 * float(np.median(np.abs(resid - np.median(resid))))
    return sig if sig > 0 else (float(np.std(resid)) or 1e-12)


def gradient_noise(edge_img, uv: np.ndarray, n: np.ndarray, radius_px: float) -> float:
    """The gradient noise (edge_img's units) on the strip +-radius_px across samples uv (S,2) of one
    projected edge with unit normal n (2,): see _noise."""
    return _noise(_strip(edge_img, uv, n, np.arange(-radius_px, radius_px + 1e-9, STEP_PX)))


def find_line(edge_img, uv: np.ndarray, n: np.ndarray, t: np.ndarray, radius_px: float) -> EdgeLine | None:
    """The line of one room edge near its projection: samples uv (S,2) on the projected edge, its unit
    normal n (2,), each sample's fraction t (S,) from the first to the last; search +-radius_px.
    edge_img: recon.edgesnap.EdgeImage (gx, gy, _sample). None when not found (module docstring)."""
    S = len(uv)
    span_px = float(np.linalg.norm(uv[np.argmax(t)] - uv[np.argmin(t)])) if S else 0.0
    if S < MIN_SAMPLES:
        return None
    ss = np.arange(-radius_px, radius_px + 1e-9, STEP_PX)  # (O,)
    O = len(ss)
    G = _strip(edge_img, uv, n, ss)
    sig_g = _noise(G)
    # every line from offset ss[i] at t=0 to ss[j] at t=1: fractional column index per sample
    a0, a1 = np.meshgrid(ss, ss, indexing="ij")  # (O,O)
    off = a0[..., None] + (a1 - a0)[..., None] * t[None, None, :]  # (O,O,S)
    col = (off + radius_px) / STEP_PX
    c0 = np.clip(np.floor(col).astype(int), 0, O - 2)
    fr = col - c0
    rows = np.arange(S)[None, None, :]
    vals = G[rows, c0] * (1 - fr) + G[rows, c0 + 1] * fr
    score = vals.mean(axis=2)  # (O,O)
    i, j = np.unravel_index(int(np.argmax(np.abs(score))), score.shape)
    best = float(score[i, j])
    pol = 1.0 if best >= 0 else -1.0
    n_ind = min(float(S), span_px / INDEPENDENT_PX + 1.0)  # independent gradient samples along the edge
    z = abs(best) / (sig_g / np.sqrt(n_ind))
    z_min = significance_z(O * O)  # every line tried counts (Bonferroni: the false alarm is at most FALSE_ALARM)
    if not z >= z_min:
        return None
    if i in (0, O - 1) or j in (0, O - 1):
        return None
    # a second significant line parallel to the best, over 1 px away, of the same polarity and over
    # edgesnap's AMBIGUOUS fraction as strong: two parallel edges (a dark band along a crease, a plank's
    # edge beside a wall), and which one the room's edge is cannot be told; the best line shifted
    # parallel across the window is the score's diagonal through the peak
    sc = pol * score
    d = np.arange(-min(i, j), O - max(i, j))
    par = sc[i + d, j + d]
    loc = np.zeros(len(par), bool)
    loc[1:-1] = (par[1:-1] >= par[:-2]) & (par[1:-1] >= par[2:])
    second = loc & (np.abs(d) * STEP_PX > 1.0) & (par >= z_min * sig_g / np.sqrt(n_ind))
    if np.any(second & (par > AMBIGUOUS * sc[i, j])):
        return None

    def vertex(lo, mid, hi):
        den = lo - 2 * mid + hi
        return float(np.clip(0.5 * (lo - hi) / den, -0.5, 0.5)) if den < 0 else 0.0

    A0 = ss[i] + STEP_PX * vertex(sc[i - 1, j], sc[i, j], sc[i + 1, j])
    A1 = ss[j] + STEP_PX * vertex(sc[i, j - 1], sc[i, j], sc[i, j + 1])
    # the line's noise from the samples' own peaks within 1 px of it
    line = A0 + (A1 - A0) * t
    near = np.abs(ss[None, :] - line[:, None]) <= 1.0
    g = np.where(near, pol * G, -np.inf)
    k = np.argmax(g, axis=1)
    kk = np.clip(k, 1, O - 2)
    lo, mid, hi = pol * G[np.arange(S), kk - 1], pol * G[np.arange(S), kk], pol * G[np.arange(S), kk + 1]
    den = lo - 2 * mid + hi
    with np.errstate(divide="ignore", invalid="ignore"):
        sub = np.where(den < 0, np.clip(0.5 * (lo - hi) / den, -0.5, 0.5), 0.0)
    peaks = ss[kk] + STEP_PX * sub
    r = peaks - line
    spread = 1.4826 * float(np.median(np.abs(r - np.median(r))))
    return EdgeLine(float(A0), float(A1), spread / np.sqrt(n_ind), float(z), pol)
