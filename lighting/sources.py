"""Source set (seed sec. 6): the brightest patches holding a fraction of the total power.

Patches are sorted by decreasing power (luminance of radiance x area); the source set is the
shortest prefix whose power reaches `fraction` of the total. fraction=1 keeps every patch with
non-zero radiance. Returned indices are in decreasing order of power.
"""
from __future__ import annotations

import numpy as np

from recon.response import luminance


def select_sources(radiance: np.ndarray, area: np.ndarray, fraction: float = 0.7) -> np.ndarray:
    """Indices (S,) of the source set; empty when nothing emits or reflects light."""
    if not 0.0 < fraction <= 1.0:
        raise ValueError(f"source fraction must be in (0, 1], got {fraction}")
    power = luminance(radiance) * np.asarray(area, np.float64)
    order = np.argsort(-power, kind="stable")
    order = order[power[order] > 0]
    if len(order) == 0:
        return order
    cum = np.cumsum(power[order])
    if fraction >= 1.0:
        return order
    n = int(np.searchsorted(cum, fraction * cum[-1], side="left")) + 1
    return order[:n]
