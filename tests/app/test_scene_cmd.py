"""`photoar scene` (issue 16 items 1, 2, 5, 9): assembling a room folder from a user's files, every
bad input as one error line, the probe pose from tape measurements, EXIF, --probe-circle auto."""
import json
import shutil
import struct

import numpy as np
import pytest

from app.cli import main
from tests.conftest import shared_scene
from tests.own_room import benchmark_camera_json, scene_argv, write_inputs

USER_KEYS = {"name", "format_version", "world", "main_camera", "primitives", "light_probe"}


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    root = shared_scene("window_room")
    tmp = tmp_path_factory.mktemp("own")
    inp = write_inputs(root, tmp / "in")
    cam = tmp / "in" / "camera.json"
    cam.write_text(json.dumps(benchmark_camera_json(inp["scene"])))
    inp["camera"] = cam
    inp["tmp"] = tmp
    return inp


def _run(argv, capsys):
    rc = main(["-q", *argv])
    return rc, capsys.readouterr().err


# ---- the probe camera from tape -----------------------------------------------------------------

@pytest.mark.parametrize("name", ["window_room", "lamps_room", "sun_room"])
def test_probe_camera_matches_benchmark(name):
    """Ball centre, radius and the probe camera's centre as shot-from give the benchmark's probe
    camera (R, t, pixel size, view direction) to 1e-9."""
    from recon.assemble import probe_camera

    lp = json.loads((shared_scene(name) / "scene.json").read_text())["light_probe"]
    c = lp["camera"]
    got = probe_camera(lp["centre"], lp["radius"], c["centre"], c["width"], c["height"])
    for k in ("R", "t", "view_direction", "pixel_size_m", "cx", "cy"):
        np.testing.assert_allclose(got[k], c[k], atol=1e-9, err_msg=k)


def test_probe_camera_straight_down_is_refused():
    from recon.assemble import probe_camera
    from recon.io import SceneError

    with pytest.raises(SceneError, match="roll is undetermined"):
        probe_camera([1, 1, 1], 0.1, [1, 2, 1], 256, 256)


# ---- a good run -----------------------------------------------------------------------------------

def test_scene_writes_a_loadable_folder(inputs, capsys):
    from recon.scene import load_scene

    room = inputs["tmp"] / "room"
    rc, err = _run(scene_argv(inputs, room, inputs["camera"]), capsys)
    assert rc == 0, err
    d = json.loads((room / "scene.json").read_text())
    assert set(d) == USER_KEYS and d["format_version"] == 1
    assert set(d["main_camera"]) == {"K", "R", "t", "exposure_time", "files", "refinement"}
    truth = inputs["scene"]
    np.testing.assert_allclose(d["light_probe"]["camera"]["R"], truth["light_probe"]["camera"]["R"], atol=1e-9)
    np.testing.assert_allclose(d["light_probe"]["camera"]["t"], truth["light_probe"]["camera"]["t"], atol=1e-9)
    assert d["light_probe"]["exposure_times"] == truth["light_probe"]["exposure_times"]
    np.testing.assert_allclose(d["world"]["room_min"], truth["world"]["room_min"])
    np.testing.assert_allclose(d["world"]["room_max"], truth["world"]["room_max"])
    names = {p["name"] for p in d["primitives"]}
    assert {"floor", "ceiling", "back", "front", "left", "right", "desk_top", "shelf", "window"} <= names
    win = next(p for p in d["primitives"] if p["name"] == "window")
    assert win["emitter"] is True and "emitted_radiance" not in win and "albedo" not in win
    # the room's six quads agree with the benchmark's (same planes, same inward normals)
    for p in truth["primitives"]:
        if p["role"] == "room":
            q = next(x for x in d["primitives"] if x["name"] == p["name"])
            np.testing.assert_allclose(q["normal"], p["normal"], atol=1e-12)
            np.testing.assert_allclose(sorted(map(tuple, q["corners"])), sorted(map(tuple, p["corners"])), atol=1e-9)
    sc = load_scene(room)
    assert sc.response is None and sc.photo.shape == (480, 640, 3)
    assert any(q.role == "window" for q in sc.quads)
    for f in ("background.png", "camera.json", "primitives.json", *d["light_probe"]["ldr_files"]):
        assert (room / f).is_file(), f
    import cv2

    assert np.array_equal(cv2.imread(str(room / "background.png")), cv2.imread(str(inputs["photo"])))


