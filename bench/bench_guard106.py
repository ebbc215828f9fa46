"""Why `scene` keeps calibrate's camera unrefined in a room (issue 34 item 6; window_106): the refinement's
objective against the guard's edge residual, camera by camera, edge group by edge group. Diagnosis only:
the product code is not changed (its _guard is wrapped to record what it was given).

Per room (the own-room flow's camera: bench/own_room_flow.calibrated_from_lines, turned as `scene` turns it,
its focal sigma as camera.json carries it), refine_camera is run as `scene` runs it, and its guard's inputs
are recorded (the input camera, the refined one, the final fit). For three cameras (truth, calibrated,
refined) it prints:
- errors against the truth's camera (bench/bench_camrefine.camera_errors: focal %, rotation deg, centre cm,
  room-edge image px, object image px: what rmse_object scores);
- the guard's edge residual (recon.camrefine._edge_chamfer: mean over SAMPLES of the 3 px-capped distance to
  the nearest oriented Canny pixel, on the samples the input or the refined camera sees), the same per room
  edge and averaged over EDGES (the search's own ranking, recon.camrefine._edge_gain), and per edge group
  (room box / furniture / window, by the edge's world axis);
- the fit's own measure: each edge's mean sub-pixel offset (recon.camrefine._subpixel, the profile stage's
  centroid, ramps dropped) and the clicked lines' chi-square (_lines_chi2);
and the refinement started from the truth's camera (no clicked lines, as bench_unseen's `true cam`).

    python bench/bench_guard106.py [--rooms DIR] [--only window_106,window_104,window_105] [--json OUT]
    python bench/bench_guard106.py --what-if [--only ...]           (a) and (b) on the calibrated camera, fit by fit
    python bench/bench_guard106.py --compare [--variants current,a,b,b2,b3] [--only ...]   one line per room
    python bench/bench_guard106.py --only window_106 --force-accept RESULTS_DIR [--variant a|b2]   (composites: minutes)
    python bench/bench_guard106.py --only window_106 --force-accept DIR --variant old|current --lights captured,photo
                                                                    (cam107: the flow before / with cam107's rule)
Variants (bench-only monkeypatches): a = widened_on_edge_refusal, b/b2/b3/b4 = canny_fallback on the fine stages as
before cam107, old = without_clipped_edges (see their docstrings); with --compare also c3/c4 (today's fit and b3's /
b4's, the lower guard chamfer kept: _pick). The product's own rule since cam107: recon.camrefine._fine_edges.
"""
from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def edge_labels(prims: list[dict], edges: np.ndarray) -> list[str]:
    """A group name per room edge: the role of the first primitive that has it (room / furniture / window)
    and its world axis (x, y, z; 'o' when oblique)."""
    from recon.camrefine import room_edges, room_faces

    key = lambda a, b: tuple(sorted((tuple(np.round(a, 4)), tuple(np.round(b, 4)))))  # noqa: E731
    owner = {}
    for p in prims:
        for a, b in room_edges(room_faces([p])):
            owner.setdefault(key(a, b), p.get("role", p.get("name", "?")))
    out = []
    for a, b in edges:
        d = np.abs(b - a) / max(np.linalg.norm(b - a), 1e-12)
        ax = "xyz"[int(np.argmax(d))] if d.max() > 0.99 else "o"
        out.append(f"{owner.get(key(a, b), '?')}:{ax}")
    return out


def per_edge(values: np.ndarray, edge: np.ndarray) -> dict[int, float]:
    return {int(e): float(np.mean(values[edge == e])) for e in np.unique(edge)}


