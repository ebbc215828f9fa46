"""The click model's windows and lamps (recon/clickmodel.py): four corners on a clicked wall or the
ceiling -> an axis-aligned quad on that plane, refined against the photo's edges."""
from __future__ import annotations

import numpy as np

from recon.io import json_bool, json_field
from recon.clickbase import (FACES, QUAD_OFFSET_M, TOLERANCE_M, WALL_TOL_M, Wall, Z99, _Clicks, _reproject_fit,
                             axis_vector, hit_plane, ray)


def _quad(P: _Clicks, c: dict, where: str, name: str, role: str, lo, hi, wall_of: dict[str, Wall]) -> dict:
    """A window / lamp click -> its quad entry on a clicked wall or the ceiling."""
    on = json_field(c, "on", where + ".", P.src)
    opening = json_bool(c, "opening", where + ".", P.src)
    if opening and role != "window":
        raise P.err(where, "only a window can be an opening (a hole in its wall)")
    uv = P.pixels(c, "corners", 4, where, nulls=True)
    if on == "ceiling":
        if opening:
            raise P.err(where, "an opening must be on a wall")
        axis, offset, inward, plane_sd = 1, float(hi[1]), -1.0, P.ceiling_sd
    elif on in wall_of:
        w = wall_of[on]
        axis, offset, inward, plane_sd = w.axis, w.offset, -float(w.side), w.sd
    else:
        raise P.err(where, f"'on' must be 'ceiling' or a clicked wall's name ({', '.join(sorted(wall_of))}), got {on!r}")
    n = axis_vector(axis)
    pts = np.full((4, 3), np.nan)
    for k in range(4):
        if not np.isfinite(uv[k, 0]):
            continue
        p = hit_plane(P.camera, uv[k], n, offset)
        if p is None:
            raise P.err(where, f"corners[{k}] = [{uv[k][0]:g}, {uv[k][1]:g}] is off its {on} (its ray does not meet "
                               f"that plane in front of the camera)")
        for ax in range(3):
            if ax == axis:
                continue
            for side, bound in ((-1, lo[ax]), (1, hi[ax])):
                if np.isfinite(bound) and side * (p[ax] - bound) > WALL_TOL_M:
                    what = "floor" if (ax, side) == (1, -1) else "ceiling" if ax == 1 else FACES[(ax, side)] + " wall"
                    raise P.err(where, f"corners[{k}] = [{uv[k][0]:g}, {uv[k][1]:g}] is off its {on}: it meets that "
                                       f"plane {side * (p[ax] - bound):.2f} m beyond the {what}")
        pts[k] = p
    known = [k for k in range(4) if np.isfinite(pts[k, 0])]
    if len(known) < 2:
        raise P.err(where, "at least two of the four corners must be clicked")
    u_ax, v_ax = [a for a in range(3) if a != axis]
    # which corners share a side: c0-c1 an edge along u (c0, c3 at one u end) or along v (c0, c1 at one)
    best = None
    for groups_u in (((0, 3), (1, 2)), ((0, 1), (2, 3))):
        groups_v = ((0, 1), (2, 3)) if groups_u == ((0, 3), (1, 2)) else ((0, 3), (1, 2))
        spread = 0.0
        for ax, groups in ((u_ax, groups_u), (v_ax, groups_v)):
            for g in groups:
                vals = [pts[k, ax] for k in g if k in known]
                spread += float(np.ptp(vals)) if len(vals) > 1 else 0.0
        if best is None or spread < best[0]:
            best = (spread, groups_u, groups_v)
    _, groups_u, groups_v = best
    size = P.sizes(c, where)
    rect, ends_all, missing = [], [], []
    for ax, groups in ((u_ax, groups_u), (v_ax, groups_v)):
        k_size = (1 if ax == 1 else 0) if axis != 1 else (0 if ax == 0 else 1)  # size_m: [across, up] / [x, z]
        ends = [[pts[k, ax] for k in g if k in known] for g in groups]
        ends = [float(np.mean(e)) if e else None for e in ends]
        missing += [e is None for e in ends]
        for i in (0, 1):
            if ends[i] is None:
                # the unclicked corners: the clicked ones of the opposite side moved to this end
                anchors = [pts[k] for k in groups[1 - i] if k in known]

                def corners(end, anchors=anchors, ax=ax):
                    return [q + (end - q[ax]) * axis_vector(ax) for q in anchors]

                ends[i] = P.missing_end(where, ends[1 - i], size, k_size, corners)
        ends_all += ends
    if P.edges is not None:
        ends_all = _refine_quad(P, name, axis, offset, (u_ax, v_ax), (groups_u, groups_v), np.array(ends_all),
                                missing, known, uv, plane_sd)
    for q, ax in enumerate((u_ax, v_ax)):
        a, b = sorted(ends_all[2 * q:2 * q + 2])
        if b - a < 0.02:
            raise P.err(where, f"its corners span {(b - a) * 100:.1f} cm along {'xyz'[ax]}: click the four corners "
                               "in order around it")
        lo_ax = lo[ax] if np.isfinite(lo[ax]) else -np.inf
        hi_ax = hi[ax] if np.isfinite(hi[ax]) else np.inf
        rect.append((max(a, lo_ax), min(b, hi_ax)))
    plane = offset + (0.0 if opening else inward * QUAD_OFFSET_M)
    corners = np.zeros((4, 3))
    for k, (i, j) in enumerate([(0, 1), (1, 1), (1, 0), (0, 0)]):  # (u, v) index: top row first
        corners[k, axis] = plane
        corners[k, u_ax] = rect[0][i]
        corners[k, v_ax] = rect[1][j]
    normal = inward * n
    if np.dot(np.cross(corners[1] - corners[0], corners[3] - corners[0]), normal) > 0:
        corners = corners[[1, 0, 3, 2]]  # the benchmark's winding: (c1-c0) x (c3-c0) against the normal
    q = {"name": name, "type": "quad", "role": role, "corners": corners.tolist(), "normal": normal.tolist(),
         "on": on}
    if opening:
        q["opening"] = True
    return q


