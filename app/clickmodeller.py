"""The model mode of `photoar gui --model`, with no GUI code: clicks on the photo build the clicks
list of `photoar model --clicks` (recon/clickmodel.py, docs/scene-format.md "Clicks file"), each
primitive is modelled and drawn as soon as its clicks are complete, a clicked point can be dragged,
edits undo and redo, and saving writes clicks.json + primitives.json through app.cmd_model.write_model
(the command's own code path).

Tools and the clicks each needs, in photo pixels (u, v), (0, 0) the centre of the top-left pixel:
  wall: 2 points on its foot (where it meets the floor);
  ceiling: 1 point where the wall `quad_on` (default: the last wall clicked) meets the ceiling;
  desk, box: 3 floor corners in order around the footprint, then the top corner above the first;
  window, lamp: 4 corners in order around it, on the wall `quad_on` (default: the last wall
  clicked) or "ceiling"; `opening` marks a window that is a hole in its wall.
A corner out of the photo is skipped (skip_corner: a null in the clicks file; furniture floor[1] or
floor[2], up to two quad corners); the side it alone would fix comes from `size_m` (metres, tape) or,
for furniture, the wall it stands `against`. A piece standing on another (`stands_on`: "on" in the
clicks file) has its floor corners clicked on that piece's top.
"""
from __future__ import annotations

import copy
import math
from dataclasses import dataclass

import numpy as np

from recon.camera import Camera

TOOLS = ("wall", "ceiling", "desk", "box", "window", "lamp")
NEEDS = {"wall": 2, "ceiling": 1, "desk": 4, "box": 4, "window": 4, "lamp": 4}
GRAB_PX = 8.0  # a press this close to a clicked point drags it instead of adding one


@dataclass
class Handle:
    """A clicked point: clicks[index][key] (or [key][k])."""

    index: int
    key: str
    k: int | None


