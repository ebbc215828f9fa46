"""Unseen rooms: the own-room flow on rooms the project was not developed on, scored against their truth.

usage: python bench/bench_unseen.py [--render] [--rooms DIR] [--only KIND_SEED,...] [--json OUT.json]
                                    [--mitsuba-python PY] [--shared ../shared] [--keep DIR]

The rooms are drawn by ../shared/tools/roomgen.py (`random --seed N --kind K`), the independent path
tracer of the shared scenes, from a FIXED list of seeds chosen before any result was seen (SEEDS below:
3 window, 3 lamps, 3 sun rooms). Every seed is reported; a room whose flow fails is a row with its error.

Rendering (`--render`): each missing room is rendered, one at a time, under `nice -n 19`, into the cache
folder (default ~/.cache/photoar/rooms/<kind>_<seed>, or $PHOTOAR_ROOMS / --rooms), outside git. It
needs Mitsuba in a venv of its own (../shared/scenes/README.md; default ~/.venvs/mitsuba/bin/python, or
$PHOTOAR_MITSUBA_PYTHON / --mitsuba-python). The full settings (2 x 128 spp, 2 x 512 with an opening)
take 4-25 min a room on 2 free cores, so the rooms are rendered at the lower spp of SPP (through the
generator's SPP_MAIN / SPP_VIEW / SPP_PROBE overrides); the spp of each room is written beside it
(bench_render.json) and printed in the table, because the truth's noise sets the `spurious` floor.
Without --render, missing rooms are listed with the command that renders them.

Per room (bench/own_room_flow.py): the user's files (photo, clicked lines, tape room with geometry only,
the probe bracket with its tape pose, the object's colour); calibrate on the lines + camera height;
scene; composite under captured and photo light. The same flow with the TRUE camera in place of
calibrate's (column `true cam`), and the benchmark folder itself under known light. Each composite is
scored by ../shared/tools/score.py; `spurious floor` is the spurious figure an exact answer would score
against the room's noisy truth (tests/lighting/test_sun.py's model), `rmse_object floor` the rmse_object of
an exact, noise-free object (the truth's object denoised: bench/own_room_flow.object_noise_floor; JSON
field "object_floor"). Prints one table per room, the median and
worst over rooms, and writes everything as JSON (--json, default <rooms>/bench_unseen.json).
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
import traceback
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

# Fixed before any result was seen; never drop one.
SEEDS: dict[str, list[int]] = {"window": [101, 102, 103], "lamps": [101, 102, 103], "sun": [101, 102, 103]}
# spp per room kind (SPP_MAIN is per half: the main images are the mean of two halves). Chosen so the
# rooms render in about an hour on 2 shared cores at nice 19: measured there under load (6 users), a
# 640x480 image costs 2-11 s per spp and the 5 extra views (unused here) ~3 min whatever their spp;
# the first room (window_101) took 17 min at 2 x 20 spp. Rooms with an opening path-trace more noisily,
# so they get twice the samples. The spp actually used is stored beside each room (bench_render.json).
SPP: dict[str, dict[str, int]] = {
    "window": {"SPP_MAIN": 12, "SPP_VIEW": 1, "SPP_PROBE": 32},
    "lamps": {"SPP_MAIN": 12, "SPP_VIEW": 1, "SPP_PROBE": 32},
    "sun": {"SPP_MAIN": 24, "SPP_VIEW": 1, "SPP_PROBE": 32},
}
METRICS = ("energy_ratio", "rmse_affected", "rmse_affected_if_untouched", "spurious", "rmse_object", "bias_object")


def room_list() -> list[tuple[str, int]]:
    """(kind, seed) in render order: kinds interleaved, so a partial cache covers every kind."""
    n = max(len(v) for v in SEEDS.values())
    return [(k, SEEDS[k][i]) for i in range(n) for k in SEEDS if i < len(SEEDS[k])]


def parse_room_name(name: str, ap: argparse.ArgumentParser) -> tuple[str, int]:
    """(kind, seed) of a KIND_SEED name (window_104); a usage error naming it otherwise."""
    kind, _, seed = name.rpartition("_")
    if kind not in SPP or not seed.isdigit():
        ap.error(f"--only: {name!r} is not KIND_SEED with KIND one of {', '.join(SPP)} (e.g. sun_104)")
    return kind, int(seed)


def rooms_dir(arg: str | None) -> Path:
    return Path(arg or os.environ.get("PHOTOAR_ROOMS") or Path.home() / ".cache" / "photoar" / "rooms").expanduser()


def render_command(py: str, roomgen: Path, kind: str, seed: int, out: Path) -> list[str]:
    return ["nice", "-n", "19", py, str(roomgen), "random", "--seed", str(seed), "--kind", kind,
            "--quality", "full", "--out", str(out)]


def render_room(py: str, roomgen: Path, kind: str, seed: int, final: Path) -> None:
    """Render one room into a temporary sibling folder, then move it to `final` (never half-written)."""
    tmp = final.with_name(final.name + ".partial")
    shutil.rmtree(tmp, ignore_errors=True)
    env = {**os.environ, **{k: str(v) for k, v in SPP[kind].items()}}
    t0 = time.time()
    log = final.with_name(final.name + ".log")
    with open(log, "w") as f:
        subprocess.run(render_command(py, roomgen, kind, seed, tmp), env=env, stdout=f, stderr=subprocess.STDOUT,
                       check=True)
    (tmp / "bench_render.json").write_text(json.dumps({"kind": kind, "seed": seed, **SPP[kind],
                                                       "seconds": round(time.time() - t0, 1)}))
    tmp.rename(final)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--render", action="store_true", help="render the missing rooms first (slow)")
    ap.add_argument("--rooms", help="cache folder of the rendered rooms (default $PHOTOAR_ROOMS or "
                                    "~/.cache/photoar/rooms)")
    ap.add_argument("--mitsuba-python", default=os.environ.get("PHOTOAR_MITSUBA_PYTHON",
                                                              str(Path.home() / ".venvs/mitsuba/bin/python")))
    ap.add_argument("--shared", default=os.environ.get("PHOTOAR_SHARED", str(ROOT.parent / "shared")))
    ap.add_argument("--only", help="comma-separated KIND_SEED names to run (default: the fixed list; a name outside "
                                         "it, e.g. a held-out seed, runs too)")
    ap.add_argument("--json", help="write all results here (default <results>/bench_unseen.json)")
    ap.add_argument("--results", help="folder of one result file per room (default <rooms>/results): a room "
                                      "with a result there is not run again unless --rerun")
    ap.add_argument("--rerun", action="store_true", help="run the rooms that already have a result again")
    ap.add_argument("--lights", default="captured,photo", help="lights of the own-room flow (default %(default)s)")
    ap.add_argument("--no-true-camera", action="store_true", help="skip the flow on the true camera")
    ap.add_argument("--true-camera-lights", default="captured",
                    help="lights of the flow on the true camera (default %(default)s), whatever --lights "
                         "holds")
    ap.add_argument("--no-declared-sun", action="store_true", help="skip the flow with the sun typed in")
    ap.add_argument("--no-known", action="store_true", help="skip the benchmark folder under known light")
    ap.add_argument("--camera-edges", choices=("profiles", "lines"), default="profiles",
                    help="scene's camera refinement: how it measures the room's edges (scene --camera-edges)")
    ap.add_argument("--keep", help="keep each room's work folders under this folder")
    ap.add_argument("--no-flow", action="store_true", help="only render (with --render)")
    ap.add_argument("--report", action="store_true",
                    help="only print the table of the results there are (a rendered room without one is a row "
                         "'not run')")
    a = ap.parse_args(argv)
    rooms = rooms_dir(a.rooms)
    rooms.mkdir(parents=True, exist_ok=True)
    shared = Path(a.shared)
    roomgen = shared / "tools" / "roomgen.py"
    todo = room_list()
    if a.only:
        want = a.only.split(",")
        fixed = {f"{k}_{s}" for k, s in todo}
        extra = [parse_room_name(n, ap) for n in want if n not in fixed]  # held-out seeds beyond the fixed list
        todo = [r for r in todo if f"{r[0]}_{r[1]}" in set(want)] + extra
    missing = [(k, s) for k, s in todo if not (rooms / f"{k}_{s}" / "scene.json").is_file()]
    if missing and a.render:
        for k, s in missing:
            print(f"rendering {k}_{s} ({SPP[k]}) ...", flush=True)
            try:
                render_room(a.mitsuba_python, roomgen, k, s, rooms / f"{k}_{s}")
            except (subprocess.CalledProcessError, OSError) as e:
                print(f"  {k}_{s}: render failed: {e} (log {rooms / f'{k}_{s}.log'})", flush=True)
        missing = [(k, s) for k, s in todo if not (rooms / f"{k}_{s}" / "scene.json").is_file()]
    elif missing:
        print(f"{len(missing)} room(s) not rendered yet; render them with --render, or each by hand:")
        for k, s in missing:
            env = " ".join(f"{n}={v}" for n, v in SPP[k].items())
            print(f"  {env} " + " ".join(render_command(a.mitsuba_python, roomgen, k, s, rooms / f"{k}_{s}")))
    if a.no_flow:
        return 0
    from bench.own_room_flow import run_room  # noqa: E402  (imports the engine: after the render step)

    from recon.io import write_json

    res_dir = Path(a.results) if a.results else rooms / "results"
    res_dir.mkdir(parents=True, exist_ok=True)
    results = []
    for k, s in todo:
        folder = rooms / f"{k}_{s}"
        row = {"room": f"{k}_{s}", "kind": k, "seed": s}
        done = res_dir / f"{k}_{s}.json"
        if (k, s) in missing:
            row["error"] = "not rendered"
            results.append(row)
            print_room(row)
            continue
        if done.is_file() and not a.rerun:
            results.append(json.loads(done.read_text()))
            print_room(results[-1])
            continue
        rj = folder / "bench_render.json"
        row["render"] = json.loads(rj.read_text()) if rj.is_file() else None
        if a.report:
            row["error"] = "not run"
            results.append(row)
            print_room(row)
            continue
        work = Path(a.keep) / f"{k}_{s}" if a.keep else Path(tempfile.mkdtemp(prefix=f"unseen_{k}_{s}_"))
        try:
            row.update(run_room(folder, work, shared, lights=tuple(a.lights.split(",")),
                                true_camera=not a.no_true_camera, known=not a.no_known,
                                declared_sun=not a.no_declared_sun,
                                true_lights=tuple(a.true_camera_lights.split(",")),
                                scene_extra=("--camera-edges", a.camera_edges)))
        except Exception as e:  # a failing room is a row with its error, never dropped
            row["error"] = f"{type(e).__name__}: {e}"
            traceback.print_exc()
        finally:
            if not a.keep:
                shutil.rmtree(work, ignore_errors=True)
        write_json(done, row)
        results.append(row)
        print_room(row, flush=True)
    print_summary(results)
    out = Path(a.json) if a.json else res_dir / "bench_unseen.json"
    write_json(out, {"seeds": SEEDS, "spp": SPP, "rooms": results})
    print(f"results: {out}")
    return 0


def _cell(v, fmt="{:.3g}") -> str:
    return "-" if v is None else fmt.format(v)


def print_room(row: dict, flush=False) -> None:
    """One table: a line per light (captured, captured with the true camera, photo, known)."""
    r = row.get("render") or {}
    spp = f"spp main 2x{r.get('SPP_MAIN', '?')} probe {r.get('SPP_PROBE', '?')}" if r else "spp ?"
    cal = row.get("calibration") or {}
    ref = cal.get("refinement") if cal else None
    if ref and ref.get("accepted"):  # scene refined calibrate's camera against the room's edges
        cal = (f"; calibrated focal {cal['calibrated_focal_rel_err']:+.2%}, centre {cal['calibrated_centre_err_m']:.3f}"
               f" m off; refined {cal['focal_rel_err']:+.2%}, {cal['centre_err_m']:.3f} m (edge rms "
               f"{ref['rms_edge_px']:.2f} px over {ref['n_edge_samples']} samples, lines {ref['rms_lines_px']:.2f} px)")
    elif ref:
        cal = (f"; calibrated focal {cal['focal_rel_err']:+.2%}, centre {cal['centre_err_m']:.3f} m off (not refined: "
               f"{ref['reason']})")
    else:
        cal = (f"; calibrated focal {cal['focal_rel_err']:+.2%}, centre {cal['centre_err_m']:.3f} m off" if cal else "")
    print(f"\n{row['room']} ({spp}; spurious floor {_cell(row.get('spurious_floor'))}, rmse_object floor "
          f"{_cell(row.get('object_floor'), '{:.2f}')}{cal})"
          + (f"  ERROR {row['error']}" if "error" in row else ""), flush=flush)
    lines = row.get("lights") or {}
    if not lines:
        return
    print(f"  {'light':<16} {'energy':>7} {'rmse_aff':>9} {'(untouched)':>11} {'spurious':>9} {'rmse_obj':>9}"
          f" {'(bias)':>7}  note")
    for name, s in lines.items():
        if "error" in s:
            print(f"  {name:<16} ERROR {s['error']}")
            continue
        print(f"  {name:<16} {_cell(s['energy_ratio'], '{:.3f}'):>7} {_cell(s['rmse_affected'], '{:.2f}'):>9}"
              f" {_cell(s['rmse_affected_if_untouched'], '({:.2f})'):>11} {_cell(s['spurious'], '{:.4f}'):>9}"
              f" {_cell(s['rmse_object'], '{:.2f}'):>9} {_cell(s.get('bias_object'), '{:+.1f}'):>7}"
              f"  {s.get('note', '')}", flush=flush)


def print_summary(results: list[dict]) -> None:
    """Median and worst over the rooms, per light and figure (worst: the energy farthest from 1)."""
    import numpy as np

    lights = sorted({n for r in results for n in (r.get("lights") or {})})
    print("\nover rooms (median / worst; worst energy = farthest from 1; rooms without a result counted apart)")
    for n in lights:
        ok = [r["lights"][n] for r in results if n in (r.get("lights") or {}) and "error" not in r["lights"][n]]
        failed = len(results) - len(ok)
        if not ok:
            print(f"  {n:<16} no result in any room")
            continue
        e = np.array([s["energy_ratio"] for s in ok])
        ra = np.array([s["rmse_affected"] / max(s["rmse_affected_if_untouched"], 1e-9) for s in ok])
        sp = np.array([s["spurious"] for s in ok])
        ro = np.array([s["rmse_object"] for s in ok])
        print(f"  {n:<16} energy {np.median(e):.3f} / {e[np.argmax(np.abs(e - 1))]:.3f}"
              f"   rmse_aff/untouched {np.median(ra):.2f} / {ra.max():.2f}"
              f"   spurious {np.median(sp):.4f} / {sp.max():.4f}"
              f"   rmse_obj {np.median(ro):.2f} / {ro.max():.2f}   ({len(ok)} rooms, {failed} without a result)")


if __name__ == "__main__":
    sys.exit(main())
