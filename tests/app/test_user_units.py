"""Values in the units people write: shutter speeds, sRGB hex colours, camera heights in metres
(with centimetres and feet caught at the command line, not later by `scene`)."""
import pytest

from app.cli import build_parser


def _refused(capsys, argv: list[str]) -> str:
    """The one error line of an argument refused by the parser (exit status 2)."""
    with pytest.raises(SystemExit) as e:
        build_parser().parse_args(argv)
    assert e.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    return err

SCENE = ["scene", "room", "--photo", "p.jpg", "--camera", "camera.json", "--primitives", "model.json"]


@pytest.mark.parametrize("written, secs", [("1/250", 0.004), ("0.004", 0.004), ("4ms", 0.004), ("4 ms", 0.004),
                                          ("1/250s", 0.004), ("250us", 250e-6), ("2s", 2.0), ("2", 2.0)])
def test_exposure_time_as_written(written, secs):
    a = build_parser().parse_args(SCENE + ["--exposure-time", written, "--probe-times", written, "1/60"])
    # Each form is one exact fraction rounded to a double once, so "1/250", "4ms" and "0.004" are the
    # same double as the literal 0.004: exact by construction (a tolerance would hide a unit slip).
    assert a.exposure_time == secs
    assert a.probe_times == [secs, 1 / 60]
    h = build_parser().parse_args(["hdr", "a.jpg", "b.jpg", "--times", written, "1/60", "--out", "o"])
    assert h.times == [secs, 1 / 60]


@pytest.mark.parametrize("bad", ["0", "-1/250", "1/0", "fast", "4 min", "nan"])
def test_exposure_time_refused_in_one_line(capsys, bad):
    err = _refused(capsys, SCENE + ["--exposure-time", bad])
    assert err.startswith("photoar scene: error: argument --exposure-time"), err
    assert repr(bad) in err
    err = _refused(capsys, SCENE + ["--probe-times", "1/60", bad])
    assert err.startswith("photoar scene: error: argument --probe-times") and repr(bad) in err, err


def test_object_colour_is_srgb_hex_made_linear():
    # The sRGB EOTF's published values: code 128 -> 0.2158605, 255 -> 1, 10 -> 10/255/12.92 (linear toe).
    a = build_parser().parse_args(["composite", "s", "--out", "o", "--object-colour", "#80ff0a"])
    assert a.object_albedo == pytest.approx((0.2158605, 1.0, 10 / 255 / 12.92), abs=1e-7)
    b = build_parser().parse_args(["gui", "s", "--object-color", "b4966a"])
    assert b.object_albedo == pytest.approx((0.4564, 0.3050, 0.1441), abs=1e-4)
    short = build_parser().parse_args(["composite", "s", "--out", "o", "--object-colour", "#fff"])
    assert short.object_albedo == pytest.approx((1.0, 1.0, 1.0), abs=1e-12)


def test_object_colour_and_albedo_exclusive(capsys):
    err = _refused(capsys, ["composite", "s", "--out", "o", "--object-colour", "#b4966a", "--object-albedo", "0.5,0.5,0.5"])
    assert "not allowed with" in err, err
    err = _refused(capsys, ["composite", "s", "--out", "o", "--object-colour", "#b4966"])
    assert "sRGB hex colour" in err and "'#b4966'" in err, err


@pytest.mark.parametrize("given, meant, unit", [("170", "1.70", "centimetres"), ("5.6", "1.71", "feet"),
                                                ("1550", "1.55", "millimetres")])
def test_calibrate_height_in_other_units_is_refused(capsys, given, meant, unit):
    err = _refused(capsys, ["calibrate", "photo.jpg", "--lines", "lines.json", "--height", given, "--out", "o"])
    assert err.startswith("photoar calibrate: error:"), err
    assert f"did you mean {meant} m ({given} {unit})?" in err, err
    assert f"did you mean {meant} m" in _refused(capsys, ["reconstruct", "photos", "--out", "o", "--camera-height", given])


@pytest.mark.parametrize("h", ["0.3", "1.55", "3"])
def test_calibrate_height_in_metres_accepted(h):
    a = build_parser().parse_args(["calibrate", "photo.jpg", "--lines", "lines.json", "--height", h, "--out", "o"])
    assert a.scale_height == pytest.approx(float(h), abs=0)  # parsed from the same text: exact


def test_height_too_small_for_any_unit(capsys):
    err = _refused(capsys, ["calibrate", "photo.jpg", "--lines", "lines.json", "--height", "0.1", "--out", "o"])
    assert "between 0.3 and 3" in err and "did you mean" not in err, err
