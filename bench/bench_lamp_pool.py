"""Photo light's lamps against the truth, the fit alone (issue 34 items 3-4; docs/unseen.md "lamp110").

Two steps, so that the fit can be measured in seconds once the rooms' transfers exist:

* `dump KEEP ROOMS ROOM[,ROOM...] --out DIR`: for each room kept by bench_unseen (--keep KEEP: KEEP/ROOM/room),
  one `composite --lighting photo` with lighting.photolight.fit_photo_light hooked: its arguments are pickled to
  DIR/ROOM.pkl with the truth's emitters (the benchmark folder's emitters_summary). `--shared-room NAME` does the
  same for a shared scene (bench_photolight.strip_scene with its bracket, the model at the truth's geometry).
* `eval DIR [--room ROOM,...] [--prior NAME=VALUE] [--detail]`: each pickled fit run again with today's code
  (PhotoPriors changed by --prior); per emitter the fitted radiance over the truth's (luminance) and the lamp
  pool's measurement (lamp_pool below, on the fit's own transfers) with its 1-sigma error, over the truth.

The lamp pool (lamp_pool): on each seen quad, weighted least squares of its patches' radiance against the light
from the rest of the room and each lamp's transfer gives the quad's albedo and each lamp's radiance, no albedo
prior; quads combined by inverse variance, widened by their spread. pool_bounds: the 2-sigma interval the
product would have held each lamp to. Measured in docs/unseen.md "lamp110" and not made the product's: it
shares the walls' fit's bias from the benchmark renderer's 4-bounce cap (lamps_109: 1.24x, the walls 1.21x) and
is 7-15 sigma off for lamps_105's and lamps_108's point lamps.

Prints one line per emitter. Loaded machine: no timings.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
import pickle
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from lighting.photoalbedo import ALBEDO_RANGE  # noqa: E402

LAMP_ROLES = ("lamp", "ceiling_lamp", "point_lamp")  # the model roles of a lamp (own_room_flow maps them to "lamp")


def load_dumps(folder: Path, rooms: str | None = None) -> list[tuple[str, dict]]:
    """(room, dump) of `dump`'s pickles in `folder` (FOLDER/ROOM.pkl: {"calls": [(args, kwargs) of each
    fit_photo_light call], "truth": {emitter name: radiance}, ...}), sorted by room; `rooms`: comma-separated, only those."""
    files = sorted(Path(folder).glob("*.pkl"))
    if rooms:
        files = [f for f in files if f.stem in rooms.split(",")]
    return [(f.stem, pickle.loads(f.read_bytes())) for f in files]


def lamp_pool(qS: np.ndarray, A1: np.ndarray, a0: np.ndarray, L_S: np.ndarray, e: np.ndarray, w: np.ndarray,
              lamp: np.ndarray, min_patches: int = 4, detail: list | None = None) -> dict[str, np.ndarray]:
    """Each lamp's radiance from the light it throws on the seen surfaces, each with its own albedo.

    On one seen quad (uniform albedo rho) patch i shows L_i = rho (base_i + sum_g A1_ig e_g): base_i the light
    from everything but the lamps (the measured patches, the other emitters at `e`), A1_ig lamp g's transfer (its
    direct pool, with visibility, and what the unseen patches pass on). Weighted least squares (w: relative) of
    L against [base, A1_g for the lamps the quad receives] over the quad gives rho and k_g = rho e_g, so
    e_g = k_g / rho: the quad's albedo from the part of it lit by the rest of the room, each lamp's radiance from
    the shape of its pool above that; no albedo prior (a quad whose rho falls outside the physical range
    ALBEDO_RANGE is not used). Its variance by the delta method; the quads' estimates combined by inverse
    variance, the combined error widened by their spread (Birge ratio) where they disagree beyond their errors. Returns {"estimate", "std"} (G,3), NaN for a group that is no lamp or that no
    quad measures. `detail` (a list): (group, quad, channel, estimate, std, rho, patches) appended per quad."""
    ng = A1.shape[1]
    lamps = np.flatnonzero(lamp)
    ests: dict[int, list[list]] = {int(g): [[], [], []] for g in lamps}
    rest = ~lamp
    for q in np.unique(qS):
        m = np.flatnonzero(qS == q)
        gs = lamps[np.any(A1[np.ix_(m, lamps)] > 0, axis=0)] if len(lamps) else lamps
        if len(gs) == 0 or len(m) < max(min_patches, len(gs) + 2):
            continue
        base = a0[m] + A1[np.ix_(m, np.flatnonzero(rest))] @ e[rest]
        for c in range(3):
            X = w[m, None] * np.column_stack([base[:, c], A1[np.ix_(m, gs)]])
            y = w[m] * L_S[m, c]
            sol, *_ = np.linalg.lstsq(X, y, rcond=None)
            dof = max(len(m) - X.shape[1], 1)
            cov = np.sum((X @ sol - y) ** 2) / dof * np.linalg.pinv(X.T @ X)
            rho = sol[0]
            for j, g in enumerate(gs, start=1):
                k = sol[j]
                if not (ALBEDO_RANGE[0] <= rho <= ALBEDO_RANGE[1] and k > 0):
                    continue  # no physical albedo: the quad's light is not this model's
                v = k / rho
                var = v ** 2 * (cov[j, j] / k ** 2 + cov[0, 0] / rho ** 2 - 2 * cov[0, j] / (k * rho))
                if detail is not None:
                    detail.append((int(g), int(q), c, float(v), float(np.sqrt(max(var, 0))), float(rho), len(m)))
                if var > 0 and np.isfinite(var):
                    ests[g][c].append((v, var))
    est, std = np.full((ng, 3), np.nan), np.full((ng, 3), np.nan)
    for g in lamps:
        for c in range(3):
            if not ests[g][c]:
                continue
            v, var = np.array(ests[g][c]).T
            est[g, c] = np.sum(v / var) / np.sum(1 / var)
            # the quads' spread beyond their own errors (Birge ratio) widens the combined error
            chi2 = np.sum((v - est[g, c]) ** 2 / var) / max(len(v) - 1, 1)
            std[g, c] = np.sqrt(max(chi2, 1.0) / np.sum(1 / var))
    return {"estimate": est, "std": std}


def pool_bounds(lower: np.ndarray, pool: dict[str, np.ndarray], k: float = 2.0
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(lower (G,3), upper (G,3), bounded (G,) bool): each lamp lamp_pool measures held within `k` of its
    standard deviations (2: a 95 % interval) of that measurement, never below its own lower bound (clipped
    pixels, the photo's view of it); the other groups keep their lower bound and no upper one."""
    est, sd = pool["estimate"], pool["std"]
    bounded = np.all(np.isfinite(est) & np.isfinite(sd), axis=1)
    lo, hi = np.array(lower, np.float64), np.full(lower.shape, np.inf)
    lo[bounded] = np.maximum(lower[bounded], est[bounded] - k * sd[bounded])
    hi[bounded] = np.maximum(est[bounded] + k * sd[bounded], lo[bounded])
    return lo, hi, bounded


