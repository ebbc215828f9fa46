"""`photoar reference SCENE_DIR --spp N --out DIR`: a ray-traced differential-rendering reference.

For scenes without a truth photo (a user's own room), the seed's comparison against a
ray-traced image (sec. 7, figs. 17-18) needs photoar's own reference: Debevec's differential
rendering by Monte-Carlo path tracing (kernels.pathtrace) over the same scene model,

  reference = T(L_b - (I_noobj - I_obj))   where the camera sees the room,
              T(I_obj)                      where it sees the object,

with L_b the photo through the inverse camera response; where the photo clips (a channel at 255,
e.g. the sunlit floor) L_b is only a floor of the radiance and max(L_b, I_noobj) takes its place
(I_noobj of the same batch of samples). Samples are taken in batches of equal
size; each batch is an unbiased estimate on its own, so the spread of the batch means gives the
standard error of every pixel (the noise estimate). Rendering stops at --spp or as soon as the
noise in the pixels the object changes falls below --noise-target (8-bit levels).

Outputs (atomically, in --out): reference.png (8-bit through the scene's response),
reference.exr (radiance), I_obj.exr, I_noobj.exr (the two HDR renders of the model),
noise.exr (standard error of reference.exr per pixel and channel), report.json.

A scene with a sun and openings has the sun traced through them (kernels.pathtrace): with --lighting
known the declared sun, with captured / photo the sun the engine estimates from the photo (report.json
`sun`: null when none is traced).
"""
from __future__ import annotations

import argparse
import logging
import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from tqdm import tqdm

from recon.response import LUMA


log = logging.getLogger("photoar")


@dataclass
class Reference:
    """A rendered reference; images (H,W,3) float64 radiance in scene units unless noted."""

    composite: np.ndarray  # differential composite (radiance)
    pixels: np.ndarray  # (H,W,3) uint8, composite through the camera response
    I_obj: np.ndarray  # the model with the object
    I_noobj: np.ndarray  # the model without it
    coverage: np.ndarray  # (H,W) fraction of samples whose camera ray hits the object
    noise: np.ndarray  # standard error of `composite` per pixel and channel
    noise_diff: np.ndarray  # standard error of I_noobj - I_obj
    rendered: np.ndarray  # (H,W) bool: pixels that were rendered (the others keep the photo)
    spp: int
    stats: dict = field(default_factory=dict)


def build_tracer(scene, patch_size: float = 0.18, emitter_patch_size: float = 0.1, textures: bool = True,
                 patches=None, device: str | None = None, sun="scene"):
    """kernels.pathtrace.PathTracer over the scene model's patches (or the given PatchMesh, e.g.
    an Engine's captured radiance mesh) with the scene's object; `textures` uses each quad's albedo
    texture where the model has one instead of the per-patch mean. sun: the recon.scene.Sun traced
    through the scene's openings ("scene": the scene's declared sun; None: no sun)."""
    from kernels.pathtrace import PathTracer
    from recon.patches import build_patches

    if scene.obj is None:
        raise ValueError(f"{scene.meta.get('json_path', scene.root)}: missing field 'synthetic_object' "
                         "(nothing to insert)")
    pm = patches if patches is not None else build_patches(scene, patch_size, emitter_patch_size)
    tex = [q.texture for q in scene.quads] if textures else None
    corners = np.stack([q.corners for q in scene.quads]) if textures else None
    o = scene.obj
    sun = scene.sun if isinstance(sun, str) and sun == "scene" else sun
    return PathTracer(pm, scene.camera, o.vertices, o.normals, o.faces, o.albedo, tex, corners, device=device,
                      sun=sun, quad_opening=np.array([q.opening for q in scene.quads], bool))