def _refine_quad(P: _Clicks, name: str, axis: int, offset: float, axes: tuple[int, int], groups, x0: np.ndarray,
                 missing: list[bool], known: list[int], uv: np.ndarray, plane_sd: float = 0.0) -> np.ndarray:
    """A quad's side coordinates x0 (4,: the two ends along axes[0], then along axes[1]; end i holds
    the corners groups[.][i]) refined with its four sides snapped to the photo (recon/clickedges.py;
    an emitter's clipped edge is used). An end no clicked corner lies on keeps its distance to the
    opposite end (size_m). The quad is reported ill-determined when its corners are pinned worse
    than TOLERANCE_M (at Z99 sigma): its sides' own uncertainty and its plane's (plane_sd, m: the
    wall's or the ceiling's), carried through the fit (a quad seen at a grazing angle moves along its
    plane many times what its plane moves)."""
    idx = [[next(i for i in (0, 1) if k in groups[q][i]) + 2 * q for q in (0, 1)] for k in range(4)]
    active = [m for m in range(4) if not missing[m]]

    def corners(y, plane=offset):
        x = x0.copy()
        x[active] = y
        for m in range(4):
            if missing[m]:
                x[m] = x[m ^ 1] + (x0[m] - x0[m ^ 1])
        out = np.zeros((4, 3))
        out[:, axis] = plane
        for k in range(4):
            out[k, axes[0]], out[k, axes[1]] = x[idx[k][0]], x[idx[k][1]]
        return out

    def clicks(y):
        return corners(y)[known]

    y0 = x0[active]
    y = _reproject_fit(y0, clicks, uv[known], P.camera)
    lines = P.edges.lines(corners(y), [(0, 1), (1, 2), (2, 3), (3, 0)], P.blocker(name), clipped_ok=True, faint=True)
    y, kept = P.edges.refine_lines(y, corners, clicks, uv[known], lines)
    P.refined[name] = f"{len(kept)} edges snapped" if kept else "as clicked"
    sd = P.edges.sd(y, corners, clicks, kept)
    if plane_sd > 0:  # the fit on the plane moved by 1 mm, scaled to the plane's sigma
        dp = 1e-3
        y2 = P.edges.fit(y, lambda q: corners(q, offset + dp), lambda q: corners(q, offset + dp)[known],
                         uv[known], kept)
        sd = np.sqrt(sd ** 2 + ((y2 - y) / dp * plane_sd) ** 2)
    worst = float(np.sqrt(np.max(sd) ** 2 + plane_sd ** 2)) if len(sd) else plane_sd
    if not Z99 * worst <= TOLERANCE_M:
        P.uncertain[name] = {"corners": worst}
    x = x0.copy()
    x[active] = y
    for m in range(4):
        if missing[m]:
            x[m] = x[m ^ 1] + (x0[m] - x0[m ^ 1])
    return x
