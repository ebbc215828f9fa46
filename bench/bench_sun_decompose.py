"""What the calibrated camera costs a room's object besides its outline: one ingredient swapped at a time.

The own-room flow on the calibrated (refined) camera and on the room's true camera differ in one input, the
camera, and in everything `scene` and `composite` derive from it (the patches' radiance read off the photo,
the sun estimated from the photo's sunlit patches, the object's outline). This bench takes the kept work
folders of `bench/bench_unseen.py --keep DIR` (DIR/<room>/room, room_true_cam, out_captured,
out_captured_true_cam) and scores:

- `registration`: the calibrated flow's composite with its object's pixels moved to where the true camera
  sees them (each true-camera pixel of the object ray cast to the object's surface and looked up in the
  calibrated composite at that point's calibrated-camera image; coverage from 4 x 4 samples a pixel; the
  pixels the calibrated object covered and the true one does not are filled from their surroundings
  (cv2.inpaint, under 1 px wide)). What is left after it is the light, not the outline.
- `--sun-swap`: each flow's estimated sun (report.json's `sun`) declared in the other's room (`scene
  --sun-direction --sun-irradiance` on the same camera), composited and scored: the sun's share.

Also printed: the object's displacement between the two cameras' images (displacement), the true composite shifted
by it and by as much in 8 directions, the calibrated one shifted back, the object's light at the same surface
points (object_light_ratio); `--best-shift`: the best whole-image shift of each composite. Results:
docs/unseen.md, "The sun rooms' object under the calibrated camera (sun34)".

`--light photo` reads out_photo and out_photo_true_cam (bench_unseen `--lights photo --true-camera-lights photo`).

`python bench/bench_sun_decompose.py KEEP_DIR ROOMS_DIR --only sun_102[,...] [--best-shift] [--sun-swap]
[--light captured|photo]`
"""
from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def object_mesh(root: Path) -> tuple[np.ndarray, np.ndarray]:
    """The benchmark's synthetic object in world coordinates: vertices (N,3), triangles (M,3)."""
    from recon.scene import load_mesh

    so = json.loads((root / "scene.json").read_text())["synthetic_object"]
    M = np.asarray(so["object_to_world"], float)
    v, _, f = load_mesh(root / so["mesh"])
    return v @ M[:3, :3].T + M[:3, 3], np.asarray(f, np.uint32)


