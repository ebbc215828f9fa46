"""`photoar tonemap EXR --op NAME --out PNG`: show an HDR output on an 8-bit display (seed sec. 9.1).

Operators (lighting.tonemap): reinhard, drago, mantiuk (OpenCV) and ward (Ward's contrast-based
scale factor, sec. 9.1.3, which needs the scene's absolute level: --nits-per-unit). The PNG is
written to a temporary file beside --out and renamed, so it appears whole or not at all.
"""
from __future__ import annotations

import argparse
from pathlib import Path


def register(sub) -> None:
    from lighting.tonemap import DISPLAY_OPERATORS

    p = sub.add_parser("tonemap", help="tone-map an HDR image (OpenEXR) for display")
    p.add_argument("exr", type=Path, help="linear RGB OpenEXR image (e.g. reference.exr, composite.exr)")
    p.add_argument("--op", choices=DISPLAY_OPERATORS, default="reinhard", help="operator (default %(default)s)")
    p.add_argument("--out", type=Path, required=True, help="output PNG")
    p.add_argument("--gamma", type=float, default=2.2, help="display gamma (default %(default)s)")
    p.add_argument("--nits-per-unit", type=float, default=1.0,
                   help="ward: cd/m^2 per radiance unit of the image (default %(default)s)")
    p.add_argument("--ld-max", type=float, default=100.0, help="ward: display white, cd/m^2 (default %(default)s)")
    p.set_defaults(run=run)


def run(a: argparse.Namespace) -> int:
    import numpy as np

    from lighting.tonemap import display_tonemap, to_display_pixels
    from recon.io import read_exr, write_png

    if not a.exr.is_file():
        raise FileNotFoundError(f"{a.exr}: file not found")
    if a.out.suffix.lower() != ".png":
        raise ValueError(f"{a.out}: --out must name a .png file")
    if not (a.gamma > 0 and a.nits_per_unit > 0 and a.ld_max > 0):
        raise ValueError(f"{a.exr}: --gamma, --nits-per-unit and --ld-max must be positive")
    hdr = read_exr(a.exr)
    if not np.all(np.isfinite(hdr)):
        raise ValueError(f"{a.exr}: image has NaN or infinite values")
    kw = {"gamma": a.gamma}
    if a.op == "ward":
        kw.update(nits_per_unit=a.nits_per_unit, L_dmax=a.ld_max)
    pixels = to_display_pixels(display_tonemap(hdr, a.op, **kw))
    write_png(a.out, pixels)  # atomic: a temporary file renamed over --out
    print(a.out)
    return 0