def measure(cam, S, photo, lines) -> dict:
    """The guard's and the fit's measures of camera `cam` on the samples S."""
    from recon.camrefine import _edge_distances, _lines_chi2, _project, _subpixel

    d = _edge_distances(cam, S, photo)
    uv, n = _project(cam, S)
    q, ok = _subpixel(photo, uv, n, S.edge)
    _, ok_raw = photo.subpixel(uv, n)  # edgesnap's rule alone (before _exclusive and the ramp mask)
    off = np.where(ok, np.sum(n * (q - uv), axis=1), np.nan)
    sub = {int(e): float(np.nanmean(np.abs(off[S.edge == e]))) if ok[S.edge == e].any() else float("nan")
           for e in np.unique(S.edge)}
    return {"chamfer_samples": float(np.mean(d)), "chamfer_edge": per_edge(d, S.edge),
            "subpix_edge": sub, "subpix_found": float(ok.mean()),
            "found_edge": {int(e): (float(ok_raw[S.edge == e].mean()), float(ok[S.edge == e].mean()))
                           for e in np.unique(S.edge)},
            "lines_chi2": _lines_chi2(cam, lines)[0] if lines[0] else float("nan")}


def run_room(root: Path) -> dict:
    from bench.bench_camrefine import camera_errors, object_points
    from bench.own_room_flow import calibrated_from_lines
    from recon import assemble as asm
    from recon import camrefine as cr

    truth, img, cal, prims, lo, hi = calibrated_from_lines(root)
    cam = dataclasses.replace(cal.camera, focal_rel_sigma=cal.focal_rel_sigma)
    cam = asm.inside_turn(cam, lo, hi)[0]
    faces = cr.room_faces(prims)
    edges = cr.room_edges(faces)
    occ = cr._Occluder(faces)
    labels = edge_labels(prims, edges)
    P = object_points(root)
    S_truth = cr._sample_edges(truth, edges, occ)
    cj = cal.to_json()
    lines = cr.clicked_lines(cj)
    out = {"room": root.name}
    for start, c0, cjs in (("calibrated", cam, cj), ("truth", truth, None)):
        calls = []
        orig = cr._guard

        def rec(cam_in, refined, fit, *a, **k):
            g = orig(cam_in, refined, fit, *a, **k)
            calls.append((refined, fit, g))
            return g

        cr._guard = rec
        try:
            r = cr.refine_camera(c0, prims, img, cjs)
        finally:
            cr._guard = orig
        if not calls:
            out[start] = {"accepted": r.accepted, "reason": r.reason}
            continue
        # the guard call that decided: the accepted camera's, else the first (the first search's; the widened
        # search's guard calls follow it, recon.camrefine.refine_camera)
        same = [c for c in calls if c[2].accepted and np.allclose(c[0].K, r.camera.K) and np.allclose(c[0].R, r.camera.R)
                and np.allclose(c[0].t, r.camera.t)]
        refined, fit, g = same[0] if r.accepted and same else calls[0]
        photo = cr.PhotoEdges(img)
        S0 = cr._sample_edges(c0, edges, occ)
        both = cr._union(S0, fit.S)  # the guard's samples
        row = {"accepted": r.accepted, "reason": r.reason, "moved_px": g.moved_px, "guard_calls": len(calls),
               "start": g.start,
               "chamfer_guard": (g.chamfer_before_px, g.chamfer_after_px)}
        for name, c in (("truth", truth), ("input", c0), ("refined", refined)):
            m = measure(c, both, photo, lines)
            m["errors"] = camera_errors(c, truth, S_truth, P)
            row[name] = m
        es = sorted(row["input"]["chamfer_edge"])
        n_e = {e: int(np.sum(both.edge == e)) for e in es}
        row["edges"] = [{"edge": e, "group": labels[e], "samples": n_e[e],
                         **{f"chamfer_{k}": row[k]["chamfer_edge"][e] for k in ("truth", "input", "refined")},
                         **{f"subpix_{k}": row[k]["subpix_edge"][e] for k in ("truth", "input", "refined")},
                         "found_input": row["input"]["found_edge"][e]}
                        for e in es]
        for k in ("truth", "input", "refined"):
            row[k]["chamfer_edge_mean"] = float(np.mean([row[k]["chamfer_edge"][e] for e in es]))
            row[k]["subpix_edge_mean"] = float(np.nanmean([row[k]["subpix_edge"][e] for e in es]))
            del row[k]["chamfer_edge"], row[k]["subpix_edge"], row[k]["found_edge"]
        groups = {}
        for r_e in row["edges"]:
            gr = groups.setdefault(r_e["group"], {"edges": 0, "samples": 0, **{f"chamfer_{k}": 0.0 for k in
                                                                             ("truth", "input", "refined")}})
            gr["edges"] += 1
            gr["samples"] += r_e["samples"]
            for k in ("truth", "input", "refined"):  # sample-weighted, as the guard weighs them
                gr[f"chamfer_{k}"] += r_e[f"chamfer_{k}"] * r_e["samples"]
        for gr in groups.values():
            for k in ("truth", "input", "refined"):
                gr[f"chamfer_{k}"] /= gr["samples"]
        row["groups"] = groups
        out[start] = row
    return out


