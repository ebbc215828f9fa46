"""Quiet, clean output: a normal run prints no library noise (Warp's missing-driver line, Open3D's
warnings, the bytes of a garbage mesh file), and its JSON outputs are valid JSON.

Warp prints its line from native code once per process, at initialisation, which an in-process
test would not see again: those runs are subprocesses."""
import json
import os
import subprocess
import sys

import pytest

from tests.conftest import ROOT

NOISE = ("Warp", "CUDA", "Open3D", "RPly", "WARNING")


def run(*args: str, timeout: float = 600) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    return subprocess.run([sys.executable, *args], cwd=ROOT, env=env, capture_output=True, text=True,
                          timeout=timeout)


def strict_json(text: str):
    def refuse(const):
        raise ValueError(f"not valid JSON: {const}")

    return json.loads(text, parse_constant=refuse)


def test_warp_initialisation_is_silent():
    r = run("-c", "from kernels import runtime; print(runtime.device())")
    assert r.returncode == 0 and r.stdout.strip() == "cpu"
    assert r.stderr == "", r.stderr


def test_quiet_demo_run_prints_only_its_result(tmp_path):
    """`photoar -q demo` (coarse settings to keep it short): stderr empty, one stdout line, and
    report.json valid JSON. Without -q the log lines are photoar's own, none from a library."""
    out = tmp_path / "demo"
    coarse = ["--patch-size", "0.6", "--map-res", "64", "--passes", "2", "--cache", str(tmp_path / "cache")]
    r = run("-m", "app.cli", "-q", "demo", "--out", str(out), *coarse)
    assert r.returncode == 0, r.stderr
    assert r.stderr == "", r.stderr
    assert r.stdout.splitlines() == [r.stdout.strip()] and "composite.png" in r.stdout
    strict_json((out / "report.json").read_text())
    r = run("-m", "app.cli", "demo", "--out", str(tmp_path / "demo2"), *coarse)  # warm cache: short
    assert r.returncode == 0, r.stderr
    assert not [ln for ln in r.stderr.splitlines() if any(n in ln for n in NOISE)], r.stderr
    # a warm run says what it wrote, not which caches it read
    assert len(r.stderr.splitlines()) == 1 and r.stderr.startswith("wrote "), r.stderr
    r = run("-m", "app.cli", "demo", "-v", "--out", str(tmp_path / "demo3"), *coarse)  # -v: the debug lines too
    assert r.returncode == 0, r.stderr
    assert any(ln.startswith("precompute: cache hit ") for ln in r.stderr.splitlines()), r.stderr
    assert not [ln for ln in r.stderr.splitlines() if any(n in ln for n in NOISE)], r.stderr


