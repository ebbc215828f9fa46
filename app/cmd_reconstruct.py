"""`photoar reconstruct` and `photoar view`: multi-image reconstruction of a room (issue 7).

  photoar reconstruct IMAGES_DIR --out DIR [--camera camera.json] [--camera-image NAME]
                      [--camera-height M | --known-distance A,B,M] [--room-size W,H,D]
                      [--single-camera] [--max-features N] [--strict]
  photoar view DIR

Exit status: 0 done; 2 bad input (nothing written), or --strict with images left out; 3 PARTIAL:
SfM worked but the room fit failed: cameras.json, points.ply and view.png are written (SfM frame),
primitives.json and model.ply are not, and the message says what failed.

The pipeline (one step per module, like hloc): recon.multiview.reconstruct (pycolmap SfM, the
largest model kept) -> metric alignment (recon.multiview) -> recon.roomfit.fit_room (room box +
furniture boxes) -> outputs, written atomically (recon.io.AtomicOutput):
  cameras.json     per registered image K, R, t, centre (frame + units stated), the images left out
                   and why, the alignment, the room-fit report, timings
  points.ply       the SfM points (coloured), in the output frame
  primitives.json  {"primitives": [...]}: the room as one box (role "room", center, size, yaw_deg,
                   "walls": per wall observed flag, support, plane) and furniture boxes (role
                   "furniture"); the user primitives format of `photoar scene --primitives`
  model.ply        the primitives as a coloured triangle mesh
  view.png         points, primitives and camera frusta (recon.view)
Frames: with --camera the calibrated photo's world frame (metres; scale from that camera's height
above the fitted floor, the world floor being y = 0, or from --known-distance); without, a frame
fitted to the room (+Y up = the floor's normal, floor y = 0, walls on the axes, the reference photo
looking towards -Z) in metres when --camera-height, --known-distance or --room-size gives the
scale, else in SfM units. Both files carry "scale": {"source", "metres_per_unit", "detail"}.
"""
from __future__ import annotations

import argparse
import logging
import sys
import time
from pathlib import Path

import numpy as np

from app.units import camera_height
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
                   help="the reference photo: the one --camera belongs to (default: its 'image'/'file' field, or "
                        "background.png for a scene.json); without --camera the one whose right names room x "
                        "and whose height --camera-height gives (default: the first registered in name order)")
    p.add_argument("--single-camera", action="store_true",
                   help="all photos share one camera (default: shared when sizes and EXIF camera agree; when the "
                        "sizes agree and no photo has EXIF, shared unless that leaves photos out)")
    p.add_argument("--camera-height", type=camera_height, default=None,
                   help="without --camera: height (m) above the floor of the reference photo (--camera-image, "
                        "default the first registered photo in name order), for scale")
    p.add_argument("--known-distance", default=None, metavar="A,B,M",
                   help="scale from two photos A and B (file names) whose camera centres were M metres apart")
    p.add_argument("--room-size", default=None, metavar="W,H,D",
                   help="taped room size (m): width along the reference photo's right, height, depth; places "
                        "the walls the photos do not show (default: a 0.3 m margin beyond the cameras) and, with "
                        "no other scale, gives the scale from a dimension whose two walls are seen")
    p.add_argument("--max-features", type=int, default=8000, help="SIFT features per image (default %(default)s)")
    p.add_argument("--peak-threshold", type=float, default=0.002,
                   help="SIFT peak threshold; lower finds more features on smooth walls (default %(default)s)")
    p.add_argument("--strict", action="store_true",
                   help="exit with status 2 (after writing the partial result) when any image is left out")
    p.epilog = ("exit status: 0 done; 2 bad input, or --strict with images left out; 3 partial result: the room fit "
                "failed, cameras.json, points.ply and view.png are written (SfM frame), no primitives")
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


def parse_known_distance(text: str | None) -> tuple[str, str, float] | None:
    """"A,B,M" -> (A, B, M metres): two photos' file names and the distance between their camera centres."""
    if text is None:
        return None
    parts = [t.strip() for t in str(text).rsplit(",", 2)]
    try:
        m = float(parts[2])
    except (IndexError, ValueError):
        raise ValueError(f"--known-distance: expected A,B,METRES (two photo names and a distance), "
                         f"got {text!r}") from None
    if not (m > 0 and np.isfinite(m)) or not parts[0] or not parts[1] or parts[0] == parts[1]:
        raise ValueError(f"--known-distance: need two different photos and a positive distance, got {text!r}")
    return Path(parts[0]).name, Path(parts[1]).name, m


