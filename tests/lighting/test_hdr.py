"""HDR: response recovery and merging (lighting/hdr.py) against the scenes' true response and
probe_truth.exr; the real Memorial Church bracket; `photoar hdr`; hard cases."""
import json

import numpy as np
import pytest

from lighting import hdr
from recon.io import read_exr, read_image_rgb, write_exr
from tests.conftest import SHARED, shared_scene


def main(argv):
    from app.cli import main as cli_main  # imported late: the CLI pulls in the whole engine

    return cli_main(argv)


def _bracket(scene_dir):
    paths, times, _ = hdr.scene_probe_files(scene_dir)
    return [read_image_rgb(p) for p in paths], times


def _median_rel_err(rad, truth, valid):
    r, t = rad[valid].astype(np.float64), truth[valid].astype(np.float64)
    k = np.median(t / np.maximum(r, 1e-12))  # one global scale
    return float(np.median(np.abs(k * r - t) / np.maximum(t, 1e-12))), float(k)


@pytest.mark.parametrize("name", ["window_room", "lamps_room"])
def test_scene_bracket_recovered_response(name):
    # recovered response: merge within 5 % of probe_truth.exr, response within 3 levels of the truth
    d = shared_scene(name)
    images, times = _bracket(d)
    truth = read_exr(d / "probe_truth.exr")
    rad, g = hdr.merge_bracket(images, times)
    assert rad.shape == truth.shape and rad.dtype == np.float32
    err, k = _median_rel_err(rad, truth, hdr.valid_mask(images))
    assert err < 0.05
    assert abs(k - 1) < 0.05  # normalisation g(255) = 1 lands in the scene's units
    lev = hdr.response_level_error(g, hdr.scene_true_response(d))
    assert lev.max() <= 3.0, lev
    assert np.all(np.diff(g, axis=0) >= 0) and g[0].max() == 0 and np.allclose(g[255], 1)


@pytest.mark.parametrize("name", ["window_room", "lamps_room"])
def test_scene_probe_with_true_response_in_scene_units(name):
    # the true inverse_table (3 x 256 as in scene.json) gives the scene's radiance units directly
    d = shared_scene(name)
    truth = read_exr(d / "probe_truth.exr")
    rad = hdr.load_scene_probe(d, hdr.scene_true_response(d).T)
    images, _ = _bracket(d)
    valid = hdr.valid_mask(images)
    r, t = rad[valid], truth[valid]
    assert np.median(np.abs(r - t) / t) < 0.01


def test_memorial_church_bracket():
    # real film bracket: monotone response, finite radiance, merged radiance follows the exposures
    md = SHARED / "data" / "exposures" / "memorial"
    if not (md / "times.json").is_file():
        pytest.skip(f"{md} not available (../shared is absent)")
    tj = json.loads((md / "times.json").read_text())["images"]
    images = [read_image_rgb(md / f)[::2, ::2] for f in tj]
    times = list(tj.values())
    rad, g = hdr.merge_bracket(images, times, method="robertson")  # see the report: MergeDebevec's triangle
    # weights let the film's fog level (z ~ 14-17 in every short exposure) bias it by tens of levels
    assert np.all(np.isfinite(rad)) and rad.min() > 0
    assert np.all(np.diff(g, axis=0) >= 0) and np.all(np.diff(g[1:], axis=0) > 0)
    # re-exposing the merged radiance through the recovered response reproduces each exposure
    border = np.any([np.all(im == (0, 0, 255), axis=-1) for im in images], axis=0)  # blue mat of some PNGs
    lv = np.arange(256.0)
    for k in (0, 3, 6, 9):
        z = images[k].astype(np.float64)
        pred = np.stack([np.interp(rad[..., c] * times[k], g[:, c], lv) for c in range(3)], -1)
        ok = (z > 40) & (z < 220) & ~border[..., None]
        assert np.median(np.abs(pred - z)[ok]) < 8.0


