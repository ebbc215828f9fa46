"""Open3D visualisation of a reconstruction: points, fitted primitives and camera frusta.

`render_png` draws the scene with Open3D's legacy Visualizer in an (invisible) window: on a
machine without a display it starts a private Xvfb server for the call (Open3D's headless
OffscreenRenderer is very slow on a CPU Vulkan driver). When no window can be opened it falls
back to a plain OpenCV projection drawing of the same geometry and says so. Conventions: world
frame of the inputs; cameras per recon/camera.py (OpenCV axes).
"""
from __future__ import annotations

import logging
import os
import shutil
import subprocess
import time
from pathlib import Path

import numpy as np

from kernels.quiet import native_output_held
from recon.camera import Camera

log = logging.getLogger("photoar.view")

BOX_EDGES = [(0, 1), (1, 3), (3, 2), (2, 0), (4, 5), (5, 7), (7, 6), (6, 4), (0, 4), (1, 5), (2, 6), (3, 7)]
BOX_FACES = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]
QUAD_COLOUR = {"floor": (0.55, 0.45, 0.35), "ceiling": (0.85, 0.85, 0.85)}
OBSERVED_RGB = (0.1, 0.6, 0.1)  # wireframe of a wall fitted to points
GUESSED_RGB = (0.95, 0.55, 0.0)  # wireframe of a wall placed beyond the cameras or from the tape
FURNITURE_RGB = (0.1, 0.3, 0.9)
# room-box walls: corner indices (bits (x, y, z) as in box_corners), wound so the normal faces inwards
ROOM_FACES = {"floor": (0, 1, 5, 4), "ceiling": (2, 6, 7, 3), "back": (0, 4, 6, 2), "front": (1, 3, 7, 5),
              "left": (0, 2, 3, 1), "right": (4, 5, 7, 6)}


def box_corners(center, size, yaw_deg: float = 0.0) -> np.ndarray:
    """(8,3) corners of a box turned by yaw_deg about +Y (R_y takes +Z towards +X, as in
    recon/primitives.py); index bits (x, y, z) = (i>>2 & 1, i>>1 & 1, i & 1) in the box's own axes."""
    c, h = np.asarray(center, float), np.asarray(size, float) / 2
    a = np.radians(float(yaw_deg))
    Ry = np.array([[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]])
    local = np.array([h * (np.array([(i >> 2) & 1, (i >> 1) & 1, i & 1]) * 2 - 1) for i in range(8)])
    return c + local @ Ry.T


def room_walls(p: dict) -> list[tuple[str, np.ndarray, bool]]:
    """A room box's six walls as (name, corners (4,3), observed); a box without "walls" counts as observed."""
    bc = box_corners(p["center"], p["size"], p.get("yaw_deg", 0.0))
    seen = {w.get("name"): bool(w.get("observed", True)) for w in p.get("walls", []) if isinstance(w, dict)}
    return [(n, bc[list(f)], seen.get(n, True)) for n, f in ROOM_FACES.items()]


def frustum_lines(cam: Camera, depth: float) -> tuple[np.ndarray, list[tuple[int, int]]]:
    """Camera frustum as world points (5,3) (centre, 4 image corners at `depth`) and edges."""
    w, h = cam.width - 1, cam.height - 1
    pix = np.array([[0, 0, 1], [w, 0, 1], [w, h, 1], [0, h, 1]], float)
    d = (pix @ np.linalg.inv(cam.K).T) * depth
    pts = np.vstack([cam.centre, (d - cam.t) @ cam.R])
    return pts, [(0, 1), (0, 2), (0, 3), (0, 4), (1, 2), (2, 3), (3, 4), (4, 1)]


def model_mesh(primitives: list[dict]):
    """Open3D TriangleMesh of the room quads and furniture boxes (model.ply), per-vertex colours."""
    from recon.io import open3d

    o3d = open3d()

    V, F, C = [], [], []
    for p in primitives:
        if p.get("type") == "quad":
            quads = [(np.asarray(p["corners"], float), p.get("name"))]
        elif p.get("type") == "box" and p.get("role") == "room":
            quads = [(q, n) for n, q, _ in room_walls(p)]
        elif p.get("type") == "box":
            bc = box_corners(p["center"], p["size"], p.get("yaw_deg", 0.0))
            quads = [(bc[list(f)], None) for f in BOX_FACES]
        else:
            continue
        for q, name in quads:
            col = QUAD_COLOUR.get(name, (0.7, 0.7, 0.65) if p.get("role") == "room" else (0.2, 0.5, 0.8))
            b = len(V) * 4
            V.append(q)
            F += [(b, b + 1, b + 2), (b, b + 2, b + 3)]
            C += [col] * 4
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(np.vstack(V) if V else np.zeros((0, 3))),
                                     o3d.utility.Vector3iVector(np.array(F, np.int32).reshape(-1, 3)))
    mesh.vertex_colors = o3d.utility.Vector3dVector(np.array(C, float).reshape(-1, 3))
    mesh.compute_vertex_normals()
    return mesh