def parse_room_size(text: str | None) -> tuple[float, float, float] | None:
    """"W,H,D" (metres) -> (W, H, D)."""
    if text is None:
        return None
    try:
        v = tuple(float(t) for t in str(text).split(","))
    except ValueError:
        v = ()
    if len(v) != 3 or not all(np.isfinite(x) and x > 0 for x in v):
        raise ValueError(f"--room-size: expected three positive numbers W,H,D in metres, got {text!r}")
    return v


def _fit(res, up, ref: str | None = None, margin: float | None = None, room_size=None, aligned: bool = False,
         floor_y: float | None = None):
    """fit_room on an SfM result; aligned: the frame's axes are the room's (walls snapped to them);
    floor_y: the floor's height when the frame's scale was set by a height above it."""
    from recon.roomfit import FitOptions, fit_room

    C = np.array([c.centre for c in res.cameras.values()])
    ups = np.array([-c.R[1] for c in res.cameras.values()])
    right = tuple(res.cameras[ref].R[0]) if ref is not None else None
    return fit_room(res.points, res.colors, C, ups,
                    FitOptions(up=up, margin=margin, room_size=room_size, ref_right=right,
                               axes=np.eye(3) if aligned else None, floor_y=floor_y))


def _distance_scale(res, kd: tuple[str, str, float]) -> tuple[float, str]:
    a, b, m = kd
    missing = [n for n in (a, b) if n not in res.cameras]
    if missing:
        raise RuntimeError(f"--known-distance: {', '.join(missing)} not registered (registered: "
                           f"{', '.join(res.registered)})")
    from recon import multiview as mv

    s = mv.scale_from_length(res.cameras[a].centre, res.cameras[b].centre, m)
    return s, f"camera centres of {a} and {b} {m} m apart"


def align_and_fit(res, known: tuple[Camera, str] | None, camera_height: float | None = None,
                  known_distance: tuple[str, str, float] | None = None,
                  room_size: tuple[float, float, float] | None = None, ref: str | None = None):
    """Align the SfM result, fix its scale and fit the room.

    Returns (aligned result, RoomFit, scale) with scale = {"source": "camera" | "camera-height" |
    "known-distance" | "room-size" | "none", "metres_per_unit": metres per SfM unit (None when
    unknown), "detail": str}. Raises RoomError / ValueError / RuntimeError saying what failed.
    """
    from recon import multiview as mv
    from recon.roomfit import WALL_MARGIN_M, RoomError

    up = (0.0, 1.0, 0.0)
    if known is not None:
        cam, name = known
        if name not in res.cameras:
            raise RuntimeError(f"{name}: the calibrated photo was not registered, so the model cannot be put in "
                               f"its frame (registered: {', '.join(res.registered)})")
        if camera_height is not None:
            raise ValueError("--camera-height applies without --camera (the calibrated camera's own height, from "
                             "`photoar calibrate --scale-height`, gives the scale)")
        sim0 = mv.similarity_from_camera(res.cameras[name], cam, 1.0)
        if known_distance is not None:
            s, detail = _distance_scale(res, known_distance)
            source = "known-distance"
        else:
            fit0 = _fit(res.transformed(sim0), up, aligned=True)
            n, d = fit0.surface_plane("floor")
            s = mv.scale_from_height(float(n @ cam.centre + d), 0.0, float(cam.centre[1]))
            source, detail = "camera", (f"height of {name} above the fitted floor = its calibrated height "
                                        f"{cam.centre[1]:.3f} m")
        sim = sim0.then(mv.scale_about(cam.centre, s))
        out = res.transformed(sim, "m", f"pose of {name}; scale: {detail}")
        scale = {"source": source, "metres_per_unit": float(s), "detail": detail}
        # the calibrated world's X and Z come from the room's vanishing lines: the room is aligned with them
        return out, _fit(out, up, margin=WALL_MARGIN_M, room_size=room_size, aligned=True,
                         floor_y=0.0 if source == "camera" else None), scale
    ref = ref or res.registered[0]
    if ref not in res.cameras:
        raise RuntimeError(f"{ref}: the reference photo (--camera-image) was not registered "
                           f"(registered: {', '.join(res.registered)})")
    fit0 = _fit(res, None, ref)
    s, source, detail = 1.0, "none", "SfM units: give --camera-height, --known-distance or --room-size for metres"
    if camera_height is not None and known_distance is not None:
        raise ValueError("give one of --camera-height and --known-distance")
    if camera_height is not None:
        s = mv.scale_from_height(float(fit0.axes[1] @ res.cameras[ref].centre), fit0.lo[1], camera_height)
        source, detail = "camera-height", f"{ref} {camera_height} m above the fitted floor"
    elif known_distance is not None:
        s, detail = _distance_scale(res, known_distance)
        source = "known-distance"
    elif room_size is not None:
        both = [k for k, (a, b) in enumerate((("left", "right"), ("floor", "ceiling"), ("back", "front")))
                if fit0.surfaces[a].observed and fit0.surfaces[b].observed]
        if not both:
            raise RoomError("--room-size alone cannot give the scale: no dimension has both its walls observed; "
                             "add --camera-height or --known-distance")
        ratios = [room_size[k] / (fit0.hi[k] - fit0.lo[k]) for k in both]
        s = float(np.median(ratios))
        source, detail = "room-size", f"taped {'/'.join('WHD'[k] for k in both)} over the fitted walls"
    metric = source != "none"
    sim = mv.Similarity(s, fit0.axes, -s * fit0.lo)
    how = f"room frame fitted to the points (+Y the floor normal, floor y = 0, walls on the axes, {ref} looking to -Z)"
    out = res.transformed(sim, "m" if metric else "sfm", f"{how}; scale: {detail}")
    scale = {"source": source, "metres_per_unit": float(s) if metric else None, "detail": detail}
    return out, _fit(out, up, ref, margin=WALL_MARGIN_M if metric else None,
                     room_size=room_size if metric else None, aligned=True, floor_y=0.0), scale