def test_cli_hdr_writes_outputs(tmp_path):
    # a synthetic 3-exposure bracket through a gamma response: outputs, tables and recovered scale
    rng = np.random.default_rng(1)
    L = np.exp(rng.uniform(np.log(0.02), np.log(4.0), (64, 96, 3))).astype(np.float32)
    times = [0.0625, 0.25, 1.0]
    paths = []
    from recon.io import write_png

    for i, t in enumerate(times):
        z = np.rint(255 * np.clip(L * t, 0, 1) ** (1 / 2.2)).astype(np.uint8)
        paths.append(tmp_path / f"e{i}.png")
        write_png(paths[-1], z)
    out = tmp_path / "out"
    assert main(["-q", "hdr", *map(str, paths), "--times", "1/16", "0.25", "1", "--out", str(out)]) == 0
    assert {p.name for p in out.iterdir()} == {"radiance.exr", "response.json", "response.png"}
    resp = json.loads((out / "response.json").read_text())
    assert np.array(resp["forward_table"]).shape == (3, 256) and np.array(resp["inverse_table"]).shape == (3, 256)
    rad = read_exr(out / "radiance.exr")
    valid = L * times[0] <= 0.98
    assert np.median(np.abs(rad[valid] - L[valid]) / L[valid]) < 0.02
    gt = (np.arange(256) / 255.0) ** 2.2
    assert np.abs(np.array(resp["inverse_table"]) - gt).max() < 0.01


def test_one_exposure_is_a_clear_error(tmp_path):
    z = np.full((8, 8, 3), 128, np.uint8)
    with pytest.raises(ValueError, match="at least 2 exposures"):
        hdr.merge_bracket([z], [0.1])
    from recon.io import write_png

    write_png(tmp_path / "a.png", z)
    out = tmp_path / "out"
    assert main(["-q", "hdr", str(tmp_path / "a.png"), "--times", "0.1", "--out", str(out)]) == 2
    assert not out.exists()


def test_bad_brackets_are_clear_errors():
    z = np.full((8, 8, 3), 128, np.uint8)
    with pytest.raises(ValueError, match="size"):
        hdr.merge_bracket([z, np.zeros((8, 9, 3), np.uint8)], [0.1, 0.4])
    with pytest.raises(ValueError, match="finite and positive"):
        hdr.merge_bracket([z, z], [0.1, float("nan")])
    with pytest.raises(ValueError, match="NaN"):
        hdr.merge_bracket([z.astype(np.float32) * np.nan, z], [0.1, 0.4])
    with pytest.raises(ValueError, match="NaN"):
        hdr.merge_bracket([z, z], [0.1, 0.4], response=np.full((256, 3), np.nan))
    with pytest.raises(ValueError, match="2 images but 3"):
        hdr.merge_bracket([z, z], [0.1, 0.4, 1.6])


def test_saturated_pixels_are_flagged_and_stay_finite():
    # a source brighter than the shortest exposure can record: flagged, finite, a lower bound
    L = np.full((16, 16, 3), 0.5, np.float32)
    L[4:6, 4:6] = 1e4
    times = [0.01, 0.04, 0.16, 0.64]
    imgs = [np.rint(255 * np.clip(L * t, 0, 1) ** (1 / 2.2)).astype(np.uint8) for t in times]
    g = np.tile(((np.arange(256) / 255.0) ** 2.2)[:, None], (1, 3))
    rad, _ = hdr.merge_bracket(imgs, times, g)
    sat = hdr.saturated_mask(imgs, times)
    assert sat[4:6, 4:6].all() and sat.sum() == 4
    assert np.all(np.isfinite(rad)) and np.all(rad[4:6, 4:6] >= 0.9 / times[0])
    assert np.allclose(rad[~sat], 0.5, rtol=0.02)


