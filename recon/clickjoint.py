"""A clicked wall and the pieces standing against it, solved together (for recon/clickmodel.py, with
the photo).

A wall's offset comes from its own floor-line clicks and foot edges; a piece held on it
(recon/clickfurniture._hold_on_walls) has its own fit of that side, from its clicks and edges,
independent of the wall's. Both measure one plane, so the plane's least-squares estimate is
their mean weighted by their inverse variances (the side's variance is d^2 / rise, as in
_against_chi2: the piece fit's chi-square rise when the side is moved d onto the wall). The hold
already puts each piece's side at the mean of the wall and that side alone; here the wall itself
takes every piece held on it, and each of those sides is moved to the one plane (pieces against
one wall share its face). A wall whose foot is grainy and seen at a grazing angle (1 px = 4-5 cm of
floor there) gains most: its two clicks are no surer than one piece's corners against it. The
windows and lamps on the wall are modelled after this, on the wall's new plane.
"""
from __future__ import annotations

import numpy as np

from recon.clickbase import Wall, _Clicks


def joint_walls(P: _Clicks, walls: dict[str, Wall], lo: np.ndarray, hi: np.ndarray,
                pieces: dict[str, list[dict]]) -> dict[str, float]:
    """Move each clicked wall in `walls` that pieces are held on (P.against: (axis, side) -> [(piece,
    its own fit of that side m, its variance m^2)]) to the inverse-variance mean of its offset (its
    variance P.wall_sd^2) and those sides; update lo / hi (the room box, m), the wall's sd and
    P.wall_sd, and stretch each such piece's boxes (`pieces`: name -> boxes, in place) along the
    wall's axis, its opposite side fixed, so that its held side lies on the new plane. A wall with
    no variance known (P.wall_sd 0) keeps its place. Returns {wall face: the move, m}."""
    moved: dict[str, float] = {}
    for w in walls.values():
        held = P.against.get((w.axis, w.side), [])
        var_w = P.wall_sd.get((w.axis, w.side), 0.0) ** 2
        if not held or not var_w > 0.0:
            continue
        weights = np.array([1.0 / var_w] + [1.0 / v for _, _, v in held])
        values = np.array([w.offset] + [s for _, s, _ in held])
        offset = float(weights @ values / weights.sum())
        sd = float(np.sqrt(1.0 / weights.sum()))
        moved[w.face] = offset - w.offset
        w.offset = offset
        (lo if w.side < 0 else hi)[w.axis] = offset
        P.wall_sd[(w.axis, w.side)] = sd
        w.sd = min(w.sd, sd) if w.sd > 0 else sd
        for name in {n for n, _, _ in held}:
            _stretch(pieces[name], w.axis, w.side, offset)
    return moved


def _stretch(boxes: list[dict], axis: int, side: int, plane: float) -> None:
    """Stretch upright, axis-aligned box entries (a piece's: a desk's slab and legs) along `axis` (0 or
    2), their common extent's end on `side` (-1 the min end, +1 the max end) moved to `plane` (m) and
    the opposite end fixed: each coordinate x goes to o + (x - o) (plane - o) / (end - o)."""
    lo = min(b["center"][axis] - b["size"][axis] / 2 for b in boxes)
    hi = max(b["center"][axis] + b["size"][axis] / 2 for b in boxes)
    end, o = (lo, hi) if side < 0 else (hi, lo)
    if end == o:
        return
    scale = (plane - o) / (end - o)
    for b in boxes:
        a0 = o + (b["center"][axis] - b["size"][axis] / 2 - o) * scale
        a1 = o + (b["center"][axis] + b["size"][axis] / 2 - o) * scale
        b["center"][axis] = (a0 + a1) / 2
        b["size"][axis] = abs(a1 - a0)
