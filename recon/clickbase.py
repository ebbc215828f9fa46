"""The click model's shared parts (recon/clickmodel.py): constants, the model's types, rays on
planes, and the clicks file's parsing and validation (_Clicks).

Conventions: the camera's world frame (floor y = 0, +Y up), metres; pixel (u, v) with (0, 0) the centre
of the top-left pixel."""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, field

import numpy as np

from recon.camera import Camera
from recon.io import SceneError, json_array, json_field, read_json


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
    measure: dict[str, list[dict]] | None = None  # with the photo: piece -> [{"size_m": index, "floor": [i, i + 1],
    # "along": "x" | "z", "loose": side, "about_m": the fit's length}]: the one size a tape gives for a loose
    # side whose opposite side is sure (_refine_box)

    def to_json(self) -> dict:
        model = {"from": "clicks", "ceiling_from": self.ceiling_from, "guessed_walls": self.guessed}
        if self.refined is not None:
            model["refined_from_photo"] = self.refined
            model["ill_determined"] = {k: {side: round(Z99 * v, 4) for side, v in sides.items()}
                                       for k, sides in (self.uncertain or {}).items()}
            model["measure"] = self.measure or {}
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
        self.measure: dict[str, list[dict]] = {}  # piece -> the sizes to tape that would pin its loose sides
        self.ceiling_sd = 0.0  # m: the ceiling height's standard deviation when clicked (with the photo)
        self.wall_sd: dict[tuple[int, int], float] = {}  # (axis, side) -> a clicked wall offset's sd (m) for
        # _hold_on_walls, with the photo: at least its foot line's noise floor in metres
        self.against: dict[tuple[int, int], list[tuple[str, float, float]]] = {}  # with the photo: (axis, side) of a
        # clicked wall -> [(piece, its own fit of its side held on that wall m, that fit's variance m^2)]
        # (recon/clickjoint.py)
        self.sides: dict[str, tuple[np.ndarray, dict[int, float]]] = {}  # with the photo: an axis-aligned piece ->
        # ([x min, x max, z min, z max] m, {side: sd m}), for the pieces modelled after it (_piece_planes)

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
        """The optional "size_m" [a, b] (m, positive; one of them may be null: nan, the one size the
        model asked to tape, `model.measure`) of a primitive with corners out of the photo or a side
        its clicks and the photo pin loosely."""
        if c.get("size_m") is None:
            return None
        raw = c["size_m"]
        if isinstance(raw, list) and len(raw) == 2 and any(q is None for q in raw) and not all(q is None for q in raw):
            k = next(i for i, q in enumerate(raw) if q is not None)
            one = json_array([raw[k]], (1,), f"{where}.size_m[{k}]", self.src)[0]
            v = np.full(2, np.nan)
            v[k] = one
        else:
            v = json_array(raw, (2,), f"{where}.size_m", self.src)
        if not np.all(v[np.isfinite(v)] > 0) or np.isnan(v).all():
            raise self.err(where, f"size_m must be positive (one of the two may be null), got {raw!r}")
        return v

    def missing_end(self, where: str, known: float, size: np.ndarray | None, k: int, corners,
                    behind: bool = False) -> float:
        """The end of a side no clicked corner pins: `known` -/+ size[k], whichever puts the unclicked
        corners (callable end -> list of world points) out of the photo; when both put them in it, the
        corners are hidden (behind the piece, or another one): the end that puts them further from
        the camera. behind: the user says the unclicked corner is in the photo, hidden (the clicks
        file's "hidden"): the end that puts it in the photo (of two, the further from the camera)."""
        if size is None or not np.isfinite(size[k]):
            raise self.err(where, "a side has no clicked corner (corners out of the photo are null): give its "
                                  f"length in size_m[{k}], or the wall it stands against in 'against'")
        ends = (known - size[k], known + size[k])

        def farthest(cands) -> float:  # the end whose corners lie furthest from the camera (mean distance)
            far = [float(np.mean([np.linalg.norm(X - self.camera.centre) for X in corners(e)])) for e in cands]
            return float(cands[int(np.argmax(far))])

        if behind:
            return farthest([e for e in ends if not any(self.outside(X) for X in corners(e))] or list(ends))
        ok = [e for e in ends if all(self.outside(X) for X in corners(e))]
        if not ok:
            ok = [farthest(ends)]
        if len(ok) != 1:
            raise self.err(where, "cannot tell on which side the corners out of the photo lie (size_m puts them "
                                  "out of it both ways): click them")
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


def _floor(P: _Clicks, uv, where: str, at: str, base: float = 0.0, on: str | None = None) -> np.ndarray:
    """The point (3,) where click uv's ray meets the floor (y = 0), or with `on` (a piece's name) the
    top of that piece, the plane y = base (m, below the camera); ClickError when it meets it behind
    the camera (on or above the plane's horizon)."""
    p = hit_plane(P.camera, uv, [0.0, 1.0, 0.0], base)
    if p is None:
        if on is not None:
            raise P.err(where, f"{at} = [{uv[0]:g}, {uv[1]:g}] is on or above the horizon of the top of {on!r} "
                               f"({base:.2f} m high): a corner on it must be clicked below that horizon")
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


def _pixel_metres(P: _Clicks, uv, base: float = 0.0) -> float:
    """Metres on the floor (or the plane y = base, m) that one pixel spans at the click uv there (the
    larger of u and v)."""
    p = hit_plane(P.camera, uv, [0.0, 1.0, 0.0], base)
    steps = [hit_plane(P.camera, np.asarray(uv) + d, [0.0, 1.0, 0.0], base) for d in ((1.0, 0.0), (0.0, 1.0))]
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