def test_rerun_updates_the_folder(inputs, capsys):
    """A second run with fewer probe images and another exposure time replaces the copies, drops the
    stale probe image and keeps the user's own files."""
    room = inputs["tmp"] / "room2"
    assert _run(scene_argv(inputs, room, inputs["camera"]), capsys)[0] == 0
    (room / "my_notes.txt").write_text("keep me")
    argv = scene_argv(dict(inputs, probes=inputs["probes"][:4], times=inputs["times"][:4]), room, inputs["camera"])
    argv[argv.index("--exposure-time") + 1] = "0.25"
    rc, err = _run(argv, capsys)
    assert rc == 0, err
    d = json.loads((room / "scene.json").read_text())
    assert d["main_camera"]["exposure_time"] == 0.25 and len(d["light_probe"]["ldr_files"]) == 4
    assert not (room / "probe_04.png").exists() and (room / "my_notes.txt").read_text() == "keep me"
    assert not list(room.parent.glob(".room2.*"))


# ---- bad input: one line naming the file and field, exit 2, nothing written -------------------------

def _bad_cases(inp, tmp):
    cam = json.loads(inp["camera"].read_text())
    prims = json.loads(inp["room"].read_text())

    def w(name, data):
        p = tmp / name
        p.write_bytes(data) if isinstance(data, bytes) else p.write_text(json.dumps(data))
        return p

    R = np.array(cam["R"])
    no_k = {k: v for k, v in cam.items() if k not in ("K", "fx", "fy", "cx", "cy")}
    small = dict(cam, K=dict(cam["K"], width=320, height=240), width=320, height=240)
    outside = dict(cam, t=(np.array(cam["t"]) - R @ np.array([0, 0, 20.0])).tolist())
    half = tmp / "half.png"
    import cv2

    cv2.imwrite(str(half), cv2.imread(str(inp["probes"][1]))[:128, :128])
    oblong = [tmp / f"oblong_{i}.png" for i in range(len(inp["probes"]))]
    for f, o in zip(inp["probes"], oblong):
        cv2.imwrite(str(o), cv2.imread(str(f))[:, :200])
    return [
        ("photo missing", {"--photo": str(tmp / "nope.jpg")}, "nope.jpg: file not found"),
        ("photo garbage", {"--photo": str(w("garbage.png", b"not an image at all"))}, "garbage.png: not a readable"),
        ("camera without K", {"--camera": str(w("nok.json", no_k))}, "nok.json: missing field 'K'"),
        ("camera without R", {"--camera": str(w("nor.json", {k: v for k, v in cam.items() if k != "R"}))},
         "nor.json: missing field 'R'"),
        ("R not a rotation", {"--camera": str(w("badr.json", dict(cam, R=(2 * R).tolist())))},
         "badr.json: field 'R' is not a rotation"),
        ("R a reflection", {"--camera": str(w("refl.json", dict(cam, R=(-R).tolist())))},
         "refl.json: field 'R' is not a rotation"),
        ("photo size", {"--camera": str(w("small.json", small))}, "photo.png: image is 640x480"),
        ("camera outside room", {"--camera": str(w("out.json", outside))}, "out.json: the camera centre"),
        ("primitives malformed", {"--primitives": str(w("broken.json", b"{\"primitives\": [}"))},
         "broken.json: malformed JSON"),
        ("primitives no room", {"--primitives": str(w("noroom.json", {"primitives": prims["primitives"][1:]}))},
         "noroom.json: no room"),
        ("box without size", {"--primitives": str(w("nosize.json", {"primitives": [
            prims["primitives"][0], {"name": "b", "type": "box", "center": [1, 1, 1]}]}))},
         "nosize.json: missing field 'primitives[1].size'"),
        ("unknown role", {"--primitives": str(w("role.json", {"primitives": [
            prims["primitives"][0], dict(prims["primitives"][1], role="sofa")]}))}, "role.json: field 'primitives[1].role'"),
        ("times count", {"--probe-times": [str(t) for t in inp["times"][:3]]}, "--probe-times: 3 times for 5"),
        ("probe sizes differ", {"--probe": [str(inp["probes"][0]), str(half), *map(str, inp["probes"][2:])]},
         "half.png: image is 128x128"),
        ("no exposure time", {"--exposure-time": None}, "photo.png: no exposure time"),
        ("probe not square", {"--probe": list(map(str, oblong))}, "oblong_0.png: probe image is 200x256"),
        ("probe without pose", {"--probe-centre": None}, "--probe-centre: required with --probe"),
        ("ball outside the room", {"--probe-centre": "2,0.05,1"}, "--probe-centre: the ball"),
        ("no probe times", {"--probe-times": None}, "ball_0.png: no exposure time: give --probe-times"),
        ("probe shot from the other side", {"--probe-shot-from": ",".join(
            str(c + (c - s)) if i != 1 else str(s) for i, (c, s) in enumerate(zip(inp["centre"], inp["shot_from"])))},
         "--probe-shot-from: the probe images disagree with the pose"),
    ]


