"""`photoar calibrate IMAGE --lines LINES.json [--scale-height H] --out DIR`: single-photo camera
calibration from vanishing points (seed sec. 3, recon/vanishing.py).

The clicked segments are snapped to the photo's edges first (recon/edgesnap.py; `--no-snap` keeps
them as clicked). Writes camera.json (fx, fy, cx, cy, width, height, K, R, t, centre in the OpenCV
convention of recon/camera.py, plus the vanishing points, which segments were snapped, and the
conditioning figure) and overlay.png (the segments, their lines to the vanishing points and the
projected world axes), all or nothing.
"""
from __future__ import annotations

import argparse
import logging
from pathlib import Path

log = logging.getLogger("photoar")


def register(sub) -> None:
    p = sub.add_parser("calibrate", help="calibrate a single photo's camera from vanishing lines")
    p.add_argument("image", type=Path, help="the photo")
    p.add_argument("--lines", type=Path, required=True,
                   help='LINES.json: {"x": [[u1,v1,u2,v2],...], "y": [...], "z": [...], "origin": [u,v]} '
                        "(at least two of x/y/z; y = world vertical; origin optional)")
    p.add_argument("--scale-height", type=float, default=None,
                   help="camera height above the floor (m) through the origin pixel on the floor")
    p.add_argument("--flip-xz", action="store_true",
                   help="take world +X pointing leftwards in the image (default rightwards)")
    p.add_argument("--no-snap", action="store_true",
                   help="use the segments as clicked (default: snap each to the photo's edge under it, sub-pixel, "
                        "where one is found unambiguously)")
    p.add_argument("--allow-ill-conditioned", action="store_true",
                   help="write the camera even when the focal length is ill-conditioned (flagged in camera.json)")
    p.add_argument("--out", type=Path, required=True, help="output folder")
    p.set_defaults(run=run)


def run(a: argparse.Namespace) -> int:
    from recon.io import AtomicOutput, read_image_rgb, write_json, write_png
    from recon.vanishing import calibrate_lines, draw_overlay, load_lines

    photo = read_image_rgb(a.image)
    h, w = photo.shape[:2]
    lines = load_lines(a.lines)
    if a.scale_height is not None and not a.scale_height > 0:
        raise ValueError(f"--scale-height must be positive, got {a.scale_height}")
    calib = calibrate_lines(lines, w, h, camera_height=a.scale_height, src=str(a.lines), flip_xz=a.flip_xz,
                            raise_ill_conditioned=not a.allow_ill_conditioned, image=None if a.no_snap else photo)
    for n in calib.notes:
        log.warning("%s", n)
    K = calib.camera.K
    log.info("f = %.2f px, principal point (%.1f, %.1f) [%s], std(f)/f = %.2g, segment RMS %.2f px, scale: %s",
             K[0, 0], K[0, 2], K[1, 2], calib.principal_point_from, calib.focal_rel_sigma, calib.rms_px, calib.scale)
    with AtomicOutput(a.out) as stage:
        d = calib.to_json()
        d["image"] = str(a.image)
        d["lines"] = str(a.lines)
        write_json(stage / "camera.json", d)
        write_png(stage / "overlay.png", draw_overlay(photo, calib, lines["families"], lines.get("origin")))
    print(a.out / "camera.json")
    return 0
