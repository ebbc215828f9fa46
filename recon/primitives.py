"""Primitive modelling with a scene graph and constraints (seed sec. 3; Gibson, Hubbold & Cook,
"Interactive reconstruction of virtual environments from video sequences", the seed's ref. 29).

The room and its furniture are boxes and quads arranged in a scene graph. Two kinds of
constraint act on them:
  * hierarchical constraints, enforced EXACTLY by construction: a child's axis-aligned bounding
    box (AABB) touches one face of its parent's AABB (default: the child's bottom sits on the
    parent's top face; a root primitive with attach "top" sits on the ground plane y = 0);
  * image constraints, satisfied in the least-squares sense: vertex k of a primitive should
    project to pixel (u, v) of the calibrated camera.
`PrimitiveModel.fit` solves all image constraints at once (scipy least_squares); `drag` changes
one image constraint and re-solves only the dragged primitive and its children (optionally its
parent too: recursion at most one level up and down), warm-started from the last solution.

Model JSON schema (`save_model` / `load_model`; a scene.json loads too, its "primitives" list is
the same format without the scene-graph fields):
{
  "format": "photoar-primitives", "version": 1,
  "primitives": [
    {"name": str (unique), "type": "box" | "quad", "role": "room" | "furniture" | "window" | ...,
     "albedo": [r,g,b] (linear), "emitter": bool, "emitted_radiance": [r,g,b] (emitters only),
     # box: world centre, full extents along its own axes, rotation about world +Y
     "center": [x,y,z] m, "size": [sx,sy,sz] m, "yaw_deg": float (optional, default 0;
                                          local axes = R_y(yaw) world axes, R_y(a) rotates +Z towards +X)
     # quad: as in scene.json; c0->c1 = texture columns, c0->c3 = texture rows
     "corners": [c0,c1,c2,c3] m, "normal": [3] (lit side), "size_m": [|c1-c0|, |c3-c0|],
     # scene graph (all optional):
     "parent": str | null (default null = child of the ground plane),
     "attach": "top" | "bottom" | "left" | "right" | "back" | "front" | "free"
               (which face of the parent's AABB the child's AABB rests on: "top" = child's min y =
                parent's max y + gap, "right" = child's min x = parent's max x + gap, "back" = child's
                max z = parent's min z - gap, ...; default "top" for boxes, "free" for quads; a root may
                only be "top" (on the floor, y = 0) or "free"),
     "gap": float m (default 0), "locked": list of "x","y","z","size","yaw" (default [])
     ... any other keys (albedo_texture, texture_shape, ...) are kept as they are}
  ],
  "image_constraints": [{"primitive": name, "vertex": int, "px": [u, v], "weight": float (default 1)}]
}
Vertex numbering: box vertex k = center + R_y(yaw) @ (size/2 * s) with s_x = +1 if k & 1 else -1,
s_y = +1 if k & 2, s_z = +1 if k & 4; quad vertex k = corner c_k.
Units: metres, radians internally (degrees in JSON), pixels in the OpenCV camera convention of
recon/camera.py.
"""
from __future__ import annotations

import logging
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from recon.io import SceneError, json_array, read_image_rgb, read_json, write_json
from recon.scene import box_quads, parse_primitive, quad_primitive, rot_y

log = logging.getLogger(__name__)

FORMAT_NAME = "photoar-primitives"
FORMAT_VERSION = 1
SIDES: dict[str, tuple[int, int]] = {"top": (1, 1), "bottom": (1, -1), "right": (0, 1), "left": (0, -1),
                                     "front": (2, 1), "back": (2, -1)}
_LOCKABLE = ("x", "y", "z", "size", "yaw")
_KNOWN_KEYS = {"name", "type", "role", "albedo", "emitter", "emitted_radiance", "center", "size", "yaw_deg",
               "corners", "normal", "size_m", "parent", "attach", "gap", "locked"}