def _replace(argv, opt, value):
    argv = list(argv)
    i = argv.index(opt)
    j = i + 1
    while j < len(argv) and not argv[j].startswith("--"):
        j += 1
    if value is None:
        return argv[:i] + argv[j:]
    return argv[:i + 1] + (value if isinstance(value, list) else [value]) + argv[j:]


def test_bad_inputs_one_line_exit_2_nothing_written(inputs, capsys):
    tmp = inputs["tmp"] / "bad"
    tmp.mkdir(exist_ok=True)
    room = tmp / "room"
    good = scene_argv(inputs, room, inputs["camera"])
    for what, changes, expect in _bad_cases(inputs, tmp):
        argv = good
        for opt, val in changes.items():
            argv = _replace(argv, opt, val)
        rc, err = _run(argv, capsys)
        lines = err.strip().splitlines()
        assert rc == 2, (what, err)
        assert len(lines) == 1 and lines[0].startswith("photoar: error: ") and expect in lines[0], (what, lines)
        assert not room.exists() and not list(tmp.glob(".room.*")), what
    # a failed run leaves an earlier good folder as it was
    assert _run(good, capsys)[0] == 0
    before = (room / "scene.json").read_bytes()
    rc, _ = _run(_replace(good, "--probe-times", [str(t) for t in inputs["times"][:2]]), capsys)
    assert rc == 2 and (room / "scene.json").read_bytes() == before


# ---- EXIF -----------------------------------------------------------------------------------------

def _exif_jpeg(img_bgr, exposure: tuple[int, int] | None, orientation: int | None, endian: str = "<") -> bytes:
    """A JPEG (cv2) with a hand-built APP1 Exif block: IFD0 (Orientation, ExifIFD pointer) and an
    Exif IFD holding ExposureTime as a RATIONAL."""
    import cv2

    ok, jpg = cv2.imencode(".jpg", img_bgr, [cv2.IMWRITE_JPEG_QUALITY, 95])
    assert ok
    e = endian
    ifd0 = []
    if orientation is not None:
        ifd0.append(struct.pack(e + "HHI", 0x0112, 3, 1) + struct.pack(e + "H", orientation) + b"\0\0")
    n0 = len(ifd0) + 1
    exif_ifd_off = 8 + 2 + 12 * n0 + 4
    ifd0.append(struct.pack(e + "HHII", 0x8769, 4, 1, exif_ifd_off))
    rational_off = exif_ifd_off + 2 + 12 + 4
    exif = struct.pack(e + "H", 1) + struct.pack(e + "HHII", 0x829A, 5, 1, rational_off) + b"\0\0\0\0"
    rational = struct.pack(e + "II", *(exposure or (0, 0)))
    tiff = ((b"II" if e == "<" else b"MM") + struct.pack(e + "HI", 42, 8) + struct.pack(e + "H", n0) + b"".join(ifd0)
            + b"\0\0\0\0" + exif + rational)
    app1 = b"Exif\0\0" + tiff
    seg = b"\xff\xe1" + struct.pack(">H", len(app1) + 2) + app1
    data = jpg.tobytes()
    return data[:2] + seg + data[2:]