def _lineset(points, edges, colour):
    from recon.io import open3d

    o3d = open3d()

    ls = o3d.geometry.LineSet(o3d.utility.Vector3dVector(np.asarray(points, float)),
                              o3d.utility.Vector2iVector(np.asarray(edges, np.int32).reshape(-1, 2)))
    ls.paint_uniform_color(colour)
    return ls


def scene_lines(cameras: dict[str, Camera], primitives: list[dict], extent: float) -> list[tuple]:
    """Line geometry as (points (N,3), edges, rgb colour in [0,1]) for primitives and frusta: room walls
    green where observed (fitted to points), orange where guessed; furniture blue; cameras red."""
    out = []
    quad = [(0, 1), (1, 2), (2, 3), (3, 0)]
    for p in primitives:
        if p.get("type") == "quad":
            seen = p.get("fit", {}).get("observed", p.get("observed", True))
            out.append((np.asarray(p["corners"], float), quad, OBSERVED_RGB if seen else GUESSED_RGB))
        elif p.get("type") == "box" and p.get("role") == "room":
            walls = room_walls(p)  # guessed first, so that the observed colour wins on shared edges
            for _, q, seen in sorted(walls, key=lambda w: w[2]):
                out.append((q, quad, OBSERVED_RGB if seen else GUESSED_RGB))
        elif p.get("type") == "box":
            out.append((box_corners(p["center"], p["size"], p.get("yaw_deg", 0.0)), BOX_EDGES, FURNITURE_RGB))
    for cam in cameras.values():
        pts, edges = frustum_lines(cam, 0.06 * extent)
        out.append((pts, edges, (0.85, 0.1, 0.1)))
    return out


def geometries(points: np.ndarray, colors: np.ndarray | None, cameras: dict[str, Camera],
               primitives: list[dict]) -> list:
    """Open3D geometries: coloured point cloud, primitive wireframes, camera frusta."""
    from recon.io import open3d

    o3d = open3d()

    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, float)))
    if colors is not None and len(colors):
        pcd.colors = o3d.utility.Vector3dVector(np.asarray(colors, float) / 255.0)
    ext = _extent(points, cameras)
    return [pcd] + [_lineset(p, e, c) for p, e, c in scene_lines(cameras, primitives, ext)]


def _extent(points, cameras) -> float:
    allp = np.vstack([np.asarray(points, float).reshape(-1, 3)] + [c.centre[None] for c in cameras.values()])
    return float(np.linalg.norm(np.percentile(allp, 98, 0) - np.percentile(allp, 2, 0))) or 1.0


def _view_pose(points, cameras) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A bird's-eye viewpoint behind and above the cameras: eye, look-at, up (world)."""
    C = np.array([c.centre for c in cameras.values()])
    look = np.median(np.asarray(points, float), 0) if len(points) else C.mean(0)
    fwd = np.mean([c.R[2] for c in cameras.values()], 0)
    up = -np.mean([c.R[1] for c in cameras.values()], 0)
    up /= np.linalg.norm(up)
    fwd = fwd - (fwd @ up) * up
    fwd = fwd / np.linalg.norm(fwd) if np.linalg.norm(fwd) > 1e-9 else np.cross(up, [1.0, 0, 0])
    ext = _extent(points, cameras)
    eye = C.mean(0) - 0.6 * ext * fwd + 0.5 * ext * up
    return eye, look, up