@dataclass
class Primitive:
    """One box or quad of the model. `center` is world metres; for a quad `frame0` holds the
    columns (u, v, n) of its orientation at yaw 0 (u = c0->c1 direction, v = c0->c3, n = lit side)."""
    name: str
    kind: str  # "box" | "quad"
    center: np.ndarray  # (3,) m
    size: np.ndarray  # box (3,) full extents in local axes; quad (2,) [w, h] along u, v
    yaw: float = 0.0  # rad about +Y (box: absolute; quad: applied on top of frame0)
    frame0: np.ndarray | None = None  # quad only (3,3)
    parent: str | None = None
    attach: str = "top"
    gap: float = 0.0
    locked: tuple[str, ...] = ()
    role: str = "furniture"
    albedo: np.ndarray = field(default_factory=lambda: np.full(3, 0.5))
    emitter: bool = False
    emitted_radiance: np.ndarray = field(default_factory=lambda: np.zeros(3))
    extra: dict = field(default_factory=dict)  # other JSON keys, written back unchanged

    @staticmethod
    def box(name: str, center, size, yaw_deg: float = 0.0, **kw) -> "Primitive":
        return Primitive(name, "box", np.asarray(center, float), np.asarray(size, float),
                         np.radians(yaw_deg), **kw)

    @staticmethod
    def quad(name: str, corners, normal=None, **kw) -> "Primitive":
        """Quad from 4 corners (c0..c3, a rectangle) and its lit-side normal (default (c1-c0)x(c3-c0))."""
        c = np.asarray(corners, float)
        if c.shape != (4, 3) or not np.all(np.isfinite(c)):
            raise ValueError(f"quad '{name}': corners must be 4 x 3 finite numbers")
        eu, ev = c[1] - c[0], c[3] - c[0]
        w, h = np.linalg.norm(eu), np.linalg.norm(ev)
        if w < 1e-9 or h < 1e-9:
            raise ValueError(f"quad '{name}': degenerate corners (zero-length side)")
        u = eu / w
        v = ev - u * np.dot(ev, u)
        v /= np.linalg.norm(v)
        n = np.cross(u, v)
        if normal is not None and np.dot(np.asarray(normal, float), n) < 0:
            n = -n
        kw.setdefault("attach", "free")
        return Primitive(name, "quad", c.mean(0), np.array([w, h]), 0.0, np.stack([u, v, n], 1), **kw)

    def rotation(self) -> np.ndarray:
        """(3,3) local-to-world rotation (box axes, or quad columns u, v, n)."""
        r = rot_y(self.yaw)
        return r if self.kind == "box" else r @ self.frame0

    def vertices(self, center: np.ndarray | None = None) -> np.ndarray:
        """World vertices: box (8,3) in the documented order, quad (4,3) c0..c3."""
        c = self.center if center is None else center
        r = self.rotation()
        if self.kind == "box":
            return c + (_BOX_SIGNS * (self.size / 2)) @ r.T
        return c + (_QUAD_SIGNS * (self.size / 2)) @ r[:, :2].T

    def half_extent(self) -> np.ndarray:
        """(3,) half sizes of the world AABB."""
        r = np.abs(self.rotation())
        return r @ (self.size / 2) if self.kind == "box" else r[:, :2] @ (self.size / 2)

    def to_json(self) -> dict:
        d = dict(self.extra)
        d.update(name=self.name, type=self.kind, role=self.role, albedo=_list(self.albedo),
                 emitter=bool(self.emitter), parent=self.parent, attach=self.attach, gap=float(self.gap),
                 locked=list(self.locked))
        if self.emitter:
            d["emitted_radiance"] = _list(self.emitted_radiance)
        if self.kind == "box":
            d.update(center=_list(self.center), size=_list(self.size), yaw_deg=float(np.degrees(self.yaw)))
        else:
            corners = self.vertices()
            d.update(corners=[_list(c) for c in corners], normal=_list(self.rotation()[:, 2]),
                     size_m=_list(self.size))
        return d


_BOX_SIGNS = np.array([[1 if k & 1 else -1, 1 if k & 2 else -1, 1 if k & 4 else -1] for k in range(8)], float)
_QUAD_SIGNS = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], float)


def _list(a) -> list[float]:
    return [float(x) for x in np.asarray(a, float).ravel()]


