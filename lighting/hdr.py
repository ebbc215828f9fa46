"""HDR radiance from exposure brackets (seed sec. 4.1): response recovery and merging.

Response recovery, default `calibration="mitsunaga"`: the project's own fit after Mitsunaga &
Nayar, "Radiometric self calibration", CVPR 1999. The inverse response g_c (pixel level ->
relative exposure X) is a polynomial in the normalised level M = z/255, here written in the
Bernstein basis of degree N, g(M) = sum_k b_k B_{k,N}(M), with b_0 = 0 (g(0) = 0), b_N = 1
(g(1) = 1) and non-decreasing b_k, which makes g monotone by construction. With the known
exposure ratio R_q = t_q / t_{q+1} of neighbouring exposures, every pixel sampled in both
(levels lo..hi, neither clipped) gives one linear equation g(M_q) - R_q g(M_{q+1}) = 0; the
least-squares solution under the constraints is a non-negative least-squares problem in the
increments b_k - b_{k-1}. Samples are single pixels (not block averages), stratified by level
so that rare bright levels count as much as the common dark ones. The degree is the smallest
in 4..10 whose residual is within 2 % of the best. (OpenCV's CalibrateDebevec /
CalibrateRobertson are offered as `calibration="debevec"|"robertson"`; on the shared probe
brackets their log-domain smoothing bends the steep dark end: 5-10 % merge error and 5-20
levels of response error, against 0.3-0.6 % and about 1-2 levels here.)

Normalisation: every inverse response returned here satisfies g_c(255) = 1 per channel, i.e.
X = 1 is the exposure that just reaches the top level, the convention of the scenes'
`camera_response.inverse_table` (FORMAT.md). A bracket fixes g only up to one scale per
channel; this choice assumes the channels saturate at the same exposure (true for the shared
scenes' responses, which map X = 1 to 255 in every channel).

Merging: OpenCV's MergeDebevec (log-domain weighted average with a triangle weight) or
MergeRobertson, given the inverse response. Radiance = X / exposure_time, float32 (H,W,3),
in the scene's radiance units when g is the scene's true inverse response.

Images are uint8 RGB (H,W,3); responses are (256,3) float64 tables g[z, c] (RGB).
"""
from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np

from recon.io import read_image_rgb

log = logging.getLogger(__name__)

LOW, HIGH = 3, 251  # levels trusted for calibration (neither near black nor near saturation)
VALID_LOW, VALID_HIGH = 2, 253  # a pixel is "valid" in an exposure with every channel in this range
SATURATED = 254  # a pixel at or above this in the shortest exposure is clipped: its radiance is a lower bound


# ----------------------------------------------------------------------------- loading

