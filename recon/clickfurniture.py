"""The click model's furniture (recon/clickmodel.py): a footprint from three floor corners and a top
corner (on the floor, or on the top of a piece it stands on), refined against the photo (its edges
snapped in rounds, a desk's legs too), a side held on a wall or on another piece's face when the two
are one plane within both their noises, and its boxes (a desk's slab and legs)."""
from __future__ import annotations

import math

import numpy as np

from recon.camera import Camera
from recon.io import json_field
from recon.clickbase import (CLICK_SIGMA_PX, DESK_LEG_INSET_M, DESK_LEG_M, DESK_TOP_M, FACES, FURNITURE_KINDS,
                             RIGHT_ANGLE_DEG, SIDES, SNAP_DEG, SNAP_ROUNDS, TOLERANCE_M, TOP_MISS_PX, WALL_SNAP_M,
                             WALL_TOL_M, Wall, Z99, _Clicks, _floor, _pixel_metres, _reproject_fit, ray)


def _a_on_e1(f: np.ndarray, e1: np.ndarray, e2: np.ndarray) -> bool:
    """Whether the footprint's edge floor[1] -> floor[0] (the a edge; f (3,3), a row of nan where null, at least
    two clicked) runs along local x (e1) rather than z (e2): from the a edge when both its corners are clicked, else
    from the b edge (floor[1] -> floor[2]); True when floor[0] and floor[2] (diagonal) are the clicked ones: they
    pin every side either way."""
    known = [k for k in range(3) if np.isfinite(f[k, 0])]
    a, b = f[0] - f[1], f[2] - f[1]
    if 0 in known and 1 in known:
        return bool(abs(a @ e1) >= abs(a @ e2))
    if 1 in known:
        return bool(abs(b @ e1) < abs(b @ e2))
    return True


def _footprint(P: _Clicks, f: np.ndarray, where: str, size: np.ndarray | None, against: Wall | None = None,
               noise_m: np.ndarray | None = None, hidden: frozenset = frozenset()) -> tuple[float, np.ndarray, np.ndarray]:
    """Upright rectangle through floor corners f (3,3) (f[1] the corner between the others; a row of
    nan: a corner out of the photo): yaw (rad, about +Y as recon/scene.rot_y: local x = (cos, 0,
    -sin)), and its sorted ranges (2,) along local x and local z (m). Each side is the mean of the
    clicked corners on it; a side with none is size_m away from the opposite one, or on the wall
    `against` (the wall the piece stands against); a corner in `hidden` (indices of null corners the
    user saw in the photo, behind the piece or another one) on the side that keeps it in the photo.
    The footprint is axis-aligned when its yaw is
    within SNAP_DEG of the room's axes, or within what the clicks' noise turns its edges by (Z99
    sigma; noise_m (3,): metres of floor one click sigma spans at each corner, across its edge): two
    corners a short edge apart far off cannot tell 12 deg from 0."""
    known = [k for k in range(3) if np.isfinite(f[k, 0])]
    if len(known) < 2:
        raise P.err(where, "at least two of the three floor corners must be clicked")
    a, b = f[0] - f[1], f[2] - f[1]
    edges = [(e, math.hypot(e[0], e[2])) for e, ks in ((a, (0, 1)), (b, (1, 2))) if all(k in known for k in ks)]
    if any(le < 0.02 for _, le in edges):
        raise P.err(where, "two floor corners are less than 2 cm apart: click three corners of the footprint in "
                           "order around it")
    if len(edges) == 2:
        cos_ab = abs(a[0] * b[0] + a[2] * b[2]) / (edges[0][1] * edges[1][1])
        if math.degrees(math.asin(min(cos_ab, 1.0))) > RIGHT_ANGLE_DEG:
            raise P.err(where, f"the floor corners make a {math.degrees(math.acos(cos_ab)):.0f} deg corner at "
                               "floor[1]: click three corners of the footprint in order around it (floor[1] between "
                               "the others)")
    # each edge's yaw (mod 90 deg), averaged by length on the 4x angle circle
    z = sum(le * complex(math.cos(4 * math.atan2(-e[2], e[0])), math.sin(4 * math.atan2(-e[2], e[0])))
            for e, le in edges)
    yaw = math.atan2(z.imag, z.real) / 4 if edges else 0.0
    snap_deg = SNAP_DEG
    if noise_m is not None and edges:  # the yaw's sd from its edges' (radians): end noise across / length
        info = sum(le * le / (noise_m[i] ** 2 + noise_m[j] ** 2)
                   for (_, le), (i, j) in zip(edges, [ks for ks in ((0, 1), (1, 2)) if all(k in known for k in ks)]))
        if info > 0:
            snap_deg = max(SNAP_DEG, Z99 * math.degrees(1.0 / math.sqrt(info)))
    if abs(math.degrees(yaw)) < snap_deg:
        yaw = 0.0
    elif len(known) < 3:
        raise P.err(where, f"the footprint is turned {math.degrees(yaw):.0f} deg from the room's axes: click all three "
                           "floor corners")
    e1, e2 = np.array([math.cos(yaw), 0, -math.sin(yaw)]), np.array([math.sin(yaw), 0, math.cos(yaw)])
    a_on_e1 = _a_on_e1(f, e1, e2)
    ea, eb = (e1, e2) if a_on_e1 else (e2, e1)
    # along the a edge (f1 -> f0): f0 on one side, f1 and f2 on the other; along b: f2, and f0 and f1
    ends = []
    for axis_vec, lone, pair, k in ((ea, 0, (1, 2), 0), (eb, 2, (0, 1), 1)):
        far = f[lone] @ axis_vec if lone in known else None
        near = [f[j] @ axis_vec for j in pair if j in known]
        near = float(np.mean(near)) if near else None
        if far is None:  # f[lone] out of the photo; then f1 is clicked, and shares its other side
            def corners(end, axis_vec=axis_vec):
                return [f[1] + (end - f[1] @ axis_vec) * axis_vec]

            if size is None and against is not None and abs(axis_vec[against.axis]) > 1 - 1e-9:
                far = against.offset * float(axis_vec[against.axis])
            else:
                far = P.missing_end(where, near, size, k, corners, lone in hidden)
        ends.append(np.sort(np.array([far, near])))
    xr, zr = (ends[0], ends[1]) if a_on_e1 else (ends[1], ends[0])
    return yaw, xr, zr


