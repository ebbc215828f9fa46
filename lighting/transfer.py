"""Intensity transfers S_ij (seed sec. 6.3.1-6.3.2, fig. 13): LDR equivalents of L_ij.

Sources are taken in the given order (brightest first); even positions are assumed occluded
together in set 1, odd ones in set 2 (the 50/50 split). For each receiver vertex i,
V_1 = V_2 = L_i; for each source j of its set, V -= L_ij and S_ij = T(V_before) - T(V_after).
Subtracting sum_j S_ij M_ij from the 8-bit photo then reproduces T(L_i - sum_j L_ij M_ij)
exactly when the occluded sources are one of the two sets, and approximately otherwise.
"""
from __future__ import annotations

from typing import Callable

import numpy as np


def intensity_transfers(L_i: np.ndarray, L_ij: np.ndarray, T: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
    """S (N,S,3) in pixel levels from vertex radiance L_i (N,3) and transfers L_ij (N,S,3).

    T maps radiance (...,3) to continuous pixel levels. Radiance never goes below zero.
    """
    L_i = np.asarray(L_i, np.float64)
    L_ij = np.asarray(L_ij, np.float64)
    n, s = L_ij.shape[:2]
    S = np.zeros_like(L_ij)
    for parity in (0, 1):
        idx = np.arange(parity, s, 2)
        if len(idx) == 0:
            continue
        V = L_i[:, None, :] - np.cumsum(L_ij[:, idx, :], axis=1)
        C = T(np.maximum(np.concatenate([L_i[:, None, :], V], axis=1), 0.0))
        S[:, idx, :] = C[:, :-1, :] - C[:, 1:, :]
    return S
