"""Captured light's estimated sun against known light, per room (issue 34, docs/unseen.md "spur111").

usage: python bench/bench_spur111.py ROOM_DIR [ROOM_DIR ...] [--shared DIR] [--levels]

Per room (a benchmark folder: its probe, photo and true camera), the all-sources frame under captured light with
the sun estimated, SunSetup.captured_bounces off (the measured radiance gathered as it is) and on (the bounce rule
with each patch at its measured level), and under known light; for each: the estimate's strength against the
declared sun, score.py's figures, and the spurious pixels split by sign (ours brighter / darker than the photo).
--levels: the captured mesh's radiance against the known radiosity's B^(n-1) and B^(n) (n = the camera's bounces),
by origin (the probe's patches, the photo's) and surface: which bounce level each measured.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

LUMA = np.array([0.2126, 0.7152, 0.0722])


def spurious_split(room: Path, png: Path) -> tuple[float, float]:
    """(share of score.py's rest pixels ours moves up by > 2 levels, share it moves down)."""
    import cv2

    blur = lambda x: cv2.GaussianBlur(x, (0, 0), 2.0)  # noqa: E731
    lum = lambda p: blur(cv2.imread(str(p)).astype(np.float64) @ LUMA[::-1])  # noqa: E731 (BGR)
    lb, lt, lc = lum(room / "background.png"), lum(room / "truth.png"), lum(png)
    mk = cv2.imread(str(room / "truth_mask.png"), 0)
    mask = cv2.dilate((mk > 127).astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    rest = ~mask & (np.abs(lt - lb) <= 2.0)
    d = (lc - lb)[rest]
    return float((d > 2.0).mean()), float((d < -2.0).mean())


def run(room: Path, lighting: str, bounces: bool, shared: Path) -> tuple[str, object]:
    """(one table row's cells, the engine) of the all-sources frame."""
    import dataclasses

    from app.composite import default_cache_dir
    from app.engine import Engine, EngineParams
    from app.stages.sun import SunSetup
    from recon.io import write_png
    from recon.scene import load_scene

    SunSetup.captured_bounces = bounces
    s = load_scene(room)
    e = Engine(s, EngineParams(lighting=lighting), cache_dir=default_cache_dir(), quiet=True)
    f = e.render(s.obj, dataclasses.replace(e.frame_config(), passes=None))
    est = e.sun.estimate or {}
    strength = f"{est['strength_ratio']:.3f}x" if "strength_ratio" in est else "-"
    with tempfile.TemporaryDirectory() as tmp:
        p = Path(tmp) / "c.png"
        write_png(p, f.pixels)
        sc = json.loads(subprocess.check_output([sys.executable, str(shared / "tools" / "score.py"), str(room), str(p)]))
        up, down = spurious_split(room, p)
    return (f"{strength} | {sc['energy_ratio']:.3f} / {sc['rmse_affected']:.2f} / {sc['spurious']:.4f} / "
            f"{sc['rmse_object']:.2f} ({sc['bias_object']:+.1f}) | {up:.4f} / {down:.4f}"), e


def levels(cap, known) -> list[str]:
    """Rows: per origin and surface, the median of captured B over the known radiosity's B^(n-1) and B^(n)."""
    from lighting.radiance import PHOTO, PROBE

    n = len(known.pre.B) - 1
    pm, o = known.pre.patches, np.asarray(cap.pre.origin)
    ok = ~pm.is_emitter & ~cap.pre.patches.is_emitter & ~(known.sun.patch_light().any(1))
    rows = []
    for org, name in ((PROBE, "probe"), (PHOTO, "photo")):
        for q in np.unique(pm.quad[ok & (o == org)]):
            m = ok & (o == org) & (pm.quad == q)
            if m.sum() < 10:
                continue
            b = cap.B_src[m] @ LUMA
            r = [np.median(b / np.maximum(known.pre.B[k][m] @ LUMA, 1e-12)) for k in (n - 1, n)]
            rows.append(f"| {name} | {known.scene.quads[q].name} | {int(m.sum())} | {r[0]:.3f} | {r[1]:.3f} |")
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("rooms", nargs="+", type=Path)
    ap.add_argument("--shared", type=Path, default=Path(os.environ.get("PHOTOAR_SHARED", ROOT.parent / "shared")))
    ap.add_argument("--levels", action="store_true", help="which bounce level the probe's and photo's patches hold")
    a = ap.parse_args()
    print("| room | light | strength | energy / rmse_affected / spurious / rmse_object (bias) | spurious up / down |")
    print("| --- | --- | --- | --- | --- |")
    for room in a.rooms:
        out = {}
        for name, lighting, b in (("captured, bounce rule off", "captured", False),
                                  ("captured, bounce rule on", "captured", True), ("known", "known", True)):
            row, e = run(room, lighting, b, a.shared)
            out[name] = e
            print(f"| {room.name} | {name} | {row} |", flush=True)
        if a.levels:
            n = len(out["known"].pre.B) - 1
            print(f"\n| origin | surface | patches | captured / known B^({n - 1}) | captured / known B^({n}) |")
            print("| --- | --- | --- | --- | --- |")
            print("\n".join(levels(out["captured, bounce rule on"], out["known"])))
            print()


if __name__ == "__main__":
    main()
