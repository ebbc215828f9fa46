"""Working resolution: preview and drag on a smaller copy of the photo, write the final composite
at the photo's full resolution (issue 16, item 9).

The engine's per-pixel state grows with the photo (an ID buffer, barycentrics, transfers and
radiance per pixel: about 1 kB per pixel over a frame), so a 12-megapixel phone photo is
composited at a working resolution, its long side at most `work_res` pixels (default 1024):

  working_scene  the scene with the photo resampled (area average) and K scaled to match; the
                 world, the model and the object are unchanged.
  full_resolution  the working frame's change brought to the full photo:
    room:   the change of the room's radiance is smooth (soft shadows, reflected light), so it is
            upsampled bilinearly as a ratio r = L_room / L_b where the photo is not black
            (additive where it is) and applied to the full photo's own radiance, which keeps
            its texture and detail: L_full' = r * L_full. Pixels the working frame changes by
            less than a quarter level keep the photo's levels exactly.
    object: re-rendered at full resolution: the object's vertex radiance from the working
            frame (shading is per vertex, independent of pixels) interpolated at the full
            camera's sub-pixel hits, depth-tested against the room model, so its silhouette is
            sharp. (With a specular lobe, whose lookup is per pixel, the object's radiance is
            upsampled instead.)
Units: radiance in the scene's units; pixel centres as recon.camera (centre of the top-left pixel
at (0, 0)), so the full camera's principal point maps as c' = (c + 0.5) s - 0.5.
"""
from __future__ import annotations

import dataclasses

import cv2
import numpy as np

from recon.response import LUMA
from recon.scene import Scene

DEFAULT_WORK_RES = 1024


def scaled_camera(camera, width: int, height: int):
    """The same camera (pose, exposure) with its image resampled to width x height pixels."""
    sx, sy = width / camera.width, height / camera.height
    K = camera.K.copy()
    K[0, 0] *= sx
    K[1, 1] *= sy
    K[0, 2] = (K[0, 2] + 0.5) * sx - 0.5
    K[1, 2] = (K[1, 2] + 0.5) * sy - 0.5
    return dataclasses.replace(camera, K=K, width=int(width), height=int(height))


def working_scene(scene: Scene, work_res: int | None = DEFAULT_WORK_RES) -> Scene:
    """`scene` with its long side at most `work_res` pixels (the scene itself when it already is,
    or when work_res is None or 0)."""
    cam = scene.camera
    if not work_res or max(cam.width, cam.height) <= work_res:
        return scene
    if work_res < 16:
        raise ValueError(f"--work-res must be at least 16 pixels, got {work_res}")
    s = work_res / max(cam.width, cam.height)
    w, h = max(1, round(cam.width * s)), max(1, round(cam.height * s))
    photo = cv2.resize(scene.photo, (w, h), interpolation=cv2.INTER_AREA)
    meta = {**scene.meta, "full_resolution": [cam.width, cam.height]}
    return dataclasses.replace(scene, camera=scaled_camera(cam, w, h), photo=photo, meta=meta)


def _upsampler(small_hw: tuple[int, int], full_hw: tuple[int, int], box: tuple[int, int, int, int]):
    """A function resampling (h,w,C) working-resolution arrays bilinearly at the full-resolution
    pixels of `box` = (Y0, Y1, X0, X1) (inclusive), with pixel centres mapped as cv2.resize does:
    x_small = (X + 0.5) * w / W - 0.5. Only the box is computed (the rest of the photo is unchanged)."""
    (h, w), (H, W) = small_hw, full_hw
    Y0, Y1, X0, X1 = box
    mx = ((np.arange(X0, X1 + 1) + 0.5) * (w / W) - 0.5).astype(np.float32)
    my = ((np.arange(Y0, Y1 + 1) + 0.5) * (h / H) - 0.5).astype(np.float32)
    MX, MY = np.meshgrid(mx, my)

    def up(a: np.ndarray) -> np.ndarray:
        return cv2.remap(np.ascontiguousarray(a, np.float32), MX, MY, cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_REPLICATE)
    return up


