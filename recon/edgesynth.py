"""The sub-pixel edge detector's own bias, predicted by rendering the room's edges (analysis by synthesis).

Why: at the true camera the profile stage's sub-pixel edges (recon/photoedges.PhotoEdges.subpixel,
edgesnap's centroid rule) sit off the taped room's projected edges by a few tenths of a pixel, mostly
toward each edge's brighter side, by an amount that differs per edge (docs/unseen.md). The photo is a
box-filtered render of a geometric step, so a clean edge's linear 50 % crossing is the true edge; what
moves the detector is what lies on the edge's two sides: their levels, the pixel noise of each side
(grain scales with radiance, so the bright side's is larger and the profile's argmax leans toward it), and
the 8-bit response. All of these are measured in the photo on each face's own interior, so the detector's
error can be predicted per sample without any constant read off a room:

1. the faces each pixel sees at the camera (Open3D ray casting at SUPERSAMPLE^2 points per pixel: the
   box pixel filter of the render) give each pixel's coverage by each face;
2. each face's radiance field (linear gray, edgesnap's gamma 2.2) is the photo's, averaged over the
   pixels the face covers entirely (normalised Gaussian convolution, RADIANCE_SIGMA_PX), and its pixel
   noise the local variance of the photo about it there (NOISE_SIGMA_PX);
3. a synthetic photo: each pixel the coverage-weighted sum of its faces' radiance, plus Gaussian noise
   of the coverage-weighted variance, through edgesnap's gamma to 8 bits; the detector run on it at the
   same camera finds the edges off their true (projected) place by its own bias. The mean over DRAWS
   noise draws is the predicted offset of each sample (px, along its normal n); an edge's lean is the
   median over its samples and the draws (edge_leans).

Used by bench/bench_edgebias.py (is the photo's per-edge offset at the true camera predicted?). Subtracting
the lean in recon/camrefine.py's profile stage was measured and not kept (docs/unseen.md, "The calibrated
camera, sixth round"): it halves the sun rooms' lean at the true camera, but what remains is each edge's
own grain, and the refined camera got better in two rooms and worse in sun_101; weighing each edge by its
predicted scatter (edge_leans_and_scatter) too made sun_102 and sun_103 good and window_101 far worse.

Conventions: recon/camera.py (pixel (0,0) the centre of the top-left pixel); offsets along the sample's
unit normal n, as PhotoEdges.subpixel returns q = uv + offset n.
"""
from __future__ import annotations

import numpy as np

SUPERSAMPLE = 4  # rays per pixel side: a box filter's coverage to 1/16 (the 0.25 px profile step)
RADIANCE_SIGMA_PX = 2.0  # a face's radiance field: the photo averaged over this scale (px) on the face's own
# pixels; below it the field follows the room's shading, over ~12 pixels of support a level's noise drops 3.5x
NOISE_SIGMA_PX = 4.0  # a face's pixel noise: its variance averaged over this (px): ~50 pixels, 20 % on a std
DRAWS = 16  # noise draws: an edge's predicted lean (n samples x DRAWS offsets) has 1/sqrt(DRAWS) = 1/4 of the noise of its
# measured offset (n offsets), which adds 1/16 to its variance
NOISE = "empirical"  # "empirical": each face's own standardised residuals resampled; "gaussian"
MIN_POOL = 50  # a face with fewer own pixels draws from all faces' residuals (50 values: its tails unmeasured)
MARGIN_PX = 0  # a face's levels are read this far inside its projected outline (px): 0, the pixels it covers
# entirely. Read 1-2 px further in (against a camera a pixel or two off), the levels next to the edge are lost
# (the skirting's dark line, shading) and the prediction at the true camera got worse (docs/unseen.md); a
# caller at a camera that may be off re-renders at each new camera instead
_DISK = np.ones((2 * MARGIN_PX + 1, 2 * MARGIN_PX + 1), np.uint8)
GAMMA = 2.2  # edgesnap's linearisation (recon/edgesnap.EdgeImage), so the synthetic goes through the same


