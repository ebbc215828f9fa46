"""The shading mesh cut along the contact lines between the object's own parts.

A chair's back stands on its seat, but the seat's top is one grid of shading vertices that runs on under the back:
its rear row lies under the back (buried, filled from its neighbours) and the next row is a whole face forward, so
the strip of seat in front of the back is a linear blend that cannot darken towards the crease as the truth does.
own_contacts.lift_off_own_contacts shades a vertex on a contact line just off it; this module puts vertices there:
every face of the touched surface that the standing face's plane crosses within the contact edge's stretch is split
along the plane, so the touched surface gets a row of vertices on the contact line (which the lift then shades
from just in front of the back) and the rows on either side of the contact are shaded separately.

A contact: an edge of a face B whose two ends lie in the plane of another face A of the object, inside A (or in a
face coplanar with A), not at A's corners, the two planes crossing at own_contacts.OWN_CONTACT_MIN_SIN or more, and B
rising off A's front side (its third corner above A's plane): the back's front face on the seat's top, a leg's side
on the seat's underside. A box's convex edges (the front face goes down from the top face's plane) and one part's
faces lying in another's plane are not contacts. A mesh without contacts (a sphere, a torus, one box) is returned
as it came.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from app.stages.own_contacts import OWN_CONTACT_MIN_SIN

CUT_TOL = 1e-6  # m: a point this close to a plane lies in it (ObjectShading's shape keys round to 1 um)


def _planes(tv: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(unit normals (F,3), offsets (F,) m, valid (F,) bool) of the triangles tv (F,3,3)."""
    nf = np.cross(tv[:, 1] - tv[:, 0], tv[:, 2] - tv[:, 0])
    a = np.linalg.norm(nf, axis=1)
    ok = a > 1e-14
    nf = nf / np.maximum(a, 1e-300)[:, None]
    return nf, np.einsum("fc,fc->f", nf, tv[:, 0]), ok


def _contacts(tv: np.ndarray) -> list[tuple[int, np.ndarray, float, np.ndarray, np.ndarray]]:
    """The contacts of the triangles tv (F,3,3) (module docstring): per contact edge (a face of the touched plane,
    the standing face's unit normal (3,), its offset, the edge's two ends (3,) each)."""
    nf, df, ok = _planes(tv)
    pts = tv.reshape(-1, 3)
    _, first, inv = np.unique(np.round(pts / CUT_TOL).astype(np.int64), axis=0, return_index=True,
                              return_inverse=True)
    inv = inv.reshape(-1, 3)
    pu = pts[first]
    cen = tv.mean(1)
    rad = np.linalg.norm(tv - cen[:, None], axis=2).max(1)
    tree = cKDTree(pu)
    lists = tree.query_ball_point(cen, rad + CUT_TOL)
    cnt = np.array([len(x) for x in lists])
    fa = np.repeat(np.arange(len(tv)), cnt)
    vu = np.fromiter((j for x in lists for j in x), np.int64, cnt.sum())
    # in A's plane, not one of A's corners, the vertex's own faces cross A's plane (checked per edge below)
    on = ok[fa] & (np.abs(np.einsum("kc,kc->k", pu[vu], nf[fa]) - df[fa]) < CUT_TOL)
    on &= (inv[fa] != vu[:, None]).all(1)
    fa, vu = fa[on], vu[on]
    if not len(fa):
        return []
    a, b, c = tv[fa, 0], tv[fa, 1], tv[fa, 2]
    v0, v1, v2 = b - a, c - a, pu[vu] - a
    d00, d01, d11 = (np.einsum("kc,kc->k", x, y) for x, y in ((v0, v0), (v0, v1), (v1, v1)))
    d20, d21 = np.einsum("kc,kc->k", v2, v0), np.einsum("kc,kc->k", v2, v1)
    den = d00 * d11 - d01 * d01
    bv, bw = (d11 * d20 - d01 * d21) / den, (d00 * d21 - d01 * d20) / den
    inside = np.minimum(np.minimum(bv, bw), 1.0 - bv - bw) >= -1e-6
    fa, vu = fa[inside], vu[inside]
    if not len(fa):
        return []
    touching: dict[int, list[int]] = {}  # distinct vertex -> the faces whose plane it touches
    for u, f in zip(vu.tolist(), fa.tolist()):
        touching.setdefault(u, []).append(f)
    has = np.zeros(len(pu), bool)
    has[list(touching)] = True
    out = []
    for fb in np.flatnonzero(ok & (has[inv].sum(1) >= 2)):
        for i in range(3):
            ui, uj, k = inv[fb, i], inv[fb, (i + 1) % 3], (i + 2) % 3
            if not (has[ui] and has[uj]):
                continue
            for fa_ in touching[ui]:
                nA, dA = nf[fa_], df[fa_]
                if abs(pu[uj] @ nA - dA) >= CUT_TOL or 1.0 - (nA @ nf[fb]) ** 2 < OWN_CONTACT_MIN_SIN ** 2:
                    continue
                if tv[fb, k] @ nA - dA <= CUT_TOL:  # B does not rise off A's front side
                    continue
                out.append((fa_, nf[fb], float(df[fb]), pu[ui], pu[uj]))
                break
    return out