def _print(res: dict) -> None:
    print(f"== {res['room']}")
    for start in ("calibrated", "truth"):
        r = res.get(start)
        if r is None:
            continue
        if "input" not in r:
            print(f"  from {start}: no fit ({r['reason']})")
            continue
        print(f"  from {start}: {'accepted' if r['accepted'] else 'kept: ' + r['reason']} (moves {r['moved_px']:.2f} px; "
              f"fit from: {r['start']}; guard calls {r['guard_calls']})")
        print("    camera    focal%   rot deg  centre cm  edges px  object px | chamfer/sample  chamfer/edge  "
              "subpix/edge  lines chi2")
        for k in ("truth", "input", "refined"):
            m, e = r[k], r[k]["errors"]
            print(f"    {k:8s} {e['focal_pct']:+7.2f} {e['rot_deg']:8.3f} {e['centre_cm']:9.1f} {e['image_px']:9.2f} "
                  f"{e['object_px']:9.2f}  | {m['chamfer_samples']:13.3f} {m['chamfer_edge_mean']:13.3f} "
                  f"{m['subpix_edge_mean']:12.3f} {m['lines_chi2']:10.1f}")
        print("    group (edges, samples): guard chamfer truth / input / refined (sample mean)")
        for name, g in sorted(r["groups"].items()):
            print(f"      {name:13s} ({g['edges']:2d}, {g['samples']:4d}): {g['chamfer_truth']:.3f} / "
                  f"{g['chamfer_input']:.3f} / {g['chamfer_refined']:.3f}")
        print("    edges: group samples: guard chamfer in->ref, |sub-pixel offset| in->ref (truth's chamfer, offset), "
              "fraction of samples with a sub-pixel edge at the input (edgesnap's rule, used by the fit)")
        for x in sorted(r["edges"], key=lambda x: x["group"]):
            print(f"      {x['edge']:3d} {x['group']:13s} {x['samples']:4d}: {x['chamfer_input']:.2f}->"
                  f"{x['chamfer_refined']:.2f}  {x['subpix_input']:.2f}->{x['subpix_refined']:.2f}  "
                  f"(truth {x['chamfer_truth']:.2f}, {x['subpix_truth']:.2f})  found {x['found_input'][0]:.2f}/"
                  f"{x['found_input'][1]:.2f}")


