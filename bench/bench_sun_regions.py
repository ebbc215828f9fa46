"""Where the sun's object effect lands, per region, against the truth (issue 20's energy ratio).

usage: python bench/bench_sun_regions.py [--shared ../shared] [--scene sun_room] [--passes all]

The scorer's energy ratio is one sum over the 'affected' pixels; in a sunny room it is a small
difference of two large terms (the light the object's sun shadow takes from the room through every
bounce, and the light the sunlit object reflects onto it). This prints, per region of the room
(the sunlit floor, the shaded floor by distance from the object, each wall), the darkening the truth
shows (background.exr - truth.exr, clean: both renders share their samples) against ours
((L_b - room) / L_b x background.exr: our relative change on the exr background, so the photo's
noise and clipping cancel), in linear luminance summed over the region's pixels (outside the
object's dilated mask); then the scorer's figures of the frame. Then the share of the sun loss's
first pass through G_v that the object hides from the receivers (kernels.blocked_transfer: one ray
per (receiver vertex, shadowed patch) to the loss-weighted centre of its lost samples) against one
ray per lost sample point (Open3D).
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from recon.response import LUMA  # noqa: E402

W_LUM = LUMA


def regions(e, scene_dir: Path) -> dict[str, np.ndarray]:
    """Pixel masks (H*W,) bool: receiver pixels outside the scorer's object mask, by surface and place."""
    import cv2

    H, W = e.scene.camera.height, e.scene.camera.width
    mk = cv2.imread(str(scene_dir / "truth_mask.png"), 0)
    mask = (cv2.dilate((mk > 127).astype(np.uint8), np.ones((5, 5), np.uint8)) > 0).ravel()
    pos = e.receivers.pix_pos
    lo, hi = e.scene.obj.vertices.min(0), e.scene.obj.vertices.max(0)
    c = 0.5 * (lo + hi)
    dist = np.linalg.norm((pos - c)[:, [0, 2]], axis=1)
    rmin, rmax = np.asarray(e.scene.room_min, float), np.asarray(e.scene.room_max, float)
    sun = np.zeros(H * W, bool)
    if e.sun_pixels.pix is not None:
        sun[e.sun_pixels.pix] = True
    ok = e.receivers.recv_pix & ~mask
    floor = np.abs(pos[:, 1] - rmin[1]) < 1e-3
    out = {"sunlit floor": ok & sun & floor,
           "floor < 0.6 m from the object": ok & floor & ~sun & (dist < 0.6),
           "floor 0.6-1.2 m": ok & floor & ~sun & (dist >= 0.6) & (dist < 1.2),
           "floor 1.2-2 m": ok & floor & ~sun & (dist >= 1.2) & (dist < 2.0),
           "floor > 2 m": ok & floor & ~sun & (dist >= 2.0),
           "ceiling": ok & (np.abs(pos[:, 1] - rmax[1]) < 1e-3)}
    for name, axis, v in (("wall x=min", 0, rmin[0]), ("wall x=max", 0, rmax[0]), ("wall z=min", 2, rmin[2]),
                          ("wall z=max", 2, rmax[2])):
        out[name] = ok & ~floor & (np.abs(pos[:, axis] - v) < 1e-3)
    walls = np.any([out[k] for k in out if k.startswith("wall")], axis=0)
    out["other (furniture)"] = ok & ~floor & ~walls & ~out["ceiling"]
    out["all but the sunlit floor"] = ok & ~(sun & floor)
    return {k: v for k, v in out.items() if v.any()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shared", type=Path, default=ROOT.parent / "shared")
    ap.add_argument("--scene", default="sun_room")
    ap.add_argument("--passes", default="all")
    a = ap.parse_args()
    from app.engine import Engine, EngineParams, FrameConfig
    from recon.io import read_exr, write_png
    from recon.scene import load_scene

    scene_dir = a.shared / "scenes" / a.scene
    s = load_scene(scene_dir)
    e = Engine(s, EngineParams(), cache_dir=Path(tempfile.gettempdir()) / "photoar-bench-cache", quiet=True)
    f = e.render(s.obj, FrameConfig(passes=None if a.passes == "all" else int(a.passes)))
    bg = read_exr(scene_dir / "background.exr").reshape(-1, 3) @ W_LUM
    tr = read_exr(scene_dir / "truth.exr").reshape(-1, 3) @ W_LUM
    Lb = e.receivers.L_b @ W_LUM
    room = f.room.reshape(-1, 3) @ W_LUM
    ours = np.where(Lb > 0, (Lb - room) / np.maximum(Lb, 1e-12), 0.0) * bg
    print(f"{a.scene}, {a.passes} passes: darkening per region (linear luminance summed; < 0: brighter)")
    print(f"| region | pixels | truth | ours | ours / truth |\n| --- | --- | --- | --- | --- |")
    for name, r in regions(e, scene_dir).items():
        t, o = float((bg - tr)[r].sum()), float(ours[r].sum())
        print(f"| {name} | {int(r.sum())} | {t:.1f} | {o:.1f} | {o / t if abs(t) > 1e-9 else float('nan'):.3f} |")
    with tempfile.TemporaryDirectory() as tmp:
        write_png(Path(tmp) / "c.png", f.pixels)
        sc = json.loads(subprocess.check_output([sys.executable, str(a.shared / "tools" / "score.py"), str(scene_dir),
                                                 str(Path(tmp) / "c.png")]))
    print("score:", {k: round(v, 4) for k, v in sc.items()})
    if e.sun_pixels.stage is not None:
        blocked_share(e, s)


def blocked_share(e, s) -> None:
    """The object's share of the sun loss's first pass through G_v: centres of lost samples (ours)
    against a ray per lost sample point."""
    import open3d as o3d

    pm, st = e.pre.patches, e.sun_pixels.stage
    pv, pf, occ, _, _ = e.object_shading.object_shape(s.obj)
    st.frame(s.obj.vertices, s.obj.faces)
    dB1 = -pm.albedo * 0
    dB1[st.c_patch] = -pm.albedo[st.c_patch] * (st.lost.mean(1)[:, None] * st.E_perp)
    recv = pm.vert_inset[e.pre.recv_vert]
    blk_v, _ = st.first_pass_blocked(occ, (pv.min(0) - 1e-3, pv.max(0) + 1e-3), dB1, e.pre.G_c, e.pre.G_v, recv)
    K = st.c_vis.shape[1]
    i, k = np.nonzero(st.lost > 0)
    pts = st.c_pts.reshape(len(st.c_patch), K, 3)[i, k]
    w = (st.lost[i, k] / K) * (pm.albedo[st.c_patch[i]] @ W_LUM) * float(st.E_perp @ W_LUM)
    mesh = o3d.t.geometry.TriangleMesh()
    mesh.vertex.positions = o3d.core.Tensor(pv.astype(np.float32))
    mesh.triangle.indices = o3d.core.Tensor(pf.astype(np.int32))
    sc = o3d.t.geometry.RaycastingScene()
    sc.add_triangles(mesh)
    G = e.pre.G_v[:, st.c_patch[i]].astype(np.float64)
    hit = np.zeros(G.shape, bool)
    for a in range(0, len(recv), 256):
        d = pts[None] - recv[a:a + 256, None]
        r = np.linalg.norm(d, axis=-1)
        rays = np.concatenate([np.broadcast_to(recv[a:a + 256, None], d.shape), d / r[..., None]], -1)
        t = sc.cast_rays(o3d.core.Tensor(rays.reshape(-1, 6).astype(np.float32)))["t_hit"].numpy().reshape(r.shape)
        hit[a:a + 256] = t < r
    total = float((G @ w).sum())
    print(f"object's share of the loss's first pass at the receivers: {float((blk_v @ W_LUM).sum()) / -total:.4f} "
          f"(a centre per shadowed patch), {float(((G * hit) @ w).sum()) / total:.4f} (a ray per lost sample point)")


if __name__ == "__main__":
    main()
