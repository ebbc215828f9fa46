"""Fit a room box and a few furniture boxes to a sparse SfM point cloud.

The design card models a room as a box plus a handful of furniture boxes, not a dense mesh.
Method (photoar's own, built from Open3D's standard tools):
  1. clean-up: statistical outlier removal (Open3D `remove_statistical_outlier`);
  2. planes by RANSAC (Open3D `segment_plane`, Fischler and Bolles 1981) one after another in
     order of support, each refined by least squares (SVD) on its inliers. STOP CRITERION: the
     next plane's support falls below max(min_plane_points, min_plane_fraction * cleaned points);
     what is left is treated as clutter / noise (it may still form furniture clusters);
  3. a plane is a room surface when it bounds the cloud: at most `max_outside` of the points lie
     behind it (seen from the cameras). Up: the given one (a calibrated frame), else estimated
     from the cameras (`up_from_cameras`): photos are taken upright, so every camera's -y axis
     is within 45 deg of world up and so is their mean; the floor is then the best-supported
     bounding plane facing up (within 45 deg of that mean) with every camera above it, and its
     normal becomes up. The ceiling faces down with every camera below it; walls are vertical
     with every camera on their inner side. Orthogonality is enforced: the first wall (or the
     reference camera's right axis) fixes the horizontal axes, every wall is snapped to the
     nearest axis and its offset re-estimated (median) on its inliers;
  3b. unobserved surfaces (`observed: false`) come from the tape (`room_size`: the opposite
     observed wall + the measured size) or are placed beyond the cameras: `margin` behind the
     outermost camera (WALL_MARGIN_M = 0.3 m in metric frames: a hand-held camera has at least
     the photographer's head and body, ~0.3 m, between it and the wall behind; in SfM units the
     same fraction, 0.3/1.5, of the cameras' mean height above the floor, 1.5 m being a standing
     photographer's eye height), and never inside the points' extent (1-99 percentile). A room
     that does not contain every camera raises RoomError;
  4. furniture: points away from the room surfaces, inside the room, clustered by DBSCAN
     (Open3D `cluster_dbscan`); clusters with >= min_box_points become boxes (2-98 percentile
     extents in the room axes), dropped to the floor when they end near it.
Output (`RoomFit.primitives`): the user primitives format of `photoar scene --primitives`: the
room as one box {name "room", type "box", role "room", center, size, yaw_deg, walls: [{name,
observed, how, support: {points, fraction, rms}, normal, offset, albedo}]} and furniture boxes
(role "furniture"), in the world frame of the input points (which must have +Y up).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

log = logging.getLogger("photoar.roomfit")

WALL_MARGIN_M = 0.3  # m between a camera and an unobserved wall behind it (see the module docstring)
EYE_HEIGHT_M = 1.5  # m, a standing photographer's camera height: converts the margin into SfM units
UPRIGHT_DEG = 45.0  # an upright photo's -y axis is within this angle of world up (pitch and roll below it)


class RoomError(ValueError):
    """The room fit failed (no floor, or a room that does not contain the cameras)."""

ROOM_NAMES = {(0, -1): "left", (0, 1): "right", (1, -1): "floor", (1, 1): "ceiling", (2, -1): "back", (2, 1): "front"}


@dataclass
class FitOptions:
    """tol: RANSAC inlier distance in the points' units (None: 1 % of the cloud's 90th-percentile
    radius); up: the frame's up direction when known (e.g. +Y after alignment), else estimated
    from the cameras; angle_deg: tolerance for horizontal / vertical / axis snapping;
    margin: distance of an unobserved wall beyond the outermost camera, points' units (None:
    WALL_MARGIN_M / EYE_HEIGHT_M x the cameras' mean height above the floor); room_size: taped
    (W, H, D) along the room's x, y, z in the points' units (None: unknown); ref_right: the
    reference camera's right axis (R[0]) in the points' frame: room x is the horizontal axis
    closest to it (None: closest to the frame's X); axes: (3,3) rows x, y (up), z of a frame already
    aligned with the room (a calibrated photo's world, whose X and Z come from the room's own
    vanishing lines, or the room frame of a first fit): the walls are snapped to these axes
    instead of turning the frame to the first wall, so that the room box has yaw 0 exactly;
    floor_y: the floor's height when the frame defines it (a frame scaled by a camera's height
    above the floor found in a first pass puts it at y = 0): the floor plane must still be found,
    but sits there exactly instead of where this pass's RANSAC puts it (a few mm away)."""

    tol: float | None = None
    up: tuple[float, float, float] | None = None
    angle_deg: float = 15.0
    max_planes: int = 10
    min_plane_points: int = 30
    min_plane_fraction: float = 0.03
    max_outside: float = 0.05
    min_box_points: int = 20
    max_boxes: int = 8
    seed: int = 0
    margin: float | None = None
    room_size: tuple[float, float, float] | None = None
    ref_right: tuple[float, float, float] | None = None
    axes: np.ndarray | None = None
    floor_y: float | None = None


