"""Photo light's bounce levels on the shared scenes (issue 34 item 4): photosun34's rule against the product's.

Photo light (lighting.photolight) measures the room at the camera's level only and stands that radiance at
every bounce level (the product). photosun34's `bounce_limited` variant (bench/bench_photo_terms.py) reads the
levels the receivers and the object gather off the fitted model instead, as the truth's 4 bounces give them.
Per shared scene (window_room, lamps_room, sun_room), stripped of everything photo light may not use
(bench.bench_photolight.strip_scene, as tests/lighting/test_photolight.py and test_photolight_sun.py do),
`composite --lighting photo` through the CLI with each rule, scored by ../shared/tools/score.py:
energy / rmse_affected (untouched) / spurious / rmse_object (bias), and the composite's sha256.
The unseen rooms: bench/bench_photo_terms.py (`--variants photo,bounce_limited`). Results: docs/unseen.md,
"photo34, tenth round" (not made the product's rule: lamps_room fails its bounds with it).

`python bench/bench_photo_bounces.py [--scenes window_room,lamps_room,sun_room] [--out DIR]`
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default="window_room,lamps_room,sun_room")
    ap.add_argument("--shared", type=Path, default=Path(os.environ.get("PHOTOAR_SHARED", ROOT.parent / "shared")))
    ap.add_argument("--out", type=Path, default=None, help="work folder (default: a temporary one)")
    a = ap.parse_args()
    from app.cli import main as photoar
    from bench.bench_photo_terms import Hooks
    from bench.bench_photolight import strip_scene
    from bench.own_room_flow import score

    hooks = Hooks()  # its variants act on the composites run in this process
    out = a.out or Path(tempfile.mkdtemp(prefix="photo_bounces_"))
    for name in a.scenes.split(","):
        src = a.shared / "scenes" / name
        d = strip_scene(src, out / name / "scene")
        for v in ("photo", "bounce_limited"):
            hooks.variant = v
            o = out / name / v
            if photoar(["-q", "composite", str(d), "--out", str(o), "--lighting", "photo",
                        "--cache", str(out / name / "cache")]) != 0:
                print(f"{name} {v}: composite failed", flush=True)
                continue
            s = score(src, o / "composite.png", a.shared)
            h = hashlib.sha256((o / "composite.png").read_bytes()).hexdigest()[:12]
            rule = "bounce levels" if v == "bounce_limited" else "measured at every level"
            print(f"{name:12s} {rule:24s} energy {s['energy_ratio']:.3f} aff {s['rmse_affected']:.2f} "
                  f"({s['rmse_affected_if_untouched']:.2f}) spurious {s['spurious']:.4f} obj {s['rmse_object']:.2f} "
                  f"({s['bias_object']:+.2f}) sha256 {h}", flush=True)
            (o / "score.json").write_text(json.dumps(s))


if __name__ == "__main__":
    main()
