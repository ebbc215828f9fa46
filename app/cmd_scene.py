"""`photoar scene ROOM --photo PHOTO --exposure-time S --camera CAMERA.json --primitives MODEL.json
[--no-refine-camera] [--probe IMG... --probe-times T... --probe-centre X,Y,Z --probe-radius R --probe-shot-from X,Y,Z
[--probe-circle auto]] [--sun-direction X,Y,Z --sun-irradiance R,G,B | [--sun-from-photo] [--when DATE_TIME]
[--where LAT,LON] (--north DEG | --wall-bearing WALL=DEG) [--sun-irradiance R,G,B]]`

Assembles and validates a room folder (docs/scene-format.md, scene format 1): ROOM/scene.json,
background.png (the photo, turned upright by its EXIF orientation), probe_XX.png (the bracket,
shortest exposure first; cropped to the ball with --probe-circle auto), camera.json and
primitives.json (copies of the inputs; camera.json with the camera scene uses: turned into the
room when it has to be, refined against the photo's edges of the room unless --no-refine-camera,
recon/camrefine.py). The folder is staged beside ROOM and swapped in whole (recon.io.AtomicFolder);
files a previous run wrote and this one does not are gone, other files in ROOM are kept.
The logic lives in recon/assemble.py (pure functions); this module reads and writes files.
"""
from __future__ import annotations

import argparse
import logging
from datetime import timezone
from pathlib import Path

import numpy as np

from app.cli import xyz_arg
from app.units import seconds

log = logging.getLogger("photoar")

OWNED = ("scene.json", "background.png", "camera.json", "primitives.json")


