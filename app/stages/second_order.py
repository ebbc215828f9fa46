"""The second order's pairs that the object blocks (DESIGN "What the truth contains": second order).

The engine passes the change of patch radiance dB (the object's shadow on the patches, its reflected
light) on to the receiver vertices once, through the unoccluded transfers G_v. Where the object stands
between a receiver and a changed patch, the shadow pass has already taken that patch's whole radiance
from the receiver (the patch is one of the frame's sources): its change must not reach the receiver
again. lamps_102 (a torus under lamps, its soft shadows on the floor around it): half of the second order
at the receivers 1.5 m or more from the torus came over pairs the torus blocks,
and the wall came out darker than the truth over a wide area (-1.0 to -2.1 levels where the truth has
-0.6 to -1.3). The sun's own loss has the same rule in SunStage.later_bounces (first_pass_blocked).
"""
from __future__ import annotations

import numpy as np

from typing import Callable

from kernels.blocked_transfer import BlockedPairs
from kernels.buffers import Workspace
from kernels.visibility import Occluder, segments_visible
from recon.response import luminance

KEEP = 0.99  # share of the change's power (|luminance dB| x area) whose patches are tested; the rest,
# spread thinly over many patches, carries at most 1 % of it
EPS = 1e-3  # m: segment ends pulled off their surfaces along the normal
BLOCK = 512  # patches per block of pairs tested together (memory: Vr x BLOCK floats a few times)


def kept_patches(dB: np.ndarray, area: np.ndarray) -> np.ndarray:
    """The patches whose pairs are tested: the fewest of the largest |luminance dB| x area that hold KEEP of
    the change's power, largest first (empty when nothing changed)."""
    power = np.abs(luminance(dB)) * area
    order = np.argsort(-power)
    order = order[power[order] > 0]
    if len(order) == 0:
        return order
    keep = int(np.searchsorted(np.cumsum(power[order]), KEEP * power.sum())) + 1
    return order[:keep]


class BlockedSecondOrder:
    """blocked_pass's answer from one Warp launch (kernels.blocked_transfer.BlockedPairs): a thread per
    receiver vertex walks the kept patches, casts a ray only where the segment meets the box about the
    object and G_v > 0, and sums G_v dB over the blocked pairs in the launch (no pair lists in numpy, no
    per-block transfers gathered). The receiver vertices (lifted EPS) and G_v (float32) are uploaded once,
    when it is made (with the engine's stages); a call uploads only the kept patches' centres, columns and
    changes (buffers of capacity P: no frame allocates). Valid on any Warp device."""

    def __init__(self, G_v: np.ndarray, recv_points: np.ndarray, recv_normals: np.ndarray, centres: np.ndarray,
                 normals: np.ndarray, area: np.ndarray, device: str):
        """G_v (Vr,P) receiver-vertex -> patch transfers; recv_points, recv_normals (Vr,3) the receiver
        vertices; centres, normals (P,3), area (P,) m^2 the patches'."""
        self._b = centres + normals * EPS
        self._area = area
        self._pairs = BlockedPairs(recv_points + recv_normals * EPS, np.asarray(G_v, np.float32), device,
                                   capacity=len(self._b))

    def __call__(self, dB: np.ndarray, occluder: Occluder, box: tuple[np.ndarray, np.ndarray],
                 obb: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
                 split: Callable | None = None) -> np.ndarray | None:
        """(Vr,3) sum_j G_v[i, j] (1 - V_obj(i, j)) dB_j over the kept patches (float32 sums), or None when
        no pair is blocked. box: (lo, hi) m about the occluder, with a margin (a segment that misses it
        casts no ray); obb: (centre, axes rows, half sides) an oriented box about it tested instead
        (app.stages.sun.upright_box); split: the launch's cut over the cores (app.runtime.split)."""
        cols = kept_patches(dB, self._area)
        if len(cols) == 0:
            return None
        near, _, _ = self._pairs.sums(occluder, self._b[cols], cols, dB[cols], box, split, obb=obb)
        return near if near.any() else None


def blocked_pass(dB: np.ndarray, G_v: np.ndarray, recv_points: np.ndarray, recv_normals: np.ndarray,
                 centres: np.ndarray, normals: np.ndarray, area: np.ndarray, occluder: Occluder,
                 sphere: tuple[np.ndarray, float], workspace: Workspace | None = None) -> np.ndarray | None:
    """(Vr,3): G_v's pass of dB (P,3) over the (receiver vertex, patch) pairs the object blocks, i.e.
    sum_j G_v[i, j] (1 - V_obj(i, j)) dB_j, to be taken from the engine's one pass; None when no pair is
    blocked. recv_points, recv_normals (Vr,3): the receiver vertices; centres, normals, area: the patches'.
    One segment per pair, receiver to patch centre, cast against the object's `occluder` only where it
    passes through the object's bounding `sphere` (centre, radius); only the patches that hold KEEP of
    the change's power are tested. workspace: the call site's kernel buffers (nothing allocated once they
    exist), or None. The numpy reference of BlockedSecondOrder (the engine's; tests compare the two)."""
    cols = kept_patches(dB, area)
    if len(cols) == 0:
        return None
    c, r = np.asarray(sphere[0], float), float(sphere[1])
    a = recv_points + recv_normals * EPS  # (Vr,3)
    b = centres[cols] + normals[cols] * EPS  # (J,3)
    out = np.zeros((len(a), 3))
    hit = False
    # the segment a_i -> b_j passes within r of c: its closest point at t = clip((c - a).(b - a) / |b - a|^2, 0, 1),
    # every term from one product a b^T (no (Vr,J,3) arrays)
    aa, ac = (a * a).sum(1)[:, None], (a @ c)[:, None]
    ca2 = ((c - a) ** 2).sum(1)[:, None]
    for j0 in range(0, len(cols), BLOCK):  # blocks of patches
        jc = cols[j0:j0 + BLOCK]
        bj = b[j0:j0 + BLOCK]
        g = np.asarray(G_v[:, jc], np.float64)  # (Vr,J)
        ab = a @ bj.T
        dot = (bj @ c)[None] - ac - ab + aa  # (c - a).(b - a)
        L2 = np.maximum((bj * bj).sum(1)[None] + aa - 2.0 * ab, 1e-18)
        t = np.clip(dot / L2, 0.0, 1.0)
        cand = (g > 0) & (ca2 - 2.0 * t * dot + t * t * L2 < r * r)
        vi, jj = np.nonzero(cand)
        if len(vi) == 0:
            continue
        blocked = segments_visible(occluder, a[vi], bj[jj], workspace) == 0
        if not blocked.any():
            continue
        hit = True
        vi, jj = vi[blocked], jj[blocked]
        w = g[vi, jj]
        for k in range(3):
            out[:, k] += np.bincount(vi, w * dB[jc[jj], k], len(a))
    return out if hit else None