def cast(cam, V: np.ndarray, F: np.ndarray, sub: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Ray cast the mesh from camera `cam` through each pixel's sub x sub sample centres:
    (hit points (H,W,S,3) world m, nan where missed; hit (H,W,S) bool)."""
    import open3d as o3d

    rc = o3d.t.geometry.RaycastingScene()
    rc.add_triangles(V.astype(np.float32), F)
    d = cam.pixel_rays(sub)  # (H*sub, W*sub, 3)
    H, W = cam.height, cam.width
    o = np.broadcast_to(cam.centre, d.shape)
    ans = rc.cast_rays(o3d.core.Tensor(np.concatenate([o, d], -1).reshape(-1, 6).astype(np.float32)))
    t = ans["t_hit"].numpy().reshape(H * sub, W * sub).astype(np.float64)
    hit = np.isfinite(t)
    p = np.where(hit[..., None], o + d * np.where(hit, t, 0)[..., None], np.nan)
    # (H*sub, W*sub) -> (H, W, sub*sub)
    p = p.reshape(H, sub, W, sub, 3).transpose(0, 2, 1, 3, 4).reshape(H, W, sub * sub, 3)
    hit = hit.reshape(H, sub, W, sub).transpose(0, 2, 1, 3).reshape(H, W, sub * sub)
    return p, hit


def registered(composite: np.ndarray, cam_cal, cam_true, V: np.ndarray, F: np.ndarray, sub: int = 4) -> np.ndarray:
    """The calibrated composite (H,W,3) uint8 with its object seen by the true camera (module docstring)."""
    import cv2
    from scipy.ndimage import map_coordinates

    p_t, hit_t = cast(cam_true, V, F, sub)
    _, hit_c = cast(cam_cal, V, F, sub)
    cov_t, cov_c = hit_t.mean(2), hit_c.mean(2)
    H, W = cov_t.shape
    # the object's colour at each true-camera sample: the calibrated composite at its calibrated image
    pts = p_t[hit_t]
    uv, _ = cam_cal.project(pts)
    img = composite.astype(np.float32)
    full = cov_c >= 1.0  # use only the calibrated composite's fully covered pixels as object colour
    # fill non-full pixels of the object's colour image from the nearest full ones so a lookup at the rim
    # never mixes in the room
    mask = (~full).astype(np.uint8)
    obj = cv2.inpaint(composite, mask, 3, cv2.INPAINT_TELEA).astype(np.float32) if full.any() else img
    samp = np.stack([map_coordinates(obj[..., c], [uv[:, 1], uv[:, 0]], order=1, mode="nearest")
                     for c in range(3)], -1)
    acc = np.zeros((H, W, sub * sub, 3), np.float32)
    acc[hit_t] = samp
    obj_t = acc.sum(2) / np.maximum(hit_t.sum(2), 1)[..., None]
    # the room behind: the calibrated composite where its object did not reach, inpainted where it did
    room = cv2.inpaint(composite, (cov_c > 0).astype(np.uint8), 3, cv2.INPAINT_TELEA).astype(np.float32)
    out = cov_t[..., None] * obj_t + (1 - cov_t[..., None]) * room
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


def score_png(root: Path, img_rgb: np.ndarray, tmp: Path) -> dict:
    import cv2

    from bench.own_room_flow import score

    path = tmp / "swap.png"
    cv2.imwrite(str(path), img_rgb[..., ::-1])
    return score(root, path, Path(os.environ.get("PHOTOAR_SHARED", ROOT.parent / "shared")))


def best_shift(root: Path, img_rgb: np.ndarray, reach: float = 1.5, step: float = 0.25) -> tuple[float, float, float]:
    """(rmse_object, dx, dy): the whole composite shifted (bilinear, edges replicated) by the grid point within
    `reach` px (spacing `step`, then step/4 around the best) that scores best: a lower bound of what any
    registration of this composite can score."""
    import cv2

    from bench.bench_object_shift import _scorer

    score = _scorer()
    bgr = img_rgb[..., ::-1].copy()
    H, W = bgr.shape[:2]

    def at(dx: float, dy: float, tmp: Path) -> float:
        M = np.float32([[1, 0, dx], [0, 1, dy]])
        cv2.imwrite(str(tmp), cv2.warpAffine(bgr, M, (W, H), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE))
        return float(score(str(root), str(tmp))["rmse_object"])

    import tempfile

    with tempfile.TemporaryDirectory() as t:
        tmp = Path(t) / "s.png"
        g = np.arange(-reach, reach + 1e-9, step)
        best = min((at(dx, dy, tmp), dx, dy) for dx in g for dy in g)
        f = np.arange(-step, step + 1e-9, step / 4)
        return min((at(best[1] + dx, best[2] + dy, tmp), best[1] + dx, best[2] + dy) for dx in f for dy in f)


def displacement(cam_cal, cam_true, V: np.ndarray) -> tuple[np.ndarray, float]:
    """The calibrated camera's image of the object's vertices less the true camera's: (mean (2,) px, rms
    about the mean px). A small rms about the mean: the camera moves the object as a whole."""
    d = cam_cal.project(V)[0] - cam_true.project(V)[0]
    return d.mean(0), float(np.sqrt(((d - d.mean(0)) ** 2).sum(1).mean()))


def shifted(img_rgb: np.ndarray, dx: float, dy: float) -> np.ndarray:
    """The whole image shifted by (dx, dy) px (bilinear, edges replicated), as bench_object_shift does."""
    import cv2

    H, W = img_rgb.shape[:2]
    return cv2.warpAffine(img_rgb, np.float32([[1, 0, dx], [0, 1, dy]]), (W, H), flags=cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_REPLICATE)


def object_light_ratio(work: Path, cam_cal, cam_true, V: np.ndarray, F: np.ndarray, light: str = "captured") -> float:
    """Median over the object's inner pixels (fully covered on both cameras, 1 px inside the calibrated
    outline) of the calibrated composite's luminance radiance at each surface point over the true camera
    composite's: the light on the object, registration removed."""
    import cv2
    from scipy.ndimage import map_coordinates

    from recon.io import read_exr

    p_t, _ = cast(cam_true, V, F, 1)
    _, h_t = cast(cam_true, V, F, 4)
    _, h_c = cast(cam_cal, V, F, 4)
    full_t = h_t.all(2)
    inner_c = cv2.erode(h_c.all(2).astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    uv, _ = cam_cal.project(p_t[:, :, 0][full_t])
    lw = np.array([0.2126, 0.7152, 0.0722])
    lc = map_coordinates(read_exr(work / f"out_{light}" / "composite.exr").astype(np.float64) @ lw,
                         [uv[:, 1], uv[:, 0]], order=1)
    ok = map_coordinates(inner_c.astype(float), [uv[:, 1], uv[:, 0]], order=0) > 0
    lt = (read_exr(work / f"out_{light}_true_cam" / "composite.exr").astype(np.float64) @ lw)[full_t]
    return float(np.median(lc[ok] / np.maximum(lt[ok], 1e-9)))


def sun_of(report: Path) -> tuple[list[float], list[float]]:
    """(direction, irradiance_perpendicular) of the sun a composite used (its report.json "sun")."""
    sun = json.loads(report.read_text())["sun"]
    return sun["direction"], sun["irradiance_perpendicular"]


def with_sun(root: Path, work: Path, camera: Path, sun: tuple[list[float], list[float]], tag: str) -> float:
    """`scene` on `camera` with `sun` declared, then `composite --lighting captured`: rmse_object."""
    from bench.own_room_flow import _composite_argv, _photoar, declared_openings, fmt, scene_argv, score, write_inputs

    inp = write_inputs(root, work / "in_swap")
    declared_openings(inp["room"], inp["scene"])
    room, out = work / f"room_{tag}", work / f"out_{tag}"
    rc, err, _ = _photoar(scene_argv(inp, room, camera) + [f"--sun-direction={fmt(sun[0])}",
                                                           "--sun-irradiance", fmt(sun[1])])
    if rc != 0:
        raise SystemExit(f"scene {tag}: {err}")
    rc, err, _ = _photoar(_composite_argv(room, out, inp, "captured", work / "cache"))
    if rc != 0:
        raise SystemExit(f"composite {tag}: {err}")
    return score(root, out / "composite.png", Path(os.environ.get("PHOTOAR_SHARED", ROOT.parent / "shared")))[
        "rmse_object"]


def main() -> None:
    import tempfile

    from recon.camera import Camera
    from recon.io import read_image_rgb

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("keep", type=Path)
    ap.add_argument("rooms", type=Path)
    ap.add_argument("--only", required=True)
    ap.add_argument("--best-shift", action="store_true", help="also the best whole-image shift of each composite")
    ap.add_argument("--sun-swap", action="store_true", help="also each flow's sun declared in the other's room")
    ap.add_argument("--light", default="captured", choices=("captured", "photo"),
                    help="whose composites: out_LIGHT and out_LIGHT_true_cam (default %(default)s; --sun-swap: "
                         "captured only)")
    a = ap.parse_args()
    if a.sun_swap and a.light != "captured":
        raise SystemExit("--sun-swap declares the sun, which photo light does not take: use --light captured")
    for name in a.only.split(","):
        work, root = a.keep / name, a.rooms / name
        V, F = object_mesh(root)
        cam_cal = Camera.load(work / "room" / "scene.json")
        cam_true = Camera.load(root / "scene.json")
        row = {}
        with tempfile.TemporaryDirectory() as tmp:
            out_cal, out_true = f"out_{a.light}", f"out_{a.light}_true_cam"
            for tag, out in (("calibrated", out_cal), ("true camera", out_true)):
                row[tag] = score_png(root, read_image_rgb(work / out / "composite.png"), Path(tmp))["rmse_object"]
            comp = read_image_rgb(work / out_cal / "composite.png")
            row["calibrated, identity warp"] = score_png(root, registered(comp, cam_cal, cam_cal, V, F),
                                                         Path(tmp))["rmse_object"]
            row["calibrated, registered"] = score_png(root, registered(comp, cam_cal, cam_true, V, F),
                                                      Path(tmp))["rmse_object"]
            tc = read_image_rgb(work / out_true / "composite.png")
            d, spread = displacement(cam_cal, cam_true, V)
            print(name, f"object displacement ({d[0]:+.3f}, {d[1]:+.3f}) px, rms about it {spread:.3f} px", flush=True)
            row["true camera, shifted by the displacement"] = score_png(root, shifted(tc, *d), Path(tmp))["rmse_object"]
            mag = float(np.hypot(*d))
            ring = [score_png(root, shifted(tc, mag * np.cos(a_), mag * np.sin(a_)), Path(tmp))["rmse_object"]
                    for a_ in np.radians(np.arange(0, 360, 45))]
            print(name, f"true camera shifted by {mag:.3f} px at 0, 45, ..., 315 deg:", [round(x, 2) for x in ring],
                  flush=True)
            row["true camera, shifted as far, mean of 8 directions"] = float(np.mean(ring))
            row["calibrated, shifted back"] = score_png(root, shifted(comp, *(-d)), Path(tmp))["rmse_object"]
            row["object light calibrated / true (median)"] = object_light_ratio(work, cam_cal, cam_true, V, F, a.light)
            if a.best_shift:
                for tag, img in (("calibrated", comp), ("true camera", tc)):
                    r, dx, dy = best_shift(root, img)
                    row[f"{tag}, best shift"] = r
                    print(name, tag, f"best shift ({dx:+.3f}, {dy:+.3f}) px: {r:.2f}", flush=True)
            row["true camera, identity warp"] = score_png(root, registered(tc, cam_true, cam_true, V, F),
                                                          Path(tmp))["rmse_object"]
        if a.sun_swap:
            s_cal, s_true = sun_of(work / "out_captured" / "report.json"), sun_of(
                work / "out_captured_true_cam" / "report.json")
            print(name, "sun calibrated", s_cal, "sun true camera", s_true, flush=True)
            cal_json, true_json = work / "cal" / "camera.json", work / "in" / "camera_true.json"
            row["calibrated, own sun declared"] = with_sun(root, work, cal_json, s_cal, "cal_sun_cal")
            row["calibrated, true camera's sun"] = with_sun(root, work, cal_json, s_true, "cal_sun_true")
            row["true camera, calibrated's sun"] = with_sun(root, work, true_json, s_cal, "true_sun_cal")
        print(name, json.dumps({k: round(v, 3) for k, v in row.items()}))


if __name__ == "__main__":
    main()
