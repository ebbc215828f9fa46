"""Cost of `photoar scene` (assembly + checks) on a shared scene's photo at 640x480 and upsampled
6.25x to 4000x3000 (a 12-megapixel phone JPEG with EXIF), and the --probe-circle auto error.

    PYTHONPATH=. python bench/bench_scene.py [--scene window_room]

Prints one table row per size: wall time (warm: imports done, one run), peak RSS of the run's
process, the probe-pose check's correlations; then the ball-finding error on pasted balls.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def _child(args_path: str) -> None:
    """Run `photoar scene` in this process and print its time and peak RSS as JSON."""
    import logging

    from app.cli import main

    argv = json.loads(Path(args_path).read_text())
    logging.basicConfig(level=logging.WARNING)
    t0 = time.perf_counter()
    rc = main(["-q", *argv])
    dt = time.perf_counter() - t0
    print(json.dumps({"rc": rc, "s": dt, "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))


def main() -> None:
    import cv2

    from tests.own_room import benchmark_camera_json, scene_argv, write_inputs
    from tests.app.test_scene_cmd import _exif_jpeg, _pasted

    ap = argparse.ArgumentParser()
    ap.add_argument("--scene", default="window_room")
    a = ap.parse_args()
    shared = Path(os.environ.get("PHOTOAR_SHARED", ROOT.parent / "shared"))
    root = shared / "scenes" / a.scene
    tmp = Path(tempfile.mkdtemp(prefix="bench_scene-"))
    inp = write_inputs(root, tmp / "in")
    print("| photo | scene wall s | peak RSS MB |")
    print("| --- | --- | --- |")
    for scale in (1.0, 6.25):
        cam = benchmark_camera_json(inp["scene"])
        k = dict(cam["K"])
        k.update(fx=k["fx"] * scale, fy=k["fy"] * scale, cx=(k["cx"] + 0.5) * scale - 0.5,
                 cy=(k["cy"] + 0.5) * scale - 0.5, width=round(k["width"] * scale), height=round(k["height"] * scale))
        cam.update(K=k, **k)
        (tmp / f"cam_{scale}.json").write_text(json.dumps(cam))
        img = cv2.imread(str(inp["photo"]))
        big = cv2.resize(img, (k["width"], k["height"]), interpolation=cv2.INTER_CUBIC)
        jpg = tmp / f"phone_{scale}.jpg"
        jpg.write_bytes(_exif_jpeg(big, (int(round(inp["exposure"] * 1e6)), 10 ** 6), 1))
        argv = scene_argv(dict(inp, photo=jpg), tmp / f"room_{scale}", tmp / f"cam_{scale}.json")
        i = argv.index("--exposure-time")
        argv = argv[:i] + argv[i + 2:]  # exposure from EXIF
        (tmp / "args.json").write_text(json.dumps(argv))
        out = subprocess.run([sys.executable, __file__, "--child", str(tmp / "args.json")], capture_output=True,
                             text=True, env=dict(os.environ, PYTHONPATH=str(ROOT)))
        r = json.loads(out.stdout.strip().splitlines()[-1])
        print(f"| {k['width']}x{k['height']} JPEG | {r['s']:.1f} | {r['peak_mb']:.0f} |")

    from recon.probecircle import find_ball

    ball = cv2.imread(str(root / "probe_02.png"))[..., ::-1]
    rng = np.random.default_rng(0)
    x = np.arange(640)
    bg = np.clip(60 + 40 * np.sin(x / 37.0)[None, :, None] * np.array([1, 0.8, 0.5])
                 + rng.normal(0, 6, (480, 640, 3)), 0, 255).astype(np.uint8)
    print("\n| ball scale | centre error px | radius error px | find s |")
    print("| --- | --- | --- | --- |")
    for s, ox, oy in [(1.37, 203.4, 91.7), (1.0, 300.5, 120.3), (0.83, 55.25, 160.6), (0.5, 410.3, 200.9)]:
        img, (cx, cy, r) = _pasted(ball, bg, s, ox, oy)
        t0 = time.perf_counter()
        fx, fy, fr = find_ball(img)
        print(f"| {s} | {np.hypot(fx - cx, fy - cy):.2f} | {fr - r:+.2f} | {time.perf_counter() - t0:.2f} |")


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "--child":
        _child(sys.argv[2])
    else:
        main()
