"""Why the drag frame's energy drifts at few passes (issue 36): each cluster's blocked light against its members'.

usage: python bench/bench_cluster_occlusion.py [--scenes sun_room,window_room | DIR,...] [--passes 64,48,32,24]

Per scene (the shared scenes by name, or benchmark folders such as ~/.cache/photoar/rooms/sun_101), at the
scene's own pose, in the receiver-vertex domain the clusters' weights live in (each vertex weighted by its pixel
footprint, as the representatives' key is; luminance):
  exact      sum over the marked sources s and vertices v of G_v[v, s] B_s where the segment v -> s hits the
             object's proxy (one ray each; only segments that meet the object's box are cast): the light one
             pass per source blocks;
  clustered  per pass of the drag frame's selection (ShadowSources.select, near_split, `passes` - 1 with a
             sun), its weight W_v[v, k] where the segment v -> eye_k hits the proxy: what its one map blocks;
and prints clustered / exact per pass count, then the six clusters of largest |clustered - exact|: members,
the eye's distance to the object's box, the members' extent, both sums (as shares of exact), the strongest
member's share of the cluster's box-blocked light and the largest member radiance. No timing; the engine is
built with the default precompute cache.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.composite import default_cache_dir  # noqa: E402
from app.engine import Engine, EngineParams, FrameConfig  # noqa: E402
from bench.bench_drag import scene_dir  # noqa: E402
from kernels.raycast import cast_rays  # noqa: E402
from recon.response import luminance  # noqa: E402
from recon.scene import load_scene  # noqa: E402


def segments_meet_box(p: np.ndarray, q: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Bool (broadcast of p, q (...,3)): the segment p -> q meets the box [lo, hi] (slab test)."""
    d = q - p
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        t1, t2 = (lo - p) * inv, (hi - p) * inv
    tmin = np.nanmax(np.minimum(t1, t2), axis=-1)
    tmax = np.nanmin(np.maximum(t1, t2), axis=-1)
    return (tmax >= np.maximum(tmin, 0.0)) & (tmin <= 1.0)


def hits(occ, p: np.ndarray, e: np.ndarray, lo: np.ndarray, hi: np.ndarray, rows: int = 256) -> tuple:
    """(hit, box) bool (len(p), len(e)): the segment p_i -> e_j hits the occluder / meets the box."""
    hit = np.zeros((len(p), len(e)), bool)
    box = np.zeros_like(hit)
    for i0 in range(0, len(p), rows):
        bh = segments_meet_box(p[i0:i0 + rows, None], e[None], lo, hi)
        box[i0:i0 + rows] = bh
        a, b = np.nonzero(bh)
        if len(a):
            o = p[i0 + a]
            d = e[b] - o
            L = np.linalg.norm(d, axis=1)
            tri, _, dep = cast_rays(occ, o, d / np.maximum(L, 1e-12)[:, None])
            hit[i0 + a, b] = (tri >= 0) & (dep < L)
    return hit, box


def diagnose(d: Path, passes: list[int]) -> None:
    scene = load_scene(d)
    eng = Engine(scene, EngineParams(), cache_dir=default_cache_dir(), quiet=True)
    eng.render(scene.obj, FrameConfig(passes=passes[0], drag=3))  # the drag stages made
    ss, pre, r = eng.shadow_sources, eng.pre, eng.receivers
    pts = pre.patches.vert_pos[pre.recv_vert]
    wpx = np.bincount(r.pix_rows[r.recv_pix].ravel(), pre.pix_bary[r.recv_pix].ravel(), len(pre.recv_vert))
    pv, _, occ, *_ = eng.object_shading.object_shape(scene.obj)
    lo, hi = np.floor(pv.min(0) / 1e-3) * 1e-3, np.ceil(pv.max(0) / 1e-3) * 1e-3  # select's grid
    sun = eng.sun_pixels.stage is not None
    marked = ss.traverse(lo, hi)[0]
    pos = np.flatnonzero(marked)
    ids = ss.src_ids[pos]
    V = np.flatnonzero(wpx > 0)
    w = wpx[V]
    hit, box = hits(occ, pts[V], ss.eye_pos[ids], lo, hi)
    T = np.asarray(ss.G_v[np.ix_(V, ids)], np.float64) * luminance(ss.B[ids])[None]
    exact_s = (w[:, None] * T * hit).sum(0)
    exact = exact_s.sum()
    box_s = (w[:, None] * T * box).sum(0)
    print(f"\n{d.name}: {len(V)} receiver vertices seen, {len(pos)} marked sources, sun {sun}; "
          f"exact blocked {exact:.4g}")
    key, nf = ss.blocked_key(lo, hi), ss.near_factor(lo, hi)
    for P in passes:
        fs = ss.select(lo, hi, P - int(sun), near_split=True)
        n = len(fs.eyes)
        nodes = ss.representatives(marked, P - int(sun), key, nf)
        starts = np.searchsorted(pos, ss.src_tree.lo[nodes])
        cnt = np.diff(np.append(starts, len(pos)))
        memb = np.repeat(np.arange(n), cnt)
        eh = hits(occ, pts[V], fs.eyes, lo, hi)[0]
        clustered_c = (w[:, None] * luminance(np.asarray(fs.W_v[V], np.float64)) * eh).sum(0)
        exact_c = np.bincount(memb, exact_s, n)
        dist = np.linalg.norm(np.maximum(0, np.maximum(lo - fs.eyes, fs.eyes - hi)), axis=1)
        ext = np.array([np.ptp(ss.eye_pos[ids[memb == c]], 0).max() for c in range(n)])
        near = dist < ext  # the object lies within the cluster's extent of its eye
        print(f"  P={P}: {n} source passes ({np.sum(cnt > 1)} clusters): clustered / exact "
              f"{clustered_c.sum() / exact:.3f}; the {near.sum()} clusters whose eye is nearer the box than their "
              f"extent: {clustered_c[near].sum() / exact:.3f} against {exact_c[near].sum() / exact:.3f}")
        for c in np.argsort(-np.abs(clustered_c - exact_c))[:6]:
            m = memb == c
            print(f"    {cnt[c]:4d} src, eye {dist[c]:.2f} m from the box, extent {ext[c]:.2f} m: clustered "
                  f"{clustered_c[c] / exact:.3f} exact {exact_c[c] / exact:.3f}; top member "
                  f"{box_s[m].max() / max(box_s[m].sum(), 1e-30):.2f} of its box-blocked light, max radiance "
                  f"{ss.B[ids[m]].max():.3g}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default="sun_room,window_room")
    ap.add_argument("--passes", default="64,48,32,24")
    a = ap.parse_args()
    for name in a.scenes.split(","):
        diagnose(scene_dir(name), [int(p) for p in a.passes.split(",")])
        sys.stdout.flush()


if __name__ == "__main__":
    main()