def _refine_box(camera: Camera, yaw: float, xr: np.ndarray, zr: np.ndarray, h: float, f: np.ndarray,
                uv: np.ndarray, top_uv: np.ndarray, wall_end: bool, photo: tuple | None = None,
                sizes: np.ndarray | None = None, base: float = 0.0) -> tuple[np.ndarray, np.ndarray, float]:
    """The footprint's ranges and height (yaw kept) whose clicked corners project nearest their
    clicks and the top corner nearest the top click, in pixels (_reproject_fit): the top click also
    pins floor[0]'s position, and a click's weight follows the metres its pixel spans. A side no
    clicked corner lies on keeps its distance to the opposite side (size_m), or its place with
    `wall_end` (the wall the piece stands against). `sizes` (size_m, m, measured with a tape: surer
    than clicks a pixel of which spans centimetres far off) also hold a range both of whose ends are
    clicked: its end further from the camera follows the nearer one. photo: (the _Clicks with the
    photo's edges, the piece's name, is a desk, the room's lo, hi): then the box's edges snapped to
    the photo join the fit (recon/clickedges.py). base (m): the height the piece stands on (0: the
    floor; a piece standing on another: that one's top), where its clicked corners f lie; h is its
    top's height (m)."""
    e1, e2 = np.array([math.cos(yaw), 0, -math.sin(yaw)]), np.array([math.sin(yaw), 0, math.cos(yaw)])
    known = [k for k in range(3) if np.isfinite(f[k, 0])]
    ix = {k: int(abs(f[k] @ e1 - xr[1]) < abs(f[k] @ e1 - xr[0])) for k in known}  # each click's end of
    iz = {k: 2 + int(abs(f[k] @ e2 - zr[1]) < abs(f[k] @ e2 - zr[0])) for k in known}  # each range
    x0 = np.r_[xr, zr, h]
    active = sorted(set(ix.values()) | set(iz.values())) + [4]
    if sizes is not None and not wall_end:  # measured sizes hold a range both of whose ends are clicked:
        for j0 in (0, 2):  # its far end (from the camera) follows the near one
            if j0 in active and j0 + 1 in active:
                end = ix if j0 == 0 else iz  # size_m: [|floor[0] floor[1]|, |floor[1] floor[2]|]
                size = next((sizes[n] for n, (p, q) in enumerate(((0, 1), (1, 2)))
                             if p in end and q in end and end[p] != end[q]), None)
                if size is None or not np.isfinite(size):  # not measured (the other one was)
                    continue
                axis_vec = e1 if j0 == 0 else e2
                c = float(camera.centre @ axis_vec)
                far = j0 if abs(c - x0[j0]) > abs(c - x0[j0 + 1]) else j0 + 1
                x0[far] = x0[far ^ 1] + (size if far > far ^ 1 else -size)
                active.remove(far)

    def full(y):
        x = x0.copy()
        x[active] = y
        for j in range(4):
            if j not in active and not wall_end:
                x[j] = x[j ^ 1] + (x0[j] - x0[j ^ 1])
        return x

    def pts(y):
        x = full(y)
        out = [x[ix[k]] * e1 + x[iz[k]] * e2 + [0.0, base, 0.0] for k in known]
        return np.array(out + [out[0] + [0.0, x[4] - base, 0.0]])

    uvs = np.vstack([uv[known], top_uv[None]])
    y = _reproject_fit(x0[active], pts, uvs, camera)
    if photo is not None and photo[0].edges is not None:
        P, name, desk, lo, hi = photo

        def corners(y):  # corner b: bit 0 the x end, bit 1 bottom / top, bit 2 the z end; a desk: its slab,
            x = full(y)  # then its legs' (leg l's corner b at 8 + 8 l + b; l: bit 0 the x end, bit 1 the z end)
            bottom = x[4] - DESK_TOP_M if desk else base
            out = [x[b & 1] * e1 + x[2 + (b >> 2 & 1)] * e2 + [0.0, x[4] if b & 2 else bottom, 0.0] for b in range(8)]
            if desk:
                i0, i1 = DESK_LEG_INSET_M, DESK_LEG_INSET_M + DESK_LEG_M
                for leg in range(4):
                    lx = (x[0] + i0, x[0] + i1) if not leg & 1 else (x[1] - i1, x[1] - i0)
                    lz = (x[2] + i0, x[2] + i1) if not leg & 2 else (x[3] - i1, x[3] - i0)
                    out += [lx[b & 1] * e1 + lz[b >> 2 & 1] * e2 + [0.0, bottom if b & 2 else base, 0.0]
                            for b in range(8)]
            return np.array(out)

        slab = (lambda y: _box(name, yaw, *_slab_ranges(full(y), desk, base))) if desk else None
        y, kept = _snap_and_refine(P, name, y, corners, pts, uvs, (e1, np.array([0.0, 1, 0]), e2), slab)
        held: dict[int, tuple[str, float]] = {}
        clicked: set[int] = set()
        if yaw == 0.0:
            # the sides a click the photo shows lies on (a corner no piece hides, nor the piece itself)
            own = slab(y) if desk else _box(name, yaw, *_slab_ranges(full(y), False, base))
            shown = _shown(P, name, pts(y), own)
            on = [(ix[k], iz[k]) for k in known] + [(ix[known[0]], iz[known[0]])]
            clicked = {j for ok, sides in zip(shown, on) if ok for j in sides}
            free_of_others = _shown(P, name, pts(y), own, by_others=True)
            behind = {j for j in range(4) if any(j in sides for sides in on)
                      and all(ok for ok, sides in zip(free_of_others, on) if j in sides)}
            y, held = _hold_on_walls(P, y, active, corners, pts, uvs, kept, lo, hi, clicked, x0,
                                     _piece_planes(P, name, full(y)), behind, name)
        words = ([f"{len(kept)} edges snapped"] if kept else []) + \
            [f"{SIDES[j]} side against {what}" for j, (what, _) in held.items()]
        P.refined[name] = ", ".join(words) if words else "as clicked"
        free = [k for k, j in enumerate(active)  # a side following a held one is held too
                if j not in held and not (j < 4 and (j ^ 1) in held and (j ^ 1) not in active)]
        if free:
            def sub(q, y=y, free=free):
                out = y.copy()
                out[free] = q
                return out

            sd = P.edges.sd(y[free], lambda q: corners(sub(q)), lambda q: pts(sub(q)), kept)
            loose = {SIDES[active[k]]: float(v) for k, v in zip(free, sd) if not Z99 * v <= TOLERANCE_M}
        else:
            sd, loose = [], {}
        # a side held on a plane is as sure as the two together (a wall its own clicks pin loosely)
        loose.update({SIDES[j]: float(v) for j, (_, v) in held.items() if not Z99 * v <= TOLERANCE_M})
        if loose:
            P.uncertain[name] = loose
            ask = _sizes_to_tape(f, e1, e2, full(y), loose, sizes)
            if ask:
                P.measure[name] = ask
        if yaw == 0.0:  # its sides' places and noise, for the pieces modelled after it (_piece_planes)
            x, side_sd = full(y), {active[k]: float(v) for k, v in zip(free, sd)}
            for j in range(4):
                if j in held:
                    side_sd[j] = held[j][1]
                elif j not in side_sd:  # a side following its partner (measured size, or held)
                    side_sd[j] = side_sd.get(j ^ 1, float("inf"))
            seen = _seen_sides(clicked, kept) | set(held)  # a side only hidden clicks place holds nothing
            P.sides[name] = (x[:4].copy(), {j: v if j in seen else float("inf") for j, v in side_sd.items()})
    x = full(y)
    return np.sort(x[:2]), np.sort(x[2:4]), float(x[4])


