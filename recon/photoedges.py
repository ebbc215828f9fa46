"""The photo's edges prepared once for the camera refinement (recon/camrefine.py): oriented Canny
edges with their nearest-pixel maps (the ICP's matches), and edgesnap's linear gradient image for the
sub-pixel stage (per-sample centroid profiles).

Conventions: recon/camera.py (pixel (0,0) the centre of the top-left pixel); an edge's orientation is
the angle of its normal over [0, pi), in ORIENT_BINS bins.
"""
from __future__ import annotations

import numpy as np

ORIENT_BINS = 12  # bins of the edge normal's angle over [0, pi): 15 deg; a match may be one bin off
PROFILE_HALF_PX = 2.0  # the fine stage's search either side of the projected edge
PROFILE_STEP_PX = 0.25
SHOULDER_PX = (2.0, 3.0)  # ramp_edges: where an edge's gradient profile is read beside its found edge (|s|, px):
# past a box-filtered step's own gradient (the pixel, the bilinear sample and the Sobel reach under 2.5 px; a
# rendered step reads 0.00-0.02 of its peak there at every angle and phase)
RAMP_EDGE_MODES = ("drop", "keep")
PROFILE_LOCATOR = None  # the sub-pixel rule of PhotoEdges.subpixel: None follows recon.edgesnap.LOCATOR


