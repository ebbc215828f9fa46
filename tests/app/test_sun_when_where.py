"""`photoar scene` with the sun given by date, time and place (--sun-from-photo or --when/--where)
and the room's compass bearing (--north, --wall-bearing), on sun_room's user inputs: the direction
in scene.json, the inputs recorded, one error line for what is missing, and the composite against
the one of the declared sun."""
import json
import logging
import math
from datetime import datetime, timedelta, timezone

import numpy as np
import pytest

from app.cli import main
from recon.sunpos import room_direction, solar_position
from tests.conftest import shared_scene
from tests.own_room import fmt, scene_argv, sunlit_inputs

PARIS = (48.8566, 2.3522)
CEST = timezone(timedelta(hours=2))


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """sun_room's user files with the window as an opening and the true camera (as in
    test_own_room_sun), and its declared sun."""
    inp = sunlit_inputs(shared_scene("sun_room"), tmp_path_factory.mktemp("sun_when"))
    return inp


def when_for(direction, whole_seconds: bool = False) -> tuple[datetime, float, np.ndarray]:
    """A time on 2026-06-21 afternoon in Paris when the sun stands at the elevation of `direction`
    (to the microsecond, ~4e-9 deg; whole seconds as EXIF writes them: ~0.004 deg), the --north that
    turns its azimuth onto `direction`'s, and the room direction those give (bisection on the
    falling afternoon elevation)."""
    d = np.asarray(direction, float) / np.linalg.norm(direction)
    el = math.degrees(math.asin(d[1]))
    lo, hi = datetime(2026, 6, 21, 14, 0, tzinfo=CEST), datetime(2026, 6, 21, 21, 0, tzinfo=CEST)
    for _ in range(36):  # 7 h / 2^36 < 1 microsecond
        mid = lo + (hi - lo) / 2
        if solar_position(mid, *PARIS).elevation_deg > el:
            lo = mid
        else:
            hi = mid
    when = lo.replace(microsecond=0) if whole_seconds else lo
    pos = solar_position(when, *PARIS)
    north = (pos.azimuth_deg - math.degrees(math.atan2(d[0], -d[2]))) % 360.0
    return when, north, room_direction(pos.azimuth_deg, pos.elevation_deg, north)


def _angle(a, b) -> float:
    a, b = np.asarray(a, float), np.asarray(b, float)
    return math.degrees(math.acos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1, 1)))


def exif_jpeg(src_png, out, when: datetime | None, lat: float | None, lon: float | None, offset: bool = True):
    """The photo as a JPEG with EXIF DateTimeOriginal/OffsetTimeOriginal and GPS as a phone writes
    them (a tag left out where its value is None or offset is False), written with Pillow."""
    from PIL import Image

    im = Image.open(src_png).convert("RGB")
    ex = im.getexif()
    sub = ex.get_ifd(0x8769)
    if when is not None:
        sub[0x9003] = when.strftime("%Y:%m:%d %H:%M:%S")
        if offset:
            sub[0x9011] = when.strftime("%z")[:3] + ":" + when.strftime("%z")[3:]
    gps = ex.get_ifd(0x8825)

    def dms(x):
        x = abs(x)
        d, m = int(x), int((x - int(x)) * 60)
        return (float(d), float(m), round((x - d - m / 60) * 3600, 4))

    if lat is not None:
        gps.update({1: "N" if lat >= 0 else "S", 2: dms(lat)})
    if lon is not None:
        gps.update({3: "E" if lon >= 0 else "W", 4: dms(lon)})
    im.save(out, quality=95, exif=ex)
    return out


def _sun_entry(room) -> dict:
    d = json.loads((room / "scene.json").read_text())
    return next(p for p in d["primitives"] if p["type"] == "sun")


def _run(argv, capsys):
    """(exit status, stderr lines) of photoar; argparse's own errors exit through SystemExit."""
    try:
        rc = main(["-q", *argv])
    except SystemExit as e:
        rc = e.code
    return rc, capsys.readouterr().err.strip().splitlines()


