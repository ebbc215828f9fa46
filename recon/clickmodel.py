"""A room model from clicks on one calibrated photo: walls, ceiling, furniture, window and lamp quads.

Once the camera and the floor plane are known, a click on the floor is a 3-D point exactly (the
pixel's ray meets the floor), and a click on a known plane (a wall, the ceiling) likewise. The
clicks file (docs/scene-format.md, "Clicks file"):

    {"clicks": [
      {"label": "wall", "name": "back", "floor_line": [[u, v], [u, v]]},
      {"label": "ceiling", "wall": "back", "edge": [u, v]},
      {"label": "furniture", "name": "desk", "kind": "desk" | "box",
       "floor": [[u, v], [u, v], [u, v]], "top": [u, v]},
      {"label": "window" | "lamp", "name": "w1", "on": "back" | "ceiling",
       "corners": [[u, v], [u, v], [u, v], [u, v]], "opening": false}]}

A furniture piece may name another it stands on ("on": "desk"): its floor corners are then on that
piece's top and its box starts there (that piece is modelled first, _support_order).

Conventions: the camera's world frame (recon/camera.py; `photoar calibrate` puts the floor at
y = 0, +Y up, X and Z along the room's vanishing directions), metres; pixel (u, v) with (0, 0) the
centre of the top-left pixel, inside the photo.

Method:
  * a wall: its two (or more) floor points give a vertical plane, snapped to the nearer horizontal
    axis of the frame (the room is a box in the calibrated axes), its offset the one whose foot line
    passes nearest the clicks in pixels; its inside is the camera's side, which tells which of the box's faces it is (back =
    z min, front = z max, left = x min, right = x max). Two walls on the same face are one wall;
  * the ceiling: a click on a wall-ceiling edge is a point on that wall's plane; its height is the
    ceiling's (the mean over clicks). Else the height given, else DEFAULT_CEILING_M with a warning;
  * a furniture piece: three floor corners (floor[1] between floor[0] and floor[2]) give an upright
    rectangle (yaw from the two edges, snapped to the room axes within SNAP_DEG; each side the mean
    of the two corners on it); its height is where the vertical line over floor[0] passes closest to
    the top click's ray (least squares). A desk is a top slab DESK_TOP_M thick on four legs
    DESK_LEG_M square, set DESK_LEG_INSET_M in from the footprint's edges; a box is solid;
  * a window or lamp: four corners on a wall or the ceiling plane, fitted by the axis-aligned
    rectangle on that plane (each side the mean of the two corners nearer it); set QUAD_OFFSET_M in
    front of its surface (an emitter drawn on it), an opening (a hole in the wall) in it;
  * with the photo (model_from_clicks(photo=...)), each wall, piece and quad fitted from its clicks
    is refined: the edges of it the photo shows are snapped (recon/clickedges.py) and join its
    least-squares fit in pixels; what the photo does not confirm stays as clicked. The walls and
    the ceiling are then refitted together with the room's corner and ceiling edges (_refine_room);
    a piece's edges are snapped in rounds (_snap_and_refine; a desk's legs' vertical edges too: they
    see a move along the line of sight its top's edges do not), a side of it that is one plane with
    a clicked wall, or a face of a piece modelled before it, within both their noises is put against it
    (_hold_on_walls, _piece_planes; a side only clicks on
    hidden corners place is not judged: _shown), and a side pinned worse than TOLERANCE_M (at 99 %)
    is reported ill-determined (ClickModel.uncertain, a warning). The furniture is modelled before
    the windows and lamps: a clicked wall then takes the pieces held on it (recon/clickjoint.py: its
    offset and their own fits of their sides on it, by their inverse variances; their sides on the
    one plane), and the quads on it are fitted on that plane;
  * walls that no click shows are placed WALL_MARGIN_M beyond the camera (recon/roomfit.py's rule:
    the photographer stands between the camera and the wall behind), and beyond every clicked
    primitive, and flagged guessed.

Stages: recon/clickbase.py (constants, the model's types, rays, the clicks file's parsing),
recon/clickroom.py (walls and ceiling), recon/clickfurniture.py (pieces), recon/clickjoint.py (a wall
with the pieces against it), recon/clickquad.py (windows and lamps); this module runs them (model_from_clicks) and draws a primitive's edges (primitive_edges).

Errors (ClickError, one line naming the file and the click): a floor point on or above the horizon,
a pixel outside the photo, a footprint crossing a wall by more than WALL_TOL_M, a quad corner off its
wall or ceiling, a wall more than AXIS_DEG off the frame's axes, unknown or duplicate names.
"""
from __future__ import annotations

import logging
import math

import numpy as np

