"""What a photographer would have of a benchmark room, and nothing more: the photo, its
clicked vanishing lines, the room measured with a tape (geometry only: no albedo, no emitted
radiance), a mirror-ball bracket with its exposure times and the ball's tape-measured pose, the
object mesh. Helpers shared by test_scene_cmd, test_own_room and test_readme_walkthrough."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np

from recon.vanishing import lines_from_scene


def tape_room(scene: dict) -> dict:
    """{"primitives": [...]}: the room as one box of role "room", furniture boxes, window/lamp quads."""
    lo, hi = np.array(scene["world"]["room_min"]), np.array(scene["world"]["room_max"])
    prims = [{"name": "room", "type": "box", "role": "room", "center": ((lo + hi) / 2).tolist(),
              "size": (hi - lo).tolist()}]
    for p in scene["primitives"]:
        if p.get("role") in ("room", "sun") or p.get("type") == "sun":
            continue
        role = {"ceiling_lamp": "lamp", "point_lamp": "lamp"}.get(p["role"], p["role"])
        q = {"name": p["name"], "type": p["type"], "role": role}
        q.update({k: p[k] for k in ("center", "size", "corners", "normal") if k in p})
        prims.append(q)
    return {"primitives": prims}


def calibrated_from_lines(root: Path):
    """A benchmark room calibrated as the own-room flow does: calibrate on its clicked lines with the camera
    height, the tape-measured room parsed. Returns (truth camera, photo (H,W,3), calibration,
    primitives, room lo, room hi)."""
    from recon import assemble as asm
    from recon.camera import Camera
    from recon.io import read_image_rgb
    from recon.vanishing import calibrate_lines, parse_lines

    sc = json.loads((root / "scene.json").read_text())
    truth = Camera.load(root / "scene.json")
    img = read_image_rgb(root / "background.png")
    cal = calibrate_lines(parse_lines(lines_from_scene(sc)), truth.width, truth.height,
                          camera_height=truth.centre[1], image=img)
    prims, lo, hi = asm.parse_primitives(tape_room(sc), "room")
    return truth, img, cal, prims, lo, hi


def probe_args(scene: dict) -> dict:
    """The probe's tape pose and bracket: centre, radius, shot-from (the probe camera's centre), times."""
    lp = scene["light_probe"]
    return {"centre": lp["centre"], "radius": lp["radius"], "shot_from": lp["camera"]["centre"],
            "times": lp["exposure_times"], "files": lp["ldr_files"]}


def object_pose(scene: dict, mesh: Path) -> tuple[list[float], float]:
    """--place (world point of the bottom centre of the mesh's own bounding box) and --yaw (deg,
    right-handed about +Y) of the scene's synthetic object (object_to_world = T R_y(yaw)); for an
    object resting tilted, of the mesh `resting_mesh` writes (the tilt in the mesh: what the user's
    product file holds)."""
    from recon.scene import load_mesh

    M = np.array(scene["synthetic_object"]["object_to_world"], float)
    v, _, _ = load_mesh(mesh)
    rest = _rest_rotation(M)
    v = v @ rest.T
    lo, hi = v.min(0), v.max(0)
    pivot = np.array([(lo[0] + hi[0]) / 2, lo[1], (lo[2] + hi[2]) / 2])
    yaw = _yaw(M)
    place = _rot_y(yaw) @ pivot + M[:3, 3]
    return place.tolist(), yaw


def _yaw(M: np.ndarray) -> float:
    return float(np.degrees(np.arctan2(M[0, 2], M[0, 0])))


def _rot_y(deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _rest_rotation(M: np.ndarray) -> np.ndarray:
    """What object_to_world does besides the yaw (a tilt, a scale): R_y(yaw)^T M[:3, :3]."""
    return _rot_y(_yaw(M)).T @ M[:3, :3]


def resting_mesh(scene: dict, mesh: Path, out: Path) -> None:
    """Write the scene's object mesh as the user's product file: as it rests in the room up to its yaw
    and place (`composite` takes only --place/--yaw: a tilted object's tilt is in its mesh). A mesh
    the scene only turns about +Y (and translates) is copied as it is."""
    import open3d as o3d

    rest = _rest_rotation(np.array(scene["synthetic_object"]["object_to_world"], float))
    if np.abs(rest - np.eye(3)).max() < 1e-6:
        shutil.copy(mesh, out)
        return
    m = o3d.io.read_triangle_mesh(str(mesh))
    m.vertices = o3d.utility.Vector3dVector(np.asarray(m.vertices) @ rest.T)
    if m.has_vertex_normals():
        n = np.asarray(m.vertex_normals) @ np.linalg.inv(rest)
        m.vertex_normals = o3d.utility.Vector3dVector(n / np.linalg.norm(n, axis=1, keepdims=True))
    if not o3d.io.write_triangle_mesh(str(out), m):
        raise RuntimeError(f"{out}: could not write the object's mesh")


def write_inputs(scene_dir: Path, out: Path) -> dict:
    """Write the user's files for benchmark `scene_dir` into `out`: photo.png, lines.json, room.json,
    clicks.json (the room clicked on the photo, as `photoar gui --model` saves it: bench/clicks_truth.py,
    1 px noise), ball_N.png, the object's mesh as object.ply. Returns the numbers a user would type (the
    object's albedo is the product's colour, which the user knows)."""
    scene = json.loads((scene_dir / "scene.json").read_text())
    out.mkdir(parents=True, exist_ok=True)
    shutil.copy(scene_dir / "background.png", out / "photo.png")
    (out / "lines.json").write_text(json.dumps(lines_from_scene(scene)))
    (out / "room.json").write_text(json.dumps(tape_room(scene), indent=1))
    from bench.clicks_truth import true_clicks

    (out / "clicks.json").write_text(json.dumps(true_clicks(scene, sigma_px=1.0, seed=0)[0], indent=1))
    pa = probe_args(scene)
    probes = []
    for i, f in enumerate(pa["files"]):
        shutil.copy(scene_dir / f, out / f"ball_{i}.png")
        probes.append(out / f"ball_{i}.png")
    mesh = scene_dir / scene["synthetic_object"]["mesh"]
    resting_mesh(scene, mesh, out / "object.ply")
    place, yaw = object_pose(scene, mesh)
    return {"scene": scene, "photo": out / "photo.png", "lines": out / "lines.json", "room": out / "room.json",
            "clicks": out / "clicks.json", "probes": probes, "mesh": out / "object.ply", "exposure": scene["main_camera"]["exposure_time"],
            "height": scene["main_camera"]["centre"][1], "place": place, "yaw": yaw,
            "albedo": scene["synthetic_object"]["albedo"], **pa}


def fmt(v) -> str:
    return ",".join(repr(float(x)) for x in v)


def scene_argv(inp: dict, room: Path, camera: Path, shot_from=None) -> list[str]:
    """`photoar scene` arguments for the inputs of write_inputs."""
    return ["scene", str(room), "--photo", str(inp["photo"]), "--exposure-time", str(inp["exposure"]),
            "--camera", str(camera), "--primitives", str(inp["room"]),
            "--probe", *map(str, inp["probes"]), "--probe-times", *map(str, inp["times"]),
            "--probe-centre", fmt(inp["centre"]), "--probe-radius", str(inp["radius"]),
            "--probe-shot-from", fmt(inp["shot_from"] if shot_from is None else shot_from)]


def benchmark_camera_json(scene: dict) -> dict:
    """camera.json of the scene's true main camera (calibrate's format: K block, R, t)."""
    c = scene["main_camera"]
    return {"K": c["K"], **{k: c["K"][k] for k in ("fx", "fy", "cx", "cy", "width", "height")}, "R": c["R"],
            "t": c["t"], "centre": c["centre"]}


def spurious_noise_floor(scene: Path, sims: int = 4, seed: int = 0) -> float:
    """The `spurious` figure an exact answer would score against this scene's noisy truth.

    score.py calls a pixel 'rest' where the blurred |truth - background| is at most 2 levels: the
    truth's Monte Carlo noise decides that wherever the true change is near 2 levels. Model: the
    true change m = the truth's change blurred with sigma 4 px; the noise per pixel = the local rms
    of the truth's change about its sigma-1.5 blur (x1.3 for what that blur removes), Gaussian,
    blurred with the scorer's sigma 2. Spurious of the exact answer = share of simulated 'rest'
    pixels where |m| > 2, mean over `sims` draws."""
    import cv2

    w = np.array([0.0722, 0.7152, 0.2126])
    bg = cv2.imread(str(scene / "background.png")).astype(float) @ w
    tr = cv2.imread(str(scene / "truth.png")).astype(float) @ w
    mask = cv2.dilate((cv2.imread(str(scene / "truth_mask.png"), 0) > 127).astype(np.uint8),
                      np.ones((5, 5), np.uint8)) > 0
    blur = lambda x, s: cv2.GaussianBlur(x, (0, 0), s)  # noqa: E731
    raw = tr - bg
    m = blur(raw, 4.0)
    sd = 1.3 * np.sqrt(blur((raw - blur(raw, 1.5)) ** 2, 6.0))
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(sims):
        rest = ~mask & (np.abs(m + blur(rng.standard_normal(raw.shape) * sd, 2.0)) <= 2.0)
        out.append(float((np.abs(m)[rest] > 2.0).mean()))
    return float(np.mean(out))


OBJECT_DENOISE_SIGMA = 2.0  # px: the spatial reach of object_noise_floor's filter (the scorer's own blur)
OBJECT_DENOISE_LOG = 0.5  # its range: a neighbour's light may differ by this in log radiance (pre-smoothed);
# a sun-shadow edge on the object (a ratio of 10-40, log 2.3-3.7) stays sharp, the pixel noise of a
# pre-smoothed 24-spp truth (10-20 % in radiance) does not count
OBJECT_EDGE_LOG = 0.7  # a pixel whose smoothed light differs from a neighbour's by more (a ratio of 2) lies on
# a shadow's edge (the smoothed noise of a 24-spp truth: ~0.1); it keeps the truth's value
OBJECT_NORMAL_COS = 0.985  # neighbours on the same face (normals within 10 deg): faces' edges stay sharp


def object_render(scene_dir: Path, sub: int = 4) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(normals (H,W,3) unit, facing the camera; depth (H,W) m, inf where the object is not hit; pure (H,W)
    bool) of the scene's synthetic object alone on its true camera (Open3D ray casting): normal and depth
    at the pixel centres, `pure` where all sub x sub samples over the pixel hit the object within
    OBJECT_NORMAL_COS of the centre's normal and 2 % of its depth (the pixel sees one face)."""
    import open3d as o3d

    from recon.scene import load_mesh

    scene = json.loads((scene_dir / "scene.json").read_text())
    so, cam = scene["synthetic_object"], scene["main_camera"]
    M = np.asarray(so["object_to_world"], float)
    v, _, f = load_mesh(scene_dir / so["mesh"])
    v = v @ M[:3, :3].T + M[:3, 3]
    rc = o3d.t.geometry.RaycastingScene()
    rc.add_triangles(v.astype(np.float32), np.asarray(f, np.uint32))
    K = cam["K"]
    H, W = int(K["height"]), int(K["width"])

    def cast(offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        u, vv = np.meshgrid(np.arange(W, dtype=float), np.arange(H, dtype=float))
        u, vv = u[..., None] + offsets[:, 0], vv[..., None] + offsets[:, 1]  # (H,W,S)
        d = np.stack([(u - K["cx"]) / K["fx"], (vv - K["cy"]) / K["fy"], np.ones_like(u)], -1) @ np.asarray(cam["R"])
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        o = np.broadcast_to(np.asarray(cam["centre"], float), d.shape)
        ans = rc.cast_rays(o3d.core.Tensor(np.concatenate([o, d], -1).reshape(-1, 6).astype(np.float32)))
        depth = ans["t_hit"].numpy().reshape(d.shape[:-1]).astype(np.float64)
        n = ans["primitive_normals"].numpy().reshape(d.shape).astype(np.float64)
        return np.where((np.einsum("...c,...c->...", n, d) > 0)[..., None], -n, n), depth

    n, depth = (a[:, :, 0] for a in cast(np.zeros((1, 2))))
    g = (np.arange(sub) + 0.5) / sub - 0.5
    ns, ds = cast(np.stack(np.meshgrid(g, g), -1).reshape(-1, 2))
    with np.errstate(invalid="ignore"):  # a miss's depth is inf
        pure = np.isfinite(depth) & (np.einsum("hwsc,hwc->hws", ns, n) >= OBJECT_NORMAL_COS).all(2) & \
            (np.abs(ds - depth[..., None]) <= 0.02 * np.where(np.isfinite(depth), depth, 1.0)[..., None]).all(2)
    return n, depth, pure


def denoised_object(scene_dir: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(the truth with its object's noise filtered out (H,W,3) uint8 RGB, truth.png (H,W,3) RGB, truth_mask
    (H,W)): what an exact, noise-free object would look like in this scene, for object_noise_floor.

    The truth's object pixels carry its Monte Carlo noise (sun_101, 2 x 24 spp: ~30 levels a pixel), and
    the scorer blurs 8-bit levels: the noise, and through the concave response the noisy pixels' mean
    level sitting below the level of their mean radiance, remain. The exact object is estimated from the
    truth itself: truth.exr over the object's fully covered pixels (truth_mask 255) filtered with a joint
    bilateral filter, the neighbours on the same face (normals and depth of the scene's own mesh on its
    true camera: object_render) within OBJECT_DENOISE_SIGMA px and OBJECT_DENOISE_LOG of the pixel's light
    (a sun-shadow edge stays), then taken through the scene's response to 8 bits; its score against
    truth.png is the floor (object_noise_floor). The partly covered rim pixels and the pixels on a face's edge keep the truth's own values
    (their noise is not counted): a lower bound of the floor there."""
    import cv2

    from recon.io import read_exr
    from recon.response import CameraResponse

    scene = json.loads((scene_dir / "scene.json").read_text())
    resp = scene["camera_response"]
    response = CameraResponse(resp["forward_table"], resp["inverse_table"], scene["main_camera"]["exposure_time"])
    truth = read_exr(scene_dir / "truth.exr").astype(np.float64)
    png = cv2.imread(str(scene_dir / "truth.png"), cv2.IMREAD_COLOR)[..., ::-1]  # RGB
    cover = cv2.imread(str(scene_dir / "truth_mask.png"), cv2.IMREAD_GRAYSCALE)
    n, depth, pure = object_render(scene_dir)
    full = (cover >= 255) & pure
    if not full.any():
        return png.copy(), png, cover
    lum = truth @ np.array([0.2126, 0.7152, 0.0722])
    pre = cv2.GaussianBlur(np.where(full, lum, 0.0), (0, 0), 1.0) / np.maximum(
        cv2.GaussianBlur(full.astype(np.float64), (0, 0), 1.0), 1e-9)  # luminance smoothed over the object only
    logl = np.log(np.maximum(pre, 1e-6))
    r = int(np.ceil(3 * OBJECT_DENOISE_SIGMA))
    H, W = full.shape
    pad = lambda a, fill: np.pad(a, [(r, r), (r, r)] + [(0, 0)] * (a.ndim - 2), constant_values=fill)  # noqa: E731
    t_p, n_p, z_p, f_p, l_p = pad(truth, 0.0), pad(n, 0.0), pad(np.where(full, depth, 0.0), 0.0), pad(full, False), \
        pad(logl, 0.0)
    acc, wsum = np.zeros_like(truth), np.zeros((H, W))
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            sl = (slice(r + dy, r + dy + H), slice(r + dx, r + dx + W))
            w = np.exp(-(dx * dx + dy * dy) / (2 * OBJECT_DENOISE_SIGMA ** 2)) * f_p[sl]
            w = w * (np.einsum("hwc,hwc->hw", n_p[sl], n) >= OBJECT_NORMAL_COS)
            w = w * (np.abs(z_p[sl] - depth) <= 0.02 * np.where(full, depth, 1.0))
            w = w * np.exp(-0.5 * ((l_p[sl] - logl) / OBJECT_DENOISE_LOG) ** 2)
            acc += w[..., None] * t_p[sl]
            wsum += w
    # a pixel on a face's edge (object_render's `pure` False) mixes two faces' light, as the truth's own does,
    # and so does a pixel a shadow's edge crosses (its smoothed light changes by over OBJECT_EDGE_LOG within a
    # pixel): each keeps the truth's value (its noise is not counted); only pure pixels are neighbours
    inner = full & pure
    for dy in range(-1, 2):
        for dx in range(-1, 2):
            sl = (slice(r + dy, r + dy + H), slice(r + dx, r + dx + W))
            inner &= np.abs(l_p[sl] - logl) <= OBJECT_EDGE_LOG
    exact = png.copy()
    den = acc[inner] / np.maximum(wsum[inner], 1e-12)[:, None]
    exact[inner] = response.to_pixels(den)
    return exact, png, cover


def object_noise_floor(scene_dir: Path) -> float:
    """The `rmse_object` an exact, noise-free object would score against this scene's noisy truth:
    denoised_object's image scored against truth.png over score.py's object region (the mask dilated
    2 px, luminance blurred with sigma 2). A bench figure (it reads the truth), never used by the composite."""
    import cv2

    exact, png, cover = denoised_object(scene_dir)
    mask = cv2.dilate((cover > 127).astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    lw = np.array([0.2126, 0.7152, 0.0722])  # score.py's Rec.709 weights (it reads BGR)
    blur = lambda x: cv2.GaussianBlur(x, (0, 0), 2.0)  # noqa: E731
    d = blur(exact.astype(np.float64) @ lw) - blur(png.astype(np.float64) @ lw)
    return float(np.sqrt(np.mean(d[mask] ** 2)))


def score(scene_dir: Path, composite_png: Path, shared: Path) -> dict:
    """The shared scorer's figures (shared/tools/score.py, run as its own process)."""
    import subprocess
    import sys

    out = subprocess.run([sys.executable, str(Path(shared) / "tools" / "score.py"), str(scene_dir),
                          str(composite_png)], capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def mark_openings(room: dict, scene: dict) -> dict:
    """`room` (tape_room's) with each window the truth has as an opening in a wall marked so (a user sees the
    hole); marked in place and returned."""
    openings = {p["name"] for p in scene["primitives"] if p.get("opening")}
    for p in room["primitives"]:
        if p["name"] in openings:
            p["opening"] = True
    return room


def declared_openings(room_json: Path, scene: dict) -> None:
    """Mark in the tape room file each window the truth has as an opening in a wall (mark_openings)."""
    room_json.write_text(json.dumps(mark_openings(json.loads(room_json.read_text()), scene), indent=1))


def sunlit_room(root: Path) -> tuple[dict, list, np.ndarray, np.ndarray, dict, np.ndarray]:
    """A sun room's folder as the declared-sun flow has it: (scene.json, the tape room's primitives with the
    truth's openings marked, the room box's min and max (m), the scene's sun entry, the bracket's response)."""
    from lighting import hdr
    from recon import assemble as asm
    from recon.io import read_image_rgb

    sc = json.loads((root / "scene.json").read_text())
    prims, lo, hi = asm.parse_primitives(mark_openings(tape_room(sc), sc), "room")
    sun = next(p for p in sc["primitives"] if p.get("type") == "sun")
    lp = sc["light_probe"]
    _, g = hdr.merge_bracket([read_image_rgb(root / f) for f in lp["ldr_files"]], lp["exposure_times"])
    return sc, prims, lo, hi, sun, g


def _photoar(argv: list[str]) -> tuple[int, str, list[str]]:
    """Run `photoar ARGV` in this process: (exit code, its error text, its warning lines)."""
    import contextlib
    import io
    import logging

    from app.cli import main

    class _Keep(logging.Handler):
        def __init__(self):
            super().__init__(logging.WARNING)
            self.lines: list[str] = []

        def emit(self, record):
            self.lines.append(record.getMessage())

    keep, err = _Keep(), io.StringIO()
    log = logging.getLogger("photoar")
    log.addHandler(keep)
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            try:
                rc = main(["-q", *argv])
            except SystemExit as e:
                rc = int(e.code or 0)
    finally:
        log.removeHandler(keep)
    return rc, err.getvalue().strip(), keep.lines


def _composite_argv(room: Path, out: Path, inp: dict, lighting: str, cache: Path) -> list[str]:
    return ["composite", str(room), "--out", str(out), "--lighting", lighting, "--object", str(inp["mesh"]),
            "--place", fmt(inp["place"]), "--yaw", repr(inp["yaw"]), "--object-albedo", fmt(inp["albedo"]),
            "--cache", str(cache)]


def run_room(root: Path, work: Path, shared: Path, lights=("captured", "photo"), true_camera: bool = True,
             known: bool = True, declared_sun: bool = True, true_lights=("captured",),
             scene_extra: tuple[str, ...] = ()) -> dict:
    """The own-room flow on benchmark folder `root` (work files under `work`), every composite scored.

    calibrate (clicked lines + camera height) -> scene (tape room, geometry only; openings marked;
    the probe bracket with its tape pose) -> composite under each of `lights` with the object's
    colour; with `true_camera` also the same flow on the scene's true camera for `true_lights`
    ('<light> true cam');
    with `declared_sun`, in a room with a sun, captured light with the sun typed in (--sun-direction,
    --sun-irradiance: the truth's) on the calibrated camera ('captured sun declared');
    with `known` the benchmark folder itself under known light; `scene_extra`: more `scene` arguments
    for the calibrated camera's runs (e.g. --camera-edges lines; the true camera's rows stay as they are). Returns {"lights": {name: score or
    {"error"}}, "warnings": {step: [lines]}, "calibration": {...}, "spurious_floor", "seconds": {...}}."""
    import time

    work.mkdir(parents=True, exist_ok=True)
    cache = work / "cache"
    inp = write_inputs(root, work / "in")
    declared_openings(inp["room"], inp["scene"])
    res: dict = {"lights": {}, "warnings": {}, "seconds": {}, "spurious_floor": spurious_noise_floor(root),
                 "object_floor": object_noise_floor(root)}

    def step(name, argv):
        t0 = time.time()
        rc, err, warns = _photoar(argv)
        res["seconds"][name] = round(time.time() - t0, 1)
        if warns:
            res["warnings"][name] = warns
        return rc, err

    cams = {}
    rc, err = step("calibrate", ["calibrate", str(inp["photo"]), "--lines", str(inp["lines"]), "--height",
                                 str(inp["height"]), "--out", str(work / "cal")])
    if rc == 0:
        cams[""] = work / "cal" / "camera.json"
    else:
        for light in lights:
            res["lights"][light] = {"error": f"calibrate: {err}"}
    if true_camera:
        cams[" true cam"] = work / "in" / "camera_true.json"
        cams[" true cam"].write_text(json.dumps(benchmark_camera_json(inp["scene"])))
    for tag, cam in cams.items():
        room = work / f"room{tag.replace(' ', '_')}"
        rc, err = step(f"scene{tag}", scene_argv(inp, room, cam) + (list(scene_extra) if tag == "" else []))
        if rc == 0 and tag == "":  # the camera scene wrote (turned where it had to be) against the truth
            c = json.loads((room / "scene.json").read_text())["main_camera"]
            t = inp["scene"]["main_camera"]
            centre = -np.asarray(c["R"]).T @ np.asarray(c["t"])
            res["calibration"] = {"focal_rel_err": c["K"]["fx"] / t["K"]["fx"] - 1,
                                  "centre_err_m": float(np.linalg.norm(centre - np.asarray(t["centre"])))}
            if "refinement" in c:  # scene's camera refinement (recon/camrefine.py): calibrate's camera before it
                r = c["refinement"]
                res["calibration"]["refinement"] = r
                if r["accepted"]:
                    cal = json.loads(cams[""].read_text())
                    cal_c = np.asarray(cal["centre"], float)
                    t_c = np.asarray(t["centre"], float)
                    res["calibration"]["calibrated_focal_rel_err"] = cal["fx"] / t["K"]["fx"] - 1
                    res["calibration"]["calibrated_centre_err_m"] = float(min(  # calibrate's, or its turn about +Y
                        np.linalg.norm(cal_c - t_c), np.linalg.norm(cal_c * [-1, 1, -1] - t_c)))
        for light in (lights if tag == "" else list(true_lights)):
            name = light + tag
            if rc != 0:
                res["lights"][name] = {"error": f"scene: {err}"}
                continue
            out = work / f"out_{light}{tag.replace(' ', '_')}"
            rc2, err2 = step(f"composite {name}", _composite_argv(room, out, inp, light, cache))
            res["lights"][name] = (score(root, out / "composite.png", shared) if rc2 == 0
                                   else {"error": f"composite: {err2}"})
    sun = next((p for p in inp["scene"]["primitives"] if p["type"] == "sun"), None)
    if declared_sun and sun is not None and "" in cams:
        room = work / "room_sun"
        rc, err = step("scene sun declared", scene_argv(inp, room, cams[""]) + list(scene_extra) + [
            f"--sun-direction={fmt(sun['direction_to_sun'])}", "--sun-irradiance",
            fmt(sun["irradiance_perpendicular"])])
        name = "captured sun declared"
        if rc != 0:
            res["lights"][name] = {"error": f"scene: {err}"}
        else:
            out = work / "out_sun_declared"
            rc2, err2 = step(f"composite {name}", _composite_argv(room, out, inp, "captured", cache))
            res["lights"][name] = (score(root, out / "composite.png", shared) if rc2 == 0
                                   else {"error": f"composite: {err2}"})
    if known:
        out = work / "out_known"
        rc, err = step("composite known", ["composite", str(root), "--out", str(out), "--lighting", "known",
                                           "--cache", str(cache)])
        res["lights"]["known (benchmark)"] = (score(root, out / "composite.png", shared) if rc == 0
                                              else {"error": f"composite: {err}"})
    return res


def sunlit_inputs(scene_dir: Path, out: Path) -> dict:
    """write_inputs for a room with a sun (sun_room): the taped room with its windows marked as openings
    (room.json; room_no_opening.json keeps the unmarked one), the scene's true camera as camera.json, and
    the scene's sun entry under "sun". Adds "camera", "room_no_opening", "tmp" (= `out`), "root" and "sun"."""
    inp = write_inputs(scene_dir, out / "in")
    room = json.loads(inp["room"].read_text())
    inp["room_no_opening"] = out / "in" / "room_no_opening.json"
    inp["room_no_opening"].write_text(json.dumps(room))
    for p in room["primitives"]:
        if p["role"] == "window":
            p["opening"] = True
    inp["room"].write_text(json.dumps(room))
    inp["camera"] = out / "in" / "camera.json"
    inp["camera"].write_text(json.dumps(benchmark_camera_json(inp["scene"])))
    inp["tmp"], inp["root"] = out, scene_dir
    inp["sun"] = next((p for p in inp["scene"]["primitives"] if p["type"] == "sun"), None)
    return inp
