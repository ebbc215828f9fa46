"""Single-photo camera calibration from vanishing points (seed sec. 3, eq. 1; Cipolla, Drummond &
Robertson 1999, the seed's ref. 13; Hartley & Zisserman 2nd ed. sec. 8.8).

The user marks two or more image segments per world axis (x, y = vertical, z). Per family the
vanishing point (VP) is the least-squares intersection of the segments (residual: distance of a
segment's endpoints from the line through its midpoint and the VP), robust to one bad segment
(best pairwise-intersection hypothesis, then a soft-L1 refinement and rejection of segments more
than 3 px / 3 robust sigmas off). Intrinsics:
  * two families: principal point c at the image centre, focal length by eq. 1,
    f^2 = -(v - c) . (v' - c);
  * three finite VPs: c starts at the orthocentre of the VP triangle and is fitted, but is held at
    the image centre unless freeing it lowers the fit's chi-square significantly (likelihood
    ratio, 2 dof, 99.9 %): a free principal point costs more in noise than it gains when the true
    one is near the centre, as in most cameras (window_room's clicks: focal 2.7 % -> 1.9 %).
Rotation: the columns of R are the VP directions K^-1 v (third by cross product); signs: world +Y
points up in the image, +X runs rightwards in the image (R[0,0] >= 0; `flip_xz` takes the other
choice), Z = X x Y (right-handed). A joint least-squares refinement of (f, [c], R) over all
segments makes the axes exactly orthogonal; each segment counts by its noise. Given the photo, the
segments are first snapped to its edges (recon/edgesnap.py: about 0.1 px instead of the clicks'
0.5 px); a snapped segment the joint fit disagrees with by more than 3 sigma goes back to its
click. Translation: the world origin lies on the ray through the user's origin pixel, in front of
the camera, at the distance set by the camera height above the floor (y = 0) or by a known length
along an axis from the origin; with neither, at unit distance (scale unknown).

The standard deviation of f from the fit's covariance (the segments' noise, scaled up when the
residuals are larger) flags ill-conditioned views: a near-frontal plane puts a VP near infinity
and f is then undetermined; `calibrate` raises IllConditionedError for them unless asked not to.

Conventions: OpenCV camera (recon/camera.py): x_cam = R X + t, pixel centre of the top-left pixel
at (0,0). LINES.json: {"x": [[u1,v1,u2,v2], ...], "y": [...], "z": [...], "origin": [u, v],
"known_length": {"axis": "x", "end_px": [u, v], "metres": L}} (origin and known_length optional,
at least two of x/y/z). Segments shorter than 1 px are dropped with a warning (fallback); a family
left with fewer than two segments is an error.
"""
from __future__ import annotations

import logging
import os
from dataclasses import dataclass, field
from itertools import combinations
from pathlib import Path

import numpy as np

from recon.camera import Camera

log = logging.getLogger(__name__)

AXES = ("x", "y", "z")
MIN_SEGMENT_PX = 1.0
NOISE_FLOOR_PX = 0.5
CHI2_2DOF_999 = 13.82  # 99.9 % point of the chi-square distribution with 2 degrees of freedom


class IllConditionedError(ValueError):
    """The vanishing points do not determine the focal length reliably (e.g. near-frontal view)."""


@dataclass
class VanishingPoint:
    h: np.ndarray  # (3,) unit homogeneous pixel coordinates (u, v, 1) ~ h; h[2] ~ 0 at infinity
    inliers: np.ndarray  # (N,) bool, segments used
    residual_px: np.ndarray  # (N,) distance of each segment's endpoints from its line to the VP, px
    snapped: np.ndarray | None = None  # (N,) bool: segment snapped to an image edge (recon/edgesnap.py)
    segments: np.ndarray | None = None  # (N,4) the segments the fit used (snapped or as clicked), px

    @property
    def finite(self) -> bool:
        return abs(self.h[2]) > 1e-9

    @property
    def px(self) -> np.ndarray | None:
        """(2,) pixel position, or None at infinity."""
        return self.h[:2] / self.h[2] if self.finite else None


