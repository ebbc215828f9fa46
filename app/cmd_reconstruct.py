"""`photoar reconstruct` and `photoar view`: multi-image reconstruction of a room (issue 7).

  photoar reconstruct IMAGES_DIR --out DIR [--camera camera.json [--camera-image NAME]]
                      [--single-camera] [--camera-height M] [--max-features N] [--strict]
  photoar view DIR

The pipeline (one step per module, like hloc): recon.multiview.reconstruct (pycolmap SfM, the
largest model kept) -> metric alignment (recon.multiview) -> recon.roomfit.fit_room (room box +
furniture boxes) -> outputs, written atomically (recon.io.AtomicOutput):
  cameras.json     per registered image K, R, t, centre (frame + units stated), the images left out
                   and why, the alignment, the room-fit report, timings
  points.ply       the SfM points (coloured), in the output frame
  primitives.json  the fitted primitives (recon.primitives model JSON = scene.json primitive schema)
  model.ply        the primitives as a coloured triangle mesh
  view.png         points, primitives and camera frusta (recon.view)
Frames: with --camera the calibrated photo's world frame (metres; scale from that camera's height
above the fitted floor, the world floor being y = 0); without, a frame fitted to the room (floor
y = 0, walls on the axes) in SfM units, or metres with --camera-height.
"""
from __future__ import annotations

import argparse
import logging
import sys
import time
from pathlib import Path

import numpy as np

from recon.camera import Camera

log = logging.getLogger("photoar.reconstruct")


def register(sub) -> None:
    p = sub.add_parser("reconstruct", help="reconstruct a room from several photos (pycolmap SfM + fitted boxes)")
    p.add_argument("images", type=Path, help="folder of photos of the room")
    p.add_argument("--out", type=Path, required=True, help="output folder")
    p.add_argument("--camera", type=Path, default=None,
                   help="calibrated camera (camera.json with K, R, t, or a scene.json's main_camera) of one "
                        "of the photos: fixes K for all images and the world frame")
    p.add_argument("--camera-image", default=None,
                   help="which photo --camera belongs to (default: its 'image'/'file' field, or background.png "
                        "for a scene.json)")
    p.add_argument("--single-camera", action="store_true",
                   help="all photos share one camera (default: shared when sizes and EXIF camera agree)")
    p.add_argument("--camera-height", type=float, default=None,
                   help="without --camera: height (m) of the first registered camera above the floor, for scale")
    p.add_argument("--max-features", type=int, default=8000, help="SIFT features per image (default %(default)s)")
    p.add_argument("--peak-threshold", type=float, default=0.002,
                   help="SIFT peak threshold; lower finds more features on smooth walls (default %(default)s)")
    p.add_argument("--strict", action="store_true",
                   help="exit with status 2 (after writing the partial result) when any image is left out")
    p.set_defaults(run=run_reconstruct)

    v = sub.add_parser("view", help="open a reconstruction (points, primitives, frusta) in an Open3D window")
    v.add_argument("dir", type=Path, help="output folder of `photoar reconstruct`")
    v.set_defaults(run=run_view)


def load_camera(path: Path, image: str | None) -> tuple[Camera, str]:
    """Camera and the image it belongs to, from a camera.json or a scene.json (main_camera)."""
    from recon.io import read_json

    camera = Camera.load(path)
    d = read_json(path)
    c = d.get("main_camera", d.get("camera", d))
    name = image or c.get("image") or c.get("file") or d.get("image")
    if name is None and "main_camera" in d:
        name = c.get("files", {}).get("background_png", "background.png")
    if name is None:
        raise ValueError(f"{path}: does not say which photo it calibrates; pass --camera-image NAME")
    return camera, Path(str(name)).name


def _fit(res, opts_up):
    from recon.roomfit import FitOptions, fit_room

    C = np.array([c.centre for c in res.cameras.values()])
    ups = np.array([-c.R[1] for c in res.cameras.values()])
    return fit_room(res.points, res.colors, C, ups, FitOptions(up=opts_up))


def align_and_fit(res, known: tuple[Camera, str] | None, camera_height: float | None):
    """Align the SfM result and fit the room. Returns (aligned result, RoomFit)."""
    from recon import multiview as mv

    if known is not None:
        cam, name = known
        if name not in res.cameras:
            raise RuntimeError(f"{name}: the calibrated photo was not registered, so the model cannot be put in "
                               f"its frame (registered: {', '.join(res.registered)})")
        sim0 = mv.similarity_from_camera(res.cameras[name], cam, 1.0)
        first = res.transformed(sim0)
        fit0 = _fit(first, (0.0, 1.0, 0.0))
        n, d = fit0.surface_plane("floor")
        s = mv.scale_from_height(float(n @ cam.centre + d), 0.0, float(cam.centre[1]))
        sim = sim0.then(mv.scale_about(cam.centre, s))
        out = res.transformed(sim, "m", f"pose of {name} + its height {cam.centre[1]:.3f} m above the fitted floor")
        return out, _fit(out, (0.0, 1.0, 0.0))
    fit0 = _fit(res, None)
    s = 1.0
    units = "sfm"
    if camera_height is not None:
        first = res.cameras[res.registered[0]]
        cy = float(fit0.axes[1] @ first.centre)
        s = mv.scale_from_height(cy, fit0.lo[1], camera_height)
        units = "m"
    sim = mv.Similarity(s, fit0.axes, -s * fit0.lo)
    how = "room frame fitted to the points (floor y = 0, walls on the axes)" + (
        f", scale from camera height {camera_height} m" if camera_height else ", SfM scale")
    out = res.transformed(sim, units, how)
    return out, _fit(out, (0.0, 1.0, 0.0))


