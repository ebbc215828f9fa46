"""Is there camera information near the object that the refinement does not use? (issue 34 item 6, cam48)

Per sun room (the work folders `bench_unseen --keep DIR` leaves, and the room's truth), two sources:

1. The sunlit patch's outline on the floor: each edge of the opening quad (tape room) cast along the sun onto
   the floor. In the photo it is the boundary of the clipped region (max channel >= edgesnap.CLIP_LEVEL). Per
   outline sample (about SAMPLE_STEP_PX apart, END_TRIM_PX from an edge's ends, on the visible floor), the
   boundary's offset along the image normal (positive towards the lit side) is measured as R - the integral of
   the clipped indicator over [-R, R] (exact for a step; robust to isolated noisy pixels). Per outline edge:
   the median offset, and its jackknife std over blocks of BLOCK samples.
   At the truth's camera and sun (the sun's finite distance included: from each point the sun's centre) the
   offsets are the measurement's own bias (penumbra, the pixel box, the clip level, the photo's noise);
   at the flow's refined camera they are bias + the camera's error there (+ the sun's).
   The joint fit (linearised): offset_i - bias_i = n_i . t + n_i . (d uv_i / d sun) delta, free: the image
   translation t (2, px: the camera's error near the object taken as a whole shift, which is what it mostly
   is) and the sun's direction delta (2, rad); with the bias taken as 0 ("raw"), as the noise-free model's
   ("model": the clip level crossing of the sun fraction, a disk's penumbra boxed by the pixel, from the room's
   radiance: background.exr, its response read off background.png), or as measured at the truth ("oracle":
   what the outline could give at best). t is compared with the truth: -d, d the refined camera's image of the
   object's vertices less the truth's (mean).
2. The opening's own edges (the sky against the wall): the room's edge samples of the opening quad that the
   refinement drops for clipping (edgesnap's CLIP_RADIUS_PX), measured with the same clipped-indicator rule
   (the clipped side towards the sky), offset and jackknife per edge, at the truth's and the refined camera.

With --joint, the joint fit linearised at the flow's refined camera (calibrate + refine_camera run again, the
same camera as the flow's): the room's edges as the camera's prior (PRIOR "fit": the refinement's covariance, or
"jackknife": over the room's edges), plus the rows of SOURCES ("patch", "opening", "patch+opening"; an edge's
samples share one error: its jackknife and FLOOR px), free: the camera's 6 parameters and, with "sun free", the
sun's direction; ROWS "model" (the bias model, f_c read off background.exr), "model fc=F" (f_c fixed), "raw",
"oracle" (the offsets at the truth), "exact" (the refined camera's own error along the normals). Each variant
PRIOR/SOURCES/sun MODE/ROWS/floorFLOOR gives the object's image error after (|mean over its vertices|) and the
fit's 1 sigma there; --rescore runs the own-room flow's captured composite on chosen variants' cameras.

usage: python bench/bench_patch_info.py --keep DIR [--rooms ~/.cache/photoar/rooms] [--only sun_101,...]
       [--joint [--rescore 'none,jackknife/patch/sun held/model/floor0.1'] [--work DIR]] [--json OUT]
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

SAMPLE_STEP_PX = 3.0
END_TRIM_PX = 8.0  # an outline edge's ends: corners of the patch mix two edges
R_PX = 4.0  # the profile's half-width across the outline
STEP = 0.25
BLOCK = 8  # jackknife blocks of this many consecutive samples (the grain correlates neighbours)
SUN_RAD = np.radians(0.53 / 2)

from recon.sunoutline import _bilinear, _tmean, boundary_offset, disk_fraction  # noqa: E402  (the product's)
from recon.sunoutline import clipped as _clipped  # noqa: E402
FC_FIXED = (0.05, 0.15, 0.5)  # clip fractions tried in place of the room's own (sun_101-103 read 0.13, 0.55, 0.27)


def _load(root: Path, keep: Path):
    from recon.camera import Camera

    truth_json = json.loads((root / "scene.json").read_text())
    truth = Camera.from_json(truth_json["main_camera"], root / "scene.json", "main_camera.")
    flow_json = json.loads((keep / "room" / "scene.json").read_text())
    cam = Camera.from_json(flow_json["main_camera"], keep / "room" / "scene.json", "main_camera.")
    sun = next(p for p in truth_json["primitives"] if p.get("role") == "sun")
    prims = flow_json["primitives"]
    return truth, cam, sun, prims


def floor_hit(X: np.ndarray, dsun: np.ndarray) -> np.ndarray:
    """Points X (N,3) cast along -dsun (N,3 or 3, unit, towards the sun) onto the floor y = 0."""
    dsun = np.broadcast_to(dsun, X.shape)
    return X - (X[:, 1] / dsun[:, 1])[:, None] * dsun


def sun_dirs(sun: dict, X: np.ndarray) -> np.ndarray:
    """(N,3) the direction from each point to the truth's sun centre (finite distance)."""
    d = np.asarray(sun["centre"], float) - X
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def outline_samples(cam, opening: np.ndarray, dsun: np.ndarray, room_hi: np.ndarray, occ):
    """Samples of the patch outline: (X_opening (N,3), edge index (N,), s along the edge (N,)), each edge of the
    opening quad sampled about SAMPLE_STEP_PX apart in the image of `cam`, kept where its floor point lies in
    the room, is seen by the camera and is away from the edge's ends."""
    Xs, es = [], []
    for k in range(4):
        a, b = opening[k], opening[(k + 1) % 4]
        fa, fb = floor_hit(np.stack([a, b]), dsun)
        uv, _ = cam.project(np.stack([fa, fb]))
        n = max(int(np.ceil(np.linalg.norm(uv[1] - uv[0]) / SAMPLE_STEP_PX)), 2)
        s = (np.arange(n) + 0.5) / n
        X = a + s[:, None] * (b - a)
        F = floor_hit(X, dsun)
        uvs, z = cam.project(F)
        along = np.linalg.norm(uvs - uvs[0], axis=1)
        ok = (z > 0.05) & (along >= END_TRIM_PX) & (along <= along[-1] - END_TRIM_PX)
        ok &= np.all(F[:, [0, 2]] > 0.02, axis=1) & (F[:, 0] < room_hi[0] - 0.02) & (F[:, 2] < room_hi[2] - 0.02)
        ok &= np.all(uvs >= R_PX + 1, axis=1) & (uvs[:, 0] <= cam.width - R_PX - 2) & (uvs[:, 1] <= cam.height - R_PX - 2)
        if ok.any():
            ok[ok] &= occ.visible(cam.centre, F[ok] + np.array([0, 0.002, 0]))
        Xs.append(X[ok])
        es.append(np.full(int(ok.sum()), k))
    return np.concatenate(Xs), np.concatenate(es)