@dataclass
class Surface:
    name: str
    axis: int  # 0, 1, 2 room axis
    side: int  # -1 min side, +1 max side
    position: float  # coordinate along the room axis, points' units
    observed: bool
    n_points: int = 0
    raw_normal: np.ndarray | None = None  # (3,) RANSAC+SVD normal before snapping (world), facing the room
    raw_offset: float = 0.0  # raw plane n.x + d = 0
    rms: float = 0.0  # RMS distance of its inliers to the raw plane, points' units
    how: str = ""  # how its position was found ("plane", "tape", "beyond the cameras")
    colour: np.ndarray = field(default_factory=lambda: np.full(3, 0.5))


@dataclass
class RoomFit:
    axes: np.ndarray  # (3,3) rows: room x, y (up), z axes in world coordinates, right-handed
    surfaces: dict[str, Surface]
    lo: np.ndarray  # (3,) room box min in room coordinates r = axes @ x
    hi: np.ndarray  # (3,) room box max
    boxes: list[tuple[np.ndarray, np.ndarray, int]]  # (centre_r (3,), size (3,), n_points)
    planes: list[dict]  # every RANSAC plane in order: normal, offset, support, label
    stop_reason: str
    n_points: int
    n_clean: int
    tol: float
    up_from: str = ""
    margin: float = 0.0

    def contains(self, X: np.ndarray, slack: float = 0.0) -> np.ndarray:
        """(N,) bool: points X (N,3, world) inside the room box grown by `slack`."""
        R = np.asarray(X, np.float64).reshape(-1, 3) @ self.axes.T
        return np.all((R >= self.lo - slack) & (R <= self.hi + slack), axis=1)

    def room_box(self) -> dict:
        """The room as one box (user primitives format: center, size, yaw_deg about +Y; role "room")
        with its six walls listed under "walls" (observed flag, support, plane). Needs axes[1] = +Y."""
        if abs(self.axes[1, 1]) < 1 - 1e-6:
            raise ValueError("room_box needs a frame whose +Y is the room's up")
        yaw = float(np.degrees(np.arctan2(-self.axes[0, 2], self.axes[0, 0])))
        walls = []
        for name in ("floor", "ceiling", "back", "front", "left", "right"):
            s = self.surfaces[name]
            n, d = self.surface_plane(name)
            walls.append({"name": name, "observed": bool(s.observed), "how": s.how,
                          "support": {"points": int(s.n_points),
                                      "fraction": float(s.n_points / max(self.n_clean, 1)),
                                      "rms": float(s.rms)},
                          "normal": n.tolist(), "offset": d})
        centre = ((self.lo + self.hi) / 2) @ self.axes
        return {"name": "room", "type": "box", "role": "room", "center": centre.tolist(),
                "size": (self.hi - self.lo).tolist(), "yaw_deg": yaw, "walls": walls}

    def surface_plane(self, name: str) -> tuple[np.ndarray, float]:
        """Snapped plane of a room surface: unit normal n (facing the room) and d with n.x + d = 0."""
        s = self.surfaces[name]
        n = self.axes[s.axis] * (-s.side)
        return n, float(s.side * s.position)

    def primitives(self) -> list[dict]:
        """The room box (role "room", walls listed) and the furniture boxes (role "furniture") in the
        user primitives format of `photoar scene --primitives`, world frame (which must have +Y up)."""
        room = self.room_box()
        for w in room["walls"]:
            w["albedo"] = self.surfaces[w["name"]].colour.tolist()
        out = [room]
        for k, (c, size, n) in enumerate(self.boxes):
            out.append({"name": f"box_{k}", "type": "box", "role": "furniture", "center": (c @ self.axes).tolist(),
                        "size": size.tolist(), "yaw_deg": room["yaw_deg"], "albedo": [0.5, 0.5, 0.5],
                        "support": {"points": int(n)}})
        return out


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def _refine(P: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares plane through P (N,3): unit normal, d with n.x + d = 0."""
    c = P.mean(0)
    n = np.linalg.svd(P - c, full_matrices=False)[2][-1]
    return n, -float(n @ c)


def up_from_cameras(cam_ups: np.ndarray) -> np.ndarray:
    """Approximate world up from upright photos: the unit mean of the cameras' -y axes (M,3).

    Its error is about the photos' mean pitch (people tilt the camera down at a room, 10-30 deg);
    `fit_room` only uses it to tell the floor from the walls (UPRIGHT_DEG), then takes the floor's
    normal as up.
    """
    u = np.asarray(cam_ups, np.float64).reshape(-1, 3).sum(0)
    if not np.linalg.norm(u) > 1e-9:
        raise RoomError("the cameras' up axes cancel out: the photos are not upright, pass --camera")
    return _unit(u)


def fit_room(points: np.ndarray, colors: np.ndarray | None, cam_centres: np.ndarray,
             cam_ups: np.ndarray | None = None, opts: FitOptions | None = None) -> RoomFit:
    """Fit the room box and furniture boxes.

    points (N,3), colors (N,3) uint8 RGB or None, cam_centres (M,3) in the same frame, cam_ups
    (M,3) camera up vectors (-R[1]) used when opts.up is None. Raises RoomError (a ValueError)
    when the cloud is too small, no floor is found or the room does not contain every camera.
    """
    from recon.io import open3d

    o3d = open3d()

    opts = opts or FitOptions()
    P = np.asarray(points, np.float64).reshape(-1, 3)
    C = np.asarray(cam_centres, np.float64).reshape(-1, 3)
    if len(P) < 3 * opts.min_plane_points:
        raise RoomError(f"too few reconstructed points to fit a room ({len(P)} < {3 * opts.min_plane_points})")
    col = np.full((len(P), 3), 128, np.uint8) if colors is None else np.asarray(colors, np.uint8)
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(P))
    _, keep = pcd.remove_statistical_outlier(nb_neighbors=16, std_ratio=2.5)
    keep = np.asarray(keep, int)
    Q, qcol = P[keep], col[keep]
    centre = np.median(Q, 0)
    tol = opts.tol or 0.01 * float(np.percentile(np.linalg.norm(Q - centre, axis=1), 90))
    cam_mean = C.mean(0)
    if opts.axes is not None:
        up, up_from, up_deg = np.asarray(opts.axes, np.float64)[1], "given (room axes given)", opts.angle_deg
    elif opts.up is not None:
        up, up_from, up_deg = _unit(np.asarray(opts.up, np.float64)), "given", opts.angle_deg
    elif cam_ups is not None:
        up, up_from, up_deg = up_from_cameras(cam_ups), "floor normal (cameras' mean up to find it)", UPRIGHT_DEG
    else:
        raise ValueError("fit_room needs the up direction or the camera up vectors")

    # 2. planes in order of support
    o3d.utility.random.seed(opts.seed)
    rest = np.arange(len(Q))
    planes: list[dict] = []
    min_support = max(opts.min_plane_points, int(opts.min_plane_fraction * len(Q)))
    stop = f"reached max_planes={opts.max_planes}"
    while len(planes) < opts.max_planes:
        if len(rest) < min_support:
            stop = f"{len(rest)} points left (< {min_support}): noise"
            break
        sub = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(Q[rest]))
        _, inl = sub.segment_plane(distance_threshold=tol, ransac_n=3, num_iterations=1000)
        inl = rest[np.asarray(inl, int)]
        if len(inl) < min_support:
            stop = (f"next plane supports {len(inl)} points (< {min_support} = max({opts.min_plane_points}, "
                    f"{opts.min_plane_fraction:g} x {len(Q)})): the {len(rest)} remaining points are clutter/noise")
            break
        n, d = _refine(Q[inl])
        if n @ cam_mean + d < 0:
            n, d = -n, -d
        outside = float(np.mean(Q @ n + d < -3 * tol))
        cams_inside = bool(np.all(C @ n + d > 0))
        rms = float(np.sqrt(np.mean((Q[inl] @ n + d) ** 2)))
        planes.append({"normal": n, "offset": d, "inliers": inl, "support": len(inl), "outside": outside,
                       "cameras_inside": cams_inside, "rms": rms, "label": ""})
        rest = np.setdiff1d(rest, inl)
    log.info("%d planes found; stop: %s", len(planes), stop)

    # 3. room surfaces: bounding planes with every camera on their inner side, orthogonalised
    cos_t, sin_t = np.cos(np.radians(opts.angle_deg)), np.sin(np.radians(opts.angle_deg))
    cos_up = np.cos(np.radians(up_deg))
    bounding = [p for p in planes if p["outside"] <= opts.max_outside and p["cameras_inside"]]
    floors = [p for p in bounding if p["normal"] @ up > cos_up]
    if not floors:
        raise RoomError(f"no floor found: none of the {len(planes)} planes faces up (within {up_deg:g} deg of the "
                        f"{'given' if opts.up is not None else 'mean camera'} up), lies below every camera and "
                        f"bounds the points (stop: {stop})")
    floors[0]["label"] = "floor"
    y = up if opts.up is not None or opts.axes is not None else _unit(floors[0]["normal"])
    ceilings = [p for p in bounding if p["normal"] @ y < -cos_t]
    walls = [p for p in bounding if abs(p["normal"] @ y) < sin_t]
    if opts.axes is not None:
        a = np.asarray(opts.axes, np.float64)[0]
    elif walls:
        a = _unit(walls[0]["normal"] - (walls[0]["normal"] @ y) * y)
    elif opts.ref_right is not None:
        r = np.asarray(opts.ref_right, np.float64)
        a = _unit(r - (r @ y) * y)
    else:
        a = _unit(np.cross(y, [1.0, 0.0, 0.0]) if abs(y[0]) < 0.9 else np.cross(y, [0.0, 0.0, 1.0]))
    b = np.cross(a, y)  # a, y, b right-handed
    # x: the horizontal axis closest to the reference camera's right (else the frame's X), so that the
    # reference camera looks towards -z (at the "back" wall) as in the benchmark scenes
    ref = np.asarray(opts.ref_right, np.float64) if opts.ref_right is not None else np.array([1.0, 0.0, 0.0])
    x = a if abs(a @ ref) >= abs(b @ ref) else b
    x = x if x @ ref >= 0 else -x
    z = np.cross(x, y)
    axes = np.stack([x, y, z]) if opts.axes is None else np.asarray(opts.axes, np.float64)
    R = Q @ axes.T  # room coordinates
    RC = C @ axes.T
    surfaces: dict[str, Surface] = {}
    for p in sorted(floors[:1] + ceilings[:1] + walls, key=lambda p: -p["support"]):
        nr = axes @ p["normal"]  # normal in room axes
        k = int(np.argmax(np.abs(nr)))
        if abs(nr[k]) < cos_t:
            continue
        side = -1 if nr[k] > 0 else 1  # a normal along +axis faces into the room from the min side
        name = ROOM_NAMES[(k, side)]
        if name in surfaces:
            continue
        p["label"] = name
        pos = float(np.median(R[p["inliers"], k]))
        if name == "floor" and opts.floor_y is not None:
            pos = float(opts.floor_y)
        surfaces[name] = Surface(name, k, side, pos, True, p["support"], p["normal"], p["offset"], p["rms"], "plane",
                                 qcol[p["inliers"]].mean(0) / 255.0)

    # 3b. unobserved surfaces: tape, else beyond the cameras (and the points)
    height = float(np.mean(RC[:, 1] - surfaces["floor"].position))
    margin = opts.margin if opts.margin is not None else WALL_MARGIN_M / EYE_HEIGHT_M * height
    p_lo, p_hi = np.percentile(R, 1, axis=0), np.percentile(R, 99, axis=0)
    lo, hi = np.zeros(3), np.zeros(3)
    for k in range(3):
        s_lo, s_hi = surfaces.get(ROOM_NAMES[(k, -1)]), surfaces.get(ROOM_NAMES[(k, 1)])
        size = None if opts.room_size is None else float(opts.room_size[k])
        guess_lo = min(p_lo[k], RC[:, k].min() - margin)
        guess_hi = max(p_hi[k], RC[:, k].max() + margin)
        if s_lo is not None and s_hi is not None:
            lo[k], hi[k] = s_lo.position, s_hi.position
            continue
        if s_lo is not None:
            lo[k] = s_lo.position
            hi[k], how = (lo[k] + size, "tape") if size else (guess_hi, "beyond the cameras")
        elif s_hi is not None:
            hi[k] = s_hi.position
            lo[k], how = (hi[k] - size, "tape") if size else (guess_lo, "beyond the cameras")
        elif size:
            mid = (guess_lo + guess_hi) / 2
            lo[k], hi[k], how = mid - size / 2, mid + size / 2, "tape, centred on the cameras and points"
        else:
            lo[k], hi[k], how = guess_lo, guess_hi, "beyond the cameras"
        for side, v in ((-1, lo[k]), (1, hi[k])):
            if ROOM_NAMES[(k, side)] not in surfaces:
                surfaces[ROOM_NAMES[(k, side)]] = Surface(ROOM_NAMES[(k, side)], k, side, float(v), False, how=how)
    for sname, s in surfaces.items():
        s.position = float((lo if s.side < 0 else hi)[s.axis])
    if np.any(hi - lo <= 0):
        raise RoomError(f"the fitted room is empty (size {np.round(hi - lo, 4).tolist()} along x, y, z)")
    out = ~np.all((RC >= lo - tol) & (RC <= hi + tol), axis=1)
    if out.any():
        k = int(np.argwhere(out)[0][0])
        beyond = [n for (ax, side), n in ROOM_NAMES.items()
                  if (side < 0 and RC[k, ax] < lo[ax] - tol) or (side > 0 and RC[k, ax] > hi[ax] + tol)]
        raise RoomError(f"the fitted room (size {np.round(hi - lo, 3).tolist()}) does not contain {int(out.sum())} of "
                        f"the {len(C)} cameras: camera {k} is beyond the {', '.join(beyond)} "
                        f"({', '.join(surfaces[n].how for n in beyond)})")

    # 4. furniture clusters
    near = np.zeros(len(Q), bool)
    for s in surfaces.values():
        if s.observed:
            near |= np.abs(R[:, s.axis] - s.position) < 3 * tol
    inside = np.all((R > lo + 3 * tol) & (R < hi - 3 * tol), axis=1)
    cand = np.where(~near & inside)[0]
    boxes = []
    if len(cand) >= opts.min_box_points:
        cp = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(Q[cand]))
        labels = np.asarray(cp.cluster_dbscan(eps=6 * tol, min_points=5))
        ids, counts = np.unique(labels[labels >= 0], return_counts=True)
        for i in ids[np.argsort(-counts)][: opts.max_boxes]:
            m = cand[labels == i]
            if len(m) < opts.min_box_points:
                break
            boxes.append([np.percentile(R[m], 2, axis=0), np.percentile(R[m], 98, axis=0), len(m)])
        merged = True
        while merged:  # clusters whose boxes touch (within 2 tol) are parts of one piece of furniture
            merged = False
            for i in range(len(boxes)):
                for j in range(i + 1, len(boxes)):
                    (a0, a1, na), (b0, b1, nb) = boxes[i], boxes[j]
                    if np.all(a0 <= b1 + 2 * tol) and np.all(b0 <= a1 + 2 * tol):
                        boxes[i] = [np.minimum(a0, b0), np.maximum(a1, b1), na + nb]
                        del boxes[j]
                        merged = True
                        break
                if merged:
                    break
        for k, (blo, bhi, nm) in enumerate(boxes):
            if blo[1] - lo[1] < 0.1 * (hi[1] - lo[1]):
                blo[1] = lo[1]
            bhi = np.maximum(bhi, blo + tol)
            boxes[k] = ((blo + bhi) / 2, bhi - blo, nm)
    log.info("room surfaces seen: %s; %d furniture boxes", ", ".join(n for n, s in surfaces.items() if s.observed),
             len(boxes))
    for p in planes:
        p.pop("inliers")
        p["normal"] = p["normal"].tolist()
    return RoomFit(axes, surfaces, lo, hi, boxes, planes, stop, len(P), len(Q), tol, up_from, margin)
