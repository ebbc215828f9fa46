"""`photoar model SCENE.json --image IMAGE --camera camera.json --out DIR`: fit a primitive model's
image constraints (seed sec. 3, recon/primitives.py) and write the fitted model (model.json, the
schema of recon/primitives.py) and overlay.png (its wireframe over the photo), all or nothing.

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
    p.add_argument("scene", type=Path, help="model JSON or scene.json (primitives, image_constraints)")
    p.add_argument("--image", type=Path, required=True, help="the photo")
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


def run(a: argparse.Namespace) -> int:
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
