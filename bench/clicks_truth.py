"""Clicks a user would make on a benchmark room's photo, made by projecting the room's TRUE corners
with the TRUE camera and adding Gaussian pixel noise (seeded): wall floor lines, one wall-ceiling
edge, three footprint corners and a top corner per furniture piece, four corners per window/lamp.
Only what the photo shows is clicked (points in front of the camera and inside the frame).
Shared by tests/recon/test_clickmodel.py and tests/app/test_model_clicks.py."""
from __future__ import annotations

import numpy as np

from recon.camera import Camera

FACES = {"left": (0, 0), "right": (0, 1), "back": (2, 0), "front": (2, 1)}  # face -> (axis, side)
MARGIN_PX = 4.0  # a click is kept this far inside the frame (so that noise keeps it inside)
MIN_LINE_PX = 80.0  # a wall's visible foot shorter than this is not clicked


def _visible(cam: Camera, P: np.ndarray) -> np.ndarray:
    uv, z = cam.project(P)
    w, h = cam.width, cam.height
    return (z > 0.05) & (uv[:, 0] >= MARGIN_PX) & (uv[:, 0] <= w - 1 - MARGIN_PX) & \
        (uv[:, 1] >= MARGIN_PX) & (uv[:, 1] <= h - 1 - MARGIN_PX)


def _edge_samples(lo, hi, axis: int, side: int, y: float, n: int = 400) -> np.ndarray:
    """n points along the horizontal line at height y on face (axis, side) of the room box [lo, hi]."""
    along = 2 - axis
    P = np.zeros((n, 3))
    P[:, axis] = (lo, hi)[side][axis]
    P[:, along] = np.linspace(lo[along], hi[along], n)
    P[:, 1] = y
    return P


def furniture_groups(scene: dict) -> list[dict]:
    """The scene's furniture as the user would model it: {"name", "kind" desk|box, "x", "z" (ranges),
    "top" (m)}; a desk is a "<name>_top" box with "<name>_leg*" boxes."""
    boxes = [p for p in scene["primitives"] if p.get("role") == "furniture" and p["type"] == "box"]
    out = []
    for p in boxes:
        if "_leg" in p["name"]:
            continue
        c, s = np.array(p["center"]), np.array(p["size"])
        lo, hi = c - s / 2, c + s / 2
        desk = p["name"].endswith("_top") and any(q["name"].startswith(p["name"][:-4] + "_leg") for q in boxes)
        out.append({"name": p["name"][:-4] if desk else p["name"], "kind": "desk" if desk else "box",
                    "x": (lo[0], hi[0]), "z": (lo[2], hi[2]), "top": hi[1], "bottom": lo[1]})
    return out


def _unhidden(cam: Camera, scene: dict, g: dict, P: np.ndarray) -> np.ndarray:
    """(m,) bool: furniture group g's corners P (m,3) that no piece hides (the true boxes: another
    piece, or g's own box; a desk's own top slab), as recon/clickfurniture._shown judges them."""
    from recon.clickbase import _Clicks
    from recon.clickfurniture import _shown

    boxes = [p for p in scene["primitives"] if p.get("role") == "furniture" and p["type"] == "box"]
    desk = g["kind"] == "desk"
    own = next(p for p in boxes if p["name"] == (g["name"] + "_top" if desk else g["name"]))
    if not desk:  # the group's own box from the floor (or what it stands on) up, as the clicks model it
        lo = np.array([g["x"][0], g.get("base", 0.0), g["z"][0]])
        hi = np.array([g["x"][1], g["top"], g["z"][1]])
        own = {"name": g["name"], "center": ((lo + hi) / 2).tolist(), "size": (hi - lo).tolist()}
    others = [b for b in boxes if b["name"] != g["name"] and not b["name"].startswith(g["name"] + "_")]
    return _shown(_Clicks(cam, "truth", None, others), g["name"], np.atleast_2d(P), own)


