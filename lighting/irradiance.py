"""Irradiance anywhere in the room: SH9 volume for the indirect light, exact gather for emitters.

Nine SH coefficients smooth a small bright emitter (a window 41x the walls, lamps 1000x) into a
broad lobe: at the volume's own grid points the pure-SH9 irradiance was 4.6 % off brute force on
window_room (bench/bench_irradiance.py). Splitting the light keeps the volume for what SH9 is good at,
the smooth indirect light of the walls, and gathers the few emitter patches exactly (form factor
x visibility, kernels.visibility) at each shaded point. Units: irradiance / pi, i.e. the radiance a
white Lambertian surface would reflect.
"""
from __future__ import annotations

import numpy as np

from kernels.irradiance_volume import IrradianceVolume, build_volume
from kernels.visibility import Occluder, transfer_matrix
from lighting import sh
from recon.patches import PatchMesh


class RoomLight:
    """Indirect light in an SH9 volume plus the emitter patches, from one radiance mesh."""

    def __init__(self, patches: PatchMesh, radiance: np.ndarray, room_min: np.ndarray, room_max: np.ndarray,
                 occluder: Occluder, spacing: float = 0.25, device: str | None = None,
                 volume: IrradianceVolume | None = None):
        """volume: the SH volume of exactly these inputs when already built (app.stages.precompute's
        cache); None builds it."""
        self.patches = patches
        self.radiance = np.asarray(radiance, np.float64)
        self.occluder = occluder
        self.device = device
        emit = patches.is_emitter
        self.emitters = np.flatnonzero(emit & (self.radiance.sum(1) > 0))
        indirect = np.where(emit[:, None], 0.0, self.radiance)
        self.volume: IrradianceVolume = volume if volume is not None else build_volume(
            room_min, room_max, spacing, patches.corners, patches.normal, indirect, occluder, patches.tri_patch, device)

    def gather_exactly(self, near: np.ndarray, radiance: np.ndarray) -> None:
        """Move the non-emitting patches `near` (P,) bool into the exact gather at `radiance` (P,3):
        bright reflectors (a sunlit floor patch) that SH9's broad lobe would spread. The volume must
        have been built without them (their radiance 0 there), or they would count twice."""
        near = np.asarray(near, bool) & (np.asarray(radiance).sum(1) > 0)
        if not near.any():
            return
        self.radiance = self.radiance.copy()
        self.radiance[near] = np.asarray(radiance, np.float64)[near]
        self.emitters = np.union1d(self.emitters, np.flatnonzero(near))

    def indirect_sh(self, points: np.ndarray) -> np.ndarray:
        """Radiance SH coefficients (N,9,3) of the non-emitting patches at points (N,3)."""
        return self.volume.lookup(points)

    def direct(self, points: np.ndarray, normals: np.ndarray, occluders: list[Occluder] = (),
               n_side: int = 2, eps: float = 2e-3, workspace=None) -> np.ndarray:
        """Irradiance/pi (N,3) from the emitter patches, exact, with visibility (`workspace`:
        kernels.buffers.Workspace of the caller's call site, or None)."""
        if len(self.emitters) == 0 or len(points) == 0:
            return np.zeros((len(points), 3))
        pm = self.patches
        G = transfer_matrix(points, normals, pm.corners[self.emitters], pm.normal[self.emitters],
                            [self.occluder, *occluders][:2], n_side=n_side, eps=eps, device=self.device,
                            workspace=workspace)
        return G.astype(np.float64) @ self.radiance[self.emitters]

    def irradiance(self, points: np.ndarray, normals: np.ndarray) -> np.ndarray:
        """Irradiance/pi (N,3) at points with normals, no object present."""
        return sh.irradiance(self.indirect_sh(points), normals) / np.pi + self.direct(points, normals)
