"""What shade107 costs (issue 34): the shading mesh's cut (once per shape) and vertex_light's second bounce between
the object's own parts (per frame), A/B in one process, CPU time, on each ROOM's object.

    python bench/bench_shade107_cost.py ROOM_DIR [ROOM_DIR ...]
"""
from __future__ import annotations

import sys
import time

import numpy as np


def main(rooms: list[str]) -> None:
    import app.stages.object_shading as osh
    from app.config import ObjectConfig
    from app.stages.own_cuts import cut_along_own_contacts
    from kernels import runtime
    from recon.proxy import subdivide
    from recon.scene import load_scene

    runtime.init()
    oc = ObjectConfig()
    for room in rooms:
        obj = load_scene(room).obj
        v, n, f = subdivide(obj.vertices, obj.normals, obj.faces, max_edge=0.08, max_faces=3000)
        t = time.process_time()
        for _ in range(5):
            cv, cn, cf, groups = cut_along_own_contacts(v, n, f)
        cut_s = (time.process_time() - t) / 5
        ss = osh.ShapeShading(cv - cv.mean(0), cn, cf, oc.prt_dirs, oc.dB_samples, "cpu", oc.vis_stride, 0)
        rng = np.random.default_rng(0)
        L_room, L_sun = rng.random((len(cv), 3)), rng.random((len(cv), 3))
        albedo = np.array([0.5, 0.4, 0.3])
        fill = lambda x: osh._fill_from_neighbours(x, cf, ss.buried)  # noqa: E731
        cpu = {1: 0.0, 2: 0.0}
        for _ in range(10):  # rounds, the variants interleaved
            for b in (1, 2):
                osh.SELF_BOUNCES = b
                t = time.process_time()
                osh.vertex_light(L_room, L_sun, fill, ss.bounce, albedo)
                cpu[b] += (time.process_time() - t) / 10
        osh.SELF_BOUNCES = 2
        print(f"{room.rstrip('/').split('/')[-1]}: {len(f)} -> {len(cf)} faces, cut {1e3 * cut_s:.1f} ms CPU once per "
              f"shape; vertex_light 1 bounce {1e3 * cpu[1]:.1f} ms, 2 bounces {1e3 * cpu[2]:.1f} ms CPU per frame "
              f"(bounce {'none' if ss.bounce is None else f'{ss.bounce.nnz} entries'})")


if __name__ == "__main__":
    main(sys.argv[1:])
