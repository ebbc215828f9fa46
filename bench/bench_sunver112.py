"""The photo light's penumbra rule (docs/unseen.md "photosun111") checked room by room: base (before the rule) against
new (with it), both run by bench_unseen.py under photo light, and which level the rule used per clipped region.

    bench/bench_sunver112.py BASE_RESULTS NEW_RESULTS BASE_KEEP NEW_KEEP sun_103,sun_109,...

BASE_RESULTS / NEW_RESULTS: bench_unseen's `--results` folders (ROOM.json); BASE_KEEP / NEW_KEEP: its `--keep`
folders (ROOM/out_photo/composite.png and report.json). Prints one markdown row per room: energy / rmse_affected
(untouched) / spurious / rmse_object (bias) for base and new, whether the composites are byte-identical, the level
used per region (report.json photo_light.sunlit_levels) with the fit's over the penumbra's luminance, and which photo
bound each is over (issue 34: energy 0.7-1.4, rmse_affected <= 0.6 x untouched, spurious <= max(0.01, 1.2 x the
truth's floor), rmse_object <= 12). A room with no result on either side prints as 'not run'.
"""
from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path

LUM = (0.2126, 0.7152, 0.0722)


def _lum(v) -> float:
    return sum(a * b for a, b in zip(LUM, v))


def over(row: dict, floor: float | None) -> list[str]:
    """The photo bounds a result is over (issue 34's acceptance under photo light)."""
    out = []
    e = row["energy_ratio"]
    if not 0.7 <= e <= 1.4:
        out.append("energy")
    if row["rmse_affected"] > 0.6 * row["rmse_affected_if_untouched"]:
        out.append("rmse_aff")
    if floor is not None and row["spurious"] > max(0.01, 1.2 * floor):
        out.append("spurious")
    if row["rmse_object"] > 12:
        out.append("object")
    return out


def cell(row: dict | None, floor: float | None) -> str:
    if row is None:
        return "not run"
    bad = set(over(row, floor))

    def b(name, s):
        return f"**{s}**" if name in bad else s
    return " / ".join([
        b("energy", f"{row['energy_ratio']:.3f}"),
        b("rmse_aff", f"{row['rmse_affected']:.2f} ({row['rmse_affected_if_untouched']:.2f})"),
        b("spurious", f"{row['spurious']:.3f}"),
        b("object", f"{row['rmse_object']:.2f} ({row['bias_object']:+.1f})")])


def _load(folder: str, room: str) -> tuple[dict | None, float | None]:
    p = Path(folder) / f"{room}.json"
    if not p.exists():
        return None, None
    r = json.loads(p.read_text())
    return r.get("lights", {}).get("photo"), r.get("spurious_floor")


def _sha(keep: str, room: str) -> str | None:
    p = Path(keep) / room / "out_photo" / "composite.png"
    return hashlib.sha256(p.read_bytes()).hexdigest() if p.exists() else None


def levels(keep: str, room: str) -> str:
    p = Path(keep) / room / "out_photo" / "report.json"
    if not p.exists():
        return "no report"
    lv = json.loads(p.read_text()).get("photo_light", {}).get("sunlit_levels") or {}
    if not lv:
        return "none (no region read by its penumbra)"
    parts = []
    for name, r in sorted(lv.items()):
        fit = r.get("fit_level")
        ratio = "no fit" if fit is None else f"fit {_lum(fit) / _lum(r['lit']):.2f}x the penumbra"
        parts.append(f"{name}: {r['used']} ({ratio})")
    return "; ".join(parts)


def main(argv: list[str]) -> None:
    base_res, new_res, base_keep, new_keep, rooms = argv
    print("| room (truth floor) | base 1882bdf | new (rule on) | composites | level used | over a bound: base -> new |")
    print("| --- | --- | --- | --- | --- | --- |")
    for room in rooms.split(","):
        b, floor = _load(base_res, room)
        n, floor_n = _load(new_res, room)
        floor = floor if floor is not None else floor_n
        sb, sn = _sha(base_keep, room), _sha(new_keep, room)
        same = "byte-identical" if sb and sb == sn else ("differ" if sb and sn else "?")
        ob = ", ".join(over(b, floor)) if b else "-"
        on = ", ".join(over(n, floor)) if n else "-"
        fl = "?" if floor is None else f"{floor:.3f}"
        print(f"| {room} ({fl}) | {cell(b, floor)} | {cell(n, floor)} | {same} | {levels(new_keep, room)} | "
              f"{ob or 'none'} -> {on or 'none'} |")


if __name__ == "__main__":
    main(sys.argv[1:])