@pytest.mark.parametrize("endian", ["<", ">"])
def test_exif_tags_of_a_hand_built_jpeg(tmp_path, endian):
    """recon.phototags (Pillow) reads ExposureTime and Orientation of a JPEG whose EXIF block is
    built byte by byte here, in either byte order; no EXIF or no image: None, not an error."""
    from recon.phototags import read_tags

    img = np.zeros((8, 8, 3), np.uint8)
    f = tmp_path / "t.jpg"
    f.write_bytes(_exif_jpeg(img, (1, 125), 6, endian))
    ex = read_tags(f)
    assert ex.exposure_time == pytest.approx(1 / 125, rel=1e-12) and ex.orientation == 6
    f.write_bytes(_exif_jpeg(img, None, None, endian))
    assert read_tags(f).exposure_time is None and read_tags(f).orientation is None
    f.write_bytes(b"\x89PNG....")
    assert read_tags(f) == type(read_tags(f))()


def test_exif_gps_and_time_tags(tmp_path):
    """Date, UTC offset and GPS position written by Pillow as a phone writes them (degrees, minutes,
    seconds rationals with N/S, E/W references) come back as signed decimal degrees."""
    from PIL import Image

    from recon.phototags import read_tags

    im = Image.new("RGB", (8, 8))
    ex = im.getexif()
    sub = ex.get_ifd(0x8769)
    sub[0x9003], sub[0x9011], sub[0x829A] = "2026:06:21 15:30:00", "+02:00", 0.004
    gps = ex.get_ifd(0x8825)
    # 33 deg 51' 35.9" S, 151 deg 12' 40" E (Sydney), 58.5 m
    gps.update({1: "S", 2: (33.0, 51.0, 35.9), 3: "E", 4: (151.0, 12.0, 40.0), 5: b"\x00", 6: 58.5})
    f = tmp_path / "gps.jpg"
    im.save(f, exif=ex)
    t = read_tags(f)
    assert t.datetime_original == "2026:06:21 15:30:00" and t.offset_time_original == "+02:00"
    assert t.latitude == pytest.approx(-(33 + 51 / 60 + 35.9 / 3600), abs=1e-9)
    assert t.longitude == pytest.approx(151 + 12 / 60 + 40 / 3600, abs=1e-9)
    assert t.altitude_m == pytest.approx(58.5, abs=1e-9) and t.exposure_time == pytest.approx(0.004, rel=1e-9)


# the stored pixels -> the upright image, for EXIF Orientation 1..8 (the TIFF/EXIF specification)
UPRIGHT = {1: lambda a: a, 2: lambda a: a[:, ::-1], 3: lambda a: a[::-1, ::-1], 4: lambda a: a[::-1],
           5: lambda a: a.swapaxes(0, 1), 6: lambda a: np.rot90(a, -1), 7: lambda a: np.rot90(a, 2).swapaxes(0, 1),
           8: lambda a: np.rot90(a, 1)}


@pytest.mark.parametrize("orientation", range(1, 9))
def test_read_image_rgb_turns_by_exif_orientation(tmp_path, orientation):
    """recon.io.read_image_rgb, the one image reader, returns the stored pixels turned as EXIF
    Orientation says, and the EXIF reader finds the tag."""
    import cv2

    from recon.io import read_image_rgb
    from recon.phototags import read_tags

    rng = np.random.default_rng(orientation)
    img = cv2.resize(rng.integers(0, 255, (6, 10, 3), dtype=np.uint8), (80, 48), interpolation=cv2.INTER_NEAREST)
    f = tmp_path / "o.jpg"
    f.write_bytes(_exif_jpeg(img, (1, 60), orientation))
    raw = cv2.imread(str(f), cv2.IMREAD_COLOR | cv2.IMREAD_IGNORE_ORIENTATION)[..., ::-1]
    assert read_tags(f).orientation == orientation
    assert np.array_equal(read_image_rgb(f), UPRIGHT[orientation](raw))


