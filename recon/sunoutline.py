"""The sunlit patch's outline and the opening's own edges as camera measurements (issue 34 item 6).

When `scene` knows the sun's direction (declared), the opening's edges cast along the sun onto the room's
surfaces are 3D lines as fixed as the room's own edges: the outline of the sunlit patch. In the photo it is
the boundary of the clipped region (a pixel counts as clipped when any channel reaches edgesnap.CLIP_LEVEL).
That boundary is not the geometric outline: the sun's 0.53 deg disk blurs it into a penumbra (half-width w
px across the outline) and the pixel boxes it, and the clipped region starts where the pixel-averaged sun
fraction reaches the clip fraction f_c = (clip - shade) / (sun-lit - shade), not at one half. The boundary
lies m(w, f_c) px from the geometric outline (towards the unlit side for f_c < 1/2): docs/unseen.md, cam48,
reproduced the measured boundary within 0.14 px with this model given the room's linear radiance.

Here f_c is measured from the photo itself, linearised by the response the probe bracket gives: the
boundary's position is the clipped indicator's (R - its integral over +-R px across the outline, exact
for a step), the shade level (rest) is the photo's a few px further out, and f_c is fitted together with
the edge's position to the edge's pixels, each against min(1, rest + K F(s - delta)) with K = (1 - rest) /
f_c (F the pixel-boxed sun fraction): the unclipped part of the ramp, over the pixels' phases, carries it.
The opening's own edges (the clipped sky against the wall, the
refinement's room edges drop them for clipping) are measured the same way with w = 0 (a pixel box only).

Each measured edge gives per sample the geometric outline's position in the photo (the boundary less
m), with the edge's noise: the jackknife over blocks of BLOCK consecutive samples of its trimmed mean.
recon/camrefine.py fits them with the room's edges (_sun_stage).

Conventions: recon/camera.py (OpenCV pixels, (0,0) the centre of the top-left pixel); offsets in px along
the image normal of the outline, positive towards the lit (clipped) side.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

R_PX = 4.0  # half-width of the profile across an outline: the clipped indicator's integral runs over +-R
STEP_PX = 0.25  # the profile's step
SAMPLE_STEP_PX = 3.0  # outline samples about this far apart in the image (the room edges' step)
END_TRIM_PX = 8.0  # samples this close to an outline edge's projected ends are dropped: corners mix edges
BLOCK = 8  # the jackknife's blocks of consecutive samples (the grain and the edge's shape correlate neighbours)
SUB = 8  # the pixel box's sub-samples per side in the model (SUB x SUB)
MIN_EDGE_SAMPLES = 3 * BLOCK  # an edge measured on fewer samples is dropped (its jackknife needs blocks)
REST_PX = (R_PX + 1.0, R_PX + 4.0)  # the shade level's span beyond the boundary's window (px)
FC_GRID = np.linspace(0.02, 0.98, 49)  # the clip fractions tried
DELTA_PX = 1.5  # the edge's position searched this far either side of the boundary line less m(f_c = 1/2)


@dataclass
class OutlineEdges:
    """Measured edges: per sample the 3D point (m), its edge's 3D direction, the edge id, the measured
    geometric position in the photo (px) and its noise; per edge the figures (for the report)."""
    X: np.ndarray  # (N,3) points of the outline (on the room's surfaces) or of the opening's edges
    D: np.ndarray  # (N,3) unit directions of their 3D edges
    edge: np.ndarray  # (N,) edge ids (0.. per kind; camrefine offsets them past the room's edges)
    q: np.ndarray  # (N,2) px: the geometric edge's position in the photo (uv + (boundary - m) n)
    sigma_edge: np.ndarray  # (N,) px: the noise of its edge's mean offset (jackknife)
    info: list  # per edge: dict(kind, n, offset_px, jackknife_px, f_c, w_px)


def disk_fraction(u: np.ndarray) -> np.ndarray:
    """Lit fraction of a uniform disk cut by a chord at offset u (in radii, towards the lit side)."""
    u = np.clip(u, -1.0, 1.0)
    return 0.5 + (u * np.sqrt(1 - u * u) + np.arcsin(u)) / np.pi


def _box_profiles(w: np.ndarray, n: np.ndarray, ss: np.ndarray) -> np.ndarray:
    """(N, len(ss)) the sun fraction averaged over a pixel's box whose centre lies ss px from the geometric
    outline (along its unit image normal n, positive lit), the penumbra's half-width w px (0: a step)."""
    g = (np.arange(SUB) + 0.5) / SUB - 0.5
    gx, gy = [a.ravel() for a in np.meshgrid(g, g)]
    proj = n[:, 0:1] * gx[None] + n[:, 1:2] * gy[None]  # (N, SUB^2)
    x = ss[None, :, None] + proj[:, None, :]
    w = np.asarray(w, float)[:, None, None]
    step = (x > 0).astype(float) + 0.5 * (x == 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        F = np.where(w > 1e-3, disk_fraction(x / np.maximum(w, 1e-3)), step)
    return F.mean(axis=2)


def _bilinear(a: np.ndarray, P: np.ndarray) -> np.ndarray:
    """a (H,W) sampled at points P (..., 2) px (u, v), bilinear between pixel centres, clamped to the image.
    In float64 by hand, not cv2.remap (edgesnap's sampler): remap's bilinear weights are fixed point, the
    sample's position quantised to 1/32 px, coarse beside the outline's 0.04-0.25 px edge precision."""
    H, W = a.shape
    u = np.clip(P[..., 0], 0, W - 1.001)
    v = np.clip(P[..., 1], 0, H - 1.001)
    u0, v0 = np.floor(u).astype(int), np.floor(v).astype(int)
    fu, fv = u - u0, v - v0
    return ((1 - fu) * (1 - fv) * a[v0, u0] + fu * (1 - fv) * a[v0, u0 + 1] + (1 - fu) * fv * a[v0 + 1, u0]
            + fu * fv * a[v0 + 1, u0 + 1])


def clipped(photo: np.ndarray) -> np.ndarray:
    """(H,W) float 1 where any channel reaches edgesnap.CLIP_LEVEL, else 0."""
    from recon.edgesnap import CLIP_LEVEL

    return (np.asarray(photo)[:, :, :3].max(axis=2) >= CLIP_LEVEL).astype(np.float32)


def linear_to_clip(photo: np.ndarray, response: np.ndarray) -> np.ndarray:
    """(H,W): the photo's linear exposure in units of the clip level, the channel nearest to clipping:
    max over channels of g_c[level] / g_c[CLIP_LEVEL] (response: the inverse response (256,3), level ->
    relative exposure, lighting.hdr's); >= 1 exactly where `clipped` is 1."""
    from recon.edgesnap import CLIP_LEVEL

    g = np.asarray(response, float).reshape(256, 3) if np.shape(response) != (3, 256) else np.asarray(response).T
    img = np.asarray(photo)[:, :, :3]
    out = np.stack([g[img[:, :, c], c] / g[CLIP_LEVEL, c] for c in range(3)], axis=2).max(axis=2)
    return out.astype(np.float32)


def boundary_offset(clip: np.ndarray, uv: np.ndarray, n: np.ndarray) -> np.ndarray:
    """(N,) px: the clipped region's boundary along n (towards the clipped side) about uv: R minus the
    integral of the clipped indicator over [-R, R] (a step at b gives b)."""
    ss = np.arange(-R_PX + STEP_PX / 2, R_PX, STEP_PX)
    c = _bilinear(clip, uv[:, None, :] + ss[None, :, None] * n[:, None, :])
    return R_PX - c.sum(axis=1) * STEP_PX


def _tmean(o: np.ndarray) -> float:
    """Mean of the central 60 % (the offsets are quantised by the pixels and have outliers)."""
    o = np.sort(o)
    k = int(0.2 * len(o))
    return float(np.mean(o[k:len(o) - k]))


def _jackknife(o: np.ndarray) -> float:
    """The jackknife std (px) of _tmean over blocks of BLOCK consecutive samples."""
    blocks = [o[i:i + BLOCK] for i in range(0, len(o), BLOCK)]
    B = len(blocks)
    jk = np.array([_tmean(np.concatenate(blocks[:i] + blocks[i + 1:])) for i in range(B)])
    return float(np.sqrt((B - 1) / B * np.sum((jk - jk.mean()) ** 2)))


def measure_edges(uv: np.ndarray, n: np.ndarray, w: np.ndarray, edge: np.ndarray, clip: np.ndarray,
                  lin: np.ndarray, kind: str) -> tuple[np.ndarray, np.ndarray, list]:
    """Per sample (uv (N,2) px, unit normal n (N,2) towards the lit side, penumbra half-width w (N,) px,
    edge ids (N,)) the geometric edge's offset along n (px: the clipped boundary less the model's m) and
    a keep mask; per edge its figures. An edge is dropped when its profile does not cross from unlit to
    clipped (its lit end clipped in under half its samples, or its unlit end in over half) or it has under
    MIN_EDGE_SAMPLES samples."""
    off = np.full(len(uv), np.nan)
    keep = np.zeros(len(uv), bool)
    info = []
    ss = np.arange(-R_PX - 3.0, R_PX + 3.0, 0.02)
    for e in np.unique(edge):
        m = np.flatnonzero(edge == e)
        if len(m) < MIN_EDGE_SAMPLES:
            continue
        u, nn = uv[m], n[m]
        lit_end = _bilinear(clip, u + (R_PX - 0.5) * nn)
        dark_end = _bilinear(clip, u - (R_PX - 0.5) * nn)
        if not (np.mean(lit_end > 0.5) >= 0.5 and np.mean(dark_end > 0.5) <= 0.5):
            continue
        b = boundary_offset(clip, u, nn)
        # the boundary as a line along the edge (the camera's error varies smoothly along it): the shade level
        # is read beyond it, not beyond each sample's noisy boundary
        t = np.arange(len(m), dtype=float)
        bs = np.polyval(np.polyfit(t, np.clip(b, -R_PX, R_PX), 1), t)
        far = bs[:, None, None] - np.linspace(*REST_PX, 7)[None, :, None]  # (n, 7, 1) px beyond the boundary
        rest = np.median(np.mean(_bilinear(lin, u[:, None] + far * nn[:, None]), axis=1))
        F = _box_profiles(w[m], nn, ss)  # (n, len(ss)): each sample's pixel-boxed sun fraction, increasing
        F = np.maximum.accumulate(F, axis=1) + 1e-9 * np.arange(len(ss))[None]
        # m(f_c) per sample: where its boxed fraction reaches f_c (px from the geometric edge), on the grid
        M = np.stack([np.interp(FC_GRID, F[i], ss) for i in range(len(m))])  # (n, G)
        if not rest < 1.0:
            continue
        # f_c and the edge's position fitted together to its pixels (their centres, not interpolated: the
        # model is the pixel's box): each pixel within +-R of a sample's line, its linear value capped at the
        # clip level against min(1, rest + K F(s - delta)), K = (1 - rest) / f_c; delta searched within
        # DELTA_PX of the boundary line. The ramp's shape (its unclipped part, over the pixels' phases)
        # carries f_c; anchored to the boundary alone it would take the boundary's own quantisation
        kk = np.arange(-R_PX, R_PX + 1e-9, 0.5)
        pix = np.rint(u[:, None] + kk[None, :, None] * nn[:, None]).astype(int)  # (n, k, 2)
        pix[..., 0] = pix[..., 0].clip(0, lin.shape[1] - 1)
        pix[..., 1] = pix[..., 1].clip(0, lin.shape[0] - 1)
        s_pix = np.sum((pix - u[:, None]) * nn[:, None], axis=2)  # (n, k) px along n from the sample's line
        val = np.minimum(lin[pix[..., 1], pix[..., 0]], 1.0)
        delta = float(np.median(bs - M[:, len(FC_GRID) // 2])) + np.arange(-DELTA_PX, DELTA_PX + 1e-9, 0.05)
        x = (s_pix[:, :, None] - delta[None, None, :] - ss[0]) / (ss[1] - ss[0])  # (n, k, D) in F's grid
        i0 = np.clip(np.floor(x).astype(int), 0, len(ss) - 2)
        fr = np.clip(x - i0, 0.0, 1.0)
        Fi = np.take_along_axis(F[:, :, None], i0.reshape(len(m), -1)[:, :, None], 1)[..., 0].reshape(i0.shape)
        Fj = np.take_along_axis(F[:, :, None], (i0 + 1).reshape(len(m), -1)[:, :, None], 1)[..., 0].reshape(i0.shape)
        Fp = Fi * (1 - fr) + Fj * fr  # (n, k, D) the boxed sun fraction of each pixel for each delta
        cost = np.array([np.min(np.sum((val[:, :, None] - np.minimum(rest + (1.0 - rest) / fc * Fp, 1.0)) ** 2,
                                       axis=(0, 1))) for fc in FC_GRID])
        j = int(np.argmin(cost))
        o = b - M[:, j]
        off[m], keep[m] = o, True
        info.append({"kind": kind, "edge": int(e), "n": int(len(m)), "offset_px": _tmean(o),
                     "jackknife_px": _jackknife(o),
                     "f_c": float(FC_GRID[j]), "rest": float(rest), "w_px": float(np.median(w[m]))})
    return off, keep, info


def _cast(scene, origins: np.ndarray, direction: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rays from `origins` (N,3) along `direction` (3,) against an Open3D RaycastingScene: (hit points
    (N,3), unit face normals (N,3), triangle ids (N,); a miss has t inf and id -1)."""
    import open3d as o3d

    rays = np.concatenate([origins, np.broadcast_to(direction, origins.shape)], 1).astype(np.float32)
    ans = scene.cast_rays(o3d.core.Tensor(rays))
    t = ans["t_hit"].numpy().astype(float)
    ids = ans["primitive_ids"].numpy().astype(np.int64)
    ids[~np.isfinite(t)] = -1
    return origins + np.where(np.isfinite(t), t, 0.0)[:, None] * direction, \
        ans["primitive_normals"].numpy().astype(float), ids


class SunEdges:
    """The sunlit patch's outline (each opening edge cast along the sun onto the room's surfaces) and the
    openings' own edges, measured in a photo at a given camera (measure)."""

    def __init__(self, openings: list[np.ndarray], to_sun: np.ndarray, diameter_deg: float, occluder,
                 photo: np.ndarray, response: np.ndarray, step_m: float = 0.005):
        """openings: the (4,3) corners of each opening quad (m); to_sun: the direction towards the sun;
        diameter_deg: the sun's angular diameter; occluder: camrefine._Occluder of the room's faces;
        photo: (H,W,3) uint8; response: the inverse response (256,3) of lighting.hdr; step_m: the spacing
        of the 3D samples along an opening's edge before they are thinned in the image."""
        d = np.asarray(to_sun, float)
        self.d = d / np.linalg.norm(d)
        self.half = np.radians(diameter_deg / 2)
        self.occ = occluder
        self.clip = clipped(photo)
        self.lin = linear_to_clip(photo, response)
        self.items = []  # (kind, X (N,3) 3D points, D (N,3), fold ok (N,), inside (N,3), face normal (N,3), src (N,3))
        for quad in openings:
            quad = np.asarray(quad, float)
            centre = quad.mean(axis=0)
            for k in range(4):
                a, b = quad[k], quad[(k + 1) % 4]
                L = float(np.linalg.norm(b - a))
                if not L > 0:
                    continue
                De = (b - a) / L
                s = (np.arange(max(int(L / step_m), 2)) + 0.5) / max(int(L / step_m), 2)
                P = a + s[:, None] * (b - a)
                # the opening's own edge: the clipped sky towards the opening's centre
                self.items.append(("opening", P, np.broadcast_to(De, P.shape), np.ones(len(P), bool),
                                   P + 0.01 * _unit(centre - P), None, P))
                # its shadow: cast along -d from 1 cm inside; the edge's direction and the lit side by two
                # more rays (a neighbour along the edge, a point 1 cm towards the opening's centre)
                F, N, ids = _cast(occluder.scene, P - 0.01 * self.d, -self.d)
                F2, _, ids2 = _cast(occluder.scene, P + 0.01 * De - 0.01 * self.d, -self.d)
                Fi, _, ids3 = _cast(occluder.scene, P + 0.01 * _unit(centre - P) - 0.01 * self.d, -self.d)
                ok = (ids >= 0) & (ids2 >= 0) & (ids3 >= 0)
                ok &= (ids // 2 == ids2 // 2) & (ids // 2 == ids3 // 2)  # one face (two triangles a face): no fold
                D = _unit(F2 - F)
                for f in np.unique(ids[ok] // 2):  # one edge per face it falls on
                    self.items.append(("outline", F, D, ok & (ids // 2 == f), Fi, N, P))

    def _w(self, cam, F: np.ndarray, N: np.ndarray, src: np.ndarray, n: np.ndarray) -> np.ndarray:
        """(N,) the sun disk's half-width (px) across the image normal n of outline points F (on faces of
        normal N, cast from the opening's points src)."""
        e1 = _unit(np.cross(self.d, [0.0, 1.0, 0.0]) if abs(self.d[1]) < 0.99 else np.cross(self.d, [1.0, 0, 0]))
        e2 = np.cross(self.d, e1)
        uv0 = cam.project(F)[0]
        o = []
        for e in (e1, e2):
            dd = _unit(self.d + np.tan(self.half) * e)
            with np.errstate(divide="ignore", invalid="ignore"):
                s = np.sum((F - src) * N, axis=1) / (-(N @ dd))
            Fp = src - s[:, None] * dd
            o.append(np.sum((cam.project(Fp)[0] - uv0) * n, axis=1))
        return np.nan_to_num(np.hypot(o[0], o[1]), nan=0.0)

    def measure(self, cam) -> OutlineEdges:
        """The edges' geometric positions in the photo at `cam` (OutlineEdges; empty when none is seen)."""
        Xs, Ds, Es, Qs, Ss, info = [], [], [], [], [], []
        eid = 0
        for kind, X, D, ok, inside, N, src in self.items:
            uv, z = cam.project(X)
            keep = ok & (z > 0.05)
            keep &= np.all(uv >= R_PX + 4, axis=1) & (uv[:, 0] <= cam.width - R_PX - 5) \
                & (uv[:, 1] <= cam.height - R_PX - 5)
            if keep.sum() < 2:
                eid += 1
                continue
            # thin to about SAMPLE_STEP_PX in the image, away from the ends
            idx = np.flatnonzero(keep)
            along = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(uv[idx], axis=0), axis=1))])
            if along[-1] < 2 * END_TRIM_PX:
                eid += 1
                continue
            marks = np.arange(END_TRIM_PX, along[-1] - END_TRIM_PX + 1e-9, SAMPLE_STEP_PX)
            sel = idx[np.unique(np.searchsorted(along, marks).clip(0, len(idx) - 1))]
            sel = sel[self.occ.visible(cam.centre, X[sel])]
            if len(sel) < MIN_EDGE_SAMPLES:
                eid += 1
                continue
            u = uv[sel]
            d2 = cam.project(X[sel] + 0.01 * D[sel])[0] - u
            t = d2 / np.maximum(np.linalg.norm(d2, axis=1, keepdims=True), 1e-12)
            n = np.stack([-t[:, 1], t[:, 0]], 1)
            n *= np.sign(np.sum(n * (cam.project(inside[sel])[0] - u), axis=1))[:, None]
            w = np.zeros(len(sel)) if kind == "opening" else self._w(cam, X[sel], N[sel], src[sel], n)
            off, kept, inf = measure_edges(u, n, w, np.full(len(sel), eid), self.clip, self.lin, kind)
            if kept.any():
                jk = inf[0]["jackknife_px"]
                Xs.append(X[sel][kept]); Ds.append(D[sel][kept]); Es.append(np.full(int(kept.sum()), eid))
                Qs.append(u[kept] + off[kept, None] * n[kept]); Ss.append(np.full(int(kept.sum()), jk))
                info += inf
            eid += 1
        if not Xs:
            z = np.zeros((0, 3))
            return OutlineEdges(z, z, np.zeros(0, int), np.zeros((0, 2)), np.zeros(0), [])
        return OutlineEdges(np.concatenate(Xs), np.concatenate(Ds), np.concatenate(Es), np.concatenate(Qs),
                            np.concatenate(Ss), info)


def _unit(v: np.ndarray) -> np.ndarray:
    v = np.asarray(v, float)
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)
