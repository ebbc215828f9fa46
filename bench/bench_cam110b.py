"""Room edges' bias at the TRUE camera, and whether a shared offset term would fit it (issue 34 item 6; cam110b).

    python bench/bench_cam110b.py [--rooms DIR] --only ROOMS [--json OUT]
        per room edge at the truth's camera: group (bench_guard106.edge_labels: owner role, world axis), F when it
        lies on the floor, samples found / visible, the mean signed offset (px, along the projected normal n of
        camrefine._project) between the projected model edge and the photo edge the fine stage finds
        (camrefine._fine_edges), its spread and standard error, the photo's mean 8-bit gray 3 px along +n and -n;
        then per class (room floor-wall lines, room vertical corners, furniture floor / vertical / other edges)
        the mean offset toward the brighter side and (floor-wall lines) toward the wall (the image of 1 cm up it)
    python bench/bench_cam110b.py --offsets [--rooms DIR] --only ROOMS
        the profile stage (camrefine._profile_stage) started AT the truth's camera (where the fit's own objective
        puts the camera near the truth), with the photo's edge points moved back by a fixed offset: b px toward
        each edge's darker side (all edges), or o px toward the floor (room floor-wall lines only); focal % /
        centre cm / object px against the truth. A fixed offset is a measurement, not a rule: if one helped
        everywhere, a jointly estimated offset would be the rule
    python bench/bench_cam110b.py --jackknife [--rooms DIR] --only ROOMS
        the camera `scene` would use (refine_camera from calibrate's camera, bench_camrefine.calibrated_room),
        its error, and the fit's own edge jackknife at the object (camrefine.edge_jackknife: 1 sigma, px)
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
ROOMS = Path.home() / ".cache/photoar/rooms_full"


def _gray_at(img: np.ndarray, uv: np.ndarray) -> np.ndarray:
    g = img[..., :3].astype(np.float32).mean(-1) if img.ndim == 3 else img.astype(np.float32)
    iu = np.clip(np.rint(uv).astype(int), 0, [g.shape[1] - 1, g.shape[0] - 1])
    return g[iu[:, 1], iu[:, 0]]


def _classes(room) -> tuple[list[str], np.ndarray]:
    from bench.bench_guard106 import edge_labels

    labels = edge_labels(room.prims, room.edges)
    y0 = float(np.min(room.edges[..., 1]))
    floor = np.array([max(a[1], b[1]) - y0 < 0.01 for a, b in room.edges])
    cls = []
    for lab, fl in zip(labels, floor):
        role, ax = lab.split(":")
        cls.append(f"{'room' if role == 'room' else role}:{'floor' if fl else ('vertical' if ax == 'y' else 'other')}")
    return cls, floor


def _wall_side(cam, S, n: np.ndarray) -> np.ndarray:
    """(N,) +1 where a sample's +n points up the wall (the image of the point 1 cm above it), else -1."""
    uv, _ = cam.project(S.X)
    up, _ = cam.project(S.X + np.array([0.0, 0.01, 0.0]))
    return np.where(np.sum(n * (up - uv), axis=1) >= 0, 1.0, -1.0)


def edge_bias(root: Path) -> dict:
    from bench.bench_camrefine import calibrated_room
    from recon import camrefine as cr

    room = calibrated_room(root)
    photo = cr.PhotoEdges(room.img)
    cls, floor = _classes(room)
    S = room.S_truth
    uv, n = cr._project(room.truth, S)
    q, ok, _ = cr._fine_edges(photo, uv, n, S.edge)
    off = np.sum(n * (q - uv), axis=1)
    lp, lm = _gray_at(room.img, uv + 3 * n), _gray_at(room.img, uv - 3 * n)
    wall = _wall_side(room.truth, S, n)
    out = []
    for e in np.unique(S.edge):
        m = (S.edge == e) & ok
        k = int(m.sum())
        sd = float(np.std(off[m])) if k else float("nan")
        ae = S.edge == e
        out.append({"edge": int(e), "class": cls[e], "samples": int(ae.sum()), "found": k,
                    "offset_px": float(np.mean(off[m])) if k else float("nan"), "spread_px": sd,
                    "se_px": sd / np.sqrt(k) if k else float("nan"),
                    "gray_plus": float(np.mean(lp[ae])), "gray_minus": float(np.mean(lm[ae])),
                    "toward_bright_px": float(np.mean(off[m]) * np.sign(np.mean(lp[ae]) - np.mean(lm[ae])))
                    if k else float("nan"),
                    "toward_wall_px": float(np.mean(off[m] * wall[m])) if k and cls[e] == "room:floor"
                    else None})
    return {"room": root.name, "edges": out}


