"""Where a sun room's extra darkness sits under known light (issue 34: energy ratio above 1).

usage: python bench/bench_sunshadow109.py ROOM_DIR:COMPOSITE.png [...]

Per room, score.py's own figures (8-bit luminance blurred with sigma 2 px; 'affected' = outside the dilated object
mask, |truth - background| > 2 levels) and the energy split over parts of the affected region:
  sunlit        the background's sunlit pixels: Otsu split of log luminance of background.exr (clean render), the
                bright class
    core        sunlit, the truth's darkening (bg - truth) above half the sunlit region's 99th percentile of it
                and more than 3 px from the core's outline (the sun shadow's umbra)
    edge        sunlit, within 3 px of that outline (either side: the penumbra and the blur)
    rest        sunlit, the rest (indirect shadow inside the sunlit patch)
  unlit         the rest of the affected region, split where our composite is brighter than the background (the
                light the sunlit object reflects onto the room) and darker (the indirect shadow); split on ours,
                not the truth's sign, whose render noise would bias each side's truth away from ours; each
                again within NEAR_PX of the object's dilated mask and beyond
  the last row: outside the mask and the sunlit patch, ours brighter than the background by more than 2 levels,
                affected or not (chosen on ours alone: no selection on the truth's render noise)
For each: pixels, the truth's darkening sum(bg - truth), ours sum(bg - ours), ours - truth (levels x px; its share
of the total excess) and the clipped share (background blurred luminance >= 250).
Images only (no engine; seconds a room); COMPOSITE is `photoar evaluate ROOM --passes all`'s composite_all.png.
"""
from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from recon.io import read_exr  # noqa: E402

NEAR_PX = 20  # the unlit parts split again at this distance from the object's dilated mask (px)
LUMA_BGR = np.array([0.0722, 0.7152, 0.2126])


def _lum8(path: Path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise SystemExit(f"cannot read {path}")
    return cv2.GaussianBlur(img.astype(np.float64) @ LUMA_BGR, (0, 0), 2.0)


def _otsu(x: np.ndarray) -> float:
    """Otsu threshold of a 1-D sample (256 bins)."""
    h, e = np.histogram(x, 256)
    c = 0.5 * (e[1:] + e[:-1])
    w0 = np.cumsum(h)
    w1 = w0[-1] - w0
    m0 = np.cumsum(h * c) / np.maximum(w0, 1)
    m1 = (np.sum(h * c) - np.cumsum(h * c)) / np.maximum(w1, 1)
    return float(c[np.argmax(w0 * w1 * (m0 - m1) ** 2)])


def split(room: Path, comp: Path) -> dict[str, tuple[int, float, float, float]]:
    """Region -> (pixels, truth's darkening, ours, clipped share), in blurred 8-bit levels summed."""
    lb, lt, lc = _lum8(room / "background.png"), _lum8(room / "truth.png"), _lum8(comp)
    mk = cv2.imread(str(room / "truth_mask.png"), cv2.IMREAD_GRAYSCALE)
    mask = cv2.dilate((mk > 127).astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    aff = ~mask & (np.abs(lt - lb) > 2.0)
    ex = read_exr(room / "background.exr")[..., :3] @ np.array([0.2126, 0.7152, 0.0722])
    lex = np.log(np.maximum(cv2.GaussianBlur(ex.astype(np.float64), (0, 0), 2.0), 1e-6))
    sunlit = lex > _otsu(lex.ravel())
    d_t = lb - lt
    ref = np.percentile(d_t[aff & sunlit], 99) if (aff & sunlit).any() else np.inf
    core = sunlit & (d_t > 0.5 * ref)
    inner = cv2.erode(core.astype(np.uint8), np.ones((7, 7), np.uint8)) > 0
    outer = cv2.dilate(core.astype(np.uint8), np.ones((7, 7), np.uint8)) > 0
    parts = {"sunlit core": aff & sunlit & inner, "sunlit edge": aff & sunlit & outer & ~inner,
             "sunlit rest": aff & sunlit & ~outer, "unlit, ours brighter": aff & ~sunlit & (lb - lc < 0),
             "unlit, ours darker": aff & ~sunlit & (lb - lc >= 0)}
    near = cv2.distanceTransform((~mask).astype(np.uint8), cv2.DIST_L2, 5) <= NEAR_PX
    for k in ("unlit, ours brighter", "unlit, ours darker"):
        parts[k + f", <= {NEAR_PX} px"] = parts[k] & near
        parts[k + f", > {NEAR_PX} px"] = parts[k] & ~near
    parts["all affected"] = aff
    parts["unlit, ours brighter by > 2 (any)"] = ~mask & ~sunlit & (lb - lc < -2.0)  # chosen on ours alone
    return {k: (int(r.sum()), float(d_t[r].sum()), float((lb - lc)[r].sum()), float((lb[r] >= 250).mean()) if r.any()
                else 0.0) for k, r in parts.items()}


def main() -> None:
    if len(sys.argv) < 2 or sys.argv[1] in ("-h", "--help"):
        print(__doc__.strip())
        raise SystemExit(0 if sys.argv[1:2] in (["-h"], ["--help"]) else 2)
    print("| room | part | px | truth | ours | ours / truth | excess share | bg clipped |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    for arg in sys.argv[1:]:
        room, comp = (Path(s).expanduser() for s in arg.split(":", 1))
        s = split(room, comp)
        tot = s["all affected"][2] - s["all affected"][1]
        for k, (n, t, o, clip) in s.items():
            r = o / t if abs(t) > 1e-9 else float("nan")
            print(f"| {room.name} | {k} | {n} | {t:.0f} | {o:.0f} | {r:.3f} | {(o - t) / tot if tot else 0:+.2f} | "
                  f"{clip:.2f} |")


if __name__ == "__main__":
    main()