@contextlib.contextmanager
def canny_fallback(coarse_sigma: bool = False, whole_edges: bool = False, clipped_only: bool = False):
    """In this process, while active: the profile stage keeps a sample that has no sub-pixel edge (edgesnap's
    rule refuses it, or its edge is a ramp) at its oriented Canny match within 2 px (the coarse stage's last
    radius; _exclusive applied), so the fine fit sees the edges the guard measures. coarse_sigma: such a
    sample's noise is COARSE_SIGMA_PX (a Canny pixel) in the fit, not FINE_SIGMA_PX. whole_edges: only the
    samples of a room edge none of whose samples has a sub-pixel edge (each edge measured one way). On the fine
    stages as they were before cam107 (without_clipped_edges; b4 is cam107's rule done so). clipped_only:
    only samples edgesnap refuses for a clipped pixel within 3 px (its near_clip mask at the sample)."""
    from recon import camrefine as cr

    orig_sub, orig_solve, last = cr._subpixel, cr._solve, {}

    def sub(ph, uv, n, edge):
        q, use = orig_sub(ph, uv, n, edge)
        qc, okc = ph.match(uv, np.arctan2(n[:, 1], n[:, 0]), 2.0)
        okc &= cr._exclusive(uv, n, edge, qc)
        add = ~use & okc
        if whole_edges:
            add &= ~np.isin(edge, np.unique(edge[use]))
        if clipped_only:
            E = ph.fine
            iu = np.clip(np.rint(uv).astype(int), 0, [E.shape[1] - 1, E.shape[0] - 1])
            add &= E.near_clip[iu[:, 1], iu[:, 0]]
        last["add"] = add[use | add]  # which of the fit's samples are Canny matches, in the fit's order
        return np.where(add[:, None], qc, q), use | add

    def solve(model, x0, S, q, sig_e, *a, **k):
        add = last.get("add")
        if coarse_sigma and np.ndim(sig_e) == 0 and sig_e == cr.FINE_SIGMA_PX and add is not None \
                and len(add) == len(S.X):
            sig_e = np.where(add, cr.COARSE_SIGMA_PX, cr.FINE_SIGMA_PX)
        return orig_solve(model, x0, S, q, sig_e, *a, **k)

    cr._subpixel, cr._solve = sub, solve
    try:
        with without_clipped_edges():  # on the fine stages as they were before cam107
            yield
    finally:
        cr._subpixel, cr._solve = orig_sub, orig_solve


@contextlib.contextmanager
def widened_on_edge_refusal():
    """In this process, while active: refine_camera's second search (_widened_search) runs also when the first
    search's camera was refused because the edge residual does not drop (it runs only when that camera fails
    the clicked lines); its choice unchanged (guard accepted, _edge_gain > EDGE_MODEL_SIGMA_PX). Done by
    making refine_camera's own clicked-line test (not the guard's) read failed after such a refusal."""
    import sys as _sys

    from recon import camrefine as cr

    orig_guard, orig_chi2, state = cr._guard, cr._lines_chi2, {"reason": ""}

    def guard(*a, **k):
        g = orig_guard(*a, **k)
        state["reason"] = g.reason
        return g

    def chi2(cam, lines):
        c, lim = orig_chi2(cam, lines)
        if _sys._getframe(1).f_code.co_name == "refine_camera" and \
                state["reason"].startswith("the edge residual does not drop"):
            return float("inf"), lim
        return c, lim

    cr._guard, cr._lines_chi2 = guard, chi2
    try:
        yield
    finally:
        cr._guard, cr._lines_chi2 = orig_guard, orig_chi2


@contextlib.contextmanager
def without_clipped_edges():
    """In this process, while active: the fine stages as before cam107 (recon.camrefine._fine_edges reduced to
    _subpixel at FINE_SIGMA_PX: a room edge whose every sample lies by a clipped pixel is not fitted there)."""
    from recon import camrefine as cr

    orig = cr._fine_edges
    cr._fine_edges = lambda photo, uv, n, edge: (*cr._subpixel(photo, uv, n, edge), cr.FINE_SIGMA_PX)
    try:
        yield
    finally:
        cr._fine_edges = orig


VARIANTS = {"a": widened_on_edge_refusal, "old": without_clipped_edges, "current": contextlib.nullcontext,
            "b": canny_fallback, "b2": lambda: canny_fallback(coarse_sigma=True),
            "b3": lambda: canny_fallback(coarse_sigma=True, whole_edges=True),
            "b4": lambda: canny_fallback(coarse_sigma=True, whole_edges=True, clipped_only=True)}