def _sizes_to_tape(f: np.ndarray, e1: np.ndarray, e2: np.ndarray, x: np.ndarray, loose: dict[str, float],
                   sizes: np.ndarray | None) -> list[dict]:
    """The sizes a tape gives that pin a piece's loose sides: for each range (x, z) with one side loose
    and its opposite side sure (the photo shows it, or a wall or piece holds it), the size_m entry
    along it (size_m[0]: floor[0]-floor[1], size_m[1]: floor[1]-floor[2]; f (3,3) the clicked floor
    corners, a row of nan where null) when not given yet: with it the loose side follows the sure one
    (_refine_box), to the tape's accuracy. x: the fit [x min, x max, z min, z max, top] (m) along the
    local axes e1, e2; loose: {side name: sd m}."""
    a_on_e1 = _a_on_e1(f, e1, e2)
    out = []
    for j0, along in ((0, "x"), (2, "z")):
        bad = [SIDES[j] in loose for j in (j0, j0 + 1)]
        if bad[0] == bad[1]:  # both sure, or both loose: one size alone does not pin it
            continue
        n = 0 if a_on_e1 == (j0 == 0) else 1
        if sizes is not None and np.isfinite(sizes[n]):
            continue
        out.append({"size_m": n, "floor": [n, n + 1], "along": along, "loose": SIDES[j0 + int(bad[1])],
                    "about_m": round(float(x[j0 + 1] - x[j0]), 3)})
    return out