def register(sub) -> None:
    p = sub.add_parser("scene", help="assemble a room folder (scene.json) from a photo, its camera, a room model "
                                     "and a mirror-ball bracket")
    p.add_argument("room", type=Path, help="the room folder to write (created or updated)")
    p.add_argument("--photo", type=Path, required=True, help="the photo of the empty room (JPEG/PNG)")
    p.add_argument("--exposure-time", type=seconds, default=None, metavar="S",
                   help="the photo's exposure time: seconds, 1/250 or 4ms (default: its EXIF ExposureTime)")
    p.add_argument("--camera", type=Path, required=True, help="camera.json of `photoar calibrate`")
    p.add_argument("--no-refine-camera", action="store_true",
                   help="keep --camera as it is; by default its pose and focal length are refined against the "
                        "photo's edges of the room (recon/camrefine.py), the camera height and the room held")
    p.add_argument("--camera-edges", choices=("profiles", "lines"), default="profiles",
                   help="how the refinement measures the room's edges in the photo: 'profiles' (each sample on "
                        "its own, the default) or 'lines' (each edge as one line against the photo's own noise: "
                        "for grainy photos; docs/unseen.md)")
    p.add_argument("--primitives", type=Path, required=True,
                   help="the room model: model.json of `photoar model`, primitives.json of `photoar reconstruct`, "
                        'or {"primitives": [...]} with a box of role "room" (docs/scene-format.md)')
    g = p.add_argument_group("light probe (a mirror-ball exposure bracket, for --lighting captured)")
    g.add_argument("--probe", type=Path, nargs="+", default=None, metavar="IMG", help="the bracket's images")
    g.add_argument("--probe-times", type=seconds, nargs="+", default=None, metavar="T",
                   help="their exposure times (seconds, 1/250 or 4ms), in the same order (default: EXIF "
                        "ExposureTime)")
    g.add_argument("--probe-centre", type=xyz_arg, default=None, metavar="X,Y,Z", help="ball centre (m, world)")
    g.add_argument("--probe-radius", type=float, default=None, metavar="R", help="ball radius (m)")
    g.add_argument("--probe-shot-from", type=xyz_arg, default=None, metavar="X,Y,Z",
                   help="where the ball was photographed from (m, world; the camera held upright)")
    g.add_argument("--probe-circle", choices=["inscribed", "auto"], default="inscribed",
                   help="inscribed: the images are square crops with the ball as their inscribed circle; auto: find "
                        "the ball in wider photos and crop it (default %(default)s)")
    g.add_argument("--skip-probe-check", action="store_true",
                   help="do not compare the probe pose with the images (see docs/scene-format.md)")
    s = p.add_argument_group(
        "sun (a room lit through an opening: a window quad with \"opening\": true in --primitives)",
        "Give both, or a sun entry in --primitives (not both). Written as the scene's sun with \"declared_by\": "
        "\"user\": composite/evaluate/gui with --lighting captured and --sun auto (their default) use it in place "
        "of the sun estimated from the photo (--sun estimate); --lighting known (a folder with a camera_response) "
        "uses it too. The sun must be above the horizon (Y > 0) and shine into the room through an opening, else "
        "a warning.")
    s.add_argument("--sun-direction", type=xyz_arg, default=None, metavar="X,Y,Z",
                   help="the direction from the room towards the sun, any length (normalised), in the world frame "
                        "of --camera and --primitives: metres' axes, +Y up, origin at the floor corner marked in "
                        "`photoar calibrate`; e.g. --sun-direction -0.74,0.62,0.27")
    s.add_argument("--sun-irradiance", type=xyz_arg, default=None, metavar="R,G,B",
                   help="the sun's irradiance on a surface facing it, linear RGB in the scene's radiance units x "
                        "sr (a white card facing the sun has radiance E/pi). Without a camera_response (the "
                        "own-room flow), captured light recovers the response from the probe bracket normalised "
                        "so that radiance 1 just reaches pixel level 255 in a 1 s exposure: E is in those units")
    w = p.add_argument_group(
        "sun from when and where (in place of --sun-direction)",
        "The sun's direction from the date, time and place of the photo (NREL's solar position algorithm, "
        "pvlib) and a compass bearing of the room. Its strength is --sun-irradiance when given, else estimated "
        "from the photo's sunlit patches by composite/evaluate/gui (--lighting captured). A sun below the "
        "horizon at that time and place is an error. scene.json's sun records these inputs (\"from\").")
    w.add_argument("--sun-from-photo", action="store_true",
                   help="take the date, time and UTC offset (EXIF DateTimeOriginal, OffsetTimeOriginal) and the "
                        "place (EXIF GPS) from --photo; --when/--where replace them")
    w.add_argument("--when", default=None, metavar="DATE_TIME",
                   help="when the photo was taken, ISO 8601 with its UTC offset, e.g. 2026-06-21T15:30+02:00 "
                        "(Z for UTC); without an offset only with --sun-from-photo, whose EXIF offset is taken")
    w.add_argument("--where", default=None, metavar="LAT,LON[,ALT]",
                   help="where: latitude and longitude in degrees (north and east positive), optionally the "
                        "altitude in metres, e.g. 48.8584,2.2945")
    nb = w.add_mutually_exclusive_group()
    nb.add_argument("--north", type=float, default=None, metavar="DEG",
                    help="the compass bearing (degrees clockwise from true north) of the room's -z axis: the "
                         "way you face looking at the back wall (z min) from inside the room")
    nb.add_argument("--wall-bearing", type=_wall_bearing, default=None, metavar="WALL=DEG",
                    help="the same, given for one wall: back, front, left or right (z min, z max, x min, x max), "
                         "DEG being the bearing you face when you stand in the room looking at that wall, e.g. "
                         "back=212 (a phone compass set to true north)")
    p.set_defaults(run=run)


def _wall_bearing(s: str) -> tuple[str, float]:
    """argparse type of --wall-bearing WALL=DEG."""
    from recon.sunpos import WALL_OFFSET_DEG

    wall, _, deg = s.partition("=")
    try:
        bearing = float(deg)
    except ValueError:
        bearing = float("nan")
    if wall.strip() not in WALL_OFFSET_DEG or not np.isfinite(bearing):
        raise argparse.ArgumentTypeError(f"expected WALL=DEG with WALL one of {', '.join(WALL_OFFSET_DEG)}, got {s!r}")
    return wall.strip(), bearing