def test_scene_reads_exif_and_turns_the_photo_upright(inputs, capsys):
    """A phone JPEG stored sideways (orientation 6) with ExposureTime: no --exposure-time needed,
    background.png is upright and the exposure comes from EXIF."""
    import cv2

    photo = cv2.imread(str(inputs["photo"]))
    sideways = np.ascontiguousarray(np.rot90(photo, 1))  # stored turned; orientation 6 turns it back
    jpg = inputs["tmp"] / "phone.jpg"
    jpg.write_bytes(_exif_jpeg(sideways, (217, 1000), 6))
    room = inputs["tmp"] / "room_exif"
    argv = _replace(_replace(scene_argv(inputs, room, inputs["camera"]), "--exposure-time", None), "--photo", str(jpg))
    rc, err = _run(argv + ["--skip-probe-check"], capsys)
    assert rc == 0, err
    d = json.loads((room / "scene.json").read_text())
    assert d["main_camera"]["exposure_time"] == pytest.approx(0.217)
    bg = cv2.imread(str(room / "background.png"))
    assert bg.shape == photo.shape
    assert np.abs(bg.astype(int) - photo.astype(int)).mean() < 3  # JPEG loss only


# ---- --probe-circle auto --------------------------------------------------------------------------

def _pasted(ball, bg, s, ox, oy):
    """`ball` (square, ball = inscribed circle) scaled by s and pasted at offset (ox, oy) onto `bg`,
    with an antialiased edge; returns the image and the true circle (cx, cy, r) px."""
    import cv2

    H, W = bg.shape[:2]
    warped = cv2.warpAffine(ball, np.array([[s, 0, ox], [0, s, oy]]), (W, H), flags=cv2.INTER_LINEAR)
    n = ball.shape[0]
    cx, cy, r = s * (n - 1) / 2 + ox, s * (n - 1) / 2 + oy, s * n / 2
    ss = 4
    yy, xx = np.mgrid[0:H * ss, 0:W * ss]
    u, v = (xx + 0.5) / ss - 0.5, (yy + 0.5) / ss - 0.5
    m = ((u - cx) ** 2 + (v - cy) ** 2 <= r * r).astype(np.float32).reshape(H, ss, W, ss).mean((1, 3))[..., None]
    return (m * warped + (1 - m) * bg).round().astype(np.uint8), (cx, cy, r)


@pytest.mark.parametrize("s,ox,oy", [(1.37, 203.4, 91.7), (0.83, 55.25, 160.6), (1.0, 300.5, 120.3)])
def test_probe_circle_found_within_one_pixel(s, ox, oy):
    import cv2

    from recon.probecircle import crop_ball, find_ball

    ball = cv2.imread(str(shared_scene("window_room") / "probe_02.png"))[..., ::-1]
    rng = np.random.default_rng(0)
    x = np.arange(640)
    bg = np.clip(60 + 40 * np.sin(x / 37.0)[None, :, None] * np.array([1, 0.8, 0.5])
                 + rng.normal(0, 6, (480, 640, 3)), 0, 255).astype(np.uint8)
    img, (cx, cy, r) = _pasted(ball, bg, s, ox, oy)
    fx, fy, fr = find_ball(img)
    print(f"scale {s}: centre off by {np.hypot(fx - cx, fy - cy):.2f} px, radius by {fr - r:+.2f} px")
    assert np.hypot(fx - cx, fy - cy) < 1.0 and abs(fr - r) < 1.0
    crop = crop_ball(img, fx, fy, fr)
    inner = np.hypot(*np.meshgrid(np.arange(256) - 127.5, np.arange(256) - 127.5)) < 110
    assert np.abs(crop.astype(float) - ball.astype(float))[inner].mean() < 12  # the same ball, resampled


# ---- sun --------------------------------------------------------------------------------------------

def test_sun_entry_matches_the_benchmark_sun():
    """--sun-direction/--sun-irradiance give sun_room's sun (radiance, disk size, position) from its
    direction and perpendicular irradiance."""
    from recon.assemble import sun_primitive

    d = json.loads((shared_scene("sun_room") / "scene.json").read_text())
    sun = next(p for p in d["primitives"] if p["type"] == "sun")
    got = sun_primitive(sun["direction_to_sun"], sun["irradiance_perpendicular"], d["world"]["room_min"],
                        d["world"]["room_max"])
    np.testing.assert_allclose(got["emitted_radiance"], sun["emitted_radiance"], rtol=1e-3)
    np.testing.assert_allclose(got["radius_m"], sun["radius_m"], rtol=1e-3)
    np.testing.assert_allclose(got["normal"], sun["normal"], atol=1e-9)
    assert got["angular_diameter_deg"] == sun["angular_diameter_deg"]