def _slab_ranges(x: np.ndarray, desk: bool, base: float = 0.0) -> tuple:
    """A piece's parameters x [x min, x max, z min, z max, top] -> the (x, y, z) ranges of its box
    (a desk: its top slab), standing at height base (m)."""
    return x[:2], (x[4] - DESK_TOP_M if desk else base, x[4]), x[2:4]


def _snap_and_refine(P: _Clicks, name: str, y: np.ndarray, corners, pts, uvs: np.ndarray, axes, slab=None
                     ) -> tuple[np.ndarray, list]:
    """A piece's fit y refined with its edges snapped to the photo (recon/clickedges.py), in rounds:
    the edges are snapped around the model of the last fit and the fit redone, until a round finds
    no edge more (at most SNAP_ROUNDS): a click off by 3 sigma puts some edges beyond their search
    (a desk's slab: its top's and underside's front edges 4 cm apart), the fit on the others brings
    them in. Each edge is searched about where the last fit puts it, as far as that fit's own noise
    there reaches (PhotoEdges.predicted_sd): an edge the other edges already pin to a fraction of a
    pixel is searched no further than that (a seat's foot, its floor's plank seams 3-4 px below it).
    A desk (slab: y -> its top slab's box entry; corners(y) then holds its legs' corners
    after the slab's 8) also snaps its legs' vertical edges, where neither another piece nor its
    own slab hides them: a move along the line of sight, which its top's edges do not see, turns
    the legs' vertical planes through the camera (legs at different bearings), the floor clicks
    alone pin it otherwise."""
    from recon.clickedges import box_blocker

    y0, kept = y, []
    for _ in range(SNAP_ROUNDS):
        C = corners(y)
        pairs = _box_edges(P.camera.centre, C[:8], axes, False)
        model_sd = P.edges.predicted_sd(y, corners, pts, kept, pairs)
        lines = P.edges.lines(C, pairs, P.blocker(name), faint=True, model_sd=model_sd)
        if slab is not None:
            others, own = P.blocker(name), box_blocker(P.camera, [slab(y)])
            legs = [(8 + 8 * leg + i, 8 + 8 * leg + j) for leg in range(4)
                    for i, j in _box_edges(P.camera.centre, C[8 + 8 * leg:16 + 8 * leg], axes, False) if j - i == 2]
            lines += P.edges.lines(C, legs, lambda X: others(X) | own(X), faint=True)
        if len(lines) <= len(kept):
            break
        y, kept = P.edges.refine_lines(y0, corners, pts, uvs, lines)
    return y, kept


def _shown(P: _Clicks, name: str, X: np.ndarray, own: dict, by_others: bool = False) -> np.ndarray:
    """(m,) bool: piece `name`'s clicked corners X (m,3) (its current fit) that the photo surely
    shows: the sight line from the camera to the corner meets no other piece (the clicks-only model)
    grown by OCCLUDER_SHRINK_M, its click noise (a corner where two pieces meet, a seat's top corner
    at the end of a sofa's back, is not surely shown); a corner on the piece's own box `own` (an
    upright box entry: a box piece's, a desk's top slab) lies on a face of it turned to the camera (a
    convex box hides its other corners), and one off it (a desk's floor corners) is not hidden by it
    (grown as the others). by_others: (m,) bool the corners no other piece hides (the piece's own box
    aside)."""
    from recon.clickedges import OCCLUDER_SHRINK_M

    others = [b for b in P.occluders if b["name"] != name and not b["name"].startswith(name + "_")]
    C = P.camera.centre
    R, c = _local_axes(own), np.asarray(own["center"], float)
    h = np.asarray(own["size"], float) / 2
    loc, eye = (X - c) @ R.T, R @ (C - c)
    on_own = np.all(np.abs(loc) <= h + 1e-6, axis=1)
    turned = np.zeros(len(X), bool)
    for a in range(3):  # a corner is on the face of its end along axis a; turned when the eye is beyond it
        turned |= np.sign(loc[:, a]) * eye[a] > h[a]
    hidden = on_own & ~turned
    other = np.zeros(len(X), bool)
    for b in others + [own]:
        R, c = _local_axes(b), np.asarray(b["center"], float)
        hb = np.asarray(b["size"], float) / 2 + OCCLUDER_SHRINK_M
        o, d = R @ (C - c), (X - C) @ R.T  # the segment C + t d, t in [0, 1], in the box's frame
        with np.errstate(divide="ignore", invalid="ignore"):
            t1, t2 = (-hb - o) / d, (hb - o) / d
        par = d == 0  # parallel to a slab: inside it for every t, or never
        lo_t = np.where(par, np.where(np.abs(o) <= hb, -np.inf, np.inf), np.minimum(t1, t2)).max(axis=1)
        hi_t = np.where(par, np.where(np.abs(o) <= hb, np.inf, -np.inf), np.maximum(t1, t2)).min(axis=1)
        hit = (lo_t <= hi_t) & (hi_t >= 0.0) & (lo_t <= 1.0)
        if b is own:
            if by_others:
                return ~other
            hidden |= hit & ~on_own
        else:
            hidden |= hit
            other = other | hit
    return ~hidden