from recon.camera import Camera
from recon.io import json_field
from recon.clickbase import (AXIS_DEG, CLICK_SIGMA_PX, ClickError, ClickModel, DEFAULT_CEILING_M, FACES, LABELS,
                             WALL_TOL_M, Wall, Z99, _Clicks, _corners, _floor, _name, axis_vector, hit_plane,
                             load_clicks)
from recon.clickroom import _refine_room, _wall_offset
from recon.clickfurniture import _furniture
from recon.clickjoint import joint_walls
from recon.clickquad import _quad
from recon.roomfit import WALL_MARGIN_M

log = logging.getLogger("photoar")


# ----------------------------------------------------------------------------------------------
# The model

def model_from_clicks(d: dict, camera: Camera, src: str = "<clicks>", ceiling_height: float | None = None,
                      photo=None, click_sigma_px: float = CLICK_SIGMA_PX) -> ClickModel:
    """The room model of a clicks dict (load_clicks) in `camera`'s world (floor y = 0, +Y up).

    ceiling_height (m) is used when no click gives the ceiling; without either it is
    DEFAULT_CEILING_M with a warning. photo (RGB uint8 (H,W,3), or a recon.edgesnap.EdgeImage of
    it): refine the clicks against its edges (recon/clickedges.py; click_sigma_px the clicks' noise,
    px per coordinate); None: the clicks as they are. Raises ClickError naming `src` and the click."""
    if photo is not None:
        from recon.clickedges import PhotoEdges

        raw = model_from_clicks(d, camera, src, ceiling_height)
        P = _Clicks(camera, src, PhotoEdges(photo, camera, click_sigma_px),
                    [p for p in raw.primitives if p.get("role") == "furniture" and p["type"] == "box"])
    else:
        P = _Clicks(camera, src)
    cam_c = camera.centre
    if not cam_c[1] > 0:
        raise ClickError(f"{src}: the camera centre {np.round(cam_c, 3).tolist()} is not above the floor y = 0 of "
                         "its frame: calibrate it with the camera height (photoar calibrate --height)")
    clicks = json_field(d, "clicks", "", src)
    if not isinstance(clicks, list) or not clicks:
        raise ClickError(f"{src}: field 'clicks' must be a non-empty list")
    items: list[tuple[str, str, dict]] = []
    for i, c in enumerate(clicks):
        where = f"clicks[{i}]"
        if not isinstance(c, dict):
            raise ClickError(f"{src}: field '{where}' must be an object")
        label = c.get("label")
        if label not in LABELS:
            raise ClickError(f"{src}: field '{where}.label' must be one of {', '.join(LABELS)}, got {label!r}")
        if "name" in c or label != "ceiling":
            where = f"{where} ({label} {_name(c, where, src)!r})"
        items.append((label, where, c))

    # walls
    walls: dict[str, Wall] = {}  # face -> wall
    wall_of: dict[str, Wall] = {}  # label name -> wall
    for label, where, c in items:
        if label != "wall":
            continue
        name = c["name"]
        if name in wall_of:
            raise ClickError(f"{src}: {where}: a second wall named {name!r}")
        line = json_field(c, "floor_line", where + ".", src)
        n_pts = len(line) if isinstance(line, list) and len(line) >= 2 else 2  # two points, or more along it
        uv = P.pixels(c, "floor_line", n_pts, where)
        pts = [_floor(P, uv[k], where, f"floor_line[{k}]") for k in range(n_pts)]
        feet = P.edges.foot_lines(pts[0], pts[-1], P.blocker("")) if P.edges is not None else []
        a, b = pts[0], pts[-1]
        e = b - a
        length = math.hypot(e[0], e[2])
        if length < 0.05:
            raise ClickError(f"{src}: {where}: the two floor_line points are {length * 100:.1f} cm apart on the "
                             "floor: click two points far apart along the wall's foot")
        along = 0 if abs(e[0]) >= abs(e[2]) else 2  # the axis the wall runs along
        off_deg = math.degrees(math.atan2(min(abs(e[0]), abs(e[2])), max(abs(e[0]), abs(e[2]))))
        if off_deg > AXIS_DEG:
            raise ClickError(f"{src}: {where}: the floor line runs {off_deg:.0f} deg off the room's axes (more than "
                             f"{AXIS_DEG:g}): the room is a box in the calibrated frame's axes; check the clicks "
                             "and the calibration")
        axis = 2 - along
        offset, kept = _wall_offset(camera, pts, uv, axis, P.edges, feet)
        side = -1 if cam_c[axis] > offset else 1
        face = FACES[(axis, side)]
        if face in walls:
            w = walls[face]
            if abs(w.offset - offset) > 2 * WALL_TOL_M:
                raise ClickError(f"{src}: {where}: it is the {face} wall as {w.labels[0]!r} is, but "
                                 f"{abs(w.offset - offset):.2f} m from it: one face of the room box each")
            w.points += pts
            w.uv = np.vstack([w.uv, uv])
            w.feet += feet
            w.offset, kept = _wall_offset(camera, w.points, w.uv, axis, P.edges, w.feet)
            w.labels.append(name)
        else:
            walls[face] = Wall(face, axis, side, offset, [name], pts, uv, feet)
        if P.edges is not None:
            P.refined[name] = f"{kept} stretches of its foot snapped" if kept else "as clicked"
        wall_of[name] = walls[face]
    if not walls:
        raise ClickError(f"{src}: no wall: click at least one wall's floor line ({{\"label\": \"wall\", ...}})")

    # the room's extent along x and z where a wall was clicked (nan: not yet known)
    lo = np.array([np.nan, 0.0, np.nan])
    hi = np.array([np.nan, np.nan, np.nan])
    for w in walls.values():
        (lo if w.side < 0 else hi)[w.axis] = w.offset

    # ceiling
    heights, ceil_clicks = [], []
    for label, where, c in items:
        if label != "ceiling":
            continue
        wname = json_field(c, "wall", where + ".", src)
        if wname not in wall_of:
            raise ClickError(f"{src}: {where}: 'wall' {wname!r} names no clicked wall (walls: "
                             f"{', '.join(sorted(wall_of)) or 'none'})")
        w = wall_of[wname]
        uv = P.pixels(c, "edge", None, where)
        p = hit_plane(camera, uv, axis_vector(w.axis), w.offset)
        if p is None or not p[1] > cam_c[1]:
            raise ClickError(f"{src}: {where}: edge [{uv[0]:g}, {uv[1]:g}] does not meet wall {wname!r} above the "
                             "camera: click where that wall meets the ceiling")
        heights.append(float(p[1]))
        ceil_clicks.append((w, uv))
    if heights:
        hi[1], ceiling_from = float(np.mean(heights)), f"{len(heights)} ceiling click(s)"
    elif ceiling_height is not None:
        if not ceiling_height > cam_c[1]:
            raise ClickError(f"--ceiling-height: {ceiling_height:g} m is not above the camera "
                             f"({cam_c[1]:.2f} m above the floor)")
        hi[1], ceiling_from = float(ceiling_height), "--ceiling-height"
    else:
        hi[1], ceiling_from = max(DEFAULT_CEILING_M, float(cam_c[1]) + WALL_MARGIN_M), "default"
        log.warning("%s: no ceiling click (a point where a wall meets the ceiling) and no --ceiling-height: the "
                    "ceiling is put at %.2f m", src, hi[1])
    if not hi[1] > cam_c[1]:
        raise ClickError(f"{src}: the ceiling ({hi[1]:.2f} m, from {ceiling_from}) is below the camera "
                         f"({cam_c[1]:.2f} m)")
    if P.edges is not None:
        _refine_room(P, walls, ceil_clicks, lo, hi, ceiling_from != "default")

    names = {"room"} | set(wall_of)
    ordered = _support_order(items)
    for label, where, c in ordered:
        if c["name"] in names:
            raise ClickError(f"{src}: {where}: duplicate name {c['name']!r}")
        names.add(c["name"])
    pieces: dict[str, list[dict]] = {}  # furniture modelled so far: name -> its boxes
    for label, where, c in ordered:  # the furniture first: the walls then take the pieces held on them
        if label == "furniture":
            pieces[c["name"]] = _furniture(P, c, where, c["name"], lo, hi, wall_of, pieces)
    if P.edges is not None:
        joint_walls(P, walls, lo, hi, pieces)
    prims: list[dict] = []
    extents: list[np.ndarray] = []  # points every wall must contain (guessed walls are moved beyond them)
    names = {"room"} | set(wall_of) | {c["name"] for _, _, c in ordered}
    for label, where, c in ordered:
        name = c["name"]
        new = pieces[name] if label == "furniture" else [_quad(P, c, where, name, label, lo, hi, wall_of)]
        for p in new:
            if p["name"] in names - {name}:
                raise ClickError(f"{src}: {where}: its part {p['name']!r} has the name of another primitive")
            names.add(p["name"])
            extents.append(_corners(p))
        prims += new

    # walls no click showed: beyond the camera and every primitive
    pts = np.concatenate([cam_c[None]] + extents)
    guessed = []
    for (axis, side), face in FACES.items():
        if face in walls:
            continue
        guessed.append(face)
        if side < 0:
            lo[axis] = min(cam_c[axis] - WALL_MARGIN_M, float(pts[:, axis].min()))
        else:
            hi[axis] = max(cam_c[axis] + WALL_MARGIN_M, float(pts[:, axis].max()))
    if np.any(hi - lo <= 0):
        raise ClickError(f"{src}: the walls clicked leave an empty room ({np.round(lo, 2).tolist()} .. "
                         f"{np.round(hi, 2).tolist()}): check which side of each wall the camera is on")
    if guessed:
        log.info("%s: walls not clicked, placed %.1f m beyond the camera (guessed): %s", src, WALL_MARGIN_M,
                 ", ".join(guessed))
    wall_list = []
    for face in ("floor", "ceiling", "back", "front", "left", "right"):
        w = walls.get(face)
        how = ("floor" if face == "floor" else ceiling_from if face == "ceiling"
               else "clicked" if w is not None else "beyond the cameras")
        wall_list.append({"name": face, "observed": face == "floor" or w is not None or
                          (face == "ceiling" and bool(heights)),
                          "guessed": face in guessed or (face == "ceiling" and not heights and ceiling_height is None),
                          "how": how, "labels": [] if w is None else list(w.labels)})
    room = {"name": "room", "type": "box", "role": "room", "center": ((lo + hi) / 2).tolist(),
            "size": (hi - lo).tolist(), "walls": wall_list}
    for name, sides in P.uncertain.items():
        pinned = (f"{name}: {', '.join(sides)} pinned only to " +
                  ", ".join(f"+-{Z99 * v * 100:.1f} cm" for v in sides.values()) +
                  f" by its clicks and the photo ({Z99:g} sigma)")
        if P.measure.get(name):  # the one size a tape gives: name it plainly
            log.warning("%s: %s: %s", src, pinned, tape_request(P.measure[name]))
        else:
            log.warning("%s: %s: click its corners with care, a hidden one as null with the footprint's sizes in "
                        "size_m", src, pinned)
    return ClickModel([room] + prims, lo, hi, ceiling_from, guessed, P.refined if P.edges is not None else None,
                      P.uncertain if P.edges is not None else None, P.measure if P.edges is not None else None)