def test_sun_from_photo_exif(inputs, capsys):
    """A JPEG carrying the date, UTC offset and GPS of a moment when the sun stands where sun_room's
    does: --sun-from-photo with --north gives that direction (to 0.01 deg), the inputs are recorded,
    and without --sun-irradiance the strength is left to the estimate."""
    when, north, want = when_for(inputs["sun"]["direction_to_sun"], whole_seconds=True)
    assert _angle(want, inputs["sun"]["direction_to_sun"]) < 0.01
    jpg = exif_jpeg(inputs["photo"], inputs["tmp"] / "phone.jpg", when, *PARIS)
    room = inputs["tmp"] / "room_exif"
    argv = scene_argv(inputs, room, inputs["camera"])
    argv[argv.index("--photo") + 1] = str(jpg)
    rc, err = _run(argv + ["--skip-probe-check", "--sun-from-photo", "--north", repr(north)], capsys)
    assert rc == 0, err
    sun = _sun_entry(room)
    np.testing.assert_allclose(sun["direction_to_sun"], want, atol=1e-6)  # GPS seconds to 1e-4: ~3 mm
    assert _angle(sun["direction_to_sun"], inputs["sun"]["direction_to_sun"]) < 0.01
    assert sun["declared_by"] == "user" and sun["strength"] == "estimate"
    assert "irradiance_perpendicular" not in sun
    f = sun["from"]
    assert f["time_from"].startswith("EXIF") and f["place_from"] == "EXIF GPS"
    assert datetime.fromisoformat(f["when"]) == when and f["north_deg"] == pytest.approx(north, abs=1e-12)
    np.testing.assert_allclose(f["where"], PARIS, atol=1e-7)
    from recon.scene import load_scene

    s = load_scene(room, load_textures=False)
    assert s.sun.strength_estimated and s.meta["sun_declared_by"] == "user"


@pytest.mark.parametrize("missing", ["DateTimeOriginal", "OffsetTimeOriginal", "GPSLatitude", "GPSLongitude"])
def test_sun_from_photo_missing_tag(inputs, capsys, missing):
    """Each tag left out of the JPEG: one error line naming the file and the tag; nothing written."""
    when = datetime(2026, 6, 21, 17, 0, tzinfo=CEST)
    jpg = exif_jpeg(inputs["photo"], inputs["tmp"] / f"no_{missing}.jpg",
                    None if missing == "DateTimeOriginal" else when,
                    None if missing == "GPSLatitude" else PARIS[0], None if missing == "GPSLongitude" else PARIS[1],
                    offset=missing != "OffsetTimeOriginal")
    room = inputs["tmp"] / f"room_no_{missing}"
    argv = scene_argv(inputs, room, inputs["camera"])
    argv[argv.index("--photo") + 1] = str(jpg)
    rc, err = _run(argv + ["--skip-probe-check", "--sun-from-photo", "--north", "90"], capsys)
    assert rc == 2 and len(err) == 1, err
    assert err[0].startswith(f"photoar: error: {jpg}: no EXIF {missing} (--sun-from-photo)"), err
    assert not room.exists()


def test_when_without_offset(inputs, capsys):
    """--when without a UTC offset is refused (one line saying so) unless --sun-from-photo's EXIF
    gives the offset: then the EXIF offset is taken."""
    base = scene_argv(inputs, inputs["tmp"] / "room_naive", inputs["camera"]) + ["--skip-probe-check"]
    rc, err = _run(base + ["--when", "2026-06-21T17:00", "--where", fmt(PARIS), "--north", "90"], capsys)
    assert rc == 2 and len(err) == 1 and "--when: '2026-06-21T17:00' has no UTC offset" in err[0], err
    jpg = exif_jpeg(inputs["photo"], inputs["tmp"] / "offset_only.jpg", datetime(2026, 1, 1, 0, 0, tzinfo=CEST),
                    None, None)
    argv = base + ["--sun-from-photo", "--when", "2026-06-21T17:00", "--where", fmt(PARIS), "--north", "90"]
    argv[argv.index("--photo") + 1] = str(jpg)
    rc, err = _run(argv, capsys)
    assert rc == 0, err
    f = _sun_entry(inputs["tmp"] / "room_naive")["from"]
    assert datetime.fromisoformat(f["when"]) == datetime(2026, 6, 21, 17, 0, tzinfo=CEST)
    assert "OffsetTimeOriginal" in f["time_from"] and f["place_from"] == "--where"


