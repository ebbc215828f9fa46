"""README "Your own room": its commands, taken verbatim from the block after the
`own-room-walkthrough` marker, run on files made from a shared scene (the walkthrough's
placeholder names: photo.png, lines.json, clicks.json, ball_N.png, object.ply; the measurements as
the shell variables the README sets)."""
import json
import os
import re
import subprocess
import sys

from tests.conftest import ROOT, score, shared_scene
from tests.own_room import fmt, write_inputs

MARKER = "<!-- own-room-walkthrough"


def walkthrough_commands() -> list[str]:
    """The commands of the README's walkthrough block, continuation lines joined."""
    text = (ROOT / "README.md").read_text()
    i = text.index(MARKER)
    block = re.search(r"```sh\n(.*?)```", text[i:], re.S).group(1)
    return [c.strip() for c in block.replace("\\\n", " ").splitlines() if c.strip() and not c.startswith("#")]


def test_walkthrough_is_generic():
    cmds = walkthrough_commands()
    assert [c.split()[1] for c in cmds] == ["calibrate", "model", "hdr", "scene", "composite"]
    for c in cmds:  # measurements come from the shell variables, never from a constant of one room
        assert not re.search(r"(?<![\w_])\d", c), c


def test_walkthrough_runs(tmp_path, own_room_cache):
    root = shared_scene("window_room")
    inp = write_inputs(root, tmp_path)
    env = dict(os.environ, PYTHONPATH=str(ROOT), PHOTOAR_CACHE=str(own_room_cache),
               CAMERA_HEIGHT=repr(inp["height"]), PHOTO_TIME=repr(inp["exposure"]),
               BALL_TIMES=" ".join(map(repr, inp["times"])), BALL_CENTRE=fmt(inp["centre"]),
               BALL_RADIUS=repr(inp["radius"]), BALL_SHOT_FROM=fmt(inp["shot_from"]), PLACE=fmt(inp["place"]),
               YAW=repr(inp["yaw"]), OBJECT_ALBEDO=fmt(inp["albedo"]))
    prelude = f'photoar() {{ "{sys.executable}" -m app.cli -q "$@"; }}\n'
    for cmd in walkthrough_commands():
        r = subprocess.run(["bash", "-c", prelude + cmd], cwd=tmp_path, env=env, capture_output=True, text=True)
        assert r.returncode == 0, f"{cmd}\n{r.stderr}"
    d = json.loads((tmp_path / "room" / "scene.json").read_text())
    assert len(d["light_probe"]["ldr_files"]) == len(inp["times"])
    s = score(root, tmp_path / "out" / "composite.png")
    print(json.dumps(s))
    assert s["spurious"] < 0.01 and 0.8 <= s["energy_ratio"] <= 1.25
