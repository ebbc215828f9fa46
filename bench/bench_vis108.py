"""The object's score against the order of its mesh, under known light (issue 34, branch vis108).

For each room: one Engine (`--lighting known`, the benchmark folder's own camera and light), then for each
subset rule and each variant of the object's mesh, the frame at rest (`evaluate --passes all`) and, with
--drag, the drag frame at the scene's pose (`evaluate --path N`'s "drag" row: rendered twice, the second
scored), scored by lighting.metrics against truth.png. Variant 0 is the scene's own mesh; variant s > 0 the
same mesh with its faces, its vertices and each face's corners (cyclically, winding kept) listed in an
order drawn from seed s. Rules: `spread` (this branch: ShapeShading.subsets, by position), `mesh` (main's
rule, reproduced here: every vis_stride-th distinct vertex in the order of its first copy in the mesh, the dB
gather's vertices every len(V)//dB_samples-th vertex of the mesh, and every vis_stride-th of those), `every`
(the reference both approximate: visibility cast and the dB loss gathered at every distinct vertex, each read at
its own vertex), and
`spread_vis` / `spread_sub` (spread's visibility samples with mesh's dB subsets / the other way round);
`spread_subvis` (spread, the dB gather's visibility cast at each of its vertices);

Prints one line per (rule, variant, frame): energy / rmse_affected / spurious / rmse_object and the
composite's sha256 prefix, then per rule and frame the spread (max - min) of rmse_object over the variants.
--variants: on branch shade107's code, own_cuts' cut on/off and SELF_BOUNCES per variant (cut:bounces).
--cost R: per rule, R rounds (rules interleaved) of ObjectShading._vertex_radiance on the frame at rest's own
arguments, CPU ms (time.process_time) each, median reported.

    python bench/bench_vis108.py ROOM_DIR [ROOM_DIR ...] --rules mesh,spread --shuffles 3 --drag --cost 5
"""
from __future__ import annotations

import argparse
import dataclasses
import gc
import hashlib
import time
from pathlib import Path

import numpy as np


