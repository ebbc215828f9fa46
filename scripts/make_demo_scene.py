"""Build the bundled demo scene (app/demo/) from a benchmark scene, at half resolution.

usage: python scripts/make_demo_scene.py ../shared/scenes/window_room app/demo

Keeps only what `photoar composite` reads: camera, primitives, object, response, the photo of
the empty room (downsampled 2x2 in linear radiance, then re-encoded through the response) and
the quad textures (shrunk 8x; they only feed patch albedo means).
"""
import json
import shutil
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from recon.response import CameraResponse  # noqa: E402


def main(src: Path, dst: Path) -> None:
    d = json.loads((src / "scene.json").read_text())
    cam = d["main_camera"]
    resp = CameraResponse(d["camera_response"]["forward_table"], d["camera_response"]["inverse_table"],
                          cam["exposure_time"])
    photo = cv2.imread(str(src / cam["files"]["background_png"]))[..., ::-1]
    L = resp.to_radiance(photo)
    h, w = L.shape[0] // 2, L.shape[1] // 2
    L2 = L[: 2 * h, : 2 * w].reshape(h, 2, w, 2, 3).mean(axis=(1, 3))
    dst.mkdir(parents=True, exist_ok=True)
    (dst / "textures").mkdir(exist_ok=True)
    cv2.imwrite(str(dst / "background.png"), resp.to_pixels(L2)[..., ::-1])
    K = cam["K"]
    fx, fy = K["fx"] / 2, K["fy"] / 2
    cx, cy = (K["cx"] + 0.5) / 2 - 0.5, (K["cy"] + 0.5) / 2 - 0.5
    prims = []
    for p in d["primitives"]:
        p = dict(p)
        if p.get("albedo_texture"):
            tex = cv2.imread(str(src / p["albedo_texture"]))
            small = cv2.resize(tex, (max(8, tex.shape[1] // 8), max(8, tex.shape[0] // 8)),
                               interpolation=cv2.INTER_AREA)
            cv2.imwrite(str(dst / p["albedo_texture"]), small)
            p["texture_shape"] = list(small.shape[:2])
        p.pop("emitter_note", None)
        prims.append(p)
    so = d["synthetic_object"]
    shutil.copy(src / so["mesh"], dst / so["mesh"])
    out = {
        "name": "demo_" + d["name"], "format_version": 1, "split": "demo",
        "note": f"half-resolution copy of the benchmark scene {d['name']} (scripts/make_demo_scene.py)",
        "world": d["world"],
        "main_camera": {"K": {"fx": fx, "fy": fy, "cx": cx, "cy": cy, "width": w, "height": h},
                        "K_matrix": [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], "R": cam["R"], "t": cam["t"],
                        "exposure_time": cam["exposure_time"], "files": {"background_png": "background.png"}},
        "primitives": prims,
        "synthetic_object": {k: so[k] for k in ("mesh", "kind", "object_to_world", "albedo")},
        "camera_response": {k: d["camera_response"][k] for k in ("family", "forward_table", "inverse_table")},
    }
    (dst / "scene.json").write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main(Path(sys.argv[1]), Path(sys.argv[2]))
