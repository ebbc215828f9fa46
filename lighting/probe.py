"""Light-probe images: direction <-> pixel for mirror-ball, angular and lat-long maps; SH9 of a probe.

Seed sec. 4.2 (a mirror ball photographed in the scene) and sec. 5 (9 SH coefficients,
Ramamoorthi & Hanrahan, "An efficient representation for irradiance environment maps",
SIGGRAPH 2001). Every mapping returns, per pixel, the unit direction the pixel's radiance
ARRIVES FROM (pointing from the probe centre towards the light), its solid angle in sr and a
valid mask. Pixel coordinates: u = column, v = row, the CENTRE of the top-left pixel is (0, 0).

Mirror ball (`mirrorball_*`), the scenes' probe camera (../shared/scenes/FORMAT.md, "Light
probe"): an orthographic camera with OpenCV axes (x right, y down, z towards the ball) sees the
ball as the inscribed circle of a size x size image, centre c = (size-1)/2, radius r = size/2
pixels. Pixel (u, v) has the ball normal n = (x, y, -sqrt(1-x^2-y^2)), x = (u-c)/r, y = (v-c)/r,
and reflects the viewing direction d = (0,0,1) into w = d - 2 (d.n) n, in camera axes; world
directions are R_world_from_cam @ w with R_world_from_cam = R^T of the probe camera's R in
scene.json. The map has a constant Jacobian: a unit of image-disk area covers 4 sr, so a pixel
inside the ball subtends 4 / r^2 sr (times the fraction of it inside the circle). Valid: pixel
centre at radius x^2+y^2 <= rim^2 (default rim 0.98, i.e. w within 157 deg of the direction
back to the camera; the grazing rim beyond maps a thin ring onto the whole back of the sphere).

Angular map (`angular_*`, Debevec's Light Probe Image Gallery): a square image, a = 2 (u+0.5)/S - 1
to the right, b = 1 - 2 (v+0.5)/S upwards; rho = sqrt(a^2+b^2) <= 1, theta = pi rho is the angle
from +z and D = (sin theta a/rho, sin theta b/rho, cos theta), in Debevec's frame: x right, y up,
+z from the probe towards the camera (the centre of the image). Jacobian pi sin(pi rho)/rho per
unit (a,b) area. Valid: pixel centre inside the disk.

Latitude-longitude (`latlong_*`, pbrt's convention, ../shared/data/probes/SOURCE.md): W x H,
theta = pi (v+0.5)/H from the +z pole (row 0 = +z, up), phi = 2 pi (u+0.5)/W,
D = (sin theta cos phi, sin theta sin phi, cos theta); pixel solid angle
(2 pi / W)(cos theta_top - cos theta_bottom), exact. All pixels valid.

Each `*_directions` takes an optional rotation R_world_from_map (3x3) applied to the directions.
`sh_from_probe` fits the 9 coefficients of incident radiance (lighting/sh.py order and
normalisation) by solid-angle-weighted least squares over the valid pixels: on a complete
sphere that equals the projection integral (the basis is orthonormal), and where pixels are
masked (grazing rim, saturation) it still reproduces any band-limited (l <= 2) environment exactly.
"""
from __future__ import annotations

import numpy as np

from lighting import sh

MAPPINGS = ("mirrorball", "angular", "latlong")
DEFAULT_RIM = 0.98
_SS = 4  # sub-samples per pixel side for the coverage / Jacobian of disk-shaped maps

# probe-camera (OpenCV: x right, y down, z forward) -> Debevec frame (x right, y up, z to the camera)
R_DEBEVEC_FROM_CV = np.diag([1.0, -1.0, -1.0])


def up_rotation(up: str) -> np.ndarray:
    """Proper rotation taking the map frame's `up` axis (x, y or z) to world +Y (y: identity;
    z: -90 deg about x, (x, y, z) -> (x, z, -y); x: +90 deg about z, (x, y, z) -> (-y, x, z))."""
    rots = {"y": np.eye(3),
            "z": np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]]),
            "x": np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]])}
    if up not in rots:
        raise ValueError(f"up axis must be x, y or z, got {up!r}")
    return rots[up]


