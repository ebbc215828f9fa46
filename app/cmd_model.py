"""`photoar model SCENE.json --image IMAGE --camera camera.json --out DIR`: fit a primitive model's
image constraints (seed sec. 3, recon/primitives.py) and write the fitted model (model.json, the
schema of recon/primitives.py) and overlay.png (its wireframe over the photo), all or nothing.

`photoar model --clicks clicks.json --camera camera.json --out DIR [--image PHOTO]`: the room
modelled from clicks on the calibrated photo (recon/clickmodel.py; the clicks file is documented in
docs/scene-format.md): DIR/primitives.json (the `photoar scene --primitives` format), a copy of the
clicks as DIR/clicks.json and, with --image, DIR/overlay.png (the model drawn over the photo); with
--image the clicks are also refined against the photo's edges (recon/clickedges.py).

SCENE.json is a model file or a scene.json (its "primitives"; the scene graph is then inferred).
Without image constraints in it, nothing moves and the overlay shows the model as it is.
"""
from __future__ import annotations

import argparse
import logging
from pathlib import Path

import numpy as np

log = logging.getLogger("photoar")


def register(sub) -> None:
    p = sub.add_parser("model", help="fit a box/quad model to its image constraints in a calibrated photo")
    p.add_argument("scene", type=Path, nargs="?", default=None,
                   help="model JSON or scene.json (primitives, image_constraints); not with --clicks")
    p.add_argument("--clicks", type=Path, default=None,
                   help="clicks.json: model the room from clicks on the photo (walls' floor lines, a wall-ceiling "
                        "edge, furniture corners, window/lamp corners; docs/scene-format.md) into DIR/primitives.json")
    p.add_argument("--ceiling-height", type=float, default=None,
                   help="with --clicks: the ceiling's height above the floor (m) when no click gives it (default "
                        "2.5 m, with a warning)")
    p.add_argument("--image", type=Path, default=None,
                   help="the photo (required without --clicks; with it, the clicks are refined against its edges "
                        "and overlay.png draws the model over it)")
    p.add_argument("--camera", type=Path, required=True, help="camera.json from `photoar calibrate` (or a "
                   "scene.json, whose main_camera is used)")
    p.add_argument("--out", type=Path, required=True, help="output folder")
    p.set_defaults(run=run)


def draw_wireframe(photo: np.ndarray, model, camera) -> np.ndarray:
    """RGB uint8 copy of `photo` with every primitive's edges (in front of the camera) and the image
    constraints (target pixel -> projected vertex)."""
    import cv2

    img = photo.copy()
    box_edges = [(a, b) for a in range(8) for b in range(a + 1, 8) if bin(a ^ b).count("1") == 1]
    quad_edges = [(0, 1), (1, 2), (2, 3), (3, 0)]
    for p in model.prims:
        v = p.vertices()
        uv, z = camera.project(v)
        col = (255, 200, 0) if p.kind == "box" else (0, 220, 255)
        for a, b in box_edges if p.kind == "box" else quad_edges:
            if z[a] > 1e-3 and z[b] > 1e-3:
                cv2.line(img, tuple(np.round(uv[a]).astype(int)), tuple(np.round(uv[b]).astype(int)), col, 1,
                         cv2.LINE_AA)
    for c in model.constraints:
        uv, z = camera.project(model[c.primitive].vertices()[c.vertex][None])
        tgt = tuple(np.round(c.px).astype(int))
        cv2.circle(img, tgt, 4, (255, 0, 0), 1, cv2.LINE_AA)
        if z[0] > 0:
            cv2.line(img, tgt, tuple(np.round(uv[0]).astype(int)), (255, 0, 0), 1, cv2.LINE_AA)
    return img


def draw_primitives(photo: np.ndarray, prims: list[dict], camera, clicks: dict | None = None) -> np.ndarray:
    """RGB uint8 copy of `photo` with the edges of every box and quad of `prims` (user primitives
    format; segments clipped to the front of the camera) and the clicked pixels as small circles."""
    import cv2

    from recon.clickmodel import primitive_edges

    img = photo.copy()
    colours = {"room": (255, 200, 0), "furniture": (0, 220, 255), "window": (255, 80, 255), "lamp": (255, 255, 80)}
    for p in prims:
        for a, b in primitive_edges(p, camera):
            cv2.line(img, tuple(int(round(x)) for x in a), tuple(int(round(x)) for x in b),
                     colours.get(p.get("role", "room"), (255, 255, 255)), 1, cv2.LINE_AA)
    for c in (clicks or {}).get("clicks", []):
        for key in ("floor_line", "edge", "floor", "top", "corners"):
            pts = c.get(key) if isinstance(c, dict) else None
            if pts is None:
                continue
            for q in ([pts] if key in ("edge", "top") else pts):
                if q is not None:
                    cv2.circle(img, (int(round(q[0])), int(round(q[1]))), 3, (255, 0, 0), 1, cv2.LINE_AA)
    return img


