"""Photo light's lamps with a split rule tried and not kept (docs/unseen.md "lamp110b"), the fit alone.

`python bench/bench_lamp_spread.py DELTA` on bench_lamp_pool.py's dumps in /tmp/lamp110b/dump (DUMP env var to
change): each emitter's fitted radiance over the truth's (luminance; lamps_108 divided by its photo's radiance scale
0.36, bench_lamp_bound.py --rooms). DELTA 0: the product. DELTA > 0: among the emitters' solutions whose walls'
residual is within (1 + DELTA) of the least, the one of least sum of squared wall contributions (ridge on the
columns' contributions, its weight by bisection): emitters the walls see alike share their light instead of
trading it. Not kept: the windows' radiance runs away (lamps_105 fill_window 0.59 -> 4.9x at DELTA 0.01).
"""
import os
import sys

import numpy as np
from scipy.optimize import lsq_linear

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from bench.bench_lamp_pool import load_dumps  # noqa: E402
from lighting import photolight, photoalbedo
from lighting.sources import luminance
delta = float(sys.argv[1])
orig = photoalbedo.solve_emitters
def spread(J1, w, L_S, a0, rho, lower, unresolved):
    e, std, at_bound, resid = orig(J1, w, L_S, a0, rho, lower, unresolved)
    rho = np.broadcast_to(np.asarray(rho, np.float64).reshape(-1, 1) if np.ndim(rho) < 2 else rho, (len(w), 3))
    for c in range(3):
        J = rho[:, c, None] * J1; b = w * (L_S[:, c] - rho[:, c] * a0[:, c])
        n = np.linalg.norm(J, axis=0); live = n > 0
        if live.sum() < 2: continue
        r0 = np.linalg.norm(J @ e[:, c] - b)
        Jn = J[:, live] / n[live]; lo = lower[live, c] * n[live]
        def solve(lam):
            A = np.vstack([Jn, np.sqrt(lam) * np.eye(live.sum())]); bb = np.concatenate([b, np.zeros(live.sum())])
            return lsq_linear(A, bb, bounds=(lo, np.inf), method="bvls").x
        lo_l, hi_l = 0.0, 1e4 * (b @ b)
        x = e[live, c] * n[live]
        for _ in range(40):
            mid = np.sqrt(max(lo_l, 1e-12 * (b @ b)) * hi_l)
            xm = solve(mid)
            if np.linalg.norm(Jn @ xm - b) <= (1 + delta) * r0: lo_l, x = mid, xm
            else: hi_l = mid
        e[live, c] = x / n[live]
    return e, std, at_bound, resid
if delta > 0:
    photolight._solve_emitters = spread
for room, d in load_dumps(os.environ.get("DUMP", "/tmp/lamp110b/dump")):
    args, kw = d["calls"][-1]
    rep = photolight.fit_photo_light(*args, **kw).report
    sc = 0.36 if room == "lamps_108" else 1.0
    print(room, " ".join(f"{e['name']}={luminance(np.array(e['radiance'])) / luminance(np.array(d['truth'][e['name']])) / sc:.2f}" for e in rep["emitters"] if e["name"] in d["truth"]))