def opening_samples(cam, opening: np.ndarray, occ) -> tuple[np.ndarray, np.ndarray]:
    """Samples (N,3) of the opening quad's own edges seen by `cam` (about SAMPLE_STEP_PX apart, END_TRIM_PX
    from the ends), and their edge index (N,)."""
    Xo, eo = [], []
    for k in range(4):
        a, b = opening[k], opening[(k + 1) % 4]
        n_s = max(int(np.ceil(np.linalg.norm(np.subtract(*cam.project(np.stack([a, b]))[0])) / SAMPLE_STEP_PX)), 2)
        s = (np.arange(n_s) + 0.5) / n_s
        Y = a + s[:, None] * (b - a)
        uv, z = cam.project(Y)
        along = np.linalg.norm(uv - uv[0], axis=1)
        ok = (z > 0.05) & (along >= END_TRIM_PX) & (along <= along[-1] - END_TRIM_PX)
        ok &= np.all(uv >= R_PX + 1, axis=1) & (uv[:, 0] <= cam.width - R_PX - 2) & (uv[:, 1] <= cam.height - R_PX - 2)
        if ok.any():
            ok[ok] &= occ.visible(cam.centre, Y[ok])
        Xo.append(Y[ok])
        eo.append(np.full(int(ok.sum()), k))
    return np.concatenate(Xo), np.concatenate(eo)


