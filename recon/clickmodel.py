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
    see a move along the line of sight its top's edges do not), a side of it the fit cannot tell from
    a clicked wall is put against it (_hold_on_walls), and a side pinned worse than TOLERANCE_M (at
    99 %) is reported ill-determined (ClickModel.uncertain, a warning);
  * walls that no click shows are placed WALL_MARGIN_M beyond the camera (recon/roomfit.py's rule:
    the photographer stands between the camera and the wall behind), and beyond every clicked
    primitive, and flagged guessed.

Errors (ClickError, one line naming the file and the click): a floor point on or above the horizon,
a pixel outside the photo, a footprint crossing a wall by more than WALL_TOL_M, a quad corner off its
wall or ceiling, a wall more than AXIS_DEG off the frame's axes, unknown or duplicate names.
"""
from __future__ import annotations

import logging
import math
import os
from dataclasses import dataclass, field, replace

import numpy as np

from recon.camera import Camera
from recon.io import SceneError, json_array, json_bool, json_field, read_json
from recon.roomfit import WALL_MARGIN_M

log = logging.getLogger("photoar")

LABELS = ("wall", "ceiling", "furniture", "window", "lamp")
FURNITURE_KINDS = ("desk", "box")
DEFAULT_CEILING_M = 2.5  # m, a common ceiling height, used (with a warning) when nothing gives it
AXIS_DEG = 15.0  # a wall's floor line must run within this angle of a horizontal axis of the frame
SNAP_DEG = 10.0  # a footprint turned less than this from the room axes is axis-aligned
RIGHT_ANGLE_DEG = 20.0  # the two footprint edges must be perpendicular within this
WALL_TOL_M = 0.05  # m a footprint or quad may cross a clicked wall (click noise) before it is refused
WALL_SNAP_M = 0.03  # m: a footprint side this close to a clicked wall is put against it
TOP_MISS_PX = 25.0  # px: the top click must lie within this of the vertical line over floor[0]
DESK_TOP_M = 0.04  # m, a desk's top slab
DESK_LEG_M = 0.05  # m, a desk leg's square section
DESK_LEG_INSET_M = 0.04  # m from the footprint's edge to a leg's outer face
CLICK_SIGMA_PX = 1.0  # px per coordinate: a click's noise, what a refinement may move it (recon/clickedges.py)
SIDES = ("x min", "x max", "z min", "z max", "top")  # a piece's parameters (local axes when turned)
TOLERANCE_M = 0.03  # m: issue 38's accuracy for walls, furniture and quads; a piece's side the clicks and the
# photo pin less well than this (at Z99 sigma) is reported as ill-determined
Z99 = 2.576  # the two-sided 99 % point of the normal distribution
SNAP_ROUNDS = 3  # rounds of snapping a piece's edges around its latest fit (_snap_and_refine)
QUAD_OFFSET_M = 0.002  # m in front of its surface: a window or lamp drawn on a wall or the ceiling
FACES = {(0, -1): "left", (0, 1): "right", (2, -1): "back", (2, 1): "front"}


class ClickError(SceneError):
    """A click that cannot be modelled; the message names the file and the click."""


@dataclass
class Wall:
    face: str  # back / front / left / right
    axis: int  # 0 (x) or 2 (z): the axis its normal runs along
    side: int  # -1: the room's min side along axis, +1 its max side
    offset: float  # coordinate along axis, m
    labels: list[str] = field(default_factory=list)
    points: list[np.ndarray] = field(default_factory=list)  # floor points (3,) behind it
    uv: np.ndarray | None = None  # (m,2) their clicks
    feet: list = field(default_factory=list)  # with the photo: (start (3,), end (3,), EdgeLine) snapped stretches
    sd: float = 0.0  # with the photo: the offset's standard deviation (m) from its clicks and snapped lines


@dataclass
class ClickModel:
    """The model of a clicks file: the user primitives (`photoar scene --primitives` format) and
    what was guessed."""

    primitives: list[dict]
    lo: np.ndarray  # (3,) room box min, m
    hi: np.ndarray  # (3,) room box max, m
    ceiling_from: str
    guessed: list[str]  # room faces no click showed
    refined: dict[str, str] | None = None  # with the photo: each wall / piece / quad -> how it was refined
    uncertain: dict[str, dict[str, float]] | None = None  # with the photo: piece -> {side: standard deviation
    # m} of the sides pinned less well than TOLERANCE_M (at Z99 sigma)

    def to_json(self) -> dict:
        model = {"from": "clicks", "ceiling_from": self.ceiling_from, "guessed_walls": self.guessed}
        if self.refined is not None:
            model["refined_from_photo"] = self.refined
            model["ill_determined"] = {k: {side: round(Z99 * v, 4) for side, v in sides.items()}
                                       for k, sides in (self.uncertain or {}).items()}
        return {"primitives": self.primitives, "model": model}


# ----------------------------------------------------------------------------------------------
# Rays

def ray(camera: Camera, uv) -> tuple[np.ndarray, np.ndarray]:
    """Camera centre (3,) and unit world direction (3,) of the ray through pixel uv (2,)."""
    d = camera.R.T @ np.linalg.solve(camera.K, np.array([uv[0], uv[1], 1.0]))
    return camera.centre, d / np.linalg.norm(d)


def hit_plane(camera: Camera, uv, normal, offset: float) -> np.ndarray | None:
    """World point (3,) where pixel uv's ray meets the plane normal . x = offset; None when it
    runs parallel to it or meets it behind the camera."""
    c, d = ray(camera, uv)
    n = np.asarray(normal, np.float64)
    den = float(n @ d)
    if abs(den) < 1e-9:
        return None
    s = (offset - float(n @ c)) / den
    return c + s * d if s > 1e-6 else None


def axis_vector(axis: int) -> np.ndarray:
    e = np.zeros(3)
    e[axis] = 1.0
    return e


# ----------------------------------------------------------------------------------------------
# Parsing

class _Clicks:
    """Validation helpers bound to one clicks file and camera."""

    def __init__(self, camera: Camera, src: str, edges=None, occluders: list[dict] | None = None):
        self.camera, self.src = camera, src
        self.edges = edges  # recon.clickedges.PhotoEdges, or None: clicks only
        self.occluders = occluders or []  # the clicks-only model's furniture boxes
        self.refined: dict[str, str] = {}
        self.uncertain: dict[str, dict[str, float]] = {}  # piece -> {side: standard deviation m} (TOLERANCE_M)
        self.ceiling_sd = 0.0  # m: the ceiling height's standard deviation when clicked (with the photo)
        self.wall_sd: dict[tuple[int, int], float] = {}  # (axis, side) -> a clicked wall offset's sd (m) for
        # _hold_on_walls, with the photo: at least its foot line's noise floor in metres

    def blocker(self, name: str):
        """recon.clickedges.box_blocker of every furniture box but piece `name`'s own."""
        from recon.clickedges import box_blocker

        return box_blocker(self.camera, [b for b in self.occluders
                                         if b["name"] != name and not b["name"].startswith(name + "_")])

    def err(self, where: str, msg: str) -> ClickError:
        return ClickError(f"{self.src}: {where}: {msg}")

    def pixels(self, c: dict, key: str, n: int | None, where: str, nulls: bool = False) -> np.ndarray:
        """c[key] as pixels (n,2) (or (2,) with n None), each inside the photo; with `nulls`, an entry
        may be null (a corner out of the photo): a row of nan."""
        value = json_field(c, key, where + ".", self.src)
        if nulls and isinstance(value, list) and len(value) == n:
            rows = [np.full(2, np.nan) if v is None else json_array(v, (2,), f"{where}.{key}[{k}]", self.src)
                    for k, v in enumerate(value)]
            arr = np.array(rows)
        else:
            shape = (2,) if n is None else (n, 2)
            arr = json_array(value, shape, f"{where}.{key}", self.src)
        w, h = self.camera.width, self.camera.height
        for k, (u, v) in enumerate(arr.reshape(-1, 2)):
            if np.isfinite(u) and not (-0.5 <= u <= w - 0.5 and -0.5 <= v <= h - 0.5):
                at = key if n is None else f"{key}[{k}]"
                raise self.err(where, f"{at} = [{u:g}, {v:g}] is outside the photo ({w}x{h} px; pixel (0, 0) is "
                                      "the centre of the top-left pixel)" + (": give null for a corner out of the "
                                                                             "photo" if nulls else ""))
        return arr

    def outside(self, X: np.ndarray) -> bool:
        """World point X (3,) is not seen in the photo (behind the camera or out of the frame)."""
        uv, z = self.camera.project(X[None])
        u, v = uv[0]
        return bool(z[0] <= 0 or not (-0.5 <= u <= self.camera.width - 0.5 and -0.5 <= v <= self.camera.height - 0.5))

    def sizes(self, c: dict, where: str) -> np.ndarray | None:
        """The optional "size_m" [a, b] (m, positive) of a primitive with corners out of the photo."""
        if c.get("size_m") is None:
            return None
        v = json_array(c["size_m"], (2,), f"{where}.size_m", self.src)
        if not np.all(v > 0):
            raise self.err(where, f"size_m must be positive, got {v.tolist()}")
        return v

    def missing_end(self, where: str, known: float, size: np.ndarray | None, k: int, corners) -> float:
        """The end of a side no clicked corner pins: `known` -/+ size[k], whichever puts the unclicked
        corners (callable end -> list of world points) out of the photo."""
        if size is None:
            raise self.err(where, "a side has no clicked corner (corners out of the photo are null): give its "
                                  "length in size_m, or the wall it stands against in 'against'")
        ok = [e for e in (known - size[k], known + size[k]) if all(self.outside(X) for X in corners(e))]
        if len(ok) != 1:
            raise self.err(where, "cannot tell on which side the corners out of the photo lie (size_m puts them "
                                  f"{'in the photo both ways' if not ok else 'out of it both ways'}): click them")
        return float(ok[0])


