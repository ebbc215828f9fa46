"""The captured-light sun strength of one room, term by term (issue 34; branch sun108).

usage: python bench/bench_sun108_strength.py BENCH_ROOM SCENE_ROOM WORK
  e.g. ~/.cache/photoar/rooms_full/sun_104 RESULTS/work/sun_104/room_true_cam RESULTS/work/sun_104

Runs `photoar composite SCENE_ROOM --lighting captured` (SCENE_ROOM: a `scene` folder that bench_sun108.py kept;
WORK: its work folder, whose in/object.ply and cache are used) with lighting.sun._sun_strength wrapped, and
prints per sunlit surface the terms of its strength estimate E_perp = pi (B / rho - E_ind) / cos (median over the
surface's fully sunlit patches; B the radiance mesh, E_ind = G_c B): rho from the surface's unlit patches (median
of B / E_ind there; also their spread, nearer / farther half from the sunlit patches, and sum B / sum E_ind)
against the truth's albedo (BENCH_ROOM/scene.json, matched by name prefix), and the strength with each rho as a
ratio to the truth's sun (luminance).
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    bench_room, room, work = Path(argv[0]), Path(argv[1]), Path(argv[2])
    import lighting.sun as ls
    from bench.own_room_flow import _composite_argv, _photoar, object_pose
    from lighting.sources import luminance

    truth = json.loads((bench_room / "scene.json").read_text())
    true_sun = next(p for p in truth["primitives"] if p["type"] == "sun")
    albedo = {p["name"]: np.asarray(p["albedo"], float) for p in truth["primitives"] if "albedo" in p}
    got: dict = {}
    orig = ls._sun_strength

    def wrapped(d, holes, occluder, pm, B, G_c, info):
        got.update(d=d, pm=pm, B=np.asarray(B, float), G_c=np.asarray(G_c, float), holes=holes, occ=occluder)
        return orig(d, holes, occluder, pm, B, G_c, info)

    ls._sun_strength = wrapped
    import app.stages.sun as st

    orig_est = st.estimate_sun

    def est(scene, *a, **k):
        got["scene"] = scene
        return orig_est(scene, *a, **k)

    st.estimate_sun = est
    inp_dir = work / "in"
    mesh = inp_dir / "object.ply"
    place, yaw = object_pose(truth, bench_room / truth["synthetic_object"]["mesh"])
    inp = {"mesh": mesh, "place": place, "yaw": yaw, "albedo": truth["synthetic_object"]["albedo"]}
    rc, err, _ = _photoar(_composite_argv(room, work / "out_strength", inp, "captured", work / "cache"))
    if rc != 0 or not got:
        print(f"composite failed ({rc}): {err}")
        return 1
    d, pm, B, G_c = got["d"], got["pm"], got["B"], got["G_c"]
    light = ls.SunLight(ls.Sun(d, ls.SUN_DIAMETER_DEG, np.full(3, np.pi), np.zeros(3)), got["holes"], got["occ"],
                        where="diag")
    e = light.patch_irradiance(pm.corners, pm.normal, ~pm.is_emitter)[:, 0]
    cos = np.maximum(pm.normal @ d, 0.0)
    full = (e > 0.98 * cos) & (cos > 0.2)
    E_ind = G_c @ B
    with np.errstate(divide="ignore", invalid="ignore"):
        rho_all = np.where(E_ind > 0, B / E_ind, 0.0)
    qnames = [q.name for q in got["scene"].quads]
    E_true = float(luminance(np.asarray(true_sun["irradiance_perpendicular"], float)))
    print(f"truth's sun: E_perp lum {E_true:.3f}")
    print("| quad | n full | n unlit | rho est (lum) | truth albedo (lum) | E_perp est rho / truth | "
          "B lit (lum) | E_ind lit (lum) |")
    for q in np.unique(pm.quad[full]):
        unlit = (pm.quad == q) & (e == 0) & ~pm.is_emitter & (luminance(E_ind) > 0)
        on = full & (pm.quad == q)
        name = qnames[q]
        if unlit.sum() < 3:
            print(f"| {name} | {on.sum()} | {unlit.sum()} | (skipped) |")
            continue
        rho = np.median(rho_all[unlit], axis=0)
        s = np.median(np.pi * (B[on] / rho - E_ind[on]) / cos[on, None], axis=0)
        tname = next((k for k in albedo if name.startswith(k)), None)
        ta = albedo.get(tname)
        st = (np.median(np.pi * (B[on] / ta - E_ind[on]) / cos[on, None], axis=0) if ta is not None else None)
        print(f"| {name} | {on.sum()} | {unlit.sum()} | {float(luminance(rho)):.3f} | "
              f"{'-' if ta is None else f'{float(luminance(ta)):.3f}'} | {float(luminance(s)) / E_true:.3f}x / "
              f"{'-' if st is None else f'{float(luminance(st)) / E_true:.3f}x'} | "
              f"{float(luminance(np.median(B[on], 0))):.3f} | {float(luminance(np.median(E_ind[on], 0))):.3f} |")
        r = luminance(rho_all[unlit])
        cen = pm.corners.mean(1)
        dist = np.min(np.linalg.norm(cen[unlit][:, None] - cen[on][None], axis=2), axis=1)
        near = dist < np.median(dist)
        print(f"    unlit rho (lum): mean {r.mean():.3f}, quartiles {np.percentile(r, 25):.3f} / "
              f"{np.percentile(r, 75):.3f}; nearer half {np.median(r[near]):.3f}, farther half "
              f"{np.median(r[~near]):.3f}; sum B / sum E_ind {float(luminance(B[unlit].sum(0) / E_ind[unlit].sum(0))):.3f}; "
              f"capture's albedo (median) {float(luminance(np.median(pm.albedo[unlit], 0))):.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