def _cameras_json(res, timings: dict, scale: dict, room_fit: dict, how: str) -> dict:
    cams = {n: {"K": c.K.tolist(), "R": c.R.tolist(), "t": c.t.tolist(), "centre": c.centre.tolist(),
                "width": c.width, "height": c.height} for n, c in sorted(res.cameras.items())}
    return {
        "convention": "OpenCV axes, X_cam = R X_world + t, centre = -R^T t, pixel (0,0) = centre of the top-left "
                      "pixel",
        "units": res.units, "scale": scale, "alignment": res.alignment, "images": cams,
        "registered": res.registered, "unregistered": res.unregistered, "unreadable": res.unreadable,
        "models": res.models, "kept_model": "the largest reconstruction (models[0]); smaller ones are dropped",
        "n_images": res.n_images, "n_points": int(len(res.points)),
        "mean_reprojection_error_px": res.mean_reproj_px,
        "room_fit": room_fit, "view_png_renderer": how, "timings_s": timings}


def _write_points(path: Path, res) -> None:
    from recon.io import open3d

    o3d = open3d()
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(res.points))
    pcd.colors = o3d.utility.Vector3dVector(res.colors / 255.0)
    if not o3d.io.write_point_cloud(str(path), pcd):
        raise RuntimeError(f"{path}: could not write")


def write_outputs(stage: Path, res, fit, timings: dict, scale: dict | None = None) -> str:
    """cameras.json, points.ply, primitives.json, model.ply, view.png into `stage`. Returns the render path."""
    from recon import primitives as prim_mod
    from recon.io import open3d, write_json
    from recon.view import model_mesh, render_png

    o3d = open3d()
    scale = scale or {"source": "none", "metres_per_unit": None, "detail": ""}
    prims = fit.primitives()
    for p in prims:
        p["attach"] = "free"
    model = prim_mod.model_from_dict({"primitives": prims}, src="primitives.json", infer_graph=False)
    d = prim_mod.model_to_dict(model)
    d.update(units=res.units, scale=scale, frame=res.alignment.get("method", ""))
    write_json(stage / "primitives.json", d)
    _write_points(stage / "points.ply", res)
    if not o3d.io.write_triangle_mesh(str(stage / "model.ply"), model_mesh(prims)):
        raise RuntimeError(f"{stage / 'model.ply'}: could not write")
    t0 = time.perf_counter()
    how = render_png(stage / "view.png", res.points, res.colors, res.cameras, prims)
    timings["render_s"] = time.perf_counter() - t0
    room = prims[0]
    write_json(stage / "cameras.json", _cameras_json(res, timings, scale, {
        "stop_reason": fit.stop_reason, "tol": fit.tol, "n_points": fit.n_points, "n_clean": fit.n_clean,
        "planes": fit.planes, "axes": fit.axes.tolist(), "up_from": fit.up_from, "wall_margin": fit.margin,
        "observed": [n for n, s in fit.surfaces.items() if s.observed], "walls": room["walls"],
        "room_size": room["size"], "contains_cameras": True, "n_boxes": len(fit.boxes)}, how))
    return how