def tape_request(asks: list[dict]) -> str:
    """What to tape for a piece, in words, from its ClickModel.measure entries: 'tape its length
    along z from floor[0] to floor[1] (about 0.89 m) and give it as size_m[0] ("size_m": [L, null])'."""
    return " and ".join(f"tape its length along {m['along']} from floor[{m['floor'][0]}] to floor[{m['floor'][1]}] "
                        f"(about {m['about_m']:.2f} m) and give it as size_m[{m['size_m']}] (\"size_m\": "
                        f"{'[L, null]' if m['size_m'] == 0 else '[null, L]'})" for m in asks)


def _support_order(items: list[tuple[str, str, dict]]) -> list[tuple[str, str, dict]]:
    """The furniture, window and lamp clicks (not walls or the ceiling) in file order, except that a
    piece standing `on` another comes after that one (a piece naming no earlier-modelled piece, or
    in a cycle, keeps its place: _furniture refuses it)."""
    rest = [it for it in items if it[0] not in ("wall", "ceiling")]
    out: list[tuple[str, str, dict]] = []
    done: set[str] = set()
    while rest:
        k = next((i for i, (label, _, c) in enumerate(rest) if label != "furniture" or c.get("on") is None
                  or c.get("on") in done), None)
        if k is None:  # what is left names unknown pieces or stands in a cycle: in file order, to be refused
            k = 0
        out.append(rest.pop(k))
        done.add(out[-1][2].get("name"))
    return out


def primitive_edges(p: dict, camera: Camera, near: float = 0.05) -> list[tuple[np.ndarray, np.ndarray]]:
    """The image segments (pixel (2,), pixel (2,)) of a box's twelve or a quad's four edges (user
    primitives format), each clipped to z_cam >= near (m) so that edges running behind the camera
    are drawn up to where they leave the view."""
    V = _corners(p)
    if p["type"] == "quad":
        pairs = [(0, 1), (1, 2), (2, 3), (3, 0)]
    else:
        pairs = [(i, j) for i in range(8) for j in range(i + 1, 8) if bin(i ^ j).count("1") == 1]
    Xc = V @ camera.R.T + camera.t
    out = []
    for i, j in pairs:
        a, b = Xc[i], Xc[j]
        if a[2] < near and b[2] < near:
            continue
        if a[2] < near:
            a = a + (b - a) * (near - a[2]) / (b[2] - a[2])
        elif b[2] < near:
            b = b + (a - b) * (near - b[2]) / (a[2] - b[2])
        pa, pb = camera.K @ a, camera.K @ b
        out.append((pa[:2] / pa[2], pb[:2] / pb[2]))
    return out