def test_hdr_file_formats_and_bad_exr(tmp_path):
    # .pfm / .hdr load like the EXR; missing channels and NaN are clear errors naming the file
    pd = SHARED / "data" / "probes"
    if (pd / "grace_latlong.exr").is_file():
        exr = hdr.load_radiance(pd / "grace_latlong.exr")
        assert np.array_equal(hdr.load_radiance(pd / "grace_latlong.pfm"), exr)
        rel = np.abs(hdr.load_radiance(pd / "grace_latlong.hdr") - exr) / np.maximum(exr, 1e-3)
        assert np.median(rel) < 0.01
    import OpenEXR

    hdr_ = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with OpenEXR.File(hdr_, {"R": np.ones((4, 4), np.float32), "G": np.ones((4, 4), np.float32)}) as f:
        f.write(str(tmp_path / "rg.exr"))
    with pytest.raises(ValueError, match=r"rg\.exr.*no B channel"):
        hdr.load_radiance(tmp_path / "rg.exr")
    bad = np.ones((4, 4, 3), np.float32)
    bad[1, 2, 0] = np.nan
    write_exr(tmp_path / "nan.exr", bad)
    with pytest.raises(ValueError, match=r"nan\.exr.*NaN"):
        hdr.load_radiance(tmp_path / "nan.exr")
    with pytest.raises(FileNotFoundError):
        hdr.load_radiance(tmp_path / "absent.exr")


def _gamma_bracket(tmp_path, green_gains=(1.0, 1.0, 1.0)):
    """A synthetic 3-exposure bracket through a gamma-2.2 response; green's exposure scaled per shot by
    `green_gains` (a shot whose green gain drifted: no one curve maps its levels to X = L t)."""
    from recon.io import write_png

    rng = np.random.default_rng(1)
    L = np.exp(rng.uniform(np.log(0.02), np.log(4.0), (64, 96, 3))).astype(np.float32)
    times = [0.0625, 0.25, 1.0]
    paths = []
    for i, (t, k) in enumerate(zip(times, green_gains)):
        X = L * t
        X[..., 1] *= k
        paths.append(tmp_path / f"e{i}.png")
        write_png(paths[-1], np.rint(255 * np.clip(X, 0, 1) ** (1 / 2.2)).astype(np.uint8))
    return paths, times


def _warnings(caplog):
    return [r.getMessage() for r in caplog.records if r.levelno >= 30]


def test_response_check_flags_a_broken_channel(caplog):
    # lamps_room's bracket merged with its true response: every channel's exposures agree with the merge
    # to about a level; with green's curve broken (g^1.5: 8 % off at level 128) green disagrees by many levels
    import logging

    scene = shared_scene("lamps_room")
    images, times = _bracket(scene)
    gt = hdr.scene_true_response(scene)
    good = hdr.channel_residuals(images, times, gt)
    assert np.all(good < 1.0), good
    broken = gt.copy()
    broken[:, 1] = gt[:, 1] ** 1.5
    bad = hdr.channel_residuals(images, times, broken)
    assert bad[1] > 5.0 and np.all(np.abs(bad[[0, 2]] - good[[0, 2]]) < 0.05), (good, bad)
    with caplog.at_level(logging.WARNING, logger="photoar"):
        assert hdr.warn_unfit_channel(good, "ball") is None
        assert hdr.warn_unfit_channel(bad, "ball") == 1
    w = _warnings(caplog)
    assert len(w) == 1 and w[0].startswith("ball: ") and "green channel" in w[0] and f"{bad[1]:.1f} levels" in w[0]


@pytest.mark.parametrize("gains", [(1.0, 1.0, 1.0), (1.0, 1.6, 0.7)])
def test_cli_hdr_warns_when_one_channel_does_not_fit(tmp_path, caplog, gains):
    import logging

    paths, times = _gamma_bracket(tmp_path, gains)
    out = tmp_path / "out"
    with caplog.at_level(logging.WARNING, logger="photoar"):
        assert main(["-q", "hdr", *map(str, paths), "--times", *map(str, times), "--out", str(out)]) == 0
    r = json.loads((out / "response.json").read_text())["channel_residual_levels"]
    w = [m for m in _warnings(caplog) if "camera response" in m]
    if gains[1] == 1.0:
        assert max(r) < 2.0 and w == [], (r, w)
    else:
        assert r[1] > 3 * max(r[0], r[2]), r
        assert len(w) == 1 and w[0].startswith(f"{paths[0]}: ") and "green channel" in w[0], w
