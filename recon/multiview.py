"""Multi-image reconstruction: structure from motion with pycolmap, then a similarity alignment.

Implements the "multi-image reconstruction" step of the design card by wrapping COLMAP's
incremental SfM (Schoenberger and Frahm, "Structure-from-Motion Revisited", CVPR 2016) through
pycolmap 4.x: SIFT extraction, exhaustive matching with geometric verification, incremental
mapping. Like hloc's `reconstruction.py` it keeps the LARGEST reconstruction COLMAP returns and
says so; images left out of it are reported, never silently dropped.

Metric alignment is a similarity transform X_world = s R X_sfm + t, either
  * least squares over camera centres (Umeyama 1991, via `pycolmap.estimate_sim3d`) to known
    cameras (>= 3), or
  * from ONE known camera pose (a photo calibrated from vanishing points, issue "calibration"),
    with the scale from a known length or the camera's height above the floor.

Conventions (recon/camera.py): OpenCV camera axes, X_cam = R X_world + t, pixel (0, 0) is the
CENTRE of the top-left pixel. COLMAP puts the centre of the top-left pixel at (0.5, 0.5), so
principal points are shifted by 0.5 px on the way in and out.
"""
from __future__ import annotations

import logging
import tempfile
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from recon.camera import Camera

log = logging.getLogger("photoar.multiview")

IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp")
COLMAP_PIXEL_OFFSET = 0.5  # COLMAP pixel-centre coordinate minus photoar's


@dataclass
class SfmOptions:
    """Options of `reconstruct`.

    max_features: SIFT features per image; max_image_size: longest side used for extraction (px,
    the poses and K stay in full-resolution pixels); single_camera: True = one shared camera,
    False = one per image, None = shared when all images have the same size and EXIF camera
    model (COLMAP's `exif_camera_model`), or the same size and no EXIF camera at all (tried
    first, see `reconstruct`); camera: known intrinsics (K, width, height), shared and held fixed;
    num_threads: CPU threads for every stage; seed: COLMAP's random seed.
    """

    max_features: int = 4000
    max_image_size: int = 1600
    single_camera: bool | None = None
    camera: Camera | None = None
    num_threads: int = 2
    seed: int = 0
    min_model_size: int = 3
    peak_threshold: float | None = None  # SIFT detection threshold (None: COLMAP's default 0.0067)
    two_view_tracks: bool = False  # also triangulate points seen in only two images
    abs_pose_min_inliers: int = 15  # 2D-3D inliers needed to register an image (COLMAP: 30; 15 joins
    # the temple ring into one model instead of two)


@dataclass
class Similarity:
    """X_dst = s R X_src + t; s > 0, R (3,3) a rotation, t (3,)."""

    s: float = 1.0
    R: np.ndarray = field(default_factory=lambda: np.eye(3))
    t: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def apply(self, X: np.ndarray) -> np.ndarray:
        """Points (N,3) -> (N,3)."""
        return self.s * np.asarray(X, np.float64) @ self.R.T + self.t

    def apply_camera(self, cam: Camera) -> Camera:
        """The same physical camera expressed in the destination frame (K unchanged)."""
        R = cam.R @ self.R.T
        return replace(cam, R=R, t=self.s * cam.t - R @ self.t)

    def then(self, other: "Similarity") -> "Similarity":
        """other o self."""
        return Similarity(other.s * self.s, other.R @ self.R, other.s * other.R @ self.t + other.t)

    def to_dict(self) -> dict:
        return {"scale": float(self.s), "R": self.R.tolist(), "t": self.t.tolist()}


