"""Whether the camera refinement frees the principal point: model selection on the photo's edges.

calibrate takes the principal point from three vanishing points when they move it significantly from
the image centre (recon/vanishing.calibrate_lines: a likelihood-ratio test on the clicked lines, chi-square
2 dof, 99.9 %). In a grainy photo its snapped segments are more confident than they are right, and the
orthocentre of a triangle with a distant vanishing point moves far: sun_103's lands 31 px off. Refined
against the room's edges, a free principal point trades against the rotation (a shift of the principal
point and a small rotation move far edges alike), and a few edges found a few px off in grain pull the
pair 13-20 px / 1.6-2.3 deg away (docs/unseen.md). So the refinement redoes calibrate's test on the room's
edges: the camera is fitted with the principal point held at the image centre (calibrate's default),
then, on exactly the same measured edges and clicked lines, with it free; it is freed only when the
fit's cost drops by more than the chi-square 99.9 % point for 2 parameters (13.8), calibrate's own rule.
The cost is the fit's own (recon/camrefine._solve): each edge sample against its noise, each edge
carrying the room model's shared error (camrefine.EDGE_MODEL_SIGMA_PX, per-edge model-error term), and
the clicked lines against theirs; so a photo where a couple of edges sit a few px off cannot buy a
principal point with them, and a camera whose principal point really is off (all edges agree) frees it.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from recon.camera import Camera

CHI2_2DOF_999 = 13.8155  # chi-square 99.9 % point, 2 dof (calibrate's test for freeing the principal point)


def at_image_centre(cam: Camera) -> Camera:
    """`cam` with its principal point moved to the image centre ((w-1)/2, (h-1)/2 px) and turned so
    that the direction it saw at its old principal point stays at that pixel: the start of a fit with
    the principal point held there (an exact match at that pixel, a small-angle one elsewhere)."""
    import cv2

    c0 = cam.K[:2, 2]
    c = np.array([(cam.width - 1) / 2.0, (cam.height - 1) / 2.0])
    v = np.array([(c0[0] - c[0]) / cam.K[0, 0], (c0[1] - c[1]) / cam.K[1, 1], 1.0])
    v /= np.linalg.norm(v)
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(z, v)
    s = np.linalg.norm(axis)
    Q = np.eye(3) if s < 1e-12 else cv2.Rodrigues(axis / s * np.arctan2(s, float(z @ v)))[0]
    K = cam.K.copy()
    K[0, 2], K[1, 2] = c
    R = Q @ cam.R
    return dataclasses.replace(cam, K=K, R=R, t=-R @ cam.centre)


def select(held, free, fit, solve, refit):
    """(fit, model, note): the held model's `fit` kept, or the free model's fit when freeing the
    principal point drops the fit's cost by more than CHI2_2DOF_999 on the held fit's own data (its
    last solve's edge samples, matched edge points, noise and shared edge error, and the clicked
    lines), both solved with the per-edge model error; then the free model's sub-pixel stage runs on
    from there. held, free: recon.camrefine._Model of the same input camera without and with the
    principal point; solve(model, x0, data): the least-squares result (camrefine._solve with the
    "model" edge weighting) on `data`; refit(model, x): the sub-pixel stage's fit from x (None: too
    few edges)."""
    held_res = solve(held, fit.x, fit.data)
    res = solve(free, np.concatenate([held_res.x, np.zeros(free.n - held.n)]), fit.data)
    drop = 2.0 * (float(held_res.cost) - float(res.cost))
    moved = float(np.linalg.norm(free.camera(res.x).K[:2, 2] - held.cam0.K[:2, 2]))
    if not drop > CHI2_2DOF_999:
        return fit, held, (f"held at the image centre (freeing it, {moved:.1f} px away, drops the fit's "
                           f"chi-square by {drop:.1f} <= {CHI2_2DOF_999:.1f})")
    out = refit(free, res.x)
    if out is None:
        return fit, held, f"held at the image centre (the free fit found too few edges; chi-square drop {drop:.1f})"
    return (dataclasses.replace(out, start=fit.start), free,
            f"freed (chi-square drop {drop:.1f} > {CHI2_2DOF_999:.1f})")