def noise_summary(ref_radiance: np.ndarray, se: np.ndarray, se_diff: np.ndarray, photo_radiance: np.ndarray,
                  I_obj: np.ndarray, I_noobj: np.ndarray, coverage: np.ndarray, response) -> dict:
    """Noise figures of a reference over N rendered pixels (arrays (N,3) / (N,)).

    noise_levels_rms / _p95: standard error of the 8-bit luminance, (T(L + se) - T(L - se)) / 2, over
      the pixels the object changes (covered, or more than 2 levels and 2 standard errors from the
      photo);
    shadow_noise: RMS standard error of luminance(I_noobj - I_obj) in radiance over the object's
      shadow (not covered, luminance(I_obj) < 0.85 luminance(I_noobj)), the definition of the
      benchmark scenes' `shadow_difference_noise_final`; shadow_signal: mean of that difference.
    """
    se = np.nan_to_num(se, nan=0.0)
    se_lv = 0.5 * (response.to_levels(ref_radiance + se)
                   - response.to_levels(np.maximum(ref_radiance - se, 0.0))) @ LUMA
    lv_ref = response.to_levels(ref_radiance) @ LUMA
    lv_photo = response.to_levels(photo_radiance) @ LUMA
    dlv = np.abs(lv_ref - lv_photo)
    changed = (coverage > 0) | ((dlv > 2.0) & (dlv > 2.0 * se_lv))
    shadow = (coverage == 0) & (I_obj @ LUMA < 0.85 * (I_noobj @ LUMA))
    se_d = se_diff @ LUMA
    out = {
        "changed_px": int(changed.sum()),
        "noise_levels_rms": float(np.sqrt(np.mean(se_lv[changed] ** 2))) if changed.any() else 0.0,
        "noise_levels_p95": float(np.percentile(se_lv[changed], 95)) if changed.any() else 0.0,
        "shadow_px": int(shadow.sum()),
        "shadow_noise": float(np.sqrt(np.mean(se_d[shadow] ** 2))) if shadow.any() else 0.0,
        "shadow_signal": float(np.mean(((I_noobj - I_obj) @ LUMA)[shadow])) if shadow.any() else 0.0,
    }
    return out