def test_probe_circle_auto_cli(inputs, capsys):
    """The bracket shot wider (each image pasted into a larger picture at one scaled, sub-pixel
    pose): --probe-circle auto crops the ball back; the crops match the benchmark's probe images."""
    import cv2

    rng = np.random.default_rng(1)
    bg = np.clip(90 + rng.normal(0, 8, (400, 520, 3)), 0, 255).astype(np.uint8)
    wide = []
    for i, f in enumerate(inputs["probes"]):
        img, _ = _pasted(cv2.imread(str(f)), bg, 1.21, 101.3, 47.6)
        wide.append(inputs["tmp"] / f"wide_{i}.png")
        cv2.imwrite(str(wide[-1]), img)
    room = inputs["tmp"] / "room_auto"
    rc, err = _run(scene_argv(dict(inputs, probes=wide), room, inputs["camera"]) + ["--probe-circle", "auto"], capsys)
    assert rc == 0, err
    inner = np.hypot(*np.meshgrid(np.arange(256) - 127.5, np.arange(256) - 127.5)) < 110
    for k, f in enumerate(inputs["probes"]):
        a, b = cv2.imread(str(room / f"probe_{k:02d}.png")), cv2.imread(str(f))
        assert np.abs(a.astype(float) - b.astype(float))[inner].mean() < 12, k


@pytest.mark.parametrize("name", ["window_room", "lamps_room"])
def test_probe_pose_check_flags_the_turned_pose(name):
    """The benchmark probe agrees with the photo for its true pose and clearly better than for the
    pose turned 180 degrees; with a deliberately flipped shot-from point the check says so."""
    import cv2

    from lighting.probecheck import check_probe_pose
    from recon.assemble import light_probe_block, parse_primitives
    from recon.camera import Camera
    from tests.own_room import tape_room

    root = shared_scene(name)
    d = json.loads((root / "scene.json").read_text())
    cam = Camera.from_json(d["main_camera"], name, "main_camera.")
    prims, lo, hi = parse_primitives(tape_room(d), name)
    lp = d["light_probe"]
    c, s = np.array(lp["centre"]), np.array(lp["camera"]["centre"])
    imgs = [cv2.imread(str(root / f))[..., ::-1].copy() for f in lp["ldr_files"]]
    photo = cv2.imread(str(root / "background.png"))[..., ::-1].copy()
    res = {}
    for label, shot in (("true", s), ("flipped", c + (s - c) * np.array([-1, 1, -1]))):
        blk = light_probe_block(c, lp["radius"], shot, 256, lp["ldr_files"], lp["exposure_times"])
        res[label] = check_probe_pose(blk, shot, imgs, lp["exposure_times"], photo,
                                      d["main_camera"]["exposure_time"], cam, prims)
        print(name, label, res[label])
    assert not res["true"].turned_fits_better and res["true"].corr_given > 0.7
    assert res["flipped"].turned_fits_better


def test_probe_times_from_exif(inputs, capsys):
    """A bracket of JPEGs with EXIF ExposureTime needs no --probe-times; files given in any order
    are sorted shortest first."""
    import cv2

    jpgs = []
    for i, (f, t) in enumerate(zip(inputs["probes"], inputs["times"])):
        jpgs.append(inputs["tmp"] / f"ball_exif_{i}.jpg")
        jpgs[-1].write_bytes(_exif_jpeg(cv2.imread(str(f)), (int(round(t * 1e7)), 10 ** 7), 1))
    room = inputs["tmp"] / "room_exif_probe"
    argv = _replace(scene_argv(dict(inputs, probes=jpgs[::-1]), room, inputs["camera"]), "--probe-times", None)
    rc, err = _run(argv, capsys)
    assert rc == 0, err
    got = json.loads((room / "scene.json").read_text())["light_probe"]["exposure_times"]
    np.testing.assert_allclose(got, inputs["times"], rtol=1e-6)