def read_photo(path: Path) -> tuple[np.ndarray, float | None]:
    """Upright 8-bit RGB image (recon.io.read_image_rgb honours the EXIF orientation) and its EXIF
    exposure time (None if absent); errors name the file."""
    from recon.io import read_image_rgb
    from recon.phototags import read_tags

    return read_image_rgb(path), read_tags(path).exposure_time


def assemble(a: argparse.Namespace) -> tuple[dict, dict[str, np.ndarray], dict[str, bytes]]:
    """The scene dict, the images to write (name -> RGB uint8) and the files to copy (name -> bytes)."""
    from recon import assemble as asm
    from recon.camera import Camera
    from recon.io import SceneError, read_json

    cam = Camera.load(a.camera)
    model = read_json(a.primitives, SceneError)
    prims, lo, hi = asm.parse_primitives(model, str(a.primitives))
    given_sun = asm.input_sun(model, str(a.primitives))
    photo, exif_t = read_photo(a.photo)
    if photo.shape[:2] != (cam.height, cam.width):
        raise ValueError(f"{a.photo}: image is {photo.shape[1]}x{photo.shape[0]} (upright), {a.camera} says "
                         f"{cam.width}x{cam.height}")
    t = a.exposure_time if a.exposure_time is not None else exif_t
    if t is None:
        raise ValueError(f"{a.photo}: no exposure time: give --exposure-time S (the file has no EXIF ExposureTime)")
    if not (np.isfinite(t) and t > 0):
        raise ValueError(f"--exposure-time: must be a positive number of seconds, got {t}")
    cam, turned = _camera_in_room(a, cam, lo, hi)
    images = {"background.png": photo}
    probe = None
    if a.probe:
        probe = _load_probe(a, lo, hi, images)
    elif any(x is not None for x in (a.probe_times, a.probe_centre, a.probe_radius, a.probe_shot_from)):
        raise ValueError("--probe: probe options given without the --probe images")
    sun = None
    by_time = _sun_by_time(a)
    if by_time and a.sun_direction is not None:
        raise ValueError("--sun-direction: the sun's direction is given twice: drop --sun-direction or "
                         "--sun-from-photo/--when/--where/--north")
    if by_time:
        if given_sun is not None:
            raise ValueError(f"--when/--where: {a.primitives} has a sun entry too: give the sun once (drop "
                             "the sun options, or the file's sun)")
        sun = _sun_from_when_where(a, lo, hi)
    elif (a.sun_direction is None) != (a.sun_irradiance is None):
        raise ValueError("--sun-direction/--sun-irradiance: give both or neither")
    elif a.sun_direction is not None:
        if given_sun is not None:
            raise ValueError(f"--sun-direction: {a.primitives} has a sun entry too: give the sun once (drop "
                             "--sun-direction/--sun-irradiance, or the file's sun)")
        sun = asm.sun_primitive(a.sun_direction, a.sun_irradiance, lo, hi)
    else:
        sun = given_sun
    if sun is not None:
        _warn_no_sun(sun, prims, "--sun-direction" if a.sun_direction is not None else
                     "--when/--where" if by_time else f"{a.primitives}: sun")
    # the refinement takes the sun's direction (the sunlit patch's outline), read through the bracket's response
    refinement = None if a.no_refine_camera else _refine_camera(a, cam, prims, model, photo, sun,
                                                                probe[3][1] if probe is not None else None)
    if refinement is not None and refinement.accepted:
        cam = refinement.camera
    rel = cam.focal_rel_sigma
    if (refinement is None or not refinement.accepted) and (cam.ill_conditioned or (rel is not None and rel > 0.05)):
        log.warning("%s: the focal length is uncertain%s: the composite may be misregistered", a.camera,
                    f" (std(f)/f = {rel:.1%})" if rel is not None else "")
    light_probe = None if probe is None else _check_probe_pose(a, cam, prims, photo, t, *probe)
    scene = asm.scene_dict(a.room.name, cam, t, prims, lo, hi, light_probe, sun)
    if refinement is not None:
        scene["main_camera"]["refinement"] = refinement.to_json()
    changed = turned or (refinement is not None and refinement.accepted)
    copies = {"camera.json": _camera_json(a.camera, cam) if changed else a.camera.read_bytes(),
              "primitives.json": a.primitives.read_bytes()}
    return scene, images, copies


