"""Refine a calibrated camera against the photo's edges of the taped room (issue 34, item 6).

`photoar calibrate` gets the camera from a few clicked vanishing lines and the camera height; a
percent of focal length or a few cm of centre move an object's outline by pixels. Once `scene` has
the room (room box, furniture boxes, window/lamp quads, world metres), the room's own edges are
projected into the photo and aligned with the photo's edges:

1. edges: every edge of every quad / box face (duplicates shared by two faces merged), sampled in
   3D; a sample is kept where the ray from the camera reaches it before anything else of the room
   (Open3D RaycastingScene) and it projects inside the image;
2. coarse (ICP on oriented edges; the photo's edges prepared once in recon/photoedges.py): the
   photo's Canny edges are split by the orientation of their
   gradient; each sample is matched to the nearest edge pixel whose orientation is within one bin
   of its projected edge's normal (distance transform with labels); robust least squares
   (scipy.optimize.least_squares, Cauchy loss) of the point-to-line distances n.(q - uv); the match
   radius shrinks 64 -> 2 px;
3. fine: each sample's edge is re-measured to sub-pixel accuracy as the centroid of the gradient
   profile across the projected edge (recon/edgesnap.py's gradient image, its clipped-pixel mask
   and its centroid rule), and the fit repeated; an edge whose found profile is the steep side of a ramp,
   not a step (a crease whose radiance falls smoothly into it: the centroid lands 1-1.5 px up the slope;
   recon/photoedges.ramp_edge_mask) is left out of that stage; or, with fine_stage="lines" (not the default: see
   docs/unseen.md), each edge is found as one line against the photo's own noise (recon/edgelines.py,
   _line_stage);
4. the clicked vanishing lines of calibrate (camera.json "vanishing_points": the segments it used)
   enter the same least squares with calibrate's residual (recon/vanishing._seg_residual);
3b. when the guard refuses the camera because the edge residual does not drop, the search runs again with
   the room edges whose every sample lies by a clipped pixel (a blown-out window: edgesnap refuses them all)
   kept in the fine stages at their oriented Canny matches, at a Canny pixel's noise (_fine_edges): the guard
   measures those edges, the profile stage otherwise never sees them, and its fit slides off them;
3c. when an accepted fit's room edges say less about the focal length than the clicked lines do (its own sigma of
   log f, camera_covariance with the lines included, above calibrate's sigma / sqrt(2): _focal_from_lines), the
   search runs again as in 3b and that camera is taken when the guard accepts it and its edges determine the focal
   length: a room whose only other edges are blown-out windows otherwise gets the clicked lines' focal length
   moved by its few room edges' model errors (docs/unseen.md, cam109);
5. more starts (_centre_search): the clicked lines fix the rotation and focal length, not where the
   camera stands, and a centre tens of cm off can send the wide first match radius into a wrong basin
   (a sunlit patch's border, floor texture). A grid of centres (rotation, focal, height held) is scored
   by the capped edge residual, and its best local minima are fitted too (stages 2-3 from a smaller
   radius). A start's fit replaces the input camera's own when it brings the room's edges closer to
   the photo's edges, on average over the room's edges (_edge_gain);
5b. when the accepted fit has moved the focal length from calibrate's by more than calibrate's own sigma, the
   widened focal search (_widened_search) runs and its fits the guard accepts replace the camera when their
   completed objective (_fit_cost: the profile stage's cost with a sample that found no edge counted at the
   profile's reach, plus the clicked lines) is lower (_focal_recheck): the fit's own cost does not charge an
   edge it has pushed beyond the profile's reach, and it can stop in such a basin (docs/unseen.md, cam108).
   Each fit is compared with the accepted camera on the samples neither of the two projects by a clipped pixel
   (_measurable): there no camera can measure a profile, and charging such a sample the reach rewarded a camera
   that moves a blown-out window's edge or a box edge beside a sunlit patch off the clipped pixels onto the
   glow's ramp (docs/unseen.md, cam110);
6. a photo edge point explains one room edge (_exclusive): a match nearer to another parallel room
   edge is dropped, so two close parallel edges do not both lock onto the stronger photo edge.

Free: rotation (3), centre x and z (m), focal length (fx = fy, log-parametrised); held: the camera
height (centre y, from calibrate's --height), the principal point, the room (taped). A principal point
calibrate took from three vanishing points (camera.json "principal_point_from"; that estimate is weak)
is moved to the image centre and held there, and freed only when the room's edges and the clicked
lines fit significantly better with it free (recon/campp.py: calibrate's chi-square test redone on the
room's edges, each edge carrying the room model's own error). The refined camera is accepted when the fit
is well-conditioned, agrees with the clicked lines and lowers the edge residual (_guard); else the
input camera is kept, as it is also when the refinement would move the room's edges by under
MIN_MOVE_PX (the camera already fits: a true camera stays put). The refined fit's own uncertainty
(camera_covariance, point_std_px) and a jackknife over the room's edges (edge_jackknife: the edges, not their
samples, as the independent units) come with it (Refinement.covariance / without_edge; bench/bench_camrefine.py).

Conventions: recon/camera.py (OpenCV, x_cam = R X + t, pixel (0,0) the centre of the top-left pixel).
"""
from __future__ import annotations

import copy
import dataclasses
import time
from dataclasses import dataclass

import numpy as np

from recon.camera import Camera
from recon.photoedges import ORIENT_BINS, PROFILE_HALF_PX, PROFILE_STEP_PX, PhotoEdges  # noqa: F401 (re-exported)

SAMPLE_STEP_PX = 3.0  # spacing of the edge samples in the image at the input camera
END_TRIM_PX = 6.0  # samples closer than this to an edge's projected end are dropped: corners mix edges
BORDER_PX = 3.0  # samples this close to the image border are dropped (the gradient needs its neighbours)
MIN_EDGE_PX = 12.0  # an edge shorter than this in the image is skipped (a point lamp's box)
COARSE_RADII_PX = (64.0, 32.0, 16.0, 8.0, 4.0, 2.0)  # match radius of the coarse stages (a 4 % focal
# error moves a 640 px photo's edges by up to 13 px, a 0.3 m centre error by tens of px)
ROBUST_SIGMAS = 2.0  # the robust loss's scale, in sigmas of the stage's edge noise
FINE_STAGES = ("profiles", "lines")  # the sub-pixel stage: per sample (the default) or whole edges (edgelines)
LINE_RADIUS_PX = 4.0  # the line stage's search either side of the projected edge: twice the coarse stage's
# last match radius (2 px), which leaves each sample within 2 px of a photo edge, with room for the tilt
FINE_SIGMA_PX = 0.3  # noise of a sub-pixel edge sample (edgesnap's spreads: 0.05-0.25 px)
COARSE_SIGMA_PX = 1.0  # noise of a Canny edge pixel: quantised to 1 px
SNAPPED_SIGMA_PX = 0.25  # a clicked line that calibrate snapped: edgesnap accepts spreads up to 0.25 px
CLICKED_SIGMA_PX = 0.5  # a clicked line left as clicked: the click noise calibrate assumes
CHAMFER_CAP_PX = 3.0  # edge residual: mean over samples of min(distance to the photo's edge, cap)
MIN_SAMPLES = 60  # 10 per free parameter
PP_PRIOR_REL = 0.01  # a freed principal point's prior: the image centre, 1 sigma = this fraction of the larger
# image side (calibrate's own assumption, recon/vanishing.calibrate_lines pp_sigma_px): a principal point
# shift and a small rotation move far edges alike, and in a noisy photo with few edges found the fit
# trades one for the other
EDGE_WEIGHT_SAMPLES = 20  # the fit: one edge's samples share its model error, it weighs at most this many (_solve)
EDGE_MODEL_SIGMA_PX = 0.3  # the model selection (recon/campp.py): the room model's own error of one edge's image
# (px, 1 sigma, shared by its samples): the taped room's edges sit 0.2-0.4 px off the photo's at the true camera
# (creases, contact shadows, shading, the tape), so an edge of n samples counts as one measurement of variance
# sigma_sample^2 / n + this^2 (_edge_weights "model"). Not the fit's weighting: fitted so (docs/unseen.md) the
# short furniture edges weigh as much as the room's long ones and the clicked lines far more than before, and
# window_103's refined camera went 0.19 -> 5.6 px off, window_101's 0.55 -> 2.0 px
FOCAL_FROM_LINES_RATIO = 1.0 / np.sqrt(2.0)  # a fit's own sigma of log f over calibrate's above which its room
# edges hold less information on the focal length (1 / sigma^2) than the clicked lines do (_focal_from_lines)
MAX_PRED_STD_PX = 0.25  # conditioning: a 1-sigma parameter error may move the samples this much (rms)
MIN_MOVE_PX = 1.0  # a refinement that moves the room's edges less (rms) is not made: the room model's own
# edges sit 0.2-0.4 px off the photo's (creases, contact shadows, shading; per edge, at the true camera), and
# refining the true camera moved them 0.17-0.77 px in 8 of 11 rooms (the shared three, 8 unseen ones; in the
# other three the residual check refused the move); a pixel of error is what moves an object's outline
CENTRE_STEP_PX = 4.0  # the centre search's grid step, as the motion of an edge at the median depth: twice
# the coarse stage's 2 px final match radius, so the grid's best point is within the ICP's reach
CENTRE_HYPOTHESES = 3  # the centre search's best local minima refined besides the input camera: each costs
# one fit; three leave room for the true basin when texture basins score better on the grid's coarse residual
# the match radii of a centre-search start's ICP: from 4 grid steps (an edge at a quarter of the median depth) down
GRID_RADII_PX = tuple(r for r in COARSE_RADII_PX if r <= 4 * CENTRE_STEP_PX)
EDGE_RESIDUAL_REFUSAL = "the edge residual does not drop"  # the guard's reason when it does not (_guard)
AXIS = {"x": 0, "y": 1, "z": 2}  # a clicked line family's world axis: the column of K R its vanishing point is
MIN_LINE_DIRECTIONS_DEG = 20.0  # the samples' 3D edges must span two directions at least this far apart


