"""The floor's B / (G_c B) under captured and known light, patch by patch (issue 34; branch sun108; a diagnosis).

usage: python bench/bench_sun108_gather.py BENCH_ROOM WORK
  (WORK: a room's work folder that bench/bench_sun108.py kept: room_true_cam, in/object.ply, cache)

Runs composite under captured light (WORK/room_true_cam) and under known light (BENCH_ROOM) with
SunSetup.apply wrapped to keep the precompute, matches the floor's patches by centre, and prints on the floor's
unlit patches: captured / known B and E_ind = G_c B[-1], the median B / E_ind of each, the irradiance the floor
gathers per source surface, the known patch albedo (all / unlit / sunlit), and known light's bounce truncation
(G_c B[-2] / G_c B[-1]). Output is plain lines, not a table.
"""
import json
import sys
from pathlib import Path

import numpy as np
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import app.stages.sun as st
from bench.own_room_flow import _composite_argv, _photoar, object_pose
from lighting.sources import luminance
bench_room, work = Path(sys.argv[1]), Path(sys.argv[2])
got = {}
orig = st.SunSetup.apply
def apply(self, pre, rm, device):
    got[self.lighting] = (pre, self.scene)
    return orig(self, pre, rm, device)
st.SunSetup.apply = apply
truth = json.loads((bench_room / "scene.json").read_text())
place, yaw = object_pose(truth, bench_room / truth["synthetic_object"]["mesh"])
inp = {"mesh": work / "in" / "object.ply", "place": place, "yaw": yaw, "albedo": truth["synthetic_object"]["albedo"]}
rc, err, _ = _photoar(_composite_argv(work / "room_true_cam", work / "out_bvse", inp, "captured", work / "cache"))
rc2, err2, _ = _photoar(["composite", str(bench_room), "--out", str(work / "out_bvse_known"), "--lighting", "known", "--cache", str(work / "cache")])
print(rc, err, rc2, err2)
def floor(pre, scene):
    pm = pre.patches
    q = [i for i, qq in enumerate(scene.quads) if qq.name == "floor"][0]
    sel = np.flatnonzero(pm.quad == q)
    c = pm.corners[sel].mean(1)
    B = np.asarray(pre.B[-1], float); E = np.asarray(pre.G_c, float) @ B
    return sel, c, B[sel], E[sel]
sc, cc, Bc, Ec = floor(*got["captured"])
sk, ck, Bk, Ek = floor(*got["known"])
print("floor patches", len(sc), len(sk))
# match by centre
d = np.linalg.norm(cc[:, None] - ck[None], axis=2); j = d.argmin(1); ok = d[np.arange(len(j)), j] < 1e-3
pmc = got["captured"][0].patches
lit = np.asarray(pmc.is_emitter)[sc]  # flagged sunlit patches in the capture
m = ok & ~lit & (luminance(Ek[j]) > 0)
rB = luminance(Bc[m]) / luminance(Bk[j][m]); rE = luminance(Ec[m]) / luminance(Ek[j][m])
print("matched unlit", m.sum(), "B capt/known median", np.median(rB).round(3), "E_ind capt/known median", np.median(rE).round(3),
      "rho known median", np.median(luminance(Bk[j][m]) / luminance(Ek[j][m])).round(3), "rho capt", np.median(luminance(Bc[m]) / luminance(Ec[m])).round(3))
# what does the floor gather from: split E_ind by source quad
for lab, (pre, scene) in (("capt", got["captured"]), ("known", got["known"])):
    pm = pre.patches; B = np.asarray(pre.B[-1], float); G = np.asarray(pre.G_c, float)
    s, c, _, _ = floor(pre, scene)
    if lab == "capt": s = s[m]
    else: s = s[j][m]
    parts = {}
    for qi, qq in enumerate(scene.quads):
        cols = pm.quad == qi
        v = luminance(G[np.ix_(s, np.flatnonzero(cols))] @ B[cols]).mean()
        key = qq.name.split(".")[0]
        parts[key] = parts.get(key, 0) + v
    print(lab, {k: round(float(v), 4) for k, v in sorted(parts.items(), key=lambda x: -x[1])[:8]})
pre_k, scene_k = got["known"]
pmk = pre_k.patches
ak = luminance(np.asarray(pmk.albedo, float)[sk])
Bk_all = np.asarray(pre_k.B[-1], float); Ek_all = np.asarray(pre_k.G_c, float) @ Bk_all
rk = luminance(Bk_all[sk]) / np.maximum(luminance(Ek_all[sk]), 1e-12)
litk = np.zeros(len(sk), bool); litk[j[ok & lit]] = True
print("known patch albedo floor: all mean", ak.mean().round(3), "median", np.median(ak).round(3),
      "| unlit mean", ak[~litk].mean().round(3), "median", np.median(ak[~litk]).round(3),
      "| lit (capture-flagged) mean", ak[litk].mean().round(3), "median", np.median(ak[litk]).round(3), "n", litk.sum())
print("known B/E_ind vs patch albedo (unlit, median ratio)", np.median(rk[~litk] / ak[~litk]).round(3))
Bs = np.asarray(pre_k.B, float)
print("known bounces", Bs.shape[0] - 1, "floor unlit median B[-2]/B[-1] gathered:",
      np.nanmedian(luminance((np.asarray(pre_k.G_c, float) @ Bs[-2])[sk][~litk]) / luminance(Ek_all[sk][~litk])).round(3), "B[-2]/B[-1] floor", np.nanmedian(luminance(Bs[-2][sk][~litk]) / luminance(Bs[-1][sk][~litk])).round(3), "isnan", np.isnan(Bs).sum())
pre_c, _ = got["captured"]
print("captured B iterates", np.asarray(pre_c.B).shape[0], "capt albedo floor unlit median", np.median(luminance(np.asarray(pre_c.patches.albedo, float)[sc][~lit])).round(3))
