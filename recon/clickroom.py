"""The click model's walls (recon/clickmodel.py): a wall's offset from its floor line's clicks, and
the clicked walls and ceiling refined together against the photo (recon/clickedges.py)."""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from recon.camera import Camera
from recon.clickbase import TOLERANCE_M, Wall, Z99, _Clicks, _reproject_fit, axis_vector, hit_plane


def _refine_room(P: _Clicks, walls: dict[str, Wall], ceil_clicks: list[tuple[Wall, np.ndarray]], lo: np.ndarray,
                 hi: np.ndarray, ceiling_known: bool) -> None:
    """The clicked walls' offsets and the ceiling's height refined together against the photo (in
    place: walls, lo, hi, P.refined): each wall's foot alone fixes it only where its foot snapped,
    but the room's other straight edges hold it too: the vertical corner where two clicked walls
    meet (through the known camera it fixes the one wall's offset once the other's is known) and
    each wall's ceiling edge (with a known ceiling). One least-squares fit in pixels of every wall
    and ceiling click and every snapped line (recon/clickedges.PhotoEdges.refine_lines), started
    from the walls fitted one by one; it keeps them when it fails. With the ceiling from clicks,
    its height is a parameter too; with the ceiling unknown (the default), the corner lines are
    snapped up to the camera's height only (the ceiling is surely above it) and no ceiling edge is."""
    cam = P.camera
    ws = list(walls.values())
    nw = len(ws)
    free_h = bool(ceil_clicks)
    nh = int(free_h)
    x0, owner, uv = [w.offset for w in ws] + ([float(hi[1])] if free_h else []), [], []
    for k, w in enumerate(ws):
        for p, q in zip(w.points, w.uv):
            x0.append(float(p[2 - w.axis]))
            owner.append((k, False))
            uv.append(q)
    for w, q in ceil_clicks:
        k = ws.index(w)
        p = hit_plane(cam, q, axis_vector(w.axis), w.offset)
        x0.append(float(p[2 - w.axis]))
        owner.append((k, True))
        uv.append(q)
    x0, uv = np.array(x0, float), np.array(uv, float)

    def height(x):
        return float(x[nw]) if free_h else float(hi[1])

    def clicks(x):
        out = np.zeros((len(owner), 3))
        for j, (k, up) in enumerate(owner):
            w = ws[k]
            out[j, w.axis], out[j, 2 - w.axis], out[j, 1] = x[k], x[nw + nh + j], height(x) if up else 0.0
        return out

    # the ends of the lines to fit (callables x -> (3,)) and which walls each line touches
    ends: list = []  # each: callable x -> (3,)
    lines, touches = [], []
    for k, w in enumerate(ws):  # the feet already snapped
        for s, e, L in w.feet:
            for q in (s, e):
                ends.append(lambda x, q=q, k=k, a=w.axis: np.where(np.arange(3) == a, x[k], q * [1, 0, 1]))
            lines.append(replace(L, i=len(ends) - 2, j=len(ends) - 1, t0=0.0, t1=1.0))
            touches.append(("foot", (k,)))
    top = (lambda x: height(x)) if ceiling_known else (lambda x: float(cam.centre[1]))
    model_pairs, model_touch = [], []
    for k1, w1 in enumerate(ws):  # vertical corners of two clicked walls
        for k2, w2 in enumerate(ws):
            if w1.axis == 0 and w2.axis == 2:
                for y in (0, 1):
                    ends.append(lambda x, k1=k1, k2=k2, y=y: np.array([x[k1], y * top(x), x[k2]]))
                model_pairs.append((len(ends) - 2, len(ends) - 1))
                model_touch.append(("corner", (k1, k2)))
    if ceiling_known:
        for k, w in enumerate(ws):  # each wall's ceiling edge, between its neighbours or its clicks
            along = 2 - w.axis
            pos = [p[along] for p in w.points]
            rng = [lo[along] if np.isfinite(lo[along]) else min(pos), hi[along] if np.isfinite(hi[along]) else max(pos)]
            kk = [next((m for m, v in enumerate(ws) if v.axis == along and v.side == sd), None) for sd in (-1, 1)]
            for r, m in zip(rng, kk):
                ends.append(lambda x, k=k, a=w.axis, al=along, r=r, m=m:
                            np.where(np.arange(3) == a, x[k],
                                     np.where(np.arange(3) == al, r if m is None else x[m], height(x))))
            model_pairs.append((len(ends) - 2, len(ends) - 1))
            model_touch.append(("ceiling", (k,)))

    def corners(x):
        return np.array([f(x) for f in ends]) if ends else np.zeros((0, 3))

    if model_pairs:
        from recon.clickedges import box_edges_px

        found = P.edges.lines(corners(x0), model_pairs, P.blocker(""), faint=True,
                              others=box_edges_px(cam, P.occluders))
        by_pair = {pair: t for pair, t in zip(model_pairs, model_touch)}
        lines += found
        touches += [by_pair[(L.i, L.j)] for L in found]
    x, kept = P.edges.refine_lines(x0, corners, clicks, uv, lines) if lines else (x0, [])
    sd = P.edges.sd(x, corners, clicks, kept)
    if free_h:
        P.ceiling_sd = float(sd[nw])
    from recon.clickedges import LINE_SIGMA_FLOOR_PX

    for k, w in enumerate(ws):  # a wall its clicks and the photo pin worse than TOLERANCE_M (at Z99 sigma)
        w.sd = float(sd[k])
        P.wall_sd[(w.axis, w.side)] = max(w.sd, LINE_SIGMA_FLOOR_PX * _foot_metres_per_px(cam, w))
        if not Z99 * sd[k] <= TOLERANCE_M:
            for name in w.labels:
                P.uncertain[name] = {"offset": float(sd[k])}
    if not kept:
        return
    kept_touch = [touches[next(i for i, M in enumerate(lines) if M is L)] for L in kept]
    for k, w in enumerate(ws):
        w.offset = float(x[k])
        (lo if w.side < 0 else hi)[w.axis] = w.offset
        what = {t: sum(1 for kind, ks in kept_touch if kind == t and k in ks) for t in ("foot", "corner", "ceiling")}
        if any(what.values()):
            words = [f"{n} {label}" for n, label in ((what["foot"], "stretches of its foot"),
                                                       (what["corner"], "corner lines"),
                                                       (what["ceiling"], "ceiling edges")) if n]
            for name in w.labels:
                P.refined[name] = ", ".join(words) + " snapped"
    if free_h:
        hi[1] = height(x)