def _name(c: dict, where: str, src: str) -> str:
    v = json_field(c, "name", where + ".", src)
    if not isinstance(v, str) or not v.strip():
        raise ClickError(f"{src}: field '{where}.name' must be a non-empty string, got {v!r}")
    return v


def load_clicks(path: str | os.PathLike) -> dict:
    """The parsed clicks file (a JSON object with a non-empty "clicks" list); ClickError otherwise."""
    d = read_json(path, ClickError)
    clicks = d.get("clicks") if isinstance(d, dict) else None
    if not isinstance(clicks, list) or not clicks:
        raise ClickError(f"{path}: field 'clicks' must be a non-empty list")
    return d


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
    prims: list[dict] = []
    extents: list[np.ndarray] = []  # points every wall must contain (guessed walls are moved beyond them)
    for label, where, c in items:
        if label in ("wall", "ceiling"):
            continue
        name = c["name"]
        if name in names:
            raise ClickError(f"{src}: {where}: duplicate name {name!r}")
        names.add(name)
        if label == "furniture":
            new = _furniture(P, c, where, name, lo, hi, wall_of)
        else:
            new = [_quad(P, c, where, name, label, lo, hi, wall_of)]
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
        log.warning("%s: %s: %s pinned only to %s by its clicks and the photo (%s sigma): click its corners with care "
                    "or give its sizes (size_m)", src, name, ", ".join(sides),
                    ", ".join(f"+-{Z99 * v * 100:.1f} cm" for v in sides.values()), f"{Z99:g}")
    return ClickModel([room] + prims, lo, hi, ceiling_from, guessed, P.refined if P.edges is not None else None,
                      P.uncertain if P.edges is not None else None)


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
        found = P.edges.lines(corners(x0), model_pairs, P.blocker(""), faint=True)
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


