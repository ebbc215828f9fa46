"""bench_unseen's flow (cam107's code) with every refine_camera call also made with the fine stages as before cam107
(bench_guard106.without_clipped_edges): appends to LOG, per call, whether the two cameras are bitwise identical
(a room whose cameras all are gives the same composites).

    python bench/bench_cam107_flowcheck.py LOG [bench_unseen.py's arguments]
"""
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench import bench_unseen
from bench.bench_guard106 import without_clipped_edges
from recon import camrefine as cr
orig = cr.refine_camera
log = open(sys.argv[1], 'a')
def wrapped(cam, prims, image, *a, **k):
    r = orig(cam, prims, image, *a, **k)
    with without_clipped_edges():
        r0 = orig(cam, prims, image, *a, **k)
    same = all(np.array_equal(getattr(r.camera, f), getattr(r0.camera, f)) for f in ('K', 'R', 't'))
    log.write(f"identical {same} accepted {r.accepted}/{r0.accepted} sun {k.get('sun') is not None} reason {r.reason[:60]!r}\n"); log.flush()
    return r
cr.refine_camera = wrapped
bench_unseen.main(sys.argv[2:])