def test_wall_bearing_equals_north(inputs, capsys):
    """--wall-bearing left=B is --north B+90 (the left wall, x min, faces -x); the sun entry records
    the wall."""
    base = scene_argv(inputs, inputs["tmp"] / "room_wall", inputs["camera"]) + [
        "--skip-probe-check", "--when", "2026-06-21T17:00+02:00", "--where", fmt(PARIS)]
    assert _run(base + ["--wall-bearing", "left=200"], capsys)[0] == 0
    by_wall = _sun_entry(inputs["tmp"] / "room_wall")
    assert by_wall["from"]["wall_bearing"] == {"left": 200.0} and by_wall["from"]["room_north_deg"] == 290.0
    assert _run(base + ["--north", "290"], capsys)[0] == 0
    np.testing.assert_allclose(by_wall["direction_to_sun"], _sun_entry(inputs["tmp"] / "room_wall")["direction_to_sun"],
                               atol=1e-12)


@pytest.mark.parametrize("case", ["below_horizon", "no_north", "no_where", "twice", "bad_wall"])
def test_sun_by_time_errors(inputs, capsys, case):
    room = inputs["tmp"] / f"room_err_{case}"
    base = scene_argv(inputs, room, inputs["camera"]) + ["--skip-probe-check"]
    args = {"below_horizon": ["--when", "2026-06-21T23:30+02:00", "--where", fmt(PARIS), "--north", "0"],
            "no_north": ["--when", "2026-06-21T17:00+02:00", "--where", fmt(PARIS)],
            "no_where": ["--when", "2026-06-21T17:00+02:00", "--north", "0"],
            "twice": ["--when", "2026-06-21T17:00+02:00", "--where", fmt(PARIS), "--north", "0",
                      "--sun-direction", "-1,1,0", "--sun-irradiance", "1,1,1"],
            "bad_wall": ["--when", "2026-06-21T17:00+02:00", "--where", fmt(PARIS), "--wall-bearing", "ceiling=3"]}
    rc, err = _run(base + args[case], capsys)
    want = {"below_horizon": "the sun is below the horizon at 2026-06-21T23:30:00+02:00", "no_north": "--north:",
            "no_where": "--where: the place is needed", "twice": "--sun-direction: the sun's direction is given twice",
            "bad_wall": "argument --wall-bearing: expected WALL=DEG with WALL one of back, front, left, right"}[case]
    assert rc == 2 and len(err) == 1 and want in err[0], err
    assert not room.exists()


def test_composite_with_the_sun_from_when_and_where(inputs, tmp_path):
    """sun_room assembled with --when/--where/--north chosen to put the sun where its declared one is
    (and its declared irradiance) composites like the declared sun: max difference <= 0.5 level.
    The time is given to the microsecond (the direction then agrees to ~1e-8 deg): the composite is
    not continuous in the sun's direction at the 8-bit level (a sunlit patch's edge moves by a pixel
    for ~0.01 deg), so whole seconds (0.0017 deg here) would test that, not the wiring."""
    import cv2

    when, north, want = when_for(inputs["sun"]["direction_to_sun"])
    E = inputs["sun"]["irradiance_perpendicular"]
    rooms = {"declared": ["--sun-direction", fmt(inputs["sun"]["direction_to_sun"]), "--sun-irradiance", fmt(E)],
             "when": ["--when", when.isoformat(), "--where", fmt(PARIS), "--north", repr(north),
                      "--sun-irradiance", fmt(E)]}
    common = ["--lighting", "captured", "--object", str(inputs["mesh"]), "--place", fmt(inputs["place"]),
              "--yaw", repr(inputs["yaw"]), "--object-albedo", fmt(inputs["albedo"])]
    out = {}
    for k, sun_args in rooms.items():
        room = tmp_path / f"room_{k}"
        assert main(["-q", *scene_argv(inputs, room, inputs["camera"]), "--skip-probe-check", *sun_args]) == 0
        assert main(["-q", "composite", str(room), "--out", str(tmp_path / k), *common,
                     "--cache", str(tmp_path / f"c_{k}")]) == 0
        out[k] = cv2.imread(str(tmp_path / k / "composite.png")).astype(int)
    assert _angle(_sun_entry(tmp_path / "room_when")["direction_to_sun"], inputs["sun"]["direction_to_sun"]) < 1e-6
    diff = np.abs(out["when"] - out["declared"])
    print(f"sun from when/where vs declared: max diff {diff.max()} levels, mean {diff.mean():.4f}")
    assert diff.max() <= 0.5


