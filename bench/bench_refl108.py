"""Before -> after of bench_unseen's captured light, with the sun's strength and the composite's hash (issue 34; refl108).

usage: python bench/bench_refl108.py ROOMS BEFORE_RESULTS BEFORE_KEEP AFTER_RESULTS AFTER_KEEP
  each RESULTS / KEEP: bench_unseen.py's --results / --keep folders of one run
  (`--lights captured --no-known --no-true-camera --no-declared-sun --rerun --keep KEEP`) on the same rooms.

Prints per room: the sun's strength (luminance of the estimate's irradiance_perpendicular over the truth's,
ROOMS/<room>/scene.json) and the bounce ratio the estimate used (report sun_estimate.bounce_ratio_median, '-'
when absent), energy / rmse_affected / spurious / rmse_object (bias) before -> after, and whether the captured
composites are byte-identical (sha256 of out_captured/composite.png).
"""
from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path

W = (0.2126, 0.7152, 0.0722)


def _lum(v) -> float:
    return sum(w * x for w, x in zip(W, v))


def _strength(rooms: Path, keep: Path, room: str) -> tuple[str, str]:
    """(strength ratio, bounce ratio) as text, '-' where the room has no estimated sun."""
    rep = keep / room / "out_captured" / "report.json"
    if not rep.exists():
        return "-", "-"
    est = json.loads(rep.read_text()).get("sun_estimate") or {}
    truth = next((p for p in json.loads((rooms / room / "scene.json").read_text())["primitives"]
                  if p.get("type") == "sun"), None)
    if "irradiance_perpendicular" not in est or truth is None:
        return "-", "-"
    r = _lum(est["irradiance_perpendicular"]) / _lum(truth["irradiance_perpendicular"])
    b = est.get("bounce_ratio_median")
    return f"{r:.3f}x", ("-" if b is None else f"{b:.3f}")


def _sha(keep: Path, room: str) -> str:
    p = keep / room / "out_captured" / "composite.png"
    return hashlib.sha256(p.read_bytes()).hexdigest()[:12] if p.exists() else "missing"


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    rooms, rb, kb, ra, ka = (Path(a).expanduser() for a in argv[:5])
    print("| room | strength before -> after | bounce ratio | energy | rmse_affected | spurious | rmse_object (bias) "
          "| composite |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    for f in sorted(ra.glob("*.json")):
        room = f.stem
        if not (rb / f.name).exists() or room == "bench_unseen":
            continue
        b = json.loads((rb / f.name).read_text())["lights"]["captured"]
        a = json.loads(f.read_text())["lights"]["captured"]
        s0, _ = _strength(rooms, kb, room)
        s1, br = _strength(rooms, ka, room)
        same = "identical" if _sha(kb, room) == _sha(ka, room) else "changed"
        print(f"| {room} | {s0} -> {s1} | {br} | {b['energy_ratio']:.3f} -> {a['energy_ratio']:.3f} | "
              f"{b['rmse_affected']:.2f} -> {a['rmse_affected']:.2f} | {b['spurious']:.4f} -> {a['spurious']:.4f} | "
              f"{b['rmse_object']:.2f} ({b['bias_object']:+.1f}) -> {a['rmse_object']:.2f} ({a['bias_object']:+.1f}) "
              f"| {same} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