CANDIDATES = {"c3": "b3", "c4": "b4"}  # today's fit and the variant's, the guard's chamfer picks (_pick)


def _pick(cam, rs, prims, img):
    """Of refinements rs (today's first), the accepted one with the lowest guard chamfer (mean over samples of the
    capped distance, on the samples the input or any accepted camera sees); rs[0] when none is accepted."""
    from recon import camrefine as cr

    ok = [r for r in rs if r.accepted]
    if len(ok) < 2:
        return ok[0] if ok else rs[0]
    faces = cr.room_faces(prims)
    edges, occ, photo = cr.room_edges(faces), cr._Occluder(faces), cr.PhotoEdges(img)
    S = cr._union(cr._sample_edges(cam, edges, occ), *[cr._sample_edges(r.camera, edges, occ) for r in ok])
    return min(ok, key=lambda r: cr._edge_chamfer(r.camera, S, photo))


def compare(root: Path, variants=("current", "b", "b2", "b3")) -> dict:
    """Object / room-edge image error of the camera `scene` would use (calibrated, refined when the guard
    accepts) now and with canny_fallback (b: fine sigma; b2: coarse sigma for the Canny samples), and
    of the refinement started from the truth's camera (no clicked lines); b3: b2 on the edges without any
    sub-pixel sample only."""
    from bench.bench_camrefine import camera_errors, object_points
    from bench.own_room_flow import calibrated_from_lines
    from recon import assemble as asm
    from recon import camrefine as cr

    truth, img, cal, prims, lo, hi = calibrated_from_lines(root)
    cam = dataclasses.replace(cal.camera, focal_rel_sigma=cal.focal_rel_sigma)
    cam = asm.inside_turn(cam, lo, hi)[0]
    faces = cr.room_faces(prims)
    S_truth = cr._sample_edges(truth, cr.room_edges(faces), cr._Occluder(faces))
    P = object_points(root)
    out = {"room": root.name, "calibrated": camera_errors(cam, truth, S_truth, P)}
    done = {}

    def run(v):
        if v not in done:
            with VARIANTS[v]():
                done[v] = (cr.refine_camera(cam, prims, img, cal.to_json()), cr.refine_camera(truth, prims, img, None))
        return done[v]

    for name in variants:
        if name in CANDIDATES:
            (r0, rt0), (r1, rt1) = run("current"), run(CANDIDATES[name])
            r, rt = _pick(cam, [r0, r1], prims, img), _pick(truth, [rt0, rt1], prims, img)
        else:
            r, rt = run(name)
        out[name] = {"accepted": r.accepted, "reason": r.reason, **camera_errors(r.camera, truth, S_truth, P),
                     "from_truth": {"accepted": rt.accepted, **camera_errors(rt.camera, truth, S_truth, P)}}
    return out


