"""Where captured light's wall glow in a sun room parts from known light's (issue 34, docs/unseen.md "glow110b").

usage: python bench/bench_glow110b.py terms|blocked|sunlit ROOM_DIR

All three load the room's engine under known and then captured light (one at a time, the declared sun) and
print known against captured:
- terms: one all-sources HDR frame, per place (bench_sun_energy.places) the sum over the receiver pixels of
  term / E_x (luminance): the object's first pass R_pix, the shadow pass's listed pixels O_pix (the filled ones
  not counted), the second order's parts (rho R_cen room / sun, the rest of dB: the shadows and the sun's later
  bounces, added there), and dE_more (the blocked pairs). The response's slope at L_b is the same under both
  lights on sun_109 (59.2 levels per ln L on the walls), so these are the levels' ratios.
- blocked: what the object hides from the walls' and the floor's receiver vertices, by source group (the
  sunlit patches, emitters, the other floor, the rest): Engine._blocked_second_order of B_src masked per group,
  over E_v.
- sunlit: per sunlit patch B_src under both lights, captured light's origin (0 gathered, 1 probe, 2 photo),
  ranked by its transfer to the wall vertices; the wall-weighted sums by origin.
Engine.captured_sun_sources (class attribute) is left as it is: set PHOTOAR_GLOW_SOURCES=off for main's sources.
"""
from __future__ import annotations

import dataclasses
import os
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))
L = np.array([0.2126, 0.7152, 0.0722])

def terms(room: Path) -> None:
    """Wall/floor terms of one all-sources HDR frame, known vs captured: sum over the place's receiver pixels of (term luminance / E_x luminance), i.e. relative change, which the same response slope turns into levels."""
    from bench_sun_energy import places
    from app.composite import default_cache_dir
    from app.engine import Engine, EngineParams
    from recon.scene import load_scene
    selfl = False
    s = load_scene(room)
    for lighting in ("known", "captured"):
        e = Engine(s, EngineParams(lighting=lighting, sun="declared"), cache_dir=default_cache_dir(), quiet=True)
        e.object_self_light = selfl
        cap = {}
        f0, so0 = e.compose.frame, e.compose.second_order
        def fr(mode, pix_sel, O_pix, fill_sel, fill, R_pix, dE_v, cov, obj_rad, sun_pix=None, sun_loss=None):
            cap.update(pix_sel=np.asarray(pix_sel), O_pix=np.array(O_pix), n_fill=len(fill_sel), R=np.array(R_pix),
                       dE=np.array(dE_v), sun_pix=sun_pix, sun_loss=None if sun_loss is None else np.array(sun_loss))
            return f0(mode, pix_sel, O_pix, fill_sel, fill, R_pix, dE_v, cov, obj_rad, sun_pix, sun_loss)
        def so(dB, more=None, dE_more=None):
            cap.update(dB=np.array(dB), dE_more=None if dE_more is None else np.array(dE_more))
            return so0(dB, more=more, dE_more=dE_more)
        e.compose.frame, e.compose.second_order = fr, so
        # R_cen split
        ol0 = e._object_light
        def olw(*a, **k):
            out = ol0(*a, **k); cap.update(R_cen=np.array(out[1]), R_cen_sun=None if out[2] is None else np.array(out[2])); return out
        e._object_light = olw
        e.render(s.obj, dataclasses.replace(e.frame_config(), passes=None, mode="hdr"))
        r, pre, pm = e.receivers, e.pre, e.pre.patches
        where, mask = places(e, room)
        Ex = np.maximum(r.E_x @ L, 1e-9)
        Gv = np.asarray(pre.G_v)
        def at_pix(v):  # (Vr,3) -> (N,) luminance at receiver pixels
            out = np.zeros(len(Ex)); rp = r.recv_pix
            out[rp] = np.einsum("nk,nk->n", pre.pix_bary[rp], (v @ L)[r.pix_rows[rp]]); return out
        O = np.zeros(len(Ex)); O[cap["pix_sel"]] = cap["O_pix"] @ L
        dB = cap["dB"]; Rc = cap["R_cen"]; Rs = cap["R_cen_sun"] if cap["R_cen_sun"] is not None else 0 * Rc
        alb = pm.albedo
        parts = {"R_pix": cap["R"] @ L, "O_pix(-)": -O,
                 "so: alb R_cen_room": at_pix(Gv @ (alb * (Rc - Rs))), "so: alb R_cen_sun": at_pix(Gv @ (alb * Rs)),
                 "so: rest of dB (shadows)": at_pix(Gv @ (dB - alb * Rc)),
                 "later+blk (dE_more)": at_pix(cap["dE_more"]) if cap["dE_more"] is not None else 0 * Ex,
                 "dE total": at_pix(cap["dE"])}
        print(f"{room.name} {lighting} self={selfl}: n_fill {cap['n_fill']} (not counted), R_cen_sun sum {float((Rs@L).sum()):.4g}, R_cen room {float(((Rc-Rs)@L).sum()):.4g}")
        for place in ("walls", "floor < 0.3 m", "floor 0.3-1 m"):
            m = where[place].reshape(-1) & r.recv_pix
            print(f"  {place:14s} " + "  ".join(f"{k} {float((v[m] / Ex[m]).sum()):.1f}" for k, v in parts.items()))
        del e