class ModelController:
    """State of the model mode: the clicks, the points of the primitive being clicked, undo/redo."""

    def __init__(self, camera: Camera, photo: np.ndarray, clicks: dict | None = None, src: str = "clicks.json",
                 ceiling_height: float | None = None):
        self.camera, self.photo, self.src, self.ceiling_height = camera, photo, src, ceiling_height
        self.clicks: list[dict] = copy.deepcopy((clicks or {}).get("clicks", []))
        self.tool = "wall"
        self.quad_on: str | None = None  # None: the last wall clicked
        self.opening = False
        self.size_m: list[float] | None = None  # [a, b] m for sides no clicked corner fixes
        self.against: str | None = None  # the wall a furniture piece stands against
        self.stands_on: str | None = None  # the furniture piece a new one stands on ("on"; None: the floor)
        self.pending: list[list[float] | None] = []
        self.pending_hidden: list[int] = []  # the pending piece's null floor corners seen behind a piece ("hidden")
        self._undo: list[tuple] = []
        self._redo: list[tuple] = []
        self._drag: Handle | None = None
        self.message = ""
        self._edges = None  # the photo's recon.edgesnap.EdgeImage, made at the first model

    @property
    def edges(self):
        """The photo prepared once for refining the clicks (the model is redone on every click)."""
        if self._edges is None:
            from recon.edgesnap import EdgeImage

            self._edges = EdgeImage(self.photo)
        return self._edges

    # ------------------------------------------------------------------ state and history
    def _state(self) -> tuple:
        return copy.deepcopy(self.clicks), copy.deepcopy(self.pending), list(self.pending_hidden)

    def _push(self) -> None:
        self._undo.append(self._state())
        self._redo.clear()

    def undo(self) -> bool:
        if not self._undo:
            return False
        self._redo.append(self._state())
        self.clicks, self.pending, self.pending_hidden = self._undo.pop()
        return True

    def redo(self) -> bool:
        if not self._redo:
            return False
        self._undo.append(self._state())
        self.clicks, self.pending, self.pending_hidden = self._redo.pop()
        return True

    def set_tool(self, tool: str) -> None:
        if tool not in TOOLS:
            raise ValueError(f"unknown tool {tool!r} (one of {', '.join(TOOLS)})")
        if tool != self.tool and self.pending:
            self._push()
            self.pending, self.pending_hidden = [], []
        self.tool = tool

    def walls(self) -> list[str]:
        return [c["name"] for c in self.clicks if c.get("label") == "wall"]

    def pieces(self) -> list[str]:
        """The furniture clicked so far (what a new piece may stand on)."""
        return [c["name"] for c in self.clicks if c.get("label") == "furniture"]

    def _name(self, base: str) -> str:
        used = {c.get("name") for c in self.clicks}
        k = 1
        while f"{base}{k}" in used:
            k += 1
        return f"{base}{k}"

    def set_size(self, name: str, k: int, metres: float) -> None:
        """Give furniture piece `name` its size_m[k] (m, taped; the other entry kept, or null): the one
        size the model asks for where a side is pinned worse than 3 cm and its opposite side is sure
        (ClickModel.measure, shown in `message`). Undoable."""
        c = next((c for c in self.clicks if c.get("label") == "furniture" and c.get("name") == name), None)
        if c is None:
            raise ValueError(f"no furniture piece {name!r} clicked (one of {', '.join(self.pieces()) or 'none'})")
        if k not in (0, 1) or not (math.isfinite(metres) and metres > 0):
            raise ValueError(f"size_m[{k}] = {metres!r}: expected index 0 or 1 and a positive length in metres")
        self._push()
        sizes = list(c.get("size_m") or [None, None])
        sizes[k] = float(metres)
        c["size_m"] = sizes

    # ------------------------------------------------------------------ clicking
    def inside(self, u: float, v: float) -> bool:
        return -0.5 <= u <= self.camera.width - 0.5 and -0.5 <= v <= self.camera.height - 0.5

    def click(self, u: float, v: float) -> dict | None:
        """Add a point for the current tool; returns the click entry it completes (else None)."""
        if not self.inside(u, v):
            raise ValueError(f"[{u:.1f}, {v:.1f}] is outside the photo")
        walls = self.walls()
        if self.tool in ("ceiling", "window") and not walls and not (self.tool == "window" and self.quad_on):
            raise ValueError(f"click a wall's foot first: a {self.tool} lies on a clicked wall")
        self._push()
        self.pending.append([float(u), float(v)])
        return self._complete()

    def skip_corner(self, hidden: bool = False) -> dict | None:
        """The next corner is out of the photo (null), or with `hidden` (furniture) in the photo but
        behind the piece or another one (null, listed in the click's "hidden"); returns the click
        entry it completes."""
        k = len(self.pending)
        if not ((self.tool in ("desk", "box") and k in (1, 2)) or (self.tool in ("window", "lamp") and k < 4)):
            raise ValueError(f"{self.tool}: point {k + 1} cannot be out of the photo (furniture: the second or third "
                             "floor corner; windows and lamps: any corner)")
        if hidden and self.tool not in ("desk", "box"):
            raise ValueError(f"{self.tool}: only a furniture floor corner can be marked hidden")
        self._push()
        if hidden:
            self.pending_hidden.append(k)
        self.pending.append(None)
        return self._complete()

    def _complete(self) -> dict | None:
        if len(self.pending) < NEEDS[self.tool]:
            return None
        walls = self.walls()
        p, self.pending = self.pending, []
        hidden, self.pending_hidden = self.pending_hidden, []
        t = self.tool
        if t == "wall":
            c = {"label": "wall", "name": self._name("wall"), "floor_line": p}
        elif t == "ceiling":
            on = self.quad_on if self.quad_on in walls else walls[-1]
            c = {"label": "ceiling", "wall": on, "edge": p[0]}
        elif t in ("desk", "box"):
            c = {"label": "furniture", "name": self._name(t), "kind": t, "floor": p[:3], "top": p[3]}
            if self.against and None in p:
                c["against"] = self.against
            if self.stands_on:  # its floor corners clicked on that piece's top
                c["on"] = self.stands_on
            if hidden:
                c["hidden"] = sorted(hidden)
        else:
            on = self.quad_on or (walls[-1] if walls else "ceiling")
            c = {"label": t, "name": self._name(t), "on": on, "corners": p,
                 "opening": bool(self.opening and t == "window")}
        if None in p and self.size_m is not None:
            c["size_m"] = [float(x) for x in self.size_m]
        self.clicks.append(c)
        return c

    def points(self) -> list[tuple[Handle, list[float]]]:
        """Every clicked point of the complete clicks, with its handle."""
        out = []
        for i, c in enumerate(self.clicks):
            for key in ("floor_line", "floor", "corners"):
                for k, q in enumerate(c.get(key) or []):
                    if q is not None:
                        out.append((Handle(i, key, k), q))
            for key in ("edge", "top"):
                if c.get(key) is not None:
                    out.append((Handle(i, key, None), c[key]))
        return out

    def grab(self, u: float, v: float, radius: float = GRAB_PX) -> bool:
        """Start dragging the clicked point nearest (u, v) within `radius` px; False if none."""
        best = None
        for h, q in self.points():
            d = math.hypot(q[0] - u, q[1] - v)
            if d <= radius and (best is None or d < best[0]):
                best = (d, h)
        if best is None:
            return False
        self._push()
        self._drag = best[1]
        return True

    def drag_to(self, u: float, v: float) -> None:
        """Move the grabbed point (kept inside the photo)."""
        h = self._drag
        if h is None:
            return
        u = float(np.clip(u, -0.5, self.camera.width - 0.5))
        v = float(np.clip(v, -0.5, self.camera.height - 0.5))
        c = self.clicks[h.index]
        if h.k is None:
            c[h.key] = [u, v]
        else:
            c[h.key][h.k] = [u, v]

    def release(self) -> None:
        self._drag = None

    @property
    def dragging(self) -> bool:
        return self._drag is not None

    # ------------------------------------------------------------------ the model
    def clicks_json(self) -> dict:
        return {"clicks": copy.deepcopy(self.clicks)}

    def model(self):
        """(ClickModel or None, message): the model of the clicks so far (None with the refusal's
        one line while the clicks do not make a room yet, e.g. before the first wall); with a model,
        the message names each size to tape (ClickModel.measure: set_size gives it), else empty."""
        from recon.clickmodel import model_from_clicks, tape_request
        from recon.io import SceneError

        if not self.clicks:
            return None, "click a wall's foot (two points where it meets the floor)"
        try:
            import logging

            logger = logging.getLogger("photoar")
            level = logger.level
            logger.setLevel(logging.ERROR)  # the preview is redone on every click: no repeated warnings
            try:
                m = model_from_clicks(self.clicks_json(), self.camera, self.src, self.ceiling_height, photo=self.edges)
                return m, "\n".join(f"{name}: {tape_request(asks)}" for name, asks in (m.measure or {}).items())
            finally:
                logger.setLevel(level)
        except SceneError as e:
            return None, str(e)

    def overlay(self) -> np.ndarray:
        """The photo with the model drawn over it (app.cmd_model.draw_primitives), the clicked
        points circled and the pending points of the primitive being clicked as filled dots."""
        import cv2

        from app.cmd_model import draw_primitives

        model, self.message = self.model()
        img = draw_primitives(self.photo, model.primitives if model else [], self.camera, self.clicks_json())
        for q in (q for q in self.pending if q is not None):
            cv2.circle(img, (int(round(q[0])), int(round(q[1]))), 3, (255, 60, 60), -1, cv2.LINE_AA)
        return img

    def save(self, out) -> object:
        """Write out/clicks.json and out/primitives.json (and overlay.png) with app.cmd_model.write_model."""
        from app.cmd_model import write_model

        return write_model(out, self.clicks_json(), self.camera, self.photo, self.src, self.ceiling_height,
                           self.edges)