def what_if(root: Path) -> dict:
    """Two alternatives, measured only (monkeypatched in this process; the product code is unchanged), on the
    calibrated camera: (a) refine_camera's second search (_widened_search, the focal length moved by its own
    sigma) run also when the first search's camera fails the edge residual (it runs only when it fails the
    clicked lines), chosen as refine_camera chooses (guard accepted, _edge_gain > EDGE_MODEL_SIGMA_PX);
    (b) the profile stage with a sample whose edge has no sub-pixel profile (edgesnap refuses it: a clipped
    pixel within 3 px, a ramp) kept at its oriented Canny match within 2 px (the coarse stage's last radius),
    so the fit sees the edges the guard measures. Camera errors of each."""
    from bench.bench_camrefine import camera_errors, object_points
    from bench.own_room_flow import calibrated_from_lines
    from recon import assemble as asm
    from recon import camrefine as cr

    truth, img, cal, prims, lo, hi = calibrated_from_lines(root)
    cam = dataclasses.replace(cal.camera, focal_rel_sigma=cal.focal_rel_sigma)
    cam = asm.inside_turn(cam, lo, hi)[0]
    faces = cr.room_faces(prims)
    edges, occ = cr.room_edges(faces), cr._Occluder(faces)
    S_truth, P = cr._sample_edges(truth, edges, occ), object_points(root)
    cj = cal.to_json()
    lines, photo = cr.clicked_lines(cj), cr.PhotoEdges(img)
    out = {"room": root.name, "pp_from": cj.get("principal_point_from"), "focal_rel_sigma": cal.focal_rel_sigma,
           "calibrated": camera_errors(cam, truth, S_truth, P)}
    # (a) the widened search
    model = cr._Model(cam, free_pp=False)
    wide = cr._widened_search(model, edges, occ, photo, lines, "profiles", float(cal.focal_rel_sigma))
    rows = []
    ok = []
    for f in wide:
        g = cr._guard(cam, model.camera(f.x), f, lines, edges, occ, photo, 0.0)
        rows.append({"accepted": g.accepted, "reason": g.reason, **camera_errors(model.camera(f.x), truth, S_truth, P)})
        if g.accepted:
            ok.append((f, g))
    chosen = None
    if ok:
        common = cr._union(cr._sample_edges(cam, edges, occ), *[f.S for f, _ in ok])
        gains = [cr._edge_gain(cam, g.camera, common, photo) for _, g in ok]
        i = int(np.argmax(gains))
        chosen = {"gain_px": gains[i], "taken": gains[i] > cr.EDGE_MODEL_SIGMA_PX,
                  **camera_errors(ok[i][1].camera, truth, S_truth, P)}
    out["widened"] = {"fits": rows, "chosen": chosen}
    # (b) the Canny fallback in the profile stage
    with canny_fallback():
        r = cr.refine_camera(cam, prims, img, cj)
        rt = cr.refine_camera(truth, prims, img, None)
    out["canny_fallback"] = {"accepted": r.accepted, "reason": r.reason, "chamfer": (r.chamfer_before_px,
                             r.chamfer_after_px), **camera_errors(r.camera if r.accepted else r.camera_at(r.x)
                                                                   if r.x is not None else r.camera, truth, S_truth, P)}
    out["canny_fallback_from_truth"] = {"accepted": rt.accepted, "reason": rt.reason, "chamfer": (
        rt.chamfer_before_px, rt.chamfer_after_px), **camera_errors(rt.camera_at(rt.x) if rt.x is not None else rt.camera,
                                                                    truth, S_truth, P)}
    return out