def _sun_by_time(a: argparse.Namespace) -> bool:
    """True when the sun is given by date, time and place (any of its options)."""
    return bool(a.sun_from_photo or a.when is not None or a.where is not None or a.north is not None
                or a.wall_bearing is not None)


def _sun_from_when_where(a: argparse.Namespace, lo, hi) -> dict:
    """The sun entry from --sun-from-photo/--when/--where and --north/--wall-bearing (recon.sunpos):
    direction from NREL SPA, strength --sun-irradiance or left to the engine's estimate ("strength":
    "estimate"), and "from" recording the inputs. ValueError naming the option, or the file and the
    EXIF tag, for what is missing or wrong."""
    from recon import assemble as asm
    from recon import sunpos
    from recon.phototags import read_tags

    tags = read_tags(a.photo) if a.sun_from_photo else None
    if a.when is not None:
        try:
            when = sunpos.parse_when(a.when)
        except ValueError as e:
            raise ValueError(f"--when: {e}") from None
        time_from = "--when"
        if when.tzinfo is None:
            if tags is None or tags.offset_time_original is None:
                raise ValueError(f"--when: {a.when!r} has no UTC offset: add it, e.g. {when.isoformat()}+02:00 "
                                 "(Z for UTC)" + ("" if tags is None else f"; {a.photo} has no EXIF OffsetTimeOriginal"))
            when = when.replace(tzinfo=sunpos.parse_offset(tags.offset_time_original))
            time_from = "--when, UTC offset from EXIF OffsetTimeOriginal"
    elif tags is not None:
        for tag, v in (("DateTimeOriginal", tags.datetime_original), ("OffsetTimeOriginal", tags.offset_time_original)):
            if v is None:
                raise ValueError(f"{a.photo}: no EXIF {tag} (--sun-from-photo): give --when with its UTC offset, "
                                 "e.g. 2026-06-21T15:30+02:00")
        try:
            when = sunpos.parse_exif_time(tags.datetime_original, tags.offset_time_original)
        except ValueError as e:
            raise ValueError(f"{a.photo}: EXIF {e}") from None
        time_from = "EXIF DateTimeOriginal, OffsetTimeOriginal"
    else:
        raise ValueError("--when: the date and time are needed for the sun (or --sun-from-photo)")
    if a.where is not None:
        try:
            lat, lon, alt = sunpos.parse_where(a.where)
        except ValueError as e:
            raise ValueError(f"--where: {e}") from None
        place_from = "--where"
    elif tags is not None:
        for tag, v in (("GPSLatitude", tags.latitude), ("GPSLongitude", tags.longitude)):
            if v is None:
                raise ValueError(f"{a.photo}: no EXIF {tag} (--sun-from-photo): give --where LAT,LON")
        lat, lon, alt = tags.latitude, tags.longitude, tags.altitude_m
        place_from = "EXIF GPS"
    else:
        raise ValueError("--where: the place is needed for the sun (or --sun-from-photo)")
    if a.north is not None:
        if not np.isfinite(a.north):
            raise ValueError(f"--north: must be a finite bearing in degrees, got {a.north}")
        north, bearing = a.north % 360.0, {"north_deg": a.north}
    elif a.wall_bearing is not None:
        wall, deg = a.wall_bearing
        north, bearing = sunpos.north_from_wall(wall, deg), {"wall_bearing": {wall: deg}}
    else:
        raise ValueError("--north: the room's compass bearing is needed for the sun: --north DEG (of the room's "
                         "-z axis) or --wall-bearing WALL=DEG")
    pos = sunpos.solar_position(when, lat, lon, alt or 0.0)
    where_txt = f"{lat:.5f},{lon:.5f}"
    if pos.elevation_deg <= 0.0:
        raise ValueError(f"the sun is below the horizon at {when.isoformat()} at {where_txt} (elevation "
                         f"{pos.elevation_deg:.1f} deg, from {time_from} and {place_from}): check the date, time, "
                         "UTC offset and place")
    d = sunpos.room_direction(pos.azimuth_deg, pos.elevation_deg, north)
    log.info("sun at %s, %s: azimuth %.2f deg, elevation %.2f deg -> direction %.4f,%.4f,%.4f in room axes",
             when.isoformat(), where_txt, pos.azimuth_deg, pos.elevation_deg, *d)
    E = a.sun_irradiance if a.sun_irradiance is not None else (1.0, 1.0, 1.0)
    sun = asm.sun_primitive(d, E, lo, hi)
    if a.sun_irradiance is None:  # the engine estimates the strength from the photo
        for k in ("irradiance_perpendicular", "emitted_radiance"):
            del sun[k]
        sun["strength"] = "estimate"
    sun["from"] = {"when": when.isoformat(), "when_utc": when.astimezone(timezone.utc).isoformat(),
                   "time_from": time_from, "where": [lat, lon] + ([alt] if alt is not None else []),
                   "place_from": place_from, **bearing, "room_north_deg": north,
                   "azimuth_deg": pos.azimuth_deg, "elevation_deg": pos.elevation_deg,
                   "algorithm": "NREL SPA (pvlib.solarposition.spa_python)"}
    return sun