@dataclass
class Refinement:
    """Outcome of refine_camera. Distances in metres, angles in degrees, errors in pixels."""
    camera: Camera  # the refined camera when accepted, else the input camera
    accepted: bool
    reason: str  # why not accepted ("" when accepted)
    fits: bool  # not accepted because the input camera already fits (the refinement moves under MIN_MOVE_PX)
    moved_px: float  # rms image motion of the room's edge samples from the input to the refined camera
    n_edge_samples: int  # edge samples of the final fit (inliers of the sub-pixel stage)
    rms_edge_px: float  # rms distance of those samples from their sub-pixel edges, refined camera
    n_lines: int  # clicked segments of calibrate used
    rms_lines_px: float  # rms endpoint distance of the clicked segments from their vanishing lines
    focal_change: float  # refined / input focal - 1
    principal_point_moved_px: float  # 0 unless calibrate took it from three vanishing points (then refined)
    start: str  # the fit kept: "input" (from the input camera) or "centre search" (from one of its centres)
    centre_moved_m: float
    rotation_deg: float
    chamfer_before_px: float  # edge residual (CHAMFER_CAP_PX-capped mean distance) at the input camera
    chamfer_after_px: float  # ... at the refined camera
    seconds: float
    principal_point: str = ""  # how the principal point was modelled (recon/campp.py); "" when held as given
    covariance: object = dataclasses.field(default=None, repr=False)  # the fit's camera-parameter covariance
    # (camera_covariance), its parameters `x` and `camera_at(x)` -> Camera: the refined fit's own uncertainty
    x: object = dataclasses.field(default=None, repr=False)
    camera_at: object = dataclasses.field(default=None, repr=False)
    without_edge: object = dataclasses.field(default=None, repr=False)  # (edge index) -> Camera: the final fit
    # solved again without that room edge (edge_jackknife); None without a profile-stage fit
    edge_ids: object = dataclasses.field(default=None, repr=False)  # the room edges of the final fit
    sun_edges: list | None = None  # the sunlit outline's and the openings' edges the final fit used (_sun_stage):
    # per edge its kind, samples, offset from the clipped boundary (px), jackknife, clip fraction f_c, penumbra

    def to_json(self) -> dict:
        d = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)
             if f.name not in ("camera", "covariance", "x", "camera_at", "without_edge", "edge_ids")
             and not (f.name == "sun_edges" and self.sun_edges is None)}
        return {k: (round(v, 6) if isinstance(v, float) else v) for k, v in d.items()}

    def summary(self) -> str:
        """One line for the log."""
        return (f"{self.n_edge_samples} room-edge samples, rms {self.rms_edge_px:.2f} px; {self.n_lines} clicked "
                f"lines, rms {self.rms_lines_px:.2f} px; moved focal {100 * self.focal_change:+.2f} %, centre "
                f"{self.centre_moved_m:.3f} m, {self.rotation_deg:.2f} deg, principal point "
                f"{self.principal_point_moved_px:.1f} px ({self.moved_px:.2f} px; from the {self.start}); edge "
                f"residual {self.chamfer_before_px:.2f} -> {self.chamfer_after_px:.2f} px ({self.seconds:.1f} s)"
                + (f"; principal point {self.principal_point}" if self.principal_point else ""))


# ----------------------------------------------------------------------------------------------
# The room's edges

def room_faces(prims: list[dict]) -> list[np.ndarray]:
    """The (4,3) corners of every quad / box face of scene.json primitives (recon/assemble.py's
    parse_primitives output: quads and axis-aligned boxes), metres."""
    from recon.scene import box_faces

    faces = []
    for p in prims:
        if p.get("type") == "quad":
            faces.append(np.asarray(p["corners"], float))
        elif p.get("type") == "box":
            c, s = np.asarray(p["center"], float), np.asarray(p["size"], float)
            faces += [f[2] for f in box_faces(c - s / 2, c + s / 2)]
    return faces


def room_edges(faces: list[np.ndarray]) -> np.ndarray:
    """(E,2,3) distinct edges of the faces (an edge two faces share counts once), metres."""
    seen, out = set(), []
    for f in faces:
        for k in range(4):
            a, b = f[k], f[(k + 1) % 4]
            key = tuple(sorted((tuple(np.round(a, 4)), tuple(np.round(b, 4)))))
            if key not in seen and np.linalg.norm(b - a) > 1e-6:
                seen.add(key)
                out.append((a, b))
    return np.asarray(out, float).reshape(-1, 2, 3)


class _Occluder:
    """Ray casting against the room's faces (Open3D RaycastingScene)."""

    def __init__(self, faces: list[np.ndarray]):
        import open3d as o3d

        V = np.concatenate(faces).astype(np.float32)
        F = np.concatenate([np.array([[0, 1, 2], [0, 2, 3]]) + 4 * i for i in range(len(faces))]).astype(np.uint32)
        self.scene = o3d.t.geometry.RaycastingScene()
        self.scene.add_triangles(o3d.core.Tensor(V), o3d.core.Tensor(F))

    def visible(self, centre: np.ndarray, pts: np.ndarray) -> np.ndarray:
        """(N,) bool: nothing of the room lies between `centre` and each point (a point on a surface
        is reached by its own surface: 1 cm + 0.5 % of the distance of slack)."""
        import open3d as o3d

        d = pts - centre
        dist = np.linalg.norm(d, axis=1)
        rays = np.concatenate([np.broadcast_to(centre, pts.shape), d / dist[:, None]], 1).astype(np.float32)
        t = self.scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
        return t >= dist - (0.01 + 0.005 * dist)


@dataclass
class _Samples:
    X: np.ndarray  # (N,3) points on the edges, m
    D: np.ndarray  # (N,3) unit edge direction, m
    edge: np.ndarray  # (N,) index of the edge


def _sample_edges(cam: Camera, edges: np.ndarray, occ: _Occluder) -> _Samples:
    """Visible samples along the edges, about SAMPLE_STEP_PX apart in the image of `cam`."""
    Xs, Ds, idx = [], [], []
    C = cam.centre
    for i, (a, b) in enumerate(edges):
        # clip the edge to the part in front of the camera (z_cam > 5 cm)
        za, zb = (cam.R @ a + cam.t)[2], (cam.R @ b + cam.t)[2]
        if za < 0.05 and zb < 0.05:
            continue
        t0, t1 = 0.0, 1.0
        if za < 0.05:
            t0 = (0.05 - za) / (zb - za)
        if zb < 0.05:
            t1 = (0.05 - za) / (zb - za)
        p, q = a + t0 * (b - a), a + t1 * (b - a)
        uv, _ = cam.project(np.stack([p, q]))
        length = float(np.linalg.norm(uv[1] - uv[0]))
        if not length >= MIN_EDGE_PX:
            continue
        n = int(np.ceil(length / SAMPLE_STEP_PX))
        s = (np.arange(n) + 0.5) / n
        X = p + s[:, None] * (q - p)
        Xs.append(X)
        Ds.append(np.broadcast_to((b - a) / np.linalg.norm(b - a), X.shape))
        idx.append(np.full(n, i))
    if not Xs:
        return _Samples(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, int))
    X, D, idx = np.concatenate(Xs), np.concatenate(Ds), np.concatenate(idx)
    uv, z = cam.project(X)
    ok = (z > 0.05) & np.all(uv >= BORDER_PX, axis=1) & (uv[:, 0] <= cam.width - 1 - BORDER_PX) \
        & (uv[:, 1] <= cam.height - 1 - BORDER_PX)
    # away from the ends of each edge's projected (clipped) run: corners mix two edges' gradients
    for i in np.unique(idx):
        m = idx == i
        u = uv[m]
        along = np.linalg.norm(u - u[0], axis=1)
        ok[np.flatnonzero(m)] &= (along >= END_TRIM_PX - SAMPLE_STEP_PX / 2) & (along <= along[-1] - END_TRIM_PX
                                                                                 + SAMPLE_STEP_PX / 2)
    ok[ok] &= occ.visible(C, X[ok])
    return _Samples(X[ok], D[ok], idx[ok])


# ----------------------------------------------------------------------------------------------
# The fit

def clicked_lines(camera_json: dict | None) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """calibrate's segments ({axis: (N,4) px}) and their noise ({axis: (N,) px per endpoint}) from a
    camera.json's "vanishing_points" (the segments its fit used: snapped, or as clicked); empty for a
    camera.json without them."""
    segs, sig = {}, {}
    vps = (camera_json or {}).get("vanishing_points") or {}
    for a, v in vps.items():
        try:
            s = np.asarray(v["segments"], float).reshape(-1, 4)
            inl = np.asarray(v.get("inliers", [True] * len(s)), bool)
            snapped = np.asarray(v.get("snapped") or [False] * len(s), bool)
        except (KeyError, TypeError, ValueError):
            continue
        if a in ("x", "y", "z") and len(s) == len(inl) == len(snapped) and np.all(np.isfinite(s)):
            segs[a], sig[a] = s[inl], np.where(snapped[inl], SNAPPED_SIGMA_PX, CLICKED_SIGMA_PX)
    return segs, sig


class _Model:
    """Camera parameters x = [rotation vector (3, applied after the input R), centre x, centre z
    (m), log(f / f0)] about the input camera, and with `free_pp` the principal point's offset
    [du, dv] (px) after them."""

    def __init__(self, cam: Camera, free_pp: bool = False, pp_prior: bool = False):
        self.cam0 = cam
        self.C0 = cam.centre
        self.free_pp = free_pp
        self.pp_prior = pp_prior  # a freed principal point held near the image centre (_solve, PP_PRIOR_REL)
        self.n = 8 if free_pp else 6

    def camera(self, x: np.ndarray) -> Camera:
        import cv2

        R = cv2.Rodrigues(np.asarray(x[:3], float).reshape(3, 1))[0] @ self.cam0.R
        C = np.array([self.C0[0] + x[3], self.C0[1], self.C0[2] + x[4]])
        K = self.cam0.K.copy()
        K[0, 0], K[1, 1] = self.cam0.K[0, 0] * np.exp(x[5]), self.cam0.K[1, 1] * np.exp(x[5])
        if self.free_pp:
            K[0, 2], K[1, 2] = self.cam0.K[0, 2] + x[6], self.cam0.K[1, 2] + x[7]
        return dataclasses.replace(self.cam0, K=K, R=R, t=-R @ C)


def _project(cam: Camera, S: _Samples) -> tuple[np.ndarray, np.ndarray]:
    """Projected samples (N,2) and the unit normals (N,2) of their projected edges."""
    uv, _ = cam.project(S.X)
    uv2, _ = cam.project(S.X + 0.01 * S.D)
    d = uv2 - uv
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
    return uv, np.stack([-d[:, 1], d[:, 0]], 1)


