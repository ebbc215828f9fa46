"""Known-lighting radiance mesh: patch radiosity from declared emitters and albedos.

Jacobi gathering over the patch-to-patch transfer matrix G (form factor x visibility, from
kernels.visibility): B^(0) = E, B^(k) = E + rho * (G @ B^(k-1)). After k iterations B holds
light paths of up to k bounces; the benchmark truth stops after 4 bounces past the camera hit,
so the camera sees B^(4) and the light gathered at a receiver comes from B^(3) (DESIGN.md,
"What the truth contains"). Radiance in the scene's units; patches are Lambertian.
"""
from __future__ import annotations

import numpy as np


def gather(G: np.ndarray, albedo: np.ndarray, emission: np.ndarray, bounces: int) -> list[np.ndarray]:
    """[B^(0), ..., B^(bounces)], each (P,3) float64, from G (P,P), albedo (P,3), emission (P,3)."""
    if G.shape[0] != G.shape[1] or G.shape[0] != len(albedo):
        raise ValueError(f"transfer matrix {G.shape} does not match {len(albedo)} patches")
    B = [np.asarray(emission, np.float64)]
    G64 = G.astype(np.float64)
    for _ in range(bounces):
        B.append(emission + albedo * (G64 @ B[-1]))
    return B