@dataclass
class Calibration:
    camera: Camera
    vps: dict[str, VanishingPoint]
    focal_rel_sigma: float  # std(f)/f from the fit covariance
    ill_conditioned: bool
    principal_point_from: str  # "image centre" | "three vanishing points" | "given"
    scale: str  # "camera height" | "known length" | "unknown (unit distance)" | "no origin"
    rms_px: float  # RMS segment residual of the joint fit, px
    notes: list[str] = field(default_factory=list)

    def to_json(self) -> dict:
        c = self.camera
        k = c.intrinsics_json()
        return {
            **k, "K": k,
            "K_matrix": c.K.tolist(), "R": c.R.tolist(), "t": c.t.tolist(), "centre": c.centre.tolist(),
            "convention": "OpenCV: x_cam = R @ X_world + t, centre = -R^T t; u = fx x/z + cx, v = fy y/z + cy; "
                          "pixel (0,0) is the centre of the top-left pixel; world +Y up, metres",
            "vanishing_points": {a: {"h": v.h.tolist(), "px": None if v.px is None else v.px.tolist(),
                                     "inliers": v.inliers.tolist(), "residual_px": v.residual_px.tolist(),
                                     "snapped": None if v.snapped is None else v.snapped.tolist(),
                                     "segments": None if v.segments is None else v.segments.tolist()}
                                 for a, v in self.vps.items()},
            "focal_rel_sigma": self.focal_rel_sigma, "ill_conditioned": self.ill_conditioned,
            "principal_point_from": self.principal_point_from, "scale": self.scale, "rms_px": self.rms_px,
            "notes": self.notes,
        }


# ----------------------------------------------------------------------------------------------
# Input

def _segments(value, where: str) -> np.ndarray:
    try:
        a = np.asarray(value, float)
    except (TypeError, ValueError):
        raise ValueError(f"{where}: segments must be numbers [[u1,v1,u2,v2], ...]") from None
    if a.ndim != 2 or a.shape[1] != 4 or not np.all(np.isfinite(a)):
        raise ValueError(f"{where}: segments must be a list of [u1,v1,u2,v2] with finite numbers, "
                         f"got shape {a.shape}")
    return a


def parse_lines(d: dict, src: str = "<lines>") -> dict:
    """Validate a LINES dict -> {"families": {axis: (N,4)}, "origin": (2,) | None, "known_length": dict | None}."""
    if not isinstance(d, dict):
        raise ValueError(f"{src}: top level must be an object")
    fams = {}
    for a in AXES:
        for key in (a, a.upper()):
            if key in d:
                fams[a] = _segments(d[key], f"{src}: field '{key}'")
    if len(fams) < 2:
        raise ValueError(f"{src}: need line families for at least two of x/y/z, got {sorted(fams) or 'none'} "
                         "(one family gives one vanishing point: no focal length, no rotation)")
    origin = None
    if d.get("origin") is not None:
        origin = np.asarray(d["origin"], float)
        if origin.shape != (2,) or not np.all(np.isfinite(origin)):
            raise ValueError(f"{src}: field 'origin' must be [u, v]")
    kl = d.get("known_length")
    if kl is not None:
        if not (isinstance(kl, dict) and kl.get("axis") in AXES and "end_px" in kl and "metres" in kl):
            raise ValueError(f"{src}: field 'known_length' must be {{'axis': x|y|z, 'end_px': [u, v], 'metres': L}}")
        if not float(kl["metres"]) > 0:
            raise ValueError(f"{src}: field 'known_length.metres' must be positive")
    return {"families": fams, "origin": origin, "known_length": kl}


def load_lines(path: str | os.PathLike) -> dict:
    """Read LINES.json (see module docstring); errors name the file."""
    path = Path(path)
    from recon.io import read_json

    d = read_json(path)
    return parse_lines(d, str(path))


def lines_from_scene(scene: dict, noisy: bool = True) -> dict:
    """A scene.json's annotations (vanishing_segments, world_origin_px) in the LINES.json format.
    `noisy` picks the noisy endpoints 'px' (what a user would click), else 'px_true'."""
    ann = scene.get("annotations", {}) if isinstance(scene, dict) else {}
    segs = ann.get("vanishing_segments")
    if not isinstance(segs, dict):
        raise ValueError("scene has no 'annotations.vanishing_segments'")
    key = "px" if noisy else "px_true"
    out: dict = {a.lower(): [[*s[key][0], *s[key][1]] for s in v] for a, v in segs.items()}
    o = ann.get("world_origin_px" if noisy else "world_origin_px_true")
    if o is not None:
        out["origin"] = list(o)
    return out