def _edge_weights(S: _Samples, sig_e, edge_var=None, weighting: str = "capped") -> np.ndarray:
    """(N,) weight of each sample's squared normalised residual. "capped" (the fit's): min(1,
    EDGE_WEIGHT_SAMPLES / n_e), n_e the samples of its edge: an edge weighs at most that many samples.
    "model" (the model selection's, the per-edge model-error term): sig^2 / (sig^2 + n_e V_e), sig the
    sample's own noise (px), V_e (px^2, default EDGE_MODEL_SIGMA_PX^2) the error the edge's samples share
    (the room model's, plus a measured line's noise): summed over an edge's samples, a common offset d of
    the edge costs d^2 / (sig^2 / n_e + V_e), the generalised least squares of samples sharing an error."""
    _, inv, counts = np.unique(S.edge, return_inverse=True, return_counts=True)
    if weighting == "capped":
        return np.minimum(1.0, EDGE_WEIGHT_SAMPLES / counts[inv])
    if weighting != "model":
        raise ValueError(f"weighting: expected 'capped' or 'model', got {weighting!r}")
    sig2 = np.broadcast_to(np.asarray(sig_e, float), (len(S.X),)) ** 2
    V = EDGE_MODEL_SIGMA_PX ** 2 if edge_var is None else np.asarray(edge_var, float)
    return sig2 / (sig2 + counts[inv] * V)


def _solve(model: _Model, x0: np.ndarray, S: _Samples, q: np.ndarray, sig_e, lines, f_scale: float, edge_var=None,
           weighting: str = "capped"):
    """Least squares of the edge residuals n.(q - uv)/sig_e (sig_e: px, one figure or one per sample;
    robust: Cauchy at f_scale, whose pull of a wrong match falls as 1/r, so texture matched at a wide
    radius hardly moves a camera that already fits; soft-L1's pull stays constant and let such matches
    drag a true camera by 6 % of focal) and of the clicked lines' residuals (calibrate's, normalised by
    their noise; not robust: calibrate kept only the segments its own fit agreed with), and, with
    model.pp_prior and a free principal point, calibrate's prior on it (the image centre, PP_PRIOR_REL
    of the larger side, 1 sigma). Samples along one edge share its error (_edge_weights): "capped" scales
    each sample's residual by the root of its weight (each edge weighs at most EDGE_WEIGHT_SAMPLES
    independent samples); "model" (edge_var px^2 per sample) weights each sample's loss instead, so the
    robust loss still judges each sample against its own noise while an edge weighs what its shared error
    allows; the result then carries `edge_weight` (those weights) for the conditioning."""
    from scipy.optimize import least_squares

    a_e = _edge_weights(S, sig_e, edge_var, weighting)
    w = (np.sqrt(a_e) if weighting == "capped" else 1.0) / np.asarray(sig_e, float)
    if weighting == "capped":
        a_e = np.ones(len(S.X))
    ne = len(S.X)
    pp0 = np.array([(model.cam0.width - 1) / 2.0, (model.cam0.height - 1) / 2.0])
    pp_sig = PP_PRIOR_REL * max(model.cam0.width, model.cam0.height)

    def fun(x):
        cam = model.camera(x)
        uv, n = _project(cam, S)
        r = [np.sum(n * (q - uv), axis=1) * w]
        r += _line_residuals(cam, lines)
        if model.free_pp and model.pp_prior:  # calibrate's prior: the principal point near the image centre
            r.append((cam.K[:2, 2] - pp0) / pp_sig)
        return np.concatenate(r)

    def loss(z):  # weighted Cauchy on the edge samples, squares on the clicked lines (z = (r / f_scale)^2)
        out = np.empty((3, len(z)))
        t = 1.0 + z[:ne]
        out[0, :ne], out[1, :ne], out[2, :ne] = a_e * np.log1p(z[:ne]), a_e / t, -a_e / t ** 2
        out[0, ne:], out[1, ne:], out[2, ne:] = z[ne:], 1.0, 0.0
        return out

    x_scale = [1e-3, 1e-3, 1e-3, 0.01, 0.01, 1e-3, 1.0, 1.0][:len(x0)]  # rad, m, log f, px (principal point)
    res = least_squares(fun, x0, loss=loss, f_scale=f_scale, x_scale=x_scale, method="trf", max_nfev=50)
    res.edge_weight = a_e if weighting == "model" else None
    return res


def _edge_chamfer(cam: Camera, S: _Samples, photo: PhotoEdges) -> float:
    """The edge residual of a camera on the samples S: mean distance of their projections from the
    nearest oriented photo edge, capped at CHAMFER_CAP_PX (a sample out of the image counts the cap)."""
    if len(S.X) == 0:
        return float("inf")
    uv, n = _project(cam, S)
    d = np.full(len(uv), CHAMFER_CAP_PX)
    inside = np.all(uv >= 0, axis=1) & (uv[:, 0] <= cam.width - 1) & (uv[:, 1] <= cam.height - 1)
    d[inside] = photo.distance(uv[inside], np.arctan2(n[inside, 1], n[inside, 0]))
    return float(np.mean(np.minimum(d, CHAMFER_CAP_PX)))