def write_partial(stage: Path, res, timings: dict, error: str) -> str:
    """cameras.json, points.ply and view.png of the SfM result (no room) into `stage`."""
    from recon.io import write_json
    from recon.view import render_png

    _write_points(stage / "points.ply", res)
    how = render_png(stage / "view.png", res.points, res.colors, res.cameras, [])
    write_json(stage / "cameras.json", _cameras_json(
        res, timings, {"source": "none", "metres_per_unit": None, "detail": "SfM frame and units (room fit failed)"},
        {"error": error, "partial": True}, how))
    return how


def finish(res, a: argparse.Namespace, known: tuple[Camera, str] | None, timings: dict) -> int:
    """Everything after SfM: align, fit, write. Returns the exit status (0, 2 with --strict, 3 partial)."""
    from recon.io import AtomicOutput
    from recon.multiview import Similarity

    t1 = time.perf_counter()
    kd, size = parse_known_distance(a.known_distance), parse_room_size(a.room_size)
    try:
        aligned, fit, scale = align_and_fit(res, known, a.camera_height, kd, size,
                                            None if known else a.camera_image)
        error = None
    except (ValueError, RuntimeError) as e:
        error = str(e)
    timings["align_fit_s"] = time.perf_counter() - t1
    if error is not None:
        with AtomicOutput(a.out) as stage:
            write_partial(stage, res.transformed(Similarity(), "sfm", "SfM frame (room fit failed)"), timings, error)
        for stale in ("primitives.json", "model.ply"):  # from an earlier run into the same folder
            (a.out / stale).unlink(missing_ok=True)
        print(f"photoar: error: {a.images}: room fit failed: {error}. Partial result (cameras.json, points.ply, "
              f"view.png in the SfM frame) written to {a.out}; exit status 3", file=sys.stderr)
        return 3
    with AtomicOutput(a.out) as stage:
        write_outputs(stage, aligned, fit, timings, scale)
    print(a.out / "view.png")
    left = res.unregistered + list(res.unreadable)
    if left:
        print(f"photoar: warning: {a.images}: {len(left)} of {res.n_images} images left out of the model "
              f"({', '.join(left)}); see {a.out / 'cameras.json'}", file=sys.stderr)
        if a.strict:
            return 2
    return 0


def run_reconstruct(a: argparse.Namespace) -> int:
    from recon import multiview as mv

    known = load_camera(a.camera, a.camera_image) if a.camera is not None else None
    if a.camera_height is not None and not a.camera_height > 0:
        raise ValueError(f"--camera-height must be positive, got {a.camera_height}")
    parse_known_distance(a.known_distance), parse_room_size(a.room_size)  # bad options fail before SfM
    if a.camera_height is not None and a.camera is not None:
        raise ValueError("--camera-height applies without --camera (the calibrated camera's own height, from "
                         "`photoar calibrate --scale-height`, gives the scale)")
    if a.camera_height is not None and a.known_distance is not None:
        raise ValueError("give one of --camera-height and --known-distance")
    opts = mv.SfmOptions(max_features=a.max_features, peak_threshold=a.peak_threshold, two_view_tracks=True,
                         single_camera=True if a.single_camera else None,
                         camera=known[0] if known else None)
    t0 = time.perf_counter()
    res = mv.reconstruct(a.images, opts, progress=not a.quiet)
    timings = dict(res.timings)
    rc = finish(res, a, known, timings)
    timings["total_s"] = time.perf_counter() - t0
    return rc


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