# ----------------------------------------------------------------------------------------------
# Vanishing points

def _seg_residual(segs: np.ndarray, vh: np.ndarray) -> np.ndarray:
    """Signed distance (px) of each segment's first endpoint from the line through its midpoint and
    the homogeneous VP `vh` (pixels); the second endpoint is at the opposite distance."""
    a, b = segs[:, :2], segs[:, 2:]
    m = np.concatenate([(a + b) / 2, np.ones((len(segs), 1))], 1)
    lines = np.cross(m, vh[None, :] if vh.ndim == 1 else vh)
    nrm = np.maximum(np.linalg.norm(lines[:, :2], axis=1), 1e-12)
    return (lines[:, 0] * a[:, 0] + lines[:, 1] * a[:, 1] + lines[:, 2]) / nrm


def _normaliser(width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """T (3,3) maps homogeneous pixels to centred, scaled coordinates, and its inverse."""
    s = max(width, height) / 2.0
    c = np.array([(width - 1) / 2.0, (height - 1) / 2.0])
    T = np.array([[1 / s, 0, -c[0] / s], [0, 1 / s, -c[1] / s], [0, 0, 1.0]])
    return T, np.linalg.inv(T)


def fit_vanishing_point(segs: np.ndarray, width: int, height: int, name: str = "family",
                        src: str = "<lines>") -> VanishingPoint:
    """Robust least-squares VP of a family of segments (N,4) in pixels. See the module docstring."""
    from scipy.optimize import least_squares

    segs = np.asarray(segs, float)
    length = np.linalg.norm(segs[:, 2:] - segs[:, :2], axis=1)
    keep = length >= MIN_SEGMENT_PX
    if not np.all(keep):
        log.warning("%s: family '%s': dropped %d segment(s) shorter than %.0f px", src, name, int((~keep).sum()),
                    MIN_SEGMENT_PX)
    if keep.sum() < 2:
        raise ValueError(f"{src}: family '{name}' needs at least two segments of non-zero length, "
                         f"has {int(keep.sum())}")
    T, Ti = _normaliser(width, height)
    scale = 1.0 / T[0, 0]
    s = segs[keep]
    hom = lambda p: np.concatenate([p, np.ones((len(p), 1))], 1) @ T.T  # noqa: E731
    ln = np.cross(hom(s[:, :2]), hom(s[:, 2:]))
    ln /= np.linalg.norm(ln[:, :2], axis=1, keepdims=True)

    def resid(vn: np.ndarray) -> np.ndarray:
        return _seg_residual(s, Ti @ vn)

    # hypotheses: every pairwise intersection and the algebraic least-squares point
    cands = [np.linalg.eigh(ln.T @ ln)[1][:, 0]]
    for i, j in combinations(range(len(s)), 2):
        v = np.cross(ln[i], ln[j])
        if np.linalg.norm(v) > 1e-12:
            cands.append(v / np.linalg.norm(v))
    thr = 2.0
    scores = [np.sum(np.minimum(resid(v) ** 2, thr ** 2)) for v in cands]
    v0 = cands[int(np.argmin(scores))]
    if np.linalg.norm(v0) < 0.5:
        raise ValueError(f"{src}: family '{name}': segments are collinear, the vanishing point is undetermined")
    inl = np.ones(len(s), bool)
    for _ in range(2):
        e1 = np.cross(v0, [1.0, 0, 0] if abs(v0[0]) < 0.9 else [0, 1.0, 0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(v0, e1)

        def f(x, e1=e1, e2=e2, v0=v0):
            v = v0 + x[0] * e1 + x[1] * e2
            return _seg_residual(s[inl], Ti @ (v / np.linalg.norm(v)))

        loss = "soft_l1" if inl.sum() > 2 else "linear"
        res = least_squares(f, np.zeros(2), loss=loss, f_scale=1.0, x_scale=1.0 / scale, xtol=1e-12, ftol=1e-12)
        v = v0 + res.x[0] * e1 + res.x[1] * e2
        v0 = v / np.linalg.norm(v)
        r = np.abs(resid(v0))
        if len(s) < 3:
            break
        sig = 1.4826 * np.median(r[inl])
        new = r <= max(3.0, 3 * sig)
        if new.sum() < 2 or np.array_equal(new, inl):
            break
        if (~new).sum() > max(1, len(s) // 3):
            log.warning("%s: family '%s': %d of %d segments disagree", src, name, int((~new).sum()), len(s))
        inl = new
    vh = Ti @ v0
    vh /= np.linalg.norm(vh)
    full_inl = np.zeros(len(segs), bool)
    full_inl[np.flatnonzero(keep)[inl]] = True
    full_res = np.full(len(segs), np.nan)
    full_res[keep] = np.abs(_seg_residual(s, vh))
    if inl.sum() < len(s):
        log.info("%s: family '%s': rejected segment(s) %s (residual %s px)", src, name,
                 np.flatnonzero(keep)[~inl].tolist(), np.round(full_res[keep][~inl], 1).tolist())
    return VanishingPoint(vh, full_inl, full_res)


# ----------------------------------------------------------------------------------------------
# Camera

def focal_from_vps(v1: np.ndarray, v2: np.ndarray, c: np.ndarray) -> float:
    """Eq. 1 with the principal point c: f^2 = -(v1-c).(v2-c); NaN when not positive. Pixels."""
    f2 = -float(np.dot(v1 - c, v2 - c))
    return float(np.sqrt(f2)) if f2 > 0 else float("nan")


def orthocentre(v1: np.ndarray, v2: np.ndarray, v3: np.ndarray) -> np.ndarray:
    """Orthocentre of the triangle of three finite VPs (the principal point), pixels."""
    A = np.array([v3 - v2, v3 - v1])
    b = np.array([np.dot(v3 - v2, v1), np.dot(v3 - v1, v2)])
    return np.linalg.solve(A, b)


def _rotation_from_dirs(dirs: dict[str, np.ndarray], flip_xz: bool) -> np.ndarray:
    """R (world->camera) from camera-frame axis directions (any sign) of >= 2 axes."""
    d = {a: v / np.linalg.norm(v) for a, v in dirs.items()}
    if "y" in d and d["y"][1] > 0:
        d["y"] = -d["y"]  # +Y up: image y grows downwards
    if "x" in d and "y" in d:
        x, y = d["x"], d["y"]
        z = np.cross(x, y)
    elif "y" in d:
        y, z = d["y"], d["z"]
        x = np.cross(y, z)
    else:
        x, z = d["x"], d["z"]
        y = np.cross(z, x)
        if y[1] > 0:
            y, z = -y, -z
    M = np.stack([x, y, z], 1)
    U, _, Vt = np.linalg.svd(M)
    R = U @ Vt
    if np.linalg.det(R) < 0:
        R = U @ np.diag([1, 1, -1]) @ Vt
    if (R[0, 0] < 0) != flip_xz:
        R = R @ np.diag([-1.0, 1.0, -1.0])  # rotate 180 deg about world Y: X and Z flip together
    return R


def _rotvec(R: np.ndarray) -> np.ndarray:
    import cv2

    return cv2.Rodrigues(R)[0].ravel()


def _rotmat(r: np.ndarray) -> np.ndarray:
    import cv2

    return cv2.Rodrigues(np.asarray(r, float).reshape(3, 1))[0]


def calibrate(families: dict[str, np.ndarray], width: int, height: int, origin=None,
              camera_height: float | None = None, known_length: dict | None = None,
              principal_point=None, flip_xz: bool = False, max_focal_rel_sigma: float = 0.05,
              refuse_focal_rel_sigma: float = 0.15, raise_ill_conditioned: bool = True, sigma_px: float = NOISE_FLOOR_PX, pp_sigma_px: float | None = None,
              image: np.ndarray | None = None, src: str = "<lines>") -> Calibration:
    """Calibrated camera from line families {axis: (N,4) pixel segments}; see the module docstring.

    principal_point: (2,) pixels to hold fixed (default: fitted when three finite VPs move it
    significantly from the image centre, else the image centre). `image`: the photo (H,W[,3] uint8);
    given, the segments are snapped to its edges (recon/edgesnap.py) and weighted by their noise.
    Raises ValueError naming `src` on bad input (also an image of another size), IllConditionedError
    when std(f)/f > refuse_focal_rel_sigma (the focal length is undetermined; unless
    raise_ill_conditioned is False; above max_focal_rel_sigma the result is only flagged
    `ill_conditioned` with a note), or when eq. 1 has
    no solution while the VPs lie far outside the image (a near-frontal view). `sigma_px`: the noise
    of the segments as given (per endpoint, px: 0.5 for hand-clicked endpoints, lower for fitted
    lines); it weights them in the fit and is the floor of the noise assumed for std(f);
    `pp_sigma_px`: how far the true principal point may be from the image centre (1 sigma, px) when
    it is assumed there (default 1 % of the larger image side); it adds eq. 1's sensitivity to it
    to std(f)/f."""
    fams = {a.lower(): np.asarray(s, float) for a, s in families.items()}
    if len(fams) < 2:
        raise ValueError(f"{src}: need at least two line families, got {sorted(fams)}")
    vps = {a: fit_vanishing_point(s, width, height, a, src) for a, s in fams.items()}
    notes: list[str] = []
    centre = np.array([(width - 1) / 2.0, (height - 1) / 2.0])
    finite = [a for a in AXES if a in vps and vps[a].finite
              and np.linalg.norm(vps[a].px - centre) < 1e3 * max(width, height)]
    pp_from = "given" if principal_point is not None else "image centre"
    c = np.asarray(principal_point, float) if principal_point is not None else centre
    free_pp = False
    if principal_point is None and len(finite) == 3:
        try:
            o = orthocentre(*(vps[a].px for a in AXES))
            fo = focal_from_vps(vps["x"].px, vps["y"].px, o)
            if np.all(np.abs(o - centre) < 0.25 * np.array([width, height])) and np.isfinite(fo):
                c, pp_from, free_pp = o, "three vanishing points", True
            else:
                notes.append("orthocentre of the three VPs is implausible; principal point at the image centre")
        except np.linalg.LinAlgError:
            notes.append("three VPs collinear; principal point at the image centre")
    # initial focal length by eq. 1 from the best-conditioned finite pair
    pairs = [(a, b) for a, b in combinations(finite, 2) if np.isfinite(focal_from_vps(vps[a].px, vps[b].px, c))]
    pair = pairs[0] if pairs else None
    f0 = float(np.median([focal_from_vps(vps[a].px, vps[b].px, c) for a, b in pairs])) if pairs else float("nan")
    if pair is None:
        inf = [a for a in vps if a not in finite]
        if inf:
            raise ValueError(f"{src}: the segments of family {inf} are parallel in the image (vanishing point at "
                             "infinity): the focal length is undetermined; mark a family whose lines converge")
        far = [a for a in finite if np.linalg.norm(vps[a].px - c) > max(width, height)]
        if len(far) >= len(finite) - 1:
            raise IllConditionedError(f"{src}: ill-conditioned vanishing points: eq. 1 has no solution and the "
                                      f"vanishing points of {far} lie far outside the image (near-frontal view)")
        raise ValueError(f"{src}: the vanishing points are not consistent with orthogonal axes for the principal "
                         f"point {np.round(c, 1).tolist()} (eq. 1 gives f^2 <= 0): check the axis labels")
    if len(finite) < len(vps):
        notes.append(f"vanishing point(s) {[a for a in vps if a not in finite]} at infinity; focal length "
                     f"from {pair}")
    K0 = np.array([[f0, 0, c[0]], [0, f0, c[1]], [0, 0, 1.0]])
    Ki = np.linalg.inv(K0)
    R0 = _rotation_from_dirs({a: Ki @ v.h for a, v in vps.items()}, flip_xz)

    clicked = {a: fams[a][vps[a].inliers] for a in vps}
    segs = {a: s.copy() for a, s in clicked.items()}
    sig = {a: np.full(len(s), float(sigma_px)) for a, s in clicked.items()}
    snapped = {a: np.zeros(len(s), bool) for a, s in clicked.items()}
    if image is not None:
        from recon.edgesnap import EdgeImage, snap_segments

        if np.asarray(image).shape[:2] != (height, width):
            raise ValueError(f"{src}: the image is {np.asarray(image).shape[1::-1]} px, the calibration is for "
                             f"{width}x{height}")
        edges = EdgeImage(image)
        for a in segs:
            r = snap_segments(edges, clicked[a], sigma_px)
            segs[a], sig[a], snapped[a] = r.segments, r.sigma_px, r.snapped

    def solve(c, free):
        """Joint fit; a snapped segment the fit disagrees with (> 3 sigma) goes back to its click.
        Returns K, R, std(f)/f, RMS px, chi-square."""
        while True:
            K, R, rel, rms, chi2, nres = _refine(segs, sig, f0, c, free, R0, width, height, flip_xz)
            worst = max(((abs(nres[a][i]), a, i) for a in segs for i in np.flatnonzero(snapped[a])),
                        default=(0.0, None, None))
            if worst[0] <= 3.0:
                return K, R, rel, rms, chi2
            _, a, i = worst
            log.info("%s: family '%s': snapped segment %d disagrees with the fit (%.1f sigma); using the click",
                     src, a, i, worst[0])
            segs[a][i], sig[a][i], snapped[a][i] = clicked[a][i], sigma_px, False

    if free_pp:
        # model selection: hold the principal point at the image centre unless the three VPs move it
        # significantly: likelihood ratio (chi-square, 2 dof, 99.9 %) of the free against the held fit,
        # on the same segments (a revert in either fit re-runs both)
        while True:
            n = sum(int(m.sum()) for m in snapped.values())
            held = solve(centre, False)
            free = solve(c, True)
            if sum(int(m.sum()) for m in snapped.values()) == n:
                break
        lr = held[4] - free[4]
        cf = np.round(free[0][:2, 2], 1).tolist()
        if lr > CHI2_2DOF_999 and free[2] <= max_focal_rel_sigma:
            K, R, rel, rms, _ = free
            notes.append(f"the three VPs move the principal point to {cf} (chi2 drop {lr:.1f} > {CHI2_2DOF_999} "
                         "against the image centre): fitted")
        else:
            K, R, rel, rms, _ = held
            pp_from = "image centre"
            why = (f"not significantly better than the image centre (chi2 drop {lr:.2f} <= {CHI2_2DOF_999})"
                   if not lr > CHI2_2DOF_999 else f"ill-conditioned (std(f)/f = {free[2]:.3g})")
            notes.append(f"the three VPs put the principal point at {cf}, {why}: held at the image centre")
    else:
        K, R, rel, rms, _ = solve(c, False)
    n_snapped = sum(int(m.sum()) for m in snapped.values())
    if image is not None:
        notes.append(f"{n_snapped} of {sum(len(m) for m in snapped.values())} segments snapped to image edges")
    idx = {a: AXES.index(a) for a in vps}
    rel_fit = rel
    if pp_sigma_px is None:
        pp_sigma_px = 0.01 * max(width, height)
    if pp_from == "image centre" and pp_sigma_px > 0:
        # sensitivity of eq. 1 to a principal point off the image centre: d(f)/f = (v1+v2-2c).dc / (2 f^2)
        vp_px = {a: (K @ R[:, idx[a]])[:2] / (K @ R[:, idx[a]])[2] for a in finite}
        g = [np.linalg.norm(vp_px[a] + vp_px[b] - 2 * K[:2, 2]) / (2 * K[0, 0] ** 2)
             for a, b in combinations(finite, 2)]
        rel = float(np.hypot(rel_fit, min(g) * pp_sigma_px)) if g else rel
    ill = not rel <= max_focal_rel_sigma
    used, snap_mask = {}, {}
    for a in vps:
        used[a], snap_mask[a] = fams[a].copy(), np.zeros(len(fams[a]), bool)
        used[a][vps[a].inliers], snap_mask[a][vps[a].inliers] = segs[a], snapped[a]
    vps = {a: VanishingPoint(_unit(K @ R[:, idx[a]]), vps[a].inliers,
                             np.abs(_seg_residual(used[a], K @ R[:, idx[a]])), snap_mask[a], used[a]) for a in vps}
    if ill:
        if not rel <= refuse_focal_rel_sigma:
            msg = (f"{src}: ill-conditioned vanishing points (std(f)/f = {rel:.3g} > {refuse_focal_rel_sigma}): a "
                   "line family is nearly parallel in the image (near-frontal view), so the focal length is "
                   "undetermined")
            if raise_ill_conditioned:
                raise IllConditionedError(msg)
        else:
            msg = (f"{src}: the focal length is uncertain: std(f)/f = {rel:.1%} (> {max_focal_rel_sigma:.0%}); "
                   "lines that converge more strongly (a view more oblique to the walls) would pin it down")
        notes.append(msg)

    t, scale = _translation(K, R, origin, camera_height, known_length, src)
    cam = Camera(K, R, t, int(width), int(height))
    return Calibration(cam, vps, rel, ill, pp_from, scale, rms, notes)


def _refine(segs: dict[str, np.ndarray], sig: dict[str, np.ndarray], f0: float, c: np.ndarray, free_pp: bool,
            R0: np.ndarray, width: int, height: int, flip_xz: bool):
    """Joint least-squares fit of f, [principal point], R to all segments (the VPs are K R e_axis,
    so the axes are exactly orthogonal); each segment's residual is weighted by its noise `sig` (px
    per endpoint). Returns K, R, std(f)/f, residual RMS (px), chi-square (sum of the squared
    normalised residuals) and the normalised residual of every segment {axis: (N,)}."""
    from scipy.optimize import least_squares

    s0 = float(max(width, height))
    idx = {a: AXES.index(a) for a in segs}

    def unpack(x):
        f = s0 * np.exp(x[0])  # log-parametrised: f stays positive
        cc = x[1:3] * s0 if free_pp else c
        return np.array([[f, 0, cc[0]], [0, f, cc[1]], [0, 0, 1.0]]), _rotmat(x[-3:])

    def px(x):
        K, R = unpack(x)
        return {a: _seg_residual(segs[a], K @ R[:, idx[a]]) for a in segs}

    def normalised(r):  # endpoint distance r has variance sigma^2 / 2 (two endpoints, opposite)
        return {a: r[a] * np.sqrt(2.0) / sig[a] for a in segs}

    def fun(x):
        return np.concatenate(list(normalised(px(x)).values()))

    x0 = np.concatenate([[np.log(f0 / s0)], c / s0 if free_pp else [], _rotvec(R0)])
    res = least_squares(fun, x0, xtol=1e-12, ftol=1e-12, gtol=1e-12)
    K, R = unpack(res.x)
    if not (np.all(np.isfinite(res.x)) and K[0, 0] > 0):
        raise ValueError(f"calibration fit failed (focal length {K[0, 0]:.3g})")
    r = px(res.x)
    nres = normalised(r)
    R = _rotation_from_dirs({a: R[:, idx[a]] for a in segs}, flip_xz)  # re-apply the sign conventions
    rms = float(np.sqrt(np.mean(np.concatenate(list(r.values())) ** 2)))
    # conditioning: linearised covariance, scaled up when the residuals exceed the assumed noise
    # (x[0] = log f, so std(x[0]) = std(f)/f)
    dof = max(len(res.fun) - len(res.x), 1)
    scale = max(float(res.fun @ res.fun) / dof, 1.0)
    try:
        cov = np.linalg.inv(res.jac.T @ res.jac) * scale
        rel = float(np.sqrt(max(cov[0, 0], 0.0)))
    except np.linalg.LinAlgError:
        rel = float("inf")
    return K, R, rel, rms, float(res.fun @ res.fun), nres


def _unit(v: np.ndarray) -> np.ndarray:
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def _translation(K, R, origin, camera_height, known_length, src) -> tuple[np.ndarray, str]:
    """t such that the world origin projects to `origin` at the depth the scale gives."""
    if origin is None:
        if camera_height is not None or known_length is not None:
            raise ValueError(f"{src}: a scale (camera height / known length) needs an 'origin' pixel")
        log.warning("%s: no origin pixel: camera centre put at the world origin (translation unknown)", src)
        return np.zeros(3), "no origin"
    rho = np.linalg.solve(K, np.array([origin[0], origin[1], 1.0]))  # camera-frame ray, depth 1
    if camera_height is not None:
        if not camera_height > 0:
            raise ValueError(f"{src}: camera height must be positive, got {camera_height}")
        dy = (R.T @ rho)[1]  # world-frame vertical component of the ray through the origin
        if dy > -1e-6:
            raise ValueError(f"{src}: the origin pixel {list(np.round(origin, 1))} is on or above the horizon: a "
                             f"floor origin seen from {camera_height} m up would lie behind the camera (or at "
                             "infinity); mark the origin on the floor below the horizon")
        lam = -camera_height / dy
        return lam * rho, "camera height"
    if known_length is not None:
        a = AXES.index(known_length["axis"])
        eta = np.linalg.solve(K, np.array([*map(float, known_length["end_px"]), 1.0]))
        ra = R[:, a]
        ce = np.cross(ra, eta)
        if np.linalg.norm(ce) < 1e-9:
            raise ValueError(f"{src}: 'known_length.end_px' lies at the vanishing point of axis "
                             f"{known_length['axis']}: the length is undetermined")
        s = -np.dot(ce, np.cross(rho, eta)) / np.dot(ce, ce)  # metres along the axis at unit origin depth
        if abs(s) < 1e-9:
            raise ValueError(f"{src}: 'known_length.end_px' coincides with the origin")
        lam = float(known_length["metres"]) / abs(s)
        return lam * rho, "known length"
    log.warning("%s: no scale given: the world origin is put at unit distance from the camera", src)
    return rho / np.linalg.norm(rho), "unknown (unit distance)"


def calibrate_lines(lines: dict, width: int, height: int, camera_height: float | None = None,
                    src: str = "<lines>", **kw) -> Calibration:
    """calibrate() on a parsed LINES dict (parse_lines / load_lines); `image=` snaps to the photo."""
    return calibrate(lines["families"], width, height, lines.get("origin"), camera_height,
                     lines.get("known_length"), src=src, **kw)


def rotation_error_deg(Ra: np.ndarray, Rb: np.ndarray) -> float:
    """Angle of Ra Rb^T in degrees."""
    c = (np.trace(Ra @ Rb.T) - 1) / 2
    return float(np.degrees(np.arccos(np.clip(c, -1, 1))))


def draw_overlay(image: np.ndarray, calib: Calibration, families: dict[str, np.ndarray], origin=None,
                 axis_length: float | None = None) -> np.ndarray:
    """BGR/RGB uint8 image (H,W,3) with the segments (x red, y green, z blue; a white core where
    snapped to the photo's edge; magenta: rejected), lines from each segment towards its VP, and the
    projected world axes at the origin. Returns a copy (RGB order)."""
    import cv2

    img = image.copy()
    if img.ndim == 2:
        img = cv2.cvtColor(img, cv2.COLOR_GRAY2RGB)
    col = {"x": (230, 40, 40), "y": (40, 200, 40), "z": (50, 90, 255)}
    h, w = img.shape[:2]
    for a, segs in families.items():
        vp = calib.vps[a]
        for k, s in enumerate(np.asarray(segs, float)):
            p, q = s[:2], s[2:]
            m = (p + q) / 2
            if vp.finite:
                d = vp.px - m
            else:
                d = vp.h[:2]
            d = d / max(np.linalg.norm(d), 1e-9)
            if vp.finite and np.linalg.norm(vp.px - m) < 4 * max(w, h):
                far = vp.px
            else:
                far = m + d * 2 * max(w, h)
            cv2.line(img, _pt(m), _pt(far), tuple(int(0.5 * c) for c in col[a]), 1, cv2.LINE_AA)
            thick = 2 if vp.inliers[k] else 1
            cv2.line(img, _pt(p), _pt(q), col[a] if vp.inliers[k] else (255, 0, 255), thick, cv2.LINE_AA)
            if vp.snapped is not None and vp.snapped[k]:  # white core: the segment snapped to the photo's edge
                sp = vp.segments[k]
                cv2.line(img, _pt(sp[:2]), _pt(sp[2:]), (255, 255, 255), 1, cv2.LINE_AA)
    cam = calib.camera
    if calib.scale != "no origin":
        L = axis_length or (0.5 if calib.scale in ("camera height", "known length") else 0.1)
        pts = np.array([[0, 0, 0], [L, 0, 0], [0, L, 0], [0, 0, L]], float)
        uv, z = cam.project(pts)
        if np.all(z > 0):
            for k, a in enumerate(AXES):
                cv2.arrowedLine(img, _pt(uv[0]), _pt(uv[k + 1]), col[a], 3, cv2.LINE_AA, tipLength=0.15)
                cv2.putText(img, a.upper(), _pt(uv[k + 1] + 4), cv2.FONT_HERSHEY_SIMPLEX, 0.6, col[a], 2)
    if origin is not None:
        cv2.circle(img, _pt(origin), 5, (255, 255, 0), 2, cv2.LINE_AA)
    txt = f"f = {cam.K[0, 0]:.1f} px  c = ({cam.K[0, 2]:.1f}, {cam.K[1, 2]:.1f})  std(f)/f = {calib.focal_rel_sigma:.2%}"
    cv2.putText(img, txt, (8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(img, txt, (8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
    return img


def _pt(p) -> tuple[int, int]:
    p = np.clip(np.asarray(p, float), -1e5, 1e5)
    return int(round(p[0])), int(round(p[1]))