def _local_axes(b: dict) -> np.ndarray:
    """(3,3) rows: a box entry's local x, y, z axes in the world (yaw_deg about +Y)."""
    yaw = math.radians(b.get("yaw_deg", 0.0))
    return np.array([[math.cos(yaw), 0, -math.sin(yaw)], [0, 1.0, 0], [math.sin(yaw), 0, math.cos(yaw)]])


NEAR_FACE_M = 0.1  # m: a generous bound on a side's own noise (a hidden side's, 1 px = 3-5 cm far off, 2.6
# sigma): a face of another piece further off is not worth the chi-square test


def _piece_planes(P: _Clicks, name: str, x: np.ndarray, reach: float = 3 * 0.01) -> dict[int, list]:
    """The faces of the pieces modelled before piece `name` (P.sides: axis-aligned ones, with the photo)
    that each of its sides j (0..3: x min, x max, z min, z max; x its [x min, x max, z min, z max])
    might stand on: {j: [(coordinate m, its sd m, label)]}. A side may be flush with the other's side
    of the same end (a sofa's back over its seat, both ending at one plane) or against its opposite
    side (a cabinet beside a desk), when the two footprints meet across the other axis (overlap, or
    come within `reach`, 3 cm: three pixels of click noise at a few metres). Faces further off than
    NEAR_FACE_M plus `reach` and 3 of that face's sigmas are not offered (they cannot pass
    _hold_on_walls's chi-square test, which decides)."""
    out: dict[int, list] = {j: [] for j in range(4)}
    for other, (q, sd) in P.sides.items():
        if other == name:
            continue
        for j in range(4):
            a = j // 2  # 0: the x ends, 1: the z ends; the other axis's ranges must meet
            lo_o, hi_o = q[2 * (1 - a)], q[2 * (1 - a) + 1]
            lo_s, hi_s = x[2 * (1 - a)], x[2 * (1 - a) + 1]
            if lo_s > hi_o + reach or lo_o > hi_s + reach:
                continue
            for m in (j, j ^ 1):  # flush, or against
                s_m = sd.get(m, float("inf"))
                if np.isfinite(s_m) and abs(float(x[j]) - float(q[m])) <= NEAR_FACE_M + reach + 3 * s_m:
                    out[j].append((float(q[m]), s_m, f"{other!r}"))
    return out