def render_reference(scene, spp: int, seed: int = 0, batch_spp: int | None = None,
                     noise_target: float | None = None, bounces: int = 4, pixels: np.ndarray | None = None,
                     tracer=None, photo_radiance: np.ndarray | None = None, response=None,
                     quiet: bool = False, **tracer_args) -> Reference:
    """Render the differential reference of `scene` (recon.scene.Scene with its object).

    spp: most samples per pixel (rounded up to whole batches of `batch_spp`, default spp/8, so the
      noise estimate has at least 8 batch means when spp >= 8); noise_target: stop once
      noise_levels_rms (see noise_summary) is at most this many 8-bit levels (checked from the
      third batch on); pixels: flat indices (row*W+col) to render, default all, the others keep
      the photo; photo_radiance (H*W,3) and response: L_b and T (default: the scene's photo
      through the scene's response); tracer: a PathTracer (else build_tracer(scene, **tracer_args)).
    """
    if spp < 1:
        raise ValueError(f"spp must be at least 1, got {spp}")
    cam = scene.camera
    H, W = cam.height, cam.width
    response = response or scene.response
    L_b_all = (photo_radiance if photo_radiance is not None else response.to_radiance(scene.photo)).reshape(-1, 3)
    pix = np.arange(H * W) if pixels is None else np.unique(np.asarray(pixels, np.int64))
    t0 = time.perf_counter()
    tracer = tracer or build_tracer(scene, **tracer_args)
    setup_s = time.perf_counter() - t0
    batch = batch_spp or max(1, spp // 8)
    n_batches = math.ceil(spp / batch)
    L_b = L_b_all[pix]
    # pixels the photo clips: L_b there is a floor, not the radiance (the sunlit floor); a shadow taken
    # from it would be too dark, so they start from the model's radiance where that is brighter
    clipped = (np.asarray(scene.photo).reshape(-1, 3)[pix] >= 255).any(1)
    n = len(pix)
    tot = {k: np.zeros((n, 3)) for k in ("noobj", "obj", "diff", "obj_hit")}
    count = np.zeros(n)
    m1, m2 = np.zeros((n, 3)), np.zeros((n, 3))  # sums of batch means of the composite and their squares
    d1, d2 = np.zeros((n, 3)), np.zeros((n, 3))  # the same for I_noobj - I_obj
    done, stopped_by, summary = 0, "spp", {}
    t1 = time.perf_counter()
    bar = tqdm(total=n_batches * batch, desc="reference", unit="spp", disable=quiet or not sys.stderr.isatty(),
               leave=False, dynamic_ncols=True)
    with bar:
        for k in range(n_batches):
            r = tracer.render(pix, batch, first_sample=k * batch, seed=seed, bounces=bounces)
            for name in tot:
                tot[name] += getattr(r, name)
            count += r.obj_count
            L_start = L_b.copy()
            L_start[clipped] = np.maximum(L_b[clipped], r.noobj[clipped] / batch)
            comp = (r.obj_hit + (batch - r.obj_count)[:, None] * L_start - r.diff) / batch
            dm = (r.noobj - r.obj) / batch
            m1 += comp
            m2 += comp ** 2
            d1 += dm
            d2 += dm ** 2
            done = k + 1
            bar.update(batch)
            if noise_target is not None and done >= 3:
                summary = _summary(done, m1, m2, d1, d2, tot, count, batch, L_b, response)
                bar.set_postfix(noise=f"{summary['noise_levels_rms']:.2f} lv")
                if summary["noise_levels_rms"] <= noise_target:
                    stopped_by = "noise_target"
                    break
    render_s = time.perf_counter() - t1
    N = done * batch
    comp = m1 / done
    se = _se(m1, m2, done)
    se_d = _se(d1, d2, done)
    summary = _summary(done, m1, m2, d1, d2, tot, count, batch, L_b, response)

    def image(values: np.ndarray, fill: np.ndarray) -> np.ndarray:
        out = np.array(fill, np.float64).reshape(H * W, -1)
        out[pix] = values.reshape(n, -1)
        return out.reshape(H, W, -1).squeeze(-1) if out.shape[1] == 1 else out.reshape(H, W, -1)

    zeros = np.zeros((H * W, 3))
    composite = image(np.maximum(comp, 0.0), L_b_all)
    rendered = np.zeros(H * W, bool)
    rendered[pix] = True
    stats = {"spp": N, "batches": done, "batch_spp": batch, "seed": seed, "bounces": bounces,
             "stopped_by": stopped_by, "noise_target_levels": noise_target, "rendered_px": n,
             "setup_s": setup_s, "render_s": render_s, "paths_per_s": n * N / max(render_s, 1e-9),
             "textured_albedo": bool(getattr(tracer, "textured", False)), "sun": _sun_stats(tracer), **summary}
    return Reference(composite=composite, pixels=response.to_pixels(composite), I_obj=image(tot["obj"] / N, zeros),
                     I_noobj=image(tot["noobj"] / N, zeros), coverage=image(count / N, np.zeros(H * W)),
                     noise=image(se, zeros), noise_diff=image(se_d, zeros), rendered=rendered.reshape(H, W),
                     spp=N, stats=stats)


def _sun_stats(tracer) -> dict | None:
    """The sun the tracer traces through the openings (None: none): direction to it (unit) and its
    irradiance on a surface facing it (scene radiance units x sr)."""
    sun = getattr(tracer, "sun", None)
    if sun is None:
        return None
    d = np.asarray(sun.direction, np.float64)
    return {"direction_to_sun": (d / np.linalg.norm(d)).tolist(), "angular_diameter_deg": float(sun.angular_diameter_deg),
            "irradiance_perpendicular": np.asarray(sun.irradiance, np.float64).tolist()}


def _se(s1: np.ndarray, s2: np.ndarray, k: int) -> np.ndarray:
    """Standard error of the mean of k batch means from their sum and sum of squares."""
    if k < 2:
        return np.full_like(s1, np.nan)
    var = np.maximum(s2 / k - (s1 / k) ** 2, 0.0) * k / (k - 1)
    return np.sqrt(var / k)


def _summary(done, m1, m2, d1, d2, tot, count, batch, L_b, response) -> dict:
    N = done * batch
    return noise_summary(np.maximum(m1 / done, 0.0), _se(m1, m2, done), _se(d1, d2, done), L_b, tot["obj"] / N,
                         tot["noobj"] / N, count / N, response)


def _positive_int(s: str) -> int:
    v = int(s)
    if v < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {v}")
    return v


def register(sub) -> None:
    p = sub.add_parser("reference", help="path-traced differential-rendering reference of a scene (no truth needed)")
    p.add_argument("scene", type=Path, help="scene folder (scene.json, background.png, object mesh)")
    p.add_argument("--spp", type=_positive_int, default=64, help="most samples per pixel (default %(default)s)")
    p.add_argument("--out", type=Path, required=True, help="output folder")
    p.add_argument("--noise-target", type=float, default=None,
                   help="stop earlier once the RMS standard error over the pixels the object changes is at most "
                        "this many 8-bit levels")
    p.add_argument("--seed", type=int, default=0, help="random seed (default %(default)s)")
    p.add_argument("--batch-spp", type=_positive_int, default=None,
                   help="samples per batch; batch means give the noise estimate (default spp/8)")
    p.add_argument("--bounces", type=int, default=4,
                   help="surface vertices that gather light after the camera hit (default %(default)s, as the "
                        "benchmark truth)")
    p.add_argument("--patch-size", type=float, default=0.18, help="model patch size, metres (default %(default)s)")
    p.add_argument("--no-textures", action="store_true", help="per-patch mean albedo instead of the quads' textures")
    from app.cli import add_lighting_arg

    add_lighting_arg(p)
    p.add_argument("--cache", type=Path, default=None, help="engine precompute cache (--lighting captured)")
    p.add_argument("--device", default=None, help="Warp device, e.g. cpu or cuda:0 (default cpu)")
    p.set_defaults(run=run)


def run(a: argparse.Namespace) -> int:
    from recon.io import AtomicOutput, write_exr, write_json, write_png
    from recon.scene import load_scene

    if a.noise_target is not None and not a.noise_target > 0:
        raise ValueError(f"--noise-target must be positive, got {a.noise_target}")
    if a.bounces < 0:
        raise ValueError(f"--bounces must be at least 0, got {a.bounces}")
    scene = load_scene(a.scene)
    if scene.obj is None:
        raise ValueError(f"{a.scene / 'scene.json'}: missing field 'synthetic_object' (nothing to insert)")
    kw: dict = {}
    if a.lighting in ("captured", "photo"):
        from app.composite import default_cache_dir
        from app.engine import Engine, EngineParams

        eng = Engine(scene, EngineParams(lighting=a.lighting), cache_dir=a.cache or default_cache_dir(),
                     device=a.device, quiet=a.quiet)
        scene = eng.scene  # carries the response recovered from the bracket
        sun = eng.sun.light.sun if eng.sun.on else None  # the sun estimated from the photo (never the declared one)
        if sun is None and scene.sun is not None and a.lighting == "captured":  # photo warns in the engine
            log.warning("%s: sun: no sun estimated from the photo (%s); the reference traces "
                        "none", a.scene / "scene.json", (eng.sun.estimate or {}).get("reason", "it lights nothing"))
        kw = dict(tracer=build_tracer(scene, textures=False, patches=eng.pre.patches, device=a.device, sun=sun),
                  photo_radiance=eng.receivers.L_b, response=scene.response)
    else:
        if scene.response is None:
            raise ValueError(f"{a.scene / 'scene.json'}: missing field 'camera_response'; --lighting known needs "
                             f"the camera's response (or use --lighting captured)")
        if not any(q.is_emitter for q in scene.quads):
            raise ValueError(f"{a.scene / 'scene.json'}: no emitters (no primitive declares emitted_radiance); "
                             f"use --lighting captured")
        kw = dict(patch_size=a.patch_size, textures=not a.no_textures, device=a.device)
        if scene.sun is not None and scene.sun.strength_estimated:
            raise ValueError(f"{a.scene / 'scene.json'}: sun: its strength is to be estimated from the photo "
                             "(\"strength\": \"estimate\"): use --lighting captured")
        if scene.sun is not None and not any(q.opening for q in scene.quads):
            log.warning("%s: sun: the scene has no opening (window with \"opening\": true); the "
                        "sun is not traced", a.scene / "scene.json")
    ref = render_reference(scene, a.spp, seed=a.seed, batch_spp=a.batch_spp, noise_target=a.noise_target,
                           bounces=a.bounces, quiet=a.quiet, **kw)
    report = {"scene": str(a.scene), "lighting": a.lighting, "patch_size": a.patch_size, **ref.stats}
    with AtomicOutput(a.out) as stage:
        write_png(stage / "reference.png", ref.pixels)
        write_exr(stage / "reference.exr", ref.composite)
        write_exr(stage / "I_obj.exr", ref.I_obj)
        write_exr(stage / "I_noobj.exr", ref.I_noobj)
        write_exr(stage / "noise.exr", ref.noise)
        write_json(stage / "report.json", report)
    log.info("reference: %d spp (%s) in %.1f s, noise %.2f levels RMS over %d changed pixels",
             ref.spp, ref.stats["stopped_by"], ref.stats["render_s"], ref.stats["noise_levels_rms"],
             ref.stats["changed_px"])
    print(a.out / "reference.png")
    return 0