def face_coverage(cam, occ, n_faces: int) -> np.ndarray:
    """(H, W, SUPERSAMPLE^2) int: the face (index into the faces the Occluder was built from, -1: none)
    each sub-pixel ray of `cam` hits first. One ray per pixel first; the SUPERSAMPLE^2 rays only where
    that pixel's 3x3 neighbourhood sees more than one face (elsewhere every sub-pixel ray sees the
    pixel's face: a face thinner than a pixel between two pixel centres is missed, as the detector's
    3x3 gradient misses it too)."""
    import cv2

    H, W = cam.height, cam.width
    vv, uu = np.mgrid[0:H, 0:W].astype(np.float64)
    centre = _cast(cam, occ, n_faces, uu.ravel(), vv.ravel()).reshape(H, W)
    c32 = centre.astype(np.float32)
    k = np.ones((3, 3), np.uint8)
    mixed = cv2.dilate(c32, k) != cv2.erode(c32, k)
    s = SUPERSAMPLE
    off = (np.arange(s) + 0.5) / s - 0.5
    out = np.repeat(centre[:, :, None], s * s, axis=2)
    mv, mu = np.nonzero(mixed)
    if len(mv):
        U = (mu[:, None, None] + off[None, None, :]).repeat(s, 1).reshape(len(mu), -1)
        V = (mv[:, None, None] + off[None, :, None]).repeat(s, 2).reshape(len(mv), -1)
        out[mv, mu] = _cast(cam, occ, n_faces, U.ravel(), V.ravel()).reshape(len(mv), -1)
    return out