def _hold_on_walls(P: _Clicks, y: np.ndarray, active: list[int], corners, pts, uvs: np.ndarray, lines: list,
                   lo: np.ndarray, hi: np.ndarray, clicked: set[int] = frozenset(), offsets: np.ndarray | None = None,
                   planes: dict[int, list] | None = None, behind: set[int] = frozenset(), name: str = ""
                   ) -> tuple[np.ndarray, dict[int, tuple[str, float]]]:
    """An axis-aligned piece's fit y (its parameters `active` of [x min, x max, z min, z max, top])
    with each side that the clicks and snapped `lines` allow on a clicked wall, or on a face of
    another piece (`planes`: _piece_planes), put there: a side the photo shows (a snapped line on it,
    or a click on a corner of it no piece hides: `clicked`, its indices; a side hidden under another
    piece, a sofa's seat under its back, is not judged: only clicks on hidden corners place it) is
    held on the plane when the side and the plane are one within both their noises (_against_chi2
    at most CHI2_HOLD: the side's place is one number, tested at 1 % for the piece's four sides; a
    piece the photo cannot tell from standing against the wall stands against it; a side further
    off than its noise keeps its fit); of several
    such planes, the one most alike. A side whose clicked corners only the piece itself hides
    (`behind`: its far side, which no other piece covers) is judged against a wall too: nothing
    else can stand between it and the wall unseen, as a piece under another's overhang can (a
    seat under its back, whose far side the back covers, stays unjudged). A side held on a wall is
    recorded in P.against under piece `name` (its own fit and variance), for the wall to take it
    (recon/clickjoint.py). Returns (y, {side held: (what it is held on, the held place's sd m)})."""
    from recon.clickedges import CHI2_HOLD

    base = P.edges.chi2(y, corners, pts, uvs, lines)
    held: dict[int, tuple[str, float]] = {}
    for j in range(4):
        axis, side = (0, 2)[j // 2], (-1, 1)[j % 2]
        bound = (lo if side < 0 else hi)[axis]
        seen = j in _seen_sides(clicked, lines)
        if not (seen or j in behind) or (j not in active and (j ^ 1) not in active):
            continue
        cands = ([(float(bound), P.wall_sd.get((axis, side), 0.0), "the wall")] if np.isfinite(bound) else []) + \
            (list((planes or {}).get(j, [])) if seen else [])
        shift = 0.0 if j in active else float(offsets[j] - offsets[j ^ 1])  # a side following its partner
        k = active.index(j if j in active else j ^ 1)
        best = None
        for value, plane_sd, what in cands:
            y1 = P.edges.held(y, k, value - shift, corners, pts, uvs, lines)
            d, rise = float(y[k]) + shift - value, P.edges.chi2(y1, corners, pts, uvs, lines) - base
            chi = _against_chi2(d, rise, plane_sd)
            if chi <= CHI2_HOLD and (best is None or chi < best[0]):
                best = (chi, value, plane_sd, what, d, rise, y1)
        if best is None:
            continue
        _, value, plane_sd, what, d, rise, y1 = best
        held_sd = plane_sd
        if rise > 0.0 and plane_sd > 0.0:  # the one plane: the side's fit and the other's, by their variances
            var_s, var_w = d * d / rise, plane_sd * plane_sd
            if what == "the wall":  # the wall takes it too (recon/clickjoint.py)
                P.against.setdefault((axis, side), []).append((name, float(y[k]) + shift, var_s))
            y1 = P.edges.held(y, k, value - shift + d * var_w / (var_s + var_w), corners, pts, uvs, lines)
            held_sd = float(np.sqrt(var_s * var_w / (var_s + var_w)))
        y, base = y1, P.edges.chi2(y1, corners, pts, uvs, lines)
        held[j] = (what, held_sd)
    return y, held


def _seen_sides(clicked: set[int], lines: list) -> set[int]:
    """A piece's sides (0..3: x min, x max, z min, z max) the photo shows: one a click on a corner no
    piece hides lies on (`clicked`), or one a snapped line of its box (corners 0..7 by bits: bit 0
    the x end, bit 2 the z end) runs along."""
    out = set(clicked) & {0, 1, 2, 3}
    for j in range(4):
        bit, end = (1, 4)[j // 2], j % 2
        if any(max(L.i, L.j) < 8 and bool(L.i & bit) == end and bool(L.j & bit) == end for L in lines):
            out.add(j)
    return out


def _against_chi2(d: float, rise: float, wall_sd: float) -> float:
    """The chi-square of a piece's side standing on a wall d (m) from the side's fit, when holding it
    on the wall's fitted offset raises the piece's chi-square by `rise` and the wall's offset has
    its own standard deviation wall_sd (m): the two are one plane when their difference is within
    both noises, d^2 / (var_side + var_wall), the side's variance being d^2 / rise (the piece's fit
    is linear in its sides over a few centimetres). wall_sd is at least what the snapped line's
    noise floor (LINE_SIGMA_FLOOR_PX) is in metres at the wall's foot: its stretches are one crease
    and share that error (_refine_room)."""
    if rise <= 0.0 or d == 0.0:
        return max(rise, 0.0)
    return d * d / (d * d / rise + wall_sd * wall_sd)


def _box_edges(centre: np.ndarray, corners: np.ndarray, axes, top_only: bool) -> list[tuple[int, int]]:
    """The edges (corner index pairs, corners indexed by bits: 0 along axes[0], 1 along axes[1] (up),
    2 along axes[2]) of a box that border a face turned to the camera at `centre`; with top_only,
    those of its top face (a desk: its slab's other edges depend on the assumed thickness)."""
    out = []
    for i in range(8):
        for b in (1, 2, 4):
            j = i | b
            if j == i or (top_only and not (i & 2 and j & 2)):
                continue
            for c, ax in zip((1, 2, 4), axes):
                if c == b:
                    continue
                normal = ax if i & c else -ax
                if float((centre - corners[i]) @ normal) > 0:
                    out.append((i, j))
                    break
    return out


def _against_walls(P: _Clicks, where: str, yaw: float, xr: np.ndarray, zr: np.ndarray, lo, hi, px_m: float,
                   name: str | None = None) -> None:
    """Refuse a footprint crossing a clicked wall by more than WALL_TOL_M + 3 px; put a side within
    WALL_SNAP_M of one (or across it) against it (axis-aligned footprints), clicks only: with the
    photo (P.edges) a side goes against a wall only by _hold_on_walls's chi-square test, and one
    across a wall is put on it (a side the photo does not show, a sofa's seat under its back, is
    no nearer a wall for being within WALL_SNAP_M of it when a pixel spans centimetres there).
    px_m: metres on the floor per pixel at the footprint's clicks (far from the camera a pixel
    spans centimetres). A side put on a wall the photo pins worse than TOLERANCE_M (P.wall_sd, at Z99
    sigma) is reported ill-determined for piece `name` with that wall's sd."""
    tol, snap = WALL_TOL_M + 3 * px_m, WALL_SNAP_M
    yaw_c, yaw_s = math.cos(yaw), math.sin(yaw)
    e1, e2 = np.array([yaw_c, -yaw_s]), np.array([yaw_s, yaw_c])  # world (x, z) of local x, z
    corners = np.array([x * e1 + z * e2 for x in xr for z in zr])
    for k, axis in ((0, 0), (1, 2)):
        for side, bound in ((-1, lo[axis]), (1, hi[axis])):
            if not np.isfinite(bound):
                continue
            beyond = float(np.max(side * (corners[:, k] - bound)))
            if beyond > tol:
                face = FACES[(axis, side)]
                raise P.err(where, f"the footprint crosses the {face} wall by {beyond:.2f} m: furniture stands "
                                   "inside the room (check the floor corners and the walls' floor lines)")
    if yaw != 0.0:
        return
    if P.edges is not None:
        snap = 0.0
    for rng, axis in ((xr, 0), (zr, 2)):
        for end, side, bound in ((0, -1, lo[axis]), (1, 1, hi[axis])):
            if np.isfinite(bound) and side * (bound - rng[end]) < snap:
                rng[end] = bound
                sd = P.wall_sd.get((axis, side), 0.0)  # with the photo: the side is now as sure as the wall
                if name is not None and not Z99 * sd <= TOLERANCE_M:
                    P.uncertain.setdefault(name, {})[SIDES[2 * (axis // 2) + end]] = sd


def _box(name: str, yaw: float, xr, yr, zr) -> dict:
    """A box entry from its local ranges (m) turned by yaw (rad)."""
    e1, e2 = np.array([math.cos(yaw), 0, -math.sin(yaw)]), np.array([math.sin(yaw), 0, math.cos(yaw)])
    c = (sum(xr) / 2) * e1 + (sum(zr) / 2) * e2 + np.array([0, sum(yr) / 2, 0])
    d = {"name": name, "type": "box", "role": "furniture", "center": c.tolist(),
         "size": [float(xr[1] - xr[0]), float(yr[1] - yr[0]), float(zr[1] - zr[0])]}
    if yaw != 0.0:
        d["yaw_deg"] = math.degrees(yaw)
    return d


def support_of(boxes: list[dict]) -> dict:
    """The box a piece standing on the piece made of `boxes` (its _furniture output) stands on: a
    box piece's box, a desk's top slab (the highest top)."""
    return max(boxes, key=lambda b: b["center"][1] + b["size"][1] / 2)


def _furniture(P: _Clicks, c: dict, where: str, name: str, lo, hi, wall_of: dict[str, Wall],
               pieces: dict[str, list[dict]] | None = None) -> list[dict]:
    """A furniture click -> its boxes (a desk's top slab and legs, or one box). pieces: the pieces
    modelled so far (name -> boxes), for one standing `on` another."""
    kind = json_field(c, "kind", where + ".", P.src)
    if kind not in FURNITURE_KINDS:
        raise P.err(where, f"field 'kind' must be one of {', '.join(FURNITURE_KINDS)}, got {kind!r}")
    on = c.get("on")
    base, support = 0.0, None
    if on is not None:
        if not isinstance(on, str) or on not in (pieces or {}):
            raise P.err(where, f"'on' must name a furniture piece clicked in this file, got {on!r}")
        support = support_of(pieces[on])
        base = float(support["center"][1] + support["size"][1] / 2)
        if not base < P.camera.centre[1]:
            raise P.err(where, f"the top of {on!r} ({base:.2f} m) is not below the camera "
                               f"({P.camera.centre[1]:.2f} m): corners on it cannot be seen")
    uv = P.pixels(c, "floor", 3, where, nulls=True)
    top_uv = P.pixels(c, "top", None, where)
    if not np.isfinite(uv[0, 0]):
        raise P.err(where, "floor[0] must be clicked: the top corner is the one straight above it")
    f = np.array([_floor(P, uv[k], where, f"floor[{k}]", base, on) if np.isfinite(uv[k, 0]) else np.full(3, np.nan)
                  for k in range(3)])
    against = c.get("against")
    if against is not None and against not in wall_of:
        raise P.err(where, f"'against' must name a clicked wall ({', '.join(sorted(wall_of))}), got {against!r}")
    sigma = P.edges.sigma if P.edges is not None else CLICK_SIGMA_PX
    noise_m = np.array([sigma * _pixel_metres(P, uv[k], base) if np.isfinite(uv[k, 0]) else np.nan for k in range(3)])
    hidden = c.get("hidden", [])
    if not isinstance(hidden, list) or any(type(i) is not int or i not in (1, 2) or np.isfinite(uv[i, 0])
                                           for i in hidden):
        raise P.err(where, f"'hidden' must list null floor corners (1 or 2) that lie in the photo behind the piece "
                           f"or another one, got {hidden!r}")
    yaw, xr, zr = _footprint(P, f, where, P.sizes(c, where), wall_of.get(against), noise_m, frozenset(hidden))
    # height: the vertical line over floor[0] nearest the top click's ray (least squares in h, s)
    C, d = ray(P.camera, top_uv)
    A = np.stack([np.array([0.0, 1.0, 0.0]), -d], axis=1)
    (h, s), *_ = np.linalg.lstsq(A, C - f[0], rcond=None)
    uv_line, z = P.camera.project((f[0] + [0.0, h, 0.0])[None])
    miss = float(np.linalg.norm(uv_line[0] - top_uv)) if z[0] > 0 else math.inf
    if not (h > 0 and s > 0 and miss <= TOP_MISS_PX):
        raise P.err(where, f"top [{top_uv[0]:g}, {top_uv[1]:g}] is not straight above floor[0] (the vertical line "
                           f"over it passes {miss:.0f} px away): click the top corner above floor[0]")
    xr, zr, h = _refine_box(P.camera, yaw, xr, zr, base + float(h), f, uv, top_uv,
                            against is not None and P.sizes(c, where) is None, (P, name, kind == "desk", lo, hi),
                            P.sizes(c, where), base)
    px_m = max(_pixel_metres(P, uv[k], base) for k in range(3) if np.isfinite(uv[k, 0]))
    _against_walls(P, where, yaw, xr, zr, lo, hi, px_m, name)
    if support is not None:
        _stands_on(P, where, on, support, yaw, xr, zr, px_m)
    if h > hi[1] + WALL_TOL_M:
        raise P.err(where, f"its top ({h:.2f} m) is above the ceiling ({hi[1]:.2f} m)")
    h = float(min(h, hi[1]))
    if kind == "box":
        return [_box(name, yaw, xr, (base, h), zr)]
    if h - base <= DESK_TOP_M + 0.01 or min(xr[1] - xr[0], zr[1] - zr[0]) < 2 * (DESK_LEG_M + DESK_LEG_INSET_M):
        raise P.err(where, f"a desk {xr[1] - xr[0]:.2f} x {zr[1] - zr[0]:.2f} m and {h - base:.2f} m high is too small "
                           f"for a {DESK_TOP_M * 100:g} cm top on legs: use kind 'box'")
    out = [_box(f"{name}_top", yaw, xr, (h - DESK_TOP_M, h), zr)]
    i0, i1 = DESK_LEG_INSET_M, DESK_LEG_INSET_M + DESK_LEG_M
    k = 0
    for lx in ((xr[0] + i0, xr[0] + i1), (xr[1] - i1, xr[1] - i0)):
        for lz in ((zr[0] + i0, zr[0] + i1), (zr[1] - i1, zr[1] - i0)):
            out.append(_box(f"{name}_leg{k}", yaw, lx, (base, h - DESK_TOP_M), lz))
            k += 1
    return out


def _stands_on(P: _Clicks, where: str, on: str, support: dict, yaw: float, xr: np.ndarray, zr: np.ndarray,
               px_m: float) -> None:
    """Refuse a piece standing `on` another whose footprint's centre is not over that one's top (the
    box `support`) grown by WALL_TOL_M + 3 px of click noise: a piece rests on its support when its
    centre of mass is over it (it may overhang, as a sofa's back does its seat)."""
    e1, e2 = np.array([math.cos(yaw), 0, -math.sin(yaw)]), np.array([math.sin(yaw), 0, math.cos(yaw)])
    centre = (sum(xr) / 2) * e1 + (sum(zr) / 2) * e2
    R, c = _local_axes(support), np.asarray(support["center"], float)
    loc = R @ (centre - c)
    half = np.asarray(support["size"], float) / 2 + WALL_TOL_M + 3 * px_m
    off = max(abs(loc[0]) - half[0], abs(loc[2]) - half[2])
    if off > 0:
        raise P.err(where, f"its footprint's centre lies {off + WALL_TOL_M + 3 * px_m:.2f} m beyond the top of {on!r} "
                           "it stands on: click its corners where it meets that top")