def write_outputs(stage: Path, res, fit, timings: dict) -> str:
    """cameras.json, points.ply, primitives.json, model.ply, view.png into `stage`. Returns the render path."""
    from recon import primitives as prim_mod
    from recon.io import open3d, write_json
    from recon.view import model_mesh, render_png

    o3d = open3d()

    prims = fit.primitives()
    for p in prims:
        p["attach"] = "free"
    model = prim_mod.model_from_dict({"primitives": prims}, src="primitives.json", infer_graph=False)
    prim_mod.save_model(stage / "primitives.json", model)
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(res.points))
    pcd.colors = o3d.utility.Vector3dVector(res.colors / 255.0)
    if not o3d.io.write_point_cloud(str(stage / "points.ply"), pcd):
        raise RuntimeError(f"{stage / 'points.ply'}: could not write")
    if not o3d.io.write_triangle_mesh(str(stage / "model.ply"), model_mesh(prims)):
        raise RuntimeError(f"{stage / 'model.ply'}: could not write")
    t0 = time.perf_counter()
    how = render_png(stage / "view.png", res.points, res.colors, res.cameras, prims)
    timings["render_s"] = time.perf_counter() - t0
    cams = {n: {"K": c.K.tolist(), "R": c.R.tolist(), "t": c.t.tolist(), "centre": c.centre.tolist(),
                "width": c.width, "height": c.height} for n, c in sorted(res.cameras.items())}
    write_json(stage / "cameras.json", {
        "convention": "OpenCV axes, X_cam = R X_world + t, centre = -R^T t, pixel (0,0) = centre of the top-left "
                      "pixel",
        "units": res.units, "alignment": res.alignment, "images": cams,
        "registered": res.registered, "unregistered": res.unregistered, "unreadable": res.unreadable,
        "models": res.models, "kept_model": "the largest reconstruction (models[0]); smaller ones are dropped",
        "n_images": res.n_images, "n_points": int(len(res.points)),
        "mean_reprojection_error_px": res.mean_reproj_px,
        "room_fit": {"stop_reason": fit.stop_reason, "tol": fit.tol, "n_points": fit.n_points,
                     "n_clean": fit.n_clean, "planes": fit.planes, "axes": fit.axes.tolist(),
                     "observed": [n for n, s in fit.surfaces.items() if s.observed], "n_boxes": len(fit.boxes)},
        "view_png_renderer": how, "timings_s": timings})
    return how


def run_reconstruct(a: argparse.Namespace) -> int:
    from recon.io import AtomicOutput
    from recon import multiview as mv

    known = load_camera(a.camera, a.camera_image) if a.camera is not None else None
    if a.camera_height is not None and not a.camera_height > 0:
        raise ValueError(f"--camera-height must be positive, got {a.camera_height}")
    opts = mv.SfmOptions(max_features=a.max_features, peak_threshold=a.peak_threshold, two_view_tracks=True,
                         single_camera=True if a.single_camera else None,
                         camera=known[0] if known else None)
    t0 = time.perf_counter()
    res = mv.reconstruct(a.images, opts, progress=not a.quiet)
    timings = dict(res.timings)
    t1 = time.perf_counter()
    aligned, fit = align_and_fit(res, known, a.camera_height)
    timings["align_fit_s"] = time.perf_counter() - t1
    with AtomicOutput(a.out) as stage:
        write_outputs(stage, aligned, fit, timings)
    timings["total_s"] = time.perf_counter() - t0
    print(a.out / "view.png")
    left = res.unregistered + list(res.unreadable)
    if left:
        print(f"photoar: warning: {a.images}: {len(left)} of {res.n_images} images left out of the model "
              f"({', '.join(left)}); see {a.out / 'cameras.json'}", file=sys.stderr)
        if a.strict:
            return 2
    return 0


def run_view(a: argparse.Namespace) -> int:
    from recon.io import open3d, read_json
    from recon.view import show

    o3d = open3d()

    cams_path = a.dir / "cameras.json"
    for f in (cams_path, a.dir / "points.ply", a.dir / "primitives.json"):
        if not f.is_file():
            raise FileNotFoundError(f"{f}: file not found (is {a.dir} an output of `photoar reconstruct`?)")
    d = read_json(cams_path)
    cams = {n: Camera.from_json(c, cams_path, f"images.{n}.") for n, c in d.get("images", {}).items()}
    pcd = o3d.io.read_point_cloud(str(a.dir / "points.ply"))
    prims = read_json(a.dir / "primitives.json").get("primitives", [])
    show(np.asarray(pcd.points), (np.asarray(pcd.colors) * 255).astype(np.uint8), cams, prims)
    return 0
