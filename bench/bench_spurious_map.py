"""Where a composite's spurious pixels are, and which light term puts them there (issue 34: sun_103's spurious).

usage: python bench/bench_spurious_map.py ROOM_DIR TRUTH_DIR [--lighting captured|known] [--cache DIR] [--json OUT]
       [--frames OUT.npz]

ROOM_DIR is the scene folder the engine runs on (bench_unseen's --keep KEEP/<room>/room_true_cam, or the
benchmark folder itself under known light); TRUTH_DIR the benchmark folder (background.png, truth.png,
truth_mask.png, scene.json). The scorer's (../shared/tools/score.py) `spurious`: the share of 'rest' pixels
(outside the dilated object mask, blurred |truth - background| <= 2 levels) where the composite's blurred
luminance differs from the background's by more than 2 levels.

The full frame is rendered, then again with the object's reflected light off (ObjectConfig.object_light,
which takes the sunlit object's light too), with the second order off (ObjectConfig.second_order: every
later bounce, the sun's included) and with both off (the direct shadows alone). Each term's change at a
pixel is the difference of two frames (blurred luminance, 8-bit levels); per region of the room (the
surface a pixel sees, its distance from the object, in or out of the sunlit patch) the table gives the
rest pixels, the spurious share, brighter / darker, and the mean change of each term over the spurious
pixels and over all its rest pixels, beside the truth's change smoothed with sigma 8 px (the truth's pixel
noise averaged out). Results: docs/unseen.md, "sun_103's spurious under captured light" (spur34).
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

LUM_BGR = np.array([0.0722, 0.7152, 0.2126])  # the scorer's Rec.709 weights, BGR order
THRESH = 2.0  # levels: the scorer's


def _blur(x: np.ndarray, s: float) -> np.ndarray:
    import cv2

    return cv2.GaussianBlur(x, (0, 0), s)


def _lum_rgb(pixels: np.ndarray) -> np.ndarray:
    """(H,W) luminance of an RGB uint8 image (the engine's order), levels."""
    return pixels.astype(np.float64)[..., ::-1] @ LUM_BGR


def scorer_maps(truth_dir: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(blurred background luminance, blurred truth luminance, dilated object mask, rest) (H,W)."""
    import cv2

    bg = cv2.imread(str(truth_dir / "background.png")).astype(np.float64) @ LUM_BGR
    tr = cv2.imread(str(truth_dir / "truth.png")).astype(np.float64) @ LUM_BGR
    mask = cv2.dilate((cv2.imread(str(truth_dir / "truth_mask.png"), 0) > 127).astype(np.uint8),
                      np.ones((5, 5), np.uint8)) > 0
    lb, lt = _blur(bg, 2.0), _blur(tr, 2.0)
    rest = ~mask & (np.abs(lt - lb) <= THRESH)
    return lb, lt, mask, rest


def regions(e, obj) -> dict[str, np.ndarray]:
    """(H,W) bool per region: the surface each pixel sees (the engine's receiver positions), its distance
    from the object's centre (m, horizontal), and whether the sun reaches it (the engine's sun pixels)."""
    cam = e.scene.camera
    H, W = cam.height, cam.width
    pos = e.receivers.pix_pos
    lo, hi = obj.vertices.min(0), obj.vertices.max(0)
    c = 0.5 * (lo + hi)
    r = 0.5 * float(np.max(hi - lo))
    dist = np.linalg.norm((pos - c)[:, [0, 2]], axis=1)
    rmin, rmax = np.asarray(e.scene.room_min, float), np.asarray(e.scene.room_max, float)
    sun = np.zeros(H * W, bool)
    if e.sun_pixels.pix is not None:
        sun[e.sun_pixels.pix] = True
    ok = e.receivers.recv_pix
    floor = ok & (np.abs(pos[:, 1] - rmin[1]) < 1e-3)
    ceil = ok & (np.abs(pos[:, 1] - rmax[1]) < 1e-3)
    wall = ok & ~floor & ~ceil & ((np.abs(pos[:, 0] - rmin[0]) < 1e-3) | (np.abs(pos[:, 0] - rmax[0]) < 1e-3)
                                  | (np.abs(pos[:, 2] - rmin[2]) < 1e-3) | (np.abs(pos[:, 2] - rmax[2]) < 1e-3))
    furn = ok & ~floor & ~ceil & ~wall
    near = dist < 4 * r
    out = {}
    for name, surf in (("floor", floor), ("walls", wall), ("ceiling", ceil), ("furniture", furn)):
        for where, m in (("near", near), ("far", ~near)):
            for lit, s in (("sunlit", sun), ("shade", ~sun)):
                reg = surf & m & s
                if reg.any():
                    out[f"{name} {where} {lit}"] = reg.reshape(H, W)
    out["not a receiver"] = (~ok).reshape(H, W)
    return out


def variant_frames(e, obj) -> dict[str, np.ndarray]:
    """Luminance (H,W) of the frame's pixels, blurred as the scorer does, for the full frame and with terms off."""
    p = e.params
    out = {}
    for name, ol, so in (("full", True, True), ("no object light", False, True), ("no second order", True, False),
                         ("shadows only", False, False)):
        e.params = dataclasses.replace(p, object_light=ol, second_order=so)
        f = e.render(obj)
        out[name] = _blur(_lum_rgb(f.pixels), 2.0)
    e.params = p
    return out


def report(frames: dict[str, np.ndarray], regs: dict[str, np.ndarray], truth_dir: Path) -> dict:
    """Per region: rest pixels, spurious share (of all rest pixels), brighter/darker, each term's mean change over
    the region's spurious pixels, and (terms_rest) over all its rest pixels; levels."""
    lb, lt, mask, rest = scorer_maps(truth_dir)
    t8 = _blur(lt - lb, 8.0)
    full = frames["full"]
    d = full - lb
    sp = rest & (np.abs(d) > THRESH)
    terms = {"direct shadows": frames["shadows only"] - lb,
             "object light": full - frames["no object light"],
             "second order": full - frames["no second order"]}
    n_rest = int(rest.sum())
    rows = {}
    for name, reg in {**regs, "all": np.ones_like(rest)}.items():
        r = reg & rest
        s = reg & sp
        if not r.any():
            continue
        row = {"terms_rest": {k: float(v[r].mean()) for k, v in terms.items()}, "rest_px": int(r.sum()),
               "spurious": float(s.sum() / n_rest), "brighter": float((s & (d > 0)).sum() / n_rest),
               "darker": float((s & (d < 0)).sum() / n_rest), "ours": float(d[s].mean()) if s.any() else 0.0,
               "truth_s8": float(t8[s].mean()) if s.any() else 0.0,
               "ours_rest": float(d[r].mean()), "truth_s8_rest": float(t8[r].mean())}
        for k, v in terms.items():
            row[k] = float(v[s].mean()) if s.any() else 0.0
        rows[name] = row
    return {"spurious": float(sp.sum() / n_rest), "rows": rows}


def print_table(title: str, rep: dict) -> None:
    print(f"{title}: spurious {rep['spurious']:.4f}")
    print("term means over each region's rest pixels: " + "; ".join(
        f"{n}: " + ", ".join(f"{k} {v:+.2f}" for k, v in r["terms_rest"].items()) for n, r in rep["rows"].items()))
    print("| region | rest px | spurious (share of all rest) | brighter / darker | ours on spurious | truth (s8) "
          "| direct shadows | object light | second order | ours / truth (s8) over the region's rest |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for name, r in rep["rows"].items():
        print(f"| {name} | {r['rest_px']} | {r['spurious']:.4f} | {r['brighter']:.4f} / {r['darker']:.4f} | "
              f"{r['ours']:+.2f} | {r['truth_s8']:+.2f} | {r['direct shadows']:+.2f} | {r['object light']:+.2f} | "
              f"{r['second order']:+.2f} | {r['ours_rest']:+.2f} / {r['truth_s8_rest']:+.2f} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("room", type=Path)
    ap.add_argument("truth", type=Path)
    ap.add_argument("--lighting", default="captured")
    ap.add_argument("--cache", type=Path, default=None)
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--frames", type=Path, default=None, help="save the variants' blurred luminance (.npz)")
    a = ap.parse_args()
    from app.composite import place_object
    from app.engine import Engine, EngineParams
    from bench.own_room_flow import object_pose, resting_mesh
    from recon.scene import load_scene

    sc = json.loads((a.truth / "scene.json").read_text())
    s = load_scene(a.room)
    if s.obj is None or a.room.resolve() != a.truth.resolve():  # the user's object: the truth's mesh at its pose
        mesh = a.truth / sc["synthetic_object"]["mesh"]
        tmp = Path(a.cache or "/tmp") / "object_resting.ply"
        resting_mesh(sc, mesh, tmp)
        place, yaw = object_pose(sc, mesh)
        s.obj = place_object(s, tmp, place, yaw, albedo=sc["synthetic_object"]["albedo"])
    e = Engine(s, EngineParams(lighting=a.lighting), cache_dir=a.cache, quiet=True)
    frames = variant_frames(e, s.obj)
    if a.frames:
        np.savez_compressed(a.frames, **{k.replace(" ", "_"): v for k, v in frames.items()},
                            **{"region " + k: v for k, v in regions(e, s.obj).items()})
    rep = report(frames, regions(e, s.obj), a.truth)
    print_table(f"{a.room} ({a.lighting})", rep)
    if a.json:
        a.json.write_text(json.dumps(rep, indent=1))


if __name__ == "__main__":
    main()