def _floor(P: _Clicks, uv, where: str, at: str) -> np.ndarray:
    p = hit_plane(P.camera, uv, [0.0, 1.0, 0.0], 0.0)
    if p is None:
        raise P.err(where, f"{at} = [{uv[0]:g}, {uv[1]:g}] is on or above the horizon: a floor point must be "
                           "clicked below it, where the floor is seen")
    return p


def _reproject_fit(x0: np.ndarray, points, uv: np.ndarray, camera: Camera) -> np.ndarray:
    """Parameters x (n,) minimising the pixel distance between the clicks uv (m,2) and the
    projections of points(x) (m,3): the clicks' noise is in pixels, so that far clicks (a pixel spans
    centimetres there) weigh less than near ones (Levenberg-Marquardt from x0)."""
    from scipy.optimize import least_squares

    def fun(x):
        p, z = camera.project(points(x))
        if np.any(z <= 1e-6):
            return np.full(uv.size, 1e6)
        return (p - uv).ravel()

    if uv.size < len(x0):
        return x0
    r = least_squares(fun, np.asarray(x0, np.float64), method="lm" if uv.size >= len(x0) else "trf")
    return r.x if r.success and np.all(np.isfinite(r.x)) else x0


def _pixel_metres(P: _Clicks, uv) -> float:
    """Metres on the floor that one pixel spans at the floor click uv (the larger of u and v)."""
    p = hit_plane(P.camera, uv, [0.0, 1.0, 0.0], 0.0)
    steps = [hit_plane(P.camera, np.asarray(uv) + d, [0.0, 1.0, 0.0], 0.0) for d in ((1.0, 0.0), (0.0, 1.0))]
    return max((float(np.linalg.norm(q - p)) for q in steps if q is not None), default=1.0)


def _corners(p: dict) -> np.ndarray:
    """(N,3) points spanning a primitive entry (a box's eight corners, a quad's four)."""
    if p["type"] == "quad":
        return np.asarray(p["corners"], np.float64)
    c, s = np.asarray(p["center"]), np.asarray(p["size"]) / 2
    yaw = math.radians(p.get("yaw_deg", 0.0))
    e1, e2 = np.array([math.cos(yaw), 0, -math.sin(yaw)]), np.array([math.sin(yaw), 0, math.cos(yaw)])
    return np.array([c + a * s[0] * e1 + b * s[1] * np.array([0, 1.0, 0]) + g * s[2] * e2
                     for a in (-1, 1) for b in (-1, 1) for g in (-1, 1)])


