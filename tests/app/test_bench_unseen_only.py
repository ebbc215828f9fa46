"""bench_unseen --only: held-out rooms beyond the fixed seeds, and a clear usage error for a bad name."""
import argparse

import pytest

from bench.bench_unseen import SPP, parse_room_name


def _parser() -> argparse.ArgumentParser:
    return argparse.ArgumentParser(prog="bench_unseen.py")


def test_a_held_out_name_is_its_kind_and_seed():
    assert parse_room_name("sun_104", _parser()) == ("sun", 104)
    assert parse_room_name("window_7", _parser()) == ("window", 7)


@pytest.mark.parametrize("name", ["foo", "sun_x", "mixed_3", "sun_", "_104"])
def test_a_bad_name_is_a_usage_error_naming_it(name, capsys):
    with pytest.raises(SystemExit) as e:
        parse_room_name(name, _parser())
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert f"--only: {name!r} is not KIND_SEED" in err and all(k in err for k in SPP)
    assert "Traceback" not in err