class PhotoEdges:
    """The photo prepared once: oriented Canny edges with their nearest-pixel maps, and edgesnap's
    linear gradient image for the sub-pixel stage."""

    def __init__(self, image: np.ndarray, ramp_edges: str = "drop"):
        import cv2

        from recon.edgesnap import EdgeImage

        if ramp_edges not in RAMP_EDGE_MODES:
            raise ValueError(f"ramp_edges: expected one of {RAMP_EDGE_MODES}, got {ramp_edges!r}")
        self.ramp_edges = ramp_edges  # the profile stage drops an edge whose profile is a ramp (ramp_edge_mask)
        self.clipped_edges = False  # the fine stages keep Canny matches of wholly clipped room edges
        # (recon.camrefine._fine_edges; refine_camera sets it on a copy for its second attempt)

        img = np.asarray(image)
        self.fine = EdgeImage(img)  # linear gray gradient, clipped-pixel mask (raises on a non-8-bit image)
        gray = cv2.cvtColor(img[:, :, :3], cv2.COLOR_RGB2GRAY) if img.ndim == 3 else img
        g = cv2.GaussianBlur(gray, (0, 0), 1.0)
        gx = cv2.Sobel(g.astype(np.float32), cv2.CV_32F, 1, 0, ksize=3)
        gy = cv2.Sobel(g.astype(np.float32), cv2.CV_32F, 0, 1, ksize=3)
        # hysteresis thresholds relative to the photo's own gradients: a crease between two walls
        # is a few levels; the median gradient is the photo's texture and noise
        mag = np.hypot(gx, gy) / 8.0  # levels per pixel
        hi = max(4.0, 4.0 * float(np.median(mag)))
        edges = cv2.Canny(g, 0.5 * hi * 8.0, hi * 8.0, L2gradient=True) > 0
        ang = np.mod(np.arctan2(gy, gx), np.pi)
        b = np.minimum((ang / (np.pi / ORIENT_BINS)).astype(int), ORIENT_BINS - 1)
        self.n_edge_px = int(edges.sum())
        self.shape = gray.shape
        self.near = []  # per bin: (distance (H,W), nearest edge pixel (H,W,2) as (u, v))
        for k in range(ORIENT_BINS):
            m = edges & np.isin(b, [(k - 1) % ORIENT_BINS, k, (k + 1) % ORIENT_BINS])
            self.near.append(_nearest(m))

    def match(self, uv: np.ndarray, normal_angle: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
        """Nearest oriented edge pixel (N,2) of each projected sample and whether one lies within `radius` px."""
        iu = np.clip(np.rint(uv).astype(int), 0, [self.shape[1] - 1, self.shape[0] - 1])
        k = np.minimum((np.mod(normal_angle, np.pi) / (np.pi / ORIENT_BINS)).astype(int), ORIENT_BINS - 1)
        q = np.zeros_like(uv)
        d = np.full(len(uv), np.inf)
        for b in np.unique(k):
            m = k == b
            dist, pos = self.near[b]
            d[m] = dist[iu[m, 1], iu[m, 0]]
            q[m] = pos[iu[m, 1], iu[m, 0]]
        return q, d <= radius

    def distance(self, uv: np.ndarray, normal_angle: np.ndarray) -> np.ndarray:
        """Distance (px) from each projected sample to the nearest oriented edge pixel (inf: none)."""
        q, _ = self.match(uv, normal_angle, np.inf)
        return np.linalg.norm(q - uv, axis=1) if len(uv) else np.zeros(0)

    def subpixel(self, uv: np.ndarray, n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Sub-pixel edge positions (N,2) across each projected sample (unit normal n) within
        +-PROFILE_HALF_PX, and which were found: edgesnap's rule per sample (the centroid of the
        gradient above half its peak within 1 px of it; no peak on the window's border, no second
        peak over half as strong, no clipped pixel within 3 px)."""
        from recon import edgesnap
        from recon.edgesnap import AMBIGUOUS

        E = self.fine
        ss = np.arange(-PROFILE_HALF_PX, PROFILE_HALF_PX + 1e-9, PROFILE_STEP_PX)
        P = uv[:, None, :] + ss[None, :, None] * n[:, None, :]
        g = E._sample(E.gx, P) * n[:, None, 0] + E._sample(E.gy, P) * n[:, None, 1]
        sgn = np.where(g[np.arange(len(g)), np.argmax(np.abs(g), axis=1)] >= 0, 1.0, -1.0)
        g *= sgn[:, None]  # peak > 0
        k = np.argmax(g, axis=1)
        gmax = g[np.arange(len(g)), k]
        ok = (k > 0) & (k < len(ss) - 1) & (gmax > 0)
        iu = np.clip(np.rint(uv).astype(int), 0, [E.shape[1] - 1, E.shape[0] - 1])
        ok &= ~E.near_clip[iu[:, 1], iu[:, 0]]
        locmax = np.zeros_like(g, bool)
        locmax[:, 1:-1] = (g[:, 1:-1] >= g[:, :-2]) & (g[:, 1:-1] >= g[:, 2:])
        near = np.abs(ss[None, :] - ss[k][:, None]) <= 1.0
        # ambiguous (edgesnap's rule): an opposite edge anywhere in the window (a thin bar, a dark line
        # along a crease: its far side drags the centroid) or a second one over 1 px away, over half as strong
        ok &= ~np.any((g < -AMBIGUOUS * gmax[:, None]) | (locmax & ~near & (g > AMBIGUOUS * gmax[:, None])), axis=1)
        w = np.where(near, np.clip(g - 0.5 * gmax[:, None], 0, None), 0.0)
        wsum = w.sum(axis=1)
        ok &= wsum > 0
        off = (w * ss[None, :]).sum(axis=1) / np.maximum(wsum, 1e-12)
        loc = PROFILE_LOCATOR or edgesnap.LOCATOR
        if loc in ("step", "kink") and ok.any():  # a blurred step fitted to the linear profile
            off_s, found = edgesnap.step_offsets(E, uv[ok], n[ok], ss[k[ok]], sgn[ok], slopes=loc == "kink")
            off[ok] = off_s
            ok[np.flatnonzero(ok)[~found]] = False
        return uv + off[:, None] * n, ok


def ramp_edge_mask(E, q: np.ndarray, n: np.ndarray, edge: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """(N,) bool: the samples (found sub-pixel edges q, unit normals n, room edge index) of the room edges whose
    found edge is the steep side of a ramp rather than a step: averaged over the edge's found samples (`ok`),
    the linear gradient across it, aligned at each sample's found edge, still has over AMBIGUOUS (edgesnap's
    half) of its peak, of the same polarity, at SHOULDER_PX on one side. That is a crease whose radiance falls
    smoothly into the corner and turns there (a kink: two walls' shading meeting at their crease), whose gradient
    peaks on the brighter wall's slope, not at the crease: the centroid rule finds it 1-1.5 px off the crease
    (clean sun_103's back corner: shoulder 0.67, offset -1.25 px at the true camera; a rendered step reads
    0.00-0.02). The per-sample rule (a second peak over half as strong) cannot see it: the ramp has no second
    peak, and per sample its shoulder is grain. E: the photo's EdgeImage (linear gradient gx, gy)."""
    from recon.edgesnap import AMBIGUOUS

    out = np.zeros(len(q), bool)
    if not ok.any():
        return out
    lo, hi = SHOULDER_PX
    ss = np.concatenate([-np.arange(hi, lo - 1e-9, -PROFILE_STEP_PX), [0.0], np.arange(lo, hi + 1e-9, PROFILE_STEP_PX)])
    k = len(ss) // 2
    idx = np.flatnonzero(ok)
    P = q[idx, None, :] + ss[None, :, None] * n[idx, None, :]
    g = E._sample(E.gx, P) * n[idx, None, 0] + E._sample(E.gy, P) * n[idx, None, 1]
    g *= np.where(g[:, k] >= 0, 1.0, -1.0)[:, None]  # each sample's own edge polarity (its found peak > 0)
    for e in np.unique(edge[idx]):
        m = edge[idx] == e
        G = g[m].mean(axis=0)
        if not G[k] > 0:
            continue
        if max(G[:k].mean(), G[k + 1:].mean()) >= AMBIGUOUS * G[k]:
            out[idx[m]] = True
    return out


def _nearest(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance (px) to the nearest True pixel of `mask` and that pixel's (u, v); inf where none."""
    import cv2

    H, W = mask.shape
    if not mask.any():
        return np.full((H, W), np.inf, np.float32), np.zeros((H, W, 2), np.float32)
    dist, lab = cv2.distanceTransformWithLabels((~mask).astype(np.uint8), cv2.DIST_L2, 5,
                                                labelType=cv2.DIST_LABEL_PIXEL)
    vs, us = np.nonzero(mask)
    coords = np.zeros((lab.max() + 1, 2), np.float32)
    coords[lab[vs, us]] = np.stack([us, vs], 1)
    return dist, coords[lab]