@dataclass
class SfmResult:
    """The largest reconstruction, in the SfM frame (arbitrary scale) or an aligned one.

    cameras: registered image name -> Camera (K in this image's full-resolution pixels);
    points (N,3), colors (N,3) uint8 RGB, point_errors (N,) mean reprojection error per point (px);
    unregistered: readable images not in the kept model; unreadable: name -> reason;
    models: image names of every model COLMAP found, largest first (models[0] is the kept one);
    mean_reproj_px: mean reprojection error over all observations of the kept model (px);
    timings: wall seconds per stage; units: "sfm" or "m".
    """

    cameras: dict[str, Camera]
    points: np.ndarray
    colors: np.ndarray
    point_errors: np.ndarray
    unregistered: list[str]
    unreadable: dict[str, str]
    models: list[list[str]]
    mean_reproj_px: float
    timings: dict[str, float]
    n_images: int
    units: str = "sfm"
    alignment: dict = field(default_factory=dict)

    @property
    def registered(self) -> list[str]:
        return sorted(self.cameras)

    def transformed(self, sim: Similarity, units: str | None = None, how: str = "") -> "SfmResult":
        return replace(self, cameras={n: sim.apply_camera(c) for n, c in self.cameras.items()},
                       points=sim.apply(self.points), units=units or self.units,
                       alignment={"method": how, **sim.to_dict()})

    def summary(self) -> str:
        lines = [f"kept the largest of {len(self.models)} reconstruction(s): {len(self.cameras)} of "
                 f"{self.n_images} images registered, {len(self.points)} points, mean reprojection error "
                 f"{self.mean_reproj_px:.3f} px"]
        if self.unregistered:
            lines.append(f"not registered: {', '.join(self.unregistered)}")
        for k, m in enumerate(self.models[1:], 1):
            lines.append(f"smaller model {k} (dropped): {', '.join(m)}")
        if self.unreadable:
            lines.append("unreadable: " + ", ".join(f"{n} ({r})" for n, r in self.unreadable.items()))
        return "\n".join(lines)


def list_images(folder: Path) -> tuple[list[str], dict[str, str]]:
    """Image files of `folder` (sorted names) that decode, and {name: reason} for those that do not.

    Raises FileNotFoundError for a missing folder and ValueError when it holds no image files.
    """
    import cv2

    from kernels.quiet import captured_stderr

    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder}: no such folder")
    names = sorted(p.name for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_EXTENSIONS)
    if not names:
        raise ValueError(f"{folder}: no images found (looked for {', '.join(IMAGE_EXTENSIONS)})")
    good, bad = [], {}
    for n in names:
        with captured_stderr() as decoder:  # libpng/libjpeg's own lines: the warning below says it once
            img = cv2.imread(str(folder / n), cv2.IMREAD_REDUCED_GRAYSCALE_4)
        if img is None or img.size == 0:
            bad[n] = "cannot be decoded as an image"
        elif any("Premature end" in ln for ln in decoder.lines()):
            bad[n] = "the image file is truncated"
        else:
            good.append(n)
    for n, r in bad.items():
        log.warning("%s: %s; left out", folder / n, r)
    return good, bad


def _shared_exif_camera(folder: Path, names: list[str]) -> str | None:
    """"exif" when every image has the same size and the same EXIF camera model, "size" when they
    have the same size and none has an EXIF camera model, else None."""
    import pycolmap

    keys = set()
    for n in names:
        b = pycolmap.Bitmap.read(str(folder / n), False)
        if b is None:
            return None
        keys.add((b.width, b.height, b.exif_camera_model()))
    if len(keys) != 1:
        return None
    return "exif" if next(iter(keys))[2] is not None else "size"


def _to_camera(image, cam) -> Camera:
    """pycolmap Image + Camera -> photoar Camera (OpenCV axes, top-left pixel centre at 0)."""
    K = np.array(cam.calibration_matrix(), np.float64)
    K[0, 2] -= COLMAP_PIXEL_OFFSET
    K[1, 2] -= COLMAP_PIXEL_OFFSET
    pose = image.cam_from_world()
    pose = pose() if callable(pose) else pose
    R = np.array(pose.rotation.matrix(), np.float64)
    t = np.array(pose.translation, np.float64)
    return Camera(K=K, R=R, t=t, width=int(cam.width), height=int(cam.height))


def _reader_options(opts: SfmOptions):
    import pycolmap

    ro = pycolmap.ImageReaderOptions()
    if opts.camera is not None:
        K = opts.camera.K
        ro.camera_model = "PINHOLE"
        ro.camera_params = ",".join(str(float(v)) for v in (K[0, 0], K[1, 1], K[0, 2] + COLMAP_PIXEL_OFFSET,
                                                              K[1, 2] + COLMAP_PIXEL_OFFSET))
    else:
        ro.camera_model = "SIMPLE_RADIAL"
    return ro