def blocked(room: Path) -> None:
    """What the object blocks from the wall/floor receiver vertices, by source group, known vs captured: the blocked second-order pass (Engine._blocked_second_order) of B_src masked per group, relative to E_v."""
    from bench_sun_energy import places
    from app.composite import default_cache_dir
    from app.engine import Engine, EngineParams
    from recon.scene import load_scene
    s = load_scene(room)
    for lighting in ("known", "captured"):
        e = Engine(s, EngineParams(lighting=lighting, sun="declared"), cache_dir=default_cache_dir(), quiet=True)
        cap = {}
        b0 = e._blocked_second_order
        def bw(dB, proxy_occ, pv):
            cap.update(occ=proxy_occ, pv=pv); return b0(dB, proxy_occ, pv)
        e._blocked_second_order = bw
        e.render(s.obj, dataclasses.replace(e.frame_config(), passes=None, mode="hdr"))
        r, pre, pm = e.receivers, e.pre, e.pre.patches
        where, _ = places(e, room)
        B = e.B_src
        lit = e.sun.patch_light().any(1)
        rmin = np.asarray(e.scene.room_min, float)
        fl = np.abs(pm.centre[:, 1] - rmin[1]) < 1e-3
        groups = {"sunlit": lit, "emitters": pm.is_emitter & ~lit, "floor other": fl & ~lit & ~pm.is_emitter,
                  "rest": ~fl & ~lit & ~pm.is_emitter}
        Ev = np.maximum(r.E_v @ L, 1e-9)
        # receiver vertices of wall pixels
        print(f"{room.name} {lighting}: emitters {int(pm.is_emitter.sum())}, sunlit {int(lit.sum())}, sunlit&emitter {int((lit&pm.is_emitter).sum())}, "
              f"B_src sunlit mean {float((B[lit]@L).mean()):.4g}, emitters B sum*area {float((B[pm.is_emitter]@L) @ pm.area[pm.is_emitter]):.4g}")
        for place in ("walls", "floor 0.3-1 m"):
            m = where[place].reshape(-1) & r.recv_pix
            rows = np.unique(r.pix_rows[m].reshape(-1))
            out = []
            for g, gm in groups.items():
                blk = e._blocked_second_order(np.where(gm[:, None], B, 0.0), cap["occ"], cap["pv"])
                blk = np.zeros(len(Ev)) if blk is None else blk @ L
                out.append(f"{g} {float((blk[rows] / Ev[rows]).sum()):.2f}")
            print(f"  {place} ({len(rows)} vertices): " + "  ".join(out) + f"  | E_v mean {float(Ev[rows].mean()):.4g}")
        del e

def sunlit(room: Path) -> None:
    """Per sunlit patch: B_src known vs captured, its origin under captured, its sun share, weight to the walls."""
    from bench_sun_energy import places
    from app.composite import default_cache_dir
    from app.engine import Engine, EngineParams
    from recon.scene import load_scene
    s = load_scene(room)
    res = {}
    for lighting in ("known", "captured"):
        e = Engine(s, EngineParams(lighting=lighting, sun="declared"), cache_dir=default_cache_dir(), quiet=True)
        pm, r = e.pre.patches, e.receivers
        where, _ = places(e, room)
        sl = e.sun.patch_light()
        m = where["walls"].reshape(-1) & r.recv_pix
        rows = np.unique(r.pix_rows[m].reshape(-1))
        wgt = np.asarray(e.pre.G_v)[rows].sum(0)
        oc = np.asarray(e.object_centre) if hasattr(e, "object_centre") else s.obj.vertices.mean(0)
        res[lighting] = dict(B=e.B_src @ L, sun=sl @ L, alb=pm.albedo @ L, origin=np.asarray(e.pre.origin), w=wgt,
                             d=np.linalg.norm(pm.centre - oc, axis=1))
        del e
    k, c = res["known"], res["captured"]
    lit = k["sun"] > 0
    print("patch  dist  w_walls  sun  B_known  B_capt  ratio  origin_capt  alb_known alb_capt  capt_alb*(sun)")
    idx = np.flatnonzero(lit)
    idx = idx[np.argsort(-(k["w"][idx] * k["B"][idx]))][:25]
    for i in idx:
        print(f"{i:5d} {k['d'][i]:.2f} {k['w'][i]:.4f} {k['sun'][i]:.3f} {k['B'][i]:.3f} {c['B'][i]:.3f} {c['B'][i]/k['B'][i]:.3f} {c['origin'][i]} "
              f"{k['alb'][i]:.3f} {c['alb'][i]:.3f}")
    W = k["w"][lit]
    print("wall-weighted sum B: known", float(W @ k["B"][lit]), "captured", float(W @ c["B"][lit]), "ratio",
          float(W @ c["B"][lit]) / float(W @ k["B"][lit]))
    for o in np.unique(c["origin"][lit]):
        mm = lit & (c["origin"] == o)
        print("origin", o, int(mm.sum()), "weighted ratio", float(k["w"][mm] @ c["B"][mm]) / max(float(k["w"][mm] @ k["B"][mm]), 1e-12))

def main() -> None:
    from app.engine import Engine

    if len(sys.argv) != 3 or sys.argv[1] not in ("terms", "blocked", "sunlit"):
        sys.exit(__doc__)
    Engine.captured_sun_sources = os.environ.get("PHOTOAR_GLOW_SOURCES", "on") != "off"
    {"terms": terms, "blocked": blocked, "sunlit": sunlit}[sys.argv[1]](Path(sys.argv[2]))


if __name__ == "__main__":
    main()
