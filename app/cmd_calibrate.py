"""`photoar calibrate IMAGE --lines LINES.json [--height H | --known-length AXIS U V METRES] --out DIR`: single-photo camera
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

from app.units import camera_height

log = logging.getLogger("photoar")


def register(sub) -> None:
    p = sub.add_parser("calibrate", help="calibrate a single photo's camera from vanishing lines")
    p.add_argument("image", type=Path, help="the photo")
    p.add_argument("--lines", type=Path, required=True,
                   help='LINES.json: {"x": [[u1,v1,u2,v2],...], "y": [...], "z": [...], "origin": [u,v]} '
                        "(at least two of x/y/z; y = world vertical; origin optional)")
    p.add_argument("--scale-height", "--height", type=camera_height, default=None,
                   help="camera height above the floor in metres (0.3-3) through the origin pixel on the floor")
    p.add_argument("--known-length", nargs=4, default=None, metavar=("AXIS", "U", "V", "METRES"),
                   help="scale from a known length instead: the point at pixel (U, V) lies METRES from the origin "
                        "along world axis AXIS (x, y or z), e.g. the far end of a wall edge of known length "
                        "(same as LINES.json 'known_length')")
    p.add_argument("--flip-xz", action="store_true",
                   help="take world +X pointing leftwards in the image (default rightwards)")
    p.add_argument("--no-snap", action="store_true",
                   help="use the segments as clicked (default: snap each to the photo's edge under it, sub-pixel, "
                        "where one is found unambiguously)")
    p.add_argument("--allow-ill-conditioned", action="store_true",
                   help="write the camera even when the focal length is undetermined (std(f)/f > 15 %%; between 5 "
                        "and 15 %% it is written with a warning, flagged in camera.json as ill_conditioned)")
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
    if a.known_length is not None:
        axis, u, v, metres = a.known_length
        try:
            kl = {"axis": axis.lower(), "end_px": [float(u), float(v)], "metres": float(metres)}
        except ValueError:
            raise ValueError(f"--known-length: expected AXIS U V METRES (numbers), got {' '.join(a.known_length)}") \
                from None
        if kl["axis"] not in ("x", "y", "z") or not kl["metres"] > 0:
            raise ValueError("--known-length: AXIS must be x, y or z and METRES positive")
        if a.scale_height is not None:
            raise ValueError("--known-length: give either --height or --known-length, not both")
        lines = dict(lines, known_length=kl)
    calib = calibrate_lines(lines, w, h, camera_height=a.scale_height, src=str(a.lines), flip_xz=a.flip_xz,
                            raise_ill_conditioned=not a.allow_ill_conditioned, image=None if a.no_snap else photo)
    for n in calib.notes:
        if calib.ill_conditioned and n.startswith(f"{a.lines}: ") and "focal length" in n:
            log.warning("%s", n)  # the one warning line: the focal length is uncertain
        else:
            log.info("%s", n)
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
