"""The energy ratio of a room under known light, split into the truth's shadow and glow (issue 34, sun_106).

usage: python bench/bench_sun_energy.py ROOM_DIR [ROOM_DIR ...] [--variants full,no_ol,no_so] [--save DIR]

score.py's energy_ratio is sum_affected(bg - ours) / sum_affected(bg - truth). Where the sunlit object lights
the room about as much as it shades it, the denominator is a small difference of two large sums. Per room this
renders the all-sources frame under the benchmark folder's own (known) light and splits the scorer's affected
pixels (its own definition: blurred 8-bit luminance, outside the dilated mask, |truth - bg| > 2 levels) by the
sign of the truth's change: `shadow` (truth darker than the photo) and `glow` (truth brighter), and each by place
(the sunlit patch, the floor near/far from the object, walls, the rest). Per cell: pixels, the truth's
sum(bg - truth) and ours sum(bg - ours), in 8-bit levels (the scorer's units), and ours / truth.

Variants (one engine, flags switched per frame): `full` (the product), `no_ol` (ObjectConfig.object_light off:
the object's light on the room left out), `no_so` (second_order off), `no_later`, `no_blk`, `no_fpb` (one
second-order term off: see switched()). The difference full - no_ol is our glow.
The truth's noise floor: the same sums over the pixels outside the affected set with |truth - bg| > 1 level
(the render noise's share of a threshold), and over 'affected' pixels > 1.2 m from the object.
--save DIR writes each variant's composite as DIR/<room>_<variant>.png.

--noise: the scorer's selection of noisy pixels alone: the first variant's change (bg - ours) taken as the truth's
change, plus the truth's own render noise (white, its per-pixel std from the high-pass of truth - bg, blurred as
the scorer blurs), thresholded as the scorer does; the ratio this gives over 8 draws (1.0: no selection bias).
--eyes: the object's share of the sunlit patches' sun light at the receiver vertices (first pass, G_v, the
object's proxy): what the shadow pass hides (a patch's whole sunlit light at its one eye: the patch centre, and the
engine's own eye, shadow_sources.eye_pos, SunStage.source_eyes) plus
the loss pass less its blocked pairs (a ray to the loss-weighted centre: SunStage.first_pass_blocked), against a
ray per sun sample point (4 x 4 a patch) for both.
"""
from __future__ import annotations

import argparse
import contextlib
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def lum8(img: np.ndarray) -> np.ndarray:
    """The scorer's luminance of an 8-bit RGB image (H,W,3 RGB order), blurred sigma 2 px."""
    import cv2

    x = img.astype(np.float64)
    return cv2.GaussianBlur(0.0722 * x[..., 2] + 0.7152 * x[..., 1] + 0.2126 * x[..., 0], (0, 0), 2.0)


