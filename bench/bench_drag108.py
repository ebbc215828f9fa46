"""What drag108's pose reuse does to the frames along evaluate's drag path: each path frame rendered as the drag
goes (the source list kept from an earlier pose by DragStages.frame_sources' rule; and the object's light where an
experiment's DragObject keeps it: `_kept`, `kept_frames`, not in the product, docs/benchmarks.md "drag108") against
the same pose rendered with the kept state cleared (made afresh). Per room: the frames that reused each, whether the frames whose only reuse is
the source list are the same bytes as the fresh ones (they must be: the selection is a function of the grown box),
and for frames that kept the object's light the difference in 8-bit levels (object pixels: rmse; frame: mean
absolute, largest).

usage: python bench/bench_drag108.py [--scenes window_room,lamps_room,DIR,...] [--path 30]
"""
from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.composite import default_cache_dir  # noqa: E402
from app.config import DRAG_PASSES, DRAG_SCALE  # noqa: E402
from app.dragpath import drag_offsets, moved  # noqa: E402
from app.engine import Engine, EngineParams, FrameConfig  # noqa: E402
from recon.scene import load_scene  # noqa: E402


def scene_dir(name: str) -> Path:
    p = Path(name).expanduser()
    return p if p.is_dir() else Path(os.environ.get("PHOTOAR_SHARED", ROOT.parent / "shared")) / "scenes" / name


def bench_scene(d: Path, n_path: int) -> dict:
    scene = load_scene(d)
    eng = Engine(scene, EngineParams(), cache_dir=default_cache_dir(), quiet=True)
    cfg = FrameConfig(passes=DRAG_PASSES, drag=DRAG_SCALE)
    st, od = eng.pixel_stages(DRAG_SCALE), eng.object_drag
    kept_frames = lambda: getattr(od, "kept_frames", 0)  # noqa: E731 (the object experiment's counter, if any)
    offsets = drag_offsets(scene, scene.obj, n_path)
    rows = []
    for off in offsets:
        obj = moved(scene.obj, off)
        s0, k0 = st.sources_reused, kept_frames()
        fr = eng.render(obj, cfg)
        a, cov = fr.pixels.astype(np.float64), fr.coverage > 0
        src, objk = st.sources_reused > s0, kept_frames() > k0
        kept = (st._sources, getattr(od, "_kept", None))  # the drag's own state, put back after the fresh frame
        st._sources, od._kept = None, None
        b = eng.render(obj, cfg).pixels.astype(np.float64)
        st._sources, od._kept = kept
        diff = np.abs(a - b)
        rows.append({"sources": bool(src), "object": bool(objk), "same": bool(np.array_equal(a, b)),
                     "rmse_obj": float(np.sqrt((diff[cov] ** 2).mean())) if cov.any() else 0.0,
                     "mean": float(diff.mean()), "max": float(diff.max())})
    rows = rows[1:]  # the first pose has no earlier one
    only_src = [r for r in rows if r["sources"] and not r["object"]]
    objk = [r for r in rows if r["object"]]
    return {"scene": d.name, "frames": len(rows), "sources_reused": sum(r["sources"] for r in rows),
            "object_kept": len(objk), "only_sources_same": f"{sum(r['same'] for r in only_src)}/{len(only_src)}",
            "object_rmse_mean": float(np.mean([r["rmse_obj"] for r in objk])) if objk else 0.0,
            "object_rmse_max": float(max([r["rmse_obj"] for r in objk], default=0.0)),
            "frame_mean_abs": float(np.mean([r["mean"] for r in objk])) if objk else 0.0,
            "frame_max": float(max([r["max"] for r in objk], default=0.0))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default="window_room,lamps_room,sun_room")
    ap.add_argument("--path", type=int, default=30)
    a = ap.parse_args()
    for name in a.scenes.split(","):
        r = bench_scene(scene_dir(name), a.path)
        print(f"{r['scene']}: {r['frames']} frames, source list kept {r['sources_reused']}, object light kept "
              f"{r['object_kept']}; frames with only the source list kept the same bytes {r['only_sources_same']}; "
              f"object kept: object rmse {r['object_rmse_mean']:.2f} (max {r['object_rmse_max']:.2f}) levels, frame "
              f"mean |d| {r['frame_mean_abs']:.3f}, max {r['frame_max']:.0f}", flush=True)


if __name__ == "__main__":
    main()