def _start_xvfb() -> tuple[subprocess.Popen | None, str | None]:
    exe = shutil.which("Xvfb")
    if exe is None:
        return None, None
    for n in range(90, 110):
        if Path(f"/tmp/.X{n}-lock").exists():
            continue
        proc = subprocess.Popen([exe, f":{n}", "-screen", "0", "1600x1200x24", "-nolisten", "tcp"],
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        for _ in range(50):
            if Path(f"/tmp/.X11-unix/X{n}").exists():
                return proc, f":{n}"
            if proc.poll() is not None:
                break
            time.sleep(0.1)
        proc.terminate()
    return None, None


def display_available() -> bool:
    """True when a window can be opened: $DISPLAY is set, or Xvfb is installed (started per call)."""
    return bool(os.environ.get("DISPLAY")) or shutil.which("Xvfb") is not None


def _render_open3d(geoms, eye, look, up, size) -> np.ndarray:
    from recon.io import open3d

    o3d = open3d()

    vis = o3d.visualization.Visualizer()
    if not vis.create_window(window_name="photoar", width=size[0], height=size[1], visible=False):
        raise RuntimeError("Open3D could not open a window")
    try:
        for g in geoms:
            vis.add_geometry(g)
        opt = vis.get_render_option()
        opt.point_size = 3.0
        opt.background_color = np.array([1.0, 1.0, 1.0])
        ctl = vis.get_view_control()
        ctl.set_lookat(look)
        ctl.set_front(_norm(eye - look))
        ctl.set_up(up)
        ctl.set_zoom(0.8)
        vis.poll_events()
        vis.update_renderer()
        img = np.asarray(vis.capture_screen_float_buffer(do_render=True))
    finally:
        vis.destroy_window()
    if img.size == 0 or float(img.std()) == 0.0:
        raise RuntimeError("Open3D returned an empty frame")
    return (np.clip(img, 0, 1) * 255 + 0.5).astype(np.uint8)


def _norm(v):
    return v / np.linalg.norm(v)


def _render_cv2(points, colors, cameras, primitives, eye, look, up, size) -> np.ndarray:
    """Fallback: pinhole projection drawing with OpenCV (points, primitive edges, frusta)."""
    import cv2

    w, h = size
    z = _norm(look - eye)
    x = _norm(np.cross(z, up))
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    K = np.array([[0.8 * w, 0, w / 2 - 0.5], [0, 0.8 * w, h / 2 - 0.5], [0, 0, 1]])
    cam = Camera(K, R, -R @ eye, w, h)
    img = np.full((h, w, 3), 255, np.uint8)
    if len(points):
        uv, depth = cam.project(points)
        ok = (depth > 1e-6) & np.all(np.isfinite(uv), 1)
        cols = colors if colors is not None else np.full((len(points), 3), 80, np.uint8)
        for (u, v), c in zip(uv[ok].astype(int), cols[ok]):
            cv2.circle(img, (int(u), int(v)), 2, tuple(int(k) for k in c), -1)
    for pts, edges, col in scene_lines(cameras, primitives, _extent(points, cameras)):
        uv, depth = cam.project(pts)
        rgb = tuple(int(255 * c) for c in col)  # the image is RGB (write_png converts)
        for a, b in edges:
            if depth[a] > 1e-6 and depth[b] > 1e-6:
                cv2.line(img, tuple(int(k) for k in uv[a]), tuple(int(k) for k in uv[b]), rgb, 1, cv2.LINE_AA)
    return img


def render_png(path: Path, points: np.ndarray, colors: np.ndarray | None, cameras: dict[str, Camera],
               primitives: list[dict], size: tuple[int, int] = (1024, 768)) -> str:
    """Render the scene overview to `path` (RGB PNG). Returns the path taken:
    "open3d-window" ($DISPLAY), "open3d-xvfb" (a private Xvfb) or "cv2-projection" (fallback)."""
    from recon.io import write_png

    eye, look, up = _view_pose(points, cameras)
    geoms = geometries(points, colors, cameras, primitives)
    xvfb, how = None, None
    old = os.environ.get("DISPLAY")
    try:
        if old:
            how = "open3d-window"
        else:
            xvfb, disp = _start_xvfb()
            if xvfb is not None:
                os.environ["DISPLAY"] = disp
                how = "open3d-xvfb"
        img = None
        if how:
            try:
                # GLFW and Mesa print to the C-level stdout/stderr (e.g. "XDG_RUNTIME_DIR is invalid"):
                # held back, shown with -v; a failure falls back to the drawing with a warning
                with native_output_held(show=log.isEnabledFor(logging.DEBUG), on_failure=False):
                    img = _render_open3d(geoms, eye, look, up, size)
            except Exception as e:  # noqa: BLE001 - any failure of the GL path falls back to the drawing
                log.warning("Open3D rendering failed (%s); drawing view.png with OpenCV instead", e)
        if img is None:
            how = "cv2-projection"
            img = _render_cv2(points, colors, cameras, primitives, eye, look, up, size)
    finally:
        if xvfb is not None:
            xvfb.terminate()
            xvfb.wait(timeout=10)
            if old is None:
                os.environ.pop("DISPLAY", None)
    write_png(Path(path), img)
    log.info("view.png drawn by %s", how)
    return how


def show(points, colors, cameras, primitives) -> None:
    """Open an interactive Open3D window (needs a display)."""
    from recon.io import open3d

    o3d = open3d()

    if not os.environ.get("DISPLAY") and not os.environ.get("WAYLAND_DISPLAY"):
        raise RuntimeError("no display: $DISPLAY is not set (view.png in the folder shows the same scene)")
    with native_output_held(show=log.isEnabledFor(logging.DEBUG)):
        o3d.visualization.draw_geometries(geometries(points, colors, cameras, primitives), window_name="photoar view")
