"""Captured light's estimated sun with SunSetup.captured_bounces and each choice of the sunlit patches' reflectivity
(issue 34, docs/unseen.md "capb112").

usage: python bench/bench_capb112.py ROOM_DIR [ROOM_DIR ...] [--variants off,rule,measured,penumbra] [--shared DIR]

Per room (a benchmark folder: its probe, photo and true camera) and variant, the all-sources frame under captured
light with the sun estimated: off (captured_bounces False, main's default), rule (spur111: the bounce rule's
reflectivity), measured (the strength by the rule, the sunlit patches the unlit median as measured), penumbra (the
sunlit surface's own reflectivity from its penumbra). Prints the strength against the declared sun and score.py's
energy / rmse_affected / spurious / rmse_object (bias), with bench_spur111's spurious split by sign.
"""
from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.bench_spur111 import run  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("rooms", nargs="+", type=Path)
    ap.add_argument("--variants", default="off,rule,measured,penumbra")
    ap.add_argument("--shared", type=Path, default=Path(os.environ.get("PHOTOAR_SHARED", ROOT.parent / "shared")))
    a = ap.parse_args()
    from app.stages.sun import SunSetup

    print("| room | variant | strength | energy / rmse_affected / spurious / rmse_object (bias) | spurious up / down |")
    print("| --- | --- | --- | --- | --- |")
    for room in a.rooms:
        for v in a.variants.split(","):
            SunSetup.captured_sunlit = v if v != "off" else "rule"
            row, e = run(room, "captured", v != "off", a.shared)
            extra = (e.sun.estimate or {}).get("penumbra_rho")
            print(f"| {room.name} | {v} | {row} |" + (f" penumbra rho {extra}" if extra else ""), flush=True)
    SunSetup.captured_sunlit, SunSetup.captured_bounces = "rule", False


if __name__ == "__main__":
    main()
