"""`photoar metrics A B [--mask M] [--out DIR]`: how far image A is from image B (lighting.metrics).

Prints one JSON line: RMSE, mean absolute and largest error, PSNR and SSIM of luminance over
the mask's pixels (8-bit grey, > 127; all pixels without --mask), FLIP's availability, and,
with --scene (a benchmark folder whose truth is B), the scorer's region figures. 8-bit images
(PNG, JPEG) compare in levels; two OpenEXR images compare in their radiance units. With --out,
writes error.png (|luminance difference| heat-map), ssim.png (1 - SSIM heat-map) and
metrics.json, atomically.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np


def register(sub) -> None:
    p = sub.add_parser("metrics", help="error metrics and heat-maps of image A against image B")
    p.add_argument("a", type=Path, help="image to judge (PNG/JPEG, or OpenEXR)")
    p.add_argument("b", type=Path, help="reference image (same size and kind)")
    p.add_argument("--mask", type=Path, default=None, help="8-bit grey region, > 127 = counted")
    p.add_argument("--scene", type=Path, default=None,
                   help="benchmark scene folder: also report score.py's figures (B should be its truth.png)")
    p.add_argument("--vmax", type=float, default=None, help="top of the error heat-map scale (default 10 levels)")
    p.add_argument("--out", type=Path, default=None, help="folder for error.png, ssim.png, metrics.json")
    p.set_defaults(run=run)


def _read(path: Path) -> np.ndarray:
    from recon.io import read_exr, read_image_rgb

    if not path.is_file():
        raise FileNotFoundError(f"{path}: file not found")
    if path.suffix.lower() == ".exr":
        img = read_exr(path).astype(np.float64)
        if not np.all(np.isfinite(img)):
            raise ValueError(f"{path}: image has NaN or infinite values")
        return img
    return read_image_rgb(path)


def run(a: argparse.Namespace) -> int:
    import cv2

    from lighting import metrics
    from recon.io import AtomicOutput, dumps_json, write_json, write_png

    A, B = _read(a.a), _read(a.b)
    if A.shape != B.shape:
        raise ValueError(f"{a.a}: size {A.shape[1]}x{A.shape[0]} differs from {a.b} ({B.shape[1]}x{B.shape[0]})")
    if (A.dtype == np.uint8) != (B.dtype == np.uint8):
        raise ValueError(f"{a.a}: compare 8-bit with 8-bit and OpenEXR with OpenEXR ({a.b} is the other kind)")
    region = None
    if a.mask is not None:
        if not a.mask.is_file():
            raise FileNotFoundError(f"{a.mask}: file not found")
        m = cv2.imread(str(a.mask), cv2.IMREAD_GRAYSCALE)
        if m is None:
            raise ValueError(f"{a.mask}: not a readable image")
        if m.shape != A.shape[:2]:
            raise ValueError(f"{a.mask}: size {m.shape[1]}x{m.shape[0]} differs from the images "
                             f"({A.shape[1]}x{A.shape[0]})")
        region = m > 127
        if not region.any():
            raise ValueError(f"{a.mask}: no pixel above 127, the region is empty")
    out = {"a": str(a.a), "b": str(a.b), "mask": str(a.mask) if a.mask else None,
           "units": "8-bit levels" if A.dtype == np.uint8 else "radiance", **metrics.compare(A, B, region)}
    if a.scene is not None:
        from recon.io import read_image_rgb

        if A.dtype != np.uint8:
            raise ValueError(f"{a.a}: --scene scores 8-bit composites only")
        bg = read_image_rgb(a.scene / "background.png")
        mk_path = a.scene / "truth_mask.png"
        mk = cv2.imread(str(mk_path), cv2.IMREAD_GRAYSCALE)
        if mk is None:
            raise FileNotFoundError(f"{mk_path}: file not found or unreadable")
        out["score"] = metrics.score_regions(A, bg, B, mk)
    print(dumps_json(out, sort_keys=False))  # valid JSON: an infinite PSNR (equal images) is null
    if a.out is not None:
        with AtomicOutput(a.out) as stage:
            write_png(stage / "error.png", metrics.error_heatmap(A, B, a.vmax, region=region))
            write_png(stage / "ssim.png", metrics.ssim_heatmap(A, B, region=region))
            write_json(stage / "metrics.json", out)
    return 0