def reconstruct(folder: Path, opts: SfmOptions | None = None, work_dir: Path | None = None,
                progress: bool = True) -> SfmResult:
    """Run SfM on the images of `folder` and return the largest reconstruction.

    With single_camera None and images of one size without any EXIF camera, one shared camera is
    tried first (one focal length for all: far walls 5-9 cm closer to the truth on the shared
    scenes than with a focal per image); when that leaves images out, SfM runs again with a camera
    per image and the model that registers more images is kept (the shared one on a tie).
    """
    opts = opts or SfmOptions()
    if opts.single_camera is None and opts.camera is None:
        names, _ = list_images(Path(folder))
        if _shared_exif_camera(Path(folder), names) == "size":
            res = _reconstruct(folder, replace(opts, single_camera=True), work_dir, progress)
            if not res.unregistered:
                return res
            log.info("one shared camera left %d images out; trying one camera per image", len(res.unregistered))
            other = _reconstruct(folder, replace(opts, single_camera=False), work_dir, progress)
            return other if len(other.cameras) > len(res.cameras) else res
    return _reconstruct(folder, opts, work_dir, progress)


def _reconstruct(folder: Path, opts: SfmOptions | None = None, work_dir: Path | None = None,
                 progress: bool = True) -> SfmResult:
    """One SfM run (see `reconstruct`).

    work_dir receives COLMAP's database and models (a temporary folder when None). Raises
    FileNotFoundError / ValueError for a missing or empty folder or fewer than 2 readable images,
    RuntimeError naming the folder when no two images connect into a model.
    """
    import pycolmap
    from tqdm import tqdm

    opts = opts or SfmOptions()
    pycolmap.logging.minloglevel = 0 if log.isEnabledFor(logging.DEBUG) else 2  # COLMAP's own log: errors only
    folder = Path(folder)
    names, unreadable = list_images(folder)
    if len(names) < 2:
        raise ValueError(f"{folder}: need at least 2 readable images, found {len(names)}"
                         + (f" ({len(unreadable)} unreadable: {', '.join(unreadable)})" if unreadable else ""))
    if opts.camera is not None:
        import cv2

        for n in names:
            h, w = cv2.imread(str(folder / n), cv2.IMREAD_REDUCED_GRAYSCALE_8).shape[:2]
            if abs(w * 8 - opts.camera.width) > 8 or abs(h * 8 - opts.camera.height) > 8:
                raise ValueError(f"{folder / n}: image size does not match the known camera "
                                 f"({opts.camera.width}x{opts.camera.height})")
    tmp = None
    if work_dir is None:
        tmp = tempfile.TemporaryDirectory(prefix="photoar-sfm-")
        work_dir = Path(tmp.name)
    work_dir = Path(work_dir)
    work_dir.mkdir(parents=True, exist_ok=True)
    db = work_dir / "database.db"
    if db.exists():
        db.unlink()
    try:
        shared = opts.single_camera
        if opts.camera is not None:
            shared = True
        elif shared is None:
            shared = _shared_exif_camera(folder, names) is not None
        mode = pycolmap.CameraMode.SINGLE if shared else pycolmap.CameraMode.PER_IMAGE
        log.info("SfM on %d images of %s (%s camera%s, %d SIFT features max)", len(names), folder,
                 "one shared" if shared else "one per image", ", known K held fixed" if opts.camera else "",
                 opts.max_features)
        timings: dict[str, float] = {}
        bar = tqdm(total=3 + len(names), desc="sfm", disable=not progress, unit="step")

        t0 = time.perf_counter()
        ex = pycolmap.FeatureExtractionOptions()
        ex.num_threads = opts.num_threads
        ex.max_image_size = opts.max_image_size
        ex.sift.max_num_features = opts.max_features
        if opts.peak_threshold is not None:
            ex.sift.peak_threshold = opts.peak_threshold
        bar.set_postfix_str("features")
        pycolmap.extract_features(db, folder, image_names=names, camera_mode=mode,
                                  reader_options=_reader_options(opts), extraction_options=ex,
                                  device=pycolmap.Device.cpu)
        timings["features_s"] = time.perf_counter() - t0
        bar.update(1)

        t0 = time.perf_counter()
        mo = pycolmap.FeatureMatchingOptions()
        mo.num_threads = opts.num_threads
        vo = pycolmap.TwoViewGeometryOptions()
        vo.ransac.random_seed = opts.seed
        bar.set_postfix_str("matching")
        pycolmap.match_exhaustive(db, matching_options=mo, verification_options=vo, device=pycolmap.Device.cpu)
        timings["matching_s"] = time.perf_counter() - t0
        bar.update(1)
        with pycolmap.Database.open(db) as d:
            n_pairs = d.num_verified_image_pairs()

        t0 = time.perf_counter()
        po = pycolmap.IncrementalPipelineOptions()
        po.num_threads = opts.num_threads
        po.random_seed = opts.seed
        po.min_model_size = opts.min_model_size
        po.triangulation.ignore_two_view_tracks = not opts.two_view_tracks
        po.mapper.abs_pose_min_num_inliers = opts.abs_pose_min_inliers
        if opts.camera is not None:
            po.ba_refine_focal_length = False
            po.ba_refine_principal_point = False
            po.ba_refine_extra_params = False
            po.mapper.abs_pose_refine_focal_length = False
            po.mapper.abs_pose_refine_extra_params = False
        bar.set_postfix_str("mapping")
        models_dir = work_dir / "models"
        models_dir.mkdir(exist_ok=True)
        recs = pycolmap.incremental_mapping(db, folder, models_dir, options=po,
                                            next_image_callback=lambda: bar.update(1))
        timings["mapping_s"] = time.perf_counter() - t0
        bar.close()
    finally:
        if tmp is not None:
            tmp.cleanup()

    recs = sorted(recs.values(), key=lambda r: r.num_reg_images(), reverse=True)
    if not recs:
        raise RuntimeError(f"{folder}: the images do not connect: no reconstruction from {len(names)} images "
                           f"({n_pairs} geometrically verified image pairs)")
    models = [sorted(r.images[i].name for i in r.reg_image_ids()) for r in recs]
    rec = recs[0]
    cams = {}
    for iid in rec.reg_image_ids():
        im = rec.images[iid]
        cams[im.name] = _to_camera(im, rec.cameras[im.camera_id])
    pts = list(rec.points3D.values())
    points = np.array([p.xyz for p in pts], np.float64).reshape(-1, 3)
    colors = np.array([p.color for p in pts], np.uint8).reshape(-1, 3)
    errors = np.array([p.error for p in pts], np.float64)
    res = SfmResult(cameras=cams, points=points, colors=colors, point_errors=errors,
                    unregistered=[n for n in names if n not in cams], unreadable=unreadable, models=models,
                    mean_reproj_px=float(rec.compute_mean_reprojection_error()), timings=timings,
                    n_images=len(names) + len(unreadable))
    for line in res.summary().splitlines():
        (log.warning if line.startswith(("not", "smaller", "unreadable")) else log.info)("%s", line)
    return res


