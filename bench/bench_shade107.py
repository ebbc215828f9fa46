"""Where a composite's object error sits (issue 34, branch shade107).

score.py's rmse_object is the RMSE of blurred luminance (sigma 2 px) over the object mask dilated by 5x5. This
splits its squared error (ours - truth, 8-bit levels) into the outline band (pixels of that region within BAND px
of the mask's edge, either side) and the interior, and the interior by the object face seen through each pixel
(one ray per pixel centre against the scene's object mesh): the face normal's dominant axis in the object's own
frame (+x .. -z) and the hit point's height in the object's frame (thirds of its box). Per group: pixels, share of the squared
error, bias (mean of ours - truth) and RMSE.

    python bench/bench_shade107.py SCENE_DIR composite.png [composite2.png ...]
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

BAND = 3  # px either side of the mask's edge: the outline band


def groups(scene_dir: str) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """(region (H,W) bool, {group name: (H,W) bool}) for the scene's object."""
    import cv2

    from kernels.visibility import Occluder
    from kernels.raycast import cast_rays
    from lighting.metrics import object_region
    from recon.scene import load_scene

    scene = load_scene(scene_dir)
    mask = cv2.imread(str(Path(scene_dir) / "truth_mask.png"), cv2.IMREAD_GRAYSCALE) > 127
    m = object_region(np.where(mask, 255, 0).astype(np.uint8))
    inside = cv2.distanceTransform(mask.astype(np.uint8), cv2.DIST_L2, 3)
    outside = cv2.distanceTransform((~mask).astype(np.uint8), cv2.DIST_L2, 3)
    band = m & (np.where(mask, inside, outside) <= BAND)
    cam, obj = scene.camera, scene.obj
    rays = cam.pixel_rays()
    H, W = rays.shape[:2]
    occ = Occluder(obj.vertices.astype(np.float32), obj.faces.astype(np.int32), "cpu")
    tri, _, depth = cast_rays(occ, cam.centre, rays.reshape(-1, 3).astype(np.float32))
    tri = tri.reshape(H, W)
    hit_p = cam.centre + rays.reshape(-1, 3) * np.where(np.isfinite(depth), depth, 0.0)[:, None]
    Rw = obj.object_to_world[:3, :3]
    v = obj.vertices
    fn = np.cross(v[obj.faces[:, 1]] - v[obj.faces[:, 0]], v[obj.faces[:, 2]] - v[obj.faces[:, 0]])
    fn = fn / np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-12)
    fn_local = fn @ Rw / np.linalg.norm(Rw, axis=0)  # world -> object frame (rotation x scale)
    c_local = ((v[obj.faces].mean(1) - obj.object_to_world[:3, 3]) @ Rw) / np.linalg.norm(Rw, axis=0) ** 2
    ax = np.argmax(np.abs(fn_local), 1)
    sign = np.sign(fn_local[np.arange(len(fn)), ax])
    names = np.array([f"{'+' if s > 0 else '-'}{'xyz'[a]}" for a, s in zip(ax, sign)])
    y_all = ((v - obj.object_to_world[:3, 3]) @ Rw / np.linalg.norm(Rw, axis=0) ** 2)[:, 1]
    lo, hi = y_all.min(), y_all.max()
    y = ((hit_p - obj.object_to_world[:3, 3]) @ Rw / np.linalg.norm(Rw, axis=0) ** 2)[:, 1].reshape(H, W)
    third = np.clip(((y - lo) / max(hi - lo, 1e-9) * 3).astype(int), 0, 2)  # of the hit point, object frame
    out = {"outline band": band, "interior": m & ~band}
    seen = tri >= 0
    interior = m & ~band & seen
    for name in sorted(set(names)):
        for t in range(3):
            g = interior & (names[np.where(seen, tri, 0)] == name) & (third == t)
            if g.sum():
                out[f"  interior {name} face, height {('low', 'mid', 'high')[t]}"] = g
    out["  interior, no face hit"] = m & ~band & ~seen
    # the outline band by the height of the nearest object pixel's hit point
    import cv2 as _cv2

    _, lab = _cv2.distanceTransformWithLabels((~seen).astype(np.uint8), _cv2.DIST_L2, 3,
                                               labelType=_cv2.DIST_LABEL_PIXEL)
    src = np.zeros(lab.max() + 1, np.int64)
    sy, sx = np.nonzero(seen)
    src[lab[sy, sx]] = sy * W + sx
    near_third = third.reshape(-1)[src[lab]].reshape(H, W)
    for t in range(3):
        out[f"  outline band, height {('low', 'mid', 'high')[t]}"] = band & (near_third == t)
    return m, out


def main(scene_dir: str, composites: list[str]) -> None:
    from recon.io import read_image_rgb
    from recon.response import luminance
    from lighting.metrics import _blur

    m, gs = groups(scene_dir)
    lt = _blur(luminance(read_image_rgb(Path(scene_dir) / "truth.png").astype(np.float64)), 2.0)
    for c in composites:
        d = _blur(luminance(read_image_rgb(c).astype(np.float64)), 2.0) - lt
        total = (d[m] ** 2).sum()
        print(f"{c}: rmse_object {np.sqrt(total / m.sum()):.2f}, bias {d[m].mean():+.2f}, {m.sum()} px")
        for name, g in gs.items():
            if g.sum():
                print(f"  {name:38s} {g.sum():6d} px  {100 * (d[g] ** 2).sum() / total:5.1f} %  "
                      f"bias {d[g].mean():+6.2f}  rmse {np.sqrt((d[g] ** 2).mean()):6.2f}")


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scene", help="scene folder with truth.png and scene.json (the object's mesh and pose)")
    ap.add_argument("composites", nargs="+", help="composite PNGs of that scene to split")
    a = ap.parse_args()
    main(a.scene, a.composites)
