"""The sunlit outline's measurement bias at the truth's camera and sun (issue 34 item 6; branch outline108).

usage: python bench/bench_outline108_bias.py --rooms ~/.cache/photoar/rooms_full --only sun_101,...,sun_107

Per room (the own-room flow's inputs as bench/bench_outline108.py builds them) and per outline edge that
recon/sunoutline.SunEdges measures at the truth's camera: its offset (px, positive towards the lit side; 0 for an
unbiased measurement) with the clip fraction f_c fitted to the photo (the product's), its jackknife, and the offset
with f_c = (1 - rest) / (lit - rest) read off the linear render (background.exr scaled to the photo's clip units
by the median ratio over unclipped pixels; lit: the render 3-8 px beyond the boundary on the lit side).
"""
from __future__ import annotations

import argparse
import inspect
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def _probe_measure_edges():
    """A copy of sunoutline.measure_edges that also records, per edge, the offsets at every f_c of its grid and
    the cost; returns (the function, the list it appends to)."""
    import recon.sunoutline as so

    rec: list = []
    src = inspect.getsource(so.measure_edges).replace(
        "j = int(np.argmin(cost))",
        "j = int(np.argmin(cost)); _REC.append(dict(e=int(e), cost=cost, u=u, nn=nn, bs=bs, rest=rest, "
        "offs=np.array([_tmean(b - M[:, jj]) for jj in range(len(FC_GRID))])))")
    ns = dict(so.__dict__, _REC=rec)
    exec(src, ns)
    return ns["measure_edges"], rec


def room(root: Path) -> list[dict]:
    import recon.sunoutline as so
    from bench.own_room_flow import sunlit_room
    from recon.camera import Camera
    from recon.camrefine import _Occluder, _sun_edges, room_faces
    from recon.io import read_exr, read_image_rgb

    sc, prims, _, _, sun, g = sunlit_room(root)
    cam = Camera.load(root / "scene.json")
    img = read_image_rgb(root / "background.png")
    se = _sun_edges(sun, g, prims, _Occluder(room_faces(prims)), img)
    ex = np.asarray(read_exr(root / "background.exr"), float)[:, :, :3].max(axis=2)
    m = (se.lin > 0.3) & (se.lin < 0.9)
    k = float(np.median(se.lin[m] / np.maximum(ex[m], 1e-9)))
    probe, rec = _probe_measure_edges()
    orig = so.measure_edges
    so.measure_edges = probe
    try:
        o = se.measure(cam)
    finally:
        so.measure_edges = orig
    out = []
    for d, info in zip(rec, o.info):
        far = d["u"][:, None] + (d["bs"][:, None] + np.linspace(3, 8, 6)[None])[..., None] * d["nn"][:, None]
        lit = float(np.median(so._bilinear(ex * k, far.reshape(-1, 2))))
        fc = (1 - d["rest"]) / (lit - d["rest"])
        j, jt = int(np.argmin(d["cost"])), int(np.argmin(np.abs(so.FC_GRID - fc)))
        out.append({"kind": info["kind"], "edge": d["e"], "offset_px": float(d["offs"][j]),
                    "jackknife_px": info["jackknife_px"], "f_c": float(so.FC_GRID[j]), "f_c_render": fc,
                    "offset_render_fc_px": float(d["offs"][jt])})
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rooms", required=True)
    ap.add_argument("--only", required=True)
    a = ap.parse_args(argv)
    for name in a.only.split(","):
        for e in room(Path(a.rooms).expanduser() / name):
            print(f"{name} {e['kind']:7s} edge {e['edge']:2d}: offset {e['offset_px']:+.2f} px (jackknife "
                  f"{e['jackknife_px']:.2f}, f_c {e['f_c']:.2f}); with the render's f_c {e['f_c_render']:.2f}: "
                  f"{e['offset_render_fc_px']:+.2f} px", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
