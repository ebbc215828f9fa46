"""Clicks refined against the photo's edges (for recon/clickmodel.py, when the photo is given).

A click is off by about a pixel, but the photo holds a straight edge to a fraction of a pixel along
its length (recon/edgesnap.py). So, with the photo, each wall, furniture piece and window/lamp quad
is first fitted from its clicks; then the edges of that model the photo can show are snapped to it
(EdgeImage.snap, the model's edge standing in for a clicked segment: the snap must agree with it
within the click noise, searching SEARCH_SIGMAS click sigmas either side):

  * a wall: its foot (the wall-floor edge) between its first and last click, in each stretch no
    piece of furniture hides (the clicks-only model of the furniture); a stretch that does not snap
    whole (its two sides swap which is brighter along it: a skirting over planks of varying tone)
    is tried in pieces of about PIECE_PX, and failing that as a faint edge (snap_faint);
  * the room (recon/clickmodel._refine_room): the vertical corner where two clicked walls meet and
    each wall's ceiling edge;
  * a furniture piece: its box's edges that border a face turned to the camera (a desk: its top
    slab's), along their longest stretch inside the photo and in front of every other piece, each
    searched at most half way to the piece's nearest other edge;
  * a window or lamp: its four sides (an emitter's clipped edge is used: it is all there is).

An edge edgesnap does not find over its whole search (ambiguous there: a texture's edges beside
it, a floor's plank seams a few pixels from a piece's foot) is searched again in narrow windows
across that search (snap_scan). An edge edgesnap does not find sample by sample (too faint against the texture, its
polarity swapping along it, a clipped emitter's edge stepping from pixel to pixel) is tried by
snap_faint: gradient profiles averaged over pieces of the edge.

Each snapped line adds two residuals (its distance from the model's edge at the stretch's two ends,
in units of its noise: the samples' spread, at least LINE_SIGMA_FLOOR_PX) to the same least-squares
fit in pixels as the clicks, with the same structure (walls on the room's axes, footprints
rectangles, quads on their planes). A line the fit leaves off by more than its noise allows
(chi-square, 2 dof, 99.9 %) is dropped and the fit redone; if a click then moves more than its
noise allows (chi-square, 2 dof, 99.99 %), the item keeps its clicks-only fit ("as clicked").

What the photo cannot refine stays as clicked: a desk's floor corners (under its top: its slab's
edges pin the footprint and height instead), a corner hidden behind another piece or out of the
photo, an edge with no contrast. PhotoEdges.sd gives a fit's parameter uncertainties (the
least-squares covariance), which recon/clickmodel.py reports for the sides pinned worse than 3 cm.

Conventions: pixels as recon/camera.py ((0, 0) the centre of the top-left pixel), metres.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from recon.camera import Camera
from recon.edgesnap import AMBIGUOUS, MAX_SPREAD_PX, MIN_FOUND, SEARCH_PX, STEP_PX, EdgeImage, line_sigma

SEARCH_SIGMAS = 3.5  # the search across an edge spans this many click sigmas either side
MIN_EDGE_PX = 20.0  # a model edge's visible stretch shorter than this in the photo (px) is not snapped
PIECE_PX = 40.0  # a wall's foot that does not snap whole is tried in pieces about this long (px): long
# enough for ~30 samples (a line to ~0.1 px), short enough for one floor plank's tone at a time
MIN_SEARCH_PX = 2.0  # px: an edge is searched at least this far either side: its peak's centroid spans
# +-1 px and a neighbouring edge within OPPOSITE_PX drags it, so two model edges nearer than twice this
# (a thin top face's two long edges) cannot be told apart and neither is snapped
SCAN_STEP_PX = 1.0  # px between the narrow windows of PhotoEdges.snap_scan: each spans 2 MIN_SEARCH_PX, so
# an edge anywhere in the search lies within a pixel of some window's centre, inside its peak test
SCAN_MIN_PX = 2 * PIECE_PX  # px: an edge shorter than this is not scanned: beside a texture's edges its line must
# average over several of their features (two pieces of a wall's foot) for its place to hold to a fraction of a pixel
SCAN_SAME_PX = 1.0  # px: lines the narrow windows find nearer than this are one edge (a peak's centroid spans +-1 px
# as its window moves across it)
PEAK_PX = 1.0  # px: a search from a fit's predicted place reaches this much further, so that an edge at its
# SEARCH_SIGMAS bound still shows its peak whole (an edge's gradient peak is about 2 px wide: the 3x3 Sobel)
BORDER_PX = 3.0  # samples this close to the photo's border are not used
EDGE_SAMPLES = 41  # points along a model edge tested for visibility
OCCLUDER_GAP_M = 0.01  # a sight line must pass this far before the edge to count as blocked
OCCLUDER_SHRINK_M = 0.02  # occluders are shrunk by this on every side: the clicks-only model of the other
# pieces is off by the click noise (about a centimetre a pixel), and a piece standing against another
# (a sofa's seat against its back) must not hide the edge they share
OPPOSITE_PX = 2.0  # an opposite edge further than this from a sample's peak does not drag it (the 3x3 Sobel's
# reach plus the photo's own blur, about a pixel each); a textured floor or wall has such edges nearer
# than the click noise, so the whole search window cannot be required clear of them
FAINT_MIN_PIECES = 4  # a faint edge is cut into at least this many pieces, and at least this many must find
# it: a line through 4 points shows its own spread with 2 degrees of freedom (through 3, with one: three
# pieces on two different edges can line up by chance)
FAINT_MARGIN_PX = 2.0  # a faint edge's profile is sampled this far beyond the search (its peak's half width
# and more), so that an edge near the search's end is still seen whole
FAINT_SNR = 4.0  # a piece's mean gradient profile must peak this many of its noise sigmas high (a false
# peak from the texture alone: under 1e-4 of pieces for Gaussian noise; the window holds ~30 positions)
LINE_SIGMA_FLOOR_PX = 0.25  # px: a snapped line's noise is at least this: where a crease's edge appears
# depends on its shading (a contact shadow, a skirting's texture), an error along the whole line that
# the samples' spread does not show (edgesnap's own floor, 0.1 px, is for calibrate's long lines)
CHI2_1DOF_99 = 6.63  # chi-square 99 % point, 1 dof
CHI2_HOLD = 9.14  # a side held on a wall or a face must not raise the fit's chi-square more than this: the 1 dof
# point of 1 - 0.01 / 4, so that a piece whose footprint's four sides each may stand against a plane is refused one
# it does stand against on at most 1 % of draws (Bonferroni over its sides), not 1 % a side (2.58 -> 3.02 sigma)
CHI2_2DOF_999 = 13.82  # a snapped line the fit leaves this far off (in its sigmas) is dropped
CHI2_2DOF_9999 = 18.42  # a click moved this far (in click sigmas) sends the piece back to its clicks: at
# 1e-4 a click, a room's ~20 clicks fall back for noise alone in under 0.2 % of rooms


@dataclass
class EdgeLine:
    """A model edge (corner indices i, j of the piece's corner function) snapped to the photo over
    the stretch t0..t1 (fractions from corner i): the line through p0 (2,) with unit normal n (2,),
    its noise sigma (px)."""

    i: int
    j: int
    t0: float
    t1: float
    p0: np.ndarray
    n: np.ndarray
    sigma: float


class PhotoEdges:
    """The photo prepared for refining clicks, with the click noise (px, per coordinate)."""

    def __init__(self, photo: np.ndarray | EdgeImage, camera: Camera, click_sigma_px: float = 1.0):
        self.edges = photo if isinstance(photo, EdgeImage) else EdgeImage(photo)
        if self.edges.shape != (camera.height, camera.width):
            raise ValueError(f"the photo is {self.edges.shape[1]}x{self.edges.shape[0]}, the camera "
                             f"{camera.width}x{camera.height}")
        self.camera, self.sigma = camera, float(click_sigma_px)
        self.search = max(SEARCH_PX, SEARCH_SIGMAS * self.sigma)

    def _snap(self, seg: np.ndarray, clipped_ok: bool = False, faint: bool = False, search: float | None = None,
              sigma: float | None = None):
        """edgesnap's sample-by-sample snap; failing that, with `faint`, the piecewise profile snap;
        searching `search` px either side (default self.search)."""
        seg = np.asarray(seg, float)
        search = self.search if search is None else search
        sigma = self.sigma if sigma is None else sigma
        r = self.edges.snap(seg, sigma, search, clipped_ok, OPPOSITE_PX)
        if r is None and faint:
            r = self.snap_faint(seg, clipped_ok, search, sigma)
        return r

    def snap_scan(self, seg: np.ndarray, search: float, sigma: float, clipped_ok: bool = False
                  ) -> tuple[np.ndarray, float, int] | None:
        """An edge edgesnap does not find over the whole search (ambiguous there: a texture's edges
        beside it in the window, a floor's plank seams a few px from a piece's foot, which a sample
        takes for a second peak), searched in narrow windows (MIN_SEARCH_PX either side) centred
        SCAN_STEP_PX apart across the search, for an edge at least SCAN_MIN_PX long: it counts when
        every window that finds a line finds the same one (within SCAN_SAME_PX; the one with the
        least spread is kept) and it lies within the search (the bound a whole search keeps; the fit
        then drops a line it disagrees with, as any other). The texture's edges seldom make a line
        of their own (a seam is broken, curved, of varying tone); where they do, two lines are found
        and the edge is not snapped. Returns as EdgeImage.snap, or None."""
        seg = np.asarray(seg, float)
        a, b = seg[:2], seg[2:]
        length = float(np.linalg.norm(b - a))
        if search <= MIN_SEARCH_PX or length < SCAN_MIN_PX:
            return None
        d = (b - a) / length
        n = np.array([-d[1], d[0]])
        reach = search - MIN_SEARCH_PX
        found = []
        for o in np.arange(-reach, reach + 1e-9, SCAN_STEP_PX):
            r = self.edges.snap(seg + np.r_[o * n, o * n], sigma, MIN_SEARCH_PX, clipped_ok, OPPOSITE_PX)
            if r is None:
                continue
            off = float(np.mean((r[0].reshape(2, 2) - np.stack([a, b])) @ n))
            if abs(off) <= search:
                found.append((off, r))
        if not found:
            return None
        offs = np.array([f[0] for f in found])
        if offs.max() - offs.min() > SCAN_SAME_PX:
            return None
        return min((f[1] for f in found), key=lambda r: r[1])

    def snap_faint(self, seg: np.ndarray, clipped_ok: bool = False, search: float | None = None,
                   sigma: float | None = None) -> tuple[np.ndarray, float, int] | None:
        """A straight edge too faint against the texture beside it for edgesnap's sample-by-sample
        snap (two walls of nearly one tone meeting at a corner, a skirting of the floor's tone), or
        whose polarity swaps along it (planks of varying tone against the skirting): the segment is cut
        into pieces of about PIECE_PX (at least FAINT_MIN_PIECES), and in each the gradient across the
        line is averaged along it (the texture's gradients, uncorrelated from pixel to pixel, average
        out as 1/sqrt(n); the edge's does not), its own polarity taken, and the edge is the centroid of
        the mean profile above half its peak. A piece counts when its peak stands FAINT_SNR times above
        the noise of that mean (the spread of the single profiles / sqrt(n)) and no second peak in the
        window is over AMBIGUOUS of it; a line through the pieces' edges (least squares, the piece
        furthest off dropped while the spread exceeds MAX_SPREAD_PX) is accepted when at least
        MIN_FOUND of the pieces and FAINT_MIN_PIECES count, their spread about it is at most MAX_SPREAD_PX and
        the model's segment lies within the click noise of it (chi-square, 2 dof, 99.99 %: the gate the
        fit applies to the clicks themselves; a segment pinned by one click, a corner out of the photo,
        is off by that click's noise all along).
        Returns (segment (4,) the model's endpoints projected onto the line, spread px, pieces used)
        as EdgeImage.snap does, or None."""
        E = self.edges
        search = self.search if search is None else search
        a, b = seg[:2], seg[2:]
        length = float(np.linalg.norm(b - a))
        if length < MIN_EDGE_PX:
            return None
        d = (b - a) / length
        n = np.array([-d[1], d[0]])
        ts = np.arange(0.04 * length, 0.96 * length, 1.0)
        ss = np.arange(-search - FAINT_MARGIN_PX, search + FAINT_MARGIN_PX + 1e-9, STEP_PX)
        base = a + ts[:, None] * d
        P = base[:, None, :] + ss[None, :, None] * n
        inside = np.all((P[..., 0] >= 1) & (P[..., 0] <= E.shape[1] - 2) & (P[..., 1] >= 1)
                        & (P[..., 1] <= E.shape[0] - 2), axis=1)
        iu = np.clip(np.rint(base).astype(int), 0, [E.shape[1] - 1, E.shape[0] - 1])
        ok = inside if clipped_ok else inside & ~E.near_clip[iu[:, 1], iu[:, 0]]
        g = E._sample(E.gx, P) * n[0] + E._sample(E.gy, P) * n[1]  # (T,S)
        n_pieces = max(FAINT_MIN_PIECES, int(round(length / PIECE_PX)))
        bounds = np.linspace(0, len(ts), n_pieces + 1).astype(int)
        pts = []
        for k0, k1 in zip(bounds[:-1], bounds[1:]):
            rows = np.arange(k0, k1)[ok[k0:k1]]
            if len(rows) < max(5, 0.6 * (k1 - k0)):
                continue
            m = g[rows].mean(axis=0)
            sem = float(np.median(g[rows].std(axis=0))) / np.sqrt(len(rows))
            # the extremum (either polarity) nearest the model's line, within the search
            ext = np.r_[False, ((m[1:-1] >= m[:-2]) & (m[1:-1] >= m[2:]) & (m[1:-1] > FAINT_SNR * sem)) |
                        ((m[1:-1] <= m[:-2]) & (m[1:-1] <= m[2:]) & (m[1:-1] < -FAINT_SNR * sem)), False]
            ext &= np.abs(ss) <= search
            if not ext.any():
                continue
            k = int(np.flatnonzero(ext)[np.argmin(np.abs(ss[ext]))])
            m = m * np.sign(m[k])
            peak = m[k]
            far = np.abs(ss - ss[k]) > 1.0
            if _second_peak(m, k, AMBIGUOUS * peak, FAINT_SNR * sem, np.abs(ss) <= search) or \
                    np.any(_local_min(m) & (np.abs(ss - ss[k]) <= OPPOSITE_PX) & (m < -AMBIGUOUS * peak)):
                continue
            w = np.where(~far, np.clip(m - 0.5 * peak, 0, None), 0.0)
            off = float((w * ss).sum() / w.sum())
            pts.append(base[rows].mean(axis=0) + off * n)
        if len(pts) < max(FAINT_MIN_PIECES, MIN_FOUND * n_pieces):
            return None
        pts = np.array(pts)
        while True:  # a line through the pieces' edges; a piece off it (one that straddles a swap of
            # polarity, or a crossing edge) is dropped while enough are left
            c = pts.mean(axis=0)
            _, _, vt = np.linalg.svd(pts - c)
            dd = vt[0]
            nn = np.array([-dd[1], dd[0]])
            r = (pts - c) @ nn
            spread = float(np.sqrt((r ** 2).sum() / max(1, len(r) - 2)))
            if spread <= MAX_SPREAD_PX:
                break
            if len(pts) - 1 < max(FAINT_MIN_PIECES, MIN_FOUND * n_pieces):
                return None
            pts = np.delete(pts, int(np.argmax(np.abs(r))), axis=0)
        sigma = self.sigma if sigma is None else sigma
        if ((a - c) @ nn) ** 2 + ((b - c) @ nn) ** 2 > CHI2_2DOF_9999 * sigma ** 2:
            return None
        proj = lambda q: c + np.dot(q - c, dd) * dd  # noqa: E731
        return np.concatenate([proj(a), proj(b)]), spread, int(len(pts))

    def foot_lines(self, a: np.ndarray, b: np.ndarray, blocked: Callable[[np.ndarray], np.ndarray]
                   ) -> list[tuple[np.ndarray, np.ndarray, EdgeLine]]:
        """A wall's foot between its first and last clicked floor points a, b (3,) snapped to the
        photo, in each stretch at least MIN_EDGE_PX long that no furniture (`blocked`) hides:
        (stretch start (3,), end (3,), its EdgeLine with i, j = 0, 1 over t 0..1)."""
        ts = np.linspace(0.0, 1.0, EDGE_SAMPLES)
        X = a + ts[:, None] * (b - a)
        uv, z = self.camera.project(X)
        ok = (z > 0.05) & (uv[:, 0] >= BORDER_PX) & (uv[:, 0] <= self.camera.width - 1 - BORDER_PX) & \
            (uv[:, 1] >= BORDER_PX) & (uv[:, 1] <= self.camera.height - 1 - BORDER_PX)
        ok[ok] = ~blocked(X[ok])
        out = []
        for s, e in _runs(ok):
            length = float(np.linalg.norm(uv[e] - uv[s]))
            if length < MIN_EDGE_PX:
                continue
            # the whole stretch; where its polarity changes along it (planks of varying tone against
            # the skirting), pieces of about PIECE_PX, each with its own
            # and, failing both, the whole stretch as a faint edge (snap_faint)
            n_pieces = max(1, int(length // PIECE_PX))
            for pieces, faint in (([(s, e)], False), ([] if n_pieces == 1 else
                                  list(zip(np.linspace(s, e, n_pieces + 1).astype(int)[:-1],
                                           np.linspace(s, e, n_pieces + 1).astype(int)[1:])), False),
                                  ([(s, e)], True)):
                found = []
                for ps, pe in pieces:
                    r = self.snap_faint(np.r_[uv[ps], uv[pe]]) if faint else self._snap(np.r_[uv[ps], uv[pe]])
                    if r is None:
                        continue
                    seg, spread, used = r
                    d = (seg[2:] - seg[:2]) / np.linalg.norm(seg[2:] - seg[:2])
                    found.append((X[ps], X[pe], EdgeLine(0, 1, 0.0, 1.0, seg[:2].copy(), np.array([-d[1], d[0]]),
                                                         max(LINE_SIGMA_FLOOR_PX, line_sigma(spread, used)))))
                if found:
                    out += found
                    break
        return out

    def lines(self, corners: np.ndarray, pairs: list[tuple[int, int]], blocked: Callable[[np.ndarray], np.ndarray],
              clipped_ok: bool = False, faint: bool = False, model_sd: dict | None = None,
              others: np.ndarray | None = None) -> list[EdgeLine]:
        """The model edges `pairs` of corners (N,3) snapped to the photo, each over its longest
        stretch inside the photo and not `blocked` (callable (M,3) points -> (M,) bool); an edge
        edgesnap does not find over the search is scanned in narrow windows (snap_scan); with
        `faint`, one still not found is tried as a faint one (snap_faint). An edge is
        searched at most half way to the nearest other edge of `pairs` (not sharing a corner with
        it: the median distance along its stretch), so that it cannot snap to that one's place; nearer
        than 2 MIN_SEARCH_PX (a thin top face's two long edges) it is not snapped. model_sd: {pair: px}
        the model edge's own noise across itself where a fit gives it (predicted_sd): it is searched
        SEARCH_SIGMAS of that either side (at least MIN_SEARCH_PX: a fit pinning an edge to a fraction of
        a pixel keeps the search off a texture's edges a few pixels away, a floor's plank seams along a
        piece's foot), and the edge found must agree with it within that noise or the click noise,
        whichever is larger (an edge far from every click moves more than a click does). others: (K,2,2)
        px, more edges in the photo that are not in `pairs` (other pieces' outlines, box_edges_px): an
        edge is searched at most half way to these too (a shelf's side a few pixels beside a room's
        corner line would be snapped in its place)."""
        cam = self.camera
        ts = np.linspace(0.0, 1.0, EDGE_SAMPLES)
        out = []
        proj = {}
        for i, j in pairs:
            e, z = cam.project(corners[[i, j]])
            if np.all(z > 0.05):
                proj[(i, j)] = e
        for i, j in pairs:
            X = corners[i] + ts[:, None] * (corners[j] - corners[i])
            uv, z = cam.project(X)
            ok = (z > 0.05) & (uv[:, 0] >= BORDER_PX) & (uv[:, 0] <= cam.width - 1 - BORDER_PX) & \
                (uv[:, 1] >= BORDER_PX) & (uv[:, 1] <= cam.height - 1 - BORDER_PX)
            ok[ok] = ~blocked(X[ok])
            run = _longest_run(ok)
            if run is None:
                continue
            a, b = run
            if np.linalg.norm(uv[b] - uv[a]) < MIN_EDGE_PX:
                continue
            mid = uv[a:b + 1]
            sep = min((float(np.median(_seg_dist(mid, e))) for (p, q), e in proj.items() if not {p, q} & {i, j}),
                      default=np.inf)
            if others is not None and len(others):
                sep = min(sep, min(float(np.median(_seg_dist(mid, e))) for e in others))
            sd_e = (model_sd or {}).get((i, j))
            sigma = self.sigma if sd_e is None else max(self.sigma, sd_e)
            search = self.search if sd_e is None else \
                min(self.search, max(MIN_SEARCH_PX, SEARCH_SIGMAS * sd_e + PEAK_PX))
            search = min(search, sep / 2)
            if search < MIN_SEARCH_PX:
                continue
            seg = np.r_[uv[a], uv[b]]
            r = self.edges.snap(seg, sigma, search, clipped_ok, OPPOSITE_PX)
            if r is None:
                r = self.snap_scan(seg, search, sigma, clipped_ok)
            if r is None and faint:
                r = self.snap_faint(seg, clipped_ok, search, sigma)
            if r is None:
                continue
            seg, spread, used = r
            d = (seg[2:] - seg[:2]) / np.linalg.norm(seg[2:] - seg[:2])
            out.append(EdgeLine(i, j, float(ts[a]), float(ts[b]), seg[:2].copy(), np.array([-d[1], d[0]]),
                                max(LINE_SIGMA_FLOOR_PX, line_sigma(spread, used))))
        return out

    def residuals(self, lines: list[EdgeLine], corners: np.ndarray) -> np.ndarray:
        """Each line's distance (px) from the model edge's projection at its stretch's two ends,
        scaled to click units (x click sigma / line sigma): (2 len(lines),)."""
        if not lines:
            return np.zeros(0)
        out = np.empty(2 * len(lines))
        for k, L in enumerate(lines):
            X = corners[L.i] + np.array([L.t0, L.t1])[:, None] * (corners[L.j] - corners[L.i])
            uv, z = self.camera.project(X)
            out[2 * k:2 * k + 2] = ((uv - L.p0) @ L.n) * (self.sigma / L.sigma) if np.all(z > 1e-6) else 1e6
        return out

    def chi2(self, x: np.ndarray, corners: Callable[[np.ndarray], np.ndarray],
             clicks: Callable[[np.ndarray], np.ndarray], uv: np.ndarray, lines: list[EdgeLine]) -> float:
        """The fit's chi-square at parameters x: the clicks' and the lines' residuals in their sigmas."""
        p, z = self.camera.project(clicks(x))
        if not np.all(z > 1e-6):
            return float("inf")
        r = np.r_[(p - uv).ravel(), self.residuals(lines, corners(x))] / self.sigma
        return float(r @ r)

    def predicted_sd(self, x: np.ndarray, corners: Callable[[np.ndarray], np.ndarray],
                     clicks: Callable[[np.ndarray], np.ndarray], lines: list[EdgeLine],
                     pairs: list[tuple[int, int]], step: float = 1e-4) -> dict[tuple[int, int], float]:
        """{pair: px}: the standard deviation across itself, in the photo, of each model edge `pairs` of
        corners(x) from the fit at x (its clicks and `lines`, the least-squares covariance; the larger
        of its two ends), for PhotoEdges.lines's model_sd; {} when the fit does not pin every
        parameter."""
        x = np.asarray(x, float)
        cov = self.cov(x, corners, clicks, lines, step)
        if cov is None:
            return {}
        C0 = corners(x)
        dC = [corners(x + step * np.eye(len(x))[k]) for k in range(len(x))]
        out = {}
        for i, j in pairs:
            uv, z = self.camera.project(C0[[i, j]])
            if not np.all(z > 1e-6) or np.linalg.norm(uv[1] - uv[0]) < 1e-6:
                continue
            d = (uv[1] - uv[0]) / np.linalg.norm(uv[1] - uv[0])
            n = np.array([-d[1], d[0]])
            J = np.stack([(self.camera.project(D[[i, j]])[0] - uv) @ n / step for D in dC], axis=1)  # (2, n)
            var = np.einsum("ik,kl,il->i", J, cov, J)
            out[(i, j)] = float(np.sqrt(max(var.max(), 0.0)))
        return out

    def cov(self, x: np.ndarray, corners: Callable[[np.ndarray], np.ndarray],
            clicks: Callable[[np.ndarray], np.ndarray], lines: list[EdgeLine], step: float = 1e-4
            ) -> np.ndarray | None:
        """The fit's parameter covariance sigma^2 (J^T J)^-1 at x (J by forward differences of
        `step`); None where the clicks and lines do not pin every parameter."""
        def fun(q):
            p, _ = self.camera.project(clicks(q))
            return np.r_[p.ravel(), self.residuals(lines, corners(q))]

        x = np.asarray(x, float)
        f0 = fun(x)
        J = np.stack([(fun(x + step * np.eye(len(x))[k]) - f0) / step for k in range(len(x))], axis=1)
        try:
            return np.linalg.inv(J.T @ J) * self.sigma ** 2
        except np.linalg.LinAlgError:
            return None

    def sd(self, x: np.ndarray, corners: Callable[[np.ndarray], np.ndarray], clicks: Callable[[np.ndarray], np.ndarray],
           lines: list[EdgeLine], step: float = 1e-4) -> np.ndarray:
        """Standard deviations (n,) of the fit's parameters x (n,) (their units, metres) from the
        clicks' noise and the lines' (the least-squares covariance sigma^2 (J^T J)^-1, J by forward
        differences of `step`); inf for a parameter the clicks and lines do not pin."""
        cov = self.cov(x, corners, clicks, lines, step)
        if cov is None:
            return np.full(len(np.atleast_1d(x)), np.inf)
        return np.sqrt(np.clip(np.diag(cov), 0.0, None))

    def fit(self, x0: np.ndarray, corners: Callable[[np.ndarray], np.ndarray],
            clicks: Callable[[np.ndarray], np.ndarray], uv: np.ndarray, lines: list[EdgeLine]) -> np.ndarray:
        """The least-squares fit of the clicks and `lines` from x0 (none dropped); x0 when it fails."""
        from scipy.optimize import least_squares

        def fun(q):
            p, z = self.camera.project(clicks(q))
            if not np.all(z > 1e-6):
                return np.full(uv.size + 2 * len(lines), 1e6)
            return np.r_[(p - uv).ravel(), self.residuals(lines, corners(q))]

        r = least_squares(fun, np.asarray(x0, float), method="trf")
        return r.x if r.success and np.all(np.isfinite(r.x)) else np.asarray(x0, float)

    def held(self, x: np.ndarray, j: int, value: float, corners: Callable[[np.ndarray], np.ndarray],
             clicks: Callable[[np.ndarray], np.ndarray], uv: np.ndarray, lines: list[EdgeLine]) -> np.ndarray:
        """The least-squares fit of the clicks and `lines` (as refine_lines, none dropped) from x with
        parameter j held at `value`; x itself when the fit fails."""
        from scipy.optimize import least_squares

        def full(y):
            return np.insert(y, j, value)

        def fun(y):
            q = full(y)
            p, z = self.camera.project(clicks(q))
            if not np.all(z > 1e-6):
                return np.full(uv.size + 2 * len(lines), 1e6)
            return np.r_[(p - uv).ravel(), self.residuals(lines, corners(q))]

        y0 = np.delete(np.asarray(x, float), j)
        if y0.size == 0:
            return full(y0)
        r = least_squares(fun, y0, method="trf")
        return full(r.x) if r.success and np.all(np.isfinite(r.x)) else np.asarray(x, float)

    def refine(self, x0: np.ndarray, corners: Callable[[np.ndarray], np.ndarray],
               clicks: Callable[[np.ndarray], np.ndarray], uv: np.ndarray, lines: list[EdgeLine]
               ) -> tuple[np.ndarray, int]:
        """(parameters, number of lines kept): refine_lines."""
        x, kept = self.refine_lines(x0, corners, clicks, uv, lines)
        return x, len(kept)

    def refine_lines(self, x0: np.ndarray, corners: Callable[[np.ndarray], np.ndarray],
                     clicks: Callable[[np.ndarray], np.ndarray], uv: np.ndarray, lines: list[EdgeLine]
                     ) -> tuple[np.ndarray, list[EdgeLine]]:
        """(parameters, lines kept): the least-squares fit in pixels of the clicks uv (m,2) (their
        model points clicks(x) (m,3)) and the snapped `lines` (edges of corners(x)), from x0 (the
        clicks-only fit). Lines the fit disagrees with are dropped one by one; (x0, []) when none is
        left or a click would move beyond its noise."""
        from scipy.optimize import least_squares

        lines = list(lines)
        while lines:
            def fun(x, lines=lines):
                p, z = self.camera.project(clicks(x))
                r_click = (p - uv).ravel() if np.all(z > 1e-6) else np.full(uv.size, 1e6)
                return np.r_[r_click, self.residuals(lines, corners(x))]

            r = least_squares(fun, np.asarray(x0, float), method="trf")
            if not (r.success and np.all(np.isfinite(r.x))):
                return x0, []
            rl = self.residuals(lines, corners(r.x)).reshape(-1, 2) / self.sigma  # in line sigmas
            chi = (rl ** 2).sum(axis=1)
            worst = int(np.argmax(chi))
            if chi[worst] > CHI2_2DOF_999:
                del lines[worst]
                continue
            p, _ = self.camera.project(clicks(r.x))
            if np.any(((p - uv) ** 2).sum(axis=1) > CHI2_2DOF_9999 * self.sigma ** 2):
                return x0, []
            return r.x, lines
        return x0, []


def _seg_dist(P: np.ndarray, e: np.ndarray) -> np.ndarray:
    """Distances (M,) of points P (M,2) from the segment e (2,2)."""
    d = e[1] - e[0]
    t = np.clip((P - e[0]) @ d / max(float(d @ d), 1e-12), 0.0, 1.0)
    return np.linalg.norm(P - (e[0] + t[:, None] * d), axis=1)


def _local_min(m: np.ndarray) -> np.ndarray:
    """(S,) bool: the profile's interior local minima (an edge of the opposite polarity; the tail of
    one further off is not)."""
    return np.r_[False, (m[1:-1] <= m[:-2]) & (m[1:-1] < m[2:]), False]


def _second_peak(m: np.ndarray, k: int, level: float, prominence: float, window: np.ndarray) -> bool:
    """Profile m (S,) has, inside `window` (S,) bool, a local maximum other than k above `level` that
    stands out as a peak of its own: the profile dips by more than `prominence` between it and k (a
    shoulder, the shading next to an edge, does not)."""
    locmax = np.r_[False, (m[1:-1] >= m[:-2]) & (m[1:-1] > m[2:]), False]
    for j in np.flatnonzero(locmax & window & (m > level)):
        if j == k:
            continue
        lo, hi = sorted((j, k))
        if m[j] - m[lo:hi + 1].min() > prominence:
            return True
    return False


def _runs(ok: np.ndarray) -> list[tuple[int, int]]:
    """(first, last) index of every run of True in ok at least two long."""
    out, start = [], None
    for k, v in enumerate(np.r_[ok, False]):
        if v and start is None:
            start = k
        elif not v and start is not None:
            if k - 1 > start:
                out.append((start, k - 1))
            start = None
    return out


def _longest_run(ok: np.ndarray) -> tuple[int, int] | None:
    """(first, last) index of the longest run of True in ok, or None."""
    best, start = None, None
    for k, v in enumerate(np.r_[ok, False]):
        if v and start is None:
            start = k
        elif not v and start is not None:
            if best is None or k - 1 - start > best[1] - best[0]:
                best = (start, k - 1)
            start = None
    return best if best is not None and best[1] > best[0] else None


def box_edges_px(camera: Camera, boxes: list[dict]) -> np.ndarray:
    """(K,2,2) px: the 12 edges of each box (user primitives format: center, size, yaw_deg; not
    shrunk) projected into the photo, those with both ends in front of the camera (z > 0.05 m)."""
    from recon.view import box_corners

    out = []
    for b in boxes:
        X = np.asarray(box_corners(b["center"], b["size"], b.get("yaw_deg", 0.0)), float)
        uv, z = camera.project(X)
        for a in range(8):
            for c in range(a + 1, 8):
                if bin(a ^ c).count("1") == 1 and z[a] > 0.05 and z[c] > 0.05:  # an edge: one index bit apart
                    out.append(np.array([uv[a], uv[c]]))
    return np.array(out).reshape(-1, 2, 2)


def box_blocker(camera: Camera, boxes: list[dict]) -> Callable[[np.ndarray], np.ndarray]:
    """Callable (M,3) points -> (M,) bool: the sight line from the camera to the point passes
    through one of `boxes` (user primitives format: center, size, yaw_deg; each shrunk by
    OCCLUDER_SHRINK_M), entering and leaving it before OCCLUDER_GAP_M short of the point. A point
    inside a box is not blocked by it: two pieces that touch (a sofa's seat against its back) overlap
    in their clicks-only models by the click noise, and the edge they share is in the photo."""
    import math

    C = camera.centre
    frames = []
    for b in boxes:
        yaw = math.radians(b.get("yaw_deg", 0.0))
        # rows: the box's local x (e1), y and z (e2) axes in the world
        R = np.array([[math.cos(yaw), 0, -math.sin(yaw)], [0, 1, 0], [math.sin(yaw), 0, math.cos(yaw)]])
        frames.append((R, np.asarray(b["center"], float),
                       np.maximum(np.asarray(b["size"], float) / 2 - OCCLUDER_SHRINK_M, 0.0)))

    def blocked(X: np.ndarray) -> np.ndarray:
        X = np.atleast_2d(X)
        dist = np.linalg.norm(X - C, axis=1)
        smax = np.clip(1.0 - OCCLUDER_GAP_M / np.maximum(dist, 1e-9), 0.0, 1.0)
        out = np.zeros(len(X), bool)
        for R, c, h in frames:
            o = R @ (C - c)
            d = (X - C) @ R.T
            with np.errstate(divide="ignore", invalid="ignore"):
                t1 = (-h - o) / d
                t2 = (h - o) / d
            lo = np.where(np.isnan(t1), -np.inf, np.minimum(t1, t2))
            hi = np.where(np.isnan(t2), np.inf, np.maximum(t1, t2))
            par = d == 0  # a sight line parallel to a slab: inside it or never
            inside = np.abs(o) <= h
            lo = np.where(par, np.where(inside, -np.inf, np.inf), lo)
            hi = np.where(par, np.where(inside, np.inf, -np.inf), hi)
            tin, tout = lo.max(axis=1), hi.min(axis=1)
            out |= (tin <= tout) & (tout >= 0) & (tout <= smax)  # the line leaves the box before the point
        return out

    return blocked