def places(e, scene_dir: Path) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Pixel masks (H,W) by place (outside the scorer's dilated object mask), and that mask."""
    import cv2

    H, W = e.scene.camera.height, e.scene.camera.width
    mk = cv2.imread(str(scene_dir / "truth_mask.png"), 0)
    mask = cv2.dilate((mk > 127).astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    pos = e.receivers.pix_pos.reshape(H, W, 3)
    lo, hi = e.scene.obj.vertices.min(0), e.scene.obj.vertices.max(0)
    c = 0.5 * (lo + hi)
    ext = 0.5 * float(np.linalg.norm((hi - lo)[[0, 2]]))
    dist = np.linalg.norm((pos - c)[..., [0, 2]], axis=-1) - ext  # from the object's footprint circle
    rmin, rmax = np.asarray(e.scene.room_min, float), np.asarray(e.scene.room_max, float)
    sun = np.zeros(H * W, bool)
    if e.sun_pixels.pix is not None:
        sun[e.sun_pixels.pix] = True
    sun = sun.reshape(H, W)
    ok = e.receivers.recv_pix.reshape(H, W) & ~mask
    floor = np.abs(pos[..., 1] - rmin[1]) < 1e-3
    wall = np.zeros_like(floor)
    for axis, v in ((0, rmin[0]), (0, rmax[0]), (2, rmin[2]), (2, rmax[2])):
        wall |= np.abs(pos[..., axis] - v) < 1e-3
    out = {"sunlit patch": ~mask & sun,
           "floor < 0.3 m": ok & floor & ~sun & (dist < 0.3),
           "floor 0.3-1 m": ok & floor & ~sun & (dist >= 0.3) & (dist < 1.0),
           "floor > 1 m": ok & floor & ~sun & (dist >= 1.0),
           "walls": ok & wall & ~sun,
           "other": ~mask & ~sun & ~(ok & (floor | wall))}
    return out, mask


def table(lb, lt, lc_by, aff, where, mask) -> list[str]:
    """Markdown rows: per place x sign, pixels, truth's and each variant's darkening (levels summed); sign
    'no threshold': every pixel of the place outside the mask (the scorer's selection of noisy pixels left out)."""
    names = list(lc_by)
    rows = [f"| place | sign | pixels | truth | " + " | ".join(names) + " | " + " | ".join(f"{n}/truth" for n in names)
            + " |", "| --- " * (4 + 2 * len(names)) + "|"]
    sign = {"shadow": lt < lb, "glow": lt > lb}
    for pn, pm in list(where.items()) + [("all", np.ones_like(aff))]:
        for sn, sm in list(sign.items()) + [("both", np.ones_like(aff)), ("no threshold", None)]:
            r = (pm & ~mask) if sm is None else aff & pm & sm
            if not r.any():
                continue
            t = float((lb - lt)[r].sum())
            o = [float((lb - lc_by[n])[r].sum()) for n in names]
            rows.append(f"| {pn} | {sn} | {int(r.sum())} | {t:.0f} | " + " | ".join(f"{x:.0f}" for x in o) + " | "
                        + " | ".join(f"{x / t:.3f}" if abs(t) > 1e-9 else "nan" for x in o) + " |")
    return rows


@contextlib.contextmanager
def switched(e, variant: str):
    """The engine with one second-order term left out for this frame: `no_later` (the sun's loss and the sunlit
    object's light passed on once only: Engine._sun_later_bounces off), `no_blk` (the pairs the object blocks
    kept: Engine._blocked_second_order off), `no_fpb` (the sun loss's pairs the object blocks not skipped:
    SunStage.later_bounces without its occluder), `self` / `no_self` (the object's own interreflection on / off:
    Engine.object_self_light); other names: unchanged."""
    saved = {}
    if variant == "no_later":
        saved["_sun_later_bounces"] = e.__dict__.get("_sun_later_bounces")
        e._sun_later_bounces = lambda *a, **k: None
    elif variant == "no_blk":
        saved["_blocked_second_order"] = e.__dict__.get("_blocked_second_order")
        e._blocked_second_order = lambda *a, **k: None
    elif variant in ("self", "no_self"):  # the object's own interreflection on / off (ObjectLight.self_light)
        saved["object_self_light"] = e.object_self_light
        e.object_self_light = variant == "self"
    elif variant == "no_fpb":
        st = e.sun_pixels.stage
        orig = st.later_bounces
        st.later_bounces = lambda *a, **k: orig(*a, **{**k, "occluder": None})
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                delattr(e, k)
            else:
                setattr(e, k, v)
        if variant == "no_fpb":
            del e.sun_pixels.stage.later_bounces


def selection_ratio(lb: np.ndarray, lc: np.ndarray, raw_bg: np.ndarray, raw_tr: np.ndarray, mask: np.ndarray,
                    draws: int = 8) -> list[float]:
    """The energy ratio an exact composite would score if the truth were `lc` plus the truth's render noise:
    white noise of the local std of truth - bg (unblurred luminance; high-pass energy, blurred 8 px), blurred
    sigma 2 px as the scorer's, thresholded at 2 levels as its 'affected'. lb, lc: the scorer's blurred
    luminance of the photo and a composite."""
    import cv2

    blur = lambda x, sg=2.0: cv2.GaussianBlur(x, (0, 0), sg)  # noqa: E731
    d_raw = raw_tr - raw_bg
    hp = d_raw - blur(d_raw)
    var = blur(hp ** 2, 8.0) / 0.94  # the high-pass keeps 0.94 of white noise's variance at sigma 2
    rng = np.random.default_rng(0)
    d = lb - lc
    out = []
    for _ in range(draws):
        dt = d + blur(rng.standard_normal(d.shape) * np.sqrt(var))
        a = ~mask & (np.abs(dt) > 2.0)
        out.append(float(d[a].sum() / dt[a].sum()))
    return out


def eye_check(e, s) -> str:
    """The sunlit patches' light the object takes from the receiver vertices' first pass (luminance, G_v):
    ours (the shadow pass's one eye per patch + the loss less its pairs blocked at the loss-weighted centre)
    against a ray per sun sample point, on the object's proxy."""
    import open3d as o3d

    from recon.response import LUMA

    pm, st = e.pre.patches, e.sun_pixels.stage
    st.frame(s.obj.vertices, s.obj.faces)
    pv, pf, _, _, _ = e.object_shading.object_shape(s.obj)
    J, K = st.c_vis.shape
    pts = st.c_pts.reshape(J, K, 3)
    eye = pm.centre[st.c_patch] + pm.normal[st.c_patch] * 1e-3
    mesh = o3d.t.geometry.TriangleMesh()
    mesh.vertex.positions = o3d.core.Tensor(pv.astype(np.float32))
    mesh.triangle.indices = o3d.core.Tensor(pf.astype(np.int32))
    sc = o3d.t.geometry.RaycastingScene()
    sc.add_triangles(mesh)
    recv = pm.vert_inset[e.pre.recv_vert]
    G = e.pre.G_v[:, st.c_patch].astype(np.float64)
    w = (pm.albedo[st.c_patch] @ LUMA) * float(st.E_perp @ LUMA)

    def blocked(targets: np.ndarray) -> np.ndarray:
        out = np.zeros((len(recv), len(targets)), bool)
        for a in range(0, len(recv), 512):
            d = targets[None] - recv[a:a + 512, None]
            r = np.linalg.norm(d, axis=-1)
            rays = np.concatenate([np.broadcast_to(recv[a:a + 512, None], d.shape), d / r[..., None]], -1)
            t = sc.cast_rays(o3d.core.Tensor(rays.reshape(-1, 6).astype(np.float32)))["t_hit"].numpy()
            out[a:a + 512] = t.reshape(r.shape) < r * 0.9999
        return out

    vis, lost = st.c_vis, st.lost
    n_lost = lost.sum(1)
    cen = np.where(n_lost[:, None] > 0, (lost[..., None] * pts).sum(1) / np.maximum(n_lost, 1e-12)[:, None], eye)
    hidden_eye = float(((G * blocked(eye)) @ (w * vis.mean(1))).sum())
    blk_cen = float(((G * blocked(cen)) @ (w * lost.mean(1))).sum())
    hidden_ex = blk_ex = 0.0
    for k in range(K):
        bk = G * blocked(pts[:, k])
        hidden_ex += float((bk @ (w * vis[:, k] / K)).sum())
        blk_ex += float((bk @ (w * lost[:, k] / K)).sum())
    total, loss = float((G @ (w * vis.mean(1))).sum()), float((G @ (w * lost.mean(1))).sum())
    hidden_src = float(((G * blocked(e.shadow_sources.eye_pos[st.c_patch])) @ (w * vis.mean(1))).sum())
    ours, ex, src = hidden_eye + loss - blk_cen, hidden_ex + loss - blk_ex, hidden_src + loss - blk_cen
    return (f"sunlit light at the receivers {total:.1f}: hidden by the object {hidden_eye:.1f} (centre) / "
            f"{hidden_src:.1f} (the engine's eye) / {hidden_ex:.1f} (per sample); the loss {loss:.1f}, its blocked pairs "
            f"{blk_cen:.1f} (loss centre) / {blk_ex:.1f} (per sample); net taken {ours:.1f} (centre) / {src:.1f} (the "
            f"engine's eye) / {ex:.1f}: centre / per sample {ours / ex:.3f}, the engine's eye / per sample {src / ex:.3f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("rooms", nargs="+", type=Path)
    ap.add_argument("--variants", default="full,no_ol")
    ap.add_argument("--shared", type=Path, default=Path(os.environ.get("PHOTOAR_SHARED", ROOT.parent / "shared")))
    ap.add_argument("--save", type=Path)
    ap.add_argument("--noise", action="store_true", help="the scorer's selection bias on the truth's noise")
    ap.add_argument("--eyes", action="store_true", help="the sunlit patches' hidden light: one eye against samples")
    ap.add_argument("--lighting", default="known", help="the engine's lighting (known, captured: the benchmark "
                                                       "folder's probe and photo, its true camera)")
    ap.add_argument("--sun", default="auto", help="the engine's sun source (auto, estimate, declared)")
    ap.add_argument("--captured-sun-sources", default="on", choices=("on", "off"),
                    help="Engine.captured_sun_sources (off: main's captured sources, for an A/B)")
    a = ap.parse_args()
    import dataclasses

    import cv2

    from app.composite import default_cache_dir
    from app.engine import Engine, EngineParams
    from recon.io import write_png
    from recon.scene import load_scene

    Engine.captured_sun_sources = a.captured_sun_sources == "on"
    for room in a.rooms:
        s = load_scene(room)
        e = Engine(s, EngineParams(lighting=a.lighting, sun=a.sun), cache_dir=default_cache_dir(), quiet=True)
        if e.sun.light is not None:
            print(f"sun ({a.lighting}, {a.sun}):", json.dumps(e.sun.report()))
        p0 = e.params
        lb = lum8(cv2.imread(str(room / "background.png"))[..., ::-1])
        lt = lum8(cv2.imread(str(room / "truth.png"))[..., ::-1])
        where, mask = places(e, room)
        aff = ~mask & (np.abs(lt - lb) > 2.0)
        lc_by, scores = {}, {}
        for v in a.variants.split(","):
            e.params = dataclasses.replace(p0, object_light=p0.object_light and v != "no_ol",
                                           second_order=p0.second_order and v != "no_so")
            with switched(e, v):
                f = e.render(s.obj, dataclasses.replace(e.frame_config(), passes=None))
            e.params = p0
            with tempfile.TemporaryDirectory() as tmp:
                p = Path(tmp) / "c.png"
                write_png(p, f.pixels)
                if a.save:
                    a.save.mkdir(parents=True, exist_ok=True)
                    write_png(a.save / f"{room.name}_{v}.png", f.pixels)
                scores[v] = json.loads(subprocess.check_output(
                    [sys.executable, str(a.shared / "tools" / "score.py"), str(room), str(p)]))
                lc_by[v] = lum8(cv2.imread(str(p))[..., ::-1])
        print(f"\n### {room} ({a.lighting} light, sun {a.sun}, all sources)")
        for v, sc in scores.items():
            print(f"- {v}: " + ", ".join(f"{k} {x:.4g}" for k, x in sc.items()))
        print("\n".join(table(lb, lt, lc_by, aff, where, mask)))
        # the noise floor: below-threshold pixels far from the object
        far = where["floor > 1 m"] | where["walls"]
        nz = far & ~aff
        print(f"noise: far pixels not affected: {int(nz.sum())}, sum(bg - truth) {float((lb - lt)[nz].sum()):.0f}, "
              f"rms {float(np.sqrt(np.mean((lb - lt)[nz] ** 2))):.2f} levels; far affected: {int((far & aff).sum())} px, "
              f"sum {float((lb - lt)[far & aff].sum()):.0f}")
        if a.noise:
            raw = [cv2.imread(str(room / n)).astype(np.float64) @ np.array([0.0722, 0.7152, 0.2126])
                   for n in ("background.png", "truth.png")]
            r = selection_ratio(lb, lc_by[next(iter(lc_by))], raw[0], raw[1], mask)
            print(f"selection: an exact composite with the truth's noise would score {np.mean(r):.3f} "
                  f"(8 draws, {min(r):.3f}-{max(r):.3f})")
        if a.eyes and e.sun_pixels.stage is not None:
            print("eyes:", eye_check(e, s))
        del e


if __name__ == "__main__":
    main()