def mesh_order_subsets(self, lu, nu, vis_stride, dB_samples):
    """main's rule (dfe2a05): the subsets in the mesh's own order."""
    V = len(self.inv)
    sub = np.unique(self.inv[np.arange(0, V, max(1, V // max(dB_samples, 1)))])
    return np.argsort(self.uniq)[::vis_stride], sub, np.arange(0, len(sub), vis_stride)


def every_subsets(self, lu, nu, vis_stride, dB_samples):
    """The reference the subsets approximate: visibility cast and the dB loss gathered at every distinct vertex."""
    a = np.arange(len(lu))
    return a, a, a


def hybrid(vis_rule, sub_rule):
    """The visibility samples of one rule with the dB gather's subsets of another (which subset carries the order)."""
    def rule(self, lu, nu, vis_stride, dB_samples):
        return vis_rule(self, lu, nu, vis_stride, dB_samples)[0], *sub_rule(self, lu, nu, vis_stride, dB_samples)[1:]
    return rule


def shuffled(obj, seed: int):
    """The object with its faces, vertices and each face's corners listed in an order drawn from `seed`."""
    rng = np.random.default_rng(seed)
    vp = rng.permutation(len(obj.vertices))
    new_index = np.empty_like(vp)
    new_index[vp] = np.arange(len(vp))
    f = new_index[np.asarray(obj.faces)[rng.permutation(len(obj.faces))]]
    shift = rng.integers(0, 3, len(f))
    f = np.stack([f[np.arange(len(f)), (shift + k) % 3] for k in range(3)], 1).astype(np.int32)
    return dataclasses.replace(obj, vertices=obj.vertices[vp], normals=obj.normals[vp], faces=f)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("rooms", nargs="+", type=Path)
    ap.add_argument("--rules", default="spread")
    ap.add_argument("--shuffles", type=int, default=0)
    ap.add_argument("--drag", action="store_true")
    ap.add_argument("--cost", type=int, default=0)
    ap.add_argument("--save", type=Path, default=None, help="write each composite as SAVE/ROOM_RULE_vS_FRAME.png")
    ap.add_argument("--variants", default="",
                    help="comma-separated cut:bounces (own_cuts' cut 1/0, SELF_BOUNCES), e.g. '1:2,1:1,0:2' "
                         "(default: the code as it is)")
    a = ap.parse_args()

    import cv2

    from app.composite import default_cache_dir
    from app.config import DRAG_PASSES, DRAG_SCALE, DRAG_SHADOW
    from app.engine import Engine, EngineParams
    from app.stages import object_shading as os_mod
    from lighting import metrics
    from recon.io import read_image_rgb
    from recon.scene import load_scene

    spread_rule = os_mod.ShapeShading.subsets
    cut = getattr(os_mod, "cut_along_own_contacts", None)
    knn_weights = os_mod._knn_weights

    def exact_knn(lu, nu, sub, k=6, scale=0.0):
        return np.arange(len(lu))[:, None], np.ones((len(lu), 1))

    def no_cut(v, n, f):
        return v, n, f, None

    def spread_subvis(self, lu, nu, vis_stride, dB_samples):
        vis, sub, _ = spread_rule(self, lu, nu, vis_stride, dB_samples)
        return vis, sub, np.arange(len(sub))

    rules = {"spread_subvis": spread_subvis, "spread": spread_rule, "mesh": mesh_order_subsets, "every": every_subsets,
             "spread_vis": hybrid(spread_rule, mesh_order_subsets), "spread_sub": hybrid(mesh_order_subsets, spread_rule)}
    for room in a.rooms:
        scene = load_scene(room)
        engine = Engine(scene, EngineParams(lighting="known"), cache_dir=default_cache_dir(), quiet=True)
        truth = read_image_rgb(room / "truth.png")
        mask = cv2.imread(str(room / "truth_mask.png"), cv2.IMREAD_GRAYSCALE)
        rest_cfg = dataclasses.replace(engine.frame_config(), passes=None)
        drag_cfg = dataclasses.replace(engine.frame_config(), passes=DRAG_PASSES, drag=DRAG_SCALE,
                                       drag_shadow=DRAG_SHADOW)
        spreads: dict[tuple, list[float]] = {}
        calls: dict[str, tuple] = {}
        variants = [tuple(int(x) for x in v.split(":")) for v in a.variants.split(",")] if a.variants else [None]
        for rule, variant in [(r, v) for r in a.rules.split(",") for v in variants]:
            base = rule
            os_mod.ShapeShading.subsets = rules[base]
            # `every`: the dB loss read at each vertex itself (no interpolation between vertices)
            os_mod._knn_weights = exact_knn if base == "every" else knn_weights
            if variant is not None:  # own_cuts' cut on or off, the self-bounces
                os_mod.cut_along_own_contacts = cut if variant[0] else no_cut
                os_mod.SELF_BOUNCES = variant[1]
                rule = f"{rule}[cut {variant[0]}, bounces {variant[1]}]"
            for s in range(a.shuffles + 1):
                obj = scene.obj if s == 0 else shuffled(scene.obj, s)
                engine.object_shading.forget_shapes()
                engine.object_drag._shape = None
                frames = {"rest": engine.render(obj, rest_cfg)}
                if s == 0 and a.cost:
                    ss = engine.object_shading._prt
                    calls[rule] = (ss, engine.object_shading._shade_occ, engine.object_shading._last_vr_args, variant)
                if a.drag:
                    engine.render(obj, drag_cfg)
                    frames["drag"] = engine.render(obj, drag_cfg)
                for name, fr in frames.items():
                    sc = metrics.score_regions(fr.pixels, scene.photo, truth, mask)
                    h = hashlib.sha256(np.ascontiguousarray(fr.pixels).tobytes()).hexdigest()[:8]
                    spreads.setdefault((rule, name), []).append(sc["rmse_object"])
                    if a.save is not None:
                        from recon.io import write_png

                        a.save.mkdir(parents=True, exist_ok=True)
                        write_png(a.save / f"{room.name}_{rule.replace(' ', '')}_v{s}_{name}.png", fr.pixels)
                    print(f"{room.name} {rule} v{s} {name}: {sc['energy_ratio']:.3f} / {sc['rmse_affected']:.2f} / "
                          f"{sc['spurious']:.4f} / {sc['rmse_object']:.2f}  sha {h}", flush=True)
        for (rule, name), v in spreads.items():
            if len(v) > 1:
                print(f"{room.name} {rule} {name}: rmse_object over {len(v)} orders {min(v):.2f}..{max(v):.2f} "
                      f"(spread {max(v) - min(v):.2f}, sd {np.std(v):.2f})", flush=True)
        if a.cost and calls:
            ms: dict[str, list[float]] = {r: [] for r in calls}
            for _ in range(a.cost):
                for rule, (prt, occ, args, variant) in calls.items():
                    if variant is not None:
                        os_mod.SELF_BOUNCES = variant[1]
                    engine.object_shading._prt, engine.object_shading._shade_occ = prt, occ
                    t = time.process_time()
                    engine.object_shading._vertex_radiance(*args)
                    ms[rule].append(1e3 * (time.process_time() - t))
            print(f"{room.name} object shading (vertex radiance) CPU ms, median of {a.cost}: "
                  + ", ".join(f"{r} {np.median(v):.1f}" for r, v in ms.items()), flush=True)
            # once per shape: ShapeShading made afresh on the frame at rest's shading mesh (centred), rules interleaved
            v, n, f = next(iter(calls.values()))[2][1]
            local, oc = v - v.mean(0), engine.object_shading.config
            build: dict[str, list[float]] = {r: [] for r in calls}
            for _ in range(a.cost):
                for rule in calls:
                    os_mod.ShapeShading.subsets = rules[rule.partition("[")[0]]
                    t = time.process_time()
                    os_mod.ShapeShading(local, n, f, oc.prt_dirs, oc.dB_samples, engine.object_shading.device,
                                        oc.vis_stride, len(engine.object_shading.room_light.emitters))
                    build[rule].append(1e3 * (time.process_time() - t))
            print(f"{room.name} ShapeShading (once per shape, {len(np.unique(np.round(np.c_[local, n], 6), axis=0))} "
                  f"distinct vertices) CPU ms, median of {a.cost}: "
                  + ", ".join(f"{r} {np.median(v):.1f}" for r, v in build.items()), flush=True)
        os_mod.ShapeShading.subsets, os_mod._knn_weights = spread_rule, knn_weights
        if cut is not None:
            os_mod.cut_along_own_contacts = cut
        del engine
        gc.collect()


if __name__ == "__main__":
    def _recording():
        from app.stages import object_shading as os_mod

        orig = os_mod.ObjectShading._vertex_radiance

        def rec(self, *args):
            self._last_vr_args = args
            return orig(self, *args)

        os_mod.ObjectShading._vertex_radiance = rec

    _recording()
    main()
