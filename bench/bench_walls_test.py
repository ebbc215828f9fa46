"""Photo light's walls' albedo: the interreflections' fit against the prior, the fit alone (issue 34; docs/unseen.md
"photolamp111").

On bench_lamp_pool.py's dumps (`bench_lamp_pool.py dump ... --out DIR`: each room's fit_photo_light calls pickled with
the truth's emitters), the last fit of each room is run again with PhotoPriors(albedo_test=True) and printed: the
walls fitted to the interreflections, the walls' albedo test (lighting.photoalbedo.walls_test: likelihood ratio,
threshold, which albedo it keeps) and each emitter's radiance over the truth's (luminance) with the fitted walls
(albedo_test off, the product's default) and with the test on. `--rooms DIR`: the rooms' room_config.json, for the
truth's walls (mean luminance of the four walls' base albedo; textures not counted).

`--profile`: also the walls held at 0.35-0.80 (steps of 0.05; the other seen surfaces fitted around them, the unseen ones
reflecting as their surface, lighting.photoalbedo.fit_albedo_scale with fit_walls False): the residual of every seen
patch (relative, rms, luminance-weighted mean of the channels' rms) and each emitter over the truth in that joint fit.

`python bench/bench_walls_test.py DUMP_DIR [--room ROOM,...] [--rooms ROOMS_DIR] [--profile]`. Seconds per room (a
minute with --profile).
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

from bench.bench_lamp_pool import load_dumps  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dir", type=Path)
    ap.add_argument("--room")
    ap.add_argument("--rooms", type=Path)
    ap.add_argument("--profile", action="store_true")
    a = ap.parse_args()
    from lighting import photolight
    from lighting.sources import luminance

    for room, d in load_dumps(a.dir, a.room):
        args, kw = d["calls"][-1]
        args = list(args)
        pr = args[5] or photolight.PhotoPriors()
        reps = {}
        for test in (False, True):
            args[5] = dataclasses.replace(pr, albedo_test=test)
            reps[test] = photolight.fit_photo_light(*args, **kw).report
        t = reps[True]["wall_albedo_test"]
        truth_walls = ""
        cfg = (a.rooms / room / "room_config.json") if a.rooms is not None else None
        if cfg is not None and cfg.exists():
            wb = json.loads(cfg.read_text())["wall_base"]
            truth_walls = f" truth walls {np.mean([luminance(np.array(wb[k])) for k in ('back', 'front', 'left', 'right')]):.3f}"
        if t is None:
            print(f"{room}: no test (the walls' albedo is not fitted: no measured response){truth_walls}")
            continue
        print(f"{room}: walls fitted {luminance(np.array(t['walls_fitted'])):.3f} -> {luminance(np.array(reps[True]['wall_albedo'])):.3f}"
              f"{truth_walls}; likelihood ratio {t['likelihood_ratio']:.2f} (threshold {t['threshold']:.2f}): {t['kept']}")
        for off, on in zip(reps[False]["emitters"], reps[True]["emitters"]):
            tr = d["truth"].get(off["name"])
            if tr is None:
                continue
            tl = float(luminance(np.asarray(tr, float)))
            print(f"  {off['name']:24s} fit / truth {float(luminance(np.array(off['radiance']))) / tl:.3f} -> "
                  f"{float(luminance(np.array(on['radiance']))) / tl:.3f}")
        if a.profile:
            profile(args, kw, pr, d["truth"], [e["name"] for e in reps[False]["emitters"]])


def profile(args: list, kw: dict, pr, truth: dict, names: list[str]) -> None:
    """The walls held at 0.35-0.80: the seen patches' residual and the emitters over the truth (module docstring)."""
    from lighting import photoalbedo, photolight
    from lighting.sources import luminance

    seen: dict = {}
    orig = photolight.fit_albedo_scale

    def hook(*fa, **fk):
        seen.update(args=fa, kw=fk)
        return orig(*fa, **fk)

    photolight.fit_albedo_scale = hook
    try:
        args[5] = dataclasses.replace(pr, albedo_test=False)
        photolight.fit_photo_light(*args, **kw)
    finally:
        photolight.fit_albedo_scale = orig
    fa, fk = list(seen["args"]), dict(seen["kw"], fit_walls=False)
    tl = np.array([float(luminance(np.asarray(truth[n], float))) if n in truth else np.nan for n in names])
    for rw in np.arange(0.35, 0.801, 0.05):
        fa[13] = dataclasses.replace(pr, wall_albedo=float(rw))
        r = photoalbedo.fit_albedo_scale(*fa, **fk)
        rms = float(luminance(np.sqrt(r.ss / max(r.n, 1))))
        print(f"  walls held {rw:.2f}: residual {rms:.4f}  emitters / truth "
              + " ".join(f"{n} {v:.3f}" for n, v in zip(names, luminance(r.e) / tl)))


if __name__ == "__main__":
    main()