def _rotate(d: np.ndarray, R: np.ndarray | None) -> np.ndarray:
    if R is None:
        return d
    R = np.asarray(R, np.float64)
    if R.shape != (3, 3) or not np.allclose(R @ R.T, np.eye(3), atol=1e-6):
        raise ValueError(f"rotation must be an orthonormal 3x3 matrix, got {R.tolist()}")
    return d @ R.T


def _check_size(w: int, h: int | None = None) -> None:
    for s in (w, h):
        if s is not None and (int(s) != s or s < 2):
            raise ValueError(f"probe image size must be an integer >= 2, got {s}")


def _disk_coverage(size: int, jac) -> np.ndarray:
    """Per pixel of a size x size image, mean over _SS^2 sub-samples of jac(rho) [rho <= 1],
    rho = sub-sample radius in units of size/2 around the image centre."""
    o = (np.arange(_SS) + 0.5) / _SS - 0.5
    p = np.arange(size)[:, None] + o[None, :]  # (size, SS) sub-sample coords
    x = (p - (size - 1) / 2) / (size / 2)
    rho = np.sqrt(x[:, None, :, None] ** 2 + x[None, :, None, :] ** 2)  # (rows, cols, SS, SS)
    val = np.where(rho <= 1.0, jac(np.minimum(rho, 1.0)), 0.0)
    return val.mean(axis=(2, 3))


# ----------------------------------------------------------------------------- mirror ball