def test_strength_estimated_for_the_given_direction(inputs, tmp_path, capsys):
    """Without --sun-irradiance, captured light keeps the direction from when/where and estimates
    the strength from the photo's sunlit patches (report: from declared, strength_from estimate);
    known light refuses such a sun."""
    from app.engine import Engine, EngineParams
    from recon.response import luminance
    from recon.scene import load_scene

    when, north, _ = when_for(inputs["sun"]["direction_to_sun"])
    room = tmp_path / "room"
    assert main(["-q", *scene_argv(inputs, room, inputs["camera"]), "--skip-probe-check", "--when", when.isoformat(),
                 "--where", fmt(PARIS), "--north", repr(north)]) == 0
    s = load_scene(room, load_textures=False)
    e = Engine(s, EngineParams(patch_size=0.4, emitter_patch_size=0.3, passes=8, lighting="captured"),
               cache_dir=tmp_path / "c", quiet=True)
    assert e.sun.source == "declared" and e.sun.on
    np.testing.assert_allclose(e.sun.light.sun.direction, s.sun.direction, atol=1e-12)
    rep = e.sun.report()
    assert rep["strength_from"] == "estimate" and rep["lights_room"] is True
    ratio = luminance(np.array(rep["irradiance_perpendicular"])) / luminance(np.array(inputs["sun"]["irradiance_perpendicular"]))
    print(f"strength estimated for the given direction: {ratio:.3f} x the declared sun's")
    assert 0.9 <= ratio <= 1.1  # measured 0.984
    # known light (a folder with a camera_response) has no photo estimate to take the strength from
    import types

    from app.stages.sun import SunSetup

    stub = types.SimpleNamespace(scene=s, lighting="known", where=str(room / "scene.json"))
    with pytest.raises(ValueError, match='strength is to be estimated from the photo .*"strength": "estimate"'):
        SunSetup._source(stub, "auto")
    stub.lighting = "captured"
    assert SunSetup._source(stub, "auto") == "declared"


def test_known_light_reference_refuses_a_sun_to_estimate(tmp_path, capsys):
    """sun_room (a folder with its camera_response and emitters) whose sun entry gives only the
    direction ("strength": "estimate"): `photoar reference --lighting known` has no photo estimate to
    take the strength from: one error line naming the file; a malformed strength is refused too."""
    root = shared_scene("sun_room")
    for f in root.iterdir():
        if f.name != "scene.json":
            (tmp_path / f.name).symlink_to(f)
    d = json.loads((root / "scene.json").read_text())
    sun = next(p for p in d["primitives"] if p["type"] == "sun")
    for k in ("irradiance_perpendicular", "emitted_radiance"):
        sun.pop(k)
    sun["strength"] = "estimate"
    (tmp_path / "scene.json").write_text(json.dumps(d))
    rc, err = _run(["reference", str(tmp_path), "--out", str(tmp_path / "o"), "--lighting", "known"], capsys)
    assert rc == 2 and len(err) == 1 and err[0].startswith(f"photoar: error: {tmp_path / 'scene.json'}: sun: its "
                                                           "strength is to be estimated"), err
    assert not (tmp_path / "o").exists()
    sun["strength"] = "guess"
    (tmp_path / "scene.json").write_text(json.dumps(d))
    rc, err = _run(["reference", str(tmp_path), "--out", str(tmp_path / "o"), "--lighting", "known"], capsys)
    assert rc == 2 and len(err) == 1 and ".strength' must be \"declared\" or \"estimate\"" in err[0], err