def normals_into(uv_a: np.ndarray, uv_b: np.ndarray, inside: np.ndarray) -> np.ndarray:
    d = uv_b - uv_a
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    n = np.stack([-d[:, 1], d[:, 0]], 1)
    return n * np.sign(np.sum(n * (inside - uv_a), axis=1))[:, None]


def per_edge(off: np.ndarray, edge: np.ndarray) -> dict:
    out = {}
    for e in np.unique(edge):
        o = off[edge == e]
        blocks = [o[i:i + BLOCK] for i in range(0, len(o), BLOCK)]
        med = _tmean(o)
        if len(blocks) >= 3:
            jk = np.array([_tmean(np.concatenate(blocks[:i] + blocks[i + 1:])) for i in range(len(blocks))])
            B = len(blocks)
            sd = float(np.sqrt((B - 1) / B * np.sum((jk - jk.mean()) ** 2)))
        else:
            sd = float("nan")
        out[int(e)] = {"n": int(len(o)), "median_px": med, "jackknife_px": sd}
    return out


def room_info(name: str, rooms: Path, keep: Path) -> dict:
    from PIL import Image

    from bench.bench_camrefine import object_points
    from recon.camrefine import _Occluder, room_faces

    root = rooms / name
    truth, cam, sun, prims = _load(root, keep / name)
    img = np.asarray(Image.open(keep / name / "room" / "background.png").convert("RGB"))
    clip = _clipped(img)
    faces = room_faces(prims)
    occ = _Occluder(faces)
    room = next(p for p in prims if p.get("role") == "room" or p.get("name") == "room")
    hi = np.asarray(room["center"], float) + np.asarray(room["size"], float) / 2 if "center" in room else \
        np.max(np.concatenate(faces), axis=0)
    opening = next(np.asarray(p["corners"], float) for p in prims if p.get("opening"))
    d0 = np.asarray(sun["direction_to_sun"], float)
    P = object_points(root)
    d_obj = (cam.project(P)[0] - truth.project(P)[0]).mean(axis=0)
    X, edge = outline_samples(truth, opening, d0, hi, occ)
    out = {"room": name, "d_object_px": d_obj.tolist(), "n_outline": int(len(X))}
    if len(X) < 10:
        out["note"] = "outline not seen"
        return out
    # the patch's centre (floor) for the inside direction
    Fc = floor_hit(opening.mean(axis=0, keepdims=True), d0)

    def measure(c, dsun_of):
        ds = dsun_of(X)
        F = floor_hit(X, ds)
        D = np.array([opening[(e + 1) % 4] - opening[e] for e in edge])
        uv = c.project(F)[0]
        uv2 = c.project(floor_hit(X + 0.01 * D, dsun_of(X + 0.01 * D)))[0]
        n = normals_into(uv, uv2, c.project(Fc)[0])
        return uv, n, boundary_offset(clip, uv, n)

    uv_t, n_t, off_t = measure(truth, lambda Y: sun_dirs(sun, Y))
    uv_c, n_c, off_c = measure(cam, lambda Y: np.broadcast_to(d0, Y.shape))
    out["truth"] = per_edge(off_t, edge)
    from recon.io import read_exr

    exr = read_exr(root / "background.exr")
    Lc = clip_levels(img, exr)
    f_c = clip_fraction(exr, Lc, uv_t, n_t)
    w = penumbra_px(truth, X, d0, n_t)
    out["model_inputs"] = per_edge(f_c, edge), per_edge(w, edge)
    out["model"] = per_edge(model_offset(w, n_t, f_c), edge)
    for fc in (0.03, 0.1, 0.3):
        out[f"model_fc{fc}"] = per_edge(model_offset(w, n_t, np.full(len(w), fc)), edge)
    out["refined"] = per_edge(off_c, edge)
    # the joint fit: offsets at the refined camera with a parallel sun d0 against t (2) and delta (2)
    e1 = np.cross(d0, [0, 1, 0]); e1 /= np.linalg.norm(e1)
    e2 = np.cross(d0, e1)
    h = 1e-4
    J = np.zeros((len(X), 4))
    J[:, 0], J[:, 1] = n_c[:, 0], n_c[:, 1]
    for j, e in enumerate((e1, e2)):
        dd = d0 + h * e
        dd /= np.linalg.norm(dd)
        du = (cam.project(floor_hit(X, dd))[0] - uv_c) / h
        J[:, 2 + j] = np.sum(du * n_c, axis=1)
    # the prediction moved by dU (parameters p) lowers the offset by n . dU = J p: J p = offset - bias
    fits = {}
    # the camera's own error along the outline (same parallel sun for both cameras): what an exact
    # measurement would give; the translation model's own limit
    uv_tp = truth.project(floor_hit(X, d0))[0]
    exact = np.sum((uv_tp - uv_c) * n_c, axis=1)
    out["camera_error_along_normal"] = per_edge(exact, edge)
    for label, r in (("raw", off_c), ("oracle", off_c - off_t), ("exact", exact)):
        # edges as units: weight each edge's samples to one edge's worth of BLOCK samples
        w = np.array([1.0 / np.sqrt(max(np.sum(edge == e) / BLOCK, 1.0)) for e in edge])
        p, *_ = np.linalg.lstsq(J * w[:, None], r * w, rcond=None)
        # sun only (camera held): what the flow's own sun estimate does
        ps, *_ = np.linalg.lstsq(J[:, 2:] * w[:, None], r * w, rcond=None)
        fits[label] = {"t_px": p[:2].tolist(), "sun_deg": np.degrees(p[2:]).tolist(),
                       "rms_res_px": float(np.sqrt(np.mean((r - J @ p) ** 2))),
                       "sun_only_rms_res_px": float(np.sqrt(np.mean((r - J[:, 2:] @ ps) ** 2))),
                       "cond": float(np.linalg.cond(J * w[:, None]))}
        # jackknife over edges of t
        es = np.unique(edge)
        if len(es) >= 3:
            T = []
            for e in es:
                m = edge != e
                pe, *_ = np.linalg.lstsq(J[m] * w[m, None], r[m] * w[m], rcond=None)
                T.append(pe[:2])
            T = np.array(T)
            fits[label]["t_jackknife_px"] = float(np.sqrt((len(T) - 1) / len(T) * np.sum((T - T.mean(0)) ** 2)))
    out["fit"] = fits
    # (2) the opening's own edges, the clipped side (the sky) inward
    Xo, eo = opening_samples(truth, opening, occ)
    out["n_opening"] = int(len(Xo))
    if len(Xo) >= 10:
        oc = opening.mean(axis=0, keepdims=True)
        res = {}
        for label, c in (("truth", truth), ("refined", cam)):
            D = np.array([opening[(e + 1) % 4] - opening[e] for e in eo])
            uv = c.project(Xo)[0]
            n = normals_into(uv, c.project(Xo + 0.01 * D)[0], c.project(oc)[0])
            res[label] = per_edge(boundary_offset(clip, uv, n), eo)
            res[label + "_n"] = {int(e): n[eo == e].mean(axis=0).tolist() for e in np.unique(eo)}
        out["opening"] = res
    return out