def _footprint(P: _Clicks, f: np.ndarray, where: str, size: np.ndarray | None, against: Wall | None = None
               ) -> tuple[float, np.ndarray, np.ndarray]:
    """Upright rectangle through floor corners f (3,3) (f[1] the corner between the others; a row of
    nan: a corner out of the photo): yaw (rad, about +Y as recon/scene.rot_y: local x = (cos, 0,
    -sin)), and its sorted ranges (2,) along local x and local z (m). Each side is the mean of the
    clicked corners on it; a side with none is size_m away from the opposite one, or on the wall
    `against` (the wall the piece stands against)."""
    known = [k for k in range(3) if np.isfinite(f[k, 0])]
    if len(known) < 2:
        raise P.err(where, "at least two of the three floor corners must be clicked")
    a, b = f[0] - f[1], f[2] - f[1]
    edges = [(e, math.hypot(e[0], e[2])) for e, ks in ((a, (0, 1)), (b, (1, 2))) if all(k in known for k in ks)]
    if any(le < 0.02 for _, le in edges):
        raise P.err(where, "two floor corners are less than 2 cm apart: click three corners of the footprint in "
                           "order around it")
    if len(edges) == 2:
        cos_ab = abs(a[0] * b[0] + a[2] * b[2]) / (edges[0][1] * edges[1][1])
        if math.degrees(math.asin(min(cos_ab, 1.0))) > RIGHT_ANGLE_DEG:
            raise P.err(where, f"the floor corners make a {math.degrees(math.acos(cos_ab)):.0f} deg corner at "
                               "floor[1]: click three corners of the footprint in order around it (floor[1] between "
                               "the others)")
    # each edge's yaw (mod 90 deg), averaged by length on the 4x angle circle
    z = sum(le * complex(math.cos(4 * math.atan2(-e[2], e[0])), math.sin(4 * math.atan2(-e[2], e[0])))
            for e, le in edges)
    yaw = math.atan2(z.imag, z.real) / 4 if edges else 0.0
    if abs(math.degrees(yaw)) < SNAP_DEG:
        yaw = 0.0
    elif len(known) < 3:
        raise P.err(where, f"the footprint is turned {math.degrees(yaw):.0f} deg from the room's axes: click all three "
                           "floor corners")
    e1, e2 = np.array([math.cos(yaw), 0, -math.sin(yaw)]), np.array([math.sin(yaw), 0, math.cos(yaw)])
    if 1 in known and 0 in known:
        a_on_e1 = abs(a @ e1) >= abs(a @ e2)
    elif 1 in known:
        a_on_e1 = abs(b @ e1) < abs(b @ e2)
    else:
        a_on_e1 = True  # f0 and f2 diagonal: they pin every side either way
    ea, eb = (e1, e2) if a_on_e1 else (e2, e1)
    # along the a edge (f1 -> f0): f0 on one side, f1 and f2 on the other; along b: f2, and f0 and f1
    ends = []
    for axis_vec, lone, pair, k in ((ea, 0, (1, 2), 0), (eb, 2, (0, 1), 1)):
        far = f[lone] @ axis_vec if lone in known else None
        near = [f[j] @ axis_vec for j in pair if j in known]
        near = float(np.mean(near)) if near else None
        if far is None:  # f[lone] out of the photo; then f1 is clicked, and shares its other side
            def corners(end, axis_vec=axis_vec):
                return [f[1] + (end - f[1] @ axis_vec) * axis_vec]

            if size is None and against is not None and abs(axis_vec[against.axis]) > 1 - 1e-9:
                far = against.offset * float(axis_vec[against.axis])
            else:
                far = P.missing_end(where, near, size, k, corners)
        ends.append(np.sort(np.array([far, near])))
    xr, zr = (ends[0], ends[1]) if a_on_e1 else (ends[1], ends[0])
    return yaw, xr, zr