def read_middlebury_par(path: Path) -> dict[str, Camera]:
    """Cameras of a Middlebury multi-view `*_par.txt` (name k11..k33 r11..r33 t1 t2 t3, x_cam = R X + t)."""
    lines = Path(path).read_text().split("\n")
    cams = {}
    for ln in lines[1:]:
        f = ln.split()
        if len(f) != 22:
            continue
        v = np.array(f[1:], float)
        cams[f[0]] = Camera(v[:9].reshape(3, 3), v[9:18].reshape(3, 3), v[18:21], 640, 480)
    if not cams:
        raise ValueError(f"{path}: no camera lines (name + 21 numbers)")
    return cams


# ---- alignment ---------------------------------------------------------------------------------


def similarity_from_centres(result: SfmResult, known: dict[str, Camera]) -> Similarity:
    """Least-squares similarity (Umeyama) mapping the SfM camera centres onto the known ones.

    Needs >= 3 registered images with known cameras whose centres are not collinear.
    """
    import pycolmap

    common = [n for n in result.cameras if n in known]
    if len(common) < 3:
        raise ValueError(f"alignment needs >= 3 registered images with known cameras, have {len(common)}")
    src = np.array([result.cameras[n].centre for n in common])
    dst = np.array([known[n].centre for n in common])
    sim = pycolmap.estimate_sim3d(src, dst)
    if sim is None:
        raise RuntimeError("alignment failed: camera centres are degenerate (collinear or coincident)")
    m = np.array(sim.matrix(), np.float64)
    s = float(sim.scale)
    return Similarity(s, m[:, :3] / s, m[:, 3])