def _cast(cam, occ, n_faces: int, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(N,) int: the face the ray of `cam` through pixel (u, v) hits first (-1: none)."""
    import open3d as o3d

    pix = np.stack([u, v, np.ones_like(u)], -1)
    d = (pix @ np.linalg.inv(cam.K).T) @ cam.R  # world directions (R^T K^-1 x)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    rays = np.concatenate([np.broadcast_to(cam.centre, d.shape), d], 1).astype(np.float32)
    hit = occ.scene.cast_rays(o3d.core.Tensor(rays))
    prim = hit["primitive_ids"].numpy().astype(np.int64)
    ok = np.isfinite(hit["t_hit"].numpy())
    return np.where(ok & (prim < 2 * n_faces), prim // 2, -1)


def linear_gray(image: np.ndarray) -> np.ndarray:
    """edgesnap's linear gray (gamma GAMMA, Rec.709 luminance) of an 8-bit RGB image."""
    from recon.response import luminance

    lin = (np.asarray(image)[:, :, :3].astype(np.float32) / 255.0) ** GAMMA
    return luminance(lin).astype(np.float32)


class EdgeSynth:
    """The room's synthetic photo at a camera, from the photo's own per-face radiance and noise."""

    def __init__(self, cam, occ, n_faces: int, image: np.ndarray):
        import cv2

        lab = face_coverage(cam, occ, n_faces)
        G = linear_gray(image)
        ns = lab.shape[2]
        H, W = G.shape
        mean = np.zeros((H, W), np.float64)
        var = np.zeros((H, W), np.float64)
        best = np.zeros((H, W), np.float64)  # the coverage of each pixel's main face
        self.main = np.full((H, W), -1, np.int64)  # each pixel's main face
        self.pools = {}  # per face: its standardised residuals (G - R) / sqrt(V) on its own pixels
        blur = lambda a, s: cv2.GaussianBlur(a.astype(np.float32), (0, 0), s)  # noqa: E731
        for f in np.unique(lab[lab >= 0]):
            cov = (lab == f).sum(axis=2) / ns
            full = cv2.erode((cov >= 1.0).astype(np.uint8), _DISK).astype(np.float32)
            for fallback in (cov >= 1.0, cov >= 0.5):  # a face too thin for the margin: its own pixels
                if full.sum() < 1:
                    full = fallback.astype(np.float32)
            if full.sum() < 1:
                continue
            m0 = float((G * full).sum() / full.sum())
            R = _masked_mean(G, full, RADIANCE_SIGMA_PX, blur, m0)
            res2 = np.where(full > 0, (G - R) ** 2, 0.0)
            V = _masked_mean(res2, full, NOISE_SIGMA_PX, blur, float(res2.sum() / full.sum()))
            mean += cov * R
            var += cov * V
            z = ((G - R) / np.sqrt(np.maximum(V, 1e-20)))[full > 0]
            self.pools[int(f)] = z[np.isfinite(z)]
            top = cov > best
            best[top], self.main[top] = cov[top], f
        self.mean, self.std = mean, np.sqrt(var)
        self.noise = NOISE
        allz = np.concatenate([p for p in self.pools.values()]) if self.pools else np.zeros(1)
        for f, p in list(self.pools.items()):
            if len(p) < MIN_POOL:  # too few of its own pixels: the photo's pooled noise shape
                self.pools[f] = allz

    def image(self, rng: np.random.Generator | None) -> np.ndarray:
        """(H, W, 3) uint8: one draw of the synthetic photo (rng None: noise-free)."""
        if rng is None:
            x = self.mean
        elif self.noise == "gaussian":
            x = self.mean + self.std * rng.standard_normal(self.mean.shape)
        else:  # the photo's own noise shape: each pixel's standardised residual drawn from its main face's pool
            z = np.zeros(self.mean.shape)
            for f, p in self.pools.items():
                m = self.main == f
                z[m] = p[rng.integers(0, len(p), int(m.sum()))]
            x = self.mean + self.std * z
        y = np.round(255.0 * np.clip(x, 0.0, 1.0) ** (1.0 / GAMMA)).astype(np.uint8)
        return np.repeat(y[:, :, None], 3, axis=2)


def _masked_mean(a, mask, sigma, blur, fallback: float) -> np.ndarray:
    """Normalised convolution of `a` over `mask` at `sigma` px, widened (x2, x4) where the mask's support is
    under 5 % of a full kernel; the face's mean `fallback` where even that has none."""
    out = np.full(a.shape, fallback, np.float64)
    todo = np.ones(a.shape, bool)
    for s in (sigma, 2 * sigma, 4 * sigma):
        w = blur(mask, s)
        v = blur(a * mask, s)
        ok = todo & (w > 0.05)
        out[ok] = v[ok] / w[ok]
        todo &= ~ok
    return out


def synthetic_offsets(synth: EdgeSynth, near_clip: np.ndarray, uv: np.ndarray, n: np.ndarray, draws: int = DRAWS,
                      seed: int = 0) -> np.ndarray:
    """(draws, N) px: the offset (along n) the profile detector finds on each noise draw of the synthetic
    photo at the projected samples uv (whose true edge is there); NaN where it did not find the edge.
    near_clip: the photo's clipped-pixel mask (the detector skips the same samples)."""
    from recon.edgesnap import EdgeImage
    from recon.photoedges import PhotoEdges

    rng = np.random.default_rng(seed)
    out = np.full((draws, len(uv)), np.nan)
    for k in range(draws):
        pe = PhotoEdges.__new__(PhotoEdges)
        pe.fine = EdgeImage(synth.image(rng))
        pe.fine.near_clip = near_clip
        q, ok = pe.subpixel(uv, n)
        out[k, ok] = np.sum((q[ok] - uv[ok]) * n[ok], axis=1)
    return out


def edge_leans(synth: EdgeSynth, near_clip: np.ndarray, uv: np.ndarray, n: np.ndarray, edge: np.ndarray,
               draws: int = DRAWS, seed: int = 0) -> dict[int, float]:
    """{edge index: px} the detector's lean on each room edge: the median over its samples and the draws of
    the synthetic offsets (the fit's robust loss weighs an edge's samples by their median-like centre, not
    their mean: a profile in grain finds either the edge or a noise peak). Edges found on under 3 (sample,
    draw) pairs are left out."""
    o = synthetic_offsets(synth, near_clip, uv, n, draws, seed)
    out = {}
    for e in np.unique(edge):
        v = o[:, edge == e]
        v = v[np.isfinite(v)]
        if len(v) >= 3:
            out[int(e)] = float(np.median(v))
    return out


def edge_leans_and_scatter(synth: EdgeSynth, near_clip: np.ndarray, uv: np.ndarray, n: np.ndarray,
                           edge: np.ndarray, draws: int = DRAWS, seed: int = 0) -> tuple[dict, dict]:
    """({edge: lean px}, {edge: scatter px}): edge_leans' lean, and how far one photo's per-edge median
    scatters about it from the grain alone (the standard deviation over the draws of each draw's median
    over the edge's samples; NaN with under 3 draws finding the edge)."""
    o = synthetic_offsets(synth, near_clip, uv, n, draws, seed)
    lean, scatter = {}, {}
    for e in np.unique(edge):
        v = o[:, edge == e]
        if np.isfinite(v).sum() < 3:
            continue
        lean[int(e)] = float(np.nanmedian(v))
        per = [np.median(r[np.isfinite(r)]) for r in v if np.isfinite(r).any()]
        scatter[int(e)] = float(np.std(per, ddof=1)) if len(per) >= 3 else float("nan")
    return lean, scatter
