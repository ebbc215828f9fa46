"""The chair's seat-back crease in a composite against the truth (issue 34, branch crease34).

For a scene holding roomgen's chair (seat top at y = 0.46 m, the back's front face at z = -0.19 m, half width
0.23 m, in the chair's frame): the mean luminance (levels) of the truth and of each composite over points across
the back's front face (x in -0.2 .. 0.2 m) at heights above the seat, and the share of the object's squared error
(over truth_mask) that lies in a band of BAND px about the crease's image line.

    python bench/bench_crease.py SCENE_DIR composite.png [composite2.png ...]
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

SEAT_Y, HALF, BACK_Z = 0.46, 0.23, -0.19
HEIGHTS = (0.005, 0.01, 0.02, 0.04, 0.08, 0.16)  # m above the seat
BAND = 8  # px about the crease line


def main(scene_dir: str, composites: list[str]) -> None:
    import cv2

    from recon.io import read_image_rgb
    from recon.response import luminance
    from lighting.metrics import _blur, object_region
    from recon.scene import load_scene

    scene = load_scene(scene_dir)
    M = scene.obj.object_to_world
    cam = scene.camera
    truth = read_image_rgb(Path(scene_dir) / "truth.png").astype(np.float64)
    mask = cv2.imread(str(Path(scene_dir) / "truth_mask.png"), cv2.IMREAD_GRAYSCALE) > 127
    images = {"truth": truth} | {Path(c).parent.name + "/" + Path(c).name: read_image_rgb(c).astype(np.float64)
                                 for c in composites}
    xs = np.linspace(-0.2, 0.2, 25)

    def world(pts):
        return pts @ M[:3, :3].T + M[:3, 3]

    print("mean luminance across the back's front face at heights above the seat (m):", HEIGHTS)
    for name, img in images.items():
        lum = luminance(img)
        row = []
        for h in HEIGHTS:
            uv, _ = cam.project(world(np.stack([xs, np.full_like(xs, SEAT_Y + h), np.full_like(xs, BACK_Z)], 1)))
            u = np.clip(np.rint(uv[:, 0]).astype(int), 0, lum.shape[1] - 1)
            v = np.clip(np.rint(uv[:, 1]).astype(int), 0, lum.shape[0] - 1)
            row.append(lum[v, u].mean())
        print(f"  {name:40s}", " ".join(f"{r:6.1f}" for r in row))
    # the band about the crease line
    seg = world(np.stack([np.linspace(-HALF, HALF, 200), np.full(200, SEAT_Y), np.full(200, BACK_Z)], 1))
    uv, _ = cam.project(seg)
    band = np.zeros(mask.shape, np.uint8)
    cv2.polylines(band, [np.rint(uv).astype(np.int32)], False, 1, thickness=BAND)
    m = object_region(np.where(mask, 255, 0).astype(np.uint8))
    band = band.astype(bool) & m
    lt = _blur(luminance(truth), 2.0)
    for name, img in list(images.items())[1:]:
        se = (_blur(luminance(img), 2.0) - lt) ** 2  # score.py's rmse_object: blurred luminance over the mask
        total, rest = se[m].sum() / m.sum(), se[m & ~band].sum() / m.sum()
        print(f"  {name:40s} rmse_object {np.sqrt(total):.2f}, band {band.sum()} px holds "
              f"{100 * (1 - rest / total):.0f} % of the squared error (without it {np.sqrt(rest):.2f})")

if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2:])
