"""Where a composite changes the room against the truth (issue 34 item 4; docs/unseen.md "photosun111").

score.py's regions and blurred 8-bit luminance (../shared/tools/score.py): over its `rest` pixels the share the
composite brightens / darkens by more than 2 levels (its `spurious` is their sum) and the mean change, ours and the
truth's; over its `affected` pixels the sums of bg - image split by whether the background clips (any channel >= 250,
blurred: the sunlit floor) and, for the unclipped ones, by the sign of the truth's change (the object's glow on the
room where the truth brightens, its shadows where it darkens). Images only: no product code runs.

`python bench/bench_photo_split111.py ROOM_DIR COMPOSITE.png [--image OUT.png]` (OUT: ours - bg and truth - bg,
16 per level about mid-grey, over the composite and the truth)
"""
from __future__ import annotations

import argparse

import cv2
import numpy as np


def lum(img: np.ndarray) -> np.ndarray:
    img = img.astype(np.float64)
    return 0.0722 * img[..., 0] + 0.7152 * img[..., 1] + 0.2126 * img[..., 2]  # BGR, as score.py


def split(room: str, comp: str) -> dict:
    bg, tr = cv2.imread(f"{room}/background.png"), cv2.imread(f"{room}/truth.png")
    mk, co = cv2.imread(f"{room}/truth_mask.png", cv2.IMREAD_GRAYSCALE), cv2.imread(comp)
    mask = cv2.dilate((mk > 127).astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    blur = lambda x: cv2.GaussianBlur(x, (0, 0), 2.0)  # noqa: E731
    lb, lt, lc = blur(lum(bg)), blur(lum(tr)), blur(lum(co))
    aff = ~mask & (np.abs(lt - lb) > 2)
    rest = ~mask & ~aff
    clip = blur((bg.max(2) >= 250).astype(float)) > 0.5
    d, dt = lc - lb, lt - lb
    out = {"rest_px": int(rest.sum()), "rest_brighter": float((d[rest] > 2).mean()),
           "rest_darker": float((d[rest] < -2).mean()), "rest_mean": float(d[rest].mean()),
           "rest_mean_truth": float(dt[rest].mean()), "object_bias": float((lc - lt)[mask].mean()),
           "d_img": d, "dt_img": dt, "co": co, "tr": tr}
    for name, m in (("clipped", aff & clip), ("unclipped", aff & ~clip), ("glow", aff & ~clip & (dt > 0)),
                    ("shadow", aff & ~clip & (dt < 0))):
        out[name] = (int(m.sum()), float(-d[m].sum()), float(-dt[m].sum()))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("room")
    ap.add_argument("composite")
    ap.add_argument("--image")
    a = ap.parse_args()
    s = split(a.room, a.composite)
    print(f"rest {s['rest_px']} px: brighter > 2 {s['rest_brighter']:.4f}, darker < -2 {s['rest_darker']:.4f}, mean "
          f"change {s['rest_mean']:+.3f} (truth {s['rest_mean_truth']:+.3f}); object bias {s['object_bias']:+.2f}")
    for k in ("clipped", "unclipped", "glow", "shadow"):
        n, ours, truth = s[k]
        print(f"affected {k:9s} {n:7d} px  sum(bg - ours) {ours / 1e3:8.1f}k  sum(bg - truth) {truth / 1e3:8.1f}k")
    if a.image:
        vis = lambda x: cv2.applyColorMap(np.clip(128 + 16 * x, 0, 255).astype(np.uint8), cv2.COLORMAP_JET)  # noqa
        cv2.imwrite(a.image, np.vstack([np.hstack([vis(s["d_img"]), vis(s["dt_img"])]), np.hstack([s["co"], s["tr"]])]))


if __name__ == "__main__":
    main()
