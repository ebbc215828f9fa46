"""Pinhole camera in the OpenCV convention (x right, y down, z forward).

x_cam = R @ x_world + t; pixel (u, v) = (fx x/z + cx, fy y/z + cy) with (0, 0) the CENTRE of
the top-left pixel. Units: metres, pixels.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from recon.io import SceneError, json_array, json_field, read_json


@dataclass
class Camera:
    K: np.ndarray  # (3,3) intrinsics, pixels
    R: np.ndarray  # (3,3) world -> camera rotation
    t: np.ndarray  # (3,) world -> camera translation, metres
    width: int
    height: int
    exposure_time: float = 1.0  # X = radiance * exposure_time enters the camera response
    focal_rel_sigma: float | None = None  # std(f)/f of a calibration (camera.json), None = not given
    ill_conditioned: bool = False  # calibrate flagged the focal length as uncertain

    @classmethod
    def from_json(cls, d, path: str | os.PathLike, where: str = "") -> "Camera":
        """Camera from its JSON block; errors name `path` and the field (prefixed with `where`,
        e.g. "main_camera."), as SceneError.

        Accepted forms (all in the convention of this module):
          * scene.json's main_camera: {"K": {fx, fy, cx, cy, width, height}, "R", "t",
            "exposure_time" (optional, default 1)};
          * `photoar calibrate`'s camera.json: the same "K" object (and flat copies, ignored),
            with the optional uncertainty "focal_rel_sigma" (std(f)/f; null = undetermined) and
            "ill_conditioned" (bool);
          * `photoar reconstruct`'s cameras.json entries: "K" (or "K_matrix") a 3x3 matrix,
            with "width" and "height" beside it.
        R must be a rotation (orthonormal, det +1), t 3 finite numbers, focal lengths and image
        size positive."""
        if not isinstance(d, dict):
            raise SceneError(f"{path}: field '{where.rstrip('.') or 'camera'}' must be an object")
        k = d.get("K", d.get("K_matrix"))
        if isinstance(k, dict):
            fx, fy, cx, cy = (float(json_array(json_field(k, key, f"{where}K.", path), (), f"{where}K.{key}", path))
                              for key in ("fx", "fy", "cx", "cy"))
            K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
            size_from, size_where = (k, f"{where}K.") if "width" in k or "height" in k else (d, where)
        elif k is not None:
            key = "K" if "K" in d else "K_matrix"
            K = json_array(k, (3, 3), f"{where}{key}", path)
            if not np.allclose(K[2], [0.0, 0.0, 1.0]):
                raise SceneError(f"{path}: field '{where}{key}' must have last row [0, 0, 1]")
            size_from, size_where = d, where
        else:
            raise SceneError(f"{path}: missing field '{where}K'")
        size = []
        for key in ("width", "height"):
            v = json_field(size_from, key, size_where, path)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or v != int(v) or v <= 0:
                raise SceneError(f"{path}: field '{size_where}{key}' must be a positive whole number, got {v!r}")
            size.append(int(v))
        if not (K[0, 0] > 0 and K[1, 1] > 0):
            raise SceneError(f"{path}: field '{where}K' must have positive focal lengths, got fx={K[0, 0]}, "
                             f"fy={K[1, 1]}")
        R = json_array(json_field(d, "R", where, path), (3, 3), f"{where}R", path)
        if not np.allclose(R @ R.T, np.eye(3), atol=1e-5) or np.linalg.det(R) < 0:
            raise SceneError(f"{path}: field '{where}R' is not a rotation matrix")
        t = json_array(json_field(d, "t", where, path), (3,), f"{where}t", path)
        exposure = float(json_array(d.get("exposure_time", 1.0), (), f"{where}exposure_time", path))
        if not exposure > 0:
            raise SceneError(f"{path}: field '{where}exposure_time' must be positive")
        rel = d.get("focal_rel_sigma")
        rel = None if rel is None else float(json_array(rel, (), f"{where}focal_rel_sigma", path))
        ill = d.get("ill_conditioned", False)
        if not isinstance(ill, bool):
            raise SceneError(f"{path}: field '{where}ill_conditioned' must be true or false, got {ill!r}")
        return cls(K, R, t, size[0], size[1], exposure, rel, ill)

    @classmethod
    def load(cls, path: str | os.PathLike) -> "Camera":
        """Camera from a JSON file: `photoar calibrate`'s camera.json, or a scene.json (its
        main_camera), or {"camera": {...}}; see from_json."""
        path = Path(path)
        d = read_json(path, SceneError)
        for key in ("main_camera", "camera"):
            if isinstance(d, dict) and key in d:
                return cls.from_json(d[key], path, f"{key}.")
        return cls.from_json(d, path)

    def intrinsics_json(self) -> dict:
        """The "K" object of scene.json / camera.json: {fx, fy, cx, cy, width, height}."""
        K = self.K
        return {"fx": float(K[0, 0]), "fy": float(K[1, 1]), "cx": float(K[0, 2]), "cy": float(K[1, 2]),
                "width": int(self.width), "height": int(self.height)}

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