@dataclass
class ImageConstraint:
    """Vertex `vertex` of primitive `primitive` should project to pixel `px` = (u, v)."""
    primitive: str
    vertex: int
    px: np.ndarray  # (2,) pixels
    weight: float = 1.0

    def to_json(self) -> dict:
        return {"primitive": self.primitive, "vertex": int(self.vertex), "px": _list(self.px),
                "weight": float(self.weight)}


# ----------------------------------------------------------------------------------------------
# Loading and saving

def primitive_from_json(p: dict, where: str = "primitives[?]", src: str = "<model>") -> Primitive:
    """One primitive from its JSON dict (schema in the module docstring; validated by
    recon.scene.parse_primitive, the one parser of primitives); ValueError naming `src`."""
    spec = parse_primitive(p, where, src)
    gap = float(json_array(p.get("gap", 0.0), (), f"{where}.gap", src))
    common = dict(parent=p.get("parent"), gap=gap, locked=tuple(p.get("locked", ())),
                  role=spec.role, albedo=spec.albedo, emitter=spec.emitter, emitted_radiance=spec.emitted_radiance,
                  extra={k: v for k, v in p.items() if k not in _KNOWN_KEYS})
    if "attach" in p:
        common["attach"] = str(p["attach"])
    if spec.kind == "box":
        prim = Primitive.box(spec.name, spec.center, spec.size, spec.yaw_deg, **common)
    else:
        try:
            prim = Primitive.quad(spec.name, spec.corners, spec.normal, **common)
        except ValueError as e:
            raise ValueError(f"{src}: field '{where}': {e}") from None
    if prim.attach != "free" and prim.attach not in SIDES:
        raise ValueError(f"{src}: field '{where}.attach' must be one of {sorted(SIDES) + ['free']}, "
                         f"got {prim.attach!r}")
    bad = [x for x in prim.locked if x not in _LOCKABLE]
    if bad:
        raise ValueError(f"{src}: field '{where}.locked' has unknown entries {bad} (allowed {list(_LOCKABLE)})")
    return prim


def model_from_dict(d: dict, src: str = "<model>", infer_graph: bool | None = None) -> "PrimitiveModel":
    """Model from a model dict or a scene.json dict. `infer_graph` (default: when no primitive has a
    'parent'/'attach' field, i.e. a plain scene.json) guesses the scene graph with `infer_scene_graph`."""
    if not isinstance(d, dict) or not isinstance(d.get("primitives"), list) or not d["primitives"]:
        raise ValueError(f"{src}: field 'primitives' must be a non-empty list")
    prims = [primitive_from_json(p, f"primitives[{i}]", src) for i, p in enumerate(d["primitives"])]
    if infer_graph is None:
        infer_graph = not any(isinstance(p, dict) and ("parent" in p or "attach" in p) for p in d["primitives"])
    cons = []
    for i, c in enumerate(d.get("image_constraints", [])):
        where = f"image_constraints[{i}]"
        if not isinstance(c, dict) or "primitive" not in c or "vertex" not in c:
            raise ValueError(f"{src}: field '{where}' needs 'primitive', 'vertex' and 'px'")
        vertex = float(json_array(c["vertex"], (), f"{where}.vertex", src))
        if vertex != int(vertex):
            raise SceneError(f"{src}: field '{where}.vertex' must be a whole number, got {c['vertex']!r}")
        cons.append(ImageConstraint(str(c["primitive"]), int(vertex), json_array(c.get("px"), (2,), f"{where}.px", src),
                                    float(json_array(c.get("weight", 1.0), (), f"{where}.weight", src))))
    model = PrimitiveModel(prims, cons, src=src, infer_graph=infer_graph)
    return model


def load_model(path: str | os.PathLike, infer_graph: bool | None = None) -> "PrimitiveModel":
    """Read a model JSON (or a scene.json) -> PrimitiveModel; ValueError/FileNotFoundError naming the file."""
    path = Path(path)
    d = read_json(path)
    return model_from_dict(d, str(path), infer_graph)


def model_to_dict(model: "PrimitiveModel") -> dict:
    return {"format": FORMAT_NAME, "version": FORMAT_VERSION,
            "primitives": [p.to_json() for p in model.prims],
            "image_constraints": [c.to_json() for c in model.constraints]}