def test_load_scene_refuses_a_missing_exposure_time(inputs, tmp_path):
    """A room folder whose main_camera has no exposure_time is refused, naming the field (it used
    to become 1.0 silently)."""
    from recon.scene import SceneError, load_scene

    room = tmp_path / "r"
    shutil.copytree(shared_scene("window_room"), room, ignore=shutil.ignore_patterns("views", "*.exr", "truth*"))
    d = json.loads((room / "scene.json").read_text())
    del d["main_camera"]["exposure_time"]
    (room / "scene.json").write_text(json.dumps(d))
    with pytest.raises(SceneError, match="main_camera.exposure_time"):
        load_scene(room, load_textures=False)


def test_model_output_as_primitives(inputs, capsys):
    """`photoar model`'s model.json (recon.primitives schema, scene-graph fields, default albedo)
    of the tape room gives the same geometry as the hand-written file."""
    from recon.primitives import load_model, save_model

    model_json = inputs["tmp"] / "model.json"
    save_model(model_json, load_model(inputs["room"]))
    rooms = {}
    for label, prims in (("hand", inputs["room"]), ("model", model_json)):
        room = inputs["tmp"] / f"room_{label}"
        argv = _replace(scene_argv(inputs, room, inputs["camera"]), "--primitives", str(prims))
        rc, err = _run(argv + ["--skip-probe-check"], capsys)
        assert rc == 0, err
        rooms[label] = json.loads((room / "scene.json").read_text())
    geo = lambda d: {p["name"]: (p.get("corners"), p.get("center"), p.get("size"), p["role"]) for p in d["primitives"]}
    a, b = geo(rooms["hand"]), geo(rooms["model"])
    assert a.keys() == b.keys()
    for k in a:
        for x, y in zip(a[k][:3], b[k][:3]):
            if x is not None:
                np.testing.assert_allclose(x, y, atol=1e-9, err_msg=k)
        assert a[k][3] == b[k][3]


def test_sun_option_writes_the_sun(inputs, capsys):
    """--sun-direction/--sun-irradiance (negative X written with '=') add FORMAT.md's sun entry,
    and the folder still loads (the sun is outside the room model)."""
    from recon.scene import load_scene

    room = inputs["tmp"] / "room_sun"
    argv = scene_argv(inputs, room, inputs["camera"]) + ["--skip-probe-check", "--sun-direction=-0.74,0.62,0.27",
                                                         "--sun-irradiance", "50,48,43"]
    rc, err = _run(argv, capsys)
    assert rc == 0, err
    sun = [p for p in json.loads((room / "scene.json").read_text())["primitives"] if p["type"] == "sun"]
    assert len(sun) == 1 and sun[0]["irradiance_perpendicular"] == [50.0, 48.0, 43.0]
    assert np.linalg.norm(sun[0]["direction_to_sun"]) == pytest.approx(1.0)
    load_scene(room)


def test_turned_box_becomes_the_shared_parsers_quads():
    """A furniture box turned by 30 degrees is written as six quads, the same faces recon.scene's
    box_quads gives for it (the one primitive parser); an axis-aligned box turned by 90 degrees
    stays a box with x and z swapped."""
    from recon.assemble import parse_primitives
    from recon.scene import box_quads

    room = {"name": "room", "type": "box", "role": "room", "center": [2, 1.3, 2], "size": [4, 2.6, 4]}
    turned = {"name": "t", "type": "box", "center": [2, 0.4, 2], "size": [1.0, 0.8, 0.5], "yaw_deg": 30}
    quarter = {"name": "q", "type": "box", "center": [1, 0.4, 1], "size": [1.0, 0.8, 0.5], "yaw_deg": 90}
    prims, lo, hi = parse_primitives({"primitives": [room, turned, quarter]}, "m.json")
    got = {p["name"]: p for p in prims}
    want = box_quads("t", np.array(turned["center"]), np.array(turned["size"]), np.radians(30), np.full(3, 0.5),
                     "furniture", lo, hi)
    assert len(want) == 6
    for q in want:
        np.testing.assert_allclose(got[q.name]["corners"], q.corners, atol=1e-12)
        np.testing.assert_allclose(got[q.name]["normal"], q.normal, atol=1e-12)
    assert got["q"]["type"] == "box"
    np.testing.assert_allclose(got["q"]["size"], [0.5, 0.8, 1.0], atol=1e-12)
    np.testing.assert_allclose(lo, [0, 0, 0])
    np.testing.assert_allclose(hi, [4, 2.6, 4])