def _camera_in_room(a, cam, lo, hi):
    """(camera, turned): the calibrated camera, or its 180 deg turn about +Y when only the turned one
    lies inside the taped room (the photo's +X runs leftwards: calibrate's other sign of the floor
    axes, --flip-xz); neither inside is an error naming the files."""
    from recon import assemble as asm

    turned, was_turned = asm.inside_turn(cam, lo, hi)
    if not was_turned:
        asm.check_camera_in_room(cam, lo, hi, str(a.camera), str(a.primitives))  # raises if outside, naming both files
        return cam, False
    log.warning("%s: the camera centre %s m lies outside the room of %s, turned 180 deg about +Y at %s m it lies "
                "inside: using the turned camera (the room's +X runs leftwards in the photo, as calibrate "
                "--flip-xz would take it)", a.camera, np.round(cam.centre, 2).tolist(), a.primitives,
                np.round(turned.centre, 2).tolist())
    return turned, True


def _refine_camera(a, cam, prims, model, photo, sun=None, response=None):
    """calibrate's camera refined against the photo's edges of the room and the clicked lines its
    camera.json keeps (recon.camrefine), and with a sun (scene.json's entry) and the bracket's response
    the sunlit patch's outline and the openings' edges too; one info line when taken, one warning when the
    input camera is kept. None (not tried) for a room clicked on the photo with this camera (`photoar model`)."""
    from recon.camrefine import refine_camera
    from recon.io import SceneError, read_json

    if isinstance(model, dict) and isinstance(model.get("model"), dict) and model["model"].get("from") == "clicks":
        # `photoar model --clicks` measured the room through this very camera: its edges project where
        # the camera put them, and cannot correct it
        log.info("camera not refined: %s was clicked on the photo with this camera (no independent room "
                 "measurement)", a.primitives)
        return None
    r = refine_camera(cam, prims, photo, read_json(a.camera, SceneError),
                      fine_stage=getattr(a, "camera_edges", "profiles"), sun=sun, response=response)
    if r.accepted:
        log.info("camera refined against the room's edges: %s", r.summary())
    elif r.fits:
        log.info("camera kept: %s", r.reason)
    else:
        log.warning("%s: kept this camera, not refined against the room's edges: %s", a.camera, r.reason)
    return r