def save_model(path: str | os.PathLike, model: "PrimitiveModel") -> None:
    """Write the model JSON (schema in the module docstring), atomically (temp file, then rename)."""
    write_json(path, model_to_dict(model), indent=1, sort_keys=False)


# ----------------------------------------------------------------------------------------------
# Scene graph

def infer_scene_graph(prims: list[Primitive], tol: float = 5e-3) -> None:
    """Guess the scene graph (in place) for plain scene.json input, "from the ground up":
      * a quad lying within `tol` m of the plane of a larger axis-aligned quad that contains it (a
        window on a wall, a lamp on the ceiling) is attached to it on the side its normal faces,
        with the gap between them;
      * a box or quad whose bottom is on the floor (y ~ 0) sits on the ground, or on the floor quad
        ("top"), when there is one that it overlaps in x-z (walls stand on the floor);
      * a box whose bottom touches the top of another box it overlaps in x-z sits on that box;
      * a horizontal quad level with the top of a vertical room quad (the ceiling) sits on it;
      * everything else is free.
    A single photo leaves a free quad's distance from the camera undetermined (scale ambiguity);
    attaching it to the ground fixes it."""
    aabb = {p.name: (p.center - p.half_extent(), p.center + p.half_extent()) for p in prims}

    def overlaps_xz(a: str, b: str) -> bool:
        (alo, ahi), (blo, bhi) = aabb[a], aabb[b]
        return bool(np.all(alo[[0, 2]] <= bhi[[0, 2]] + tol) and np.all(ahi[[0, 2]] >= blo[[0, 2]] - tol))

    def axis_of(p: Primitive) -> int | None:
        n = p.rotation()[:, 2]
        a = int(np.argmax(np.abs(n)))
        return a if abs(n[a]) > 1 - 1e-6 else None

    floors = [q for q in prims if q.kind == "quad" and axis_of(q) == 1 and abs(q.center[1]) < tol]
    for p in prims:
        p.parent, p.attach, p.gap = None, "free", 0.0
        lo, hi = aabb[p.name]
        if p.kind == "quad":
            axis = axis_of(p)
            if axis is None:
                continue
            others = [a for a in range(3) if a != axis]
            for q in prims:
                if q is p or q.kind != "quad" or axis_of(q) != axis or q.size.prod() <= p.size.prod():
                    continue
                qlo, qhi = aabb[q.name]
                d = p.center[axis] - q.center[axis]
                if abs(d) < tol and np.all(lo[others] >= qlo[others] - tol) and np.all(hi[others] <= qhi[others] + tol):
                    side = [s for s, (a, sg) in SIDES.items() if a == axis and sg == (1 if d >= 0 else -1)][0]
                    p.parent, p.attach, p.gap = q.name, side, abs(d)
                    break
            if p.parent is not None:
                continue
        if abs(lo[1]) < tol:
            p.attach = "top"
            base = [q for q in floors if q is not p and overlaps_xz(p.name, q.name)]
            if base and not (p.kind == "quad" and axis_of(p) == 1):
                p.parent = base[0].name
            continue
        for q in prims:
            if q is p or p.parent is not None:
                continue
            qlo, qhi = aabb[q.name]
            if abs(qhi[1] - lo[1]) < tol and overlaps_xz(p.name, q.name):
                if p.kind == "box" and q.kind == "box":
                    p.parent, p.attach = q.name, "top"
                elif p.kind == "quad" and q.kind == "quad" and axis_of(p) == 1 and axis_of(q) != 1 \
                        and q.role == "room":
                    p.parent, p.attach = q.name, "top"
        # a cycle is impossible: parents are always lower (or coplanar containers, which are larger)


