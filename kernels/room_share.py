"""The share of an object's light that reaches receiver points past the room (app.stages.object_light.room_share's
sum over the object's source groups, one thread per receiver, its segments tested in the same thread).

Per receiver x (unit normal n) and source group g (point s_g, unit normal m_g, power P_g), in float64:
  d = s_g - x;  r2 = max(d . d, 1e-12);  w_g = P_g max(d . n, 0) max(-(d . m_g), 0) / r2^2
  share(x) = sum_g w_g V(x + eps n -> s_g) / sum_g w_g   (1 where no group weighs anything)
V: the segment from the receiver lifted by eps to the group's point, in float32, unblocked by the room's mesh
(kernels.visibility.segment_blocked, as segments_visible tests it). The sums run in group order (numpy's sums
over the groups block them: the shares agree to ~1e-15 relative, not bit for bit).
"""
from __future__ import annotations

import numpy as np
import warp as wp

from kernels import runtime
from kernels.buffers import Workspace, call_buffers
from kernels.visibility import Occluder, segment_blocked


@wp.kernel
def _room_share_kernel(mesh: wp.uint64, points: wp.array(dtype=wp.vec3d), normals: wp.array(dtype=wp.vec3d),
                       src: wp.array(dtype=wp.vec3d), src_n: wp.array(dtype=wp.vec3d),
                       power: wp.array(dtype=wp.float64), n_src: int, eps: wp.float64,
                       out: wp.array(dtype=wp.float64)):
    i = wp.tid()
    x = points[i]
    n = normals[i]
    a = wp.vec3(x + n * eps)  # the segment's receiver end, float32 as segments_visible takes it
    total = wp.float64(0.0)
    seen = wp.float64(0.0)
    for g in range(n_src):
        d = src[g] - x
        r2 = wp.max(wp.dot(d, d), wp.float64(1e-12))
        w = power[g] * wp.max(wp.dot(d, n), wp.float64(0.0)) * wp.max(-wp.dot(d, src_n[g]), wp.float64(0.0)) / (
            r2 * r2)
        if w > wp.float64(0.0):
            total += w
            if not segment_blocked(mesh, a, wp.vec3(src[g])):
                seen += w
    share = wp.float64(1.0)
    if total > wp.float64(0.0):
        share = seen / total
    out[i] = share


def room_share_launch(points: np.ndarray, normals: np.ndarray, src: np.ndarray, src_n: np.ndarray,
                      power: np.ndarray, room: Occluder, eps: float, workspace: Workspace | None = None,
                      capacity: int = 0, split: int = 256) -> np.ndarray:
    """(N,) float64 in [0, 1]: the share (module docstring) at points (N,3) [unit normals (N,3)] of the source
    groups at src (G,3) [unit normals src_n (G,3), power (G,)] past the room's occluder `room`, the receiver ends
    lifted by eps (m). workspace: the call site's buffers (launches of at most its rows receivers; the groups'
    buffers of at least `capacity` rows: nothing allocated after the first call), None: fresh buffers, one
    launch. On the CPU more than `split` receivers run as two halves side by side, one per core
    (runtime.run_parallel; each receiver's share is its own thread's: the same values)."""
    n = len(points)
    out = np.ones(n)
    if n == 0 or len(src) == 0:
        return out
    device = room.device
    ws, block = call_buffers(workspace, n)
    cap = max(len(src), capacity)
    shared = [ws.upload("src", np.asarray(src, np.float64), wp.vec3d, device, cap),
              ws.upload("src_n", np.asarray(src_n, np.float64), wp.vec3d, device, cap),
              ws.upload("power", np.asarray(power, np.float64), wp.float64, device, cap), int(len(src)),
              float(eps)]
    cpu = wp.get_device(device).is_cpu
    # a kept workspace gets both slots' buffers on its first call: a later call of more than `split` receivers (the
    # object moved near more of the room) splits over both without allocating
    for slot in range(2 if cpu and block == ws.rows else 1):
        ws.buffer(f"share{slot}", block, wp.float64, device)
        for name in ("points", "normals"):
            ws.buffer(f"{name}{slot}", block, wp.vec3d, device)

    def run(lo: int, hi: int, slot: int) -> None:  # slot: which concurrent launch (its own buffers)
        res = ws.buffer(f"share{slot}", block, wp.float64, device)
        wp.launch(_room_share_kernel, dim=hi - lo, device=device,
                  inputs=[wp.uint64(room.id), ws.upload(f"points{slot}", np.asarray(points[lo:hi], np.float64),
                                                        wp.vec3d, device, block),
                          ws.upload(f"normals{slot}", np.asarray(normals[lo:hi], np.float64), wp.vec3d, device,
                                    block), *shared],
                  outputs=[res.dev[:hi - lo]])
        out[lo:hi] = res.pull(hi - lo)

    halves = [(0, n)] if n <= split or not cpu else [(0, n // 2), (n // 2, n)]
    parts = [[(s, min(e, s + block)) for s in range(a, e, block)] for a, e in halves]
    for k in range(max(len(p) for p in parts)):  # the halves side by side, one per core on the CPU
        runtime.run_parallel([lambda r=p[k], i=i: run(*r, i) for i, p in enumerate(parts) if k < len(p)])
    return out