def _centre_search(cam: Camera, S: _Samples, photo: PhotoEdges, log_focal: float = 0.0) -> list[tuple[float, np.ndarray]]:
    """(grid cost, starting point [0, 0, 0, dx, dz, log_focal] (_Model's parameters)) of the fit: the best local minima of
    the capped edge residual over a grid of camera centres about the input one, rotation, focal length
    and height held.

    Why: the clicked vanishing lines fix the rotation and the focal length, not where in the room the
    camera stands; a centre a few tens of cm off shifts the room's image by tens of px, where the ICP's
    wide first match radius can lock onto other strong edges (a sunlit patch's border, the floor's
    texture) and end in a wrong basin. The grid spans the centres that move an edge at the samples'
    median depth by up to the widest match radius (COARSE_RADII_PX[0]), in steps that move it
    CENTRE_STEP_PX; the residual is capped at 2 steps so a grid point half a step from an edge still
    counts it matched. The samples are the input camera's (the visible set changes little over the grid).
    log_focal: the grid's cameras have the focal length exp(log_focal) x the input's (_widened_search)."""
    if len(S.X) == 0:
        return []
    f = float(cam.K[0, 0]) * float(np.exp(log_focal))
    _, z = cam.project(S.X)
    zmed = float(np.median(z))
    half, step = COARSE_RADII_PX[0] * zmed / f, CENTRE_STEP_PX * zmed / f
    k = int(np.floor(half / step))
    offs = np.arange(-k, k + 1) * step
    dx, dz = np.meshgrid(offs, offs, indexing="ij")
    dC = np.stack([dx.ravel(), np.zeros(dx.size), dz.ravel()], 1)  # (G,3) world offsets of the centre
    cap = 2.0 * CENTRE_STEP_PX
    RX, RD = S.X @ cam.R.T, S.D @ cam.R.T
    K = cam.K.copy()
    K[0, 0], K[1, 1] = K[0, 0] * np.exp(log_focal), K[1, 1] * np.exp(log_focal)
    cost = np.empty(len(dC))
    dist = np.stack([d for d, _ in photo.near])  # (bins, H, W)
    H, W = photo.shape
    for i0 in range(0, len(dC), 64):
        Xc = RX[None] + cam.t[None, None] - (dC[i0:i0 + 64] @ cam.R.T)[:, None]  # (g,N,3) camera coordinates
        zc = Xc[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = (Xc @ K.T)[..., :2] / zc[..., None]
            uv2 = ((Xc + 0.01 * RD[None]) @ K.T)[..., :2] / (zc + 0.01 * RD[None, :, 2])[..., None]
        d = uv2 - uv
        ang = np.mod(np.arctan2(d[..., 0], -d[..., 1]), np.pi)  # the normal (-dv, du)'s angle
        b = np.minimum((ang / (np.pi / ORIENT_BINS)).astype(int), ORIENT_BINS - 1)
        iu = np.rint(np.nan_to_num(uv, nan=-1.0, posinf=-1.0, neginf=-1.0)).astype(np.int64)
        inside = (zc > 0.05) & (iu[..., 0] >= 0) & (iu[..., 0] < W) & (iu[..., 1] >= 0) & (iu[..., 1] < H)
        dd = np.full(zc.shape, cap)
        dd[inside] = np.minimum(dist[b[inside], iu[..., 1][inside], iu[..., 0][inside]], cap)
        cost[i0:i0 + 64] = dd.mean(axis=1)
    C = cost.reshape(dx.shape)
    pad = np.pad(C, 1, constant_values=np.inf)
    nb = np.stack([pad[1 + i:1 + i + C.shape[0], 1 + j:1 + j + C.shape[1]] for i in (-1, 0, 1) for j in (-1, 0, 1)
                   if i or j])
    minima = np.flatnonzero((C <= nb.min(axis=0)).ravel())
    best = minima[np.argsort(cost[minima])][:CENTRE_HYPOTHESES]
    # pad for a free principal point
    return [(float(cost[i]), np.array([0.0, 0.0, 0.0, dC[i, 0], dC[i, 2], log_focal])) for i in best]


@dataclass
class _Fit:
    """One candidate camera: parameters x, its last least-squares result (None: no stage ran), the
    samples of that stage, which of them it used and their residuals (px), and the stage's noise (px)."""
    x: np.ndarray
    res: object
    S: _Samples
    used: np.ndarray
    resid: np.ndarray
    sigma: np.ndarray  # (used,) noise of each used sample, px
    start: str = "input"
    data: tuple | None = None  # the last solve's data (samples, matched edge points, sigma, edge_var): campp.select
    sun_info: list | None = None  # _sun_stage: the outline's and the openings' measured edges (sunoutline)


def _fit(model: _Model, x: np.ndarray, radii, edges, occ, photo: PhotoEdges, lines,
         fine_stage: str = "profiles") -> _Fit:
    """ICP on the oriented Canny edges over the match radii `radii`, then the sub-pixel stage, from
    parameters x: the sub-pixel stage's fit (res None when it did not run)."""
    S = _sample_edges(model.camera(x), edges, occ)
    res = None
    for i, radius in enumerate(radii):
        if i == 2:  # the camera may have moved by tens of px: the visible samples again
            S = _sample_edges(model.camera(x), edges, occ)
        if len(S.X) < MIN_SAMPLES:
            break
        uv, n = _project(model.camera(x), S)
        q, ok = photo.match(uv, np.arctan2(n[:, 1], n[:, 0]), radius)
        ok &= _exclusive(uv, n, S.edge, q)
        if ok.sum() < MIN_SAMPLES:
            break
        sub = _Samples(S.X[ok], S.D[ok], S.edge[ok])
        res = _solve(model, x, sub, q[ok], COARSE_SIGMA_PX, lines, f_scale=ROBUST_SIGMAS)
        x = res.x
    fine = _line_stage(model, x, edges, occ, photo, lines) if fine_stage == "lines" else \
        _profile_stage(model, x, edges, occ, photo, lines)
    if fine is not None:
        return fine
    # no sub-pixel stage: res None (the guard reports too few edges, as for any fit that found too few)
    S = _sample_edges(model.camera(x), edges, occ)
    return _Fit(x, None, S, np.zeros(len(S.X), bool), np.zeros(0), np.zeros(0))


def _profile_stage(model: _Model, x: np.ndarray, edges, occ, photo: PhotoEdges, lines) -> _Fit | None:
    """The per-sample sub-pixel stage (edgesnap's centroid at every sample), three rounds."""
    S = _sample_edges(model.camera(x), edges, occ)
    fine = None
    for _ in range(3):
        if len(S.X) < MIN_SAMPLES:
            break
        uv, n = _project(model.camera(x), S)
        q, ok, sig = _fine_edges(photo, uv, n, S.edge)
        if ok.sum() < MIN_SAMPLES:
            break
        sub = _Samples(S.X[ok], S.D[ok], S.edge[ok])
        sig_ok = sig if np.ndim(sig) == 0 else sig[ok]
        res = _solve(model, x, sub, q[ok], sig_ok, lines, f_scale=ROBUST_SIGMAS)
        x = res.x
        uv1, n1 = _project(model.camera(x), sub)
        fine = _Fit(x, res, S, ok, np.sum(n1 * (q[ok] - uv1), axis=1),
                    np.broadcast_to(np.asarray(sig_ok, float), (int(ok.sum()),)).copy(),
                    data=(sub, q[ok], sig_ok, None))
    return fine


def _fine_edges(photo: PhotoEdges, uv: np.ndarray, n: np.ndarray, edge: np.ndarray):
    """The fine stages' photo edge point of each projected sample (uv, unit normal n, room edge index), which
    to use, and its noise (px: FINE_SIGMA_PX, one figure, when every used sample has a sub-pixel edge; else
    one per sample): the sub-pixel edge (_subpixel) where there is one; and on a room edge none of whose
    samples has one, a sample that edgesnap refuses for a clipped pixel within its reach (a blown-out window's
    or lamp's border: clipping moves a centroid by up to 0.5 px) keeps its oriented Canny match within the
    coarse stage's last radius (COARSE_RADII_PX[-1], explaining its own room edge: _exclusive) at a Canny
    pixel's noise, COARSE_SIGMA_PX.

    Why: without it the fine stage never sees an edge whose every sample lies by a clipped pixel, and a room
    whose window is blown out is fitted on its few other edges alone: the fit slides off the window's edges
    (which the coarse stage had matched and the guard measures) and the guard refuses the camera (docs/unseen.md,
    guard106 and cam107). Only clipped samples: a Canny match in an unclipped sample without a profile is
    grain or texture (edgesnap refused it for a second peak, or no peak), which pulled noisy sunlit rooms'
    cameras off (cam107)."""
    q, ok = _subpixel(photo, uv, n, edge)
    if not getattr(photo, "clipped_edges", False):
        return q, ok, FINE_SIGMA_PX
    E = photo.fine
    iu = np.clip(np.rint(uv).astype(int), 0, [E.shape[1] - 1, E.shape[0] - 1])
    cand = ~ok & E.near_clip[iu[:, 1], iu[:, 0]] & ~np.isin(edge, np.unique(edge[ok]))
    if not cand.any():
        return q, ok, FINE_SIGMA_PX
    qc, okc = photo.match(uv, np.arctan2(n[:, 1], n[:, 0]), COARSE_RADII_PX[-1])
    add = cand & okc & _exclusive(uv, n, edge, qc)
    if not add.any():
        return q, ok, FINE_SIGMA_PX
    return np.where(add[:, None], qc, q), ok | add, np.where(add, COARSE_SIGMA_PX, FINE_SIGMA_PX)


def _subpixel(photo: PhotoEdges, uv: np.ndarray, n: np.ndarray, edge: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The profile stage's sub-pixel edge of each projected sample (uv, unit normal n, room edge index) and
    which to use: found by edgesnap's rule (photo.subpixel), explaining its own room edge (_exclusive), and not
    on an edge whose profile is a ramp (recon.photoedges.ramp_edge_mask; unless photo.ramp_edges is "keep")."""
    from recon.photoedges import ramp_edge_mask

    q, ok = photo.subpixel(uv, n)
    ok &= _exclusive(uv, n, edge, q)
    if getattr(photo, "ramp_edges", "drop") == "drop":
        ok &= ~ramp_edge_mask(photo.fine, q, n, edge, ok)
    return q, ok


def _line_stage(model: _Model, x: np.ndarray, edges, occ, photo: PhotoEdges, lines) -> _Fit | None:
    """The sub-pixel stage on whole edges (recon/edgelines.py), three rounds: each room edge's line is
    found near its projection (+-LINE_RADIUS_PX, significance against the photo's own noise); its
    samples are matched to the points of that line, each with the noise
    sqrt(FINE_SIGMA_PX^2 + n_eff sigma_line^2): the room model's own error per sample, as in the
    profile stage, plus the line's measured noise (sigma_line: its mean offset's, px) spread over the
    n_eff = min(samples, EDGE_WEIGHT_SAMPLES) samples the edge weighs in _solve, so a faint edge in
    grain weighs what its measurement is worth and a clean edge weighs as in the profile stage. The
    samples of an edge not found as a line keep edgesnap's per-sample rule (the profile stage's, at
    FINE_SIGMA_PX) where the sample's gradient peak stands out of its edge strip's measured noise
    (edgelines.significance_z over the profile's positions): a short or partly hidden edge still counts
    where its profiles are clean, not where they are grain."""
    from recon.edgelines import find_line, gradient_noise, significance_z

    S = _sample_edges(model.camera(x), edges, occ)
    fine = None
    E = photo.fine
    for _ in range(3):
        if len(S.X) < MIN_SAMPLES:
            break
        uv, n = _project(model.camera(x), S)
        q = np.full_like(uv, np.nan)
        sig = np.zeros(len(uv))
        noise = np.full(len(uv), np.inf)  # gradient noise of each sample's edge strip (inf: not measured)
        iu = np.clip(np.rint(uv).astype(int), 0, [E.shape[1] - 1, E.shape[0] - 1])
        clear = ~E.near_clip[iu[:, 1], iu[:, 0]]  # edgesnap's rule: clipping moves an edge by up to 0.5 px
        for e in np.unique(S.edge):
            m = np.flatnonzero((S.edge == e) & clear)
            if len(m) < 2:
                continue
            ne = n[m].mean(axis=0)
            ne /= np.linalg.norm(ne)
            along = uv[m] @ np.array([-ne[1], ne[0]])
            span = along.max() - along.min()
            if not span > 0:
                continue
            t = (along - along.min()) / span
            L = find_line(E, uv[m], ne, t, LINE_RADIUS_PX)
            if L is not None:
                q[m] = uv[m] + L.offset(t)[:, None] * ne
                sig[m] = L.sigma_px
            else:
                noise[m] = gradient_noise(E, uv[m], ne, LINE_RADIUS_PX)
        lined = np.all(np.isfinite(q), axis=1)
        if (~lined).any():  # edges not found as a line: edgesnap's per-sample rule, where its peak stands
            # out of the edge's own noise (Bonferroni over the profile's positions, 1 % false alarm)
            qp, okp = photo.subpixel(uv[~lined], n[~lined])
            nl = n[~lined]
            g = np.abs(E._sample(E.gx, qp[None])[0] * nl[:, 0] + E._sample(E.gy, qp[None])[0] * nl[:, 1])
            z1 = significance_z(int(round(2 * PROFILE_HALF_PX / PROFILE_STEP_PX)) + 1)
            okp &= g >= z1 * noise[~lined]
            q[~lined] = np.where(okp[:, None], qp, np.nan)
            sig[~lined] = 0.0
        ok = np.all(np.isfinite(q), axis=1)
        ok &= _exclusive(uv, n, S.edge, q)
        if ok.sum() < MIN_SAMPLES:
            break
        sub = _Samples(S.X[ok], S.D[ok], S.edge[ok])
        _, inv, counts = np.unique(sub.edge, return_inverse=True, return_counts=True)
        n_eff = np.minimum(counts[inv], EDGE_WEIGHT_SAMPLES)
        sigma = np.sqrt(FINE_SIGMA_PX ** 2 + n_eff * sig[ok] ** 2)
        res = _solve(model, x, sub, q[ok], sigma, lines, f_scale=ROBUST_SIGMAS)
        x = res.x
        uv1, n1 = _project(model.camera(x), sub)
        fine = _Fit(x, res, S, ok, np.sum(n1 * (q[ok] - uv1), axis=1), sigma,
                    data=(sub, q[ok], FINE_SIGMA_PX, EDGE_MODEL_SIGMA_PX ** 2 + sig[ok] ** 2))
    return fine


def _sun_stage(model: _Model, x: np.ndarray, edges, occ, photo: PhotoEdges, lines, sun) -> _Fit | None:
    """The profile stage with the sunlit patch's outline and the openings' own edges (recon/sunoutline.py,
    `sun` a SunEdges) fitted with the room's edges, three rounds from parameters x; None when no outline
    edge is measured or too few room edges are found. An outline edge's samples enter as a room edge's
    do (FINE_SIGMA_PX each, EDGE_WEIGHT_SAMPLES at most, robust) plus its measured noise spread over them,
    as the line stage does: sigma = sqrt(FINE_SIGMA_PX^2 + n_eff sigma_edge^2), sigma_edge the jackknife of
    the edge's mean offset, so an edge weighs what its measurement is worth. Their ids follow the room's
    edges (len(edges) + the outline's own id)."""
    S = _sample_edges(model.camera(x), edges, occ)
    fine = None
    for _ in range(3):
        if len(S.X) < MIN_SAMPLES:
            break
        cam = model.camera(x)
        uv, n = _project(cam, S)
        q, ok, sig_r = _fine_edges(photo, uv, n, S.edge)
        o = sun.measure(cam)
        if ok.sum() < MIN_SAMPLES or not len(o.X):
            break
        _, inv, counts = np.unique(o.edge, return_inverse=True, return_counts=True)
        n_eff = np.minimum(counts[inv], EDGE_WEIGHT_SAMPLES)
        sig = np.concatenate([np.broadcast_to(np.asarray(sig_r, float), ok.shape)[ok],
                              np.sqrt(FINE_SIGMA_PX ** 2 + n_eff * o.sigma_edge ** 2)])
        sub = _Samples(np.concatenate([S.X[ok], o.X]), np.concatenate([S.D[ok], o.D]),
                       np.concatenate([S.edge[ok], len(edges) + o.edge]))
        qq = np.concatenate([q[ok], o.q])
        res = _solve(model, x, sub, qq, sig, lines, f_scale=ROBUST_SIGMAS)
        x = res.x
        uv1, n1 = _project(model.camera(x), sub)
        resid = np.sum(n1 * (qq - uv1), axis=1)
        info = []
        for e, d in zip(np.unique(o.edge), o.info):  # o.info is in the order of its edge ids
            m = sub.edge == len(edges) + e
            info.append({**d, "resid_px": float(np.median(resid[m])),
                         "sigma_px": float(np.sqrt(d["jackknife_px"] ** 2 + FINE_SIGMA_PX ** 2
                                                   / min(int(m.sum()), EDGE_WEIGHT_SAMPLES)))})
        fine = _Fit(x, res, sub, np.ones(len(sub.X), bool), resid, sig, data=None, sun_info=info)
    return fine


def _exclusive(uv: np.ndarray, n: np.ndarray, edge: np.ndarray, q: np.ndarray, k: int = 8) -> np.ndarray:
    """(N,) bool: the photo edge point q matched to each projected sample (uv, unit normal n, room
    edge index) is not nearer to another room edge of the same orientation (normals within one
    orientation bin), judged on the k projected samples nearest to q (8 at the 3 px sample step reach
    12 px along an edge, past the 2 px profile window and the last coarse radii): a photo edge explains one room
    edge (ICP's uniqueness rule), so two close parallel room edges (a wardrobe's silhouette and its
    corner beside it) cannot both lock onto the stronger of their photo edges."""
    from scipy.spatial import cKDTree

    keep = np.ones(len(uv), bool)
    fin = np.all(np.isfinite(q), axis=1) & np.all(np.isfinite(uv), axis=1)
    if fin.sum() < 2:
        return keep
    idx = np.flatnonzero(fin)
    tree = cKDTree(uv[idx])
    _, nb = tree.query(q[idx], k=min(k, len(idx)))
    nb = idx[nb.reshape(len(idx), -1)]
    own = np.abs(np.sum(n[idx] * (q[idx] - uv[idx]), axis=1))
    other = np.abs(np.sum(n[nb] * (q[idx][:, None] - uv[nb]), axis=2))
    parallel = np.abs(np.sum(n[nb] * n[idx][:, None], axis=2)) >= np.cos(np.pi / ORIENT_BINS)
    keep[idx] = ~np.any((edge[nb] != edge[idx][:, None]) & parallel & (other < own[:, None]), axis=1)
    return keep


def _union(*ss: _Samples) -> _Samples:
    return _Samples(np.concatenate([s.X for s in ss]), np.concatenate([s.D for s in ss]),
                    np.concatenate([s.edge for s in ss]))


PP_MODELS = ("select", "free", "held")  # a principal point from three vanishing points: chosen by the
# photo's edges (recon/campp.py), always refined, or held at the image centre


def refine_camera(cam: Camera, prims: list[dict], image: np.ndarray, camera_json: dict | None = None,
                  fine_stage: str = "profiles", principal_point: str = "select", sun: dict | None = None,
                  response: np.ndarray | None = None, ramp_edges: str = "drop",
                  focal_search: str = "moved", focal_from_lines: str = "retry",
                  recheck_samples: str = "measurable") -> Refinement:
    """Refine `cam` against the photo `image` (H,W,3 uint8, the camera's size) and the room `prims`
    (scene.json primitives, world metres), with calibrate's clicked lines from `camera_json`. See the
    module docstring; the input camera comes back (accepted False, with the reason) when the guard fails.
    fine_stage: "profiles" (per-sample sub-pixel edges, the default) or "lines" (each edge found as one
    line against the photo's own noise, recon/edgelines.py; a freed principal point then also gets
    calibrate's prior, PP_PRIOR_REL): see docs/unseen.md for where each does better.
    principal_point (used when calibrate took it from three vanishing points; else it is held as given):
    "select" (the default: fitted held at the image centre, freed only when the room's edges and the
    clicked lines fit significantly better so, recon/campp.select), "free" or "held" (at the image centre).
    sun: a scene.json sun entry ("direction_to_sun", "angular_diameter_deg") whose direction the flow knows,
    with response (the photo's inverse response (256,3), lighting.hdr's: the probe bracket's) and an opening
    quad in prims: the chosen fit is fitted again with the sunlit patch's outline and the openings' own edges
    (_sun_stage, recon/sunoutline.py) and that camera, when the guard accepts it, is the refinement's.
    ramp_edges: "drop" (the default) leaves out of the profile stage the room edges whose found profile is a ramp
    (recon/photoedges.ramp_edge_mask), "keep" keeps them (the rule before; for measurements).
    focal_search: when an accepted camera is searched again over the focal length (_focal_recheck): "moved"
    (the default: when its fit moved the focal length from calibrate's by more than calibrate's own sigma),
    "always", or "off" (the rule before; for measurements).
    focal_from_lines: when an accepted fit's room edges determine the focal length less than the clicked lines do
    (_focal_from_lines): "retry" (the default: search again with the blown-out edges' Canny matches, as after an
    edge-residual refusal, and take that camera when the guard accepts it and its edges do determine the focal
    length) or "off" (the rule before; for measurements).
    recheck_samples: which samples the focal recheck ranks its fits on (_focal_recheck): "measurable" (the default:
    those neither compared camera projects by a clipped pixel) or "all" (cam108's rule; for measurements)."""
    from recon import campp

    if fine_stage not in FINE_STAGES:
        raise ValueError(f"fine_stage: expected one of {FINE_STAGES}, got {fine_stage!r}")
    if principal_point not in PP_MODELS:
        raise ValueError(f"principal_point: expected one of {PP_MODELS}, got {principal_point!r}")
    if focal_search not in FOCAL_SEARCHES:
        raise ValueError(f"focal_search: expected one of {FOCAL_SEARCHES}, got {focal_search!r}")
    if recheck_samples not in RECHECK_SAMPLES:
        raise ValueError(f"recheck_samples: expected one of {RECHECK_SAMPLES}, got {recheck_samples!r}")
    if focal_from_lines not in ("retry", "off"):
        raise ValueError(f"focal_from_lines: expected 'retry' or 'off', got {focal_from_lines!r}")
    t0 = time.time()
    image = np.asarray(image)
    if image.shape[:2] != (cam.height, cam.width):
        raise ValueError(f"the photo is {image.shape[1]}x{image.shape[0]}, the camera {cam.width}x{cam.height}")
    faces = room_faces(prims)
    edges = room_edges(faces)
    occ = _Occluder(faces)
    photo = PhotoEdges(image, ramp_edges=ramp_edges)
    lines = clicked_lines(camera_json)
    sun_edges = _sun_edges(sun, response, prims, occ, image)
    # calibrate's principal point from three vanishing points is weak (the orthocentre of their
    # triangle moves far with a distant vanishing point): it is held at the image centre or refined
    # (principal_point); the image centre (calibrate's default) or a given one is held
    pp3 = (camera_json or {}).get("principal_point_from") == "three vanishing points"

    def attempt(photo: PhotoEdges):
        """The search (and the principal point's model, and the sun's edges) on `photo`'s edges, and the guard:
        (best fit, its model, the principal point's note, the refined camera, the guard's Refinement)."""
        stage = {"edges": edges, "occ": occ, "photo": photo, "lines": lines, "fine_stage": fine_stage}
        note = "refined (calibrate's, from three vanishing points)" if pp3 else ""
        if pp3 and principal_point != "free":
            held = _Model(campp.at_image_centre(cam), free_pp=False)
            best, model = _search(held, **stage), held
            note = "held at the image centre"
            if best is not None and principal_point == "select":
                free = _Model(held.cam0, free_pp=True, pp_prior=fine_stage == "lines")
                fine = _line_stage if fine_stage == "lines" else _profile_stage

                def solve(m, x0, data):
                    sub, q, sig, edge_var = data
                    return _solve(m, x0, sub, q, sig, lines, f_scale=ROBUST_SIGMAS, edge_var=edge_var,
                                  weighting="model")

                best, model, note = campp.select(held, free, best, solve,
                                                 lambda m, x: fine(m, x, edges, occ, photo, lines))
        else:
            model = _Model(cam, free_pp=pp3, pp_prior=fine_stage == "lines")
            best = _search(model, **stage)
        # the fit with the sun's edges when the guard accepts it, else the fit on the room's edges alone
        with_sun = None if best is None else _sun_refit(cam, model, best, edges, occ, photo, lines, sun_edges, t0)
        if with_sun is not None:
            best, r = with_sun
            refined = model.camera(best.x)
        else:
            if best is None:
                S0 = _sample_edges(cam, edges, occ)
                best, refined = _Fit(np.zeros(model.n), None, S0, np.zeros(len(S0.X), bool), np.zeros(0),
                                     np.zeros(0)), cam
            else:
                refined = model.camera(best.x)
            r = _guard(cam, refined, best, lines, edges, occ, photo, time.time() - t0)
        return best, model, note, refined, r

    best, model, note, refined, r = attempt(photo)
    if (not r.accepted and not r.fits and r.reason.startswith(EDGE_RESIDUAL_REFUSAL) and fine_stage == "profiles"
            and best.res is not None):
        # the fine stage's objective and the guard disagree: the guard measures every room edge the camera sees
        # against the photo's Canny edges, the profile stage only those with a sub-pixel profile; an edge whose
        # every sample lies by a clipped pixel (a blown-out window) is one it never sees, and the fit slides off
        # it. Search again with such edges' Canny matches in the fine stages (_fine_edges); its camera is taken
        # when the guard accepts it and, as the widened search's, it brings the room's edges closer to the
        # photo's by more than the room model's own error of an edge's image (EDGE_MODEL_SIGMA_PX, _edge_gain):
        # in a grainy sunlit room (2 x 24 spp) the true camera's second attempt walked 4 px off for 0.02 px
        clipped = _with_clipped_edges(photo)
        alt = attempt(clipped)
        if alt[4].accepted:
            common = _union(_sample_edges(cam, edges, occ), alt[0].S)
            if _edge_gain(cam, alt[3], common, photo) > EDGE_MODEL_SIGMA_PX:
                best, model, note, refined, r = alt
                photo = clipped
    if (focal_from_lines == "retry" and r.accepted and fine_stage == "profiles"
            and not getattr(photo, "clipped_edges", False) and _focal_from_lines(cam, best)):
        # the room's edges the fit found say less about the focal length than the clicked lines do, so the
        # accepted focal length is the clicked lines' (a few per cent off with short clicked verticals) moved by
        # whatever the edges' own model errors pull: window_108 (three room edges, a painted skirting beside two
        # of them, +0.2..+0.6 px at the truth) went +3.46 -> +5.09 %. The room's other edges are then blown-out
        # windows the profile stage never sees: search again with their Canny matches (_fine_edges, as 3b), and
        # take that camera when the guard accepts it and its edges do determine the focal length
        clipped = _with_clipped_edges(photo)
        alt = attempt(clipped)
        ratio = _focal_sigma_ratio(cam, alt[0])
        if alt[4].accepted and ratio is not None and ratio <= FOCAL_FROM_LINES_RATIO:
            best, model, note, refined, r = alt
            photo = clipped
    sigma_f = cam.focal_rel_sigma
    chi2_lines, chi2_lim = _lines_chi2(refined, lines)
    widened = not r.accepted and not r.fits and _usable_sigma(sigma_f) and chi2_lines > chi2_lim
    if widened:
        # the first search's camera fits the room's edges somewhere the clicked lines refuse (a wrong
        # basin, not a room model the photo disagrees with: that fails the edge residual or the
        # conditioning, and a second search would only find another camera the model fits as badly):
        # search again with the focal length moved by its own calibration sigma (_widened_search); the
        # best of those the guard accepts, by _edge_gain
        wide = _widened_search(model, edges, occ, photo, lines, fine_stage, float(sigma_f))
        ok = [(f, g) for f in wide
              for g in [_guard(cam, model.camera(f.x), f, lines, edges, occ, photo, time.time() - t0)] if g.accepted]
        if ok:
            # a camera from beyond calibrate's own estimate must bring the room's edges closer to the
            # photo's by more than the room model's own error of an edge's image (EDGE_MODEL_SIGMA_PX),
            # else its gain may be that error: a reconstructed room whose guessed walls sit 0.3 m off
            # offered a camera 12 px away for 0.11 px of residual
            common = _union(_sample_edges(cam, edges, occ), *[f.S for f, _ in ok])
            gains = [_edge_gain(cam, g.camera, common, photo) for _, g in ok]
            i = int(np.argmax(gains))
            if gains[i] > EDGE_MODEL_SIGMA_PX:
                best, r = ok[i]
                # the outline from the chosen camera, when the guard accepts it
                best, r = _sun_refit(cam, model, best, edges, occ, photo, lines, sun_edges, t0) or (best, r)
                r = dataclasses.replace(r, seconds=float(time.time() - t0))
    if r.accepted and not widened and _focal_recheck_due(cam, r.camera, focal_search):
        # the first search held calibrate's focal length in its grid and its fit left it by more than calibrate's
        # own sigma: it may have stopped in a basin where an edge sits beyond the profile's reach and costs the fit
        # nothing (window_107: -0.90 % of focal, the truth's basin 25 % cheaper by the fit's own objective).
        # Search over the focal length as the widened search does, and keep the camera with the lowest completed
        # objective (_fit_cost) among those the guard accepts
        alt = _focal_recheck(cam, model, best, edges, occ, photo, lines, float(sigma_f), fine_stage, t0,
                             recheck_samples)
        if alt is not None:
            best, r = alt
            best, r = _sun_refit(cam, model, best, edges, occ, photo, lines, sun_edges, t0) or (best, r)
            r = dataclasses.replace(r, seconds=float(time.time() - t0))
    without, ids = None, None
    if best.res is not None and best.data is not None and best.data[3] is None:  # the profile stage's fit
        sub, q, sig, _ = best.data
        ids = np.unique(sub.edge)
        x_end = best.x

        def without(e: int) -> Camera:
            keep = sub.edge != e
            res = _solve(model, x_end, _Samples(sub.X[keep], sub.D[keep], sub.edge[keep]), q[keep],
                         sig if np.ndim(sig) == 0 else sig[keep], lines,
                         f_scale=ROBUST_SIGMAS)
            return model.camera(res.x)
    return dataclasses.replace(r, principal_point=note, x=best.x, covariance=camera_covariance(best.res),
                               camera_at=model.camera, without_edge=without, edge_ids=ids,
                               sun_edges=[{k: (round(v, 4) if isinstance(v, float) else v) for k, v in e.items()}
                                          for e in best.sun_info] if best.sun_info is not None else None)


FOCAL_SEARCHES = ("moved", "always", "off")  # refine_camera's focal_search
RECHECK_SAMPLES = ("measurable", "all")  # refine_camera's recheck_samples


def _focal_recheck_due(cam: Camera, refined: Camera, mode: str) -> bool:
    """Whether an accepted camera is searched again over the focal length (refine_camera's focal_search):
    "always"; "moved": the fit's focal length left calibrate's (cam) by more than calibrate's own sigma
    (cam.focal_rel_sigma; never without one); "off": never."""
    sigma_f = cam.focal_rel_sigma
    if mode == "off" or not _usable_sigma(sigma_f):
        return False
    return mode == "always" or abs(float(np.log(refined.K[0, 0] / cam.K[0, 0]))) > float(np.log1p(sigma_f))


def _with_clipped_edges(photo: PhotoEdges) -> PhotoEdges:
    """A copy of `photo` whose wholly clipped room edges the fine stages keep at their Canny matches (_fine_edges):
    the second attempt of steps 3b and 3c."""
    clipped = copy.copy(photo)
    clipped.clipped_edges = True
    return clipped


def _focal_sigma_ratio(cam: Camera, fit: _Fit) -> float | None:
    """The fit's own sigma of log f (camera_covariance of its last solve, the clicked lines included) over calibrate's
    (cam.focal_rel_sigma, also a sigma of log f); None without a usable calibrate sigma, a solve or a regular
    covariance."""
    sigma_f = cam.focal_rel_sigma
    if not _usable_sigma(sigma_f) or fit.res is None:
        return None
    cov = camera_covariance(fit.res)
    if cov is None or not np.isfinite(cov[5, 5]):
        return None
    return float(np.sqrt(max(float(cov[5, 5]), 0.0))) / float(sigma_f)


def _focal_from_lines(cam: Camera, fit: _Fit) -> bool:
    """Whether the room's edges of the profile-stage `fit` determine the focal length less than calibrate's clicked
    lines do: _focal_sigma_ratio above 1 / sqrt(2), i.e. the edges add less information on log f (1 / sigma^2)
    than the lines hold. False when the ratio is unknown or for a fit other than the profile stage's (a sun
    stage's: data None; a principal-point model selection's: edge_var set)."""
    if fit.data is None or fit.data[3] is not None:
        return False
    ratio = _focal_sigma_ratio(cam, fit)
    return ratio is not None and ratio > FOCAL_FROM_LINES_RATIO


def _usable_sigma(sigma_f: float | None) -> bool:
    """Whether calibrate gave a relative focal sigma the focal searches can step by (finite, > 0)."""
    return sigma_f is not None and bool(np.isfinite(sigma_f)) and sigma_f > 0


def _focal_recheck(cam: Camera, model: _Model, best: _Fit, edges, occ, photo: PhotoEdges, lines,
                   sigma_f: float, fine_stage: str, t0: float,
                   samples: str = "measurable") -> tuple[_Fit, Refinement] | None:
    """(fit, guard) of the widened search's fit (_widened_search: calibrate's focal length moved by -2..+2 of
    its sigma) that the guard accepts and whose completed objective (_fit_cost, on the room points the input
    camera or any of the fits sees) is lower than `best`'s; None when none is.

    Why: the fit's own cost counts only the samples with a sub-pixel edge, so a fit started at calibrate's
    focal length can stop where an edge lies beyond the profile's reach (window_107: two furniture edges 1.1
    and 1.3 px off either way, the fit at -0.90 % of focal, 3.3 cm), and the Canny distance (_edge_gain) ranks
    that camera above the truth's (0.137 against 0.130 px: Canny pixels are quantised to 1 px); the completed
    objective ranks the truth first (776 against 1051) and picks the widened search's fit from calibrate's
    +2 sigma (-0.24 %, 0.7 cm; 727).

    samples: "measurable" (the default) compares each fit with `best` on the common samples that neither camera
    projects by a clipped pixel (_measurable), and takes the fit with the largest drop when it is a drop; "all"
    (cam108's rule, for measurements) on every common sample. Why: a sample by a clipped pixel has no profile
    (edgesnap refuses it) at one camera and may find the clipped region's ramp at another; charging it the reach
    ranked sun_109's first fit (-0.78 %, 4.0 cm, 5.8 px at the object) about 3 below the widened search's fit in the
    truth's basin (-0.50 %, 1.2 cm, 0.53 px), carried by a blown-out window's edge (+21.8) and a box edge beside
    the sunlit patch (+21.6) that the truth's camera projects by clipped pixels; on the samples both measure (1282
    of 6960 dropped: two box edges by the patch, two window edges) that fit is 8.0 lower and is taken."""
    wide = _widened_search(model, edges, occ, photo, lines, fine_stage, sigma_f)
    ok = [(f, g) for f in wide
          for g in [_guard(cam, model.camera(f.x), f, lines, edges, occ, photo, time.time() - t0)] if g.accepted]
    if not ok:
        return None
    common = _union(_sample_edges(cam, edges, occ), _sample_edges(model.camera(best.x), edges, occ),
                    *[f.S for f, _ in ok])
    b = model.camera(best.x)
    if samples == "all":  # the rule before (cam108): every common sample, for measurements
        c0 = _fit_cost(b, common, photo, lines)
        drops = [_fit_cost(g.camera, common, photo, lines) - c0 for _, g in ok]
    else:
        drops, mb = [], _measurable(b, common, photo)
        for _, g in ok:
            m = mb & _measurable(g.camera, common, photo)
            both = _Samples(common.X[m], common.D[m], common.edge[m])
            drops.append(_fit_cost(g.camera, both, photo, lines) - _fit_cost(b, both, photo, lines))
    i = int(np.argmin(drops))
    return ok[i] if drops[i] < 0 else None


def _measurable(cam: Camera, S: _Samples, photo: PhotoEdges) -> np.ndarray:
    """Which samples S `cam` can measure a sub-pixel edge at: those it does not project by a clipped pixel
    (photo.fine.near_clip, where edgesnap refuses every profile; a sample out of the image is kept: _fit_cost
    charges it the profile's reach)."""
    uv, _ = _project(cam, S)
    E = photo.fine
    inside = np.all(uv >= 0, axis=1) & (uv[:, 0] <= cam.width - 1) & (uv[:, 1] <= cam.height - 1)
    iu = np.clip(np.rint(uv).astype(int), 0, [E.shape[1] - 1, E.shape[0] - 1])
    return ~(inside & E.near_clip[iu[:, 1], iu[:, 0]])


def _sun_edges(sun: dict | None, response, prims: list[dict], occ: _Occluder, image: np.ndarray):
    """recon.sunoutline.SunEdges of the openings in prims under `sun` (its direction and angular diameter),
    measured through `response`; None without a sun, a response or an opening quad."""
    if sun is None or response is None:
        return None
    quads = [np.asarray(p["corners"], float) for p in prims if p.get("type") == "quad" and p.get("opening") is True]
    if not quads:
        return None
    from recon.sunoutline import SunEdges

    return SunEdges(quads, np.asarray(sun["direction_to_sun"], float), float(sun.get("angular_diameter_deg", 0.53)),
                    occ, image, response)


def _sun_refit(cam: Camera, model: _Model, fit: _Fit, edges, occ, photo: PhotoEdges, lines, sun_edges,
               t0: float) -> tuple[_Fit, Refinement] | None:
    """(`fit` fitted again with the sun's edges (_with_sun), its guard) when there are sun edges, that stage
    runs and the guard accepts its camera; None otherwise (the caller keeps `fit`). t0: the refinement's
    start (time.time()), for the guard's seconds."""
    if sun_edges is None:
        return None
    sb = _with_sun(model, fit, edges, occ, photo, lines, sun_edges)
    if sb is fit:
        return None
    g = _guard(cam, model.camera(sb.x), sb, lines, edges, occ, photo, time.time() - t0)
    return (sb, g) if g.accepted else None


def _with_sun(model: _Model, best: _Fit, edges, occ, photo: PhotoEdges, lines, sun_edges) -> _Fit:
    """`best` fitted again with the sun's edges (_sun_stage) from its parameters; `best` itself when that
    stage does not run."""
    from scipy.stats import chi2

    f = _sun_stage(model, best.x, edges, occ, photo, lines, sun_edges)
    if f is None:
        return best
    # the sun's edges must agree with the camera they and the room's edges give: each edge's median residual
    # within its own noise and the room model's error of an edge's image (the outline is the taped opening
    # cast along the sun; a sun direction off by tenths of a degree moves it by pixels, and a camera pulled
    # to it leaves its edges apart): a chi-square at 99.9 %
    z2 = [e["resid_px"] ** 2 / (e["sigma_px"] ** 2 + EDGE_MODEL_SIGMA_PX ** 2) for e in f.sun_info]
    if not sum(z2) <= chi2.ppf(0.999, len(z2)):
        why = f"the sunlit outline disagrees with the room's edges (chi-square {sum(z2):.1f} > " \
              f"{chi2.ppf(0.999, len(z2)):.1f})"
        return dataclasses.replace(best, sun_info=[{**e, "refused": why} for e in f.sun_info])
    return dataclasses.replace(f, start=f"{best.start}, with the sunlit outline")


def _search(model: _Model, edges, occ, photo: PhotoEdges, lines, fine_stage: str) -> _Fit | None:
    """The best fit of `model` over its starts (None when no start's sub-pixel stage ran): the input
    camera (model.cam0) with the full coarse schedule, and the centre search's best minima."""
    cam = model.cam0
    S0 = _sample_edges(cam, edges, occ)
    # hypotheses: the input camera with the full coarse schedule, and the centre search's best minima,
    # whose grid leaves an edge at the median depth within CENTRE_STEP_PX / 2: their ICP starts at the
    # match radius of 4 grid steps (an edge at a quarter of the median depth)
    starts = [(np.zeros(model.n), COARSE_RADII_PX)]
    starts += [(np.pad(x0, (0, model.n - 6)), GRID_RADII_PX) for _, x0 in _centre_search(cam, S0, photo)]
    # each start's sub-pixel fit (a start whose sub-pixel stage did not run is dropped)
    fits = [dataclasses.replace(_fit(model, x0, radii, edges, occ, photo, lines, fine_stage), start="input" if i == 0
                                else "centre search") for i, (x0, radii) in enumerate(starts)]
    fits = [f for f in fits if f.res is not None]
    if not fits:
        return None
    # the input camera's own fit stands unless a centre-search start's fit brings the room's edges
    # closer to the photo's (_edge_gain), on the room points any of them (or the input) sees
    common = _union(S0, *[f.S for f in fits])
    best = fits[0]
    gains = [_edge_gain(model.camera(best.x), model.camera(f.x), common, photo) for f in fits[1:]]
    if any(g > 0 for g in gains):
        best = fits[1 + int(np.argmax(gains))]
    return best


def _widened_search(model: _Model, edges, occ, photo: PhotoEdges, lines, fine_stage: str,
                    focal_rel_sigma: float) -> list[_Fit]:
    """The fits from centre-search starts whose focal length is calibrate's moved by -2, -1, +1 and +2
    of its own sigma (each focal length's CENTRE_HYPOTHESES best grid minima: the grid's coarse cost
    does not rank the true basin first across focal lengths, so every one is fitted): refine_camera's
    second search, run only when the first one's camera fails the guard on the clicked lines (it costs up
    to 12 fits); its camera is taken only when it brings the room's edges closer by more than
    EDGE_MODEL_SIGMA_PX (refine_camera).

    Why: calibrate's focal length comes from the vanishing points alone, and with a distant one (nearly
    parallel clicked segments) its sigma is a few per cent (focal_rel_sigma in camera.json). A start
    1.5 % off in focal length and tens of cm off in place puts the room's edges ten or more px from the
    photo's, where the ICP locks onto other edges (a sunlit patch's border, floor texture): seen on a
    clean render of an unseen sun room, whose three fits all missed the clicked lines (chi-square 70-75
    against 32.9) while the true camera fits them as well as calibrate's (21.3) and the photo's edges
    better (0.75 against 0.97-1.03 px). The first search holds the focal length in its grid, so it
    cannot start near such a camera; moving the focal length by its own sigma can."""
    cam = model.cam0
    S0 = _sample_edges(cam, edges, occ)
    pool = []
    for k in (-2.0, -1.0, 1.0, 2.0):
        if 1.0 + k * focal_rel_sigma > 0.5:  # a focal length at least half the calibrated one
            pool += _centre_search(cam, S0, photo, float(np.log1p(k * focal_rel_sigma)))
    fits = [dataclasses.replace(_fit(model, np.pad(x0, (0, model.n - 6)), GRID_RADII_PX, edges, occ, photo, lines,
                                     fine_stage), start="focal search") for _, x0 in pool]
    return [f for f in fits if f.res is not None]


def _edge_distances(cam: Camera, S: _Samples, photo: PhotoEdges) -> np.ndarray:
    """Each sample's distance (px) from the nearest oriented photo edge, capped at CHAMFER_CAP_PX (a
    sample out of the image counts the cap)."""
    uv, n = _project(cam, S)
    d = np.full(len(uv), CHAMFER_CAP_PX)
    inside = np.all(uv >= 0, axis=1) & (uv[:, 0] <= cam.width - 1) & (uv[:, 1] <= cam.height - 1)
    d[inside] = photo.distance(uv[inside], np.arctan2(n[inside, 1], n[inside, 0]))
    return np.minimum(d, CHAMFER_CAP_PX)


def _edge_gain(a: Camera, b: Camera, S: _Samples, photo: PhotoEdges) -> float:
    """How much closer camera b brings the room's edges to the photo's edges than camera a (px): the
    mean over the room's edges of the drop of each edge's mean capped distance. The edges, not the
    samples, are the units: an edge's samples share its model error, and a mean over samples lets one
    long edge lying in texture (a floor edge running towards the camera, thousands of samples) outvote
    the rest."""
    da, db = _edge_distances(a, S, photo), _edge_distances(b, S, photo)
    es = np.unique(S.edge)
    if len(es) == 0:
        return 0.0
    return float(np.mean([np.mean(da[S.edge == e] - db[S.edge == e]) for e in es]))


FIT_COST_CHUNK = 16384  # samples per call of the profile measurement in _fit_cost


def _fit_cost(cam: Camera, S: _Samples, photo: PhotoEdges, lines) -> float:
    """The profile stage's own objective of camera `cam` on the samples S, completed so that cameras seeing
    different edges compare: each sample's robust cost (Cauchy at ROBUST_SIGMAS of its noise, an edge weighing
    at most EDGE_WEIGHT_SAMPLES samples, as _solve) of its offset from its sub-pixel edge (_fine_edges), a
    sample without one (none within +-PROFILE_HALF_PX, or out of the image) counted at that reach, plus the
    clicked lines' chi-square. Dimensionless (2 x least_squares' cost).

    Why: the fit's cost counts only the samples that found an edge, so a camera that has pushed an edge
    beyond the profile's reach pays nothing for it; ranking fits by their own cost so completed, not by the
    Canny distance (_edge_gain), takes the camera the fit itself prefers over the same room edges."""
    if len(S.X) == 0:
        return float("inf")
    uv, n = _project(cam, S)
    inside = np.all(uv >= 0, axis=1) & (uv[:, 0] <= cam.width - 1) & (uv[:, 1] <= cam.height - 1)
    r = np.full(len(uv), PROFILE_HALF_PX)
    sig = np.full(len(uv), FINE_SIGMA_PX)
    idx = np.flatnonzero(inside)
    for i0 in range(0, len(idx), FIT_COST_CHUNK):  # cv2.remap takes under 2^15 rows at a time (_exclusive
        # then judges a sample among its chunk's: the same as whole below FIT_COST_CHUNK samples)
        k = idx[i0:i0 + FIT_COST_CHUNK]
        q, ok, s = _fine_edges(photo, uv[k], n[k], S.edge[k])
        r[k] = np.minimum(np.where(ok, np.abs(np.sum(n[k] * (q - uv[k]), axis=1)), PROFILE_HALF_PX), PROFILE_HALF_PX)
        sig[k] = np.broadcast_to(np.asarray(s, float), ok.shape)
    a = _edge_weights(S, FINE_SIGMA_PX)
    z = (r / sig / ROBUST_SIGMAS) ** 2
    c = float(np.sum(a * ROBUST_SIGMAS ** 2 * np.log1p(z)))
    if lines[0]:
        zl = np.concatenate(_line_residuals(cam, lines))
        c += float(zl @ zl)
    return c


def _line_residuals(cam: Camera, lines, normalised: bool = True) -> list[np.ndarray]:
    """Per axis of the clicked lines (segs, sig), calibrate's residual of each segment under `cam`
    (recon.vanishing._seg_residual, px), normalised by its noise (x sqrt(2) / sigma) unless not: the fit's
    line terms (_solve), the guard's chi-square (_lines_chi2) and its rms."""
    from recon.vanishing import _seg_residual

    segs, sig = lines
    KR = cam.K @ cam.R
    out = [_seg_residual(segs[a], KR[:, AXIS[a]]) for a in segs]
    return [r * np.sqrt(2.0) / sig[a] for r, a in zip(out, segs)] if normalised else out


def _lines_chi2(cam: Camera, lines) -> tuple[float, float]:
    """Chi-square of the clicked lines' normalised residuals (calibrate's) under `cam`, and its 99.9 %
    point for that many segments (the guard's limit); (0, inf) without lines."""
    from scipy.stats import chi2

    if not lines[0]:
        return 0.0, float("inf")
    z = np.concatenate(_line_residuals(cam, lines))
    return float(z @ z), float(chi2.ppf(0.999, len(z)))


def _guard(cam, refined, fit: _Fit, lines, edges, occ, photo, seconds) -> Refinement:
    """Accept `refined` when: enough edge samples fit it and the fit is well-conditioned
    (_conditioning); it moves the room's edges by at least MIN_MOVE_PX (else the input already fits:
    `fits`); it agrees with the clicked lines within their noise; the edge residual (capped distance
    to the photo's oriented edges, on the room points either camera sees) drops; it lies in the room."""
    from recon.vanishing import rotation_error_deg

    res, S, used, resid = fit.res, fit.S, fit.used, fit.resid
    lr = np.concatenate(_line_residuals(refined, lines, normalised=False)) if lines[0] else np.zeros(0)
    inl = np.abs(resid) <= 3 * ROBUST_SIGMAS * fit.sigma  # beyond 3x the loss's scale: an outlier
    # the same room points for both cameras: those either camera sees
    S0, S1 = _sample_edges(cam, edges, occ), S
    both = _Samples(np.concatenate([S0.X, S1.X]), np.concatenate([S0.D, S1.D]), np.concatenate([S0.edge, S1.edge]))
    before, after = _edge_chamfer(cam, both, photo), _edge_chamfer(refined, both, photo)
    # how far the room's edges move: on the fit's room-edge samples (a sun fit's S also holds the sunlit outline's
    # and the openings' samples, ids from len(edges) on: the outline on the floor near the camera moves most for a
    # small camera change, and counted in it turned a room fit within the room model's own edge offsets into an
    # accepted move: sun_107's true camera, 0.45 px on the room's edges, 1.35 px with the outline)
    room = S.edge < len(edges)
    Sr = _Samples(S.X[room], S.D[room], S.edge[room])
    u0, _ = _project(cam, Sr)
    u1, _ = _project(refined, Sr)
    out = dict(moved_px=float(np.sqrt(np.mean(np.sum((u1 - u0) ** 2, axis=1)))) if room.any() else 0.0,
               n_edge_samples=int(inl.sum()), rms_edge_px=float(np.sqrt(np.mean(resid[inl] ** 2))) if inl.any()
               else float("nan"), n_lines=int(len(lr)), rms_lines_px=float(np.sqrt(np.mean(lr ** 2))) if len(lr)
               else float("nan"), focal_change=float(refined.K[0, 0] / cam.K[0, 0] - 1),
               principal_point_moved_px=float(np.linalg.norm(refined.K[:2, 2] - cam.K[:2, 2])), start=fit.start,
               centre_moved_m=float(np.linalg.norm(refined.centre - cam.centre)),
               rotation_deg=rotation_error_deg(refined.R, cam.R), chamfer_before_px=before, chamfer_after_px=after,
               seconds=float(seconds))
    reason = ""
    if res is None or inl.sum() < MIN_SAMPLES:
        reason = (f"too few of the room's edges found in the photo ({int(inl.sum())} samples, need {MIN_SAMPLES})")
    else:
        reason = _conditioning(res, S, used, inl, fit.sigma) or ""
    moved = out["moved_px"]
    if not reason and moved < MIN_MOVE_PX:
        return Refinement(cam, False, f"the camera already fits the room's edges (refining moves them {moved:.2f} px "
                          f"rms < {MIN_MOVE_PX:g} px, within the room model's own edge offsets)", True, **out)
    if not reason and len(lr):
        # the refined camera must agree with the clicked lines within their noise (_lines_chi2)
        c2, lim = _lines_chi2(refined, lines)
        if not c2 <= lim:
            reason = f"the refined camera disagrees with the clicked lines (chi-square {c2:.1f} > {lim:.1f})"
    if not reason and not after <= before:
        reason = f"{EDGE_RESIDUAL_REFUSAL} ({before:.2f} -> {after:.2f} px)"
    lo, hi = edges.reshape(-1, 3).min(0), edges.reshape(-1, 3).max(0)
    if not reason and not (np.all(refined.centre >= lo - 1e-3) and np.all(refined.centre <= hi + 1e-3)):
        reason = "the refined camera lies outside the room"
    if reason:
        return Refinement(cam, False, reason, False, **out)
    return Refinement(refined, True, "", False, **out)


def _conditioning(res, S: _Samples, used: np.ndarray, inl: np.ndarray, sigma: np.ndarray) -> str | None:
    """None when the fit pins every free parameter: the Jacobian has full rank, the inlier samples'
    projected edges span two directions, and a one-sigma error of the parameters (the covariance
    scaled by the residuals) moves the samples by at most MAX_PRED_STD_PX rms; else the reason."""
    J = res.jac
    ne = int(used.sum())
    Je = J[:ne][inl]
    try:
        s = np.linalg.svd(J, compute_uv=False)
        if not s[-1] > 1e-9 * s[0]:
            return "the room's edges do not determine the camera (rank-deficient fit)"
        cov = np.linalg.inv(J.T @ J)
    except np.linalg.LinAlgError:
        return "the room's edges do not determine the camera (singular fit)"
    r = np.array(res.fun, float)
    a = getattr(res, "edge_weight", None)  # the per-edge weights _solve's loss applies (res.jac has them)
    if a is not None:
        r[:len(a)] *= np.sqrt(a)
    dof = max(len(r) - len(res.x), 1)
    scale = max(float(r @ r) / dof, 1.0)
    pred = np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", Je, cov * scale, Je), 0.0)) * np.asarray(sigma)[inl]
    rms_pred = float(np.sqrt(np.mean(pred ** 2))) if len(pred) else float("inf")
    if not rms_pred <= MAX_PRED_STD_PX:
        return f"the fit is ill-conditioned (a one-sigma error moves the edges {rms_pred:.2f} px rms)"
    # directions of the inlier samples' edges in 3D (world axes): at least two far enough apart
    D = S.D[used][inl]
    if len(D):
        G = np.abs(D @ D.T)
        if np.min(G) > np.cos(np.radians(MIN_LINE_DIRECTIONS_DEG)):
            return "the room's edges found in the photo run in one direction only"
    return None


# ----------------------------------------------------------------------------------------------
# The refined camera's own uncertainty (bench/bench_camrefine.py)

def camera_covariance(res, n_camera: int | None = None) -> np.ndarray | None:
    """The covariance of the camera's parameters (_Model's x) from a least-squares result: the inverse of the
    Gauss-Newton Hessian (res.jac, the robust loss's weights included), marginal over any nuisance
    parameters after the first n_camera, scaled by the reduced robust chi-square (2 cost /
    dof: the loss's, so the outliers the loss discounts do not inflate it) when it exceeds 1 (the noise figures
    under-stated). It takes the fit's noise model as given: samples independent at their sigma, an edge
    capped at EDGE_WEIGHT_SAMPLES; edge_jackknife counts the edges' own errors. None when singular."""
    if res is None:
        return None
    J = res.jac.toarray() if hasattr(res.jac, "toarray") else np.asarray(res.jac)
    k = n_camera or getattr(res, "n_camera", None) or J.shape[1]
    try:
        cov = np.linalg.inv(J.T @ J)[:k, :k]
    except np.linalg.LinAlgError:
        return None
    scale = max(2.0 * float(res.cost) / max(len(res.fun) - J.shape[1], 1), 1.0)
    return cov * scale


def point_std_px(camera_at, x: np.ndarray, cov: np.ndarray, P: np.ndarray, h: float = 1e-6) -> float:
    """rms over the world points P (m) of the 1-sigma image uncertainty (px, sqrt of the trace of each
    point's 2x2 covariance) that the parameter covariance cov gives about x, camera_at(x) -> Camera
    (finite differences of step h in each parameter's own units)."""
    u0, _ = camera_at(x).project(P)
    J = np.empty((len(P), 2, len(x)))
    for j in range(len(x)):
        dx = np.zeros(len(x))
        dx[j] = h
        J[:, :, j] = (camera_at(x + dx).project(P)[0] - u0) / h
    var = np.einsum("nij,jk,nik->n", J, cov, J)
    return float(np.sqrt(np.mean(np.maximum(var, 0.0))))


def edge_jackknife(r: Refinement, P: np.ndarray) -> tuple[float, float, int]:
    """(std px, largest shift px, its edge): the jackknife over the room's edges of the refined camera's image of
    the world points P (m): the final fit solved again without each edge in turn (Refinement.without_edge);
    std is sqrt((E-1)/E sum_e |u_(-e) - u_mean|^2) (rms over P), which counts each edge's own error however it
    is shared by its samples (the edges, not the samples, are the independent units); the largest shift is the
    one edge's influence (rms over P of u_(-e) - u). nan when the fit has no such refit."""
    if r.without_edge is None or r.edge_ids is None or len(r.edge_ids) < 2 or r.camera_at is None:
        return float("nan"), float("nan"), -1
    u0, _ = r.camera_at(np.asarray(r.x, float)).project(P)
    U = np.stack([r.without_edge(int(e)).project(P)[0] for e in r.edge_ids])  # (E, V, 2)
    E = len(U)
    var = (E - 1) / E * np.sum(np.sum((U - U.mean(axis=0)) ** 2, axis=2), axis=0)
    shift = np.sqrt(np.mean(np.sum((U - u0) ** 2, axis=2), axis=1))
    k = int(np.argmax(shift))
    return float(np.sqrt(np.mean(var))), float(shift[k]), int(r.edge_ids[k])