def _refine_box(camera: Camera, yaw: float, xr: np.ndarray, zr: np.ndarray, h: float, f: np.ndarray,
                uv: np.ndarray, top_uv: np.ndarray, wall_end: bool, photo: tuple | None = None
                ) -> tuple[np.ndarray, np.ndarray, float]:
    """The footprint's ranges and height (yaw kept) whose clicked corners project nearest their
    clicks and the top corner nearest the top click, in pixels (_reproject_fit): the top click also
    pins floor[0]'s position, and a click's weight follows the metres its pixel spans. A side no
    clicked corner lies on keeps its distance to the opposite side (size_m), or its place with
    `wall_end` (the wall the piece stands against). photo: (the _Clicks with the photo's edges, the
    piece's name, is a desk): then the box's edges snapped to the photo join the fit
    (recon/clickedges.py)."""
    e1, e2 = np.array([math.cos(yaw), 0, -math.sin(yaw)]), np.array([math.sin(yaw), 0, math.cos(yaw)])
    known = [k for k in range(3) if np.isfinite(f[k, 0])]
    ix = {k: int(abs(f[k] @ e1 - xr[1]) < abs(f[k] @ e1 - xr[0])) for k in known}  # each click's end of
    iz = {k: 2 + int(abs(f[k] @ e2 - zr[1]) < abs(f[k] @ e2 - zr[0])) for k in known}  # each range
    x0 = np.r_[xr, zr, h]
    active = sorted(set(ix.values()) | set(iz.values())) + [4]

    def full(y):
        x = x0.copy()
        x[active] = y
        for j in range(4):
            if j not in active and not wall_end:
                x[j] = x[j ^ 1] + (x0[j] - x0[j ^ 1])
        return x

    def pts(y):
        x = full(y)
        out = [x[ix[k]] * e1 + x[iz[k]] * e2 for k in known]
        return np.array(out + [out[0] + [0.0, x[4], 0.0]])

    uvs = np.vstack([uv[known], top_uv[None]])
    y = _reproject_fit(x0[active], pts, uvs, camera)
    if photo is not None and photo[0].edges is not None:
        P, name, desk, lo, hi = photo

        def corners(y):  # corner b: bit 0 the x end, bit 1 bottom / top, bit 2 the z end; a desk: its slab,
            x = full(y)  # then its legs' (leg l's corner b at 8 + 8 l + b; l: bit 0 the x end, bit 1 the z end)
            bottom = x[4] - DESK_TOP_M if desk else 0.0
            out = [x[b & 1] * e1 + x[2 + (b >> 2 & 1)] * e2 + [0.0, x[4] if b & 2 else bottom, 0.0] for b in range(8)]
            if desk:
                i0, i1 = DESK_LEG_INSET_M, DESK_LEG_INSET_M + DESK_LEG_M
                for leg in range(4):
                    lx = (x[0] + i0, x[0] + i1) if not leg & 1 else (x[1] - i1, x[1] - i0)
                    lz = (x[2] + i0, x[2] + i1) if not leg & 2 else (x[3] - i1, x[3] - i0)
                    out += [lx[b & 1] * e1 + lz[b >> 2 & 1] * e2 + [0.0, bottom if b & 2 else 0.0, 0.0]
                            for b in range(8)]
            return np.array(out)

        slab = (lambda y: _box(name, yaw, *_slab_ranges(full(y), desk))) if desk else None
        y, kept = _snap_and_refine(P, name, y, corners, pts, uvs, (e1, np.array([0.0, 1, 0]), e2), slab)
        held = []
        if yaw == 0.0:
            # the sides a click the photo shows lies on (a corner no piece hides, nor the piece itself)
            own = slab(y) if desk else _box(name, yaw, *_slab_ranges(full(y), False))
            shown = _shown(P, name, pts(y), own, not desk)
            on = [(ix[k], iz[k]) for k in known] + [(ix[known[0]], iz[known[0]])]
            clicked = {j for ok, sides in zip(shown, on) if ok for j in sides}
            y, held = _hold_on_walls(P, y, active, corners, pts, uvs, kept, lo, hi, clicked)
        words = ([f"{len(kept)} edges snapped"] if kept else []) + \
            [f"{SIDES[j]} side against the wall" for j in held]
        P.refined[name] = ", ".join(words) if words else "as clicked"
        free = [k for k, j in enumerate(active) if j not in held]
        if free:
            def sub(q, y=y, free=free):
                out = y.copy()
                out[free] = q
                return out

            sd = P.edges.sd(y[free], lambda q: corners(sub(q)), lambda q: pts(sub(q)), kept)
            loose = {SIDES[active[k]]: float(v) for k, v in zip(free, sd) if not Z99 * v <= TOLERANCE_M}
            if loose:
                P.uncertain[name] = loose
    x = full(y)
    return np.sort(x[:2]), np.sort(x[2:4]), float(x[4])


def _slab_ranges(x: np.ndarray, desk: bool) -> tuple:
    """A piece's parameters x [x min, x max, z min, z max, top] -> the (x, y, z) ranges of its box
    (a desk: its top slab)."""
    return x[:2], (x[4] - DESK_TOP_M if desk else 0.0, x[4]), x[2:4]


