"""How rmse_object follows an image error of the object: a composite shifted by sub-pixel amounts, scored.

A camera a pixel off moves the composited object's outline by about that much; the scorer's object
region (truth_mask dilated 2 px, blurred sigma 2 px) then sees the outline's contrast. This shifts one
composite (bilinear, edge pixels replicated) by d px in four directions and scores each with
../shared/tools/score.py, so a camera's object image error (bench/bench_camrefine.py) can be read as
levels of rmse_object on that room: the shift alone, with everything else of the composite as it was.

`python bench/bench_object_shift.py ROOM_DIR COMPOSITE.png [--shifts 0,0.25,0.5,1]` (ROOM_DIR: a
benchmark folder with truth.png, truth_mask.png, background.png).
"""
from __future__ import annotations

import argparse
import importlib.util
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def _scorer():
    shared = Path(os.environ.get("PHOTOAR_SHARED", ROOT.parent / "shared"))
    spec = importlib.util.spec_from_file_location("score", shared / "tools" / "score.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.score


def shifted_scores(room: Path, composite: Path, shifts: list[float]) -> dict[float, list[float]]:
    """{d: [rmse_object shifted by d px right, down, left, up]} for each d (px)."""
    import cv2

    score = _scorer()
    img = cv2.imread(str(composite), cv2.IMREAD_COLOR)
    if img is None:
        raise SystemExit(f"{composite}: cannot read the composite")
    H, W = img.shape[:2]
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "shifted.png"
        for d in shifts:
            row = []
            for ang in (0, 90, 180, 270):
                M = np.float32([[1, 0, d * np.cos(np.radians(ang))], [0, 1, d * np.sin(np.radians(ang))]])
                cv2.imwrite(str(path), cv2.warpAffine(img, M, (W, H), flags=cv2.INTER_LINEAR,
                                                      borderMode=cv2.BORDER_REPLICATE))
                row.append(float(score(str(room), str(path))["rmse_object"]))
            out[d] = row
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("room", type=Path)
    ap.add_argument("composite", type=Path)
    ap.add_argument("--shifts", default="0,0.25,0.5,0.75,1,1.5", help="shifts, px, comma-separated")
    a = ap.parse_args()
    for d, row in shifted_scores(a.room, a.composite, [float(x) for x in a.shifts.split(",")]).items():
        print(f"shift {d:.2f} px: rmse_object right / down / left / up " + " / ".join(f"{v:.2f}" for v in row)
              + f"  (mean {np.mean(row):.2f})", flush=True)


if __name__ == "__main__":
    sys.exit(main())
