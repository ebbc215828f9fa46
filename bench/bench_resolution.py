"""Working resolution against photo size (issue 16, item 9): memory and time of `photoar composite`
on a shared scene at its own 640x480 and upsampled 6.25x to 4000x3000 (12 megapixels).

usage: python bench/bench_resolution.py [--shared ../shared] [--scene window_room] [--lighting known]

The 4000x3000 scene is a temporary copy of the shared one with background.png, truth.png and
truth_mask.png resized 6.25x (bilinear) and K scaled to match (c' = (c + 0.5) s - 0.5); the
scorer (../shared/tools/score.py) takes that folder, so the composite is scored against the
truth upsampled the same way. Each row runs in a fresh process, cache cold, so peak RSS
(resource.getrusage ru_maxrss) and time are that row's own. Rows: the photo at its own size;
4000x3000 at the default working resolution (1024 px); 4000x3000 worked at 640 px (the same
working frame as the first row: the difference is the full-resolution step alone). The at640_
columns score each composite resized back to 640x480 (area average) against the original truth:
the scorer's 2 px blur and its 2-level thresholds are not scale-free, so they tell whether the
full-resolution step kept the working frame's accuracy.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

FACTOR = 6.25


def upsampled_scene(src: Path, dst: Path, factor: float) -> Path:
    """A copy of scene folder `src` with its photo, truth and mask resized by `factor`."""
    import shutil

    import cv2

    shutil.copytree(src, dst, ignore=shutil.ignore_patterns("views", "*.exr"))
    meta = json.loads((dst / "scene.json").read_text())
    K = meta["main_camera"]["K"]
    W, H = round(K["width"] * factor), round(K["height"] * factor)
    sx, sy = W / K["width"], H / K["height"]
    K.update(fx=K["fx"] * sx, fy=K["fy"] * sy, cx=(K["cx"] + 0.5) * sx - 0.5, cy=(K["cy"] + 0.5) * sy - 0.5,
             width=W, height=H)
    meta["main_camera"].pop("K_matrix", None)
    (dst / "scene.json").write_text(json.dumps(meta))
    for name, flag in (("background.png", cv2.IMREAD_COLOR), ("truth.png", cv2.IMREAD_COLOR),
                       ("truth_mask.png", cv2.IMREAD_GRAYSCALE)):
        img = cv2.imread(str(src / name), flag)
        cv2.imwrite(str(dst / name), cv2.resize(img, (W, H), interpolation=cv2.INTER_LINEAR))
    return dst


def _score(scorer: Path, scene: Path, png: Path) -> dict:
    r = subprocess.run([sys.executable, str(scorer), str(scene), str(png)], capture_output=True, text=True, check=True)
    return json.loads(r.stdout.strip().splitlines()[-1])


def child(scene: str, out: str, work_res: int, lighting: str, cache: str) -> None:
    """One composite in this process; prints its timings and peak RSS as JSON."""
    import resource
    import time

    from app import composite
    from app.engine import EngineParams

    t0 = time.perf_counter()
    rep = composite.main(scene, out, EngineParams(lighting=lighting), cache_dir=cache, quiet=True,
                         work_res=work_res)
    total = time.perf_counter() - t0
    print(json.dumps({"total_s": total, "precompute_s": rep["precompute_s"], "frame_s": rep["frame_s"],
                      "full_resolution_s": rep["full_resolution_s"], "working": rep["working_resolution"],
                      "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--shared", type=Path, default=ROOT.parent / "shared")
    ap.add_argument("--scene", default="window_room")
    ap.add_argument("--lighting", default="known")
    ap.add_argument("--child", nargs=4, metavar=("SCENE", "OUT", "WORK_RES", "CACHE"), help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child:
        return child(a.child[0], a.child[1], int(a.child[2]), a.lighting, a.child[3])
    from app.report import table

    src = a.shared / "scenes" / a.scene
    scorer = a.shared / "tools" / "score.py"
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        big = upsampled_scene(src, tmp / "big", FACTOR)
        for label, scene, work_res in ((f"{a.scene} 640x480", src, 0), ("4000x3000, work 1024", big, 1024),
                                       ("4000x3000, work 640", big, 640)):
            out = tmp / f"out{len(rows)}"
            cache = tmp / f"cache{len(rows)}"  # cold: every row pays its own precompute
            r = subprocess.run([sys.executable, __file__, "--lighting", a.lighting, "--child", str(scene), str(out),
                                str(work_res), str(cache)], capture_output=True, text=True)
            if r.returncode != 0:
                raise SystemExit(f"{label}: composite failed:\n{r.stderr[-3000:]}")
            m = json.loads(r.stdout.strip().splitlines()[-1])
            s = _score(scorer, scene, out / "composite.png")
            if scene is not src:  # the full-resolution composite brought back to 640x480, scored as the first row
                import cv2

                small = cv2.resize(cv2.imread(str(out / "composite.png")), (640, 480), interpolation=cv2.INTER_AREA)
                cv2.imwrite(str(out / "back_to_640.png"), small)
                s640 = _score(scorer, src, out / "back_to_640.png")
            else:
                s640 = s
            rows.append({"photo": label, "working": "x".join(map(str, m["working"])),
                         "peak_rss_MB": round(m["peak_rss_mb"]), "total_s": round(m["total_s"], 1),
                         "precompute_s": round(m["precompute_s"], 1), "frame_s": round(m["frame_s"], 2),
                         "full_res_s": round(m["full_resolution_s"], 2), "energy": round(s["energy_ratio"], 3),
                         "rmse_aff": round(s["rmse_affected"], 2),
                         "untouched": round(s["rmse_affected_if_untouched"], 2),
                         "spurious": round(s["spurious"], 4), "rmse_obj": round(s["rmse_object"], 2),
                         "at640_energy": round(s640["energy_ratio"], 3), "at640_rmse_aff": round(s640["rmse_affected"], 2),
                         "at640_rmse_obj": round(s640["rmse_object"], 2)})
            print(json.dumps(rows[-1]), flush=True)
    print(table(rows, list(rows[0])))


if __name__ == "__main__":
    main()