def full_resolution(engine, frame, full: Scene) -> tuple[np.ndarray, np.ndarray]:
    """(pixels (H,W,3) uint8, radiance (H,W,3) float32) of `frame` (rendered by `engine` on a
    working_scene of `full`) at the full photo's resolution (module docstring)."""
    cam = full.camera
    H, W = cam.height, cam.width
    resp = engine.scene.response  # the response the engine used (captured: recovered from the bracket)
    small = engine.scene.camera
    h, w = small.height, small.width
    # the photo's radiance through a per-level table (the photo is 8-bit)
    lut = resp.to_radiance(np.repeat(np.arange(256, dtype=np.uint8)[:, None], 3, 1)).astype(np.float32)
    photo = full.photo
    radiance = np.stack([lut[photo[..., c], c] for c in range(3)], axis=-1)
    levels = photo.astype(np.float32)

    # the room: the working frame's change, as a ratio where the photo is not black
    L_b = engine.receivers.L_b.reshape(h, w, 3)
    room = frame.room.astype(np.float64)
    # pixels the working frame changes by a quarter level or more (fainter change would round
    # away at full resolution too; leaving it out keeps the untouched photo bit for bit)
    lv_b = engine.receivers.L_b_levels.reshape(h, w, 3)
    changed_small = np.any(np.abs(resp.to_levels(room) - lv_b) >= 0.25, axis=2)
    if changed_small.any():
        ys, xs = np.nonzero(changed_small)
        y0, y1, x0, x1 = max(ys.min() - 1, 0), min(ys.max() + 1, h - 1), max(xs.min() - 1, 0), min(xs.max() + 1, w - 1)
        box = (max(int(np.floor((y0 + 0.5) * H / h - 0.5)), 0), min(int(np.ceil((y1 + 0.5) * H / h - 0.5)), H - 1),
               max(int(np.floor((x0 + 0.5) * W / w - 0.5)), 0), min(int(np.ceil((x1 + 0.5) * W / w - 0.5)), W - 1))
        up = _upsampler((h, w), (H, W), box)
        lum_b = L_b @ LUMA
        dark = (lum_b <= 1e-6 * max(float(lum_b.max()), 1e-30))[..., None]
        ratio = np.where(dark, 1.0, room / np.where(dark, 1.0, L_b))
        delta = np.where(dark, room - L_b, 0.0)
        Y0, Y1, X0, X1 = box
        sel = up(changed_small.astype(np.float32)) > 0
        r, d = up(ratio)[sel], up(delta)[sel]
        rad_box = radiance[Y0:Y1 + 1, X0:X1 + 1]
        lev_box = levels[Y0:Y1 + 1, X0:X1 + 1]
        new = np.maximum(rad_box[sel] * r + d, 0.0)
        rad_box[sel] = new
        lev_box[sel] = resp.to_levels(new)
    radiance = radiance.reshape(-1, 3)
    levels = levels.reshape(-1, 3)
    # the object: vertex radiance of the working frame at the full camera's hits
    shading = engine.last_shading
    if shading is not None and engine.params.specular == 0:
        (v, _, f), L_vert, _, _ = shading
        hits = engine.object_shading.object_hits(v, f, camera=cam, supersample=2)
        cov = hits.coverage().reshape(-1)
        hh = hits.hit
        sub = np.zeros((len(hh), 3))
        sub[hh] = np.einsum("nk,nkc->nc", hits.bary[hh], L_vert[f[hits.tri[hh]]])
        obj = hits.average(sub).reshape(-1, 3)
    else:
        cov = cv2.resize(frame.coverage, (W, H), interpolation=cv2.INTER_LINEAR).reshape(-1)
        c_s = frame.coverage[..., None]
        obj_small = np.where(c_s > 0, (frame.radiance - (1 - c_s) * frame.room) / np.maximum(c_s, 1e-6), 0.0)
        obj = cv2.resize(obj_small.astype(np.float32), (W, H), interpolation=cv2.INTER_LINEAR).reshape(-1, 3)
    on = np.flatnonzero(cov > 0)
    c = cov[on, None]
    levels[on] = (1 - c) * levels[on] + c * resp.to_levels(obj[on])
    radiance[on] = (1 - c) * radiance[on] + c * obj[on]
    pixels = np.clip(np.rint(levels), 0, 255).astype(np.uint8).reshape(H, W, 3)
    return pixels, radiance.reshape(H, W, 3)