def rescore(name: str, rooms: Path, work: Path, camera: dict, shared: Path) -> dict:
    """The own-room flow's captured composite on a given camera (scene with --no-refine-camera, then
    composite), scored: what the object scores when `scene` has that camera."""
    from bench import own_room_flow as orf
    from recon.camera import Camera

    root = rooms / name
    inp = orf.write_inputs(root, work / "in")
    orf.declared_openings(inp["room"], inp["scene"])
    cam = Camera(np.asarray(camera["K"]), np.asarray(camera["R"]), np.asarray(camera["t"]), camera["width"],
                 camera["height"])
    K = cam.K
    kb = {"fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2], "width": cam.width, "height": cam.height}
    cj = {"K": kb, **kb, "R": cam.R.tolist(), "t": cam.t.tolist(), "centre": cam.centre.tolist()}
    (work / "camera.json").write_text(json.dumps(cj))
    room = work / "room"
    rc, err, _ = orf._photoar(orf.scene_argv(inp, room, work / "camera.json") + ["--no-refine-camera"])
    if rc != 0:
        return {"error": f"scene: {err}"}
    out = work / "out"
    rc, err, _ = orf._photoar(orf._composite_argv(room, out, inp, "captured", work / "cache"))
    if rc != 0:
        return {"error": f"composite: {err}"}
    return orf.score(root, out / "composite.png", shared)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--keep", required=True)
    ap.add_argument("--rooms", default=os.environ.get("PHOTOAR_ROOMS", str(Path.home() / ".cache/photoar/rooms")))
    ap.add_argument("--only", default="sun_101,sun_102,sun_103")
    ap.add_argument("--json")
    ap.add_argument("--joint", action="store_true", help="also the joint fit against the room edges' prior "
                    "(calibrates and refines again: tens of seconds a room)")
    ap.add_argument("--rescore", help="with --joint: run the flow's captured composite on the camera of this "
                    "joint fit (e.g. 'jackknife/patch/sun held/model/floor0.1'; 'none': the refined camera itself, 'truth': the truth's; comma-separated) into --work")
    ap.add_argument("--work", default="/tmp/bench_patch_info")
    ap.add_argument("--shared", default=os.environ.get("PHOTOAR_SHARED", str(ROOT.parent / "shared")))
    a = ap.parse_args()
    res = []
    for n in a.only.split(","):
        r = room_info(n, Path(a.rooms), Path(a.keep))
        if a.joint and "fit" in r:
            r.update(joint_fit(n, Path(a.rooms), Path(a.keep)))
            if a.rescore:
                r["rescored"] = {k: rescore(n, Path(a.rooms), Path(a.work) / n / k.replace("/", "_").replace(" ", "_"),
                                            r["joint"][k]["camera"], Path(a.shared)) for k in a.rescore.split(",")}
                print(n, json.dumps(r["rescored"]), file=sys.stderr)
        res.append(r)
    print(json.dumps(res, indent=1))
    if a.json:
        Path(a.json).write_text(json.dumps(res, indent=1))


# ----------------------------------------------------------------------------------------------
# The noise-free model of the clipped boundary: the sun fraction across the outline (the disk's chord fraction,
# half-width w px along the image normal), averaged over the pixel's box, crosses the clip fraction f_c =
# (clip - rest) / (sun-lit - rest) (linear, the channel that clips first).

def penumbra_px(cam, X: np.ndarray, d0: np.ndarray, n: np.ndarray) -> np.ndarray:
    """(N,) the sun disk's half-width (px) across the outline's image normal n at each opening point X."""
    e1 = np.cross(d0, [0, 1, 0]); e1 /= np.linalg.norm(e1)
    e2 = np.cross(d0, e1)
    uv0 = cam.project(floor_hit(X, d0))[0]
    o = []
    for e in (e1, e2):
        dd = d0 + SUN_RAD * e
        o.append(np.sum((cam.project(floor_hit(X, dd / np.linalg.norm(dd)))[0] - uv0) * n, axis=1))
    return np.hypot(o[0], o[1])


def model_offset(w: np.ndarray, n: np.ndarray, f_c: np.ndarray) -> np.ndarray:
    """(N,) px: where the pixel-averaged sun fraction crosses f_c, about the geometric outline (+ lit side)."""
    ss = np.arange(-R_PX - 2, R_PX + 2, 0.02)
    g = (np.arange(8) + 0.5) / 8 - 0.5
    gx, gy = np.meshgrid(g, g)
    out = np.empty(len(w))
    for i in range(len(w)):
        proj = n[i, 0] * gx.ravel() + n[i, 1] * gy.ravel()
        F = disk_fraction((ss[:, None] + proj[None, :]) / max(w[i], 1e-3)).mean(axis=1)
        out[i] = np.interp(f_c[i], F, ss)
    return out


def clip_fraction(exr: np.ndarray, Lc: np.ndarray, uv: np.ndarray, n: np.ndarray) -> np.ndarray:
    """(N,) f_c from the room's linear radiance (background.exr) beside each sample: the shade 4-7 px on the
    unlit side, the sun-lit 4-7 px on the lit side (medians), per channel in units of its clip level; the
    channel that reaches the clip level first."""
    ss_out, ss_in = -np.arange(4, 8), np.arange(4, 8)
    f = np.full(len(uv), np.inf)
    for c in range(3):
        a = exr[:, :, c] / Lc[c]
        lo = np.median(_bilinear(a, uv[:, None, :] + ss_out[None, :, None] * n[:, None, :]), axis=1)
        hi = np.median(_bilinear(a, uv[:, None, :] + ss_in[None, :, None] * n[:, None, :]), axis=1)
        f = np.minimum(f, np.where(hi > 1, (1 - lo) / np.maximum(hi - lo, 1e-6), np.inf))
    return np.clip(f, 0.0, 1.0)


def clip_levels(png: np.ndarray, exr: np.ndarray) -> np.ndarray:
    """(3,) the linear radiance at which each channel reaches edgesnap.CLIP_LEVEL (png against exr)."""
    from recon.edgesnap import CLIP_LEVEL

    out = []
    for c in range(3):
        m = (png[:, :, c] >= CLIP_LEVEL - 2) & (png[:, :, c] < CLIP_LEVEL)
        out.append(float(np.median(exr[:, :, c][m])))
    return np.array(out)


# ----------------------------------------------------------------------------------------------
# The joint fit, linearised at the refined camera: the room's edges as the camera's prior (their fit's
# covariance, or the jackknife over the room's edges), the patch outline's rows with the sun free.

def _params_of(camera_at, cam) -> np.ndarray:
    """camrefine._Model's x for `cam` (rotation vector after the input R, centre x, z, log focal ratio)."""
    import cv2

    c0 = camera_at(np.zeros(6))
    rv = cv2.Rodrigues(cam.R @ c0.R.T)[0].ravel()
    dc = cam.centre - c0.centre
    return np.array([rv[0], rv[1], rv[2], dc[0], dc[2], np.log(cam.K[0, 0] / c0.K[0, 0])])


def joint_fit(name: str, rooms: Path, keep: Path) -> dict:
    from PIL import Image

    from bench.bench_camrefine import object_points
    from bench.own_room_flow import calibrated_from_lines
    from recon import assemble as asm
    from recon.camrefine import _Occluder, refine_camera, room_faces

    root = rooms / name
    truth, img, cal, prims, lo, hi = calibrated_from_lines(root)
    cam = cal.camera
    cam = asm.inside_turn(cam, lo, hi)[0]
    r = refine_camera(cam, prims, img, cal.to_json())
    _, flow_cam, sun, flow_prims = _load(root, keep / name)
    P = object_points(root)
    out = {"flow_vs_bench_camera_px": float(np.sqrt(np.mean(np.sum(
        (r.camera.project(P)[0] - flow_cam.project(P)[0]) ** 2, axis=1))))}
    x0 = np.asarray(r.x, float)
    camera_at = r.camera_at
    cov_fit = np.asarray(r.covariance, float)
    X_jk = np.array([_params_of(camera_at, r.without_edge(int(e))) for e in r.edge_ids])
    E = len(X_jk)
    cov_jk = (E - 1) / E * (X_jk - X_jk.mean(0)).T @ (X_jk - X_jk.mean(0))
    # the patch outline (as room_info)
    clip = _clipped(np.asarray(Image.open(keep / name / "room" / "background.png").convert("RGB")))
    faces = room_faces(flow_prims)
    occ = _Occluder(faces)
    opening = next(np.asarray(p["corners"], float) for p in flow_prims if p.get("opening"))
    d0 = np.asarray(sun["direction_to_sun"], float)
    X, edge = outline_samples(truth, opening, d0, np.max(np.concatenate(faces), axis=0), occ)
    Fc = floor_hit(opening.mean(axis=0, keepdims=True), d0)
    D = np.array([opening[(e + 1) % 4] - opening[e] for e in edge])
    c_ref = camera_at(x0)
    dX = sun_dirs(sun, X)  # the rendered sun: from each point its centre (a declared sun would be this)
    dXD = sun_dirs(sun, X + 0.01 * D)
    uv_c = c_ref.project(floor_hit(X, dX))[0]
    n_c = normals_into(uv_c, c_ref.project(floor_hit(X + 0.01 * D, dXD))[0], c_ref.project(Fc)[0])
    off_c = boundary_offset(clip, uv_c, n_c)
    uv_t = truth.project(floor_hit(X, dX))[0]
    n_t = normals_into(uv_t, truth.project(floor_hit(X + 0.01 * D, dXD))[0], truth.project(Fc)[0])
    off_t = boundary_offset(clip, uv_t, n_t)
    exact = np.sum((uv_t - uv_c) * n_c, axis=1)
    from recon.io import read_exr

    exr = read_exr(root / "background.exr")
    Lc = clip_levels(np.asarray(Image.open(keep / name / "room" / "background.png").convert("RGB")), exr)
    f_c = clip_fraction(exr, Lc, uv_c, n_c)  # at the refined camera: what the flow would read
    bias_model = model_offset(penumbra_px(c_ref, X, d0, n_c), n_c, f_c)
    e1 = np.cross(d0, [0, 1, 0]); e1 /= np.linalg.norm(e1)
    e2 = np.cross(d0, e1)

    def pred(p):
        dd = dX + p[6] * e1 + p[7] * e2
        dd /= np.linalg.norm(dd, axis=1, keepdims=True)
        return np.sum(camera_at(x0 + p[:6]).project(floor_hit(X, dd))[0] * n_c, axis=1)

    h = np.array([1e-5] * 3 + [1e-4] * 2 + [1e-5] + [1e-4] * 2)
    base = pred(np.zeros(8))
    J = np.stack([(pred(np.eye(8)[j] * h[j]) - base) / h[j] for j in range(8)], 1)
    # the object's image as a function of the camera's parameters
    u0 = c_ref.project(P)[0]
    JP = np.stack([(camera_at(x0 + np.eye(6)[j] * h[j]).project(P)[0] - u0) / h[j] for j in range(6)], 2)  # (V,2,6)
    d_obj = (u0 - truth.project(P)[0]).mean(axis=0)
    out["d_object_px"] = d_obj.tolist()
    out["bias_model_minus_truth"] = per_edge(bias_model - off_t, edge)
    # (2) the opening's own edges: camera rows only (the sky clipped: the pixel box's bias, f_c from the radiance)
    Xo, eo = opening_samples(truth, opening, occ)
    oc = opening.mean(axis=0, keepdims=True)
    Do = np.array([opening[(e + 1) % 4] - opening[e] for e in eo]).reshape(-1, 3)
    if len(Xo) >= 10:
        uv_oc = c_ref.project(Xo)[0]
        n_oc = normals_into(uv_oc, c_ref.project(Xo + 0.01 * Do)[0], c_ref.project(oc)[0])
        uv_ot = truth.project(Xo)[0]
        off_oc = boundary_offset(clip, uv_oc, n_oc)
        off_ot = boundary_offset(clip, uv_ot, normals_into(uv_ot, truth.project(Xo + 0.01 * Do)[0], truth.project(oc)[0]))
        exact_o = np.sum((uv_ot - uv_oc) * n_oc, axis=1)
        bias_o = model_offset(np.zeros(len(Xo)), n_oc, clip_fraction(exr, Lc, uv_oc, n_oc))
        Jo = np.zeros((len(Xo), 8))
        for j in range(6):
            Jo[:, j] = np.sum((camera_at(x0 + np.eye(6)[j] * h[j]).project(Xo)[0] - uv_oc) * n_oc, axis=1) / h[j]
        out["opening_bias_model_minus_truth"] = per_edge(bias_o - off_ot, eo)
    else:
        Xo = np.zeros((0, 3))
        Jo = np.zeros((0, 8))
        off_oc = off_ot = exact_o = bias_o = np.zeros(0)
    w_c = penumbra_px(c_ref, X, d0, n_c)
    rows_patch = {"exact": exact, "oracle": off_c - off_t, "model": off_c - bias_model, "raw": off_c}
    rows_open = {"exact": exact_o, "oracle": off_oc - off_ot, "model": off_oc - bias_o, "raw": off_oc}
    for fc in FC_FIXED:  # the clip fraction not read off the room: how much it matters
        rows_patch[f"model fc={fc}"] = off_c - model_offset(w_c, n_c, np.full(len(X), fc))
        rows_open[f"model fc={fc}"] = rows_open["model"]
    st_p = per_edge(off_c - off_t, edge)
    st_o = per_edge(off_oc - off_ot, eo) if len(Xo) else {}
    fits = {}
    for prior_name, cov in (("fit", cov_fit), ("jackknife", cov_jk)):
        Ip = np.linalg.pinv(cov)
        for sources in ("patch", "opening", "patch+opening"):
            if "opening" in sources and not len(Xo):
                continue
            for sun_mode in (("free", "held") if "patch" in sources else ("held",)):
                k = 8 if sun_mode == "free" else 6
                for label in rows_patch:
                    for floor_px in (0.1, 0.3):
                        Js, rs, ws = [], [], []
                        for src, JJ, rr, ee, st in (("patch", J, rows_patch[label], edge, st_p),
                                                    ("opening", Jo, rows_open[label], eo, st_o)):
                            if src not in sources:
                                continue
                            w = np.zeros(len(rr))
                            for e in np.unique(ee):
                                m = ee == e
                                sd = 0.0 if label == "exact" else np.nan_to_num(st[int(e)]["jackknife_px"], nan=0.3)
                                w[m] = 1.0 / (m.sum() * (sd ** 2 + floor_px ** 2))  # an edge's samples share one error
                            Js.append(JJ[:, :k]); rs.append(rr); ws.append(w)
                        JJ, rr, w = np.concatenate(Js), np.concatenate(rs), np.concatenate(ws)
                        A = np.zeros((k, k))
                        A[:6, :6] += Ip
                        A += JJ.T @ (w[:, None] * JJ)
                        p = np.linalg.solve(A + 1e-12 * np.eye(k), JJ.T @ (w * rr))
                        Cpost = np.linalg.inv(A)[:6, :6]
                        shift = np.einsum("vij,j->vi", JP, p[:6]).mean(axis=0)
                        std = float(np.sqrt(np.mean(np.einsum("vij,jk,vik->v", JP, Cpost, JP))))
                        std0 = float(np.sqrt(np.mean(np.einsum("vij,jk,vik->v", JP, cov, JP))))
                        cam_after = camera_at(x0 + p[:6])
                        fits[f"{prior_name}/{sources}/sun {sun_mode}/{label}/floor{floor_px}"] = {
                            "camera": {"K": cam_after.K.tolist(), "R": cam_after.R.tolist(), "t": cam_after.t.tolist(),
                                       "width": cam_after.width, "height": cam_after.height},
                            "d_after_px": (d_obj + shift).tolist(), "err_before_px": float(np.linalg.norm(d_obj)),
                            "err_after_px": float(np.linalg.norm(d_obj + shift)), "std_before_px": std0,
                            "std_after_px": std, "sun_deg": np.degrees(p[6:]).tolist(), "dx": p[:6].tolist()}
    fits["none"] = {"camera": {"K": c_ref.K.tolist(), "R": c_ref.R.tolist(), "t": c_ref.t.tolist(),
                               "width": c_ref.width, "height": c_ref.height}, "err_before_px": float(np.linalg.norm(d_obj)),
                    "err_after_px": float(np.linalg.norm(d_obj))}
    fits["truth"] = {"camera": {"K": truth.K.tolist(), "R": truth.R.tolist(), "t": truth.t.tolist(),
                                "width": truth.width, "height": truth.height}, "err_before_px": float(np.linalg.norm(d_obj)),
                     "err_after_px": 0.0}
    out["joint"] = fits
    return out


if __name__ == "__main__":
    main()