class PrimitiveModel:
    """Primitives + image constraints; hierarchical constraints are enforced in `update_poses`.

    Each primitive's parameters: an offset of its centre from its parent's centre (world axes; from
    the world origin for a root), its size and its yaw. The offset along the attach axis is not a
    parameter: it follows from the hierarchical constraint."""

    def __init__(self, prims: list[Primitive], constraints: list[ImageConstraint] | None = None,
                 src: str = "<model>", infer_graph: bool = False):
        self.src = src
        self.prims = list(prims)
        self.constraints = list(constraints or [])
        self.index = {}
        for i, p in enumerate(self.prims):
            if p.name in self.index:
                raise ValueError(f"{src}: primitive name '{p.name}' is used twice")
            self.index[p.name] = i
        if infer_graph:
            infer_scene_graph(self.prims)
        for p in self.prims:
            if p.parent is not None and p.parent not in self.index:
                raise ValueError(f"{src}: primitive '{p.name}': parent '{p.parent}' does not exist")
            if p.parent is None and p.attach not in ("top", "free"):
                raise ValueError(f"{src}: primitive '{p.name}': a root can only attach 'top' (floor) or 'free', "
                                 f"got '{p.attach}'")
        self.order = self._topological_order()
        self.children: dict[str, list[str]] = {p.name: [] for p in self.prims}
        for p in self.prims:
            if p.parent is not None:
                self.children[p.parent].append(p.name)
        for c in self.constraints:
            self._check_constraint(c)
        self.update_poses()  # snap every primitive onto its hierarchical constraint

    def _check_constraint(self, c: ImageConstraint) -> None:
        if c.primitive not in self.index:
            raise ValueError(f"{self.src}: image constraint names unknown primitive '{c.primitive}'")
        nv = 8 if self[c.primitive].kind == "box" else 4
        if not 0 <= c.vertex < nv:
            raise ValueError(f"{self.src}: image constraint on '{c.primitive}': vertex {c.vertex} not in 0..{nv - 1}")
        if not (np.all(np.isfinite(c.px)) and c.weight > 0):
            raise ValueError(f"{self.src}: image constraint on '{c.primitive}': pixel must be finite, weight > 0")

    def __getitem__(self, name: str) -> Primitive:
        return self.prims[self.index[name]]

    def _topological_order(self) -> list[int]:
        order, state = [], {}

        def visit(i: int, chain: tuple) -> None:
            if state.get(i) == 2:
                return
            if i in chain:
                raise ValueError(f"{self.src}: scene graph has a cycle through '{self.prims[i].name}'")
            p = self.prims[i]
            if p.parent is not None:
                visit(self.index[p.parent], chain + (i,))
            state[i] = 2
            order.append(i)

        for i in range(len(self.prims)):
            visit(i, ())
        return order

    # -- poses ---------------------------------------------------------------------------------
    def attached_axis(self, p: Primitive) -> int | None:
        return None if p.attach == "free" else SIDES[p.attach][0]

    def snapped_center(self, p: Primitive, center: np.ndarray) -> np.ndarray:
        """`center` with its attach-axis coordinate set by the hierarchical constraint."""
        if p.attach == "free":
            return center
        axis, sign = SIDES[p.attach]
        if p.parent is None:
            face = 0.0  # ground plane
        else:
            q = self[p.parent]
            face = q.center[axis] + sign * q.half_extent()[axis]
        c = center.copy()
        c[axis] = face + sign * (p.gap + p.half_extent()[axis])
        return c

    def update_poses(self, names: list[str] | None = None) -> None:
        """Re-apply the hierarchical constraints top-down (all primitives, or `names` in graph order)."""
        idx = self.order if names is None else [i for i in self.order if self.prims[i].name in set(names)]
        for i in idx:
            p = self.prims[i]
            p.center = self.snapped_center(p, p.center)

    def descendants(self, name: str) -> list[str]:
        out, stack = [], list(self.children[name])
        while stack:
            n = stack.pop()
            out.append(n)
            stack.extend(self.children[n])
        return out

    # -- parameters ----------------------------------------------------------------------------
    def _free_slots(self, p: Primitive) -> list[tuple[str, int]]:
        """Free parameters of a primitive: ("off", axis), ("size", k), ("yaw", 0)."""
        ax = self.attached_axis(p)
        slots = [("off", a) for a in range(3) if a != ax and "xyz"[a] not in p.locked]
        if "size" not in p.locked:
            slots += [("size", k) for k in range(len(p.size))]
        if "yaw" not in p.locked:
            slots.append(("yaw", 0))
        return slots

    def _parent_center(self, p: Primitive) -> np.ndarray:
        return np.zeros(3) if p.parent is None else self[p.parent].center

    def get_params(self, names: list[str]) -> tuple[np.ndarray, list]:
        layout, x = [], []
        for n in names:
            p = self[n]
            off = p.center - self._parent_center(p)
            for kind, k in self._free_slots(p):
                layout.append((n, kind, k))
                x.append(off[k] if kind == "off" else p.size[k] if kind == "size" else p.yaw)
        return np.array(x, float), layout

    def set_params(self, x: np.ndarray, layout: list, affected: list[int]) -> None:
        """Write a parameter vector and re-pose the affected primitives (graph order), children
        keeping their offsets from their parents."""
        offs = {}
        for i in affected:
            p = self.prims[i]
            offs[p.name] = p.center - self._parent_center(p)
        for v, (n, kind, k) in zip(x, layout):
            p = self[n]
            if kind == "off":
                offs[n][k] = v
            elif kind == "size":
                p.size[k] = v
            else:
                p.yaw = v
        for i in affected:
            p = self.prims[i]
            p.center = self.snapped_center(p, self._parent_center(p) + offs[p.name])

    # -- solving -------------------------------------------------------------------------------
    def residuals(self, camera, constraints: list[ImageConstraint] | None = None) -> np.ndarray:
        """(M,2) weighted reprojection residuals in pixels of `constraints` (default all)."""
        cons = self.constraints if constraints is None else constraints
        if not cons:
            return np.zeros((0, 2))
        verts = {}
        pts = np.empty((len(cons), 3))
        for j, c in enumerate(cons):
            if c.primitive not in verts:
                verts[c.primitive] = self[c.primitive].vertices()
            pts[j] = verts[c.primitive][c.vertex]
        xc = pts @ camera.R.T + camera.t
        z = np.maximum(xc[:, 2], 1e-6)
        K = camera.K
        uv = np.stack([K[0, 0] * xc[:, 0] / z + K[0, 2], K[1, 1] * xc[:, 1] / z + K[1, 2]], 1)
        w = np.array([c.weight for c in cons])[:, None]
        return w * (uv - np.array([c.px for c in cons]))

    def solve(self, camera, names: list[str] | None = None, prior: float = 1e-3, tol: float = 1e-10,
              max_nfev: int | None = None) -> dict:
        """Least-squares fit of the free parameters of `names` (default all primitives) to the image
        constraints on them and on everything that moves with them. `prior` (pixels per metre or
        radian) ties parameters weakly to their current values, so a parameter no constraint sees
        keeps its warm-start value. Returns {"cost", "rms_px", "nfev", "n_params"}."""
        from scipy.optimize import least_squares

        names = [p.name for p in self.prims] if names is None else list(names)
        moving = set(names)
        for n in names:
            moving.update(self.descendants(n))
        affected = [i for i in self.order if self.prims[i].name in moving]
        cons = [c for c in self.constraints if c.primitive in moving]
        x0, layout = self.get_params(names)
        if len(x0) == 0 or not cons:
            return {"cost": 0.0, "rms_px": 0.0, "nfev": 0, "n_params": len(x0)}
        lower = np.array([1e-3 if kind == "size" else -np.inf for _, kind, _ in layout])
        x0 = np.maximum(x0, lower + 1e-9)
        saved = self._snapshot(affected)

        def fun(x):
            self.set_params(x, layout, affected)
            return np.concatenate([self.residuals(camera, cons).ravel(), prior * (x - x0)])

        sparsity = self._sparsity(cons, layout) if len(x0) > 12 else None
        try:
            res = least_squares(fun, x0, bounds=(lower, np.inf), method="trf", x_scale=1.0, jac_sparsity=sparsity,
                                xtol=tol, ftol=tol, gtol=tol, max_nfev=max_nfev)
        except Exception:
            self._restore(saved)
            raise
        if not np.all(np.isfinite(res.x)):
            self._restore(saved)
            raise RuntimeError(f"{self.src}: primitive fit diverged")
        self.set_params(res.x, layout, affected)
        r = self.residuals(camera, cons)
        return {"cost": float(res.cost), "rms_px": float(np.sqrt(np.mean(np.sum(r ** 2, 1)))), "nfev": int(res.nfev),
                "n_params": len(x0)}

    def _sparsity(self, cons: list[ImageConstraint], layout: list) -> np.ndarray:
        """Which parameters each residual can depend on: its primitive's and its ancestors'."""
        anc = {}
        for c in cons:
            if c.primitive not in anc:
                chain, n = set(), c.primitive
                while n is not None:
                    chain.add(n)
                    n = self[n].parent
                    # a child's snapped centre depends on its parent's size/yaw/offsets too
                anc[c.primitive] = chain
        m = len(cons) * 2 + len(layout)
        s = np.zeros((m, len(layout)), bool)
        for j, c in enumerate(cons):
            s[2 * j:2 * j + 2] = [n in anc[c.primitive] for n, _, _ in layout]
        s[len(cons) * 2:] = np.eye(len(layout), dtype=bool)
        return s

    def _snapshot(self, idx: list[int]):
        return [(i, self.prims[i].center.copy(), self.prims[i].size.copy(), self.prims[i].yaw) for i in idx]

    def _restore(self, snap) -> None:
        for i, c, s, y in snap:
            self.prims[i].center, self.prims[i].size, self.prims[i].yaw = c, s, y

    def fit(self, camera, **kw) -> dict:
        """Fit every primitive to all image constraints at once."""
        return self.solve(camera, None, **kw)

    def set_constraint(self, name: str, vertex: int, px, weight: float = 1.0) -> ImageConstraint:
        """Add or move the image constraint on (primitive, vertex)."""
        c = ImageConstraint(name, int(vertex), np.asarray(px, float), float(weight))
        self._check_constraint(c)
        for k, old in enumerate(self.constraints):
            if old.primitive == name and old.vertex == c.vertex:
                self.constraints[k] = c
                return c
        self.constraints.append(c)
        return c

    def drag(self, camera, name: str, vertex: int, px, up: bool = False, tol: float = 1e-6,
             max_nfev: int = 50) -> dict:
        """Interactive update: move one image constraint and re-solve the dragged primitive and its
        children (one level down), warm-started from the current solution. `up` also re-solves its
        parent (one level up); the parent carries its whole subtree, so this costs more."""
        self.set_constraint(name, vertex, px)
        p = self[name]
        names = ([p.parent] if up and p.parent is not None else []) + [name] + self.children[name]
        return self.solve(camera, names, tol=tol, max_nfev=max_nfev)

    # -- export --------------------------------------------------------------------------------
    def room_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(room_min, room_max): AABB of the 'room' primitives (all primitives if there are none)."""
        sel = [p for p in self.prims if p.role == "room"] or self.prims
        v = np.concatenate([p.vertices() for p in sel])
        return v.min(0), v.max(0)

    def to_quads(self, room_min: np.ndarray | None = None, room_max: np.ndarray | None = None,
                 root: str | os.PathLike | None = None) -> list:
        """The model as the engine's one-sided quads (recon.scene.Quad), built as recon.scene.load_scene
        builds them (recon.scene.box_quads, quad_primitive). With `root`, quad albedo textures
        ('albedo_texture', relative to root) are loaded too."""
        if room_min is None or room_max is None:
            room_min, room_max = self.room_bounds()
        room_min, room_max = np.asarray(room_min), np.asarray(room_max)
        quads = []
        for p in self.prims:
            albedo = np.asarray(p.albedo, float)
            if p.kind == "box":
                quads += box_quads(p.name, p.center, p.size, p.yaw, albedo, p.role, room_min, room_max)
                continue
            emission = np.asarray(p.emitted_radiance, float) if p.emitter else np.zeros(3)
            texture = None
            if root is not None and p.extra.get("albedo_texture"):
                texture = read_image_rgb(Path(root) / p.extra["albedo_texture"]).astype(np.float32) / 255.0
            quads.append(quad_primitive(p.name, p.vertices(), p.rotation()[:, 2].copy(), albedo, emission, p.role,
                                        texture))
        return quads

    def to_scene(self, base, root: str | os.PathLike | None = None):
        """A copy of recon.scene.Scene `base` (camera, object, response, photo) whose quads and room
        bounds come from this model, ready for recon.patches.build_patches and the engine."""
        from dataclasses import replace

        lo, hi = self.room_bounds()
        return replace(base, quads=self.to_quads(lo, hi, root), room_min=lo, room_max=hi)
