"""Receiver map: which receiver vertices each pixel interpolates, and the photo's light there.

Per scene, from the precompute's camera ID buffer (pix_tri, pix_bary, pix_depth) and transfers:
  pix_patch (H*W,) patch seen per pixel (-1 none); pix_rows (H*W,3) rows of its triangle's
  vertices among the receiver vertices (-1: not a receiver vertex); pix_pos (H*W,3) float32 m
  world point; recv_pix (H*W,) bool seen non-emitter surface with all three vertices known;
  L_b (H*W,3) the photo's radiance, L_b_levels its levels T(L_b); E_v (Vr,3) irradiance/pi at
  receiver vertices from the sources B_src, E_x (H*W,3) interpolated per receiver pixel;
  rho_x = min(L_b / E_x, 1) the reflectance the photo implies (0 where E_x is 0).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from app.stages.precompute import Precomputed
from recon.scene import Scene


@dataclass
class ReceiverMap:
    dirs: np.ndarray  # (H*W,3) unit camera rays
    L_b: np.ndarray  # (H*W,3) photo radiance
    L_b_levels: np.ndarray  # (H*W,3) T(L_b): the frame where nothing changes
    pix_patch: np.ndarray  # (H*W,) int
    pix_rows: np.ndarray  # (H*W,3) int
    pix_pos: np.ndarray  # (H*W,3) float32
    recv_pix: np.ndarray  # (H*W,) bool
    E_v: np.ndarray  # (Vr,3)
    E_x: np.ndarray  # (H*W,3)
    rho_x: np.ndarray | None = None  # (H*W,3) reflectance, once E_x and L_b are final (reflectance)


def receiver_map(scene: Scene, pre: Precomputed, B_src: np.ndarray) -> ReceiverMap:
    """The receiver map of `scene`'s camera from the precompute; B_src (P,3) the radiance the
    receivers gather (rho_x comes after any change to E_x or L_b: reflectance)."""
    pm, cam = pre.patches, scene.camera
    dirs = cam.pixel_rays().reshape(-1, 3)
    L_b = scene.response.to_radiance(scene.photo).reshape(-1, 3)
    L_b_levels = scene.response.to_levels(L_b)
    hit = pre.pix_tri >= 0
    pix_patch = np.where(hit, pm.tri_patch[np.maximum(pre.pix_tri, 0)], -1)
    vert_row = np.full(len(pm.vert_pos), -1, np.int64)
    vert_row[pre.recv_vert] = np.arange(len(pre.recv_vert))
    pix_rows = np.where(hit[:, None], vert_row[pm.tris[np.maximum(pre.pix_tri, 0)]], -1)
    pix_pos = (cam.centre + dirs * np.where(hit, pre.pix_depth, 0.0)[:, None]).astype(np.float32)
    recv_pix = hit & (pix_rows.min(1) >= 0) & ~pm.is_emitter[np.maximum(pix_patch, 0)]
    E_v = pre.G_v.astype(np.float64) @ B_src
    E_x = np.zeros_like(L_b)
    E_x[recv_pix] = np.einsum("nk,nkc->nc", pre.pix_bary[recv_pix], E_v[pix_rows[recv_pix]])
    return ReceiverMap(dirs, L_b, L_b_levels, pix_patch, pix_rows, pix_pos, recv_pix, E_v, E_x)


def reflectance(L_b: np.ndarray, E_x: np.ndarray) -> np.ndarray:
    """rho_x (H*W,3) = min(L_b / E_x, 1) where E_x > 0, else 0."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(E_x > 0, np.minimum(L_b / E_x, 1.0), 0.0)