def support(groups: list[dict], g: dict) -> dict | None:
    """The group g stands on: one whose top is g's bottom (within 5 mm) and whose footprint holds g's
    footprint's centre; None for a piece on the floor."""
    if g["bottom"] < 0.005:
        return None
    cx, cz = sum(g["x"]) / 2, sum(g["z"]) / 2
    return next((o for o in groups if o is not g and abs(o["top"] - g["bottom"]) < 0.005
                 and o["x"][0] <= cx <= o["x"][1] and o["z"][0] <= cz <= o["z"][1]), None)


def true_clicks(scene: dict, sigma_px: float = 1.0, seed: int = 0, wall_points: int = 2, seen_only: bool = False,
                stacked: bool = False, hidden_marked: bool = False) -> tuple[dict, dict]:
    """(clicks dict with `wall_points` points on each wall's foot, what was clicked: {"walls": [faces], "ceiling": bool, "furniture": [names],
    "quads": [names], "skipped": [names]}) for a benchmark scene.json dict. With `seen_only`, a
    furniture corner another piece or the piece itself hides is not clicked either (as a user who
    clicks only what they see: null, with the footprint's sizes in size_m, measured), and a piece
    with no visible floor corner under its top click is skipped. With `stacked`, a piece standing on
    another (a sofa's back on its seat: bench `support`) is clicked as such: `"on"` names that one and
    its `floor` corners are where it meets that one's top (else its footprint's corners on the floor
    under it, hidden or not). With `hidden_marked` (and seen_only), a null floor corner that lies in
    the frame behind a piece is listed in the click's "hidden" (the user saw where it is)."""
    rng = np.random.default_rng(seed)
    mc = scene["main_camera"]
    cam = Camera.from_json(mc, "scene.json", "main_camera.")
    lo, hi = np.array(scene["world"]["room_min"], float), np.array(scene["world"]["room_max"], float)

    def px(P: np.ndarray) -> list:
        uv, _ = cam.project(np.atleast_2d(P))
        uv = uv + rng.normal(0.0, sigma_px, uv.shape)
        uv = np.clip(uv, [-0.5, -0.5], [cam.width - 0.5, cam.height - 0.5])
        return uv.tolist() if np.ndim(P) == 2 else uv[0].tolist()

    clicks, done = [], {"walls": [], "ceiling": False, "furniture": [], "quads": [], "skipped": []}
    for face, (axis, side) in FACES.items():
        P = _edge_samples(lo, hi, axis, side, lo[1])
        P = P[_visible(cam, P)]
        if len(P) < 2:
            continue
        uv, _ = cam.project(P[[0, -1]])
        if np.linalg.norm(uv[1] - uv[0]) < MIN_LINE_PX:
            continue
        s = np.linspace(0.1, 0.9, wall_points)[:, None]
        clicks.append({"label": "wall", "name": face, "floor_line": px(P[0] + s * (P[-1] - P[0]))})
        done["walls"].append(face)
        if not done["ceiling"]:
            E = _edge_samples(lo, hi, axis, side, hi[1])
            E = E[_visible(cam, E)]
            if len(E):
                clicks.append({"label": "ceiling", "wall": face, "edge": px(E[len(E) // 2])})
                done["ceiling"] = True
    groups = furniture_groups(scene)
    for g in groups:
        (x0, x1), (z0, z1) = g["x"], g["z"]
        under = support(groups, g) if stacked else None
        base = g["bottom"] if under is not None else 0.0
        if under is not None:
            g = {**g, "base": base}
        ring = np.array([[x0, base, z0], [x1, base, z0], [x1, base, z1], [x0, base, z1]])
        best = None
        for k in range(4):
            for step in (1, -1):
                idx = [k, (k + step) % 4, (k + 2 * step) % 4]
                top = ring[k] + [0, g["top"] - base, 0]
                vis = _visible(cam, ring[idx])
                top_vis = _visible(cam, top[None])[0]
                framed = vis.copy()
                if seen_only:
                    vis = vis & _unhidden(cam, scene, g, ring[idx])
                    top_vis = top_vis and bool(_unhidden(cam, scene, g, top)[0])
                if not (vis[0] and vis.sum() >= 2 and top_vis):
                    continue
                uv, _ = cam.project(ring[idx])
                score = (int(vis.sum()), float(np.linalg.norm(uv[1] - uv[0]) + np.linalg.norm(uv[2] - uv[1])))
                if best is None or score > best[0]:
                    best = (score, idx, top, vis, framed)
        if best is None:
            done["skipped"].append(g["name"])
            continue
        _, idx, top, vis, framed = best
        floor = [px(ring[i]) if v else None for i, v in zip(idx, vis)]
        c = {"label": "furniture", "name": g["name"], "kind": g["kind"], "floor": floor, "top": px(top)}
        if hidden_marked and (framed & ~vis).any():  # null corners seen to lie in the photo, behind a piece
            c["hidden"] = [int(k) for k in np.flatnonzero(framed & ~vis)]
        if under is not None:
            c["on"] = under["name"]
        if not vis.all():  # the user measures the footprint's sides
            c["size_m"] = [float(np.linalg.norm(ring[idx[0]] - ring[idx[1]])),
                           float(np.linalg.norm(ring[idx[2]] - ring[idx[1]]))]
        clicks.append(c)
        done["furniture"].append(g["name"])
    for p in scene["primitives"]:
        if p.get("role") not in ("window", "lamp", "ceiling_lamp", "point_lamp") or p["type"] != "quad":
            continue
        C = np.array(p["corners"], float)
        n = np.array(p["normal"], float)
        k = int(np.argmax(np.abs(n)))
        if not any(np.all(np.abs(C[:, k] - b[k]) < 0.01) for b in (lo, hi)):
            done["skipped"].append(p["name"])  # not on a wall or the ceiling (a lamp hanging in the room)
            continue
        if k == 1:
            on = "ceiling"
        else:
            on = next(f for f, (axis, side) in FACES.items() if axis == k and (side == 0) == (n[k] > 0))
        vis = _visible(cam, C)
        if vis.sum() < 2 or (on != "ceiling" and on not in done["walls"]):
            done["skipped"].append(p["name"])
            continue
        role = "window" if p["role"] == "window" else "lamp"
        c = {"label": role, "name": p["name"], "on": on, "corners": [px(X) if v else None for X, v in zip(C, vis)],
             "opening": bool(p.get("opening", False))}
        if not vis.all():
            ext = C.max(0) - C.min(0)
            c["size_m"] = [float(ext[0]), float(ext[2])] if on == "ceiling" else [float(ext[2 - k]), float(ext[1])]
        clicks.append(c)
        done["quads"].append(p["name"])
    return {"clicks": clicks}, done


def tape_asked(scene: dict, clicks: dict, measure: dict, tape_error_m: float = 0.0) -> dict:
    """A copy of clicks with each size the model asked to tape (ClickModel.measure / primitives.json's
    `model.measure`: piece -> [{"size_m": index, "along": "x" | "z", ...}]) given in that piece's
    size_m: the truth's length of the piece along that axis plus tape_error_m (m), as a user with a tape
    measure answers the model's warning (the other entry stays as it was, or null)."""
    import copy

    groups = {g["name"]: g for g in furniture_groups(scene)}
    out = copy.deepcopy(clicks)
    for c in out["clicks"]:
        for ask in measure.get(c.get("name"), []) if c.get("label") == "furniture" else []:
            g = groups[c["name"]]
            lo, hi = g[ask["along"]]
            sizes = list(c.get("size_m") or [None, None])
            sizes[ask["size_m"]] = float(hi - lo) + tape_error_m
            c["size_m"] = sizes
    return out
