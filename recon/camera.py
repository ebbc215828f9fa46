"""Pinhole camera in the OpenCV convention (x right, y down, z forward).

x_cam = R @ x_world + t; pixel (u, v) = (fx x/z + cx, fy y/z + cy) with (0, 0) the CENTRE of
the top-left pixel. Units: metres, pixels.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Camera:
    K: np.ndarray  # (3,3) intrinsics, pixels
    R: np.ndarray  # (3,3) world -> camera rotation
    t: np.ndarray  # (3,) world -> camera translation, metres
    width: int
    height: int
    exposure_time: float = 1.0  # X = radiance * exposure_time enters the camera response

    @property
    def centre(self) -> np.ndarray:
        """Camera centre in world coordinates, (3,) metres."""
        return -self.R.T @ self.t

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World points (N,3) -> pixel coordinates (N,2) and depth z_cam (N,)."""
        xc = np.asarray(points, np.float64) @ self.R.T + self.t
        z = xc[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = (xc @ self.K.T)[:, :2] / z[:, None]
        return uv, z

    def pixel_rays(self, scale: int = 1) -> np.ndarray:
        """Unit world-space ray directions through pixel centres, (H*scale, W*scale, 3).

        With scale > 1 each pixel is split into scale x scale sub-pixels (sub-pixel centres).
        """
        h, w = self.height * scale, self.width * scale
        offs = (np.arange(scale) + 0.5) / scale - 0.5
        u = (np.arange(self.width)[:, None] + offs[None, :]).reshape(-1)
        v = (np.arange(self.height)[:, None] + offs[None, :]).reshape(-1)
        uu, vv = np.meshgrid(u, v)
        pix = np.stack([uu, vv, np.ones_like(uu)], axis=-1).reshape(-1, 3)
        d_cam = pix @ np.linalg.inv(self.K).T
        d = d_cam @ self.R  # R^T applied row-wise
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        return d.reshape(h, w, 3)
