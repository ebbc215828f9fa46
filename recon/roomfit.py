"""Fit a room box and a few furniture boxes to a sparse SfM point cloud.

The design card models a room as a box plus a handful of furniture boxes, not a dense mesh.
Method (photoar's own, built from Open3D's standard tools):
  1. clean-up: statistical outlier removal (Open3D `remove_statistical_outlier`);
  2. planes by RANSAC (Open3D `segment_plane`, Fischler and Bolles 1981) one after another in
     order of support, each refined by least squares (SVD) on its inliers. STOP CRITERION: the
     next plane's support falls below max(min_plane_points, min_plane_fraction * cleaned points);
     what is left is treated as clutter / noise (it may still form furniture clusters);
  3. a plane is a room surface when it bounds the cloud: at most `max_outside` of the points lie
     behind it (seen from the cameras). Horizontal ones facing up/down are floor/ceiling,
     vertical ones walls. Orthogonality is enforced: up from the floor/ceiling normals (or the
     given up), the first wall fixes the horizontal axes, every wall is snapped to the nearest
     axis and its offset re-estimated (median) on its inliers. Unseen surfaces take the extent
     of the points and are flagged `observed: false`;
  4. furniture: points away from the room surfaces, inside the room, clustered by DBSCAN
     (Open3D `cluster_dbscan`); clusters with >= min_box_points become boxes (2-98 percentile
     extents in the room axes), dropped to the floor when they end near it.
Output: primitives in the scene.json schema of ../shared/scenes/FORMAT.md (quads with corners,
normal, name, role; boxes with center, size), world frame of the input points.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

log = logging.getLogger("photoar.roomfit")

ROOM_NAMES = {(0, -1): "left", (0, 1): "right", (1, -1): "floor", (1, 1): "ceiling", (2, -1): "back", (2, 1): "front"}


@dataclass
class FitOptions:
    """tol: RANSAC inlier distance in the points' units (None: 1 % of the cloud's 90th-percentile
    radius); up: the frame's up direction when known (e.g. +Y after alignment), else estimated
    from the cameras; angle_deg: tolerance for horizontal / vertical / axis snapping."""

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

    def surface_plane(self, name: str) -> tuple[np.ndarray, float]:
        """Snapped plane of a room surface: unit normal n (facing the room) and d with n.x + d = 0."""
        s = self.surfaces[name]
        n = self.axes[s.axis] * (-s.side)
        return n, float(s.side * s.position)

    def primitives(self) -> list[dict]:
        """Room quads and furniture boxes in the scene.json primitive schema, world frame."""
        (x0, y0, z0), (x1, y1, z1) = self.lo, self.hi
        corners_r = {
            "floor": [[x0, y0, z0], [x1, y0, z0], [x1, y0, z1], [x0, y0, z1]],
            "ceiling": [[x0, y1, z1], [x1, y1, z1], [x1, y1, z0], [x0, y1, z0]],
            "back": [[x0, y1, z0], [x1, y1, z0], [x1, y0, z0], [x0, y0, z0]],
            "front": [[x1, y1, z1], [x0, y1, z1], [x0, y0, z1], [x1, y0, z1]],
            "left": [[x0, y1, z1], [x0, y1, z0], [x0, y0, z0], [x0, y0, z1]],
            "right": [[x1, y1, z0], [x1, y1, z1], [x1, y0, z1], [x1, y0, z0]],
        }
        out = []
        for name in ("floor", "ceiling", "back", "front", "left", "right"):
            s = self.surfaces[name]
            c = np.array(corners_r[name]) @ self.axes
            n, _ = self.surface_plane(name)
            out.append({"name": name, "type": "quad", "role": "room", "corners": c.tolist(), "normal": n.tolist(),
                        "size_m": [float(np.linalg.norm(c[1] - c[0])), float(np.linalg.norm(c[3] - c[0]))],
                        "albedo": s.colour.tolist(), "emitter": False,
                        "fit": {"observed": s.observed, "n_points": s.n_points}})
        for k, (c, size, n) in enumerate(self.boxes):
            out.append({"name": f"box_{k}", "type": "box", "role": "furniture", "center": (c @ self.axes).tolist(),
                        "size": size.tolist(), "albedo": [0.5, 0.5, 0.5], "emitter": False,
                        "fit": {"n_points": n}})
        return out


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def _refine(P: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares plane through P (N,3): unit normal, d with n.x + d = 0."""
    c = P.mean(0)
    n = np.linalg.svd(P - c, full_matrices=False)[2][-1]
    return n, -float(n @ c)


