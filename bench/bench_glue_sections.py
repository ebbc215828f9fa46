"""Glue CPU (rendering thread CPU less its kernels') inside named functions, inclusive, ms per frame."""
import sys, dataclasses, time, threading, importlib, collections
sys.path.insert(0, "/work/wt/glue48")
from app.composite import default_cache_dir
from app.dragpath import drag_offsets, moved
from app.engine import Engine, EngineParams
from app.evaluate import DRAG_PASSES, DRAG_SCALE, DRAG_SHADOW
from recon.scene import load_scene
from bench.bench_drag import scene_dir
from bench.bench_glue_cpu import ThreadCpu

SECTIONS = [("app.stages.object_drag", "DragObject.shade"), ("app.stages.object_drag", "DragObject.proxy_radiance"),
            ("app.stages.object_light", "ObjectLight.light"), ("app.stages.object_light", "ObjectLight.centre_light_parts"),
            ("app.stages.object_light", "ObjectLight._coarse_centres"), ("app.stages.object_light", "_reflected"), ("app.stages.object_light", "room_share"), ("app.stages.object_light", "_light_bound"), ("app.stages.object_light", "ObjectLight._drag_sums"),
            ("app.stages.object_light", "_exact_sum"), ("app.stages.sun", "SunStage.object_emitters"),
            ("app.stages.sun", "SunStage.later_at_patches"), ("app.stages.sun", "SunStage.later_bounces"),
            ("app.stages.sun", "SunStage.refine_clipped_edges"),
            ("app.stages.object_shading", "lift_off_contacts"), ("app.stages.object_drag", "disk_sh"),
            ("kernels.hit_average", "hit_average"), ("kernels.drag_gather", "gather_seen"),
            ("app.engine", "Engine._object_light"), ("app.engine", "Engine.frame_object"),
            ("app.engine", "Engine._sun_later_bounces"), ("app.stages.compose", "ComposeStage.second_order"),
            ("lighting.frame_sources", "ShadowSources.select"), ("lighting.frame_sources", "ShadowSources.traverse"),
            ("app.stages.object_shading", "ObjectShading.object_hits")]
name = sys.argv[1]
n_path = int(sys.argv[2]) if len(sys.argv) > 2 else 8
scene = load_scene(scene_dir(name))
eng = Engine(scene, EngineParams(), cache_dir=default_cache_dir(), quiet=True)
cfg = dataclasses.replace(eng.frame_config(), passes=DRAG_PASSES, drag=DRAG_SCALE, drag_shadow=DRAG_SHADOW)
offsets = drag_offsets(scene, scene.obj, n_path)
for o in offsets[:2]:
    eng.render(moved(scene.obj, o), cfg)
cpu = ThreadCpu()
acc = collections.defaultdict(float)
depth = collections.Counter()
def wrap(label, fn):
    def w(*a, **k):
        if threading.get_ident() != cpu.main or depth[label]:
            return fn(*a, **k)
        depth[label] += 1
        c, k0 = time.thread_time(), cpu.kernel
        try:
            return fn(*a, **k)
        finally:
            acc[label] += (time.thread_time() - c) - (cpu.kernel - k0)
            depth[label] -= 1
    return w
import sys as _s
for mod, qual in SECTIONS:
    try:
        m = importlib.import_module(mod)
    except Exception as e:
        print("skip", mod, e); continue
    parts = qual.split(".")
    owner = m
    for p in parts[:-1]:
        owner = getattr(owner, p, None)
    if owner is None or not hasattr(owner, parts[-1]):
        print("skip", qual); continue
    fn = getattr(owner, parts[-1])
    setattr(owner, parts[-1], wrap(qual, fn))
    if owner is m:  # module function: patch importers too
        for mm in list(_s.modules.values()):
            if mm is not None and getattr(mm, parts[-1], None) is fn:
                setattr(mm, parts[-1], getattr(owner, parts[-1]))
acc.clear(); cpu.stage.clear()
for o in offsets:
    cpu.start_frame()
    eng.render(moved(scene.obj, o), cfg)
n = len(offsets)
print(name, "glue cpu per stage:", {k: round(1e3 * v / n, 1) for k, v in cpu.stage.items()})
for k, v in sorted(acc.items(), key=lambda x: -x[1]):
    print(f"  {1e3 * v / n:6.2f}  {k}")
