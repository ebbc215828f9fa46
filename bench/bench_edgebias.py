"""Does the synthetic photo predict the sub-pixel edges' offsets at the true camera? (recon/edgesynth.py)

Per room, at the truth's camera: the profile detector's offset of every room-edge sample (photo edge -
projected taped edge, px along the projected normal), and the offset the same detector finds on the
synthetic photo (recon/edgesynth: the photo's own per-face radiance and noise at the box-filtered faces),
noisy (the mean over the draws) and noise-free. Per edge (median over its samples found in both): the
correlation r of the photo's offsets with the predicted ones, the least-squares slope through 0, and the
rms per-edge offset before and after subtracting the prediction; the lean toward the bright side (mean of
the per-edge offsets signed by the polarity) before and after.

`python bench/bench_edgebias.py [--rooms DIR] [--only sun_101,...] [--draws 16] [--noise empirical|gaussian]
[--json OUT]`; MARGIN=k in the environment reads the faces' levels k px inside their outlines.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

UNSEEN = [f"{k}_{s}" for k in ("window", "lamps", "sun") for s in (101, 102, 103)]


def run_room(root: Path, draws: int) -> dict:
    from bench.own_room_flow import tape_room
    from recon import assemble as asm
    from recon.camera import Camera
    from recon.camrefine import _exclusive, _Occluder, _project, _sample_edges, room_edges, room_faces
    from recon.edgesnap import EdgeImage
    from recon.edgesynth import EdgeSynth, edge_leans_and_scatter
    from recon.io import read_image_rgb
    from recon.photoedges import PhotoEdges

    sc = json.loads((root / "scene.json").read_text())
    truth = Camera.load(root / "scene.json")
    img = read_image_rgb(root / "background.png")
    prims, _, _ = asm.parse_primitives(tape_room(sc), "room")
    faces = room_faces(prims)
    occ = _Occluder(faces)
    S = _sample_edges(truth, room_edges(faces), occ)
    uv, n = _project(truth, S)
    photo = PhotoEdges(img)
    q, ok = photo.subpixel(uv, n)
    ok &= _exclusive(uv, n, S.edge, q)
    d = np.sum((q - uv) * n, axis=1)
    E = photo.fine
    g = E._sample(E.gx, uv[None])[0] * n[:, 0] + E._sample(E.gy, uv[None])[0] * n[:, 1]
    synth = EdgeSynth(truth, occ, len(faces), img)
    lean, scatter = edge_leans_and_scatter(synth, E.near_clip, uv, n, S.edge, draws=draws)
    pe = PhotoEdges.__new__(PhotoEdges)  # noise-free synthetic: the detector's lean without grain
    pe.fine = EdgeImage(synth.image(None))
    pe.fine.near_clip = E.near_clip
    qc, okc = pe.subpixel(uv, n)
    p_clean = np.where(okc, np.sum((qc - uv) * n, axis=1), np.nan)
    rows = []
    for e in np.unique(S.edge):
        m = (S.edge == e) & ok
        if m.sum() < 3 or int(e) not in lean:
            continue
        pol = float(np.sign(np.median(g[m])))
        mc = m & np.isfinite(p_clean)
        rows.append({"edge": int(e), "n": int(m.sum()), "photo": float(np.median(d[m])), "pred": lean[int(e)],
                     "resid": float(np.median(d[m]) - lean[int(e)]),
                     "clean": float(np.median(p_clean[mc])) if mc.sum() >= 3 else float("nan"), "polarity": pol,
                     "scatter": scatter[int(e)]})
    return {"room": root.name, "edges": rows}


def summary(r: dict) -> str:
    E = r["edges"]
    if len(E) < 2:
        return f"{r['room']}: {len(E)} edges"
    ph, pr, rs = (np.array([e[k] for e in E]) for k in ("photo", "pred", "resid"))
    cl = np.array([e["clean"] for e in E])
    pol = np.array([e["polarity"] for e in E])
    rr = float(np.corrcoef(ph, pr)[0, 1])
    slope = float(ph @ pr / max(pr @ pr, 1e-12))
    fc = np.isfinite(cl)
    rc = float(np.corrcoef(ph[fc], cl[fc])[0, 1]) if fc.sum() > 2 else float("nan")
    rms = lambda a: float(np.sqrt(np.mean(a ** 2)))  # noqa: E731
    sc = np.array([e["scatter"] for e in E])
    fz = np.isfinite(sc) & (sc > 0)
    z = f"; residual / predicted scatter rms {rms(rs[fz] / sc[fz]):.2f} (median scatter {np.median(sc[fz]):.2f} px)" \
        if fz.any() else ""
    return (f"{r['room']}: {len(E)} edges; r(photo, predicted) {rr:+.2f} (noise-free {rc:+.2f}), slope {slope:.2f}; "
            f"rms per-edge offset {rms(ph):.2f} -> {rms(rs):.2f} px (noise-free subtracted {rms(ph[fc] - cl[fc]):.2f}); "
            f"lean to bright {np.mean(ph * pol):+.2f} -> {np.mean(rs * pol):+.2f} px (predicted {np.mean(pr * pol):+.2f}, "
            f"noise-free {np.mean(cl[fc] * pol[fc]):+.2f})" + z)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rooms", type=Path, default=Path(os.environ.get("PHOTOAR_ROOMS",
                                                                      Path.home() / ".cache/photoar/rooms")))
    ap.add_argument("--only", default=",".join(UNSEEN))
    ap.add_argument("--draws", type=int, default=16)
    ap.add_argument("--json", type=Path)
    ap.add_argument("--noise", default="empirical", help="edgesynth's noise model: empirical or gaussian")
    a = ap.parse_args()
    import recon.edgesynth as es

    es.NOISE = a.noise
    es.MARGIN_PX = int(os.environ.get("MARGIN", es.MARGIN_PX)); es._DISK = np.ones((2 * es.MARGIN_PX + 1,) * 2, np.uint8)
    out = []
    for name in a.only.split(","):
        r = run_room(a.rooms / name, a.draws)
        out.append(r)
        print(summary(r), flush=True)
        if a.json:
            a.json.write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
