#!/usr/bin/env python3
"""Where a composite's shadow energy comes from (issue 34, photoneg109): score.py's energy split by region and term.

usage: bench_photoneg109.py ROOM_DIR COMPOSITE.png [RING_PX]
       bench_photoneg109.py --terms ROOM_DIR KEEP_ROOM   (KEEP_ROOM: bench_unseen --keep's folder of that room)

--terms runs `composite --lighting photo` on KEEP_ROOM/room (the flow's scene, its cache) again with the object's
light onto the room and the second order switched off (--no-object-light, --no-second-order, both) and prints the
figures below for each (KEEP_ROOM/terms_<variant>/), so that each term's share of the energy is read off.

ROOM_DIR holds background.png, truth.png and truth_mask.png (a bench_unseen room); COMPOSITE is a kept composite.
score.py's energy is sum_affected(bg - ours) / sum_affected(bg - truth) on luminance blurred with sigma 2 px, the
affected region outside the object's mask dilated 2 px. Printed (one JSON line):
  energy            score.py's
  split             d_truth and d_ours over the affected pixels: in the ring (within RING_PX, default 6, of the
                    dilated mask, where the blur carries the object's own pixels out of the mask) and beyond it;
                    and over pixels where the background clips (luminance >= 250) or not
  object_swapped    the energy with the composite's object (truth_mask > 127, dilated 2 px) replaced by the truth's
                    pixels: what the object's own pixels add to the affected region through the blur
  brighter          affected pixels where ours is brighter than the background (count, their summed bg - ours), split
                    by ring / beyond
No engine run; luminance in 8-bit levels (Rec.709, as score.py).
"""
from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import cv2
import numpy as np


def lum(img: np.ndarray) -> np.ndarray:
    """Rec.709 luminance (levels) of a BGR uint8 image, as score.py."""
    img = img.astype(np.float64)
    return 0.0722 * img[..., 0] + 0.7152 * img[..., 1] + 0.2126 * img[..., 2]


def read(path: str, flags=cv2.IMREAD_COLOR) -> np.ndarray:
    """An image, or SystemExit naming the file."""
    im = cv2.imread(path, flags)
    if im is None:
        raise SystemExit(f"cannot read {path}")
    return im


def split(room: str, comp_path: str, ring_px: int = 6) -> dict:
    """The figures above for one composite (dict of floats / ints)."""
    bg, tr, co = read(f"{room}/background.png"), read(f"{room}/truth.png"), read(comp_path)
    mk = read(f"{room}/truth_mask.png", cv2.IMREAD_GRAYSCALE)
    mask = cv2.dilate((mk > 127).astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    blur = lambda x: cv2.GaussianBlur(x, (0, 0), 2.0)  # noqa: E731 (score.py's)
    lb, lt, lc = blur(lum(bg)), blur(lum(tr)), blur(lum(co))
    affected = (~mask) & (np.abs(lt - lb) > 2.0)
    k = 2 * ring_px + 1
    ring = cv2.dilate(mask.astype(np.uint8), np.ones((k, k), np.uint8)) > 0
    clip = lum(bg) >= 250.0
    d_t, d_o = lb - lt, lb - lc
    out = {"energy": float(d_o[affected].sum() / d_t[affected].sum()), "affected_px": int(affected.sum())}
    for name, sel in (("ring", ring), ("beyond", ~ring), ("bg_clipped", clip), ("bg_unclipped", ~clip)):
        a = affected & sel
        out[name] = {"px": int(a.sum()), "d_truth": float(d_t[a].sum()), "d_ours": float(d_o[a].sum())}
    sw = co.copy()
    sw[mask] = tr[mask]
    ls = blur(lum(sw))
    out["object_swapped_energy"] = float((lb - ls)[affected].sum() / d_t[affected].sum())
    br = affected & (lc > lb)
    out["brighter"] = {"px": int(br.sum()), "d_ours": float(d_o[br].sum()),
                       "ring_px": int((br & ring).sum()), "ring_d_ours": float(d_o[br & ring].sum())}
    raw_mask = mk > 127
    out["object_mean_levels"] = {"ours": float(lum(co)[raw_mask].mean()), "truth": float(lum(tr)[raw_mask].mean()),
                                 "bg": float(lum(bg)[raw_mask].mean())}
    return out


def terms(root: Path, keep: Path) -> None:
    """The --terms run (one process, the variants in turn; prints a line each)."""
    import tempfile

    from bench.own_room_flow import _composite_argv, _photoar, score, write_inputs

    shared = Path(os.environ.get("PHOTOAR_SHARED", "../shared"))
    with tempfile.TemporaryDirectory(prefix="photoneg109_") as tmp:  # the flow's inputs (object mesh, pose)
        inp = write_inputs(root, Path(tmp))
        for name, extra in (("full", []), ("no_object_light", ["--no-object-light"]),
                            ("no_second_order", ["--no-second-order"]),
                            ("neither", ["--no-object-light", "--no-second-order"])):
            out = keep / f"terms_{name}"
            rc, err, _ = _photoar(_composite_argv(keep / "room", out, inp, "photo", keep / "cache") + extra)
            if rc != 0:
                print(f"{name}: composite failed: {err}", flush=True)
                continue
            s, d = score(root, out / "composite.png", shared), split(str(root), str(out / "composite.png"))
            print(json.dumps({"variant": name, "score": s, "split": d}), flush=True)


def main(argv: list[str]) -> int:
    if len(argv) == 3 and argv[0] == "--terms":
        terms(Path(argv[1]).expanduser(), Path(argv[2]))
        return 0
    if len(argv) not in (2, 3):
        print(__doc__.strip())
        return 2
    print(json.dumps(split(argv[0], argv[1], int(argv[2]) if len(argv) == 3 else 6)))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