def _hook(store: list) -> None:
    from lighting import photolight

    orig = photolight.fit_photo_light

    def fit(*args, **kw):
        store.append((args, kw))
        return orig(*args, **kw)

    photolight.fit_photo_light = fit


def dump(a) -> None:
    from bench.own_room_flow import _composite_argv, _photoar, score, write_inputs

    store: list = []
    _hook(store)
    a.out.mkdir(parents=True, exist_ok=True)
    for name in a.room.split(","):
        store.clear()
        root = a.rooms / name
        work = a.keep / name
        with tempfile.TemporaryDirectory() as t:
            inp = write_inputs(root, Path(t) / "in")
            out = a.out / f"out_{name}"
            rc, err, _ = _photoar(_composite_argv(work / "room", out, inp, "photo", work / "cache"))
        if rc != 0 or not store:
            print(name, "error", err, flush=True)
            continue
        s = score(root, out / "composite.png", a.shared)
        truth = json.loads((root / "scene.json").read_text())["emitters_summary"]
        (a.out / f"{name}.pkl").write_bytes(pickle.dumps({"calls": list(store), "truth": truth, "score": s}))
        print(f"{name} energy {s['energy_ratio']:.3f} aff {s['rmse_affected']:.2f} "
              f"({s['rmse_affected_if_untouched']:.2f}) obj {s['rmse_object']:.2f} ({s['bias_object']:+.2f})",
              flush=True)