def load_radiance(path: str | Path) -> np.ndarray:
    """HDR image (.exr via OpenEXR, .hdr / .pfm via OpenCV) -> float32 RGB (H,W,3), linear.

    Raises with the file's name on a missing file, missing channels or non-finite values.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such HDR image")
    ext = path.suffix.lower()
    if ext == ".exr":
        from recon.io import read_exr

        rgb = read_exr(path)
    elif ext in (".hdr", ".pfm"):
        import cv2

        img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise ValueError(f"{path}: not a readable {ext} image")
        if img.ndim == 2:
            img = np.repeat(img[..., None], 3, axis=2)
        rgb = np.ascontiguousarray(img[..., 2::-1], np.float32)
    else:
        raise ValueError(f"{path}: unknown HDR format {ext!r} (expected .exr, .hdr or .pfm)")
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"{path}: expected an RGB image, got shape {rgb.shape}")
    bad = ~np.isfinite(rgb)
    if bad.any():
        raise ValueError(f"{path}: {int(bad.any(-1).sum())} pixels are NaN or infinite")
    if (rgb < 0).any():
        log.warning("%s: %d negative values clamped to 0", path, int((rgb < 0).sum()))
        rgb = np.maximum(rgb, 0)
    return rgb.astype(np.float32, copy=False)


# ----------------------------------------------------------------------------- checks

def check_bracket(images: list[np.ndarray], times: list[float], name: str = "bracket") -> tuple[list[np.ndarray], np.ndarray]:
    """Validate a bracket: >= 2 uint8 (H,W,3) images of one size, finite positive distinct times.

    Returns the images and times sorted by increasing exposure time.
    """
    if len(images) != len(times):
        raise ValueError(f"{name}: {len(images)} images but {len(times)} exposure times")
    if len(images) < 2:
        raise ValueError(f"{name}: a bracket needs at least 2 exposures, got {len(images)} "
                         "(one exposure fixes neither the response nor the dynamic range)")
    t = np.asarray(times, np.float64)
    if not np.all(np.isfinite(t)) or np.any(t <= 0):
        raise ValueError(f"{name}: exposure times must be finite and positive, got {list(times)}")
    shape = None
    for i, im in enumerate(images):
        im = np.asarray(im)
        if im.dtype != np.uint8:
            if np.issubdtype(im.dtype, np.floating) and not np.all(np.isfinite(im)):
                raise ValueError(f"{name}: image {i} contains NaN or infinite values")
            raise ValueError(f"{name}: image {i} must be 8-bit (uint8), got {im.dtype}")
        if im.ndim != 3 or im.shape[2] != 3:
            raise ValueError(f"{name}: image {i} must be RGB (H,W,3), got shape {im.shape}")
        if shape is None:
            shape = im.shape
        elif im.shape != shape:
            raise ValueError(f"{name}: image {i} has size {im.shape[:2]}, image 0 has {shape[:2]}")
    order = np.argsort(t, kind="stable")
    if np.any(np.diff(t[order]) <= 0):
        raise ValueError(f"{name}: exposure times must be distinct, got {list(times)}")
    return [np.asarray(images[i]) for i in order], t[order]


def check_response(response: np.ndarray, name: str = "response") -> np.ndarray:
    """Accept an inverse response as (256,3) or (3,256) (scene.json's inverse_table) -> (256,3) float64."""
    g = np.asarray(response, np.float64)
    if g.shape == (3, 256):
        g = g.T
    if g.shape != (256, 3):
        raise ValueError(f"{name}: inverse response must be 256 x 3 (or 3 x 256), got shape {g.shape}")
    if not np.all(np.isfinite(g)):
        raise ValueError(f"{name}: inverse response contains NaN or infinite values")
    if np.any(np.diff(g, axis=0) < 0) or np.any(g < 0):
        raise ValueError(f"{name}: inverse response must be non-negative and non-decreasing")
    if np.any(g[255] <= 0):
        raise ValueError(f"{name}: inverse response is zero at level 255")
    return g


def valid_mask(images: list[np.ndarray], low: int = VALID_LOW, high: int = VALID_HIGH) -> np.ndarray:
    """(H,W) bool: pixels with every channel in [low, high] in at least one exposure."""
    ok = np.zeros(np.asarray(images[0]).shape[:2], bool)
    for im in images:
        ok |= np.all((im >= low) & (im <= high), axis=-1)
    return ok


def saturated_mask(images: list[np.ndarray], times: list[float], level: int = SATURATED) -> np.ndarray:
    """(H,W) bool: pixels clipped (any channel >= level) even in the shortest exposure."""
    shortest = np.asarray(images[int(np.argmin(np.asarray(times, np.float64)))])
    return np.any(shortest >= level, axis=-1)


# ----------------------------------------------------------------------------- response

def _bernstein(m: np.ndarray, n: int) -> np.ndarray:
    from scipy.special import comb

    k = np.arange(n + 1)
    return comb(n, k) * m[:, None] ** k * (1 - m[:, None]) ** (n - k)


def _pair_samples(images, times, c, per_level, rng):
    """Pixel pairs (a in exposure q, b in q+1) of channel c, stratified by b's level."""
    rows = []
    for q in range(len(images) - 1):
        a = images[q][..., c].ravel()
        b = images[q + 1][..., c].ravel()
        ok = np.flatnonzero((a >= LOW) & (a <= HIGH) & (b >= LOW) & (b <= HIGH))
        if ok.size == 0:
            continue
        ok = rng.permutation(ok)
        lv = b[ok]
        srt = np.argsort(lv, kind="stable")
        ok, lv = ok[srt], lv[srt]
        rank = np.arange(lv.size) - np.searchsorted(lv, lv, side="left")
        sel = ok[rank < per_level]
        rows.append((a[sel] / 255.0, b[sel] / 255.0, times[q] / times[q + 1]))
    return rows


def _fit_channel(rows, degree: int) -> tuple[np.ndarray, float]:
    """Monotone Bernstein inverse response of one channel -> (g at 256 levels, rms residual)."""
    from scipy.optimize import nnls

    A = np.concatenate([_bernstein(a, degree) - r * _bernstein(b, degree) for a, b, r in rows])
    L = np.tril(np.ones((degree + 1, degree)), -1)  # b = L @ d, d = increments >= 0, b_0 = 0
    Ad = A @ L
    G = Ad.T @ Ad
    U = np.linalg.cholesky(G + 1e-12 * np.trace(G) * np.eye(degree)).T  # ||Ad d||^2 = ||U d||^2
    big = 1e3 * np.sqrt(np.trace(G) / degree)  # sum d = 1 (g(1) = 1) as a heavy row
    d, _ = nnls(np.vstack([U, big * np.ones((1, degree))]), np.append(np.zeros(degree), big))
    d = d / d.sum()
    g = _bernstein(np.arange(256) / 255.0, degree) @ (L @ d)
    return g, float(np.sqrt(np.mean((Ad @ d) ** 2)))


def fit_response_mitsunaga(images: list[np.ndarray], times: list[float], degree: int | None = None,
                           per_level: int = 50, seed: int = 0) -> tuple[np.ndarray, list[int]]:
    """Inverse response (256,3) from a bracket (module docstring) and the degree used per channel.

    images: uint8 RGB (H,W,3), times in seconds. degree None chooses 4..10 per channel by residual.
    """
    images, t = check_bracket(images, times)
    rng = np.random.default_rng(seed)
    g = np.zeros((256, 3))
    degrees = []
    for c in range(3):
        rows = _pair_samples(images, t, c, per_level, rng)
        n = sum(r[0].size for r in rows)
        if n < 20:
            raise ValueError(f"bracket: only {n} pixels of channel {'RGB'[c]} are unclipped in two neighbouring "
                             "exposures; cannot recover the response (give the response, or a wider bracket)")
        if degree is not None:
            g[:, c], _ = _fit_channel(rows, degree)
            degrees.append(degree)
            continue
        fits = {n_: _fit_channel(rows, n_) for n_ in range(4, 11)}
        best = min(r for _, r in fits.values())
        n_ = min(k for k, (_, r) in fits.items() if r <= 1.02 * best)
        g[:, c] = fits[n_][0]
        degrees.append(n_)
    log.info("response: Mitsunaga-Nayar fit, degrees %s (R, G, B)", degrees)
    return g, degrees


def normalise_response(g: np.ndarray) -> np.ndarray:
    """Monotone (running maximum), non-negative, and g_c(255) = 1 per channel (module docstring)."""
    g = np.maximum.accumulate(np.maximum(np.asarray(g, np.float64), 0), axis=0)
    if np.any(g[255] <= 0) or not np.all(np.isfinite(g)):
        raise RuntimeError("recovered response is degenerate (zero or non-finite at level 255)")
    return g / g[255]


def calibrate_response(images: list[np.ndarray], times: list[float], calibration: str = "mitsunaga",
                       samples: int = 200, lambda_: float = 10.0) -> np.ndarray:
    """Inverse response (256,3) g[z, c] -> relative exposure, normalised g(255) = 1.

    calibration: "mitsunaga" (own fit), "debevec" (cv2.CalibrateDebevec with `samples` random
    single pixels and smoothness `lambda_`) or "robertson" (cv2.CalibrateRobertson).
    """
    import cv2

    images, t = check_bracket(images, times)
    if calibration == "mitsunaga":
        g, _ = fit_response_mitsunaga(images, t)
    elif calibration == "debevec":
        cal = cv2.createCalibrateDebevec(samples=samples, lambda_=lambda_, random=True)
        g = cal.process(images, t.astype(np.float32))[:, 0, :]
    elif calibration == "robertson":
        g = cv2.createCalibrateRobertson().process(images, t.astype(np.float32))[:, 0, :]
    else:
        raise ValueError(f"unknown calibration {calibration!r} (mitsunaga, debevec or robertson)")
    return normalise_response(g)


def forward_table(g: np.ndarray) -> np.ndarray:
    """Forward response f_c(i/255) (3,256) in [0,1] from an inverse response g (256,3)."""
    g = check_response(g)
    z = np.arange(256) / 255.0
    out = np.empty((3, 256))
    for c in range(3):
        x = g[:, c] + np.arange(256) * 1e-12  # strictly increasing for interpolation
        out[c] = np.interp(z, x, z)
    return out


def response_level_error(g: np.ndarray, true_inverse: np.ndarray, lo: int = LOW, hi: int = HIGH) -> np.ndarray:
    """Per channel, max |f_rec(X) - f_true(X)| in levels at the true inverse's X for levels lo..hi (3,)."""
    g = check_response(g)
    gt = check_response(true_inverse)
    lv = np.arange(256, dtype=np.float64)
    return np.array([np.abs(np.interp(gt[lo:hi + 1, c], g[:, c] + lv * 1e-12, lv) - lv[lo:hi + 1]).max()
                     for c in range(3)])


# ----------------------------------------------------------------------------- merging

def merge_bracket(images: list[np.ndarray], times: list[float], response: np.ndarray | None = None,
                  method: str = "debevec", calibration: str = "mitsunaga") -> tuple[np.ndarray, np.ndarray]:
    """Merge a bracket into radiance.

    images: uint8 RGB (H,W,3) each; times: exposure times (s), any order; response: inverse
    response (256,3) or (3,256) mapping level -> relative exposure X (None: recovered with
    `calibration`); method: "debevec" (cv2.MergeDebevec) or "robertson" (cv2.MergeRobertson).
    Returns (radiance float32 (H,W,3) = X / t, response (256,3) float64).
    Channels clipped even in the shortest exposure get the lower bound g(255) / t_min (saturated_mask).
    """
    import cv2

    images, t = check_bracket(images, times)
    g = calibrate_response(images, t, calibration) if response is None else check_response(response)
    # OpenCV takes logs of the table: keep level 0 (g = 0, black) finite and tiny
    pos = g[g > 0]
    table = np.maximum(g, pos.min() * 0.5 if pos.size else 1e-12).astype(np.float32).reshape(256, 1, 3)
    imgs = [np.ascontiguousarray(im) for im in images]
    if method == "debevec":
        rad = cv2.createMergeDebevec().process(imgs, t.astype(np.float32), table)
    elif method == "robertson":
        rad = cv2.createMergeRobertson().process(imgs, t.astype(np.float32), table)
    else:
        raise ValueError(f"unknown merge method {method!r} (debevec or robertson)")
    rad = np.asarray(rad, np.float32)
    # clipped even in the shortest exposure: OpenCV's average over the exposures (each clipped
    # one counting X = g(255)) is far below the truth; keep the tightest lower bound instead
    clipped = images[0] >= SATURATED
    if clipped.any():
        bound = np.broadcast_to((g[255] / t[0]).astype(np.float32), rad.shape)
        rad = np.where(clipped, np.maximum(rad, bound), rad)
    if not np.all(np.isfinite(rad)):
        raise RuntimeError(f"HDR merge produced {int((~np.isfinite(rad)).sum())} non-finite values")
    return rad, g


# ----------------------------------------------------------------------------- response check

CHANNELS = ("red", "green", "blue")


def channel_residuals(images: list[np.ndarray], times: list[float], g: np.ndarray,
                      max_samples: int = 200_000, seed: int = 0) -> np.ndarray:
    """Per channel (3,), how far the bracket's exposures disagree with their merge, in pixel levels.

    The merge here is the per-channel mean of g_c(z_q) / t_q over the exposures q whose level is
    trusted (LOW..HIGH), weighted by the triangle weight of the level; a level clipped in some
    exposure never enters it (OpenCV's merge still gives level 255 a small weight, which biases
    pixels that clip in the longer exposures and would hide a channel's own error). Each trusted
    exposure then predicts the level f_c(L t_q) = g_c^-1(L t_q); the residual is the rms of
    (observed - predicted) over the pixels trusted in at least two exposures. A response that fits
    the bracket leaves quantisation and sensor noise (about a level); a channel whose curve is wrong,
    or whose shots differ in more than the exposure time, leaves many levels."""
    images, t = check_bracket(images, times)
    g = check_response(g)
    lv = np.arange(256, dtype=np.float64)
    w_lv = np.minimum(lv - LOW + 1, HIGH + 1 - lv).clip(0)  # triangle weight, 0 outside LOW..HIGH
    n_px = images[0].shape[0] * images[0].shape[1]
    idx = np.arange(n_px)
    if n_px > max_samples:
        idx = np.random.default_rng(seed).choice(n_px, max_samples, replace=False)
    out = np.full(3, np.nan)
    for c in range(3):
        z = np.stack([im[..., c].ravel()[idx] for im in images])  # (Q, N) levels
        w = w_lv[z]
        logx = np.log(np.maximum(g[z, c], 1e-12) / t[:, None])
        two = (w > 0).sum(0) >= 2
        L = np.exp((w * logx).sum(0)[two] / w.sum(0)[two])
        x = g[:, c] + lv * 1e-12  # strictly increasing for the inverse lookup
        use = w[:, two] > 0
        pred = np.interp((L[None] * t[:, None])[use], x, lv)
        if use.any():
            out[c] = float(np.sqrt(np.mean((z[:, two][use] - pred) ** 2)))
    return out


def warn_unfit_channel(residuals: np.ndarray, name: str = "bracket", floor: float = 2.0, ratio: float = 3.0) -> int | None:
    """Log one warning when one channel's response fits the bracket far worse than the others.

    residuals: channel_residuals' (3,) levels. A channel is far off when its residual exceeds both
    `floor` levels (8-bit quantisation alone leaves 0.3 level rms; sensor noise about 1) and `ratio` x
    the median channel's (the merge's own noise on this bracket). Returns the channel, or None."""
    r = np.asarray(residuals, float)
    if not np.all(np.isfinite(r)):
        return None
    c = int(np.argmax(r))
    med = float(np.median(r))
    if r[c] <= max(floor, ratio * med):
        return None
    others = ", ".join(f"{CHANNELS[k]} {r[k]:.1f}" for k in range(3) if k != c)
    log.warning("%s: the camera response recovered for the %s channel does not fit the bracket: its exposures "
                "disagree with their merge by %.1f levels rms (%s); that channel's light is unreliable: check "
                "that the shots differ in exposure time only (same aperture, ISO, white balance)",
                name, CHANNELS[c], r[c], others)
    return c


# ----------------------------------------------------------------------------- scenes

def scene_probe_files(scene_dir: Path) -> tuple[list[Path], list[float], dict]:
    """A scene folder's probe bracket: (files, exposure times in s, the parsed scene.json);
    errors name scene.json."""
    sj = Path(scene_dir) / "scene.json"
    if not sj.is_file():
        raise FileNotFoundError(f"{sj}: no such file")
    try:
        scene = json.loads(sj.read_text())
    except ValueError as e:
        raise ValueError(f"{sj}: light_probe: missing or malformed ldr_files / exposure_times ({e})") from None
    files, times = probe_bracket(sj, scene)
    return files, times, scene


def probe_bracket(sj: Path, scene: dict) -> tuple[list[Path], list[float]]:
    """The probe bracket (files, exposure times in s) of a parsed scene.json `scene` read from `sj` (the file,
    named by the errors)."""
    try:
        lp = scene["light_probe"]
        files, times = lp["ldr_files"], lp["exposure_times"]
        if len(files) != len(times):
            raise ValueError(f"{sj}: light_probe: {len(files)} ldr_files but {len(times)} exposure_times")
        return [Path(sj).parent / f for f in files], [float(x) for x in times]
    except (KeyError, TypeError) as e:
        raise ValueError(f"{sj}: light_probe: missing or malformed ldr_files / exposure_times ({e})") from None


def load_scene_probe(scene_dir: str | Path, response: np.ndarray | None = None, method: str = "debevec",
                     calibration: str = "mitsunaga") -> np.ndarray:
    """Merge the scene's bracketed mirror-ball probe (light_probe.ldr_files, exposure_times).

    response: the inverse response (256,3) or scene.json's inverse_table (3,256); with the scene's
    true one the result is in the scene's radiance units; None recovers it from the bracket
    (normalised g(255) = 1, so still close to the scene's units when channels saturate at X = 1).
    Returns radiance float32 (256,256,3), probe-camera pixel grid.
    """
    scene_dir = Path(scene_dir)
    paths, times, _ = scene_probe_files(scene_dir)
    images = [read_image_rgb(p) for p in paths]
    try:
        rad, _ = merge_bracket(images, times, response, method=method, calibration=calibration)
    except ValueError as e:
        raise ValueError(f"{scene_dir / 'scene.json'}: light_probe: {e}") from None
    return rad


def scene_true_response(scene_dir: str | Path) -> np.ndarray:
    """The scene's true inverse response (256,3) from scene.json camera_response.inverse_table."""
    sj = Path(scene_dir) / "scene.json"
    try:
        inv = json.loads(sj.read_text())["camera_response"]["inverse_table"]
    except (OSError, ValueError, KeyError) as e:
        raise ValueError(f"{sj}: camera_response.inverse_table: {e}") from None
    return check_response(inv, f"{sj}: camera_response.inverse_table")