def mirrorball_directions(size: int, R_world_from_cam: np.ndarray | None = None, rim: float = DEFAULT_RIM
                          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mirror ball filling a size x size orthographic image (module docstring).

    Returns dirs (H,W,3) unit directions radiance arrives from (probe-camera axes, or world with
    R_world_from_cam = R^T), solid_angle (H,W) sr, valid (H,W) bool. Outside the ball dirs = 0.
    """
    _check_size(size)
    if not 0 < rim <= 1:
        raise ValueError(f"rim must be in (0, 1], got {rim}")
    c, r = (size - 1) / 2, size / 2
    x = (np.arange(size) - c) / r
    X, Y = np.meshgrid(x, x)  # columns, rows
    rho2 = X ** 2 + Y ** 2
    inside = rho2 <= 1.0
    nz = -np.sqrt(np.clip(1.0 - rho2, 0.0, 1.0))
    n = np.stack([X, Y, nz], -1)
    dn = n[..., 2:3]  # d.n with d = (0,0,1)
    w = np.array([0.0, 0.0, 1.0]) - 2 * dn * n
    w = w / np.linalg.norm(w, axis=-1, keepdims=True)
    w[~inside] = 0.0
    sa = 4.0 / r ** 2 * _disk_coverage(size, lambda rho: np.ones_like(rho))
    valid = inside & (rho2 <= rim ** 2)
    return _rotate(w, R_world_from_cam), sa, valid


def mirrorball_pixels(dirs: np.ndarray, size: int, R_world_from_cam: np.ndarray | None = None) -> np.ndarray:
    """Pixel (u, v) (...,2) where the mirror ball shows directions dirs (...,3) (world if R given).

    The normal is the half-vector n = normalize(w - d); w = d (straight behind the ball) maps to the rim.
    """
    w = np.asarray(dirs, np.float64)
    if R_world_from_cam is not None:
        w = w @ np.asarray(R_world_from_cam, np.float64)  # world -> camera: R^T^T = R
    w = w / np.maximum(np.linalg.norm(w, axis=-1, keepdims=True), 1e-300)
    h = w - np.array([0.0, 0.0, 1.0])
    hn = np.linalg.norm(h, axis=-1, keepdims=True)
    n = np.where(hn > 1e-12, h / np.maximum(hn, 1e-300), np.array([1.0, 0.0, 0.0]))
    c, r = (size - 1) / 2, size / 2
    return np.stack([c + n[..., 0] * r, c + n[..., 1] * r], -1)


# ----------------------------------------------------------------------------- angular map

def angular_directions(size: int, R_world_from_map: np.ndarray | None = None
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Debevec angular map of size x size (module docstring) -> dirs (H,W,3), solid_angle (H,W), valid."""
    _check_size(size)
    t = 2 * (np.arange(size) + 0.5) / size - 1
    A, B = np.meshgrid(t, -t)  # a right (columns), b up (rows)
    rho = np.sqrt(A ** 2 + B ** 2)
    valid = rho <= 1.0
    theta = np.pi * np.minimum(rho, 1.0)
    s = np.where(rho > 0, np.sin(theta) / np.maximum(rho, 1e-300), np.pi)
    d = np.stack([s * A, s * B, np.cos(theta)], -1)
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    d[~valid] = 0.0
    jac = lambda r: np.where(r > 1e-12, np.pi * np.sin(np.pi * r) / np.maximum(r, 1e-300), np.pi ** 2)
    sa = (2.0 / size) ** 2 * _disk_coverage(size, jac)
    return _rotate(d, R_world_from_map), sa, valid


def angular_pixels(dirs: np.ndarray, size: int, R_world_from_map: np.ndarray | None = None) -> np.ndarray:
    """Pixel (u, v) (...,2) of directions (...,3) in a size x size angular map."""
    d = np.asarray(dirs, np.float64)
    if R_world_from_map is not None:
        d = d @ np.asarray(R_world_from_map, np.float64)
    d = d / np.maximum(np.linalg.norm(d, axis=-1, keepdims=True), 1e-300)
    rho = np.arccos(np.clip(d[..., 2], -1, 1)) / np.pi
    phi = np.arctan2(d[..., 1], d[..., 0])
    a, b = rho * np.cos(phi), rho * np.sin(phi)
    return np.stack([(a + 1) / 2 * size - 0.5, (1 - b) / 2 * size - 0.5], -1)


# ----------------------------------------------------------------------------- lat-long

def latlong_directions(width: int, height: int | None = None, R_world_from_map: np.ndarray | None = None
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """pbrt lat-long map W x H (default H = W/2) -> dirs (H,W,3), solid_angle (H,W) exact, valid (all)."""
    height = width // 2 if height is None else height
    _check_size(width, height)
    theta = np.pi * (np.arange(height) + 0.5) / height
    phi = 2 * np.pi * (np.arange(width) + 0.5) / width
    T, P = np.meshgrid(theta, phi, indexing="ij")
    d = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1)
    edges = np.cos(np.pi * np.arange(height + 1) / height)
    sa = np.repeat(((edges[:-1] - edges[1:]) * 2 * np.pi / width)[:, None], width, axis=1)
    return _rotate(d, R_world_from_map), sa, np.ones((height, width), bool)


def latlong_pixels(dirs: np.ndarray, width: int, height: int | None = None,
                   R_world_from_map: np.ndarray | None = None) -> np.ndarray:
    """Pixel (u, v) (...,2) of directions (...,3) in a W x H pbrt lat-long map (u in [-0.5, W-0.5))."""
    height = width // 2 if height is None else height
    d = np.asarray(dirs, np.float64)
    if R_world_from_map is not None:
        d = d @ np.asarray(R_world_from_map, np.float64)
    d = d / np.maximum(np.linalg.norm(d, axis=-1, keepdims=True), 1e-300)
    theta = np.arccos(np.clip(d[..., 2], -1, 1))
    phi = np.mod(np.arctan2(d[..., 1], d[..., 0]), 2 * np.pi)
    return np.stack([phi / (2 * np.pi) * width - 0.5, theta / np.pi * height - 0.5], -1)


# ----------------------------------------------------------------------------- generic

def probe_directions(mapping: str, shape: tuple[int, int], R_world_from_map: np.ndarray | None = None,
                     rim: float = DEFAULT_RIM) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Dispatch on mapping for an image of shape (H, W); disk maps must be square."""
    h, w = int(shape[0]), int(shape[1])
    if mapping == "latlong":
        return latlong_directions(w, h, R_world_from_map)
    if mapping not in MAPPINGS:
        raise ValueError(f"unknown probe mapping {mapping!r} (one of {', '.join(MAPPINGS)})")
    if h != w:
        raise ValueError(f"a {mapping} probe must be square, got {w} x {h}")
    if mapping == "mirrorball":
        return mirrorball_directions(w, R_world_from_map, rim)
    return angular_directions(w, R_world_from_map)


def probe_pixels(mapping: str, dirs: np.ndarray, shape: tuple[int, int],
                 R_world_from_map: np.ndarray | None = None) -> np.ndarray:
    """Inverse of probe_directions: pixel (u, v) (...,2) for directions (...,3)."""
    h, w = int(shape[0]), int(shape[1])
    if mapping == "mirrorball":
        return mirrorball_pixels(dirs, w, R_world_from_map)
    if mapping == "angular":
        return angular_pixels(dirs, w, R_world_from_map)
    if mapping == "latlong":
        return latlong_pixels(dirs, w, h, R_world_from_map)
    raise ValueError(f"unknown probe mapping {mapping!r} (one of {', '.join(MAPPINGS)})")


def lookup(radiance: np.ndarray, mapping: str, dirs: np.ndarray, R_world_from_map: np.ndarray | None = None
           ) -> np.ndarray:
    """Bilinear radiance (N,3) float32 of probe image (H,W,3) in directions (N,3) (lat-long wraps in phi)."""
    import cv2

    rad = np.ascontiguousarray(radiance, np.float32)
    uv = probe_pixels(mapping, np.asarray(dirs, np.float64).reshape(-1, 3), rad.shape[:2], R_world_from_map)
    mx = uv[:, 0].astype(np.float32).reshape(1, -1)
    my = uv[:, 1].astype(np.float32).reshape(1, -1)
    border = cv2.BORDER_WRAP if mapping == "latlong" else cv2.BORDER_REPLICATE
    if mapping == "latlong":  # wrap columns only; clamp rows
        my = np.clip(my, 0, rad.shape[0] - 1)
    out = cv2.remap(rad, mx, my, cv2.INTER_LINEAR, borderMode=border)
    return out.reshape(-1, 3)


def sh_from_probe(radiance: np.ndarray, mapping: str, R_world_from_map: np.ndarray | None = None,
                  valid: np.ndarray | None = None, rim: float = DEFAULT_RIM, fit: str = "lsq") -> np.ndarray:
    """SH9 coefficients (9,3) float64 of the incident radiance in a probe image.

    radiance: (H,W,3) linear; mapping: mirrorball | angular | latlong; R_world_from_map rotates the
    map's directions (module docstring) into the output frame; valid: extra (H,W) mask, e.g.
    ~hdr.saturated_mask(...); fit: "lsq" (solid-angle-weighted least squares over valid pixels)
    or "project" (plain quadrature sum over valid pixels: masked directions count as black).
    """
    rad = np.asarray(radiance)
    if rad.ndim != 3 or rad.shape[2] != 3:
        raise ValueError(f"probe radiance must be (H,W,3), got shape {rad.shape}")
    if not np.all(np.isfinite(rad)):
        raise ValueError(f"probe radiance contains {int((~np.isfinite(rad)).any(-1).sum())} NaN or infinite pixels")
    dirs, sa, ok = probe_directions(mapping, rad.shape[:2], R_world_from_map, rim)
    if valid is not None:
        valid = np.asarray(valid, bool)
        if valid.shape != ok.shape:
            raise ValueError(f"valid mask has shape {valid.shape}, probe is {ok.shape}")
        ok = ok & valid
    ok &= sa > 0
    if ok.sum() < 9:
        raise ValueError(f"probe has only {int(ok.sum())} valid pixels; cannot fit 9 SH coefficients")
    d, w, L = dirs[ok], sa[ok], rad[ok].astype(np.float64)
    if fit == "project":
        return sh.project(d, L, w)
    if fit != "lsq":
        raise ValueError(f"unknown fit {fit!r} (lsq or project)")
    Y = sh.basis(d)  # (N,9)
    G = np.einsum("nk,n,nj->kj", Y, w, Y)
    b = np.einsum("nk,n,nc->kc", Y, w, L)
    return np.linalg.solve(G, b)


SH_NAMES = ("L00", "L1m1", "L10", "L11", "L2m2", "L2m1", "L20", "L21", "L22")


def sh_to_dict(coeffs: np.ndarray) -> dict[str, list[float]]:
    """(9,3) -> {"L00": [r,g,b], ...} in Ramamoorthi-Hanrahan order."""
    c = np.asarray(coeffs, np.float64).reshape(9, 3)
    return {name: [float(v) for v in c[i]] for i, name in enumerate(SH_NAMES)}