def _snap_and_refine(P: _Clicks, name: str, y: np.ndarray, corners, pts, uvs: np.ndarray, axes, slab=None
                     ) -> tuple[np.ndarray, list]:
    """A piece's fit y refined with its edges snapped to the photo (recon/clickedges.py), in rounds:
    the edges are snapped around the model of the last fit and the fit redone, until a round finds
    no edge more (at most SNAP_ROUNDS): a click off by 3 sigma puts some edges beyond their search
    (a desk's slab: its top's and underside's front edges 4 cm apart), the fit on the others brings
    them in. A desk (slab: y -> its top slab's box entry; corners(y) then holds its legs' corners
    after the slab's 8) also snaps its legs' vertical edges, where neither another piece nor its
    own slab hides them: a move along the line of sight, which its top's edges do not see, turns
    the legs' vertical planes through the camera (legs at different bearings), the floor clicks
    alone pin it otherwise."""
    from recon.clickedges import box_blocker

    y0, kept = y, []
    for _ in range(SNAP_ROUNDS):
        C = corners(y)
        lines = P.edges.lines(C, _box_edges(P.camera.centre, C[:8], axes, False), P.blocker(name), faint=True)
        if slab is not None:
            others, own = P.blocker(name), box_blocker(P.camera, [slab(y)])
            legs = [(8 + 8 * leg + i, 8 + 8 * leg + j) for leg in range(4)
                    for i, j in _box_edges(P.camera.centre, C[8 + 8 * leg:16 + 8 * leg], axes, False) if j - i == 2]
            lines += P.edges.lines(C, legs, lambda X: others(X) | own(X), faint=True)
        if len(lines) <= len(kept):
            break
        y, kept = P.edges.refine_lines(y0, corners, pts, uvs, lines)
    return y, kept


def _shown(P: _Clicks, name: str, X: np.ndarray, own: dict, solid: bool) -> np.ndarray:
    """(m,) bool: piece `name`'s clicked corners X (m,3) (its current fit, corners of the upright box
    `own`) that the photo surely shows: the sight line from the camera to the corner meets no other
    piece (the clicks-only model) grown by OCCLUDER_SHRINK_M, its click noise (a corner where two
    pieces meet, a seat's top corner at the end of a sofa's back, is not surely shown), and, for a
    `solid` piece, the corner is on a face of its own box turned to the camera (a convex box hides
    its other corners); a desk's own top slab is tested as another piece (its floor corners are not
    its corners)."""
    from recon.clickedges import OCCLUDER_SHRINK_M

    others = [b for b in P.occluders if b["name"] != name and not b["name"].startswith(name + "_")]
    C = P.camera.centre
    hidden = np.zeros(len(X), bool)
    for b in others + ([] if solid else [own]):
        R, c = _local_axes(b), np.asarray(b["center"], float)
        h = np.asarray(b["size"], float) / 2 + OCCLUDER_SHRINK_M
        o, d = R @ (C - c), (X - C) @ R.T  # the segment C + t d, t in [0, 1], in the box's frame
        with np.errstate(divide="ignore", invalid="ignore"):
            t1, t2 = (-h - o) / d, (h - o) / d
        par = d == 0  # parallel to a slab: inside it for every t, or never
        lo_t = np.where(par, np.where(np.abs(o) <= h, -np.inf, np.inf), np.minimum(t1, t2)).max(axis=1)
        hi_t = np.where(par, np.where(np.abs(o) <= h, np.inf, -np.inf), np.maximum(t1, t2)).min(axis=1)
        hidden |= (lo_t <= hi_t) & (hi_t >= 0.0) & (lo_t <= 1.0)
    if solid:
        c, h = np.asarray(own["center"], float), np.asarray(own["size"], float) / 2
        R = _local_axes(own)
        loc, eye = (X - c) @ R.T, R @ (C - c)
        turned = np.zeros(len(X), bool)
        for a in range(3):  # a corner is on the face of its end along axis a; turned when the eye is beyond it
            turned |= np.sign(loc[:, a]) * eye[a] > h[a]
        hidden |= ~turned
    return ~hidden


def _local_axes(b: dict) -> np.ndarray:
    """(3,3) rows: a box entry's local x, y, z axes in the world (yaw_deg about +Y)."""
    yaw = math.radians(b.get("yaw_deg", 0.0))
    return np.array([[math.cos(yaw), 0, -math.sin(yaw)], [0, 1.0, 0], [math.sin(yaw), 0, math.cos(yaw)]])