def run_clicks(a: argparse.Namespace) -> int:
    """The --clicks mode: clicks.json + camera.json -> DIR/primitives.json (+ clicks.json, overlay.png)."""
    from recon.camera import Camera
    from recon.clickmodel import load_clicks
    from recon.io import read_image_rgb

    if a.scene is not None:
        raise ValueError(f"{a.scene}: give either a model file to fit or --clicks, not both")
    if a.ceiling_height is not None and not a.ceiling_height > 0:
        raise ValueError(f"--ceiling-height must be positive, got {a.ceiling_height}")
    camera = Camera.load(a.camera)
    clicks = load_clicks(a.clicks)
    photo = None
    if a.image is not None:
        photo = read_image_rgb(a.image)
        if photo.shape[:2] != (camera.height, camera.width):
            raise ValueError(f"{a.image}: image is {photo.shape[1]}x{photo.shape[0]}, camera {a.camera} says "
                             f"{camera.width}x{camera.height}")
    write_model(a.out, clicks, camera, photo, str(a.clicks), a.ceiling_height)
    print(a.out / "primitives.json")
    return 0


def write_model(out: Path, clicks: dict, camera, photo: np.ndarray | None, src: str,
                ceiling_height: float | None = None, edges=None):
    """Model `clicks` (recon.clickmodel; with the photo, refined against its edges: `edges` is its
    recon.edgesnap.EdgeImage when the caller keeps one) and write out/primitives.json,
    out/clicks.json and, with the photo, out/overlay.png, all or nothing (the one code path of
    `model --clicks` and the gui's model mode). Returns the ClickModel; ClickError (nothing
    written) for a click it refuses."""
    from recon.clickmodel import model_from_clicks
    from recon.io import AtomicOutput, write_json, write_png

    model = model_from_clicks(clicks, camera, src, ceiling_height,
                              photo=None if photo is None else edges if edges is not None else photo)
    if model.refined:
        log.info("refined against the photo: %s", ", ".join(f"{k}: {v}" for k, v in model.refined.items()))
    log.info("%d primitives from %d clicks; room %s m (walls guessed: %s; ceiling from %s)", len(model.primitives),
             len(clicks["clicks"]), np.round(model.hi - model.lo, 2).tolist(), ", ".join(model.guessed) or "none",
             model.ceiling_from)
    with AtomicOutput(out) as stage:
        write_json(stage / "primitives.json", model.to_json())
        write_json(stage / "clicks.json", clicks)
        if photo is not None:
            write_png(stage / "overlay.png", draw_primitives(photo, model.primitives, camera, clicks))
    return model


def run(a: argparse.Namespace) -> int:
    if a.clicks is not None:
        return run_clicks(a)
    if a.scene is None:
        raise ValueError("photoar model: give a model file to fit (SCENE.json) or --clicks clicks.json")
    if a.image is None:
        raise ValueError(f"{a.scene}: fitting a model needs the photo (--image)")
    if a.ceiling_height is not None:
        raise ValueError("--ceiling-height: only with --clicks")
    from recon.camera import Camera
    from recon.io import AtomicOutput, read_image_rgb, write_json, write_png
    from recon.primitives import load_model, model_to_dict

    model = load_model(a.scene)
    camera = Camera.load(a.camera)
    photo = read_image_rgb(a.image)
    if photo.shape[:2] != (camera.height, camera.width):
        raise ValueError(f"{a.image}: image is {photo.shape[1]}x{photo.shape[0]}, camera {a.camera} says "
                         f"{camera.width}x{camera.height}")
    info = model.fit(camera)
    log.info("fitted %d primitives to %d image constraints: RMS %.2f px (%d evaluations)", len(model.prims),
             len(model.constraints), info["rms_px"], info["nfev"])
    with AtomicOutput(a.out) as stage:
        d = model_to_dict(model)
        d["fit"] = info
        write_json(stage / "model.json", d)
        write_png(stage / "overlay.png", draw_wireframe(photo, model, camera))
    print(a.out / "model.json")
    return 0