def similarity_from_camera(sfm_cam: Camera, known: Camera, scale: float = 1.0) -> Similarity:
    """Similarity that puts `sfm_cam` exactly onto the known pose, with the given scale (m per SfM unit).

    From R_k (s A X + b) + t_k = s (R_c X + t_c): A = R_k^T R_c, b = R_k^T (s t_c - t_k).
    """
    A = known.R.T @ sfm_cam.R
    return Similarity(scale, A, known.R.T @ (scale * sfm_cam.t - known.t))


def scale_about(point: np.ndarray, s: float) -> Similarity:
    """Uniform scaling by s about a fixed point (3,)."""
    p = np.asarray(point, np.float64)
    return Similarity(s, np.eye(3), p - s * p)


def scale_from_length(p: np.ndarray, q: np.ndarray, metres: float) -> float:
    """Metres per SfM unit from two reconstructed points a known distance apart."""
    d = float(np.linalg.norm(np.asarray(p, float) - np.asarray(q, float)))
    if not d > 0 or not metres > 0:
        raise ValueError(f"scale from length: need two distinct points and a positive length, got {d}, {metres}")
    return metres / d


def scale_from_height(camera_y: float, floor_y: float, true_height: float) -> float:
    """Scale about the camera so that its height above the floor becomes `true_height` (metres).

    camera_y, floor_y: heights along the up axis in the current frame.
    """
    h = camera_y - floor_y
    if not h > 0 or not true_height > 0:
        raise ValueError(f"scale from camera height: camera {h:.4g} above the floor (must be > 0), "
                         f"true height {true_height}")
    return true_height / h


def rotation_error_deg(Ra: np.ndarray, Rb: np.ndarray) -> float:
    """Angle of Ra Rb^T in degrees."""
    c = (np.trace(Ra @ Rb.T) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def pose_errors(cameras: dict[str, Camera], known: dict[str, Camera]) -> dict[str, tuple[float, float]]:
    """Per common image: (rotation error deg, centre error in the frame's units)."""
    return {n: (rotation_error_deg(c.R, known[n].R), float(np.linalg.norm(c.centre - known[n].centre)))
            for n, c in cameras.items() if n in known}


def similarity_from_poses(result: SfmResult, known: dict[str, Camera]) -> Similarity:
    """Similarity to known cameras using their orientations and centres (>= 2 common images).

    The rotation is the chordal mean of R_known^T R_sfm over the common images (projected onto
    SO(3) by SVD); scale and translation then minimise the squared centre residuals in closed form.
    Orientations constrain the rotation far better than a few nearly coplanar centres do.
    """
    common = [n for n in result.cameras if n in known]
    if len(common) < 2:
        raise ValueError(f"alignment needs >= 2 registered images with known cameras, have {len(common)}")
    M = sum(known[n].R.T @ result.cameras[n].R for n in common)
    U, _, Vt = np.linalg.svd(M)
    A = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    C = np.array([result.cameras[n].centre for n in common])
    Kc = np.array([known[n].centre for n in common])
    c0, k0 = C - C.mean(0), Kc - Kc.mean(0)
    den = float(np.sum(c0 ** 2))
    if not den > 0:
        raise RuntimeError("alignment failed: the registered camera centres coincide")
    s = float(np.sum((c0 @ A.T) * k0)) / den
    if not s > 0:
        raise RuntimeError("alignment failed: the reconstruction is mirrored or degenerate against the known cameras")
    return Similarity(s, A, Kc.mean(0) - s * A @ C.mean(0))