def _hold_on_walls(P: _Clicks, y: np.ndarray, active: list[int], corners, pts, uvs: np.ndarray, lines: list,
                   lo: np.ndarray, hi: np.ndarray, clicked: set[int] = frozenset()) -> tuple[np.ndarray, list[int]]:
    """An axis-aligned piece's fit y (its parameters `active` of [x min, x max, z min, z max, top])
    with each side that the clicks and snapped `lines` allow on a clicked wall put there: a side the
    photo shows (a snapped line on it, or a click on a corner of it no piece hides: `clicked`, its
    indices; a side hidden under another piece, a sofa's seat under its back, is not judged: only
    clicks on hidden corners place it) is held on the wall when the side and the wall are one plane
    within both their noises (_against_chi2 at most CHI2_1DOF_99: the side's place is one number; a
    piece the photo cannot tell from standing against the wall stands against it; a side further
    off than its noise keeps its fit). Returns (y, the sides held)."""
    from recon.clickedges import CHI2_1DOF_99

    base = P.edges.chi2(y, corners, pts, uvs, lines)
    held = []
    for j in range(4):
        axis, side = (0, 2)[j // 2], (-1, 1)[j % 2]
        bound = (lo if side < 0 else hi)[axis]
        bit, end = (1, 4)[j // 2], j % 2  # corner bits: bit 0 the x end, bit 2 the z end
        seen = j in clicked or any(max(L.i, L.j) < 8 and bool(L.i & bit) == end and bool(L.j & bit) == end
                                   for L in lines)
        if j not in active or not np.isfinite(bound) or not seen:
            continue
        k = active.index(j)
        y1 = P.edges.held(y, k, float(bound), corners, pts, uvs, lines)
        d, rise, wall_sd = float(y[k]) - float(bound), P.edges.chi2(y1, corners, pts, uvs, lines) - base, \
            P.wall_sd.get((axis, side), 0.0)
        if _against_chi2(d, rise, wall_sd) <= CHI2_1DOF_99:
            if rise > 0.0 and wall_sd > 0.0:  # the one plane: the side's fit and the wall's, by their variances
                var_s, var_w = d * d / rise, wall_sd * wall_sd
                y1 = P.edges.held(y, k, float(bound) + d * var_w / (var_s + var_w), corners, pts, uvs, lines)
            y, base = y1, P.edges.chi2(y1, corners, pts, uvs, lines)
            held.append(j)
    return y, held


def _against_chi2(d: float, rise: float, wall_sd: float) -> float:
    """The chi-square of a piece's side standing on a wall d (m) from the side's fit, when holding it
    on the wall's fitted offset raises the piece's chi-square by `rise` and the wall's offset has
    its own standard deviation wall_sd (m): the two are one plane when their difference is within
    both noises, d^2 / (var_side + var_wall), the side's variance being d^2 / rise (the piece's fit
    is linear in its sides over a few centimetres). wall_sd is at least what the snapped line's
    noise floor (LINE_SIGMA_FLOOR_PX) is in metres at the wall's foot: its stretches are one crease
    and share that error (_refine_room)."""
    if rise <= 0.0 or d == 0.0:
        return max(rise, 0.0)
    return d * d / (d * d / rise + wall_sd * wall_sd)


def _box_edges(centre: np.ndarray, corners: np.ndarray, axes, top_only: bool) -> list[tuple[int, int]]:
    """The edges (corner index pairs, corners indexed by bits: 0 along axes[0], 1 along axes[1] (up),
    2 along axes[2]) of a box that border a face turned to the camera at `centre`; with top_only,
    those of its top face (a desk: its slab's other edges depend on the assumed thickness)."""
    out = []
    for i in range(8):
        for b in (1, 2, 4):
            j = i | b
            if j == i or (top_only and not (i & 2 and j & 2)):
                continue
            for c, ax in zip((1, 2, 4), axes):
                if c == b:
                    continue
                normal = ax if i & c else -ax
                if float((centre - corners[i]) @ normal) > 0:
                    out.append((i, j))
                    break
    return out


def _against_walls(P: _Clicks, where: str, yaw: float, xr: np.ndarray, zr: np.ndarray, lo, hi, px_m: float) -> None:
    """Refuse a footprint crossing a clicked wall by more than WALL_TOL_M + 3 px; put a side within
    WALL_SNAP_M of one (or across it) against it (axis-aligned footprints), clicks only: with the
    photo (P.edges) a side goes against a wall only by _hold_on_walls's chi-square test, and one
    across a wall is put on it (a side the photo does not show, a sofa's seat under its back, is
    no nearer a wall for being within WALL_SNAP_M of it when a pixel spans centimetres there).
    px_m: metres on the floor per pixel at the footprint's clicks (far from the camera a pixel
    spans centimetres)."""
    tol, snap = WALL_TOL_M + 3 * px_m, WALL_SNAP_M
    yaw_c, yaw_s = math.cos(yaw), math.sin(yaw)
    e1, e2 = np.array([yaw_c, -yaw_s]), np.array([yaw_s, yaw_c])  # world (x, z) of local x, z
    corners = np.array([x * e1 + z * e2 for x in xr for z in zr])
    for k, axis in ((0, 0), (1, 2)):
        for side, bound in ((-1, lo[axis]), (1, hi[axis])):
            if not np.isfinite(bound):
                continue
            beyond = float(np.max(side * (corners[:, k] - bound)))
            if beyond > tol:
                face = FACES[(axis, side)]
                raise P.err(where, f"the footprint crosses the {face} wall by {beyond:.2f} m: furniture stands "
                                   "inside the room (check the floor corners and the walls' floor lines)")
    if yaw != 0.0:
        return
    if P.edges is not None:
        snap = 0.0
    for rng, axis in ((xr, 0), (zr, 2)):
        if np.isfinite(lo[axis]) and rng[0] - lo[axis] < snap:
            rng[0] = lo[axis]
        if np.isfinite(hi[axis]) and hi[axis] - rng[1] < snap:
            rng[1] = hi[axis]


def _box(name: str, yaw: float, xr, yr, zr) -> dict:
    """A box entry from its local ranges (m) turned by yaw (rad)."""
    e1, e2 = np.array([math.cos(yaw), 0, -math.sin(yaw)]), np.array([math.sin(yaw), 0, math.cos(yaw)])
    c = (sum(xr) / 2) * e1 + (sum(zr) / 2) * e2 + np.array([0, sum(yr) / 2, 0])
    d = {"name": name, "type": "box", "role": "furniture", "center": c.tolist(),
         "size": [float(xr[1] - xr[0]), float(yr[1] - yr[0]), float(zr[1] - zr[0])]}
    if yaw != 0.0:
        d["yaw_deg"] = math.degrees(yaw)
    return d


def _furniture(P: _Clicks, c: dict, where: str, name: str, lo, hi, wall_of: dict[str, Wall]) -> list[dict]:
    """A furniture click -> its boxes (a desk's top slab and legs, or one box)."""
    kind = json_field(c, "kind", where + ".", P.src)
    if kind not in FURNITURE_KINDS:
        raise P.err(where, f"field 'kind' must be one of {', '.join(FURNITURE_KINDS)}, got {kind!r}")
    uv = P.pixels(c, "floor", 3, where, nulls=True)
    top_uv = P.pixels(c, "top", None, where)
    if not np.isfinite(uv[0, 0]):
        raise P.err(where, "floor[0] must be clicked: the top corner is the one straight above it")
    f = np.array([_floor(P, uv[k], where, f"floor[{k}]") if np.isfinite(uv[k, 0]) else np.full(3, np.nan)
                  for k in range(3)])
    against = c.get("against")
    if against is not None and against not in wall_of:
        raise P.err(where, f"'against' must name a clicked wall ({', '.join(sorted(wall_of))}), got {against!r}")
    yaw, xr, zr = _footprint(P, f, where, P.sizes(c, where), wall_of.get(against))
    # height: the vertical line over floor[0] nearest the top click's ray (least squares in h, s)
    C, d = ray(P.camera, top_uv)
    A = np.stack([np.array([0.0, 1.0, 0.0]), -d], axis=1)
    (h, s), *_ = np.linalg.lstsq(A, C - f[0], rcond=None)
    uv_line, z = P.camera.project((f[0] + [0.0, h, 0.0])[None])
    miss = float(np.linalg.norm(uv_line[0] - top_uv)) if z[0] > 0 else math.inf
    if not (h > 0 and s > 0 and miss <= TOP_MISS_PX):
        raise P.err(where, f"top [{top_uv[0]:g}, {top_uv[1]:g}] is not straight above floor[0] (the vertical line "
                           f"over it passes {miss:.0f} px away): click the top corner above floor[0]")
    xr, zr, h = _refine_box(P.camera, yaw, xr, zr, float(h), f, uv, top_uv,
                            against is not None and P.sizes(c, where) is None, (P, name, kind == "desk", lo, hi))
    px_m = max(_pixel_metres(P, uv[k]) for k in range(3) if np.isfinite(uv[k, 0]))
    _against_walls(P, where, yaw, xr, zr, lo, hi, px_m)
    if h > hi[1] + WALL_TOL_M:
        raise P.err(where, f"its top ({h:.2f} m) is above the ceiling ({hi[1]:.2f} m)")
    h = float(min(h, hi[1]))
    if kind == "box":
        return [_box(name, yaw, xr, (0.0, h), zr)]
    if h <= DESK_TOP_M + 0.01 or min(xr[1] - xr[0], zr[1] - zr[0]) < 2 * (DESK_LEG_M + DESK_LEG_INSET_M):
        raise P.err(where, f"a desk {xr[1] - xr[0]:.2f} x {zr[1] - zr[0]:.2f} m and {h:.2f} m high is too small for "
                           f"a {DESK_TOP_M * 100:g} cm top on legs: use kind 'box'")
    out = [_box(f"{name}_top", yaw, xr, (h - DESK_TOP_M, h), zr)]
    i0, i1 = DESK_LEG_INSET_M, DESK_LEG_INSET_M + DESK_LEG_M
    k = 0
    for lx in ((xr[0] + i0, xr[0] + i1), (xr[1] - i1, xr[1] - i0)):
        for lz in ((zr[0] + i0, zr[0] + i1), (zr[1] - i1, zr[1] - i0)):
            out.append(_box(f"{name}_leg{k}", yaw, lx, (0.0, h - DESK_TOP_M), lz))
            k += 1
    return out


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
