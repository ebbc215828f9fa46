"""The sunlit object's first-pass light on the room (its "glow"), ours against a brute-force gather (issue 34).

usage: python bench/bench_sunglow110.py ROOM_DIR [ROOM_DIR ...] [--n 200] [--rays 1024] [--face-rays 128]

Per room (known light, the benchmark folder's own scene) this renders the all-sources frame once, keeping what
the engine hands ObjectLight.light: the proxy (pv, pf), the room-lit radiance of its faces (room_tri_rad, from
triangle_radiance) and, after SunStage.object_emitters, the faces' radiance with the sun (tri_rad) and the lit
pieces (extra). At receiver pixels sampled by place (bench_sun_energy.places: floor < 0.3 m, 0.3-1 m, walls;
`--n` a place, seeded) it then sums, as irradiance/pi (the engine's R units), luminance:

- ours: ObjectLight.light of the sun's part alone (tri_rad - room_tri_rad with the pieces) and of the room's part
  alone (room_tri_rad, no pieces); the sum is linear in the radiance.
- proxy ref: a cosine-weighted gather (`--rays` a pixel, Open3D RaycastingScene over the room's patch triangles and
  the proxy): an object hit takes the hit face's room_tri_rad plus albedo E_perp x the sun's visibility at the
  hit point (SunLight.visibility: cos, the openings' disk share, the room and the proxy in the way). Tests the
  sum (form factors, visibility, the pieces) on the same emitters.
- true ref: the same gather from the true object mesh (scene.obj), its sun at each hit point against the true
  mesh, its room light per true face from `--face-rays` cosine rays off the face's centroid into the room: a
  patch hit takes B_obj of the patch with its sun part (rho x patch_light) replaced by rho E_perp x the sun's
  visibility at the hit point past the true object (its own shadow on the floor, exact); an object hit 0 here.
  Tests the proxy (its sunlit area and the room light of its faces near the floor).
- the object's own interreflection: the true faces' rays that hit the object itself carry the hit face's sun and
  room light back (self_light: two bounces, as ObjectLight.self_light), gathered at the pixels as the true ref
  ("true ref with it"); main's first pass left it out. Ours with it: ObjectLight.self_light of the proxy's room
  and sun (face averages, SunStage.face_sun) summed by ObjectLight.light, against the same cosine gather's self
  hits on the proxy (printed as power x area).
The columns "ours" are main's first pass (the frame's emitters before self_light is added); the last column adds
ours' self_light.

All sums are over the sampled pixels; ratios ours / ref. Deterministic up to the Monte Carlo's seed (fixed).
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

LUMA = np.array([0.2126, 0.7152, 0.0722])


def cosine_dirs(normals: np.ndarray, k: int, rng) -> np.ndarray:
    """(N,k,3) cosine-weighted unit directions about each unit normal (N,3) (stratified in sqrt(k) x sqrt(k))."""
    s = int(np.ceil(np.sqrt(k)))
    i, j = np.meshgrid(np.arange(s), np.arange(s), indexing="ij")
    u = (i.reshape(-1)[:k][None] + rng.random((len(normals), k))) / s
    v = (j.reshape(-1)[:k][None] + rng.random((len(normals), k))) / s
    r, phi = np.sqrt(u), 2 * np.pi * v
    loc = np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(np.maximum(1 - u, 0.0))], -1)
    n = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    a = np.where(np.abs(n[:, :1]) < 0.9, np.array([[1.0, 0, 0]]), np.array([[0, 1.0, 0]]))
    t = np.cross(n, a)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    b = np.cross(n, t)
    return loc[..., :1] * t[:, None] + loc[..., 1:2] * b[:, None] + loc[..., 2:] * n[:, None]


class Gather:
    """Open3D ray casts against the room's patch triangles (geometry 0) and an object mesh (geometry 1)."""

    def __init__(self, pm, v: np.ndarray, f: np.ndarray):
        import open3d as o3d

        self.o3d = o3d
        self.sc = o3d.t.geometry.RaycastingScene()
        for vv, ff in ((pm.vert_pos, pm.tris), (v, f)):
            m = o3d.t.geometry.TriangleMesh()
            m.vertex.positions = o3d.core.Tensor(np.asarray(vv, np.float32))
            m.triangle.indices = o3d.core.Tensor(np.asarray(ff, np.int32))
            self.sc.add_triangles(m)

    def cast(self, org: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(geometry id (-1 miss), primitive id, t) per ray; org (N,3), dirs (N,3)."""
        out = self.sc.cast_rays(self.o3d.core.Tensor(np.concatenate([org, dirs], 1).astype(np.float32)))
        g = out["geometry_ids"].numpy().astype(np.int64)
        g[~np.isfinite(out["t_hit"].numpy())] = -1
        return g, out["primitive_ids"].numpy().astype(np.int64), out["t_hit"].numpy().astype(np.float64)


def face_normals(v: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    t = v[f]
    c = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    a = np.linalg.norm(c, axis=1)
    return c / np.maximum(a, 1e-30)[:, None], 0.5 * a


def reference(e, gather: Gather, v, f, face_room: np.ndarray, occ, pts, nrm, rays: int, rng, chunk=64):
    """(sun (N,), room (N,), object hits share) luminance irradiance/pi at points pts (N,3) from the object
    mesh (v, f) in `gather`: per hit its face's room light face_room (F,3) and the sun at the hit point."""
    fn, _ = face_normals(v, f)
    light = e.sun.light
    alb = np.asarray(e.scene.obj.albedo, float)
    sun_out, room_out = np.zeros(len(pts)), np.zeros(len(pts))
    Eperp = light.sun.irradiance / np.pi
    for a in range(0, len(pts), chunk):
        p, n = pts[a:a + chunk], nrm[a:a + chunk]
        d = cosine_dirs(n, rays, rng)
        org = np.repeat(p + 1e-3 * n, rays, 0)
        g, prim, t = gather.cast(org, d.reshape(-1, 3))
        hit = g == 1
        hp = org[hit] + t[hit, None] * d.reshape(-1, 3)[hit]
        hf = prim[hit]
        vis = light.visibility(hp, fn[hf], extra=[occ], disk=True)
        L_sun = (alb * Eperp) @ LUMA * vis
        L_room = face_room[hf] @ LUMA
        row = np.repeat(np.arange(len(p)), rays)[hit]
        sun_out[a:a + chunk] = np.bincount(row, L_sun, len(p)) / rays
        room_out[a:a + chunk] = np.bincount(row, L_room, len(p)) / rays
    return sun_out, room_out


def true_face_room(e, gather: Gather, v, f, occ, face_rays: int, rng, chunk=256) -> tuple[np.ndarray, float]:
    """(F,3) room light albedo x E_room/pi of each true face (cosine gather off its centroid), and the share of
    those rays that hit the object itself (left at 0)."""
    pm = e.pre.patches
    fn, _ = face_normals(v, f)
    cen = v[f].mean(1)
    B = np.asarray(e.B_obj, np.float64)
    pl = e.sun.patch_light()
    B_nosun = B - pm.albedo * pl
    light = e.sun.light
    Eperp = light.sun.irradiance / np.pi
    alb = np.asarray(e.scene.obj.albedo, float)
    out = np.zeros((len(f), 3))
    self_hits = 0
    pairs = []
    for a in range(0, len(f), chunk):
        p, n = cen[a:a + chunk], fn[a:a + chunk]
        d = cosine_dirs(n, face_rays, rng).reshape(-1, 3)
        org = np.repeat(p + 1e-4 * n, face_rays, 0)
        g, prim, t = gather.cast(org, d)
        self_hits += int((g == 1).sum())
        own = g == 1
        pairs.append((a + np.repeat(np.arange(len(p)), face_rays)[own], prim[own]))
        room = g == 0
        pid = pm.tri_patch[prim[room]]
        hp = org[room] + t[room, None] * d[room]
        lit = pl[pid].any(1)
        L = B[pid].copy()
        if lit.any():
            vis = light.visibility(hp[lit], pm.normal[pid[lit]], extra=[occ], disk=True)
            L[lit] = B_nosun[pid[lit]] + pm.albedo[pid[lit]] * (vis[:, None] * Eperp)
        row = np.repeat(np.arange(len(p)), face_rays)[room]
        for c in range(3):
            out[a:a + chunk, c] = np.bincount(row, L[:, c], len(p)) / face_rays
    e._glow_self_pairs = (np.concatenate([q[0] for q in pairs]), np.concatenate([q[1] for q in pairs]), face_rays)
    return alb * out, self_hits / (len(f) * face_rays)


def self_light(e, L_direct: np.ndarray, bounces: int = 2) -> np.ndarray:
    """(F,3) the light the object's faces get from the object itself (its interreflection: rows, faces hit),
    albedo x the mean over each face's rays of the hit faces' radiance, iterated `bounces` times from L_direct."""
    rows, hit, k = e._glow_self_pairs
    alb = np.asarray(e.scene.obj.albedo, float)
    extra = np.zeros_like(L_direct)
    for _ in range(bounces):
        L = L_direct + extra
        extra = alb * np.stack([np.bincount(rows, L[hit, c], len(L)) for c in range(3)], 1) / k
    return extra


def receivers(room: Path) -> None:
    """Per place (bench_sun_energy.places) the receiver pixels' mean reflectance rho_x, gathered light E_x and
    photo radiance L_b (luminance), and the sunlit patches' mean B_src, under known and captured light (one engine
    at a time): a glow rho_x x R carries rho_x = L_b / E_x, so a captured E_x short on the walls makes their glow
    too strong by the same factor."""
    import gc

    from app.composite import default_cache_dir
    from app.engine import Engine, EngineParams
    from bench_sun_energy import places
    from recon.scene import load_scene

    s = load_scene(room)
    print(f"\n### {room.name}: receivers by place (luminance means)")
    print("| lighting | place | px | rho_x | E_x | L_b |")
    print("| --- | --- | --- | --- | --- | --- |")
    for lighting in ("known", "captured"):
        e = Engine(s, EngineParams(lighting=lighting), cache_dir=default_cache_dir(), quiet=True)
        r = e.receivers
        where, _ = places(e, room)
        for name in ("floor < 0.3 m", "floor 0.3-1 m", "walls"):
            px = np.flatnonzero(where[name].reshape(-1))
            print(f"| {lighting} | {name} | {len(px)} | {float((r.rho_x[px] @ LUMA).mean()):.4f} | "
                  f"{float((r.E_x[px] @ LUMA).mean()):.4g} | {float((r.L_b[px] @ LUMA).mean()):.4g} |")
        lit = e.sun.patch_light().any(1)
        b_lit = float((e.B_src[lit] @ LUMA).mean())
        print(f"| {lighting} | sunlit patches B_src | {int(lit.sum())} | | | {b_lit:.4g} |")
        pm = e.pre.patches
        rmin, rmax = np.asarray(e.scene.room_min, float), np.asarray(e.scene.room_max, float)
        c = pm.centre
        fl = np.abs(c[:, 1] - rmin[1]) < 1e-3
        wl = np.zeros(len(c), bool)
        for axis, v in ((0, rmin[0]), (0, rmax[0]), (2, rmin[2]), (2, rmax[2])):
            wl |= np.abs(c[:, axis] - v) < 1e-3
        for name, m in (("floor patches", fl & ~pm.is_emitter), ("wall patches", wl & ~pm.is_emitter)):
            w = pm.area[m]
            alb, b = float(w @ (pm.albedo[m] @ LUMA) / w.sum()), float(w @ (e.B_src[m] @ LUMA) / w.sum())
            print(f"| {lighting} | {name}: albedo (area mean) | {int(m.sum())} | {alb:.4f} | | {b:.4g} |")
        del e
        gc.collect()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--lighting", default="known", help="the engine's lighting for the first-pass table (known, "
                                                       "captured: the benchmark folder's probe, the sun estimated)")
    ap.add_argument("--receivers", action="store_true", help="only the receivers' rho_x, E_x, L_b by place, known "
                                                              "and captured light (receivers())")
    ap.add_argument("rooms", nargs="+", type=Path)
    ap.add_argument("--n", type=int, default=200, help="receiver pixels a place")
    ap.add_argument("--rays", type=int, default=1024)
    ap.add_argument("--face-rays", type=int, default=128)
    a = ap.parse_args()
    if a.receivers:
        for room in a.rooms:
            receivers(room)
        return
    from app.composite import default_cache_dir
    from app.engine import Engine, EngineParams
    from bench_sun_energy import places
    from kernels.visibility import Occluder
    from recon.scene import load_scene

    for room in a.rooms:
        s = load_scene(room)
        e = Engine(s, EngineParams(lighting=a.lighting), cache_dir=default_cache_dir(), quiet=True)
        ol, st = e.object_light, e.sun_pixels.stage
        got = {}
        orig_em, orig_light = st.object_emitters, ol.light

        def em(pv, pf, tri_rad, albedo, proxy_occ, radius):
            out = orig_em(pv, pf, tri_rad, albedo, proxy_occ, radius)
            got.update(pv=pv, pf=pf, room=tri_rad.copy(), tri=out[0].copy(), extra=out[1], occ=proxy_occ, r=radius)
            return out

        def li(*args, **kw):
            out = orig_light(*args, **kw)
            got.setdefault("centre", args[4])
            return out

        st.object_emitters, ol.light = em, li
        e.render(s.obj, dataclasses.replace(e.frame_config(), passes=None))
        st.object_emitters, ol.light = orig_em, orig_light
        pv, pf, occ, centre, radius = got["pv"], got["pf"], got["occ"], got["centre"], got["r"]
        R_sun, _ = ol.light(pv, pf, got["tri"] - got["room"], occ, centre, radius, None, got["extra"], centres=False)
        R_room, _ = ol.light(pv, pf, got["room"], occ, centre, radius, None, None, centres=False)
        where, _ = places(e, room)
        rng = np.random.default_rng(0)
        pm = e.pre.patches
        r = e.receivers
        sel = {}
        for name in ("floor < 0.3 m", "floor 0.3-1 m", "walls"):
            idx = np.flatnonzero(where[name].reshape(-1))
            sel[name] = rng.choice(idx, min(a.n, len(idx)), replace=False) if len(idx) else idx
        tv, tf = s.obj.vertices, s.obj.faces
        true_occ = Occluder(tv, tf, e.device)
        g_true, g_prox = Gather(pm, tv, tf), Gather(pm, pv, pf)
        face_room, self_share = true_face_room(e, g_true, tv, tf, true_occ, a.face_rays, rng)
        fn_t, ar_t = face_normals(tv, tf)
        fn_p, ar_p = face_normals(pv, pf)
        vis_t = e.sun.light.visibility(tv[tf].mean(1), fn_t, extra=[true_occ], disk=True)
        vis_p = e.sun.light.visibility(pv[pf].mean(1), fn_p, extra=[occ], disk=True)
        print(f"\n### {room.name}: object {len(tf)} faces (area {ar_t.sum():.4f} m2), proxy {len(pf)} "
              f"(area {ar_p.sum():.4f} m2); sunlit power area x cos x vis (centroids): true {(ar_t * vis_t).sum():.5f}"
              f", proxy {(ar_p * vis_p).sum():.5f}; room light x area (lum): true {(face_room @ LUMA * ar_t).sum():.5f}"
              f", proxy {(got['room'] @ LUMA * ar_p).sum():.5f}; true faces' rays hitting the object {self_share:.3f}")
        Eperp = e.sun.light.sun.irradiance / np.pi
        L_sun_t = np.asarray(s.obj.albedo, float) * (vis_t[:, None] * Eperp)
        L_self = self_light(e, L_sun_t + face_room)
        print(f"object's own interreflection: x area (lum) {(L_self @ LUMA * ar_t).sum():.5f} against sun "
              f"{(L_sun_t @ LUMA * ar_t).sum():.5f} + room {(face_room @ LUMA * ar_t).sum():.5f}")
        # ours (ObjectLight.self_light on the proxy) against the same cosine gather's self hits on the proxy
        face_sun = st.face_sun
        ours_self = sum(ol.self_light(pv, pf, occ, [got["room"], face_sun], np.asarray(s.obj.albedo, float)))
        true_face_room(e, g_prox, pv, pf, occ, a.face_rays, rng)
        ref_self = self_light(e, got["room"] + face_sun)
        print(f"proxy self-light x area (lum): ours {(ours_self @ LUMA * ar_p).sum():.5f}, cosine gather "
              f"{(ref_self @ LUMA * ar_p).sum():.5f}; of the proxy's room + sun "
              f"{((got['room'] + face_sun) @ LUMA * ar_p).sum():.5f}")
        R_self, _ = ol.light(pv, pf, ours_self, occ, centre, radius, None, None, centres=False)
        print("| place | px | ours sun / proxy ref / true ref | ours room / proxy ref / true ref | ours all / true ref "
              "| object's self-light (ours all / true ref with it) | ours with self_light / true ref with it |")
        print("| --- | --- | --- | --- | --- | --- | --- |")
        for name, px in sel.items():
            if len(px) == 0:
                continue
            pts, nrm = r.pix_pos[px], pm.normal[r.pix_patch[px]]
            ps, pr = reference(e, g_prox, pv, pf, got["room"], occ, pts, nrm, a.rays, rng)
            ts, tr = reference(e, g_true, tv, tf, face_room, true_occ, pts, nrm, a.rays, rng)
            _, tself = reference(e, g_true, tv, tf, L_self, true_occ, pts, nrm, a.rays // 4, rng)
            os_, or_ = float((R_sun[px] @ LUMA).sum()), float((R_room[px] @ LUMA).sum())
            print(f"| {name} | {len(px)} | {os_:.4g} / {ps.sum():.4g} / {ts.sum():.4g} ({os_ / ts.sum():.3f}) | "
                  f"{or_:.4g} / {pr.sum():.4g} / {tr.sum():.4g} ({or_ / tr.sum():.3f}) | "
                  f"{(os_ + or_) / (ts.sum() + tr.sum()):.3f} "
                  f"(proxy ref {(ps.sum() + pr.sum()) / (ts.sum() + tr.sum()):.3f}) | "
                  f"{tself.sum():.4g} ({(os_ + or_) / (ts.sum() + tr.sum() + tself.sum()):.3f}) | "
                  f"{(os_ + or_ + float((R_self[px] @ LUMA).sum())) / (ts.sum() + tr.sum() + tself.sum()):.3f} |")
        del e


if __name__ == "__main__":
    main()