def _edge_point(p: np.ndarray, q: np.ndarray, sp: float, sq: float) -> np.ndarray:
    """The point where the plane (signed distances sp, sq of p, q) crosses the edge p-q, the same float for both
    triangles that share the edge (its ends taken in a fixed order)."""
    if tuple(q) < tuple(p):
        p, q, sp, sq = q, p, sq, sp
    return p + (sp / (sp - sq)) * (q - p)


def _split(tv: np.ndarray, tn: np.ndarray, s: np.ndarray) -> tuple[list, list]:
    """The triangle tv (3,3) with normals tn (3,3) split along the plane of signed distances s (3,) (it crosses
    the triangle's interior): 2 or 3 triangles, the winding kept; lists of (3,3) corners and normals."""
    z = np.where(np.abs(s) < CUT_TOL, 0, np.sign(s)).astype(int)

    def at(i: int, j: int) -> tuple[np.ndarray, np.ndarray]:
        p = _edge_point(tv[i], tv[j], s[i], s[j])
        t = np.linalg.norm(p - tv[i]) / max(np.linalg.norm(tv[j] - tv[i]), 1e-300)
        nrm = (1 - t) * tn[i] + t * tn[j]
        return p, nrm / max(np.linalg.norm(nrm), 1e-12)

    if (z == 0).any():  # through a corner a and across the opposite edge b-c
        ka = int(np.flatnonzero(z == 0)[0])
        a, b, c = ka, (ka + 1) % 3, (ka + 2) % 3
        m, mn = at(b, c)
        return ([np.stack([tv[a], tv[b], m]), np.stack([tv[a], m, tv[c]])],
                [np.stack([tn[a], tn[b], mn]), np.stack([tn[a], mn, tn[c]])])
    ka = int(np.flatnonzero(z != np.sign(z.sum()))[0])  # the corner alone on its side
    a, b, c = ka, (ka + 1) % 3, (ka + 2) % 3
    m1, n1 = at(a, b)
    m2, n2 = at(c, a)
    return ([np.stack([tv[a], m1, m2]), np.stack([m1, tv[b], tv[c]]), np.stack([m1, tv[c], m2])],
            [np.stack([tn[a], n1, n2]), np.stack([n1, tn[b], tn[c]]), np.stack([n1, tn[c], n2])])


def cut_along_own_contacts(v: np.ndarray, n: np.ndarray, f: np.ndarray
                           ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """The shading mesh (v (V,3) m, unit normals n (V,3), faces (F,3)) with the faces of each touched surface cut
    along the contact lines (module docstring), as separate triangles (vertices not shared, as recon.proxy.subdivide
    makes them; the cut faces' pieces in their place), and each new face's face before the cut (F',) int64 (the sun
    per camera hit treats a cut face's pieces as the one face: lighting.sun.SunLight.hit_codes). Without contacts
    the arrays come back as they are, and None."""
    tv = np.asarray(v, np.float64)[f]
    tn = np.asarray(n, np.float64)[f]
    cuts = _contacts(tv)
    if not cuts:
        return v, n, f, None
    nf, df, _ = _planes(tv)
    # each face's plane as a key: the faces coplanar with a touched face (same side) are cut with it
    key = np.round(np.concatenate([nf, df[:, None]], 1) / CUT_TOL).astype(np.int64)
    n0 = len(tv)
    parent = np.arange(n0)
    for ka, nA, nB, dB, p, q in [(key[c[0]], nf[c[0]]) + c[1:] for c in cuts]:  # keys before any cut renumbers
        L = np.cross(nA, nB)
        L /= np.linalg.norm(L)
        lo, hi = sorted((float(p @ L), float(q @ L)))
        s = tv @ nB - dB  # (F,3) the corners' signed distances to the standing face's plane
        cand = np.flatnonzero((key == ka).all(1) & (s.max(1) > CUT_TOL) & (s.min(1) < -CUT_TOL))
        pieces = {}
        for i in cand.tolist():
            t, si = tv[i], s[i]
            # the stretch of the cut inside this face (along the contact line) overlaps the contact edge
            along = [float(t[j] @ L) for j in range(3) if abs(si[j]) < CUT_TOL]
            along += [float(_edge_point(t[j], t[k], si[j], si[k]) @ L) for j, k in ((0, 1), (1, 2), (2, 0))
                      if min(abs(si[j]), abs(si[k])) >= CUT_TOL and si[j] * si[k] < 0]
            if min(along) < hi - CUT_TOL and max(along) > lo + CUT_TOL:
                pieces[i] = _split(t, tn[i], si)
        if not pieces:
            continue
        cnt = np.ones(len(tv), np.int64)
        for i, (pv, _) in pieces.items():
            cnt[i] = len(pv)
        at = np.repeat(np.arange(len(tv)), cnt)  # each output face's source face, the pieces in its place
        tv2, tn2, key, parent = tv[at], tn[at], key[at], parent[at]
        first = np.cumsum(cnt) - cnt
        for i, (pv, pn) in pieces.items():
            tv2[first[i]:first[i] + len(pv)] = pv
            tn2[first[i]:first[i] + len(pv)] = pn
        tv, tn = tv2, tn2
    if len(tv) == n0:
        return v, n, f, None
    return tv.reshape(-1, 3), tn.reshape(-1, 3), np.arange(3 * len(tv)).reshape(-1, 3).astype(np.int32), parent