def _camera_json(path: Path, cam) -> bytes:
    """The user's camera.json with the camera scene uses (turned and/or refined: focal length,
    principal point, R, t, centre) written in, other fields kept."""
    from recon.io import SceneError, dumps_json, read_json

    d = read_json(path, SceneError)
    block = next((d[k] for k in ("main_camera", "camera") if k in d), d)
    fx, fy = float(cam.K[0, 0]), float(cam.K[1, 1])
    cx, cy = float(cam.K[0, 2]), float(cam.K[1, 2])  # refined too when calibrate took it from three VPs
    block.update({"R": cam.R.tolist(), "t": cam.t.tolist(), "centre": cam.centre.tolist()})
    if isinstance(block.get("K"), dict):
        block["K"].update({"fx": fx, "fy": fy, "cx": cx, "cy": cy})
    elif "K" in block:
        block["K"] = cam.K.tolist()
    for k, v in (("fx", fx), ("fy", fy), ("cx", cx), ("cy", cy)):
        if k in block:
            block[k] = v
    if "K_matrix" in block:
        block["K_matrix"] = cam.K.tolist()
    return (dumps_json(d, indent=2) + "\n").encode()


def _warn_no_sun(sun: dict, prims: list[dict], where: str) -> None:
    """Warn when the sun cannot light the room: the engine's test (lighting.sun.no_sun_reason: below
    the horizon, no opening, zero irradiance, every opening facing away)."""
    from lighting.sun import no_sun_reason

    d = np.asarray(sun["direction_to_sun"], float)
    normals = [np.asarray(p["normal"], float) for p in prims if p.get("opening") is True]
    E = sun.get("irradiance_perpendicular", [1.0, 1.0, 1.0])  # a strength still to estimate: not zero
    reason = no_sun_reason(d / np.linalg.norm(d), np.asarray(E, float), normals,
                           where)
    if reason:
        log.warning("%s", reason)


def _load_probe(a, lo, hi, images) -> tuple:
    """The bracket read, checked, cropped and merged (its images added to `images`), before any camera:
    (the light_probe block, the shots shortest first, their times, (radiance, response) of the merge)."""
    from recon import assemble as asm

    for opt in ("probe_centre", "probe_radius", "probe_shot_from"):
        if getattr(a, opt) is None:
            raise ValueError(f"--{opt.replace('_', '-')}: required with --probe (the ball's tape-measured pose)")
    if not a.probe_radius > 0:
        raise ValueError(f"--probe-radius: must be positive, got {a.probe_radius}")
    shots, times = [], []
    for f in a.probe:
        img, et = read_photo(f)
        shots.append(img)
        times.append(et)
    if a.probe_times is not None:
        if len(a.probe_times) != len(a.probe):
            raise ValueError(f"--probe-times: {len(a.probe_times)} times for {len(a.probe)} --probe images")
        times = list(a.probe_times)
    for f, et in zip(a.probe, times):
        if et is None:
            raise ValueError(f"{f}: no exposure time: give --probe-times (the file has no EXIF ExposureTime)")
        if not (np.isfinite(et) and et > 0):
            raise ValueError(f"--probe-times: exposure times must be positive seconds, got {et} for {f}")
    if len(set(times)) != len(times):
        raise ValueError(f"--probe-times: exposure times must differ, got {times}")
    if len(shots) < 2:
        raise ValueError(f"--probe: a bracket needs at least two exposures, got {len(shots)}")
    for f, img in zip(a.probe[1:], shots[1:]):
        if img.shape != shots[0].shape:
            raise ValueError(f"{f}: image is {img.shape[1]}x{img.shape[0]}, {a.probe[0]} is "
                             f"{shots[0].shape[1]}x{shots[0].shape[0]}: a bracket's images share one size")
    if a.probe_circle == "auto":
        from recon.probecircle import crop_ball, find_ball_in_bracket

        c = find_ball_in_bracket(shots, [str(f) for f in a.probe])
        log.info("probe ball at (%.2f, %.2f) px, radius %.2f px", *c)
        shots = [crop_ball(img, *c) for img in shots]
    elif shots[0].shape[0] != shots[0].shape[1]:
        raise ValueError(f"{a.probe[0]}: probe image is {shots[0].shape[1]}x{shots[0].shape[0]}: with "
                         "--probe-circle inscribed it must be a square crop with the ball as its inscribed circle "
                         "(use --probe-circle auto for a wider photo)")
    order = np.argsort(times)
    files = [f"probe_{k:02d}.png" for k in range(len(shots))]
    for k, i in enumerate(order):
        images[files[k]] = shots[i]
    times = [float(times[i]) for i in order]
    asm.check_probe_inside(a.probe_centre, a.probe_radius, a.probe_shot_from, lo, hi)
    lp = asm.light_probe_block(a.probe_centre, a.probe_radius, a.probe_shot_from, shots[0].shape[0], files, times)
    merged = _check_response(a, [shots[i] for i in order], times)
    return lp, [shots[i] for i in order], times, merged