def _foot_metres_per_px(camera: Camera, w: Wall) -> float:
    """Metres wall w's offset moves per pixel its foot line moves across itself in the photo (the
    mean over its floor clicks; a far wall seen at a grazing angle: centimetres)."""
    n, a = axis_vector(w.axis), axis_vector(2 - w.axis)
    out = []
    for p in w.points:
        uv, z = camera.project(np.array([p, p + 0.01 * a, p + 0.01 * n]))
        if not np.all(z > 0):
            continue
        d = uv[1] - uv[0]
        across = abs(float((uv[2] - uv[0]) @ np.array([-d[1], d[0]]) / max(np.linalg.norm(d), 1e-12)))
        if across > 0:
            out.append(0.01 / across)
    return float(np.mean(out)) if out else 0.0


def _wall_offset(camera: Camera, points: list[np.ndarray], uv: np.ndarray, axis: int, edges=None,
                 feet: list | None = None) -> tuple[float, int]:
    """(the wall's coordinate along `axis` (m) whose foot line (y = 0) passes nearest the clicks uv
    (m,2) in pixels, the number of snapped stretches used); each click's position along the wall
    is a free parameter. Starts from the mean of the clicks' floor points `points`. With `edges`
    (recon.clickedges.PhotoEdges) and `feet` (stretches of the foot snapped to the photo: (start,
    end, EdgeLine)), the snapped lines join the fit (PhotoEdges.refine)."""
    from dataclasses import replace

    along = 2 - axis
    x0 = np.r_[np.mean([p[axis] for p in points]), [p[along] for p in points]]
    uv = np.asarray(uv, np.float64)

    def pts(x):
        out = np.zeros((len(points), 3))
        out[:, axis], out[:, along] = x[0], x[1:]
        return out

    x = _reproject_fit(x0, pts, uv, camera)
    if edges is None or not feet:
        return float(x[0]), 0
    ends = np.array([q for s, e, _ in feet for q in (s, e)])
    lines = [replace(L, i=2 * k, j=2 * k + 1, t0=0.0, t1=1.0) for k, (_, _, L) in enumerate(feet)]

    def corners(x):
        out = ends.copy()
        out[:, axis], out[:, 1] = x[0], 0.0
        return out

    x, kept = edges.refine(x, corners, pts, uv, lines)
    return float(x[0]), kept
