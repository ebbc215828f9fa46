"""What goes wrong where in bench_unseen's composites: the sun shadow's speckle and the object's halves.

usage: python bench/bench_unseen_diag.py KEEP_DIR [--rooms DIR]

KEEP_DIR is bench_unseen.py's --keep folder (KEEP_DIR/<room>/out_*/composite.png); the rooms are
read from --rooms (default $PHOTOAR_ROOMS or ~/.cache/photoar/rooms). Per composite:

* sun band (rooms with a sun): the pixels of the object's shadow on the sunlit, clipped floor
  (outside the dilated object mask, truth < 0.85 x background after the scorer's sigma-2 blur,
  background clipped >= 254 in some channel). `spread` = std of the 8-bit luminance there, `hp` =
  rms of its high-pass (luminance minus its sigma-2 blur: the per-pixel speckle), ours and the
  truth's. `partial clip` = share of the photo's clipped sunlit pixels that clip in one or two
  channels only (the engine treats a pixel as clipped when any channel is >= 254).
* object halves: the bias ours - truth (blurred luminance, levels) over the lower and the upper
  half of the object's mask rows (near-field light from the floor shows in the lower half).
"""
from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

import numpy as np

W = np.array([0.0722, 0.7152, 0.2126])  # Rec.709 luminance of BGR


def _lum(path: Path) -> np.ndarray:
    import cv2

    return cv2.imread(str(path)).astype(np.float64) @ W


def sun_band(root: Path, composite: Path) -> dict:
    """The sun shadow band's spread, ours against the truth (module docstring)."""
    import cv2

    blur = lambda x: cv2.GaussianBlur(x, (0, 0), 2.0)  # noqa: E731
    bg8 = cv2.imread(str(root / "background.png"))
    bg, tr, co = _lum(root / "background.png"), _lum(root / "truth.png"), _lum(composite)
    mask = cv2.dilate((cv2.imread(str(root / "truth_mask.png"), 0) > 127).astype(np.uint8),
                      np.ones((5, 5), np.uint8)) > 0
    clipped_any = (bg8 >= 254).any(-1)
    clipped_all = (bg8 >= 254).all(-1)
    band = ~mask & (blur(tr) < 0.85 * blur(bg)) & clipped_any
    out = {"band_px": int(band.sum()),
           "partial_clip": float((clipped_any & ~clipped_all).sum() / max(clipped_any.sum(), 1))}
    if band.sum() < 20:
        return out
    for name, img in (("truth", tr), ("ours", co)):
        out[f"spread_{name}"] = float(img[band].std())
        out[f"hp_{name}"] = float(np.sqrt(np.mean((img - blur(img))[band] ** 2)))
        out[f"mean_{name}"] = float(img[band].mean())
    return out


def object_halves(root: Path, composite: Path) -> dict:
    """Bias ours - truth over the lower / upper half of the object mask's rows (levels)."""
    import cv2

    blur = lambda x: cv2.GaussianBlur(x, (0, 0), 2.0)  # noqa: E731
    mask = cv2.imread(str(root / "truth_mask.png"), 0) > 127
    d = blur(_lum(composite)) - blur(_lum(root / "truth.png"))
    rows = np.nonzero(mask)[0]
    mid = np.median(rows)
    low = mask & (np.arange(mask.shape[0])[:, None] >= mid)
    return {"bias_lower": float(d[low].mean()), "bias_upper": float(d[mask & ~low].mean())}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("keep", type=Path)
    ap.add_argument("--rooms", default=os.environ.get("PHOTOAR_ROOMS", str(Path.home() / ".cache/photoar/rooms")))
    a = ap.parse_args(argv)
    rooms = Path(a.rooms).expanduser()
    res = {}
    for work in sorted(p for p in a.keep.iterdir() if p.is_dir()):
        root = rooms / work.name
        if not (root / "scene.json").is_file():
            continue
        has_sun = any(p["type"] == "sun" for p in json.loads((root / "scene.json").read_text())["primitives"])
        for out in sorted(work.glob("out_*")):
            comp = out / "composite.png"
            if not comp.is_file():
                continue
            row = object_halves(root, comp)
            if has_sun:
                row.update(sun_band(root, comp))
            res[f"{work.name} {out.name[4:]}"] = row
            print(f"{work.name:<12} {out.name[4:]:<20} " + "  ".join(
                f"{k} {v:.3g}" if isinstance(v, float) else f"{k} {v}" for k, v in row.items()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