def test_first_run_says_the_kernels_compile(tmp_path):
    """An empty Warp kernel cache (a first run after installing) is announced, since the first
    precompute and frame then take minutes of compiling; a filled one is not."""
    code = "from kernels import runtime; runtime.device(); print(runtime.kernel_cache_cold())"
    env = dict(os.environ, WARP_CACHE_PATH=str(tmp_path / "empty"))
    r = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=dict(env, PYTHONPATH=str(ROOT)),
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and r.stdout.strip() == "True", r.stderr
    r = subprocess.run([sys.executable, "-c", "import logging; logging.basicConfig(level=logging.INFO, "
                        "format='%(message)s'); " + code], cwd=ROOT, env=dict(env, PYTHONPATH=str(ROOT)),
                       capture_output=True, text=True, timeout=120)
    assert r.stderr.startswith("first run: Warp compiles photoar's kernels"), r.stderr
    built = tmp_path / "built"
    import warp as wp  # Warp keeps each version's builds in a folder named for it

    (built / wp.config.version / "wp_kernels.raycast_0123abc").mkdir(parents=True)  # a compiled module's folder
    r = subprocess.run([sys.executable, "-c", code], cwd=ROOT,
                       env=dict(os.environ, WARP_CACHE_PATH=str(built), PYTHONPATH=str(ROOT)),
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and r.stdout.strip() == "False", r.stderr


@pytest.mark.parametrize("content", [
    bytes(range(256)) * 2,  # binary garbage: RPly says "Wrong magic number"
    b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nend_header\n\x01\x02\xff\x1b[31mred\n",
])
def test_garbage_mesh_gives_one_clean_line(tmp_path, capfd, content):
    """In-process; capfd sees the file descriptors, so native (C-level) output counts too."""
    from app.cli import main

    mesh = tmp_path / "garbage.ply"
    mesh.write_bytes(content)
    out = tmp_path / "out"
    code = main(["composite", str(ROOT / "app" / "demo"), "--object", str(mesh), "--out", str(out),
                 "--cache", str(tmp_path / "cache")])
    r = capfd.readouterr()
    assert code == 2
    lines = r.err.splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"photoar: error: {mesh}: "), r.err
    assert lines[0].isprintable() and lines[0].isascii()
    assert r.out == "" and not out.exists()


@pytest.mark.parametrize("name, said", [("background.png", "libpng error: Read Error"),
                                        ("photo.jpg", "Premature end of JPEG file")])
def test_truncated_image_gives_one_clean_line(tmp_path, capfd, name, said):
    """A photo cut short: photoar's one error line, which carries the decoder's complaint; nothing
    else on either descriptor (libpng and libjpeg print theirs from C). A truncated JPEG decodes
    with grey rows in place of the missing ones: refused too, not composited."""
    import shutil

    import cv2

    from app.cli import main

    scene = tmp_path / "scene"
    shutil.copytree(ROOT / "app" / "demo", scene)
    photo = scene / "background.png"
    if name.endswith(".jpg"):
        assert cv2.imwrite(str(tmp_path / "full.jpg"), cv2.imread(str(photo)))
        data = (tmp_path / "full.jpg").read_bytes()
    else:
        data = photo.read_bytes()
    photo.write_bytes(data[:len(data) // 2])  # the demo reads background.png whatever its format
    out = tmp_path / "out"
    code = main(["composite", str(scene), "--out", str(out), "--cache", str(tmp_path / "cache")])
    r = capfd.readouterr()
    assert code == 2
    assert r.err.splitlines() == [f"photoar: error: {photo}: " + ("not a readable image" if name.endswith(".png") else
                                  "the image file is truncated") + f" (decoder: {said})"], r.err
    assert r.out == "" and not out.exists()


def test_sun_estimate_is_one_short_line():
    """The captured sun estimate is logged as one short line (report.json holds the whole dict)."""
    from app.engine import _sun_estimate_line

    info = {"direction": [-0.7431366189590701, 0.6135873509593606, 0.2669429308012415],
            "irradiance_perpendicular": [48.93954818444531, 45.40802324294877, 39.974155939910275],
            "direction_error_deg": 0.24265392746991737, "strength_ratio": 0.9342805673771398}
    assert _sun_estimate_line(info) == ("sun estimate: direction (-0.743, 0.614, 0.267), irradiance (48.9, 45.4, 40); "
                                        "0.24 deg and 0.93x against the declared sun")
    assert _sun_estimate_line({"reason": "no opening"}) == "sun estimate: no sun (no opening)"


def test_reconstruct_folder_with_truncated_photos_is_quiet(tmp_path, capfd, caplog):
    """A photo folder with a truncated PNG and JPEG: each left out with photoar's warning (the JPEG,
    which libjpeg would decode with grey rows, as truncated), then photoar's one error (too few
    photos); the decoders' own lines reach neither descriptor."""
    import cv2
    import numpy as np

    from app.cli import main

    folder = tmp_path / "photos"
    folder.mkdir()
    img = np.random.default_rng(0).integers(0, 255, (240, 320, 3), dtype=np.uint8)
    for ext in (".png", ".jpg"):
        assert cv2.imwrite(str(tmp_path / f"full{ext}"), img)
        data = (tmp_path / f"full{ext}").read_bytes()
        (folder / f"cut{ext}").write_bytes(data[:len(data) // 2])
    with caplog.at_level("WARNING"):
        assert main(["-q", "reconstruct", str(folder), "--out", str(tmp_path / "out")]) == 2
    r = capfd.readouterr()
    assert r.out == "" and len(r.err.splitlines()) == 1, r.err
    assert r.err.startswith(f"photoar: error: {folder}: need at least 2 readable images, found 0"), r.err
    assert any("cut.jpg: the image file is truncated; left out" in m for m in caplog.messages), caplog.messages


def test_reconstruct_view_png_is_quiet(tmp_path):
    """`reconstruct`'s view.png through Open3D's window on a private Xvfb: GLFW/Mesa's own lines
    (e.g. "XDG_RUNTIME_DIR is invalid") are held back; a subprocess, since they come from C."""
    code = ("import numpy as np; from recon.view import render_png; from recon.camera import Camera; "
            "cam = Camera(np.array([[500, 0, 320], [0, 500, 240], [0, 0, 1.0]]), np.eye(3), "
            "np.array([0, -1.5, 4.0]), 640, 480); "
            f"print(render_png({str(tmp_path / 'view.png')!r}, np.random.default_rng(0).uniform(-1, 1, (200, 3)), "
            "None, {'a': cam}, [], size=(320, 240)))")
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "XDG_RUNTIME_DIR")}
    r = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=dict(env, PYTHONPATH=str(ROOT)),
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert r.stderr == "", r.stderr
    assert r.stdout.strip() in ("open3d-xvfb", "cv2-projection") and (tmp_path / "view.png").is_file(), r.stdout


@pytest.mark.parametrize("op", ["reinhard", "drago", "mantiuk"])
def test_tonemap_prints_only_its_result(tmp_path, op):
    """OpenCV's tone mappers log an internal "multi-channel arrays" warning from C++ (once per
    process, hence a subprocess): not shown."""
    import numpy as np

    from recon.io import write_exr

    write_exr(tmp_path / "x.exr", np.random.default_rng(0).uniform(0.01, 20.0, (48, 64, 3)).astype(np.float32))
    r = run("-m", "app.cli", "tonemap", str(tmp_path / "x.exr"), "--op", op, "--out", str(tmp_path / "x.png"))
    assert r.returncode == 0, r.stderr
    assert r.stderr == "" and r.stdout.strip() == str(tmp_path / "x.png"), (r.stdout, r.stderr)
