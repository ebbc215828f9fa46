"""`photoar hdr IMAGE... --times T... --out DIR`: merge an exposure bracket (lighting/hdr.py).

Writes radiance.exr (float32 RGB, X / t), response.json (forward_table and inverse_table,
3 x 256 each, as in scene.json's camera_response, plus method and normalisation) and
response.png (the recovered curves: pixel level against log2 relative exposure).
"""
from __future__ import annotations

import argparse
import logging
import time
from pathlib import Path

import numpy as np

from app.units import seconds

log = logging.getLogger("photoar")


def register(sub) -> None:
    p = sub.add_parser("hdr", help="recover the camera response from an exposure bracket and merge it to HDR")
    p.add_argument("images", type=Path, nargs="+", help="8-bit images of one view at different exposures")
    p.add_argument("--times", type=seconds, nargs="+", required=True,
                   help="exposure time of each image, same order: seconds, 1/250 or 4ms")
    p.add_argument("--out", type=Path, required=True, help="output folder")
    p.add_argument("--merge", choices=["debevec", "robertson"], default="debevec", help="OpenCV merge (default %(default)s)")
    p.add_argument("--calibration", choices=["mitsunaga", "debevec", "robertson"], default="mitsunaga",
                   help="response recovery (default %(default)s: monotone Mitsunaga-Nayar fit)")
    p.set_defaults(run=run)


def plot_response(g: np.ndarray, path: Path, size: tuple[int, int] = (640, 420)) -> None:
    """Inverse response curves (256,3): x = log2 relative exposure, y = pixel level; drawn with OpenCV."""
    import cv2

    W, H = size
    ml, mr, mt, mb = 60, 20, 30, 50
    img = np.full((H, W, 3), 255, np.uint8)
    lv = np.arange(1, 256)
    lx = np.log2(np.maximum(g[1:], 1e-12))
    x0 = max(float(np.floor(lx[g[1:] > 0].min())), -16.0)
    px = lambda x: (ml + (np.clip(x, x0, 0) - x0) / (0 - x0) * (W - ml - mr)).astype(np.int32)
    py = lambda y: (H - mb - y / 255 * (H - mt - mb)).astype(np.int32)
    cv2.rectangle(img, (ml, mt), (W - mr, H - mb), (0, 0, 0), 1)
    for e in range(int(x0), 1, max(1, int(-x0) // 8)):
        cv2.putText(img, str(e), (int(px(np.array(e))) - 6, H - mb + 16), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1)
    for y in (0, 64, 128, 192, 255):
        cv2.putText(img, str(y), (ml - 30, int(py(np.array(y))) + 4), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1)
    cv2.putText(img, "log2 relative exposure X (X=1 at level 255)", (ml + 80, H - 12), cv2.FONT_HERSHEY_SIMPLEX,
                0.5, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(img, "pixel level", (5, mt - 10), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    for c, col in enumerate([(40, 40, 220), (40, 160, 40), (220, 80, 40)]):  # R, G, B in BGR
        pts = np.stack([px(lx[:, c]), py(lv)], -1).reshape(-1, 1, 2)
        cv2.polylines(img, [pts], False, col, 2, cv2.LINE_AA)
    from recon.io import write_png

    write_png(path, img[..., ::-1])  # drawn in OpenCV's BGR


def run(a: argparse.Namespace) -> int:
    from lighting import hdr
    from recon.io import AtomicOutput, read_image_rgb, write_exr, write_json

    if len(a.images) != len(a.times):
        raise ValueError(f"{a.images[0]}: {len(a.images)} images but {len(a.times)} --times")
    t0 = time.perf_counter()
    images = [read_image_rgb(p) for p in a.images]
    try:
        g = hdr.calibrate_response(images, a.times, a.calibration)
        rad, g = hdr.merge_bracket(images, a.times, g, method=a.merge)
    except ValueError as e:
        raise ValueError(f"{a.images[0]}: {e}") from None
    resid = hdr.channel_residuals(images, a.times, g)
    hdr.warn_unfit_channel(resid, str(a.images[0]))
    valid = hdr.valid_mask(images)
    sat = hdr.saturated_mask(images, a.times)
    log.info("merged %d exposures: radiance %.3g .. %.3g, %.1f %% pixels clipped in the shortest exposure",
             len(images), float(rad.min()), float(rad.max()), 100 * sat.mean())
    with AtomicOutput(a.out) as stage:
        write_exr(stage / "radiance.exr", rad)
        write_json(stage / "response.json", {
            "forward_table": hdr.forward_table(g), "inverse_table": g.T,
            "forward_table_doc": "forward_table[c][i] = f_c(i/255), pixel value / 255 at relative exposure i/255",
            "inverse_table_doc": "inverse_table[c][z] = relative exposure X giving level z; radiance = X / t",
            "normalisation": "inverse_table[c][255] = 1 per channel (X = 1 just reaches level 255)",
            "calibration": a.calibration, "merge": a.merge,
            "images": [str(p) for p in a.images], "times": a.times,
            "channel_residual_levels": resid,
            "channel_residual_doc": "per channel (R, G, B), rms of each exposure's level minus the level its merged "
                                    "radiance predicts through the response (about 1 when the response fits)",
            "valid_fraction": float(valid.mean()), "saturated_fraction": float(sat.mean()),
            "seconds": time.perf_counter() - t0})
        plot_response(g, stage / "response.png")
    print(a.out / "radiance.exr")
    return 0