def forced_unseen(rooms: Path, only: str, results: Path, variant: str = "", lights: str = "captured",
                  keep: Path | None = None) -> None:
    """bench/bench_unseen.py's own-room flow on `only` with the guard's edge-residual refusal overridden (the
    refined camera taken whenever that is the only reason to refuse it; in this process only): what rmse_object
    the refused camera would have given. Both `scene` runs (calibrated and true camera) are affected. With a
    variant (VARIANTS), no override: the flow with that variant."""
    from bench import bench_unseen
    from recon import camrefine as cr

    orig = cr._guard

    def forced(cam_in, refined, fit, *a, **k):
        g = orig(cam_in, refined, fit, *a, **k)
        if variant in ("", None) and not g.accepted and g.reason.startswith("the edge residual does not drop"):
            return dataclasses.replace(g, camera=refined, accepted=True, reason="")
        return g

    cr._guard = forced
    ctx = VARIANTS[variant or "current"]
    try:
        with ctx():
            bench_unseen.main(["--rooms", str(rooms), "--only", only, "--results", str(results), "--rerun",
                               "--lights", lights, "--no-known", "--no-declared-sun"]
                              + (["--keep", str(keep)] if keep else []))
    finally:
        cr._guard = orig


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rooms", type=Path, default=Path.home() / ".cache/photoar/rooms_full")
    ap.add_argument("--only", default="window_106,window_104,window_105")
    ap.add_argument("--json", type=Path, help="write the results here")
    ap.add_argument("--variant", choices=("", "a", "b", "b2", "b3", "b4", "old", "current"), default="",
                    help="with --force-accept: this variant instead of the forced guard (a, b, b2, b3, b4; old: the "
                         "fine stages before cam107; current: the product as it is)")
    ap.add_argument("--lights", default="captured", help="with --force-accept: bench_unseen's --lights")
    ap.add_argument("--keep", type=Path, help="with --force-accept: bench_unseen's --keep (work folders)")
    ap.add_argument("--variants", default="current,b,b2,b3", help="with --compare: which (default %(default)s; also b4, "
                    "and the candidates c3 / c4: today's fit and b3's / b4's, the lower guard chamfer kept)")
    ap.add_argument("--compare", action="store_true", help="instead: one line per room, the camera scene would use "
                                                          "now and with the Canny fallback (compare())")
    ap.add_argument("--what-if", action="store_true", help="instead: the two alternatives of what_if() (measured "
                                                           "by monkeypatching in this process)")
    ap.add_argument("--force-accept", type=Path, metavar="RESULTS",
                    help="instead: run bench_unseen's flow (captured light, and the true camera) on --only with the "
                         "guard's edge-residual refusal overridden; its results into this folder")
    a = ap.parse_args(argv)
    if a.compare:
        res = []
        vs = tuple(a.variants.split(","))
        print("room         calibrated  | " + " | ".join(f"{v:>15s}" for v in vs) + "    object px (room-edge px); "
              "[from truth: object px]")
        for n in a.only.split(","):
            r = compare(a.rooms / n, vs)
            res.append(r)
            c = lambda k: f"{r[k]['object_px']:6.2f} ({r[k]['image_px']:5.2f}){' ' if r[k]['accepted'] else '*'}"  # noqa: E731
            print(f"{n:12s} {r['calibrated']['object_px']:6.2f} ({r['calibrated']['image_px']:5.2f}) | "
                  + " | ".join(c(v) for v in vs) + "    [" + " / ".join(f"{r[v]['from_truth']['object_px']:.2f}"
                                                                        for v in vs) + "]", flush=True)
            if a.json:
                a.json.write_text(json.dumps(res, indent=1))
        print("* the guard kept the input camera")
        return 0
    if a.what_if:
        res = [what_if(a.rooms / n) for n in a.only.split(",")]
        for r in res:
            f = lambda e: (f"focal {e['focal_pct']:+.2f} %, rot {e['rot_deg']:.3f} deg, centre {e['centre_cm']:.1f} cm, "  # noqa: E731
                           f"edges {e['image_px']:.2f} px, object {e['object_px']:.2f} px")
            print(f"== {r['room']} (pp from {r['pp_from']}, focal sigma {r['focal_rel_sigma']:.2%})")
            print(f"  calibrated: {f(r['calibrated'])}")
            for i, w in enumerate(r["widened"]["fits"]):
                print(f"  (a) focal-search fit {i}: {f(w)}: {'accepted' if w['accepted'] else w['reason']}")
            c = r["widened"]["chosen"]
            print(f"  (a) chosen: " + (f"gain {c['gain_px']:.3f} px, {'taken' if c['taken'] else 'not taken (gain <= 0.3 px)'}:"
                                      f" {f(c)}" if c else "none accepted"))
            for k in ("canny_fallback", "canny_fallback_from_truth"):
                c = r[k]
                print(f"  (b) {k}: {'accepted' if c['accepted'] else 'kept: ' + c['reason']} (chamfer "
                      f"{c['chamfer'][0]:.3f} -> {c['chamfer'][1]:.3f}); its fit: {f(c)}")
        if a.json:
            a.json.write_text(json.dumps(res, indent=1))
        return 0
    if a.force_accept:
        forced_unseen(a.rooms, a.only, a.force_accept, a.variant, a.lights, a.keep)
        return 0
    results = []
    for name in a.only.split(","):
        results.append(run_room(a.rooms / name))
        _print(results[-1])
        if a.json:
            a.json.write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
