"""Object light stage: the light the object reflects onto the room (pixels and patch centres), as
irradiance / pi (DESIGN "Per-frame stages"). The object's proxy triangles are the emitters."""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from kernels.visibility import Occluder, emitter_sum, transfer_matrix
from recon.response import luminance
from recon.scene import SceneObject

if TYPE_CHECKING:
    from app.engine import Engine


def object_irradiance(eng: "Engine", pts: np.ndarray, nrm: np.ndarray, proxy_occ: Occluder, B: np.ndarray
                       ) -> np.ndarray:
    """Irradiance/pi (N,3) at object surface points from patches of radiance B (P,3), with
    self-occlusion."""
    pm = eng.pre.patches
    G = transfer_matrix(pts, nrm, pm.corners, pm.normal, [eng.scene_occ, proxy_occ], n_side=1,
                        eps=2e-3, device=eng.device)
    return G.astype(np.float64) @ B


def triangle_radiance(eng: "Engine", obj: SceneObject, pv, pf, proxy_occ, B: np.ndarray) -> np.ndarray:
    """Outgoing radiance (T,3) of each proxy triangle, lit at its centroid by patches of radiance B."""
    c = pv[pf].mean(1)
    n = np.cross(pv[pf[:, 1]] - pv[pf[:, 0]], pv[pf[:, 2]] - pv[pf[:, 0]])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    return obj.albedo * eng._object_irradiance(c, n, proxy_occ, B)


def object_light(eng: "Engine", pv, pf, tri_rad, proxy_occ, centre, radius):
    """Light reflected by the object onto pixels (H*W,3) and patch centres (P,3), as irradiance/pi.

    Far from the object the reflected light varies slowly: it is evaluated at receiver vertices
    and interpolated like the transfers. Within `near_factor` bounding radii of the object's
    centre, where it changes fast (contact, under a seat), it is evaluated per pixel; there only
    pixels whose upper bound of gain exceeds a quarter level are computed.
    """
    pre, pm = eng.pre, eng.pre.patches
    resp = eng.scene.response
    tris = pv[pf]
    rv = pre.recv_vert
    R_v = emitter_sum(pm.vert_inset[rv], pm.vert_normal[rv], tris, tri_rad, proxy_occ, device=eng.device)
    R_pix = np.zeros((len(eng.L_b), 3))
    rp = np.flatnonzero(eng.recv_pix)
    R_pix[rp] = np.einsum("nk,nkc->nc", pre.pix_bary[rp], R_v[eng.pix_rows[rp]])
    dist = np.linalg.norm(eng.pix_pos[rp] - centre, axis=1)
    near = dist < eng.near_factor * radius
    rp, dist = rp[near], dist[near]
    f_bound = np.minimum(1.0, (radius / np.maximum(dist, 1e-6)) ** 2)
    bound = eng.rho_x[rp] * tri_rad.max(0) * f_bound[:, None]
    gain = (resp.to_levels(eng.L_b[rp] + bound) - resp.to_levels(eng.L_b[rp])).max(1)
    sel = rp[gain > 0.25]
    normals = pm.normal[eng.pix_patch[sel]]
    R_pix[sel] = emitter_sum(eng.pix_pos[sel], normals, tris, tri_rad, proxy_occ, device=eng.device)
    # patch centres, for the second-order term
    dist_c = np.linalg.norm(pm.centre - centre, axis=1)
    reach = np.minimum(1.0, (radius / np.maximum(dist_c, 1e-6)) ** 2) * luminance(tri_rad.max(0))
    near_c = np.flatnonzero((reach > 1e-4 * luminance(eng.B_src).mean()) & ~pm.is_emitter)
    R_cen = np.zeros((pm.n_patches, 3))
    R_cen[near_c] = emitter_sum(pm.centre[near_c], pm.normal[near_c], tris, tri_rad, proxy_occ, device=eng.device)
    eng._n_object_light_pixels = len(sel)
    return R_pix, R_cen
