"""Speed-against-error reporting: aligned text tables and simple line plots (drawn with OpenCV,
which the stack already has, so no plotting library is needed)."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

_COLOURS = [(200, 90, 30), (40, 140, 230), (60, 170, 60), (180, 60, 180), (30, 30, 200)]  # BGR


def table(rows: list[dict], columns: list[str], floatfmt: str = ".3g") -> str:
    """Plain-text table of `rows` (dicts) with the given column order."""
    def fmt(v):
        if isinstance(v, float):
            return format(v, floatfmt)
        return str(v)

    cells = [[fmt(r.get(c, "")) for c in columns] for r in rows]
    widths = [max(len(c), *(len(row[i]) for row in cells)) if cells else len(c) for i, c in enumerate(columns)]
    line = "  ".join(c.rjust(w) for c, w in zip(columns, widths))
    sep = "  ".join("-" * w for w in widths)
    body = ["  ".join(v.rjust(w) for v, w in zip(row, widths)) for row in cells]
    return "\n".join([line, sep, *body])


def plot_xy(series: dict[str, tuple[list[float], list[float]]], xlabel: str, ylabel: str, path: str | Path,
            title: str = "", logx: bool = False, size: tuple[int, int] = (720, 480)) -> None:
    """Line plot with markers of named (x, y) series into a PNG."""
    import cv2

    W, H = size
    ml, mr, mt, mb = 70, 20, 40, 50
    img = np.full((H, W, 3), 255, np.uint8)
    xs = [x for s in series.values() for x in s[0]]
    ys = [y for s in series.values() for y in s[1]]
    if not xs:
        raise ValueError("nothing to plot")
    tx = (lambda v: math.log10(v)) if logx else (lambda v: v)
    x0, x1 = min(map(tx, xs)), max(map(tx, xs))
    y0, y1 = 0.0, max(ys) * 1.1 if max(ys) > 0 else 1.0
    x1 = x1 if x1 > x0 else x0 + 1
    px = lambda v: int(ml + (tx(v) - x0) / (x1 - x0) * (W - ml - mr))
    py = lambda v: int(H - mb - (v - y0) / (y1 - y0) * (H - mt - mb))
    cv2.rectangle(img, (ml, mt), (W - mr, H - mb), (0, 0, 0), 1)
    for k in range(5):
        yv = y0 + (y1 - y0) * k / 4
        cv2.line(img, (ml - 4, py(yv)), (ml, py(yv)), (0, 0, 0), 1)
        cv2.putText(img, f"{yv:.3g}", (5, py(yv) + 4), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
    for xv in sorted(set(xs)):
        cv2.line(img, (px(xv), H - mb), (px(xv), H - mb + 4), (0, 0, 0), 1)
        cv2.putText(img, f"{xv:.3g}", (px(xv) - 12, H - mb + 18), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1,
                    cv2.LINE_AA)
    cv2.putText(img, xlabel, (W // 2 - 60, H - 12), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(img, ylabel, (5, mt - 12), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    if title:
        cv2.putText(img, title, (ml + 150, mt - 12), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    for k, (name, (sx, sy)) in enumerate(series.items()):
        col = _COLOURS[k % len(_COLOURS)]
        pts = sorted(zip(sx, sy))
        for (a, b), (c, d) in zip(pts, pts[1:]):
            cv2.line(img, (px(a), py(b)), (px(c), py(d)), col, 2, cv2.LINE_AA)
        for a, b in pts:
            cv2.circle(img, (px(a), py(b)), 4, col, -1, cv2.LINE_AA)
        cv2.putText(img, name, (W - mr - 170, mt + 20 + 18 * k), cv2.FONT_HERSHEY_SIMPLEX, 0.5, col, 1, cv2.LINE_AA)
    from recon.io import write_png

    write_png(path, img[..., ::-1])  # drawn in OpenCV's BGR


def stages_ms(stats: dict) -> dict[str, float]:
    """The engine's per-phase frame timings (Frame.stats["timings"], seconds) in milliseconds,
    in the order the frame runs them."""
    return {k: 1e3 * float(v) for k, v in stats.get("timings", {}).items()}


def mean_stages_ms(all_stats: list[dict]) -> dict[str, float]:
    """Per-phase mean milliseconds over several frames (phases missing from a frame count as 0)."""
    names = list(dict.fromkeys(k for s in all_stats for k in s.get("timings", {})))
    return {k: 1e3 * float(np.mean([s.get("timings", {}).get(k, 0.0) for s in all_stats])) for k in names}
