"""Does the tape-measured probe pose agree with the images? (issue 16, "correct or loud")

Each probe pixel's reflected ray is followed into the room model; where it lands on a surface the
photo also sees, the probe's radiance there should match the photo's (both read through the
response recovered from the bracket; a constant factor between them is allowed). The agreement
is the correlation of log luminance over those pairs. The same is computed for the pose turned
180 degrees about +Y through the ball (the commonest tape mistake: the ball shot from the other
side); when the turned pose agrees clearly better, the given pose is wrong.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from recon.camera import Camera
from recon.response import LUMA



@dataclass
class PoseCheck:
    corr_given: float  # correlation of log luminance, probe vs photo, for the given pose
    corr_turned: float  # the same for the pose turned 180 deg about +Y
    n_given: int  # number of probe pixels compared
    n_turned: int

    @property
    def turned_fits_better(self) -> bool:
        """The turned pose explains the images clearly better (by 0.2 in correlation)."""
        return self.corr_turned > self.corr_given + 0.2


def _quad_list(prims: list[dict]) -> list[tuple[np.ndarray, np.ndarray]]:
    """(corners (4,3), unit normal) of every surface of scene.json primitives (boxes as 6 faces)."""
    from recon.scene import box_faces

    out = []
    for p in prims:
        if p.get("type") == "quad":
            c = np.asarray(p["corners"], float)
            out.append((c, np.asarray(p["normal"], float)))
        elif p.get("type") == "box":
            c, s = np.asarray(p["center"], float), np.asarray(p["size"], float)
            out += [(f[2], f[3]) for f in box_faces(c - s / 2, c + s / 2)]
    return out


def first_hit(quads: list[tuple[np.ndarray, np.ndarray]], origins: np.ndarray, dirs: np.ndarray
              ) -> np.ndarray:
    """Distance (N,) along each ray to the nearest quad (either side), inf where none."""
    best = np.full(len(origins), np.inf)
    for c, n in quads:
        e1, e3 = c[1] - c[0], c[3] - c[0]
        den = dirs @ n
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ((c[0] - origins) @ n) / den
        ok = (np.abs(den) > 1e-12) & (t > 1e-6) & (t < best)
        p = origins[ok] + t[ok, None] * dirs[ok] - c[0]
        a, b = p @ e1 / (e1 @ e1), p @ e3 / (e3 @ e3)
        inside = (a >= 0) & (a <= 1) & (b >= 0) & (b <= 1)
        idx = np.flatnonzero(ok)[inside]
        best[idx] = t[idx]
    return best


def _agreement(light_probe: dict, probe_lum: np.ndarray, photo: np.ndarray, g: np.ndarray, exposure_time: float,
               cam: Camera, quads) -> tuple[float, int]:
    """Correlation of log luminance between probe pixels and the photo pixels that see the same
    surface points, and the number of pairs; the photo (uint8) is linearised through g only at
    those pixels (a 12-megapixel photo is never converted whole)."""
    from lighting.radiance import probe_rays

    S = probe_lum.shape[0]
    origins, dirs, _, pixel = probe_rays(light_probe, S, sub=1)
    t = first_hit(quads, origins, dirs)
    hit = np.isfinite(t)
    P = origins[hit] + t[hit, None] * dirs[hit]
    pl = probe_lum.reshape(-1)[pixel[hit]]
    uv, z = cam.project(P)
    front = z > 1e-6
    ui, vi = (np.round(np.where(front[:, None], uv, -1)).astype(int)).T
    H, W = photo.shape[:2]
    inimg = front & (ui >= 0) & (ui < W) & (vi >= 0) & (vi < H)
    # visible from the camera: nothing nearer along the camera ray
    C = cam.centre
    idx = np.flatnonzero(inimg)
    d = P[idx] - C
    dist = np.linalg.norm(d, axis=1)
    tv = first_hit(quads, np.repeat(C[None], len(idx), 0), d / dist[:, None])
    vis = np.zeros(len(P), bool)
    vis[idx] = tv > dist - 1e-2
    z8 = photo[vi[vis], ui[vis]]  # (M,3) uint8
    ok = np.all((z8 > 8) & (z8 < 247), axis=1)  # neither clipped nor in the noise
    lum = (np.stack([g[z8[:, c], c] for c in range(3)], -1) / float(exposure_time)) @ LUMA
    sel = np.zeros(len(P), bool)
    sel[np.flatnonzero(vis)[ok]] = True
    photo_lum = np.zeros(len(P))
    photo_lum[vis] = lum
    sel &= pl > 0
    n = int(sel.sum())
    if n < 50:
        return float("nan"), n
    a, b = np.log(pl[sel]), np.log(photo_lum[sel])
    if a.std() < 1e-9 or b.std() < 1e-9:
        return float("nan"), n
    return float(np.corrcoef(a, b)[0, 1]), n


def check_probe_pose(light_probe: dict, shot_from, probe_images: list[np.ndarray], times: list[float],
                     photo: np.ndarray, exposure_time: float, cam: Camera, prims: list[dict],
                     merged: tuple[np.ndarray, np.ndarray] | None = None) -> PoseCheck:
    """Agreement of the probe bracket with the photo for the given pose and the pose turned 180 deg
    (module docstring). cam: the photo's camera; prims: scene.json primitives (recon.assemble);
    merged: the bracket's (radiance, inverse response) when already merged (lighting.hdr)."""
    from lighting.hdr import merge_bracket
    from recon.assemble import probe_camera

    rad, g = merge_bracket(probe_images, times) if merged is None else merged
    probe_lum = rad.astype(np.float64) @ LUMA
    quads = _quad_list(prims)
    c = np.asarray(light_probe["centre"], float)
    s = np.asarray(shot_from, float)
    turned = dict(light_probe)
    S = light_probe["camera"]["width"]
    turned["camera"] = probe_camera(c, light_probe["radius"], c + (s - c) * np.array([-1.0, 1.0, -1.0]), S, S)
    cg, ng = _agreement(light_probe, probe_lum, photo, g, exposure_time, cam, quads)
    ct, nt = _agreement(turned, probe_lum, photo, g, exposure_time, cam, quads)
    return PoseCheck(cg, ct, ng, nt)
