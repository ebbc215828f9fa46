"""`photoar gui SCENE --drag-bench N` in alternated processes, per window size: the CLI's own figures, A/B.

    python -m bench.bench_gui_window /work/shared/scenes/window_room --n 60 --runs 3 --windows 1280x720,default

Runs the CLI under `xvfb-run -a` once per window size per round, the order alternating (A B, B A, A B, ...), each
in its own process (the window's size is fixed when it opens). `default`: no --window (the frames 1:1 beside the
panel, gui36). Prints one JSON line per run (the CLI's line, the window, the process's CPU seconds from
getrusage(RUSAGE_CHILDREN), the 1-minute load) and a table.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
from pathlib import Path


def run_one(scene: Path, n: int, window: str) -> dict:
    """One `photoar gui SCENE -q --drag-bench n [--window W]` under xvfb-run; its JSON line plus CPU and load."""
    cmd = ["xvfb-run", "-a", sys.executable, "-m", "app.cli", "-q", "gui", str(scene), "--drag-bench", str(n)]
    if window != "default":
        cmd += ["--window", window]
    ru0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=1200, env=os.environ)
    ru1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    if r.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed ({r.returncode}): {r.stderr[-2000:]}")
    line = [ln for ln in r.stdout.splitlines() if ln.startswith("{")][-1]
    return {**json.loads(line), "window": window, "load": round(os.getloadavg()[0], 2),
            "process_cpu_s": round(ru1.ru_utime + ru1.ru_stime - ru0.ru_utime - ru0.ru_stime, 2)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scene", type=Path)
    ap.add_argument("--n", type=int, default=60)
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--windows", default="1280x720,default")
    a = ap.parse_args()
    wins = a.windows.split(",")
    rows = []
    for k in range(a.runs):
        for w in (wins if k % 2 == 0 else wins[::-1]):
            r = run_one(a.scene, a.n, w)
            rows.append(r)
            print(json.dumps(r), flush=True)
    print("window | mean / p95 ms | frames shown | process CPU s | load")
    for r in rows:
        print(f"{r['window']} | {r['event_to_screen_ms_mean']:.0f} / {r['event_to_screen_ms_p95']:.0f} | "
              f"{r['frames_shown']} | {r['process_cpu_s']} | {r['load']}")


if __name__ == "__main__":
    main()