def offsets_room(root: Path, bs=(0.1, 0.2), os_=(0.25, 0.5)) -> dict:
    from bench.bench_camrefine import calibrated_room
    from recon import camrefine as cr

    room = calibrated_room(root)
    model = cr._Model(room.truth)
    photo = cr.PhotoEdges(room.img)
    lines = cr.clicked_lines(room.cal.to_json())
    cls, _ = _classes(room)
    floor = np.array([c == "room:floor" for c in cls])
    # which way along an edge's normal is up the wall: per edge, at the truth (the normal's sign follows the edge's
    # direction, the same at every camera near the truth)
    S = room.S_truth
    w = _wall_side(room.truth, S, cr._project(room.truth, S)[1])
    wall = np.zeros(len(room.edges))
    for e in np.unique(S.edge):
        wall[e] = np.sign(np.mean(w[S.edge == e]))
    fine = cr._fine_edges

    def shifted(b: float, o: float):
        def fe(ph, uv, n, edge):
            q, ok, sig = fine(ph, uv, n, edge)
            s = np.zeros(len(uv))
            for e in np.unique(edge):
                m = edge == e
                s[m] = b * np.sign(np.mean(_gray_at(room.img, uv[m] + 3 * n[m]) - _gray_at(room.img, uv[m] - 3 * n[m])))
            s += o * floor[edge] * wall[edge]
            return q - s[:, None] * n, ok, sig
        return fe

    out = {"room": root.name}
    for key, b, o in [("none", 0.0, 0.0)] + [(f"bright{b}", b, 0.0) for b in bs] + [(f"floor{o}", 0.0, o) for o in os_]:
        cr._fine_edges = shifted(b, o)
        try:
            f = cr._profile_stage(model, np.zeros(model.n), room.edges, room.occ, photo, lines)
        finally:
            cr._fine_edges = fine
        out[key] = room.errors(model.camera(f.x))
    return out


def jackknife_room(root: Path) -> dict:
    from bench.bench_camrefine import calibrated_room
    from recon import camrefine as cr

    room = calibrated_room(root)
    r = cr.refine_camera(room.cam, room.prims, room.img, room.cal.to_json())
    jk = cr.edge_jackknife(r, room.P)
    return {"room": root.name, "refined": room.errors(r.camera), "jackknife_px": jk[0], "one_edge_px": jk[1],
            "one_edge": jk[2]}


def _f(e: dict) -> str:
    return f"{e['focal_pct']:+.2f}/{e['centre_cm']:.1f}/{e['object_px']:.2f}"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rooms", type=Path, default=ROOMS)
    ap.add_argument("--only", default="sun_104")
    ap.add_argument("--json", type=Path)
    ap.add_argument("--offsets", action="store_true")
    ap.add_argument("--jackknife", action="store_true")
    ap.add_argument("--locator", choices=("centroid", "step", "kink"), help="recon.edgesnap.LOCATOR for this run")
    a = ap.parse_args(argv)
    if a.locator:
        from recon import edgesnap

        edgesnap.LOCATOR = a.locator
    res = []
    for name in a.only.split(","):
        if a.offsets:
            o = offsets_room(a.rooms / name)
            print(f"{name:11s} " + " | ".join(f"{k} {_f(v)}" for k, v in o.items() if k != "room"), flush=True)
        elif a.jackknife:
            o = jackknife_room(a.rooms / name)
            print(f"{name:11s} refined {_f(o['refined'])} edge jackknife {o['jackknife_px']:.2f} px "
                  f"(edge {o['one_edge']} alone {o['one_edge_px']:.2f} px)", flush=True)
        else:
            o = edge_bias(a.rooms / name)
            print(name, flush=True)
            for d in o["edges"]:
                if d["found"]:
                    print(f"  e{d['edge']:<3d} {d['class']:18s} {d['found']:4d}/{d['samples']:<4d} "
                          f"{d['offset_px']:+.2f} sd {d['spread_px']:.2f} se {d['se_px']:.3f} "
                          f"gray+ {d['gray_plus']:.0f} gray- {d['gray_minus']:.0f}", flush=True)
        res.append(o)
        if a.json:
            a.json.write_text(json.dumps(res, indent=1))
    if not (a.offsets or a.jackknife):
        cls = {}
        for o in res:
            for d in o["edges"]:
                if d["found"] >= 8:
                    cls.setdefault(d["class"], []).append(d)
        for c, ds in sorted(cls.items()):
            tb = np.array([d["toward_bright_px"] for d in ds])
            rms = np.sqrt(np.mean([d["offset_px"] ** 2 for d in ds]))
            s = (f"{c:18s} {len(ds):3d} edges: toward the brighter side mean {tb.mean():+.3f} px, "
                 f"{np.mean(tb > 0):.0%} positive; rms offset {rms:.3f} px")
            if c == "room:floor":
                tw = np.array([d["toward_wall_px"] for d in ds])
                s += f"; toward the wall mean {tw.mean():+.3f} px, {np.mean(tw > 0):.0%} positive"
            print(s)
    return 0


if __name__ == "__main__":
    sys.exit(main())
