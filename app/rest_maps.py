"""The all-sources frame's map size per source (issue 36, "At rest").

The all-sources frame (one shadow map per source, hard lookup) draws ~3300 maps and tests ~30 M
(point, map) pairs. A map of half the size (CLUSTER_MAP_RES, 128 px) costs a quarter of the raster and
its lookups stay in cache; its hard edge lies up to one 256 px texel away from the full map's. Such a
shift can change a pixel only by the source's own share of that pixel's light, so a source whose share
is small at every receiver moves no pixel by a visible step with its edge. The rule, per source j:

    share_j = max over the receiver vertices i of Y(W_ij) / Y(E_i)

(W_ij: the source's transfer at vertex i, irradiance/pi; E_i: the vertex's light from every source; Y
luminance). A source is *weak* when share_j <= WEBER: its shadow's edge, wherever it lies, is a step of at
most that fraction of the light, about the smallest luminance contrast the eye sees (the graded
lattice's REFINE_TOL, app.stages.shadow_pass, for the same reason). The weak sources get half-size maps,
the others keep the engine's map_res (a lamp that lights most of a floor, the window patches that light
the floor beside the object). The maximum runs over every receiver vertex (also ones the object cannot
shade from j), so the rule errs towards the full map; it depends on the room's light only (not on the
photo or a fitted constant), and is computed once per list of sources (the frames at rest of one pose
list the same ones). For the same reason the shadow pass does not sum the weak sources at the pixels near
the object that it lists off its lattice beyond the bounding sphere, and fills their part there from the
listed pixels around (ShadowPass.weak_ring), and beyond weak_far radii sums them on the spacing-4 lattice
only, filling the spacing-2 one there bilinearly (ShadowPass.weak_coarse); the strong ones are summed at
every listed pixel.
"""
from __future__ import annotations

import numpy as np

from app.stages.shadow_pass import REFINE_TOL
from lighting.frame_sources import FrameSources
from recon.response import LUMA, luminance

# share of a receiver's light: a weak source's shadow edge is a luminance step of at most this (Weber's
# fraction; module docstring)
WEBER = REFINE_TOL


class RestMaps:
    """Which sources of an all-sources frame take the half-size map (module docstring), and the frame's
    sources' order for ShadowPass.run(order=): the full-size ones first."""

    def __init__(self, E_v: np.ndarray, budget: float = WEBER):
        """E_v (Vr,3) each receiver vertex's light (irradiance/pi); budget: the largest share of a weak
        source (WEBER; inf: every source weak, 0: none, for A/B)."""
        self.scale = 1.0 / np.maximum(luminance(np.asarray(E_v, np.float64)), 1e-30)
        self.budget = float(budget)
        self._last: tuple | None = None  # (eyes, shares (S,)) of the last list

    def shares(self, W_v) -> np.ndarray:
        """(S,) share_j of each pass of W_v (Vr,S,3) (an array or a ColumnView), in slabs of rows."""
        Vr, S = W_v.shape[0], W_v.shape[1]
        out = np.zeros(S)
        for r0 in range(0, Vr, 128):
            r1 = min(r0 + 128, Vr)
            y = np.asarray(W_v[r0:r1], np.float32) @ LUMA.astype(np.float32)  # luminance (recon.response)
            np.maximum(out, (y * self.scale[r0:r1, None].astype(np.float32)).max(0), out=out)
        return out

    def weak(self, fs: FrameSources) -> np.ndarray:
        """(S,) bool: the frame's passes (one per source) whose share_j <= the budget."""
        last = self._last
        if last is None or not np.array_equal(last[0], fs.eyes):
            self._last = last = (np.array(fs.eyes), self.shares(fs.W_v))
        return last[1] <= self.budget

    def order(self, fs: FrameSources) -> tuple[np.ndarray, int] | None:
        """ShadowPass.run's order of fs's passes: (perm: the full-size ones first, then the weak ones, each
        part in its list order; how many take the full size), or None when every one takes the full size."""
        weak = self.weak(fs)
        if not weak.any():
            return None
        return np.argsort(weak, kind="stable"), int((~weak).sum())