def _check_probe_pose(a, cam, prims, photo, photo_t, lp, shots, times, merged) -> dict:
    """The light_probe block lp, once its pose agrees with the photo seen through the camera scene uses
    (lighting.probecheck; an error when the ball's turned pose fits better, a warning when it fits poorly)."""
    if not a.skip_probe_check:
        from lighting.probecheck import check_probe_pose

        try:
            chk = check_probe_pose(lp, a.probe_shot_from, shots, times, photo, photo_t, cam, prims, merged=merged)
        except ValueError as e:
            raise ValueError(f"--probe: {e}") from None
        log.info("probe pose check: log-luminance correlation with the photo %.2f (turned 180 deg: %.2f)",
                 chk.corr_given, chk.corr_turned)
        if not np.isfinite(chk.corr_given):
            log.warning("--probe-shot-from: the probe pose could not be checked (the probe and the photo see too "
                        "few surface points in common)")
            return lp
        if chk.turned_fits_better:
            raise ValueError(f"--probe-shot-from: the probe images disagree with the pose (correlation with the photo "
                             f"{chk.corr_given:.2f}; with the ball shot from the opposite side {chk.corr_turned:.2f}): "
                             "check the shot-from point (or pass --skip-probe-check)")
        if not chk.corr_given > 0.5:
            log.warning("--probe-shot-from: the probe images agree poorly with the photo for this pose "
                        "(log-luminance correlation %.2f)", chk.corr_given)
    return lp


def _check_response(a, shots: list[np.ndarray], times: list[float]) -> tuple[np.ndarray, np.ndarray]:
    """Merge the bracket (shortest first) with the response recovered from it, as captured light will,
    and warn when one channel's response does not fit the bracket. Returns (radiance, response)."""
    from lighting import hdr

    try:
        rad, g = hdr.merge_bracket(shots, times)
    except ValueError as e:
        raise ValueError(f"--probe: {e}") from None
    hdr.warn_unfit_channel(hdr.channel_residuals(shots, times, g), f"--probe {a.probe[0]}")
    return rad, g


def write_room(room: Path, scene: dict, images: dict[str, np.ndarray], copies: dict[str, bytes]) -> None:
    """Replace the folder `room` by the new version (recon.io.AtomicFolder); files in it that no run
    of `scene` wrote (OWNED, probe_*, the previous scene's probe files) are the user's and stay."""
    from recon.io import AtomicFolder, read_json, write_json, write_png

    owned = set(OWNED)
    try:
        owned |= set(read_json(Path(room) / "scene.json").get("light_probe", {}).get("ldr_files", []))
    except (OSError, ValueError, AttributeError):
        pass
    with AtomicFolder(room, lambda name: name in owned or name.startswith("probe_")) as stage:
        for name, img in images.items():
            write_png(stage / name, img)
        for name, data in copies.items():
            (stage / name).write_bytes(data)
        write_json(stage / "scene.json", scene)


def run(a: argparse.Namespace) -> int:
    if a.room.exists() and not a.room.is_dir():
        raise ValueError(f"{a.room}: exists and is not a folder")
    scene, images, copies = assemble(a)
    write_room(a.room, scene, images, copies)
    print(a.room / "scene.json")
    return 0
