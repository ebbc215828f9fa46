"""Drag-frame levers A/B of drag110 (issue 36): bench_drag36b's per-room interleaved run (process CPU per frame and
per stage, the drag row at the scene's own pose against the truth, its SHA-256) with this branch's variants added.

usage: python bench/bench_drag110.py --scenes window_room,sun_room,DIR,... --variants base,cn15,... [--path 8]
                                     [--rounds 1]

Variants (each an attribute of the engine's drag stages at DRAG_SCALE set while its frames run, then restored):
  cn15 / cn10   ObjectLight.centre_near 1.5 / 1.0 bounding radii (DRAG_CENTRE_NEAR 2): fewer patch centres summed as
                the near pixels are (rays per proxy triangle, the sun's pieces a ray each)
  ff15          ObjectLight.far_field 1.5 (DRAG_FAR_FIELD 2): the receiver vertices see the far groups from 1.5 radii
  gn15          ShadowPass.graded_near 1.5 (DRAG_GRADED_NEAR 2): every pixel summed exactly within 1.5 radii
  weak4, weak6, weak8, weak16, weakall
                the weak cluster maps' budget (ShadowPass.weak_clusters.budget; WEBER 0.02) 0.04 ... 0.16, inf:
                more cluster maps take their eye's hard lookup (no PCSS penumbra)
  weber2        the budget WEBER (0.02): main's drag frame before drag110 (base: drag_weak_budget(3) = 0.06)
  tt10          ObjectLight.table_tolerance 0.10 (DRAG_LIGHT_TABLES 0.05): more proxy triangles as point emitters
"""
from __future__ import annotations

import contextlib
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_drag36b as b36  # noqa: E402
from app.config import DRAG_SCALE  # noqa: E402


@contextlib.contextmanager
def _attr(eng, part: str, name: str, value, scale: int = DRAG_SCALE):
    """The drag stages' `part` (object_light, shadow_pass) with attribute `name` = value while the block runs."""
    obj = getattr(eng.pixel_stages(scale), part)
    old = getattr(obj, name)
    setattr(obj, name, value)
    try:
        yield
    finally:
        setattr(obj, name, old)


@contextlib.contextmanager
def _weak(eng, budget: float, scale: int = DRAG_SCALE):
    """The drag stages' weak-cluster budget (ShadowPass.weak_clusters.budget, app.rest_maps.RestMaps) = budget while
    the block runs."""
    wc = eng.pixel_stages(scale).shadow_pass.weak_clusters
    old = wc.budget
    wc.budget = budget
    try:
        yield
    finally:
        wc.budget = old


@contextlib.contextmanager
def _both(*cms):
    with contextlib.ExitStack() as st:
        for cm in cms:
            st.enter_context(cm)
        yield


b36.VARIANTS.update({
    "cn15": (b36._cfg(), lambda e: _attr(e, "object_light", "centre_near", 1.5)),
    "cn10": (b36._cfg(), lambda e: _attr(e, "object_light", "centre_near", 1.0)),
    "ff15": (b36._cfg(), lambda e: _attr(e, "object_light", "far_field", 1.5)),
    "cn15ff15": (b36._cfg(), lambda e: _both(_attr(e, "object_light", "centre_near", 1.5),
                                            _attr(e, "object_light", "far_field", 1.5))),
    "gn15": (b36._cfg(), lambda e: _attr(e, "shadow_pass", "graded_near", 1.5)),
    "weak4": (b36._cfg(), lambda e: _weak(e, 0.04)),
    "weak8": (b36._cfg(), lambda e: _weak(e, 0.08)),
    "weber2": (b36._cfg(), lambda e: _weak(e, 0.02)),  # main's drag frame before drag110 (WEBER)
    "weak6": (b36._cfg(), lambda e: _weak(e, 0.06)),
    "weak16": (b36._cfg(), lambda e: _weak(e, 0.16)),
    "weakall": (b36._cfg(), lambda e: _weak(e, float("inf"))),
    "tt10": (b36._cfg(), lambda e: _attr(e, "object_light", "table_tolerance", 0.10)),
    "gn15weak4": (b36._cfg(), lambda e: _both(_attr(e, "shadow_pass", "graded_near", 1.5), _weak(e, 0.04))),
})

def _count_hard() -> None:
    """Each frame's stats get "hard_maps": the drag stages' cluster maps looked up hard (ShadowPass.last_hard)."""
    from app.engine import Engine

    made = Engine._stats

    def stats(self, *a, **kw):
        st = made(self, *a, **kw)
        d = self._drag.get(DRAG_SCALE)
        st["hard_maps"] = int(getattr(getattr(d, "shadow_pass", None), "last_hard", 0))
        return st

    Engine._stats = stats


if __name__ == "__main__":
    _count_hard()
    b36.main()