def dump_shared(a) -> None:
    from app.engine import Engine, EngineParams
    from bench.bench_photolight import strip_scene
    from recon.scene import load_scene

    store: list = []
    _hook(store)
    a.out.mkdir(parents=True, exist_ok=True)
    src = a.shared / "scenes" / a.shared_room
    with tempfile.TemporaryDirectory() as t:
        d = strip_scene(src, Path(t) / a.shared_room, keep_bracket=True)
        Engine(load_scene(d), EngineParams(lighting="photo"), quiet=True)
    truth = json.loads((src / "scene.json").read_text()).get("emitters_summary") or {
        q.name: [float(v) for v in q.emission] for q in load_scene(src).quads if np.any(q.emission > 0)}
    (a.out / f"{a.shared_room}.pkl").write_bytes(pickle.dumps({"calls": list(store), "truth": truth}))
    print(a.shared_room, "dumped", len(store), "fit call(s)", flush=True)


def evaluate(a) -> list[dict]:
    from lighting import photolight
    from lighting.sources import luminance

    seen: dict = {}
    orig = photolight.fit_albedo_scale

    def fit_albedo_scale(*args, **kw):  # the fit's seen patches, weights and transfers
        res = orig(*args, **kw)
        seen.update(qS=args[5], w=args[7], L_S=args[8], a0=res.a0, A1=res.A1)
        return res

    photolight.fit_albedo_scale = fit_albedo_scale
    rows = []
    for room, d in load_dumps(a.dir, a.room):
        args, kw = d["calls"][-1]
        args = list(args)
        extra = {k: type(getattr(photolight.PhotoPriors(), k))(v) for k, v in (x.split("=") for x in a.prior)}
        args[5] = dataclasses.replace(args[5] or photolight.PhotoPriors(), **extra)
        seen.clear()
        rep = photolight.fit_photo_light(*args, **kw).report
        names, roles = args[6], args[8]
        ems = rep["emitters"]
        lamp = np.array([e["name"] in names and roles[names.index(e["name"])] in LAMP_ROLES for e in ems], bool)
        detail: list | None = [] if a.detail else None
        pool = lamp_pool(seen["qS"], seen["A1"], seen["a0"], seen["L_S"], np.array([e["radiance"] for e in ems]),
                         seen["w"], lamp, detail=detail)
        for g, q, c, v, sd, rho, n in detail or []:
            t = d["truth"].get(ems[g]["name"])
            if c == 1 and t is not None:
                print(f"  {room} {ems[g]['name']} on {names[q]}: {v / t[1]:.3f} +- {sd / t[1]:.3f} "
                      f"(albedo {rho:.3f}, {n} patches)")
        for g, em in enumerate(ems):
            t = d["truth"].get(em["name"])
            if t is None:
                continue
            tl = float(luminance(np.asarray(t)))
            r = {"room": room, "emitter": em["name"], "fit_over_truth": float(luminance(em["radiance"])) / tl}
            if lamp[g] and np.all(np.isfinite(pool["estimate"][g])):
                r["pool_over_truth"] = float(luminance(pool["estimate"][g])) / tl
                r["pool_std"] = float(luminance(pool["std"][g])) / tl
            rows.append(r)
            print(" ".join(f"{k} {v:.3f}" if isinstance(v, float) else f"{k} {v}" for k, v in r.items()), flush=True)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    d = sub.add_parser("dump")
    d.add_argument("keep", type=Path)
    d.add_argument("rooms", type=Path)
    d.add_argument("room", nargs="?", default="")
    d.add_argument("--out", type=Path, required=True)
    d.add_argument("--shared-room")
    d.add_argument("--shared", type=Path, default=Path(os.environ.get("PHOTOAR_SHARED", ROOT.parent / "shared")))
    e = sub.add_parser("eval")
    e.add_argument("dir", type=Path)
    e.add_argument("--room")
    e.add_argument("--json", type=Path)
    e.add_argument("--prior", action="append", default=[], help="NAME=VALUE: a PhotoPriors field (int / float)")
    e.add_argument("--detail", action="store_true", help="each quad's estimate of each lamp (green channel)")
    a = ap.parse_args()
    if a.cmd == "dump":
        dump_shared(a) if a.shared_room else dump(a)
    else:
        rows = evaluate(a)
        if a.json:
            a.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
