"""Where one part of the object stands on another: the shading vertices on the contact line, lifted off it.

A chair's back stands on its seat: the back's bottom row of shading vertices lies in the seat's top plane. There a
vertex sees the seat edge-on (its form factor is 0) and its hemisphere rays start on the seat, so it counts as buried
(app.stages.object_shading.ShapeShading.buried) and takes the light of its face's other corners, a whole face up the
back, where the room is seen: the back brightens towards the crease where the truth darkens (at any height above
a plane the plane fills the lower half of the view). As app.stages.object_shading.lift_off_contacts does against the
room's surfaces, such a vertex stands for the surface just off the contact: it is shaded at a point moved within its
own tangent plane to a height h above the other part's face (CONTACT_LIFT x that face's bounding radius, at
least 2 x the rays' eps), the limit from above.

A vertex is on a contact line with a face of the object (not one of its own: no corner that is the same distinct
vertex, position and normal; a vertex's copies count as one) when it lies within h of the face's plane and inside
the face, the face's plane crosses its tangent plane at OWN_CONTACT_MIN_SIN
or more (a fold, not a near-tangent neighbour), and its own surface goes on away from that face (one of its faces
has its centroid on the rising side): the back's front face above the seat. A convex edge of one part (a box's front
face at its top edge: the top face lies in the plane, but the front face does not go on above it) and a vertex
covered by another part (the seat's rear row under the back's rear face: the seat does not go on behind the back)
are left as they are.
"""
from __future__ import annotations

import numpy as np

CONTACT_LIFT = 0.1  # of a touched face's bounding radius: the height above it at which a vertex touching it is shaded,
# for another part's face (here) and for a room patch (app.stages.object_shading.lift_off_contacts)
OWN_CONTACT_MIN_SIN = 0.5  # the sine of the angle between the two surfaces at least (30 degrees): a crease
RISE_COS = 0.1  # a face of the vertex's own goes on along the lift when its centroid's direction has this cosine


def _outer_dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(A,B) the dot products of the rows of a (A,3) and b (B,3), elementwise (a (256,3) x (3,F) BLAS product
    spent more CPU in its threads than the whole rest of lift_off_own_contacts)."""
    return a[:, 0:1] * b[:, 0] + a[:, 1:2] * b[:, 1] + a[:, 2:3] * b[:, 2]


def lift_off_own_contacts(p: np.ndarray, n: np.ndarray, faces: np.ndarray, eps: float = 1e-3, block: int = 256
                          ) -> np.ndarray:
    """Offsets (V,3) m that move each vertex (p (V,3), unit normals n (V,3), faces (F,3)) lying on a contact line
    with another part of the same mesh to CONTACT_LIFT x the touched face's radius (at least 2 eps) above that
    face, within the vertex's tangent plane (module docstring); 0 for the others. Per vertex its deepest contact;
    two rounds (a vertex in a corner touches two faces)."""
    p = np.asarray(p, np.float64)
    n = np.asarray(n, np.float64)
    faces = np.asarray(faces, np.int64)
    out = np.zeros_like(p)
    if len(p) == 0 or len(faces) == 0:
        return out
    tri = p[faces]  # (F,3,3)
    nf = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area2 = np.linalg.norm(nf, axis=1)
    ok = area2 > 1e-14
    nf = nf / np.maximum(area2, 1e-300)[:, None]
    cen = tri.mean(1)
    rad = np.linalg.norm(tri - cen[:, None], axis=2).max(1)
    h = np.maximum(CONTACT_LIFT * rad, 2.0 * eps)
    # each vertex's own faces for the rising test, as a CSR list over the distinct (position, normal) vertices:
    # a vertex's copies (own_cuts: a row on a contact line, with faces on either side) count together
    _, grp = np.unique(np.round(np.concatenate([p, n], 1), 6), axis=0, return_inverse=True)
    grp = grp.reshape(-1)
    corner_grp = grp[faces.reshape(-1)]
    order = np.argsort(corner_grp, kind="stable")
    start = np.searchsorted(corner_grp[order], np.arange(grp.max() + 2))
    own_face = order // 3
    moved = p.copy()
    for _ in range(2):
        any_moved = False
        for s in range(0, len(p), block):
            e = min(len(p), s + block)
            q = moved[s:e]
            d = _outer_dot(q, nf) - np.einsum("fc,fc->f", nf, tri[:, 0])[None]  # (B,F) signed distance to the plane
            C = _outer_dot(n[s:e], nf)  # (B,F) the normals' cosine: a crease, not a face in (or near) the vertex's plane
            bi, fj = np.nonzero((np.abs(d) < h[None] - 1e-9) & ok[None] & (1.0 - C * C >= OWN_CONTACT_MIN_SIN ** 2))
            if not len(bi):
                continue
            vi = bi + s
            # not one of its own faces: no corner that is the same distinct vertex (position and normal; a face of
            # another surface through the same point, as a cut contact line's two sides, is not its own)
            keep = (grp[faces[fj]] != grp[vi][:, None]).all(1)
            bi, fj, vi = bi[keep], fj[keep], vi[keep]
            cos = C[bi, fj]
            dk = d[bi, fj]
            # inside the face: barycentrics of the point projected onto its plane
            x = moved[vi] - dk[:, None] * nf[fj]
            a, b, c = tri[fj, 0], tri[fj, 1], tri[fj, 2]
            v0, v1, v2 = b - a, c - a, x - a
            d00, d01, d11 = (np.einsum("kc,kc->k", u, w) for u, w in ((v0, v0), (v0, v1), (v1, v1)))
            d20, d21 = np.einsum("kc,kc->k", v2, v0), np.einsum("kc,kc->k", v2, v1)
            den = d00 * d11 - d01 * d01
            bv = (d11 * d20 - d01 * d21) / den
            bw = (d00 * d21 - d01 * d20) / den
            inside = np.minimum(np.minimum(bv, bw), 1.0 - bv - bw) >= -1e-4
            bi, fj, vi, cos, dk = bi[inside], fj[inside], vi[inside], cos[inside], dk[inside]
            if not len(vi):
                continue
            t = nf[fj] - cos[:, None] * n[vi]  # the tangent direction rising off the touched face
            tu = t / np.linalg.norm(t, axis=1, keepdims=True)
            # the vertex's own surface goes on along the lift: one of its faces' centroids lies that way
            gi = grp[vi]
            cnt = start[gi + 1] - start[gi]
            pair = np.repeat(np.arange(len(vi)), cnt)
            at = np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt, cnt) + np.repeat(start[gi], cnt)
            r = cen[own_face[at]] - p[vi[pair]]
            ok_r = np.einsum("kc,kc->k", r, tu[pair]) > RISE_COS * np.linalg.norm(r, axis=1)
            rises = np.bincount(pair[ok_r], minlength=len(vi)) > 0
            vi, fj, dk, t = vi[rises], fj[rises], dk[rises], t[rises]
            if not len(vi):
                continue
            first = np.lexsort((dk, vi))  # per vertex its deepest contact
            pick = first[np.r_[True, vi[first][1:] != vi[first][:-1]]]
            vi, fj, dk, t = vi[pick], fj[pick], dk[pick], t[pick]
            moved[vi] += ((h[fj] - dk) / np.einsum("kc,kc->k", t, t))[:, None] * t
            any_moved = True
        if not any_moved:
            break
    return moved - p