@pytest.mark.parametrize("drift", [False, True])
def test_scene_checks_the_brackets_response(inputs, caplog, drift):
    """The probe bracket's recovered response is checked per channel against the bracket: window_room's
    bracket passes quietly; with green's gain drifting from shot to shot (x1.3, x0.8: a white balance
    that changed) one warning names green and its figure."""
    import logging

    from lighting import hdr
    from recon.io import read_image_rgb, write_png

    argv = scene_argv(inputs, inputs["tmp"] / f"room_resp_{drift}", inputs["camera"])
    if drift:
        gt = hdr.scene_true_response(shared_scene("window_room"))
        f = hdr.forward_table(gt)[1]
        probes = []
        for i, p in enumerate(inputs["probes"]):
            img = read_image_rgb(p)
            X = gt[img[..., 1], 1] * (1.0, 1.3, 0.8)[i % 3]
            img[..., 1] = np.where(img[..., 1] >= 254, 255, np.rint(255 * np.interp(np.clip(X, 0, 1),
                                                                                     np.arange(256) / 255.0, f)))
            probes.append(inputs["tmp"] / f"drift_{i}.png")
            write_png(probes[-1], img)
        i0 = argv.index("--probe") + 1
        argv[i0:i0 + len(probes)] = map(str, probes)
    with caplog.at_level(logging.WARNING, logger="photoar"):
        assert main(["-q", *argv, "--skip-probe-check"]) == 0
    w = [r.getMessage() for r in caplog.records if "camera response" in r.getMessage()]
    if drift:
        assert len(w) == 1 and "green channel" in w[0] and w[0].startswith(f"--probe {probes[0]}: "), w
    else:
        assert w == []


def test_camera_turned_about_y_lands_inside(inputs, caplog, capsys):
    """window_room's true camera with the floor axes' other sign (the world turned 180 deg about +Y: what
    calibrate gives when the room's +X runs leftwards in the photo) lies outside the taped room; scene
    turns it back, says so in one line, and writes the true pose into scene.json and camera.json."""
    import logging

    from recon.camera import Camera

    truth = benchmark_camera_json(inputs["scene"])
    F = np.diag([-1.0, 1.0, -1.0])
    flipped = {**truth, "R": (np.array(truth["R"]) @ F).tolist(), "centre": (F @ truth["centre"]).tolist()}
    cam = inputs["tmp"] / "in" / "camera_flipped.json"
    cam.write_text(json.dumps(flipped))
    room = inputs["tmp"] / "room_flipped"
    with caplog.at_level(logging.WARNING, logger="photoar"):
        rc, err = _run([*scene_argv(inputs, room, cam), "--skip-probe-check", "--no-refine-camera"], capsys)
    assert rc == 0, err
    w = [r.getMessage() for r in caplog.records if "turned 180 deg" in r.getMessage()]
    assert len(w) == 1 and w[0].startswith(f"{cam}: the camera centre") and "--flip-xz" in w[0], w
    d = json.loads((room / "scene.json").read_text())
    np.testing.assert_allclose(d["main_camera"]["R"], truth["R"], atol=1e-12)
    np.testing.assert_allclose(d["main_camera"]["t"], truth["t"], atol=1e-12)
    written = Camera.load(room / "camera.json")
    np.testing.assert_allclose(written.R, truth["R"], atol=1e-12)
    np.testing.assert_allclose(written.centre, truth["centre"], atol=1e-9)


def test_camera_outside_either_way_is_refused(inputs, capsys):
    # moved 20 m along +X: outside the room and turned too; one error line, nothing written
    truth = benchmark_camera_json(inputs["scene"])
    C = np.array(truth["centre"]) + [20.0, 0, 0]
    far = {**truth, "t": (-np.array(truth["R"]) @ C).tolist(), "centre": C.tolist()}
    cam = inputs["tmp"] / "in" / "camera_far.json"
    cam.write_text(json.dumps(far))
    room = inputs["tmp"] / "room_far"
    rc, err = _run([*scene_argv(inputs, room, cam), "--skip-probe-check"], capsys)
    assert rc == 2 and len(err.strip().splitlines()) == 1 and "check the calibration's scale" in err, err
    assert not room.exists()