def fit_room(points: np.ndarray, colors: np.ndarray | None, cam_centres: np.ndarray,
             cam_ups: np.ndarray | None = None, opts: FitOptions | None = None) -> RoomFit:
    """Fit the room box and furniture boxes.

    points (N,3), colors (N,3) uint8 RGB or None, cam_centres (M,3) in the same frame (the
    cameras are assumed inside the room), cam_ups (M,3) camera up vectors (-R[1]) used when
    opts.up is None. Raises ValueError when the cloud is too small or no floor is found.
    """
    from recon.io import open3d

    o3d = open3d()

    opts = opts or FitOptions()
    P = np.asarray(points, np.float64)
    if len(P) < 3 * opts.min_plane_points:
        raise ValueError(f"too few reconstructed points to fit a room ({len(P)} < {3 * opts.min_plane_points})")
    col = np.full((len(P), 3), 128, np.uint8) if colors is None else np.asarray(colors, np.uint8)
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(P))
    _, keep = pcd.remove_statistical_outlier(nb_neighbors=16, std_ratio=2.5)
    keep = np.asarray(keep, int)
    Q, qcol = P[keep], col[keep]
    centre = np.median(Q, 0)
    tol = opts.tol or 0.01 * float(np.percentile(np.linalg.norm(Q - centre, axis=1), 90))
    cam_mean = np.asarray(cam_centres, np.float64).reshape(-1, 3).mean(0)
    if opts.up is not None:
        up = _unit(np.asarray(opts.up, np.float64))
    elif cam_ups is not None:
        up = _unit(np.asarray(cam_ups, np.float64).reshape(-1, 3).mean(0))
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
        planes.append({"normal": n, "offset": d, "inliers": inl, "support": len(inl), "outside": outside,
                       "label": ""})
        rest = np.setdiff1d(rest, inl)
    log.info("%d planes found; stop: %s", len(planes), stop)

    # 3. room surfaces, orthogonalised
    cos_t, sin_t = np.cos(np.radians(opts.angle_deg)), np.sin(np.radians(opts.angle_deg))
    bounding = [p for p in planes if p["outside"] <= opts.max_outside]
    floors = [p for p in bounding if p["normal"] @ up > cos_t]
    ceilings = [p for p in bounding if p["normal"] @ up < -cos_t]
    walls = [p for p in bounding if abs(p["normal"] @ up) < sin_t]
    if floors:
        floors[0]["label"] = "floor"
    if ceilings:
        ceilings[0]["label"] = "ceiling"
    ys = [p["normal"] * p["support"] for p in floors[:1]] + [-p["normal"] * p["support"] for p in ceilings[:1]]
    y = _unit(sum(ys)) if ys else up
    if walls:
        a = _unit(walls[0]["normal"] - (walls[0]["normal"] @ y) * y)
    else:
        a = _unit(np.cross(y, [1.0, 0.0, 0.0]) if abs(y[0]) < 0.9 else np.cross(y, [0.0, 0.0, 1.0]))
    b = np.cross(a, y)  # a, y, b right-handed
    # name the horizontal axes so that x is the one closest to the frame's X (a given frame keeps its names)
    x = a if abs(a[0]) >= abs(b[0]) else b
    x = x if x[0] >= 0 else -x
    z = np.cross(x, y)
    axes = np.stack([x, y, z])
    R = Q @ axes.T  # room coordinates
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
        surfaces[name] = Surface(name, k, side, pos, True, p["support"], p["normal"], p["offset"],
                                 qcol[p["inliers"]].mean(0) / 255.0)
    if "floor" not in surfaces:
        raise ValueError(f"no floor found: none of the {len(planes)} planes faces up and bounds the points "
                         f"(stop: {stop})")
    ext = np.vstack([R, np.asarray(cam_centres).reshape(-1, 3) @ axes.T])
    lo, hi = np.percentile(ext, 1, axis=0), np.percentile(ext, 99, axis=0)
    for (k, side), name in ROOM_NAMES.items():
        if name in surfaces:
            (lo if side < 0 else hi)[k] = surfaces[name].position
        else:
            surfaces[name] = Surface(name, k, side, float((lo if side < 0 else hi)[k]), False)
    for s in surfaces.values():
        s.position = float((lo if s.side < 0 else hi)[s.axis])

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
    return RoomFit(axes, surfaces, lo, hi, boxes, planes, stop, len(P), len(Q), tol)
